//! [`RawConfig`] to [`Config`]: defaults, ranges, names, references and DBC lookups.
//!
//! Every check reports into the [`Report`] and carries on, so one run lists every
//! problem. Each check returns `Option`: `None` means "reported, no value"; the final
//! [`Config`] is only handed out when the report is empty, and then every value is
//! present.
//!
//! One file per part of the configuration: `sources`, `channels`, `drivelines`,
//! `tandem_mills`, `rod_mills`, `outputs` (with `opcua`), `history`; `values` holds the checks of
//! single values they share.

use std::collections::HashMap;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use can_dbc::Dbc;

use crate::error::Report;
use crate::layout::BLOCK_REGISTERS;
use crate::raw::{RawCanSource, RawConfig, RawModbusSource};
use crate::{
    AnalysisSettings, Channel, Config, Driveline, LogFormat, ModbusSource, RodMill, ServiceDirs,
    TandemMill, CACHE_DIRECTORY,
};

/// What the gateway writes at a configured path, and so which service folder a
/// relative path of it is resolved against.
#[derive(Debug, Clone, Copy)]
enum Written {
    /// `history.path`, `outputs.opcua.pki_dir`: `$STATE_DIRECTORY` (`StateDirectory=`).
    State,
    /// `cache_dir`: `$CACHE_DIRECTORY` (`CacheDirectory=`).
    Cache,
}

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
/// HMI clients the Modbus server serves at once when `max_connections` is not given.
pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 8;
/// Connections one HMI address may hold when `max_connections_per_peer` is not given
/// (at most `max_connections`).
pub(crate) const DEFAULT_MAX_CONNECTIONS_PER_PEER: usize = 4;
/// Idle time after which the Modbus server closes a connection, when not given, ms.
pub(crate) const DEFAULT_IDLE_TIMEOUT_MS: u64 = 60_000;
/// Prometheus endpoint when `[outputs.metrics]` has no `bind`.
pub(crate) const DEFAULT_METRICS_BIND: &str = "127.0.0.1:9187";
/// Default `outputs.web.bind`: loopback only.
pub(crate) const DEFAULT_WEB_BIND: &str = "127.0.0.1:8080";
/// Stands a tandem mill may have.
const STANDS_RANGE: RangeInclusive<usize> = 2..=8;
/// Most driveline slots: 16 global registers and 64 per slot (its block and its
/// extension block) fill the 65 536 registers a Modbus table addresses.
const MAX_DRIVELINE_SLOTS: i64 = 1022;
/// Longest Linux network interface name, bytes (IFNAMSIZ - 1).
const MAX_INTERFACE_NAME: usize = 15;
/// Highest first register of a block: the block must end by register 65535.
const MAX_BLOCK_BASE: i64 = 65_536 - BLOCK_REGISTERS as i64;

/// What a configuration is loaded for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Purpose {
    /// Running the service (or checking it): every key it needs.
    Service,
    /// Commissioning a tandem mill's chatter thresholds: `gain_thresholds` may be
    /// missing (they are what commissioning computes).
    Commissioning,
}

/// Validates `raw` for `purpose`; paths are resolved against `base_dir`, those of
/// files the gateway writes against the service folders `dirs` where set.
pub(crate) fn validate(
    raw: RawConfig,
    base_dir: &Path,
    dirs: &ServiceDirs,
    report: &mut Report,
    purpose: Purpose,
) -> Option<Config> {
    let mut checker = Checker {
        base_dir,
        dirs,
        report,
        source_names: HashMap::new(),
        purpose,
    };
    let name = checker.name("name", &raw.name);
    let gateway_identification = checker.identification(
        "gateway.identification",
        raw.gateway.identification.as_ref(),
    );
    let cache_dir = cache_dir(&mut checker, raw.cache_dir.as_deref());
    let log_format = match &raw.log_format {
        Some(text) => checker.choice(
            "log_format",
            "format",
            text,
            &LogFormat::ALL,
            LogFormat::name,
        ),
        None => Some(LogFormat::default()),
    };
    let analysis = raw
        .analysis
        .workers
        .map_or(Some(0), |workers| {
            checker.int_in(
                "analysis.workers",
                workers,
                AnalysisSettings::WORKERS_RANGE,
                " threads, 0 = one per core",
            )
        })
        .map(|workers| AnalysisSettings {
            workers: workers as usize,
        });
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
    let channels = channels(&mut checker, &raw, &sources, &modbus_sources);
    let channel_facts = ChannelFacts {
        names: raw
            .channels
            .iter()
            .map(|channel| channel.name.as_str())
            .collect(),
        channels: &channels,
    };
    let watched = watched(&mut checker, &raw, &channel_facts);
    let history_path = raw
        .history
        .as_ref()
        .map(|history| base_dir.join(&history.path));
    let outputs = checker.outputs(&raw.outputs, history_path.as_deref());
    if let Some(slots) = raw.outputs.driveline_slots {
        let drivelines = raw.drivelines.len();
        if (1..=MAX_DRIVELINE_SLOTS).contains(&slots) && (slots as usize) < drivelines {
            checker.report.push(
                "outputs.driveline_slots",
                format!(
                    "{slots} is fewer than the {drivelines} drivelines configured (must be \
                     {drivelines}..={}: a register block each; raise it, or leave it out for \
                     exactly the drivelines)",
                    MAX_DRIVELINE_SLOTS
                ),
            );
        }
    }
    let history = raw.history.as_ref().map(|history| checker.history(history));
    Some(Config {
        name: name?,
        gateway_identification: gateway_identification?,
        cache_dir: cache_dir?,
        log_format: log_format?,
        analysis: analysis?,
        modbus_sources: modbus_sources.into_iter().collect::<Option<_>>()?,
        can_sources: can_sources.into_iter().collect::<Option<_>>()?,
        channels: channels.into_iter().collect::<Option<_>>()?,
        drivelines: watched.drivelines.into_iter().collect::<Option<_>>()?,
        tandem_mills: watched.tandem_mills.into_iter().collect::<Option<_>>()?,
        rod_mills: watched.rod_mills.into_iter().collect::<Option<_>>()?,
        outputs: outputs?,
        history: optional(history)?,
        // The text's, set by `parse_and_validate`, which has it.
        hash: String::new(),
    })
}

/// `cache_dir`: `None` when reported; `Some(None)` leaves it to the service folder
/// (`dirs.cache`) or the user's cache folder.
fn cache_dir(checker: &mut Checker<'_>, raw: Option<&str>) -> Option<Option<PathBuf>> {
    let dirs = checker.dirs;
    match raw {
        None => Some(dirs.cache.clone()),
        Some(dir) if dir.trim().is_empty() => {
            checker.report.push(
                "cache_dir",
                format!(
                    "must not be empty (leave it out for ${CACHE_DIRECTORY} under systemd, \
                     else the user's cache folder)"
                ),
            );
            None
        }
        Some(dir) => Some(Some(checker.written_path(dir, Written::Cache).0)),
    }
}

/// `[[channels]]`, then the checks across them: overlapping registers, block poll
/// periods, the serial lines' load.
fn channels(
    checker: &mut Checker<'_>,
    raw: &RawConfig,
    sources: &Sources<'_>,
    modbus_sources: &[Option<ModbusSource>],
) -> Vec<Option<Channel>> {
    let channels = checker.named_list(
        "channels",
        "channel",
        &raw.channels,
        |channel| &channel.name,
        |checker, key, channel| checker.channel(key, channel, sources),
    );
    checker.register_overlaps(&raw.channels, &channels, &raw.modbus_sources);
    checker.block_poll_periods(&raw.channels, &channels, &raw.modbus_sources);
    checker.serial_loads(modbus_sources, &channels);
    channels
}

/// What is watched, each `None` where reported.
struct Watched {
    drivelines: Vec<Option<Driveline>>,
    tandem_mills: Vec<Option<TandemMill>>,
    rod_mills: Vec<Option<RodMill>>,
}

/// What is watched: `[[drivelines]]`, `[[tandem_mills]]` and `[[rod_mills]]`.
fn watched(
    checker: &mut Checker<'_>,
    raw: &RawConfig,
    channel_facts: &ChannelFacts<'_>,
) -> Watched {
    let drivelines = checker.named_list(
        "drivelines",
        "driveline",
        &raw.drivelines,
        |driveline| &driveline.name,
        |checker, key, driveline| checker.driveline(key, driveline, channel_facts),
    );
    let tandem_mills = checker.named_list(
        "tandem_mills",
        "tandem mill",
        &raw.tandem_mills,
        |mill| &mill.name,
        |checker, key, mill| checker.tandem_mill(key, mill, channel_facts),
    );
    let rod_mills = checker.named_list(
        "rod_mills",
        "rod mill",
        &raw.rod_mills,
        |mill| &mill.name,
        |checker, key, mill| checker.rod_mill(key, mill, channel_facts),
    );
    Watched {
        drivelines,
        tandem_mills,
        rod_mills,
    }
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
    dirs: &'a ServiceDirs,
    report: &'a mut Report,
    /// Source name -> key of the source that first used it (Modbus and CAN share
    /// one namespace).
    source_names: HashMap<String, String>,
    purpose: Purpose,
}

mod channels;
mod drivelines;
mod history;
mod identification;
mod opcua;
mod outputs;
mod rod_mills;
mod sources;
mod tandem_mills;
mod values;

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
