//! `DaqReader`: polls one Modbus TCP DAQ in the millgate acquisition layout.
//!
//! tokio-modbus has neither timeouts nor reconnects, so every request here is
//! wrapped in the source's timeout, and any transport error or timeout drops the
//! connection and reconnects with capped exponential backoff. A device exception
//! ("the DAQ refused") is counted but keeps the connection.
//!
//! Blocks are tracked by sequence number: a jump of k > 1 means k - 1 blocks were
//! lost and is passed on as an [`Acquired::Gap`] before the new samples, so the
//! analysis never joins across missing data. A sequence that goes backwards, or jumps
//! further than the time elapsed explains, is a DAQ restart: counted as one, marked
//! as a gap, and not counted as lost blocks. A sequence that stands still while the
//! DAQ answers (a frozen DAQ) is no new data: the source is "answered" only when a
//! block advanced, so it goes stale, and the stall is counted. Saturated samples
//! become gaps ([`crate::field::quality`]).
//!
//! Reconnects: a connection that fails or is dropped is made again after the backoff
//! delay, which restarts from its initial value only after a poll that brought new
//! data (not on TCP connect: a DAQ at its client limit accepts and closes at once,
//! and would be reconnected thousands of times a second). Repeating warnings are
//! rate-limited (one line per 10 s with the count suppressed, `warn_limit.rs`).

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::layout::{self, BlockError, BLOCK_REGISTERS};
use millgate_config::{ChannelSource, Config, ModbusSource, RegisterTable, ValueType, WordOrder};
use tokio::sync::mpsc;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::ExceptionCode;

use crate::field::acquired::Acquired;
use crate::field::backoff::Backoff;
use crate::field::counters::ChannelCounters;
use crate::field::modbus_client::{self, CheckedError, ConnectError, ReplyMismatch};
use crate::field::quality::{self, SaturationLimits};
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Block periods a sequence may stand still before the stall is counted.
const STALL_BLOCK_PERIODS: u32 = 3;

/// Why one poll of a DAQ failed.
#[derive(Debug, thiserror::Error)]
pub enum DaqError {
    /// No TCP connection could be made.
    #[error("cannot connect to {address}: {source}")]
    Connect {
        /// The DAQ's `host:port`.
        address: String,
        /// Refused, unreachable, unresolvable, ...
        source: std::io::Error,
    },
    /// The device did not answer in time.
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    /// The connection failed or the reply could not be decoded.
    #[error("transport: {0}")]
    Transport(#[from] tokio_modbus::Error),
    /// The reply does not answer the request (another register count).
    #[error("reply does not match the request: {0}")]
    Mismatch(#[from] ReplyMismatch),
    /// The device answered with a Modbus exception: it refused the request.
    #[error("device refused register {address}: {exception}")]
    Exception {
        /// The first register of the request.
        address: u16,
        /// The exception code the device answered with.
        #[source]
        exception: ExceptionCode,
    },
    /// The device answered, but the block does not follow the layout.
    #[error("malformed block at register {address}: {source}")]
    Block {
        /// The block's first register.
        address: u16,
        /// What is wrong with it.
        source: BlockError,
    },
}

impl DaqError {
    /// Whether the connection must be dropped and made again.
    fn needs_reconnect(&self) -> bool {
        matches!(
            self,
            DaqError::Connect { .. }
                | DaqError::Timeout(_)
                | DaqError::Transport(_)
                | DaqError::Mismatch(_)
        )
    }
}

impl From<CheckedError> for DaqError {
    fn from(error: CheckedError) -> Self {
        match error {
            CheckedError::Transport(error) => DaqError::Transport(error),
            CheckedError::Mismatch(mismatch) => DaqError::Mismatch(mismatch),
        }
    }
}

#[derive(Debug)]
struct BlockChannel {
    channel: usize,
    table: RegisterTable,
    base: u16,
    scale: f64,
    offset: f64,
    sample_rate_hz: f64,
    limits: SaturationLimits,
    /// Sequence, time it was first seen and sample count of the last new block.
    last: Option<(u16, Instant, u16)>,
    /// The sequence has stood still past [`STALL_BLOCK_PERIODS`] (counted once).
    stalled: bool,
    counters: Arc<ChannelCounters>,
}

/// What one block read brought.
#[derive(Debug, PartialEq)]
enum BlockNews {
    /// The block already seen.
    Same,
    /// A new block: the messages for analysis.
    New(Vec<Acquired>),
}

#[derive(Debug)]
struct ValueChannel {
    channel: usize,
    table: RegisterTable,
    address: u16,
    value_type: ValueType,
    word_order: WordOrder,
    scale: f64,
    offset: f64,
    counters: Arc<ChannelCounters>,
}

/// Reads every channel of one Modbus source.
#[derive(Debug)]
pub struct DaqReader {
    name: String,
    source: ModbusSource,
    blocks: Vec<BlockChannel>,
    values: Vec<ValueChannel>,
    health: Arc<SourceHealth>,
}

impl DaqReader {
    /// The reader of `config.modbus_sources[source_index]`, with one counter set per
    /// channel (indexed like `config.channels`, shared with the caller).
    pub fn new(
        config: &Config,
        source_index: usize,
        counters: &[Arc<ChannelCounters>],
        health: Arc<SourceHealth>,
    ) -> Self {
        let source = config.modbus_sources[source_index].clone();
        let mut blocks = Vec::new();
        let mut values = Vec::new();
        for (channel, spec) in config.channels.iter().enumerate() {
            match spec.source {
                ChannelSource::ModbusBlock {
                    source: s,
                    table,
                    base,
                } if s == source_index => blocks.push(BlockChannel {
                    channel,
                    table,
                    base,
                    scale: spec.scale,
                    offset: spec.offset,
                    sample_rate_hz: spec.sample_rate_hz,
                    limits: quality::saturation_limits(spec),
                    last: None,
                    stalled: false,
                    counters: Arc::clone(&counters[channel]),
                }),
                ChannelSource::ModbusValue {
                    source: s,
                    table,
                    address,
                    value_type,
                    word_order,
                } if s == source_index => values.push(ValueChannel {
                    channel,
                    table,
                    address,
                    value_type,
                    word_order,
                    scale: spec.scale,
                    offset: spec.offset,
                    counters: Arc::clone(&counters[channel]),
                }),
                _ => {}
            }
        }
        Self {
            name: source.name.clone(),
            source,
            blocks,
            values,
            health,
        }
    }

    async fn connect(&self) -> Result<Context, DaqError> {
        let source = &self.source;
        modbus_client::connect(&source.address, source.unit_id, source.timeout)
            .await
            .map_err(|error| match error {
                ConnectError::Timeout(timeout) => DaqError::Timeout(timeout),
                ConnectError::Io(error) => DaqError::Connect {
                    address: source.address.clone(),
                    source: error,
                },
            })
    }

    /// Poll until shutdown, reconnecting as needed. Ends when `shutdown` fires or
    /// the analysis side hangs up.
    pub async fn run(mut self, samples: mpsc::Sender<Acquired>, mut shutdown: Shutdown) {
        let mut backoff = Backoff::new();
        let mut connect_warnings = WarnLimit::new(WARN_PERIOD);
        let mut drop_warnings = WarnLimit::new(WARN_PERIOD);
        while !shutdown.is_shutdown() {
            let connected = tokio::select! {
                connected = self.connect() => connected,
                () = shutdown.recv() => break,
            };
            match connected {
                Ok(mut context) => {
                    tracing::debug!(source = %self.name, address = %self.source.address, "DAQ connected");
                    self.health.set_connected(true);
                    let ended = self
                        .poll_connection(&mut context, &samples, &mut shutdown, &mut backoff)
                        .await;
                    self.health.set_connected(false);
                    match ended {
                        ConnectionEnd::Stop => return,
                        ConnectionEnd::Dropped(error) => {
                            if let Some(suppressed) =
                                drop_warnings.occurred(tokio::time::Instant::now())
                            {
                                tracing::warn!(source = %self.name, %error, suppressed, "DAQ connection dropped, reconnecting");
                            }
                        }
                    }
                }
                Err(error) => {
                    if let Some(suppressed) = connect_warnings.occurred(tokio::time::Instant::now())
                    {
                        tracing::warn!(source = %self.name, %error, suppressed, "DAQ connect failed");
                    }
                }
            }
            let delay = backoff.next_delay();
            tokio::select! {
                () = tokio::time::sleep(delay) => {}
                () = shutdown.recv() => break,
            }
        }
    }

    /// Poll on one connection until it fails, shutdown fires (`Stop`) or the
    /// analysis side hangs up (`Stop`). A poll that brought new data resets `backoff`.
    async fn poll_connection(
        &mut self,
        context: &mut Context,
        samples: &mpsc::Sender<Acquired>,
        shutdown: &mut Shutdown,
        backoff: &mut Backoff,
    ) -> ConnectionEnd {
        let period = self.source.poll_period;
        let mut due = tokio::time::Instant::now();
        let mut reply_warnings = WarnLimit::new(WARN_PERIOD);
        loop {
            // Only wait on the timer when the poll is not due yet: a poll that
            // took a period or longer starts the next at once. (`Interval`
            // re-arms its timer every tick, and once 5 ms behind waits for the
            // timer's next 1 ms tick: a third fewer polls when polls are fast.)
            if tokio::time::Instant::now() < due {
                tokio::select! {
                    () = tokio::time::sleep_until(due) => {}
                    () = shutdown.recv() => return ConnectionEnd::Stop,
                }
            } else if shutdown.is_shutdown() {
                return ConnectionEnd::Stop;
            }
            due = next_poll(due, tokio::time::Instant::now(), period);
            match self.poll(context, samples).await {
                Ok(Poll::NewData) => {
                    self.health.answered();
                    backoff.reset();
                    reply_warnings.clear();
                }
                Ok(Poll::NothingNew) => {}
                Ok(Poll::AnalysisGone) => return ConnectionEnd::Stop,
                Err(error) if error.needs_reconnect() => return ConnectionEnd::Dropped(error),
                Err(error) => {
                    if let Some(suppressed) = reply_warnings.occurred(tokio::time::Instant::now()) {
                        tracing::warn!(source = %self.name, %error, suppressed, "DAQ reply rejected");
                    }
                }
            }
        }
    }

    /// One poll of every channel: whether it brought new data (a block advanced, or
    /// a process value was read on a source without blocks), or the analysis is gone.
    async fn poll(
        &mut self,
        context: &mut Context,
        samples: &mpsc::Sender<Acquired>,
    ) -> Result<Poll, DaqError> {
        let timeout = self.source.timeout;
        let mut first_error = None;
        let mut new_data = false;
        for block in &mut self.blocks {
            let registers =
                match read(context, block.table, block.base, BLOCK_REGISTERS, timeout).await {
                    Ok(registers) => registers,
                    Err(error) => {
                        count_error(&block.counters, &error);
                        if error.needs_reconnect() {
                            return Err(error);
                        }
                        first_error.get_or_insert(error);
                        continue;
                    }
                };
            let decoded = match layout::decode_block(&registers) {
                Ok(decoded) => decoded,
                Err(error) => {
                    block.counters.error();
                    first_error.get_or_insert(DaqError::Block {
                        address: block.base,
                        source: error,
                    });
                    continue;
                }
            };
            let BlockNews::New(messages) =
                block.accept(decoded.sequence, decoded.raw, Instant::now())
            else {
                continue;
            };
            new_data = true;
            for message in messages {
                if samples.send(message).await.is_err() {
                    return Ok(Poll::AnalysisGone);
                }
            }
        }
        for value in &self.values {
            let count = value.value_type.register_count();
            let registers = match read(context, value.table, value.address, count, timeout).await {
                Ok(registers) => registers,
                Err(error) => {
                    count_error(&value.counters, &error);
                    if error.needs_reconnect() {
                        return Err(error);
                    }
                    first_error.get_or_insert(error);
                    continue;
                }
            };
            let Some(raw) = layout::decode_value(&registers, value.value_type, value.word_order)
            else {
                value.counters.error();
                continue;
            };
            value.counters.block(1);
            new_data |= self.blocks.is_empty();
            let message = Acquired::ProcessValue {
                channel: value.channel,
                value: raw * value.scale + value.offset,
            };
            if samples.send(message).await.is_err() {
                return Ok(Poll::AnalysisGone);
            }
        }
        match first_error {
            Some(error) => Err(error),
            None if new_data => Ok(Poll::NewData),
            None => Ok(Poll::NothingNew),
        }
    }
}

/// What one poll of every channel gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Poll {
    /// A block advanced (or a process value was read on a source without blocks).
    NewData,
    /// Every block was the one already seen: a frozen DAQ, or polled early.
    NothingNew,
    /// The analysis task is gone: stop.
    AnalysisGone,
}

/// Why a connection's poll loop ended.
#[derive(Debug)]
enum ConnectionEnd {
    /// Shutdown, or the analysis is gone.
    Stop,
    /// The connection failed: reconnect after the backoff.
    Dropped(DaqError),
}

impl BlockChannel {
    /// What a block read at `now` brings: `Same` when it is the block already seen
    /// (counting a stall once it stands still past [`STALL_BLOCK_PERIODS`]), else the
    /// messages: an optional gap (lost blocks, or a DAQ restart), then the samples,
    /// saturated ones replaced by gaps.
    fn accept(&mut self, sequence: u16, raw: &[u16], now: Instant) -> BlockNews {
        let count = raw.len() as u16;
        let mut messages = Vec::with_capacity(2);
        if let Some((last_sequence, last_time, last_count)) = self.last {
            let advance = layout::sequence_advance(last_sequence, sequence);
            let elapsed = now.saturating_duration_since(last_time);
            let block_period = self.block_period(last_count);
            if advance == 0 {
                if !self.stalled && elapsed > block_period * STALL_BLOCK_PERIODS {
                    self.stalled = true;
                    self.counters.stall();
                }
                return BlockNews::Same;
            }
            let by_time = (elapsed.as_secs_f64() / block_period.as_secs_f64()).round() as u64;
            if u64::from(advance) <= by_time + 2 {
                if advance > 1 {
                    let missed_blocks = u64::from(advance - 1);
                    self.counters.missed(missed_blocks);
                    messages.push(Acquired::Gap {
                        channel: self.channel,
                        missed_samples: Some(missed_blocks * u64::from(count)),
                    });
                }
            } else {
                // Backwards, or further than the clock allows: the DAQ restarted (its
                // sequence began anew) or replays old blocks. What was lost is not
                // known from the sequence; the clock estimates it for the analysis's
                // sample count, and it is not counted as lost blocks.
                self.counters.restart();
                tracing::warn!(
                    channel = self.channel,
                    from = last_sequence,
                    to = sequence,
                    "DAQ block sequence restarted"
                );
                messages.push(Acquired::Gap {
                    channel: self.channel,
                    missed_samples: Some(by_time.saturating_sub(1) * u64::from(count)),
                });
            }
        }
        self.last = Some((sequence, now, count));
        self.stalled = false;
        self.counters.block(raw.len());
        let values = layout::Block { sequence, raw }
            .values(self.scale, self.offset)
            .collect();
        let saturated =
            quality::split_saturated(&self.limits, self.channel, values, None, &mut messages);
        self.counters.saturated(saturated);
        BlockNews::New(messages)
    }

    /// Duration of a block of `count` samples.
    fn block_period(&self, count: u16) -> Duration {
        Duration::from_secs_f64(f64::from(count.max(1)) / self.sample_rate_hz)
    }
}

/// When the poll after one due at `due` and started at `started` is due: one
/// `period` after `due`, keeping polls on their grid, unless the poll started a
/// period or more late; then one `period` after `started` (no burst of catch-up
/// polls, as `MissedTickBehavior::Delay`).
fn next_poll(
    due: tokio::time::Instant,
    started: tokio::time::Instant,
    period: Duration,
) -> tokio::time::Instant {
    let on_grid = due + period;
    if on_grid > started {
        on_grid
    } else {
        started + period
    }
}

fn count_error(counters: &ChannelCounters, error: &DaqError) {
    match error {
        DaqError::Timeout(_) => counters.timeout(),
        _ => counters.error(),
    }
}

async fn read(
    context: &mut Context,
    table: RegisterTable,
    address: u16,
    count: u16,
    timeout: Duration,
) -> Result<Vec<u16>, DaqError> {
    let request = modbus_client::read_registers(context, table, address, count);
    let reply = tokio::time::timeout(timeout, request)
        .await
        .map_err(|_| DaqError::Timeout(timeout))??;
    reply.map_err(|exception| DaqError::Exception { address, exception })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel() -> BlockChannel {
        BlockChannel {
            channel: 3,
            table: RegisterTable::Input,
            base: 0,
            scale: 1.0,
            offset: 0.0,
            sample_rate_hz: 1000.0,
            limits: quality::SaturationLimits {
                low: -32767.0,
                high: 32767.0,
            },
            last: None,
            stalled: false,
            counters: Arc::default(),
        }
    }

    fn messages(news: BlockNews) -> Vec<Acquired> {
        match news {
            BlockNews::New(messages) => messages,
            BlockNews::Same => panic!("expected a new block"),
        }
    }

    #[test]
    fn repeated_block_is_ignored_and_gap_is_marked() {
        let mut block = channel();
        let t0 = Instant::now();
        assert_eq!(messages(block.accept(10, &[1, 2], t0)).len(), 1);
        assert_eq!(
            block.accept(10, &[1, 2], t0),
            BlockNews::Same,
            "same block twice"
        );
        let messages = messages(block.accept(13, &[3, 4], t0 + Duration::from_millis(6)));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(4)
            }
        );
        assert_eq!(
            messages[1],
            Acquired::Samples {
                channel: 3,
                values: vec![3.0, 4.0],
                received: None,
            }
        );
        let counters = block.counters.snapshot();
        assert_eq!((counters.blocks_read, counters.blocks_missed), (2, 2));
    }

    #[test]
    fn polls_keep_their_grid_and_do_not_burst_after_a_late_one() {
        let t0 = tokio::time::Instant::now();
        let period = Duration::from_millis(20);
        let ms = Duration::from_millis;
        assert_eq!(next_poll(t0, t0, period), t0 + ms(20));
        // Woken 1 ms late (timer granularity): the next poll stays on the grid.
        assert_eq!(next_poll(t0 + ms(20), t0 + ms(21), period), t0 + ms(40));
        // A slow poll: 30 ms late. The next is a period after it began, not at once.
        assert_eq!(next_poll(t0 + ms(40), t0 + ms(70), period), t0 + ms(90));
    }

    #[test]
    fn sequence_wrap_is_continuous() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(65535, &[1], t0);
        let messages = messages(block.accept(0, &[2], t0 + Duration::from_millis(1)));
        assert_eq!(messages.len(), 1, "65535 -> 0 is the next block");
    }

    #[test]
    fn restarted_daq_gap_is_estimated_from_time() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(5000, &[0; 100], t0);
        // The DAQ restarted: its sequence began again at 1, 2 s later (20 blocks).
        let messages = messages(block.accept(1, &[0; 100], t0 + Duration::from_secs(2)));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(1900)
            }
        );
        let counters = block.counters.snapshot();
        assert_eq!((counters.sequence_restarts, counters.blocks_missed), (1, 0));
    }

    #[test]
    fn a_sequence_going_backwards_is_a_restart_not_lost_blocks() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(5000, &[0; 100], t0);
        // One block period later the sequence is 100 behind: the wrapping jump of
        // 65 436 counted 101 missed blocks before.
        let messages = messages(block.accept(4900, &[7; 100], t0 + Duration::from_millis(100)));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(0)
            },
            "a gap: the detector restarts"
        );
        assert!(matches!(messages[1], Acquired::Samples { .. }));
        let counters = block.counters.snapshot();
        assert_eq!(counters.sequence_restarts, 1);
        assert_eq!(counters.blocks_missed, 0);
        // It goes on from there as usual.
        let next = messages_of(&mut block, 4901, t0 + Duration::from_millis(200));
        assert_eq!(next.len(), 1);
    }

    fn messages_of(block: &mut BlockChannel, sequence: u16, at: Instant) -> Vec<Acquired> {
        messages(block.accept(sequence, &[0; 100], at))
    }

    #[test]
    fn a_frozen_sequence_is_counted_once_per_stall() {
        let mut block = channel();
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        block.accept(10, &[0; 100], t0);
        // Block period 100 ms: still within three periods, no stall yet.
        assert_eq!(block.accept(10, &[0; 100], t0 + ms(250)), BlockNews::Same);
        assert_eq!(block.counters.snapshot().sequence_stalls, 0);
        for later in [350, 500, 2000] {
            assert_eq!(block.accept(10, &[0; 100], t0 + ms(later)), BlockNews::Same);
        }
        assert_eq!(block.counters.snapshot().sequence_stalls, 1);
        // Moving again, then frozen again: a second stall.
        messages_of(&mut block, 11, t0 + ms(2100));
        block.accept(11, &[0; 100], t0 + ms(2500));
        assert_eq!(block.counters.snapshot().sequence_stalls, 2);
    }

    #[test]
    fn saturated_samples_become_gaps_and_are_counted() {
        let mut block = channel();
        let t0 = Instant::now();
        let raw = [100, 32767, 32767, (-32768i16) as u16, 5];
        let messages = messages(block.accept(1, &raw, t0));
        assert_eq!(
            messages,
            [
                Acquired::Samples {
                    channel: 3,
                    values: vec![100.0],
                    received: None
                },
                Acquired::Gap {
                    channel: 3,
                    missed_samples: Some(3)
                },
                Acquired::Samples {
                    channel: 3,
                    values: vec![5.0],
                    received: None
                },
            ]
        );
        assert_eq!(block.counters.snapshot().saturated_samples, 3);
    }
}
