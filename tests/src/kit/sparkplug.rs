//! A Sparkplug edge node run in-process against a history file holding a backlog:
//! shared by gateway/tests/sparkplug.rs and gateway/benches/sparkplug.rs (the broker
//! is [`super::broker::Broker`]).

use std::path::Path;
use std::sync::Arc;

use millgate::outputs::sparkplug::{forward, next_bd_seq, SparkplugNode};
use millgate::state::board::Board;
use millgate_config::Config;

/// The demo's configuration (one driveline, F1) with `[outputs.mqtt]` on
/// `127.0.0.1:port` as `<group>/f1` and the history at `history`; `extra` goes into
/// `[outputs.mqtt]` (pacing keys).
pub fn node_config(port: u16, group: &str, history: &Path, extra: &str) -> Config {
    let repo = super::repo();
    let text = std::fs::read_to_string(repo.join("config/examples/demo.toml")).unwrap()
        + &format!(
            "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"{group}\"\n\
             node_id = \"f1\"\nkeep_alive_s = 5\n{extra}\n\n[history]\npath = \"{}\"\n",
            history.display()
        );
    // The example's model path is relative to its folder; the model is in sim/models.
    millgate_config::from_toml_str(&text, "demo.toml", &repo.join("sim/models"))
        .unwrap_or_else(|error| panic!("{error}"))
}

/// A new history file at `path` with `count` bites of driveline F1 (bite counters
/// 1..=count, 10 ms apart from 2026-01-01T00:00:00.010Z) and the replay cursor of
/// node `<group>/f1` before the first: all of them are its backlog.
pub fn write_backlog(path: &Path, group: &str, count: u32) {
    let connection = millgate::history::writer::connect(path).unwrap();
    connection
        .execute(
            "INSERT INTO gateway_runs (id, started_at, version, config_name)
             VALUES (1, '2026-01-01T00:00:00.000Z', 'backlog', 'demo')",
            [],
        )
        .unwrap();
    connection
        .execute(
            "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < ?1)
             INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, quality, degraded)
             SELECT 1, 'F1', strftime('%Y-%m-%dT%H:%M:%fZ', 1767225600 + i / 100.0, 'unixepoch'),
                 i, 'spindle_top', 400.0 + i % 50, (400.0 + i % 50) * 1.3, 1.3, 'good', 0
             FROM n",
            [count],
        )
        .unwrap();
    drop(connection);
    let node = format!("{group}/f1");
    next_bd_seq(path, &node).unwrap();
    forward::store_cursor(path, &node, 0).unwrap();
}

/// The node of `config` started on the current tokio runtime; trigger the returned
/// handle to stop it.
pub fn start_node(
    config: &Config,
) -> (
    millgate::shutdown::ShutdownTrigger,
    Arc<millgate::outputs::sparkplug::SparkplugStatus>,
    tokio::task::JoinHandle<()>,
) {
    let board = Arc::new(Board::new(config, Vec::new()));
    let history = config.history.as_ref().unwrap().path.clone();
    let node = SparkplugNode::new(config.outputs.mqtt.clone().unwrap(), history, board)
        .unwrap_or_else(|error| panic!("{error}"));
    let status = node.status();
    let (trigger, shutdown) = millgate::shutdown::channel();
    (trigger, status, tokio::spawn(node.run(shutdown)))
}
