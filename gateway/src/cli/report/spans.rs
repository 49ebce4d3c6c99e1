//! Spans of time on the plots' axis: while the gateway ran, while an alarm was set,
//! clipped to the report's period.

use plotters::style::RGBColor;

use super::plots::TimeAxis;
use crate::history::query::{AlarmRow, HistoryReader, RunRow};
use crate::state::time::UtcTime;

/// Overlap of `[from, to)` with the axis' period, in axis units.
pub(super) fn clip(axis: &TimeAxis, from: f64, to: f64) -> Option<(f64, f64)> {
    let (from, to) = (from.max(0.0), to.min(axis.span));
    (to > from).then_some((from, to))
}

pub(super) fn at_time(axis: &TimeAxis, time: &str) -> Option<f64> {
    axis.x(time)
}

/// Spans while a latched alarm or warning was set: from raised to cleared or
/// acknowledged (or the period's end).
pub(super) fn alarm_spans(axis: &TimeAxis, alarms: &[&AlarmRow]) -> Vec<(f64, f64, RGBColor)> {
    let mut spans = Vec::new();
    let mut since: Option<f64> = None;
    for alarm in alarms {
        let Some(x) = at_time(axis, &alarm.time) else {
            continue;
        };
        match (alarm.event.as_str(), since) {
            ("raised", None) => since = Some(x),
            ("cleared" | "acknowledged", Some(from)) => {
                spans.extend(clip(axis, from, x).map(|(a, b)| (a, b, RGBColor(250, 200, 190))));
                since = None;
            }
            _ => {}
        }
    }
    if let Some(from) = since {
        spans.extend(clip(axis, from, axis.span).map(|(a, b)| (a, b, RGBColor(250, 200, 190))));
    }
    spans
}

/// When the gateway ran, in axis units, as far as the file tells.
#[derive(Debug, Default)]
pub(super) struct RunSpans {
    /// Known to be running: each run from its start to its recorded stop, or, for a
    /// run without one (killed, its power cut, or still running), to its last
    /// recorded event.
    pub(super) up: Vec<(f64, f64)>,
    /// Not known: for a run without a recorded stop, from its last recorded event to
    /// the next run's start (or the period's end).
    pub(super) unknown: Vec<(f64, f64)>,
    /// Runs without a recorded stop.
    pub(super) open: usize,
}

/// The run spans of `runs` (in start order) on `axis`.
pub(super) fn run_spans(
    reader: &HistoryReader,
    axis: &TimeAxis,
    runs: &[RunRow],
) -> anyhow::Result<RunSpans> {
    let mut spans = RunSpans::default();
    for (index, run) in runs.iter().enumerate() {
        let Some(from) = at_time(axis, &run.started_at) else {
            continue;
        };
        if let Some(to) = run.stopped_at.as_deref().and_then(|t| at_time(axis, t)) {
            spans.up.extend(clip(axis, from, to));
            continue;
        }
        spans.open += 1;
        let next = runs.get(index + 1);
        let next_start = next.and_then(|n| UtcTime::parse(&n.started_at).ok());
        let seen = reader
            .last_event(run, next_start)?
            .map_or(from, |time| axis.x_of(time).max(from));
        spans.up.extend(clip(axis, from, seen));
        let until = next_start.map_or(axis.span, |time| axis.x_of(time));
        spans.unknown.extend(clip(axis, seen, until));
    }
    Ok(spans)
}
