//! The event history: every bite, wear estimate, alarm, chatter episode, source
//! outage and gateway start and stop in one SQLite file per gateway
//! (`history.path`), and the state a restart restores.
//!
//! - **One writer.** [`History`] is the handle the analysis, the publisher and the
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
//!   trend per week, aggregated by SQLite; [`summary`] what a report reads over a
//!   year without holding it (a driveline's TAF quantiles, its bites one by one, when
//!   a run without a recorded stop was last seen).
//!
//! Schema: [`schema`]; times: [`time`] (UTC ISO-8601 text).

pub mod events;
pub mod outages;
pub mod query;
pub mod restore;
pub mod retention;
pub mod schema;
pub mod series;
pub mod summary;
pub mod time;
pub mod writer;

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use events::HistoryEvent;
use restore::Restored;
use retention::Retention;

/// Events in flight to the writer. A bite every second on ten drivelines fills it in
/// minutes, not seconds: enough to ride out a slow commit (a busy SD card), small
/// enough (a few MiB) to bound memory when the store is stuck.
pub const QUEUE_CAPACITY: usize = 4096;

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

/// What the history is doing, for `/metrics` and the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HistoryState {
    /// No `[history]` configured.
    Disabled,
    /// The last batch committed (or nothing was written yet and the file is open).
    Ok,
    /// The last batch or the last open failed: see [`HistoryStatus::last_error`].
    Failing,
}

impl HistoryState {
    /// Gauge value: 0 disabled, 1 ok, 2 failing.
    pub fn code(self) -> u8 {
        match self {
            HistoryState::Disabled => 0,
            HistoryState::Ok => 1,
            HistoryState::Failing => 2,
        }
    }

    fn from_code(code: u8) -> Self {
        match code {
            1 => HistoryState::Ok,
            2 => HistoryState::Failing,
            _ => HistoryState::Disabled,
        }
    }
}

/// A snapshot of the history's counters.
#[derive(Debug, Clone, PartialEq)]
pub struct HistoryStatus {
    /// Disabled, ok or failing.
    pub state: HistoryState,
    /// Events handed to the writer.
    pub enqueued: u64,
    /// Events committed to the file.
    pub stored: u64,
    /// Events dropped because the queue was full.
    pub dropped_queue_full: u64,
    /// Events dropped because the file could not take them (open or commit failed).
    pub dropped_error: u64,
    /// Transactions committed.
    pub commits: u64,
    /// Sum of commit durations (the transaction from BEGIN to COMMIT), s.
    pub commit_seconds_sum: f64,
    /// Longest commit since start, s.
    pub commit_seconds_max: f64,
    /// Rows deleted by the retention.
    pub retention_deleted: u64,
    /// File size at the last retention check, bytes (0 before the first).
    pub file_bytes: u64,
    /// The last error, with its time (UTC), while the state is failing or since.
    pub last_error: Option<(time::UtcTime, String)>,
}

/// Counters shared by the handle and the writer thread.
#[derive(Debug, Default)]
pub(crate) struct Counters {
    state: AtomicU8,
    enqueued: AtomicU64,
    stored: AtomicU64,
    dropped_queue_full: AtomicU64,
    dropped_error: AtomicU64,
    commits: AtomicU64,
    commit_ns_sum: AtomicU64,
    commit_ns_max: AtomicU64,
    retention_deleted: AtomicU64,
    file_bytes: AtomicU64,
    last_error: Mutex<Option<(time::UtcTime, String)>>,
}

impl Counters {
    pub(crate) fn set_state(&self, state: HistoryState) {
        self.state.store(state.code(), Ordering::Relaxed);
    }

    pub(crate) fn state(&self) -> HistoryState {
        HistoryState::from_code(self.state.load(Ordering::Relaxed))
    }

    pub(crate) fn set_error(&self, message: String) {
        *crate::lock(&self.last_error) = Some((time::UtcTime::now(), message));
        self.set_state(HistoryState::Failing);
    }

    pub(crate) fn committed(&self, events: u64, took: Duration) {
        let ns = u64::try_from(took.as_nanos()).unwrap_or(u64::MAX);
        self.stored.fetch_add(events, Ordering::Relaxed);
        self.commits.fetch_add(1, Ordering::Relaxed);
        self.commit_ns_sum.fetch_add(ns, Ordering::Relaxed);
        self.commit_ns_max.fetch_max(ns, Ordering::Relaxed);
    }

    pub(crate) fn dropped(&self, events: u64) {
        self.dropped_error.fetch_add(events, Ordering::Relaxed);
    }

    pub(crate) fn retention(&self, deleted: u64, file_bytes: u64) {
        self.retention_deleted.fetch_add(deleted, Ordering::Relaxed);
        self.file_bytes.store(file_bytes, Ordering::Relaxed);
    }
}

/// The queue's sending end and the count of events put on it, changed together so
/// that the count orders events as the queue does.
#[derive(Debug)]
struct Queue {
    sender: Option<SyncSender<HistoryEvent>>,
    enqueued: u64,
}

/// What [`History::start`] hands the writer thread.
#[derive(Debug)]
struct Pending {
    config: millgate_config::History,
    receiver: Receiver<HistoryEvent>,
    settled: tokio::sync::watch::Sender<u64>,
}

#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    counters: Arc<Counters>,
    /// Events settled (committed or dropped by the writer), in queue order.
    settled: tokio::sync::watch::Receiver<u64>,
    /// The writer's ends until [`History::start`].
    pending: Mutex<Option<Pending>>,
    writer: Mutex<Option<std::thread::JoinHandle<()>>>,
    /// When a full queue was last logged (one warning per minute at most).
    full_logged: Mutex<Option<Instant>>,
}

/// The handle everything records through; cheap to clone. A disabled history (no
/// `[history]`) takes every event and does nothing with it.
#[derive(Debug, Clone)]
pub struct History {
    shared: Arc<Shared>,
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

impl History {
    /// A history that records nothing.
    pub fn disabled() -> Self {
        Self::new(None)
    }

    /// The history of `config` (disabled for `None`): events are queued from now on
    /// and written once [`Self::start`] has opened the file. No file is touched here
    /// (`millgate check` builds this too).
    pub fn new(config: Option<&millgate_config::History>) -> Self {
        let counters = Arc::new(Counters::default());
        let (settled_tx, settled) = tokio::sync::watch::channel(0);
        let (sender, pending) = match config {
            Some(config) => {
                counters.set_state(HistoryState::Ok);
                let (sender, receiver) = sync_channel(QUEUE_CAPACITY);
                let pending = Pending {
                    config: config.clone(),
                    receiver,
                    settled: settled_tx,
                };
                (Some(sender), Some(pending))
            }
            None => (None, None),
        };
        Self {
            shared: Arc::new(Shared {
                queue: Mutex::new(Queue {
                    sender,
                    enqueued: 0,
                }),
                counters,
                settled,
                pending: Mutex::new(pending),
                writer: Mutex::new(None),
                full_logged: Mutex::new(None),
            }),
        }
    }

    /// Open (or create) the file, bring its schema up to date, record this run and
    /// read what it restores; then start the writer thread. Blocks on file I/O (call
    /// it from a blocking task in async code); does nothing when disabled or started
    /// before. An unusable file is logged and shown on `/metrics`, not returned: the
    /// writer retries it and the service runs on with nothing restored.
    pub fn start(&self, run: RunInfo) -> Restored {
        let Some(pending) = crate::lock(&self.shared.pending).take() else {
            return Restored::default();
        };
        let counters = Arc::clone(&self.shared.counters);
        let retention = Retention::from_config(&pending.config);
        let (writer, restored) =
            writer::Writer::open(pending.config.path, retention, run, Arc::clone(&counters));
        let (receiver, settled) = (pending.receiver, pending.settled);
        let spawned = std::thread::Builder::new()
            .name("HistoryWriter".into())
            .spawn(move || writer.run(receiver, settled));
        match spawned {
            Ok(handle) => *crate::lock(&self.shared.writer) = Some(handle),
            Err(error) => {
                tracing::error!(%error, "cannot start the history writer thread");
                counters.set_error(format!("cannot start the history writer thread: {error}"));
                crate::lock(&self.shared.queue).sender = None;
            }
        }
        restored
    }

    /// Hand `event` to the writer without waiting; `false` when it was dropped (the
    /// queue is full, or the history is disabled or closed).
    pub fn record(&self, event: HistoryEvent) -> bool {
        let mut queue = crate::lock(&self.shared.queue);
        let Some(sender) = queue.sender.as_ref() else {
            return false;
        };
        match sender.try_send(event) {
            Ok(()) => {
                queue.enqueued += 1;
                self.shared
                    .counters
                    .enqueued
                    .store(queue.enqueued, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Full(_)) => {
                drop(queue);
                self.shared
                    .counters
                    .dropped_queue_full
                    .fetch_add(1, Ordering::Relaxed);
                let mut logged = crate::lock(&self.shared.full_logged);
                if logged.is_none_or(|at| at.elapsed() > Duration::from_secs(60)) {
                    *logged = Some(Instant::now());
                    tracing::warn!(
                        capacity = QUEUE_CAPACITY,
                        "history queue full: events dropped (the writer is stuck or too slow)"
                    );
                }
                false
            }
            Err(TrySendError::Disconnected(_)) => {
                self.shared.counters.dropped(1);
                false
            }
        }
    }

    /// Whether events are kept (a `[history]` is configured).
    pub fn is_enabled(&self) -> bool {
        self.shared.counters.state() != HistoryState::Disabled
    }

    /// Events handed to the writer so far.
    pub fn enqueued(&self) -> u64 {
        crate::lock(&self.shared.queue).enqueued
    }

    /// Events committed to the file so far.
    pub fn stored(&self) -> u64 {
        self.shared.counters.stored.load(Ordering::Relaxed)
    }

    /// Wait until the first `through` events recorded are settled (committed, or
    /// dropped by a failing writer), at most `limit`; returns whether they are. Returns
    /// at once when the history is disabled or failing: the PLC must not wait on a
    /// store that cannot take its events.
    pub async fn wait_settled(&self, through: u64, limit: Duration) -> bool {
        if self.shared.counters.state() != HistoryState::Ok {
            return true;
        }
        let mut settled = self.shared.settled.clone();
        let reached = tokio::time::timeout(limit, settled.wait_for(|&n| n >= through)).await;
        matches!(reached, Ok(Ok(_)))
    }

    /// The counters, for `/metrics`.
    pub fn status(&self) -> HistoryStatus {
        let c = &self.shared.counters;
        let load = |counter: &AtomicU64| counter.load(Ordering::Relaxed);
        HistoryStatus {
            state: c.state(),
            enqueued: load(&c.enqueued),
            stored: load(&c.stored),
            dropped_queue_full: load(&c.dropped_queue_full),
            dropped_error: load(&c.dropped_error),
            commits: load(&c.commits),
            commit_seconds_sum: load(&c.commit_ns_sum) as f64 * 1e-9,
            commit_seconds_max: load(&c.commit_ns_max) as f64 * 1e-9,
            retention_deleted: load(&c.retention_deleted),
            file_bytes: load(&c.file_bytes),
            last_error: crate::lock(&c.last_error).clone(),
        }
    }

    /// Stop taking events, let the writer commit what is queued, record the stop and
    /// close the file; waits for the writer thread (blocking: call it from a blocking
    /// task in async code). Later [`Self::record`]s are dropped.
    pub fn close(&self) {
        crate::lock(&self.shared.queue).sender = None;
        let handle = crate::lock(&self.shared.writer).take();
        if let Some(handle) = handle {
            if handle.join().is_err() {
                tracing::error!("the history writer thread panicked");
            }
        }
    }
}
