//! The history's `/metrics` families: state, events stored and dropped, commits,
//! retention, the file's size and the last error (an info metric with the message as
//! label, and its time).

use crate::exposition::{Exposition, Families, Kind};
use crate::state::history::History;

impl Families for History {
    fn write_families(&self, page: &mut Exposition) {
        let status = &self.status();
        let scalars: [(&str, Kind, &str, f64); 8] = [
            (
                "millgate_history_state",
                Kind::Gauge,
                "Event history: 0 disabled, 1 ok, 2 failing (see millgate_history_last_error_info).",
                f64::from(status.state.code()),
            ),
            (
                "millgate_history_events_stored_total",
                Kind::Counter,
                "Events committed to the history file.",
                status.stored as f64,
            ),
            (
                "millgate_history_queue_events",
                Kind::Gauge,
                "Events waiting for the history writer.",
                status
                    .enqueued
                    .saturating_sub(status.stored + status.dropped_error) as f64,
            ),
            (
                "millgate_history_commits_total",
                Kind::Counter,
                "History transactions committed (each a group of events).",
                status.commits as f64,
            ),
            (
                "millgate_history_commit_seconds_total",
                Kind::Counter,
                "Time spent in history transactions, s.",
                status.commit_seconds_sum,
            ),
            (
                "millgate_history_commit_max_seconds",
                Kind::Gauge,
                "Longest history transaction since start, s.",
                status.commit_seconds_max,
            ),
            (
                "millgate_history_retention_deleted_total",
                Kind::Counter,
                "Rows deleted by the history's retention (age and size).",
                status.retention_deleted as f64,
            ),
            (
                "millgate_history_file_bytes",
                Kind::Gauge,
                "Size of the history file at the last retention check, bytes.",
                status.file_bytes as f64,
            ),
        ];
        page.scalars(scalars);
        page.family(
            "millgate_history_events_dropped_total",
            Kind::Counter,
            "Events not stored: the queue was full, or the file could not take them.",
            [
                (
                    vec![("reason", "queue_full")],
                    status.dropped_queue_full as f64,
                ),
                (vec![("reason", "error")], status.dropped_error as f64),
            ],
        );
        page.scalar(
            "millgate_history_captures_dropped_total",
            Kind::Counter,
            "Captures (a bite's window with its bite, a chatter episode, a manual request) not stored: the queue was full or the file could not take them; never announced, as nothing reads them from the file.",
            status.captures_dropped as f64,
        );
        let last = status.last_error.as_ref();
        page.family(
            "millgate_history_last_error_info",
            Kind::Gauge,
            "The history's last error: the message is the label (always 1; no sample before the first error).",
            last.map(|(_, message)| (vec![("error", message.as_str())], 1.0)),
        );
        page.family(
            "millgate_history_last_error_timestamp_seconds",
            Kind::Gauge,
            "When the history's last error happened, Unix seconds.",
            last.map(|(time, _)| (Vec::new(), time.unix_s())),
        );
    }
}
