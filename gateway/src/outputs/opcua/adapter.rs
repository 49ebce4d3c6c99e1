//! Today's results ([`crate::outputs::results`]) as the OPC UA server's address space,
//! snapshots and alarm events: the one file that knows both. The catalogue of
//! published figures (key, unit, type, quality bit, stale rule) replaces it.
//!
//! The statuses follow the register map's rules: a value whose quality bit the map
//! clears is published without a value, its status saying why
//! ([`Quality::BadNoCommunication`] when its source is stale or lost,
//! [`Quality::BadWaitingForInitialData`] before the first bite or window,
//! [`Quality::BadDeviceFailure`] after a degraded bite, [`Quality::BadOutOfRange`] for
//! refused rod-mill inputs, [`Quality::BadNoData`] when the last computation gave
//! none); what the map keeps while a source is stale (the bite counter, the flags) is
//! published with [`Quality::UncertainLastUsableValue`]. Source timestamps: the bite
//! time for a driveline's figures, the time the adapter saw a new window or
//! evaluation for a mill's.

use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::Config;
use tokio::sync::{mpsc, watch};

use crate::field::source_health::SourceStatus;
use crate::outputs::history::events::CommandOrigin;
use crate::outputs::publisher::Publisher;
use crate::outputs::results::{
    DrivelineResults, GatewayState, MillResults, Results, RodMillResults, RodSpanResults,
};
use crate::shutdown::Shutdown;

use super::model::{
    AddressSpaceSpec, AlarmEventSpec, ObjectKind, ObjectSpec, Quality, Snapshot, Unit, Value,
    VariableSpec, VariableType, VariableUpdate,
};
use super::nodes::Acknowledger;

/// How often the results are read: the server's subscriptions sample no faster
/// (async-opcua's 100 ms subscription tick).
pub const FEED_PERIOD: Duration = Duration::from_millis(100);
/// Alarm events waiting for the server; more are dropped (and logged).
pub const EVENT_QUEUE: usize = 256;

/// Severity of warnings (OPC UA: medium).
const WARNING_SEVERITY: u16 = 500;
/// Severity of latched alarms and unstable spans (OPC UA: medium high).
const ALARM_SEVERITY: u16 = 800;
/// Severity of a stale source.
const STALE_SEVERITY: u16 = 600;
/// Severity of a lost source and of the slow-down request.
const LOST_SEVERITY: u16 = 700;

/// Where each part of the results sits in the spec.
#[derive(Debug, Clone)]
struct Layout {
    sources: Vec<usize>,
    drivelines: Vec<usize>,
    mills: Vec<usize>,
    rod_mills: Vec<(usize, Vec<usize>)>,
}

/// What the mapping needs of the configuration.
#[derive(Debug, Clone)]
pub struct ResultsAdapter {
    layout: Layout,
    driveline_names: Vec<String>,
    source_names: Vec<String>,
    mill_names: Vec<String>,
    rod_names: Vec<String>,
    /// Per driveline: whether it has a model (wear and gap figures).
    models: Vec<bool>,
    thresholds: Vec<millgate_config::DrivelineThresholds>,
    /// Per tandem mill: evaluations last seen and when.
    mill_seen: Vec<(u64, Option<SystemTime>)>,
    /// Per rod mill: evaluations last seen and when.
    rod_seen: Vec<(u64, Option<SystemTime>)>,
}

fn variable(
    key: &str,
    datatype: VariableType,
    unit: Option<Unit>,
    range: Option<(f64, f64)>,
    description: &str,
) -> VariableSpec {
    VariableSpec {
        key: key.into(),
        description: description.into(),
        unit,
        datatype,
        range,
    }
}

fn flag(key: &str, description: &str) -> VariableSpec {
    variable(key, VariableType::Boolean, None, None, description)
}

impl ResultsAdapter {
    /// The mapping of `config`'s results, its rod mills having `rod_spans` spans each;
    /// and the address space it fills.
    pub fn new(config: &Config, rod_spans: &[usize]) -> (Self, AddressSpaceSpec) {
        use VariableType::{Double, UInt32, UInt64};
        let mut objects = vec![ObjectSpec {
            name: "Gateway".into(),
            kind: ObjectKind::Gateway,
            parent: None,
            description: "The gateway's own state".into(),
            variables: vec![
                variable("state", UInt32, None, None, "0 starting, 1 running, 2 stopped (an orderly stop: every other value keeps its last running value)"),
                variable("heartbeat", UInt32, None, None, "Incremented every PLC write period (every second without a PLC output); a watchdog checks it moves"),
                flag("sources_ok", "Every source answers"),
            ],
        }];
        let source_names: Vec<String> = config
            .modbus_sources
            .iter()
            .map(|s| s.name.clone())
            .chain(config.can_sources.iter().map(|s| s.name.clone()))
            .collect();
        let mut push = |object: ObjectSpec| {
            objects.push(object);
            objects.len() - 1
        };
        let sources = source_names
            .iter()
            .map(|name| {
                push(ObjectSpec {
                    name: name.clone(),
                    kind: ObjectKind::Source,
                    parent: None,
                    description: "A field source (Modbus TCP or CAN)".into(),
                    variables: vec![variable(
                        "status",
                        UInt32,
                        None,
                        None,
                        "0 ok (answering), 1 stale (no good answer for longer than its stale time), 2 lost",
                    )],
                })
            })
            .collect();
        let models: Vec<bool> = config
            .drivelines
            .iter()
            .map(|d| d.model.is_some())
            .collect();
        let drivelines = config
            .drivelines
            .iter()
            .zip(&models)
            .map(|(driveline, &model)| {
                let mut variables = vec![
                    variable("bite_counter", UInt32, None, None, "Bites analysed since start (continued across restarts with a history)"),
                    variable("last_bite_time", VariableType::DateTime, None, None, "Time of the last bite"),
                    variable("static_torque", Double, Some(Unit::KILONEWTON_METRE), None, "Static (settled) rolling torque of the last bite"),
                    variable("peak_torque", Double, Some(Unit::KILONEWTON_METRE), None, "Peak torque of the last bite"),
                    variable("taf", Double, None, None, "Torque amplification factor of the last bite (peak / static)"),
                    variable("period_shift", Double, Some(Unit::SECOND), None, "First minus second oscillation period of the last bite"),
                    variable("beta1", Double, Some(Unit::HERTZ), None, "First natural frequency identified from the last bite"),
                    variable("beta2", Double, Some(Unit::HERTZ), None, "Second natural frequency identified from the last bite"),
                ];
                if model {
                    variables.extend([
                        variable("wear_index", Double, None, None, "Secondary figure: TAF-ratio wear index of the last bite, its TAF / the linear model's TAF - 1"),
                        variable("wear_trend", Double, None, None, "Secondary figure: mean of the wear index over bites (EWMA, weight 0.1)"),
                        variable("gap_mrad", Double, Some(Unit::MILLIRADIAN), None, "Opened gap (total dead-zone width, referred to the rolls), maximum likelihood over the pooled bites"),
                        variable("gap_low_mrad", Double, Some(Unit::MILLIRADIAN), None, "Lower end of the gap's 90% interval"),
                        variable("gap_high_mrad", Double, Some(Unit::MILLIRADIAN), None, "Upper end of the gap's 90% interval"),
                        variable("gap_coupling", UInt32, None, None, "Coupling holding the gap (model index, 0 = motor side); 65535 = undetermined"),
                        variable("bites_pooled", UInt32, None, None, "Bites pooled into the gap estimate"),
                    ]);
                }
                variables.extend([
                    flag("warning", "TAF at or above the warning threshold at the last bite"),
                    flag("alarm", "TAF reached the alarm threshold; latched until acknowledged"),
                    flag("source_stale", "The torque channel's source is stale or lost: the figures are withdrawn"),
                    flag("degraded", "The last bite's window had gaps, saturated or non-finite samples: its figures are withdrawn"),
                    flag("restored", "The values are from before the last restart (from the history); cleared by the next bite"),
                ]);
                if model {
                    variables.extend([
                        flag("gap_warning", "The estimated gap is at or above the gap warning threshold"),
                        flag("gap_alarm", "The gap's 90% interval lay at or above the gap alarm threshold; latched until acknowledged"),
                    ]);
                }
                push(ObjectSpec {
                    name: driveline.name.clone(),
                    kind: ObjectKind::Driveline,
                    parent: None,
                    description: "A hot-mill driveline analysed at each bite".into(),
                    variables,
                })
            })
            .collect();
        let mills = config
            .tandem_mills
            .iter()
            .map(|mill| {
                let stands = mill.stands.len() as f64;
                push(ObjectSpec {
                    name: mill.name.clone(),
                    kind: ObjectKind::TandemMill,
                    parent: None,
                    description: "A tandem cold mill watched for chatter".into(),
                    variables: vec![
                        variable("evaluations", UInt64, None, None, "Windows evaluated since start"),
                        variable("sigma_n", Double, Some(Unit::HERTZ), None, "RMS deviation of the adjacent stands' principal chatter-band frequencies"),
                        variable("k_mean", Double, None, Some((-1.0, 1.0)), "Mean correlation of adjacent stands over the window"),
                        variable("chatter_frequency", Double, Some(Unit::HERTZ), None, "Mean principal frequency in the chatter band"),
                        variable("chatter_gain", Double, None, None, "Largest chatter-band gain of any stand (chatter-band RMS / reference-band RMS)"),
                        variable("gain_ratio", Double, None, None, "Largest gain / threshold of any stand: >= 1 is the band-gain alarm"),
                        variable("band_rms_max", Double, None, None, "Largest chatter-band RMS of any stand, in the stand channels' unit"),
                        variable("worst_stand", UInt32, None, Some((1.0, stands)), "Stand of gain_ratio, 1-based in the mill's stands order"),
                        flag("warning", "The configured detector's warning in the last window"),
                        flag("alarm", "The configured detector's alarm; latched until acknowledged"),
                        flag("slow_down_request", "Slow-down request to the PLC, with hysteresis"),
                        flag("source_stale", "A stand's source is stale or lost, or the window restarted: the figures are withdrawn"),
                    ],
                })
            })
            .collect();
        let rod_mills = config
            .rod_mills
            .iter()
            .enumerate()
            .map(|(k, mill)| {
                let configurations = mill.configurations.len().saturating_sub(1) as f64;
                let index = push(ObjectSpec {
                    name: mill.name.clone(),
                    kind: ObjectKind::RodMill,
                    parent: None,
                    description: "A rod mill whose spans are checked against the Mathieu tongues".into(),
                    variables: vec![
                        variable("evaluations", UInt64, None, None, "Evaluations since start (one per change of the inputs)"),
                        variable("configuration", UInt32, None, Some((0.0, configurations)), "Drive configuration in use (index into the rod mill's configurations)"),
                        variable("pass", UInt32, None, None, "Pass in use (1-based row of the schedule)"),
                        variable("finishing_speed", Double, Some(Unit::METRE_PER_SECOND), None, "Finishing speed the spans were evaluated at"),
                        variable("rod_temperature", Double, Some(Unit::DEGREE_CELSIUS), None, "Rod temperature of the pass setup in use"),
                        variable("worst_margin", Double, Some(Unit::METRE_PER_SECOND), None, "Smallest speed margin of any valid span (negative: unstable)"),
                        variable("worst_span", UInt32, None, None, "Span (1-based, rolling order) of worst_margin"),
                        flag("unstable", "A span is unstable"),
                        flag("near_tongue", "A span is near a tongue"),
                        flag("input_refused", "The last inputs were out of range: the spans are not evaluated"),
                        flag("source_stale", "An input's source is stale or lost: the figures are withdrawn"),
                    ],
                });
                let spans = (0..rod_spans.get(k).copied().unwrap_or(0))
                    .map(|span| {
                        push(ObjectSpec {
                            name: format!("span{}", span + 1),
                            kind: ObjectKind::RodSpan,
                            parent: Some(index),
                            description: format!("Span {} (stand {} to {} in rolling order)", span + 1, span + 1, span + 2),
                            variables: vec![
                                variable("speed_margin", Double, Some(Unit::METRE_PER_SECOND), None, "Finishing-speed change to the nearest unstable band edge: > 0 stable, < 0 unstable"),
                                variable("worst_exponent", Double, Some(Unit::RECIPROCAL_SECOND), None, "Largest growth exponent of the span's points (< 0 decaying)"),
                                variable("configuration", UInt32, None, Some((0.0, configurations)), "Drive configuration the span was evaluated in"),
                                flag("unstable", "Unstable (with hysteresis)"),
                                flag("near_tongue", "Stable but near a tongue (with hysteresis)"),
                            ],
                        })
                    })
                    .collect();
                (index, spans)
            })
            .collect();
        let adapter = Self {
            layout: Layout {
                sources,
                drivelines,
                mills,
                rod_mills,
            },
            driveline_names: config.drivelines.iter().map(|d| d.name.clone()).collect(),
            source_names,
            mill_names: config.tandem_mills.iter().map(|m| m.name.clone()).collect(),
            rod_names: config.rod_mills.iter().map(|m| m.name.clone()).collect(),
            models,
            thresholds: config.drivelines.iter().map(|d| d.thresholds).collect(),
            mill_seen: vec![(0, None); config.tandem_mills.len()],
            rod_seen: vec![(0, None); config.rod_mills.len()],
        };
        let spec = AddressSpaceSpec {
            name: config.name.clone(),
            objects,
        };
        (adapter, spec)
    }

    /// Every variable's state in `results`, seen at `now`.
    pub fn snapshot(&mut self, results: &Results, now: SystemTime) -> Snapshot {
        let objects = 1
            + self.layout.sources.len()
            + self.layout.drivelines.len()
            + self.layout.mills.len()
            + self
                .layout
                .rod_mills
                .iter()
                .map(|(_, spans)| 1 + spans.len())
                .sum::<usize>();
        let mut snapshot = vec![Vec::new(); objects];
        let good = |value| VariableUpdate::good(value, None);
        let sources_ok = results.sources.iter().all(|s| *s == Some(SourceStatus::Ok));
        snapshot[0] = vec![
            good(Value::UInt32(match results.state {
                GatewayState::Starting => 0,
                GatewayState::Running => 1,
                GatewayState::Stopped => 2,
            })),
            good(Value::UInt32(u32::from(results.heartbeat))),
            good(Value::Boolean(sources_ok)),
        ];
        for (&index, status) in self.layout.sources.iter().zip(&results.sources) {
            snapshot[index] = vec![match status {
                Some(status) => good(Value::UInt32(u32::from(status.code()))),
                None => VariableUpdate::missing(Quality::BadWaitingForInitialData),
            }];
        }
        for (k, &index) in self.layout.drivelines.iter().enumerate() {
            if let Some(driveline) = results.drivelines.get(k) {
                snapshot[index] = driveline_updates(driveline, self.models[k]);
            }
        }
        for (m, &index) in self.layout.mills.iter().enumerate() {
            if let Some(mill) = results.mills.get(m) {
                let seen = &mut self.mill_seen[m];
                if mill.evaluations != seen.0 {
                    *seen = (mill.evaluations, Some(now));
                }
                snapshot[index] = mill_updates(mill, seen.1);
            }
        }
        for (k, (index, spans)) in self.layout.rod_mills.iter().enumerate() {
            if let Some(mill) = results.rod_mills.get(k) {
                let seen = &mut self.rod_seen[k];
                if mill.evaluations != seen.0 {
                    *seen = (mill.evaluations, Some(now));
                }
                snapshot[*index] = rod_mill_updates(mill, seen.1);
                for (span, &span_index) in spans.iter().enumerate() {
                    let results = mill.spans.get(span).cloned().unwrap_or_default();
                    snapshot[span_index] = rod_span_updates(mill, &results, seen.1);
                }
            }
        }
        Snapshot { objects: snapshot }
    }

    /// The alarms raised, cleared or acknowledged between `before` and `after`, seen at
    /// `now`; a raised alarm is dated by its bite (`now` for mills, rod mills and
    /// sources), a cleared or acknowledged one `now`.
    pub fn events(
        &self,
        before: &Results,
        after: &Results,
        now: SystemTime,
    ) -> Vec<AlarmEventSpec> {
        let mut events = Vec::new();
        let mut transition = |object: usize,
                              was: bool,
                              is: bool,
                              kind: &str,
                              severity: u16,
                              latched: bool,
                              message: String,
                              raised: SystemTime| {
            if was != is {
                events.push(AlarmEventSpec {
                    object,
                    kind: kind.into(),
                    severity,
                    message,
                    active: is,
                    unacknowledged: latched && is,
                    time: if is { raised } else { now },
                });
            }
        };
        let state = |is: bool, latched: bool| match (is, latched) {
            (true, _) => "raised",
            (false, true) => "acknowledged",
            (false, false) => "cleared",
        };
        let pairs = before.sources.iter().zip(&after.sources);
        for ((index, name), (was, is)) in self
            .layout
            .sources
            .iter()
            .zip(&self.source_names)
            .zip(pairs)
        {
            let stale = |s: &Option<SourceStatus>| *s == Some(SourceStatus::Stale);
            let lost = |s: &Option<SourceStatus>| *s == Some(SourceStatus::Lost);
            transition(
                *index,
                stale(was),
                stale(is),
                "source_stale",
                STALE_SEVERITY,
                false,
                format!("{name}: source stale {}", state(stale(is), false)),
                now,
            );
            transition(
                *index,
                lost(was),
                lost(is),
                "source_lost",
                LOST_SEVERITY,
                false,
                format!("{name}: source lost {}", state(lost(is), false)),
                now,
            );
        }
        let pairs = before.drivelines.iter().zip(&after.drivelines);
        for (k, (was, is)) in pairs.enumerate() {
            let index = self.layout.drivelines[k];
            let name = &self.driveline_names[k];
            let limits = &self.thresholds[k];
            let time = is.last_bite_unix_s.map_or(now, unix_time);
            let taf = is
                .taf
                .map_or(String::new(), |taf| format!(", TAF {taf:.2}"));
            transition(
                index,
                was.warning,
                is.warning,
                "taf_warning",
                WARNING_SEVERITY,
                false,
                format!(
                    "{name}: TAF warning {}{taf} (warning at {})",
                    state(is.warning, false),
                    limits.taf_warning
                ),
                time,
            );
            transition(
                index,
                was.alarm,
                is.alarm,
                "taf_alarm",
                ALARM_SEVERITY,
                true,
                format!(
                    "{name}: TAF alarm {}{taf} (alarm at {})",
                    state(is.alarm, true),
                    limits.taf_alarm
                ),
                time,
            );
            let gap = is.gap.map_or(String::new(), |gap| {
                format!(
                    ", gap {:.2} mrad (90% {:.2}..{:.2})",
                    gap.gap_mrad, gap.low_mrad, gap.high_mrad
                )
            });
            transition(
                index,
                was.gap_warning,
                is.gap_warning,
                "gap_warning",
                WARNING_SEVERITY,
                false,
                format!(
                    "{name}: gap warning {}{gap} (warning at {} mrad)",
                    state(is.gap_warning, false),
                    limits.gap_warning_mrad
                ),
                time,
            );
            transition(
                index,
                was.gap_alarm,
                is.gap_alarm,
                "gap_alarm",
                ALARM_SEVERITY,
                true,
                format!(
                    "{name}: gap alarm {}{gap} (alarm at {} mrad)",
                    state(is.gap_alarm, true),
                    limits.gap_alarm_mrad
                ),
                time,
            );
        }
        let pairs = before.mills.iter().zip(&after.mills);
        for (m, (was, is)) in pairs.enumerate() {
            let index = self.layout.mills[m];
            let name = &self.mill_names[m];
            let ratio = is
                .gain_ratio
                .map_or(String::new(), |r| format!(", gain ratio {r:.2}"));
            transition(
                index,
                was.warning,
                is.warning,
                "chatter_warning",
                WARNING_SEVERITY,
                false,
                format!(
                    "{name}: chatter warning {}{ratio}",
                    state(is.warning, false)
                ),
                now,
            );
            transition(
                index,
                was.alarm,
                is.alarm,
                "chatter_alarm",
                ALARM_SEVERITY,
                true,
                format!("{name}: chatter alarm {}{ratio}", state(is.alarm, true)),
                now,
            );
            transition(
                index,
                was.slow_down_request,
                is.slow_down_request,
                "slow_down_request",
                LOST_SEVERITY,
                false,
                format!(
                    "{name}: slow-down request {}{ratio}",
                    state(is.slow_down_request, false)
                ),
                now,
            );
        }
        let pairs = before.rod_mills.iter().zip(&after.rod_mills);
        for (k, (was, is)) in pairs.enumerate() {
            let index = self.layout.rod_mills[k].0;
            let name = &self.rod_names[k];
            let unstable =
                |m: &RodMillResults| m.valid() && m.spans.iter().any(|s| s.valid && s.unstable);
            let near =
                |m: &RodMillResults| m.valid() && m.spans.iter().any(|s| s.valid && s.near_tongue);
            let margin = is.worst_span().map_or(String::new(), |(span, margin)| {
                format!(", span{} margin {margin:.2} m/s", span + 1)
            });
            transition(
                index,
                unstable(was),
                unstable(is),
                "span_unstable",
                ALARM_SEVERITY,
                false,
                format!(
                    "{name}: unstable span {}{margin}",
                    state(unstable(is), false)
                ),
                now,
            );
            transition(
                index,
                near(was),
                near(is),
                "near_tongue",
                WARNING_SEVERITY,
                false,
                format!(
                    "{name}: span near a tongue {}{margin}",
                    state(near(is), false)
                ),
                now,
            );
        }
        events
    }
}

/// Unix seconds as a time.
fn unix_time(seconds: u32) -> SystemTime {
    UNIX_EPOCH + Duration::from_secs(u64::from(seconds))
}

/// A figure's update: good with its value; else why not, from `missing`.
fn figure(value: Option<Value>, time: Option<SystemTime>, missing: Quality) -> VariableUpdate {
    match value {
        Some(Value::Double(v)) if !v.is_finite() => VariableUpdate::missing(missing),
        Some(value) => VariableUpdate::good(value, time),
        None => VariableUpdate::missing(missing),
    }
}

/// A value the register map keeps while the source is stale: uncertain then.
fn kept(value: Value, stale: bool, time: Option<SystemTime>) -> VariableUpdate {
    VariableUpdate {
        value: Some(value),
        quality: if stale {
            Quality::UncertainLastUsableValue
        } else {
            Quality::Good
        },
        source_time: time,
    }
}

fn driveline_updates(d: &DrivelineResults, model: bool) -> Vec<VariableUpdate> {
    let time = d.last_bite_unix_s.map(unix_time);
    let never = d.bite_counter == 0 && d.last_bite_unix_s.is_none();
    // Why a figure of the last bite is missing.
    let per_bite = if d.source_stale {
        Quality::BadNoCommunication
    } else if never {
        Quality::BadWaitingForInitialData
    } else if d.last_bite_degraded {
        Quality::BadDeviceFailure
    } else {
        Quality::BadNoData
    };
    // Why an estimate over bites is missing (maps building, reset, no bite yet).
    let estimate = if d.source_stale {
        Quality::BadNoCommunication
    } else {
        Quality::BadWaitingForInitialData
    };
    let double = |v: Option<f64>| v.map(Value::Double);
    let fresh = |value: Option<Value>, missing| {
        if d.source_stale {
            VariableUpdate::missing(Quality::BadNoCommunication)
        } else {
            figure(value, time, missing)
        }
    };
    let gap = d.gap.as_ref();
    let mut updates = vec![
        kept(Value::UInt32(d.bite_counter), d.source_stale, time),
        fresh(time.map(Value::DateTime), estimate),
        fresh(double(d.static_torque_knm), per_bite),
        fresh(double(d.peak_torque_knm), per_bite),
        fresh(double(d.taf), per_bite),
        fresh(double(d.first_period_shift_s), per_bite),
        fresh(double(d.beta1_hz), per_bite),
        fresh(double(d.beta2_hz), per_bite),
    ];
    if model {
        let coupling = |g: &crate::outputs::results::GapResults| {
            Value::UInt32(
                g.coupling
                    .map_or(65_535, |c| u32::try_from(c).unwrap_or(65_535)),
            )
        };
        updates.extend([
            fresh(double(d.wear_index), per_bite),
            fresh(double(d.wear_trend), estimate),
            fresh(double(gap.map(|g| g.gap_mrad)), estimate),
            fresh(double(gap.map(|g| g.low_mrad)), estimate),
            fresh(double(gap.map(|g| g.high_mrad)), estimate),
            fresh(gap.map(coupling), estimate),
            fresh(
                gap.map(|g| Value::UInt32(u32::try_from(g.bites_pooled).unwrap_or(u32::MAX))),
                estimate,
            ),
        ]);
    }
    let flag = |set: bool| kept(Value::Boolean(set), d.source_stale, None);
    updates.extend([
        flag(d.warning),
        flag(d.alarm),
        VariableUpdate::good(Value::Boolean(d.source_stale), None),
        flag(d.last_bite_degraded),
        flag(d.restored),
    ]);
    if model {
        updates.extend([flag(d.gap_warning), flag(d.gap_alarm)]);
    }
    updates
}

fn mill_updates(m: &MillResults, time: Option<SystemTime>) -> Vec<VariableUpdate> {
    let missing = if m.source_stale {
        Quality::BadNoCommunication
    } else if m.evaluations == 0 {
        Quality::BadWaitingForInitialData
    } else {
        Quality::BadNoData
    };
    let double = |v: Option<f64>| {
        if m.source_stale {
            VariableUpdate::missing(missing)
        } else {
            figure(v.map(Value::Double), time, missing)
        }
    };
    let flag = |set: bool| kept(Value::Boolean(set), m.source_stale, time);
    let worst_stand = m
        .worst_stand
        .filter(|_| !m.source_stale)
        .map(|stand| Value::UInt32(u32::try_from(stand + 1).unwrap_or(u32::MAX)));
    vec![
        kept(Value::UInt64(m.evaluations), m.source_stale, time),
        double(m.sigma_n_hz),
        double(m.k_mean),
        double(m.chatter_frequency_hz),
        double(m.chatter_gain),
        double(m.gain_ratio),
        double(m.band_rms_max),
        figure(worst_stand, time, missing),
        flag(m.warning),
        flag(m.alarm),
        flag(m.slow_down_request),
        VariableUpdate::good(Value::Boolean(m.source_stale), None),
    ]
}

/// Why a rod mill's figures are missing, `None` when it is valid.
fn rod_missing(m: &RodMillResults) -> Option<Quality> {
    if m.source_stale {
        Some(Quality::BadNoCommunication)
    } else if m.input_refused {
        Some(Quality::BadOutOfRange)
    } else if m.evaluations == 0 {
        Some(Quality::BadWaitingForInitialData)
    } else {
        None
    }
}

fn rod_mill_updates(m: &RodMillResults, time: Option<SystemTime>) -> Vec<VariableUpdate> {
    let missing = rod_missing(m);
    let value = |v: Option<Value>| match missing {
        Some(quality) => VariableUpdate::missing(quality),
        None => figure(v, time, Quality::BadNoData),
    };
    let uint = |v: Option<u16>| v.map(|v| Value::UInt32(u32::from(v)));
    let worst = m.worst_span();
    let any = |pick: fn(&RodSpanResults) -> bool| {
        Some(Value::Boolean(m.spans.iter().any(|s| s.valid && pick(s))))
    };
    vec![
        kept(Value::UInt64(m.evaluations), m.source_stale, time),
        value(uint(m.configuration)),
        value(uint(m.pass)),
        value(m.finishing_speed_m_s.map(Value::Double)),
        value(m.temperature_c.map(Value::Double)),
        value(worst.map(|(_, margin)| Value::Double(margin))),
        value(worst.map(|(span, _)| Value::UInt32(u32::try_from(span + 1).unwrap_or(u32::MAX)))),
        value(any(|s| s.unstable)),
        value(any(|s| s.near_tongue)),
        VariableUpdate::good(Value::Boolean(m.input_refused), None),
        VariableUpdate::good(Value::Boolean(m.source_stale), None),
    ]
}

fn rod_span_updates(
    m: &RodMillResults,
    span: &RodSpanResults,
    time: Option<SystemTime>,
) -> Vec<VariableUpdate> {
    // A span the last evaluation did not cover (fewer spans, or not valid) has no
    // values; the mill says why when it is not valid itself.
    let missing = rod_missing(m).or((!span.valid).then_some(Quality::BadNoData));
    let value = |v: Option<Value>| match missing {
        Some(quality) => VariableUpdate::missing(quality),
        None => figure(v, time, Quality::BadNoData),
    };
    vec![
        value(span.speed_margin_m_s.map(Value::Double)),
        value(span.worst_exponent_per_s.map(Value::Double)),
        value(span.configuration.map(|c| Value::UInt32(u32::from(c)))),
        value(Some(Value::Boolean(span.unstable))),
        value(Some(Value::Boolean(span.near_tongue))),
    ]
}

/// The acknowledge method's action: clear the latched alarms, recorded as an OPC UA
/// client's command.
pub fn acknowledger(publisher: Arc<Publisher>) -> Acknowledger {
    Arc::new(move |acknowledgement| {
        publisher.acknowledge_alarms(CommandOrigin::OpcUa(acknowledgement.peer));
    })
}

/// Read the results every [`FEED_PERIOD`] into `updates` (when they changed) and the
/// alarms' transitions into `events`, until `shutdown`.
pub async fn feed(
    mut adapter: ResultsAdapter,
    publisher: Arc<Publisher>,
    updates: watch::Sender<Snapshot>,
    events: mpsc::Sender<AlarmEventSpec>,
    mut shutdown: Shutdown,
) {
    let mut before = publisher.results();
    let mut tick = tokio::time::interval(FEED_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut dropped = 0u64;
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            () = shutdown.recv() => break,
        }
        let results = publisher.results();
        let now = SystemTime::now();
        let snapshot = adapter.snapshot(&results, now);
        updates.send_if_modified(|current| {
            let changed = *current != snapshot;
            if changed {
                *current = snapshot;
            }
            changed
        });
        for event in adapter.events(&before, &results, now) {
            if events.try_send(event).is_err() {
                dropped += 1;
                tracing::warn!(dropped, "OPC UA alarm event dropped: the server is behind");
            }
        }
        before = results;
    }
}

/// The OPC UA output as the service runs it: the server of `config`'s results, the
/// feed from the publisher, and their channels.
pub struct OpcUaOutputTask {
    server: super::OpcUaServer,
    adapter: ResultsAdapter,
    publisher: Arc<Publisher>,
}

impl std::fmt::Debug for OpcUaOutputTask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaOutputTask")
            .field("server", &self.server)
            .finish()
    }
}

impl OpcUaOutputTask {
    /// The OPC UA output of `config` (`None` without `[outputs.opcua]`), its rod mills
    /// having `rod_spans` spans; an error when its address space cannot be built.
    pub fn prepare(
        config: &Config,
        rod_spans: &[usize],
        publisher: &Arc<Publisher>,
    ) -> Result<Option<Self>, super::OpcUaError> {
        let Some(settings) = &config.outputs.opcua else {
            return Ok(None);
        };
        let (adapter, spec) = ResultsAdapter::new(config, rod_spans);
        let server =
            super::OpcUaServer::new(settings.clone(), spec, acknowledger(Arc::clone(publisher)))?;
        Ok(Some(Self {
            server,
            adapter,
            publisher: Arc::clone(publisher),
        }))
    }

    /// The server's counts.
    pub fn status(&self) -> super::OpcUaStatus {
        self.server.status()
    }

    /// Serve on `listener` and feed the server until `shutdown`: two tasks in
    /// `outputs`, each returning its name and what ended it.
    pub fn spawn(
        self,
        listener: tokio::net::TcpListener,
        outputs: &mut tokio::task::JoinSet<(&'static str, Result<(), String>)>,
        shutdown: &Shutdown,
    ) {
        let Self {
            server,
            mut adapter,
            publisher,
        } = self;
        let initial = adapter.snapshot(&publisher.results(), SystemTime::now());
        let (updates, updates_rx) = watch::channel(initial);
        let (events, events_rx) = mpsc::channel(EVENT_QUEUE);
        let feeding = feed(adapter, publisher, updates, events, shutdown.clone());
        outputs.spawn(async move {
            feeding.await;
            ("OPC UA feed", Ok(()))
        });
        let serving = server.run(listener, updates_rx, events_rx, shutdown.clone());
        outputs.spawn(async move {
            let served = serving.await;
            ("OPC UA server", served.map_err(|error| error.to_string()))
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::outputs::results::GapResults;

    fn demo() -> (ResultsAdapter, AddressSpaceSpec) {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples/demo.toml");
        let config = millgate_config::load(&path).unwrap();
        ResultsAdapter::new(&config, &[])
    }

    /// Driveline F1's updates in `snapshot`, by key.
    fn f1<'a>(
        spec: &'a AddressSpaceSpec,
        snapshot: &'a Snapshot,
    ) -> impl Fn(&str) -> VariableUpdate + 'a {
        let index = spec.objects.iter().position(|o| o.name == "F1").unwrap();
        move |key| {
            let at = spec.objects[index]
                .variables
                .iter()
                .position(|v| v.key == key)
                .unwrap_or_else(|| panic!("no {key}"));
            snapshot.objects[index][at]
        }
    }

    fn bitten() -> Results {
        let mut results = Results::new(1, 1, 0);
        results.sources = vec![Some(SourceStatus::Ok)];
        let d = &mut results.drivelines[0];
        d.bite_counter = 7;
        d.last_bite_unix_s = Some(1_700_000_000);
        d.taf = Some(1.4);
        d.static_torque_knm = Some(60.0);
        d.alarm = true;
        d.gap = Some(GapResults {
            gap_mrad: 2.0,
            low_mrad: 1.8,
            high_mrad: 2.2,
            coupling: None,
            likeliest_coupling: Some(1),
            bites_pooled: 5,
        });
        results
    }

    #[test]
    fn fresh_values_are_good_and_dated_by_their_bite() {
        let (mut adapter, spec) = demo();
        let snapshot = adapter.snapshot(&bitten(), SystemTime::now());
        let f1 = f1(&spec, &snapshot);
        let bite = UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        assert_eq!(
            f1("taf"),
            VariableUpdate::good(Value::Double(1.4), Some(bite))
        );
        assert_eq!(f1("gap_coupling").value, Some(Value::UInt32(65_535)));
        assert_eq!(f1("alarm").quality, Quality::Good);
        // The fit gave no frequency from a clean window: no data, not a zero.
        assert_eq!(f1("beta1"), VariableUpdate::missing(Quality::BadNoData));
    }

    #[test]
    fn a_stale_source_withdraws_figures_and_keeps_counters_uncertain() {
        let (mut adapter, spec) = demo();
        let mut results = bitten();
        results.drivelines[0].source_stale = true;
        let snapshot = adapter.snapshot(&results, SystemTime::now());
        let f1 = f1(&spec, &snapshot);
        for key in [
            "taf",
            "static_torque",
            "gap_mrad",
            "last_bite_time",
            "wear_trend",
        ] {
            assert_eq!(
                f1(key),
                VariableUpdate::missing(Quality::BadNoCommunication),
                "{key}"
            );
        }
        let bites = f1("bite_counter");
        assert_eq!(
            (bites.value, bites.quality),
            (Some(Value::UInt32(7)), Quality::UncertainLastUsableValue)
        );
        assert_eq!(f1("alarm").quality, Quality::UncertainLastUsableValue);
        assert_eq!(
            f1("source_stale"),
            VariableUpdate::good(Value::Boolean(true), None)
        );
    }

    #[test]
    fn missing_values_say_why() {
        let (mut adapter, spec) = demo();
        let never = Results::new(1, 1, 0);
        let snapshot = adapter.snapshot(&never, SystemTime::now());
        assert_eq!(
            f1(&spec, &snapshot)("taf"),
            VariableUpdate::missing(Quality::BadWaitingForInitialData)
        );
        let mut degraded = bitten();
        degraded.drivelines[0].last_bite_degraded = true;
        degraded.drivelines[0].taf = None;
        let snapshot = adapter.snapshot(&degraded, SystemTime::now());
        assert_eq!(
            f1(&spec, &snapshot)("taf"),
            VariableUpdate::missing(Quality::BadDeviceFailure)
        );
        // A non-finite number is never published as good.
        let mut nan = bitten();
        nan.drivelines[0].taf = Some(f64::NAN);
        let snapshot = adapter.snapshot(&nan, SystemTime::now());
        assert!(!f1(&spec, &snapshot)("taf").quality.carries_value());
    }

    #[test]
    fn alarm_transitions_become_events() {
        let (adapter, spec) = demo();
        let now = UNIX_EPOCH + Duration::from_secs(1_800_000_000);
        let quiet = {
            let mut results = bitten();
            results.drivelines[0].alarm = false;
            results
        };
        let raised = adapter.events(&quiet, &bitten(), now);
        assert_eq!(raised.len(), 1, "{raised:?}");
        let event = &raised[0];
        assert_eq!(spec.objects[event.object].name, "F1");
        assert_eq!(event.kind, "taf_alarm");
        assert!(event.active && event.unacknowledged);
        assert_eq!(event.severity, ALARM_SEVERITY);
        assert_eq!(
            event.time,
            UNIX_EPOCH + Duration::from_secs(1_700_000_000),
            "raised at its bite"
        );
        assert!(event.message.starts_with("F1: TAF alarm raised, TAF 1.40"));
        let acknowledged = adapter.events(&bitten(), &quiet, now);
        assert_eq!(acknowledged.len(), 1);
        assert!(!acknowledged[0].active && !acknowledged[0].unacknowledged);
        assert_eq!(acknowledged[0].time, now);
        assert!(acknowledged[0].message.contains("acknowledged"));
        // A source going stale, from the source's object.
        let mut stale = bitten();
        stale.sources = vec![Some(SourceStatus::Stale)];
        let events = adapter.events(&bitten(), &stale, now);
        assert_eq!(events.len(), 1);
        assert_eq!(events[0].kind, "source_stale");
        assert_eq!(spec.objects[events[0].object].kind, ObjectKind::Source);
        assert!(adapter.events(&bitten(), &bitten(), now).is_empty());
    }
}
