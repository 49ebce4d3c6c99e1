//! `DaqReader`: polls one Modbus DAQ (TCP, or RTU on a serial line) in the millgate
//! acquisition layout.
//!
//! tokio-modbus has neither timeouts nor reconnects, so every request here is
//! wrapped in the source's timeout, and any transport error or timeout drops the
//! connection and reconnects with capped exponential backoff (over RTU: the serial
//! device is closed and opened again, its buffers cleared). A device exception
//! ("the DAQ refused") is counted but keeps the connection. Over RTU every request
//! waits out the line's inter-frame silence after the last reply (`rtu.rs`).
//!
//! Blocks are tracked by sequence number: a jump of k > 1 means k - 1 blocks were
//! lost and is passed on as an [`Acquired::Gap`] before the new samples, so the
//! analysis never joins across missing data. A sequence that goes backwards, or jumps
//! further than the time elapsed explains, is a DAQ restart: counted as one, marked
//! as a gap, and not counted as lost blocks. A sequence that stands still while the
//! DAQ answers (a frozen DAQ) is no new data: the source is "answered" only when a
//! block advanced, so it goes stale, and the stall is counted. Saturated samples
//! become gaps ([`crate::field::quality`]); the block tracking is in [`super::block`].
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

use super::block::{BlockChannel, BlockNews};
use super::client;
use super::error::ModbusError;
use super::rtu::{self, FrameSpacing};
use crate::field::acquired::Acquired;
use crate::field::backoff::Backoff;
use crate::field::counters::ChannelCounters;
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Why one poll of a DAQ failed.
#[derive(Debug, thiserror::Error)]
pub enum DaqError {
    /// The request failed: the network, or the device refused.
    #[error(transparent)]
    Modbus(#[from] ModbusError),
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
        matches!(self, DaqError::Modbus(error) if error.needs_reconnect())
    }
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
    /// Over RTU, the silence between frames on the line; `None` over TCP.
    spacing: Option<FrameSpacing>,
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
                } if s == source_index => blocks.push(BlockChannel::new(
                    (channel, spec),
                    table,
                    base,
                    Arc::clone(&counters[channel]),
                )),
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
            spacing: source
                .serial
                .map(|line| FrameSpacing::new(line.inter_frame_delay)),
            source,
            blocks,
            values,
            health,
        }
    }

    async fn connect(&mut self) -> Result<Context, ModbusError> {
        let source = &self.source;
        match (&source.serial, &mut self.spacing) {
            (Some(line), Some(spacing)) => {
                let context = rtu::connect(&source.address, line, source.unit_id)?;
                spacing.opened();
                Ok(context)
            }
            _ => client::connect(&source.address, source.unit_id, source.timeout).await,
        }
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
            let what = (block.table, block.base, BLOCK_REGISTERS);
            let registers = match read(context, &mut self.spacing, what, timeout).await {
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
            let what = (value.table, value.address, count);
            let registers = match read(context, &mut self.spacing, what, timeout).await {
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
        DaqError::Modbus(ModbusError::Timeout(_)) => counters.timeout(),
        _ => counters.error(),
    }
}

/// [`client::read`] as a poll's error; over RTU (`spacing`) after the line's silence.
async fn read(
    context: &mut Context,
    spacing: &mut Option<FrameSpacing>,
    what: (RegisterTable, u16, u16),
    timeout: Duration,
) -> Result<Vec<u16>, DaqError> {
    if let Some(spacing) = spacing {
        spacing.before_request().await;
    }
    let read = client::read(context, what, timeout).await;
    if let Some(spacing) = spacing {
        spacing.after_reply();
    }
    Ok(read?)
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
