//! `[[channels]]`: kind, unit, sample rate and where each channel is read (a Modbus
//! block or register, a CAN signal from the DBC); registers that overlap; poll periods
//! that keep up with the blocks; references to channels by name.

use std::collections::BTreeMap;

use crate::dbc::{signal_layout, SignalLookupError};
use crate::layout::{BLOCK_REGISTERS, MAX_BLOCK_SAMPLES};
use crate::raw::{RawChannel, RawChannelSource, RawModbusSource};
use crate::text::{ByteOrder, MAX_TEXT_REGISTERS};
use crate::{Channel, ChannelKind, ChannelSource, RegisterTable, ValueType, WordOrder};

use super::{format_ms, known_list, ChannelFacts, Checker, Sources, MAX_BLOCK_BASE};

/// The `type` of a text channel (a coil id in characters): not a [`ValueType`].
const TEXT_TYPE: &str = "ascii";

impl Checker<'_> {
    pub(super) fn channel(
        &mut self,
        key: &str,
        raw: &RawChannel,
        sources: &Sources<'_>,
    ) -> Option<Channel> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let kind = self.choice(
            &format!("{key}.kind"),
            "kind",
            &raw.kind,
            &ChannelKind::ALL,
            ChannelKind::name,
        );
        let unit = self.unit(key, raw, kind);
        let source_key = format!("{key}.source");
        let source = &raw.source;
        let (source, sample_rate_hz, scale, offset) = match (&source.modbus, &source.can) {
            (Some(modbus), None) => {
                let channel_source =
                    self.modbus_channel_source(&source_key, modbus, source, sources);
                let is_value = source.address.is_some() && source.block.is_none();
                let sample_rate_hz = match (is_value, raw.sample_rate_hz) {
                    (true, Some(_)) => {
                        self.report.push(
                            format!("{key}.sample_rate_hz"),
                            format!(
                                "not used for a register value: it is read at the poll rate of \
                                 source \"{modbus}\" (poll_period_ms); remove it"
                            ),
                        );
                        None
                    }
                    (true, None) => sources
                        .modbus
                        .iter()
                        .find(|source| source.name == *modbus)
                        .and_then(|source| {
                            (source.poll_period_ms > 0)
                                .then(|| 1000.0 / source.poll_period_ms as f64)
                        }),
                    (false, rate) => self.sample_rate(key, rate),
                };
                if matches!(channel_source, Some(ChannelSource::ModbusText { .. })) {
                    self.not_applicable(
                        key,
                        &[
                            ("scale", raw.scale.is_some()),
                            ("offset", raw.offset.is_some()),
                        ],
                        "a text channel (type = \"ascii\")",
                    );
                }
                let scale = raw.scale.unwrap_or(1.0);
                let scale = self.float(
                    &format!("{key}.scale"),
                    scale,
                    scale != 0.0,
                    "finite and non-zero",
                );
                let offset = self.float(
                    &format!("{key}.offset"),
                    raw.offset.unwrap_or(0.0),
                    true,
                    "finite",
                );
                (channel_source, sample_rate_hz, scale, offset)
            }
            (None, Some(can)) => {
                for (given, field) in [
                    (raw.scale.is_some(), "scale"),
                    (raw.offset.is_some(), "offset"),
                ] {
                    if given {
                        self.report.push(
                            format!("{key}.{field}"),
                            format!(
                                "not allowed on a CAN channel: the DBC's factor and offset \
                                 give the engineering value; remove {field}"
                            ),
                        );
                    }
                }
                let channel_source = self.can_channel_source(&source_key, can, source, sources);
                let sample_rate_hz = self.sample_rate(key, raw.sample_rate_hz);
                (channel_source, sample_rate_hz, Some(1.0), Some(0.0))
            }
            _ => {
                self.report.push(
                    source_key,
                    "must name exactly one source: modbus = \"<source>\" or can = \"<source>\"",
                );
                return None;
            }
        };
        Some(Channel {
            name: name?,
            kind: kind?,
            unit: unit?,
            scale: scale?,
            offset: offset?,
            sample_rate_hz: sample_rate_hz?,
            source: source?,
        })
    }

    /// The unit: non-empty, and `kN*m` for torque (thresholds are in kN*m).
    pub(super) fn unit(
        &mut self,
        key: &str,
        raw: &RawChannel,
        kind: Option<ChannelKind>,
    ) -> Option<String> {
        let unit_key = format!("{key}.unit");
        if raw.unit.trim().is_empty() {
            self.report.push(
                unit_key,
                "must not be empty (e.g. \"kN*m\", \"m/s^2\", \"1\")",
            );
            return None;
        }
        if kind == Some(ChannelKind::Torque) && raw.unit != "kN*m" {
            self.report.push(
                unit_key,
                format!(
                    "\"{}\" is not allowed for a torque channel (must be \"kN*m\"; convert \
                     with scale, e.g. scale = 0.001 for N*m counts)",
                    raw.unit
                ),
            );
            return None;
        }
        Some(raw.unit.clone())
    }

    pub(super) fn sample_rate(&mut self, key: &str, rate: Option<f64>) -> Option<f64> {
        let key = format!("{key}.sample_rate_hz");
        match rate {
            Some(rate) => self.float(&key, rate, rate > 0.0, "> 0 Hz"),
            None => {
                self.report
                    .push(key, "missing (the channel's sample rate, Hz)");
                None
            }
        }
    }

    /// Reports each key in `keys` that is given although it does not apply; `why`
    /// completes "does not apply to ...".
    pub(super) fn not_applicable(&mut self, key: &str, keys: &[(&str, bool)], why: &str) {
        for (field, given) in keys {
            if *given {
                self.report.push(
                    format!("{key}.{field}"),
                    format!("does not apply to {why}; remove it"),
                );
            }
        }
    }

    /// A Modbus block or register value.
    pub(super) fn modbus_channel_source(
        &mut self,
        key: &str,
        source_name: &str,
        raw: &RawChannelSource,
        sources: &Sources<'_>,
    ) -> Option<ChannelSource> {
        self.not_applicable(
            key,
            &[
                ("message", raw.message.is_some()),
                ("signal", raw.signal.is_some()),
            ],
            "a Modbus source (message and signal name CAN signals)",
        );
        let source = self.modbus_source_index(key, source_name, sources);
        let table = self.register_table(key, raw);
        match (raw.block, raw.address) {
            (Some(base), None) => self.block_source(key, raw, base, source, table),
            (None, Some(address)) => self.value_source(key, raw, address, source, table),
            _ => {
                self.report.push(
                    key,
                    "must give exactly one of block = <first register> (a millgate sample \
                     block) or address = <register> (a single value)",
                );
                None
            }
        }
    }

    /// The index of Modbus source `source_name`, reporting an unknown one (with a hint
    /// when it names a CAN source).
    fn modbus_source_index(
        &mut self,
        key: &str,
        source_name: &str,
        sources: &Sources<'_>,
    ) -> Option<usize> {
        let source = sources
            .modbus
            .iter()
            .position(|source| source.name == source_name);
        if source.is_none() {
            let hint = if sources.can.iter().any(|source| source.name == source_name) {
                format!(" (\"{source_name}\" is a CAN source: write can = \"{source_name}\")")
            } else {
                String::new()
            };
            let known: Vec<_> = sources
                .modbus
                .iter()
                .map(|source| source.name.as_str())
                .collect();
            self.report.push(
                format!("{key}.modbus"),
                format!(
                    "unknown Modbus source \"{source_name}\" ({}){hint}",
                    known_list(&known)
                ),
            );
        }
        source
    }

    /// `table`: `input` or `holding`.
    fn register_table(&mut self, key: &str, raw: &RawChannelSource) -> Option<RegisterTable> {
        match &raw.table {
            Some(table) => self.choice(
                &format!("{key}.table"),
                "register table",
                table,
                &RegisterTable::ALL,
                RegisterTable::name,
            ),
            None => {
                self.report.push(
                    format!("{key}.table"),
                    "missing (\"input\" for FC 04 input registers or \"holding\" for FC 03 holding registers)",
                );
                None
            }
        }
    }

    /// A millgate sample block starting at register `base` of `source`'s `table`.
    fn block_source(
        &mut self,
        key: &str,
        raw: &RawChannelSource,
        base: i64,
        source: Option<usize>,
        table: Option<RegisterTable>,
    ) -> Option<ChannelSource> {
        self.not_applicable(
            key,
            &[
                ("type", raw.value_type.is_some()),
                ("word_order", raw.word_order.is_some()),
                ("registers", raw.registers.is_some()),
                ("byte_order", raw.byte_order.is_some()),
            ],
            "a block (block samples are i16 in the millgate layout)",
        );
        let base = self.int_in(&format!("{key}.block"), base, 0..=MAX_BLOCK_BASE, "")?;
        Some(ChannelSource::ModbusBlock {
            source: source?,
            table: table?,
            base: u16::try_from(base).ok()?,
        })
    }

    /// A single value at register `address` of `source`'s `table`, with its type and
    /// word order.
    fn value_source(
        &mut self,
        key: &str,
        raw: &RawChannelSource,
        address: i64,
        source: Option<usize>,
        table: Option<RegisterTable>,
    ) -> Option<ChannelSource> {
        if raw.value_type.as_deref() == Some(TEXT_TYPE) {
            return self.text_source(key, raw, address, source, table);
        }
        self.not_applicable(
            key,
            &[
                ("registers", raw.registers.is_some()),
                ("byte_order", raw.byte_order.is_some()),
            ],
            "a number (only a text, type = \"ascii\", spans `registers` in a `byte_order`)",
        );
        let value_type = match &raw.value_type {
            Some(text) => self.choice(
                &format!("{key}.type"),
                "value type (a text is \"ascii\")",
                text,
                &ValueType::ALL,
                ValueType::name,
            ),
            None => Some(ValueType::U16),
        };
        let word_order = match &raw.word_order {
            Some(text) => self.choice(
                &format!("{key}.word_order"),
                "word order",
                text,
                &WordOrder::ALL,
                WordOrder::name,
            ),
            None => Some(WordOrder::Abcd),
        };
        let value_type = value_type?;
        let address = self.first_register(key, address, value_type.register_count())?;
        Some(ChannelSource::ModbusValue {
            source: source?,
            table: table?,
            address,
            value_type,
            word_order: word_order?,
        })
    }

    /// `address` (key `{key}.address`) as the first of `count` registers, all inside
    /// the table.
    fn first_register(&mut self, key: &str, address: i64, count: u16) -> Option<u16> {
        let last = 65_535 - i64::from(count) + 1;
        let address = self.int_in(&format!("{key}.address"), address, 0..=last, "")?;
        u16::try_from(address).ok()
    }

    /// A text (`type = "ascii"`) of `registers` registers from `address` of
    /// `source`'s `table`, in its byte order.
    fn text_source(
        &mut self,
        key: &str,
        raw: &RawChannelSource,
        address: i64,
        source: Option<usize>,
        table: Option<RegisterTable>,
    ) -> Option<ChannelSource> {
        self.not_applicable(
            key,
            &[("word_order", raw.word_order.is_some())],
            "a text (its registers are in text order; give byte_order = \"high_first\" or \
             \"low_first\")",
        );
        let registers_key = format!("{key}.registers");
        let registers = match raw.registers {
            Some(registers) => self.int_in(
                &registers_key,
                registers,
                1..=i64::from(MAX_TEXT_REGISTERS),
                " registers, two characters each",
            ),
            None => {
                self.report.push(
                    registers_key,
                    format!(
                        "missing (the registers the text spans, 1..={MAX_TEXT_REGISTERS}, two \
                         characters each)"
                    ),
                );
                None
            }
        };
        let byte_order = match &raw.byte_order {
            Some(text) => self.choice(
                &format!("{key}.byte_order"),
                "byte order",
                text,
                &ByteOrder::ALL,
                ByteOrder::name,
            ),
            None => Some(ByteOrder::default()),
        };
        let registers = u16::try_from(registers?).ok()?;
        let address = self.first_register(key, address, registers)?;
        Some(ChannelSource::ModbusText {
            source: source?,
            table: table?,
            address,
            registers,
            byte_order: byte_order?,
        })
    }

    pub(super) fn can_channel_source(
        &mut self,
        key: &str,
        source_name: &str,
        raw: &RawChannelSource,
        sources: &Sources<'_>,
    ) -> Option<ChannelSource> {
        self.not_applicable(
            key,
            &[
                ("table", raw.table.is_some()),
                ("block", raw.block.is_some()),
                ("address", raw.address.is_some()),
                ("type", raw.value_type.is_some()),
                ("word_order", raw.word_order.is_some()),
                ("registers", raw.registers.is_some()),
                ("byte_order", raw.byte_order.is_some()),
            ],
            "a CAN source (the DBC describes the signal)",
        );
        let message = raw.message.as_deref();
        let signal = raw.signal.as_deref();
        for (field, given) in [("message", message.is_some()), ("signal", signal.is_some())] {
            if !given {
                self.report.push(
                    format!("{key}.{field}"),
                    format!("missing (the DBC {field} name)"),
                );
            }
        }
        let Some(source) = sources
            .can
            .iter()
            .position(|source| source.name == source_name)
        else {
            let hint = if sources
                .modbus
                .iter()
                .any(|source| source.name == source_name)
            {
                format!(" (\"{source_name}\" is a Modbus source: write modbus = \"{source_name}\")")
            } else {
                String::new()
            };
            let known: Vec<_> = sources
                .can
                .iter()
                .map(|source| source.name.as_str())
                .collect();
            self.report.push(
                format!("{key}.can"),
                format!(
                    "unknown CAN source \"{source_name}\" ({}){hint}",
                    known_list(&known)
                ),
            );
            return None;
        };
        let (message, signal) = (message?, signal?);
        // An unreadable DBC has been reported on the source already.
        let dbc = sources.dbcs.get(source)?.as_ref()?;
        let dbc_name = &sources.can[source].dbc;
        match signal_layout(dbc, message, signal) {
            Ok(signal_layout) => Some(ChannelSource::Can {
                source,
                message: message.to_owned(),
                signal: signal.to_owned(),
                signal_layout,
            }),
            Err(SignalLookupError::UnknownMessage { known }) => {
                self.report.push(
                    format!("{key}.message"),
                    format!(
                        "unknown message \"{message}\" in {dbc_name} ({})",
                        known_list(&known.iter().map(String::as_str).collect::<Vec<_>>())
                    ),
                );
                None
            }
            Err(SignalLookupError::UnknownSignal { known }) => {
                self.report.push(
                    format!("{key}.signal"),
                    format!(
                        "unknown signal \"{signal}\" in message {message} of {dbc_name} ({})",
                        known_list(&known.iter().map(String::as_str).collect::<Vec<_>>())
                    ),
                );
                None
            }
            Err(SignalLookupError::Unsupported(why)) => {
                self.report.push(
                    format!("{key}.signal"),
                    format!("signal \"{signal}\" of message {message} in {dbc_name}: {why}"),
                );
                None
            }
        }
    }

    /// Two channels must not read overlapping registers of one table of one source.
    pub(super) fn register_overlaps(
        &mut self,
        raw: &[RawChannel],
        channels: &[Option<Channel>],
        modbus: &[RawModbusSource],
    ) {
        // (source, table name) -> [(first register, last register, channel index)]
        type Ranges = Vec<(u32, u32, usize)>;
        let mut ranges: BTreeMap<(usize, &str), Ranges> = BTreeMap::new();
        for (index, channel) in channels.iter().enumerate() {
            let Some(channel) = channel else { continue };
            let (source, table, first, count) = match channel.source {
                ChannelSource::ModbusBlock {
                    source,
                    table,
                    base,
                } => (source, table, base, BLOCK_REGISTERS),
                ChannelSource::ModbusValue {
                    source,
                    table,
                    address,
                    value_type,
                    ..
                } => (source, table, address, value_type.register_count()),
                ChannelSource::ModbusText {
                    source,
                    table,
                    address,
                    registers,
                    ..
                } => (source, table, address, registers),
                ChannelSource::Can { .. } => continue,
            };
            let first = u32::from(first);
            ranges.entry((source, table.name())).or_default().push((
                first,
                first + u32::from(count) - 1,
                index,
            ));
        }
        for ((source, table), mut list) in ranges {
            list.sort_unstable();
            for (position, &(first, last, index)) in list.iter().enumerate() {
                let Some(&(other_first, other_last, other)) = list[..position]
                    .iter()
                    .find(|(_, other_last, _)| *other_last >= first)
                else {
                    continue;
                };
                let field = match raw[index].source.block {
                    Some(_) => "block",
                    None => "address",
                };
                self.report.push(
                    format!("channels[{index}].source.{field}"),
                    format!(
                        "registers {first}..={last} overlap registers {other_first}..={other_last} \
                         of channel \"{}\" in the {} registers of source \"{}\"",
                        raw[other].name,
                        table,
                        modbus[source].name
                    ),
                );
            }
        }
    }

    /// A source must be polled faster than any of its block channels fills a block,
    /// else the DAQ overwrites blocks the gateway has not read.
    pub(super) fn block_poll_periods(
        &mut self,
        raw: &[RawChannel],
        channels: &[Option<Channel>],
        modbus: &[RawModbusSource],
    ) {
        for (index, channel) in channels.iter().enumerate() {
            let Some(Channel {
                sample_rate_hz,
                source: ChannelSource::ModbusBlock { source, .. },
                ..
            }) = channel
            else {
                continue;
            };
            let poll_period_ms = modbus[*source].poll_period_ms;
            let block_period_ms = f64::from(MAX_BLOCK_SAMPLES) * 1000.0 / sample_rate_hz;
            if poll_period_ms as f64 >= block_period_ms {
                self.report.push(
                    format!("sources.modbus[{source}].poll_period_ms"),
                    format!(
                        "{poll_period_ms} ms is not allowed (must be < {} ms: channel \"{}\" \
                         (channels[{index}]) fills a {MAX_BLOCK_SAMPLES}-sample block every {} ms \
                         at {sample_rate_hz} Hz, and slower polling loses blocks)",
                        format_ms(block_period_ms),
                        raw[index].name,
                        format_ms(block_period_ms)
                    ),
                );
            }
        }
    }

    /// Looks up the channel called `name` for the reference at `key`; checks its kind.
    pub(super) fn channel_ref(
        &mut self,
        key: &str,
        name: &str,
        facts: &ChannelFacts<'_>,
        want: ChannelKind,
    ) -> Option<usize> {
        let Some(index) = facts.names.iter().position(|known| *known == name) else {
            self.report.push(
                key,
                format!("unknown channel \"{name}\" ({})", known_list(&facts.names)),
            );
            return None;
        };
        // A channel that failed validation has been reported already.
        let channel = facts.channels[index].as_ref()?;
        if channel.kind != want {
            self.report.push(
                key,
                format!(
                    "channel \"{name}\" is a {} channel (must be {})",
                    channel.kind.name(),
                    want.name()
                ),
            );
            return None;
        }
        if matches!(channel.source, ChannelSource::ModbusText { .. }) && !key.ends_with(".coil") {
            self.report.push(
                key,
                format!(
                    "channel \"{name}\" is a text channel (type = \"ascii\"): allowed only as \
                     a context tag `coil` (context = {{ coil = \"{name}\" }}), not here"
                ),
            );
            return None;
        }
        Some(index)
    }
}
