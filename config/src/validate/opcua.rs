//! `[outputs.opcua]`: the OPC UA server's address, security, users and limits.

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::raw::RawOpcUaOutput;
use crate::{OpcUaOutput, OpcUaSecurityMode, OpcUaUser};

use super::{Checker, Written};

/// Allowed `max_connections`.
const CONNECTIONS_RANGE: RangeInclusive<i64> = 1..=256;
/// Allowed `max_sessions`.
const SESSIONS_RANGE: RangeInclusive<i64> = 1..=100;
/// Allowed `max_subscriptions_per_session`.
const SUBSCRIPTIONS_RANGE: RangeInclusive<i64> = 1..=100;
/// Allowed `max_monitored_items_per_subscription`.
const MONITORED_ITEMS_RANGE: RangeInclusive<i64> = 1..=100_000;
/// Allowed `max_session_timeout_ms`.
const SESSION_TIMEOUT_RANGE_MS: RangeInclusive<i64> = 1_000..=3_600_000;
/// Longest user name in `users_file`, characters.
const MAX_USER_NAME: usize = 64;

/// The default `pki_dir`: `opcua-pki` in `$STATE_DIRECTORY` ([`crate::ServiceDirs`])
/// when systemd sets it, else beside the history file, else beside the configuration
/// file.
fn default_pki_dir(state: Option<&Path>, history: Option<&Path>, base_dir: &Path) -> PathBuf {
    let folder = match (state, history.and_then(Path::parent)) {
        (Some(state), _) => state.to_path_buf(),
        (None, Some(history_folder)) if !history_folder.as_os_str().is_empty() => {
            history_folder.to_path_buf()
        }
        _ => base_dir.to_path_buf(),
    };
    folder.join(OpcUaOutput::DEFAULT_PKI_FOLDER)
}

/// The server's limits, each `None` when reported.
struct Limits {
    connections: Option<usize>,
    sessions: Option<usize>,
    sessions_per_peer: Option<usize>,
    subscriptions: Option<usize>,
    monitored_items: Option<usize>,
    session_timeout_ms: Option<usize>,
}

impl Checker<'_> {
    /// `[outputs.opcua]`; `history` is the history file (resolved), where the default
    /// `pki_dir` goes when `$STATE_DIRECTORY` is not set.
    pub(super) fn opcua(
        &mut self,
        raw: &RawOpcUaOutput,
        history: Option<&Path>,
    ) -> Option<OpcUaOutput> {
        let key = "outputs.opcua";
        let bind = self.bind(
            &format!("{key}.bind"),
            raw.bind.as_deref().unwrap_or(OpcUaOutput::DEFAULT_BIND),
        );
        let host = self.opcua_endpoint_host(key, raw, bind);
        let security_modes = self.opcua_modes(key, raw, bind);
        let pki_dir = match &raw.pki_dir {
            Some(dir) => self.opcua_pki_dir(&format!("{key}.pki_dir"), dir),
            None => Some(default_pki_dir(
                self.dirs.state.as_deref(),
                history,
                self.base_dir,
            )),
        };
        let users = match &raw.users_file {
            Some(file) => self.opcua_users(&format!("{key}.users_file"), file),
            None => Some(Vec::new()),
        };
        let anonymous = raw.anonymous.unwrap_or(true);
        if !anonymous && raw.users_file.is_none() {
            self.report.push(
                format!("{key}.anonymous"),
                "false is not allowed without users_file: no client could sign in \
                 (give users_file, or allow anonymous sessions)",
            );
        }
        let limits = self.opcua_limits(key, raw);
        if !anonymous && raw.users_file.is_none() {
            return None;
        }
        Some(OpcUaOutput {
            bind: bind?,
            host: host?,
            security_modes: security_modes?,
            pki_dir: pki_dir?,
            anonymous,
            users: users?,
            allow_remote_commands: raw.allow_remote_commands.unwrap_or(false),
            max_connections: limits.connections?,
            max_sessions: limits.sessions?,
            max_sessions_per_peer: limits.sessions_per_peer?,
            max_subscriptions_per_session: limits.subscriptions?,
            max_monitored_items_per_subscription: limits.monitored_items?,
            max_session_timeout: Duration::from_millis(limits.session_timeout_ms? as u64),
        })
    }

    /// `host`: as given, or the bind address's when it is not the unspecified one
    /// (which clients cannot reach).
    fn opcua_endpoint_host(
        &mut self,
        key: &str,
        raw: &RawOpcUaOutput,
        bind: Option<SocketAddr>,
    ) -> Option<String> {
        match (&raw.host, bind) {
            (Some(host), _) => self.opcua_host(&format!("{key}.host"), host),
            (None, Some(bind)) if bind.ip().is_unspecified() => {
                self.report.push(
                    format!("{key}.host"),
                    format!(
                        "missing: bind {bind} listens on every address; give the host name or \
                         IP address clients reach the gateway at (written into the endpoint \
                         URL and the server certificate)"
                    ),
                );
                None
            }
            (None, Some(bind)) => Some(bind.ip().to_string()),
            (None, None) => None,
        }
    }

    /// `security_modes`: as given, else none on loopback and sign, sign-and-encrypt
    /// elsewhere.
    fn opcua_modes(
        &mut self,
        key: &str,
        raw: &RawOpcUaOutput,
        bind: Option<SocketAddr>,
    ) -> Option<Vec<OpcUaSecurityMode>> {
        match (&raw.security_modes, bind) {
            (Some(modes), _) => self.opcua_security_modes(&format!("{key}.security_modes"), modes),
            (None, Some(bind)) if bind.ip().is_loopback() => Some(vec![OpcUaSecurityMode::None]),
            (None, _) => Some(vec![
                OpcUaSecurityMode::Sign,
                OpcUaSecurityMode::SignAndEncrypt,
            ]),
        }
    }

    /// The connection, session, subscription, monitored-item and session-timeout
    /// limits, each in its range (defaults from [`OpcUaOutput`]).
    fn opcua_limits(&mut self, key: &str, raw: &RawOpcUaOutput) -> Limits {
        let mut limit = |name: &str, value: Option<i64>, default: usize, range, unit: &str| {
            self.int_in(
                &format!("{key}.{name}"),
                value.unwrap_or(default as i64),
                range,
                unit,
            )
            .and_then(|value| usize::try_from(value).ok())
        };
        let connections = limit(
            "max_connections",
            raw.max_connections,
            OpcUaOutput::DEFAULT_MAX_CONNECTIONS,
            CONNECTIONS_RANGE,
            "",
        );
        let sessions = limit(
            "max_sessions",
            raw.max_sessions,
            OpcUaOutput::DEFAULT_MAX_SESSIONS,
            SESSIONS_RANGE,
            "",
        );
        let subscriptions = limit(
            "max_subscriptions_per_session",
            raw.max_subscriptions_per_session,
            OpcUaOutput::DEFAULT_MAX_SUBSCRIPTIONS_PER_SESSION,
            SUBSCRIPTIONS_RANGE,
            "",
        );
        let monitored_items = limit(
            "max_monitored_items_per_subscription",
            raw.max_monitored_items_per_subscription,
            OpcUaOutput::DEFAULT_MAX_MONITORED_ITEMS_PER_SUBSCRIPTION,
            MONITORED_ITEMS_RANGE,
            "",
        );
        let session_timeout_ms = limit(
            "max_session_timeout_ms",
            raw.max_session_timeout_ms,
            OpcUaOutput::DEFAULT_MAX_SESSION_TIMEOUT_MS as usize,
            SESSION_TIMEOUT_RANGE_MS,
            " ms",
        );
        // At most max_sessions (half of it by default); an invalid max_sessions is
        // reported on its own.
        let most = sessions.unwrap_or(*SESSIONS_RANGE.end() as usize);
        let sessions_per_peer = self
            .int_in(
                &format!("{key}.max_sessions_per_peer"),
                raw.max_sessions_per_peer
                    .unwrap_or(OpcUaOutput::default_max_sessions_per_peer(most) as i64),
                1..=most as i64,
                &format!(", at most {key}.max_sessions"),
            )
            .and_then(|value| usize::try_from(value).ok());
        Limits {
            connections,
            sessions,
            sessions_per_peer,
            subscriptions,
            monitored_items,
            session_timeout_ms,
        }
    }

    /// A host name or IP address for the endpoint URL: letters, digits, `.`, `-`, or an
    /// IP address.
    fn opcua_host(&mut self, key: &str, host: &str) -> Option<String> {
        let is_name = !host.is_empty()
            && host.len() <= 253
            && host
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '.' || c == '-');
        if is_name || host.parse::<std::net::IpAddr>().is_ok() {
            Some(host.to_owned())
        } else {
            self.report.push(
                key,
                format!(
                    "\"{host}\" is not allowed (must be a host name of letters, digits, '.' and \
                     '-', or an IP address, e.g. gateway1.plant.local or 192.168.0.20)"
                ),
            );
            None
        }
    }

    /// One or more distinct security modes by their file spelling.
    fn opcua_security_modes(
        &mut self,
        key: &str,
        modes: &[String],
    ) -> Option<Vec<OpcUaSecurityMode>> {
        if modes.is_empty() {
            self.report.push(
                key,
                "[] is not allowed (must list one or more of none, sign, sign_and_encrypt)",
            );
            return None;
        }
        let mut chosen = Vec::new();
        for (index, text) in modes.iter().enumerate() {
            let mode = self.choice(
                &format!("{key}[{index}]"),
                "security mode",
                text,
                &OpcUaSecurityMode::ALL,
                OpcUaSecurityMode::name,
            )?;
            if chosen.contains(&mode) {
                self.report.push(
                    format!("{key}[{index}]"),
                    format!("\"{text}\" is listed twice"),
                );
                return None;
            }
            chosen.push(mode);
        }
        Some(chosen)
    }

    /// A folder whose parent exists (the folder itself is created at the first start);
    /// a relative one is resolved like `history.path` (against `$STATE_DIRECTORY` under
    /// systemd, else the configuration file's folder).
    fn opcua_pki_dir(&mut self, key: &str, relative: &str) -> Option<PathBuf> {
        if relative.trim().is_empty() {
            self.report.push(
                key,
                "must not be empty (leave it out for the default: opcua-pki beside the history)",
            );
            return None;
        }
        let (path, resolution) = self.written_path(relative, Written::State);
        if path.is_file() {
            self.report
                .push(key, format!("\"{relative}\" is a file (must be a folder)"));
            return None;
        }
        let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
        if path.is_dir() || parent.is_none_or(Path::is_dir) {
            Some(path)
        } else {
            self.report.push(
                key,
                format!(
                    "the folder above \"{relative}\" does not exist (looked for {}; {resolution})",
                    parent.map_or_else(String::new, |p| p.display().to_string())
                ),
            );
            None
        }
    }

    /// The users of `users_file`: one `name:password` per line; blank lines and lines
    /// starting with `#` are skipped.
    fn opcua_users(&mut self, key: &str, relative: &str) -> Option<Vec<OpcUaUser>> {
        let path = self.base_dir.join(relative);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(error) => {
                self.report.push(
                    key,
                    format!(
                        "cannot read \"{relative}\" ({}: {error}; paths are relative to the \
                         configuration file)",
                        path.display()
                    ),
                );
                return None;
            }
        };
        let mut users: Vec<OpcUaUser> = Vec::new();
        let mut valid = true;
        for (index, line) in text.lines().enumerate() {
            let line = line.strip_suffix('\r').unwrap_or(line);
            if line.trim().is_empty() || line.trim_start().starts_with('#') {
                continue;
            }
            let at = format!("{relative}:{}", index + 1);
            let problem = match line.split_once(':') {
                None => Some("must be name:password".to_owned()),
                Some((name, _)) if name.is_empty() || name.chars().count() > MAX_USER_NAME => Some(
                    format!("user name must be 1..={MAX_USER_NAME} characters before the ':'"),
                ),
                Some((name, _)) if name.chars().any(char::is_control) => {
                    Some("user name must not hold control characters".to_owned())
                }
                Some((_, "")) => Some("password must not be empty".to_owned()),
                Some((name, _)) if users.iter().any(|user| user.name == name) => {
                    Some(format!("user \"{name}\" is listed twice"))
                }
                Some((name, password)) => {
                    users.push(OpcUaUser {
                        name: name.to_owned(),
                        password: password.to_owned(),
                    });
                    None
                }
            };
            if let Some(problem) = problem {
                self.report.push(key, format!("{at}: {problem}"));
                valid = false;
            }
        }
        if users.is_empty() && valid {
            self.report.push(
                key,
                format!("\"{relative}\" lists no user (one name:password per line)"),
            );
            return None;
        }
        valid.then_some(users)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_pki_dir_prefers_the_state_directory_then_the_history() {
        let base = Path::new("/etc/millgate");
        let history = Path::new("/var/lib/millgate/history.db");
        assert_eq!(
            default_pki_dir(
                Some(Path::new("/var/lib/millgate-state")),
                Some(history),
                base
            ),
            Path::new("/var/lib/millgate-state/opcua-pki")
        );
        assert_eq!(
            default_pki_dir(None, Some(history), base),
            Path::new("/var/lib/millgate/opcua-pki")
        );
        assert_eq!(
            default_pki_dir(None, None, base),
            Path::new("/etc/millgate/opcua-pki")
        );
    }
}
