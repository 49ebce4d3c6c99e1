//! A seeded generator of "measured" bites with one hidden effect, for testing the
//! workflow the way it is used: it only sees the records and a model without the
//! effect, often with the stiffness from drawings rather than the true one.
//!
//! The records come from the simulator at its own accuracy ([`simulate_with_noise`]:
//! RK4 at 50 steps per period of the fastest motion, gap crossings located inside the
//! step), not from the workflow's fit model (which integrates with fewer steps).

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use crate::chain::simulate_with_noise;
use crate::model::{Load, Model, ModelError};
use crate::schedule::{rolling_schedule_of, BarTiming};

use super::decision::describe;
use super::effects::Effect;
use super::split::split_bites;
use super::{Measured, Report, Verdict};

/// Largest relative error of a recovered effect size.
pub const SIZE_TOLERANCE: f64 = 0.25;
/// Largest RMS residual after, as a multiple of the true noise.
pub const RESIDUAL_TOLERANCE: f64 = 1.2;

/// The Table 2 driveline, stiffness adjusted to measurement (the truth's basis).
const ADJUSTED: &str = include_str!("../../models/table2-adjusted.toml");
/// The Table 2 driveline, stiffness from drawings.
const DRAWINGS: &str = include_str!("../../models/table2-drawings.toml");

/// Static torques of the bites, kN*m.
pub const STATIC_TORQUE_KNM: (f64, f64) = (40.0, 170.0);
/// Noise RMS, kN*m (drawn log-uniformly).
pub const NOISE_KNM: (f64, f64) = (0.2, 2.0);
/// Factor between the handed and the true stiffness of a coupling when the handed
/// stiffness is "from drawings": `1/4 ..= 1/1.3` or `1.3 ..= 4` (drawn log-uniformly).
pub const DRAWING_FACTOR: (f64, f64) = (1.3, 4.0);
/// Gap widths, rad.
pub const BACKLASH_RAD: (f64, f64) = (1.0e-3, 5.0e-3);
/// Gap widths of the `Recorded::Schedule` cases, rad: a big gap already open when the
/// record was taken (the wear diagnosis's calibration records).
pub const SCHEDULE_BACKLASH_RAD: (f64, f64) = (3.0e-3, 5.0e-3);
/// Timing of each bar of a [`Recorded::Schedule`] case.
pub(crate) const SCHEDULE_TIMING: BarTiming = BarTiming {
    idle_s: 0.3,
    rolling_s: 0.7,
};

/// An effect hidden in the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hidden {
    /// The effect.
    pub effect: Effect,
    /// Its coupling, or `None` for the measured channel.
    pub location: Option<usize>,
    /// Its size, in the unit of `Effect::parameter_key`.
    pub value: f64,
}

/// Where the handed model's stiffness comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Handed {
    /// The true stiffness.
    Right,
    /// The paper's Table 2 drawing values (the truth is the adjusted row).
    PaperDrawings,
    /// Each coupling's true stiffness times a random factor (see [`DRAWING_FACTOR`]).
    Drawings,
}

/// How a case's bites were recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Recorded {
    /// Each bite its own record of 0.6 s, from before the rise into the settled part.
    Separate,
    /// One record of a rolling schedule ([`SCHEDULE_TIMING`]: idle, bite, rolling, a
    /// smooth tail-out per bar), split into bites by
    /// [`split_bites`] as a long recording is.
    Schedule,
}

/// One test case: the truth, what the workflow is handed, and the hidden effect.
#[derive(Debug, Clone, PartialEq)]
pub struct HiddenCase {
    /// Short name for reports.
    pub name: String,
    /// The hidden effect, or `None`.
    pub hidden: Option<Hidden>,
    /// Where the handed stiffness comes from.
    pub handed_from: Handed,
    /// How the bites were recorded.
    pub(crate) recorded: Recorded,
    /// Noise RMS added to every bite, kN*m.
    pub noise_rms: f64,
    /// Seed of the noise (bite `b` uses `seed + b`).
    pub(crate) seed: u64,
    /// The true linear driveline.
    pub truth: Model,
    /// The model handed to the workflow (no effect; maybe other stiffness).
    pub handed: Model,
    /// The load of each bite.
    pub loads: Vec<Load>,
}

/// A generated record of one bite.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// Sample times, s.
    pub(crate) t_s: Vec<f64>,
    /// Torque, kN*m.
    pub(crate) torque_knm: Vec<f64>,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
}

impl Record {
    /// The record as the workflow's input.
    pub fn measured(&self) -> Measured<'_> {
        Measured {
            t0_s: self.t_s.first().copied().unwrap_or(0.0),
            sample_rate_hz: self.sample_rate_hz,
            torque_knm: &self.torque_knm,
        }
    }
}

impl HiddenCase {
    /// The truth with the hidden effect, under bite `bite`'s load.
    pub(crate) fn true_model(&self, bite: usize) -> Result<Model, ModelError> {
        let mut model = self.truth.clone();
        model.load = self.loads[bite].clone();
        match self.hidden {
            Some(h) => h.effect.apply(&model, h.location, h.value),
            None => Ok(model),
        }
    }

    /// Whether `report` recovered this case: the hidden effect named (not merely among
    /// rivals) at its location with its size within [`SIZE_TOLERANCE`], or `none` when
    /// nothing is hidden; and the residual after within [`RESIDUAL_TOLERANCE`] times the
    /// true noise. The error says what went wrong.
    pub fn check(&self, report: &Report) -> Result<(), String> {
        let named = report
            .effect
            .map_or("none".to_owned(), |e| describe(&e, report.location));
        match self.hidden {
            None if report.verdict != Verdict::None => {
                return Err(format!("{} {named} in a null case", report.verdict));
            }
            None => {}
            Some(hidden) => {
                let truth = describe(&hidden.effect, hidden.location);
                if report.verdict != Verdict::Named {
                    return Err(format!("{} {named}, hidden {truth}", report.verdict));
                }
                if (report.effect, report.location) != (Some(hidden.effect), hidden.location) {
                    return Err(format!("named {named}, hidden {truth}"));
                }
                let fitted = report
                    .parameters
                    .get(hidden.effect.parameter_key())
                    .copied()
                    .unwrap_or(f64::NAN);
                let error = (fitted / hidden.value - 1.0).abs();
                if error.is_nan() || error > SIZE_TOLERANCE {
                    return Err(format!("size {fitted:.4e}, hidden {:.4e}", hidden.value));
                }
            }
        }
        if report.rmse_after.is_nan() || report.rmse_after > RESIDUAL_TOLERANCE * self.noise_rms {
            return Err(format!(
                "rmse_after {:.3} > {RESIDUAL_TOLERANCE} x noise {:.3}",
                report.rmse_after, self.noise_rms
            ));
        }
        Ok(())
    }

    /// Simulates every bite of the truth with the hidden effect and adds the seeded
    /// noise; a `Recorded::Schedule` case's bites are split from one record (as many
    /// as [`split_bites`] finds).
    pub fn records(&self) -> Result<Vec<Record>, ModelError> {
        if self.recorded == Recorded::Schedule {
            let models = (0..self.loads.len())
                .map(|b| self.true_model(b))
                .collect::<Result<Vec<_>, _>>()?;
            let schedule =
                rolling_schedule_of(&models, SCHEDULE_TIMING, self.noise_rms, self.seed)?;
            let whole = Measured {
                t0_s: 0.0,
                sample_rate_hz: schedule.sample_rate_hz,
                torque_knm: &schedule.torque_knm,
            };
            return Ok(split_bites(&whole)
                .iter()
                .map(|bite| Record {
                    t_s: (0..bite.torque_knm.len())
                        .map(|k| bite.t0_s + k as f64 / bite.sample_rate_hz)
                        .collect(),
                    torque_knm: bite.torque_knm.to_vec(),
                    sample_rate_hz: bite.sample_rate_hz,
                })
                .collect());
        }
        (0..self.loads.len())
            .map(|b| {
                let model = self.true_model(b)?;
                let transient = simulate_with_noise(&model, self.noise_rms, self.seed + b as u64)?;
                Ok(Record {
                    t_s: transient.t,
                    torque_knm: transient.torque_knm,
                    sample_rate_hz: model.measurement.sample_rate,
                })
            })
            .collect()
    }
}

/// What one generated case hides, where, with which handed stiffness, how many bites
/// and how they were recorded.
type Design = (Option<Effect>, Option<usize>, Handed, usize, Recorded);

/// The designs of [`suite`]: every effect, gaps in either coupling, right stiffness and
/// drawings, one to five bites; last, bites split from a rolling schedule with a big gap
/// in the measured coupling or none, from drawings (new designs go last: the earlier
/// cases keep their numbers).
const DESIGNS: [Design; 37] = {
    use Effect::*;
    use Handed::*;
    use Recorded::*;
    [
        (None, None, Right, 1, Separate),
        (None, None, Drawings, 1, Separate),
        (None, None, PaperDrawings, 1, Separate),
        (None, None, Drawings, 3, Separate),
        (Some(Backlash), Some(1), Right, 1, Separate),
        (Some(Backlash), Some(1), Drawings, 1, Separate),
        (Some(Backlash), Some(1), Drawings, 1, Separate),
        (Some(Backlash), Some(1), Drawings, 1, Separate),
        (Some(Backlash), Some(1), PaperDrawings, 1, Separate),
        (Some(Backlash), Some(0), Right, 1, Separate),
        (Some(Backlash), Some(0), Drawings, 1, Separate),
        (Some(Backlash), Some(0), Drawings, 1, Separate),
        (Some(Backlash), Some(0), PaperDrawings, 1, Separate),
        (Some(Backlash), Some(1), Drawings, 3, Separate),
        (Some(Backlash), Some(0), Drawings, 5, Separate),
        (Some(Backlash), Some(1), Right, 2, Separate),
        (Some(Hardening), Some(1), Right, 1, Separate),
        (Some(Hardening), Some(1), Drawings, 1, Separate),
        (Some(Hardening), Some(0), Drawings, 1, Separate),
        (Some(Hardening), Some(1), Drawings, 2, Separate),
        (Some(CoulombDamping), Some(1), Right, 1, Separate),
        (Some(CoulombDamping), Some(1), Drawings, 1, Separate),
        (Some(CoulombDamping), Some(0), Drawings, 1, Separate),
        (Some(CoulombDamping), Some(0), Drawings, 2, Separate),
        (Some(SensorLag), None, Right, 1, Separate),
        (Some(SensorLag), None, Drawings, 1, Separate),
        (Some(SensorLag), None, PaperDrawings, 1, Separate),
        (Some(SensorLag), None, Drawings, 2, Separate),
        (Some(ExtraInertia), Some(1), Right, 1, Separate),
        (Some(ExtraInertia), Some(0), Drawings, 1, Separate),
        (Some(Hardening), Some(0), Right, 1, Separate),
        (Some(CoulombDamping), Some(1), PaperDrawings, 1, Separate),
        (None, None, PaperDrawings, 3, Schedule),
        (None, None, Drawings, 3, Schedule),
        (Some(Backlash), Some(1), PaperDrawings, 3, Schedule),
        (Some(Backlash), Some(1), Drawings, 3, Schedule),
        (Some(Backlash), Some(1), Drawings, 5, Schedule),
    ]
};

/// The generated test suite: one case per design, every number drawn from `seed`.
///
/// The truth is the Table 2 adjusted driveline with each coupling's stiffness scaled by
/// up to 20% either way (the paper's adjusted values for `PaperDrawings` cases), bites
/// of 0.6 s at 2 kHz (or split from a rolling schedule, `Recorded::Schedule`) with
/// static torque in [`STATIC_TORQUE_KNM`] (several bites spread over it), onset 30-80 ms,
/// rise rate 25-50/s, noise in [`NOISE_KNM`]. Sizes: gaps in [`BACKLASH_RAD`]
/// ([`SCHEDULE_BACKLASH_RAD`] in schedule cases); hardening adding 15-50% of the linear torque at the largest static
/// twist; friction 2.5-6% of the largest static torque; a sensor lag of 3-15 ms; an
/// extra inertia of 15-30% of the smaller neighbouring mass.
pub fn suite(seed: u64) -> Result<Vec<HiddenCase>, ModelError> {
    let adjusted = Model::from_toml_str(ADJUSTED, "table2-adjusted.toml")?;
    let paper_drawings = Model::from_toml_str(DRAWINGS, "table2-drawings.toml")?;
    let mut rng = StdRng::seed_from_u64(seed);
    let mut cases = Vec::with_capacity(DESIGNS.len());
    for (index, &(effect, location, handed_from, bites, recorded)) in DESIGNS.iter().enumerate() {
        let mut truth = adjusted.clone();
        let mut handed = adjusted.clone();
        match handed_from {
            Handed::PaperDrawings => handed = paper_drawings.clone(),
            Handed::Right | Handed::Drawings => {
                for (t, h) in truth.couplings.iter_mut().zip(handed.couplings.iter_mut()) {
                    t.stiffness *= log_uniform(&mut rng, 1.0 / 1.2, 1.2);
                    h.stiffness = t.stiffness;
                    if handed_from == Handed::Drawings {
                        let factor = log_uniform(&mut rng, DRAWING_FACTOR.0, DRAWING_FACTOR.1);
                        h.stiffness *= if rng.random_bool(0.5) {
                            factor
                        } else {
                            1.0 / factor
                        };
                    }
                }
            }
        }
        let loads: Vec<Load> = (0..bites)
            .map(|b| {
                let (low, high) = STATIC_TORQUE_KNM;
                let share = (b as f64 + rng.random_range(0.0..1.0)) / bites as f64;
                let mut load = adjusted.load.clone();
                load.static_torque = low + (high - low) * share;
                load.rise_rate = rng.random_range(25.0..50.0);
                load.onset = rng.random_range(0.03..0.08);
                load
            })
            .collect();
        let largest_knm = loads.iter().fold(0.0_f64, |a, l| a.max(l.static_torque));
        let hidden = effect.map(|effect| {
            let coupling = location.map(|i| &truth.couplings[i]);
            let stiffness = coupling.map_or(0.0, |c| c.stiffness);
            let twist = largest_knm * 1.0e3 / stiffness.max(f64::MIN_POSITIVE);
            let value = match effect {
                Effect::Backlash => {
                    let (low, high) = match recorded {
                        Recorded::Separate => BACKLASH_RAD,
                        Recorded::Schedule => SCHEDULE_BACKLASH_RAD,
                    };
                    log_uniform(&mut rng, low, high)
                }
                Effect::Hardening => rng.random_range(0.15..0.5) * stiffness / (twist * twist),
                Effect::CoulombDamping => rng.random_range(0.025..0.06) * largest_knm,
                Effect::SensorLag => rng.random_range(3.0e-3..15.0e-3),
                Effect::ExtraInertia => {
                    let i = location.unwrap_or(0);
                    let smaller = truth.masses[i].inertia.min(truth.masses[i + 1].inertia);
                    rng.random_range(0.15..0.3) * smaller
                }
            };
            Hidden {
                effect,
                location,
                value,
            }
        });
        // An extra inertia of this size changes the record by about 0.2 kN*m RMS: it is
        // looked for under noise up to 0.5 kN*m.
        let noise_high = match effect {
            Some(Effect::ExtraInertia) => 0.5,
            _ => NOISE_KNM.1,
        };
        let noise_rms = log_uniform(&mut rng, NOISE_KNM.0, noise_high);
        let name = format!(
            "{index:02} {}{} {:?}, {bites} bite{}{}",
            effect.map_or("none", Effect::key),
            location.map_or(String::new(), |i| format!("@{i}")),
            handed_from,
            if bites == 1 { "" } else { "s" },
            if recorded == Recorded::Schedule {
                " split"
            } else {
                ""
            }
        );
        cases.push(HiddenCase {
            name,
            hidden,
            handed_from,
            recorded,
            noise_rms,
            seed: seed.wrapping_mul(1000) + 10 * index as u64,
            truth,
            handed,
            loads,
        });
    }
    Ok(cases)
}

/// A log-uniform draw from `[low, high)`.
fn log_uniform(rng: &mut StdRng, low: f64, high: f64) -> f64 {
    (rng.random_range(low.ln()..high.ln())).exp()
}
