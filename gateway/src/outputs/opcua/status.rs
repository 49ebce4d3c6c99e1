//! What the OPC UA server counts: its own counters and async-opcua's diagnostics, for
//! `/metrics` and tests.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use opcua::server::ServerHandle;
use opcua::types::{VariableId, Variant};

/// What the server has seen: counted here, logged where it happens.
#[derive(Debug, Default)]
pub(crate) struct OpcUaCounters {
    pub(super) connections: AtomicU64,
    pub(super) refused: AtomicU64,
    pub(super) evicted: AtomicU64,
    pub(super) sessions_refused: AtomicU64,
    pub(super) discovery_closed: AtomicU64,
    pub(super) malformed_frames: AtomicU64,
    pub(super) protocol_errors: AtomicU64,
    pub(super) identities_refused: AtomicU64,
    pub(super) acknowledgements: AtomicU64,
    pub(super) acknowledgements_refused: AtomicU64,
    pub(super) acknowledgements_limited: AtomicU64,
    pub(super) condition_refreshes: AtomicU64,
    pub(super) condition_calls_refused: AtomicU64,
    pub(super) rejected_certificates_removed: AtomicU64,
    pub(super) value_changes: AtomicU64,
    pub(super) invalid_updates: AtomicU64,
    pub(super) events: AtomicU64,
}

/// A copy of the server's counters and async-opcua's own counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OpcUaCounts {
    /// TCP connections accepted.
    pub connections: u64,
    /// Connections closed at once: `max_connections` were open and none idle, or
    /// the client held half of them.
    pub refused: u64,
    /// Idle connections closed to make room for a new client.
    pub evicted: u64,
    /// CreateSession refused (`Bad_TooManySessions`): the client address held
    /// `max_sessions_per_peer` sessions on open connections.
    pub sessions_refused: u64,
    /// Channels without security closed after their discovery requests (where
    /// `none` is not a security mode).
    pub discovery_closed: u64,
    /// Connections closed because what the client sent was not OPC UA TCP framing.
    pub malformed_frames: u64,
    /// ERR messages the server sent: messages its decoder or its secure channel
    /// refused (a malformed body, an unknown channel, a timeout).
    pub protocol_errors: u64,
    /// Sign-ins refused: a wrong password, an unknown user, an anonymous client where
    /// none is allowed.
    pub identities_refused: u64,
    /// Requests the server refused for security: a secure channel it would not open
    /// (an invalid client certificate or signature), an unknown session, an access
    /// denied (async-opcua's diagnostics).
    pub security_rejected_requests: u64,
    /// Requests the server answered with a bad service result, these included: an
    /// untrusted client certificate (`Bad_CertificateUntrusted` at CreateSession), a
    /// refused sign-in (async-opcua's diagnostics).
    pub rejected_requests: u64,
    /// Acknowledge calls carried out.
    pub acknowledgements: u64,
    /// Acknowledge calls refused by the guard.
    pub acknowledgements_refused: u64,
    /// Acknowledge calls refused because one was carried out less than a second
    /// before (`Bad_TooManyOperations`).
    pub acknowledgements_limited: u64,
    /// ConditionRefresh and ConditionRefresh2 calls carried out.
    pub condition_refreshes: u64,
    /// Calls of a condition's methods refused for what they asked (not for rights or
    /// pace): an unknown subscription or monitored item (`Bad_SubscriptionIdInvalid`,
    /// `Bad_MonitoredItemIdInvalid`), an unknown condition, a stale or another
    /// condition's EventId (`Bad_EventIdUnknown`), a condition acknowledged already,
    /// arguments missing or of the wrong type.
    pub condition_calls_refused: u64,
    /// Refused client certificates removed from `pki_dir/rejected/`, the oldest
    /// first, to keep it within its bound.
    pub rejected_certificates_removed: u64,
    /// Subscriptions on the server now, closed sessions' included until they expire.
    pub subscriptions: u64,
    /// Monitored items on the server now.
    pub monitored_items: u64,
    /// Subscriptions of closed or expired sessions now (left behind, until they
    /// expire).
    pub orphaned_subscriptions: u64,
    /// Variable values changed in the address space.
    pub value_changes: u64,
    /// Updates refused: a value not of its variable's type, or a non-finite number
    /// given as good (published as `Bad_TypeMismatch`).
    pub invalid_updates: u64,
    /// Condition events sent (a ConditionRefresh's not counted).
    pub events: u64,
}

impl OpcUaCounters {
    /// Current values; `handle` adds async-opcua's diagnostics.
    pub(super) fn snapshot(&self, handle: Option<&ServerHandle>) -> OpcUaCounts {
        let load = |counter: &AtomicU64| counter.load(Ordering::Relaxed);
        let diagnostic = |variable: VariableId| {
            handle
                .and_then(|h| h.info().summary().get(variable))
                .and_then(|value| value.value)
                .and_then(|value| match value {
                    Variant::UInt32(count) => Some(u64::from(count)),
                    _ => None,
                })
                .unwrap_or(0)
        };
        let (subscriptions, monitored_items) =
            handle.map_or((0, 0), |h| h.subscriptions().counts());
        let orphaned_subscriptions = handle.map_or(0, |h| h.subscriptions().orphans());
        OpcUaCounts {
            connections: load(&self.connections),
            refused: load(&self.refused),
            evicted: load(&self.evicted),
            sessions_refused: load(&self.sessions_refused),
            discovery_closed: load(&self.discovery_closed),
            malformed_frames: load(&self.malformed_frames),
            protocol_errors: load(&self.protocol_errors),
            identities_refused: load(&self.identities_refused),
            security_rejected_requests: diagnostic(
                VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_SecurityRejectedRequestsCount,
            ),
            rejected_requests: diagnostic(
                VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_RejectedRequestsCount,
            ),
            acknowledgements: load(&self.acknowledgements),
            acknowledgements_refused: load(&self.acknowledgements_refused),
            acknowledgements_limited: load(&self.acknowledgements_limited),
            condition_refreshes: load(&self.condition_refreshes),
            condition_calls_refused: load(&self.condition_calls_refused),
            rejected_certificates_removed: load(&self.rejected_certificates_removed),
            subscriptions: subscriptions as u64,
            monitored_items: monitored_items as u64,
            orphaned_subscriptions: orphaned_subscriptions as u64,
            value_changes: load(&self.value_changes),
            invalid_updates: load(&self.invalid_updates),
            events: load(&self.events),
        }
    }
}

pub(super) fn count(counter: &AtomicU64) {
    counter.fetch_add(1, Ordering::Relaxed);
}

/// The counts of a running server, for `/metrics` and tests.
#[derive(Clone)]
pub struct OpcUaStatus {
    pub(super) counters: Arc<OpcUaCounters>,
    pub(super) handle: Arc<std::sync::Mutex<Option<ServerHandle>>>,
}

impl std::fmt::Debug for OpcUaStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaStatus")
            .field("counts", &self.counts())
            .finish()
    }
}

impl OpcUaStatus {
    /// The counts now.
    pub fn counts(&self) -> OpcUaCounts {
        let handle = crate::lock(&self.handle).clone();
        self.counters.snapshot(handle.as_ref())
    }
}
