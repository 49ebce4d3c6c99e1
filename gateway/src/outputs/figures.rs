//! The generated table of published figures: for each figure of the catalogue, its
//! unit, type, guard and stale rule, and what every output calls it and how it
//! carries it (register, Sparkplug metric, `/metrics` family, history column, web API
//! member). `millgate figures` prints it ([`crate::cli::figures`]); the root README
//! holds it, and a test fails when they differ.

use serde::Serialize;

use crate::outputs::metrics;
use crate::outputs::modbus::register_map::{source_bits_name, GATEWAY_STATUS};
use crate::outputs::sparkplug::devices;
use crate::state::catalogue::{self, FigureInfo, FigureType, Guard, Register, SubjectKind};

/// One figure and its names in every output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct FigureRow {
    /// `gateway`, `source`, `driveline`, `tandem_mill`, `rod_mill` or `rod_span`.
    pub subject: &'static str,
    /// The catalogue key (also the web API's member and the OPC UA variable).
    pub key: &'static str,
    /// Unit (empty for ratios, counts, indices, flags, times).
    pub unit: &'static str,
    /// `real`, `count`, `index`, `bool`, `time`, `sequence`, or `state` with its
    /// values (`state: 0 starting, 1 running, 2 stopped`).
    pub figure_type: String,
    /// What it is.
    pub description: &'static str,
    /// `quality bit n`, `flags bit n`, `always` or `has a value`.
    pub guard: String,
    /// `withdrawn`, `last usable` or `kept` (see the stale rule).
    pub stale: &'static str,
    /// The register (its offset in the block and type; the gateway's: its address, its
    /// flags in `gateway_status`; a source's flag: bit i of a global register), or why
    /// none.
    pub register: String,
    /// The Sparkplug metric name and datatype.
    pub sparkplug: String,
    /// The `/metrics` family (in base units).
    pub metric: String,
    /// The family's name before base units when it was renamed, written beside it,
    /// deprecated (kept one release); `None` otherwise.
    pub metric_deprecated: Option<String>,
    /// The history's `bites` column, or why none.
    pub history: String,
}

fn register_of(figure: &FigureInfo) -> String {
    match (figure.register, figure.guard) {
        (
            Register::At {
                offset, value_type, ..
            },
            _,
        ) if figure.subject == SubjectKind::Gateway => {
            format!("{} ({offset}) {}", figure.key, value_type.name())
        }
        (Register::Flag, Guard::FlagBit(bit)) if figure.subject == SubjectKind::Gateway => {
            format!("{} ({}) bit {bit}", GATEWAY_STATUS.1, GATEWAY_STATUS.0)
        }
        (Register::IndexBit { address }, _) => {
            format!(
                "{} ({address}) bit <source index>",
                source_bits_name(figure.key)
            )
        }
        (
            Register::At {
                page,
                offset,
                value_type,
            },
            _,
        ) => match page {
            0 => format!("+{offset} {}", value_type.name()),
            _ => format!("extension +{offset} {}", value_type.name()),
        },
        (Register::Flag, Guard::FlagBit(bit)) => format!("flags bit {bit}"),
        (Register::NotMapped(why), _) => format!("none: {why}"),
        (Register::Flag, _) => "none".to_owned(),
    }
}

fn history_of(figure: &FigureInfo) -> String {
    let mut kept = Vec::new();
    if let Some(column) = figure.columns.bite {
        kept.push(format!("bites.{column}"));
    }
    if let Some(kind) = figure.alarm {
        kept.push(format!("alarms (kind {})", kind.name()));
    }
    if let Some(column) = figure.columns.state {
        let table = match figure.subject {
            SubjectKind::Driveline => "driveline_state",
            _ => "mill_state",
        };
        kept.push(format!("restored from {table}.{column}"));
    }
    match (kept.is_empty(), figure.subject) {
        (false, _) => kept.join("; "),
        (true, SubjectKind::Driveline) => "none: a flag or count of the moment".into(),
        (true, SubjectKind::Gateway) => "none: gateway_runs keeps each run's start and stop".into(),
        (true, SubjectKind::Source) => "none: source_outages keeps each stale or lost spell".into(),
        (true, _) => {
            "none: the chatter episodes keep their own summary; rod figures are not kept".into()
        }
    }
}

/// The type's name; a state's with its values.
fn type_of(figure_type: FigureType) -> String {
    match figure_type.state_values() {
        Some(values) => format!("{}: {values}", figure_type.name()),
        None => figure_type.name().to_owned(),
    }
}

/// Every figure's row, in catalogue order.
pub(crate) fn rows() -> Vec<FigureRow> {
    catalogue::all()
        .iter()
        .map(|figure| {
            let sparkplug = match figure.subject {
                SubjectKind::Gateway | SubjectKind::Source => {
                    "none: not published (the node's birth and death say whether it is online)"
                        .to_owned()
                }
                subject => {
                    let name = match subject {
                        SubjectKind::RodSpan => format!("span<i>/{}", figure.key),
                        _ => figure.key.to_owned(),
                    };
                    format!("{name} ({:?})", devices::datatype(figure.figure_type))
                }
            };
            let metric = metrics::metric_name(figure);
            let metric_deprecated = metrics::deprecated_metric_name(figure);
            FigureRow {
                subject: figure.subject.name(),
                key: figure.key,
                unit: figure.unit,
                figure_type: type_of(figure.figure_type),
                description: figure.description,
                guard: match figure.guard {
                    Guard::QualityBit(bit) => format!("quality bit {bit}"),
                    Guard::FlagBit(bit) => format!("flags bit {bit}"),
                    Guard::Always => "always".into(),
                    Guard::Presence => "has a value".into(),
                },
                stale: figure.stale.name(),
                register: register_of(figure),
                sparkplug,
                metric,
                metric_deprecated,
                history: history_of(figure),
            }
        })
        .collect()
}
