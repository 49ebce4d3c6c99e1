//! A driveline's extra channels in its bite captures, through the real `millgate run`
//! binary: the demo's virtual DAQ serves the torque and a motor current (derived from
//! the simulated torque) as two block channels over Modbus TCP on loopback; the
//! driveline names the current in `extra_channels`.
//!
//! - each exported bite's `motor_current` column is, sample for sample, a run of the
//!   values the DAQ served (the sim's signal through the DAQ's 16-bit counts), every
//!   row filled, lined up with the torque column to within one DAQ block (a Modbus
//!   block carries no time: both are dated when the analysis handles them; the
//!   offset is printed, 3-4 samples in a debug build);
//! - the torque column and `millgate analyze` on the export still give the figures
//!   the gateway published for the bite;
//! - pyarrow reads both columns from the Parquet export, equal to the CSV's, with the
//!   current's unit in the metadata.

mod common;

use std::process::Command;
use std::time::Duration;

use common::{millgate, terminate, text, wait_for, Setup, MILLGATE};
use millgate::history::query::{BiteRow, Filter, HistoryReader};
use millgate_config::layout::to_raw_sample;
use millgate_config::ChannelSource;
use millgate_sim::devices::demo::SAMPLES_PER_BLOCK;
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};

/// The current's scale, A per count.
const CURRENT_SCALE_A: f64 = 0.1;
/// The current's block base register (after the torque's block at 0).
const CURRENT_BLOCK: u16 = 122;

/// The motor current the simulated drive draws at shaft torque `torque_knm`, A.
fn motor_current_a(torque_knm: f64) -> f64 {
    80.0 + 3.2 * torque_knm
}

/// `value` as the gateway reads it back from a block of counts at `scale`.
fn served(value: f64, scale: f64) -> f64 {
    millgate_config::Scaling::new(scale, 0.0).apply(f64::from(to_raw_sample(value, scale, 0.0)))
}

/// Where `run` starts in `signal` (the only place: the simulated torque is noisy).
fn position_of(run: &[f64], signal: &[f64]) -> Option<usize> {
    let mut found = (0..=signal.len().saturating_sub(run.len()))
        .filter(|&start| signal[start..start + run.len()] == *run);
    let first = found.next()?;
    assert!(found.next().is_none(), "the run repeats in the signal");
    Some(first)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn extra_channel_columns_are_what_the_daq_served() {
    columns_as_served(None).await;
}

/// The same with the DAQ's two block channels read with requests in flight (the
/// virtual DAQ, tokio-modbus's server, takes them): the same samples.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_requests_in_flight_the_columns_are_what_the_daq_served() {
    columns_as_served(Some(8)).await;
}

/// Three bites of the demo with a motor current beside the torque on the same DAQ,
/// its source's `requests_in_flight` set when given: each bite's exported columns are
/// the samples the DAQ served, in the CSV and in the Parquet file.
async fn columns_as_served(requests_in_flight: Option<u32>) {
    let mut served_torque = Vec::new();
    let mut served_current = Vec::new();
    let setup = Setup::with_daq(MILLGATE, "extra-channels", "db", |config, schedule| {
        let torque = &config.channels[config.drivelines[0].torque];
        let ChannelSource::ModbusBlock { table, base, .. } = torque.source else {
            panic!("the demo's torque is a block channel");
        };
        let current: Vec<f64> = schedule
            .torque_knm
            .iter()
            .map(|&t| motor_current_a(t))
            .collect();
        served_torque = schedule
            .torque_knm
            .iter()
            .map(|&t| served(t, torque.scale))
            .collect();
        served_current = current
            .iter()
            .map(|&a| served(a, CURRENT_SCALE_A))
            .collect();
        let channel = |address, scale, signal| DaqChannel {
            placement: Placement {
                table,
                address,
                scale,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal,
        };
        VirtualDaq::new(
            torque.sample_rate_hz,
            SAMPLES_PER_BLOCK,
            vec![
                channel(base, torque.scale, schedule.torque_knm.clone()),
                channel(CURRENT_BLOCK, CURRENT_SCALE_A, current),
            ],
        )
    })
    .await;
    let config = std::fs::read_to_string(&setup.config).unwrap();
    let edited = config.replacen(
        "torque = \"spindle_top\"\n",
        "torque = \"spindle_top\"\nextra_channels = [\"motor_current\"]\n",
        1,
    );
    assert_ne!(
        edited, config,
        "the demo's driveline names its torque otherwise"
    );
    let edited = match requests_in_flight {
        Some(n) => edited.replacen(
            "name = \"daq1\"\n",
            &format!("name = \"daq1\"\nrequests_in_flight = {n}\n"),
            1,
        ),
        None => edited,
    };
    assert!(requests_in_flight.is_none() || edited.contains("requests_in_flight"));
    std::fs::write(&setup.config, edited).unwrap();
    setup.append_config(&format!(
        "\n[[channels]]\nname = \"motor_current\"\nkind = \"process_value\"\nunit = \"A\"\n\
         scale = {CURRENT_SCALE_A}\nsample_rate_hz = 2000.0\n\
         source = {{ modbus = \"daq1\", table = \"input\", block = {CURRENT_BLOCK} }}\n"
    ));

    let plc = setup.plc();
    let mut service = setup.spawn("run.log");
    wait_for("3 bites in the PLC", Duration::from_secs(40), || {
        plc.counter() >= 3
    })
    .await;
    terminate(&mut service);
    // Read with requests in flight throughout: the reader never fell back to one at a
    // time (it warns when it does).
    let log = setup.log_text("run.log");
    assert!(!log.contains("requests in flight"), "{log}");

    let db = setup.history.clone();
    let reader = HistoryReader::open(&db).unwrap();
    let bites: Vec<BiteRow> = reader.bites(&Filter::default()).unwrap();
    assert!(bites.len() >= 3, "{} bites", bites.len());
    let out = setup.scratch.join("export");
    let block = usize::from(SAMPLES_PER_BLOCK);
    let mut pairs = Vec::new();
    for bite in &bites {
        let csv = MILLGATE.export_bite(&db, &out, bite.figures.bite_counter, "csv");
        let table = std::fs::read_to_string(&csv).unwrap();
        let mut lines = table.lines();
        assert_eq!(lines.next(), Some("t,spindle_top,motor_current"));
        let rows: Vec<Vec<Option<f64>>> = lines
            .map(|line| line.split(',').map(|cell| cell.parse().ok()).collect())
            .collect();
        let torque: Vec<f64> = rows.iter().map(|r| r[1].unwrap()).collect();
        let current: Vec<Option<f64>> = rows.iter().map(|r| r[2]).collect();
        // The torque column: the DAQ's samples, as before.
        let at = position_of(&torque, &served_torque)
            .unwrap_or_else(|| panic!("bite {}: torque not served", bite.figures.bite_counter));
        // The current: the rows holding a sample are one run of what the DAQ served.
        let first_row = current.iter().position(Option::is_some).unwrap();
        let end_row = current.iter().rposition(Option::is_some).unwrap() + 1;
        let held: Vec<f64> = current[first_row..end_row]
            .iter()
            .map(|c| c.expect("no hole inside the run"))
            .collect();
        assert_eq!(
            (first_row, end_row),
            (0, torque.len()),
            "bite {}: the hold waits for the current",
            bite.figures.bite_counter
        );
        let current_at = position_of(&held, &served_current)
            .unwrap_or_else(|| panic!("bite {}: current not served", bite.figures.bite_counter));
        let offset = current_at as i64 - (at + first_row) as i64;
        assert!(
            offset.unsigned_abs() as usize <= block,
            "bite {}: the current is {offset} samples off the torque",
            bite.figures.bite_counter
        );
        eprintln!(
            "bite {}: current offset {offset} samples, rows {first_row}..{end_row} of {}",
            bite.figures.bite_counter,
            torque.len()
        );
        // The header beside the CSV gives the current's unit and own timing.
        let sidecar = std::path::Path::new(&csv).with_extension("json");
        let header: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(sidecar).unwrap()).unwrap();
        let meta = &header["channels"][1];
        assert_eq!(meta["name"], "motor_current");
        assert_eq!(meta["unit"], "A");
        assert_eq!(meta["encoding"], "counts", "{meta}");
        assert_eq!(meta["timing"]["first_row"], first_row);
        assert_eq!(meta["timing"]["end_row"], end_row);
        assert_eq!(meta["timing"]["sample_rate_hz"], 2000.0);
        assert!(header["channels"][0].get("timing").is_none());
        // `millgate analyze` reads the torque column as before.
        let analyzed = millgate(&["analyze", "--input", &csv]);
        assert!(analyzed.status.success(), "{}", text(&analyzed));
        let printed = String::from_utf8_lossy(&analyzed.stdout).into_owned();
        let expected = format!(
            "static_torque = {:.2} kN*m, peak_torque = {:.2} kN*m",
            bite.figures.static_torque_knm.unwrap(),
            bite.figures.peak_torque_knm.unwrap(),
        );
        assert!(
            printed.contains(&expected),
            "expected `{expected}` in\n{printed}"
        );
        if let Some(taf) = bite.figures.taf {
            assert!(printed.contains(&format!("taf = {taf:.3}")), "{printed}");
        }
        pairs.push((
            csv,
            MILLGATE.export_bite(&db, &out, bite.figures.bite_counter, "parquet"),
        ));
    }

    // pyarrow: both columns in the Parquet file, equal to the CSV's, with units.
    let script = r##"
import json, math, sys
import pyarrow.parquet as pq
args = sys.argv[1:]
for csv, parquet in zip(args[::2], args[1::2]):
    table = pq.read_table(parquet)
    assert table.column_names == ["time", "t", "spindle_top", "motor_current"], table.column_names
    meta = table.schema.metadata
    assert json.loads(meta[b"millgate.units"]) == {"spindle_top": "kN*m", "motor_current": "A"}
    rows = [l.split(",") for l in open(csv) if not l.startswith("#")][1:]
    for name, k in (("spindle_top", 1), ("motor_current", 2)):
        values = table.column(name).to_pylist()
        assert len(values) == len(rows)
        for value, row in zip(values, rows):
            cell = row[k].strip()
            assert (math.isnan(value) if cell == "" else value == float(cell)), (name, value, cell)
print("ok", len(args) // 2)
"##;
    let mut python = Command::new("python3");
    python.args(["-c", script]);
    for (csv, parquet) in &pairs {
        python.args([csv, parquet]);
    }
    let checked = python.output().expect("python3");
    assert!(checked.status.success(), "{}", text(&checked));
    setup.finish().await;
}

/// The analysis alone (no service), blocks dated as a CAN reader dates them: a bite
/// is held until the current's block that covers its window comes in, and its capture
/// holds the current's samples for the torque's rows exactly; without the current it
/// is released when its bound has passed, the missing tail marked.
#[tokio::test]
async fn a_bite_waits_for_its_extra_channel_at_most_its_bound() {
    use std::sync::Arc;
    use std::time::{Instant, SystemTime};

    use millgate::analysis::Analysis;
    use millgate::field::acquired::Acquired;
    use millgate::field::source_health::SourceHealth;
    use millgate::state::board::Board;
    use millgate::state::captures::{CapturedBite, KeepClass};
    use millgate::state::time::UtcTime;

    let demo = millgate_sim::devices::demo::setup(30.0, 0.5, 5).unwrap();
    let mut config = demo.config;
    config.history = Some(millgate_config::History {
        path: std::env::temp_dir().join("unused-history.db"),
        retention_days: 400,
        max_size_mb: 1024,
        captures: millgate_config::CaptureSettings::defaults(1024),
        synchronous: millgate_config::Synchronous::default(),
    });
    let mut current = config.channels[0].clone();
    current.name = "motor_current".into();
    current.unit = "A".into();
    current.scale = CURRENT_SCALE_A;
    if let ChannelSource::ModbusBlock { base, .. } = &mut current.source {
        *base = CURRENT_BLOCK;
    }
    config.channels.push(current);
    config.drivelines[0].extra_channels = vec![1];
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(3600),
        Duration::from_secs(3600),
    ));
    let board = Arc::new(Board::new(&config, vec![health]));
    let (bites, _) = tokio::sync::broadcast::channel(16);
    let mut analysis = Analysis::new(&config, board, bites).unwrap();

    let fs = config.channels[0].sample_rate_hz;
    let torque: Vec<f64> = demo
        .schedule
        .torque_knm
        .iter()
        .map(|&t| served(t, 0.01))
        .collect();
    let current: Vec<f64> = demo
        .schedule
        .torque_knm
        .iter()
        .map(|&t| served(motor_current_a(t), CURRENT_SCALE_A))
        .collect();
    let start = SystemTime::now();
    let dated = |end: usize| Some(start + Duration::from_secs_f64((end - 1) as f64 / fs));
    let block = usize::from(SAMPLES_PER_BLOCK);
    let first_bar_end = (demo.schedule.bites[1].onset_sample / block - 1) * block;
    let mut released = Vec::new();
    for at in (0..first_bar_end).step_by(block) {
        let end = at + block;
        let held = analysis.handle(Acquired::Samples {
            channel: 0,
            values: torque[at..end].to_vec(),
            received: dated(end),
            handed: Instant::now(),
        });
        assert!(held.is_empty(), "a bite released before the current came");
        released.extend(analysis.handle(Acquired::Samples {
            channel: 1,
            values: current[at..end].to_vec(),
            received: dated(end),
            handed: Instant::now(),
        }));
    }
    assert_eq!(released.len(), 1, "the first bar's bite");
    let capture = |report: &millgate::analysis::driveline::BiteReport| {
        report
            .capture(
                CapturedBite {
                    counter: 1,
                    time: UtcTime::now(),
                },
                KeepClass::Ordinary,
            )
            .unwrap()
    };
    let record = capture(&released[0]);
    assert_eq!(record.channels.len(), 2);
    let rows = record.channels[0].samples.clone();
    let at = position_of(&rows, &torque).unwrap();
    assert_eq!(record.channels[1].name, "motor_current");
    assert_eq!(record.channels[1].samples, current[at..at + rows.len()]);
    let timing = record.channels[1].timing.unwrap();
    assert_eq!((timing.first_row, timing.end_row), (0, rows.len()));
    assert!((timing.first_sample_unix_ns - record.first_sample_unix_ns).abs() < 1_000);

    // The second bar, its current stopping two blocks after the bite's onset: held,
    // then released at its bound with the current's tail missing.
    let second_bar_end = (demo.schedule.bites[2].onset_sample / block - 1) * block;
    let current_stops = demo.schedule.bites[1].onset_sample + 2 * block;
    let mut held = Vec::new();
    for at in (first_bar_end..second_bar_end).step_by(block) {
        let end = at + block;
        held.extend(analysis.handle(Acquired::Samples {
            channel: 0,
            values: torque[at..end].to_vec(),
            received: dated(end),
            handed: Instant::now(),
        }));
        if end <= current_stops {
            held.extend(analysis.handle(Acquired::Samples {
                channel: 1,
                values: current[at..end].to_vec(),
                received: dated(end),
                handed: Instant::now(),
            }));
        }
    }
    assert!(held.is_empty(), "released without waiting");
    assert!(analysis.release_held(Instant::now(), false).is_empty());
    let late = analysis.release_held(Instant::now() + Duration::from_secs(1), false);
    assert_eq!(late.len(), 1);
    let record = capture(&late[0]);
    let rows = record.channels[0].samples.clone();
    let at = position_of(&rows, &torque).unwrap();
    let timing = record.channels[1].timing.unwrap();
    let end_row = current_stops / block * block - at;
    assert_eq!(
        (timing.first_row, timing.end_row),
        (0, end_row),
        "{timing:?}"
    );
    let samples = &record.channels[1].samples;
    assert_eq!(samples[..end_row], current[at..at + end_row]);
    assert!(samples[end_row..].iter().all(|s| s.is_nan()));
}
