//! The writer thread: owns the history's only read-write connection and commits
//! queued events in groups.
//!
//! Each turn takes every event queued (up to [`MAX_BATCH`]) and writes them in one
//! transaction; the counters say an event is stored only after that transaction has
//! committed with `synchronous=FULL` in WAL mode, i.e. after the WAL is on disk.
//! Between turns the writer runs one bounded retention step when one is due.

use std::path::PathBuf;

use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rusqlite::{params, Connection, OpenFlags, Transaction};

use super::error::{explain, HistoryError};
use super::restore::Restored;
use super::retention::{Retention, RetentionState};
use super::run::RunInfo;
use super::schema;
use crate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, BiteRecord, ChatterWindow, HistoryEvent,
};
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
/// Largest WAL kept after a checkpoint, bytes.
const WAL_SIZE_LIMIT: i64 = 64 * 1024 * 1024;
/// Repeat an unchanged error in the log at most this often.
const ERROR_LOG_PERIOD: Duration = Duration::from_secs(60);

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

/// The writer: its connection (when the file is usable), this run's row and the
/// retention's progress.
#[derive(Debug)]
pub(crate) struct Writer {
    path: PathBuf,
    run: RunInfo,
    started_at: UtcTime,
    connection: Option<Connection>,
    run_id: Option<i64>,
    next_open: Instant,
    retention: Retention,
    retention_state: RetentionState,
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
        "INSERT INTO gateway_runs (started_at, version, config_name) VALUES (?1, ?2, ?3)",
        params![started_at, run.version, run.config_name],
    )?;
    let run_id = connection.last_insert_rowid();
    for driveline in &run.drivelines {
        connection.execute(
            "INSERT INTO driveline_settings (run_id, time, driveline, taf_warning, taf_alarm,
                 model, gap_warning_mrad, gap_alarm_mrad)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
            params![
                run_id,
                started_at,
                driveline.name,
                driveline.taf_warning,
                driveline.taf_alarm,
                driveline.model,
                driveline.gap_warning_mrad,
                driveline.gap_alarm_mrad
            ],
        )?;
    }
    Ok(run_id)
}

impl Writer {
    /// Open the file, record this run, and read what it restores. A failure is
    /// logged and counted; the writer tries again later.
    pub(crate) fn open(
        path: PathBuf,
        retention: Retention,
        run: RunInfo,
        counters: Arc<Counters>,
    ) -> (Self, Restored) {
        let mut writer = Self {
            path,
            run,
            started_at: UtcTime::now(),
            connection: None,
            run_id: None,
            next_open: Instant::now(),
            retention,
            retention_state: RetentionState::default(),
            counters,
            last_logged: None,
        };
        let restored = writer.try_open().unwrap_or_default();
        (writer, restored)
    }

    /// Connect, close what the last run left open, insert this run; returns the
    /// restored state. On failure: logged, counted, retried after [`REOPEN_PERIOD`].
    fn try_open(&mut self) -> Option<Restored> {
        self.next_open = Instant::now() + REOPEN_PERIOD;
        let opened = connect(&self.path).and_then(|mut connection| {
            let restored =
                super::restore::read(&connection).map_err(|source| self.error(source))?;
            let run_id = self
                .begin_run(&mut connection)
                .map_err(|source| self.error(source))?;
            Ok((connection, run_id, restored))
        });
        match opened {
            Ok((connection, run_id, restored)) => {
                tracing::info!(
                    path = %self.path.display(),
                    run = run_id,
                    drivelines_restored = restored.drivelines.len(),
                    "history open"
                );
                self.connection = Some(connection);
                self.run_id = Some(run_id);
                self.recovered();
                Some(restored)
            }
            Err(error) => {
                self.failed(&error.to_string(), 0, true);
                None
            }
        }
    }

    fn error(&self, source: rusqlite::Error) -> HistoryError {
        HistoryError::Sqlite {
            path: self.path.clone(),
            source,
        }
    }

    /// Mark what the previous run left open as ended by the restart and insert this
    /// run's row (a retry after a failed open keeps the run's start time).
    fn begin_run(&self, connection: &mut Connection) -> rusqlite::Result<i64> {
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
        let run_id = insert_run(&transaction, self.started_at, &self.run)?;
        transaction.commit()?;
        Ok(run_id)
    }

    /// Commit until every sender has gone and the queue is empty, then record the
    /// stop. `settled` counts the events committed or dropped so far, in queue order.
    pub(crate) fn run(
        mut self,
        events: Receiver<HistoryEvent>,
        settled: tokio::sync::watch::Sender<u64>,
    ) {
        let mut batch = Vec::with_capacity(MAX_BATCH);
        let mut done = 0u64;
        loop {
            let wait = self.retention_state.wait();
            match events.recv_timeout(wait) {
                Ok(event) => batch.push(event),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            while batch.len() < MAX_BATCH {
                match events.try_recv() {
                    Ok(event) => batch.push(event),
                    Err(_) => break,
                }
            }
            if !batch.is_empty() {
                self.write(&batch);
                done += batch.len() as u64;
                batch.clear();
                settled.send_replace(done);
            }
            self.retention_step();
        }
        self.finish();
    }

    /// Write `batch` in one transaction; count it stored or dropped.
    fn write(&mut self, batch: &[HistoryEvent]) {
        let events = batch.len() as u64;
        if self.connection.is_none() && Instant::now() >= self.next_open {
            self.try_open();
        }
        let (Some(connection), Some(run_id)) = (self.connection.as_mut(), self.run_id) else {
            self.counters.dropped(events);
            return;
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
            }
            Err(error) => {
                let full = error.sqlite_error_code() == Some(rusqlite::ErrorCode::DiskFull);
                let message = format!(
                    "history {}: cannot store {events} events: {}",
                    self.path.display(),
                    explain(&error)
                );
                // A full disk may free up with the connection as it is; anything else
                // (a file made read-only, replaced or damaged) is opened afresh.
                self.failed(&message, events, !full);
            }
        }
    }

    /// Record a failure: counters, state, a log line unless the same one was logged
    /// within [`ERROR_LOG_PERIOD`]; `reopen` drops the connection.
    fn failed(&mut self, message: &str, dropped: u64, reopen: bool) {
        self.counters.dropped(dropped);
        self.counters.set_error(message.to_owned());
        if reopen {
            self.connection = None;
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
        if self.counters.state() == HistoryState::Failing {
            tracing::info!(path = %self.path.display(), "history stored again");
        }
        self.counters.set_state(HistoryState::Ok);
        self.last_logged = None;
    }

    /// One retention step when one is due.
    fn retention_step(&mut self) {
        let Some(connection) = self.connection.as_ref() else {
            return;
        };
        if !self.retention_state.due() {
            return;
        }
        match self
            .retention
            .step(connection, UtcTime::now(), &mut self.retention_state)
        {
            Ok(step) => self.counters.retention(step.deleted, step.file_bytes),
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

/// Insert one event as the writer does (its rows, its state updates) in `transaction`
/// under the run `run_id`; bulk loads (the year fixture, `examples/history_year.rs`)
/// call it in transactions of their own.
pub fn insert(
    transaction: &Transaction<'_>,
    run_id: i64,
    event: &HistoryEvent,
) -> rusqlite::Result<()> {
    match event {
        HistoryEvent::Bite(bite) => insert_bite(transaction, run_id, bite),
        HistoryEvent::Alarm(alarm) => insert_alarm(transaction, run_id, alarm),
        HistoryEvent::WearReset {
            time,
            driveline,
            origin,
        } => {
            transaction
                .prepare_cached(
                    "INSERT INTO wear_estimates (run_id, driveline, time, event, origin, peer)
                     VALUES (?1, ?2, ?3, 'reset', ?4, ?5)",
                )?
                .execute(params![
                    run_id,
                    driveline,
                    time.to_string(),
                    origin.name(),
                    origin.peer().map(|peer| peer.to_string())
                ])?;
            transaction
                .prepare_cached(
                    "UPDATE driveline_state SET wear_trend = NULL, updated_at = ?2
                     WHERE driveline = ?1",
                )?
                .execute(params![driveline, time.to_string()])?;
            Ok(())
        }
        HistoryEvent::ChatterStarted { time, mill, window } => {
            transaction
                .prepare_cached(
                    "INSERT INTO chatter_episodes (run_id, mill, started_at, windows,
                         min_sigma_n_hz, max_k_mean, frequency_hz, alarm)
                     VALUES (?1, ?2, ?3, 1, ?4, ?5, ?6, ?7)",
                )?
                .execute(params![
                    run_id,
                    mill,
                    time.to_string(),
                    window.sigma_n_hz,
                    window.k_mean,
                    window.frequency_hz,
                    window.synchronized
                ])?;
            Ok(())
        }
        HistoryEvent::ChatterWindow { mill, window } => chatter_window(transaction, mill, window),
        HistoryEvent::ChatterEnded {
            time,
            mill,
            ended_by,
        } => {
            transaction
                .prepare_cached(
                    "UPDATE chatter_episodes SET ended_at = ?2, ended_by = ?3
                     WHERE mill = ?1 AND ended_at IS NULL",
                )?
                .execute(params![mill, time.to_string(), ended_by.name()])?;
            Ok(())
        }
        HistoryEvent::OutageStarted {
            time,
            source,
            status,
        } => {
            transaction
                .prepare_cached(
                    "INSERT INTO source_outages (run_id, source, started_at, worst_status, blocks_missed)
                     VALUES (?1, ?2, ?3, ?4, 0)",
                )?
                .execute(params![run_id, source, time.to_string(), status])?;
            Ok(())
        }
        HistoryEvent::OutageWorse { source } => {
            transaction
                .prepare_cached(
                    "UPDATE source_outages SET worst_status = 'lost'
                     WHERE source = ?1 AND ended_at IS NULL",
                )?
                .execute([source])?;
            Ok(())
        }
        HistoryEvent::OutageEnded {
            time,
            source,
            blocks_missed,
            ended_by,
        } => {
            transaction
                .prepare_cached(
                    "UPDATE source_outages SET ended_at = ?2, ended_by = ?3, blocks_missed = ?4
                     WHERE source = ?1 AND ended_at IS NULL",
                )?
                .execute(params![
                    source,
                    time.to_string(),
                    ended_by.name(),
                    i64::try_from(*blocks_missed).unwrap_or(i64::MAX)
                ])?;
            Ok(())
        }
    }
}

fn chatter_window(
    transaction: &Transaction<'_>,
    mill: &str,
    window: &ChatterWindow,
) -> rusqlite::Result<()> {
    transaction
        .prepare_cached(
            "UPDATE chatter_episodes SET windows = windows + 1,
                 min_sigma_n_hz = min(coalesce(min_sigma_n_hz, ?2), ?2),
                 max_k_mean = max(coalesce(max_k_mean, ?3), ?3),
                 frequency_hz = coalesce(?4, frequency_hz),
                 alarm = max(alarm, ?5)
             WHERE mill = ?1 AND ended_at IS NULL",
        )?
        .execute(params![
            mill,
            window.sigma_n_hz,
            window.k_mean,
            window.frequency_hz,
            window.synchronized
        ])?;
    Ok(())
}

fn insert_bite(
    transaction: &Transaction<'_>,
    run_id: i64,
    bite: &BiteRecord,
) -> rusqlite::Result<()> {
    let time = bite.time.to_string();
    let state = &bite.state;
    let gap = bite.gap.as_ref();
    let coupling = gap
        .and_then(|g| g.coupling)
        .and_then(|c| i64::try_from(c).ok());
    transaction
        .prepare_cached(
            "INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, first_period_s, second_period_s,
                 period_shift_s, beta1_hz, beta2_hz, quality, degraded, wear_index, wear_trend,
                 reference_taf, shift_over_linear_s,
                 gap_mrad, gap_low_mrad, gap_high_mrad, gap_coupling, bites_pooled,
                 gap_taf_sigma, gap_period_shift_sigma_s)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16,
                 ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, ?25, ?26)",
        )?
        .execute(params![
            run_id,
            bite.driveline,
            time,
            state.bite_counter,
            bite.channel,
            bite.static_torque_knm,
            bite.peak_torque_knm,
            bite.taf,
            bite.first_period_s,
            bite.second_period_s,
            bite.period_shift_s,
            bite.beta_hz.map(|(beta1, _)| beta1),
            bite.beta_hz.map(|(_, beta2)| beta2),
            bite.quality,
            bite.degraded,
            state.wear_index,
            state.wear_trend,
            bite.reference_taf,
            bite.shift_over_linear_s,
            gap.map(|g| g.gap_mrad),
            gap.map(|g| g.gap_low_mrad),
            gap.map(|g| g.gap_high_mrad),
            coupling,
            gap.and_then(|g| i64::try_from(g.bites_pooled).ok()),
            bite.pooled.map(|p| p.taf_sigma),
            bite.pooled.map(|p| p.period_shift_sigma_s),
        ])?;
    if state.wear_index.is_some() || gap.is_some() {
        transaction
            .prepare_cached(
                "INSERT INTO wear_estimates (run_id, driveline, time, event, origin,
                     wear_index, wear_trend, reference_taf, reference_level_knm,
                     shift_over_linear_s, gap_mrad, gap_low_mrad, gap_high_mrad, gap_coupling,
                     bites_pooled, state, alarm_latched)
                 VALUES (?1, ?2, ?3, 'bite', 'analysis', ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12,
                     ?13, ?14, ?15)",
            )?
            .execute(params![
                run_id,
                bite.driveline,
                time,
                state.wear_index,
                state.wear_trend,
                bite.reference_taf,
                bite.reference_level_knm,
                bite.shift_over_linear_s,
                gap.map(|g| g.gap_mrad),
                gap.map(|g| g.gap_low_mrad),
                gap.map(|g| g.gap_high_mrad),
                coupling,
                gap.and_then(|g| i64::try_from(g.bites_pooled).ok()),
                gap.map(|g| g.state.name()),
                gap.map(|g| g.alarm_latched),
            ])?;
    }
    transaction
        .prepare_cached(
            "INSERT INTO driveline_state (driveline, updated_at, bite_counter, last_bite_time,
                 static_torque_knm, peak_torque_knm, taf, period_shift_s, beta1_hz, beta2_hz,
                 wear_index, wear_trend, degraded, warning, alarm_latched, extra,
                 gap_alarm_latched, gap_warning)
             VALUES (?1, ?2, ?3, ?2, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16,
                 ?17)
             ON CONFLICT (driveline) DO UPDATE SET
                 updated_at = excluded.updated_at, bite_counter = excluded.bite_counter,
                 last_bite_time = excluded.last_bite_time,
                 static_torque_knm = excluded.static_torque_knm,
                 peak_torque_knm = excluded.peak_torque_knm, taf = excluded.taf,
                 period_shift_s = excluded.period_shift_s, beta1_hz = excluded.beta1_hz,
                 beta2_hz = excluded.beta2_hz, wear_index = excluded.wear_index,
                 wear_trend = excluded.wear_trend, degraded = excluded.degraded,
                 warning = excluded.warning, alarm_latched = excluded.alarm_latched,
                 extra = coalesce(excluded.extra, driveline_state.extra),
                 gap_alarm_latched = excluded.gap_alarm_latched,
                 gap_warning = excluded.gap_warning",
        )?
        .execute(params![
            bite.driveline,
            time,
            state.bite_counter,
            state.static_torque_knm,
            state.peak_torque_knm,
            state.taf,
            state.first_period_shift_s,
            state.beta1_hz,
            state.beta2_hz,
            state.wear_index,
            state.wear_trend,
            state.last_bite_degraded,
            state.taf_warning,
            state.taf_alarm,
            bite.extra_state.as_ref().map(ToString::to_string),
            state.gap_alarm,
            state.gap_warning,
        ])?;
    Ok(())
}

fn insert_alarm(
    transaction: &Transaction<'_>,
    run_id: i64,
    alarm: &AlarmRecord,
) -> rusqlite::Result<()> {
    let time = alarm.time.to_string();
    let origin = alarm.origin.map_or("analysis", |origin| origin.name());
    let peer = alarm
        .origin
        .and_then(|origin| origin.peer())
        .map(|peer| peer.to_string());
    transaction
        .prepare_cached(
            "INSERT INTO alarms (run_id, time, subject, kind, event, origin, peer, value, threshold)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
        )?
        .execute(params![
            run_id,
            time,
            alarm.subject,
            alarm.kind.name(),
            alarm.event.name(),
            origin,
            peer,
            alarm.value,
            alarm.threshold
        ])?;
    let raised = alarm.event == AlarmEvent::Raised;
    match alarm.kind {
        // The bite's own record carries the latch when it raises it; an
        // acknowledgement clears it here.
        AlarmKind::TafAlarm if !raised => {
            transaction
                .prepare_cached(
                    "UPDATE driveline_state SET alarm_latched = 0, updated_at = ?2
                     WHERE driveline = ?1",
                )?
                .execute(params![alarm.subject, time])?;
        }
        AlarmKind::GapAlarm if !raised => {
            transaction
                .prepare_cached(
                    "UPDATE driveline_state SET gap_alarm_latched = 0, updated_at = ?2
                     WHERE driveline = ?1",
                )?
                .execute(params![alarm.subject, time])?;
        }
        AlarmKind::ChatterAlarm => {
            transaction
                .prepare_cached(
                    "INSERT INTO mill_state (mill, updated_at, alarm_latched) VALUES (?1, ?2, ?3)
                     ON CONFLICT (mill) DO UPDATE SET
                         updated_at = excluded.updated_at, alarm_latched = excluded.alarm_latched",
                )?
                .execute(params![alarm.subject, time, raised])?;
        }
        // A gap warning changes with the estimate, which maps installed or a wear reset
        // change without a bite.
        AlarmKind::GapWarning if alarm.event != AlarmEvent::Acknowledged => {
            transaction
                .prepare_cached(
                    "UPDATE driveline_state SET gap_warning = ?3, updated_at = ?2
                     WHERE driveline = ?1",
                )?
                .execute(params![alarm.subject, time, raised])?;
        }
        _ => {}
    }
    Ok(())
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
    let (writer, restored) = Writer::open(ends.config.path, retention, run, counters);
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
