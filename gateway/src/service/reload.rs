//! `SIGHUP` to `millgate run`: the configuration file is read and checked again, and
//! the service says what became of it, without stopping.
//!
//! - A file with errors is refused with them (file, line, key, allowed range): the
//!   service runs on with the configuration it has.
//! - An unchanged file (by its [`millgate_config::Config::hash`]) changes nothing.
//! - A changed file is compared section by section with the running one; the
//!   sections that differ are named, and applying them needs a restart today (the
//!   running service goes on with the configuration it started with: nothing in
//!   flight, no bite, capture or store-and-forward backlog, is touched).
//!
//! A hang-up is never the default action of the signal (which ends the process with
//! no final PLC write and leaves its run `unclean` in the history).

use std::fmt;
use std::path::Path;

use millgate_config::Config;

/// What a reload request found.
#[derive(Debug, Clone, PartialEq)]
pub enum Reload {
    /// The file has errors (their report): nothing changes.
    Refused(String),
    /// The file's settings are the running ones.
    Unchanged,
    /// These sections differ from the running configuration; a restart applies them.
    NeedsRestart(Vec<&'static str>),
}

impl fmt::Display for Reload {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reload::Refused(errors) => write!(
                f,
                "reload refused: the configuration has errors; the service runs on with the \
                 one it has: {errors}"
            ),
            Reload::Unchanged => write!(f, "reload: the configuration is unchanged"),
            Reload::NeedsRestart(sections) => write!(
                f,
                "reload: changed {}: applying them needs a restart (systemctl restart \
                 millgate); the service runs on with the configuration it started with",
                sections.join(", ")
            ),
        }
    }
}

/// The file at `path` checked and compared with `running`.
pub fn reload(running: &Config, path: &Path) -> Reload {
    match millgate_config::load(path) {
        Err(errors) => Reload::Refused(errors.to_string()),
        Ok(new) => compare(running, &new),
    }
}

/// What differs between `running` and `new`, by section.
fn compare(running: &Config, new: &Config) -> Reload {
    if running.hash == new.hash && running == new {
        return Reload::Unchanged;
    }
    let outputs = (&running.outputs, &new.outputs);
    let sections = [
        ("name", running.name != new.name),
        ("cache_dir", running.cache_dir != new.cache_dir),
        ("log_format", running.log_format != new.log_format),
        ("sources", running.modbus_sources != new.modbus_sources),
        ("can_sources", running.can_sources != new.can_sources),
        ("channels", running.channels != new.channels),
        ("drivelines", running.drivelines != new.drivelines),
        ("tandem_mills", running.tandem_mills != new.tandem_mills),
        ("rod_mills", running.rod_mills != new.rod_mills),
        ("outputs.plc", outputs.0.plc != outputs.1.plc),
        ("outputs.server", outputs.0.server != outputs.1.server),
        ("outputs.metrics", outputs.0.metrics != outputs.1.metrics),
        ("outputs.mqtt", outputs.0.mqtt != outputs.1.mqtt),
        ("outputs.web", outputs.0.web != outputs.1.web),
        ("outputs.opcua", outputs.0.opcua != outputs.1.opcua),
        ("history", running.history != new.history),
    ];
    let changed: Vec<&'static str> = sections
        .iter()
        .filter(|(_, changed)| *changed)
        .map(|(name, _)| *name)
        .collect();
    match changed.is_empty() {
        // Only what the hash sees and the settings do not (a default written out).
        true => Reload::Unchanged,
        false => Reload::NeedsRestart(changed),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The demo's configuration with its model named by its full path, so the file
    /// can sit in a scratch folder.
    fn demo() -> String {
        let examples = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples");
        include_str!("../../../config/examples/demo.toml").replace(
            "model = \"table2-adjusted.toml\"",
            &format!("model = \"{examples}/table2-adjusted.toml\""),
        )
    }

    #[test]
    fn a_reload_names_errors_changed_sections_or_nothing() {
        let folder = std::env::temp_dir().join(format!("millgate-reload-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("mill.toml");
        std::fs::write(&path, demo()).unwrap();
        let running = millgate_config::load(&path).unwrap();
        assert_eq!(reload(&running, &path), Reload::Unchanged);
        // A comment does not count.
        std::fs::write(&path, format!("# edited\n{}", demo())).unwrap();
        assert_eq!(reload(&running, &path), Reload::Unchanged);
        let changed = demo().replace("taf_alarm = 2.6", "taf_alarm = 2.8");
        std::fs::write(&path, &changed).unwrap();
        assert_eq!(
            reload(&running, &path),
            Reload::NeedsRestart(vec!["drivelines"])
        );
        let broken = demo().replace("taf_alarm = 2.6", "taf_alarm = -1.0");
        std::fs::write(&path, broken).unwrap();
        let refused = reload(&running, &path);
        let Reload::Refused(errors) = &refused else {
            panic!("a file with errors is refused: {refused:?}");
        };
        assert!(
            errors.contains("mill.toml") && errors.contains("taf_alarm"),
            "{errors}"
        );
        assert!(
            refused.to_string().starts_with("reload refused"),
            "{refused}"
        );
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
