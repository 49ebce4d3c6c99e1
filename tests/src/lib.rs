//! Test support for millgate, in one place: the demo's devices sized for a
//! configuration ([`demo_devices`]), waiting for a condition ([`wait_for`]), HTTP to a
//! running gateway ([`net`], shared with `gateway/tests`), scraping `/metrics`
//! ([`scrape`]), a scripted hostile DAQ ([`hostile_daq`]), a serial line with a
//! pymodbus RTU device on it ([`serial_line`]), the counting allocator of the
//! zero-allocation tests ([`counting_allocator`]), the chatter detectors' race
//! ([`chatter_eval`]) and the chatter closed loop offline ([`chatter_loop`]: the online
//! tandem mill and its automation with the gateway's own monitor fed each block, the
//! runs of the README's closed-loop table; the real-time runs through the service are
//! `tests/chatter_loop_e2e.rs` over Modbus and `tests/vcan.rs` over CAN, on
//! `millgate_sim::devices::tandem_rig`). A running gateway is started with
//! `millgate::Service::new(config)?.spawn().await?` ([`millgate::Service::spawn`]);
//! tolerance comparisons are `millgate_dsp::testing`.

pub mod counting_allocator;
pub mod hostile_daq;
pub mod serial_line;

pub mod chatter_eval;
pub mod chatter_loop;

// Shared with the gateway's integration tests (`gateway/tests/common` includes the file).
pub mod net;
pub use net::until as wait_for;

use millgate::outputs::modbus::register_map::RegisterMap;
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

/// The maintenance page's `/api/overview` at `address`, as JSON.
pub async fn web_overview(address: std::net::SocketAddr) -> anyhow::Result<serde_json::Value> {
    let answer = net::http(address, "GET", "/api/overview").await;
    anyhow::ensure!(answer.status == 200, "/api/overview: {}", answer.body);
    Ok(serde_json::from_str(&answer.body)?)
}

/// GET /metrics as Prometheus does; checks the status and that every metric family's
/// samples sit in one block after its `# TYPE` line ([`net::exposition_blocks`]).
pub async fn scrape(address: std::net::SocketAddr) -> anyhow::Result<String> {
    let answer = net::http(address, "GET", "/metrics").await;
    anyhow::ensure!(answer.status == 200, "/metrics: {}", answer.body);
    net::exposition_blocks(&answer.body).map_err(anyhow::Error::msg)?;
    Ok(answer.body)
}
