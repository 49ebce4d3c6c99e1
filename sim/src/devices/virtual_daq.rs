//! A virtual Modbus TCP DAQ that streams simulated channels in the millgate
//! acquisition layout (`millgate_config::layout`).
//!
//! Each block period (`samples_per_block / sample_rate_hz`) the DAQ writes the next
//! block of every channel into its buffer and bumps the block's sequence number, as a
//! real DAQ's firmware would. Process values are refreshed at the same moment with
//! the signal's value at the end of the block.
//!
//! Streaming: a DAQ whose samples are made while it runs (the closed loop, whose mill
//! is simulated a block at a time) is served with [`VirtualDaq::serve`] and given each
//! block with [`VirtualDaq::publish`] by its owner, who keeps the time.

use std::future::Future;
use std::io;
use std::time::Duration;

use millgate_config::layout::{self, BLOCK_HEADER_REGISTERS, MAX_BLOCK_SAMPLES};
use millgate_config::{RegisterTable, ValueType, WordOrder};
use tokio::net::TcpListener;

use super::modbus_bank::{serve, RegisterBank, Running, ServeOptions, SharedBank};

/// Where a signal is published and how it is scaled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Input or holding registers.
    pub table: RegisterTable,
    /// First register (block base, or the process value's register).
    pub address: u16,
    /// Engineering value = raw * scale + offset.
    pub scale: f64,
    /// Engineering value at raw 0.
    pub offset: f64,
}

/// What a DAQ channel publishes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Publish {
    /// A block buffer of i16 samples.
    Block,
    /// A scalar process value.
    Value {
        /// How the registers encode the value.
        value_type: ValueType,
        /// Where the value's bytes land in the registers.
        word_order: WordOrder,
    },
}

/// One channel of the virtual DAQ.
#[derive(Debug, Clone, PartialEq)]
pub struct DaqChannel {
    /// Where the channel is published and how it is scaled.
    pub placement: Placement,
    /// As a block buffer or a process value.
    pub publish: Publish,
    /// The signal in engineering units at the DAQ's sample rate; played once,
    /// then the last value is held.
    pub signal: Vec<f64>,
}

/// A virtual DAQ: a register bank and the channels it streams into it.
#[derive(Debug, Clone)]
pub struct VirtualDaq {
    bank: SharedBank,
    channels: Vec<DaqChannel>,
    sample_rate_hz: f64,
    samples_per_block: u16,
    next_sample: usize,
    sequence: u16,
    looped: bool,
    from_first_read: bool,
}

impl VirtualDaq {
    /// A DAQ streaming `channels` at `sample_rate_hz` in blocks of
    /// `samples_per_block` (1..=120) samples. The tables are sized to fit every channel.
    pub fn new(sample_rate_hz: f64, samples_per_block: u16, channels: Vec<DaqChannel>) -> Self {
        let samples_per_block = samples_per_block.clamp(1, MAX_BLOCK_SAMPLES);
        let end = |table: RegisterTable| {
            channels
                .iter()
                .filter(|c| c.placement.table == table)
                .map(|c| usize::from(c.placement.address) + usize::from(Self::span(c)))
                .max()
                .unwrap_or(0)
        };
        let bank = RegisterBank::new(
            end(RegisterTable::Input),
            end(RegisterTable::Holding),
            false,
        );
        Self {
            bank: SharedBank::new(bank),
            channels,
            sample_rate_hz,
            samples_per_block,
            next_sample: 0,
            sequence: 0,
            looped: false,
            from_first_read: false,
        }
    }

    /// This DAQ with its block sequence at `sequence` (its first block is
    /// `sequence + 1`), as one that has been running for a while: a restart then sets
    /// the sequence back by far more than any delay of a reader could advance it.
    pub fn with_sequence(mut self, sequence: u16) -> Self {
        self.sequence = sequence;
        self
    }

    /// This DAQ playing each channel's signal over and over instead of holding its
    /// last value (a long run from a short signal: load benchmarks and soaks).
    pub fn looped(mut self) -> Self {
        self.looped = true;
        self
    }

    /// This DAQ holding its first block until a client has read it, then playing in
    /// real time: the whole signal reaches a reader that connects late (a test's
    /// gateway starting on a loaded machine), from the first block on.
    pub fn playing_from_first_read(mut self) -> Self {
        self.from_first_read = true;
        self
    }

    fn span(channel: &DaqChannel) -> u16 {
        match channel.publish {
            Publish::Block => BLOCK_HEADER_REGISTERS + MAX_BLOCK_SAMPLES,
            Publish::Value { value_type, .. } => value_type.register_count(),
        }
    }

    /// This DAQ recording the time and first word (a block's sequence) of every read
    /// of its input registers (drained through [`SharedBank::take_read_log`]).
    pub fn logging_reads(self) -> Self {
        self.bank.lock().read_log = Some(Vec::new());
        self
    }

    /// The register bank, for inspection by tests.
    pub fn bank(&self) -> SharedBank {
        self.bank.clone()
    }

    /// Time between two blocks.
    pub(crate) fn block_period(&self) -> Duration {
        Duration::from_secs_f64(f64::from(self.samples_per_block) / self.sample_rate_hz)
    }

    /// Publish the next block of every channel and advance the sequence number.
    pub(crate) fn publish_next_block(&mut self) {
        let start = self.next_sample;
        let end = start + usize::from(self.samples_per_block);
        self.sequence = self.sequence.wrapping_add(1);
        let mut bank = self.bank.lock();
        for channel in &self.channels {
            let signal = &channel.signal;
            let at = |i: usize| {
                let i = if self.looped && !signal.is_empty() {
                    i % signal.len()
                } else {
                    i
                };
                signal.get(i).or(signal.last()).copied().unwrap_or(0.0)
            };
            let values: Vec<f64> = (start..end).map(at).collect();
            write_channel(&mut bank, channel, self.sequence, &values);
        }
        self.next_sample = end;
    }

    /// Publish one block given by the caller: `blocks[k]` holds the samples (at most
    /// 120) of the k-th channel, in channel order; the sequence number advances. The
    /// channels' own signals are not used.
    pub fn publish(&mut self, blocks: &[&[f64]]) {
        self.sequence = self.sequence.wrapping_add(1);
        let mut bank = self.bank.lock();
        for (channel, values) in self.channels.iter().zip(blocks) {
            write_channel(&mut bank, channel, self.sequence, values);
        }
        self.next_sample += blocks.first().map_or(0, |b| b.len());
    }

    /// Serve the bank in the background until the handle is stopped, without
    /// publishing: the owner publishes with [`VirtualDaq::publish`].
    pub fn serve(&self, listener: TcpListener, options: ServeOptions) -> Running {
        let bank = self.bank();
        Running::spawn(|stop| serve(listener, bank, options, stop.wait()))
    }

    /// Serve and publish in the background until the handle is stopped.
    pub fn spawn(self, listener: TcpListener, options: ServeOptions) -> Running {
        Running::spawn(|stop| self.run(listener, options, stop.wait()))
    }

    /// Serve the DAQ on `listener` and publish a block every block period until
    /// `shutdown` completes.
    pub(crate) async fn run(
        mut self,
        listener: TcpListener,
        options: ServeOptions,
        shutdown: impl Future<Output = ()> + Send + Sync + 'static,
    ) -> io::Result<()> {
        // A DAQ answers with its first block already in the buffer, never an empty one.
        self.publish_next_block();
        let mut server = tokio::spawn(serve(listener, self.bank(), options, shutdown));
        if self.from_first_read {
            // Polled: the bank is a plain mutex shared with the server.
            while self.bank.lock().reads == 0 {
                tokio::select! {
                    () = tokio::time::sleep(Duration::from_millis(1)) => {}
                    served = &mut server => return served.map_err(io::Error::other)?,
                }
            }
        }
        let period = self.block_period();
        let mut ticks = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        loop {
            tokio::select! {
                _ = ticks.tick() => self.publish_next_block(),
                served = &mut server => return served.map_err(io::Error::other)?,
            }
        }
    }
}

/// Write `values` (samples of one block, or the value at its end) of `channel` into
/// `bank`, with `sequence` for a block.
fn write_channel(bank: &mut RegisterBank, channel: &DaqChannel, sequence: u16, values: &[f64]) {
    let Placement {
        table,
        address,
        scale,
        offset,
    } = channel.placement;
    let registers = match table {
        RegisterTable::Input => &mut bank.input,
        RegisterTable::Holding => &mut bank.holding,
    };
    let base = usize::from(address);
    match channel.publish {
        Publish::Block => {
            let raw: Vec<i16> = values
                .iter()
                .map(|&v| layout::to_raw_sample(v, scale, offset))
                .collect();
            layout::encode_block(sequence, &raw, &mut registers[base..]);
        }
        Publish::Value {
            value_type,
            word_order,
        } => {
            let last = values.last().copied().unwrap_or(0.0);
            let raw = (last - offset) / scale;
            let (words, used) = layout::encode_value(raw, value_type, word_order);
            registers[base..base + used].copy_from_slice(&words[..used]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_carry_sequence_count_and_scaled_samples() {
        let signal: Vec<f64> = (0..250).map(|i| f64::from(i) * 0.5).collect();
        let channel = DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: 10,
                scale: 0.5,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal,
        };
        let mut daq = VirtualDaq::new(1000.0, 100, vec![channel]);
        daq.publish_next_block();
        daq.publish_next_block();
        let bank = daq.bank();
        let bank = bank.lock();
        let block = layout::decode_block(&bank.input[10..]).unwrap();
        assert_eq!(block.sequence, 2);
        assert_eq!(block.raw.len(), 100);
        assert_eq!(
            block.values(millgate_config::Scaling::new(0.5, 0.0)).next(),
            Some(50.0)
        );
        assert_eq!(daq.next_sample, 200);
        assert_eq!(daq.block_period(), Duration::from_millis(100));
        drop(bank);
        // A block given by the owner replaces the signal's next one.
        let given: Vec<f64> = (0..100).map(|i| f64::from(i) * -0.5).collect();
        daq.publish(&[&given]);
        let bank = daq.bank();
        let bank = bank.lock();
        let block = layout::decode_block(&bank.input[10..]).unwrap();
        assert_eq!(block.sequence, 3);
        assert_eq!(
            block.values(millgate_config::Scaling::new(0.5, 0.0)).nth(7),
            Some(-3.5)
        );
        assert_eq!(daq.next_sample, 300);
    }

    #[test]
    fn a_looped_daq_plays_its_signal_again() {
        let channel = DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: 0,
                scale: 1.0,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal: vec![1.0, 2.0, 3.0],
        };
        let mut daq = VirtualDaq::new(1000.0, 4, vec![channel]).looped();
        daq.publish_next_block();
        daq.publish_next_block();
        let input = daq.bank().lock().input.clone();
        let block = layout::decode_block(&input).unwrap();
        assert_eq!(
            block
                .values(millgate_config::Scaling::new(1.0, 0.0))
                .collect::<Vec<_>>(),
            [2.0, 3.0, 1.0, 2.0]
        );
    }

    #[test]
    fn process_values_hold_the_last_sample_of_the_block() {
        let channel = DaqChannel {
            placement: Placement {
                table: RegisterTable::Holding,
                address: 0,
                scale: 0.1,
                offset: 0.0,
            },
            publish: Publish::Value {
                value_type: ValueType::F32,
                word_order: WordOrder::Cdab,
            },
            signal: vec![1.0, 2.0, 3.0],
        };
        let mut daq = VirtualDaq::new(1000.0, 2, vec![channel]);
        daq.publish_next_block();
        let bank = daq.bank();
        let words = bank.lock().holding.clone();
        let raw = layout::decode_value(&words, ValueType::F32, WordOrder::Cdab).unwrap();
        assert!((raw * 0.1 - 2.0).abs() < 1e-5);
    }
}
