//! The history's commands on a file two demo runs wrote: `millgate demo --history`
//! continues the counter and the wear trend; `millgate history` exports what Debian's
//! `sqlite3` counts in the file, in every format and time range; `millgate report`
//! writes the Markdown, the offline HTML and the SVG plots; bad input is a clear error.
#![cfg(feature = "sim-tools")]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{millgate, scratch};
use millgate::analysis::wear::next_trend;

fn ok(args: &[&str]) -> String {
    let output = millgate(args);
    assert!(
        output.status.success(),
        "millgate {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap()
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

#[test]
fn two_demo_runs_continue_and_history_and_report_read_the_file() {
    let scratch = scratch("history-cli");
    let dir = scratch.path();
    let db = dir.join("history.db");
    let db_arg = db.to_str().unwrap();

    let first = ok(&["demo", "--duration", "5", "--history", db_arg]);
    assert!(
        first.contains(&format!("history: {db_arg} (new)")),
        "{first}"
    );
    let second = ok(&[
        "demo",
        "--duration",
        "4",
        "--seed",
        "2",
        "--history",
        db_arg,
    ]);
    let first_count: i64 = sqlite3(&db, "SELECT max(bite_counter) FROM bites WHERE run_id = 1")
        .parse()
        .unwrap();
    assert!(first_count >= 2, "{first}");
    assert!(
        second.contains(&format!("continuing: bite counter {first_count},")),
        "{second}"
    );

    // The export against the file as sqlite3 reads it.
    let json: serde_json::Value =
        serde_json::from_str(&ok(&["history", "--db", db_arg, "--format", "json"])).unwrap();
    let bites = json.as_array().unwrap();
    assert_eq!(
        bites.len().to_string(),
        sqlite3(&db, "SELECT count(*) FROM bites")
    );
    let runs: Vec<i64> = bites
        .iter()
        .map(|b| b["run_id"].as_i64().unwrap())
        .collect();
    assert!(runs.contains(&1) && runs.contains(&2), "{runs:?}");
    // One counter across both runs, and the trend goes on from the first run's.
    let mut trend: Option<f64> = None;
    for (n, bite) in bites.iter().enumerate() {
        assert_eq!(bite["bite_counter"].as_i64(), Some(n as i64 + 1), "{bite}");
        assert_eq!(bite["driveline"], "F1");
        if let (Some(index), false) = (bite["wear_index"].as_f64(), bite["degraded"] == true) {
            trend = Some(next_trend(trend, index));
        }
        // serde_json parses floats to within an ulp (no float_roundtrip feature).
        let stored = bite["wear_trend"].as_f64();
        let close = match (stored, trend) {
            (Some(a), Some(b)) => (a - b).abs() <= 1e-12 * b.abs(),
            (a, b) => a == b,
        };
        assert!(close, "{stored:?} against {trend:?}: {bite}");
    }

    let csv = ok(&["history", "--db", db_arg, "--format", "csv"]);
    let mut lines = csv.lines();
    assert!(lines
        .next()
        .unwrap()
        .starts_with("id,run_id,driveline,time,bite_counter"));
    assert_eq!(lines.count(), bites.len());
    let md = ok(&["history", "--db", db_arg, "--format", "md"]);
    assert_eq!(
        md.lines().filter(|line| line.starts_with("| ")).count(),
        bites.len() + 1,
        "a header and a row per bite: {md}"
    );

    // A time range: from the second run's first bite on.
    let since = bites.iter().find(|b| b["run_id"] == 2).unwrap()["time"]
        .as_str()
        .unwrap()
        .to_owned();
    let later: serde_json::Value = serde_json::from_str(&ok(&[
        "history", "--db", db_arg, "--since", &since, "--format", "json",
    ]))
    .unwrap();
    assert_eq!(
        later.as_array().unwrap().len().to_string(),
        sqlite3(
            &db,
            &format!("SELECT count(*) FROM bites WHERE time >= '{since}'")
        )
    );
    let runs: serde_json::Value = serde_json::from_str(&ok(&[
        "history", "--db", db_arg, "--kind", "runs", "--format", "json",
    ]))
    .unwrap();
    let ended: Vec<&str> = runs
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["ended"].as_str().unwrap_or("open"))
        .collect();
    assert_eq!(ended, ["stopped", "stopped"]);

    // The wear trend: the second run continued the first's (one trend over every
    // bite with a gap estimate since the start, none reset), and `millgate wear --db`
    // reads what the service kept after its last bite.
    let with_gap: usize = sqlite3(&db, "SELECT count(*) FROM bites WHERE gap_mrad IS NOT NULL")
        .parse()
        .unwrap();
    assert!(
        with_gap >= 3,
        "the demo's maps come from its cache: {first}"
    );
    let wear: serde_json::Value = serde_json::from_str(&ok(&[
        "wear",
        "--db",
        db_arg,
        "--driveline",
        "F1",
        "--format",
        "json",
    ]))
    .unwrap();
    assert_eq!(
        wear["bites_pooled"].as_u64(),
        Some(with_gap as u64),
        "{wear}"
    );
    let kept: f64 = sqlite3(
        &db,
        "SELECT gap_mrad FROM driveline_state WHERE driveline = 'F1'",
    )
    .parse()
    .unwrap();
    assert!(
        (wear["gap_mrad"].as_f64().unwrap() - kept).abs() < 1e-9,
        "{wear} against {kept}"
    );
    assert_eq!(
        wear["forecast"]["alarm_mrad"], 4.0,
        "the run's gap_alarm_mrad"
    );
    assert!(
        wear["trend_mrad_per_day"].as_f64().unwrap() > 0.0,
        "the demo's gap grows: {wear}"
    );
    let unknown = millgate(&["wear", "--db", db_arg, "--driveline", "F9"]);
    let stderr = String::from_utf8_lossy(&unknown.stderr);
    assert!(
        !unknown.status.success() && stderr.contains("no driveline `F9` (drivelines: F1)"),
        "{stderr}"
    );

    // The report.
    let out = dir.join("report");
    ok(&["report", "--db", db_arg, "--out", out.to_str().unwrap()]);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("F1"), "{md}");
    let svgs: Vec<PathBuf> = std::fs::read_dir(&out)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "svg"))
        .collect();
    assert!(!svgs.is_empty(), "SVG plots");
    for svg in &svgs {
        let name = svg.file_name().unwrap().to_str().unwrap();
        assert!(md.contains(name), "report.md links {name}");
        assert!(std::fs::read_to_string(svg).unwrap().contains("<svg"));
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.matches("<svg").count() >= svgs.len(),
        "the plots inline"
    );
    assert!(
        !html.contains("src=\"http") && !html.contains("href=\"http"),
        "offline"
    );

    // Bad input: a clear error naming what is wrong, no panic.
    let missing = millgate(&["history", "--db", "/nonexistent/h.db", "--format", "csv"]);
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success());
    assert!(
        stderr.contains("/nonexistent/h.db") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let bad_time = millgate(&["history", "--db", db_arg, "--since", "yesterday"]);
    let stderr = String::from_utf8_lossy(&bad_time.stderr);
    assert!(!bad_time.status.success());
    assert!(
        stderr.contains("--since") && stderr.contains("yesterday"),
        "{stderr}"
    );
}
