//! The history's `/metrics` families: state, events stored and dropped, commits,
//! retention, the file's size, the evidence whose context was not valid, and the last
//! error (an info metric with the message as label, and its time).

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
        page.family(
            "millgate_context_untrusted_total",
            Kind::Counter,
            "Evidence handed to the history whose process context was not valid, by subject (tandem mill or driveline), evidence (episode: a chatter episode; capture) and status (stale: a configured context tag had no fresh value, that value left out; invalid: an impossible value, every value left out); no sample before the first.",
            status.context_untrusted.iter().map(|(key, count)| {
                (
                    vec![
                        ("subject", key.subject.as_str()),
                        ("evidence", key.evidence),
                        ("status", key.status),
                    ],
                    *count as f64,
                )
            }),
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

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use millgate_config::{CaptureSettings, Synchronous};

    use crate::exposition::{Exposition, Families};
    use crate::state::captures::CaptureKind;
    use crate::state::context::{ContextError, ContextReading, ProcessContext, StaleTags};
    use crate::state::events::HistoryEvent;
    use crate::state::history::History;
    use crate::testing::{capture_without_samples, chatter_started};

    /// A chatter episode's start of `mill` in `context`.
    fn episode(mill: &str, context: Option<ContextReading>) -> HistoryEvent {
        chatter_started(mill, context, None)
    }

    /// A manual capture of `subject` (no samples) in `context`.
    fn capture(subject: &str, context: Option<ContextReading>) -> HistoryEvent {
        HistoryEvent::Capture(Box::new(capture_without_samples(
            CaptureKind::Manual,
            subject,
            context,
        )))
    }

    /// Episodes and captures handed to the history with a stale or invalid context
    /// are counted by subject, evidence and status; valid ones and those without
    /// context tags are not.
    #[test]
    fn evidence_with_a_stale_or_invalid_context_is_counted_by_subject_and_status() {
        let config = millgate_config::History {
            path: PathBuf::from("unused.db"),
            retention_days: 400,
            max_size_mb: 1024,
            captures: CaptureSettings::defaults(1024),
            synchronous: Synchronous::Normal,
        };
        let history = History::new(Some(&config));
        let valid = ContextReading {
            context: Ok(ProcessContext::default()),
            stale: StaleTags::default(),
        };
        let mut stale_tags = StaleTags::default();
        stale_tags.insert("product");
        let stale = ContextReading {
            context: Ok(ProcessContext::default()),
            stale: stale_tags,
        };
        let invalid = ContextReading {
            context: Err(ContextError::Speed(-1.0)),
            stale: StaleTags::default(),
        };
        for event in [
            episode("TCM", Some(valid)),
            episode("TCM", Some(stale)),
            episode("TCM", Some(stale)),
            episode("TCM", Some(invalid)),
            episode("TCM", None),
            capture("TCM", Some(invalid)),
            capture("F1", Some(stale)),
            capture("F1", Some(valid)),
        ] {
            assert!(history.record(event));
        }
        let mut page = Exposition::new();
        history.write_families(&mut page);
        let text = page.into_text();
        let samples: Vec<&str> = text
            .lines()
            .filter(|line| line.starts_with("millgate_context_untrusted_total{"))
            .collect();
        assert_eq!(
            samples,
            [
                r#"millgate_context_untrusted_total{subject="F1",evidence="capture",status="stale"} 1"#,
                r#"millgate_context_untrusted_total{subject="TCM",evidence="capture",status="invalid"} 1"#,
                r#"millgate_context_untrusted_total{subject="TCM",evidence="episode",status="invalid"} 1"#,
                r#"millgate_context_untrusted_total{subject="TCM",evidence="episode",status="stale"} 2"#,
            ],
            "{text}"
        );
        // Without [history] nothing is recorded, nothing counted.
        let disabled = History::disabled();
        assert!(!disabled.record(episode("TCM", Some(invalid))));
        assert!(disabled.status().context_untrusted.is_empty());
    }
}
