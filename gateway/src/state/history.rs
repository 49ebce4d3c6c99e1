//! The history's sending side: the handle the analysis, the board (commands) and the
//! outage monitor record events through, and the counters its writer keeps.
//!
//! [`History::record`] puts an event on a bounded queue with `try_send` and never
//! waits (a full queue drops the event and counts it). The writer thread
//! ([`crate::history`]) owns the file; an event counts as stored only once
//! its transaction has committed: [`History::stored`] counts those,
//! [`History::wait_settled`] waits until every event recorded so far is committed or
//! known dropped. The PLC writer waits for that (bounded) before each write, so a bite
//! the PLC has seen is in the file.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::broadcast;

use super::changes::Signal;
use super::context::ContextStatus;
use super::events::HistoryEvent;
use super::time;

/// Events in flight to the writer. A bite every second on ten drivelines fills it in
/// minutes, not seconds: enough to ride out a slow commit (a busy SD card), small
/// enough (a few MiB) to bound memory when the store is stuck.
pub const QUEUE_CAPACITY: usize = 4096;

/// Alarm and outage events a receiver of [`History::alarms`] may fall behind by: far
/// more than a burst of bites raises (each raises at most a few).
pub const ALARM_STREAM_CAPACITY: usize = 1024;

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
    /// Captures among the dropped events (queue full or error): never in the file,
    /// so never announced (Sparkplug and the web API read the file).
    pub captures_dropped: u64,
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
    /// Evidence handed to the history whose process context was not valid, per
    /// `(subject, evidence, status)` (evidence `episode` or `capture`, status `stale`
    /// or `invalid`), in that order.
    pub context_untrusted: Vec<(UntrustedEvidence, u64)>,
}

/// Which evidence a count of [`HistoryStatus::context_untrusted`] is of.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct UntrustedEvidence {
    /// The tandem mill or driveline.
    pub subject: String,
    /// `episode` (a chatter episode) or `capture`.
    pub evidence: &'static str,
    /// `stale` or `invalid` ([`ContextStatus::name`]).
    pub status: &'static str,
}

/// Counters shared by the handle and the writer thread.
#[derive(Debug, Default)]
pub(crate) struct Counters {
    state: AtomicU8,
    enqueued: AtomicU64,
    stored: AtomicU64,
    dropped_queue_full: AtomicU64,
    dropped_error: AtomicU64,
    captures_dropped: AtomicU64,
    commits: AtomicU64,
    commit_ns_sum: AtomicU64,
    commit_ns_max: AtomicU64,
    retention_deleted: AtomicU64,
    file_bytes: AtomicU64,
    last_error: Mutex<Option<(time::UtcTime, String)>>,
    /// The last checkpoint failed (the state stays failing until one succeeds).
    checkpoint_failing: AtomicBool,
    /// Evidence recorded with a context that was not valid, counted.
    context_untrusted: Mutex<BTreeMap<UntrustedEvidence, u64>>,
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

    /// Whether the last checkpoint failed.
    pub(crate) fn checkpoint_failing(&self) -> bool {
        self.checkpoint_failing.load(Ordering::Relaxed)
    }

    /// A checkpoint failed (`Some`, why: the state is failing until one succeeds) or
    /// succeeded (`None`); whether that changes what the last one did.
    pub(crate) fn checkpointed(&self, failure: Option<String>) -> bool {
        let failing = failure.is_some();
        if let Some(message) = failure {
            self.set_error(message);
        }
        self.checkpoint_failing.swap(failing, Ordering::Relaxed) != failing
    }

    /// Events handed to the writer so far (the writer compares it with what it took,
    /// to see whether anything is queued).
    pub(crate) fn enqueued(&self) -> u64 {
        self.enqueued.load(Ordering::Relaxed)
    }

    pub(crate) fn committed(&self, events: u64, took: Duration) {
        let ns = u64::try_from(took.as_nanos()).unwrap_or(u64::MAX);
        self.stored.fetch_add(events, Ordering::Relaxed);
        self.commits.fetch_add(1, Ordering::Relaxed);
        self.commit_ns_sum.fetch_add(ns, Ordering::Relaxed);
        self.commit_ns_max.fetch_max(ns, Ordering::Relaxed);
    }

    /// `events` could not be stored (the file could not take them).
    pub(crate) fn dropped(&self, events: &[HistoryEvent]) {
        self.dropped_error
            .fetch_add(events.len() as u64, Ordering::Relaxed);
        self.captures_lost(events);
    }

    /// Count `event` when it is evidence (a chatter episode's start, a capture) whose
    /// context was stale or invalid.
    fn evidence_recorded(&self, event: &HistoryEvent) {
        let Some((subject, evidence, context)) = event.evidence_context() else {
            return;
        };
        let status = context.status();
        if status == ContextStatus::Valid {
            return;
        }
        let key = UntrustedEvidence {
            subject: subject.to_owned(),
            evidence,
            status: status.name(),
        };
        *crate::lock(&self.context_untrusted).entry(key).or_default() += 1;
    }

    fn captures_lost(&self, events: &[HistoryEvent]) {
        let captures = events.iter().filter(|e| e.holds_capture()).count();
        self.captures_dropped
            .fetch_add(captures as u64, Ordering::Relaxed);
    }

    /// Events dropped because the file could not take them, so far.
    pub(crate) fn dropped_errors(&self) -> u64 {
        self.dropped_error.load(Ordering::Relaxed)
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

/// What the writer thread takes from the handle when the file is opened.
#[derive(Debug)]
pub(crate) struct WriterEnds {
    /// The history's settings.
    pub(crate) config: millgate_config::History,
    /// The queue's receiving end.
    pub(crate) receiver: Receiver<HistoryEvent>,
    /// Where the writer says how many events are settled (committed or dropped), in
    /// queue order.
    pub(crate) signal: Signal,
}

#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    counters: Arc<Counters>,
    /// The change signal: the writer's settled events, the board's results.
    signal: Signal,
    /// The alarm stream: every alarm and outage event recorded (also without a file).
    alarms: broadcast::Sender<HistoryEvent>,
    /// The writer's ends until the writer side takes them.
    pending: Mutex<Option<WriterEnds>>,
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

impl History {
    /// A history that records nothing.
    pub fn disabled() -> Self {
        Self::new(None)
    }

    /// The history of `config` (disabled for `None`): events are queued from now on
    /// and written once [`crate::history::start`] has opened the file. No file is touched here
    /// (`millgate check` builds this too).
    pub fn new(config: Option<&millgate_config::History>) -> Self {
        let counters = Arc::new(Counters::default());
        let signal = Signal::default();
        let (sender, pending) = match config {
            Some(config) => {
                counters.set_state(HistoryState::Ok);
                let (sender, receiver) = sync_channel(QUEUE_CAPACITY);
                let pending = WriterEnds {
                    config: config.clone(),
                    receiver,
                    signal: signal.clone(),
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
                signal,
                alarms: broadcast::channel(ALARM_STREAM_CAPACITY).0,
                pending: Mutex::new(pending),
                writer: Mutex::new(None),
                full_logged: Mutex::new(None),
            }),
        }
    }

    /// The writer's ends (the queue's receiving end, the settled count), once: the
    /// history's writer side ([`crate::history::start`]) takes them when it
    /// opens the file; `None` when disabled or taken before.
    pub(crate) fn take_writer_ends(&self) -> Option<WriterEnds> {
        crate::lock(&self.shared.pending).take()
    }

    /// The counters the writer updates.
    pub(crate) fn counters(&self) -> Arc<Counters> {
        Arc::clone(&self.shared.counters)
    }

    /// The writer thread, joined by [`Self::close`]; `None` when it could not start
    /// (then nothing more is taken: every later event is dropped and counted).
    pub(crate) fn set_writer(&self, writer: Option<std::thread::JoinHandle<()>>) {
        match writer {
            Some(handle) => *crate::lock(&self.shared.writer) = Some(handle),
            None => crate::lock(&self.shared.queue).sender = None,
        }
    }

    /// Hand `event` to the writer without waiting; `false` when it was dropped (the
    /// queue is full, or the history is disabled or closed).
    pub fn record(&self, event: HistoryEvent) -> bool {
        if event.is_alarm_stream() {
            // No receiver (no OPC UA server) is no error.
            let _ = self.shared.alarms.send(event.clone());
        }
        let mut queue = crate::lock(&self.shared.queue);
        let Some(sender) = queue.sender.as_ref() else {
            return false;
        };
        self.shared.counters.evidence_recorded(&event);
        match sender.try_send(event) {
            Ok(()) => {
                queue.enqueued += 1;
                self.shared
                    .counters
                    .enqueued
                    .store(queue.enqueued, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Full(event)) => {
                drop(queue);
                let counters = &self.shared.counters;
                counters.dropped_queue_full.fetch_add(1, Ordering::Relaxed);
                counters.captures_lost(std::slice::from_ref(&event));
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
            Err(TrySendError::Disconnected(event)) => {
                self.shared.counters.dropped(std::slice::from_ref(&event));
                false
            }
        }
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
        if self.settled_now(through) {
            return true;
        }
        let mut changes = self.shared.signal.subscribe();
        tokio::time::timeout(limit, changes.settled_through(through))
            .await
            .is_ok()
    }

    /// Whether the first `through` events recorded are settled now, or need not be
    /// waited for (the history is disabled or failing): [`Self::wait_settled`] without
    /// the wait.
    pub(crate) fn settled_now(&self, through: u64) -> bool {
        self.shared.counters.state() != HistoryState::Ok
            || self.shared.signal.now().settled >= through
    }

    /// The change signal this history's writer reports to (the board reports the
    /// results' changes to the same one: [`crate::state::board::Board::with_history`]).
    pub fn signal(&self) -> Signal {
        self.shared.signal.clone()
    }

    /// The alarm stream: every alarm and source outage event recorded from now on, as
    /// the history stores it (also without a `[history]` file). A receiver that falls
    /// more than [`ALARM_STREAM_CAPACITY`] events behind is told how many it missed.
    pub fn alarms(&self) -> broadcast::Receiver<HistoryEvent> {
        self.shared.alarms.subscribe()
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
            captures_dropped: load(&c.captures_dropped),
            commits: load(&c.commits),
            commit_seconds_sum: load(&c.commit_ns_sum) as f64 * 1e-9,
            commit_seconds_max: load(&c.commit_ns_max) as f64 * 1e-9,
            retention_deleted: load(&c.retention_deleted),
            file_bytes: load(&c.file_bytes),
            last_error: crate::lock(&c.last_error).clone(),
            context_untrusted: crate::lock(&c.context_untrusted)
                .iter()
                .map(|(key, &count)| (key.clone(), count))
                .collect(),
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
