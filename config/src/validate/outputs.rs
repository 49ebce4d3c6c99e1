//! `[outputs]`: the PLC writer, the HMI server and the metrics endpoint.

use std::time::Duration;

use crate::raw::{RawMqttOutput, RawOutputs};
use crate::{MetricsOutput, MqttOutput, Outputs, PlcOutput, ServerOutput};

use super::{optional, Checker, DEFAULT_METRICS_BIND, DEFAULT_TIMEOUT_MS};

impl Checker<'_> {
    /// `[outputs]`; `history` says whether `[history]` is configured (the MQTT output
    /// keeps its session number there).
    pub(super) fn outputs(&mut self, raw: &RawOutputs, history: bool) -> Option<Outputs> {
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
        let mqtt = raw.mqtt.as_ref().map(|mqtt| self.mqtt(mqtt, history));
        Some(Outputs {
            plc: optional(plc)?,
            server: optional(server)?,
            metrics: optional(metrics)?,
            mqtt: optional(mqtt)?,
        })
    }

    fn mqtt(&mut self, raw: &RawMqttOutput, history: bool) -> Option<MqttOutput> {
        let key = "outputs.mqtt";
        let broker = self.host_port(&format!("{key}.broker"), &raw.broker);
        let group_id = self.sparkplug_id(&format!("{key}.group_id"), &raw.group_id);
        let node_id = self.sparkplug_id(&format!("{key}.node_id"), &raw.node_id);
        let client_id = match &raw.client_id {
            Some(id) if id.is_empty() || id.chars().count() > 64 => {
                self.report.push(
                    format!("{key}.client_id"),
                    format!("\"{id}\" is not allowed (must be 1..=64 characters)"),
                );
                None
            }
            Some(id) => Some(id.clone()),
            None => Some(format!("millgate-{}-{}", raw.group_id, raw.node_id)),
        };
        let keep_alive = self.int_in(
            &format!("{key}.keep_alive_s"),
            raw.keep_alive_s.unwrap_or(30),
            5..=3600,
            " s",
        );
        let data_period = self.period(
            &format!("{key}.data_period_ms"),
            raw.data_period_ms.unwrap_or(1000),
        );
        let command_qos = self.int_in(
            &format!("{key}.command_qos"),
            raw.command_qos.unwrap_or(1),
            0..=1,
            "",
        );
        let primary_host_id = match &raw.primary_host_id {
            Some(id) => self
                .sparkplug_id(&format!("{key}.primary_host_id"), id)
                .map(Some),
            None => Some(None),
        };
        let credentials = match (&raw.username, &raw.password) {
            (Some(user), Some(password)) => Some(Some((user.clone(), password.clone()))),
            (None, None) => Some(None),
            (Some(_), None) => {
                self.report.push(
                    format!("{key}.password"),
                    "missing: username and password are given together",
                );
                None
            }
            (None, Some(_)) => {
                self.report.push(
                    format!("{key}.username"),
                    "missing: username and password are given together",
                );
                None
            }
        };
        if !history {
            self.report.push(
                key,
                "needs [history]: the Sparkplug session number (bdSeq) is kept in the history file",
            );
            return None;
        }
        Some(MqttOutput {
            broker: broker?,
            group_id: group_id?,
            node_id: node_id?,
            client_id: client_id?,
            keep_alive: Duration::from_secs(u64::try_from(keep_alive?).ok()?),
            data_period: data_period?,
            command_qos: u8::try_from(command_qos?).ok()?,
            primary_host_id: primary_host_id?,
            credentials: credentials?,
        })
    }

    /// A Sparkplug group, node or device id: non-empty, none of `/ + #`.
    fn sparkplug_id(&mut self, key: &str, id: &str) -> Option<String> {
        if !crate::is_sparkplug_id(id) {
            self.report.push(
                key,
                format!("\"{id}\" is not allowed (must be non-empty, without / + or #)"),
            );
            None
        } else {
            Some(id.to_owned())
        }
    }
}
