//! `PlcWriter`: writes the register map into the PLC's holding registers (FC 16).
//!
//! Every write period, and at once whenever the results change (a bite was
//! analysed, an alarm acknowledged), the heartbeat is incremented and the whole map is written
//! at the configured base, in chunks of at most 123 registers (the FC 16 limit).
//! A PLC that is unreachable, or whose connection fails, is retried with capped
//! exponential backoff, which starts again from its initial delay only after a write
//! went through (a PLC that accepts and closes is not retried every period); the
//! results and the heartbeat keep moving meanwhile (HMIs read them from the server),
//! so the first write after it appears is fresh. Repeating warnings are rate-limited.
//! On shutdown a last write publishes the "stopped" status.
//!
//! With a history, each write first waits (at most [`HISTORY_WAIT`]) until the
//! events recorded before the map was read are committed: a bite the PLC sees is in
//! the file, even if the gateway is killed right after. A failing history is not
//! waited for.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use millgate_config::PlcOutput;
use tokio_modbus::client::Context;

use crate::field::backoff::Backoff;
use crate::field::modbus::{client, ModbusError};
use crate::outputs::register_map::RegisterMap;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::results::GatewayState;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Largest register count of one FC 16 request.
const MAX_WRITE_REGISTERS: usize = 123;
/// Longest wait for the history to commit what a write shows (a commit takes
/// milliseconds; this bounds a slow disk's delay of the PLC's values).
pub const HISTORY_WAIT: Duration = Duration::from_millis(500);

/// The reason a failed PLC write is counted under on `/metrics`.
fn reason(error: &ModbusError) -> PlcFailure {
    match error {
        ModbusError::Connect { .. } => PlcFailure::Connect,
        ModbusError::Timeout(_) => PlcFailure::Timeout,
        ModbusError::Transport(_) => PlcFailure::Transport,
        ModbusError::Mismatch(_) => PlcFailure::Mismatch,
        ModbusError::Exception { .. } => PlcFailure::Refused,
    }
}

/// Why a PLC write failed, as counted: the network ("connect", "timeout",
/// "transport", "mismatch") apart from the PLC saying no ("refused").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlcFailure {
    /// No TCP connection could be made.
    Connect,
    /// No answer in time.
    Timeout,
    /// The connection failed or the reply was not Modbus.
    Transport,
    /// The reply did not match the write.
    Mismatch,
    /// The PLC answered with a Modbus exception.
    Refused,
}

impl PlcFailure {
    /// Every reason, in the order of [`PlcCounts::failures`].
    pub const ALL: [PlcFailure; 5] = [
        PlcFailure::Connect,
        PlcFailure::Timeout,
        PlcFailure::Transport,
        PlcFailure::Mismatch,
        PlcFailure::Refused,
    ];

    /// The `/metrics` label value.
    pub fn name(self) -> &'static str {
        match self {
            PlcFailure::Connect => "connect",
            PlcFailure::Timeout => "timeout",
            PlcFailure::Transport => "transport",
            PlcFailure::Mismatch => "mismatch",
            PlcFailure::Refused => "refused",
        }
    }
}

/// What the PLC writer has done, for `/metrics`.
#[derive(Debug, Default)]
pub struct PlcCounters {
    writes: AtomicU64,
    failures: [AtomicU64; 5],
    last_success_ms: AtomicU64,
}

/// A copy of [`PlcCounters`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlcCounts {
    /// Whole maps written.
    pub writes: u64,
    /// Failed writes (and connection attempts) per [`PlcFailure::ALL`].
    pub failures: [u64; 5],
    /// When the last write went through, ms since the Unix epoch (0: never).
    pub last_success_unix_ms: u64,
}

impl PlcCounters {
    /// Current values.
    pub fn snapshot(&self) -> PlcCounts {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        PlcCounts {
            writes: load(&self.writes),
            failures: self.failures.each_ref().map(load),
            last_success_unix_ms: load(&self.last_success_ms),
        }
    }

    fn written(&self) {
        self.writes.fetch_add(1, Ordering::Relaxed);
        let now = crate::state::time::UtcTime::now().unix_ms();
        self.last_success_ms
            .store(u64::try_from(now).unwrap_or(0), Ordering::Relaxed);
    }

    fn failed(&self, error: &ModbusError) {
        let at = PlcFailure::ALL
            .iter()
            .position(|failure| *failure == reason(error))
            .unwrap_or(0);
        self.failures[at].fetch_add(1, Ordering::Relaxed);
    }
}

/// Writes the published register map to one PLC.
#[derive(Debug)]
pub struct PlcWriter {
    output: PlcOutput,
    map: Arc<RegisterMap>,
    board: Arc<Board>,
    counters: Arc<PlcCounters>,
    /// Told once the first write was attempted (the service's readiness).
    first_attempt: Option<tokio::sync::watch::Sender<bool>>,
}

impl PlcWriter {
    /// A writer of `board`'s results, encoded by `map`, to the PLC of `output`,
    /// counting into `counters`.
    pub fn new(
        output: PlcOutput,
        (map, board): (Arc<RegisterMap>, Arc<Board>),
        counters: Arc<PlcCounters>,
    ) -> Self {
        Self {
            output,
            map,
            board,
            counters,
            first_attempt: None,
        }
    }

    /// Send `true` on `attempted` once the first write was attempted (connected or
    /// not, written or not).
    pub fn on_first_attempt(mut self, attempted: tokio::sync::watch::Sender<bool>) -> Self {
        self.first_attempt = Some(attempted);
        self
    }

    async fn connect(&self) -> Result<Context, ModbusError> {
        let output = &self.output;
        client::connect(&output.address, output.unit_id, output.timeout).await
    }

    async fn write(&self, context: &mut Context, words: &[u16]) -> Result<(), ModbusError> {
        for (i, chunk) in words.chunks(MAX_WRITE_REGISTERS).enumerate() {
            let address = self.output.register_base + (i * MAX_WRITE_REGISTERS) as u16;
            client::write(context, address, chunk, self.output.timeout).await?;
        }
        Ok(())
    }

    /// Write every period until shutdown, then write the final "stopped" map.
    ///
    /// The heartbeat moves every period even while the PLC is unreachable (the map is
    /// also served to HMIs); connection attempts are spaced by the backoff meanwhile.
    pub async fn run(mut self, mut shutdown: Shutdown) {
        let mut context: Option<Context> = None;
        let mut backoff = Backoff::new();
        let mut next_attempt = Instant::now();
        let mut connect_warnings = WarnLimit::new(WARN_PERIOD);
        let mut write_warnings = WarnLimit::new(WARN_PERIOD);
        let mut ticks = tokio::time::interval(self.output.write_period);
        ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = ticks.tick() => {}
                () = self.board.changed() => {}
                () = shutdown.recv() => break,
            }
            self.board.beat();
            if context.is_none() && Instant::now() >= next_attempt {
                match self.connect().await {
                    Ok(connected) => {
                        tracing::info!(plc = %self.output.address, "PLC connected");
                        context = Some(connected);
                    }
                    Err(error) => {
                        self.counters.failed(&error);
                        let delay = backoff.next_delay();
                        if let Some(suppressed) = connect_warnings.occurred(Instant::now()) {
                            tracing::warn!(plc = %self.output.address, %error, retry_in = ?delay, suppressed, "PLC unreachable");
                        }
                        next_attempt = Instant::now() + delay;
                    }
                }
            }
            if let Some(connected) = context.as_mut() {
                let words = self.map.encode(&self.board.results());
                let history = self.board.history();
                if !history.wait_settled(history.enqueued(), HISTORY_WAIT).await {
                    tracing::debug!(wait = ?HISTORY_WAIT, "history commit slower than the PLC wait");
                }
                match self.write(connected, &words).await {
                    Ok(()) => {
                        self.counters.written();
                        backoff.reset();
                        connect_warnings.clear();
                        write_warnings.clear();
                    }
                    Err(error) => {
                        self.counters.failed(&error);
                        if let Some(suppressed) = write_warnings.occurred(Instant::now()) {
                            tracing::warn!(plc = %self.output.address, %error, suppressed, "PLC write failed");
                        }
                        if error.needs_reconnect() {
                            context = None;
                            next_attempt = Instant::now() + backoff.next_delay();
                        }
                    }
                }
            }
            if let Some(attempted) = self.first_attempt.take() {
                attempted.send_replace(true);
            }
        }
        self.board
            .update(|results| results.state = GatewayState::Stopped);
        self.board.beat();
        let words = self.map.encode(&self.board.results());
        let connected = match context {
            Some(connected) => Ok(connected),
            None => self.connect().await,
        };
        let written = match connected {
            Ok(mut connected) => self.write(&mut connected, &words).await,
            Err(error) => Err(error),
        };
        match written {
            Ok(()) => tracing::info!("final registers written, status stopped"),
            Err(error) => tracing::warn!(%error, "final PLC write failed"),
        }
    }
}
