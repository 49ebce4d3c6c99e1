//! The Sparkplug B edge node's `/metrics` families: the session, messages and bites
//! published and replayed, the backlog, rebirths, refused commands, connection
//! failures by reason, and the server set: the server in use, the switches, the time
//! without a broker.

use super::{ConnectFailure, SparkplugStatus};
use crate::exposition::{Exposition, Families, Kind};

impl Families for SparkplugStatus {
    fn write_families(&self, page: &mut Exposition) {
        let counts = &self.counts();
        let scalars: [(&str, Kind, &str, f64); 12] = [
            (
                "millgate_sparkplug_connected",
                Kind::Gauge,
                "1 while a session with the MQTT broker is up.",
                f64::from(u8::from(counts.connected)),
            ),
            (
                "millgate_sparkplug_server_switches_total",
                Kind::Counter,
                "Moves to the next MQTT server of outputs.mqtt.brokers, after a failed connection or a lost session.",
                counts.switches as f64,
            ),
            (
                "millgate_sparkplug_without_broker_seconds_total",
                Kind::Counter,
                "Time without a session with any MQTT server since the start, the current outage included.",
                counts.without_broker.as_secs_f64(),
            ),
            (
                "millgate_sparkplug_bd_seq",
                Kind::Gauge,
                "The current session's Sparkplug bdSeq (0..=255).",
                f64::from(counts.bd_seq),
            ),
            (
                "millgate_sparkplug_messages_published_total",
                Kind::Counter,
                "Sparkplug messages handed to the broker connection.",
                counts.published as f64,
            ),
            (
                "millgate_sparkplug_bites_published_total",
                Kind::Counter,
                "Bites published live as their own DDATA.",
                counts.bites as f64,
            ),
            (
                "millgate_sparkplug_replayed_total",
                Kind::Counter,
                "Bites replayed from the history as DDATA flagged historical.",
                counts.replayed as f64,
            ),
            (
                "millgate_sparkplug_backlog_bites",
                Kind::Gauge,
                "Bites in the history the broker has not confirmed (PUBACK) yet.",
                counts.backlog as f64,
            ),
            (
                "millgate_sparkplug_sessions_total",
                Kind::Counter,
                "Sessions the MQTT broker accepted.",
                counts.connections as f64,
            ),
            (
                "millgate_sparkplug_rebirths_total",
                Kind::Counter,
                "Rebirths on a Node Control/Rebirth command (at most one per 5 s).",
                counts.rebirths as f64,
            ),
            (
                "millgate_sparkplug_rebirth_requests_total",
                Kind::Counter,
                "Node Control/Rebirth commands received (those within 5 s of the last births answered by one rebirth).",
                counts.rebirth_requests as f64,
            ),
            (
                "millgate_sparkplug_commands_refused_total",
                Kind::Counter,
                "NCMDs refused: retained, over 64 KiB or undecodable.",
                counts.commands_refused as f64,
            ),
        ];
        page.scalars(scalars);
        page.family(
            "millgate_sparkplug_server_in_use",
            Kind::Gauge,
            "1 for the MQTT server the node is connected or connecting to, 0 for the others of the list.",
            self.servers.iter().enumerate().map(|(index, server)| {
                (
                    vec![("server", server.as_str())],
                    f64::from(u8::from(index == counts.server)),
                )
            }),
        );
        page.family(
            "millgate_sparkplug_connect_failures_total",
            Kind::Counter,
            "Failed connections to the MQTT broker and lost sessions, by reason (unreachable, tls, not_authorised, refused).",
            ConnectFailure::ALL
                .iter()
                .zip(counts.failures)
                .map(|(failure, count)| (vec![("reason", failure.name())], count as f64)),
        );
    }
}
