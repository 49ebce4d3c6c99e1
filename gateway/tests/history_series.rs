//! The history's series for a page (`HistoryReader::wear_series`, `gap_trend`) on a
//! small file written by the real writer, against computations that do not use SQL:
//! the buckets rebuilt in Rust from every bite row, the slope by a two-pass
//! least-squares fit in Rust and by numpy's `polyfit` (Python's sqlite3 reading the
//! file; skipped with a message when python3 or numpy is missing), and the slope the
//! gaps were generated with.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use millgate::history::query::{BiteRow, Filter, HistoryReader};
use millgate::history::series::{WearIndexPoint, WearPoint, MAX_SERIES_POINTS, MIN_TREND_BITES};
use millgate::history::{DrivelineSettings, HistoryError, RunInfo};
use millgate::state::commands::CommandOrigin;
use millgate::state::events::{BiteRecord, HistoryEvent, WearState};
use millgate::state::history::History;
use millgate::state::results::{DrivelineResults, GapResults};
use millgate::state::time::UtcTime;
use millgate_tests::kit::scratch;

const MINUTE_MS: i64 = 60_000;
const DAY_MS: i64 = 86_400_000;
const WEEK_MS: i64 = 7 * DAY_MS;
/// Bite spacing of the file, ms.
const EVERY_MS: i64 = 15 * MINUTE_MS;
/// Days the file covers.
const DAYS: i64 = 20;
/// No bites from day 5 to day 8 (a stop of the mill): buckets without bites.
const HOLE_DAYS: std::ops::Range<i64> = 5..8;
/// The wear trend is reset (a new coupling) at day 12.
const RESET_DAY: i64 = 12;
/// Gap growth before and after the reset, mrad/week.
const GROWTH_BEFORE: f64 = 0.5;
const GROWTH_AFTER: f64 = 0.8;

fn start() -> UtcTime {
    UtcTime::parse("2026-03-01T00:00:00Z").unwrap()
}

fn reset_time() -> UtcTime {
    UtcTime::from_unix_ms(start().unix_ms() + RESET_DAY * DAY_MS + 7 * MINUTE_MS)
}

/// A deterministic noise in [-1, 1) (a 64-bit LCG), so the fit has residuals.
fn noise(n: u64) -> f64 {
    let x = n
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Bite `n` of F1 at `time`: the gap grows linearly (a new line from the reset on),
/// plus noise; no estimate for the first 10 bites of each coupling (the pool fills);
/// every 37th window degraded with an absurd TAF the series must leave out.
fn bite(n: u32, time: UtcTime) -> HistoryEvent {
    let after_reset = time > reset_time();
    let (origin, growth, base) = if after_reset {
        (reset_time(), GROWTH_AFTER, 0.4)
    } else {
        (start(), GROWTH_BEFORE, 1.0)
    };
    let weeks = (time.unix_ms() - origin.unix_ms()) as f64 / WEEK_MS as f64;
    let gap_mrad = base + growth * weeks + 0.05 * noise(u64::from(n));
    let pool_filling = (time.unix_ms() - origin.unix_ms()) < 10 * EVERY_MS;
    let degraded = n.is_multiple_of(37);
    let taf = if degraded {
        9.0
    } else {
        1.3 + 0.1 * noise(u64::from(n) + 7_777)
    };
    let static_torque_knm = 400.0 + 50.0 * noise(u64::from(n) + 99);
    let state = DrivelineResults {
        bite_counter: n,
        taf: Some(taf),
        // A wear index for clean windows, and a trend that moves on its own.
        wear_index: (!degraded).then_some(taf / 1.3 - 1.0),
        wear_trend: (!n.is_multiple_of(41)).then_some(0.01 * f64::from(n % 100)),
        ..DrivelineResults::default()
    };
    HistoryEvent::Bite(Box::new(BiteRecord {
        driveline: "F1".into(),
        channel: "spindle_top".into(),
        time,
        figures: DrivelineResults {
            last_bite_unix_ms: Some(time.unix_ms()),
            static_torque_knm: Some(static_torque_knm),
            peak_torque_knm: Some(taf * static_torque_knm),
            taf: (!n.is_multiple_of(53)).then_some(taf),
            first_period_s: Some(0.05),
            first_period_shift_s: Some(0.002),
            last_bite_degraded: degraded,
            gap: (!pool_filling).then(|| GapResults {
                gap_mrad,
                low_mrad: gap_mrad - 0.3 - 0.1 * noise(u64::from(n) + 5),
                high_mrad: gap_mrad + 0.4 + 0.1 * noise(u64::from(n) + 11),
                coupling: Some(1),
                likeliest_coupling: None,
                bites_pooled: 20,
                growth: None,
                forecast: None,
            }),
            ..state.clone()
        },
        second_period_s: Some(0.048),
        quality: "good",
        reference_taf: Some(1.3),
        reference_level_knm: Some(400.0),
        shift_over_linear_s: None,
        gap_state: (!pool_filling).then_some(WearState::Ok),
        gap_trend: None,
        fatigue_ledger: None,
        context: None,
        pooled: None,
        state,
    }))
}

fn settings(name: &str) -> DrivelineSettings {
    DrivelineSettings {
        name: name.into(),
        taf_warning: 1.8,
        taf_alarm: 2.2,
        model: None,
        gap_warning_mrad: Some(4.0),
        gap_alarm_mrad: Some(6.0),
    }
}

/// F1: a bite every 15 min for 20 days (hole and reset as above); F2 configured
/// without bites. Written by the gateway's writer thread.
fn write_file(folder: &Path) -> PathBuf {
    let path = folder.join("history.db");
    let history = History::new(Some(&millgate_config::History {
        path: path.clone(),
        retention_days: 3650,
        max_size_mb: 1024,
        captures: millgate_config::CaptureSettings::defaults(1024),
        synchronous: millgate_config::Synchronous::default(),
    }));
    millgate::history::start(
        &history,
        RunInfo {
            version: "test".into(),
            config_name: "series test".into(),
            config_hash: String::new(),
            drivelines: vec![settings("F1"), settings("F2")],
        },
    );
    let mut n = 0;
    let mut reset_done = false;
    let mut time_ms = start().unix_ms();
    while time_ms < start().unix_ms() + DAYS * DAY_MS {
        let time = UtcTime::from_unix_ms(time_ms);
        if !reset_done && time > reset_time() {
            reset_done = true;
            assert!(history.record(HistoryEvent::WearReset {
                time: reset_time(),
                driveline: "F1".into(),
                origin: CommandOrigin::Local,
            }));
        }
        let day = (time_ms - start().unix_ms()) / DAY_MS;
        if !HOLE_DAYS.contains(&day) {
            n += 1;
            // The queue holds 4096 events: far more than this file's ~1600.
            assert!(history.record(bite(n, time)), "bite {n} dropped");
        }
        time_ms += EVERY_MS;
    }
    history.close();
    path
}

/// F1's bites as (Unix ms, row), read through the plain row API (no aggregation).
fn all_bites(reader: &HistoryReader) -> Vec<(i64, millgate::history::query::BiteRow)> {
    reader
        .bites(&Filter {
            name: Some("F1".into()),
            ..Filter::default()
        })
        .unwrap()
        .into_iter()
        .map(|row| (UtcTime::parse(&row.time()).unwrap().unix_ms(), row))
        .collect()
}

/// The buckets rebuilt from every row, as `wear_series` documents them.
fn reference_series(
    reader: &HistoryReader,
    since: Option<UtcTime>,
    until: Option<UtcTime>,
    points: usize,
) -> Vec<WearPoint> {
    let bites = all_bites(reader);
    let since = since.map_or(bites[0].0, UtcTime::unix_ms);
    let until = until.map_or(bites.last().unwrap().0 + 1, UtcTime::unix_ms);
    let width = ((until - since) + points as i64 - 1) / points as i64;
    let mut series: Vec<WearPoint> = Vec::new();
    for (ms, row) in bites.iter().filter(|(ms, _)| (since..until).contains(ms)) {
        let bucket = (ms - since) / width;
        let start = UtcTime::from_unix_ms(since + bucket * width);
        if series.last().is_none_or(|p| p.start != start) {
            series.push(WearPoint {
                start,
                end: UtcTime::from_unix_ms((start.unix_ms() + width).min(until)),
                bites: 0,
                gap_mrad: None,
                gap_low_mrad: None,
                gap_high_mrad: None,
                taf_mean: None,
                taf_min: None,
                taf_max: None,
            });
        }
        let point = series.last_mut().unwrap();
        point.bites += 1;
        if row.figures.gap.map(|g| g.gap_mrad).is_some() {
            point.gap_mrad = row.figures.gap.map(|g| g.gap_mrad);
        }
        let min = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let max = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        point.gap_low_mrad = min(point.gap_low_mrad, row.figures.gap.map(|g| g.low_mrad));
        point.gap_high_mrad = max(point.gap_high_mrad, row.figures.gap.map(|g| g.high_mrad));
        if !row.figures.last_bite_degraded {
            point.taf_min = min(point.taf_min, row.figures.taf);
            point.taf_max = max(point.taf_max, row.figures.taf);
        }
    }
    // Mean TAF in a second pass, per bucket.
    for point in &mut series {
        let tafs: Vec<f64> = bites
            .iter()
            .filter(|(ms, row)| {
                (point.start.unix_ms()..point.end.unix_ms()).contains(ms)
                    && !row.figures.last_bite_degraded
            })
            .filter_map(|(_, row)| row.figures.taf)
            .collect();
        point.taf_mean = (!tafs.is_empty()).then(|| tafs.iter().sum::<f64>() / tafs.len() as f64);
    }
    series
}

fn assert_close(a: Option<f64>, b: Option<f64>, what: &str) {
    match (a, b) {
        (Some(a), Some(b)) => assert!(
            (a - b).abs() <= 1e-12 * a.abs().max(1.0),
            "{what}: {a} vs {b}"
        ),
        (a, b) => assert_eq!(a, b, "{what}"),
    }
}

fn assert_same_series(got: &[WearPoint], want: &[WearPoint]) {
    assert_eq!(got.len(), want.len(), "bucket count");
    for (g, w) in got.iter().zip(want) {
        assert_eq!((g.start, g.end, g.bites), (w.start, w.end, w.bites));
        // Min, max and last are values of the file: exact.
        assert_eq!(g.gap_mrad, w.gap_mrad, "gap of {}", g.start);
        assert_eq!(g.gap_low_mrad, w.gap_low_mrad);
        assert_eq!(g.gap_high_mrad, w.gap_high_mrad);
        assert_eq!(g.taf_min, w.taf_min);
        assert_eq!(g.taf_max, w.taf_max);
        assert_close(g.taf_mean, w.taf_mean, "taf mean");
    }
}

/// The wear index's buckets rebuilt from every row, as `wear_index_series` documents
/// them: the buckets of the bites (those of `reference_series`), each with the range
/// of its bites' wear index and the trend after its last bite that had one.
fn reference_index_series(
    reader: &HistoryReader,
    since: Option<UtcTime>,
    until: Option<UtcTime>,
    points: usize,
) -> Vec<WearIndexPoint> {
    let bites = all_bites(reader);
    reference_series(reader, since, until, points)
        .iter()
        .filter_map(|bucket| {
            let rows: Vec<&BiteRow> = bites
                .iter()
                .filter(|(ms, _)| (bucket.start.unix_ms()..bucket.end.unix_ms()).contains(ms))
                .map(|(_, row)| row)
                .collect();
            let indexes: Vec<f64> = rows
                .iter()
                .filter_map(|row| row.figures.wear_index)
                .collect();
            let index_min = indexes.iter().copied().reduce(f64::min)?;
            Some(WearIndexPoint {
                start: bucket.start,
                end: bucket.end,
                bites: indexes.len() as u32,
                index_min,
                index_max: indexes.iter().copied().reduce(f64::max)?,
                trend: rows.iter().rev().find_map(|row| row.figures.wear_trend),
                static_torque_min_knm: rows
                    .iter()
                    .filter_map(|row| row.figures.static_torque_knm)
                    .reduce(f64::min)?,
                static_torque_max_knm: rows
                    .iter()
                    .filter_map(|row| row.figures.static_torque_knm)
                    .reduce(f64::max)?,
            })
        })
        .collect()
}

/// Least-squares slope by the two-pass (centred) formula, per week.
fn reference_slope(points: &[(i64, f64)]) -> f64 {
    let n = points.len() as f64;
    let mean_x = points.iter().map(|p| p.0 as f64).sum::<f64>() / n;
    let mean_y = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = points
        .iter()
        .map(|p| (p.0 as f64 - mean_x) * (p.1 - mean_y))
        .sum();
    let sxx: f64 = points.iter().map(|p| (p.0 as f64 - mean_x).powi(2)).sum();
    sxy / sxx * WEEK_MS as f64
}

#[test]
fn series_and_trend_match_computations_without_sql() {
    let scratch = scratch("series-all");
    let path = write_file(scratch.path());
    let reader = HistoryReader::open(&path).unwrap();
    let bites = all_bites(&reader);
    assert!(bites.len() > 1500, "{} bites", bites.len());

    // The whole file in 100 buckets (about 4.8 h each): the 3-day hole leaves ~15
    // buckets out, none is empty.
    let series = reader.wear_series("F1", None, None, 100).unwrap();
    assert_same_series(&series, &reference_series(&reader, None, None, 100));
    assert!(
        (80..=90).contains(&series.len()),
        "{} buckets",
        series.len()
    );
    assert!(series.iter().all(|p| p.bites > 0));
    assert_eq!(
        series.iter().map(|p| p.bites as usize).sum::<usize>(),
        bites.len()
    );
    let hole_start = start().unix_ms() + HOLE_DAYS.start * DAY_MS;
    let hole_end = start().unix_ms() + HOLE_DAYS.end * DAY_MS;
    assert!(!series
        .iter()
        .any(|p| p.start.unix_ms() >= hole_start && p.end.unix_ms() <= hole_end));
    // Degraded windows' TAF of 9 is left out of the TAF figures.
    assert!(series.iter().all(|p| p.taf_max.unwrap() < 1.5));
    // The first bucket starts while the pool fills: a gap nonetheless (later bites).
    assert!(series[0].gap_mrad.is_some());

    // A range given: day 2.5 to day 14 in 37 buckets (width not a divisor of the
    // range, last bucket short), across the hole and the reset.
    let since = UtcTime::from_unix_ms(start().unix_ms() + 5 * DAY_MS / 2);
    let until = UtcTime::from_unix_ms(start().unix_ms() + 14 * DAY_MS);
    let ranged = reader
        .wear_series("F1", Some(since), Some(until), 37)
        .unwrap();
    assert_same_series(
        &ranged,
        &reference_series(&reader, Some(since), Some(until), 37),
    );
    assert_eq!(ranged[0].start, since);
    assert!(ranged.last().unwrap().end <= until);

    // The wear index in the same buckets (min, max and last are the file's values:
    // exact).
    for (since, until, points) in [(None, None, 100), (Some(since), Some(until), 37)] {
        let index = reader
            .wear_index_series("F1", since, until, points)
            .unwrap();
        assert!(index.len() >= 25, "{} buckets", index.len());
        assert_eq!(index, reference_index_series(&reader, since, until, points));
    }

    // One point: every bite, the last gap of the file.
    let one = reader.wear_series("F1", None, None, 1).unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(one[0].bites as usize, bites.len());
    assert_eq!(
        one[0].gap_mrad,
        bites
            .iter()
            .rev()
            .find_map(|(_, row)| row.figures.gap.map(|g| g.gap_mrad))
    );
    assert_same_series(&one, &reference_series(&reader, None, None, 1));

    // More points than bites: one bucket per bite at most.
    let fine = reader
        .wear_series("F1", None, None, MAX_SERIES_POINTS)
        .unwrap();
    assert_same_series(
        &fine,
        &reference_series(&reader, None, None, MAX_SERIES_POINTS),
    );
    assert!(fine.iter().all(|p| p.bites == 1));

    // The trend over four weeks: after the reset only (the bites before it grew at
    // another rate), against a two-pass fit of those bites and the generated rate.
    let trend = reader
        .gap_trend("F1", None, Duration::from_secs(28 * 86_400))
        .unwrap()
        .expect("a trend");
    let after: Vec<(i64, f64)> = bites
        .iter()
        .filter(|(ms, _)| *ms > reset_time().unix_ms())
        .filter_map(|(ms, row)| row.figures.gap.map(|g| g.gap_mrad).map(|gap| (*ms, gap)))
        .collect();
    assert_eq!(trend.bites as usize, after.len());
    assert_eq!(trend.since.unix_ms(), after[0].0);
    let want = reference_slope(&after);
    assert!(
        (trend.mrad_per_week - want).abs() < 1e-9,
        "{} vs {want}",
        trend.mrad_per_week
    );
    assert!(
        (trend.mrad_per_week - GROWTH_AFTER).abs() < 0.05,
        "slope {} against the generated {GROWTH_AFTER}",
        trend.mrad_per_week
    );

    // Before the reset, a window of 3 days ending at day 11: the first coupling's rate.
    let until_11 = UtcTime::from_unix_ms(start().unix_ms() + 11 * DAY_MS);
    let before = reader
        .gap_trend("F1", Some(until_11), Duration::from_secs(3 * 86_400))
        .unwrap()
        .expect("a trend");
    let window: Vec<(i64, f64)> = bites
        .iter()
        .filter(|(ms, _)| (until_11.unix_ms() - 3 * DAY_MS..until_11.unix_ms()).contains(ms))
        .filter_map(|(ms, row)| row.figures.gap.map(|g| g.gap_mrad).map(|gap| (*ms, gap)))
        .collect();
    assert_eq!(before.bites as usize, window.len());
    assert!((before.mrad_per_week - reference_slope(&window)).abs() < 1e-9);
    assert!((before.mrad_per_week - GROWTH_BEFORE).abs() < 0.1);

    // Right after the reset the pool fills: fewer than MIN_TREND_BITES estimates.
    let just_after = UtcTime::from_unix_ms(reset_time().unix_ms() + 14 * EVERY_MS);
    let few = reader
        .gap_trend("F1", Some(just_after), Duration::from_secs(28 * 86_400))
        .unwrap();
    let estimates = bites
        .iter()
        .filter(|(ms, row)| {
            (reset_time().unix_ms() + 1..just_after.unix_ms()).contains(ms)
                && row.figures.gap.map(|g| g.gap_mrad).is_some()
        })
        .count();
    assert!(estimates < MIN_TREND_BITES as usize, "{estimates}");
    assert_eq!(few, None);

    numpy_agrees(&path, trend.mrad_per_week, reset_time());
}

/// numpy's polyfit of the bites after `reset` read by Python's sqlite3; skipped with
/// a message when python3 or numpy is missing.
fn numpy_agrees(path: &Path, slope: f64, reset: UtcTime) {
    let script = r#"
import sqlite3, sys, datetime
import numpy
rows = sqlite3.connect(sys.argv[1]).execute(
    "SELECT time, gap_mrad FROM bites WHERE driveline = 'F1' AND gap_mrad IS NOT NULL "
    "AND time > ?", (sys.argv[2],)).fetchall()
parse = lambda t: datetime.datetime.fromisoformat(t.replace('Z', '+00:00')).timestamp()
x = numpy.array([parse(t) for t, _ in rows]) / (7 * 86400.0)
y = numpy.array([g for _, g in rows])
print(repr(float(numpy.polyfit(x - x[0], y, 1)[0])))
"#;
    let output = match Command::new("python3")
        .args(["-c", script])
        .arg(path)
        .arg(reset.to_string())
        .output()
    {
        Ok(output) => output,
        Err(error) => {
            eprintln!("SKIPPED numpy check: python3 not found ({error})");
            return;
        }
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if stderr.contains("No module named 'numpy'") {
        eprintln!("SKIPPED numpy check: python3 has no numpy (pip install numpy)");
        return;
    }
    assert!(output.status.success(), "python: {stderr}");
    let numpy: f64 = String::from_utf8_lossy(&output.stdout)
        .trim()
        .parse()
        .unwrap();
    assert!((numpy - slope).abs() < 1e-9, "numpy {numpy} vs {slope}");
}

#[test]
fn empty_unknown_and_bad_arguments() {
    let scratch = scratch("series-edges");
    let path = write_file(scratch.path());
    let reader = HistoryReader::open(&path).unwrap();

    // F2 is configured, without bites.
    assert_eq!(reader.wear_series("F2", None, None, 500).unwrap(), vec![]);
    assert_eq!(
        reader
            .gap_trend("F2", None, Duration::from_secs(86_400))
            .unwrap(),
        None
    );
    // A range without bites (the hole) is empty too, a range before the file too.
    let hole = |day| UtcTime::from_unix_ms(start().unix_ms() + day * DAY_MS);
    assert_eq!(
        reader
            .wear_series("F1", Some(hole(5)), Some(hole(8)), 10)
            .unwrap(),
        vec![]
    );
    assert_eq!(
        reader
            .gap_trend("F1", Some(hole(8)), Duration::from_secs(3 * 86_400))
            .unwrap(),
        None
    );
    assert_eq!(
        reader
            .wear_series("F1", Some(hole(-9)), Some(hole(-8)), 10)
            .unwrap(),
        vec![]
    );

    let unknown = reader.wear_series("F9", None, None, 10).unwrap_err();
    assert!(matches!(unknown, HistoryError::UnknownDriveline { .. }));
    assert!(
        unknown
            .to_string()
            .ends_with("no driveline \"F9\" in the file"),
        "{unknown}"
    );
    assert!(matches!(
        reader.gap_trend("F9", None, Duration::from_secs(60)),
        Err(HistoryError::UnknownDriveline { .. })
    ));

    for points in [0, MAX_SERIES_POINTS + 1] {
        let error = reader.wear_series("F1", None, None, points).unwrap_err();
        assert_eq!(
            error.to_string(),
            format!("history query: points = {points} is out of range (1..=10000)")
        );
    }
    let error = reader
        .wear_series("F1", Some(hole(2)), Some(hole(1)), 10)
        .unwrap_err();
    assert!(
        error
            .to_string()
            .starts_with("history query: since = 2026-03-03T00:00:00.000Z is out of range"),
        "{error}"
    );
    let error = reader.gap_trend("F1", None, Duration::ZERO).unwrap_err();
    assert!(
        error.to_string().starts_with("history query: window ="),
        "{error}"
    );
}
