//! `[[sources.modbus]]` (Modbus TCP, or RTU on a serial line with the load its poll
//! plan puts on the line) and `[[sources.can]]` (the CAN source's DBC is read here).

use std::ops::RangeInclusive;
use std::time::Duration;

use can_dbc::Dbc;

use crate::dbc::read_dbc;
use crate::layout::BLOCK_REGISTERS;
use crate::raw::{RawCanSource, RawModbusSource};
use crate::serial::{self, Parity, PollLoad, SerialLine};
use crate::{CanSource, Channel, ChannelSource, ModbusSource, MAX_REQUESTS_IN_FLIGHT};

use super::{format_ms, Checker, DEFAULT_TIMEOUT_MS, DEFAULT_UNIT_ID, MAX_INTERFACE_NAME};

/// Line rate of an RTU source when none is given (the specification's default), Bd.
pub(crate) const DEFAULT_BAUD_RATE: i64 = 19_200;
/// Line rates an RTU source may have, Bd.
const BAUD_RATES: RangeInclusive<i64> = 300..=1_000_000;
/// Longest inter-frame silence, us.
const MAX_INTER_FRAME_DELAY_US: i64 = 100_000;
/// Unit ids of RTU devices: 0 is the broadcast address, 248..=255 are reserved.
const RTU_UNIT_IDS: RangeInclusive<i64> = 1..=247;

impl Checker<'_> {
    pub(super) fn modbus_source(
        &mut self,
        index: usize,
        raw: &RawModbusSource,
    ) -> Option<ModbusSource> {
        let key = format!("sources.modbus[{index}]");
        let name = self.source_name(&key, &raw.name);
        let (address, serial) = match (&raw.address, &raw.device) {
            (Some(address), None) => {
                self.no_serial_settings(&key, raw);
                (
                    self.host_port(&format!("{key}.address"), address),
                    Some(None),
                )
            }
            (None, Some(device)) => (
                self.serial_device(&format!("{key}.device"), device),
                self.serial_line(&key, raw).map(Some),
            ),
            (address, _) => {
                self.report.push(
                    key.as_str(),
                    format!(
                        "{} (must have exactly one: address = \"host:port\" for Modbus TCP, \
                         or device = \"/dev/ttyUSB0\" for Modbus RTU on a serial line)",
                        if address.is_some() {
                            "both address and device are set"
                        } else {
                            "neither address nor device is set"
                        }
                    ),
                );
                (None, None)
            }
        };
        let unit_id_key = format!("{key}.unit_id");
        let unit_id = if raw.device.is_some() && raw.address.is_none() {
            // 0 is the broadcast address (no device answers it), 248..=255 reserved.
            self.int_in(
                &unit_id_key,
                raw.unit_id.unwrap_or(DEFAULT_UNIT_ID),
                RTU_UNIT_IDS,
                "",
            )
            .and_then(|id| u8::try_from(id).ok())
        } else {
            self.unit_id(&unit_id_key, raw.unit_id)
        };
        let poll_period = self.period(&format!("{key}.poll_period_ms"), raw.poll_period_ms);
        let timeout = self.period(
            &format!("{key}.timeout_ms"),
            raw.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS),
        );
        let requests_in_flight = self.int_in(
            &format!("{key}.requests_in_flight"),
            raw.requests_in_flight.unwrap_or(1),
            1..=MAX_REQUESTS_IN_FLIGHT,
            "",
        );
        if raw.device.is_some() && raw.requests_in_flight.is_some_and(|n| n > 1) {
            self.report.push(
                format!("{key}.requests_in_flight"),
                "only for a Modbus TCP source (address): a serial line carries one request at a time: remove it",
            );
        }
        Some(ModbusSource {
            name: name?,
            address: address?,
            serial: serial?,
            unit_id: unit_id?,
            poll_period: poll_period?,
            timeout: timeout?,
            requests_in_flight: usize::try_from(requests_in_flight?).ok()?,
        })
    }

    /// A TCP source's serial keys, each reported: they belong to `device`.
    fn no_serial_settings(&mut self, key: &str, raw: &RawModbusSource) {
        let serial_keys = [
            ("baud_rate", raw.baud_rate.is_some()),
            ("parity", raw.parity.is_some()),
            ("data_bits", raw.data_bits.is_some()),
            ("stop_bits", raw.stop_bits.is_some()),
            ("inter_frame_delay_us", raw.inter_frame_delay_us.is_some()),
        ];
        for (serial_key, _) in serial_keys.iter().filter(|(_, set)| *set) {
            self.report.push(
                format!("{key}.{serial_key}"),
                "only for a Modbus RTU source (device = \"/dev/...\"); a Modbus TCP source \
                 (address) has no serial line: remove it",
            );
        }
    }

    /// The serial device: an absolute path (it need not exist yet: a USB adapter may
    /// be plugged in later, and the reader retries).
    fn serial_device(&mut self, key: &str, device: &str) -> Option<String> {
        if device.starts_with('/') && !device.contains(|c: char| c.is_control()) {
            Some(device.to_owned())
        } else {
            self.report.push(
                key,
                format!(
                    "{device:?} is not allowed (must be the absolute path of a serial device, \
                     e.g. /dev/ttyUSB0, /dev/ttyAMA0 or /dev/serial/by-id/...)"
                ),
            );
            None
        }
    }

    /// The line settings of an RTU source, defaults per the Modbus serial line
    /// specification: 19 200 Bd, even parity, 8 data bits, 1 stop bit with a parity
    /// bit and 2 without, 3.5 character times of silence (1.75 ms above 19 200 Bd).
    fn serial_line(&mut self, key: &str, raw: &RawModbusSource) -> Option<SerialLine> {
        let baud_rate = self.int_in(
            &format!("{key}.baud_rate"),
            raw.baud_rate.unwrap_or(DEFAULT_BAUD_RATE),
            BAUD_RATES,
            " Bd",
        );
        let parity = match raw.parity.as_deref() {
            None => Some(Parity::Even),
            Some(text) => self.choice(
                &format!("{key}.parity"),
                "parity",
                text,
                &Parity::ALL,
                Parity::name,
            ),
        };
        let data_bits = raw.data_bits.unwrap_or(8);
        if data_bits != 8 {
            self.report.push(
                format!("{key}.data_bits"),
                format!("{data_bits} is not allowed (must be 8: Modbus RTU sends 8-bit bytes)"),
            );
        }
        let default_stop_bits = if parity == Some(Parity::None) { 2 } else { 1 };
        let stop_bits = self.int_in(
            &format!("{key}.stop_bits"),
            raw.stop_bits.unwrap_or(default_stop_bits),
            1..=2,
            "",
        );
        let (baud_rate, parity, stop_bits) = (
            u32::try_from(baud_rate?).ok()?,
            parity?,
            u8::try_from(stop_bits?).ok()?,
        );
        if data_bits != 8 {
            return None;
        }
        let character_bits = serial::character_bits(parity, 8, stop_bits);
        let shortest = SerialLine::min_inter_frame_delay(baud_rate, character_bits);
        // Whole microseconds, rounded up: never below the specification's silence.
        let shortest_us = shortest.as_nanos().div_ceil(1000) as i64;
        let inter_frame_delay_us = self.int_in(
            &format!("{key}.inter_frame_delay_us"),
            raw.inter_frame_delay_us.unwrap_or(shortest_us),
            shortest_us..=MAX_INTER_FRAME_DELAY_US,
            &format!(
                " us; at least {}",
                if baud_rate > serial::FIXED_DELAY_ABOVE_BAUD {
                    format!(
                        "the fixed 1.75 ms above {} Bd",
                        serial::FIXED_DELAY_ABOVE_BAUD
                    )
                } else {
                    format!("3.5 characters of {character_bits} bits at {baud_rate} Bd")
                }
            ),
        )?;
        Some(SerialLine {
            baud_rate,
            parity,
            data_bits: 8,
            stop_bits,
            inter_frame_delay: Duration::from_micros(u64::try_from(inter_frame_delay_us).ok()?),
        })
    }

    /// Over RTU: refuses a poll plan the line cannot carry (its frames and silences
    /// per second above the baud rate) and a timeout shorter than the longest read
    /// takes on the line, with the arithmetic.
    pub(super) fn serial_loads(
        &mut self,
        sources: &[Option<ModbusSource>],
        channels: &[Option<Channel>],
    ) {
        for (index, source) in sources.iter().enumerate() {
            let Some(ModbusSource {
                serial: Some(line),
                poll_period,
                timeout,
                ..
            }) = source
            else {
                continue;
            };
            let reads: Vec<u16> = channels
                .iter()
                .flatten()
                .filter_map(|channel| match channel.source {
                    ChannelSource::ModbusBlock { source, .. } if source == index => {
                        Some(BLOCK_REGISTERS)
                    }
                    ChannelSource::ModbusValue {
                        source, value_type, ..
                    } if source == index => Some(value_type.register_count()),
                    ChannelSource::ModbusText {
                        source, registers, ..
                    } if source == index => Some(registers),
                    _ => None,
                })
                .collect();
            let key = format!("sources.modbus[{index}]");
            if let Some(&longest) = reads.iter().max() {
                let read_time = line.read_time(longest);
                if *timeout <= read_time {
                    self.report.push(
                        format!("{key}.timeout_ms"),
                        format!(
                            "{} ms is not allowed (must be > {} ms: a read of {longest} registers \
                             holds the line that long at {} Bd {})",
                            timeout.as_millis(),
                            format_ms(read_time.as_secs_f64() * 1e3),
                            line.baud_rate,
                            line.format()
                        ),
                    );
                }
            }
            let load = PollLoad {
                line: *line,
                reads,
                poll_period: *poll_period,
            };
            if !load.fits() {
                self.report.push(
                    format!("{key}.poll_period_ms"),
                    format!(
                        "{} ms is not allowed at {} Bd (must be >= {} ms, or the baud rate higher): \
                         {load}",
                        poll_period.as_millis(),
                        line.baud_rate,
                        load.poll_time().as_millis() + 1,
                    ),
                );
            }
        }
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
