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
    pub(crate) name: String,
    pub(crate) address: Option<String>,
    pub(crate) device: Option<String>,
    pub(crate) baud_rate: Option<i64>,
    pub(crate) parity: Option<String>,
    pub(crate) data_bits: Option<i64>,
    pub(crate) stop_bits: Option<i64>,
    pub(crate) inter_frame_delay_us: Option<i64>,
    pub(crate) unit_id: Option<i64>,
    pub(crate) poll_period_ms: i64,
    pub(crate) timeout_ms: Option<i64>,
    pub(crate) requests_in_flight: Option<i64>,
}

/// `[[sources.can]]`: a SocketCAN interface and its DBC file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawCanSource {
    pub(crate) name: String,
    pub(crate) interface: String,
    pub(crate) dbc: String,
}

/// `[[channels]]`: one measured channel.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawChannel {
    pub(crate) name: String,
    pub(crate) kind: String,
    pub(crate) unit: String,
    pub(crate) scale: Option<f64>,
    pub(crate) offset: Option<f64>,
    pub(crate) sample_rate_hz: Option<f64>,
    pub(crate) source: RawChannelSource,
}

/// `channels[].source`: one inline table covering the three source forms; which keys
/// may appear together is checked in validation, with messages saying why.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawChannelSource {
    pub(crate) modbus: Option<String>,
    pub(crate) can: Option<String>,
    pub(crate) table: Option<String>,
    pub(crate) block: Option<i64>,
    pub(crate) address: Option<i64>,
    #[serde(rename = "type")]
    pub(crate) value_type: Option<String>,
    pub(crate) word_order: Option<String>,
    pub(crate) registers: Option<i64>,
    pub(crate) byte_order: Option<String>,
    pub(crate) message: Option<String>,
    pub(crate) signal: Option<String>,
}

/// `[[drivelines]]`: a hot-mill driveline.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDriveline {
    pub(crate) name: String,
    pub(crate) torque: String,
    pub(crate) metal_in_stand: Option<String>,
    pub(crate) extra_channels: Option<Vec<String>>,
    pub(crate) model: Option<String>,
    pub(crate) bite: RawBite,
    pub(crate) thresholds: RawThresholds,
    pub(crate) wear: Option<RawWear>,
    pub(crate) fatigue: Option<RawFatigue>,
    pub(crate) identification: Option<RawIdentification>,
    pub(crate) context: Option<RawContextTags>,
    pub(crate) pool_speed_range_mpm: Option<Vec<f64>>,
}

/// `identification`: a machine's nameplate (OPC 40001-1 `MachineIdentificationType`),
/// of the gateway (`[gateway.identification]`), a driveline or a mill.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawIdentification {
    pub(crate) manufacturer: Option<String>,
    pub(crate) manufacturer_uri: Option<String>,
    pub(crate) model: Option<String>,
    pub(crate) product_code: Option<String>,
    pub(crate) hardware_revision: Option<String>,
    pub(crate) serial_number: Option<String>,
    pub(crate) product_instance_uri: Option<String>,
    pub(crate) year_of_construction: Option<i64>,
    pub(crate) asset_id: Option<String>,
    pub(crate) location: Option<String>,
}

/// `[gateway]`: about the gateway itself.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawGateway {
    pub(crate) identification: Option<RawIdentification>,
}

/// `[analysis]`: how the analysis runs.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawAnalysis {
    pub(crate) workers: Option<i64>,
}

/// `drivelines[].fatigue`: the fatigue ledger.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawFatigue {
    pub(crate) gate_knm: Option<f64>,
    pub(crate) life_limit: Option<f64>,
    pub(crate) components: Vec<RawFatigueComponent>,
}

/// `drivelines[].fatigue.components[]`: one component's S-N curve.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawFatigueComponent {
    pub(crate) name: String,
    pub(crate) m: f64,
    pub(crate) ref_cycles: f64,
    pub(crate) ref_range_knm: f64,
    pub(crate) torque_share: Option<f64>,
    pub(crate) endurance_knm: Option<f64>,
    pub(crate) endurance_rule: Option<String>,
    pub(crate) ultimate_knm: Option<f64>,
}

/// `drivelines[].wear`: the gap diagnosis against the driveline model.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawWear {
    pub(crate) couplings: Option<Vec<i64>>,
    pub(crate) max_gap_mrad: Option<f64>,
    pub(crate) gap_step_mrad: Option<f64>,
    pub(crate) static_torque_knm: Option<Vec<f64>>,
    pub(crate) torque_points: Option<i64>,
    /// Deprecated (the gap is a wear trend over every bite since the last reset, not
    /// a pool of the last N): still accepted and checked (1..=1000) for one release,
    /// without effect.
    pub(crate) pool_bites: Option<i64>,
    pub(crate) horizon_days: Option<f64>,
    pub(crate) growth_span_s: Option<f64>,
}

/// `drivelines[].bite`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBite {
    pub(crate) threshold_knm: f64,
    pub(crate) pre_trigger_s: Option<f64>,
    pub(crate) post_trigger_s: Option<f64>,
}

/// `drivelines[].thresholds`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawThresholds {
    pub(crate) taf_warning: f64,
    pub(crate) taf_alarm: f64,
    pub(crate) gap_warning_mrad: Option<f64>,
    pub(crate) gap_alarm_mrad: Option<f64>,
}

/// `[[tandem_mills]]`: a tandem cold mill.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTandemMill {
    pub(crate) name: String,
    pub(crate) stands: Vec<String>,
    pub(crate) chatter_band_hz: Vec<f64>,
    pub(crate) window_s: f64,
    pub(crate) k_max: f64,
    pub(crate) detector: Option<String>,
    pub(crate) reference_band_hz: Option<Vec<f64>>,
    pub(crate) gain_window_s: Option<f64>,
    pub(crate) gain_thresholds: Option<Vec<f64>>,
    pub(crate) product_groups: Option<Vec<RawProductGroup>>,
    pub(crate) slow_down_release: Option<f64>,
    pub(crate) slow_down_hold_s: Option<f64>,
    pub(crate) weld_settle_s: Option<f64>,
    pub(crate) weld_alarm_factor: Option<f64>,
    pub(crate) context: Option<RawContextTags>,
    pub(crate) capture_before_s: Option<f64>,
    pub(crate) capture_after_s: Option<f64>,
    pub(crate) capture_max_s: Option<f64>,
    pub(crate) identification: Option<RawIdentification>,
}

/// `tandem_mills[].product_groups[]`: chatter thresholds for a group of products.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawProductGroup {
    pub(crate) name: String,
    pub(crate) products: Vec<i64>,
    pub(crate) gain_thresholds: Option<Vec<f64>>,
}

/// `tandem_mills[].context`: the process-context tags, each a process-value channel.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawContextTags {
    pub(crate) weld: Option<String>,
    pub(crate) weld_stands: Option<Vec<String>>,
    pub(crate) speed_mpm: Option<String>,
    pub(crate) coil: Option<String>,
    pub(crate) product: Option<String>,
    pub(crate) thickness_mm: Option<String>,
    pub(crate) pass: Option<String>,
    pub(crate) state: Option<String>,
    pub(crate) products: Option<Vec<i64>>,
}

/// `[[rod_mills]]`: a rod mill checked online against the Mathieu tongues.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawRodMill {
    pub(crate) name: String,
    pub(crate) mill: String,
    pub(crate) schedule: String,
    pub(crate) configuration: String,
    pub(crate) configurations: Vec<String>,
    pub(crate) pass: String,
    pub(crate) finishing_speed: String,
    pub(crate) temperature: Option<String>,
    pub(crate) near_tongue_m_s: Option<f64>,
    pub(crate) hysteresis_m_s: Option<f64>,
    pub(crate) temperature_step_c: Option<f64>,
    pub(crate) identification: Option<RawIdentification>,
}

/// `[outputs]`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawOutputs {
    pub(crate) driveline_slots: Option<i64>,
    pub(crate) plc: Option<RawPlcOutput>,
    pub(crate) server: Option<RawServerOutput>,
    pub(crate) metrics: Option<RawMetricsOutput>,
    pub(crate) mqtt: Option<RawMqttOutput>,
    pub(crate) web: Option<RawWebOutput>,
    pub(crate) opcua: Option<RawOpcUaOutput>,
}

/// `[outputs.opcua]`: the OPC UA server.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawOpcUaOutput {
    pub(crate) bind: Option<String>,
    pub(crate) host: Option<String>,
    pub(crate) security_modes: Option<Vec<String>>,
    pub(crate) pki_dir: Option<String>,
    pub(crate) anonymous: Option<bool>,
    pub(crate) users_file: Option<String>,
    pub(crate) allow_remote_commands: Option<bool>,
    pub(crate) max_connections: Option<i64>,
    pub(crate) max_sessions: Option<i64>,
    pub(crate) max_sessions_per_peer: Option<i64>,
    pub(crate) max_subscriptions_per_session: Option<i64>,
    pub(crate) max_monitored_items_per_subscription: Option<i64>,
    pub(crate) max_session_timeout_ms: Option<i64>,
}

/// `[outputs.plc]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawPlcOutput {
    pub(crate) address: String,
    pub(crate) unit_id: Option<i64>,
    pub(crate) register_base: Option<i64>,
    pub(crate) write_period_ms: i64,
    pub(crate) timeout_ms: Option<i64>,
    pub(crate) extension_blocks: Option<bool>,
    pub(crate) requests_in_flight: Option<i64>,
}

/// `[outputs.server]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawServerOutput {
    pub(crate) bind: String,
    pub(crate) unit_id: Option<i64>,
    pub(crate) max_connections: Option<i64>,
    pub(crate) max_connections_per_peer: Option<i64>,
    pub(crate) idle_timeout_ms: Option<i64>,
    pub(crate) allow_remote_commands: Option<bool>,
}

/// `[outputs.metrics]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMetricsOutput {
    pub(crate) bind: Option<String>,
}

/// `[outputs.web]`: the maintenance web page.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawWebOutput {
    pub(crate) bind: Option<String>,
    pub(crate) max_connections: Option<i64>,
    pub(crate) header_timeout_ms: Option<i64>,
    pub(crate) request_timeout_ms: Option<i64>,
    pub(crate) history_queries: Option<i64>,
    pub(crate) max_event_streams: Option<i64>,
    pub(crate) allowed_hosts: Option<Vec<String>>,
    pub(crate) allow_commands: Option<bool>,
}

/// `[outputs.mqtt]`: the Sparkplug B edge node.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMqttOutput {
    pub(crate) broker: Option<String>,
    pub(crate) brokers: Option<Vec<RawBroker>>,
    pub(crate) group_id: String,
    pub(crate) node_id: String,
    pub(crate) client_id: Option<String>,
    pub(crate) keep_alive_s: Option<i64>,
    pub(crate) data_period_ms: Option<i64>,
    pub(crate) command_qos: Option<i64>,
    pub(crate) primary_host_id: Option<String>,
    pub(crate) username: Option<String>,
    pub(crate) password: Option<String>,
    pub(crate) replay_batch: Option<i64>,
    pub(crate) replay_period_ms: Option<i64>,
    pub(crate) password_file: Option<String>,
    pub(crate) password_credential: Option<String>,
    pub(crate) tls: Option<RawMqttTls>,
}

/// An entry of `outputs.mqtt.brokers`: `"host:port"` (the shared TLS and
/// credentials), or a table with the server's own.
#[derive(Debug)]
pub(crate) enum RawBroker {
    /// `"host:port"`.
    Address(String),
    /// `{ address = "host:port", tls = {...}, username = ..., password_file = ... }`.
    Server(RawMqttServer),
}

impl RawBroker {
    /// The entry's `host:port`.
    pub(crate) fn address(&self) -> &str {
        match self {
            RawBroker::Address(address) => address,
            RawBroker::Server(server) => &server.address,
        }
    }
}

/// A string or a table, each read by its own rules, so a table's error names its key
/// (an untagged enum would only say that no variant matched).
impl<'de> Deserialize<'de> for RawBroker {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Entry;
        impl<'de> serde::de::Visitor<'de> for Entry {
            type Value = RawBroker;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(
                    "\"host:port\" or a table { address = \"host:port\", tls = { ... }, \
                     username = ..., password_file = ... }",
                )
            }
            fn visit_str<E: serde::de::Error>(self, address: &str) -> Result<RawBroker, E> {
                Ok(RawBroker::Address(address.to_owned()))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<RawBroker, A::Error> {
                RawMqttServer::deserialize(serde::de::value::MapAccessDeserializer::new(map))
                    .map(RawBroker::Server)
            }
        }
        deserializer.deserialize_any(Entry)
    }
}

/// A table entry of `outputs.mqtt.brokers`: the server's address, TLS and credentials.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMqttServer {
    pub(crate) address: String,
    pub(crate) username: Option<String>,
    pub(crate) password: Option<String>,
    pub(crate) password_file: Option<String>,
    pub(crate) password_credential: Option<String>,
    pub(crate) tls: Option<RawMqttTls>,
}

/// `[outputs.mqtt.tls]`: TLS to the broker.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMqttTls {
    pub(crate) ca_file: String,
    pub(crate) cert_file: Option<String>,
    pub(crate) key_file: Option<String>,
}

/// `[history]`: the event history file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawHistory {
    pub(crate) path: String,
    pub(crate) retention_days: Option<i64>,
    pub(crate) max_size_mb: Option<i64>,
    pub(crate) captures: Option<bool>,
    pub(crate) captures_max_mb: Option<i64>,
    pub(crate) captures_thin_after_days: Option<i64>,
    pub(crate) captures_keep_every: Option<i64>,
    pub(crate) synchronous: Option<String>,
}

/// The whole document after the schema pass. List elements that failed to
/// deserialize are absent, but then validation does not run (see [`crate::parse`]).
#[derive(Debug, Default)]
pub(crate) struct RawConfig {
    pub(crate) name: String,
    pub(crate) cache_dir: Option<String>,
    pub(crate) log_format: Option<String>,
    pub(crate) gateway: RawGateway,
    pub(crate) analysis: RawAnalysis,
    pub(crate) modbus_sources: Vec<RawModbusSource>,
    pub(crate) can_sources: Vec<RawCanSource>,
    pub(crate) channels: Vec<RawChannel>,
    pub(crate) drivelines: Vec<RawDriveline>,
    pub(crate) tandem_mills: Vec<RawTandemMill>,
    pub(crate) rod_mills: Vec<RawRodMill>,
    pub(crate) outputs: RawOutputs,
    pub(crate) history: Option<RawHistory>,
}
