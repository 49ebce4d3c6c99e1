//! `[outputs]`: the PLC writer, the HMI server, the metrics endpoint, the Sparkplug
//! node and the web page (the OPC UA server's keys are in `opcua.rs`).

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::Path;
use std::time::Duration;

use crate::raw::{
    RawBroker, RawMqttOutput, RawMqttServer, RawMqttTls, RawOutputs, RawPlcOutput, RawServerOutput,
    RawWebOutput,
};
use crate::{
    MetricsOutput, MqttOutput, MqttSecurity, MqttTls, Outputs, PlcOutput, ServerOutput, WebOutput,
    CREDENTIALS_DIRECTORY, MAX_REQUESTS_IN_FLIGHT,
};

use super::{
    optional, Checker, DEFAULT_IDLE_TIMEOUT_MS, DEFAULT_MAX_CONNECTIONS,
    DEFAULT_MAX_CONNECTIONS_PER_PEER, DEFAULT_METRICS_BIND, DEFAULT_TIMEOUT_MS, DEFAULT_UNIT_ID,
    DEFAULT_WEB_BIND, MAX_DRIVELINE_SLOTS,
};

/// Most HMI clients `outputs.server.max_connections` may allow.
const MAX_CONNECTIONS_LIMIT: i64 = 64;
/// Allowed `outputs.server.idle_timeout_ms`.
const IDLE_TIMEOUT_RANGE_MS: RangeInclusive<i64> = 100..=3_600_000;
/// Most MQTT servers `outputs.mqtt.brokers` may list.
const MAX_MQTT_SERVERS: usize = 16;
/// Allowed `outputs.web.max_connections`.
const WEB_CONNECTIONS_RANGE: RangeInclusive<i64> = 1..=1024;
/// Allowed `outputs.web.header_timeout_ms` and `request_timeout_ms`.
const WEB_TIMEOUT_RANGE_MS: RangeInclusive<i64> = 100..=60_000;
/// Allowed `outputs.web.history_queries`.
const WEB_HISTORY_QUERIES_RANGE: RangeInclusive<i64> = 1..=8;

impl Checker<'_> {
    /// `[outputs]`; `history` is the history file when `[history]` is configured (the
    /// MQTT output keeps its session number there; the OPC UA server's certificates go
    /// beside it by default).
    pub(super) fn outputs(
        &mut self,
        raw: &RawOutputs,
        history: Option<&std::path::Path>,
    ) -> Option<Outputs> {
        let plc = raw.plc.as_ref().map(|plc| self.plc(plc));
        let server = raw.server.as_ref().map(|server| self.server(server));
        let metrics = raw.metrics.as_ref().map(|metrics| {
            let bind = metrics.bind.as_deref().unwrap_or(DEFAULT_METRICS_BIND);
            Some(MetricsOutput {
                bind: self.bind("outputs.metrics.bind", bind)?,
            })
        });
        let web = raw.web.as_ref().map(|web| self.web(web));
        let opcua = raw.opcua.as_ref().map(|opcua| self.opcua(opcua, history));
        let (server, metrics, web) = (optional(server), optional(metrics), optional(web));
        let opcua = optional(opcua);
        let listeners: Vec<(&str, SocketAddr)> = [
            (
                "outputs.server.bind",
                server.as_ref().and_then(|s| s.as_ref().map(|s| s.bind)),
            ),
            (
                "outputs.metrics.bind",
                metrics.as_ref().and_then(|m| m.as_ref().map(|m| m.bind)),
            ),
            (
                "outputs.web.bind",
                web.as_ref().and_then(|w| w.as_ref().map(|w| w.bind)),
            ),
            (
                "outputs.opcua.bind",
                opcua.as_ref().and_then(|o| o.as_ref().map(|o| o.bind)),
            ),
        ]
        .into_iter()
        .filter_map(|(key, bind)| Some((key, bind?)))
        .collect();
        self.distinct_listeners(&listeners);
        let mqtt = raw
            .mqtt
            .as_ref()
            .map(|mqtt| self.mqtt(mqtt, history.is_some()));
        let driveline_slots = raw.driveline_slots.map(|slots| {
            self.int_in(
                "outputs.driveline_slots",
                slots,
                1..=MAX_DRIVELINE_SLOTS,
                "",
            )
        });
        Some(Outputs {
            driveline_slots: optional(driveline_slots)?.map(|slots| slots as usize),
            plc: optional(plc)?,
            server: server?,
            metrics: metrics?,
            mqtt: optional(mqtt)?,
            web: web?,
            opcua: opcua?,
        })
    }

    /// `[outputs.plc]`: the PLC the gateway writes, where, how often.
    fn plc(&mut self, plc: &RawPlcOutput) -> Option<PlcOutput> {
        let key = "outputs.plc";
        let address = self.host_port(&format!("{key}.address"), &plc.address);
        let unit_id = self.unit_id(&format!("{key}.unit_id"), plc.unit_id);
        let register_base = self.int_in(
            &format!("{key}.register_base"),
            plc.register_base.unwrap_or(0),
            0..=65_535,
            "",
        );
        let write_period = self.period(&format!("{key}.write_period_ms"), plc.write_period_ms);
        let timeout = self.period(
            &format!("{key}.timeout_ms"),
            plc.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS),
        );
        let requests_in_flight = self.int_in(
            &format!("{key}.requests_in_flight"),
            plc.requests_in_flight.unwrap_or(1),
            1..=MAX_REQUESTS_IN_FLIGHT,
            "",
        );
        Some(PlcOutput {
            address: address?,
            unit_id: unit_id?,
            register_base: u16::try_from(register_base?).ok()?,
            write_period: write_period?,
            timeout: timeout?,
            extension_blocks: plc.extension_blocks.unwrap_or(false),
            requests_in_flight: usize::try_from(requests_in_flight?).ok()?,
        })
    }

    /// `[outputs.server]`: the HMI's Modbus server, its unit and connection limits.
    fn server(&mut self, server: &RawServerOutput) -> Option<ServerOutput> {
        let key = "outputs.server";
        let bind = self.bind(&format!("{key}.bind"), &server.bind);
        let unit_id = self.int_in(
            &format!("{key}.unit_id"),
            server.unit_id.unwrap_or(DEFAULT_UNIT_ID),
            1..=255,
            "; 0 is the broadcast address, which a server never answers",
        );
        let max_connections = self.int_in(
            &format!("{key}.max_connections"),
            server
                .max_connections
                .unwrap_or(DEFAULT_MAX_CONNECTIONS as i64),
            1..=MAX_CONNECTIONS_LIMIT,
            "",
        );
        // At most max_connections (its default too when max_connections is
        // smaller); an invalid max_connections is reported on its own.
        let most = max_connections.unwrap_or(MAX_CONNECTIONS_LIMIT);
        let max_connections_per_peer = self.int_in(
            &format!("{key}.max_connections_per_peer"),
            server
                .max_connections_per_peer
                .unwrap_or((DEFAULT_MAX_CONNECTIONS_PER_PEER as i64).min(most)),
            1..=most,
            &format!(", at most {key}.max_connections"),
        );
        let idle_timeout_ms = self.int_in(
            &format!("{key}.idle_timeout_ms"),
            server
                .idle_timeout_ms
                .unwrap_or(DEFAULT_IDLE_TIMEOUT_MS as i64),
            IDLE_TIMEOUT_RANGE_MS,
            " ms",
        );
        Some(ServerOutput {
            bind: bind?,
            unit_id: u8::try_from(unit_id?).ok()?,
            max_connections: usize::try_from(max_connections?).ok()?,
            max_connections_per_peer: usize::try_from(max_connections_per_peer?).ok()?,
            idle_timeout: Duration::from_millis(u64::try_from(idle_timeout_ms?).ok()?),
            allow_remote_commands: server.allow_remote_commands.unwrap_or(false),
        })
    }

    fn web(&mut self, raw: &RawWebOutput) -> Option<WebOutput> {
        let key = "outputs.web";
        let bind = self.bind(
            &format!("{key}.bind"),
            raw.bind.as_deref().unwrap_or(DEFAULT_WEB_BIND),
        );
        let max_connections = self.int_in(
            &format!("{key}.max_connections"),
            raw.max_connections
                .unwrap_or(WebOutput::DEFAULT_MAX_CONNECTIONS as i64),
            WEB_CONNECTIONS_RANGE,
            "",
        );
        let mut timeout = |name: &str, value: Option<i64>, default: i64| {
            self.int_in(
                &format!("{key}.{name}"),
                value.unwrap_or(default),
                WEB_TIMEOUT_RANGE_MS,
                " ms",
            )
            .and_then(|ms| Some(Duration::from_millis(u64::try_from(ms).ok()?)))
        };
        let header_timeout = timeout(
            "header_timeout_ms",
            raw.header_timeout_ms,
            WebOutput::DEFAULT_HEADER_TIMEOUT_MS as i64,
        );
        let request_timeout = timeout(
            "request_timeout_ms",
            raw.request_timeout_ms,
            WebOutput::DEFAULT_REQUEST_TIMEOUT_MS as i64,
        );
        let history_queries = self.int_in(
            &format!("{key}.history_queries"),
            raw.history_queries
                .unwrap_or(WebOutput::DEFAULT_HISTORY_QUERIES as i64),
            WEB_HISTORY_QUERIES_RANGE,
            "",
        );
        // An open page holds one stream: the streams leave at least one connection
        // for everything else.
        let most_streams = max_connections.map_or(1, |max| (max - 1).max(1));
        let max_event_streams = self.int_in(
            &format!("{key}.max_event_streams"),
            raw.max_event_streams
                .unwrap_or((WebOutput::DEFAULT_MAX_EVENT_STREAMS as i64).min(most_streams)),
            1..=most_streams,
            " (below outputs.web.max_connections)",
        );
        let allowed_hosts = self.host_names(
            &format!("{key}.allowed_hosts"),
            raw.allowed_hosts.as_deref().unwrap_or_default(),
        );
        Some(WebOutput {
            bind: bind?,
            max_connections: usize::try_from(max_connections?).ok()?,
            header_timeout: header_timeout?,
            request_timeout: request_timeout?,
            history_queries: usize::try_from(history_queries?).ok()?,
            max_event_streams: usize::try_from(max_event_streams?).ok()?,
            allowed_hosts: allowed_hosts?,
            allow_commands: raw.allow_commands.unwrap_or(false),
        })
    }

    /// Host names as a `Host` header gives them: 1..=253 characters of lower-case
    /// letters, digits, `-` and `.`.
    fn host_names(&mut self, key: &str, names: &[String]) -> Option<Vec<String>> {
        let mut valid = Some(Vec::with_capacity(names.len()));
        for (index, name) in names.iter().enumerate() {
            let allowed = (1..=253).contains(&name.len())
                && name.bytes().all(|b| {
                    b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-' || b == b'.'
                });
            if allowed {
                if let Some(valid) = valid.as_mut() {
                    valid.push(name.clone());
                }
            } else {
                self.report.push(
                    format!("{key}[{index}]"),
                    format!(
                        "\"{name}\" is not allowed (a host name: 1..=253 characters of \
                         lower-case letters, digits, '-' and '.')"
                    ),
                );
                valid = None;
            }
        }
        valid
    }

    /// Reports every pair of listeners that cannot both bind: the same port on the
    /// same address, or on an address and the wildcard (`0.0.0.0` or `[::]`) of the same
    /// family. Port 0 (the OS picks a free port) never clashes.
    fn distinct_listeners(&mut self, listeners: &[(&str, SocketAddr)]) {
        for (index, (key, address)) in listeners.iter().enumerate() {
            let clash = listeners[..index].iter().find(|(_, earlier)| {
                let same_family = earlier.is_ipv4() == address.is_ipv4();
                address.port() != 0
                    && earlier.port() == address.port()
                    && same_family
                    && (earlier.ip() == address.ip()
                        || earlier.ip().is_unspecified()
                        || address.ip().is_unspecified())
            });
            if let Some((earlier_key, earlier)) = clash {
                self.report.push(
                    *key,
                    format!(
                        "{address} is not allowed: {earlier_key} ({earlier}) listens on the \
                         same port; each listener needs its own port"
                    ),
                );
            }
        }
    }

    fn mqtt(&mut self, raw: &RawMqttOutput, history: bool) -> Option<MqttOutput> {
        let key = "outputs.mqtt";
        let brokers = self.mqtt_servers(raw);
        let group_id = self.sparkplug_id(&format!("{key}.group_id"), &raw.group_id);
        let node_id = self.sparkplug_id(&format!("{key}.node_id"), &raw.node_id);
        let client_id = match &raw.client_id {
            Some(id) if id.is_empty() || id.chars().count() > 64 => {
                self.report.push(
                    format!("{key}.client_id"),
                    format!("\"{id}\" is not allowed (must be 1..=64 characters)"),
                );
                None
            }
            Some(id) => Some(id.clone()),
            None => Some(format!("millgate-{}-{}", raw.group_id, raw.node_id)),
        };
        let keep_alive = self.int_in(
            &format!("{key}.keep_alive_s"),
            raw.keep_alive_s.unwrap_or(30),
            5..=3600,
            " s",
        );
        let data_period = self.period(
            &format!("{key}.data_period_ms"),
            raw.data_period_ms.unwrap_or(1000),
        );
        let command_qos = self.int_in(
            &format!("{key}.command_qos"),
            raw.command_qos.unwrap_or(1),
            0..=1,
            "",
        );
        let primary_host_id = match &raw.primary_host_id {
            Some(id) => self
                .sparkplug_id(&format!("{key}.primary_host_id"), id)
                .map(Some),
            None => Some(None),
        };
        let credentials = self.mqtt_credentials(key, &Credentials::of(raw));
        let tls = match &raw.tls {
            Some(tls) => self.mqtt_tls(&format!("{key}.tls"), tls).map(Some),
            None => Some(None),
        };
        let security = self.mqtt_security(raw, credentials.as_ref(), tls.as_ref());
        if !history {
            self.report.push(
                key,
                "needs [history]: the Sparkplug session number (bdSeq) is kept in the history file",
            );
            return None;
        }
        let replay_batch = self.int_in(
            &format!("{key}.replay_batch"),
            raw.replay_batch.unwrap_or(100),
            1..=100_000,
            "",
        );
        let replay_period = self.period(
            &format!("{key}.replay_period_ms"),
            raw.replay_period_ms.unwrap_or(100),
        );
        Some(MqttOutput {
            brokers: brokers?,
            group_id: group_id?,
            node_id: node_id?,
            client_id: client_id?,
            keep_alive: Duration::from_secs(u64::try_from(keep_alive?).ok()?),
            data_period: data_period?,
            command_qos: u8::try_from(command_qos?).ok()?,
            primary_host_id: primary_host_id?,
            credentials: credentials?,
            replay_batch: u32::try_from(replay_batch?).ok()?,
            replay_period: replay_period?,
            tls: tls?,
            security: security?,
        })
    }

    /// Per entry of `brokers` (or the one `broker`), its TLS and credentials: the
    /// shared ones (`shared_credentials`, `shared_tls`, `None` when they have errors)
    /// for a `"host:port"`, its own for a table.
    fn mqtt_security(
        &mut self,
        raw: &RawMqttOutput,
        shared_credentials: Option<&Option<(String, String)>>,
        shared_tls: Option<&Option<MqttTls>>,
    ) -> Option<Vec<MqttSecurity>> {
        let shared = || {
            Some(MqttSecurity {
                tls: shared_tls?.clone(),
                credentials: shared_credentials?.clone(),
            })
        };
        let Some(brokers) = &raw.brokers else {
            return shared().map(|security| vec![security]);
        };
        let mut all = Some(Vec::with_capacity(brokers.len()));
        for (index, broker) in brokers.iter().enumerate() {
            let security = match broker {
                RawBroker::Address(_) => shared(),
                RawBroker::Server(server) => {
                    let key = format!("outputs.mqtt.brokers[{index}]");
                    let credentials = self.mqtt_credentials(&key, &Credentials::of_server(server));
                    let tls = match &server.tls {
                        Some(tls) => self.mqtt_tls(&format!("{key}.tls"), tls).map(Some),
                        None => Some(None),
                    };
                    tls.zip(credentials)
                        .map(|(tls, credentials)| MqttSecurity { tls, credentials })
                }
            };
            match (&mut all, security) {
                (Some(all), Some(security)) => all.push(security),
                _ => all = None,
            }
        }
        all
    }

    /// The MQTT servers: `brokers` (1..=[`MAX_MQTT_SERVERS`], none twice) or `broker`,
    /// one of them; each `host:port`.
    fn mqtt_servers(&mut self, raw: &RawMqttOutput) -> Option<Vec<String>> {
        let key = "outputs.mqtt";
        match (&raw.broker, &raw.brokers) {
            (Some(broker), None) => Some(vec![self.host_port(&format!("{key}.broker"), broker)?]),
            (None, Some(entries)) => {
                let brokers: Vec<&str> = entries.iter().map(RawBroker::address).collect();
                if brokers.is_empty() || brokers.len() > MAX_MQTT_SERVERS {
                    self.report.push(
                        format!("{key}.brokers"),
                        format!(
                            "{} servers are not allowed (must be 1..={MAX_MQTT_SERVERS} \
                             \"host:port\" strings)",
                            brokers.len()
                        ),
                    );
                    return None;
                }
                let mut servers = Vec::with_capacity(brokers.len());
                for (index, broker) in brokers.iter().enumerate() {
                    let entry = match entries[index] {
                        RawBroker::Address(_) => format!("{key}.brokers[{index}]"),
                        RawBroker::Server(_) => format!("{key}.brokers[{index}].address"),
                    };
                    if let Some(first) = brokers[..index].iter().position(|b| b == broker) {
                        self.report.push(
                            entry,
                            format!("\"{broker}\" is listed already at brokers[{first}]"),
                        );
                        continue;
                    }
                    if let Some(server) = self.host_port(&entry, broker) {
                        servers.push(server);
                    }
                }
                (servers.len() == brokers.len()).then_some(servers)
            }
            (Some(_), Some(_)) => {
                self.report.push(
                    format!("{key}.brokers"),
                    "not allowed together with broker (give one of them: brokers for a list)",
                );
                None
            }
            (None, None) => {
                self.report.push(
                    format!("{key}.broker"),
                    "missing: give broker = \"host:port\" or brokers = [\"host:port\", ...]",
                );
                None
            }
        }
    }

    /// `username` with one of `password`, `password_file` (read now) and
    /// `password_credential` (read now from `$CREDENTIALS_DIRECTORY`), or none of them,
    /// of the table at `key`.
    fn mqtt_credentials(
        &mut self,
        key: &str,
        raw: &Credentials<'_>,
    ) -> Option<Option<(String, String)>> {
        let given: Vec<&str> = [
            ("password", raw.password.is_some()),
            ("password_file", raw.password_file.is_some()),
            ("password_credential", raw.password_credential.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, given)| given.then_some(name))
        .collect();
        if let [first, second, ..] = given[..] {
            self.report.push(
                format!("{key}.{second}"),
                format!("not allowed together with {first} (give one of them)"),
            );
            return None;
        }
        let password = if let Some(password) = &raw.password {
            Some((*password).clone())
        } else if let Some(file) = &raw.password_file {
            Some(self.password_file(&format!("{key}.password_file"), file)?)
        } else if let Some(name) = &raw.password_credential {
            Some(self.password_credential(&format!("{key}.password_credential"), name)?)
        } else {
            None
        };
        match (&raw.username, password) {
            (Some(user), Some(password)) => Some(Some(((*user).clone(), password))),
            (None, None) => Some(None),
            (Some(_), None) => {
                self.report.push(
                    format!("{key}.password"),
                    "missing: username needs password, password_file or password_credential",
                );
                None
            }
            (None, Some(_)) => {
                self.report.push(
                    format!("{key}.username"),
                    "missing: a password needs a username",
                );
                None
            }
        }
    }

    /// The password in the file `relative` (to the configuration file).
    fn password_file(&mut self, key: &str, relative: &str) -> Option<String> {
        let path = self.base_dir.join(relative);
        self.secret(
            key,
            &path,
            &format!("\"{relative}\""),
            "paths are relative to the configuration file",
        )
    }

    /// The password in the systemd credential `name`: the file of that name in
    /// `$CREDENTIALS_DIRECTORY` (the unit's `LoadCredential=name:<file>`).
    fn password_credential(&mut self, key: &str, name: &str) -> Option<String> {
        if name.is_empty() || name.contains('/') || name == "." || name == ".." {
            self.report.push(
                key,
                format!(
                    "\"{name}\" is not a credential name (the ID of LoadCredential=ID:FILE in \
                     the unit, a file name without `/`, e.g. \"mqtt\")"
                ),
            );
            return None;
        }
        let Some(folder) = &self.dirs.credentials else {
            self.report.push(
                key,
                format!(
                    "${CREDENTIALS_DIRECTORY} is not set: systemd sets it for a unit with \
                     LoadCredential={name}:FILE (deploy/millgate.service.d/mqtt-password.conf); \
                     outside systemd give password_file instead"
                ),
            );
            return None;
        };
        let path = folder.join(name);
        self.secret(
            key,
            &path,
            &format!("credential \"{name}\""),
            &format!(
                "${CREDENTIALS_DIRECTORY} is {}; the unit needs LoadCredential={name}:FILE",
                folder.display()
            ),
        )
    }

    /// The secret in the file at `path` (`what` names it for problems, `hint` says
    /// where it was looked for): its text without one trailing newline; not empty.
    fn secret(&mut self, key: &str, path: &Path, what: &str, hint: &str) -> Option<String> {
        match std::fs::read_to_string(path) {
            Ok(text) => {
                let password = text
                    .strip_suffix('\n')
                    .map_or(text.as_str(), |t| t.strip_suffix('\r').unwrap_or(t));
                if password.is_empty() {
                    self.report
                        .push(key, format!("{what} is empty ({})", path.display()));
                    return None;
                }
                Some(password.to_owned())
            }
            Err(error) => {
                self.report.push(
                    key,
                    format!("cannot read {what} ({}: {error}; {hint})", path.display()),
                );
                None
            }
        }
    }

    /// `[outputs.mqtt.tls]`: the files exist and hold PEM certificates and a key; a
    /// client certificate needs its key and a key its certificate.
    fn mqtt_tls(&mut self, key: &str, raw: &RawMqttTls) -> Option<MqttTls> {
        let ca_file = self.existing_file(&format!("{key}.ca_file"), &raw.ca_file);
        let client = match (&raw.cert_file, &raw.key_file) {
            (Some(cert), Some(private)) => {
                let cert = self.existing_file(&format!("{key}.cert_file"), cert);
                let private = self.existing_file(&format!("{key}.key_file"), private);
                Some(Some((cert?, private?)))
            }
            (None, None) => Some(None),
            (Some(_), None) => {
                self.report.push(
                    format!("{key}.key_file"),
                    "missing: a client certificate (cert_file) needs its private key",
                );
                None
            }
            (None, Some(_)) => {
                self.report.push(
                    format!("{key}.cert_file"),
                    "missing: a private key (key_file) needs its client certificate",
                );
                None
            }
        };
        let tls = MqttTls {
            key: key.to_owned(),
            ca_file: ca_file?,
            client: client?,
        };
        if let Err(error) = tls.read() {
            self.report.push(
                format!("{key}.{}", error.key),
                format!("{}: {}", error.path.display(), error.why),
            );
            return None;
        }
        Some(tls)
    }

    /// A Sparkplug group, node or device id: non-empty, none of `/ + #`.
    fn sparkplug_id(&mut self, key: &str, id: &str) -> Option<String> {
        if !crate::is_sparkplug_id(id) {
            self.report.push(
                key,
                format!("\"{id}\" is not allowed (must be non-empty, without / + or #)"),
            );
            None
        } else {
            Some(id.to_owned())
        }
    }
}

/// The credential keys of an `[outputs.mqtt]` table or of a server's table in
/// `brokers`.
struct Credentials<'a> {
    username: Option<&'a String>,
    password: Option<&'a String>,
    password_file: Option<&'a String>,
    password_credential: Option<&'a String>,
}

impl<'a> Credentials<'a> {
    fn of(raw: &'a RawMqttOutput) -> Self {
        Self {
            username: raw.username.as_ref(),
            password: raw.password.as_ref(),
            password_file: raw.password_file.as_ref(),
            password_credential: raw.password_credential.as_ref(),
        }
    }

    fn of_server(raw: &'a RawMqttServer) -> Self {
        Self {
            username: raw.username.as_ref(),
            password: raw.password.as_ref(),
            password_file: raw.password_file.as_ref(),
            password_credential: raw.password_credential.as_ref(),
        }
    }
}
