//! Where results go: the PLC, the HMI server, MQTT (Sparkplug B), OPC UA, the web
//! page and `/metrics`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Where results go.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    /// Driveline blocks the register map reserves (`driveline_slots`, at least the
    /// drivelines configured; `None`: as many as there are drivelines, the map's first
    /// layout): a driveline added within them takes the next reserved block and moves
    /// no other address. Use [`crate::Config::driveline_slots`].
    pub driveline_slots: Option<usize>,
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
    /// TCP connections served at once, 1..=256 (default 16): a client address holds
    /// at most half, the last free one is kept for a new address, and when all are
    /// taken the connection idle longest (10 s at least) makes room; else a further
    /// one is closed at once.
    pub max_connections: usize,
    /// Sessions at once, 1..=100 (default 10).
    pub max_sessions: usize,
    /// Sessions one client address may hold on open connections,
    /// 1..=`max_sessions` (default half of `max_sessions`, rounded up); a further
    /// CreateSession from that address is answered `Bad_TooManySessions`.
    pub max_sessions_per_peer: usize,
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
    pub(crate) const DEFAULT_BIND: &'static str = "127.0.0.1:4840";
    /// Default `max_connections`.
    pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 16;
    /// Default `max_sessions`.
    pub(crate) const DEFAULT_MAX_SESSIONS: usize = 10;
    /// Default `max_sessions_per_peer` for `max_sessions`: half of them, rounded up
    /// (one address cannot take every session, as it cannot take every connection).
    pub(crate) const fn default_max_sessions_per_peer(max_sessions: usize) -> usize {
        max_sessions.div_ceil(2)
    }
    /// Default `max_subscriptions_per_session`.
    pub(crate) const DEFAULT_MAX_SUBSCRIPTIONS_PER_SESSION: usize = 10;
    /// Default `max_monitored_items_per_subscription`.
    pub(crate) const DEFAULT_MAX_MONITORED_ITEMS_PER_SUBSCRIPTION: usize = 1000;
    /// Default `max_session_timeout_ms`.
    pub(crate) const DEFAULT_MAX_SESSION_TIMEOUT_MS: u64 = 60_000;
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
            max_sessions_per_peer: Self::default_max_sessions_per_peer(Self::DEFAULT_MAX_SESSIONS),
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
    pub(crate) const ALL: [Self; 3] = [Self::None, Self::Sign, Self::SignAndEncrypt];

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
    pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 32;
    /// Default `header_timeout`, ms.
    pub(crate) const DEFAULT_HEADER_TIMEOUT_MS: u64 = 5_000;
    /// Default `request_timeout`, ms.
    pub(crate) const DEFAULT_REQUEST_TIMEOUT_MS: u64 = 10_000;
    /// Default `history_queries`.
    pub(crate) const DEFAULT_HISTORY_QUERIES: usize = 2;
    /// Default `max_event_streams`.
    pub(crate) const DEFAULT_MAX_EVENT_STREAMS: usize = 8;

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
    /// The MQTT servers, `host:port` each (port 1..=65535, resolved at connect time),
    /// 1..=16 of them, none twice: `brokers`, or the single `broker`. The node connects
    /// to the first that answers and, when a connection fails or a session ends, moves
    /// on to the next (after the last, the first again).
    pub brokers: Vec<String>,
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
    /// Per server of `brokers` (in its order), its TLS and credentials: a `"host:port"`
    /// entry has the shared `tls` and `credentials`; a table entry (`{ address = ...,
    /// tls = {...}, username = ..., password_file = ... }`) has its own, and only those
    /// (a table without `tls` is plain MQTT, one without `username` sends none).
    pub security: Vec<MqttSecurity>,
}

/// The TLS and credentials the edge node uses with one MQTT server.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MqttSecurity {
    /// TLS; plain MQTT without it.
    pub tls: Option<MqttTls>,
    /// User name and password.
    pub credentials: Option<(String, String)>,
}

/// `[outputs.mqtt.tls]`: the broker's certificate is checked against `ca_file`; with
/// `cert_file` and `key_file` the gateway also authenticates with a client
/// certificate. The files exist at load; their PEM content is read when the edge node
/// starts (errors name the key and the file).
#[derive(Debug, Clone, PartialEq)]
pub struct MqttTls {
    /// Its key in the configuration (`outputs.mqtt.tls`, `outputs.mqtt.brokers[1].tls`),
    /// for errors.
    pub key: String,
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
    /// FC 16 requests of one write sent before their answers came, 1..=16 (default 1:
    /// one at a time). More needs a PLC whose Modbus TCP server takes requests in
    /// flight on one connection (the implementation guide's
    /// `NumberMaxOfServerTransaction`); a write of many blocks then costs about one
    /// round trip instead of one per request.
    pub requests_in_flight: usize,
}

/// Most requests sent to one Modbus TCP device before their answers came (a PLC
/// write's, a DAQ poll's).
pub const MAX_REQUESTS_IN_FLIGHT: i64 = 16;

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
