//! `[outputs]`: the PLC writer, the HMI server and the metrics endpoint.

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::time::Duration;

use crate::raw::RawOutputs;
use crate::{MetricsOutput, Outputs, PlcOutput, ServerOutput};

use super::{
    optional, Checker, DEFAULT_IDLE_TIMEOUT_MS, DEFAULT_MAX_CONNECTIONS, DEFAULT_METRICS_BIND,
    DEFAULT_TIMEOUT_MS, DEFAULT_UNIT_ID,
};

/// Most HMI clients `outputs.server.max_connections` may allow.
const MAX_CONNECTIONS_LIMIT: i64 = 64;
/// Allowed `outputs.server.idle_timeout_ms`.
const IDLE_TIMEOUT_RANGE_MS: RangeInclusive<i64> = 100..=3_600_000;

impl Checker<'_> {
    pub(super) fn outputs(&mut self, raw: &RawOutputs) -> Option<Outputs> {
        let plc = raw.plc.as_ref().map(|plc| {
            let key = "outputs.plc";
            let address = self.host_port(&format!("{key}.address"), &plc.address);
            let unit_id = self.unit_id(&format!("{key}.unit_id"), plc.unit_id);
            let register_base = self.int_in(
                &format!("{key}.register_base"),
                plc.register_base.unwrap_or(0),
                0..=65_535,
                "",
            );
            let write_period = self.period(&format!("{key}.write_period_ms"), plc.write_period_ms);
            let timeout = self.period(
                &format!("{key}.timeout_ms"),
                plc.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS),
            );
            Some(PlcOutput {
                address: address?,
                unit_id: unit_id?,
                register_base: u16::try_from(register_base?).ok()?,
                write_period: write_period?,
                timeout: timeout?,
            })
        });
        let server = raw.server.as_ref().map(|server| {
            let key = "outputs.server";
            let bind = self.bind(&format!("{key}.bind"), &server.bind);
            let unit_id = self.int_in(
                &format!("{key}.unit_id"),
                server.unit_id.unwrap_or(DEFAULT_UNIT_ID),
                1..=255,
                "; 0 is the broadcast address, which a server never answers",
            );
            let max_connections = self.int_in(
                &format!("{key}.max_connections"),
                server
                    .max_connections
                    .unwrap_or(DEFAULT_MAX_CONNECTIONS as i64),
                1..=MAX_CONNECTIONS_LIMIT,
                "",
            );
            let idle_timeout_ms = self.int_in(
                &format!("{key}.idle_timeout_ms"),
                server
                    .idle_timeout_ms
                    .unwrap_or(DEFAULT_IDLE_TIMEOUT_MS as i64),
                IDLE_TIMEOUT_RANGE_MS,
                " ms",
            );
            Some(ServerOutput {
                bind: bind?,
                unit_id: u8::try_from(unit_id?).ok()?,
                max_connections: usize::try_from(max_connections?).ok()?,
                idle_timeout: Duration::from_millis(u64::try_from(idle_timeout_ms?).ok()?),
                allow_remote_commands: server.allow_remote_commands.unwrap_or(false),
            })
        });
        let metrics = raw.metrics.as_ref().map(|metrics| {
            let bind = metrics.bind.as_deref().unwrap_or(DEFAULT_METRICS_BIND);
            Some(MetricsOutput {
                bind: self.bind("outputs.metrics.bind", bind)?,
            })
        });
        let (server, metrics) = (optional(server), optional(metrics));
        if let (Some(Some(server)), Some(Some(metrics))) = (&server, &metrics) {
            self.distinct_listeners(&[
                ("outputs.server.bind", server.bind),
                ("outputs.metrics.bind", metrics.bind),
            ]);
        }
        Some(Outputs {
            plc: optional(plc)?,
            server: server?,
            metrics: metrics?,
        })
    }

    /// Reports every pair of listeners that cannot both bind: the same port on the
    /// same address, or on an address and the wildcard (0.0.0.0 or [::]) of the same
    /// family. Port 0 (the OS picks a free port) never clashes.
    fn distinct_listeners(&mut self, listeners: &[(&str, SocketAddr)]) {
        for (index, (key, address)) in listeners.iter().enumerate() {
            let clash = listeners[..index].iter().find(|(_, earlier)| {
                let same_family = earlier.is_ipv4() == address.is_ipv4();
                address.port() != 0
                    && earlier.port() == address.port()
                    && same_family
                    && (earlier.ip() == address.ip()
                        || earlier.ip().is_unspecified()
                        || address.ip().is_unspecified())
            });
            if let Some((earlier_key, earlier)) = clash {
                self.report.push(
                    *key,
                    format!(
                        "{address} is not allowed: {earlier_key} ({earlier}) listens on the \
                         same port; each listener needs its own port"
                    ),
                );
            }
        }
    }
}
