//! Checks of single values: names, integers and floats in range, periods, addresses,
//! files, choices. Each reports a problem naming the key and the allowed range.

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::time::Duration;

use super::{Checker, Names, Written, DEFAULT_UNIT_ID, PERIOD_RANGE_MS};
use crate::{CACHE_DIRECTORY, STATE_DIRECTORY};

impl Checker<'_> {
    /// Checks each item of the list at `list_key` with `check`, given the item's key
    /// (`channels[2]`), and reports a name used twice; `what` names the kind of item.
    pub(super) fn named_list<T, U>(
        &mut self,
        list_key: &str,
        what: &'static str,
        items: &[T],
        name: impl Fn(&T) -> &str,
        mut check: impl FnMut(&mut Self, &str, &T) -> Option<U>,
    ) -> Vec<Option<U>> {
        let mut names = Names::new(what);
        items
            .iter()
            .enumerate()
            .map(|(index, item)| {
                let key = format!("{list_key}[{index}]");
                names.add(self, &key, name(item));
                check(self, &key, item)
            })
            .collect()
    }

    /// A non-empty name without control characters: names end up in log lines,
    /// register names, Prometheus labels and HMI screens, where a NUL or a line break
    /// would cut or forge a line.
    pub(super) fn name(&mut self, key: &str, name: &str) -> Option<String> {
        if name.trim().is_empty() {
            self.report.push(key, "must not be empty");
            None
        } else if let Some((at, control)) = name.char_indices().find(|(_, c)| c.is_control()) {
            self.report.push(
                key,
                format!(
                    "{name:?} is not allowed (must not contain control characters; \
                     U+{:04X} at byte {at})",
                    u32::from(control)
                ),
            );
            None
        } else {
            Some(name.to_owned())
        }
    }

    /// A source name, unique across `[[sources.modbus]]` and `[[sources.can]]`.
    pub(super) fn source_name(&mut self, key: &str, name: &str) -> Option<String> {
        let name_key = format!("{key}.name");
        let name = self.name(&name_key, name)?;
        if let Some(first) = self.source_names.get(&name) {
            self.report.push(
                name_key,
                format!("duplicate source name \"{name}\" (already used by {first})"),
            );
            return None;
        }
        self.source_names.insert(name.clone(), key.to_owned());
        Some(name)
    }

    /// An integer within `range`; `unit` is appended to the allowed range.
    pub(super) fn int_in(
        &mut self,
        key: &str,
        value: i64,
        range: RangeInclusive<i64>,
        unit: &str,
    ) -> Option<i64> {
        if range.contains(&value) {
            Some(value)
        } else {
            self.report.push(
                key,
                format!(
                    "{value} is not allowed (must be {}..={}{unit})",
                    range.start(),
                    range.end()
                ),
            );
            None
        }
    }

    pub(super) fn unit_id(&mut self, key: &str, value: Option<i64>) -> Option<u8> {
        let value = self.int_in(key, value.unwrap_or(DEFAULT_UNIT_ID), 0..=255, "")?;
        u8::try_from(value).ok()
    }

    pub(super) fn period(&mut self, key: &str, value_ms: i64) -> Option<Duration> {
        let value_ms = self.int_in(key, value_ms, PERIOD_RANGE_MS, " ms")?;
        Some(Duration::from_millis(u64::try_from(value_ms).ok()?))
    }

    /// A finite float for which `allowed` holds; `rule` says what is allowed.
    pub(super) fn float(
        &mut self,
        key: &str,
        value: f64,
        allowed: bool,
        rule: &str,
    ) -> Option<f64> {
        if value.is_finite() && allowed {
            Some(value)
        } else {
            self.report
                .push(key, format!("{value} is not allowed (must be {rule})"));
            None
        }
    }

    /// `host:port` with a port 1..=65535, kept as written (resolved at connect time).
    pub(super) fn host_port(&mut self, key: &str, address: &str) -> Option<String> {
        let valid = match address.rsplit_once(':') {
            Some((host, port)) => {
                let host_ok = if let Some(inner) = host
                    .strip_prefix('[')
                    .and_then(|host| host.strip_suffix(']'))
                {
                    inner.parse::<std::net::Ipv6Addr>().is_ok()
                } else {
                    !host.is_empty() && !host.contains(|c: char| c == ':' || c.is_whitespace())
                };
                host_ok && port.parse::<u16>().is_ok_and(|port| port > 0)
            }
            None => false,
        };
        if valid {
            Some(address.to_owned())
        } else {
            self.report.push(
                key,
                format!(
                    "\"{address}\" is not allowed (must be host:port with a port 1..=65535, \
                     e.g. 192.168.0.10:502 or plc1.local:502)"
                ),
            );
            None
        }
    }

    /// An IP socket address to listen on.
    pub(super) fn bind(&mut self, key: &str, address: &str) -> Option<SocketAddr> {
        match address.parse() {
            Ok(address) => Some(address),
            Err(_) => {
                self.report.push(
                    key,
                    format!(
                        "\"{address}\" is not allowed (must be an IP address and port, \
                         e.g. 0.0.0.0:502 or 127.0.0.1:5503)"
                    ),
                );
                None
            }
        }
    }

    /// `path`, which the gateway writes (`what`), resolved: an absolute path as is, a
    /// relative one against the service folder systemd set for it (`$STATE_DIRECTORY`,
    /// `$CACHE_DIRECTORY`), else against the configuration file's folder. Also says
    /// how relative paths are resolved, for problems.
    pub(super) fn written_path(&self, path: &str, what: Written) -> (PathBuf, String) {
        let (folder, variable, setting) = match what {
            Written::State => (&self.dirs.state, STATE_DIRECTORY, "StateDirectory="),
            Written::Cache => (&self.dirs.cache, CACHE_DIRECTORY, "CacheDirectory="),
        };
        match folder {
            Some(folder) => (
                folder.join(path),
                format!(
                    "relative paths are resolved against ${variable} ({})",
                    folder.display()
                ),
            ),
            None => (
                self.base_dir.join(path),
                format!(
                    "relative paths are resolved against the configuration file's folder, \
                     or ${variable} when systemd sets it ({setting})"
                ),
            ),
        }
    }

    /// A file relative to the configuration file's directory that must exist.
    pub(super) fn existing_file(&mut self, key: &str, relative: &str) -> Option<PathBuf> {
        let path = self.base_dir.join(relative);
        if path.is_file() {
            Some(path)
        } else {
            self.report.push(
                key,
                format!(
                    "file \"{relative}\" not found (looked for {}; paths are relative to \
                     the configuration file)",
                    path.display()
                ),
            );
            None
        }
    }

    /// One of `all` by its file spelling, else a problem listing the spellings.
    pub(super) fn choice<T: Copy>(
        &mut self,
        key: &str,
        what: &str,
        text: &str,
        all: &[T],
        name: fn(T) -> &'static str,
    ) -> Option<T> {
        let found = all.iter().copied().find(|&item| name(item) == text);
        if found.is_none() {
            let allowed: Vec<_> = all.iter().map(|&item| name(item)).collect();
            self.report.push(
                key,
                format!(
                    "unknown {what} \"{text}\" (allowed: {})",
                    allowed.join(", ")
                ),
            );
        }
        found
    }
}
