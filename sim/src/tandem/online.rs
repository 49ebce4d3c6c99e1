//! A tandem mill simulated online, one PLC cycle at a time: the speed automation
//! ([`super::control::SpeedControl`]) reads the slow-down request and moves the speed,
//! then the physics ([`super::simulate::Simulation`]) runs the cycle at that speed (at
//! the automation's rate until its new speed, `control::SpeedSegment`), with the
//! truth kept on the way: the chatter amplitude (the largest interstand tension swing
//! over its developed limit, `truth::tension_swing`) and when chatter first
//! developed.

use super::control::{PolicyError, SpeedControl};
use super::linear::TandemMill;
use super::simulate::{Record, RunError, Simulation, SimulationSetup, SpeedRange};
use super::truth::{first_developed, tension_swing};

/// Why an online mill cannot be built or run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OnlineError {
    /// The simulation refused a setting or failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The automation refused a setting.
    #[error(transparent)]
    Policy(#[from] PolicyError),
    /// A cycle must hold at least one sample.
    #[error("cycle_samples: 0 is not allowed (must be >= 1)")]
    Cycle,
}

/// What one PLC cycle did to the mill.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleTruth {
    /// Time at the cycle's end, s.
    pub time_s: f64,
    /// Exit speed at the cycle's end, m/s.
    pub speed_m_s: f64,
    /// The chatter amplitude over the cycle: largest tension swing / developed limit.
    pub swing: f64,
}

/// A tandem mill whose speed its automation sets while it runs (see the module docs).
#[derive(Debug)]
pub struct OnlineMill {
    simulation: Simulation,
    control: SpeedControl,
    /// Exit speed at speed factor 1, m/s.
    unit_m_s: f64,
    sample_rate_hz: f64,
    /// Output samples per cycle.
    pub(crate) cycle_samples: usize,
    developed_s: Option<f64>,
}

impl OnlineMill {
    /// `mill` under `setup`, its speed set by `control` every `cycle_samples` output
    /// samples. `setup.speeds` is replaced by `OnlineMill::speed_range` up to
    /// `top_speed_m_s` (the highest setpoint the run will see).
    pub fn new(
        mill: &TandemMill,
        setup: &SimulationSetup,
        control: SpeedControl,
        cycle_samples: usize,
        top_speed_m_s: f64,
    ) -> Result<OnlineMill, OnlineError> {
        if cycle_samples == 0 {
            return Err(OnlineError::Cycle);
        }
        let unit_m_s = mill.exit_speed(mill.stands().len() - 1, 1.0);
        let setup = SimulationSetup {
            speeds: Self::speed_range(&control, top_speed_m_s, unit_m_s),
            ..setup.clone()
        };
        Ok(OnlineMill {
            simulation: Simulation::new(mill, &setup)?,
            control,
            unit_m_s,
            sample_rate_hz: setup.sensor.sample_rate_hz,
            cycle_samples,
            developed_s: None,
        })
    }

    /// The speed factors `control` can reach with setpoints up to `top_speed_m_s`:
    /// from its floor (or its speed now, if lower) to the top (or its speed now).
    pub(crate) fn speed_range(
        control: &SpeedControl,
        top_speed_m_s: f64,
        unit_m_s: f64,
    ) -> SpeedRange {
        let speed = control.speed_m_s();
        SpeedRange {
            lowest: control.policy().min_speed_m_s.min(speed) / unit_m_s,
            highest: top_speed_m_s.max(speed).max(control.setpoint_m_s()) / unit_m_s,
        }
    }

    /// The automation.
    pub fn control(&self) -> &SpeedControl {
        &self.control
    }

    /// The automation, to change the operator's setpoint (within the top speed).
    pub fn control_mut(&mut self) -> &mut SpeedControl {
        &mut self.control
    }

    /// Length of a cycle, s.
    pub fn cycle_s(&self) -> f64 {
        self.cycle_samples as f64 / self.sample_rate_hz
    }

    /// Time simulated, s.
    pub fn time_s(&self) -> f64 {
        self.simulation.time_s()
    }

    /// When an interstand tension first swung past its developed limit, s.
    pub fn developed_s(&self) -> Option<f64> {
        self.developed_s
    }

    /// An empty record for the mill's output.
    pub fn record(&self, samples: usize) -> Record {
        self.simulation.record(samples)
    }

    /// One PLC cycle with the slow-down `request` as the automation reads it at the
    /// cycle's start; the cycle's samples are appended to `record`.
    pub fn cycle(&mut self, request: bool, record: &mut Record) -> Result<CycleTruth, OnlineError> {
        let from = record.len();
        let t0 = self.simulation.time_s();
        let dt = self.cycle_s();
        let segment = self.control.step(dt, request);
        let unit = self.unit_m_s;
        self.simulation
            .advance(self.cycle_samples, |t| segment.at(t - t0) / unit, record)?;
        let mill = self.simulation.mill();
        let swing = tension_swing(mill, record, from..record.len());
        if self.developed_s.is_none() {
            self.developed_s = first_developed(mill, record, from..record.len())
                .map(|k| t0 + (k - from) as f64 / self.sample_rate_hz);
        }
        Ok(CycleTruth {
            time_s: t0 + dt,
            speed_m_s: segment.to_m_s,
            swing,
        })
    }
}
