//! The file format as written: serde structures mirroring the TOML, before any check.
//!
//! Every table denies unknown keys so that a misspelt key is an error naming it.
//! Integers are read as `i64`, floats as `f64` and enumerations as strings: range and
//! name checks happen in [`crate::validate`], which can then report every bad value
//! with the allowed range instead of stopping at serde's first type error.

use serde::Deserialize;

/// `[[sources.modbus]]`: a Modbus TCP device (`address`) or a Modbus RTU device on a
/// serial line (`device` and the line's settings).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawModbusSource {
    pub name: String,
    pub address: Option<String>,
    pub device: Option<String>,
    pub baud_rate: Option<i64>,
    pub parity: Option<String>,
    pub data_bits: Option<i64>,
    pub stop_bits: Option<i64>,
    pub inter_frame_delay_us: Option<i64>,
    pub unit_id: Option<i64>,
    pub poll_period_ms: i64,
    pub timeout_ms: Option<i64>,
}

/// `[[sources.can]]`: a SocketCAN interface and its DBC file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawCanSource {
    pub name: String,
    pub interface: String,
    pub dbc: String,
}

/// `[[channels]]`: one measured channel.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawChannel {
    pub name: String,
    pub kind: String,
    pub unit: String,
    pub scale: Option<f64>,
    pub offset: Option<f64>,
    pub sample_rate_hz: Option<f64>,
    pub source: RawChannelSource,
}

/// `channels[].source`: one inline table covering the three source forms; which keys
/// may appear together is checked in validation, with messages saying why.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawChannelSource {
    pub modbus: Option<String>,
    pub can: Option<String>,
    pub table: Option<String>,
    pub block: Option<i64>,
    pub address: Option<i64>,
    #[serde(rename = "type")]
    pub value_type: Option<String>,
    pub word_order: Option<String>,
    pub message: Option<String>,
    pub signal: Option<String>,
}

/// `[[drivelines]]`: a hot-mill driveline.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDriveline {
    pub name: String,
    pub torque: String,
    pub metal_in_stand: Option<String>,
    pub extra_channels: Option<Vec<String>>,
    pub model: Option<String>,
    pub bite: RawBite,
    pub thresholds: RawThresholds,
    pub wear: Option<RawWear>,
}

/// `drivelines[].wear`: the gap diagnosis against the driveline model.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawWear {
    pub couplings: Option<Vec<i64>>,
    pub max_gap_mrad: Option<f64>,
    pub gap_step_mrad: Option<f64>,
    pub static_torque_knm: Option<Vec<f64>>,
    pub torque_points: Option<i64>,
    pub pool_bites: Option<i64>,
}

/// `drivelines[].bite`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBite {
    pub threshold_knm: f64,
    pub pre_trigger_s: Option<f64>,
    pub post_trigger_s: Option<f64>,
}

/// `drivelines[].thresholds`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawThresholds {
    pub taf_warning: f64,
    pub taf_alarm: f64,
    pub gap_warning_mrad: Option<f64>,
    pub gap_alarm_mrad: Option<f64>,
}

/// `[[tandem_mills]]`: a tandem cold mill.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTandemMill {
    pub name: String,
    pub stands: Vec<String>,
    pub chatter_band_hz: Vec<f64>,
    pub window_s: f64,
    pub k_max: f64,
    pub detector: Option<String>,
    pub reference_band_hz: Option<Vec<f64>>,
    pub gain_window_s: Option<f64>,
    pub gain_thresholds: Option<Vec<f64>>,
    pub slow_down_release: Option<f64>,
    pub slow_down_hold_s: Option<f64>,
    pub capture_before_s: Option<f64>,
    pub capture_after_s: Option<f64>,
    pub capture_max_s: Option<f64>,
}

/// `[[rod_mills]]`: a rod mill checked online against the Mathieu tongues.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawRodMill {
    pub name: String,
    pub mill: String,
    pub schedule: String,
    pub configuration: String,
    pub configurations: Vec<String>,
    pub pass: String,
    pub finishing_speed: String,
    pub temperature: Option<String>,
    pub near_tongue_m_s: Option<f64>,
    pub hysteresis_m_s: Option<f64>,
    pub temperature_step_c: Option<f64>,
}

/// `[outputs]`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawOutputs {
    pub plc: Option<RawPlcOutput>,
    pub server: Option<RawServerOutput>,
    pub metrics: Option<RawMetricsOutput>,
    pub mqtt: Option<RawMqttOutput>,
    pub web: Option<RawWebOutput>,
    pub opcua: Option<RawOpcUaOutput>,
}

/// `[outputs.opcua]`: the OPC UA server.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawOpcUaOutput {
    pub bind: Option<String>,
    pub host: Option<String>,
    pub security_modes: Option<Vec<String>>,
    pub pki_dir: Option<String>,
    pub anonymous: Option<bool>,
    pub users_file: Option<String>,
    pub allow_remote_commands: Option<bool>,
    pub max_connections: Option<i64>,
    pub max_sessions: Option<i64>,
    pub max_subscriptions_per_session: Option<i64>,
    pub max_monitored_items_per_subscription: Option<i64>,
    pub max_session_timeout_ms: Option<i64>,
}

/// `[outputs.plc]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawPlcOutput {
    pub address: String,
    pub unit_id: Option<i64>,
    pub register_base: Option<i64>,
    pub write_period_ms: i64,
    pub timeout_ms: Option<i64>,
    pub extension_blocks: Option<bool>,
}

/// `[outputs.server]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawServerOutput {
    pub bind: String,
    pub unit_id: Option<i64>,
    pub max_connections: Option<i64>,
    pub max_connections_per_peer: Option<i64>,
    pub idle_timeout_ms: Option<i64>,
    pub allow_remote_commands: Option<bool>,
}

/// `[outputs.metrics]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMetricsOutput {
    pub bind: Option<String>,
}

/// `[outputs.web]`: the maintenance web page.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawWebOutput {
    pub bind: Option<String>,
    pub max_connections: Option<i64>,
    pub header_timeout_ms: Option<i64>,
    pub request_timeout_ms: Option<i64>,
    pub history_queries: Option<i64>,
    pub max_event_streams: Option<i64>,
    pub allowed_hosts: Option<Vec<String>>,
    pub allow_commands: Option<bool>,
}

/// `[outputs.mqtt]`: the Sparkplug B edge node.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMqttOutput {
    pub broker: String,
    pub group_id: String,
    pub node_id: String,
    pub client_id: Option<String>,
    pub keep_alive_s: Option<i64>,
    pub data_period_ms: Option<i64>,
    pub command_qos: Option<i64>,
    pub primary_host_id: Option<String>,
    pub username: Option<String>,
    pub password: Option<String>,
    pub replay_batch: Option<i64>,
    pub replay_period_ms: Option<i64>,
    pub password_file: Option<String>,
    pub password_credential: Option<String>,
    pub tls: Option<RawMqttTls>,
}

/// `[outputs.mqtt.tls]`: TLS to the broker.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMqttTls {
    pub ca_file: String,
    pub cert_file: Option<String>,
    pub key_file: Option<String>,
}

/// `[history]`: the event history file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawHistory {
    pub path: String,
    pub retention_days: Option<i64>,
    pub max_size_mb: Option<i64>,
    pub captures: Option<bool>,
    pub captures_max_mb: Option<i64>,
    pub captures_thin_after_days: Option<i64>,
    pub captures_keep_every: Option<i64>,
    pub synchronous: Option<String>,
}

/// The whole document after the schema pass. List elements that failed to
/// deserialize are absent, but then validation does not run (see [`crate::parse`]).
#[derive(Debug, Default)]
pub(crate) struct RawConfig {
    pub name: String,
    pub cache_dir: Option<String>,
    pub modbus_sources: Vec<RawModbusSource>,
    pub can_sources: Vec<RawCanSource>,
    pub channels: Vec<RawChannel>,
    pub drivelines: Vec<RawDriveline>,
    pub tandem_mills: Vec<RawTandemMill>,
    pub rod_mills: Vec<RawRodMill>,
    pub outputs: RawOutputs,
    pub history: Option<RawHistory>,
}
