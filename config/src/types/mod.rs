//! Validated configuration: what the rest of millgate sees.
//!
//! Everything here has been checked by [`crate::load`]: names are unique, references
//! resolve to indices, durations and rates are positive, and units are SI
//! (seconds, hertz) except torque, which stays in kN*m as in files and registers.

mod history;
mod identification;
mod mills;
mod outputs;
mod sources;

use std::path::PathBuf;

pub use history::{CaptureSettings, History, Synchronous};
pub use identification::{Identification, IdentificationField, IdentificationValue};
pub use mills::{
    BiteSettings, ChatterDetectorKind, ContextTags, Driveline, DrivelineThresholds,
    FatigueComponent, FatigueSettings, ProductGroup, RodMill, TandemMill, WearSettings,
};
pub use outputs::{
    MetricsOutput, MqttOutput, MqttSecurity, MqttTls, OpcUaOutput, OpcUaSecurityMode, OpcUaUser,
    Outputs, PlcOutput, ServerOutput, WebOutput, MAX_REQUESTS_IN_FLIGHT,
};
pub use sources::{
    CanSource, Channel, ChannelKind, ChannelSource, ModbusSource, RegisterTable, ValueType,
    WordOrder,
};

/// `log_format`: how the service writes its log lines on stderr (the journal).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LogFormat {
    /// `text`: one line per event, `LEVEL target: message key=value ...`.
    #[default]
    Text,
    /// `json`: one JSON object per line (`timestamp`, `level`, `target`, `fields`
    /// with the message and every key as a JSON value), for a log shipper.
    Json,
}

impl LogFormat {
    /// Both formats.
    pub const ALL: [Self; 2] = [Self::Text, Self::Json];

    /// The spelling in the file and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Text => "text",
            Self::Json => "json",
        }
    }
}

/// `[analysis]`: how the analysis runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AnalysisSettings {
    /// Threads that analyse the bites completing together (`workers`,
    /// [`Self::WORKERS_RANGE`]); 0 (the default) sizes the pool from the machine's
    /// cores.
    pub workers: usize,
}

impl AnalysisSettings {
    /// The allowed `workers`: 0 (one per core) to 64.
    pub const WORKERS_RANGE: std::ops::RangeInclusive<i64> = 0..=64;
}

/// A whole, validated millgate configuration, as returned by [`crate::load`].
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Plant or mill name, for logs and the HMI.
    pub name: String,
    /// The gateway's nameplate (`[gateway.identification]`, empty when left out).
    pub gateway_identification: Identification,
    /// Folder for files the gateway may rebuild (the wear maps): `cache_dir`, resolved
    /// against `$CACHE_DIRECTORY` when systemd sets it, else against the configuration
    /// file's folder; without `cache_dir`, `$CACHE_DIRECTORY`; `None` (neither): the
    /// user's cache folder (see the gateway).
    pub cache_dir: Option<PathBuf>,
    /// How `millgate run` writes its log lines (`log_format`, default `text`;
    /// `millgate run --log-format` overrides it).
    pub log_format: LogFormat,
    /// How the analysis runs (`[analysis]`).
    pub analysis: AnalysisSettings,
    /// Modbus DAQs and PLCs that the gateway polls, over TCP or a serial line (RTU).
    pub modbus_sources: Vec<ModbusSource>,
    /// SocketCAN interfaces.
    pub can_sources: Vec<CanSource>,
    /// Measured channels, in file order.
    pub channels: Vec<Channel>,
    /// Hot-mill drivelines analysed at each metal biting.
    pub drivelines: Vec<Driveline>,
    /// Tandem mills watched for chatter.
    pub tandem_mills: Vec<TandemMill>,
    /// Rod mills whose rod spans are checked against the Mathieu tongues online.
    pub rod_mills: Vec<RodMill>,
    /// Where results go.
    pub outputs: Outputs,
    /// The event history file; `None` keeps no history.
    pub history: Option<History>,
    /// SHA-256 (64 lower-case hex digits) of the file's canonical TOML: its tables
    /// with every key sorted, written back by `toml` (comments, blank lines, key order
    /// and number spelling do not count; a default written out does). The history
    /// stores it with each run and the capture exports carry it, so an export names
    /// the configuration that produced it (`millgate check --format json` prints it).
    pub hash: String,
}

impl Config {
    /// Driveline blocks the register map holds: `outputs.driveline_slots`, else the
    /// drivelines configured (the map's first layout). Never fewer than the drivelines.
    pub fn driveline_slots(&self) -> usize {
        self.outputs
            .driveline_slots
            .unwrap_or(0)
            .max(self.drivelines.len())
    }

    /// Index into [`Config::channels`] of the channel called `name`.
    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channels
            .iter()
            .position(|channel| channel.name == name)
    }

    /// Every source in the gateway's one source order: the Modbus sources, then the
    /// CAN sources, each in file order. Source `i` of this order is bit `i` of the
    /// status registers and the `i`-th source on `/metrics` and the web page.
    pub fn sources(&self) -> impl Iterator<Item = SourceRef<'_>> + '_ {
        self.modbus_sources
            .iter()
            .map(SourceRef::Modbus)
            .chain(self.can_sources.iter().map(SourceRef::Can))
    }

    /// The index in [`Self::sources`] of the source channel `channel` is read from.
    pub fn source_of_channel(&self, channel: usize) -> usize {
        match self.channels[channel].source {
            ChannelSource::ModbusBlock { source, .. }
            | ChannelSource::ModbusValue { source, .. }
            | ChannelSource::ModbusText { source, .. } => source,
            ChannelSource::Can { source, .. } => self.modbus_sources.len() + source,
        }
    }
}

/// A source in the order of [`Config::sources`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SourceRef<'a> {
    /// A Modbus device.
    Modbus(&'a ModbusSource),
    /// A SocketCAN interface.
    Can(&'a CanSource),
}

impl SourceRef<'_> {
    /// The source's name (unique among all sources).
    pub fn name(&self) -> &str {
        match self {
            SourceRef::Modbus(source) => &source.name,
            SourceRef::Can(source) => &source.name,
        }
    }

    /// `modbus` or `can`.
    pub fn kind(&self) -> &'static str {
        match self {
            SourceRef::Modbus(_) => "modbus",
            SourceRef::Can(_) => "can",
        }
    }
}
