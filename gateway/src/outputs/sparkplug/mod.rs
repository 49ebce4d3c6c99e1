//! Northbound: the gateway as a Sparkplug B edge node on an MQTT broker
//! (`[outputs.mqtt]`).
//!
//! - [`payload`]: the Sparkplug B protobuf messages (prost, written by hand).
//! - [`node`]: the edge node's messages and sequence numbers, without I/O.
//! - The task ([`SparkplugNode::run`]): one MQTT session at a time with `rumqttc`.
//!   Before each connection it takes the next `bdSeq` from the history file
//!   ([`next_bd_seq`]) and sets the Will (NDEATH with that bdSeq); at the broker's
//!   CONNACK it subscribes to its NCMD topic and publishes NBIRTH and the DBIRTHs;
//!   then every bite as its own DDATA at once and the other changed values every
//!   `data_period`; an NCMD `Node Control/Rebirth` gets the births again. On a clean
//!   stop it publishes its NDEATH before disconnecting. Births and data are QoS 0 and
//!   not retained, the Will QoS 1, as the specification asks.
//!
//! - With `primary_host_id`, it also subscribes to the host's STATE and sends no
//!   birth until the host is online; a STATE offline gets the NDEATH and ends the
//!   session (the next one, with the next bdSeq, waits for the host again).
//!
//! - With `[outputs.mqtt.tls]` the session runs over TLS ([`tls`]); username and
//!   password go in the CONNECT.
//!
//! Not yet (issue 19): store-and-forward from the history.

pub mod node;
pub mod payload;
pub mod tls;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::MqttOutput;
use rumqttc::{
    AsyncClient, ConnectReturnCode, ConnectionError, Event, EventLoop, LastWill, MqttOptions,
    Packet, QoS, TlsConfiguration, Transport,
};

use crate::outputs::history::writer::connect;
use crate::outputs::history::HistoryError;
use crate::outputs::publisher::Publisher;
use crate::shutdown::Shutdown;
use node::EdgeNode;

/// How often the results are looked at for a new bite.
const BITE_POLL: Duration = Duration::from_millis(20);
/// Wait before connecting again after a failed connection.
const RECONNECT_DELAY: Duration = Duration::from_secs(1);
/// Requests the MQTT client queues for its event loop.
const CLIENT_QUEUE: usize = 256;

/// The next session number of `node` (`group_id/node_id`) in the history file at
/// `path`: the last one plus one, modulo 256 (0 for a new node); stored before it is
/// returned, so the Will and the NBIRTH of the next session always carry a new one.
pub fn next_bd_seq(path: &Path, node: &str) -> Result<u8, HistoryError> {
    let connection = connect(path)?;
    let bd_seq: i64 = connection
        .query_row(
            "INSERT INTO sparkplug_node (node, bd_seq, updated_at) VALUES (?1, 0, ?2)
             ON CONFLICT (node) DO UPDATE SET bd_seq = (bd_seq + 1) % 256,
                 updated_at = excluded.updated_at
             RETURNING bd_seq",
            rusqlite::params![
                node,
                crate::outputs::history::time::UtcTime::now().to_string()
            ],
            |row| row.get(0),
        )
        .map_err(|source| HistoryError::Sqlite {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(u8::try_from(bd_seq).unwrap_or(0))
}

/// Why a connection to the broker failed (the log and `/metrics` say which).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConnectFailure {
    /// No answer, connection refused by the host, or the session broke off.
    Unreachable,
    /// The TLS handshake failed (an unknown CA, a name mismatch, a certificate the
    /// broker does not accept).
    Tls,
    /// The broker refused the user name and password or the client.
    NotAuthorised,
    /// The broker refused the connection for another reason.
    Refused,
}

impl ConnectFailure {
    /// Every kind, in the order of [`SparkplugCounts::failures`].
    pub const ALL: [Self; 4] = [
        Self::Unreachable,
        Self::Tls,
        Self::NotAuthorised,
        Self::Refused,
    ];

    /// The label on `/metrics`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Unreachable => "unreachable",
            Self::Tls => "tls",
            Self::NotAuthorised => "not_authorised",
            Self::Refused => "refused",
        }
    }

    /// The kind of `error`.
    pub fn of(error: &ConnectionError) -> Self {
        match error {
            ConnectionError::Tls(_) => Self::Tls,
            // A TLS alert after the handshake (TLS 1.3 reports a refused client
            // certificate there) comes as an I/O error holding the rustls error.
            ConnectionError::Io(io) if io.get_ref().is_some_and(|e| e.is::<rustls::Error>()) => {
                Self::Tls
            }
            ConnectionError::ConnectionRefused(
                ConnectReturnCode::BadUserNamePassword | ConnectReturnCode::NotAuthorized,
            ) => Self::NotAuthorised,
            ConnectionError::ConnectionRefused(_) => Self::Refused,
            _ => Self::Unreachable,
        }
    }

    /// What to check, for the log.
    fn hint(self) -> &'static str {
        match self {
            Self::Unreachable => "check outputs.mqtt.broker and that the broker runs",
            Self::Tls => "check outputs.mqtt.tls (ca_file against the broker's certificate and its name, cert_file/key_file against the broker's require_certificate)",
            Self::NotAuthorised => "not authorised: check outputs.mqtt.username and password (or password_file) against the broker",
            Self::Refused => "check outputs.mqtt.client_id and the broker's log",
        }
    }
}

/// Counters of the edge node, for `/metrics`.
#[derive(Debug, Default)]
pub struct SparkplugStatus {
    failures: [AtomicU64; 4],
    connected: AtomicU8,
    bd_seq: AtomicU8,
    published: AtomicU64,
    bites: AtomicU64,
    connections: AtomicU64,
    rebirths: AtomicU64,
}

/// A snapshot of [`SparkplugStatus`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SparkplugCounts {
    /// A session with the broker is up.
    pub connected: bool,
    /// The current session's bdSeq.
    pub bd_seq: u8,
    /// Messages handed to the broker connection (births, data, deaths).
    pub published: u64,
    /// Bites published as their own DDATA.
    pub bites: u64,
    /// Sessions the broker accepted.
    pub connections: u64,
    /// Rebirth commands obeyed.
    pub rebirths: u64,
    /// Failed connections and lost sessions by [`ConnectFailure`] (in the order of
    /// [`ConnectFailure::ALL`]).
    pub failures: [u64; 4],
}

impl SparkplugStatus {
    /// The counters now.
    pub fn counts(&self) -> SparkplugCounts {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        SparkplugCounts {
            connected: self.connected.load(Ordering::Relaxed) != 0,
            bd_seq: self.bd_seq.load(Ordering::Relaxed),
            published: load(&self.published),
            bites: load(&self.bites),
            connections: load(&self.connections),
            rebirths: load(&self.rebirths),
            failures: self.failures.each_ref().map(load),
        }
    }
}

/// The edge node task.
#[derive(Debug)]
pub struct SparkplugNode {
    config: MqttOutput,
    history: PathBuf,
    publisher: Arc<Publisher>,
    status: Arc<SparkplugStatus>,
    tls: Option<Arc<rustls::ClientConfig>>,
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
        publisher: Arc<Publisher>,
    ) -> Result<Self, tls::TlsSetupError> {
        let tls = config.tls.as_ref().map(tls::client_config).transpose()?;
        Ok(Self {
            config,
            history,
            publisher,
            status: Arc::new(SparkplugStatus::default()),
            tls,
            rod_mills: Vec::new(),
        })
    }

    /// The node with these rod mills as devices: `(name, span count)` in config order
    /// (the span count from the mill file; it fixes the `span<i>` metrics at birth).
    pub fn with_rod_mills(mut self, rod_mills: Vec<(String, usize)>) -> Self {
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

    /// The next bdSeq; when the history file cannot take it, one more than the last in
    /// memory (logged: a host then may see a bdSeq repeat after a restart).
    async fn next_bd_seq(&self, last: Option<u8>) -> u8 {
        let (path, key) = (self.history.clone(), self.node_key());
        let stored = tokio::task::spawn_blocking(move || next_bd_seq(&path, &key)).await;
        match stored {
            Ok(Ok(bd_seq)) => bd_seq,
            Ok(Err(error)) => {
                tracing::error!(%error, "Sparkplug bdSeq not stored; counting in memory");
                last.map_or(0, |last| last.wrapping_add(1))
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug bdSeq task failed");
                last.map_or(0, |last| last.wrapping_add(1))
            }
        }
    }

    fn options(&self, will: node::Outgoing) -> MqttOptions {
        let (host, port) = self
            .config
            .broker
            .rsplit_once(':')
            .map(|(host, port)| (host.trim_matches(['[', ']']), port.parse().unwrap_or(1883)))
            .unwrap_or((self.config.broker.as_str(), 1883));
        let mut options = MqttOptions::new(self.config.client_id.clone(), host, port);
        options.set_keep_alive(self.config.keep_alive);
        options.set_clean_session(true);
        options.set_last_will(LastWill::new(
            will.topic,
            will.payload,
            QoS::AtLeastOnce,
            false,
        ));
        if let Some((user, password)) = &self.config.credentials {
            options.set_credentials(user.clone(), password.clone());
        }
        if let Some(config) = &self.tls {
            options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
                Arc::clone(config),
            )));
        }
        options
    }

    fn publish(&self, client: &AsyncClient, messages: Vec<node::Outgoing>) {
        for message in messages {
            match client.try_publish(message.topic, QoS::AtMostOnce, false, message.payload) {
                Ok(()) => {
                    self.status.published.fetch_add(1, Ordering::Relaxed);
                }
                Err(error) => tracing::warn!(%error, "Sparkplug message not queued"),
            }
        }
    }

    /// Publish the births; returns the bite counters they carry.
    fn births(&self, client: &AsyncClient, node: &mut EdgeNode) -> Vec<u32> {
        let results = self.publisher.results();
        self.publish(client, node.births(&results, now_ms()));
        results.drivelines.iter().map(|d| d.bite_counter).collect()
    }

    /// Publish until `shutdown`, reconnecting with a new bdSeq after each lost session.
    pub async fn run(self, mut shutdown: Shutdown) {
        let publisher = Arc::clone(&self.publisher);
        let mut bd_seq = self.next_bd_seq(None).await;
        let mut node = EdgeNode::new(
            &self.config.group_id,
            &self.config.node_id,
            publisher.driveline_names(),
            publisher.mill_names(),
            bd_seq,
        )
        .with_rod_mills(&self.rod_mills);
        self.status.bd_seq.store(bd_seq, Ordering::Relaxed);
        let (client, mut events) =
            AsyncClient::new(self.options(node.death(now_ms())), CLIENT_QUEUE);
        let command_qos = if self.config.command_qos == 0 {
            QoS::AtMostOnce
        } else {
            QoS::AtLeastOnce
        };
        let state_topic = self
            .config
            .primary_host_id
            .as_deref()
            .map(node::state_topic);
        let mut connected = false;
        // The last failure logged as a warning: the same failure again is only debug.
        let mut last_failure = None;
        // Births sent in this session (with a primary host: after its STATE online).
        let mut born = false;
        let mut counters: Vec<u32> = Vec::new();
        let mut bite_poll = tokio::time::interval(BITE_POLL);
        let mut data = tokio::time::interval(self.config.data_period);
        loop {
            tokio::select! {
                () = shutdown.recv() => break,
                event = events.poll() => match event {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        last_failure = None;
                        tracing::info!(broker = %self.config.broker, bd_seq, "Sparkplug session up");
                        connected = true;
                        self.status.connected.store(1, Ordering::Relaxed);
                        self.status.connections.fetch_add(1, Ordering::Relaxed);
                        if let Err(error) = client.try_subscribe(node.command_topic(), command_qos) {
                            tracing::warn!(%error, "Sparkplug NCMD subscription not queued");
                        }
                        match &state_topic {
                            Some(topic) => {
                                if let Err(error) = client.try_subscribe(topic.clone(), QoS::AtLeastOnce) {
                                    tracing::warn!(%error, "Sparkplug STATE subscription not queued");
                                }
                            }
                            None => {
                                counters = self.births(&client, &mut node);
                                born = true;
                            }
                        }
                    }
                    Ok(Event::Incoming(Packet::Publish(message))) => {
                        if message.topic == node.command_topic() {
                            match node::is_rebirth(&message.payload) {
                                Ok(true) if born => {
                                    tracing::info!("Sparkplug rebirth requested");
                                    self.status.rebirths.fetch_add(1, Ordering::Relaxed);
                                    counters = self.births(&client, &mut node);
                                }
                                Ok(_) => {}
                                Err(error) => tracing::warn!(%error, "undecodable Sparkplug NCMD"),
                            }
                        } else if state_topic.as_deref() == Some(message.topic.as_str()) {
                            match node::host_online(&message.payload) {
                                Some(true) if !born => {
                                    tracing::info!(host = ?self.config.primary_host_id, "primary host online");
                                    counters = self.births(&client, &mut node);
                                    born = true;
                                }
                                Some(false) if born => {
                                    // The specification: NDEATH and disconnect; the next
                                    // session waits for the host again.
                                    tracing::warn!(host = ?self.config.primary_host_id, "primary host offline: ending the session");
                                    let death = node.death(now_ms());
                                    let _ = client.try_publish(death.topic, QoS::AtLeastOnce, false, death.payload);
                                    let _ = client.try_disconnect();
                                    born = false;
                                }
                                Some(_) => {}
                                None => tracing::warn!(topic = %message.topic, "unreadable Sparkplug STATE"),
                            }
                        }
                    }
                    Ok(_) => {}
                    Err(error) => {
                        let failure = ConnectFailure::of(&error);
                        let slot = ConnectFailure::ALL.iter().position(|&f| f == failure).unwrap_or(0);
                        self.status.failures[slot].fetch_add(1, Ordering::Relaxed);
                        if connected {
                            tracing::warn!(%error, broker = %self.config.broker, "Sparkplug session ended");
                        } else if last_failure != Some(failure) {
                            tracing::warn!(%error, broker = %self.config.broker, reason = failure.name(), "Sparkplug broker connection failed, retrying every {} s: {}", RECONNECT_DELAY.as_secs(), failure.hint());
                        } else {
                            tracing::debug!(%error, broker = %self.config.broker, "Sparkplug broker connection failed again");
                        }
                        last_failure = Some(failure);
                        // What the dead session had queued belongs to it: its seq
                        // numbers mean nothing in the next session.
                        drop_pending(&mut events);
                        // A new bdSeq only after a session the broker accepted: a
                        // refused or failed CONNECT never registered its Will.
                        if connected {
                            bd_seq = self.next_bd_seq(Some(bd_seq)).await;
                            node.new_session(bd_seq);
                            self.status.bd_seq.store(bd_seq, Ordering::Relaxed);
                            let will = node.death(now_ms());
                            events.mqtt_options.set_last_will(LastWill::new(will.topic, will.payload, QoS::AtLeastOnce, false));
                        }
                        connected = false;
                        born = false;
                        self.status.connected.store(0, Ordering::Relaxed);
                        tokio::select! {
                            () = shutdown.recv() => break,
                            () = tokio::time::sleep(RECONNECT_DELAY) => {}
                        }
                    }
                },
                _ = bite_poll.tick(), if born => {
                    let results = publisher.results();
                    for (index, after) in results.drivelines.iter().enumerate() {
                        if counters.get(index).is_some_and(|&before| after.bite_counter != before) {
                            let time = after.last_bite_unix_ms.unwrap_or_else(now_ms);
                            self.publish(&client, vec![node.bite(index, after, time, false)]);
                            self.status.bites.fetch_add(1, Ordering::Relaxed);
                            counters[index] = after.bite_counter;
                        }
                    }
                }
                _ = data.tick(), if born => {
                    self.publish(&client, node.data(&publisher.results(), now_ms()));
                }
            }
        }
        if born {
            // A clean stop: the NDEATH the Will would have sent, then DISCONNECT (which
            // discards the Will).
            let death = node.death(now_ms());
            let _ = client.try_publish(death.topic, QoS::AtLeastOnce, false, death.payload);
            let _ = client.try_disconnect();
            let flush = async {
                while let Ok(event) = events.poll().await {
                    if matches!(event, Event::Outgoing(rumqttc::Outgoing::Disconnect)) {
                        break;
                    }
                }
            };
            let _ = tokio::time::timeout(Duration::from_secs(2), flush).await;
        }
        self.status.connected.store(0, Ordering::Relaxed);
    }
}

/// Drop what the event loop would send at its next connection.
fn drop_pending(events: &mut EventLoop) {
    events.clean();
    events.pending.clear();
}
