//! The adapter's tests: the catalogue as variables, the results as snapshots, the alarm
//! stream as events.

use super::*;
use crate::field::source_health::SourceStatus;
use crate::state::events::HistoryEvent;
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
        growth: None,
        forecast: None,
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
    let read = |snapshot: &Snapshot, object, key| snapshot.objects[object][variable(object, key).0];
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
