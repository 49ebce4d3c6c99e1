//! The demo's rig, shared by `millgate demo`, the end-to-end tests and the gateway's
//! benchmarks: the demo configuration (`config/examples/demo.toml`, whose driveline
//! model is the linear Table 2 driveline `sim/models/table2-adjusted.toml`), a rolling
//! schedule simulated from that driveline with a gap opened in the spindles that grows
//! from [`GAP_START_RAD`] to [`GAP_END_RAD`] over the run, as wear does, and a virtual
//! DAQ playing it and a virtual PLC, both on free loopback ports.
//!
//! ```no_run
//! # async fn demo() -> Result<(), millgate_sim::devices::demo::DemoError> {
//! use millgate_sim::devices::demo::{setup, DemoDevices};
//! let mut demo = setup(3.0, 0.5, 7)?;
//! // The gateway's register map decides how many registers the PLC needs.
//! let devices = DemoDevices::start(&mut demo.config, &demo.schedule, 64).await?;
//! // ... run the gateway on `demo.config`, read `devices.plc.holding()` ...
//! devices.stop().await?;
//! # Ok(()) }
//! ```

use std::net::SocketAddr;

use millgate_config::{ChannelSource, Config, ConfigError};
use tokio::net::TcpListener;

use super::modbus_bank::{Running, ServeOptions};
use super::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use super::virtual_plc::VirtualPlc;
use crate::model::{Model, ModelError};
use crate::schedule::{rolling_schedule_with_gap, BarTiming, Schedule, TAIL_OUT_S};

/// The demo's configuration (addresses are replaced by the loopback ports taken at start).
pub(super) const DEMO_CONFIG: &str = include_str!("../../../config/examples/demo.toml");
/// The driveline model: the configuration names it (the gateway's monitoring model),
/// and the virtual DAQ simulates it with the growing gap.
const DEMO_MODEL: &str = include_str!("../../models/table2-adjusted.toml");
/// File name of the model, as `config/examples/demo.toml` names it.
const DEMO_MODEL_FILE: &str = "table2-adjusted.toml";
/// Coupling whose gap opens during the demo: the spindles (C23).
pub const GAP_COUPLING: usize = 1;
/// Opened gap of the first bar, rad.
pub const GAP_START_RAD: f64 = 1.0e-3;
/// Opened gap of the last bar, rad.
pub const GAP_END_RAD: f64 = 3.0e-3;
/// Static torques of successive bars, kN*m: light and heavy passes alternate so the
/// effect of the gap on TAF shows.
const BAR_STATIC_TORQUES_KNM: [f64; 6] = [112.0, 60.0, 150.0, 80.0, 130.0, 45.0];
/// Bars in one cycle of static torques (they repeat; the gap does not).
pub const BARS_PER_CYCLE: usize = BAR_STATIC_TORQUES_KNM.len();
/// Idle and rolling time of each bar.
const BAR_TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// Samples per DAQ block: 50 ms at 2 kHz.
pub const SAMPLES_PER_BLOCK: u16 = 100;

/// Why the demo's rig could not be built or started.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// The bundled demo configuration does not load (a bug of the bundled file).
    #[error("the demo configuration: {0}")]
    Config(#[from] ConfigError),
    /// The bundled model does not load or simulate.
    #[error("the demo model: {0}")]
    Model(#[from] ModelError),
    /// The configuration's first driveline's torque is not a Modbus block channel.
    #[error("the demo's torque channel must be a Modbus block channel")]
    TorqueNotABlock,
    /// The configuration has no `[outputs.plc]` for the virtual PLC.
    #[error("the demo configuration needs outputs.plc")]
    NoPlcOutput,
    /// The configuration lacks what the demo's tandem mill needs (a bug of the bundled
    /// `demo-tandem.toml`).
    #[error("the demo's tandem mill needs {0}")]
    NoTandem(&'static str),
    /// The online tandem mill refused a setting.
    #[error("the demo's tandem mill: {0}")]
    Online(crate::tandem::online::OnlineError),
    /// A loopback port could not be bound, or a device did not stop cleanly.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: &'static str,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// The demo configuration and the schedule the DAQ will play.
#[derive(Debug, Clone)]
pub struct DemoSetup {
    /// The demo configuration: one driveline on a Modbus block channel, a PLC output.
    pub config: Config,
    /// The simulated bars and the truth of each bite.
    pub schedule: Schedule,
}

/// The demo's configuration and a schedule of bars covering `duration_s` (s), with
/// `noise_rms_knm` (kN*m RMS) of Gaussian noise seeded with `seed`. The bundled model
/// is written to `millgate-demo` in the system's temporary folder, where the
/// configuration's `model` finds it.
pub fn setup(duration_s: f64, noise_rms_knm: f64, seed: u64) -> Result<DemoSetup, DemoError> {
    setup_from(DEMO_CONFIG, duration_s, noise_rms_knm, seed)
}

/// [`setup`] on the configuration `text` (the demo's, extended).
pub(super) fn setup_from(
    text: &str,
    duration_s: f64,
    noise_rms_knm: f64,
    seed: u64,
) -> Result<DemoSetup, DemoError> {
    let folder = write_model()?;
    let config = millgate_config::from_toml_str(text, "demo.toml", &folder)?;
    let mut model = Model::from_toml_str(DEMO_MODEL, DEMO_MODEL_FILE)?;
    let torque = &config.channels[config.drivelines[0].torque];
    model.measurement.sample_rate = torque.sample_rate_hz;
    let bar_s = BAR_TIMING.idle_s + BAR_TIMING.rolling_s + TAIL_OUT_S;
    let bars = (duration_s / bar_s).ceil() as usize + 1;
    let torques: Vec<f64> = BAR_STATIC_TORQUES_KNM
        .iter()
        .copied()
        .cycle()
        .take(bars)
        .collect();
    let gaps: Vec<f64> = (0..bars)
        .map(|k| {
            let progress = k as f64 / (bars - 1).max(1) as f64;
            GAP_START_RAD + (GAP_END_RAD - GAP_START_RAD) * progress
        })
        .collect();
    let schedule = rolling_schedule_with_gap(
        &model,
        &torques,
        BAR_TIMING,
        noise_rms_knm,
        seed,
        GAP_COUPLING,
        &gaps,
    )?;
    Ok(DemoSetup { config, schedule })
}

/// Writes the bundled model into the demo's folder (a temporary file renamed into
/// place: demos and tests may run at once); returns the folder.
fn write_model() -> Result<std::path::PathBuf, DemoError> {
    let io = |what| move |source| DemoError::Io { what, source };
    let folder = std::env::temp_dir().join("millgate-demo");
    std::fs::create_dir_all(&folder).map_err(io("creating the demo's folder"))?;
    static WRITES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let write = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let temporary = folder.join(format!(
        "{DEMO_MODEL_FILE}.{}-{write}.tmp",
        std::process::id()
    ));
    std::fs::write(&temporary, DEMO_MODEL).map_err(io("writing the demo's model"))?;
    std::fs::rename(&temporary, folder.join(DEMO_MODEL_FILE))
        .map_err(io("writing the demo's model"))?;
    Ok(folder)
}

/// The virtual DAQ that plays `schedule` on the first driveline's torque channel of
/// `config` (a Modbus block channel), in blocks of [`SAMPLES_PER_BLOCK`].
pub fn demo_daq(config: &Config, schedule: &Schedule) -> Result<VirtualDaq, DemoError> {
    let torque = &config.channels[config.drivelines[0].torque];
    let ChannelSource::ModbusBlock { table, base, .. } = torque.source else {
        return Err(DemoError::TorqueNotABlock);
    };
    let channel = DaqChannel {
        placement: Placement {
            table,
            address: base,
            scale: torque.scale,
            offset: torque.offset,
        },
        publish: Publish::Block,
        signal: schedule.torque_knm.clone(),
    };
    Ok(VirtualDaq::new(
        torque.sample_rate_hz,
        SAMPLES_PER_BLOCK,
        vec![channel],
    ))
}

/// The virtual DAQ and PLC of the demo, running on loopback.
#[derive(Debug)]
pub struct DemoDevices {
    /// The PLC the gateway writes; read its registers with [`VirtualPlc::holding`].
    pub plc: VirtualPlc,
    running: [Running; 2],
}

impl DemoDevices {
    /// Starts a virtual DAQ playing `schedule` and a virtual PLC of `plc_registers`
    /// holding registers on free loopback ports, and points `config`'s first Modbus
    /// source and its PLC output (register base 0) at them; the HMI server, when
    /// configured, binds a free loopback port too.
    pub async fn start(
        config: &mut Config,
        schedule: &Schedule,
        plc_registers: usize,
    ) -> Result<Self, DemoError> {
        let daq = demo_daq(config, schedule)?;
        Self::start_with(config, daq, plc_registers).await
    }

    /// As [`DemoDevices::start`], with the caller's DAQ (a rig of its own, such as
    /// [`demo_daq`] on another schedule, [`VirtualDaq::looped`]).
    pub async fn start_with(
        config: &mut Config,
        daq: VirtualDaq,
        plc_registers: usize,
    ) -> Result<Self, DemoError> {
        let io = |what| move |source| DemoError::Io { what, source };
        let plc = VirtualPlc::new(plc_registers);
        let daq_listener = TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(io("binding the virtual DAQ"))?;
        let plc_listener = TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(io("binding the virtual PLC"))?;
        let local = |listener: &TcpListener| listener.local_addr().map_err(io("a local address"));
        config.modbus_sources[0].address = local(&daq_listener)?.to_string();
        let plc_output = config.outputs.plc.as_mut().ok_or(DemoError::NoPlcOutput)?;
        plc_output.address = local(&plc_listener)?.to_string();
        plc_output.register_base = 0;
        if let Some(server) = config.outputs.server.as_mut() {
            server.bind = SocketAddr::from(([127, 0, 0, 1], 0));
        }
        let running = [
            daq.spawn(daq_listener, ServeOptions::default()),
            plc.spawn(plc_listener, ServeOptions::default()),
        ];
        Ok(Self { plc, running })
    }

    /// Stops both devices.
    pub async fn stop(self) -> Result<(), DemoError> {
        for device in self.running {
            device.stop().await.map_err(|source| DemoError::Io {
                what: "stopping a virtual device",
                source,
            })?;
        }
        Ok(())
    }
}
