//! `[outputs]`: the PLC writer, the HMI server and the metrics endpoint.

use crate::raw::RawOutputs;
use crate::{MetricsOutput, Outputs, PlcOutput, ServerOutput};

use super::{optional, Checker, DEFAULT_METRICS_BIND, DEFAULT_TIMEOUT_MS};

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
            let bind = self.bind("outputs.server.bind", &server.bind);
            let unit_id = self.unit_id("outputs.server.unit_id", server.unit_id);
            Some(ServerOutput {
                bind: bind?,
                unit_id: unit_id?,
            })
        });
        let metrics = raw.metrics.as_ref().map(|metrics| {
            let bind = metrics.bind.as_deref().unwrap_or(DEFAULT_METRICS_BIND);
            Some(MetricsOutput {
                bind: self.bind("outputs.metrics.bind", bind)?,
            })
        });
        Some(Outputs {
            plc: optional(plc)?,
            server: optional(server)?,
            metrics: optional(metrics)?,
        })
    }
}
