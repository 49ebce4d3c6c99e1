//! The alarm stream as the OPC UA server's events: every alarm and source outage event
//! the history records ([`History::alarms`](crate::state::history::History::alarms),
//! with or without a file), on the object it is about. The events are the history's:
//! what a client is told is what the history keeps, at the time it keeps.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use super::model::{AlarmEventSpec, ConditionSpec};
use crate::state::catalogue::{self, AlarmKind, Figure, Subject, SubjectKind};
use crate::state::events::{AlarmEvent, AlarmRecord, HistoryEvent};
use crate::state::results::Results;
use crate::state::time::UtcTime;

/// Severity of warnings (OPC UA: medium).
pub(super) const WARNING_SEVERITY: u16 = 500;
/// Severity of latched alarms and unstable spans (OPC UA: medium high).
pub(super) const ALARM_SEVERITY: u16 = 800;
/// Severity of a stale source.
const STALE_SEVERITY: u16 = 600;
/// Severity of a lost source and of the slow-down request.
const LOST_SEVERITY: u16 = 700;

/// A source's condition while it is stale (no fresh sample within its stale time).
const SOURCE_STALE: &str = "source_stale";
/// A source's condition while it is lost (no answer within its lost time).
const SOURCE_LOST: &str = "source_lost";

/// The conditions of a source: its outages, stale or lost (not latched).
pub(super) fn source_conditions() -> Vec<ConditionSpec> {
    [
        (
            SOURCE_STALE,
            "The source is stale: its figures are withdrawn or marked",
        ),
        (SOURCE_LOST, "The source is lost: it does not answer"),
    ]
    .into_iter()
    .map(|(kind, description)| ConditionSpec {
        kind: kind.into(),
        description: description.into(),
        latched: false,
    })
    .collect()
}

/// The severity of an alarm of `kind`.
fn severity(kind: AlarmKind) -> u16 {
    match kind {
        AlarmKind::SlowDownRequest => LOST_SEVERITY,
        AlarmKind::Unstable => ALARM_SEVERITY,
        kind if kind.latched() => ALARM_SEVERITY,
        _ => WARNING_SEVERITY,
    }
}

/// The objects events are about, by name, and what each source's open outage is.
#[derive(Debug, Clone)]
pub(super) struct EventObjects {
    /// Per subject kind, (name, object index).
    pub(super) drivelines: Vec<(String, usize)>,
    pub(super) tandem_mills: Vec<(String, usize)>,
    pub(super) rod_mills: Vec<(String, usize)>,
    pub(super) sources: Vec<(String, usize)>,
    /// Per source: the kind of the event its open outage raised.
    outages: Vec<Option<&'static str>>,
}

impl EventObjects {
    /// The objects of drivelines, tandem mills, rod mills and sources, (name, object
    /// index) each, in config order.
    pub(super) fn new(
        drivelines: Vec<(String, usize)>,
        tandem_mills: Vec<(String, usize)>,
        rod_mills: Vec<(String, usize)>,
        sources: Vec<(String, usize)>,
    ) -> Self {
        let outages = vec![None; sources.len()];
        Self {
            drivelines,
            tandem_mills,
            rod_mills,
            sources,
            outages,
        }
    }

    /// The server's events of `event` (none for an event that is not the alarm
    /// stream's, or of a subject the address space does not have); `results` give the
    /// message its context (the figures behind it now).
    pub(super) fn events(
        &mut self,
        event: &HistoryEvent,
        results: &Results,
    ) -> Vec<AlarmEventSpec> {
        match event {
            HistoryEvent::Alarm(alarm) => self.alarm(alarm, results).into_iter().collect(),
            HistoryEvent::OutageStarted {
                time,
                source,
                status,
            } => {
                let kind = if *status == "lost" {
                    SOURCE_LOST
                } else {
                    SOURCE_STALE
                };
                self.outage(source, Some(kind), to_system(*time))
            }
            HistoryEvent::OutageWorse { source } => {
                self.outage(source, Some(SOURCE_LOST), SystemTime::now())
            }
            HistoryEvent::OutageEnded { time, source, .. } => {
                self.outage(source, None, to_system(*time))
            }
            _ => Vec::new(),
        }
    }

    fn alarm(&self, alarm: &AlarmRecord, results: &Results) -> Option<AlarmEventSpec> {
        let kind = alarm.kind;
        let find = |objects: &[(String, usize)]| {
            objects
                .iter()
                .enumerate()
                .find(|(_, (name, _))| *name == alarm.subject)
                .map(|(k, (_, object))| (k, *object))
        };
        let (object, context) = match kind.subject() {
            SubjectKind::Driveline => {
                let (k, object) = find(&self.drivelines)?;
                (
                    object,
                    context(results.drivelines.get(k), &["taf", "gap_mrad"]),
                )
            }
            SubjectKind::TandemMill => {
                let (k, object) = find(&self.tandem_mills)?;
                let keys = ["gain_ratio", "worst_stand"];
                (object, context(results.tandem_mills.get(k), &keys))
            }
            SubjectKind::RodMill => {
                let (k, object) = find(&self.rod_mills)?;
                let keys = ["worst_span", "worst_margin_m_s"];
                (object, context(results.rod_mills.get(k), &keys))
            }
            // No alarm kind is a span's, the gateway's or a source's (a source's
            // outages are events of their own).
            SubjectKind::RodSpan | SubjectKind::Gateway | SubjectKind::Source => return None,
        };
        let active = alarm.event == AlarmEvent::Raised;
        Some(AlarmEventSpec {
            object,
            kind: kind.name().into(),
            severity: severity(kind),
            message: format!(
                "{}: {} {}{context}",
                alarm.subject,
                kind.name(),
                alarm.event.name()
            ),
            active,
            unacknowledged: active && kind.latched(),
            time: to_system(alarm.time),
        })
    }

    /// The events of source `name`'s outage becoming `now` (`None`: ended): the kind
    /// raised before cleared, the new one raised.
    fn outage(
        &mut self,
        name: &str,
        now: Option<&'static str>,
        time: SystemTime,
    ) -> Vec<AlarmEventSpec> {
        let Some(k) = self.sources.iter().position(|(source, _)| source == name) else {
            return Vec::new();
        };
        let object = self.sources[k].1;
        let before = std::mem::replace(&mut self.outages[k], now);
        let event = |kind: &'static str, active: bool| AlarmEventSpec {
            object,
            kind: kind.into(),
            severity: match kind {
                SOURCE_LOST => LOST_SEVERITY,
                _ => STALE_SEVERITY,
            },
            message: format!(
                "{name}: {kind} {}",
                if active { "raised" } else { "cleared" }
            ),
            active,
            unacknowledged: false,
            time,
        };
        let mut events = Vec::new();
        if before != now {
            events.extend(before.map(|kind| event(kind, false)));
            events.extend(now.map(|kind| event(kind, true)));
        }
        events
    }
}

fn to_system(time: UtcTime) -> SystemTime {
    let ms = time.unix_ms();
    match u64::try_from(ms) {
        Ok(ms) => UNIX_EPOCH + Duration::from_millis(ms),
        Err(_) => UNIX_EPOCH,
    }
}

/// `, key value unit` for each of `keys` of `subject` that has a good value.
fn context<R: Subject>(subject: Option<&R>, keys: &[&str]) -> String {
    let Some(subject) = subject else {
        return String::new();
    };
    keys.iter()
        .filter_map(|key| {
            let figure: &Figure<R> = catalogue::find(R::FIGURES, key);
            let value = figure.read(subject).good()?;
            let unit = if figure.unit.is_empty() {
                String::new()
            } else {
                format!(" {}", figure.unit)
            };
            Some(match value {
                catalogue::Value::Real(v) => format!(", {key} {v:.2}{unit}"),
                other => format!(", {key} {}{unit}", other.as_f64()),
            })
        })
        .collect()
}
