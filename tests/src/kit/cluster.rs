//! Clustered MQTT brokers for the failover tests, each started on loopback by the test
//! with every process a child of it, killed when the cluster is dropped:
//!
//! - [`AedesCluster`]: three aedes 1.2.0 processes (`tests/peers/aedes_node.mjs`,
//!   npm, pinned by `tests/peers/package-lock.json`) sharing one Debian
//!   `redis-server`: messages pass between nodes through mqemitter-redis, retained
//!   messages, subscriptions, QoS 1 queues and Wills are kept in redis by
//!   aedes-persistence-redis. It keeps Sparkplug topics as they are.
//! - [`RabbitCluster`]: Debian's `rabbitmq-server` (3.10) with its MQTT plugin.
//!
//! What aedes on redis does, measured with paho (docs/sparkplug.md, "Brokers measured"):
//! a message published on one node reaches subscribers on the others, topic
//! unchanged; a retained message published on one node is delivered by the others;
//! the Will of a client of a killed node is sent by another node once the dead node's
//! heartbeat is missed (3 heartbeats of [`AEDES_HEARTBEAT_MS`], checked every 4: 3-7 s;
//! with a workaround in `aedes_node.mjs`, without which a subscriber may drop it as a
//! duplicate).
//!
//! RabbitMQ, three nodes on loopback (`n0@localhost` ..) joined by the
//! classic peer discovery, with an `epmd` of their own on a port of the test's; their
//! data, logs and Erlang cookie in a folder of the caller's. Every process is a child
//! of the test (the nodes run `erl` in the foreground), killed when the cluster is
//! dropped.
//!
//! What it does, measured with paho against 3.10.8 (docs/sparkplug.md, "Server sets"):
//! a QoS 1 message published on one node reaches a QoS 1 subscriber on another, in
//! order, also across the kill of the publisher's node, and a client connects to
//! another node at once after the kill. But retained messages are kept by the node
//! they were published on (a subscriber on another node does not get them), the Will
//! of a client of a killed node is never sent, and a topic's `.` comes back as `/`
//! (MQTT `/` is AMQP `.` inside RabbitMQ, and 3.10 does not map a `.` back), so
//! `spBv1.0/...` reaches subscribers as `spBv1/0/...`.
//! (Debian's other clustered broker, `nats-server` 2.9.10, refuses any topic with a
//! `.`, so every Sparkplug topic.)

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

use super::cli::KillOnDrop;

/// The heartbeat of each aedes node, ms: a node is taken for dead (and its clients'
/// Wills sent by the others) 3 heartbeats after its last.
pub const AEDES_HEARTBEAT_MS: u64 = 1000;

/// How long a cluster may take to form, and each RabbitMQ node to boot after the one
/// before it (RabbitMQ, measured: about 20 s for the three on a 2-core machine; aedes
/// on redis: under 2 s).
const FORM_LIMIT: Duration = Duration::from_secs(90);
/// The nodes of the cluster.
const NODES: usize = 3;
/// Where Debian installs the scripts that run the broker as the calling user
/// (`/usr/sbin/rabbitmq-server` switches to the `rabbitmq` user).
const SCRIPTS: &str = "/usr/lib/rabbitmq/bin";

/// A running three-node aedes cluster on one redis.
#[derive(Debug)]
pub struct AedesCluster {
    nodes: Vec<Option<KillOnDrop>>,
    /// Dropped after the nodes (fields drop in order).
    _redis: KillOnDrop,
    mqtt_ports: Vec<u16>,
}

impl AedesCluster {
    /// The cluster with redis' folder in `folder`; returns once every node listens.
    /// Panics when it cannot start (a test's setup).
    pub fn start(folder: &Path) -> Self {
        let start = Instant::now();
        let redis_port = super::free_port();
        let redis = Command::new("redis-server")
            .args(["--bind", "127.0.0.1", "--port", &redis_port.to_string()])
            // Nothing written to disk: the cluster lives as long as the test.
            .args(["--save", "", "--appendonly", "no", "--dir"])
            .arg(folder)
            .args(["--logfile"])
            .arg(folder.join("redis.log"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .map(KillOnDrop)
            .unwrap_or_else(|e| panic!("redis-server (apt install redis-server): {e}"));
        wait_for_port(redis_port, start, folder);
        let mut nodes = Vec::new();
        let mut mqtt_ports = Vec::new();
        for node in 0..NODES {
            let port = super::free_port();
            let (child, _stdin, lines) = super::json_peer(
                &super::peer("aedes_node.mjs"),
                &[
                    &port.to_string(),
                    &redis_port.to_string(),
                    &format!("n{node}"),
                    &AEDES_HEARTBEAT_MS.to_string(),
                ],
            );
            let left = FORM_LIMIT.saturating_sub(start.elapsed());
            match lines.recv_timeout(left) {
                Ok(ready) => assert_eq!(ready["ready"], true, "{ready}"),
                Err(RecvTimeoutError::Timeout) => panic!("aedes node {node} not ready in {left:?}"),
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("aedes node {node} ended (npm ci --prefix tests/peers)")
                }
            }
            nodes.push(Some(child));
            mqtt_ports.push(port);
        }
        Self {
            nodes,
            _redis: redis,
            mqtt_ports,
        }
    }

    /// The MQTT port of each node.
    pub fn mqtt_ports(&self) -> &[u16] {
        &self.mqtt_ports
    }

    /// Kill node `node` (SIGKILL: its clients' sockets close without a DISCONNECT).
    pub fn kill(&mut self, node: usize) {
        self.nodes[node] = None;
    }

    /// Stop node `node` (SIGSTOP): its port still accepts connections, it answers
    /// nothing until [`resume`](Self::resume).
    pub fn pause(&mut self, node: usize) {
        self.signal(node, "-STOP");
    }

    /// Let node `node` run on (SIGCONT).
    pub fn resume(&mut self, node: usize) {
        self.signal(node, "-CONT");
    }

    fn signal(&self, node: usize, signal: &str) {
        let child = self.nodes[node].as_ref().expect("a running node");
        let sent = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success(), "kill {signal} aedes node {node}");
    }
}

/// A running three-node RabbitMQ cluster.
#[derive(Debug)]
pub struct RabbitCluster {
    nodes: Vec<Option<Child>>,
    epmd: Child,
    mqtt_ports: Vec<u16>,
}

impl RabbitCluster {
    /// The cluster with its files in `folder`; returns once every node accepts MQTT
    /// connections and the first sees all three running. Panics when it cannot start
    /// (a test's setup).
    pub fn start(folder: &Path) -> Self {
        let epmd_port = super::free_port();
        let epmd = Command::new("epmd")
            .args(["-port", &epmd_port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("epmd (apt install rabbitmq-server): {e}"));
        let mqtt_ports: Vec<u16> = (0..NODES).map(|_| super::free_port()).collect();
        let mut cluster = Self {
            nodes: Vec::new(),
            epmd,
            mqtt_ports,
        };
        let start = Instant::now();
        wait_for_port(epmd_port, start, folder);
        let home = folder.join("rabbit-home");
        std::fs::create_dir_all(&home).unwrap();
        let cookie = home.join(".erlang.cookie");
        std::fs::write(&cookie, "millgate-failover-test").unwrap();
        std::fs::set_permissions(&cookie, std::os::unix::fs::PermissionsExt::from_mode(0o400))
            .unwrap();
        std::fs::write(folder.join("enabled_plugins"), "[rabbitmq_mqtt].\n").unwrap();
        let peers: String = (0..NODES)
            .map(|n| {
                format!(
                    "cluster_formation.classic_config.nodes.{} = n{n}@localhost\n",
                    n + 1
                )
            })
            .collect();
        for node in 0..NODES {
            let config = folder.join(format!("rabbit-n{node}.conf"));
            std::fs::write(
                &config,
                format!(
                    "listeners.tcp.default = 127.0.0.1:{amqp}\n\
                     mqtt.listeners.tcp.default = 127.0.0.1:{mqtt}\n\
                     mqtt.allow_anonymous = true\n\
                     cluster_formation.peer_discovery_backend = classic_config\n{peers}",
                    amqp = super::free_port(),
                    mqtt = cluster.mqtt_ports[node],
                ),
            )
            .unwrap();
            let child = rabbit_command(folder, &home, epmd_port, node, "rabbitmq-server")
                .env("RABBITMQ_CONFIG_FILE", &config)
                .env(
                    "RABBITMQ_ENABLED_PLUGINS_FILE",
                    folder.join("enabled_plugins"),
                )
                .env("RABBITMQ_DIST_PORT", super::free_port().to_string())
                .env("RABBITMQ_MNESIA_BASE", folder.join("rabbit-mnesia"))
                .env("RABBITMQ_LOG_BASE", folder.join("rabbit-log"))
                // `erl` in the foreground, in place of the script (no proxy process
                // to outlive a kill), without reading its input.
                .env("RABBITMQ_ALLOW_INPUT", "true")
                .env("RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS", "-noinput")
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap_or_else(|e| panic!("rabbitmq-server (apt install rabbitmq-server): {e}"));
            cluster.nodes.push(Some(child));
            // One node after another: RabbitMQ 3.10's MQTT plugin keeps its client ids
            // in a Raft cluster, and nodes that boot together can each wait for the
            // other's leader, so that no MQTT listener ever opens ("mqtt_node: leader
            // call - leader not known" in every node's log; it failed so under load).
            // A node that boots after the first joins a cluster whose leader is known.
            cluster.wait_for_node(node, Instant::now(), folder);
        }
        let start = Instant::now();
        let left = FORM_LIMIT.saturating_sub(start.elapsed()).as_secs().max(1);
        let formed = rabbit_command(folder, &home, epmd_port, 0, "rabbitmqctl")
            .args([
                "-n",
                "n0@localhost",
                "await_online_nodes",
                &NODES.to_string(),
                "--timeout",
            ])
            .arg((left * 1000).to_string())
            .stdin(Stdio::null())
            .output()
            .expect("rabbitmqctl");
        assert!(
            formed.status.success(),
            "the RabbitMQ cluster did not form: {}\n{}",
            String::from_utf8_lossy(&formed.stderr),
            rabbit_logs(folder)
        );
        // An open port is not yet an MQTT server: after the cluster forms, the MQTT
        // plugin refuses or leaves unanswered the first CONNECTs for a while (a
        // subscriber connecting then timed out in CI).
        for (node, &port) in cluster.mqtt_ports.iter().enumerate() {
            while super::broker::connack(port, &format!("millgate-probe-n{node}")) != Some(0) {
                assert!(
                    start.elapsed() < FORM_LIMIT,
                    "RabbitMQ node n{node} accepts no MQTT session on port {port} within \
                     {FORM_LIMIT:?}\n{}",
                    rabbit_logs(folder)
                );
                std::thread::sleep(Duration::from_millis(200));
            }
        }
        cluster
    }

    /// Wait until node `node` accepts MQTT connections, within [`FORM_LIMIT`] of
    /// `start`; a node that ended is reported at once, with the nodes' logs (the
    /// folder is removed with the test's scratch).
    fn wait_for_node(&mut self, node: usize, start: Instant, folder: &Path) {
        let port = self.mqtt_ports[node];
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            let child = self.nodes[node].as_mut().expect("a started node");
            if let Ok(Some(status)) = child.try_wait() {
                panic!(
                    "RabbitMQ node n{node} ended ({status}) before its MQTT port {port} opened\n{}",
                    rabbit_logs(folder)
                );
            }
            assert!(
                start.elapsed() < FORM_LIMIT,
                "MQTT port {port} of RabbitMQ node n{node} not open within {FORM_LIMIT:?}\n{}",
                rabbit_logs(folder)
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The MQTT port of each node.
    pub fn mqtt_ports(&self) -> &[u16] {
        &self.mqtt_ports
    }

    /// Kill node `node` (SIGKILL: no clean shutdown, no Will for its clients).
    pub fn kill(&mut self, node: usize) {
        if let Some(mut child) = self.nodes[node].take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// `script` of Debian's RabbitMQ for node `node` (`n<node>@localhost`), with the
/// cluster's cookie (in `home`) and epmd, and no system-wide environment file.
fn rabbit_command(
    folder: &Path,
    home: &Path,
    epmd_port: u16,
    node: usize,
    script: &str,
) -> Command {
    let mut command = Command::new(PathBuf::from(SCRIPTS).join(script));
    command
        .env("HOME", home)
        .env("ERL_EPMD_PORT", epmd_port.to_string())
        .env("RABBITMQ_NODENAME", format!("n{node}@localhost"))
        .env("RABBITMQ_CONF_ENV_FILE", "/dev/null")
        .env(
            "RABBITMQ_PID_FILE",
            folder.join(format!("rabbit-n{node}.pid")),
        );
    command
}

/// Wait until loopback `port` accepts connections, within [`FORM_LIMIT`] of `start`.
fn wait_for_port(port: u16, start: Instant, folder: &Path) {
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < FORM_LIMIT,
            "port {port} of the cluster not open within {FORM_LIMIT:?} (logs in {})",
            folder.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The last lines of each RabbitMQ node's log, for a failed start.
fn rabbit_logs(folder: &Path) -> String {
    const LINES: usize = 25;
    let Ok(entries) = std::fs::read_dir(folder.join("rabbit-log")) else {
        return "no RabbitMQ log written".to_owned();
    };
    let mut logs: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
    logs.sort();
    logs.iter()
        .map(|log| {
            let text = std::fs::read_to_string(log).unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            let tail = lines[lines.len().saturating_sub(LINES)..].join("\n");
            format!("--- {} (last {LINES} lines)\n{tail}", log.display())
        })
        .collect::<Vec<_>>()
        .join("\n")
}

impl Drop for RabbitCluster {
    fn drop(&mut self) {
        for node in 0..self.nodes.len() {
            self.kill(node);
        }
        let _ = self.epmd.kill();
        let _ = self.epmd.wait();
    }
}
