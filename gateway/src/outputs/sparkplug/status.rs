//! What the edge node has done, for `/metrics` and the log: its counters, and why a
//! connection to the broker failed.

use std::sync::atomic::{AtomicU64, AtomicU8, AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use rumqttc::{ConnectReturnCode, ConnectionError};
use tokio::time::Instant;

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

    /// Whether the CONNECT of a connection that failed with `error` may have reached
    /// the broker, so that the broker may hold (or still register) that CONNECT's
    /// Will. No when nothing was sent (the TCP connection refused, the name not
    /// resolved, the TLS handshake failed: it comes before the CONNECT) or the broker
    /// answered with a refusing CONNACK (no session, no Will); yes for the rest (no
    /// CONNACK in time, the connection reset or closed after the CONNECT, a session
    /// that ended).
    pub(super) fn may_have_registered_will(error: &ConnectionError) -> bool {
        use std::io::ErrorKind;
        match error {
            ConnectionError::ConnectionRefused(_) => false,
            ConnectionError::Io(io)
                if matches!(
                    io.kind(),
                    ErrorKind::ConnectionRefused
                        | ErrorKind::NotFound
                        | ErrorKind::AddrNotAvailable
                ) =>
            {
                false
            }
            _ => Self::of(error) != Self::Tls,
        }
    }

    /// What to check, for the log.
    pub(super) fn hint(self) -> &'static str {
        match self {
            Self::Unreachable => "check outputs.mqtt.broker (or brokers) and that the broker runs",
            Self::Tls => "check outputs.mqtt.tls, or the server's own tls in outputs.mqtt.brokers (ca_file against the broker's certificate and its name, cert_file/key_file against the broker's require_certificate)",
            Self::NotAuthorised => "not authorised: check outputs.mqtt.username and password (or password_file) against the broker",
            Self::Refused => "check outputs.mqtt.client_id and the broker's log",
        }
    }
}

/// Counters of the edge node, for `/metrics`.
#[derive(Debug, Default)]
pub struct SparkplugStatus {
    /// The configured MQTT servers, in failover order.
    pub(super) servers: Vec<String>,
    /// The index in `servers` of the server in use (connected or being connected to).
    pub(super) server: AtomicUsize,
    pub(super) switches: AtomicU64,
    outage: Mutex<Outage>,
    pub(super) failures: [AtomicU64; 4],
    pub(super) connected: AtomicU8,
    pub(super) bd_seq: AtomicU8,
    pub(super) published: AtomicU64,
    pub(super) bites: AtomicU64,
    pub(super) connections: AtomicU64,
    pub(super) rebirths: AtomicU64,
    pub(super) rebirth_requests: AtomicU64,
    pub(super) commands_refused: AtomicU64,
    pub(super) replayed: AtomicU64,
    pub(super) backlog: AtomicU64,
}

/// Time without a session: the outages that ended, and since when the current one
/// lasts.
#[derive(Debug, Default)]
struct Outage {
    ended: Duration,
    since: Option<Instant>,
}

/// A snapshot of [`SparkplugStatus`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SparkplugCounts {
    /// A session with the broker is up.
    pub connected: bool,
    /// The index, in the configured list, of the server in use (connected or being
    /// connected to).
    pub server: usize,
    /// Moves to another server of the list (after a failed connection or a lost
    /// session).
    pub switches: u64,
    /// Time without a session with any server since the node started (from its start
    /// to the first CONNACK, and every outage since, the current one included).
    pub without_broker: Duration,
    /// The current session's bdSeq.
    pub bd_seq: u8,
    /// Messages handed to the broker connection (births, data, deaths).
    pub published: u64,
    /// Bites published live as their own DDATA.
    pub bites: u64,
    /// Bites replayed from the history, flagged historical.
    pub replayed: u64,
    /// Bites in the history the broker has not acknowledged yet.
    pub backlog: u64,
    /// Sessions the broker accepted.
    pub connections: u64,
    /// Rebirths on command (at most one per
    /// [`REBIRTH_INTERVAL`](super::REBIRTH_INTERVAL)).
    pub rebirths: u64,
    /// Rebirth commands received during a session (one rebirth answers all those of
    /// an interval).
    pub rebirth_requests: u64,
    /// NCMDs refused: retained, too large or undecodable.
    pub commands_refused: u64,
    /// Failed connections and lost sessions by [`ConnectFailure`] (in the order of
    /// [`ConnectFailure::ALL`]).
    pub failures: [u64; 4],
}

impl SparkplugStatus {
    /// The counters of a node with these MQTT `servers` (in failover order).
    pub fn for_servers(servers: Vec<String>) -> Self {
        Self {
            servers,
            ..Self::default()
        }
    }

    /// The configured servers, in failover order.
    pub fn servers(&self) -> &[String] {
        &self.servers
    }

    fn outage(&self) -> std::sync::MutexGuard<'_, Outage> {
        // The counters stay usable after a panic elsewhere: they hold no invariant.
        self.outage.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// No session from now on (the node started, or its session ended).
    pub(super) fn session_down(&self) {
        self.connected.store(0, Ordering::Relaxed);
        self.outage().since.get_or_insert_with(Instant::now);
    }

    /// The broker accepted a session (CONNACK): the outage, if any, ends.
    pub(super) fn session_up(&self) {
        self.connected.store(1, Ordering::Relaxed);
        self.connections.fetch_add(1, Ordering::Relaxed);
        let mut outage = self.outage();
        if let Some(since) = outage.since.take() {
            outage.ended += since.elapsed();
        }
    }

    /// The node moved on to server `index` of the list.
    pub(super) fn switched_to(&self, index: usize) {
        self.server.store(index, Ordering::Relaxed);
        self.switches.fetch_add(1, Ordering::Relaxed);
    }

    /// The counters now.
    pub fn counts(&self) -> SparkplugCounts {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let without_broker = {
            let outage = self.outage();
            outage.ended + outage.since.map_or(Duration::ZERO, |since| since.elapsed())
        };
        SparkplugCounts {
            connected: self.connected.load(Ordering::Relaxed) != 0,
            server: self.server.load(Ordering::Relaxed),
            switches: load(&self.switches),
            without_broker,
            bd_seq: self.bd_seq.load(Ordering::Relaxed),
            published: load(&self.published),
            bites: load(&self.bites),
            connections: load(&self.connections),
            rebirths: load(&self.rebirths),
            rebirth_requests: load(&self.rebirth_requests),
            commands_refused: load(&self.commands_refused),
            replayed: load(&self.replayed),
            backlog: load(&self.backlog),
            failures: self.failures.each_ref().map(load),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_connect_the_broker_may_have_taken_is_told_from_one_it_cannot_have() {
        use std::io::{Error, ErrorKind};
        let io = |kind| ConnectionError::Io(Error::from(kind));
        let taken = ConnectFailure::may_have_registered_will;
        // Nothing sent, or refused by a CONNACK: no Will registered.
        assert!(!taken(&io(ErrorKind::ConnectionRefused)));
        assert!(!taken(&io(ErrorKind::NotFound)));
        assert!(!taken(&ConnectionError::ConnectionRefused(
            ConnectReturnCode::NotAuthorized
        )));
        assert!(!taken(&ConnectionError::Io(Error::other(
            rustls::Error::HandshakeNotComplete
        ))));
        // The CONNECT went out and no CONNACK came, or the connection broke after it.
        assert!(taken(&ConnectionError::NetworkTimeout));
        assert!(taken(&io(ErrorKind::ConnectionReset)));
        assert!(taken(&io(ErrorKind::UnexpectedEof)));
    }

    #[tokio::test(start_paused = true)]
    async fn time_without_a_broker_counts_every_outage_the_current_one_included() {
        let status = SparkplugStatus::for_servers(vec!["a:1883".into(), "b:1883".into()]);
        let pass = |s: u64| tokio::time::advance(Duration::from_secs(s));
        // Started: 3 s to the first CONNACK.
        status.session_down();
        pass(3).await;
        status.session_up();
        pass(10).await;
        assert_eq!(status.counts().without_broker, Duration::from_secs(3));
        // Lost; a second "down" (a failed connection meanwhile) does not restart it.
        status.session_down();
        pass(2).await;
        status.session_down();
        status.switched_to(1);
        pass(5).await;
        let during = status.counts();
        assert_eq!(
            (
                during.without_broker,
                during.connected,
                during.server,
                during.switches
            ),
            (Duration::from_secs(10), false, 1, 1),
            "the current outage counts while it lasts"
        );
        status.session_up();
        pass(60).await;
        let after = status.counts();
        assert_eq!(
            (after.without_broker, after.connected, after.connections),
            (Duration::from_secs(10), true, 2)
        );
    }
}
