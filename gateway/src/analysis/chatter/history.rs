//! The chatter history of one mill: episodes (from the warning condition set to it
//! cleared, or the window restarted) and the alarm when it latches.

use super::monitor::ChatterUpdate;
use crate::outputs::history::events::{
    AlarmEvent, AlarmKind, AlarmRecord, ChatterWindow, EndedBy, HistoryEvent,
};
use crate::outputs::history::time::UtcTime;
use crate::outputs::results::MillResults;

/// The history events of one update: an episode starts, goes on or ends with the
/// warning condition (a window restart ends it too); the alarm is recorded when it
/// latches.
pub(super) fn record_episode(
    events: &mut Vec<HistoryEvent>,
    mill: &str,
    change: &ChatterUpdate,
    (was_warning, was_alarm): (bool, bool),
    published: &MillResults,
) {
    let time = UtcTime::now();
    let window = match change {
        ChatterUpdate::Evaluated(result) => Some(ChatterWindow {
            sigma_n_hz: result.sigma_n_hz,
            k_mean: result.k_mean,
            frequency_hz: published.chatter_frequency_hz,
            synchronized: result.synchronized,
        }),
        _ => None,
    };
    match (was_warning, published.warning, window) {
        (false, true, Some(window)) => events.push(HistoryEvent::ChatterStarted {
            time,
            mill: mill.to_owned(),
            window,
        }),
        (true, true, Some(window)) => events.push(HistoryEvent::ChatterWindow {
            mill: mill.to_owned(),
            window,
        }),
        (true, false, window) => events.push(HistoryEvent::ChatterEnded {
            time,
            mill: mill.to_owned(),
            ended_by: if window.is_some() {
                EndedBy::Analysis
            } else {
                EndedBy::WindowRestart
            },
        }),
        _ => {}
    }
    if published.alarm && !was_alarm {
        events.push(HistoryEvent::Alarm(AlarmRecord {
            time,
            subject: mill.to_owned(),
            kind: AlarmKind::ChatterAlarm,
            event: AlarmEvent::Raised,
            origin: None,
            value: published.k_mean,
            threshold: None,
        }));
    }
}
