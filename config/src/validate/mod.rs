//! [`RawConfig`] to [`Config`]: defaults, ranges, names, references and DBC lookups.
//!
//! Every check reports into the [`Report`] and carries on, so one run lists every
//! problem. Each check returns `Option`: `None` means "reported, no value"; the final
//! [`Config`] is only handed out when the report is empty, and then every value is
//! present.

use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::time::Duration;

use can_dbc::Dbc;

use crate::dbc::{read_dbc, signal_layout, SignalLookupError};
use crate::error::Report;
use crate::layout::{BLOCK_REGISTERS, MAX_BLOCK_SAMPLES};
use crate::raw::{
    RawCanSource, RawChannel, RawChannelSource, RawConfig, RawDriveline, RawModbusSource,
    RawOutputs, RawTandemMill,
};
use crate::{
    BiteSettings, CanSource, Channel, ChannelKind, ChannelSource, Config, Driveline,
    DrivelineThresholds, MetricsOutput, ModbusSource, Outputs, PlcOutput, RegisterTable,
    ServerOutput, TandemMill, ValueType, WordOrder,
};

/// Modbus unit identifier when none is given.
pub(crate) const DEFAULT_UNIT_ID: i64 = 1;
/// Modbus request timeout when none is given, ms.
pub(crate) const DEFAULT_TIMEOUT_MS: i64 = 1000;
/// Allowed poll, write and timeout periods, ms.
const PERIOD_RANGE_MS: RangeInclusive<i64> = 1..=60_000;
/// Bite capture before the trigger when none is given, s.
pub(crate) const DEFAULT_PRE_TRIGGER_S: f64 = 0.1;
/// Bite capture after the trigger when none is given, s.
pub(crate) const DEFAULT_POST_TRIGGER_S: f64 = 0.5;
/// Longest bite capture window and chatter window, s.
const MAX_WINDOW_S: f64 = 10.0;
/// Prometheus endpoint when `[outputs.metrics]` has no `bind`.
pub(crate) const DEFAULT_METRICS_BIND: &str = "127.0.0.1:9187";
/// Stands a tandem mill may have.
const STANDS_RANGE: RangeInclusive<usize> = 2..=8;
/// Longest Linux network interface name, bytes (IFNAMSIZ - 1).
const MAX_INTERFACE_NAME: usize = 15;
/// Highest first register of a block: the block must end by register 65535.
const MAX_BLOCK_BASE: i64 = 65_536 - BLOCK_REGISTERS as i64;

/// Validates `raw`; paths are resolved against `base_dir`.
pub(crate) fn validate(raw: RawConfig, base_dir: &Path, report: &mut Report) -> Option<Config> {
    let mut checker = Checker {
        base_dir,
        report,
        source_names: HashMap::new(),
    };
    let name = checker.name("name", &raw.name);
    let modbus_sources: Vec<_> = raw
        .modbus_sources
        .iter()
        .enumerate()
        .map(|(index, source)| checker.modbus_source(index, source))
        .collect();
    let (can_sources, dbcs): (Vec<_>, Vec<_>) = raw
        .can_sources
        .iter()
        .enumerate()
        .map(|(index, source)| checker.can_source(index, source))
        .unzip();
    let sources = Sources {
        modbus: &raw.modbus_sources,
        can: &raw.can_sources,
        dbcs: &dbcs,
    };
    let channels = checker.named_list(
        "channels",
        "channel",
        &raw.channels,
        |channel| &channel.name,
        |checker, key, channel| checker.channel(key, channel, &sources),
    );
    checker.register_overlaps(&raw.channels, &channels, &raw.modbus_sources);
    checker.block_poll_periods(&raw.channels, &channels, &raw.modbus_sources);
    let channel_facts = ChannelFacts {
        names: raw
            .channels
            .iter()
            .map(|channel| channel.name.as_str())
            .collect(),
        channels: &channels,
    };
    let drivelines = checker.named_list(
        "drivelines",
        "driveline",
        &raw.drivelines,
        |driveline| &driveline.name,
        |checker, key, driveline| checker.driveline(key, driveline, &channel_facts),
    );
    let tandem_mills = checker.named_list(
        "tandem_mills",
        "tandem mill",
        &raw.tandem_mills,
        |mill| &mill.name,
        |checker, key, mill| checker.tandem_mill(key, mill, &channel_facts),
    );
    let outputs = checker.outputs(&raw.outputs);
    Some(Config {
        name: name?,
        modbus_sources: modbus_sources.into_iter().collect::<Option<_>>()?,
        can_sources: can_sources.into_iter().collect::<Option<_>>()?,
        channels: channels.into_iter().collect::<Option<_>>()?,
        drivelines: drivelines.into_iter().collect::<Option<_>>()?,
        tandem_mills: tandem_mills.into_iter().collect::<Option<_>>()?,
        outputs: outputs?,
    })
}

/// The raw sources and the parsed DBC of each CAN source (`None` when unreadable).
struct Sources<'a> {
    modbus: &'a [RawModbusSource],
    can: &'a [RawCanSource],
    dbcs: &'a [Option<Dbc>],
}

/// What drivelines and mills need to know about channels: names (even of channels
/// that failed validation, so references to them are not reported twice) and the
/// validated channels.
struct ChannelFacts<'a> {
    names: Vec<&'a str>,
    channels: &'a [Option<Channel>],
}

/// Names seen so far in one list, to report duplicates.
struct Names {
    what: &'static str,
    first_key: HashMap<String, String>,
}

impl Names {
    fn new(what: &'static str) -> Self {
        Names {
            what,
            first_key: HashMap::new(),
        }
    }

    /// Records `name` of the element at `key`, reporting a duplicate.
    fn add(&mut self, checker: &mut Checker<'_>, key: &str, name: &str) {
        if let Some(first) = self.first_key.get(name) {
            checker.report.push(
                format!("{key}.name"),
                format!(
                    "duplicate {} name \"{name}\" (already used by {first})",
                    self.what
                ),
            );
        } else {
            self.first_key.insert(name.to_owned(), key.to_owned());
        }
    }
}

struct Checker<'a> {
    base_dir: &'a Path,
    report: &'a mut Report,
    /// Source name -> key of the source that first used it (Modbus and CAN share
    /// one namespace).
    source_names: HashMap<String, String>,
}

impl Checker<'_> {
    /// Checks each item of the list at `list_key` with `check`, given the item's key
    /// (`channels[2]`), and reports a name used twice; `what` names the kind of item.
    fn named_list<T, U>(
        &mut self,
        list_key: &str,
        what: &'static str,
        items: &[T],
        name: impl Fn(&T) -> &str,
        mut check: impl FnMut(&mut Self, &str, &T) -> Option<U>,
    ) -> Vec<Option<U>> {
        let mut names = Names::new(what);
        items
            .iter()
            .enumerate()
            .map(|(index, item)| {
                let key = format!("{list_key}[{index}]");
                names.add(self, &key, name(item));
                check(self, &key, item)
            })
            .collect()
    }

    /// A non-empty name.
    fn name(&mut self, key: &str, name: &str) -> Option<String> {
        if name.trim().is_empty() {
            self.report.push(key, "must not be empty");
            None
        } else {
            Some(name.to_owned())
        }
    }

    /// A source name, unique across `[[sources.modbus]]` and `[[sources.can]]`.
    fn source_name(&mut self, key: &str, name: &str) -> Option<String> {
        let name_key = format!("{key}.name");
        let name = self.name(&name_key, name)?;
        if let Some(first) = self.source_names.get(&name) {
            self.report.push(
                name_key,
                format!("duplicate source name \"{name}\" (already used by {first})"),
            );
            return None;
        }
        self.source_names.insert(name.clone(), key.to_owned());
        Some(name)
    }

    /// An integer within `range`; `unit` is appended to the allowed range.
    fn int_in(
        &mut self,
        key: &str,
        value: i64,
        range: RangeInclusive<i64>,
        unit: &str,
    ) -> Option<i64> {
        if range.contains(&value) {
            Some(value)
        } else {
            self.report.push(
                key,
                format!(
                    "{value} is not allowed (must be {}..={}{unit})",
                    range.start(),
                    range.end()
                ),
            );
            None
        }
    }

    fn unit_id(&mut self, key: &str, value: Option<i64>) -> Option<u8> {
        let value = self.int_in(key, value.unwrap_or(DEFAULT_UNIT_ID), 0..=255, "")?;
        u8::try_from(value).ok()
    }

    fn period(&mut self, key: &str, value_ms: i64) -> Option<Duration> {
        let value_ms = self.int_in(key, value_ms, PERIOD_RANGE_MS, " ms")?;
        Some(Duration::from_millis(u64::try_from(value_ms).ok()?))
    }

    /// A finite float for which `allowed` holds; `rule` says what is allowed.
    fn float(&mut self, key: &str, value: f64, allowed: bool, rule: &str) -> Option<f64> {
        if value.is_finite() && allowed {
            Some(value)
        } else {
            self.report
                .push(key, format!("{value} is not allowed (must be {rule})"));
            None
        }
    }

    /// `host:port` with a port 1..=65535, kept as written (resolved at connect time).
    fn host_port(&mut self, key: &str, address: &str) -> Option<String> {
        let valid = match address.rsplit_once(':') {
            Some((host, port)) => {
                let host_ok = if let Some(inner) = host
                    .strip_prefix('[')
                    .and_then(|host| host.strip_suffix(']'))
                {
                    inner.parse::<std::net::Ipv6Addr>().is_ok()
                } else {
                    !host.is_empty() && !host.contains(|c: char| c == ':' || c.is_whitespace())
                };
                host_ok && port.parse::<u16>().is_ok_and(|port| port > 0)
            }
            None => false,
        };
        if valid {
            Some(address.to_owned())
        } else {
            self.report.push(
                key,
                format!(
                    "\"{address}\" is not allowed (must be host:port with a port 1..=65535, \
                     e.g. 192.168.0.10:502 or plc1.local:502)"
                ),
            );
            None
        }
    }

    /// An IP socket address to listen on.
    fn bind(&mut self, key: &str, address: &str) -> Option<SocketAddr> {
        match address.parse() {
            Ok(address) => Some(address),
            Err(_) => {
                self.report.push(
                    key,
                    format!(
                        "\"{address}\" is not allowed (must be an IP address and port, \
                         e.g. 0.0.0.0:502 or 127.0.0.1:5503)"
                    ),
                );
                None
            }
        }
    }

    /// A file relative to the configuration file's directory that must exist.
    fn existing_file(&mut self, key: &str, relative: &str) -> Option<PathBuf> {
        let path = self.base_dir.join(relative);
        if path.is_file() {
            Some(path)
        } else {
            self.report.push(
                key,
                format!(
                    "file \"{relative}\" not found (looked for {}; paths are relative to \
                     the configuration file)",
                    path.display()
                ),
            );
            None
        }
    }

    /// One of `all` by its file spelling, else a problem listing the spellings.
    fn choice<T: Copy>(
        &mut self,
        key: &str,
        what: &str,
        text: &str,
        all: &[T],
        name: fn(T) -> &'static str,
    ) -> Option<T> {
        let found = all.iter().copied().find(|&item| name(item) == text);
        if found.is_none() {
            let allowed: Vec<_> = all.iter().map(|&item| name(item)).collect();
            self.report.push(
                key,
                format!(
                    "unknown {what} \"{text}\" (allowed: {})",
                    allowed.join(", ")
                ),
            );
        }
        found
    }

    fn modbus_source(&mut self, index: usize, raw: &RawModbusSource) -> Option<ModbusSource> {
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
    fn can_source(&mut self, index: usize, raw: &RawCanSource) -> (Option<CanSource>, Option<Dbc>) {
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

    fn channel(&mut self, key: &str, raw: &RawChannel, sources: &Sources<'_>) -> Option<Channel> {
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
    fn unit(&mut self, key: &str, raw: &RawChannel, kind: Option<ChannelKind>) -> Option<String> {
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

    fn sample_rate(&mut self, key: &str, rate: Option<f64>) -> Option<f64> {
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
    fn not_applicable(&mut self, key: &str, keys: &[(&str, bool)], why: &str) {
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
    fn modbus_channel_source(
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
        let table = match &raw.table {
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
        };
        let channel_source = match (raw.block, raw.address) {
            (Some(base), None) => {
                self.not_applicable(
                    key,
                    &[
                        ("type", raw.value_type.is_some()),
                        ("word_order", raw.word_order.is_some()),
                    ],
                    "a block (block samples are i16 in the millgate layout)",
                );
                let base = self.int_in(&format!("{key}.block"), base, 0..=MAX_BLOCK_BASE, "")?;
                ChannelSource::ModbusBlock {
                    source: source?,
                    table: table?,
                    base: u16::try_from(base).ok()?,
                }
            }
            (None, Some(address)) => {
                let value_type = match &raw.value_type {
                    Some(text) => self.choice(
                        &format!("{key}.type"),
                        "value type",
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
                let last = 65_535 - i64::from(value_type.register_count()) + 1;
                let address = self.int_in(&format!("{key}.address"), address, 0..=last, "")?;
                ChannelSource::ModbusValue {
                    source: source?,
                    table: table?,
                    address: u16::try_from(address).ok()?,
                    value_type,
                    word_order: word_order?,
                }
            }
            _ => {
                self.report.push(
                    key,
                    "must give exactly one of block = <first register> (a millgate sample \
                     block) or address = <register> (a single value)",
                );
                return None;
            }
        };
        Some(channel_source)
    }

    fn can_channel_source(
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
    fn register_overlaps(
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
    fn block_poll_periods(
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
    fn channel_ref(
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
        Some(index)
    }

    fn driveline(
        &mut self,
        key: &str,
        raw: &RawDriveline,
        facts: &ChannelFacts<'_>,
    ) -> Option<Driveline> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let torque = self.channel_ref(
            &format!("{key}.torque"),
            &raw.torque,
            facts,
            ChannelKind::Torque,
        );
        let metal_in_stand = optional(raw.metal_in_stand.as_ref().map(|channel| {
            self.channel_ref(
                &format!("{key}.metal_in_stand"),
                channel,
                facts,
                ChannelKind::ProcessValue,
            )
        }));
        let model = optional(
            raw.model
                .as_ref()
                .map(|model| self.existing_file(&format!("{key}.model"), model)),
        );
        let bite_key = format!("{key}.bite");
        let threshold_knm = self.float(
            &format!("{bite_key}.threshold_knm"),
            raw.bite.threshold_knm,
            raw.bite.threshold_knm > 0.0,
            "> 0 kN*m",
        );
        let pre_trigger_s = raw.bite.pre_trigger_s.unwrap_or(DEFAULT_PRE_TRIGGER_S);
        let pre_trigger_s = self.float(
            &format!("{bite_key}.pre_trigger_s"),
            pre_trigger_s,
            (0.0..=MAX_WINDOW_S).contains(&pre_trigger_s),
            &format!("0..={MAX_WINDOW_S} s"),
        );
        let post_trigger_s = raw.bite.post_trigger_s.unwrap_or(DEFAULT_POST_TRIGGER_S);
        let post_trigger_s = self.float(
            &format!("{bite_key}.post_trigger_s"),
            post_trigger_s,
            post_trigger_s > 0.0 && post_trigger_s <= MAX_WINDOW_S,
            &format!("> 0 and <= {MAX_WINDOW_S} s"),
        );
        let thresholds_key = format!("{key}.thresholds");
        let taf_warning = raw.thresholds.taf_warning;
        let taf_warning = self.float(
            &format!("{thresholds_key}.taf_warning"),
            taf_warning,
            taf_warning > 1.0,
            "> 1: TAF is peak over static torque",
        );
        let taf_alarm = raw.thresholds.taf_alarm;
        let taf_alarm = self.float(
            &format!("{thresholds_key}.taf_alarm"),
            taf_alarm,
            taf_warning.is_none_or(|warning| taf_alarm >= warning),
            &format!(">= taf_warning = {}", raw.thresholds.taf_warning),
        );
        Some(Driveline {
            name: name?,
            torque: torque?,
            metal_in_stand: metal_in_stand?,
            model: model?,
            bite: BiteSettings {
                threshold_knm: threshold_knm?,
                pre_trigger_s: pre_trigger_s?,
                post_trigger_s: post_trigger_s?,
            },
            thresholds: DrivelineThresholds {
                taf_warning: taf_warning?,
                taf_alarm: taf_alarm?,
            },
        })
    }

    fn tandem_mill(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        facts: &ChannelFacts<'_>,
    ) -> Option<TandemMill> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let stands_key = format!("{key}.stands");
        let mut stands_ok = true;
        if !STANDS_RANGE.contains(&raw.stands.len()) {
            self.report.push(
                &stands_key,
                format!(
                    "{} stands is not allowed (must be {}..={} stand channels)",
                    raw.stands.len(),
                    STANDS_RANGE.start(),
                    STANDS_RANGE.end()
                ),
            );
            stands_ok = false;
        }
        let mut stands = Vec::with_capacity(raw.stands.len());
        for (position, stand) in raw.stands.iter().enumerate() {
            let stand_key = format!("{stands_key}[{position}]");
            if raw.stands[..position].contains(stand) {
                self.report
                    .push(stand_key, format!("channel \"{stand}\" is listed twice"));
                stands_ok = false;
                continue;
            }
            match self.channel_ref(&stand_key, stand, facts, ChannelKind::Acceleration) {
                Some(index) => stands.push(index),
                None => stands_ok = false,
            }
        }
        // One chatter window spans all stands sample for sample: one rate for all.
        let resolved = || {
            stands
                .iter()
                .filter_map(|&index| facts.channels[index].as_ref())
        };
        if let Some(first) = resolved().next() {
            if let Some(other) = resolved().find(|c| c.sample_rate_hz != first.sample_rate_hz) {
                self.report.push(
                    &stands_key,
                    format!(
                        "stand channels \"{}\" ({} Hz) and \"{}\" ({} Hz) sample at different \
                         rates (must share one: the stands are compared sample for sample)",
                        first.name, first.sample_rate_hz, other.name, other.sample_rate_hz
                    ),
                );
                stands_ok = false;
            }
        }
        let band_key = format!("{key}.chatter_band_hz");
        let band = match raw.chatter_band_hz[..] {
            [low, high] if low.is_finite() && high.is_finite() && 0.0 < low && low < high => {
                Some((low, high))
            }
            _ => {
                self.report.push(
                    &band_key,
                    format!(
                        "{:?} is not allowed (must be [low, high] with 0 < low < high, Hz)",
                        raw.chatter_band_hz
                    ),
                );
                None
            }
        };
        if let Some(((_, high), channel)) = band.zip(resolved().next()) {
            let nyquist_hz = channel.sample_rate_hz / 2.0;
            if high >= nyquist_hz {
                self.report.push(
                    &band_key,
                    format!(
                        "upper edge {high} Hz is not allowed (must be < {nyquist_hz} Hz, half \
                         the {} Hz sample rate of stand channel \"{}\")",
                        channel.sample_rate_hz, channel.name
                    ),
                );
            }
        }
        let window_s = self.float(
            &format!("{key}.window_s"),
            raw.window_s,
            raw.window_s > 0.0 && raw.window_s <= MAX_WINDOW_S,
            &format!("> 0 and <= {MAX_WINDOW_S} s"),
        );
        let k_max = self.float(
            &format!("{key}.k_max"),
            raw.k_max,
            raw.k_max > 0.0 && raw.k_max < 1.0,
            "> 0 and < 1, a correlation coefficient; typically 0.2..0.3",
        );
        Some(TandemMill {
            name: name?,
            stands: stands_ok.then_some(stands)?,
            chatter_band_hz: band?,
            window_s: window_s?,
            k_max: k_max?,
        })
    }

    fn outputs(&mut self, raw: &RawOutputs) -> Option<Outputs> {
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

/// An optional setting after its check: absent stays absent (`Some(None)`), a
/// setting that failed its check (`Some(None)` inside) becomes `None`.
fn optional<T>(checked: Option<Option<T>>) -> Option<Option<T>> {
    match checked {
        None => Some(None),
        Some(None) => None,
        Some(Some(value)) => Some(Some(value)),
    }
}

/// `known: a, b` or `none defined`.
fn known_list(names: &[&str]) -> String {
    if names.is_empty() {
        "none defined".to_owned()
    } else {
        format!("known: {}", names.join(", "))
    }
}

/// Milliseconds with at most three decimals and no trailing zeros.
fn format_ms(value_ms: f64) -> String {
    let text = format!("{value_ms:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_owned()
}
