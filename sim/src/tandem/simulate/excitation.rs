//! The excitation's running state and what it gives one internal step: force noise,
//! the work rolls' eccentricity, the incoming gauge and the reel-tension steps, and
//! the mill's inputs at the step's Runge-Kutta stages.

use std::f64::consts::TAU;

use rand::rngs::SmallRng;
use rand::Rng;
use rand_distr::StandardNormal;

use super::delay::GaugeHistory;
use super::settings::{Excitation, TensionStep};
use crate::tandem::linear::{Inputs, TandemMill, MAX_STANDS};

/// The excitation between internal steps: the roll angles, the force-noise level, the
/// incoming gauge's first-order low-pass, the reel-tension steps in time order, and
/// the gap offsets and incoming gauge at the next step's start.
pub(super) struct Sources {
    excitation: Excitation,
    angles: Vec<RollAngle>,
    /// Force-noise standard deviation over one internal step, N (before bursts).
    force_sigma: f64,
    gauge_decay: f64,
    gauge_kick: f64,
    /// Incoming gauge deviation at the step's start, m.
    gauge: f64,
    /// The reel-tension steps in time order.
    tension_steps: Vec<TensionStep>,
    /// Gap offsets (eccentricity) at the step's start, m.
    gap: [f64; MAX_STANDS],
}

impl Sources {
    /// The excitation of `stands` stands in steps of `h` s at t = 0: random roll phases
    /// and incoming gauge drawn from `rng`.
    pub(super) fn new(
        excitation: &Excitation,
        stands: usize,
        h: f64,
        rng: &mut SmallRng,
    ) -> Sources {
        let excitation = excitation.clone();
        let angles: Vec<RollAngle> = (0..stands)
            .map(|_| {
                let [p1, p2] = [rng.random::<f64>() * TAU, rng.random::<f64>() * TAU];
                RollAngle {
                    cos: 1.0,
                    sin: 0.0,
                    phases: [(p1.cos(), p1.sin()), (p2.cos(), p2.sin())],
                }
            })
            .collect();
        let force_sigma = excitation.force_noise_density * (0.5 / h).sqrt();
        let gauge_decay = (-TAU * excitation.entry_gauge_bandwidth_hz * h).exp();
        let gauge_kick = excitation.entry_gauge_rms_m * (1.0 - gauge_decay * gauge_decay).sqrt();
        let gauge = excitation.entry_gauge_rms_m * rng.sample::<f64, _>(StandardNormal);
        let mut tension_steps = excitation.tension_steps.clone();
        tension_steps.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
        let mut gap = [0.0; MAX_STANDS];
        for (slot, angle) in gap.iter_mut().zip(&angles) {
            *slot = angle.eccentricity(excitation.eccentricity_m);
        }
        Sources {
            excitation,
            angles,
            force_sigma,
            gauge_decay,
            gauge_kick,
            gauge,
            tension_steps,
            gap,
        }
    }

    /// The force noise on each of the first `stands` work rolls over the step at `t`
    /// s, N: white, held over the step, louder in a burst.
    pub(super) fn force(&self, t: f64, stands: usize, rng: &mut SmallRng) -> [f64; MAX_STANDS] {
        let mut force = [0.0; MAX_STANDS];
        for (stand, value) in force.iter_mut().take(stands).enumerate() {
            let sigma = self.force_sigma * self.excitation.force_noise_factor(t, stand);
            *value = sigma * rng.sample::<f64, _>(StandardNormal);
        }
        force
    }

    /// The excitation over the step of `h` s from `t`, with `force` held over it and
    /// the speed factor going from `speeds.0` to `speeds.1`: the rolls turn, the
    /// incoming gauge moves on; [`Sources::commit`] makes its end the next start.
    pub(super) fn step(
        &mut self,
        (t, h): (f64, f64),
        force: [f64; MAX_STANDS],
        (speed_start, speed_end): (f64, f64),
        mill: &TandemMill,
        rng: &mut SmallRng,
    ) -> Step {
        let radius = mill.roll_radius_m();
        let mut gap_next = [0.0; MAX_STANDS];
        for ((slot, angle), model) in gap_next
            .iter_mut()
            .zip(self.angles.iter_mut())
            .zip(mill.stands())
        {
            angle.turn(0.5 * (speed_start + speed_end) * model.roll_speed / radius * h);
            *slot = angle.eccentricity(self.excitation.eccentricity_m);
        }
        let gauge_next =
            self.gauge * self.gauge_decay + self.gauge_kick * rng.sample::<f64, _>(StandardNormal);
        let (entry_tension_pa, exit_tension_pa) = self
            .tension_steps
            .iter()
            .take_while(|s| s.time_s <= t)
            .fold((0.0, 0.0), |(a, b), s| {
                (a + s.entry_mpa * 1e6, b + s.exit_mpa * 1e6)
            });
        Step {
            t,
            h,
            force,
            gap: [self.gap, gap_next],
            gauge: [self.gauge, gauge_next],
            entry_tension_pa,
            exit_tension_pa,
        }
    }

    /// Moves on to the end of `step` (a step the mill completed).
    pub(super) fn commit(&mut self, step: &Step) {
        self.gap = step.gap[1];
        self.gauge = step.gauge[1];
    }
}

/// The excitation over one internal step: the force noise held over it, the gap
/// offsets and incoming gauge at its start and end (interpolated between), the reel
/// tensions.
pub(super) struct Step {
    /// Start, s.
    t: f64,
    /// Length, s.
    h: f64,
    force: [f64; MAX_STANDS],
    /// Gap offsets at the start and the end, m.
    gap: [[f64; MAX_STANDS]; 2],
    /// Incoming gauge deviation at the start and the end, m.
    gauge: [f64; 2],
    entry_tension_pa: f64,
    exit_tension_pa: f64,
}

impl Step {
    /// The speed factor and the mill's inputs at `t + weight h`; the delayed entry
    /// gauges are read from `history` (rows stored before this step).
    pub(super) fn inputs_at(
        &self,
        weight: f64,
        speed: &impl Fn(f64) -> f64,
        mill: &TandemMill,
        history: &GaugeHistory,
    ) -> (f64, Inputs) {
        let n = mill.stands().len();
        let t_stage = self.t + weight * self.h;
        let speed = speed(t_stage);
        let mut inputs = Inputs {
            entry_tension_pa: self.entry_tension_pa,
            exit_tension_pa: self.exit_tension_pa,
            force_n: self.force,
            ..Inputs::default()
        };
        let [gauge, gauge_next] = self.gauge;
        inputs.entry_thickness_m[0] = gauge + weight * (gauge_next - gauge);
        let [gap_now, gap_next] = &self.gap;
        for stand in 0..n {
            inputs.gap_offset_m[stand] =
                gap_now[stand] + weight * (gap_next[stand] - gap_now[stand]);
            if stand + 1 < n {
                let delay = mill.delay_s(stand, speed);
                inputs.entry_thickness_m[stand + 1] = history.at(stand, (t_stage - delay) / self.h);
            }
        }
        (speed, inputs)
    }

    /// The step's start from the last step's end (`carried`), with this step's force
    /// noise and tensions.
    pub(super) fn carry(&self, (speed, inputs): (f64, Inputs)) -> (f64, Inputs) {
        (
            speed,
            Inputs {
                force_n: self.force,
                entry_tension_pa: self.entry_tension_pa,
                exit_tension_pa: self.exit_tension_pa,
                ..inputs
            },
        )
    }
}

/// A work roll's angle as (cos, sin), advanced by small rotations (no sine call per
/// step) and renormalised, with the 1x and 2x eccentricity read from it.
#[derive(Clone, Copy)]
struct RollAngle {
    cos: f64,
    sin: f64,
    /// (cos, sin) of the random phases of the 1x and 2x components.
    phases: [(f64, f64); 2],
}

impl RollAngle {
    /// Turn by `delta` rad (|delta| << 1: Taylor to 4th order).
    fn turn(&mut self, delta: f64) {
        let d2 = delta * delta;
        let (c, s) = (1.0 - d2 / 2.0 + d2 * d2 / 24.0, delta * (1.0 - d2 / 6.0));
        let (cos, sin) = (self.cos * c - self.sin * s, self.sin * c + self.cos * s);
        let norm = 1.0 / (cos * cos + sin * sin).sqrt();
        self.cos = cos * norm;
        self.sin = sin * norm;
    }

    /// `e1 sin(phi + p1) + e2 sin(2 phi + p2)`.
    fn eccentricity(&self, amplitudes: [f64; 2]) -> f64 {
        let (c2, s2) = (
            self.cos * self.cos - self.sin * self.sin,
            2.0 * self.sin * self.cos,
        );
        let [(pc1, ps1), (pc2, ps2)] = self.phases;
        amplitudes[0] * (self.sin * pc1 + self.cos * ps1) + amplitudes[1] * (s2 * pc2 + c2 * ps2)
    }
}
