//! The `millgate` binary as a user runs it.

use std::path::PathBuf;
use std::process::{Command, Output};

fn millgate(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_millgate"))
        .args(args)
        .output()
        .expect("run millgate")
}

fn text(output: &Output) -> String {
    String::from_utf8_lossy(&output.stdout).to_string() + &String::from_utf8_lossy(&output.stderr)
}

fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/examples")
}

fn write_config(name: &str, body: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("millgate-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("mill.toml");
    std::fs::write(&path, body).unwrap();
    path
}

#[test]
fn check_accepts_every_example_and_prints_a_summary() {
    for example in ["hot-mill.toml", "tandem-5stand.toml", "demo.toml"] {
        let path = examples().join(example);
        let output = millgate(&["check", "--config", path.to_str().unwrap()]);
        assert!(output.status.success(), "{example}: {}", text(&output));
        assert!(!output.stdout.is_empty(), "{example}: empty summary");
    }
}

#[test]
fn check_names_the_key_and_the_known_channels_of_a_misspelt_name() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let misspelt = demo.replace("torque = \"spindle_top\"", "torque = \"spindel_top\"");
    assert_ne!(demo, misspelt, "the demo config names spindle_top as the torque");
    let path = write_config("misspelt", &misspelt);
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(said.contains("mill.toml"), "names the file: {said}");
    assert!(said.contains("drivelines[0].torque"), "names the key: {said}");
    assert!(said.contains("spindel_top") && said.contains("spindle_top"), "names both: {said}");
}

#[test]
fn check_names_the_line_of_malformed_toml() {
    let path = write_config("malformed", "name = \"x\"\n\n[[channels]\nname = 1\n");
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(said.contains("line 3"), "names the line: {said}");
}

#[test]
fn demo_prints_bites_within_two_percent_of_the_simulated_truth() {
    let output = millgate(&["demo", "--duration", "4"]);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    // Bite rows end with the TAF error against the truth, e.g. "-0.13%".
    let errors: Vec<f64> = said
        .lines()
        .filter(|l| l.contains("spindle_top"))
        .filter_map(|l| l.split_whitespace().last()?.strip_suffix('%')?.parse().ok())
        .collect();
    assert!(!errors.is_empty(), "no bite printed: {said}");
    assert!(errors.iter().all(|e: &f64| e.abs() < 2.0), "TAF errors {errors:?}: {said}");
    assert!(said.contains("F1.taf"), "register snapshot printed: {said}");
}
