//! `millgate check --config FILE`: validate a configuration and describe it.

use std::path::Path;

use millgate_config::ConfigError;

/// Loads and validates the configuration at `path` and returns its summary (what
/// `millgate check` prints).
///
/// The error lists every problem found, one per line, as
/// `<file>: <key path>: <problem>`; `main` prints it and exits non-zero.
///
/// ```no_run
/// match millgate::cli::check::check(std::path::Path::new("config/examples/demo.toml")) {
///     Ok(summary) => print!("{summary}"),
///     Err(problems) => eprintln!("{problems}"),
/// }
/// ```
pub fn check(path: &Path) -> Result<String, ConfigError> {
    let config = millgate_config::load(path)?;
    Ok(format!(
        "{}: OK\n{}",
        path.display(),
        millgate_config::summary(&config)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config/examples")
            .join(name)
    }

    #[test]
    fn accepts_each_example_and_summarises_it() {
        for (file, expected) in [
            ("demo.toml", "spindle_top: torque"),
            ("hot-mill.toml", "F1 main drive: torque spindle_top"),
            ("tandem-5stand.toml", "TCM 2030: 5 stands"),
        ] {
            let summary = check(&example(file)).unwrap_or_else(|error| panic!("{error}"));
            assert!(summary.contains(": OK\n"), "{summary}");
            assert!(summary.contains(expected), "{file}: {summary}");
        }
    }

    #[test]
    fn lists_every_problem() {
        let directory = std::env::temp_dir().join(format!("millgate-check-{}", std::process::id()));
        std::fs::create_dir_all(&directory).expect("temporary directory");
        let path = directory.join("bad.toml");
        std::fs::write(
            &path,
            "name = \"bad\"\n\
             [[sources.modbus]]\n\
             name = \"daq1\"\n\
             address = \"127.0.0.1\"\n\
             unit_id = 300\n\
             poll_period_ms = 20\n",
        )
        .expect("write the test file");
        let error = check(&path).expect_err("two problems");
        std::fs::remove_dir_all(&directory).expect("remove the temporary directory");
        assert_eq!(error.problems.len(), 2, "{error}");
        let text = error.to_string();
        assert!(
            text.contains("bad.toml: sources.modbus[0].address: \"127.0.0.1\" is not allowed"),
            "{text}"
        );
        assert!(
            text.contains(
                "bad.toml: sources.modbus[0].unit_id: 300 is not allowed (must be 0..=255)"
            ),
            "{text}"
        );
    }
}
