//! `[[sources.modbus]]` and `[[sources.can]]` (the CAN source's DBC is read here).

use can_dbc::Dbc;

use crate::dbc::read_dbc;
use crate::raw::{RawCanSource, RawModbusSource};
use crate::{CanSource, ModbusSource};

use super::{Checker, DEFAULT_TIMEOUT_MS, MAX_INTERFACE_NAME};

impl Checker<'_> {
    pub(super) fn modbus_source(
        &mut self,
        index: usize,
        raw: &RawModbusSource,
    ) -> Option<ModbusSource> {
        let key = format!("sources.modbus[{index}]");
        let name = self.source_name(&key, &raw.name);
        let address = self.host_port(&format!("{key}.address"), &raw.address);
        let unit_id = self.unit_id(&format!("{key}.unit_id"), raw.unit_id);
        let poll_period = self.period(&format!("{key}.poll_period_ms"), raw.poll_period_ms);
        let timeout = self.period(
            &format!("{key}.timeout_ms"),
            raw.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS),
        );
        Some(ModbusSource {
            name: name?,
            address: address?,
            unit_id: unit_id?,
            poll_period: poll_period?,
            timeout: timeout?,
        })
    }

    /// A CAN source and its parsed DBC (read even when another field is bad, so the
    /// channels that use it can still be checked).
    pub(super) fn can_source(
        &mut self,
        index: usize,
        raw: &RawCanSource,
    ) -> (Option<CanSource>, Option<Dbc>) {
        let key = format!("sources.can[{index}]");
        let name = self.source_name(&key, &raw.name);
        let interface = if raw.interface.is_empty()
            || raw.interface.len() > MAX_INTERFACE_NAME
            || raw
                .interface
                .contains(|c: char| c == '/' || c.is_whitespace())
        {
            self.report.push(
                format!("{key}.interface"),
                format!(
                    "\"{}\" is not allowed (must be a network interface name of 1..={MAX_INTERFACE_NAME} \
                     bytes without spaces or '/', e.g. can0 or vcan0)",
                    raw.interface
                ),
            );
            None
        } else {
            Some(raw.interface.clone())
        };
        let dbc_key = format!("{key}.dbc");
        let dbc_path = self.existing_file(&dbc_key, &raw.dbc);
        let dbc = dbc_path.as_ref().and_then(|path| match read_dbc(path) {
            Ok(dbc) => Some(dbc),
            Err(message) => {
                self.report
                    .push(&dbc_key, format!("DBC file \"{}\": {message}", raw.dbc));
                None
            }
        });
        let source = (|| {
            Some(CanSource {
                name: name?,
                interface: interface?,
                dbc: dbc_path?,
            })
        })();
        (source, dbc)
    }
}
