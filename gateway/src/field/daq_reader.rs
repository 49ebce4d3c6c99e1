//! `DaqReader`: polls one Modbus TCP DAQ in the millgate acquisition layout.
//!
//! tokio-modbus has neither timeouts nor reconnects, so every request here is
//! wrapped in the source's timeout, and any transport error or timeout drops the
//! connection and reconnects with capped exponential backoff. A device exception
//! ("the DAQ refused") is counted but keeps the connection.
//!
//! Blocks are tracked by sequence number: a jump of k > 1 means k - 1 blocks were
//! lost and is passed on as an [`Acquired::Gap`] before the new samples, so the
//! analysis never joins across missing data.

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::layout::{self, BlockError, BLOCK_REGISTERS};
use millgate_config::{ChannelSource, Config, ModbusSource, RegisterTable, ValueType, WordOrder};
use tokio::sync::mpsc;
use tokio_modbus::client::{Context, Reader};
use tokio_modbus::prelude::ExceptionCode;

use crate::field::acquired::Acquired;
use crate::field::backoff::Backoff;
use crate::field::counters::ChannelCounters;
use crate::field::modbus_client::{self, ConnectError};
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;

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
            DaqError::Connect { .. } | DaqError::Timeout(_) | DaqError::Transport(_)
        )
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
    last: Option<(u16, Instant, u16)>,
    counters: Arc<ChannelCounters>,
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
                    last: None,
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
        while !shutdown.is_shutdown() {
            let connected = tokio::select! {
                connected = self.connect() => connected,
                () = shutdown.recv() => break,
            };
            let mut context = match connected {
                Ok(context) => context,
                Err(error) => {
                    let delay = backoff.next_delay();
                    tracing::warn!(source = %self.name, %error, retry_in = ?delay, "DAQ connect failed");
                    tokio::select! {
                        () = tokio::time::sleep(delay) => {}
                        () = shutdown.recv() => break,
                    }
                    continue;
                }
            };
            tracing::info!(source = %self.name, address = %self.source.address, "DAQ connected");
            self.health.set_connected(true);
            backoff.reset();
            let period = self.source.poll_period;
            let mut due = tokio::time::Instant::now();
            loop {
                // Only wait on the timer when the poll is not due yet: a poll that
                // took a period or longer starts the next at once. (`Interval`
                // re-arms its timer every tick, and once 5 ms behind waits for the
                // timer's next 1 ms tick: a third fewer polls when polls are fast.)
                if tokio::time::Instant::now() < due {
                    tokio::select! {
                        () = tokio::time::sleep_until(due) => {}
                        () = shutdown.recv() => break,
                    }
                } else if shutdown.is_shutdown() {
                    break;
                }
                due = next_poll(due, tokio::time::Instant::now(), period);
                match self.poll(&mut context, &samples).await {
                    Ok(true) => self.health.answered(),
                    Ok(false) => return,
                    Err(error) if error.needs_reconnect() => {
                        tracing::warn!(source = %self.name, %error, "DAQ connection dropped, reconnecting");
                        break;
                    }
                    Err(error) => {
                        tracing::warn!(source = %self.name, %error, "DAQ reply rejected");
                    }
                }
            }
            self.health.set_connected(false);
        }
    }

    /// One poll of every channel. `Ok(false)` when the analysis side is gone.
    async fn poll(
        &mut self,
        context: &mut Context,
        samples: &mpsc::Sender<Acquired>,
    ) -> Result<bool, DaqError> {
        let timeout = self.source.timeout;
        let mut first_error = None;
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
            for message in block.accept(decoded.sequence, decoded.raw, Instant::now()) {
                if samples.send(message).await.is_err() {
                    return Ok(false);
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
            let message = Acquired::ProcessValue {
                channel: value.channel,
                value: raw * value.scale + value.offset,
            };
            if samples.send(message).await.is_err() {
                return Ok(false);
            }
        }
        first_error.map_or(Ok(true), Err)
    }
}

impl BlockChannel {
    /// Messages for a block read at `now`: nothing when it is the block already
    /// seen, else an optional gap and the samples.
    fn accept(&mut self, sequence: u16, raw: &[u16], now: Instant) -> Vec<Acquired> {
        let count = raw.len() as u16;
        let mut messages = Vec::with_capacity(2);
        if let Some((last_sequence, last_time, last_count)) = self.last {
            let advance = layout::sequence_advance(last_sequence, sequence);
            if advance == 0 {
                return messages;
            }
            if advance > 1 {
                let missed_blocks = self.plausible_missed(advance - 1, now - last_time, last_count);
                self.counters.missed(missed_blocks);
                messages.push(Acquired::Gap {
                    channel: self.channel,
                    missed_samples: Some(missed_blocks * u64::from(count)),
                });
            }
        }
        self.last = Some((sequence, now, count));
        self.counters.block(raw.len());
        let values = layout::Block { sequence, raw }
            .values(self.scale, self.offset)
            .collect();
        messages.push(Acquired::Samples {
            channel: self.channel,
            values,
            received: None,
        });
        messages
    }

    /// Blocks missed given the sequence jump, checked against the time elapsed: a
    /// DAQ that restarted begins its sequence anew, and then the clock is the
    /// better witness.
    fn plausible_missed(&self, by_sequence: u16, elapsed: Duration, count: u16) -> u64 {
        let block_period_s = f64::from(count.max(1)) / self.sample_rate_hz;
        let by_time = (elapsed.as_secs_f64() / block_period_s).round() as u64;
        if u64::from(by_sequence) <= by_time + 2 {
            u64::from(by_sequence)
        } else {
            by_time.saturating_sub(1).max(1)
        }
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
    let request = async {
        match table {
            RegisterTable::Input => context.read_input_registers(address, count).await,
            RegisterTable::Holding => context.read_holding_registers(address, count).await,
        }
    };
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
            last: None,
            counters: Arc::default(),
        }
    }

    #[test]
    fn repeated_block_is_ignored_and_gap_is_marked() {
        let mut block = channel();
        let t0 = Instant::now();
        assert_eq!(block.accept(10, &[1, 2], t0).len(), 1);
        assert!(block.accept(10, &[1, 2], t0).is_empty(), "same block twice");
        let messages = block.accept(13, &[3, 4], t0 + Duration::from_millis(6));
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
        let messages = block.accept(0, &[2], t0 + Duration::from_millis(1));
        assert_eq!(messages.len(), 1, "65535 -> 0 is the next block");
    }

    #[test]
    fn restarted_daq_gap_is_estimated_from_time() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(5000, &[0; 100], t0);
        // The DAQ restarted: its sequence began again at 1, 2 s later (20 blocks).
        let messages = block.accept(1, &[0; 100], t0 + Duration::from_secs(2));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(1900)
            }
        );
    }
}
