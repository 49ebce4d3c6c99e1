//! The tandem mill linearised about its pass schedule: per stand the top half of the
//! vertical roll stack, the roll-gap force and forward slip, the interstand tensions
//! driven by mass flow and the thickness carried from stand to stand.
//!
//! State (SI, deviations from the schedule), stand `i` of `n`, interstand `j` between
//! stands `j` and `j + 1`:
//!
//! ```text
//! x[4i] = y_w (work roll, up = gap opens)   x[4i + 1] = y_b (backup roll)
//! x[4i + 2] = y_w'                          x[4i + 3] = y_b'
//! x[4n + j] = dsigma_j (interstand tension stress, Pa)
//! ```
//!
//! Equations (speed factor `s` scales every roll speed of the schedule):
//!
//! ```text
//! m_w y_w'' = dF - k_wb (y_w - y_b) - c_wb (y_w' - y_b') + force noise
//! m_b y_b'' = k_wb (y_w - y_b) + c_wb (y_w' - y_b') - k_bh y_b - c_bh y_b'
//! dh  = 2 y_w + e (roll eccentricity)         dH = entry thickness deviation
//! dF  = F_H dH + F_h dh + F_b dsigma_b + F_f dsigma_f
//! df  = f_H dH + f_h dh + f_b dsigma_b + f_f dsigma_f
//! dv_out = s v_R df - 2 x_n y_w' / h
//! dv_in  = [s v_R h df + v_out dh + 2 (l - x_n) y_w'] / H - v_in dH / H
//! dsigma_j' = (E / L) (dv_in[j + 1] - dv_out[j])
//! dH[i + 1](t) = dh[i](t - L / v_out[i])
//! ```
//!
//! with `v_out = s v_R (1 + f)` and `v_in = v_out h / H` at the schedule. The first
//! stand's back tension and the last stand's front tension are held by the reels (their
//! deviations are inputs: tension steps). The force and slip partials do not depend on
//! speed, so the system is `A0 + s A1` with delays `L / v_out` that shrink as `1 / s`.

use nalgebra::{DMatrix, DVector};

use super::rollgap::{partials, GapPartials, RollGap};
use super::schedule::PassSchedule;
use crate::model::{Checker, ModelError};

/// Most stands (the chatter detectors take up to 8).
pub(crate) const MAX_STANDS: usize = 8;

/// One stand's linearisation.
#[derive(Debug, Clone, PartialEq)]
pub struct StandModel {
    /// Entry thickness H at the schedule, m.
    pub(crate) entry_m: f64,
    /// Exit thickness h at the schedule, m.
    pub(crate) exit_m: f64,
    /// Work-roll speed at speed factor 1, m/s.
    pub(crate) roll_speed: f64,
    /// Back and front tension stress at the schedule, Pa.
    pub(crate) tension_pa: [f64; 2],
    /// The roll gap at the schedule.
    pub gap: RollGap,
    /// Force and forward-slip partials.
    pub partials: GapPartials,
}

/// Stack constants in SI units (masses as their inverses, for the hot path).
#[derive(Debug, Clone, Copy, PartialEq)]
struct StackSi {
    inverse_work_mass: f64,
    inverse_backup_mass: f64,
    work_backup_stiffness: f64,
    work_backup_damping: f64,
    backup_housing_stiffness: f64,
    backup_housing_damping: f64,
}

/// A stand's mass-flow coefficients (see [`TandemMill::derivative`]), precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FlowCoefficients {
    /// 2 x_n / h, 1/s per m/s of work-roll velocity on the exit speed.
    exit_by_rate: f64,
    /// h / H: forward slip on the entry speed, per unit roll speed.
    entry_by_slip: f64,
    /// (1 + f) / H: exit gap on the entry speed, per unit roll speed, 1/m.
    entry_by_gap: f64,
    /// (1 + f) h / H^2: entry thickness on the entry speed, per unit roll speed, 1/m.
    entry_by_entry: f64,
    /// 2 (l - x_n) / H: work-roll velocity on the entry speed.
    entry_by_rate: f64,
}

/// Excitation and boundary inputs at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Inputs {
    /// Entry thickness deviation dH per stand, m: stand 0's is the incoming gauge, stand
    /// i's the deviation stand i - 1 put out one transport delay earlier.
    pub(crate) entry_thickness_m: [f64; MAX_STANDS],
    /// Roll-gap deviation from eccentricity per stand, m (adds to `2 y_w`).
    pub(crate) gap_offset_m: [f64; MAX_STANDS],
    /// Force noise on each work roll, N.
    pub(crate) force_n: [f64; MAX_STANDS],
    /// Deviation of the first stand's back (payoff reel) tension, Pa.
    pub(crate) entry_tension_pa: f64,
    /// Deviation of the last stand's front (coiler) tension, Pa.
    pub(crate) exit_tension_pa: f64,
}

/// A delayed term of the linear system: `x' += column * 2 x[source](t - delay)`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DelayedCoupling {
    /// Transport delay, s.
    pub(crate) delay_s: f64,
    /// State index of the work-roll displacement whose gap is carried (`2 y_w`).
    pub(crate) source: usize,
    /// Effect of a unit entry-thickness deviation (1 m) of the next stand on `x'`.
    pub(crate) column: DVector<f64>,
}

/// The linear delay system `x' = A x + sum_k column_k 2 x[source_k](t - delay_k)` at one
/// speed.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearSystem {
    /// Speed factor it was built for.
    pub(crate) speed: f64,
    /// Undelayed system matrix (SI state, see the module docs).
    pub(crate) a: DMatrix<f64>,
    /// One delayed coupling per interstand, in stand order.
    pub(crate) delayed: Vec<DelayedCoupling>,
}

/// A tandem mill linearised about its schedule (speed enters at evaluation).
#[derive(Debug, Clone, PartialEq)]
pub struct TandemMill {
    stands: Vec<StandModel>,
    flow: Vec<FlowCoefficients>,
    stack: StackSi,
    /// E / L, Pa/m.
    strip_spring: f64,
    interstand_m: f64,
    roll_radius_m: f64,
}

impl TandemMill {
    /// Linearises every stand of a validated schedule.
    pub fn new(schedule: &PassSchedule) -> Result<TandemMill, ModelError> {
        let mut stands = Vec::with_capacity(schedule.stands.len());
        for index in 0..schedule.stands.len() {
            let pass = schedule.pass(index);
            let (gap, partials) = partials(&pass).map_err(|problem| {
                Checker { file: "<schedule>" }.error(
                    &format!("stand[{index}]"),
                    format_args!("{} -> {} mm", pass.entry_m * 1e3, pass.exit_m * 1e3),
                    format_args!("a pass whose roll gap can be linearised: {problem}"),
                )
            })?;
            stands.push(StandModel {
                entry_m: pass.entry_m,
                exit_m: pass.exit_m,
                roll_speed: schedule.stands[index].roll_speed,
                tension_pa: [pass.back_tension_pa, pass.front_tension_pa],
                gap,
                partials,
            });
        }
        if !(2..=MAX_STANDS).contains(&stands.len()) {
            return Err(Checker { file: "<schedule>" }.error(
                "stand",
                stands.len(),
                format_args!("2 to {MAX_STANDS} stands"),
            ));
        }
        let stack = &schedule.stack;
        let flow = stands
            .iter()
            .map(|s| {
                let (h, big_h, f) = (s.exit_m, s.entry_m, s.gap.forward_slip);
                let (x_n, l) = (s.gap.neutral_point_m, s.gap.contact_length_m);
                FlowCoefficients {
                    exit_by_rate: 2.0 * x_n / h,
                    entry_by_slip: h / big_h,
                    entry_by_gap: (1.0 + f) / big_h,
                    entry_by_entry: (1.0 + f) * h / (big_h * big_h),
                    entry_by_rate: 2.0 * (l - x_n) / big_h,
                }
            })
            .collect();
        Ok(TandemMill {
            stands,
            flow,
            stack: StackSi {
                inverse_work_mass: 1.0 / stack.work_roll_mass,
                inverse_backup_mass: 1.0 / stack.backup_roll_mass,
                work_backup_stiffness: stack.work_backup_stiffness,
                work_backup_damping: stack.work_backup_damping,
                backup_housing_stiffness: stack.backup_housing_stiffness,
                backup_housing_damping: stack.backup_housing_damping,
            },
            strip_spring: schedule.strip.youngs_modulus / schedule.interstand_distance,
            interstand_m: schedule.interstand_distance,
            roll_radius_m: schedule.rolls.work_roll_radius,
        })
    }

    /// The stands' linearisations, in rolling order.
    pub fn stands(&self) -> &[StandModel] {
        &self.stands
    }

    /// Number of states: 4 per stand and one tension per interstand.
    pub(crate) fn state_len(&self) -> usize {
        5 * self.stands.len() - 1
    }

    /// State index of stand `i`'s work-roll displacement (backup roll `+ 1`, their
    /// velocities `+ 2`, `+ 3`).
    pub(crate) fn work_roll(stand: usize) -> usize {
        4 * stand
    }

    /// State index of the tension between stands `j` and `j + 1`.
    pub(crate) fn tension(&self, interstand: usize) -> usize {
        4 * self.stands.len() + interstand
    }

    /// Exit strip speed of stand `i` at speed factor `speed`, m/s.
    pub fn exit_speed(&self, stand: usize, speed: f64) -> f64 {
        let model = &self.stands[stand];
        speed * model.roll_speed * (1.0 + model.gap.forward_slip)
    }

    /// Transport delay from stand `j` to stand `j + 1` at speed factor `speed`, s.
    pub(crate) fn delay_s(&self, interstand: usize, speed: f64) -> f64 {
        self.interstand_m / self.exit_speed(interstand, speed)
    }

    /// Work-roll radius, m.
    pub(crate) fn roll_radius_m(&self) -> f64 {
        self.roll_radius_m
    }

    /// Nominal tension stress between stands `j` and `j + 1`, Pa.
    pub(crate) fn nominal_tension_pa(&self, interstand: usize) -> f64 {
        self.stands[interstand].tension_pa[1]
    }

    /// The exit-gauge deviation of stand `i`: `2 y_w + e`, m.
    pub(crate) fn gap_deviation(&self, state: &[f64], inputs: &Inputs, stand: usize) -> f64 {
        2.0 * state[Self::work_roll(stand)] + inputs.gap_offset_m[stand]
    }

    /// `x'` at speed factor `speed` for state `x` and `inputs` (see the module docs).
    /// `x` and `dx` have [`TandemMill::state_len`] entries.
    pub(crate) fn derivative(&self, speed: f64, x: &[f64], inputs: &Inputs, dx: &mut [f64]) {
        let n = self.stands.len();
        let st = &self.stack;
        let mut speed_out = [0.0; MAX_STANDS];
        let mut speed_in = [0.0; MAX_STANDS];
        for (i, (model, k)) in self.stands.iter().zip(&self.flow).enumerate() {
            let o = 4 * i;
            let (y_w, y_b, v_w, v_b) = (x[o], x[o + 1], x[o + 2], x[o + 3]);
            let back = if i == 0 {
                inputs.entry_tension_pa
            } else {
                x[4 * n + i - 1]
            };
            let front = if i + 1 == n {
                inputs.exit_tension_pa
            } else {
                x[4 * n + i]
            };
            let gap = 2.0 * y_w + inputs.gap_offset_m[i];
            let entry = inputs.entry_thickness_m[i];
            let (pf, ps) = (&model.partials.force, &model.partials.slip);
            let force = pf[0] * entry + pf[1] * gap + pf[2] * back + pf[3] * front;
            let slip = ps[0] * entry + ps[1] * gap + ps[2] * back + ps[3] * front;
            let contact =
                st.work_backup_stiffness * (y_w - y_b) + st.work_backup_damping * (v_w - v_b);
            dx[o] = v_w;
            dx[o + 1] = v_b;
            dx[o + 2] = (force - contact + inputs.force_n[i]) * st.inverse_work_mass;
            dx[o + 3] =
                (contact - st.backup_housing_stiffness * y_b - st.backup_housing_damping * v_b)
                    * st.inverse_backup_mass;
            // dv_out = v_R df - 2 x_n y_w' / h
            // dv_in = [v_R h df + v_R (1 + f) dh + 2 (l - x_n) y_w'] / H - v_in dH / H
            let roll = speed * model.roll_speed;
            speed_out[i] = roll * slip - k.exit_by_rate * v_w;
            speed_in[i] = roll
                * (k.entry_by_slip * slip + k.entry_by_gap * gap - k.entry_by_entry * entry)
                + k.entry_by_rate * v_w;
        }
        for j in 0..n - 1 {
            dx[4 * n + j] = self.strip_spring * (speed_in[j + 1] - speed_out[j]);
        }
    }

    /// The linear delay system at speed factor `speed` (> 0), built from
    /// `TandemMill::derivative` with unit states and inputs, so the time simulation
    /// and the characteristic roots use the same equations.
    pub fn linear_system(&self, speed: f64) -> LinearSystem {
        let len = self.state_len();
        let zero = Inputs::default();
        let mut unit = vec![0.0; len];
        let mut column = vec![0.0; len];
        let mut a = DMatrix::zeros(len, len);
        for c in 0..len {
            unit[c] = 1.0;
            self.derivative(speed, &unit, &zero, &mut column);
            a.set_column(c, &DVector::from_column_slice(&column));
            unit[c] = 0.0;
        }
        let delayed = (0..self.stands.len() - 1)
            .map(|j| {
                let mut inputs = Inputs::default();
                inputs.entry_thickness_m[j + 1] = 1.0;
                self.derivative(speed, &unit, &inputs, &mut column);
                DelayedCoupling {
                    delay_s: self.delay_s(j, speed),
                    source: Self::work_roll(j),
                    column: DVector::from_column_slice(&column),
                }
            })
            .collect();
        LinearSystem { speed, a, delayed }
    }
}
