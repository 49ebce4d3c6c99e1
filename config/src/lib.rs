#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

mod dbc;
mod error;
pub mod frame;
pub mod layout;
mod parse;
mod raw;
pub mod signal;
mod summary;
mod tls;
mod types;
mod validate;

use std::path::Path;

pub use error::{ConfigError, Problem};
pub use summary::summary;
pub use tls::{TlsFileError, TlsMaterial};
pub use types::*;

use error::Report;

/// Reads, parses and validates the configuration file at `path`.
///
/// Relative paths inside the file (`dbc`, `model`) are resolved against the file's
/// directory. Problems are reported against `path` as given.
///
/// ```no_run
/// let config = millgate_config::load(std::path::Path::new("config/examples/demo.toml"))?;
/// println!("{}", millgate_config::summary(&config));
/// # Ok::<(), millgate_config::ConfigError>(())
/// ```
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    load_for(path, validate::Purpose::Service)
}

/// As [`load`], for commissioning a tandem mill's chatter thresholds: a tandem mill
/// may leave out `gain_thresholds` (`millgate chatter commission` computes them); its
/// thresholds are then empty, so its gain ratio is not computed. Everything else is
/// checked as for the service.
pub fn load_uncommissioned(path: &Path) -> Result<Config, ConfigError> {
    load_for(path, validate::Purpose::Commissioning)
}

fn load_for(path: &Path, purpose: validate::Purpose) -> Result<Config, ConfigError> {
    let file_name = path.display().to_string();
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(error) => {
            let mut report = Report::new(&file_name);
            report.push("", format!("cannot read the file: {error}"));
            return report.finish(None);
        }
    };
    let base_dir = path.parent().unwrap_or(Path::new("."));
    parse_and_validate(&text, &file_name, base_dir, purpose)
}

/// Parses and validates configuration `text`; `file_name` names it in problems and
/// relative paths inside it are resolved against `base_dir`.
///
/// All problems are collected, in three passes that each run only when the previous
/// one found nothing: TOML syntax, schema (unknown or misspelt keys, wrong types,
/// missing keys), then values and references.
pub fn from_toml_str(text: &str, file_name: &str, base_dir: &Path) -> Result<Config, ConfigError> {
    parse_and_validate(text, file_name, base_dir, validate::Purpose::Service)
}

fn parse_and_validate(
    text: &str,
    file_name: &str,
    base_dir: &Path,
    purpose: validate::Purpose,
) -> Result<Config, ConfigError> {
    let mut report = Report::new(file_name);
    let config = parse::parse(text, &mut report)
        .and_then(|raw| validate::validate(raw, base_dir, &mut report, purpose));
    report.finish(config)
}

/// Whether `id` can be a Sparkplug B group, edge node or device id: non-empty and
/// none of the MQTT topic characters `/ + #`.
pub fn is_sparkplug_id(id: &str) -> bool {
    !id.is_empty() && !id.contains(['/', '+', '#'])
}
