//! `millgate report` and `millgate history` on two weeks of bites of two drivelines
//! (a bite every 30 s: 80 636), written through the gateway's own writer inserts:
//! the report's plots are time buckets and binned cells, not a mark per bite, its
//! driveline table has the gap columns the file holds (the growth and the expected
//! date of the gap alarm too, rows sorted by that date), the gap's forecast redrawn
//! from a saved wear trend (the dsp filter fed a linear gap) holds the true crossing
//! of the alarm, a run killed without a stop counts as running only until its last
//! recorded event, and both commands stay in bounded memory (GNU time's peak RSS) and
//! show progress only on a terminal (`script` gives them one). The bites carry a
//! product (issue 39): the report's table by product and `history --product` against
//! the file. Another application's
//! SQLite file is refused. Independent readings of the file come from Debian's
//! `sqlite3`.
#![cfg(feature = "plot")]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use common::{millgate, scratch, MILLGATE};
use millgate::history::schema::APPLICATION_ID;
use millgate::history::writer;
use millgate::history::{DrivelineSettings, RunInfo};
use millgate::state::context::{BiteGate, MillState, ProcessContext};
use millgate::state::events::{BiteRecord, HistoryEvent, WearState};
use millgate::state::results::{
    DrivelineResults, ForecastState, GapForecast, GapGrowth, GapResults,
};
use millgate::state::time::UtcTime;
use millgate_dsp::wear_trend::{Phase, WearTrend};

const DAY_MS: i64 = 86_400_000;
const WEEK_MS: f64 = 7.0 * 86_400_000.0;
/// Days of bites, the bite period, the day the first run stops.
const DAYS: i64 = 14;
const EVERY_MS: i64 = 30_000;
const FIRST_RUN_DAYS: i64 = 7;
/// The gap opens at exactly this rate from 0.5 mrad: the report's trend must say it.
const GROWTH_MRAD_PER_WEEK: f64 = 0.2;
/// The report's period ends this long after the last bite.
const AFTER_LAST_MS: i64 = 5 * DAY_MS;

/// `millgate args` under GNU time: its output and its peak RSS in KiB (`None` when
/// /usr/bin/time is missing; scripts/test installs it).
fn millgate_measured(args: &[&str]) -> (Output, Option<u64>) {
    if !Path::new("/usr/bin/time").is_file() {
        eprintln!("/usr/bin/time missing (apt install time): peak RSS not checked");
        return (millgate(args), None);
    }
    let folder = scratch("report-rss");
    let report = folder.path().join("peak-rss");
    let output = Command::new("/usr/bin/time")
        .arg("-f")
        .arg("%M")
        .arg("-o")
        .arg(&report)
        .arg(MILLGATE.0)
        .args(args)
        .output()
        .expect("run millgate under /usr/bin/time");
    let kib = std::fs::read_to_string(&report)
        .ok()
        .and_then(|text| text.trim().parse().ok());
    (output, kib)
}

fn sqlite3(db: &Path, sql: &str) -> String {
    let output = Command::new("sqlite3")
        .arg("-readonly")
        .arg(db)
        .arg(sql)
        .output()
        .expect("Debian's sqlite3 (apt install sqlite3)");
    assert!(output.status.success(), "{output:?}");
    String::from_utf8(output.stdout).unwrap().trim().to_owned()
}

fn start() -> UtcTime {
    UtcTime::parse("2026-02-01T00:00:00Z").unwrap()
}

/// A deterministic value in [0, 1).
fn unit(n: u64) -> f64 {
    let x = n
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// The gap alarm threshold of the runs' settings, mrad.
const GAP_ALARM_MRAD: f64 = 6.0;

/// The true gap at `time_ms`, mrad.
fn true_gap_mrad(time_ms: i64) -> f64 {
    0.5 + GROWTH_MRAD_PER_WEEK * (time_ms - start().unix_ms()) as f64 / WEEK_MS
}

/// The forecast figures a bite of `driveline` at `time_ms` stores: F1's point value
/// at the true crossing of the alarm with a +-10% interval; F2's at half those days
/// (its alarm comes sooner: it sorts first).
fn stored_forecast(driveline: &str, time_ms: i64) -> (GapGrowth, GapForecast) {
    let rate = GROWTH_MRAD_PER_WEEK / 7.0;
    let days = (GAP_ALARM_MRAD - true_gap_mrad(time_ms))
        / rate
        / if driveline == "F2" { 2.0 } else { 1.0 };
    let growth = GapGrowth {
        mrad_per_day: rate,
        low_mrad_per_day: 0.9 * rate,
        high_mrad_per_day: 1.1 * rate,
    };
    let forecast = GapForecast {
        state: ForecastState::Forecast,
        days: Some(days),
        days_low: Some(0.9 * days),
        days_high: Some(1.1 * days),
        date_unix_ms: Some(time_ms + (days * DAY_MS as f64).round() as i64),
        cone: None,
    };
    (growth, forecast)
}

/// The wear trend F1's last bite at `last_ms` leaves in the history, in its saved
/// form: the dsp filter fed a Gaussian observation (sd 0.1 mrad) of the true gap
/// once a day over the two weeks, as the gateway's trend would hold it.
fn saved_trend(last_ms: i64) -> String {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(1).unwrap();
    let first_ms = start().unix_ms();
    let mut bites = 0;
    for day in 0.. {
        let time_ms = (first_ms + day * DAY_MS).min(last_ms);
        trend
            .predict(&mut state, time_ms as f64 / DAY_MS as f64)
            .unwrap();
        trend
            .update_gaussian(&mut state, 0, true_gap_mrad(time_ms), 0.01)
            .unwrap();
        trend.finish_bite(&mut state, None);
        bites += 1;
        if time_ms == last_ms {
            break;
        }
    }
    let h = state.hypotheses[0];
    assert_eq!(h.phase, Phase::Tracking, "{bites} bites: {h:?}");
    serde_json::json!({
        "version": 1,
        "couplings": [1],
        "first_bite_unix_ms": first_ms,
        "last_bite_unix_ms": last_ms,
        "t_last_days": state.t_last_days,
        "bites": state.bites,
        "floor2_mrad2": state.floor2_mrad2,
        "floor_measured": state.floor_measured,
        "hypotheses": [{
            "gap_mrad": h.gap_mrad,
            "rate_mrad_per_day": h.rate_mrad_per_day,
            "p": h.p,
            "loglik": h.loglik,
            "scale": h.scale,
            "phase": "tracking",
            "time_days": h.time_days,
            "outlier_run": h.outlier_run,
        }],
    })
    .to_string()
}

fn bite(driveline: &str, n: u32, time_ms: i64, last: bool) -> HistoryEvent {
    let gap_mrad = true_gap_mrad(time_ms);
    let (growth, forecast) = stored_forecast(driveline, time_ms);
    let degraded = n.is_multiple_of(211);
    let static_torque_knm = 300.0 + 300.0 * unit(u64::from(n) * 3);
    let taf = 1.2 + 0.05 * gap_mrad + 0.1 * unit(u64::from(n) * 7) - 1e-4 * static_torque_knm;
    let state = DrivelineResults {
        bite_counter: n,
        taf: Some(taf),
        wear_index: (!degraded).then_some(taf / 1.25 - 1.0),
        wear_trend: Some(0.001 * f64::from(n % 1000)),
        last_bite_gated: Some(if n.is_multiple_of(5) {
            BiteGate::State
        } else {
            BiteGate::Pooled
        }),
        ..DrivelineResults::default()
    };
    HistoryEvent::Bite(Box::new(BiteRecord {
        driveline: driveline.into(),
        channel: "spindle".into(),
        time: UtcTime::from_unix_ms(time_ms),
        figures: DrivelineResults {
            last_bite_unix_ms: Some(time_ms),
            static_torque_knm: Some(static_torque_knm),
            peak_torque_knm: Some(taf * static_torque_knm),
            first_period_s: Some(0.05),
            first_period_shift_s: Some(0.002),
            last_bite_degraded: degraded,
            gap: Some(GapResults {
                gap_mrad,
                low_mrad: gap_mrad - 0.4,
                high_mrad: gap_mrad + 0.5,
                coupling: Some(1),
                likeliest_coupling: None,
                bites_pooled: 200,
                growth: Some(growth),
                forecast: Some(forecast),
            }),
            ..state.clone()
        },
        second_period_s: Some(0.048),
        quality: "good",
        reference_taf: Some(1.25),
        reference_level_knm: Some(400.0),
        shift_over_linear_s: None,
        gap_state: Some(WearState::Ok),
        gap_trend: (last && driveline == "F1").then(|| saved_trend(time_ms)),
        fatigue_ledger: None,
        context: Some(context(n)),
        pooled: None,
        state,
    }))
}

/// Bite `n`'s process context: product 101 every third bite, else 205; threading
/// (not pooled) every fifth.
fn context(n: u32) -> ProcessContext {
    ProcessContext {
        product: Some(if n.is_multiple_of(3) { 101 } else { 205 }),
        speed_mpm: Some(250.0),
        state: Some(if n.is_multiple_of(5) {
            MillState::Threading
        } else {
            MillState::Rolling
        }),
        ..ProcessContext::default()
    }
}

fn run_info() -> RunInfo {
    RunInfo {
        version: "test".into(),
        config_name: "report test mill".into(),
        config_hash: String::new(),
        drivelines: ["F1", "F2"]
            .map(|name| DrivelineSettings {
                name: name.into(),
                taf_warning: 1.6,
                taf_alarm: 1.9,
                model: None,
                gap_warning_mrad: Some(4.0),
                gap_alarm_mrad: Some(GAP_ALARM_MRAD),
            })
            .to_vec(),
    }
}

/// Two weeks of bites of F1 and F2 every 30 s: a first run stopped cleanly after
/// 7 days, a second run killed (no stop recorded) after the last bite. Returns the
/// file and the last bite's time.
fn write_history(folder: &Path) -> (PathBuf, UtcTime) {
    let path = folder.join("history.db");
    let mut connection = writer::connect(&path).unwrap();
    let stop_ms = start().unix_ms() + FIRST_RUN_DAYS * DAY_MS;
    let second_ms = stop_ms + 60_000;
    let transaction = connection.transaction().unwrap();
    let mut run_id = writer::insert_run(&transaction, start(), &run_info()).unwrap();
    let mut counters = [0u32; 2];
    let mut time_ms = start().unix_ms();
    let end_ms = start().unix_ms() + DAYS * DAY_MS;
    let mut last = start();
    while time_ms < end_ms {
        if time_ms >= stop_ms && run_id == 1 {
            transaction
                .execute(
                    "UPDATE gateway_runs SET stopped_at = ?1, ended = 'stopped' WHERE id = 1",
                    [UtcTime::from_unix_ms(stop_ms).to_string()],
                )
                .unwrap();
            time_ms = time_ms.max(second_ms);
            run_id =
                writer::insert_run(&transaction, UtcTime::from_unix_ms(second_ms), &run_info())
                    .unwrap();
        }
        for (k, name) in ["F1", "F2"].iter().enumerate() {
            counters[k] += 1;
            let at = time_ms + 7_500 * k as i64;
            let last_bite = time_ms + EVERY_MS >= end_ms;
            let bite = bite(name, counters[k], at, last_bite);
            millgate::history::rows::insert(&transaction, run_id, &bite).unwrap();
            last = UtcTime::from_unix_ms(at);
        }
        time_ms += EVERY_MS;
    }
    transaction.commit().unwrap();
    (path, last)
}

/// The row of `driveline` in the report's driveline table.
fn table_row<'a>(md: &'a str, driveline: &str) -> Vec<&'a str> {
    md.lines()
        .find(|line| line.starts_with(&format!("| {driveline} |")))
        .unwrap_or_else(|| panic!("no row for {driveline}: {md}"))
        .trim_matches('|')
        .split('|')
        .map(str::trim)
        .collect()
}

/// A percentage the report prints after `prefix`.
fn percent_after(text: &str, prefix: &str) -> f64 {
    let at = text
        .find(prefix)
        .unwrap_or_else(|| panic!("{prefix}: {text}"))
        + prefix.len();
    text[at..]
        .split('%')
        .next()
        .and_then(|number| number.trim().parse().ok())
        .unwrap_or_else(|| panic!("a percentage after {prefix}: {text}"))
}

#[test]
fn report_of_two_weeks_of_bites_plots_buckets_and_cells_and_counts_a_killed_run_honestly() {
    let scratch = scratch("history-report-report");
    let (db, last) = write_history(scratch.path());
    let db_arg = db.to_str().unwrap();
    let until = UtcTime::from_unix_ms(last.unix_ms() + AFTER_LAST_MS);
    let out = scratch.path().join("report");
    let (output, peak_kib) = millgate_measured(&[
        "report",
        "--db",
        db_arg,
        "--out",
        out.to_str().unwrap(),
        "--until",
        &until.to_string(),
    ]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // Not a terminal: no progress on stderr.
    assert!(
        output.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let bites: u64 = sqlite3(&db, "SELECT count(*) FROM bites").parse().unwrap();
    assert!(bites > 80_000, "{bites} bites");
    // Bounded memory: the old report held every bite and an SVG element per bite
    // (some 1.7 KB a bite: 140 MB here).
    if let Some(kib) = peak_kib {
        assert!(
            kib < 100 * 1024,
            "report peak RSS {kib} KiB for {bites} bites"
        );
    }

    // Plots reduced to what a reader can see: no mark per bite.
    for name in ["F1", "F2"] {
        let time = std::fs::read_to_string(out.join(format!("{name}-time.svg"))).unwrap();
        let taf = std::fs::read_to_string(out.join(format!("{name}-taf.svg"))).unwrap();
        assert_eq!(time.matches("<circle").count(), 0, "{name}-time.svg");
        assert!(
            time.len() < 400_000,
            "{name}-time.svg: {} bytes",
            time.len()
        );
        // At most a cell per 180 x 90 (clean) and a dot per cell (degraded).
        assert!(
            taf.matches("<rect").count() <= 180 * 90 + 50,
            "{name}-taf.svg"
        );
        assert!(
            taf.matches("<circle").count() <= 180 * 90 + 10,
            "{name}-taf.svg"
        );
        assert!(taf.len() < 2_000_000, "{name}-taf.svg: {} bytes", taf.len());
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.len() < 5_000_000, "report.html: {} bytes", html.len());
    assert!(
        html.contains("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"),
        "viewport"
    );

    // The driveline table: counts and the gap columns against the file.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for name in ["F1", "F2"] {
        let row = table_row(&md, name);
        let count = sqlite3(
            &db,
            &format!("SELECT count(*) FROM bites WHERE driveline = '{name}'"),
        );
        let degraded = sqlite3(
            &db,
            &format!("SELECT count(*) FROM bites WHERE driveline = '{name}' AND degraded"),
        );
        assert_eq!(
            (row[1], row[2]),
            (count.as_str(), degraded.as_str()),
            "{row:?}"
        );
        let max = sqlite3(
            &db,
            &format!(
                "SELECT printf('%.3f', max(taf)) FROM bites WHERE driveline = '{name}' \
                 AND NOT degraded"
            ),
        );
        assert_eq!(row[5], max, "{row:?}");
        let last_gap = sqlite3(
            &db,
            &format!(
                "SELECT printf('%.2f|%.2f..%.2f|%s', gap_mrad, gap_low_mrad, gap_high_mrad, \
                 gap_coupling) FROM bites WHERE driveline = '{name}' ORDER BY time DESC LIMIT 1"
            ),
        );
        assert_eq!(row[9..12].join("|"), last_gap, "{row:?}");
        // The gap opened at exactly 0.2 mrad/week.
        assert_eq!(row[12], "+0.200", "{row:?}");
        // The growth and the expected date after the last bite, as stored.
        let stored = sqlite3(
            &db,
            &format!(
                "SELECT printf('%+.4f (%+.4f..%+.4f)|%s (%s..%s)', gap_growth_mrad_per_day, \
                 gap_growth_low_mrad_per_day, gap_growth_high_mrad_per_day, \
                 substr(gap_alarm_date, 1, 10), \
                 date(time, printf('%+.6f days', days_to_gap_alarm_low)), \
                 date(time, printf('%+.6f days', days_to_gap_alarm_high))) \
                 FROM bites WHERE driveline = '{name}' ORDER BY time DESC LIMIT 1"
            ),
        );
        assert_eq!(row[13..15].join("|"), stored, "{row:?}");
    }
    // Bites by product (issue 39): counts, the not pooled and TAF against the file.
    for name in ["F1", "F2"] {
        for product in ["101", "205"] {
            let row: Vec<&str> = md
                .lines()
                .find(|line| line.starts_with(&format!("| {name} | {product} |")))
                .unwrap_or_else(|| panic!("no product row {name} {product}: {md}"))
                .trim_matches('|')
                .split('|')
                .map(str::trim)
                .collect();
            let stored = sqlite3(
                &db,
                &format!(
                    "SELECT printf('%d|%d|%.3f|%.3f', count(*), \
                     count(CASE WHEN gated = 1 THEN 1 END), \
                     avg(CASE WHEN NOT degraded THEN taf END), \
                     max(CASE WHEN NOT degraded THEN taf END)) \
                     FROM bites WHERE driveline = '{name}' AND product = {product}"
                ),
            );
            assert_eq!(row[2..6].join("|"), stored, "{row:?}");
        }
    }
    // Sorted by the expected date: F2's comes first.
    let at = |name: &str| md.find(&format!("\n| {name} |")).unwrap();
    assert!(at("F2") < at("F1"), "{md}");

    // F1's forecast from the wear trend the history saved: its date and interval
    // against the true crossing of the alarm (the gap grows linearly).
    let section = &md[md.find("### F1").unwrap()..];
    let said = section
        .split("alarm expected ")
        .nth(1)
        .unwrap_or_else(|| panic!("no expected date: {md}"));
    let date = |text: &str| UtcTime::parse(text).unwrap_or_else(|_| panic!("{text}: {said}"));
    let (point, low, high) = (date(&said[..10]), date(&said[12..22]), date(&said[24..34]));
    let truth_ms =
        start().unix_ms() + ((GAP_ALARM_MRAD - 0.5) / GROWTH_MRAD_PER_WEEK * WEEK_MS) as i64;
    let ahead_ms = (truth_ms - last.unix_ms()) as f64;
    assert!(
        low.unix_ms() - DAY_MS <= truth_ms && truth_ms <= high.unix_ms() + DAY_MS,
        "true crossing {} outside {said}",
        UtcTime::from_unix_ms(truth_ms)
    );
    assert!(
        ((point.unix_ms() - truth_ms) as f64).abs() <= 0.2 * ahead_ms,
        "expected {point}, truly {}: {said}",
        UtcTime::from_unix_ms(truth_ms)
    );
    let gap_svg = std::fs::read_to_string(out.join("F1-gap.svg")).unwrap();
    for drawn in [
        "forecast 90% band",
        "fitted growth",
        "alarm expected",
        "alarm 6",
    ] {
        assert!(gap_svg.contains(drawn), "F1-gap.svg lacks {drawn:?}");
    }
    // F2 has gap estimates but no saved trend: its plot without a forecast, and why.
    let f2_svg = std::fs::read_to_string(out.join("F2-gap.svg")).unwrap();
    assert!(!f2_svg.contains("alarm expected"), "F2-gap.svg");
    assert!(
        md.contains("No forecast drawn: the history keeps no wear trend"),
        "{md}"
    );

    // The killed run counts as running until its last bite, not to the period's end;
    // what follows is said to be unknown.
    let period_ms = (until.unix_ms() - start().unix_ms()) as f64;
    let second_ms = start().unix_ms() + FIRST_RUN_DAYS * DAY_MS + 60_000;
    let up_ms = (FIRST_RUN_DAYS * DAY_MS + (last.unix_ms() - second_ms)) as f64;
    let ran = percent_after(&md, "The gateway ran ");
    assert!(
        (ran - 100.0 * up_ms / period_ms).abs() < 0.06,
        "{ran}: {md}"
    );
    assert!(
        md.contains("(2 runs, 0 ended uncleanly). 1 run(s) have no recorded stop"),
        "{md}"
    );
    let unknown = percent_after(&md, "the next start or the period's end, ");
    assert!(
        (unknown - 100.0 * AFTER_LAST_MS as f64 / period_ms).abs() < 0.06,
        "{unknown}: {md}"
    );
    let availability = std::fs::read_to_string(out.join("availability.svg")).unwrap();
    assert!(
        availability.contains("#BEBEBE"),
        "the unknown span drawn grey"
    );
}

#[test]
fn history_streams_two_weeks_of_bites_quits_quietly_on_a_closed_pipe_and_shows_progress_on_a_terminal(
) {
    let scratch = scratch("history-report-history");
    let (db, _) = write_history(scratch.path());
    let db_arg = db.to_str().unwrap();
    let (output, peak_kib) = millgate_measured(&["history", "--db", db_arg, "--format", "json"]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        output.stderr.is_empty(),
        "no progress when stderr is not a terminal"
    );
    let count: usize = sqlite3(&db, "SELECT count(*) FROM bites").parse().unwrap();
    // One object per line between the brackets.
    let text = String::from_utf8(output.stdout).unwrap();
    assert_eq!(text.lines().count(), count + 2);
    let rows: Vec<serde_json::Value> = serde_json::from_str(&text).unwrap();
    assert_eq!(rows.len(), count);
    assert_eq!(
        rows.last().unwrap()["id"].as_i64().map(|id| id.to_string()),
        Some(sqlite3(&db, "SELECT max(id) FROM bites"))
    );
    // The old export held every row and the whole text: some 200 MB here.
    if let Some(kib) = peak_kib {
        assert!(
            kib < 64 * 1024,
            "history peak RSS {kib} KiB for {count} rows"
        );
    }

    // Only one product's bites (`--product`), as the file holds them.
    let output = millgate(&[
        "history",
        "--db",
        db_arg,
        "--format",
        "csv",
        "--product",
        "101",
    ]);
    assert!(output.status.success(), "{output:?}");
    let text = String::from_utf8(output.stdout).unwrap();
    assert_eq!(
        (text.lines().count() - 1).to_string(),
        sqlite3(&db, "SELECT count(*) FROM bites WHERE product = 101")
    );
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let product = header
        .iter()
        .position(|c| *c == "product")
        .expect("a product column");
    assert!(text
        .lines()
        .skip(1)
        .all(|line| line.split(',').nth(product) == Some("101")));
    let refused = millgate(&[
        "history",
        "--db",
        db_arg,
        "--kind",
        "alarms",
        "--product",
        "101",
    ]);
    assert!(
        String::from_utf8_lossy(&refused.stderr)
            .contains("--product applies to bites and chatter episodes only"),
        "{refused:?}"
    );

    // A reader that stops early (`| head`): the export ends without an error.
    let mut child = common::MILLGATE
        .command()
        .args(["history", "--db", db_arg, "--format", "csv"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut head = [0u8; 4096];
    std::io::Read::read_exact(child.stdout.as_mut().unwrap(), &mut head).unwrap();
    drop(child.stdout.take());
    let ended = child.wait_with_output().unwrap();
    assert!(ended.status.success(), "{ended:?}");
    assert!(
        ended.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&ended.stderr)
    );

    // On a terminal (script's pseudo-terminal), the last progress line says the total.
    let terminal = Command::new("script")
        .args(["-qec"])
        .arg(format!(
            "{} history --db {db_arg} --format csv > /dev/null",
            env!("CARGO_BIN_EXE_millgate")
        ))
        .arg("/dev/null")
        .output()
        .expect("script (bsdutils)");
    let shown = String::from_utf8_lossy(&terminal.stdout);
    assert!(terminal.status.success(), "{shown}");
    assert!(
        shown.contains(&format!("history: {count} rows of bites in ")),
        "{shown}"
    );
}

#[test]
fn another_application_s_sqlite_file_is_refused_and_a_new_history_is_marked() {
    let scratch = scratch("history-report-foreign");
    let foreign = scratch.path().join("notes.db");
    sqlite_write(
        &foreign,
        "PRAGMA application_id = 1598902094; CREATE TABLE notes (x); INSERT INTO notes VALUES (1);",
    );
    let read = millgate(&["history", "--db", foreign.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&read.stderr);
    assert_eq!(read.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("not a millgate history") && stderr.contains("application_id 0x5f4d4f4e"),
        "{stderr}"
    );
    let error = writer::connect(&foreign).unwrap_err().to_string();
    assert!(error.contains("not a millgate history"), "{error}");
    // Left alone: its own table only, no WAL, its rows.
    assert_eq!(
        sqlite3(&foreign, "SELECT group_concat(name) FROM sqlite_schema"),
        "notes"
    );
    assert_eq!(sqlite3(&foreign, "PRAGMA journal_mode"), "delete");
    assert_eq!(sqlite3(&foreign, "SELECT count(*) FROM notes"), "1");
    // A file without an id but with tables of its own is refused too.
    let plain = scratch.path().join("plain.db");
    sqlite_write(&plain, "CREATE TABLE things (x);");
    let error = writer::connect(&plain).unwrap_err().to_string();
    assert!(error.contains("not a millgate history"), "{error}");

    // The gateway's new file carries millgate's id, as sqlite3 reads it.
    let new = scratch.path().join("history.db");
    drop(writer::connect(&new).unwrap());
    assert_eq!(
        sqlite3(&new, "PRAGMA application_id"),
        APPLICATION_ID.to_string()
    );
    assert_eq!(APPLICATION_ID, i64::from_be_bytes(*b"\0\0\0\0MLGT"));
}

fn sqlite_write(db: &Path, sql: &str) {
    let output = Command::new("sqlite3")
        .arg(db)
        .arg(sql)
        .output()
        .expect("Debian's sqlite3");
    assert!(output.status.success(), "{output:?}");
}
