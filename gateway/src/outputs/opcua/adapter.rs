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
use tokio::sync::{broadcast, mpsc, watch};

use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::catalogue::{self, Figure, FigureType, NoValue, Reading, Subject};
use crate::state::commands::{Command, CommandOrigin, CommandSender};
use crate::state::events::HistoryEvent;
use crate::state::results::{DrivelineResults, Results, RodMillResults, TandemMillResults};

use super::alarms::EventObjects;
use super::model::{
    AddressSpaceSpec, AlarmEventSpec, ObjectKind, ObjectSpec, Quality, Snapshot, Unit, Value,
    VariableSpec, VariableType, VariableUpdate,
};
use super::nodes::Acknowledger;

/// Alarm events waiting for the server; more are dropped (counted and logged).
pub const EVENT_QUEUE: usize = 256;

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

/// What the mapping needs of the configuration, and when it saw each mill's
/// evaluations change.
#[derive(Debug, Clone)]
pub struct CatalogueAdapter {
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
    pub fn new(config: &Config, rod_spans: &[usize]) -> (Self, AddressSpaceSpec) {
        let mut objects = vec![ObjectSpec {
            name: "Gateway".into(),
            kind: ObjectKind::Gateway,
            parent: None,
            description: "The gateway's own state".into(),
            variables: variables(catalogue::GATEWAY),
        }];
        let mut push = |object: ObjectSpec| {
            objects.push(object);
            objects.len() - 1
        };
        let source_names: Vec<String> = config.sources().map(|s| s.name().to_owned()).collect();
        let sources = source_names
            .iter()
            .map(|name| {
                push(ObjectSpec {
                    name: name.clone(),
                    kind: ObjectKind::Source,
                    parent: None,
                    description: "A field source (Modbus or CAN)".into(),
                    variables: variables(catalogue::SOURCE),
                })
            })
            .collect();
        let drivelines = config
            .drivelines
            .iter()
            .map(|driveline| {
                push(ObjectSpec {
                    name: driveline.name.clone(),
                    kind: ObjectKind::Driveline,
                    parent: None,
                    description: "A hot-mill driveline analysed at each bite".into(),
                    variables: variables(catalogue::DRIVELINE),
                })
            })
            .collect();
        let tandem_mills = config
            .tandem_mills
            .iter()
            .map(|mill| {
                push(ObjectSpec {
                    name: mill.name.clone(),
                    kind: ObjectKind::TandemMill,
                    parent: None,
                    description: "A tandem cold mill watched for chatter".into(),
                    variables: variables(catalogue::TANDEM_MILL),
                })
            })
            .collect();
        let rod_mills = config
            .rod_mills
            .iter()
            .enumerate()
            .map(|(k, mill)| {
                let index = push(ObjectSpec {
                    name: mill.name.clone(),
                    kind: ObjectKind::RodMill,
                    parent: None,
                    description: "A rod mill whose spans are checked against the Mathieu tongues"
                        .into(),
                    variables: variables(catalogue::ROD_MILL),
                });
                let spans = (0..rod_spans.get(k).copied().unwrap_or(0))
                    .map(|span| {
                        push(ObjectSpec {
                            name: format!("span{}", span + 1),
                            kind: ObjectKind::RodSpan,
                            parent: Some(index),
                            description: format!(
                                "Span {} (stand {} to {} in rolling order)",
                                span + 1,
                                span + 1,
                                span + 2
                            ),
                            variables: variables(catalogue::ROD_SPAN),
                        })
                    })
                    .collect();
                (index, spans)
            })
            .collect();
        let names = |names: Vec<&String>| names.into_iter().cloned().collect();
        let adapter = Self {
            layout: Layout {
                sources,
                drivelines,
                tandem_mills,
                rod_mills,
            },
            source_names,
            driveline_names: names(config.drivelines.iter().map(|d| &d.name).collect()),
            tandem_names: names(config.tandem_mills.iter().map(|m| &m.name).collect()),
            rod_names: names(config.rod_mills.iter().map(|m| &m.name).collect()),
            tandem_seen: vec![(0, None); config.tandem_mills.len()],
            rod_seen: vec![(0, None); config.rod_mills.len()],
        };
        let spec = AddressSpaceSpec {
            name: config.name.clone(),
            objects,
        };
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
    pub fn snapshot(&mut self, results: &Results, now: SystemTime) -> Snapshot {
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
        Snapshot { objects: snapshot }
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

/// The acknowledge method's action: clear the latched alarms, as an OPC UA client's
/// command to the analysis (which records it in the history).
pub fn acknowledger(commands: CommandSender) -> Acknowledger {
    std::sync::Arc::new(move |acknowledgement| {
        let origin = CommandOrigin::OpcUa(acknowledgement.peer);
        if let Err(error) = commands.send(Command::AcknowledgeAlarms { origin }) {
            tracing::warn!(%error, "OPC UA acknowledge not taken");
        }
    })
}

/// Feed the server until `shutdown`: a snapshot of the board into `updates` at each
/// change of the results (the server's subscriptions sample it), and the alarm
/// stream's events into `events`.
async fn feed(
    mut adapter: CatalogueAdapter,
    board: std::sync::Arc<Board>,
    mut alarms: broadcast::Receiver<HistoryEvent>,
    updates: watch::Sender<Snapshot>,
    events: mpsc::Sender<AlarmEventSpec>,
    mut shutdown: Shutdown,
) {
    let mut changes = board.changes();
    let mut objects = adapter.event_objects();
    let mut dropped = 0u64;
    loop {
        tokio::select! {
            _ = changes.results() => {
                let snapshot = adapter.snapshot(&board.results(), SystemTime::now());
                updates.send_if_modified(|current| {
                    let changed = *current != snapshot;
                    if changed {
                        *current = snapshot;
                    }
                    changed
                });
            }
            event = alarms.recv() => {
                let event = match event {
                    Ok(event) => event,
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        dropped += missed;
                        tracing::warn!(dropped, "OPC UA alarm events missed: the server is behind");
                        continue;
                    }
                    // The history handle outlives the service: no more events.
                    Err(broadcast::error::RecvError::Closed) => std::future::pending().await,
                };
                for spec in objects.events(&event, &board.results()) {
                    if events.try_send(spec).is_err() {
                        dropped += 1;
                        tracing::warn!(dropped, "OPC UA alarm event dropped: the server is behind");
                    }
                }
            }
            () = shutdown.recv() => break,
        }
    }
}

/// The OPC UA output as the service runs it: the server of `config`'s figures and the
/// feed from the board.
pub struct OpcUaOutputTask {
    server: super::OpcUaServer,
    adapter: CatalogueAdapter,
    board: std::sync::Arc<Board>,
    /// The alarm stream, subscribed when the output was prepared (before any event).
    alarms: broadcast::Receiver<HistoryEvent>,
}

impl std::fmt::Debug for OpcUaOutputTask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaOutputTask")
            .field("server", &self.server)
            .finish()
    }
}

impl OpcUaOutputTask {
    /// The OPC UA output of `config` (`None` without `[outputs.opcua]`), its rod mills
    /// having `rod_spans` spans; an error when its address space or its certificate
    /// store cannot be made.
    pub fn prepare(
        config: &Config,
        rod_spans: &[usize],
        board: std::sync::Arc<Board>,
        commands: CommandSender,
    ) -> Result<Option<Self>, super::OpcUaError> {
        let Some(settings) = &config.outputs.opcua else {
            return Ok(None);
        };
        let (adapter, spec) = CatalogueAdapter::new(config, rod_spans);
        let server = super::OpcUaServer::new(settings.clone(), spec, acknowledger(commands))?;
        let alarms = board.history().alarms();
        Ok(Some(Self {
            server,
            adapter,
            board,
            alarms,
        }))
    }

    /// The server's counts.
    pub fn status(&self) -> super::OpcUaStatus {
        self.server.status()
    }

    /// Serve on `listener` and feed the server until `shutdown`; what ended the
    /// server (an error before the shutdown is a failure).
    pub async fn run(
        self,
        listener: tokio::net::TcpListener,
        shutdown: Shutdown,
    ) -> Result<(), String> {
        let Self {
            server,
            mut adapter,
            board,
            alarms,
        } = self;
        let initial = adapter.snapshot(&board.results(), SystemTime::now());
        let (updates, updates_rx) = watch::channel(initial);
        let (events, events_rx) = mpsc::channel(EVENT_QUEUE);
        let feeding = feed(adapter, board, alarms, updates, events, shutdown.clone());
        let serving = server.run(listener, updates_rx, events_rx, shutdown);
        tokio::pin!(serving);
        let served = tokio::select! {
            served = &mut serving => served,
            () = feeding => serving.await,
        };
        served.map_err(|error| error.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::source_health::SourceStatus;
    use crate::state::results::GapResults;

    fn demo() -> (CatalogueAdapter, AddressSpaceSpec) {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples/demo.toml");
        let config = millgate_config::load(&path).unwrap();
        CatalogueAdapter::new(&config, &[])
    }

    /// Driveline F1's updates in `snapshot`, by key.
    fn f1<'a>(
        spec: &'a AddressSpaceSpec,
        snapshot: &'a Snapshot,
    ) -> impl Fn(&str) -> VariableUpdate + 'a {
        let index = spec.objects.iter().position(|o| o.name == "F1").unwrap();
        move |key| {
            let at = spec.objects[index]
                .variables
                .iter()
                .position(|v| v.key == key)
                .unwrap_or_else(|| panic!("no {key}"));
            snapshot.objects[index][at]
        }
    }

    const BITE_MS: i64 = 1_700_000_000_250;

    fn bitten() -> Results {
        let mut results = Results::new(1, 1, 0);
        results.sources = vec![Some(SourceStatus::Ok)];
        let d = &mut results.drivelines[0];
        d.bite_counter = 7;
        d.last_bite_unix_ms = Some(BITE_MS);
        d.taf = Some(1.4);
        d.static_torque_knm = Some(60.0);
        d.taf_alarm = true;
        d.gap = Some(GapResults {
            gap_mrad: 2.0,
            low_mrad: 1.8,
            high_mrad: 2.2,
            coupling: None,
            likeliest_coupling: Some(1),
            bites_pooled: 5,
        });
        results
    }

    #[test]
    fn every_catalogue_figure_is_a_variable_and_every_unit_maps() {
        let (_, spec) = demo();
        let f1 = spec.objects.iter().find(|o| o.name == "F1").unwrap();
        let keys: Vec<&str> = f1.variables.iter().map(|v| v.key.as_str()).collect();
        let catalogue: Vec<&str> = catalogue::DRIVELINE.iter().map(|f| f.key).collect();
        assert_eq!(keys, catalogue);
        for figure in catalogue::all() {
            assert_eq!(
                figure.unit.is_empty(),
                unit(figure.unit).is_none(),
                "{}: unit {:?}",
                figure.key,
                figure.unit
            );
        }
    }

    /// `Gateway/state`, `Gateway/heartbeat`, `Gateway/sources_ok` and each source's
    /// `status` keep the types and ranges they had before the catalogue held them; the
    /// flags are new variables beside them.
    #[test]
    fn the_gateway_and_source_variables_keep_their_types_and_values() {
        let (mut adapter, spec) = demo();
        let source = spec
            .objects
            .iter()
            .position(|o| o.kind == ObjectKind::Source)
            .expect("a source");
        let variable = |object: usize, key: &str| {
            let at = spec.objects[object]
                .variables
                .iter()
                .position(|v| v.key == key)
                .unwrap_or_else(|| panic!("no {key}"));
            (at, spec.objects[object].variables[at].clone())
        };
        let kinds = [
            (0, "state", VariableType::UInt32, Some((0.0, 2.0))),
            (0, "heartbeat", VariableType::UInt32, None),
            (0, "sources_ok", VariableType::Boolean, None),
            (0, "stopped", VariableType::Boolean, None),
            (source, "status", VariableType::UInt32, Some((0.0, 2.0))),
            (source, "lost", VariableType::Boolean, None),
        ];
        for (object, key, datatype, range) in kinds {
            let (_, spec) = variable(object, key);
            assert_eq!((spec.datatype, spec.range), (datatype, range), "{key}");
        }
        assert!(variable(0, "state")
            .1
            .description
            .ends_with("0 starting, 1 running, 2 stopped"));

        let mut results = Results::new(1, 1, 0);
        let snapshot = adapter.snapshot(&results, SystemTime::now());
        let read =
            |snapshot: &Snapshot, object, key| snapshot.objects[object][variable(object, key).0];
        assert_eq!(
            read(&snapshot, source, "status"),
            VariableUpdate::missing(Quality::BadWaitingForInitialData),
            "no status yet"
        );
        results.state = crate::state::results::GatewayState::Running;
        results.heartbeat = 65_535;
        results.sources = vec![Some(SourceStatus::Stale)];
        let snapshot = adapter.snapshot(&results, SystemTime::now());
        let good = |value| VariableUpdate::good(value, None);
        assert_eq!(read(&snapshot, 0, "state"), good(Value::UInt32(1)));
        assert_eq!(read(&snapshot, 0, "heartbeat"), good(Value::UInt32(65_535)));
        assert_eq!(
            read(&snapshot, 0, "sources_ok"),
            good(Value::Boolean(false))
        );
        assert_eq!(read(&snapshot, source, "status"), good(Value::UInt32(1)));
        assert_eq!(read(&snapshot, source, "stale"), good(Value::Boolean(true)));
    }

    #[test]
    fn fresh_values_are_good_and_dated_by_their_bite() {
        let (mut adapter, spec) = demo();
        let snapshot = adapter.snapshot(&bitten(), SystemTime::now());
        let f1 = f1(&spec, &snapshot);
        let bite = unix_ms(BITE_MS);
        assert_eq!(
            f1("taf"),
            VariableUpdate::good(Value::Double(1.4), Some(bite))
        );
        assert_eq!(
            f1("bite_counter"),
            VariableUpdate::good(Value::UInt64(7), Some(bite))
        );
        assert_eq!(f1("likeliest_coupling").value, Some(Value::UInt32(1)));
        // Undetermined coupling, no fitted frequency: no data, not a zero.
        assert_eq!(
            f1("gap_coupling"),
            VariableUpdate::missing(Quality::BadNoData)
        );
        assert_eq!(f1("beta1_hz"), VariableUpdate::missing(Quality::BadNoData));
        assert_eq!(f1("taf_alarm").quality, Quality::Good);
    }

    #[test]
    fn a_stale_source_keeps_the_last_bite_uncertain_and_counters_good() {
        let (mut adapter, spec) = demo();
        let mut results = bitten();
        results.drivelines[0].source_stale = true;
        let snapshot = adapter.snapshot(&results, SystemTime::now());
        let f1 = f1(&spec, &snapshot);
        for key in ["taf", "static_torque_knm", "gap_mrad", "last_bite_time"] {
            let update = f1(key);
            assert_eq!(update.quality, Quality::UncertainLastUsableValue, "{key}");
            assert!(update.value.is_some(), "{key}: the last usable value");
        }
        assert_eq!(f1("bite_counter").quality, Quality::Good);
        assert_eq!(f1("taf_alarm").quality, Quality::Good);
        assert_eq!(f1("source_stale").value, Some(Value::Boolean(true)));
    }

    #[test]
    fn missing_values_say_why() {
        let (mut adapter, spec) = demo();
        let never = Results::new(1, 1, 0);
        let snapshot = adapter.snapshot(&never, SystemTime::now());
        assert_eq!(
            f1(&spec, &snapshot)("taf"),
            VariableUpdate::missing(Quality::BadWaitingForInitialData)
        );
        let mut degraded = bitten();
        degraded.drivelines[0].last_bite_degraded = true;
        degraded.drivelines[0].taf = None;
        let snapshot = adapter.snapshot(&degraded, SystemTime::now());
        assert_eq!(
            f1(&spec, &snapshot)("taf"),
            VariableUpdate::missing(Quality::BadDeviceFailure)
        );
        // A non-finite number is never published as good.
        let mut nan = bitten();
        nan.drivelines[0].taf = Some(f64::NAN);
        let snapshot = adapter.snapshot(&nan, SystemTime::now());
        assert!(!f1(&spec, &snapshot)("taf").quality.carries_value());
    }

    #[test]
    fn the_alarm_streams_events_become_events_of_their_objects() {
        use super::super::alarms::{ALARM_SEVERITY, WARNING_SEVERITY};
        use crate::state::events::{AlarmEvent, AlarmKind, AlarmRecord};
        use crate::state::time::UtcTime;
        let (adapter, spec) = demo();
        let mut objects = adapter.event_objects();
        let at = UtcTime::from_unix_ms(BITE_MS);
        let alarm = |kind, event| {
            HistoryEvent::Alarm(AlarmRecord {
                time: at,
                subject: "F1".into(),
                kind,
                event,
                origin: None,
                value: Some(1.4),
                threshold: Some(1.35),
            })
        };
        let raised = objects.events(&alarm(AlarmKind::TafAlarm, AlarmEvent::Raised), &bitten());
        assert_eq!(raised.len(), 1, "{raised:?}");
        let event = &raised[0];
        assert_eq!(spec.objects[event.object].name, "F1");
        assert_eq!(event.kind, "taf_alarm");
        assert!(event.active && event.unacknowledged);
        assert_eq!(event.severity, ALARM_SEVERITY);
        assert_eq!(event.time, unix_ms(BITE_MS), "raised at its bite");
        assert_eq!(
            event.message,
            "F1: taf_alarm raised, taf 1.40, gap_mrad 2.00 mrad"
        );
        let acknowledged = objects.events(
            &alarm(AlarmKind::TafAlarm, AlarmEvent::Acknowledged),
            &bitten(),
        );
        assert_eq!(acknowledged.len(), 1);
        assert!(!acknowledged[0].active && !acknowledged[0].unacknowledged);
        assert!(acknowledged[0].message.contains("acknowledged"));
        let warning = objects.events(&alarm(AlarmKind::TafWarning, AlarmEvent::Raised), &bitten());
        assert_eq!(
            (warning[0].severity, warning[0].unacknowledged),
            (WARNING_SEVERITY, false)
        );
        // A source going stale, then lost, then back: from the source's object.
        let source = spec
            .objects
            .iter()
            .position(|o| o.kind == ObjectKind::Source)
            .unwrap();
        let name = spec.objects[source].name.clone();
        let started = HistoryEvent::OutageStarted {
            time: at,
            source: name.clone(),
            status: "stale",
        };
        let events = objects.events(&started, &bitten());
        assert_eq!(events.len(), 1);
        assert_eq!(
            (events[0].object, events[0].kind.as_str()),
            (source, "source_stale")
        );
        assert!(events[0].active);
        let worse = objects.events(
            &HistoryEvent::OutageWorse {
                source: name.clone(),
            },
            &bitten(),
        );
        let kinds: Vec<(&str, bool)> = worse.iter().map(|e| (e.kind.as_str(), e.active)).collect();
        assert_eq!(kinds, [("source_stale", false), ("source_lost", true)]);
        let ended = HistoryEvent::OutageEnded {
            time: at,
            source: name,
            blocks_missed: 3,
            ended_by: crate::state::events::EndedBy::Recovered,
        };
        let kinds: Vec<(String, bool)> = objects
            .events(&ended, &bitten())
            .into_iter()
            .map(|e| (e.kind, e.active))
            .collect();
        assert_eq!(kinds, [("source_lost".to_owned(), false)]);
        // An alarm of a subject the address space does not have: nothing.
        let stranger = HistoryEvent::Alarm(AlarmRecord {
            subject: "F9".into(),
            ..match alarm(AlarmKind::TafAlarm, AlarmEvent::Raised) {
                HistoryEvent::Alarm(record) => record,
                _ => unreachable!(),
            }
        });
        assert!(objects.events(&stranger, &bitten()).is_empty());
    }
}
