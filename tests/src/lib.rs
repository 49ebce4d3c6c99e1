//! Test support for millgate, in one place: the demo's devices sized for a
//! configuration ([`demo_devices`]), waiting for a condition ([`wait_for`]), scraping
//! `/metrics` ([`scrape`]), a scripted hostile DAQ ([`hostile_daq`]), the counting
//! allocator of the zero-allocation tests ([`counting_allocator`]), the chatter
//! detectors' race ([`chatter_eval`]) and the chatter closed loop offline
//! ([`chatter_loop`]: the online tandem mill and its automation with the gateway's own
//! monitor fed each block, the runs of the README's closed-loop table; the real-time
//! runs through the service are `tests/chatter_loop_e2e.rs` over Modbus and
//! `tests/vcan.rs` over CAN, on `millgate_sim::devices::tandem_rig`). A running gateway
//! is started with `millgate::Service::new(config)?.spawn().await?`
//! ([`millgate::Service::spawn`]); tolerance comparisons are `millgate_dsp::testing`.

pub mod counting_allocator;
pub mod hostile_daq;

pub mod chatter_eval;
pub mod chatter_loop;

use std::time::{Duration, Instant};

use millgate::outputs::register_map::RegisterMap;
use millgate_config::Config;
use millgate_sim::devices::demo::DemoDevices;
use millgate_sim::schedule::Schedule;

/// The demo's virtual DAQ playing `schedule` and a virtual PLC holding `config`'s whole
/// register map, started on loopback; `config` is pointed at them
/// ([`DemoDevices::start`]).
pub async fn demo_devices(config: &mut Config, schedule: &Schedule) -> anyhow::Result<DemoDevices> {
    let plc_registers = usize::from(RegisterMap::new(config).len()) + 16;
    Ok(DemoDevices::start(config, schedule, plc_registers).await?)
}

/// Poll `done` every 20 ms until it holds; panic naming `what` after `limit`.
pub async fn wait_for(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// `GET path` over a new connection that the answer closes; the whole answer (status
/// line, headers, body) once it is 200 OK.
async fn get(address: std::net::SocketAddr, path: &str) -> anyhow::Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(address).await?;
    stream
        .write_all(
            format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )
        .await?;
    let mut response = String::new();
    stream.read_to_string(&mut response).await?;
    anyhow::ensure!(
        response.starts_with("HTTP/1.1 200 OK"),
        "{path}: {response}"
    );
    Ok(response)
}

/// The maintenance page's `/api/overview` at `address`, as JSON.
pub async fn web_overview(address: std::net::SocketAddr) -> anyhow::Result<serde_json::Value> {
    let response = get(address, "/api/overview").await?;
    let body = response.split("\r\n\r\n").nth(1).unwrap_or_default();
    Ok(serde_json::from_str(body)?)
}

/// GET /metrics over a plain TCP connection, as Prometheus does; checks the status and
/// that every metric family's samples sit in one block after its `# TYPE` line (the
/// exposition format's rule, which strict parsers enforce).
pub async fn scrape(address: std::net::SocketAddr) -> anyhow::Result<String> {
    let response = get(address, "/metrics").await?;
    let body = response.split("\r\n\r\n").nth(1).unwrap_or_default();
    let mut seen = std::collections::HashSet::new();
    let mut current = "";
    for line in body.lines().filter(|l| !l.is_empty()) {
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            current = rest.split(' ').next().unwrap_or_default();
            anyhow::ensure!(seen.insert(current.to_owned()), "family {current} twice");
        } else if !line.starts_with('#') {
            let name = line.split(['{', ' ']).next().unwrap_or_default();
            anyhow::ensure!(name == current, "sample {line:?} outside its family block");
        }
    }
    Ok(response)
}
