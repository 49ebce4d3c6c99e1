//! Validated configuration: what the rest of millgate sees.
//!
//! Everything here has been checked by [`crate::load`]: names are unique, references
//! resolve to indices, durations and rates are positive, and units are SI
//! (seconds, hertz) except torque, which stays in kN*m as in files and registers.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::SerialLine;

/// A whole, validated millgate configuration, as returned by [`crate::load`].
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Plant or mill name, for logs and the HMI.
    pub name: String,
    /// Folder for files the gateway may rebuild (the wear maps): `cache_dir`, resolved
    /// against `$CACHE_DIRECTORY` when systemd sets it, else against the configuration
    /// file's folder; without `cache_dir`, `$CACHE_DIRECTORY`; `None` (neither): the
    /// user's cache folder (see the gateway).
    pub cache_dir: Option<PathBuf>,
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
            | ChannelSource::ModbusValue { source, .. } => source,
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
    pub const ALL: [ChannelKind; 3] = [
        ChannelKind::Torque,
        ChannelKind::Acceleration,
        ChannelKind::ProcessValue,
    ];

    /// The spelling used in configuration files: `torque`, `acceleration`,
    /// `process_value`.
    pub fn name(self) -> &'static str {
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
    pub const ALL: [RegisterTable; 2] = [RegisterTable::Input, RegisterTable::Holding];

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
    pub const ALL: [ValueType; 5] = [
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
    pub const ALL: [WordOrder; 4] = [
        WordOrder::Abcd,
        WordOrder::Cdab,
        WordOrder::Badc,
        WordOrder::Dcba,
    ];

    /// The spelling used in configuration files: `ABCD`, `CDAB`, `BADC`, `DCBA`.
    pub fn name(self) -> &'static str {
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
        /// Index into [`Config::modbus_sources`].
        source: usize,
        /// Input or holding registers.
        table: RegisterTable,
        /// First register of the block, 0..=65414 (the block spans
        /// [`crate::layout::BLOCK_REGISTERS`] registers from here).
        base: u16,
    },
    /// A scalar process value in plain registers.
    ModbusValue {
        /// Index into [`Config::modbus_sources`].
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
    /// A signal of a CAN message described by the source's DBC file, resolved at
    /// load time. The DBC's factor and offset give the engineering value; the
    /// channel's own `scale`/`offset` are then 1 and 0.
    Can {
        /// Index into [`Config::can_sources`].
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

/// Bite detection settings of one driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteSettings {
    /// Rise above the tracked baseline that marks a bite, kN*m (> 0).
    pub threshold_knm: f64,
    /// Window kept before the trigger, s, 0..=10 (default 0.1).
    pub pre_trigger_s: f64,
    /// Window captured after the trigger, s, > 0 and <= 10 (default 0.5).
    pub post_trigger_s: f64,
}

/// A hot-mill driveline: one torque channel analysed at each bite.
#[derive(Debug, Clone, PartialEq)]
pub struct Driveline {
    /// Unique among drivelines.
    pub name: String,
    /// Index into [`Config::channels`] of the torque channel.
    pub torque: usize,
    /// Index into [`Config::channels`] of an optional "metal in stand" trigger.
    pub metal_in_stand: Option<usize>,
    /// Indices into [`Config::channels`] of other sampled channels kept in each bite's
    /// capture beside the torque (motor current, speed, ...): distinct, not the torque
    /// channel, block or CAN channels at the torque channel's sample rate.
    pub extra_channels: Vec<usize>,
    /// Optional driveline model file (sim model TOML), relative to the config file.
    pub model: Option<PathBuf>,
    /// Bite detection.
    pub bite: BiteSettings,
    /// TAF and gap warning and alarm.
    pub thresholds: DrivelineThresholds,
    /// The gap diagnosis against `model` (used only with a model).
    pub wear: WearSettings,
}

/// Alarm thresholds of a driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrivelineThresholds {
    /// TAF above which the TAF warning bit is set (> 1).
    pub taf_warning: f64,
    /// TAF above which the TAF alarm bit is set (>= warning).
    pub taf_alarm: f64,
    /// Estimated opened gap (maximum likelihood) at or above which the gap warning bit
    /// is set, mrad (> 0; default 2).
    pub gap_warning_mrad: f64,
    /// Opened gap whose 90% interval lies wholly at or above it sets the gap alarm
    /// bit (latched until acknowledged), mrad (>= `gap_warning_mrad`; default 4).
    pub gap_alarm_mrad: f64,
}

/// The gap diagnosis of a driveline with a model: which couplings may carry the gap,
/// the wear maps' grid and the pool of bites.
#[derive(Debug, Clone, PartialEq)]
pub struct WearSettings {
    /// Couplings (model indices, motor side first) that may carry the gap, distinct;
    /// `None`: every coupling of the model.
    pub couplings: Option<Vec<usize>>,
    /// Largest opened gap the maps cover, mrad, in (0, 100] (default 8).
    pub max_gap_mrad: f64,
    /// Gap step of the maps, mrad, > 0 with at most 400 steps up to `max_gap_mrad`
    /// (default 0.125).
    pub gap_step_mrad: f64,
    /// Static torque range the maps cover, kN*m, `0 < low < high`; `None`: from the
    /// model's static torque (0.25x to 2x, and at least 1.25x the bite threshold).
    pub static_torque_knm: Option<(f64, f64)>,
    /// Static torques of the maps' grid (geometric spacing over the range), 3..=64
    /// (default 16).
    pub torque_points: usize,
    /// Bites pooled into the gap estimate (the last N), 1..=1000 (default 20).
    pub pool_bites: usize,
}

impl Default for WearSettings {
    /// The defaults of a `[drivelines.wear]` table left out.
    fn default() -> Self {
        Self {
            couplings: None,
            max_gap_mrad: 8.0,
            gap_step_mrad: 0.125,
            static_torque_knm: None,
            torque_points: 16,
            pool_bites: 20,
        }
    }
}

impl DrivelineThresholds {
    /// Default gap warning threshold, mrad.
    pub const DEFAULT_GAP_WARNING_MRAD: f64 = 2.0;
    /// Default gap alarm threshold, mrad.
    pub const DEFAULT_GAP_ALARM_MRAD: f64 = 4.0;
}

/// A tandem cold mill watched for chatter.
#[derive(Debug, Clone, PartialEq)]
pub struct TandemMill {
    /// Unique among tandem mills.
    pub name: String,
    /// Indices into [`Config::channels`] of the stands' vibration channels, in rolling
    /// order; 2..=8 distinct acceleration channels sharing one sample rate.
    pub stands: Vec<usize>,
    /// Chatter band, Hz: (low, high), 0 < low < high < half of every stand's sample rate.
    pub chatter_band_hz: (f64, f64),
    /// Sliding analysis window, s, > 0 and <= 10.
    pub window_s: f64,
    /// K_max: largest adjacent-stand correlation seen in steady rolling (0..1).
    pub k_max: f64,
    /// Which detector raises the chatter alarm and the slow-down request.
    pub detector: ChatterDetectorKind,
    /// Reference band of the chatter-band gain, Hz: (low, high), above the chatter
    /// band (low >= its upper edge) and below half the sample rate. Default: 1.5 to 3
    /// times the chatter band's upper edge.
    pub reference_band_hz: (f64, f64),
    /// Window of the chatter-band gain, s, > 0 and <= 10 (default 2); the monitor
    /// checks it is 1..=16 hops of `window_s / 2`.
    pub gain_window_s: f64,
    /// Alarm threshold of the chatter-band gain per stand, in `stands` order, each
    /// finite and > 0 (from commissioning: the largest gain in stable rolling up to
    /// the highest allowed speed, plus a margin). Required with the band-gain
    /// detector; may be empty with the paper's (no gain ratio is then published).
    pub gain_thresholds: Vec<f64>,
    /// The slow-down request clears once the alarm figure (the gain ratio, or for the
    /// paper's detector the synchronization) has stayed below this fraction of its
    /// alarm level for `slow_down_hold_s`; > 0 and < 1 (default 0.8).
    pub slow_down_release: f64,
    /// Time the alarm figure must stay below the release level before the slow-down
    /// request clears, s, >= 0 and <= 600 (default 5).
    pub slow_down_hold_s: f64,
    /// Chatter-episode captures (with `[history]`): stand samples kept before the
    /// warning is raised, s, >= 0 and <= 60 (default 5).
    pub capture_before_s: f64,
    /// Stand samples kept after the warning clears, s, >= 0 and <= 60 (default 2).
    pub capture_after_s: f64,
    /// Longest chatter-episode capture, s, > `capture_before_s` and <= 600 (default
    /// 120): a longer episode's capture is cut there and says so.
    pub capture_max_s: f64,
}

/// The chatter detector that raises a tandem mill's alarm (`detector` key).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChatterDetectorKind {
    /// `"band_gain"` (the default): chatter-band RMS over reference-band RMS per stand
    /// against `gain_thresholds`; the detector that warned earliest at zero false
    /// alarms in the tandem-model race (`tests/src/chatter_eval.rs`).
    #[default]
    BandGain,
    /// `"paper"`: the synchronization conditions (sigma_n <= sigma_min and K_mean >=
    /// K_max); in the race they fired before developed chatter in 38 of 60 ramps.
    Paper,
}

/// A rod (wire) mill whose rod spans are checked online against the Mathieu
/// instability tongues, from PLC process values (`[[rod_mills]]`).
#[derive(Debug, Clone, PartialEq)]
pub struct RodMill {
    /// Unique among rod mills.
    pub name: String,
    /// Rod-mill file (`millgate-sim` rod mill TOML: drive, stands, spans, modulus
    /// table), relative to the config file; its content is checked by the service.
    pub mill: PathBuf,
    /// Pass schedule CSV (rod diameters and temperature per pass), relative to the
    /// config file.
    pub schedule: PathBuf,
    /// Index into [`Config::channels`] of the process value carrying the active drive
    /// configuration: value k (an integer 0..configurations.len()) selects
    /// `configurations[k]`.
    pub configuration: usize,
    /// Drive configuration names (of the mill's drive) by PLC value, 1..=64 names.
    pub configurations: Vec<String>,
    /// Index into [`Config::channels`] of the process value carrying the pass number:
    /// k (1-based) selects the k-th row of the schedule.
    pub pass: usize,
    /// Index into [`Config::channels`] of the finishing speed, m/s (rod speed out of
    /// the last stand).
    pub finishing_speed: usize,
    /// Index into [`Config::channels`] of the rod temperature, deg C; without it the
    /// schedule's temperature of the pass is used.
    pub temperature: Option<usize>,
    /// A stable span whose speed margin is below this is "near a tongue", m/s, > 0
    /// (default 2).
    pub near_tongue_m_s: f64,
    /// Speed hysteresis of the unstable and near-tongue flags, m/s, >= 0 (default
    /// 0.5): a flag clears only once the margin is this much beyond where it was set.
    pub hysteresis_m_s: f64,
    /// Rod temperature step, deg C, > 0 (default 10): the measured temperature is
    /// rounded to a multiple of it before the pass's setup is (re)computed.
    pub temperature_step_c: f64,
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
    /// Sparkplug B edge node on an MQTT broker.
    pub mqtt: Option<MqttOutput>,
    /// The maintenance web page and its JSON API.
    pub web: Option<WebOutput>,
    /// The OPC UA server.
    pub opcua: Option<OpcUaOutput>,
}

/// The OPC UA server (`[outputs.opcua]`): the results as an address space, alarms as
/// events, an acknowledge method.
#[derive(Debug, Clone, PartialEq)]
pub struct OpcUaOutput {
    /// Address to listen on (default `127.0.0.1:4840`); port 0 picks a free port.
    pub bind: SocketAddr,
    /// Host name or IP address clients reach the server at: written into the
    /// endpoint URL (`opc.tcp://<host>:<port>/`) and the server certificate. Default:
    /// the `bind` address; required with a wildcard `bind` (0.0.0.0, `[::]`).
    pub host: String,
    /// Security modes offered, each an endpoint (default `none` on a loopback bind,
    /// `sign` and `sign_and_encrypt` otherwise); signing uses Basic256Sha256.
    pub security_modes: Vec<OpcUaSecurityMode>,
    /// The server's certificate store: `own/cert.der` and `private/private.pem`
    /// (created at the first start), `trusted/` (client certificates accepted),
    /// `rejected/` (client certificates refused, to be moved to `trusted/`).
    pub pki_dir: PathBuf,
    /// Whether anonymous sessions are accepted (default true).
    pub anonymous: bool,
    /// Users who may sign in with a password, from `users_file` (read at load).
    pub users: Vec<OpcUaUser>,
    /// Whether clients on other hosts may call the acknowledge method (default false:
    /// only loopback clients may; with true, a remote client must also sign in as a
    /// user of `users_file`).
    pub allow_remote_commands: bool,
    /// TCP connections served at once, 1..=256 (default 16); a further one is closed
    /// at once.
    pub max_connections: usize,
    /// Sessions at once, 1..=100 (default 10).
    pub max_sessions: usize,
    /// Subscriptions per session, 1..=100 (default 10).
    pub max_subscriptions_per_session: usize,
    /// Monitored items per subscription, 1..=100000 (default 1000).
    pub max_monitored_items_per_subscription: usize,
    /// Longest session timeout a client may ask for, 1000..=3600000 ms (default
    /// 60000 ms); a session idle for its timeout is closed.
    pub max_session_timeout: Duration,
}

impl OpcUaOutput {
    /// Default `bind`.
    pub const DEFAULT_BIND: &'static str = "127.0.0.1:4840";
    /// Default `max_connections`.
    pub const DEFAULT_MAX_CONNECTIONS: usize = 16;
    /// Default `max_sessions`.
    pub const DEFAULT_MAX_SESSIONS: usize = 10;
    /// Default `max_subscriptions_per_session`.
    pub const DEFAULT_MAX_SUBSCRIPTIONS_PER_SESSION: usize = 10;
    /// Default `max_monitored_items_per_subscription`.
    pub const DEFAULT_MAX_MONITORED_ITEMS_PER_SUBSCRIPTION: usize = 1000;
    /// Default `max_session_timeout_ms`.
    pub const DEFAULT_MAX_SESSION_TIMEOUT_MS: u64 = 60_000;
    /// Folder name of the default `pki_dir` (under `$STATE_DIRECTORY`, beside the
    /// history file, or beside the configuration file).
    pub const DEFAULT_PKI_FOLDER: &'static str = "opcua-pki";

    /// The server on `bind` with `pki_dir`, anonymous access, security mode `none` and
    /// the defaults of every other key (tests, the demo).
    pub fn on(bind: SocketAddr, pki_dir: PathBuf) -> Self {
        Self {
            bind,
            host: bind.ip().to_string(),
            security_modes: vec![OpcUaSecurityMode::None],
            pki_dir,
            anonymous: true,
            users: Vec::new(),
            allow_remote_commands: false,
            max_connections: Self::DEFAULT_MAX_CONNECTIONS,
            max_sessions: Self::DEFAULT_MAX_SESSIONS,
            max_subscriptions_per_session: Self::DEFAULT_MAX_SUBSCRIPTIONS_PER_SESSION,
            max_monitored_items_per_subscription:
                Self::DEFAULT_MAX_MONITORED_ITEMS_PER_SUBSCRIPTION,
            max_session_timeout: Duration::from_millis(Self::DEFAULT_MAX_SESSION_TIMEOUT_MS),
        }
    }

    /// The endpoint URL clients connect to: `opc.tcp://<host>:<port>/` (an IPv6 host in
    /// brackets).
    pub fn endpoint_url(&self) -> String {
        let host = match self.host.parse::<std::net::Ipv6Addr>() {
            Ok(_) => format!("[{}]", self.host),
            Err(_) => self.host.clone(),
        };
        format!("opc.tcp://{host}:{}/", self.bind.port())
    }
}

/// An OPC UA endpoint's message security mode (`security_modes`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OpcUaSecurityMode {
    /// `none`: neither signed nor encrypted (loopback, or a closed cell network).
    None,
    /// `sign`: Basic256Sha256, signed.
    Sign,
    /// `sign_and_encrypt`: Basic256Sha256, signed and encrypted.
    SignAndEncrypt,
}

impl OpcUaSecurityMode {
    /// Every mode, in the order endpoints are listed.
    pub const ALL: [Self; 3] = [Self::None, Self::Sign, Self::SignAndEncrypt];

    /// The spelling in the file.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Sign => "sign",
            Self::SignAndEncrypt => "sign_and_encrypt",
        }
    }
}

/// A user of the OPC UA server (a line `name:password` of `users_file`).
#[derive(Clone, PartialEq, Eq)]
pub struct OpcUaUser {
    /// User name, 1..=64 characters, no `:`.
    pub name: String,
    /// Password, not empty.
    pub password: String,
}

impl std::fmt::Debug for OpcUaUser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaUser")
            .field("name", &self.name)
            .field("password", &"****")
            .finish()
    }
}

/// The maintenance web page and its JSON API (read-only HTTP/1.1).
#[derive(Debug, Clone, PartialEq)]
pub struct WebOutput {
    /// Address to listen on (default `127.0.0.1:8080`); port 0 picks a free port.
    pub bind: SocketAddr,
    /// Connections served at once, 1..=1024 (default 32); a further connection waits
    /// in the listen backlog until one closes. Each open page holds one for its live
    /// updates.
    pub max_connections: usize,
    /// Time a client has to send a request's headers, counted from the connection's
    /// start or the previous response, 100..=60000 ms (default 5000 ms); a slower
    /// connection is closed.
    pub header_timeout: Duration,
    /// Time allowed to answer one request (the history queries), 100..=60000 ms
    /// (default 10000 ms); past it the answer is 503. Live updates
    /// (`/api/events`) are not bounded by it; a query past it is interrupted.
    pub request_timeout: Duration,
    /// History queries run at once, 1..=8 (default 2), each on a thread of its own
    /// at the lowest CPU priority; a further request waits up to a second for one,
    /// then is answered 503 with `Retry-After`.
    pub history_queries: usize,
    /// Live-update streams (`/api/events`) open at once, 1..=`max_connections`
    /// (default 8; at most `max_connections - 1` when that is above 1); a further one is answered 503.
    pub max_event_streams: usize,
    /// Host names the page answers to besides IP addresses and `localhost` (a request
    /// naming another host in its `Host` header is refused 421: DNS rebinding);
    /// default none. Lower case, letters, digits, `-` and `.`.
    pub allowed_hosts: Vec<String>,
    /// Whether `POST /api/captures` takes manual-capture requests (default false:
    /// the page and its API are read-only, and the request is refused 403).
    pub allow_commands: bool,
}

impl WebOutput {
    /// Default `max_connections`.
    pub const DEFAULT_MAX_CONNECTIONS: usize = 32;
    /// Default `header_timeout`, ms.
    pub const DEFAULT_HEADER_TIMEOUT_MS: u64 = 5_000;
    /// Default `request_timeout`, ms.
    pub const DEFAULT_REQUEST_TIMEOUT_MS: u64 = 10_000;
    /// Default `history_queries`.
    pub const DEFAULT_HISTORY_QUERIES: usize = 2;
    /// Default `max_event_streams`.
    pub const DEFAULT_MAX_EVENT_STREAMS: usize = 8;

    /// The page on `bind` with the defaults of every other key.
    pub fn on(bind: SocketAddr) -> Self {
        Self {
            bind,
            max_connections: Self::DEFAULT_MAX_CONNECTIONS,
            header_timeout: Duration::from_millis(Self::DEFAULT_HEADER_TIMEOUT_MS),
            request_timeout: Duration::from_millis(Self::DEFAULT_REQUEST_TIMEOUT_MS),
            history_queries: Self::DEFAULT_HISTORY_QUERIES,
            max_event_streams: Self::DEFAULT_MAX_EVENT_STREAMS,
            allowed_hosts: Vec::new(),
            allow_commands: false,
        }
    }
}

/// The Sparkplug B edge node: the gateway publishes its drivelines and tandem mills
/// as devices to an MQTT broker (`spBv1.0/<group_id>/.../<node_id>[/<device>]`).
#[derive(Debug, Clone, PartialEq)]
pub struct MqttOutput {
    /// Broker `host:port`, port 1..=65535; resolved at connect time.
    pub broker: String,
    /// Sparkplug group id: non-empty, none of `/ + #`.
    pub group_id: String,
    /// Sparkplug edge node id: non-empty, none of `/ + #`.
    pub node_id: String,
    /// MQTT client id (default `millgate-<group_id>-<node_id>`), 1..=64 characters.
    pub client_id: String,
    /// MQTT keep-alive, 5..=3600 s (default 30 s).
    pub keep_alive: Duration,
    /// Longest time between a change of a value and its DDATA, 1..=60000 ms
    /// (default 1000 ms); bites are published at once.
    pub data_period: Duration,
    /// QoS of the NCMD subscription (commands from hosts), 0 or 1 (default 1).
    pub command_qos: u8,
    /// The primary host application's id: no births until its STATE
    /// (`spBv1.0/STATE/<id>`) says online; offline ends the session. Same rules as
    /// `group_id`.
    pub primary_host_id: Option<String>,
    /// User name and password for the broker, both or neither; the password from
    /// `password`, or read at load from `password_file` or from the systemd credential
    /// `password_credential` (one trailing newline dropped).
    pub credentials: Option<(String, String)>,
    /// Store-and-forward: bites replayed from the history per `replay_period`,
    /// 1..=100000 (default 100).
    pub replay_batch: u32,
    /// Store-and-forward: the period of one replay batch, 1..=60000 ms (default
    /// 100 ms); the defaults replay 1000 bites/s.
    pub replay_period: Duration,
    /// TLS to the broker (`[outputs.mqtt.tls]`); plain MQTT without it.
    pub tls: Option<MqttTls>,
}

/// `[outputs.mqtt.tls]`: the broker's certificate is checked against `ca_file`; with
/// `cert_file` and `key_file` the gateway also authenticates with a client
/// certificate. The files exist at load; their PEM content is read when the edge node
/// starts (errors name the key and the file).
#[derive(Debug, Clone, PartialEq)]
pub struct MqttTls {
    /// PEM file of the certificate authorities trusted for the broker, relative to the
    /// configuration file.
    pub ca_file: PathBuf,
    /// Client certificate (PEM chain) and its private key (PEM: PKCS#8, PKCS#1 or
    /// SEC1), both or neither.
    pub client: Option<(PathBuf, PathBuf)>,
}

/// The PLC written by the gateway.
#[derive(Debug, Clone, PartialEq)]
pub struct PlcOutput {
    /// `host:port`, port 1..=65535; resolved at connect time.
    pub address: String,
    /// Modbus unit identifier, 0..=255 (default 1).
    pub unit_id: u8,
    /// First holding register of the millgate map in the PLC (default 0).
    pub register_base: u16,
    /// Time between writes of the whole map, 1..=60000 ms (a change is written at once,
    /// as the blocks that changed).
    pub write_period: Duration,
    /// Time allowed for one write, 1..=60000 ms (default 1000 ms).
    pub timeout: Duration,
    /// Whether the extension blocks (the figures added since the map's first layout,
    /// after every block) are written too (default false: a PLC whose area was sized
    /// for the first layout gets exactly what it got before).
    pub extension_blocks: bool,
}

/// The gateway's own Modbus TCP server.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerOutput {
    /// Address to listen on; port 0 picks a free port.
    pub bind: SocketAddr,
    /// Unit identifier the server answers to, 1..=255 (default 1); requests to unit
    /// 255 are answered too, requests to unit 0 (broadcast) never.
    pub unit_id: u8,
    /// Clients served at once, 1..=64 (default 8). A further connection takes the
    /// place of the connection idle longest (one that never sent a request first); it
    /// is closed at once only when every connection is inside a request.
    pub max_connections: usize,
    /// Connections one client address may hold, 1..=`max_connections` (default 4,
    /// or `max_connections` when smaller); a further one from that address takes the
    /// place of its own connection idle longest.
    pub max_connections_per_peer: usize,
    /// A connection without a request for this long is closed, 100..=3600000 ms
    /// (default 60000 ms).
    pub idle_timeout: Duration,
    /// Whether clients on other hosts may write the command registers (default
    /// false: only loopback clients may; others get exception 01).
    pub allow_remote_commands: bool,
}

/// The Prometheus endpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsOutput {
    /// Address to listen on (default `127.0.0.1:9187`).
    pub bind: SocketAddr,
}

/// The event history: one SQLite file per gateway holding every bite, wear estimate,
/// alarm, chatter episode, source outage and start and stop, and the state restored
/// at the next start.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    /// The SQLite file; a relative `path` resolved against `$STATE_DIRECTORY` when
    /// systemd sets it, else against the configuration file's folder; its folder exists.
    pub path: PathBuf,
    /// Events older than this are deleted, 1..=36500 days (default 400).
    pub retention_days: u32,
    /// Largest size of the file's data before the oldest events are deleted,
    /// 1..=1048576 MiB (default 1024).
    pub max_size_mb: u32,
    /// The captures (bite windows, chatter episodes, manual) kept in the file.
    pub captures: CaptureSettings,
    /// When a commit counts as durable (`synchronous`, default `normal`).
    pub synchronous: Synchronous,
}

/// `history.synchronous`: how far a commit is on disk before the PLC sees what it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Synchronous {
    /// `normal`: a commit is in the operating system's write-ahead log file, synced at
    /// each checkpoint: it survives a crash or kill of the gateway, but a power cut may
    /// lose the last commits since the last checkpoint (SQLite's WAL with
    /// `synchronous=NORMAL`).
    #[default]
    Normal,
    /// `full`: every commit is synced to the disk before it counts (`synchronous=FULL`):
    /// a power cut loses nothing committed, at the cost of an `fsync` per commit.
    Full,
}

impl Synchronous {
    /// Both settings.
    pub const ALL: [Self; 2] = [Self::Normal, Self::Full];

    /// The spelling in the file (and SQLite's name of the pragma's value).
    pub fn name(self) -> &'static str {
        match self {
            Self::Normal => "normal",
            Self::Full => "full",
        }
    }
}

/// `[history]`'s capture keys: whether the samples behind each bite are kept, and the
/// budget they are kept within.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureSettings {
    /// Keep captures at all (default true).
    pub enabled: bool,
    /// Largest size of the captures' samples, 1..=`max_size_mb` / 2 MiB (default
    /// `max_size_mb` / 2): past it the oldest ordinary bites' captures go first, those of
    /// warning bites next, the important ones (alarm bites) last.
    pub max_mb: u32,
    /// Ordinary bites' captures older than this are thinned to every
    /// `keep_every`-th bite, 1..=36500 days (default 7).
    pub thin_after_days: u32,
    /// After `thin_after_days`, an ordinary bite's capture is kept when its bite
    /// counter is a multiple of this, 1..=1000 (default 10; 1 keeps all).
    pub keep_every: u32,
}

impl CaptureSettings {
    /// The defaults for a file of `max_size_mb` MiB.
    pub fn defaults(max_size_mb: u32) -> Self {
        Self {
            enabled: true,
            max_mb: (max_size_mb / 2).max(1),
            thin_after_days: 7,
            keep_every: 10,
        }
    }
}
