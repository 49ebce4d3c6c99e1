//! The generated table of published figures: for each figure of the catalogue, its
//! unit, type, guard and stale rule, and what every output calls it and how it
//! carries it (register, Sparkplug metric, `/metrics` family, history column, web API
//! member). `millgate figures` prints it ([`crate::cli::figures`]); the root README
//! holds it, and a test fails when they differ.

use serde::Serialize;

use crate::outputs::metrics;
use crate::outputs::sparkplug::devices;
use crate::state::catalogue::{self, FigureInfo, Guard, Register, SubjectKind};

/// One figure and its names in every output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FigureRow {
    /// `driveline`, `tandem_mill`, `rod_mill` or `rod_span`.
    pub subject: &'static str,
    /// The catalogue key (also the web API's member and the OPC UA variable).
    pub key: &'static str,
    /// Unit (empty for ratios, counts, indices, flags, times).
    pub unit: &'static str,
    /// `real`, `count`, `index`, `bool`, `time`.
    pub figure_type: &'static str,
    /// What it is.
    pub description: &'static str,
    /// `quality bit n`, `flags bit n`, `always` or `has a value`.
    pub guard: String,
    /// `withdrawn`, `last usable` or `kept` (see the stale rule).
    pub stale: &'static str,
    /// The register (`<block>.<key>`, its offset in the block and type), or why none.
    pub register: String,
    /// The Sparkplug metric name and datatype.
    pub sparkplug: String,
    /// The `/metrics` family.
    pub metric: String,
    /// The history's `bites` column, or why none.
    pub history: String,
}

fn register_of(figure: &FigureInfo) -> String {
    match (figure.register, figure.guard) {
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
        (true, _) => {
            "none: the chatter episodes keep their own summary; rod figures are not kept".into()
        }
    }
}

/// Every figure's row, in catalogue order.
pub fn rows() -> Vec<FigureRow> {
    catalogue::all()
        .iter()
        .map(|figure| {
            let sparkplug_name = match figure.subject {
                SubjectKind::RodSpan => format!("span<i>/{}", figure.key),
                _ => figure.key.to_owned(),
            };
            let metric = metrics::metric_name(figure);
            FigureRow {
                subject: figure.subject.name(),
                key: figure.key,
                unit: figure.unit,
                figure_type: figure.figure_type.name(),
                description: figure.description,
                guard: match figure.guard {
                    Guard::QualityBit(bit) => format!("quality bit {bit}"),
                    Guard::FlagBit(bit) => format!("flags bit {bit}"),
                    Guard::Always => "always".into(),
                    Guard::Presence => "has a value".into(),
                },
                stale: figure.stale.name(),
                register: register_of(figure),
                sparkplug: format!(
                    "{sparkplug_name} ({:?})",
                    devices::datatype(figure.figure_type)
                ),
                metric,
                history: history_of(figure),
            }
        })
        .collect()
}
