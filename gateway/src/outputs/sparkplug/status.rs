//! What the edge node has done, for `/metrics` and the log: its counters, and why a
//! connection to the broker failed.

use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};

use rumqttc::{ConnectReturnCode, ConnectionError};

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
    pub(super) fn hint(self) -> &'static str {
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

/// A snapshot of [`SparkplugStatus`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SparkplugCounts {
    /// A session with the broker is up.
    pub connected: bool,
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
            rebirth_requests: load(&self.rebirth_requests),
            commands_refused: load(&self.commands_refused),
            replayed: load(&self.replayed),
            backlog: load(&self.backlog),
            failures: self.failures.each_ref().map(load),
        }
    }
}
