//! The event history: every bite, wear estimate, alarm, chatter episode, source
//! outage and gateway start and stop in one SQLite file per gateway
//! (`history.path`), and the state a restart restores.
//!
//! - **One writer.** [`History`] is the handle the analysis, the board and the
//!   outage monitor record through: [`History::record`] puts an event on a bounded
//!   queue with `try_send` and never waits (a full queue drops the event and counts
//!   it). The writer thread ([`writer`]) owns the only read-write connection (WAL,
//!   `synchronous=FULL`) and commits whatever is queued in one transaction (group
//!   commit). An event counts as stored only once its transaction has committed:
//!   [`History::stored`] counts those, [`History::wait_settled`] waits until every
//!   event recorded so far is committed or known dropped. The PLC writer waits for
//!   that (bounded) before each write, so a bite the PLC has seen is in the file.
//! - **Failures** (a full disk, a read-only folder, a corrupt file): the writer logs
//!   one clear error, drops what it cannot store (counted), shows the error on
//!   `/metrics` and tries again (a full disk at the next batch, a file it cannot open
//!   every [`writer::REOPEN_PERIOD`]); the analysis and the PLC writes go on.
//! - **Restart**: at start the file's per-driveline and per-mill state tables give the
//!   bite counters, the wear trend, latched alarms and the last values with their time
//!   ([`restore`]); restored values carry the driveline's "restored" flag until the
//!   next bite.
//! - **Retention** ([`retention`]): events older than `history.retention_days`, and the
//!   oldest events while the data passes `history.max_size_mb`, are deleted in chunks
//!   between batches; freed pages go back to the file system (incremental vacuum).
//! - **Reading** ([`query`]): [`query::HistoryReader`] opens its own read-only
//!   connection; `millgate history` and `millgate report` use it. [`series`] adds
//!   what a page plots over months: the gap and TAF in time buckets and the gap's
//!   trend per week, aggregated by SQLite.
//!
//! Schema: [`schema`]; times: [`crate::state::time`] (UTC ISO-8601 text). The handle
//! everything records through, [`History`], is the state layer's
//! ([`crate::state::history`]): this folder is the writer's side and the readers.

pub mod outages;
pub mod query;
pub mod restore;
pub mod retention;
pub mod schema;
pub mod series;
pub mod writer;

use std::path::PathBuf;

use crate::state::history::History;
use restore::Restored;
use retention::Retention;

/// Why the history file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    /// SQLite refused to open or use the file.
    #[error("history {}: {}", path.display(), explain(source))]
    Sqlite {
        /// The file.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// The schema could not be brought up to date.
    #[error("history {}: {source}", path.display())]
    Schema {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: schema::SchemaError,
    },
    /// A query's argument is outside its allowed range.
    #[error("history query: {name} = {value} is out of range ({allowed})")]
    Argument {
        /// The argument's name.
        name: &'static str,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// The driveline is neither configured in any run recorded in the file nor has
    /// bites in it.
    #[error("history {}: no driveline \"{name}\" in the file", path.display())]
    UnknownDriveline {
        /// The file.
        path: PathBuf,
        /// The name asked for.
        name: String,
    },
}

/// The driveline figures a bite row keeps ([`crate::state::catalogue::DRIVELINE`]'s
/// keys) and the column of table `bites` each is in: the history's mapping from the
/// catalogue. The other driveline figures are flags of the moment (the alarms table
/// records their changes) or counters of the run. A test holds the schema to it.
pub const BITE_COLUMNS: &[(&str, &str)] = &[
    ("bite_counter", "bite_counter"),
    ("last_bite_time", "time"),
    ("static_torque_knm", "static_torque_knm"),
    ("peak_torque_knm", "peak_torque_knm"),
    ("taf", "taf"),
    ("period_shift_s", "period_shift_s"),
    ("beta1_hz", "beta1_hz"),
    ("beta2_hz", "beta2_hz"),
    ("wear_index", "wear_index"),
    ("wear_trend", "wear_trend"),
    ("gap_mrad", "gap_mrad"),
    ("gap_low_mrad", "gap_low_mrad"),
    ("gap_high_mrad", "gap_high_mrad"),
    ("gap_coupling", "gap_coupling"),
    ("bites_pooled", "bites_pooled"),
    ("degraded", "degraded"),
];

/// SQLite's message, with what it means for the operator where the code says more.
pub(crate) fn explain(error: &rusqlite::Error) -> String {
    use rusqlite::ffi::ErrorCode;
    let hint = match error.sqlite_error_code() {
        Some(ErrorCode::DiskFull) => {
            " (the disk is full: free space, or lower history.max_size_mb)"
        }
        Some(ErrorCode::ReadOnly) => {
            " (the file or its folder is read-only: the service's user must be able to write both)"
        }
        Some(ErrorCode::CannotOpen) => {
            " (cannot create or open the file: does its folder exist and is it writable?)"
        }
        Some(ErrorCode::NotADatabase) | Some(ErrorCode::DatabaseCorrupt) => {
            " (the file is not a readable SQLite history: move it aside to start a new one)"
        }
        Some(ErrorCode::PermissionDenied) => " (permission denied)",
        _ => "",
    };
    format!("{error}{hint}")
}

/// What the history records about this run at its start.
#[derive(Debug, Clone)]
pub struct RunInfo {
    /// millgate's version, stored with the run.
    pub version: String,
    /// The configuration's `name`.
    pub config_name: String,
    /// Each driveline's settings (table `driveline_settings`).
    pub drivelines: Vec<DrivelineSettings>,
}

/// A driveline's settings as the history keeps them for reports.
#[derive(Debug, Clone, PartialEq)]
pub struct DrivelineSettings {
    /// The driveline's name.
    pub name: String,
    /// TAF warning threshold.
    pub taf_warning: f64,
    /// TAF alarm threshold.
    pub taf_alarm: f64,
    /// The driveline model file, as configured.
    pub model: Option<String>,
    /// The gap diagnosis' warning threshold, mrad; `None` without a model (no gap
    /// diagnosis).
    pub gap_warning_mrad: Option<f64>,
    /// The gap diagnosis' alarm threshold, mrad; `None` without a model.
    pub gap_alarm_mrad: Option<f64>,
}

impl RunInfo {
    /// The run of `config` with this millgate's version.
    pub fn of(config: &millgate_config::Config) -> Self {
        Self {
            version: env!("CARGO_PKG_VERSION").to_owned(),
            config_name: config.name.clone(),
            drivelines: config
                .drivelines
                .iter()
                .map(|driveline| DrivelineSettings {
                    name: driveline.name.clone(),
                    taf_warning: driveline.thresholds.taf_warning,
                    taf_alarm: driveline.thresholds.taf_alarm,
                    model: driveline
                        .model
                        .as_ref()
                        .map(|path| path.display().to_string()),
                    // The gap diagnosis runs only with a model.
                    gap_warning_mrad: driveline
                        .model
                        .as_ref()
                        .map(|_| driveline.thresholds.gap_warning_mrad),
                    gap_alarm_mrad: driveline
                        .model
                        .as_ref()
                        .map(|_| driveline.thresholds.gap_alarm_mrad),
                })
                .collect(),
        }
    }
}

/// Open (or create) `history`'s file, bring its schema up to date, record this run and
/// read what it restores; then start the writer thread. Blocks on file I/O (call it
/// from a blocking task in async code); does nothing when disabled or started before.
/// An unusable file is logged and shown on `/metrics`, not returned: the writer
/// retries it and the service runs on with nothing restored.
pub fn start(history: &History, run: RunInfo) -> Restored {
    let Some(ends) = history.take_writer_ends() else {
        return Restored::default();
    };
    let counters = history.counters();
    let retention = Retention::from_config(&ends.config);
    let (writer, restored) = writer::Writer::open(ends.config.path, retention, run, counters);
    let (receiver, settled) = (ends.receiver, ends.settled);
    let spawned = std::thread::Builder::new()
        .name("HistoryWriter".into())
        .spawn(move || writer.run(receiver, settled));
    match spawned {
        Ok(handle) => history.set_writer(Some(handle)),
        Err(error) => {
            tracing::error!(%error, "cannot start the history writer thread");
            history
                .counters()
                .set_error(format!("cannot start the history writer thread: {error}"));
            history.set_writer(None);
        }
    }
    restored
}
