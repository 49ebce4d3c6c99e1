//! Northbound: the gateway as a Sparkplug B edge node on an MQTT broker
//! (`[outputs.mqtt]`).
//!
//! - [`payload`]: the Sparkplug B protobuf messages (prost, written by hand).
//! - `devices`: the devices and their metrics, from the catalogue of figures.
//! - [`node`]: the edge node's messages and sequence numbers, without I/O.
//! - `status.rs`: the counters `/metrics` shows and why a connection failed;
//!   `store.rs`: the node's state in the history file (bdSeq, the bites, the cursor).
//! - `session.rs`: one session's state and what each MQTT event does to it;
//!   `outbox.rs`: what the node sends (births, bites, captures, data).
//! - The task ([`SparkplugNode::run`]): one MQTT session at a time with `rumqttc`.
//!   Before each connection it takes the next `bdSeq` from the history file
//!   ([`next_bd_seq`]) and sets the Will (NDEATH with that bdSeq); at the broker's
//!   CONNACK it subscribes to its NCMD topic and publishes NBIRTH and the DBIRTHs;
//!   then every bite as its own DDATA at once and the other changed values every
//!   `data_period`; an NCMD `Node Control/Rebirth` gets the births again, at most once
//!   per [`REBIRTH_INTERVAL`] (requests meanwhile are answered by one rebirth at its
//!   end). An NCMD that is retained (Sparkplug forbids it), larger than
//!   [`MAX_COMMAND_BYTES`] or undecodable is refused and counted, and the session goes
//!   on; the client reads packets up to [`MAX_INCOMING_PACKET`]. A larger one ends the
//!   session: rumqttc refuses a packet by its header and ends the connection, it cannot
//!   skip the packet. The next connection then waits twice as long as the last, up to
//!   a minute, and first clears any retained message on the node's NCMD topic (an
//!   empty retained publish, before it subscribes), so a retained oversized NCMD ends
//!   one session, not every one. On a clean
//!   stop it publishes its NDEATH before disconnecting. Births and data are QoS 0 and
//!   not retained, the Will QoS 1, as the specification asks.
//!
//! - With `primary_host_id`, it also subscribes to the host's STATE and sends no
//!   birth until the host is online; a STATE offline gets the NDEATH and ends the
//!   session (the next one, with the next bdSeq, waits for the host again).
//!
//! - Bites go from the history file, in order, each as its own DDATA at QoS 1; bites
//!   the broker did not acknowledge before a session ended, or recorded while the
//!   broker or the primary host was away, are replayed flagged historical after the
//!   next births, paced ([`forward`]).
//!
//! - With `[outputs.mqtt.tls]` the session runs over TLS (`tls`); username and
//!   password go in the CONNECT.
//!
//! - A server set (`brokers`): the node connects to the first server; a failed
//!   connection, a lost session or (with `primary_host_id`) the primary host offline
//!   on this server moves it on to the next, after the usual wait (after the last, the
//!   first again). Each session on another server is a new session: a new bdSeq and
//!   Will, new births, and the replay of what no server confirmed. TLS and credentials
//!   are shared by every server of the list, or a server's own (a table entry).

pub(crate) mod devices;
pub mod forward;
mod metrics;
pub mod node;
mod outbox;
pub mod payload;
mod session;
mod status;
mod store;
mod timers;
pub(crate) mod tls;

pub use status::{ConnectFailure, SparkplugCounts, SparkplugStatus};
pub use store::next_bd_seq;
pub use timers::REBIRTH_INTERVAL;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use millgate_config::MqttOutput;
use rumqttc::{LastWill, MqttOptions, QoS, TlsConfiguration, Transport};

use crate::shutdown::Shutdown;
use crate::state::board::Board;
use timers::RECONNECT_DELAY;

/// Requests the MQTT client queues for its event loop.
const CLIENT_QUEUE: usize = 256;
/// Bites handed to the client and not yet acknowledged, at most: below
/// [`CLIENT_QUEUE`], so the births and data of the session always find room.
const MAX_OUTSTANDING: usize = 192;
/// Largest MQTT packet the node reads, bytes (rumqttc's default, 10 KiB, let one
/// large NCMD end the session).
pub const MAX_INCOMING_PACKET: usize = 1 << 20;
/// Largest packet the node sends, bytes (rumqttc's default).
const MAX_OUTGOING_PACKET: usize = 10 * 1024;
/// Largest NCMD payload decoded, bytes (a Rebirth is about 40).
pub const MAX_COMMAND_BYTES: usize = 64 * 1024;

/// The edge node task.
#[derive(Debug)]
pub struct SparkplugNode {
    config: MqttOutput,
    history: PathBuf,
    board: Arc<Board>,
    status: Arc<SparkplugStatus>,
    /// Per server of the list, its TLS client configuration (`None`: plain MQTT).
    tls: Vec<Option<Arc<rustls::ClientConfig>>>,
    /// Rod mills: name and span count.
    rod_mills: Vec<(String, usize)>,
}

fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

impl SparkplugNode {
    /// The node of `config`, keeping its bdSeq in the history file `history`; fails
    /// when the TLS files of `config` cannot be used.
    pub fn new(
        config: MqttOutput,
        history: PathBuf,
        board: Arc<Board>,
    ) -> Result<Self, tls::TlsSetupError> {
        let tls = config
            .security
            .iter()
            .map(|security| security.tls.as_ref().map(tls::client_config).transpose())
            .collect::<Result<_, _>>()?;
        let status = Arc::new(SparkplugStatus::for_servers(config.brokers.clone()));
        Ok(Self {
            config,
            history,
            board,
            status,
            tls,
            rod_mills: Vec::new(),
        })
    }

    /// The node with these rod mills as devices: `(name, span count)` in config order
    /// (the span count from the mill file; it fixes the `span<i>` metrics at birth).
    pub(crate) fn with_rod_mills(mut self, rod_mills: Vec<(String, usize)>) -> Self {
        self.rod_mills = rod_mills;
        self
    }

    /// The counters, shared with `/metrics`.
    pub fn status(&self) -> Arc<SparkplugStatus> {
        Arc::clone(&self.status)
    }

    fn node_key(&self) -> String {
        format!("{}/{}", self.config.group_id, self.config.node_id)
    }

    /// The next bdSeq from the history file; `None` when the file cannot take it
    /// (logged as an error when `loud`, else at debug level).
    async fn stored_bd_seq(&self, loud: bool) -> Option<u8> {
        let (path, key) = (self.history.clone(), self.node_key());
        match tokio::task::spawn_blocking(move || next_bd_seq(&path, &key)).await {
            Ok(Ok(bd_seq)) => Some(bd_seq),
            Ok(Err(error)) if loud => {
                tracing::error!(%error, "Sparkplug bdSeq not read from the history file");
                None
            }
            Ok(Err(error)) => {
                tracing::debug!(%error, "Sparkplug bdSeq not read from the history file");
                None
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug bdSeq task failed");
                None
            }
        }
    }

    /// The next bdSeq; when the history file cannot take it, one more than `last`
    /// (logged: a host then may see a bdSeq repeat after a restart).
    async fn next_bd_seq(&self, last: u8) -> u8 {
        self.stored_bd_seq(true)
            .await
            .unwrap_or_else(|| last.wrapping_add(1))
    }

    /// `read` until it gives a value (every [`RECONNECT_DELAY`]; only the first
    /// failure is `loud`, logged as an error), `None` when `shutdown` came first: the
    /// session's first bdSeq and replay cursor come from the file, never from a
    /// default below what it holds.
    async fn from_file<T, F: std::future::Future<Output = Option<T>>>(
        shutdown: &mut Shutdown,
        mut read: impl FnMut(bool) -> F,
    ) -> Option<T> {
        let mut loud = true;
        loop {
            if let Some(value) = read(loud).await {
                return Some(value);
            }
            loud = false;
            tokio::select! {
                () = shutdown.recv() => return None,
                () = tokio::time::sleep(RECONNECT_DELAY) => {}
            }
        }
    }

    /// The connection to server `server` of the list, with `will` as the Will.
    fn options(&self, server: usize, will: node::Outgoing) -> MqttOptions {
        let server = server % self.config.brokers.len();
        let broker = self.config.brokers[server].as_str();
        let security = self.config.security.get(server);
        let (host, port) = broker
            .rsplit_once(':')
            .map(|(host, port)| (host.trim_matches(['[', ']']), port.parse().unwrap_or(1883)))
            .unwrap_or((broker, 1883));
        let mut options = MqttOptions::new(self.config.client_id.clone(), host, port);
        options.set_keep_alive(self.config.keep_alive);
        options.set_max_packet_size(MAX_INCOMING_PACKET, MAX_OUTGOING_PACKET);
        options.set_clean_session(true);
        options.set_last_will(LastWill::new(
            will.topic,
            will.payload,
            QoS::AtLeastOnce,
            false,
        ));
        if let Some((user, password)) = security.and_then(|s| s.credentials.as_ref()) {
            options.set_credentials(user.clone(), password.clone());
        }
        if let Some(config) = self.tls.get(server).and_then(Option::as_ref) {
            options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
                Arc::clone(config),
            )));
        }
        options
    }

    /// The stored replay cursor (the history's last bite for a new node); `None`
    /// when the file cannot be read (logged as an error when `loud`).
    async fn load_cursor(&self, loud: bool) -> Option<i64> {
        let (path, key) = (self.history.clone(), self.node_key());
        match tokio::task::spawn_blocking(move || forward::load_cursor(&path, &key)).await {
            Ok(Ok(cursor)) => Some(cursor),
            Ok(Err(error)) if loud => {
                tracing::error!(%error, "Sparkplug replay cursor not read from the history file");
                None
            }
            Ok(Err(error)) => {
                tracing::debug!(%error, "Sparkplug replay cursor not read from the history file");
                None
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug cursor task failed");
                None
            }
        }
    }
}
