//! The writer thread: owns the history's only read-write connection and commits
//! queued events in groups.
//!
//! Each turn takes every event queued (up to [`MAX_BATCH`]) and writes them in one
//! transaction; the counters say an event is stored only after that transaction has
//! committed in WAL mode: with `history.synchronous = "normal"` (the default) once the
//! WAL holds it (it survives a crash or kill of the gateway; a power cut may lose the
//! commits since the last checkpoint), with `"full"` once the WAL is synced to disk.
//! Checkpoints run on a thread of their own (`checkpoint.rs`). Between turns, only
//! while nothing is queued, the writer runs one bounded retention step when one is
//! due; an event recorded meanwhile interrupts it (after 20 steps interrupted in a
//! row, one runs to its end).

use std::path::PathBuf;

use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rusqlite::{params, Connection, OpenFlags};

use super::checkpoint::file_identity;
use super::error::{explain, HistoryError};
use super::restore::Restored;
use super::retention::{Retention, RetentionState};
use super::rows::insert;
use super::run::{insert_settings, RunInfo};
use super::schema;
use crate::state::events::HistoryEvent;
use crate::state::history::History;
use crate::state::history::{Counters, HistoryState};
use crate::state::time::UtcTime;

/// Most events committed in one transaction: bounds the time a commit holds the
/// write lock (a read-only reader never waits for it in WAL mode).
pub const MAX_BATCH: usize = 2048;
/// How long the writer waits before opening a file again after it failed to open or
/// to write (a corrupt file, a read-only folder): a failing file is tried again at
/// this pace, not on every event.
pub const REOPEN_PERIOD: Duration = Duration::from_secs(5);
/// Longest wait of a busy connection on a lock held by another process (a tool
/// writing the file, a checkpoint), ms.
const BUSY_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest wait before a batch kept for a locked file is tried again.
const RETRY_PERIOD: Duration = Duration::from_millis(500);
/// Largest WAL kept after a checkpoint, bytes.
const WAL_SIZE_LIMIT: i64 = 64 * 1024 * 1024;
/// Repeat an unchanged error in the log at most this often.
const ERROR_LOG_PERIOD: Duration = Duration::from_secs(60);
/// SQLite instructions between two looks, during a retention step, at whether an
/// event was recorded (well under a millisecond of work).
const RETENTION_CHECK_OPS: std::ffi::c_int = 1_000;
/// Retention steps interrupted in a row by recorded events after which the next one
/// runs to its end: under a load that never leaves the queue empty for a step's
/// length, the file is still trimmed (a step is bounded: [`Retention`]'s chunks).
const MAX_INTERRUPTED_STEPS: u32 = 20;

/// Open `path` read-write (creating it), in WAL mode with `synchronous=FULL`, and
/// bring its schema up to date.
pub fn connect(path: &std::path::Path) -> Result<Connection, HistoryError> {
    let sqlite = |source| HistoryError::Sqlite {
        path: path.to_path_buf(),
        source,
    };
    let mut connection = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_CREATE
            | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sqlite)?;
    connection.busy_timeout(BUSY_TIMEOUT).map_err(sqlite)?;
    // Another application's SQLite file is refused before anything here changes it
    // (WAL mode, auto-vacuum, tables).
    super::error::check_file_owner(&connection, path)?;
    // A new file gets incremental auto-vacuum, so the retention can hand freed pages
    // back to the file system in small steps. It can only be set before the first
    // table and before WAL mode.
    let tables: i64 = connection
        .query_row("SELECT count(*) FROM sqlite_schema", [], |row| row.get(0))
        .map_err(sqlite)?;
    if tables == 0 {
        connection
            .pragma_update(None, "auto_vacuum", "INCREMENTAL")
            .map_err(sqlite)?;
    }
    let mode: String = connection
        .pragma_update_and_check(None, "journal_mode", "WAL", |row| row.get(0))
        .map_err(sqlite)?;
    if !mode.eq_ignore_ascii_case("wal") {
        return Err(sqlite(rusqlite::Error::SqliteFailure(
            rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_CANTOPEN),
            Some(format!(
                "WAL mode refused (journal mode {mode}): the file system must support shared memory"
            )),
        )));
    }
    connection
        .pragma_update(None, "synchronous", "FULL")
        .map_err(sqlite)?;
    connection
        .pragma_update(None, "journal_size_limit", WAL_SIZE_LIMIT)
        .map_err(sqlite)?;
    schema::migrate(&mut connection).map_err(|source| HistoryError::Schema {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(connection)
}

/// Mark what the previous run left open as ended by the restart and insert the run
/// `run` started at `started_at`; its id.
fn begin_run(
    connection: &mut Connection,
    started_at: UtcTime,
    run: &RunInfo,
) -> rusqlite::Result<i64> {
    let now = UtcTime::now().to_string();
    let transaction = connection.transaction()?;
    transaction.execute(
        "UPDATE gateway_runs SET ended = 'unclean' WHERE ended IS NULL",
        [],
    )?;
    for table in ["source_outages", "chatter_episodes"] {
        transaction.execute(
            &format!(
                "UPDATE {table} SET ended_at = ?1, ended_by = 'restart' WHERE ended_at IS NULL"
            ),
            [&now],
        )?;
    }
    let run_id = insert_run(&transaction, started_at, run)?;
    transaction.commit()?;
    Ok(run_id)
}

/// Whether `error` says another connection holds the lock (past the busy timeout).
fn locked(error: &rusqlite::Error) -> bool {
    matches!(
        error.sqlite_error_code(),
        Some(rusqlite::ErrorCode::DatabaseBusy | rusqlite::ErrorCode::DatabaseLocked)
    )
}

/// Whether `error` says the disk is full.
fn disk_full(error: &rusqlite::Error) -> bool {
    error.sqlite_error_code() == Some(rusqlite::ErrorCode::DiskFull)
}

/// What became of a batch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Written {
    /// Committed, or dropped and counted.
    Settled,
    /// Kept for another try (the file is locked by another process).
    Kept,
}

/// The writer: its connection (when the file is usable), this run's row and the
/// retention's progress.
#[derive(Debug)]
pub(crate) struct Writer {
    path: PathBuf,
    run: RunInfo,
    started_at: UtcTime,
    connection: Option<Connection>,
    /// The file the connection has open (device and inode), to notice it deleted or
    /// replaced.
    file: Option<(u64, u64)>,
    /// This run's row in the open file; `None` until it is confirmed there.
    run_id: Option<i64>,
    /// This run's row id in the file it was last written to (a reopen of that same
    /// file finds it again instead of inserting a second row).
    last_run_id: Option<i64>,
    /// Whether the file's state was read once (a start restores only once).
    restored: bool,
    next_open: Instant,
    retention: Retention,
    retention_state: RetentionState,
    /// Retention steps interrupted in a row by recorded events.
    retention_interrupted: u32,
    synchronous: millgate_config::Synchronous,
    counters: Arc<Counters>,
    last_logged: Option<(Instant, String)>,
}

/// Insert `run`'s row, started at `started_at`, and its drivelines' settings; the
/// run's id. (Public for fixtures that write a history as the writer would.)
pub fn insert_run(
    connection: &Connection,
    started_at: UtcTime,
    run: &RunInfo,
) -> rusqlite::Result<i64> {
    let started_at = started_at.to_string();
    connection.execute(
        "INSERT INTO gateway_runs (started_at, version, config_name, config_hash)
             VALUES (?1, ?2, ?3, ?4)",
        params![started_at, run.version, run.config_name, run.config_hash],
    )?;
    let run_id = connection.last_insert_rowid();
    insert_settings(connection, run_id, &started_at, &run.drivelines)?;
    Ok(run_id)
}

impl Writer {
    /// A writer for `path`; nothing is opened yet ([`Self::run`] does).
    pub(crate) fn new(
        config: &millgate_config::History,
        run: RunInfo,
        counters: Arc<Counters>,
    ) -> Self {
        Self {
            path: config.path.clone(),
            run,
            started_at: UtcTime::now(),
            connection: None,
            file: None,
            run_id: None,
            last_run_id: None,
            restored: false,
            next_open: Instant::now(),
            retention: Retention::from_config(config),
            retention_state: RetentionState::default(),
            retention_interrupted: 0,
            synchronous: config.synchronous,
            counters,
            last_logged: None,
        }
    }

    /// Connect, check the file (`quick_check`), read what it restores (the first
    /// time only: `Some` then), and record this run in it. A failure to record the
    /// run (a full disk) keeps the connection: the run is recorded with the next
    /// batch. Retried after [`REOPEN_PERIOD`] on failure.
    fn try_open(&mut self) -> Result<Option<Restored>, HistoryError> {
        self.next_open = Instant::now() + REOPEN_PERIOD;
        let connection = connect(&self.path)?;
        // `connect` leaves `synchronous=FULL` (the other writers of the file, rare,
        // keep it); the checkpointer thread checkpoints, this connection only past the
        // fallback.
        connection
            .pragma_update(None, "synchronous", self.synchronous.name())
            .and_then(|()| {
                connection.pragma_update(
                    None,
                    "wal_autocheckpoint",
                    super::checkpoint::FALLBACK_CHECKPOINT_PAGES,
                )
            })
            .map_err(|source| self.error(source))?;
        super::query::quick_check(&connection, &self.path)?;
        let restored = match self.restored {
            false => Some(super::restore::read(&connection).map_err(|source| self.error(source))?),
            true => None,
        };
        self.restored = true;
        self.file = file_identity(&self.path);
        self.connection = Some(connection);
        self.run_id = None;
        match self.confirm_run() {
            Ok(run_id) => {
                tracing::info!(path = %self.path.display(), run = run_id, "history open");
                self.recovered();
            }
            Err(error) => {
                let message = format!(
                    "history {}: this run cannot be recorded: {}",
                    self.path.display(),
                    explain(&error)
                );
                // A full disk may free up and a lock be released under this
                // connection; a file SQLite could open only read-only (a read-only
                // folder or file system) stays so until it is opened again.
                self.failed(&message, &[], !(disk_full(&error) || locked(&error)));
            }
        }
        Ok(restored)
    }

    /// This run's row in the open file: found again (a reopen of the same file), or
    /// inserted after closing what the previous run left open.
    fn confirm_run(&mut self) -> rusqlite::Result<i64> {
        if let Some(run_id) = self.run_id {
            return Ok(run_id);
        }
        let Some(connection) = self.connection.as_mut() else {
            return Err(rusqlite::Error::InvalidQuery);
        };
        let started_at = self.started_at.to_string();
        let ours = match self.last_run_id {
            Some(run_id) => connection
                .query_row(
                    "SELECT id FROM gateway_runs WHERE id = ?1 AND started_at = ?2",
                    params![run_id, started_at],
                    |row| row.get::<_, i64>(0),
                )
                .map(Some)
                .or_else(|error| match error {
                    rusqlite::Error::QueryReturnedNoRows => Ok(None),
                    error => Err(error),
                })?,
            None => None,
        };
        let run_id = match ours {
            Some(run_id) => run_id,
            None => begin_run(connection, self.started_at, &self.run)?,
        };
        self.run_id = Some(run_id);
        self.last_run_id = Some(run_id);
        Ok(run_id)
    }

    /// Open the file the first time and read what it restores. While the file exists
    /// but cannot be read for now (locked by another process, a file system error),
    /// the start waits for it: nothing may count bites before the file's counters are
    /// known. A file that cannot be a history (damaged, another application's) or
    /// cannot be created is given up at once: the service runs without what it would
    /// restore, and the writer tries it again later. `None` when the history was
    /// closed while waiting; events recorded meanwhile are kept in `batch`.
    fn open_first(
        &mut self,
        events: &Receiver<HistoryEvent>,
        batch: &mut Vec<HistoryEvent>,
    ) -> Option<Restored> {
        loop {
            let existed = self.path.exists();
            let error = match self.try_open() {
                Ok(restored) => return Some(restored.unwrap_or_default()),
                Err(error) => error,
            };
            if !existed || !error.may_pass() {
                self.failed(&error.to_string(), &[], true);
                return Some(Restored::default());
            }
            let message = error.to_string();
            self.counters.set_error(message.clone());
            tracing::error!(
                error = message,
                retry_in = ?REOPEN_PERIOD,
                "the history file cannot be read: the start waits for it (no bite is \
                 counted or published before its counters are restored)"
            );
            match events.recv_timeout(REOPEN_PERIOD) {
                Ok(event) => batch.push(event),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return None,
            }
        }
    }

    fn error(&self, source: rusqlite::Error) -> HistoryError {
        HistoryError::Sqlite {
            path: self.path.clone(),
            source,
        }
    }

    /// Whether the open connection's file is still the one at the path (not deleted,
    /// not replaced by another file).
    fn same_file(&self) -> bool {
        self.file.is_some() && file_identity(&self.path) == self.file
    }

    /// Open the file (the start waits while it exists but cannot be read: see
    /// [`Self::open_first`]) and send what it restores on `opened`; then commit
    /// until every sender has gone and the queue is empty, and record the stop.
    /// `settled` counts the events committed or dropped so far, in queue order.
    ///
    /// A batch the file refuses because another process holds its lock past the
    /// busy timeout is kept and tried again (at most [`MAX_BATCH`] events kept here;
    /// meanwhile the queue fills, and past its [`QUEUE_CAPACITY`] events are dropped
    /// there, counted and logged).
    ///
    /// [`QUEUE_CAPACITY`]: crate::state::history::QUEUE_CAPACITY
    pub(crate) fn run(
        mut self,
        events: Receiver<HistoryEvent>,
        signal: crate::state::changes::Signal,
        opened: std::sync::mpsc::SyncSender<Restored>,
    ) {
        let mut batch = Vec::with_capacity(MAX_BATCH);
        let Some(restored) = self.open_first(&events, &mut batch) else {
            return;
        };
        let _ = opened.send(restored);
        // Stopped (and its connection closed) after the writer's, at the return.
        let _checkpointer =
            super::checkpoint::Checkpointer::start(self.path.clone(), Arc::clone(&self.counters));
        let mut done = 0u64;
        let mut closing = false;
        while !closing {
            // A kept batch is retried at the pace of new events, at least every
            // RETRY_PERIOD.
            let wait = match batch.is_empty() {
                true => self.retention_state.wait(),
                false => RETRY_PERIOD,
            };
            if batch.len() < MAX_BATCH {
                match events.recv_timeout(wait) {
                    Ok(event) => batch.push(event),
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => closing = true,
                }
            } else {
                std::thread::sleep(wait);
            }
            while batch.len() < MAX_BATCH {
                match events.try_recv() {
                    Ok(event) => batch.push(event),
                    Err(_) => break,
                }
            }
            if !batch.is_empty() {
                let settled_now = match self.write(&batch) {
                    Written::Settled => true,
                    Written::Kept if closing => {
                        // The last try at the stop: what the lock still keeps out is lost.
                        self.counters.dropped(&batch);
                        tracing::error!(
                            events = batch.len(),
                            "history: events not stored at the stop (the file stayed locked)"
                        );
                        true
                    }
                    Written::Kept => false,
                };
                if settled_now {
                    done += batch.len() as u64;
                    batch.clear();
                    signal.settled(done);
                }
            }
            if batch.is_empty() {
                self.retention_step(done);
            }
        }
        self.finish();
    }

    /// Write `batch` in one transaction: stored, or dropped (counted) when the file
    /// cannot take it, or kept for another try when another process holds the lock.
    /// A file deleted or replaced since it was opened is noticed here: an error, and
    /// the batch goes to the file now at the path (a new one when there is none).
    fn write(&mut self, batch: &[HistoryEvent]) -> Written {
        let events = batch.len() as u64;
        if self.connection.is_some() && !self.same_file() {
            let message = format!(
                "history {}: the file was deleted or replaced while in use: a new file is \
                 opened at the path (nothing more goes to the old one)",
                self.path.display()
            );
            self.failed(&message, &[], true);
            self.next_open = Instant::now();
        }
        if self.connection.is_none() && Instant::now() >= self.next_open {
            if let Err(error) = self.try_open() {
                self.failed(&error.to_string(), &[], true);
            }
        }
        if self.connection.is_some() && self.run_id.is_none() {
            if let Err(error) = self.confirm_run() {
                let message = format!(
                    "history {}: this run cannot be recorded: {}",
                    self.path.display(),
                    explain(&error)
                );
                if locked(&error) {
                    self.failed(&format!("{message} (events kept, tried again)"), &[], false);
                    return Written::Kept;
                }
                self.failed(&message, batch, !disk_full(&error));
                return Written::Settled;
            }
        }
        let (Some(connection), Some(run_id)) = (self.connection.as_mut(), self.run_id) else {
            self.counters.dropped(batch);
            return Written::Settled;
        };
        let started = Instant::now();
        let written = connection.transaction().and_then(|transaction| {
            for event in batch {
                insert(&transaction, run_id, event)?;
            }
            transaction.commit()
        });
        match written {
            Ok(()) => {
                self.counters.committed(events, started.elapsed());
                if self.counters.state() == HistoryState::Failing {
                    self.recovered();
                }
                Written::Settled
            }
            Err(error) => {
                let message = format!(
                    "history {}: cannot store {events} events: {}",
                    self.path.display(),
                    explain(&error)
                );
                if locked(&error) {
                    // Another process holds the lock: nothing is wrong with the file or
                    // the connection; the batch waits for the lock.
                    self.failed(&format!("{message} (kept, tried again)"), &[], false);
                    return Written::Kept;
                }
                // A full disk may free up with the connection as it is; anything else
                // (a file made read-only, replaced or damaged) is opened afresh.
                self.failed(&message, batch, !disk_full(&error));
                Written::Settled
            }
        }
    }

    /// Record a failure: counters, state, a log line unless the same one was logged
    /// within [`ERROR_LOG_PERIOD`]; `dropped` are the events lost; `reopen` drops the
    /// connection.
    fn failed(&mut self, message: &str, dropped: &[HistoryEvent], reopen: bool) {
        self.counters.dropped(dropped);
        self.counters.set_error(message.to_owned());
        if reopen {
            self.connection = None;
            self.file = None;
            self.run_id = None;
            self.next_open = Instant::now() + REOPEN_PERIOD;
        }
        let repeat = self
            .last_logged
            .as_ref()
            .is_some_and(|(at, last)| last == message && at.elapsed() < ERROR_LOG_PERIOD);
        if !repeat {
            tracing::error!(
                error = message,
                dropped_total = self.counters.dropped_errors(),
                retry_in = ?REOPEN_PERIOD,
                "history not stored; the service goes on without it"
            );
            self.last_logged = Some((Instant::now(), message.to_owned()));
        }
    }

    fn recovered(&mut self) {
        self.last_logged = None;
        // A failing checkpoint keeps the state failing until one succeeds.
        if self.counters.checkpoint_failing() {
            return;
        }
        if self.counters.state() == HistoryState::Failing {
            tracing::info!(path = %self.path.display(), "history stored again");
        }
        self.counters.set_state(HistoryState::Ok);
    }

    /// One retention step when one is due and no event is queued beyond the `taken`
    /// the writer has taken: an event recorded during the step interrupts it (its
    /// transaction rolls back, and the step is tried again after that event's commit),
    /// unless [`MAX_INTERRUPTED_STEPS`] steps were interrupted in a row.
    fn retention_step(&mut self, taken: u64) {
        let counters = Arc::clone(&self.counters);
        self.retention_step_unless(move || counters.enqueued() > taken);
    }

    /// [`Self::retention_step`] with `queued` saying whether an event waits: looked at
    /// before the step, and during it every [`RETENTION_CHECK_OPS`] instructions.
    fn retention_step_unless(&mut self, mut queued: impl FnMut() -> bool + Send + 'static) {
        let Some(connection) = self.connection.as_mut() else {
            return;
        };
        if !self.retention_state.due() || queued() {
            return;
        }
        if self.retention_interrupted < MAX_INTERRUPTED_STEPS {
            // Only fails on a closed connection, which the writer never holds.
            let _ = connection.progress_handler(RETENTION_CHECK_OPS, Some(queued));
        }
        let step = self
            .retention
            .step(connection, UtcTime::now(), &mut self.retention_state);
        let _ = connection.progress_handler(RETENTION_CHECK_OPS, None::<fn() -> bool>);
        match step {
            Ok(step) => {
                self.retention_interrupted = 0;
                self.counters.retention(step.deleted, step.file_bytes);
            }
            Err(error)
                if error.sqlite_error_code() == Some(rusqlite::ErrorCode::OperationInterrupted) =>
            {
                // Still due: tried again once the queue is empty.
                self.retention_interrupted += 1;
            }
            Err(error) => {
                let message = format!(
                    "history {}: retention failed: {}",
                    self.path.display(),
                    explain(&error)
                );
                self.retention_state.failed();
                tracing::warn!(error = message, "history retention step failed");
            }
        }
    }

    /// Record the clean stop: this run's end and what it leaves open.
    fn finish(mut self) {
        let (Some(connection), Some(run_id)) = (self.connection.as_mut(), self.run_id) else {
            return;
        };
        let now = UtcTime::now().to_string();
        let stopped = connection.transaction().and_then(|transaction| {
            transaction.execute(
                "UPDATE gateway_runs SET stopped_at = ?1, ended = 'stopped' WHERE id = ?2",
                params![now, run_id],
            )?;
            for table in ["source_outages", "chatter_episodes"] {
                transaction.execute(
                    &format!(
                        "UPDATE {table} SET ended_at = ?1, ended_by = 'stop' WHERE ended_at IS NULL"
                    ),
                    [&now],
                )?;
            }
            transaction.commit()
        });
        match stopped {
            Ok(()) => tracing::info!(path = %self.path.display(), "history closed"),
            Err(error) => tracing::warn!(
                path = %self.path.display(),
                error = explain(&error),
                "history: the stop could not be recorded"
            ),
        }
    }
}

/// Start the writer thread for `history`: it opens (or creates) the file, brings its
/// schema up to date, records this run and reads what the start restores, then
/// commits what is recorded. Returns the restored state once read (blocking: call it
/// from a blocking task in async code); does nothing when disabled or started
/// before. While the file exists but cannot be read (another process holds it
/// locked), this waits. A file that cannot be used (damaged, another
/// application's, a folder that cannot take it) is logged and shown on `/metrics`,
/// not returned: the writer retries it and the service runs on with nothing restored.
pub fn start(history: &History, run: RunInfo) -> Restored {
    spawn(history, run)
        .and_then(|opened| opened.recv().ok())
        .unwrap_or_default()
}

/// Start the writer thread for `history` (see [`start`]) and return at once; the
/// restored state comes on the receiver once the file was read. The receiver ends
/// without one when the history is closed ([`History::close`]) before that: the
/// file never became readable. `None` when disabled or started before.
pub(crate) fn spawn(
    history: &History,
    run: RunInfo,
) -> Option<std::sync::mpsc::Receiver<Restored>> {
    let ends = history.take_writer_ends()?;
    let counters = history.counters();
    let writer = Writer::new(&ends.config, run, counters);
    let (receiver, signal) = (ends.receiver, ends.signal);
    let (opened, restored) = std::sync::mpsc::sync_channel(1);
    let spawned = std::thread::Builder::new()
        .name("HistoryWriter".into())
        .spawn(move || writer.run(receiver, signal, opened));
    match spawned {
        Ok(handle) => history.set_writer(Some(handle)),
        Err(error) => {
            tracing::error!(%error, "cannot start the history writer thread");
            history
                .counters()
                .set_error(format!("cannot start the history writer thread: {error}"));
            history.set_writer(None);
            return None;
        }
    }
    Some(restored)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A writer on a new file whose retention (1 day, 500 rows a step) has 3 000 bites
    /// of ten days ago to delete, with its step due; the file's folder, to remove.
    fn writer_with_old_bites(name: &str) -> (Writer, PathBuf) {
        let folder =
            std::env::temp_dir().join(format!("millgate-writer-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&folder);
        std::fs::create_dir_all(&folder).unwrap();
        let config = millgate_config::History {
            path: folder.join("history.db"),
            retention_days: 1,
            max_size_mb: 1024,
            captures: millgate_config::CaptureSettings::defaults(1024),
            synchronous: millgate_config::Synchronous::default(),
        };
        let run = RunInfo {
            version: "test".into(),
            config_name: "test".into(),
            drivelines: Vec::new(),
            config_hash: String::new(),
        };
        let mut writer = Writer::new(&config, run, Arc::default());
        writer.try_open().unwrap();
        let start = UtcTime::now().minus(Duration::from_secs(10 * 86_400));
        writer
            .connection
            .as_ref()
            .unwrap()
            .execute(
                "WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n WHERE i < 2999)
                 INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, taf, quality, degraded)
                 SELECT ?2, 'F1', strftime('%Y-%m-%dT%H:%M:%fZ', ?1, '+' || i || ' minutes'),
                     i, 'torque', 100.0, 200.0, 2.0, 'good', 0 FROM n",
                params![start.to_string(), writer.run_id.unwrap()],
            )
            .unwrap();
        std::thread::sleep(super::super::retention::BUSY_PERIOD);
        assert!(writer.retention_state.due());
        (writer, folder)
    }

    fn bites(writer: &Writer) -> i64 {
        writer
            .connection
            .as_ref()
            .unwrap()
            .query_row("SELECT count(*) FROM bites", [], |row| row.get(0))
            .unwrap()
    }

    #[test]
    fn a_queued_event_keeps_a_due_retention_step_from_starting() {
        let (mut writer, folder) = writer_with_old_bites("queued");
        writer.retention_step_unless(|| true);
        assert_eq!(bites(&writer), 3000, "no step while an event waits");
        assert!(writer.retention_state.due());
        writer.retention_step_unless(|| false);
        assert_eq!(bites(&writer), 2500, "one chunk once the queue is empty");
        drop(writer);
        std::fs::remove_dir_all(folder).unwrap();
    }

    /// An event recorded once the step has started (the condition is false when the
    /// step begins, true from then on) interrupts it: nothing deleted, still due;
    /// after `MAX_INTERRUPTED_STEPS` such steps the next one runs to its end.
    #[test]
    fn an_event_recorded_during_a_step_interrupts_it_until_too_many_were() {
        let (mut writer, folder) = writer_with_old_bites("interrupted");
        let arriving = || {
            let mut looks = 0u32;
            move || {
                looks += 1;
                looks > 1
            }
        };
        for interrupted in 1..=MAX_INTERRUPTED_STEPS {
            writer.retention_step_unless(arriving());
            assert_eq!(bites(&writer), 3000, "step {interrupted} rolled back");
            assert_eq!(writer.retention_interrupted, interrupted);
            assert!(writer.retention_state.due(), "tried again");
        }
        writer.retention_step_unless(arriving());
        assert_eq!(
            bites(&writer),
            2500,
            "the step after too many interrupted ones"
        );
        assert_eq!(writer.retention_interrupted, 0);
        drop(writer);
        std::fs::remove_dir_all(folder).unwrap();
    }
}
