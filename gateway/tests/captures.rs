//! Captures in the history file, written as the writer writes them: the retention
//! keeps them within their budget, deleting ordinary bites' captures first and
//! keeping every alarm bite's; after `thin_after_days` the ordinary ones are thinned
//! to every N-th bite; a capture reads back with the samples it was given.

use std::time::Duration;

use millgate::history::query::{CaptureRow, Filter, HistoryReader};
use millgate::history::retention::{CaptureRetention, Retention, RetentionState};
use millgate::history::rows::insert;
use millgate::history::writer::{connect, insert_run};
use millgate::history::{DrivelineSettings, RunInfo};
use millgate::state::captures::{
    BiteWindowAnalysis, CaptureChannel, CaptureKind, CaptureRecord, CapturedBite, KeepClass,
};
use millgate::state::events::{BiteRecord, HistoryEvent};
use millgate::state::results::DrivelineResults;
use millgate::state::time::UtcTime;
use millgate_tests::kit::scratch;

/// A deterministic bite window as a 16-bit DAQ gives it: a damped oscillation on a
/// 100 kN*m step plus noise, counts of 0.01 kN*m.
fn window(seed: u64) -> Vec<f64> {
    let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
    (0..1256)
        .map(|i| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let noise = ((state >> 33) as f64 / f64::from(1u32 << 31) - 0.5) * 0.6;
            let t = (f64::from(i) - 256.0).max(0.0) / 2000.0;
            let torque = if i < 256 {
                0.0
            } else {
                100.0 * (1.0 - (-8.0 * t).exp() * (2.0 * std::f64::consts::PI * 12.0 * t).cos())
            };
            millgate_config::Scaling::new(0.01, 0.0)
                .apply(f64::from(((torque + noise) / 0.01).round() as i16))
        })
        .collect()
}

/// Bite `n` of F1 at `time` and its capture, kept as `keep`.
fn bite_with_capture(n: u32, time: UtcTime, keep: KeepClass) -> [HistoryEvent; 2] {
    let bite = BiteRecord::clean(
        "F1",
        "torque",
        time,
        DrivelineResults {
            bite_counter: n,
            static_torque_knm: Some(100.0),
            peak_torque_knm: Some(180.0),
            taf: Some(1.8),
            ..DrivelineResults::default()
        },
    );
    let capture = CaptureRecord {
        kind: CaptureKind::Bite,
        subject: "F1".into(),
        bite: Some(CapturedBite { counter: n, time }),
        first_sample_unix_ns: (time.unix_ms() - 128) * 1_000_000,
        kernel_time: false,
        sample_rate_hz: 2000.0,
        channels: vec![CaptureChannel {
            name: "torque".into(),
            unit: "kN*m".into(),
            scale: 0.01,
            offset: 0.0,
            samples: window(u64::from(n)),
            timing: None,
        }],
        gaps: vec![],
        analysis: Some(BiteWindowAnalysis {
            trigger_index: 256,
            baseline_knm: 0.0,
            onset_knm: 2.0,
            period_lowpass_hz: 40.0,
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: 10.0,
        }),
        episode: None,
        keep,
        context: None,
    };
    [
        HistoryEvent::Bite(Box::new(bite)),
        HistoryEvent::Capture(Box::new(capture)),
    ]
}

fn run_info() -> RunInfo {
    RunInfo {
        version: "test".into(),
        config_name: "captures".into(),
        config_hash: String::new(),
        drivelines: vec![DrivelineSettings {
            name: "F1".into(),
            taf_warning: 2.2,
            taf_alarm: 2.6,
            model: None,
            gap_warning_mrad: None,
            gap_alarm_mrad: None,
        }],
    }
}

fn keep_of(n: u32) -> KeepClass {
    if n.is_multiple_of(50) {
        KeepClass::Important
    } else if n.is_multiple_of(7) {
        KeepClass::Warning
    } else {
        KeepClass::Ordinary
    }
}

#[test]
fn a_long_run_stays_within_the_budget_and_keeps_every_alarm_capture() {
    let scratch = scratch("captures-budget");
    let path = scratch.path().join("history.db");
    let mut connection = connect(&path).unwrap();
    let start = UtcTime::parse("2026-01-01T00:00:00Z").unwrap();
    let run = insert_run(&connection, start, &run_info()).unwrap();
    let budget: u64 = 1 << 20;
    let retention = Retention {
        max_age: Duration::from_secs(400 * 86_400),
        max_bytes: 1 << 40,
        chunk_rows: 500,
        vacuum_pages: 256,
        captures: Some(CaptureRetention {
            thin_after: Duration::from_secs(365 * 86_400),
            keep_every: 10,
            max_bytes: budget,
        }),
    };
    let mut state = RetentionState::default();
    let bites = 3000u32;
    let mut largest = 0u64;
    for batch in 0..bites / 100 {
        let transaction = connection.transaction().unwrap();
        for n in batch * 100 + 1..=batch * 100 + 100 {
            let time = UtcTime::from_unix_ms(start.unix_ms() + i64::from(n) * 30_000);
            for event in bite_with_capture(n, time, keep_of(n)) {
                insert(&transaction, run, &event).unwrap();
            }
        }
        transaction.commit().unwrap();
        let now = UtcTime::from_unix_ms(start.unix_ms() + i64::from(batch * 100) * 30_000);
        while retention.step(&connection, now, &mut state).unwrap().more {}
        let reader = HistoryReader::open(&path).unwrap();
        let (_, bytes) = reader.capture_totals().unwrap();
        largest = largest.max(bytes);
    }
    assert!(largest <= budget, "captures reached {largest} bytes");
    let reader = HistoryReader::open(&path).unwrap();
    let rows: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
    let (count, bytes) = reader.capture_totals().unwrap();
    assert_eq!(
        count,
        rows.len() as u64,
        "the totals follow inserts and deletes"
    );
    assert_eq!(bytes, rows.iter().map(|r| r.bytes as u64).sum::<u64>());
    // 3000 bites of ~1.7 KiB do not fit 1 MiB: ordinary ones went, oldest first.
    assert!(rows.len() < bites as usize / 2, "{} kept", rows.len());
    let kept = |n: u32| rows.iter().any(|r| r.bite_counter == Some(i64::from(n)));
    for n in (50..=bites).step_by(50) {
        assert!(kept(n), "the capture of alarm bite {n} was deleted");
    }
    let ordinary: Vec<i64> = rows
        .iter()
        .filter(|r| r.keep == 0)
        .filter_map(|r| r.bite_counter)
        .collect();
    let warnings = rows.iter().filter(|r| r.keep == 1).count();
    assert!(
        ordinary.is_empty()
            || warnings
                == (1..=bites)
                    .filter(|n| keep_of(*n) == KeepClass::Warning)
                    .count(),
        "warnings go only once no ordinary capture is left"
    );
    // What is kept reads back sample for sample.
    let last = rows.last().unwrap();
    let capture = reader.capture(last.id).unwrap().unwrap();
    let n = u32::try_from(last.bite_counter.unwrap()).unwrap();
    assert_eq!(capture.channels[0].samples, window(u64::from(n)));
    assert!(reader.capture(last.id + 1000).unwrap().is_none());
    drop(connection);
}

#[test]
fn ordinary_captures_are_thinned_after_some_days_and_the_others_kept() {
    let scratch = scratch("captures-thin");
    let path = scratch.path().join("history.db");
    let mut connection = connect(&path).unwrap();
    let start = UtcTime::parse("2026-03-01T00:00:00Z").unwrap();
    let run = insert_run(&connection, start, &run_info()).unwrap();
    let transaction = connection.transaction().unwrap();
    for n in 1..=200u32 {
        let time = UtcTime::from_unix_ms(start.unix_ms() + i64::from(n) * 30_000);
        for event in bite_with_capture(n, time, keep_of(n)) {
            insert(&transaction, run, &event).unwrap();
        }
    }
    transaction.commit().unwrap();
    let retention = Retention {
        max_age: Duration::from_secs(400 * 86_400),
        max_bytes: 1 << 40,
        chunk_rows: 30,
        vacuum_pages: 256,
        captures: Some(CaptureRetention {
            thin_after: Duration::from_secs(7 * 86_400),
            keep_every: 10,
            max_bytes: 1 << 30,
        }),
    };
    let mut state = RetentionState::default();
    // Six days on, nothing is thinned; eight days on, the ordinary ones are.
    let day = |d: i64| UtcTime::from_unix_ms(start.unix_ms() + d * 86_400_000);
    while retention
        .step(&connection, day(6), &mut state)
        .unwrap()
        .more
    {}
    let reader = HistoryReader::open(&path).unwrap();
    assert_eq!(reader.capture_totals().unwrap().0, 200);
    while retention
        .step(&connection, day(8), &mut state)
        .unwrap()
        .more
    {}
    let rows: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
    let mut kept: Vec<i64> = rows.iter().filter_map(|r| r.bite_counter).collect();
    kept.sort_unstable();
    let expected: Vec<i64> = (1..=200)
        .filter(|n| n % 10 == 0 || keep_of(*n as u32) != KeepClass::Ordinary)
        .collect();
    assert_eq!(kept, expected);
    let integrity: String = connection
        .query_row("PRAGMA integrity_check", [], |row| row.get(0))
        .unwrap();
    assert_eq!(integrity, "ok");
}

/// `millgate report` draws the captured torque of each driveline's last alarm bites
/// (`ALARM_TRACES`), newest first, each its own SVG named by the capture's id with
/// the command that exports it; the bites' own captures, not others: the trace's
/// envelope spans the window's lowest to highest sample (the plot's y range is
/// padded around exactly those).
#[cfg(feature = "plot")]
#[test]
fn the_report_draws_the_last_alarm_bites_captured_traces() {
    use millgate::cli::report::ALARM_TRACES;
    let scratch = scratch("captures-report");
    let path = scratch.path().join("history.db");
    let mut connection = connect(&path).unwrap();
    let start = UtcTime::parse("2026-03-01T00:00:00Z").unwrap();
    let run = insert_run(&connection, start, &run_info()).unwrap();
    let transaction = connection.transaction().unwrap();
    for n in 1..=400u32 {
        let time = UtcTime::from_unix_ms(start.unix_ms() + i64::from(n) * 30_000);
        for event in bite_with_capture(n, time, keep_of(n)) {
            insert(&transaction, run, &event).unwrap();
        }
    }
    transaction.commit().unwrap();
    drop(connection);
    let reader = HistoryReader::open(&path).unwrap();
    let rows: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
    // The alarm bites (every 50th), newest first: the last ALARM_TRACES of them.
    let mut alarms: Vec<&CaptureRow> = rows.iter().filter(|r| r.keep == 2).collect();
    assert_eq!(alarms.len(), 8);
    alarms.reverse();
    let expected: Vec<&CaptureRow> = alarms.into_iter().take(ALARM_TRACES as usize).collect();

    let out = scratch.path().join("report");
    let report = std::process::Command::new(env!("CARGO_BIN_EXE_millgate"))
        .args(["report", "--db", path.to_str().unwrap()])
        .args(["--out", out.to_str().unwrap(), "--until", "2026-03-02"])
        .output()
        .unwrap();
    assert!(
        report.status.success(),
        "{}",
        String::from_utf8_lossy(&report.stderr)
    );
    let markdown = std::fs::read_to_string(out.join("report.md")).unwrap();
    let traces: Vec<&str> = markdown
        .lines()
        .filter(|l| l.contains("](F1-capture-"))
        .collect();
    assert_eq!(traces.len(), expected.len(), "{markdown}");
    for (line, row) in traces.iter().zip(&expected) {
        let file = format!("F1-capture-{}.svg", row.id);
        assert!(
            line.contains(&format!(
                "alarm bite {} at {} UTC, capture {}",
                row.bite_counter.unwrap(),
                row.bite_time.as_deref().unwrap(),
                row.id
            )) && line.contains(&file),
            "{line}"
        );
        let svg = std::fs::read_to_string(out.join(&file)).unwrap();
        // The trace: the longest polyline (the mesh, the trigger and the legend are
        // lines of two points).
        let points = svg
            .split("<polyline")
            .skip(1)
            .filter_map(|p| p.split("points=\"").nth(1)?.split('"').next())
            .max_by_key(|p| p.len())
            .unwrap();
        let ys: Vec<f64> = points
            .split_whitespace()
            .map(|p| p.split(',').nth(1).unwrap().parse().unwrap())
            .collect();
        // Computed here from the window: each column's lowest and highest sample in
        // the order they came (a column of the plot's 450).
        let samples = window(u64::try_from(row.bite_counter.unwrap()).unwrap());
        let per_column = samples.len().div_ceil(450);
        let mut envelope = Vec::new();
        for chunk in samples.chunks(per_column) {
            let low = (0..chunk.len()).min_by(|&a, &b| chunk[a].total_cmp(&chunk[b]));
            let high = (0..chunk.len()).max_by(|&a, &b| chunk[a].total_cmp(&chunk[b]));
            let (low, high) = (low.unwrap(), high.unwrap());
            envelope.push(chunk[low.min(high)]);
            if low != high {
                envelope.push(chunk[low.max(high)]);
            }
        }
        assert_eq!(ys.len(), envelope.len(), "points");
        assert!(ys.len() <= 900);
        // The pixels are the values on a linear axis, to the pixel.
        let (lowest, highest) = envelope
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        let at = |value: f64| envelope.iter().position(|&v| v == value).unwrap();
        let (y_low, y_high) = (ys[at(lowest)], ys[at(highest)]);
        for (y, value) in ys.iter().zip(&envelope) {
            let expected = y_low + (y_high - y_low) * (value - lowest) / (highest - lowest);
            assert!((y - expected).abs() <= 1.0, "{y} for {value}: {expected}");
        }
    }
    assert!(
        markdown.contains(&format!(
            "millgate capture export --db {} --id ID",
            path.display()
        )),
        "{markdown}"
    );
}
