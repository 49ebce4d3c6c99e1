//! What the unit tests of several rooms share: the example configurations, and
//! evidence as the analysis hands it to the history.

use std::path::PathBuf;

use millgate_config::Config;

use crate::state::captures::{CaptureKind, CaptureRecord, KeepClass};
use crate::state::context::ContextReading;
use crate::state::events::{ChatterWindow, HistoryEvent};
use crate::state::time::UtcTime;

/// The path of `config/examples/<name>`.
pub(crate) fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../config/examples")
        .join(name)
}

/// `connection`'s file at the current schema, with gateway run 1 that rows can name.
pub(crate) fn history_with_run(connection: &mut rusqlite::Connection) {
    crate::history::schema::migrate(connection).expect("the schema");
    connection
        .execute_batch(
            "INSERT INTO gateway_runs (id, started_at, version, config_name)
             VALUES (1, 't', 'v', 'c')",
        )
        .expect("a run");
}

/// A history file `history.db` in a new folder of the temporary directory named after
/// `name` ([`history_with_run`]): the folder, the file and a connection to it.
pub(crate) fn history_file(name: &str) -> (PathBuf, PathBuf, rusqlite::Connection) {
    let folder = std::env::temp_dir().join(format!(
        "millgate-{name}-{}-{}",
        std::process::id(),
        UtcTime::now().unix_ms()
    ));
    std::fs::create_dir_all(&folder).expect("a folder");
    let path = folder.join("history.db");
    let mut connection = rusqlite::Connection::open(&path).expect("the file");
    history_with_run(&mut connection);
    (folder, path, connection)
}

/// The example configuration `config/examples/<name>`, loaded.
pub(crate) fn example_config(name: &str) -> Config {
    millgate_config::load(&example(name)).expect("the example loads")
}

/// A capture of `kind` of `subject` without channels, kept as important, in `context`.
pub(crate) fn capture_without_samples(
    kind: CaptureKind,
    subject: &str,
    context: Option<ContextReading>,
) -> CaptureRecord {
    CaptureRecord {
        kind,
        subject: subject.into(),
        bite: None,
        first_sample_unix_ns: 1_790_000_000_000_000_000,
        kernel_time: false,
        sample_rate_hz: 2500.0,
        channels: Vec::new(),
        gaps: Vec::new(),
        analysis: None,
        episode: None,
        keep: KeepClass::Important,
        context,
    }
}

/// A chatter episode's start of `mill` at 2026-11-29T10:00:00Z (sigma_n 0.5 Hz,
/// K_mean 0.9, 180 Hz) in `context`, judged by the thresholds of product group
/// `thresholds_group` (`None`: the mill's).
pub(crate) fn chatter_started(
    mill: &str,
    context: Option<ContextReading>,
    thresholds_group: Option<&str>,
) -> HistoryEvent {
    HistoryEvent::ChatterStarted {
        time: UtcTime::parse("2026-11-29T10:00:00.000Z").expect("a time"),
        mill: mill.into(),
        window: ChatterWindow {
            sigma_n_hz: 0.5,
            k_mean: 0.9,
            frequency_hz: Some(180.0),
            synchronized: false,
        },
        context,
        thresholds_group: thresholds_group.map(str::to_owned),
    }
}
