//! `millgate check --config FILE [--format text|json]`: validate a configuration,
//! build everything the service builds from it, check the history file when it exists
//! (SQLite's `quick_check`: a damaged file is a warning), and describe it.
//!
//! `--format json` prints one JSON document on stdout whether the file passes or not
//! ([`report_json`]), for CI: `{"file", "ok", "summary", "config_hash", "problems",
//! "warnings"}` (`config_hash`: [`millgate_config::Config::hash`], the hash the
//! history stores with each run and the capture exports carry; null when the file
//! does not load), each
//! problem and warning `{"file", "key", "message", "text"}`; the exit code is the
//! text format's (0 valid, with or without warnings; 1 with problems).

use std::path::Path;

use millgate_config::ConfigError;
use serde::Serialize;

use crate::service::{Service, ServiceError};

/// Why `millgate check` rejects a configuration.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// The file does not load: every problem, one per line, as
    /// `<file>: <key path>: <problem>`.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The file is valid, but the service cannot be built from it (a driveline model
    /// that does not load, a bite window beyond the detector's capacity, a chatter
    /// window too short for its band): `<file>: <key path>: <problem>`.
    #[error("{file}: {source}")]
    Service {
        /// The configuration file as given.
        file: String,
        /// What the service refused (boxed: a service error is large, a check error
        /// should not be).
        #[source]
        source: Box<ServiceError>,
    },
    /// A driveline names a model the wear diagnosis cannot use (the model does not
    /// load, or its `wear` settings do not fit it): one `<file>: <key path>: <problem>`
    /// per line.
    #[error("{}", problems.iter().map(|problem| format!("{file}: {problem}")).collect::<Vec<_>>().join("\n"))]
    Wear {
        /// The configuration file as given.
        file: String,
        /// Each problem, naming the key and the model file.
        problems: Vec<String>,
    },
}

/// Loads and validates the configuration at `path`, builds what `millgate run` builds
/// before it opens a socket (detectors, wear references from the driveline models,
/// chatter monitors), and returns the summary `millgate check` prints.
///
/// The error names the file, the key and the problem; `main` prints it and exits
/// non-zero.
///
/// ```no_run
/// match millgate::cli::check::check(std::path::Path::new("config/examples/demo.toml")) {
///     Ok(summary) => print!("{summary}"),
///     Err(problems) => eprintln!("{problems}"),
/// }
/// ```
pub fn check(path: &Path) -> Result<String, CheckError> {
    let (summary, warnings, _) = inspect(path)?;
    let mut report = format!("{}: OK\n{summary}", path.display());
    for warning in warnings {
        report.push_str(&format!("warning: {}: {warning}\n", path.display()));
    }
    Ok(report)
}

/// The configuration at `path` loaded and built as `run` builds it: its summary and
/// the warnings (each `<key path>: <what>`) and its hash, or what is wrong.
fn inspect(path: &Path) -> Result<(String, Vec<String>, String), CheckError> {
    let mut config = millgate_config::load(path)?;
    // Without `cache_dir` and outside systemd the gateway picks the user's cache
    // folder: the summary names the one `run` would use.
    config
        .cache_dir
        .get_or_insert_with(crate::analysis::gap_map_cache::default_dir);
    let summary = millgate_config::summary(&config);
    let hash = config.hash.clone();
    let file = path.display().to_string();
    let service = Service::new(config).map_err(|source| match source {
        ServiceError::Wear(problems) => CheckError::Wear { file, problems },
        source => CheckError::Service {
            file: path.display().to_string(),
            source: Box::new(source),
        },
    })?;
    let mut warnings = service.warnings();
    warnings.extend(history_warning(&service));
    Ok((summary, warnings, hash))
}

/// A warning when the history file exists but is not a sound millgate history
/// (SQLite's `quick_check` finds damage, another application's file, a newer
/// schema): the service leaves such a file untouched and runs without it, so this
/// is a warning for the operator (move it aside), not a reason to refuse the start.
/// A missing file is created at the first start.
fn history_warning(service: &Service) -> Option<String> {
    let history = service.history_path()?;
    if !history.exists() {
        return None;
    }
    let checked =
        crate::history::query::HistoryReader::open(history).and_then(|reader| reader.quick_check());
    checked.err().map(|error| {
        format!("history.path: {error}: the service will not write to it nor restore from it")
    })
}

/// One problem or warning of [`report_json`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub(crate) struct Finding {
    /// The configuration file as given (or the model file a problem is in, as the
    /// configuration names it).
    pub file: String,
    /// The key path (`drivelines[0].torque`, `outputs.plc.register_base`), or the
    /// line and column of malformed TOML; `None` for a problem of no one key (a
    /// listener that cannot bind).
    pub key: Option<String>,
    /// What is wrong and what is allowed.
    pub message: String,
    /// The line the text format prints: `<file>: <key>: <message>`.
    pub text: String,
}

impl Finding {
    /// A finding of `file` from a `<key path>: <message>` line (as the service's
    /// errors and warnings read); a line that does not start with a key path is all
    /// message.
    fn from_line(file: &str, line: &str) -> Self {
        let (key, message) = match line.split_once(": ") {
            Some((key, message)) if is_key_path(key) => (Some(key.to_owned()), message),
            _ => (None, line),
        };
        Finding {
            file: file.to_owned(),
            key,
            message: message.to_owned(),
            text: format!("{file}: {line}"),
        }
    }
}

/// Whether `text` reads as a key path: `drivelines[0].wear.couplings[1]`, or a list
/// of them (`drivelines, tandem_mills`).
fn is_key_path(text: &str) -> bool {
    text.split(", ").all(|key| {
        key.starts_with(|c: char| c.is_ascii_alphabetic())
            && key
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_.[]".contains(c))
    })
}

/// The document `millgate check --format json` prints.
#[derive(Debug, Serialize)]
struct JsonReport {
    file: String,
    ok: bool,
    summary: Option<String>,
    config_hash: Option<String>,
    problems: Vec<Finding>,
    warnings: Vec<Finding>,
}

/// What [`check`] finds, as one JSON document (pretty-printed) and whether the file
/// passed (the exit code: 0 when it did). Problems keep the key and the message
/// apart.
///
/// ```no_run
/// let (json, ok) = millgate::cli::check::report_json(std::path::Path::new("mill.toml"));
/// println!("{json}");
/// std::process::exit(if ok { 0 } else { 1 });
/// ```
pub fn report_json(path: &Path) -> (String, bool) {
    let file = path.display().to_string();
    let report = match inspect(path) {
        Ok((summary, warnings, hash)) => JsonReport {
            ok: true,
            summary: Some(summary),
            config_hash: Some(hash),
            problems: Vec::new(),
            warnings: warnings
                .iter()
                .map(|warning| Finding::from_line(&file, warning))
                .collect(),
            file,
        },
        Err(error) => JsonReport {
            ok: false,
            summary: None,
            config_hash: None,
            problems: findings(&file, &error),
            warnings: Vec::new(),
            file,
        },
    };
    let ok = report.ok;
    (
        serde_json::to_string_pretty(&report).unwrap_or_default(),
        ok,
    )
}

/// The problems of `error`, one per line of its text.
fn findings(file: &str, error: &CheckError) -> Vec<Finding> {
    match error {
        CheckError::Config(error) => error
            .problems
            .iter()
            .map(|problem| Finding {
                file: problem.file.clone(),
                key: (!problem.key.is_empty()).then(|| problem.key.clone()),
                message: problem.message.clone(),
                text: problem.to_string(),
            })
            .collect(),
        CheckError::Service { source, .. } => source
            .to_string()
            .lines()
            .map(|line| Finding::from_line(file, line))
            .collect(),
        CheckError::Wear { problems, .. } => problems
            .iter()
            .map(|problem| Finding::from_line(file, problem))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::testing::example;

    #[test]
    fn accepts_each_example_and_summarises_it() {
        for (file, expected) in [
            ("demo.toml", "spindle_top: torque"),
            ("hot-mill.toml", "F1 main drive: torque spindle_top"),
            ("tandem-5stand.toml", "TCM 2030: 5 stands"),
            ("rod-mill.toml", "RSM: mill "),
        ] {
            let summary = check(&example(file)).unwrap_or_else(|error| panic!("{error}"));
            assert!(summary.contains(": OK\n"), "{summary}");
            assert!(summary.contains(expected), "{file}: {summary}");
        }
    }

    /// `example` with `from` replaced by `to`, written as `name.toml` beside the
    /// examples' DBC and models in a fresh directory; checked, then removed.
    fn check_variant(example_file: &str, from: &str, to: &str) -> Result<String, CheckError> {
        let text = std::fs::read_to_string(example(example_file)).expect("the example");
        assert!(text.contains(from), "{example_file} has `{from}`");
        // One directory per call: tests run in parallel.
        static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let directory =
            std::env::temp_dir().join(format!("millgate-check-{}-{call}", std::process::id()));
        std::fs::create_dir_all(&directory).expect("temporary directory");
        std::fs::copy(example("mill.dbc"), directory.join("mill.dbc")).expect("copy the DBC");
        std::fs::copy(
            example("table2-adjusted.toml"),
            directory.join("table2-adjusted.toml"),
        )
        .expect("copy the model");
        let path = directory.join("variant.toml");
        std::fs::write(&path, text.replace(from, to)).expect("write the variant");
        let result = check(&path);
        std::fs::remove_dir_all(&directory).expect("remove the temporary directory");
        result
    }

    #[test]
    fn bite_window_beyond_the_detector_capacity_is_reported_with_its_key() {
        // 2 s after the trigger at 2 kHz: 4000 samples, the detector holds 1792.
        let error = check_variant("demo.toml", "post_trigger_s = 0.5", "post_trigger_s = 2.0")
            .expect_err("window beyond capacity");
        let text = error.to_string();
        assert!(matches!(error, CheckError::Service { .. }), "{text}");
        assert!(
            text.contains(
                "variant.toml: drivelines[0].bite: pre_trigger_s 0.1 s and post_trigger_s 2 s"
            ),
            "{text}"
        );
        assert!(text.contains("need 200 + 4000 samples"), "{text}");
        assert!(text.contains("at most 256 + 1792"), "{text}");
    }

    #[test]
    fn wear_settings_that_do_not_fit_the_model_are_reported_with_their_key() {
        let error = check_variant(
            "demo.toml",
            "wear = { gap_step_mrad",
            "wear = { couplings = [0, 3], gap_step_mrad",
        )
        .expect_err("the model has couplings 0 and 1");
        let text = error.to_string();
        assert!(matches!(error, CheckError::Wear { .. }), "{text}");
        // The file as given (here a temporary path), then the key and the allowed range.
        assert!(
            text.ends_with(
                "variant.toml: drivelines[0].wear.couplings[1]: 3 is not allowed (must be a \
                 coupling of the model \"Table 2 driveline, stiffness adjusted to \
                 measurement\": 0 ..= 1)"
            ),
            "{text}"
        );
    }

    #[test]
    fn chatter_window_too_short_for_the_band_is_reported_with_its_key() {
        // 20 ms: a 50 Hz frequency step, no bin inside 110..140 Hz.
        let error = check_variant(
            "tandem-5stand.toml",
            "chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5",
            "chatter_band_hz = [110.0, 140.0]\nwindow_s = 0.02",
        )
        .expect_err("window too short for the band");
        let text = error.to_string();
        assert!(
            text.contains("variant.toml: tandem_mills[0].window_s: 0.02 s is too short for the chatter band 110..140 Hz"),
            "{text}"
        );
        assert!(text.contains("frequency step 50 Hz"), "{text}");
    }

    #[test]
    fn a_register_base_that_runs_the_map_past_65535_is_reported() {
        // The demo's map spans 80 registers with its extension block, which the demo's
        // PLC is written: base 65500 would end at 65579.
        let error = check_variant("demo.toml", "register_base = 0", "register_base = 65500")
            .expect_err("map past 65535");
        assert_eq!(
            error
                .to_string()
                .rsplit_once("variant.toml: ")
                .map(|(_, tail)| tail),
            Some(
                "outputs.plc.register_base: 65500 is not allowed: the register map spans 80 \
                 registers and would end at register 65579, past 65535 (must be 0..=65456)"
            )
        );
        assert!(check_variant("demo.toml", "register_base = 0", "register_base = 65456").is_ok());
    }

    #[test]
    fn a_server_reachable_from_other_hosts_is_a_warning() {
        let summary = check_variant(
            "demo.toml",
            "bind = \"127.0.0.1:5503\"",
            "bind = \"0.0.0.0:5503\"",
        )
        .expect("valid");
        assert!(
            summary.contains("warning: ")
                && summary
                    .contains("outputs.server.bind: 0.0.0.0:5503 accepts clients from other hosts")
                && summary.contains("command writes are refused"),
            "{summary}"
        );
        let loopback = check(&example("demo.toml")).expect("valid");
        assert!(!loopback.contains("warning: "), "{loopback}");
    }

    #[test]
    fn a_web_page_reachable_from_other_hosts_is_a_warning() {
        let page = |bind: &str| {
            check_variant(
                "demo.toml",
                "[outputs.server]",
                &format!("[outputs.web]\nbind = \"{bind}\"\n\n[outputs.server]"),
            )
            .expect("valid")
        };
        let open = page("0.0.0.0:8080");
        assert!(
            open.contains("Maintenance page: http://0.0.0.0:8080/, at most 32 connections")
                && open.contains("warning: ")
                && open.contains(
                    "variant.toml: outputs.web.bind: 0.0.0.0:8080 accepts clients from other hosts"
                ),
            "{open}"
        );
        let loopback = page("127.0.0.1:8080");
        assert!(
            loopback.contains("Maintenance page: http://127.0.0.1:8080/")
                && !loopback.contains("warning: "),
            "{loopback}"
        );
    }

    #[test]
    fn metrics_reachable_from_other_hosts_is_a_warning() {
        let metrics = |bind: &str| {
            check_variant(
                "demo.toml",
                "[outputs.server]",
                &format!("[outputs.metrics]\nbind = \"{bind}\"\n\n[outputs.server]"),
            )
            .expect("valid")
        };
        let open = metrics("0.0.0.0:9187");
        assert!(
            open.contains("warning: ")
                && open.contains(
                    "variant.toml: outputs.metrics.bind: 0.0.0.0:9187 accepts clients from \
                     other hosts"
                ),
            "{open}"
        );
        assert!(!metrics("127.0.0.1:9187").contains("warning: "));
    }

    #[test]
    fn rod_mill_configuration_unknown_to_the_drive_is_reported_with_its_key() {
        let text = std::fs::read_to_string(example("rod-mill.toml")).expect("the example");
        let absolute = text
            .replace(
                "../../sim/models/rod/",
                &format!("{}/", example("../../sim/models/rod").display()),
            )
            .replace("[\"table3\", \"fast\"]", "[\"table3\", \"fastest\"]");
        let error = check_text(&absolute).expect_err("unknown configuration");
        let message = error.to_string();
        assert!(matches!(error, CheckError::Service { .. }), "{message}");
        assert!(
            message.contains(
                "rod_mills[0].configurations[1]: \"fastest\" is not allowed (must be a \
                 configuration of the drive of"
            ),
            "{message}"
        );
        assert!(message.contains("table3, fast)"), "{message}");
    }

    /// Check `text` written to a fresh file.
    fn check_text(text: &str) -> Result<String, CheckError> {
        let directory =
            std::env::temp_dir().join(format!("millgate-check-rod-{}", std::process::id()));
        std::fs::create_dir_all(&directory).expect("temporary directory");
        let path = directory.join("rod.toml");
        std::fs::write(&path, text).expect("write the variant");
        let result = check(&path);
        std::fs::remove_dir_all(&directory).expect("remove the temporary directory");
        result
    }

    #[test]
    fn a_service_problem_line_keeps_its_key_apart_when_it_starts_with_one() {
        let finding = Finding::from_line(
            "mill.toml",
            "drivelines[0].wear.couplings[1]: 3 is not allowed (must be 0 ..= 1)",
        );
        assert_eq!(
            finding.key.as_deref(),
            Some("drivelines[0].wear.couplings[1]")
        );
        assert_eq!(finding.message, "3 is not allowed (must be 0 ..= 1)");
        assert_eq!(
            finding.text,
            "mill.toml: drivelines[0].wear.couplings[1]: 3 is not allowed (must be 0 ..= 1)"
        );
        let listed = Finding::from_line("m.toml", "drivelines, tandem_mills: too many registers");
        assert_eq!(listed.key.as_deref(), Some("drivelines, tandem_mills"));
        let sentence = Finding::from_line(
            "m.toml",
            "cannot bind the metrics endpoint to 127.0.0.1:9187: Address in use",
        );
        assert_eq!(sentence.key, None);
        assert_eq!(
            sentence.message,
            "cannot bind the metrics endpoint to 127.0.0.1:9187: Address in use"
        );
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
        let CheckError::Config(error) = error else {
            panic!("a configuration problem: {error}");
        };
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
