//! Model TOML: example files load, errors name the file, key path and allowed range,
//! and a model survives a write/read round trip.

use millgate_sim::model::{Model, ModelError};

const ADJUSTED: &str = include_str!("../models/table2-adjusted.toml");

fn models_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models")
}

#[test]
fn every_example_model_loads() -> anyhow::Result<()> {
    let mut loaded = 0;
    for entry in std::fs::read_dir(models_dir())? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "toml") {
            let model = Model::load(&path)?;
            loaded += 1;
            // The RSM tree drives are checked in rsm_table3.rs.
            let table2 = path
                .file_name()
                .is_some_and(|name| name.to_string_lossy().starts_with("table2"));
            if !table2 {
                continue;
            }
            assert_eq!(model.masses.len(), 3, "{}", path.display());
            assert_eq!(model.couplings.len(), 2, "{}", path.display());
            assert_eq!(model.load.static_torque, 112.0);
            assert_eq!(model.load.rise_rate, 36.7);
        }
    }
    assert!(
        loaded >= 5,
        "expected at least 5 example models, found {loaded}"
    );
    Ok(())
}

#[test]
fn round_trip_through_toml_keeps_every_value() -> anyhow::Result<()> {
    let model = Model::load(models_dir().join("table2-adjusted-backlash.toml"))?;
    let text = model.to_toml_string()?;
    assert!(text.contains("[[mass]]") && text.contains("[[coupling]]"));
    let again = Model::from_toml_str(&text, "written.toml")?;
    assert_eq!(again, model);
    // Backlash 0 is the default and is not written.
    let linear = Model::from_toml_str(ADJUSTED, "adjusted.toml")?;
    assert!(!linear.to_toml_string()?.contains("backlash"));
    Ok(())
}

fn error_for(text: &str) -> String {
    match Model::from_toml_str(text, "f1.toml") {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(error) => error.to_string(),
    }
}

#[test]
fn negative_inertia_names_file_key_and_range() {
    let text = ADJUSTED.replacen("inertia = 11.85e3", "inertia = -3", 1);
    assert_eq!(
        error_for(&text),
        "f1.toml: mass[1].inertia: -3 is not allowed (must be > 0 kg*m^2)"
    );
}

#[test]
fn unknown_key_names_file_line_key_and_allowed_keys() {
    let text = ADJUSTED.replacen("damping = 5.0e3", "dampnig = 5.0e3", 1);
    let line = text
        .lines()
        .position(|l| l.starts_with("dampnig"))
        .map(|i| i + 1)
        .unwrap_or_default();
    let message = error_for(&text);
    assert!(
        message.starts_with(&format!("f1.toml:{line}: coupling[1]")),
        "{message}"
    );
    assert!(message.contains("dampnig"), "{message}");
    assert!(
        message.contains("damping") && message.contains("backlash"),
        "{message}"
    );
}

#[test]
fn coupling_count_must_be_one_fewer_than_masses() {
    let cut = ADJUSTED
        .find("[[coupling]]\nname = \"spindles")
        .unwrap_or(ADJUSTED.len());
    let end = ADJUSTED.find("[motor]").unwrap_or(ADJUSTED.len());
    let text = format!("{}{}", &ADJUSTED[..cut], &ADJUSTED[end..]);
    let message = error_for(&text);
    assert!(
        message.starts_with("f1.toml: coupling: 1 entries"),
        "{message}"
    );
    assert!(message.contains("2 entries"), "{message}");
}

#[test]
fn measured_coupling_out_of_range() {
    let text = ADJUSTED.replacen("coupling = 1", "coupling = 2", 1);
    assert_eq!(
        error_for(&text),
        "f1.toml: measurement.coupling: 2 is not allowed (must be a coupling index, 0 ..= 1)"
    );
}

#[test]
fn other_ranges_are_checked() {
    for (from, to, key) in [
        ("damping = 5.0e3", "damping = -1.0", "coupling[1].damping"),
        (
            "stiffness = 32.81e6",
            "stiffness = 0.0",
            "coupling[1].stiffness",
        ),
        ("rise_rate = 36.7", "rise_rate = 0.0", "load.rise_rate"),
        (
            "sample_rate = 2000.0",
            "sample_rate = nan",
            "measurement.sample_rate",
        ),
        ("duration = 0.6", "duration = 1e9", "measurement.duration"),
        ("speed_kp = 5.0e5", "speed_kp = -5.0e5", "motor.speed_kp"),
    ] {
        let text = ADJUSTED.replacen(from, to, 1);
        assert_ne!(text, ADJUSTED, "{from} not found");
        let message = error_for(&text);
        assert!(
            message.starts_with(&format!("f1.toml: {key}: ")),
            "{message}"
        );
        assert!(message.contains("must be"), "{message}");
    }
}

#[test]
fn malformed_toml_reports_its_line() {
    let text = ADJUSTED.replacen("inertia = 2.48e3", "inertia = = 2.48e3", 1);
    let line = text
        .lines()
        .position(|l| l.contains("= = 2.48e3"))
        .map(|i| i + 1)
        .unwrap_or_default();
    let error = Model::from_toml_str(&text, "f1.toml").err();
    match error {
        Some(ModelError::Syntax {
            file, line: found, ..
        }) => {
            assert_eq!(file, "f1.toml");
            assert_eq!(found, line);
        }
        other => panic!("expected a syntax error, got {other:?}"),
    }
    assert!(error_for(&text).starts_with(&format!("f1.toml:{line}: malformed TOML")));
}

#[test]
fn missing_file_is_an_io_error_naming_the_path() {
    let message = match Model::load("/nonexistent/f9.toml") {
        Ok(_) => panic!("loaded a missing file"),
        Err(error) => error.to_string(),
    };
    assert!(
        message.starts_with("/nonexistent/f9.toml: cannot read"),
        "{message}"
    );
}
