#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

mod dbc;
mod error;
pub mod frame;
mod hash;
pub mod layout;
mod parse;
mod raw;
mod scaling;
pub mod serial;
mod service_dirs;
pub mod signal;
mod summary;
pub mod text;
mod tls;
mod types;
mod validate;

use std::path::Path;

pub use error::{ConfigError, Problem};
pub use scaling::{f32_decimal, Scaling};
pub use serial::{Parity, SerialLine};
pub use service_dirs::{ServiceDirs, CACHE_DIRECTORY, CREDENTIALS_DIRECTORY, STATE_DIRECTORY};
pub use summary::summary;
pub use tls::{TlsFileError, TlsMaterial};
pub use types::*;

use error::Report;

/// Reads, parses and validates the configuration file at `path`.
///
/// Relative paths inside the file (`dbc`, `model`) are resolved against the file's
/// directory; the folders systemd hands a service (`ServiceDirs::from_env`) place
/// the history file, the cache and the MQTT password credential (see
/// [`from_toml_str_with`]). Problems are reported against `path` as given.
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
    parse_and_validate(
        &text,
        &file_name,
        base_dir,
        &ServiceDirs::from_env(),
        purpose,
    )
}

/// Parses and validates configuration `text`; `file_name` names it in problems and
/// relative paths inside it are resolved against `base_dir`.
///
/// All problems are collected, in three passes that each run only when the previous
/// one found nothing: TOML syntax, schema (unknown or misspelt keys, wrong types,
/// missing keys), then values and references. No service folders apply (as outside
/// systemd); [`from_toml_str_with`] takes them.
pub fn from_toml_str(text: &str, file_name: &str, base_dir: &Path) -> Result<Config, ConfigError> {
    from_toml_str_with(text, file_name, base_dir, &ServiceDirs::default())
}

/// [`from_toml_str`] with the folders systemd hands a service: a relative
/// `history.path` is resolved against `dirs.state`, `cache_dir` defaults to
/// `dirs.cache` (a relative one is resolved against it), and
/// `outputs.mqtt.password_credential` is read from `dirs.credentials`; a folder that
/// is `None` leaves the configuration file's folder (history) or the user's cache
/// folder (cache) in place.
///
/// ```
/// use millgate_config::{from_toml_str_with, ServiceDirs};
/// let dirs = ServiceDirs {
///     state: Some(std::env::temp_dir()),
///     ..ServiceDirs::default()
/// };
/// let text = "name = \"F1\"\n[history]\npath = \"history.db\"\n";
/// let config = from_toml_str_with(text, "mill.toml", "/etc/millgate".as_ref(), &dirs)?;
/// assert_eq!(config.history.unwrap().path, std::env::temp_dir().join("history.db"));
/// # Ok::<(), millgate_config::ConfigError>(())
/// ```
pub fn from_toml_str_with(
    text: &str,
    file_name: &str,
    base_dir: &Path,
    dirs: &ServiceDirs,
) -> Result<Config, ConfigError> {
    parse_and_validate(text, file_name, base_dir, dirs, validate::Purpose::Service)
}

fn parse_and_validate(
    text: &str,
    file_name: &str,
    base_dir: &Path,
    dirs: &ServiceDirs,
    purpose: validate::Purpose,
) -> Result<Config, ConfigError> {
    let mut report = Report::new(file_name);
    let config = parse::parse(text, &mut report)
        .and_then(|raw| validate::validate(raw, base_dir, dirs, &mut report, purpose))
        .map(|config| Config {
            hash: hash::canonical_hash(text),
            ..config
        });
    report.finish(config)
}

/// Whether `id` can be a Sparkplug B group, edge node or device id: non-empty and
/// none of the MQTT topic characters `/ + #`.
pub fn is_sparkplug_id(id: &str) -> bool {
    !id.is_empty() && !id.contains(['/', '+', '#'])
}
