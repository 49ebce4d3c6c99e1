//! Python and Node.js peers: clients, hosts and readers that are not ours (paho-mqtt's
//! Sparkplug host, asyncua's and node-opcua's OPC UA clients, pymodbus' PLC and
//! devices, pyarrow and numpy readers), kept in `tests/peers/` ([`peer`]);
//! [`json_peer`] runs one that talks JSON lines. Prometheus' linter checks a
//! `/metrics` page ([`promtool_passes`]).

use std::path::{Path, PathBuf};
use std::process::{ChildStdin, Command, Stdio};
use std::sync::mpsc::Receiver;

use super::cli::KillOnDrop;

/// The peer script `name` (`sparkplug_host.py`) in `tests/peers/`.
pub fn peer(name: &str) -> PathBuf {
    let path = super::repo().join("tests/peers").join(name);
    assert!(path.is_file(), "no peer {}", path.display());
    path
}

/// `python3 script args` (`node script args` for a `.mjs` script; `script` a path,
/// [`peer`]): the child (killed when dropped), its stdin for commands and its
/// stdout's JSON lines, read on a thread.
pub fn json_peer(
    script: &Path,
    args: &[&str],
) -> (KillOnDrop, ChildStdin, Receiver<serde_json::Value>) {
    use std::io::BufRead;
    let interpreter = match script.extension().and_then(|e| e.to_str()) {
        Some("mjs") => "node",
        _ => "python3",
    };
    let mut child = Command::new(interpreter)
        .arg(script)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap_or_else(|error| panic!("{interpreter}: {error}"));
    let stdin = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            let value: serde_json::Value =
                serde_json::from_str(&line).unwrap_or_else(|e| panic!("peer line {line:?}: {e}"));
            if tx.send(value).is_err() {
                break;
            }
        }
    });
    (KillOnDrop(child), stdin, lines)
}

/// `promtool check metrics` (Debian's `prometheus`, which `scripts/test` installs)
/// finds no problem in `page` (an HTTP answer, whose body is checked, or a body).
pub fn promtool_passes(page: &str) {
    use std::io::Write;
    let body = page.split_once("\r\n\r\n").map_or(page, |(_, body)| body);
    let mut promtool = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool is not installed: scripts/test installs it (apt-get install prometheus)");
    promtool
        .stdin
        .take()
        .unwrap()
        .write_all(body.as_bytes())
        .unwrap();
    let output = promtool.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "promtool check metrics: {}{}\n{body}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}
