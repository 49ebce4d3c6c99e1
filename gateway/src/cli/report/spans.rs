//! Spans of time on the plots' axis: while the gateway ran, while an alarm was set,
//! clipped to the report's period.

use plotters::style::RGBColor;

use super::plots::TimeAxis;
use crate::outputs::history::query::{AlarmRow, BiteRow, RunRow};

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

/// When the gateway ran, in axis units: each run from its start to its stop; a run
/// that was killed to its last recorded bite.
pub(super) fn run_spans(axis: &TimeAxis, runs: &[RunRow], bites: &[BiteRow]) -> Vec<(f64, f64)> {
    runs.iter()
        .filter_map(|run| {
            let from = at_time(axis, &run.started_at)?;
            let to = match (&run.stopped_at, &run.ended) {
                (Some(stopped), _) => at_time(axis, stopped)?,
                (None, None) => axis.span,
                (None, Some(_)) => bites
                    .iter()
                    .filter(|b| b.run_id == run.id)
                    .filter_map(|b| at_time(axis, &b.time))
                    .fold(from, f64::max),
            };
            clip(axis, from, to)
        })
        .collect()
}
