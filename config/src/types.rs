//! Validated configuration: what the rest of millgate sees.
//!
//! Everything here has been checked by [`crate::load`]: names are unique, references
//! resolve to indices, durations and rates are positive, and units are SI
//! (seconds, hertz) except torque, which stays in kN*m as in files and registers.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// A whole, validated millgate configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Plant or mill name, for logs and the HMI.
    pub name: String,
    /// Modbus TCP DAQs and PLCs that the gateway polls.
    pub modbus_sources: Vec<ModbusSource>,
    /// SocketCAN interfaces.
    pub can_sources: Vec<CanSource>,
    /// Measured channels, in file order.
    pub channels: Vec<Channel>,
    /// Hot-mill drivelines analysed at each metal biting.
    pub drivelines: Vec<Driveline>,
    /// Tandem mills watched for chatter.
    pub tandem_mills: Vec<TandemMill>,
    /// Where results go.
    pub outputs: Outputs,
}

/// A Modbus TCP device polled by the gateway.
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusSource {
    pub name: String,
    /// `host:port`; resolved at connect time, so a DNS name is kept as written.
    pub address: String,
    /// Modbus unit identifier (slave id), 0..=255.
    pub unit_id: u8,
    /// Time between polls; must be shorter than a block period of its channels.
    pub poll_period: Duration,
    /// Time allowed for one request/response.
    pub timeout: Duration,
}

/// A SocketCAN interface with the DBC file that describes its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct CanSource {
    pub name: String,
    /// Kernel interface name, e.g. `can0` or `vcan0`.
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

/// Modbus register table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegisterTable {
    /// Input registers, read with function code 04.
    Input,
    /// Holding registers, read with function code 03.
    Holding,
}

/// Type of a scalar process value in registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueType {
    U16,
    I16,
    U32,
    I32,
    F32,
}

impl ValueType {
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
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WordOrder {
    Abcd,
    Cdab,
    Badc,
    Dcba,
}

/// Where a channel's samples come from.
#[derive(Debug, Clone, PartialEq)]
pub enum ChannelSource {
    /// A block buffer in the millgate acquisition layout (see the README):
    /// `base+0` sequence, `base+1` count n, `base+2..base+2+n` i16 samples.
    ModbusBlock {
        /// Index into [`Config::modbus_sources`].
        source: usize,
        table: RegisterTable,
        base: u16,
    },
    /// A scalar process value in plain registers.
    ModbusValue {
        /// Index into [`Config::modbus_sources`].
        source: usize,
        table: RegisterTable,
        address: u16,
        value_type: ValueType,
        word_order: WordOrder,
    },
    /// A signal of a CAN message described by the source's DBC file, resolved at
    /// load time. The DBC's factor and offset give the engineering value; the
    /// channel's own `scale`/`offset` are then 1 and 0.
    Can {
        /// Index into [`Config::can_sources`].
        source: usize,
        message: String,
        signal: String,
        /// Resolved from the DBC.
        signal_layout: crate::signal::SignalLayout,
    },
}

/// A measured channel. Engineering value = raw * scale + offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    pub name: String,
    pub kind: ChannelKind,
    /// Unit of the engineering value, e.g. `kN*m`.
    pub unit: String,
    pub scale: f64,
    pub offset: f64,
    /// Nominal sample rate, Hz (for process values: the poll rate).
    pub sample_rate_hz: f64,
    pub source: ChannelSource,
}

/// Bite detection settings of one driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteSettings {
    /// Rise above the tracked baseline that marks a bite, kN*m (> 0).
    pub threshold_knm: f64,
    /// Window kept before the trigger, s.
    pub pre_trigger_s: f64,
    /// Window captured after the trigger, s.
    pub post_trigger_s: f64,
}

/// A hot-mill driveline: one torque channel analysed at each bite.
#[derive(Debug, Clone, PartialEq)]
pub struct Driveline {
    pub name: String,
    /// Index into [`Config::channels`] of the torque channel.
    pub torque: usize,
    /// Index into [`Config::channels`] of an optional "metal in stand" trigger.
    pub metal_in_stand: Option<usize>,
    /// Optional driveline model file (sim model TOML), relative to the config file.
    pub model: Option<PathBuf>,
    pub bite: BiteSettings,
    pub thresholds: DrivelineThresholds,
}

/// Alarm thresholds of a driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrivelineThresholds {
    /// TAF above which the wear warning bit is set.
    pub taf_warning: f64,
    /// TAF above which the wear alarm bit is set (>= warning).
    pub taf_alarm: f64,
}

/// A tandem cold mill watched for chatter.
#[derive(Debug, Clone, PartialEq)]
pub struct TandemMill {
    pub name: String,
    /// Indices into [`Config::channels`] of the stands' vibration channels, in rolling order.
    pub stands: Vec<usize>,
    /// Chatter band, Hz: (low, high).
    pub chatter_band_hz: (f64, f64),
    /// Sliding analysis window, s.
    pub window_s: f64,
    /// K_max: largest adjacent-stand correlation seen in steady rolling (0..1).
    pub k_max: f64,
}

/// Where results go.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    /// PLC whose holding registers the gateway writes (FC 16).
    pub plc: Option<PlcOutput>,
    /// Modbus TCP server serving the same register map to HMIs.
    pub server: Option<ServerOutput>,
    /// Prometheus `/metrics` endpoint.
    pub metrics: Option<MetricsOutput>,
}

/// The PLC written by the gateway.
#[derive(Debug, Clone, PartialEq)]
pub struct PlcOutput {
    pub address: String,
    pub unit_id: u8,
    /// First holding register of the millgate map in the PLC.
    pub register_base: u16,
    pub write_period: Duration,
    pub timeout: Duration,
}

/// The gateway's own Modbus TCP server.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerOutput {
    pub bind: SocketAddr,
    pub unit_id: u8,
}

/// The Prometheus endpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsOutput {
    pub bind: SocketAddr,
}
