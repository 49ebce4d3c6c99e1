//! The test kit: what the end-to-end tests (`tests/tests`), the gateway's integration
//! tests and benches (`gateway/tests`, `gateway/benches`, through a dev-dependency on
//! this crate) and the examples share, in one place.
//!
//! - [`scratch`](mod@scratch): scratch folders (`tempfile`), removed when dropped.
//! - [`net`]: waiting for a condition, loopback ports, HTTP to a running gateway
//!   (its page, its `/metrics`).
//! - [`cli`]: the `millgate` binary run to its end ([`cli::Millgate`]), a child killed
//!   when dropped ([`cli::KillOnDrop`]), SIGTERM as systemd sends it.
//! - [`service`]: the demo's virtual DAQ and PLC ([`service::demo_devices`]); `millgate
//!   run` between them with its configuration and history in a scratch folder
//!   ([`service::Setup`]); the PLC's driveline registers.
//! - [`tandem`]: the reference ramp of the simulated five-stand mill and the
//!   configuration of N stand accelerometers with a tandem mill over them.
//! - [`episode`]: a synthetic chatter episode stored as a capture.
//! - [`broker`], [`sparkplug`]: Debian's mosquitto; a Sparkplug node in-process
//!   against a history holding a backlog. [`cluster`]: a three-node `nats-server`
//!   cluster with MQTT, for the failover tests.
//! - [`peers`]: the Python peers in `tests/peers/`, talking JSON lines; promtool.
//! - [`hostile_daq`]: a scripted Modbus TCP DAQ for the faults real ones show.
//! - [`serial_line`]: a pseudo-terminal pair and a pymodbus RTU device on it.
//! - [`counting_allocator`]: the zero-allocation tests' global allocator.
//!
//! A gateway in-process is `millgate::Service::new(config)?.spawn().await?`;
//! tolerance comparisons are `millgate_dsp::testing`.

pub mod broker;
pub mod cli;
pub mod cluster;
pub mod counting_allocator;
pub mod episode;
pub mod hostile_daq;
pub mod net;
pub mod peers;
pub mod process_plc;
pub mod scratch;
pub mod serial_line;
pub mod service;
pub mod sparkplug;
pub mod tandem;

pub use cli::{hang_up, terminate, text, KillOnDrop, Millgate};
pub use net::{
    connect, free_port, http, http_raw, http_within, metric_line, scrape, try_http,
    until_scraped_at_least, wait_for, web_overview, web_ready, FromSource, HttpAnswer,
};
pub use peers::{json_peer, peer, promtool_passes};
pub use scratch::{fill_file_system, scratch, TempDir};
pub use service::{as_daq_sends, demo_devices, demo_devices_with, Plc, Setup};

use std::path::PathBuf;

/// The repository's root folder.
pub fn repo() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// A small seeded generator for test cases (xorshift64*).
#[derive(Debug, Clone)]
pub struct Seeded(pub u64);

impl Seeded {
    /// The next draw, uniform in [low, high).
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let unit = (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
        low + (high - low) * unit
    }
}
