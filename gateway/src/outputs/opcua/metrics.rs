//! The OPC UA server's `/metrics` families: connections, framing and protocol
//! errors, refused sign-ins and requests, acknowledgements, value changes and events.

use super::OpcUaStatus;
use crate::exposition::{Exposition, Families, Kind};

impl Families for OpcUaStatus {
    fn write_families(&self, page: &mut Exposition) {
        let counts = &self.counts();
        let scalars: [(&str, Kind, &str, f64); 22] = [
            (
                "millgate_opcua_connections_total",
                Kind::Counter,
                "TCP connections the OPC UA server accepted.",
                counts.connections as f64,
            ),
            (
                "millgate_opcua_connections_refused_total",
                Kind::Counter,
                "Connections closed at once because max_connections were open.",
                counts.refused as f64,
            ),
            (
                "millgate_opcua_connections_evicted_total",
                Kind::Counter,
                "Idle connections closed to make room for a new client.",
                counts.evicted as f64,
            ),
            (
                "millgate_opcua_sessions_refused_total",
                Kind::Counter,
                "CreateSession refused because the client address held max_sessions_per_peer sessions.",
                counts.sessions_refused as f64,
            ),
            (
                "millgate_opcua_discovery_channels_closed_total",
                Kind::Counter,
                "Channels without security closed after discovery (security none not configured).",
                counts.discovery_closed as f64,
            ),
            (
                "millgate_opcua_malformed_frames_total",
                Kind::Counter,
                "Connections closed because the client did not speak OPC UA TCP framing.",
                counts.malformed_frames as f64,
            ),
            (
                "millgate_opcua_protocol_errors_total",
                Kind::Counter,
                "ERR messages the server sent (a message its decoder or secure channel refused).",
                counts.protocol_errors as f64,
            ),
            (
                "millgate_opcua_identities_refused_total",
                Kind::Counter,
                "Sign-ins refused (wrong password, unknown user, anonymous where not allowed).",
                counts.identities_refused as f64,
            ),
            (
                "millgate_opcua_security_rejected_requests_total",
                Kind::Counter,
                "Requests refused for security (certificate, signature, session, access).",
                counts.security_rejected_requests as f64,
            ),
            (
                "millgate_opcua_rejected_requests_total",
                Kind::Counter,
                "Requests answered with a bad service result.",
                counts.rejected_requests as f64,
            ),
            (
                "millgate_opcua_acknowledgements_total",
                Kind::Counter,
                "Acknowledge calls carried out.",
                counts.acknowledgements as f64,
            ),
            (
                "millgate_opcua_acknowledgements_refused_total",
                Kind::Counter,
                "Acknowledge calls the guard refused (a remote host, a read-only user).",
                counts.acknowledgements_refused as f64,
            ),
            (
                "millgate_opcua_acknowledgements_limited_total",
                Kind::Counter,
                "Acknowledge calls refused: one was carried out less than a second before.",
                counts.acknowledgements_limited as f64,
            ),
            (
                "millgate_opcua_condition_refreshes_total",
                Kind::Counter,
                "ConditionRefresh and ConditionRefresh2 calls carried out.",
                counts.condition_refreshes as f64,
            ),
            (
                "millgate_opcua_condition_calls_refused_total",
                Kind::Counter,
                "Calls of a condition's methods refused for what they asked: an unknown subscription, condition or EventId, a condition acknowledged already, bad arguments.",
                counts.condition_calls_refused as f64,
            ),
            (
                "millgate_opcua_rejected_certificates_removed_total",
                Kind::Counter,
                "Refused client certificates removed from pki_dir/rejected/ to keep its bound.",
                counts.rejected_certificates_removed as f64,
            ),
            (
                "millgate_opcua_subscriptions",
                Kind::Gauge,
                "Subscriptions on the server, closed sessions' included until they expire.",
                counts.subscriptions as f64,
            ),
            (
                "millgate_opcua_monitored_items",
                Kind::Gauge,
                "Monitored items on the server.",
                counts.monitored_items as f64,
            ),
            (
                "millgate_opcua_orphaned_subscriptions",
                Kind::Gauge,
                "Subscriptions of closed or expired sessions, kept until they expire.",
                counts.orphaned_subscriptions as f64,
            ),
            (
                "millgate_opcua_value_changes_total",
                Kind::Counter,
                "Variable values changed in the address space.",
                counts.value_changes as f64,
            ),
            (
                "millgate_opcua_invalid_updates_total",
                Kind::Counter,
                "Updates refused (wrong type, a non-finite number given as good).",
                counts.invalid_updates as f64,
            ),
            (
                "millgate_opcua_events_total",
                Kind::Counter,
                "Alarm events sent to clients.",
                counts.events as f64,
            ),
        ];
        page.scalars(scalars);
    }
}
