//! The edge node's devices as the catalogue makes them: a device per driveline, tandem
//! mill and rod mill, one metric per figure named by its key (a rod span's as
//! `span<i>/<key>`), its Sparkplug datatype and unit, and its value as the stale rule
//! lets it be published.

use super::payload::{DataType, MetricValue};
use crate::state::catalogue::{self, Figure, FigureType, Subject, Value};
use crate::state::results::Results;

/// The Sparkplug datatype of a catalogue figure type. Counts, indices and states (their
/// value's index) go as UInt64: Tahu's JavaScript codec (2.x) decodes every UInt32
/// metric as null (its open bug), and a UInt64 holds every count the gateway keeps.
pub(crate) fn datatype(figure_type: FigureType) -> DataType {
    match figure_type {
        FigureType::Real => DataType::Double,
        FigureType::Count | FigureType::Sequence => DataType::UInt64,
        FigureType::Index | FigureType::State(_) => DataType::UInt64,
        FigureType::Bool => DataType::Boolean,
        FigureType::Time => DataType::DateTime,
    }
}

/// A figure's value on the wire.
pub(super) fn wire(value: Value) -> MetricValue {
    match value {
        Value::Real(v) => MetricValue::DoubleValue(v),
        Value::Count(v) | Value::Index(v) => MetricValue::LongValue(v),
        Value::Bool(v) => MetricValue::BooleanValue(v),
        Value::Time(ms) => MetricValue::LongValue(u64::try_from(ms).unwrap_or(0)),
    }
}

/// A metric of a device: its name, datatype and unit (from the catalogue).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Column {
    pub(super) name: String,
    pub(super) datatype: DataType,
    pub(super) unit: &'static str,
}

/// The columns of `figures`, named `prefix` + key.
pub(super) fn columns<'a, R>(
    figures: &'a [Figure<R>],
    prefix: &str,
) -> impl Iterator<Item = Column> + 'a {
    let prefix = prefix.to_owned();
    figures.iter().map(move |figure| Column {
        name: format!("{prefix}{}", figure.key),
        datatype: datatype(figure.figure_type),
        unit: figure.unit,
    })
}

/// What `figures` of `subject` publish: the good values (null otherwise: Sparkplug
/// cannot mark a last usable value, so it withholds it, as the PLC registers do).
pub(super) fn values<R: Subject>(figures: &[Figure<R>], subject: &R) -> Vec<Option<Value>> {
    figures.iter().map(|f| f.read(subject).good()).collect()
}

/// What a device is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// Driveline k.
    Driveline(usize),
    /// Tandem mill k.
    TandemMill(usize),
    /// Rod mill k with this many spans (fixed at birth).
    RodMill(usize, usize),
}

/// A device of the node: its name, kind, metric columns (aliases run on from
/// `first_alias`) and what the last birth or data message said.
#[derive(Debug)]
pub(super) struct Device {
    pub(super) name: String,
    pub(super) kind: Kind,
    pub(super) columns: Vec<Column>,
    pub(super) first_alias: u64,
    pub(super) sent: Vec<Option<Value>>,
    /// A driveline's bite counter as last sent (at birth or with a bite's DDATA).
    pub(super) bite_counter: Option<u32>,
    /// Since when (ms) a newer bite than [`Self::bite_counter`] shows in the results
    /// while its own DDATA has not gone yet.
    pub(super) held_since: Option<u64>,
}

impl Device {
    /// The device's values in `results`, in column order.
    pub(super) fn values(&self, results: &Results) -> Vec<Option<Value>> {
        match self.kind {
            Kind::Driveline(k) => values(
                catalogue::DRIVELINE,
                &results.drivelines.get(k).cloned().unwrap_or_default(),
            ),
            Kind::TandemMill(k) => values(
                catalogue::TANDEM_MILL,
                &results.tandem_mills.get(k).cloned().unwrap_or_default(),
            ),
            Kind::RodMill(k, spans) => {
                let mill = results.rod_mills.get(k).cloned().unwrap_or_default();
                let mut out = values(catalogue::ROD_MILL, &mill);
                for span in 0..spans {
                    out.extend(values(catalogue::ROD_SPAN, &mill.published_span(span)));
                }
                out
            }
        }
    }
}
