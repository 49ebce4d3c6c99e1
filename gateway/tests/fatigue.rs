//! `millgate fatigue` against an implementation it was not built from: the Python
//! `rainflow` package (3.2.0, ASTM E1049-85's three-point rule, installed by
//! `scripts/test`) on simulator records of the Table 2 driveline with backlash (bars
//! with their entries, ring-downs and exits, seeded noise). The same cycles (range,
//! mean, count; equal ones merged, as the package's `count_cycles` does) and the same
//! Miner damage, computed in Python from the package's cycles. Skipped with a message
//! when python3 or the package is missing.

mod common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::{millgate, scratch, text};
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};

const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");

/// Four bars of the backlash model with `gap_rad` in the spindles, 1 kN*m RMS noise.
fn record(dir: &Path, gap_rad: f64, seed: u64) -> PathBuf {
    let model =
        Model::load(PathBuf::from(MODELS).join("table2-adjusted-backlash.toml")).expect("model");
    let timing = BarTiming {
        idle_s: 0.5,
        rolling_s: 1.5,
    };
    let schedule = rolling_schedule_with_gap(
        &model,
        &[90.0, 110.0, 100.0, 120.0],
        timing,
        1.0,
        seed,
        1,
        &[gap_rad],
    )
    .expect("schedule");
    let mut csv = String::from("t,torque\n");
    for (i, torque) in schedule.torque_knm.iter().enumerate() {
        writeln!(csv, "{},{torque}", i as f64 / schedule.sample_rate_hz).unwrap();
    }
    let path = dir.join(format!("bars-{seed}.csv"));
    std::fs::write(&path, csv).unwrap();
    path
}

/// The package's cycles of `path`'s torque column, merged by (range, mean), and the
/// Miner damage on m = 5, 2e6 cycles at 150 kN*m: JSON from Python.
const PYTHON: &str = r#"
import csv, json, sys
from collections import defaultdict
import rainflow
assert rainflow.__version__ == "3.2.0", rainflow.__version__
with open(sys.argv[1]) as f:
    rows = list(csv.DictReader(f))
series = [float(r["torque"]) for r in rows]
merged = defaultdict(float)
damage = 0.0
for rng, mean, count, _, _ in rainflow.extract_cycles(series):
    if rng > 0:
        merged[(rng, mean)] += count
    damage += count * (rng / 150.0) ** 5 / 2e6
print(json.dumps({"cycles": sorted([r, m, n] for (r, m), n in merged.items()), "damage": damage}))
"#;

/// Runs [`PYTHON`] on `path`; `None` (with a message) when python3 or the package is
/// missing.
fn python_rainflow(path: &Path) -> Option<serde_json::Value> {
    let output = match Command::new("python3")
        .args(["-c", PYTHON])
        .arg(path)
        .output()
    {
        Ok(output) => output,
        Err(error) => {
            eprintln!("SKIPPED rainflow check: python3 not found ({error})");
            return None;
        }
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if stderr.contains("No module named 'rainflow'") {
        eprintln!("SKIPPED rainflow check: python3 has no rainflow (pip install rainflow==3.2.0)");
        return None;
    }
    assert!(output.status.success(), "python: {stderr}");
    Some(serde_json::from_slice(&output.stdout).expect("python's JSON"))
}

/// Our cycles of the list merged by (range, mean), zero ranges left out, sorted.
fn merged(list: &[serde_json::Value]) -> Vec<(f64, f64, f64)> {
    let mut cycles: Vec<(f64, f64, f64)> = list
        .iter()
        .map(|c| {
            (
                c[0].as_f64().unwrap(),
                c[1].as_f64().unwrap(),
                c[2].as_f64().unwrap(),
            )
        })
        .filter(|c| c.0 > 0.0)
        .collect();
    cycles.sort_by(|a, b| (a.0, a.1).partial_cmp(&(b.0, b.1)).unwrap());
    let mut out: Vec<(f64, f64, f64)> = Vec::new();
    for c in cycles {
        match out.last_mut() {
            Some(last) if last.0 == c.0 && last.1 == c.1 => last.2 += c.2,
            _ => out.push(c),
        }
    }
    out
}

/// `millgate fatigue` of `path` with a gate of `gate` kN*m on the curve m = 5, 2e6
/// cycles at 150 kN*m, as JSON; `extra` options added.
fn fatigue_json(path: &Path, gate: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "fatigue",
        "--input",
        path.to_str().unwrap(),
        "--m",
        "5",
        "--ref-cycles",
        "2e6",
        "--ref-range-knm",
        "150",
        "--gate-knm",
        gate,
        "--format",
        "json",
    ];
    args.extend_from_slice(extra);
    let output = millgate(&args);
    assert!(output.status.success(), "{}", text(&output));
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn same_cycles_and_damage_as_the_python_rainflow_package() {
    let dir = scratch("fatigue-python");
    for (gap_rad, seed) in [(0.0, 1), (3e-3, 2)] {
        let path = record(dir.path(), gap_rad, seed);
        let ours = fatigue_json(&path, "0", &["--list-cycles"]);
        assert_eq!(ours["overflows"], 0, "the stack held the record");
        let Some(python) = python_rainflow(&path) else {
            return;
        };
        let theirs: Vec<(f64, f64, f64)> = python["cycles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                (
                    c[0].as_f64().unwrap(),
                    c[1].as_f64().unwrap(),
                    c[2].as_f64().unwrap(),
                )
            })
            .collect();
        let mine = merged(ours["cycle_list"].as_array().unwrap());
        // Thousands of cycles, from the noise and from the bars.
        assert!(mine.len() > 1000, "{}", mine.len());
        assert_eq!(mine, theirs, "gap {gap_rad} rad");
        let (damage, expected) = (
            ours["damage"].as_f64().unwrap(),
            python["damage"].as_f64().unwrap(),
        );
        assert!(damage > 0.0);
        assert!(
            (damage / expected - 1.0).abs() < 1e-9,
            "{damage} vs {expected}"
        );
    }
}

#[test]
fn the_gate_keeps_the_bars_cycles_and_drops_the_noise() {
    let dir = scratch("fatigue-gate");
    let path = record(dir.path(), 3e-3, 3);
    let (ungated, gated) = (fatigue_json(&path, "0", &[]), fatigue_json(&path, "6", &[]));
    let cycles = |v: &serde_json::Value| v["cycles"].as_f64().unwrap();
    let damage = |v: &serde_json::Value| v["damage"].as_f64().unwrap();
    // Noise (1 kN*m RMS) makes most reversals: a gate of 6 kN*m drops them...
    assert!(cycles(&gated) < 0.1 * cycles(&ungated), "{gated} {ungated}");
    // ... and hardly any damage: the bars' large cycles carry it (m = 5).
    assert!(
        damage(&gated) > 0.95 * damage(&ungated),
        "{gated} {ungated}"
    );
    assert_eq!(gated["max_range_knm"], ungated["max_range_knm"]);
}

/// Bad input is refused with the option and its allowed range: an S-N curve with
/// non-positive values (negative numbers reach the check, not clap's "unexpected
/// argument"), a gate larger than the signal's range.
#[test]
fn bad_curves_and_gates_are_refused_with_the_option_and_its_range() {
    let dir = scratch("fatigue-refused");
    let path = record(dir.path(), 0.0, 5);
    let input = path.to_str().unwrap();
    let curve = ["--m", "5", "--ref-cycles", "2e6", "--ref-range-knm", "150"];
    let cases: [(&[&str], &str); 5] = [
        (&["--m", "-3"], "--m -3: m must be finite and > 0"),
        (
            &["--ref-cycles", "0"],
            "--ref-cycles 0: ref_cycles must be finite and > 0",
        ),
        (
            &["--ref-range-knm", "-150"],
            "--ref-range-knm -150: ref_range_knm must be finite and > 0",
        ),
        (
            &["--endurance-knm", "-1"],
            "--endurance-knm -1: endurance_knm must be finite and > 0",
        ),
        (
            &["--gate-knm", "5000"],
            "--gate-knm 5000: must be >= 0 and below the range",
        ),
    ];
    for (bad, said) in cases {
        let mut args = vec!["fatigue", "--input", input];
        // The bad option replaces the curve's one of the same name.
        let mut k = 0;
        while k < curve.len() {
            if curve[k] != bad[0] {
                args.extend_from_slice(&curve[k..k + 2]);
            }
            k += 2;
        }
        args.extend_from_slice(bad);
        let output = millgate(&args);
        assert!(!output.status.success(), "{bad:?} accepted");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains(said), "{bad:?}: {stderr}");
    }
}
