//! The demo's tandem mill (`millgate demo` without `--no-tandem`): the five stands of
//! the project's tandem model ([`PassSchedule::example`]) simulated online in real
//! time ([`super::tandem_rig`]), their chock accelerations streamed by a second virtual
//! DAQ, a weld passing the stands early in the run and the operator's ramp past the
//! critical speed once the weld hold is over. The demo's virtual PLC is the mill's
//! PLC: its weld-tracking bit sits in one of its holding registers (the
//! configuration's `weld_in_mill` tag, `config/examples/demo-tandem.toml`), which the
//! gateway reads over Modbus TCP as it reads a plant's, and its program reads the
//! slow-down request from the registers the gateway writes and slows the mill.
//!
//! The script ([`TandemScript`]): rolling at [`START_OF_CRITICAL`] of the critical
//! speed; the weld in the mill from [`WELD_AT_S`] for [`WELD_S`] (the force noise
//! [`WELD_FACTOR`] times louder, the weld bit 1); the operator's setpoint at
//! [`SETPOINT_OF_CRITICAL`] of the critical speed, approached at [`RAMP_ACCEL_M_S2`],
//! once the mill's weld hold (`weld_settle_s`) after the weld is over.

use millgate_config::{ChannelSource, Config, RegisterTable};
use tokio::net::TcpListener;

use super::demo::{setup_from, DemoError, DemoSetup, DEMO_CONFIG};
use super::modbus_bank::{Running, ServeOptions};
use super::tandem_rig::{self, RequestBit, RigError, RigRun};
use super::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use super::virtual_plc::VirtualPlc;
use crate::tandem::control::{SlowDownPolicy, SpeedControl};
use crate::tandem::online::OnlineMill;
use crate::tandem::simulate::{Accelerometer, Excitation, NoiseBurst, SimulationSetup, SpeedRange};
use crate::tandem::{PassSchedule, TandemMill};

/// The tandem part of the demo's configuration, appended to `demo.toml`.
pub const DEMO_TANDEM_CONFIG: &str = include_str!("../../../config/examples/demo-tandem.toml");
/// The source of the stand accelerometers in [`DEMO_TANDEM_CONFIG`].
const STAND_SOURCE: &str = "stand_daq";
/// The mill PLC's source (the weld bit) in [`DEMO_TANDEM_CONFIG`].
const PLC_SOURCE: &str = "mill_plc";
/// The weld-tracking tag's channel in [`DEMO_TANDEM_CONFIG`].
const WELD_CHANNEL: &str = "weld_in_mill";
/// Samples per DAQ block and PLC cycle: 48 ms at the stands' 2500 Hz.
pub const CYCLE_SAMPLES: usize = 120;
/// Speed at the start, a fraction of the critical speed: stable, the closed loop's
/// highest allowed speed (`tests/src/experiments/chatter_loop`).
pub const START_OF_CRITICAL: f64 = 0.95;
/// When the weld reaches the first stand, s after the start.
pub const WELD_AT_S: f64 = 2.0;
/// Time from the weld reaching the first stand to it leaving the last, s.
pub const WELD_S: f64 = 4.0;
/// Factor on the force noise while the weld is in the mill (the closed loop's welds
/// draw 2-4): with it the gain ratio passed 1 after the weld in each of seeds 1, 2, 3
/// and 7 (4-13 windows held off).
pub const WELD_FACTOR: f64 = 4.0;
/// The operator's setpoint after the weld, a fraction of the critical speed (past it).
pub const SETPOINT_OF_CRITICAL: f64 = 1.3;
/// The operator's acceleration to it, m/s^2.
pub const RAMP_ACCEL_M_S2: f64 = 2.0;

/// As [`super::demo::setup`], with the demo's tandem mill ([`DEMO_TANDEM_CONFIG`]
/// appended to the configuration).
pub fn setup_with_tandem(
    duration_s: f64,
    noise_rms_knm: f64,
    seed: u64,
) -> Result<DemoSetup, DemoError> {
    let text = format!("{DEMO_CONFIG}\n{DEMO_TANDEM_CONFIG}");
    setup_from(&text, duration_s, noise_rms_knm, seed)
}

/// The critical speed of [`PassSchedule::example`] as a factor on its roll speeds
/// (`truth::mill_critical_speed`, to 1e-3; a test recomputes it): the search takes
/// most of a second, which the demo's start-up does not spend.
const CRITICAL_SPEED_FACTOR: f64 = 1.098046875;

/// When what happens in the demo's tandem mill, and its speeds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TandemScript {
    /// The mill's critical speed (last stand's exit strip speed), m/s.
    pub critical_m_s: f64,
    /// Speed at the start, m/s.
    pub start_m_s: f64,
    /// The weld.
    pub weld: NoiseBurst,
    /// When the operator raises the setpoint, s: the weld hold is over.
    pub ramp_at_s: f64,
    /// The operator's setpoint from then, m/s.
    pub setpoint_m_s: f64,
}

impl TandemScript {
    /// Whether the PLC's weld bit is set at `t_s`.
    pub fn weld_in_mill(&self, t_s: f64) -> bool {
        (self.weld.time_s..self.weld.time_s + self.weld.duration_s).contains(&t_s)
    }
}

/// What the mill does at one PLC cycle (for the demo's console).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TandemMoment {
    /// Simulated time (wall time since the rig started, within a cycle), s.
    pub t_s: f64,
    /// Exit strip speed, m/s.
    pub speed_m_s: f64,
    /// The operator's setpoint, m/s.
    pub setpoint_m_s: f64,
    /// The PLC's weld bit.
    pub weld: bool,
    /// The slow-down request as the PLC read it for this cycle.
    pub request: bool,
}

/// The demo's tandem mill, its DAQ serving on loopback: [`TandemDemo::run`] runs it.
#[derive(Debug)]
pub struct TandemDemo {
    mill: OnlineMill,
    script: TandemScript,
    daq: VirtualDaq,
    plc: VirtualPlc,
    weld_register: usize,
    request: RequestBit,
}

/// The mill of [`PassSchedule::example`], its critical speed and the script of a run
/// whose weld hold lasts `weld_settle_s` after the weld.
pub fn tandem_mill(weld_settle_s: f64) -> Result<(TandemMill, TandemScript), DemoError> {
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    let critical_m_s = CRITICAL_SPEED_FACTOR * mill.exit_speed(mill.stands().len() - 1, 1.0);
    let script = TandemScript {
        critical_m_s,
        start_m_s: START_OF_CRITICAL * critical_m_s,
        weld: NoiseBurst {
            time_s: WELD_AT_S,
            duration_s: WELD_S,
            factor: WELD_FACTOR,
            stand: None,
        },
        ramp_at_s: WELD_AT_S + WELD_S + weld_settle_s,
        setpoint_m_s: SETPOINT_OF_CRITICAL * critical_m_s,
    };
    Ok((mill, script))
}

/// The demo's tandem mill built, before its DAQ serves ([`TandemDemo::start`]): the
/// simulation's set-up (the critical speed, the mill's discretisation) takes a moment,
/// done before the driveline's DAQ starts streaming.
#[derive(Debug)]
pub struct PreparedTandem {
    mill: OnlineMill,
    script: TandemScript,
    placements: Vec<Placement>,
    sample_rate_hz: f64,
}

impl PreparedTandem {
    /// The mill of `config`'s first tandem mill (the demo's, [`DEMO_TANDEM_CONFIG`]) with
    /// noise seeded by `seed`.
    pub fn new(config: &Config, seed: u64) -> Result<Self, DemoError> {
        let tandem = config
            .tandem_mills
            .first()
            .ok_or(DemoError::NoTandem("a tandem mill"))?;
        let mut placements = Vec::new();
        for &stand in &tandem.stands {
            let channel = &config.channels[stand];
            let ChannelSource::ModbusBlock { table, base, .. } = channel.source else {
                return Err(DemoError::NoTandem("the stands on Modbus block channels"));
            };
            placements.push(Placement {
                table,
                address: base,
                scale: channel.scale,
                offset: channel.offset,
            });
        }
        let sample_rate_hz = config.channels[tandem.stands[0]].sample_rate_hz;
        let (mill, script) = tandem_mill(tandem.weld_settle_s)?;
        let policy = SlowDownPolicy {
            accel_m_s2: RAMP_ACCEL_M_S2,
            ..SlowDownPolicy::default()
        };
        let control = SpeedControl::new(policy, script.start_m_s, script.start_m_s)
            .map_err(|e| DemoError::Online(e.into()))?;
        let setup = SimulationSetup {
            excitation: Excitation {
                noise_bursts: vec![script.weld],
                ..Excitation::default()
            },
            sensor: Accelerometer {
                sample_rate_hz,
                ..Accelerometer::default()
            },
            seed,
            internal_rate_hz: None,
            speeds: SpeedRange {
                lowest: 1.0,
                highest: 1.0,
            },
        };
        let mill = OnlineMill::new(&mill, &setup, control, CYCLE_SAMPLES, script.setpoint_m_s)
            .map_err(DemoError::Online)?;
        Ok(Self {
            mill,
            script,
            placements,
            sample_rate_hz,
        })
    }
}

impl TandemDemo {
    /// Serves `prepared`'s stand DAQ on a free loopback port, and points `config`'s
    /// stand source there and its PLC source at `plc` (the demo's virtual PLC, at
    /// `config`'s PLC output address: start [`super::demo::DemoDevices`] first). The
    /// PLC program reads the slow-down request from bit 3 of holding register
    /// `flags_register` (the mill's `flags` in the gateway's register map). Returns the
    /// mill and its serving DAQ (stop it after the gateway: the DAQ keeps answering
    /// with its last block once the run is over).
    pub async fn start(
        prepared: PreparedTandem,
        config: &mut Config,
        plc: &VirtualPlc,
        flags_register: usize,
    ) -> Result<(Self, Running), DemoError> {
        let io = |what| move |source| DemoError::Io { what, source };
        let source_index = |name: &str| {
            config
                .modbus_sources
                .iter()
                .position(|s| s.name == name)
                .ok_or(DemoError::NoTandem(
                    "a modbus source named stand_daq and mill_plc",
                ))
        };
        let (stands_at, plc_at) = (source_index(STAND_SOURCE)?, source_index(PLC_SOURCE)?);
        let weld_register = config
            .channels
            .iter()
            .find(|c| c.name == WELD_CHANNEL)
            .and_then(|c| match c.source {
                ChannelSource::ModbusValue {
                    table: RegisterTable::Holding,
                    address,
                    ..
                } => Some(usize::from(address)),
                _ => None,
            })
            .filter(|&address| address < plc.holding().len() && address != flags_register)
            .ok_or(DemoError::NoTandem(
                "the weld_in_mill tag in a holding register of the PLC",
            ))?;
        let PreparedTandem {
            mill,
            script,
            placements,
            sample_rate_hz,
        } = prepared;
        let channels = placements
            .into_iter()
            .map(|placement| DaqChannel {
                placement,
                publish: Publish::Block,
                signal: Vec::new(),
            })
            .collect::<Vec<_>>();
        let stands = channels.len();
        let mut daq = VirtualDaq::new(sample_rate_hz, CYCLE_SAMPLES as u16, channels);
        // A DAQ answers with a block from power-up: the first, at rest.
        let rest = vec![0.0; CYCLE_SAMPLES];
        daq.publish(&vec![rest.as_slice(); stands]);
        let listener = TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(io("binding the stands' virtual DAQ"))?;
        config.modbus_sources[stands_at].address = listener
            .local_addr()
            .map_err(io("a local address"))?
            .to_string();
        let plc_address = config
            .outputs
            .plc
            .as_ref()
            .ok_or(DemoError::NoPlcOutput)?
            .address
            .clone();
        config.modbus_sources[plc_at].address = plc_address;
        let serving = daq.serve(listener, ServeOptions::default());
        let demo = Self {
            mill,
            script,
            daq,
            plc: plc.clone(),
            weld_register,
            request: RequestBit {
                plc: plc.clone(),
                register: flags_register,
                bit: SLOW_DOWN_BIT,
            },
        };
        Ok((demo, serving))
    }

    /// The run's script.
    pub fn script(&self) -> TandemScript {
        self.script
    }

    /// Length of a PLC cycle, s.
    pub fn cycle_s(&self) -> f64 {
        self.mill.cycle_s()
    }

    /// Runs the mill for `cycles` PLC cycles in real time: the weld bit and the
    /// operator's setpoint as the script says, the PLC obeying the slow-down request;
    /// `moment` gets each cycle's state.
    pub async fn run(
        mut self,
        cycles: usize,
        mut moment: impl FnMut(TandemMoment),
    ) -> Result<RigRun, RigError> {
        let script = self.script;
        let (plc, weld_register) = (self.plc.clone(), self.weld_register);
        let request = self.request.clone();
        let daq = &mut self.daq;
        tandem_rig::run(
            &mut self.mill,
            &request,
            cycles,
            |t_s, control: &mut SpeedControl| {
                let weld = script.weld_in_mill(t_s);
                if let Some(word) = plc.bank().lock().holding.get_mut(weld_register) {
                    *word = u16::from(weld);
                }
                if t_s >= script.ramp_at_s {
                    control.set_setpoint(script.setpoint_m_s);
                }
                moment(TandemMoment {
                    t_s,
                    speed_m_s: control.speed_m_s(),
                    setpoint_m_s: control.setpoint_m_s(),
                    weld,
                    request: request.read(),
                });
            },
            async |samples| {
                let blocks: Vec<&[f64]> = samples.acceleration.iter().map(Vec::as_slice).collect();
                daq.publish(&blocks);
                Ok(())
            },
        )
        .await
    }
}

/// The slow-down request: bit 3 of the mill's flags register.
const SLOW_DOWN_BIT: u16 = 3;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tandem::truth::mill_critical_speed;

    #[test]
    fn the_demo_s_critical_speed_is_the_schedule_s() {
        let mill = TandemMill::new(&PassSchedule::example().expect("example")).expect("mill");
        let critical = mill_critical_speed(&mill).expect("critical speed");
        assert_eq!(critical.speed, CRITICAL_SPEED_FACTOR);
    }
}
