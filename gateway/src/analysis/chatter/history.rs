//! The chatter history of one mill: episodes (from the warning condition set to it
//! cleared, or the window restarted), the warning raised and cleared, and the alarm
//! when it latches (with the mill's state after it).

use super::monitor::ChatterUpdate;
use crate::state::context::ContextReading;
use crate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, ChatterWindow, EndedBy, HistoryEvent, StateRecord,
    SubjectResults,
};
use crate::state::results::TandemMillResults;
use crate::state::time::UtcTime;

/// The history events of one update: an episode starts, goes on or ends with the
/// warning condition (a window restart ends it too); the warning is recorded when it
/// is raised or cleared, the alarm when it latches (with the gain ratio, or K_mean
/// for the paper's detector). An episode keeps the mill's `context` at its start, and
/// the thresholds that judged that window (`published.thresholds_group_name`).
pub(super) fn record_episode(
    events: &mut Vec<HistoryEvent>,
    (mill, context): (&str, Option<ContextReading>),
    change: &ChatterUpdate,
    (was_warning, was_alarm): (bool, bool),
    published: &TandemMillResults,
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
    match (was_warning, published.chatter_warning, window) {
        (false, true, Some(window)) => events.push(HistoryEvent::ChatterStarted {
            time,
            mill: mill.to_owned(),
            window,
            context,
            thresholds_group: published.thresholds_group_name.clone(),
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
    let alarm = |kind, event| {
        HistoryEvent::Alarm(AlarmRecord {
            time,
            subject: mill.to_owned(),
            kind,
            event,
            origin: None,
            value: published.gain_ratio.or(published.k_mean),
            threshold: None,
        })
    };
    if published.chatter_warning != was_warning {
        let event = if published.chatter_warning {
            AlarmEvent::Raised
        } else {
            AlarmEvent::Cleared
        };
        events.push(alarm(AlarmKind::ChatterWarning, event));
    }
    if published.chatter_alarm && !was_alarm {
        events.push(alarm(AlarmKind::ChatterAlarm, AlarmEvent::Raised));
        // The latch is the mill's restorable state.
        events.push(HistoryEvent::State(StateRecord {
            time,
            subject: mill.to_owned(),
            results: SubjectResults::TandemMill(Box::new(published.clone())),
        }));
    }
}
