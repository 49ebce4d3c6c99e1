//! The catalogue ([`crate::state::catalogue`]) as the OPC UA server's address space,
//! the board's results as its snapshots and the alarm flags' changes as its events:
//! the one file that knows both the catalogue and the server's vocabulary.
//!
//! Every figure of the gateway, a source, a driveline, tandem mill, rod mill and rod
//! span is a variable of its object named by its catalogue key, typed and described
//! as the catalogue says (`Gateway/state`, `Sources/<name>/status`,
//! `Drivelines/<name>/taf`). A figure's status follows
//! the catalogue's stale rule, as every output does: a good value is `Good`, the last
//! bite's value while its source is stale is `Uncertain_LastUsableValue` (with the
//! value), a figure withdrawn by a stale source is `Bad_NoCommunication` (no value),
//! and one without a value says why: `Bad_WaitingForInitialData` before the first bite
//! or window, `Bad_DeviceFailure` after a degraded bite, `Bad_OutOfRange` for a rod
//! mill's refused inputs, `Bad_NoData` otherwise (a fit that gave nothing, no model,
//! an undetermined coupling). Source timestamps: the bite for a driveline's figures,
//! the time the adapter saw a new window or evaluation for a mill's.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::Config;

use crate::state::catalogue::{self, Figure, FigureType, NoValue, Reading, Subject};
use crate::state::results::{DrivelineResults, Results, RodMillResults, TandemMillResults};

use super::alarms::{source_conditions, EventObjects};
use super::model::{
    AddressSpaceSpec, ConditionSpec, ObjectKind, ObjectSpec, Quality, Snapshot, Unit, Value,
    VariableSpec, VariableType, VariableUpdate,
};

/// The OPC UA unit of a catalogue unit; `None` for none (ratios, counts, flags,
/// times). A test checks every catalogue unit has one.
fn unit(catalogue_unit: &str) -> Option<Unit> {
    match catalogue_unit {
        "kN*m" => Some(Unit::KILONEWTON_METRE),
        "Hz" => Some(Unit::HERTZ),
        "s" => Some(Unit::SECOND),
        "mrad" => Some(Unit::MILLIRADIAN),
        "m/s" => Some(Unit::METRE_PER_SECOND),
        "1/s" => Some(Unit::RECIPROCAL_SECOND),
        "degC" => Some(Unit::DEGREE_CELSIUS),
        "d" => Some(Unit::DAY),
        "mrad/d" => Some(Unit::MILLIRADIAN_PER_DAY),
        "1/d" => Some(Unit::RECIPROCAL_DAY),
        _ => None,
    }
}

/// The OPC UA type of a catalogue type: counts as UInt64 (they only grow), indices,
/// states (their value's index) and the heartbeat's sequence as UInt32.
fn datatype(figure_type: FigureType) -> VariableType {
    match figure_type {
        FigureType::Real => VariableType::Double,
        FigureType::Count => VariableType::UInt64,
        FigureType::Index | FigureType::State(_) | FigureType::Sequence => VariableType::UInt32,
        FigureType::Bool => VariableType::Boolean,
        FigureType::Time => VariableType::DateTime,
    }
}

/// A catalogue value as an OPC UA value of `datatype`; a non-finite number has none.
fn value(datatype: VariableType, value: catalogue::Value) -> Option<Value> {
    match value {
        catalogue::Value::Real(v) => v.is_finite().then_some(Value::Double(v)),
        catalogue::Value::Count(v) | catalogue::Value::Index(v) => Some(match datatype {
            VariableType::UInt64 => Value::UInt64(v),
            _ => Value::UInt32(u32::try_from(v).unwrap_or(u32::MAX)),
        }),
        catalogue::Value::Bool(v) => Some(Value::Boolean(v)),
        catalogue::Value::Time(ms) => Some(Value::DateTime(unix_ms(ms))),
    }
}

/// Milliseconds since the Unix epoch as a time.
fn unix_ms(ms: i64) -> SystemTime {
    UNIX_EPOCH + Duration::from_millis(u64::try_from(ms).unwrap_or(0))
}

/// The variables of `figures`, in catalogue order; a state's description says which
/// number is which state.
fn variables<R>(figures: &[Figure<R>]) -> Vec<VariableSpec> {
    figures
        .iter()
        .map(|figure| VariableSpec {
            key: figure.key.into(),
            description: match figure.figure_type.state_values() {
                Some(values) => format!("{}; as a number: {values}", figure.description),
                None => figure.description.into(),
            },
            unit: unit(figure.unit),
            datatype: datatype(figure.figure_type),
            // A flag's 0..1 is its type, not an engineering range.
            range: figure
                .range
                .filter(|_| figure.figure_type != FigureType::Bool),
            states: match figure.figure_type {
                FigureType::State(names) => names.iter().map(|&name| name.into()).collect(),
                _ => Vec::new(),
            },
        })
        .collect()
}

/// The conditions of `figures`: one per alarm flag, named by its key.
fn conditions<R>(figures: &[Figure<R>]) -> Vec<ConditionSpec> {
    figures
        .iter()
        .filter(|figure| figure.alarm.is_some())
        .map(|figure| ConditionSpec {
            kind: figure.key.into(),
            description: figure.description.into(),
            latched: figure.latched,
        })
        .collect()
}

/// A reading as an update of a variable of `datatype`: `why` says why a value is
/// missing when the catalogue only says "not available".
fn update(
    reading: Reading,
    datatype: VariableType,
    time: Option<SystemTime>,
    why: Quality,
) -> VariableUpdate {
    let converted = reading.value.and_then(|v| value(datatype, v));
    match (reading.quality, converted) {
        (catalogue::Quality::Good, Some(v)) => VariableUpdate::good(v, time),
        (catalogue::Quality::LastUsable, Some(v)) => VariableUpdate {
            value: Some(v),
            quality: Quality::UncertainLastUsableValue,
            source_time: time,
        },
        (catalogue::Quality::Bad(NoValue::SourceStale), _) => {
            VariableUpdate::missing(Quality::BadNoCommunication)
        }
        (catalogue::Quality::Bad(NoValue::NotAvailable), _) => VariableUpdate::missing(why),
        // A value that is not a number.
        (_, None) => VariableUpdate::missing(Quality::BadNoData),
    }
}

/// The updates of `figures` of `subject`.
fn updates<R: Subject>(
    figures: &[Figure<R>],
    subject: &R,
    time: Option<SystemTime>,
    why: Quality,
) -> Vec<VariableUpdate> {
    figures
        .iter()
        .map(|figure| {
            let datatype = datatype(figure.figure_type);
            update(figure.read(subject), datatype, time, why)
        })
        .collect()
}

/// Why a driveline's figure has no value.
fn driveline_why(d: &DrivelineResults) -> Quality {
    if d.bite_counter == 0 && d.last_bite_unix_ms.is_none() {
        Quality::BadWaitingForInitialData
    } else if d.last_bite_degraded {
        Quality::BadDeviceFailure
    } else {
        Quality::BadNoData
    }
}

/// Why a tandem mill's figure has no value.
fn tandem_why(m: &TandemMillResults) -> Quality {
    if m.evaluations == 0 {
        Quality::BadWaitingForInitialData
    } else {
        Quality::BadNoData
    }
}

/// Why a rod mill's figure (or one of its spans') has no value.
fn rod_why(m: &RodMillResults) -> Quality {
    if m.input_refused {
        Quality::BadOutOfRange
    } else if m.evaluations == 0 {
        Quality::BadWaitingForInitialData
    } else {
        Quality::BadNoData
    }
}

/// Where each part of the results sits in the spec.
#[derive(Debug, Clone)]
struct Layout {
    sources: Vec<usize>,
    drivelines: Vec<usize>,
    tandem_mills: Vec<usize>,
    rod_mills: Vec<(usize, Vec<usize>)>,
}

impl Layout {
    /// The objects of the drivelines, tandem mills and rod mills, in this order.
    fn mills(&self) -> Vec<usize> {
        let rod_mills = self.rod_mills.iter().map(|(mill, _)| *mill);
        let drivelines = self.drivelines.iter().chain(&self.tandem_mills).copied();
        drivelines.chain(rod_mills).collect()
    }

    /// How many drivelines, tandem mills and rod mills.
    fn mill_counts(&self) -> (usize, usize, usize) {
        let rod_mills = self.rod_mills.len();
        (self.drivelines.len(), self.tandem_mills.len(), rod_mills)
    }
}

/// The address space's objects as they are added.
struct Objects(Vec<ObjectSpec>);

impl Objects {
    /// Add an object named `name` (under `parent`); its index.
    fn add(
        &mut self,
        (name, parent): (&str, Option<usize>),
        kind: ObjectKind,
        description: String,
        (variables, conditions): (Vec<VariableSpec>, Vec<ConditionSpec>),
    ) -> usize {
        self.0.push(ObjectSpec {
            name: name.into(),
            kind,
            parent,
            description,
            variables,
            conditions,
        });
        self.0.len() - 1
    }

    /// An object of `figures` for each of `names`; their indices.
    fn each<R>(
        &mut self,
        names: &[String],
        kind: ObjectKind,
        description: &str,
        figures: &[Figure<R>],
    ) -> Vec<usize> {
        names
            .iter()
            .map(|name| {
                let nodes = (variables(figures), conditions(figures));
                self.add((name, None), kind, description.into(), nodes)
            })
            .collect()
    }

    /// A rod mill's object and its `spans` span objects under it; their indices.
    fn rod_mill(&mut self, name: &str, spans: usize) -> (usize, Vec<usize>) {
        let mill = self.add(
            (name, None),
            ObjectKind::RodMill,
            "A rod mill whose spans are checked against the Mathieu tongues".into(),
            (
                variables(catalogue::ROD_MILL),
                conditions(catalogue::ROD_MILL),
            ),
        );
        let spans = (0..spans)
            .map(|span| {
                let name = format!("span{}", span + 1);
                let description = format!(
                    "Span {} (stand {} to {} in rolling order)",
                    span + 1,
                    span + 1,
                    span + 2
                );
                let nodes = (
                    variables(catalogue::ROD_SPAN),
                    conditions(catalogue::ROD_SPAN),
                );
                self.add((&name, Some(mill)), ObjectKind::RodSpan, description, nodes)
            })
            .collect();
        (mill, spans)
    }
}

/// What the mapping needs of the configuration, and when it saw each mill's
/// evaluations change.
#[derive(Debug, Clone)]
pub(crate) struct CatalogueAdapter {
    layout: Layout,
    source_names: Vec<String>,
    driveline_names: Vec<String>,
    tandem_names: Vec<String>,
    rod_names: Vec<String>,
    /// Per tandem mill: evaluations last seen and when.
    tandem_seen: Vec<(u64, Option<SystemTime>)>,
    /// Per rod mill: evaluations last seen and when.
    rod_seen: Vec<(u64, Option<SystemTime>)>,
}

impl CatalogueAdapter {
    /// The mapping of `config`'s figures, its rod mills having `rod_spans` spans each;
    /// and the address space it fills.
    pub(crate) fn new(config: &Config, rod_spans: &[usize]) -> (Self, AddressSpaceSpec) {
        let mut objects = Objects(Vec::new());
        objects.add(
            ("Gateway", None),
            ObjectKind::Gateway,
            "The gateway's own state".into(),
            (
                variables(catalogue::GATEWAY),
                conditions(catalogue::GATEWAY),
            ),
        );
        let source_names: Vec<String> = config.sources().map(|s| s.name().to_owned()).collect();
        let names = |names: &mut dyn Iterator<Item = &String>| names.cloned().collect::<Vec<_>>();
        let driveline_names = names(&mut config.drivelines.iter().map(|d| &d.name));
        let tandem_names = names(&mut config.tandem_mills.iter().map(|m| &m.name));
        let rod_names = names(&mut config.rod_mills.iter().map(|m| &m.name));
        let layout = Layout {
            sources: objects.each(
                &source_names,
                ObjectKind::Source,
                "A field source (Modbus or CAN)",
                catalogue::SOURCE,
            ),
            drivelines: objects.each(
                &driveline_names,
                ObjectKind::Driveline,
                "A hot-mill driveline analysed at each bite",
                catalogue::DRIVELINE,
            ),
            tandem_mills: objects.each(
                &tandem_names,
                ObjectKind::TandemMill,
                "A tandem cold mill watched for chatter",
                catalogue::TANDEM_MILL,
            ),
            rod_mills: rod_names
                .iter()
                .enumerate()
                .map(|(k, name)| objects.rod_mill(name, rod_spans.get(k).copied().unwrap_or(0)))
                .collect(),
        };
        // A source's outages are its conditions (the alarm stream's outage events).
        for &source in &layout.sources {
            objects.0[source].conditions = source_conditions();
        }
        let adapter = Self {
            layout,
            source_names,
            tandem_seen: vec![(0, None); tandem_names.len()],
            rod_seen: vec![(0, None); rod_names.len()],
            driveline_names,
            tandem_names,
            rod_names,
        };
        let spec = AddressSpaceSpec {
            name: config.name.clone(),
            objects: objects.0,
            machines: machines::machines(&config.gateway_identification, {
                let nameplates = config.drivelines.iter().map(|d| &d.identification);
                let nameplates = nameplates
                    .chain(config.tandem_mills.iter().map(|m| &m.identification))
                    .chain(config.rod_mills.iter().map(|m| &m.identification));
                adapter.layout.mills().into_iter().zip(nameplates)
            }),
        };
        (adapter, spec)
    }

    /// The adapter and address space of `config`, this one's configuration with
    /// drivelines added live: the mills keep the windows seen so far (their figures'
    /// source timestamps stay those of their last window).
    pub(crate) fn grown(&self, config: &Config, rod_spans: &[usize]) -> (Self, AddressSpaceSpec) {
        let (mut adapter, spec) = Self::new(config, rod_spans);
        if adapter.tandem_seen.len() == self.tandem_seen.len() {
            adapter.tandem_seen.clone_from(&self.tandem_seen);
        }
        if adapter.rod_seen.len() == self.rod_seen.len() {
            adapter.rod_seen.clone_from(&self.rod_seen);
        }
        (adapter, spec)
    }

    /// The objects the alarm stream's events are about, by name.
    fn event_objects(&self) -> EventObjects {
        let named = |names: &[String], objects: &[usize]| -> Vec<(String, usize)> {
            names.iter().cloned().zip(objects.iter().copied()).collect()
        };
        let rods: Vec<usize> = self
            .layout
            .rod_mills
            .iter()
            .map(|(mill, _)| *mill)
            .collect();
        EventObjects::new(
            named(&self.driveline_names, &self.layout.drivelines),
            named(&self.tandem_names, &self.layout.tandem_mills),
            named(&self.rod_names, &rods),
            named(&self.source_names, &self.layout.sources),
        )
    }

    /// Every variable's state in `results`, seen at `now`.
    pub(crate) fn snapshot(&mut self, results: &Results, now: SystemTime) -> Snapshot {
        let layout = &self.layout;
        let objects = 1
            + layout.sources.len()
            + layout.drivelines.len()
            + layout.tandem_mills.len()
            + layout
                .rod_mills
                .iter()
                .map(|(_, spans)| 1 + spans.len())
                .sum::<usize>();
        let mut snapshot = vec![Vec::new(); objects];
        // The gateway's figures always have a value.
        let gateway = results.gateway();
        snapshot[0] = updates(catalogue::GATEWAY, &gateway, None, Quality::BadNoData);
        for (k, &index) in layout.sources.iter().enumerate() {
            let waiting = Quality::BadWaitingForInitialData;
            snapshot[index] = updates(catalogue::SOURCE, &results.source(k), None, waiting);
        }
        let empty = DrivelineResults::default();
        for (k, &index) in layout.drivelines.iter().enumerate() {
            let d = results.drivelines.get(k).unwrap_or(&empty);
            let time = d.last_bite_unix_ms.map(unix_ms);
            snapshot[index] = updates(catalogue::DRIVELINE, d, time, driveline_why(d));
        }
        let empty = TandemMillResults::default();
        for (m, &index) in layout.tandem_mills.iter().enumerate() {
            let mill = results.tandem_mills.get(m).unwrap_or(&empty);
            let time = seen(&mut self.tandem_seen[m], mill.evaluations, now);
            snapshot[index] = updates(catalogue::TANDEM_MILL, mill, time, tandem_why(mill));
        }
        let empty = RodMillResults::default();
        for (k, (index, spans)) in layout.rod_mills.iter().enumerate() {
            let mill = results.rod_mills.get(k).unwrap_or(&empty);
            let time = seen(&mut self.rod_seen[k], mill.evaluations, now);
            let why = rod_why(mill);
            snapshot[*index] = updates(catalogue::ROD_MILL, mill, time, why);
            for (span, &span_index) in spans.iter().enumerate() {
                // Empty (no values) unless the span and its mill are valid: a stale
                // mill's spans say so, as the mill does.
                let published = mill.published_span(span);
                let why = if mill.source_stale {
                    Quality::BadNoCommunication
                } else {
                    why
                };
                snapshot[span_index] = updates(catalogue::ROD_SPAN, &published, time, why);
            }
        }
        Snapshot {
            objects: snapshot,
            machines: machines::states(results, self.layout.mill_counts()),
        }
    }
}

/// When the evaluations last changed: `now` if they did since `seen`.
fn seen(
    seen: &mut (u64, Option<SystemTime>),
    evaluations: u64,
    now: SystemTime,
) -> Option<SystemTime> {
    if evaluations != seen.0 {
        *seen = (evaluations, Some(now));
    }
    seen.1
}

mod machines;
mod task;

pub(crate) use task::OpcUaOutputTask;

#[cfg(test)]
mod tests;
