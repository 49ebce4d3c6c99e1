//! The Modbus outputs' `/metrics` families: the PLC writer's writes and failures and
//! the HMI server's connections and requests (the heartbeat written to the PLC is the
//! catalogue's, `outputs::metrics`).

use super::hmi_server::{ServerCounters, ServerCounts};
use super::plc_writer::{PlcCounters, PlcFailure};
use crate::exposition::{Exposition, Families, Kind};

impl Families for PlcCounters {
    /// Writes, failures by reason, the last success.
    fn write_families(&self, page: &mut Exposition) {
        let counts = self.snapshot();
        page.scalar(
            "millgate_plc_writes_total",
            Kind::Counter,
            "Register maps written to the PLC.",
            counts.writes as f64,
        );
        page.family(
            "millgate_plc_write_failures_total",
            Kind::Counter,
            "Failed PLC connections and writes, by reason: connect, timeout, transport, mismatch (the network) or refused (a Modbus exception from the PLC).",
            PlcFailure::ALL
                .iter()
                .zip(counts.failures)
                .map(|(reason, n)| (vec![("reason", reason.name())], n as f64)),
        );
        page.family(
            "millgate_plc_last_write_success_timestamp_seconds",
            Kind::Gauge,
            "When a register map last reached the PLC, Unix seconds (no sample before the first).",
            (counts.last_success_unix_ms > 0)
                .then(|| (Vec::new(), counts.last_success_unix_ms as f64 / 1000.0)),
        );
    }
}

impl Families for ServerCounters {
    /// Connections by how they ended, requests, exceptions, broadcasts.
    fn write_families(&self, page: &mut Exposition) {
        let counts = &self.snapshot();
        type ServerCountOf = fn(&ServerCounts) -> u64;
        let families: [(&str, &str, ServerCountOf); 9] = [
            ("connections", "HMI connections accepted", |c| c.connections),
            (
                "refused_connections",
                "HMI connections closed at once: the server was full and every connection inside a request",
                |c| c.refused,
            ),
            (
                "evicted_connections",
                "Idle HMI connections closed to make room for a new one (max_connections or max_connections_per_peer reached)",
                |c| c.evicted,
            ),
            (
                "idle_closed_connections",
                "HMI connections closed for idling or a request not completed in time",
                |c| c.idle_closed,
            ),
            (
                "silent_closed_connections",
                "Of those, HMI connections closed for sending no request within 5 s of connecting (or idle_timeout_ms, when shorter)",
                |c| c.silent_closed,
            ),
            (
                "not_modbus_connections",
                "HMI connections closed because the stream was not Modbus TCP",
                |c| c.not_modbus,
            ),
            ("requests", "HMI requests answered", |c| c.requests),
            (
                "exceptions",
                "HMI requests answered with a Modbus exception",
                |c| c.exceptions,
            ),
            (
                "broadcasts",
                "HMI broadcast requests (unit 0), never answered nor acted on",
                |c| c.broadcasts,
            ),
        ];
        for (name, help, value) in families {
            page.scalar(
                &format!("millgate_server_{name}_total"),
                Kind::Counter,
                &format!("{help}."),
                value(counts) as f64,
            );
        }
    }
}
