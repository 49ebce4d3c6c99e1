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
//!
//! A TCP source with `requests_in_flight` above 1 is read over a [`TcpLink`]: the
//! block channels due in one poll are read with that many requests sent before their
//! answers came, each answer then taken as one read's. A DAQ that fails such a poll
//! for want of an answer (its stack takes one request at a time) is warned about and
//! read one request at a time from the next connection on.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::layout::{self, BlockError, BLOCK_REGISTERS};
use millgate_config::text::{decode_ascii, ByteOrder};
use millgate_config::{
    ChannelSource, Config, ModbusSource, RegisterTable, Scaling, ValueType, WordOrder,
};
use tokio::sync::{mpsc, watch};
use tokio_modbus::client::Context;

use super::block::{BlockChannel, BlockNews};
use super::client;
use super::error::ModbusError;
use super::link::{Answer, Request, TcpLink};
use super::rtu::{self, FrameSpacing};
use crate::field::acquired::Acquired;
use crate::field::backoff::Backoff;
use crate::field::counters::ChannelCounters;
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Why one poll of a DAQ failed.
#[derive(Debug, thiserror::Error)]
pub(crate) enum DaqError {
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
    scaling: Scaling,
    counters: Arc<ChannelCounters>,
}

/// A text channel (`type = "ascii"`): decoded here and handed over as text, not as
/// samples (a text has no engineering value to scale or saturate).
#[derive(Debug)]
struct TextChannel {
    channel: usize,
    table: RegisterTable,
    address: u16,
    registers: u16,
    byte_order: ByteOrder,
    counters: Arc<ChannelCounters>,
}

/// The channels a reload appended, for the running readers of their sources: the
/// running configuration with them (appended after the others), and one counter set
/// per channel of it (indexed like its `channels`).
#[derive(Debug, Clone)]
pub struct NewChannels {
    /// The running configuration with the channels appended.
    pub config: Arc<Config>,
    /// One counter set per channel of `config`.
    pub counters: Vec<Arc<ChannelCounters>>,
}

/// A connection to the DAQ: tokio-modbus's client (TCP or RTU, one request at a
/// time), or a TCP link with requests in flight.
enum Connection {
    Client(Context),
    Link(TcpLink),
}

/// Reads every channel of one Modbus source.
#[derive(Debug)]
pub struct DaqReader {
    name: String,
    /// Its index in `config.modbus_sources`.
    source_index: usize,
    source: ModbusSource,
    /// The channels of the configuration considered so far (its channels beyond
    /// are ones a reload appends: [`Self::with_new_channels`]).
    channels_seen: usize,
    /// Channels a reload appends, taken between two polls.
    new_channels: Option<watch::Receiver<NewChannels>>,
    blocks: Vec<BlockChannel>,
    values: Vec<ValueChannel>,
    texts: Vec<TextChannel>,
    health: Arc<SourceHealth>,
    /// Over RTU, the silence between frames on the line; `None` over TCP.
    spacing: Option<FrameSpacing>,
    /// Block reads of one poll sent before their answers came (the source's
    /// `requests_in_flight`; 1 once the DAQ failed to answer them).
    in_flight: usize,
    /// The unit tests' DAQ: connections made in memory, so the reconnect and stale
    /// timing run on a paused clock (`tests` below).
    #[cfg(test)]
    connector: Option<tests::Connector>,
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
        let mut reader = Self {
            name: source.name.clone(),
            source_index,
            spacing: source
                .serial
                .map(|line| FrameSpacing::new(line.inter_frame_delay)),
            in_flight: source.requests_in_flight,
            source,
            channels_seen: 0,
            new_channels: None,
            blocks: Vec::new(),
            values: Vec::new(),
            texts: Vec::new(),
            health,
            #[cfg(test)]
            connector: None,
        };
        reader.add_channels(config, counters);
        reader
    }

    /// This reader with the channels a reload appends on its source, as `new_channels`
    /// sends them: taken between two polls (the poll in flight ends as it began), each
    /// polled from the next poll on after the channels it reads already, whose blocks
    /// keep their sequence tracking (no block missed).
    pub fn with_new_channels(mut self, new_channels: watch::Receiver<NewChannels>) -> Self {
        self.new_channels = Some(new_channels);
        self
    }

    /// Read the channels of `config` on this source past the ones seen so far, counting
    /// into `counters` (indexed like `config.channels`). Returns how many it added.
    fn add_channels(&mut self, config: &Config, counters: &[Arc<ChannelCounters>]) -> usize {
        let source_index = self.source_index;
        let before = self.blocks.len() + self.values.len() + self.texts.len();
        let seen = self.channels_seen;
        for (channel, spec) in config.channels.iter().enumerate().skip(seen) {
            match spec.source {
                ChannelSource::ModbusBlock {
                    source: s,
                    table,
                    base,
                } if s == source_index => self.blocks.push(BlockChannel::new(
                    (channel, spec),
                    (table, base),
                    self.source.poll_period,
                    Arc::clone(&counters[channel]),
                )),
                ChannelSource::ModbusValue {
                    source: s,
                    table,
                    address,
                    value_type,
                    word_order,
                } if s == source_index => self.values.push(ValueChannel {
                    channel,
                    table,
                    address,
                    value_type,
                    word_order,
                    scaling: spec.scaling(),
                    counters: Arc::clone(&counters[channel]),
                }),
                ChannelSource::ModbusText {
                    source: s,
                    table,
                    address,
                    registers,
                    byte_order,
                } if s == source_index => self.texts.push(TextChannel {
                    channel,
                    table,
                    address,
                    registers,
                    byte_order,
                    counters: Arc::clone(&counters[channel]),
                }),
                _ => {}
            }
        }
        self.channels_seen = self.channels_seen.max(config.channels.len());
        self.blocks.len() + self.values.len() + self.texts.len() - before
    }

    /// Take the channels a reload appended since the last poll, if any.
    fn take_new_channels(&mut self) {
        let Some(receiver) = &mut self.new_channels else {
            return;
        };
        if !receiver.has_changed().unwrap_or(false) {
            return;
        }
        let new = receiver.borrow_and_update().clone();
        let added = self.add_channels(&new.config, &new.counters);
        tracing::info!(source = %self.name, added, "reload: channels added, read from the next poll on");
    }

    async fn connect(&mut self) -> Result<Connection, ModbusError> {
        #[cfg(test)]
        if let Some(connector) = &mut self.connector {
            return Ok(Connection::Client(connector.connect()));
        }
        let source = &self.source;
        match (&source.serial, &mut self.spacing) {
            (Some(line), Some(spacing)) => {
                let context = rtu::connect(&source.address, line, source.unit_id)?;
                spacing.opened();
                Ok(Connection::Client(context))
            }
            _ if self.in_flight > 1 => {
                TcpLink::connect(&source.address, source.unit_id, source.timeout)
                    .await
                    .map(Connection::Link)
            }
            _ => client::connect(&source.address, source.unit_id, source.timeout)
                .await
                .map(Connection::Client),
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
        context: &mut Connection,
        samples: &mpsc::Sender<Acquired>,
        shutdown: &mut Shutdown,
        backoff: &mut Backoff,
    ) -> ConnectionEnd {
        let period = self.source.poll_period;
        // The poll grid of the process values and texts; block channels are read when
        // their next block is due (`block.rs`).
        let mut due = tokio::time::Instant::now();
        let mut reply_warnings = WarnLimit::new(WARN_PERIOD);
        loop {
            // Only wait on the timer when no read is due yet: a poll that took a
            // period or longer starts the next at once. (`Interval` re-arms its
            // timer every tick, and once 5 ms behind waits for the timer's next
            // 1 ms tick: a third fewer polls when polls are fast.)
            let wake = self.next_wake(due);
            if tokio::time::Instant::now() < wake {
                tokio::select! {
                    () = tokio::time::sleep_until(wake) => {}
                    () = shutdown.recv() => return ConnectionEnd::Stop,
                }
            } else if shutdown.is_shutdown() {
                return ConnectionEnd::Stop;
            }
            let now = tokio::time::Instant::now();
            let on_grid = now >= due;
            if on_grid {
                due = next_poll(due, now, period);
            }
            match self.poll(context, samples, on_grid).await {
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

    /// When the next read is due: the first block channel's next read, or the next
    /// poll on the grid (`grid`) of the process values and texts.
    fn next_wake(&self, grid: tokio::time::Instant) -> tokio::time::Instant {
        let blocks = self
            .blocks
            .iter()
            .map(|block| {
                block
                    .next_read()
                    .map_or_else(tokio::time::Instant::now, tokio::time::Instant::from_std)
            })
            .min();
        match blocks {
            Some(block) if self.values.is_empty() && self.texts.is_empty() => block,
            Some(block) => block.min(grid),
            None => grid,
        }
    }

    /// Over a link with requests in flight, the block channels due now read together:
    /// each one's index and answer, in order; `None` (read them one at a time) over
    /// tokio-modbus's client or when fewer than two are due. A failure of the exchange
    /// counts against every block read, and one for want of an answer makes the
    /// reader warn and read one request at a time from the next connection on.
    async fn read_due_blocks(
        &mut self,
        context: &mut Connection,
    ) -> Result<Option<VecDeque<(usize, Answer)>>, DaqError> {
        let Connection::Link(link) = context else {
            return Ok(None);
        };
        let due: Vec<usize> = (0..self.blocks.len())
            .filter(|&index| self.blocks[index].due(now()))
            .collect();
        if due.len() < 2 {
            return Ok(None);
        }
        let requests: Vec<Request<'_>> = due
            .iter()
            .map(|&index| {
                let block = &self.blocks[index];
                Request::Read(block.table, block.base, BLOCK_REGISTERS)
            })
            .collect();
        match link.exchange(&requests, self.in_flight, false).await {
            Ok(answers) => Ok(Some(due.into_iter().zip(answers).collect())),
            Err(error) => {
                let error = DaqError::from(error);
                for &index in &due {
                    self.blocks[index].failed(now());
                    count_error(&self.blocks[index].counters, &error);
                }
                if error.needs_reconnect() && self.in_flight > 1 {
                    tracing::warn!(
                        source = %self.name,
                        %error,
                        requests_in_flight = self.in_flight,
                        "the DAQ did not answer a poll's requests in flight: its blocks are \
                         read one request at a time from the next connection on (set \
                         requests_in_flight = 1 for this source)"
                    );
                    self.in_flight = 1;
                }
                Err(error)
            }
        }
    }

    /// One poll: the block channels whose read is due and, on the grid (`on_grid`),
    /// the process values and texts. Whether it brought new data (a block advanced,
    /// or a process value was read on a source without blocks), or the analysis is
    /// gone.
    async fn poll(
        &mut self,
        context: &mut Connection,
        samples: &mpsc::Sender<Acquired>,
        on_grid: bool,
    ) -> Result<Poll, DaqError> {
        self.take_new_channels();
        let timeout = self.source.timeout;
        let mut first_error = None;
        let mut new_data = false;
        let mut answered = self.read_due_blocks(context).await?;
        for (index, block) in self.blocks.iter_mut().enumerate() {
            let read = match &mut answered {
                // Read together: the answer of this block, if it was due.
                Some(answers) => {
                    if answers.front().is_none_or(|(due, _)| *due != index) {
                        continue;
                    }
                    let Some((_, answer)) = answers.pop_front() else {
                        continue;
                    };
                    answer.map_err(|exception| {
                        DaqError::from(ModbusError::Exception {
                            address: block.base,
                            exception,
                        })
                    })
                }
                None if !block.due(now()) => continue,
                None => {
                    let what = (block.table, block.base, BLOCK_REGISTERS);
                    read(context, &mut self.spacing, what, timeout).await
                }
            };
            let registers = match read {
                Ok(registers) => registers,
                Err(error) => {
                    block.failed(now());
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
                    block.failed(now());
                    block.counters.error();
                    first_error.get_or_insert(DaqError::Block {
                        address: block.base,
                        source: error,
                    });
                    continue;
                }
            };
            let BlockNews::New(messages) = block.accept(decoded.sequence, decoded.raw, now())
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
        let (values, texts) = if on_grid {
            (&self.values[..], &self.texts[..])
        } else {
            (&[][..], &[][..])
        };
        for value in values {
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
                value: value.scaling.apply(raw),
            };
            if samples.send(message).await.is_err() {
                return Ok(Poll::AnalysisGone);
            }
        }
        for text in texts {
            let what = (text.table, text.address, text.registers);
            let registers = match read(context, &mut self.spacing, what, timeout).await {
                Ok(registers) => registers,
                Err(error) => {
                    count_error(&text.counters, &error);
                    if error.needs_reconnect() {
                        return Err(error);
                    }
                    first_error.get_or_insert(error);
                    continue;
                }
            };
            // Junk in the registers is the PLC's value, not a failed read: it goes on
            // as an invalid text (the context invalid, counted by the analysis).
            text.counters.block(1);
            new_data |= self.blocks.is_empty();
            let message = Acquired::Text {
                channel: text.channel,
                text: decode_ascii(&registers, text.byte_order),
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

/// The time now: the system's clock, the paused clock of the unit tests.
fn now() -> Instant {
    tokio::time::Instant::now().into_std()
}

fn count_error(counters: &ChannelCounters, error: &DaqError) {
    match error {
        DaqError::Modbus(ModbusError::Timeout(_)) => counters.timeout(),
        _ => counters.error(),
    }
}

/// One read ([`client::read`], or one request over a link) as a poll's error; over
/// RTU (`spacing`) after the line's silence.
async fn read(
    context: &mut Connection,
    spacing: &mut Option<FrameSpacing>,
    what: (RegisterTable, u16, u16),
    timeout: Duration,
) -> Result<Vec<u16>, DaqError> {
    let context = match context {
        Connection::Client(context) => context,
        Connection::Link(link) => return Ok(link.read(what).await?),
    };
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
    //! The reconnect backoff and the source's stale and lost timing on a paused clock:
    //! the reader runs as in the service, its DAQ in memory (a [`Connector`] instead
    //! of the source's address), so every wait is the code's own timer. The real-time
    //! end-to-end runs are `tests/tests/daq_faults.rs` (a DAQ that accepts and closes,
    //! a frozen sequence, the cable pulled).

    use std::sync::Mutex;

    use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
    use tokio::time::Instant;
    use tokio_modbus::prelude::Slave;

    use super::*;
    use crate::field::source_health::SourceStatus;

    /// What the in-memory DAQ does on one connection.
    #[derive(Debug, Clone, Copy)]
    pub(super) enum Daq {
        /// Accepts and closes at once (a DAQ at its client limit).
        Closes,
        /// Reads every request and never answers.
        Silent,
        /// Answers every poll with the block of the moment.
        Streams(Stream),
    }

    /// A streaming DAQ: a new block every `period` since the test began (block
    /// `late.0` that much later than its time), the same one from `frozen_at` on;
    /// closes at the first request `closes_after` or more into the connection.
    #[derive(Debug, Clone, Copy)]
    pub(super) struct Stream {
        frozen_at: Duration,
        closes_after: Duration,
        period: Duration,
        late: Option<(u128, Duration)>,
    }

    impl Stream {
        /// The sequence of the block of the moment, `elapsed` into the test.
        fn sequence(&self, elapsed: Duration) -> u16 {
            let elapsed = elapsed.min(self.frozen_at);
            let mut blocks = elapsed.as_nanos() / self.period.as_nanos();
            if let Some((block, by)) = self.late {
                if blocks == block && elapsed < self.period * block as u32 + by {
                    blocks -= 1;
                }
            }
            1 + blocks as u16
        }
    }

    /// A DAQ that streams for ever at the test channel's rate.
    const STREAM: Stream = Stream {
        frozen_at: Duration::MAX,
        closes_after: Duration::MAX,
        period: BLOCK_PERIOD,
        late: None,
    };
    const STREAMS: Daq = Daq::Streams(STREAM);

    /// 100 samples at the test channel's 2 kHz.
    const BLOCK_PERIOD: Duration = Duration::from_millis(50);

    /// The reader's connections: the `n`-th made in memory with `script[n]` (the last
    /// entry for the ones after), the time of each noted.
    pub(super) struct Connector {
        script: Vec<Daq>,
        start: Instant,
        made: Arc<Mutex<Vec<Instant>>>,
        /// The requests the DAQs answered: when, and the sequence of the block.
        requests: Requests,
    }

    /// The requests a DAQ answered: when (since the test began), and the sequence of
    /// the block answered.
    type Requests = Arc<Mutex<Vec<(Duration, u16)>>>;

    impl std::fmt::Debug for Connector {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.debug_struct("Connector")
                .field("script", &self.script)
                .finish_non_exhaustive()
        }
    }

    impl Connector {
        pub(super) fn connect(&mut self) -> Context {
            let mut made = self.made.lock().unwrap();
            let daq = self.script[made.len().min(self.script.len() - 1)];
            made.push(Instant::now());
            let (gateway, device) = tokio::io::duplex(4096);
            tokio::spawn(serve(device, daq, self.start, Arc::clone(&self.requests)));
            tokio_modbus::client::tcp::attach_slave(gateway, Slave(1))
        }
    }

    /// The DAQ's end of one connection.
    async fn serve(mut device: DuplexStream, daq: Daq, start: Instant, requests: Requests) {
        let stream = match daq {
            Daq::Closes => return,
            Daq::Silent => {
                let _ = device.read_to_end(&mut Vec::new()).await;
                return;
            }
            Daq::Streams(stream) => stream,
        };
        let connected = Instant::now();
        loop {
            let mut header = [0u8; 7];
            if device.read_exact(&mut header).await.is_err() {
                return;
            }
            let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
            let mut pdu = vec![0u8; length.saturating_sub(1)];
            if device.read_exact(&mut pdu).await.is_err()
                || connected.elapsed() >= stream.closes_after
            {
                return;
            }
            let elapsed = start.elapsed();
            let sequence = stream.sequence(elapsed);
            requests.lock().unwrap().push((elapsed, sequence));
            let mut words = vec![0u16; usize::from(BLOCK_REGISTERS)];
            layout::encode_block(sequence, &[0; 100], &mut words);
            let bytes = (words.len() * 2) as u8;
            let mut frame = vec![header[0], header[1], 0, 0];
            frame.extend((3 + u16::from(bytes)).to_be_bytes());
            frame.extend([header[6], pdu[0], bytes]);
            frame.extend(words.iter().flat_map(|word| word.to_be_bytes()));
            if device.write_all(&frame).await.is_err() {
                return;
            }
        }
    }

    /// The test source (polled every 20 ms, 300 ms timeout) with one 2 kHz block
    /// channel, and as many more after it as `more` names (blocks right after it).
    fn source_config(more: &[&str]) -> Config {
        let mut text = String::from(
            "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\n\
             poll_period_ms = 20\ntimeout_ms = 300\n",
        );
        for (k, name) in std::iter::once(&"a").chain(more).enumerate() {
            text += &format!(
                "[[channels]]\nname = \"{name}\"\nkind = \"acceleration\"\n\
                 unit = \"m/s^2\"\nsample_rate_hz = 2000\n\
                 source = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
                k * usize::from(BLOCK_REGISTERS)
            );
        }
        millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
            .unwrap_or_else(|error| panic!("{error}"))
    }

    /// What a test watches of a running reader.
    struct Watched {
        /// The times of its connections.
        made: Arc<Mutex<Vec<Instant>>>,
        /// Its source's health (stale after 200 ms, lost after 1 s).
        health: Arc<SourceHealth>,
        /// Its channel's counters.
        counters: Arc<ChannelCounters>,
        /// The requests its DAQs answered.
        requests: Requests,
    }

    /// A reader of one 2 kHz block channel (polled every 20 ms, 300 ms timeout) on
    /// `script`'s DAQs, its samples drained, until `shutdown` fires.
    fn reader(script: Vec<Daq>, shutdown: Shutdown) -> Watched {
        let config = source_config(&[]);
        let counters = Arc::new(ChannelCounters::default());
        let health = Arc::new(SourceHealth::new(
            Duration::from_millis(200),
            Duration::from_secs(1),
        ));
        let mut reader = DaqReader::new(
            &config,
            0,
            std::slice::from_ref(&counters),
            Arc::clone(&health),
        );
        let made = Arc::new(Mutex::new(Vec::new()));
        let requests = Requests::default();
        reader.connector = Some(Connector {
            script,
            start: Instant::now(),
            made: Arc::clone(&made),
            requests: Arc::clone(&requests),
        });
        let (samples, mut drain) = mpsc::channel(64);
        tokio::spawn(async move { while drain.recv().await.is_some() {} });
        tokio::spawn(reader.run(samples, shutdown));
        Watched {
            made,
            health,
            counters,
            requests,
        }
    }

    /// The gaps between the connections made, ms.
    fn spacing_ms(made: &Mutex<Vec<Instant>>) -> Vec<u128> {
        let made = made.lock().unwrap();
        made.windows(2)
            .map(|pair| (pair[1] - pair[0]).as_millis())
            .collect()
    }

    #[tokio::test(start_paused = true)]
    async fn a_daq_that_accepts_and_closes_is_retried_with_a_doubling_backoff_to_5_s() {
        let (_stop, shutdown) = crate::shutdown::channel();
        let Watched { made, health, .. } = reader(vec![Daq::Closes], shutdown);
        tokio::time::sleep(Duration::from_secs(20)).await;
        // Each attempt fails at once: the attempts are the backoff apart, not a storm.
        assert_eq!(
            spacing_ms(&made),
            [100, 200, 400, 800, 1600, 3200, 5000, 5000]
        );
        assert_eq!(health.connects(), 9, "every attempt connected");
        assert_eq!(health.status(), SourceStatus::Lost, "never answered");
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_daq_times_out_each_connection_then_backs_off() {
        let (_stop, shutdown) = crate::shutdown::channel();
        let Watched {
            made,
            health,
            counters,
            ..
        } = reader(vec![Daq::Silent], shutdown);
        tokio::time::sleep(Duration::from_millis(3500)).await;
        // The request's 300 ms timeout, then the backoff.
        assert_eq!(spacing_ms(&made), [400, 500, 700, 1100]);
        assert_eq!(counters.snapshot().timeouts, 5);
        assert_eq!(health.status(), SourceStatus::Lost);
    }

    #[tokio::test(start_paused = true)]
    async fn new_data_restarts_the_backoff_and_a_connect_alone_does_not() {
        let (_stop, shutdown) = crate::shutdown::channel();
        let half_a_second = Daq::Streams(Stream {
            closes_after: Duration::from_millis(490),
            ..STREAM
        });
        let script = vec![
            Daq::Closes,
            Daq::Closes,
            Daq::Closes,
            half_a_second,
            Daq::Closes,
        ];
        let Watched { made, health, .. } = reader(script, shutdown);
        tokio::time::sleep(Duration::from_secs(2)).await;
        // Connects at 0, 0.1, 0.3 and 0.7 s: the backoff grew over three connects. The
        // fourth brought data until it closed at its read of 1.203 s; the next attempts
        // start from 100 ms again.
        assert_eq!(spacing_ms(&made), [100, 200, 400, 603, 200, 400]);
        assert_eq!(
            health.status(),
            SourceStatus::Stale,
            "new data until 1.16 s: stale, not yet lost"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_streaming_daq_is_polled_on_one_connection_and_stays_ok() {
        let (_stop, shutdown) = crate::shutdown::channel();
        let Watched {
            made,
            health,
            counters,
            ..
        } = reader(vec![STREAMS], shutdown);
        tokio::time::sleep(Duration::from_millis(1990)).await;
        assert_eq!(made.lock().unwrap().len(), 1);
        assert_eq!(health.status(), SourceStatus::Ok);
        assert_eq!(
            counters.snapshot().blocks_read,
            40,
            "blocks 1..=40 by 1.98 s"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_frozen_daq_goes_stale_after_its_stale_time_and_lost_after_its_lost_time() {
        let (_stop, shutdown) = crate::shutdown::channel();
        let frozen_at = Duration::from_millis(1000);
        let daq = Daq::Streams(Stream {
            frozen_at,
            ..STREAM
        });
        let Watched {
            made,
            health,
            counters,
            ..
        } = reader(vec![daq], shutdown);
        let start = Instant::now();
        // The last new block is the one of 1.000 s, read at the first poll after it.
        tokio::time::sleep_until(start + frozen_at).await;
        assert_eq!(health.status(), SourceStatus::Ok);
        tokio::time::sleep_until(start + frozen_at + Duration::from_millis(190)).await;
        assert_eq!(health.status(), SourceStatus::Ok, "within the stale time");
        tokio::time::sleep_until(start + frozen_at + Duration::from_millis(230)).await;
        assert_eq!(health.status(), SourceStatus::Stale, "past the stale time");
        tokio::time::sleep_until(start + frozen_at + Duration::from_millis(990)).await;
        assert_eq!(health.status(), SourceStatus::Stale, "within the lost time");
        tokio::time::sleep_until(start + frozen_at + Duration::from_millis(1030)).await;
        assert_eq!(health.status(), SourceStatus::Lost, "past the lost time");
        // The DAQ kept answering: one connection, its blocks read once each.
        assert_eq!(made.lock().unwrap().len(), 1);
        assert_eq!(counters.snapshot().blocks_read, 21, "blocks 1..=21");
    }

    #[tokio::test(start_paused = true)]
    async fn a_channel_added_between_two_polls_is_read_and_the_running_one_misses_no_block() {
        let (stop, shutdown) = crate::shutdown::channel();
        let running = Arc::new(source_config(&[]));
        let grown = Arc::new(source_config(&["b"]));
        let counters: Vec<Arc<ChannelCounters>> = (0..2).map(|_| Arc::default()).collect();
        let (feed, new_channels) = watch::channel(NewChannels {
            config: Arc::clone(&running),
            counters: counters[..1].to_vec(),
        });
        let health = Arc::new(SourceHealth::new(
            Duration::from_millis(200),
            Duration::from_secs(1),
        ));
        let mut reader =
            DaqReader::new(&running, 0, &counters[..1], health).with_new_channels(new_channels);
        let made = Arc::new(Mutex::new(Vec::new()));
        reader.connector = Some(Connector {
            script: vec![STREAMS],
            start: Instant::now(),
            made: Arc::clone(&made),
            requests: Arc::default(),
        });
        let (samples, mut received) = mpsc::channel(64);
        let messages = tokio::spawn(async move {
            let mut messages = Vec::new();
            while let Some(message) = received.recv().await {
                messages.push(message);
            }
            messages
        });
        let reading = tokio::spawn(reader.run(samples, shutdown));
        // 1 s of reads of channel a (blocks 1..=21, the 21st read within a poll period of
        // its coming at 1 s), then channel b appended.
        tokio::time::sleep(Duration::from_millis(1025)).await;
        assert_eq!(counters[0].snapshot().blocks_read, 21, "blocks 1..=21");
        feed.send_replace(NewChannels {
            config: grown,
            counters: counters.clone(),
        });
        tokio::time::sleep(Duration::from_millis(960)).await;
        stop.trigger();
        reading.await.unwrap();
        let messages = messages.await.unwrap();
        // One connection throughout; a read every block on, none missed or restarted.
        assert_eq!(made.lock().unwrap().len(), 1);
        let (a, b) = (counters[0].snapshot(), counters[1].snapshot());
        assert_eq!(a.blocks_read, 40, "blocks 1..=40 by 1.985 s");
        assert_eq!((a.blocks_missed, a.sequence_restarts), (0, 0));
        // Channel b is taken at the source's next read, of a's block 22 (due at 1.05 s).
        assert_eq!(b.blocks_read, 19, "blocks 22..=40 for the channel added");
        assert_eq!((b.blocks_missed, b.sequence_restarts), (0, 0));
        let gaps = messages
            .iter()
            .filter(|message| matches!(message, Acquired::Gap { .. }))
            .count();
        assert_eq!(gaps, 0, "no gap on either channel");
        let blocks_of = |wanted: usize| {
            messages
                .iter()
                .filter(|m| matches!(m, Acquired::Samples { channel, .. } if *channel == wanted))
                .count()
        };
        assert_eq!((blocks_of(0), blocks_of(1)), (40, 19));
    }

    /// Per block a DAQ made while `watched` read it for `seconds`: how long after it
    /// came it was first read, and how many reads were made in all. `stream` is the
    /// DAQ's timing.
    async fn read_delays(stream: Stream, seconds: u64) -> (Vec<Duration>, usize, Watched) {
        let (_stop, shutdown) = crate::shutdown::channel();
        let watched = reader(vec![Daq::Streams(stream)], shutdown);
        tokio::time::sleep(Duration::from_secs(seconds)).await;
        let requests = watched.requests.lock().unwrap().clone();
        let mut delays = Vec::new();
        for (k, pair) in requests.windows(2).enumerate() {
            let ((_, before), (at, sequence)) = (pair[0], pair[1]);
            if sequence != before {
                // Block `sequence` came (sequence - 1) periods in, later if it was late.
                let index = u128::from(sequence - 1);
                let mut came = stream.period * (sequence - 1) as u32;
                if let Some((late, by)) = stream.late {
                    came += if index == late { by } else { Duration::ZERO };
                }
                assert!(at >= came, "read {k}: block {sequence} before it came");
                delays.push(at - came);
            }
        }
        (delays, requests.len(), watched)
    }

    /// The poll period of the test source, and the timer's millisecond on top.
    const WITHIN_A_POLL: Duration = Duration::from_millis(21);

    #[tokio::test(start_paused = true)]
    async fn each_block_is_read_once_and_within_a_poll_period_of_its_coming() {
        let (delays, reads, watched) = read_delays(STREAM, 10).await;
        let counters = watched.counters.snapshot();
        assert_eq!((counters.blocks_read, counters.blocks_missed), (200, 0));
        assert_eq!(delays.len(), 199, "every block after the first");
        let late = delays.iter().max().unwrap();
        assert!(*late < WITHIN_A_POLL, "a block read {late:?} after it came");
        // A read every poll period would make 500 reads: 2.5 a block.
        assert!(reads <= 240, "{reads} reads for 200 blocks");
    }

    #[tokio::test(start_paused = true)]
    async fn a_daq_clock_a_few_percent_off_is_followed() {
        for period_us in [48_500, 51_500] {
            let stream = Stream {
                period: Duration::from_micros(period_us),
                ..STREAM
            };
            let (delays, reads, watched) = read_delays(stream, 20).await;
            let counters = watched.counters.snapshot();
            assert_eq!(counters.blocks_missed, 0, "period {period_us} us");
            assert_eq!(counters.blocks_read as usize, delays.len() + 1);
            let late = delays.iter().max().unwrap();
            assert!(
                *late < WITHIN_A_POLL,
                "{period_us} us: a block read {late:?} after it came"
            );
            let per_block = reads as f64 / counters.blocks_read as f64;
            assert!(per_block < 1.4, "{period_us} us: {per_block} reads a block");
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_late_block_is_read_when_it_comes_and_the_next_ones_catch_up() {
        let by = Duration::from_millis(30);
        let stream = Stream {
            late: Some((20, by)),
            ..STREAM
        };
        let (delays, _, watched) = read_delays(stream, 5).await;
        let counters = watched.counters.snapshot();
        assert_eq!((counters.blocks_read, counters.blocks_missed), (100, 0));
        // delays[k] is block k + 2's: block 21 (index 20) 30 ms late.
        assert!(
            delays[19] < WITHIN_A_POLL,
            "the late block: {:?}",
            delays[19]
        );
        // The next blocks came on time: read at most the lateness after, and within a
        // poll period again after ten blocks.
        assert!(delays[20..].iter().all(|delay| *delay < by + WITHIN_A_POLL));
        assert!(delays[30..].iter().all(|delay| *delay < WITHIN_A_POLL));
    }

    #[tokio::test(start_paused = true)]
    async fn a_daq_twice_as_fast_as_configured_loses_blocks_counted_and_is_read_every_poll() {
        let stream = Stream {
            period: BLOCK_PERIOD / 2,
            ..STREAM
        };
        let (_, reads, watched) = read_delays(stream, 10).await;
        let counters = watched.counters.snapshot();
        // A loss, then a read every poll period for 64 block periods (3.2 s): a few
        // losses in 10 s, each counted, and about a read every poll period.
        assert!(
            (1..=4).contains(&counters.blocks_missed),
            "{} blocks missed",
            counters.blocks_missed
        );
        assert_eq!(counters.blocks_read + counters.blocks_missed, 400);
        assert!(reads > 400, "{reads} reads in 10 s");
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

    /// A DAQ on loopback whose stack takes one request at a time, as pymodbus 3.16's
    /// server does: of what one read brings it, it answers the first frame (exception
    /// 02, which keeps the connection) and drops the rest. Gives its address and the
    /// frames each connection brought in one read.
    async fn one_at_a_time_daq() -> (String, Arc<Mutex<Vec<Vec<usize>>>>) {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap().to_string();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let connections = Arc::clone(&seen);
        tokio::spawn(async move {
            while let Ok((mut socket, _)) = listener.accept().await {
                let connection = {
                    let mut seen = connections.lock().unwrap();
                    seen.push(Vec::new());
                    seen.len() - 1
                };
                let seen = Arc::clone(&connections);
                tokio::spawn(async move {
                    let mut buffer = [0u8; 4096];
                    while let Ok(n @ 1..) = socket.read(&mut buffer).await {
                        let frames = buffer[..n].chunks(12).count();
                        seen.lock().unwrap()[connection].push(frames);
                        let (id, unit, function) = (&buffer[..2], buffer[6], buffer[7]);
                        let answer = [id, &[0, 0, 0, 3, unit, function | 0x80, 2]].concat();
                        if socket.write_all(&answer).await.is_err() {
                            break;
                        }
                    }
                });
            }
        });
        (address, seen)
    }

    /// Two block channels due together, read with requests in flight from a DAQ that
    /// answers the first only: the poll times out once (each channel counts the
    /// timeout), the reader connects again and reads one request at a time from then
    /// on, each read answered (the DAQ's refusal, counted as an error).
    #[tokio::test]
    async fn a_daq_that_takes_one_request_at_a_time_is_read_one_at_a_time_after_one_timeout() {
        let (address, seen) = one_at_a_time_daq().await;
        let mut config = source_config(&["b"]);
        config.modbus_sources[0].address = address;
        config.modbus_sources[0].requests_in_flight = 8;
        let counters = [
            Arc::new(ChannelCounters::default()),
            Arc::new(ChannelCounters::default()),
        ];
        let health = Arc::new(SourceHealth::new(
            Duration::from_millis(200),
            Duration::from_secs(1),
        ));
        let reader = DaqReader::new(&config, 0, &counters, health);
        let (samples, mut drain) = mpsc::channel(64);
        tokio::spawn(async move { while drain.recv().await.is_some() {} });
        let (stop, shutdown) = crate::shutdown::channel();
        let running = tokio::spawn(reader.run(samples, shutdown));
        // The timeout (300 ms), the backoff before the next connection, then polls.
        tokio::time::sleep(Duration::from_millis(2500)).await;
        stop.trigger();
        running.await.unwrap();
        let seen = seen.lock().unwrap().clone();
        assert!(seen.len() >= 2, "connections: {seen:?}");
        // The first read of the first connection brought both requests (24 bytes: two
        // FC 04 frames of 12).
        assert_eq!(seen[0].first(), Some(&2), "{seen:?}");
        // From the next connection on, one request at a time, and many of them.
        let later: Vec<usize> = seen[1..].iter().flatten().copied().collect();
        assert!(later.iter().all(|&frames| frames == 1), "{seen:?}");
        assert!(later.len() >= 10, "{seen:?}");
        for counter in &counters {
            let counted = counter.snapshot();
            assert_eq!(counted.timeouts, 1, "{counted:?}");
            assert!(counted.errors >= 5, "{counted:?}");
        }
    }
}
