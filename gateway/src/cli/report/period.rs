//! What the report reads of the whole history for its period, before any driveline:
//! the alarms, runs, outages and settings, the state a restart would restore, the
//! drivelines to report on and the time axis of the plots.

use super::plots::TimeAxis;
use crate::history::query::{AlarmRow, Filter, HistoryReader, OutageRow, RunRow, SettingsRow};
use crate::history::restore::Restored;
use crate::state::time::UtcTime;

/// The report's period and what the history holds of it besides the bites.
#[derive(Debug)]
pub(super) struct Period {
    /// `--since`, when given.
    pub(super) since: Option<UtcTime>,
    /// `--until`, when given.
    pub(super) until: Option<UtcTime>,
    /// Start of the period: `--since`, else the first event.
    pub(super) start: UtcTime,
    /// End of the period: `--until`, else now.
    pub(super) end: UtcTime,
    /// The plots' time axis over the period.
    pub(super) axis: TimeAxis,
    /// The alarm events in the period.
    pub(super) alarms: Vec<AlarmRow>,
    /// Every run of the gateway.
    pub(super) runs: Vec<RunRow>,
    /// The source outages up to the period's end.
    pub(super) outages: Vec<OutageRow>,
    /// The drivelines' settings of every run.
    pub(super) settings: Vec<SettingsRow>,
    /// The state a restart would restore.
    pub(super) state: Restored,
    /// The drivelines with bites, then those only in the state.
    pub(super) drivelines: Vec<String>,
    /// The configuration's name in the last run.
    pub(super) config_name: String,
}

impl Period {
    /// The period `[since, until)` of the history `reader` reads (open ends: from the
    /// first event, up to now).
    pub(super) fn read(
        reader: &HistoryReader,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
    ) -> anyhow::Result<Self> {
        let window = Filter {
            since,
            until,
            ..Filter::default()
        };
        let alarms = reader.alarms(&window)?;
        let runs = reader.runs(&Filter::default())?;
        let outages = reader.outages(&Filter {
            until,
            ..Filter::default()
        })?;
        let settings = reader.settings(&Filter::default())?;
        let state = reader.state()?;
        let drivelines = drivelines(reader, &state)?;
        let first_time = runs
            .first()
            .and_then(|r| UtcTime::parse(&r.started_at).ok())
            .into_iter()
            .chain(first_bite(reader, &drivelines)?)
            .min();
        let start = since.or(first_time).unwrap_or_else(UtcTime::now);
        let end = until.unwrap_or_else(UtcTime::now);
        anyhow::ensure!(
            end > start,
            "--until must be after --since (or after the first event)"
        );
        let config_name = runs
            .last()
            .map_or("millgate", |r| r.config_name.as_str())
            .to_owned();
        Ok(Self {
            since,
            until,
            start,
            end,
            axis: TimeAxis::new(start, end),
            alarms,
            runs,
            outages,
            settings,
            state,
            drivelines,
            config_name,
        })
    }

    /// The settings of driveline `name` in the last run that recorded them.
    pub(super) fn setting(&self, name: &str) -> Option<SettingsRow> {
        self.settings
            .iter()
            .rev()
            .find(|s| s.driveline == name)
            .cloned()
    }
}

/// The drivelines with bites in the history, then those only in its `state`.
fn drivelines(reader: &HistoryReader, state: &Restored) -> anyhow::Result<Vec<String>> {
    let mut drivelines: Vec<String> = reader.drivelines()?;
    for restored in &state.drivelines {
        if !drivelines.contains(&restored.name) {
            drivelines.push(restored.name.clone());
        }
    }
    Ok(drivelines)
}

/// The time of the first bite of any of `drivelines`.
fn first_bite(reader: &HistoryReader, drivelines: &[String]) -> anyhow::Result<Option<UtcTime>> {
    let mut first_bite = None;
    for name in drivelines {
        if let Some((first, _)) = reader.bite_span(name)? {
            first_bite = first_bite.min(Some(first)).or(Some(first));
        }
    }
    Ok(first_bite)
}
