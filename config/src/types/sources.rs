//! The field sources (Modbus devices, CAN interfaces) and the channels read from them.

use std::path::PathBuf;
use std::time::Duration;

use crate::SerialLine;

/// A Modbus device polled by the gateway: over TCP, or over a serial line (RTU).
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusSource {
    /// Unique among all sources.
    pub name: String,
    /// Where the device is. Modbus TCP: `host:port`, resolved at connect time, so a
    /// DNS name is kept as written. Modbus RTU (`serial` set): the serial device's
    /// absolute path (the file's `device` key), e.g. `/dev/ttyUSB0`.
    pub address: String,
    /// The serial line's settings for a Modbus RTU device (`device` in the file);
    /// `None` for Modbus TCP (`address`).
    pub serial: Option<SerialLine>,
    /// Modbus unit identifier (slave id): 0..=255 over TCP, 1..=247 over RTU (0 is
    /// the broadcast address, which no device answers).
    pub unit_id: u8,
    /// Time between polls, 1..=60000 ms; shorter than the block period
    /// (120 samples / sample rate) of every block channel on this source, and over
    /// RTU long enough for the line to carry one poll's frames and silences.
    pub poll_period: Duration,
    /// Time allowed for one request/response (over RTU the response timeout),
    /// 1..=60000 ms (default 1000 ms).
    pub timeout: Duration,
    /// Block reads of one poll sent before their answers came, 1..=16 (default 1: one
    /// at a time); Modbus TCP only, for a DAQ whose server takes requests in flight.
    pub requests_in_flight: usize,
}

/// A SocketCAN interface with the DBC file that describes its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct CanSource {
    /// Unique among all sources.
    pub name: String,
    /// Kernel interface name, e.g. `can0` or `vcan0` (1..=15 bytes).
    pub interface: String,
    /// DBC file, resolved relative to the configuration file.
    pub dbc: PathBuf,
}

/// What a channel measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelKind {
    /// Shaft torque, kN*m.
    Torque,
    /// Vibration acceleration, m/s^2 (or g, as the unit says).
    Acceleration,
    /// A slow process value: speed, a "metal in stand" bit, ...
    ProcessValue,
}

impl ChannelKind {
    /// Every kind, in the order the documentation lists them.
    pub(crate) const ALL: [ChannelKind; 3] = [
        ChannelKind::Torque,
        ChannelKind::Acceleration,
        ChannelKind::ProcessValue,
    ];

    /// The spelling used in configuration files: `torque`, `acceleration`,
    /// `process_value`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            ChannelKind::Torque => "torque",
            ChannelKind::Acceleration => "acceleration",
            ChannelKind::ProcessValue => "process_value",
        }
    }
}

/// Modbus register table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegisterTable {
    /// Input registers, read with function code 04.
    Input,
    /// Holding registers, read with function code 03.
    Holding,
}

impl RegisterTable {
    /// Both tables.
    pub(crate) const ALL: [RegisterTable; 2] = [RegisterTable::Input, RegisterTable::Holding];

    /// The spelling used in configuration files: `input`, `holding`.
    pub fn name(self) -> &'static str {
        match self {
            RegisterTable::Input => "input",
            RegisterTable::Holding => "holding",
        }
    }
}

/// Type of a scalar process value in registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueType {
    /// Unsigned 16-bit, one register.
    U16,
    /// Signed 16-bit (two's complement), one register.
    I16,
    /// Unsigned 32-bit, two registers.
    U32,
    /// Signed 32-bit (two's complement), two registers.
    I32,
    /// IEEE 754 single precision, two registers.
    F32,
}

impl ValueType {
    /// Every type.
    pub(crate) const ALL: [ValueType; 5] = [
        ValueType::U16,
        ValueType::I16,
        ValueType::U32,
        ValueType::I32,
        ValueType::F32,
    ];

    /// The spelling used in configuration files: `u16`, `i16`, `u32`, `i32`, `f32`.
    pub fn name(self) -> &'static str {
        match self {
            ValueType::U16 => "u16",
            ValueType::I16 => "i16",
            ValueType::U32 => "u32",
            ValueType::I32 => "i32",
            ValueType::F32 => "f32",
        }
    }

    /// Number of 16-bit registers the value occupies.
    pub fn register_count(self) -> u16 {
        match self {
            ValueType::U16 | ValueType::I16 => 1,
            ValueType::U32 | ValueType::I32 | ValueType::F32 => 2,
        }
    }
}

/// Byte order of a 32-bit value in two registers, named by where bytes A (most
/// significant) to D (least significant) land: `ABCD` is big-endian words and
/// bytes (Modbus default), `CDAB` swaps words, `BADC` swaps bytes, `DCBA` both.
///
/// For 16-bit types (one register, bytes A and B) `BADC` and `DCBA` swap the two
/// bytes and `ABCD` and `CDAB` read the register as is (see [`crate::layout`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WordOrder {
    /// Big-endian words and bytes (the Modbus default).
    Abcd,
    /// Words swapped.
    Cdab,
    /// Bytes swapped in each word.
    Badc,
    /// Words and bytes swapped (little-endian).
    Dcba,
}

impl WordOrder {
    /// Every order.
    pub(crate) const ALL: [WordOrder; 4] = [
        WordOrder::Abcd,
        WordOrder::Cdab,
        WordOrder::Badc,
        WordOrder::Dcba,
    ];

    /// The spelling used in configuration files: `ABCD`, `CDAB`, `BADC`, `DCBA`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            WordOrder::Abcd => "ABCD",
            WordOrder::Cdab => "CDAB",
            WordOrder::Badc => "BADC",
            WordOrder::Dcba => "DCBA",
        }
    }
}

/// Where a channel's samples come from.
#[derive(Debug, Clone, PartialEq)]
pub enum ChannelSource {
    /// A block buffer in the millgate acquisition layout (see the README):
    /// `base+0` sequence, `base+1` count n, `base+2..base+2+n` i16 samples.
    ModbusBlock {
        /// Index into [`Config::modbus_sources`](crate::Config::modbus_sources).
        source: usize,
        /// Input or holding registers.
        table: RegisterTable,
        /// First register of the block, 0..=65414 (the block spans
        /// [`crate::layout::BLOCK_REGISTERS`] registers from here).
        base: u16,
    },
    /// A scalar process value in plain registers.
    ModbusValue {
        /// Index into [`Config::modbus_sources`](crate::Config::modbus_sources).
        source: usize,
        /// Input or holding registers.
        table: RegisterTable,
        /// First register of the value.
        address: u16,
        /// How the registers encode the value.
        value_type: ValueType,
        /// Where the value's bytes land in the registers.
        word_order: WordOrder,
    },
    /// A short ASCII text in plain registers (`type = "ascii"`), two characters per
    /// register: a coil or bar id ([`crate::text`]); allowed only as a context `coil`
    /// tag.
    ModbusText {
        /// Index into [`Config::modbus_sources`](crate::Config::modbus_sources).
        source: usize,
        /// Input or holding registers.
        table: RegisterTable,
        /// First register of the text.
        address: u16,
        /// Registers the text spans, 1..=[`crate::text::MAX_TEXT_REGISTERS`].
        registers: u16,
        /// Where the characters sit in each register.
        byte_order: crate::text::ByteOrder,
    },
    /// A signal of a CAN message described by the source's DBC file, resolved at
    /// load time. The DBC's factor and offset give the engineering value; the
    /// channel's own `scale`/`offset` are then 1 and 0.
    Can {
        /// Index into [`Config::can_sources`](crate::Config::can_sources).
        source: usize,
        /// Message name in the DBC.
        message: String,
        /// Signal name in the message.
        signal: String,
        /// Resolved from the DBC.
        signal_layout: crate::signal::SignalLayout,
    },
}

/// A measured channel. Engineering value = raw * scale + offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// Unique among channels.
    pub name: String,
    /// What the channel measures.
    pub kind: ChannelKind,
    /// Unit of the engineering value, e.g. `kN*m` (always `kN*m` for torque).
    pub unit: String,
    /// Engineering units per raw count; finite and non-zero (1 for CAN channels).
    pub scale: f64,
    /// Engineering value at raw 0 (0 for CAN channels).
    pub offset: f64,
    /// Nominal sample rate, Hz, > 0 (for register values: 1 / the source's poll period).
    pub sample_rate_hz: f64,
    /// Where the samples come from.
    pub source: ChannelSource,
}

impl Channel {
    /// Its counts to engineering values (`scale` and `offset`, decimal-exact).
    pub fn scaling(&self) -> crate::Scaling {
        crate::Scaling::new(self.scale, self.offset)
    }
}
