//! `PlcWriter`: writes the register map into the PLC's holding registers (FC 16).
//!
//! Every write period, and at once whenever the results change (a bite was
//! analysed, an alarm acknowledged), the heartbeat is incremented and the map is
//! written at the configured base: the whole map every write period, and on a change
//! only the blocks (the global registers, a driveline's, a mill's) that differ from
//! the last write that went through, so a bite reaches the PLC in one or two requests
//! whatever the number of drivelines. After a failed write, a reconnect or a start the
//! next write is whole. Requests hold whole blocks, up to 123 registers (the FC 16
//! limit): a PLC never holds part of a block's new values beside the rest's old ones.
//! Unchanged blocks between two changed ones go along in one request when it stays
//! within the limit (a round trip saved for a few registers the PLC holds already).
//! A PLC that is unreachable, or whose connection fails, is retried with capped
//! exponential backoff, which starts again from its initial delay only after a write
//! went through (a PLC that accepts and closes is not retried every period); the
//! results and the heartbeat keep moving meanwhile (HMIs read them from the server),
//! so the first write after it appears is fresh. Repeating warnings are rate-limited.
//! On shutdown a last write publishes the "stopped" status.
//!
//! The requests of a write go one at a time, each after the last one's answer, or
//! with `requests_in_flight` up to that many sent before their answers came
//! (`crate::field::modbus::link`). A PLC whose stack takes one at a time answers the first of
//! them at most (pymodbus 3.16 drops the others: `tests/tests/pymodbus_peers.rs`):
//! a write of several requests that fails then for want of an answer (a timeout, the
//! connection closed) makes the writer warn and send one at a time for the rest of
//! the run.
//!
//! Before its first write the writer reads each driveline's bite counter back from the
//! PLC: while no bite of this run has been counted, a counter the PLC holds above the
//! restored one is continued (the history can lack bites the PLC saw: a full disk or
//! a read-only folder stopped storing them), so the PLC never sees its counter go
//! back and bite numbers repeat.
//!
//! Each bite's latency, from the block that completed its window to the write that
//! carried its counter, is observed when the PLC acknowledged that write (the board
//! hands the writer the bites' stamps with the results it encodes:
//! `crate::state::latency`); a bite of a write that failed is observed at the next
//! that goes through.
//!
//! With a history, each write first waits (at most [`HISTORY_WAIT`]) until the
//! events recorded with the results it shows are committed (the board counts them
//! under the lock the results are copied under, so the wait covers exactly those, not
//! events of bites published after): a bite the PLC sees is in the file, even if the
//! gateway is killed right after. A failing history is not waited for. When the wait
//! ends, results published meanwhile whose events are committed already (the writer
//! thread committed them with those waited for, or since) replace the copy: their
//! bites go in this write instead of waiting for it to end and then for a write of
//! their own; results whose events are not committed yet wait for the next write.

use std::ops::Range;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use millgate_config::layout::decode_value;
use millgate_config::PlcOutput;

use crate::field::backoff::Backoff;
use crate::field::modbus::link::TcpLink;
use crate::field::modbus::ModbusError;
use crate::outputs::modbus::register_map::RegisterMap;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::results::GatewayState;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Largest register count of one FC 16 request.
const MAX_WRITE_REGISTERS: usize = 123;
/// Longest wait for the history to commit what a write shows (a commit takes
/// milliseconds; this bounds a slow disk's delay of the PLC's values).
pub const HISTORY_WAIT: Duration = Duration::from_millis(500);

/// The FC 16 requests (ranges from the map's start) that write the `blocks` for which
/// `send` is true: a block joins the request before it when the request then spans
/// at most [`MAX_WRITE_REGISTERS`], taking the blocks between along (`blocks` are
/// contiguous, and a block not sent holds what the PLC holds already, so writing it
/// again changes nothing there); a block is never split. Greedy from the first block,
/// this makes the fewest requests; a request costs a round trip to the PLC, a register
/// two bytes more of one.
fn requests(blocks: &[Range<u16>], mut send: impl FnMut(&Range<u16>) -> bool) -> Vec<Range<u16>> {
    let mut requests: Vec<Range<u16>> = Vec::new();
    for block in blocks.iter().filter(|&block| send(block)) {
        match requests.last_mut() {
            Some(last) if usize::from(block.end - last.start) <= MAX_WRITE_REGISTERS => {
                last.end = block.end;
            }
            _ => requests.push(block.clone()),
        }
    }
    requests
}

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
    /// Set before the shutdown when another writer takes over (a reload): no final
    /// "stopped" write then.
    handover: Option<Arc<AtomicBool>>,
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
            handover: None,
        }
    }

    /// At a shutdown with `handover` set, end without the final "stopped" write and
    /// leave the gateway's state as it is: a writer with new settings takes over (a
    /// reload), and the PLC must not see the gateway stop.
    pub(crate) fn with_handover(mut self, handover: Arc<AtomicBool>) -> Self {
        self.handover = Some(handover);
        self
    }

    /// Send `true` on `attempted` once the first write was attempted (connected or
    /// not, written or not).
    pub(crate) fn on_first_attempt(mut self, attempted: tokio::sync::watch::Sender<bool>) -> Self {
        self.first_attempt = Some(attempted);
        self
    }

    async fn connect(&self) -> Result<TcpLink, ModbusError> {
        let output = &self.output;
        TcpLink::connect(&output.address, output.unit_id, output.timeout).await
    }

    /// Write the registers of `requests` (ranges of `words`, from the map's start),
    /// one FC 16 request each, up to `in_flight` of them sent before their answers
    /// came.
    async fn write(
        &self,
        link: &mut TcpLink,
        (words, requests): (&[u16], &[Range<u16>]),
        in_flight: usize,
    ) -> Result<(), ModbusError> {
        let mut writes = Vec::with_capacity(requests.len());
        for request in requests {
            let range = usize::from(request.start)..usize::from(request.end);
            // A request is at most 123 registers (`requests` packs blocks so); chunked
            // all the same, so that no map could make an oversized request.
            for (i, chunk) in words[range].chunks(MAX_WRITE_REGISTERS).enumerate() {
                let address =
                    self.output.register_base + request.start + (i * MAX_WRITE_REGISTERS) as u16;
                writes.push((address, chunk));
            }
        }
        link.write(&writes, in_flight).await
    }

    /// Continue each driveline's bite counter from what the PLC holds, when that is
    /// more than the board's and the board's is still `at_start` (no bite counted in
    /// this run yet). A read that fails leaves the counters as they are.
    async fn continue_counters(&self, link: &mut TcpLink, at_start: &[u32]) {
        for (index, name) in self.board.driveline_names().iter().enumerate() {
            let register_name = format!("{name}.bite_counter");
            let Some(register) = self
                .map
                .registers()
                .iter()
                .find(|r| r.name == register_name)
            else {
                continue;
            };
            let address = self.output.register_base + register.address;
            let count = register.value_type.register_count();
            let read = link
                .read((millgate_config::RegisterTable::Holding, address, count))
                .await;
            let words = match read {
                Ok(words) => words,
                Err(error) => {
                    tracing::debug!(%error, driveline = %name, "the PLC's bite counter not read back");
                    continue;
                }
            };
            let Some(held) = decode_value(&words, register.value_type, register.word_order)
                .and_then(|value| u32::try_from(value as i64).ok())
            else {
                continue;
            };
            // Looked at first: an update, even one that changes nothing, is a change
            // the writers act on.
            let counter = self
                .board
                .results()
                .drivelines
                .get(index)
                .map(|d| d.bite_counter);
            if counter
                .is_none_or(|counter| held <= counter || at_start.get(index) != Some(&counter))
            {
                continue;
            }
            let raised = self.board.update(|results| {
                let driveline = results.drivelines.get_mut(index)?;
                let untouched = at_start.get(index) == Some(&driveline.bite_counter);
                (untouched && held > driveline.bite_counter).then(|| {
                    let restored = driveline.bite_counter;
                    driveline.bite_counter = held;
                    restored
                })
            });
            if let Some(restored) = raised {
                tracing::warn!(
                    driveline = %name,
                    restored,
                    plc = held,
                    "bite counter continued from the PLC's: the history lacks bites the PLC \
                     saw (it could not store them)"
                );
            }
        }
    }

    /// Write every period until shutdown, then write the final "stopped" map.
    ///
    /// The heartbeat moves every period even while the PLC is unreachable (the map is
    /// also served to HMIs); connection attempts are spaced by the backoff meanwhile.
    pub async fn run(mut self, mut shutdown: Shutdown) {
        let mut context: Option<TcpLink> = None;
        let mut backoff = Backoff::new();
        let mut next_attempt = Instant::now();
        let mut connect_warnings = WarnLimit::new(WARN_PERIOD);
        let mut write_warnings = WarnLimit::new(WARN_PERIOD);
        let mut ticks = tokio::time::interval(self.output.write_period);
        ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        // The map as the PLC holds it after the last write that went through (None
        // before the first, after a failure or a reconnect: the next write is whole).
        let mut at_plc: Option<Vec<u16>> = None;
        let mut changes = self.board.changes();
        let blocks = self.map.plc_blocks(self.output.extension_blocks);
        let whole = requests(blocks, |_| true);
        // The counters as restored: the PLC's are continued only while they are.
        let at_start: Vec<u32> = self
            .board
            .results()
            .drivelines
            .iter()
            .map(|d| d.bite_counter)
            .collect();
        let mut counters_read = false;
        // Requests sent before their answers came; 1 for the rest of the run once the
        // PLC failed to answer them (its stack takes one at a time).
        let mut in_flight = self.output.requests_in_flight;
        // The bites' stamps are kept for this writer while it runs (`/metrics`' bite
        // -> PLC latency, observed when a write that carried them went through).
        let latencies = Arc::clone(self.board.latencies());
        let _latency_stamps = latencies.plc_writer();
        loop {
            let period = tokio::select! {
                _ = ticks.tick() => true,
                _ = changes.results() => false,
                () = shutdown.recv() => break,
            };
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
                if !counters_read {
                    self.continue_counters(connected, &at_start).await;
                    counters_read = true;
                }
                let mut image = self.board.results_for_plc();
                let mut words = self.map.encode(&image.results);
                let history = self.board.history();
                if !history.wait_settled(image.through, HISTORY_WAIT).await {
                    tracing::debug!(wait = ?HISTORY_WAIT, "history commit slower than the PLC wait");
                } else if self.board.newer_settled_for_plc(&mut image) {
                    // Bites published during the wait and already committed go in
                    // this write, not in the next one after it.
                    words = self.map.encode(&image.results);
                }
                // What the write shows needs no other write.
                changes.saw_results(image.version);
                let bites = image.bites;
                // On a change, the blocks that differ from what the PLC holds.
                let changed = at_plc.as_deref().filter(|_| !period).map(|held| {
                    requests(blocks, |block| {
                        let block = usize::from(block.start)..usize::from(block.end);
                        words[block.clone()] != held[block]
                    })
                });
                let requests = changed.as_ref().unwrap_or(&whole);
                let sent = std::time::Instant::now();
                match self.write(connected, (&words, requests), in_flight).await {
                    Ok(()) => {
                        latencies.written(&bites, sent);
                        at_plc = Some(words);
                        self.counters.written();
                        backoff.reset();
                        connect_warnings.clear();
                        write_warnings.clear();
                    }
                    Err(error) => {
                        latencies.not_written(bites);
                        self.counters.failed(&error);
                        if in_flight > 1 && requests.len() > 1 && error.needs_reconnect() {
                            in_flight = 1;
                            tracing::warn!(
                                plc = %self.output.address,
                                %error,
                                requests_in_flight = self.output.requests_in_flight,
                                "the PLC did not answer a write's requests in flight: requests \
                                 go one at a time from now on (set outputs.plc.requests_in_flight \
                                 = 1 for this PLC)"
                            );
                        }
                        if let Some(suppressed) = write_warnings.occurred(Instant::now()) {
                            tracing::warn!(plc = %self.output.address, %error, suppressed, "PLC write failed");
                        }
                        at_plc = None;
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
        if self
            .handover
            .as_ref()
            .is_some_and(|handover| handover.load(Ordering::Relaxed))
        {
            tracing::info!(plc = %self.output.address, "PLC writer handed over (reload)");
            return;
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
            Ok(mut connected) => {
                self.write(&mut connected, (&words, &whole), in_flight)
                    .await
            }
            Err(error) => Err(error),
        };
        match written {
            Ok(()) => tracing::info!("final registers written, status stopped"),
            Err(error) => tracing::warn!(%error, "final PLC write failed"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::source_health::SourceHealth;
    use crate::outputs::modbus::register_map::decode_u32;
    use millgate_sim::devices::modbus_bank::ServeOptions;
    use millgate_sim::devices::virtual_plc::VirtualPlc;

    /// Blocks of `lengths` registers from 0 on.
    fn tile(lengths: &[u16]) -> Vec<Range<u16>> {
        let mut blocks: Vec<Range<u16>> = Vec::new();
        for &length in lengths {
            let start = blocks.last().map_or(0, |b| b.end);
            blocks.push(start..start + length);
        }
        blocks
    }

    #[test]
    fn requests_pack_whole_blocks_up_to_the_fc16_limit() {
        let blocks = tile(&[16, 32, 32, 32, 32, 32, 96]);
        assert_eq!(
            requests(&blocks, |_| true),
            vec![0..112, 112..176, 176..272]
        );
        let chosen = [0, 80, 112];
        assert_eq!(
            requests(&blocks, |b| chosen.contains(&b.start)),
            vec![0..112, 112..144],
            "the blocks between go along up to the limit"
        );
        let chosen = [0, 112, 176];
        assert_eq!(
            requests(&blocks, |b| chosen.contains(&b.start)),
            vec![0..16, 112..144, 176..272],
            "blocks further apart than a request are apart"
        );
        let chosen = [16, 80];
        assert_eq!(
            requests(&blocks, |b| chosen.contains(&b.start)),
            vec![16..112],
            "two changed blocks with two unchanged between: one request"
        );
        assert_eq!(requests(&blocks, |_| false), Vec::<Range<u16>>::new());
    }

    /// With 8 drivelines (a map of several requests), a bite of one driveline is
    /// written as the global registers and that driveline's block only, and leaves the
    /// PLC holding the whole map as encoded; the first write was the whole map.
    #[tokio::test]
    async fn a_change_writes_the_blocks_that_changed_and_the_periodic_write_all() {
        change_and_period(false, 1).await;
    }

    /// With `extension_blocks` the whole map, extension blocks too, goes to the PLC.
    #[tokio::test]
    async fn with_extension_blocks_the_plc_gets_the_whole_map() {
        change_and_period(true, 1).await;
    }

    /// With requests in flight, the same requests reach the PLC in the same order and
    /// leave it holding the same map.
    #[tokio::test]
    async fn with_requests_in_flight_the_plc_gets_the_same_requests_in_order() {
        change_and_period(false, 8).await;
    }

    /// The test above with `outputs.plc.extension_blocks` = `extension` and
    /// `requests_in_flight`: the PLC's area is exactly what it is written (the first
    /// layout without it: a write past it would be refused).
    async fn change_and_period(extension: bool, requests_in_flight: usize) {
        let mut config = crate::testing::example_config("demo.toml");
        let first = config.drivelines[0].clone();
        config.drivelines = (0..8)
            .map(|k| millgate_config::Driveline {
                name: format!("D{k}"),
                ..first.clone()
            })
            .collect();
        let map = Arc::new(RegisterMap::new(&config));
        assert!(usize::from(map.len()) > 2 * MAX_WRITE_REGISTERS);
        let base = 100u16;
        let span = map.plc_span(extension);
        assert_eq!(span < map.len(), !extension, "the map has extension blocks");
        let plc = VirtualPlc::new(usize::from(base + span)).logging_writes();
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let mut output = config
            .outputs
            .plc
            .clone()
            .expect("the demo has a PLC output");
        output.address = listener.local_addr().unwrap().to_string();
        output.register_base = base;
        output.write_period = Duration::from_secs(3600);
        output.extension_blocks = extension;
        output.requests_in_flight = requests_in_flight;
        let running = plc.clone().spawn(listener, ServeOptions::default());
        let health = Arc::new(SourceHealth::new(
            Duration::from_secs(3600),
            Duration::from_secs(3600),
        ));
        let board = Arc::new(Board::new(&config, vec![health]));
        let (stop, shutdown) = crate::shutdown::channel();
        let writer = tokio::spawn(
            PlcWriter::new(
                output,
                (Arc::clone(&map), Arc::clone(&board)),
                Arc::default(),
            )
            .run(shutdown),
        );
        // The writes of one write, as (first register from the map's start, count).
        let next_write = || async {
            let deadline = Instant::now() + Duration::from_secs(10);
            loop {
                let log = plc.take_write_log();
                if !log.is_empty() {
                    // Let the rest of this write's requests arrive.
                    tokio::time::sleep(Duration::from_millis(200)).await;
                    return log
                        .into_iter()
                        .chain(plc.take_write_log())
                        .map(|w| (w.address - base, w.words.len()))
                        .collect::<Vec<_>>();
                }
                assert!(Instant::now() < deadline, "no write in 10 s");
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        };
        let whole = next_write().await;
        assert_eq!(whole.iter().map(|w| w.1).sum::<usize>(), usize::from(span));
        assert!(whole.len() > 2, "several requests: {whole:?}");
        for (start, count) in &whole {
            let end = start + *count as u16;
            assert!(
                map.blocks().iter().any(|b| b.start == *start)
                    && map.blocks().iter().any(|b| b.end == end),
                "a request of whole blocks: {start}..{end}"
            );
        }

        board.update(|results| results.drivelines[5].bite_counter = 7);
        let after_bite = next_write().await;
        let block = map.blocks()[1 + 5].clone();
        assert_eq!(
            after_bite,
            vec![
                (0, usize::from(map.blocks()[0].end)),
                (block.start, block.len())
            ],
            "the globals (heartbeat) and driveline D5's block"
        );
        let counter = usize::from(base + map.named("D5.bite_counter").unwrap().address);
        let held = plc.holding();
        assert_eq!(decode_u32(&held[counter..counter + 2]), Some(7));
        assert_eq!(
            held[usize::from(base)..],
            map.encode(&board.results())[..usize::from(span)],
            "the PLC holds what it is written of the map, as encoded"
        );
        stop.trigger();
        writer.await.unwrap();
        running.stop().await.unwrap();
    }
}
