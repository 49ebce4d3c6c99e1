//! `millgate rod ...` as a user runs it: results on the examples, and bad input
//! reported with the file, line or key and the allowed range, with a non-zero exit.

mod common;

use common::{millgate, scratch, text, TempDir};
use std::path::PathBuf;

fn rod_examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/rod")
}

fn example(name: &str) -> String {
    rod_examples().join(name).to_str().unwrap().to_owned()
}

/// Writes `body` as `file` in the folder `name` of the scratch folder; returns its path.
fn write(scratch: &TempDir, name: &str, file: &str, body: &str) -> String {
    let folder = scratch.path().join(name);
    std::fs::create_dir_all(&folder).unwrap();
    let path = folder.join(file);
    std::fs::write(&path, body).unwrap();
    path.to_str().unwrap().to_owned()
}

fn schedule_text() -> String {
    std::fs::read_to_string(rod_examples().join("rsm-schedule.csv")).unwrap()
}

/// The example mill with its drive taken from `drive` (a path).
fn mill_with_drive(scratch: &TempDir, name: &str, drive: &str) -> String {
    let mill = std::fs::read_to_string(rod_examples().join("rsm-mill.toml")).unwrap();
    let mill = mill.replace(
        "drive = \"../rsm-drive.toml\"",
        &format!("drive = {drive:?}"),
    );
    write(scratch, name, "mill.toml", &mill)
}

fn failure(args: &[&str]) -> String {
    let output = millgate(args);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    said
}

#[test]
fn mathieu_prints_the_characteristic_values_as_json() {
    let output = millgate(&[
        "rod", "mathieu", "--q", "1", "--order", "2", "--format", "json",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let value: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(value["q"], 1.0);
    let a: Vec<f64> = serde_json::from_value(value["a"].clone()).unwrap();
    let b: Vec<f64> = serde_json::from_value(value["b"].clone()).unwrap();
    // Abramowitz and Stegun Table 20.1, q = 1.
    let expected_a = [-0.45513860, 1.85910807, 4.37130098];
    let expected_b = [-0.11024882, 3.91702477];
    assert_eq!((a.len(), b.len()), (3, 2));
    for (x, y) in a.iter().zip(expected_a).chain(b.iter().zip(expected_b)) {
        assert!((x - y).abs() < 6e-9, "{x} vs {y}");
    }
}

#[test]
fn floquet_prints_the_exponent_and_stability() {
    let run = |args: &[&str]| -> serde_json::Value {
        let output = millgate(args);
        assert!(output.status.success(), "{}", text(&output));
        serde_json::from_slice(&output.stdout).unwrap()
    };
    // Principal tongue at q = 0.4: mu ~ 0.2 undamped; damping 0.3 stabilises.
    let undamped = run(&[
        "rod", "floquet", "--a", "1", "--q", "0.4", "--format", "json",
    ]);
    assert!(undamped["exponent"].as_f64().unwrap() > 0.19);
    assert_eq!(undamped["stable"], false);
    let damped = run(&[
        "rod",
        "floquet",
        "--a",
        "1",
        "--q",
        "0.4",
        "--damping",
        "0.3",
    ]);
    assert!((damped["exponent"].as_f64().unwrap() + 0.3).abs() < 0.2);
    assert_eq!(damped["stable"], true);
    let negative = run(&["rod", "floquet", "--a", "-1", "--q", "-2"]);
    assert_eq!(negative["stable"], false);
}

#[test]
fn check_reports_every_pass_and_writes_the_plots() {
    let mill = example("rsm-mill.toml");
    let schedule = example("rsm-schedule.csv");
    let scratch = scratch("rod-cli-plots");
    let plots = scratch.path();
    let output = millgate(&[
        "rod",
        "check",
        "--mill",
        &mill,
        "--schedule",
        &schedule,
        "--plot",
        plots.to_str().unwrap(),
    ]);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(said.contains("Pass P1 (configuration table3)"), "{said}");
    assert!(
        said.contains("Finishing speeds to avoid, by configuration"),
        "{said}"
    );
    for file in ["ince-strutt.svg", "campbell-P1.svg", "campbell-P4.svg"] {
        let svg = std::fs::read_to_string(plots.join(file)).unwrap();
        assert!(svg.starts_with("<svg"), "{file}");
    }
    let output = millgate(&[
        "rod",
        "check",
        "--mill",
        &mill,
        "--schedule",
        &schedule,
        "--format",
        "json",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let value: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(value["passes"].as_array().unwrap().len(), 4);
    let point = &value["passes"][0]["spans"][0]["points"][0];
    for key in [
        "f_rod_hz",
        "theta_hz",
        "a",
        "q",
        "c",
        "tongue",
        "exponent_per_s",
        "stable",
        "margin_a",
        "speed_change_m_s",
    ] {
        assert!(point.get(key).is_some(), "{key} missing: {point}");
    }
}

#[test]
fn bad_schedules_name_the_line_column_and_range() {
    let mill = example("rsm-mill.toml");
    let original = schedule_text();
    let scratch = scratch("rod-cli-schedules");
    let cases = [
        (
            "negative",
            original.clone() + "P9,table3,60.0,950,16.0;-13.5;10.5;9.0\n",
            "schedule.csv:8: diameters_mm: -13.5 is not allowed (must be > 0 mm)",
        ),
        (
            "zero",
            original.replacen("P2,table3,60.0", "P2,table3,0", 1),
            "schedule.csv:5: finishing_speed_m_s: 0 is not allowed (must be > 0 m/s)",
        ),
        (
            "malformed",
            original.replacen("P4,fast,110.0,850,", "P4,fast,110.0 850 ", 1),
            "schedule.csv:7: (row): 3 fields, the header has 5",
        ),
        (
            "configuration",
            original.replacen("P3,fast", "P3,slow", 1),
            "schedule.csv:6: configuration: \"slow\" is not allowed (must be a configuration of \
             the drive (known: \"table3\", \"fast\"))",
        ),
    ];
    for (name, body, expected) in cases {
        assert_ne!(body, original, "{name}");
        let schedule = write(&scratch, name, "schedule.csv", &body);
        let said = failure(&["rod", "check", "--mill", &mill, "--schedule", &schedule]);
        assert!(said.contains(expected), "{name}: {said}");
    }
}

#[test]
fn a_drive_with_a_loop_or_a_disconnected_mass_is_refused_with_its_key() {
    let drive = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/rsm-drive.toml"),
    )
    .unwrap();
    let schedule = example("rsm-schedule.csv");
    let scratch = scratch("rod-cli-drives");
    let looped = drive.replace(
        "engaged = [\"M3\", \"M5\"]",
        "engaged = [\"M3\", \"M4\", \"M5\"]",
    );
    let path = write(&scratch, "loop", "drive.toml", &looped);
    let said = failure(&[
        "rod",
        "check",
        "--mill",
        &mill_with_drive(&scratch, "loop", &path),
        "--schedule",
        &schedule,
    ]);
    assert!(
        said.contains("drive.toml: coupling[3].between:") && said.contains("loop"),
        "{said}"
    );
    let cut = drive.replace("engaged = [\"M4\", \"M6\"]", "engaged = [\"M4\"]");
    let path = write(&scratch, "cut", "drive.toml", &cut);
    let said = failure(&[
        "rod",
        "check",
        "--mill",
        &mill_with_drive(&scratch, "cut", &path),
        "--schedule",
        &schedule,
    ]);
    assert!(
        said.contains("drive.toml: mass[4]: \"stage D\" is not allowed"),
        "{said}"
    );
    assert!(
        said.contains("none reaches it in configuration \"fast\""),
        "{said}"
    );
}

#[test]
fn bad_mill_values_and_mathieu_arguments_name_the_key_and_range() {
    let mill = std::fs::read_to_string(rod_examples().join("rsm-mill.toml")).unwrap();
    let body = mill.replacen("roll_diameter = 0.228", "roll_diameter = -0.228", 1);
    let scratch = scratch("rod-cli-mill");
    let path = write(
        &scratch,
        "roll",
        "mill.toml",
        &body.replace("../rsm-drive.toml", &example("../rsm-drive.toml")),
    );
    let said = failure(&[
        "rod",
        "check",
        "--mill",
        &path,
        "--schedule",
        &example("rsm-schedule.csv"),
    ]);
    assert!(
        said.contains("mill.toml: stand[0].roll_diameter: -0.228 is not allowed (must be > 0 m)"),
        "{said}"
    );
    let said = failure(&["rod", "mathieu", "--q", "150"]);
    assert!(
        said.contains("--q 150: Mathieu q must be finite with |q| <= 100"),
        "{said}"
    );
    let said = failure(&["rod", "mathieu", "--q", "1", "--order", "11"]);
    assert!(
        said.contains("--order: 11 is not allowed (must be 1 ..= 10)"),
        "{said}"
    );
    let said = failure(&["rod", "floquet", "--a", "1", "--q", "1", "--damping", "-1"]);
    assert!(
        said.contains("damping c must be finite and in 0..=10"),
        "{said}"
    );
}
