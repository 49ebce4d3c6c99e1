//! Fitting a model to measured bites: the parametrisation shared by the linear
//! calibration and every candidate effect, and the residual it minimises.
//!
//! One model is fitted to every bite at once: coupling stiffness, damping and the
//! effect's size are shared, the load (static torque, rise rate, onset) is each bite's
//! own. Parameters live in a space where the fit is well scaled and the bounds hold by
//! construction, smoothly (a clamp would stall the fit at a bound): `ln(value /
//! anchor)` for stiffness, damping, static torque and rise rate, squashed by a tanh
//! into a factor 10 (100 for damping) of the anchor; the logit of the effect size's
//! position between the logarithms of its range's ends; and `(onset - anchor) / 1 ms`
//! for the onset. With hardening in coupling `i`, that coupling's stiffness parameter is
//! its tangent `C + 3 k3 e^2` at the anchor's static twist `e = M / C_anchor` under the
//! largest load `M` (about what the record's loaded part pins down); `C` follows from it
//! and `k3`, so the long valley where more hardening and less stiffness explain the
//! record alike lies along the `k3` axis. (The tangent of the true twist would be
//! exact, but it is not monotonic in `C` once the cubic share exceeds the linear one.)
//! The integration step is fixed for a whole fit (from the anchor model
//! with the effect at the top of its range), so the residual is a smooth function of
//! the parameters and forward differences work. A bite's load moves only that bite's
//! residuals, so the Jacobian simulates one bite per load column
//! ([`Problem`]'s [`Residuals::jacobian`]).

use nalgebra::DMatrix;

use crate::chain::Simulator;
use crate::model::{Model, ModelError};

use super::effects::{Effect, Range};
use super::levenberg_marquardt::{minimise, LmSettings, Residuals};
use super::{BiteProblem, DiscrepancyError, Measured, MIN_SAMPLES};

/// Onset parameter unit, s.
const ONSET_UNIT_S: f64 = 1.0e-3;

/// RK4 steps per period of the fastest motion during the search. RK4 is stable up to
/// 2.78 / (2 pi) = 0.44 periods per step, so 15 steps leave a 6.6x margin and resolve
/// the stick-slip transitions of friction (whose slope sets the fastest motion); the slow
/// modes that the record shows get hundreds of steps per period anyway. (The simulator's
/// own choice, 50, buys accuracy for the fastest motion, which here is a heavily damped
/// or stiff one that the record does not resolve.)
const SEARCH_STEPS_PER_FASTEST_PERIOD: f64 = 15.0;

/// The integration step of a fit is chosen for its effect at this multiple of the start
/// (the short fits start at five sizes spread over the range, the full fits at the best
/// short fits' sizes, so no fit needs to travel further); sized for the top of the
/// range instead, a friction or hardening fit spent 2-7 RK4 steps per sample where it
/// needs one or two.
const STIFFEST_EFFECT_FACTOR: f64 = 10.0;

/// Cap on RK4 steps per output sample during the search.
const MAX_SEARCH_SUBSTEPS: f64 = 24.0;

/// A simulation is abandoned once its output exceeds this multiple of the record's
/// largest |value|: no model that far off can win, and unstable trials end early.
const DIVERGENCE_FACTOR: f64 = 20.0;

/// Largest |ln ratio| a stiffness, static torque or rise rate may move from its anchor
/// in one fit (a factor of 10): the calibration's starts are within a factor 10 of the
/// drawings, and a fit needs no more room than that around its start.
pub(crate) const MAX_LOG_RATIO: f64 = std::f64::consts::LN_10;

/// Largest |ln ratio| a damping may move from its anchor (a factor of 100): model
/// damping is often a guess.
const MAX_LOG_DAMPING_RATIO: f64 = 2.0 * std::f64::consts::LN_10;

/// Levenberg-Marquardt settings of the simulation fits: the Jacobian (one simulation per
/// parameter) carried by Broyden updates over up to four accepted steps.
pub(crate) const FIT_SETTINGS: LmSettings = LmSettings {
    max_iterations: 40,
    cost_tolerance: 1.0e-7,
    difference_step: 1.0e-6,
    max_step: 2.0,
    jacobian_refresh: 4,
};

/// Load parameters per bite in the parameter vector: static torque, rise rate, onset.
const LOAD_PARAMETERS: usize = 3;

/// One measured bite as the fits see it.
#[derive(Debug, Clone)]
pub(crate) struct BiteRecord<'a> {
    /// The handed model, sampled at the bite's rate over its length.
    pub(crate) template: Model,
    /// The measured torque, kN*m, from the bite record's first sample.
    pub(crate) measured: &'a [f64],
}

/// The load of one bite.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BiteLoad {
    /// Static rolling torque, kN*m, > 0.
    pub(crate) static_torque_knm: f64,
    /// Load rise rate, 1/s, > 0.
    pub(crate) rise_rate_per_s: f64,
    /// Onset of the load rise from the bite record's first sample, s, >= 0.
    pub(crate) onset_s: f64,
}

impl BiteLoad {
    /// The load written in `model` (a zero static torque becomes 1 N*m so its logarithm
    /// exists).
    pub(crate) fn of(model: &Model) -> BiteLoad {
        BiteLoad {
            static_torque_knm: model.load.static_torque.max(1.0e-3),
            rise_rate_per_s: model.load.rise_rate,
            onset_s: model.load.onset,
        }
    }
}

/// Values of the linear model's calibrated quantities.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LinearValues {
    /// Coupling stiffness, N*m/rad, one per coupling (shared by the bites).
    pub(crate) stiffness: Vec<f64>,
    /// Coupling damping, N*m*s/rad, one per coupling, > 0 (shared by the bites).
    pub(crate) damping: Vec<f64>,
    /// Load of each bite.
    pub(crate) loads: Vec<BiteLoad>,
}

impl LinearValues {
    /// The values written in `model`, its load repeated for `bites` bites; a zero
    /// damping becomes a small positive one so its logarithm exists (1e-6 of the
    /// stiffness, s).
    pub(crate) fn of(model: &Model, bites: usize) -> LinearValues {
        LinearValues {
            stiffness: model.couplings.iter().map(|c| c.stiffness).collect(),
            damping: model
                .couplings
                .iter()
                .map(|c| c.damping.max(1.0e-6 * c.stiffness))
                .collect(),
            loads: vec![BiteLoad::of(model); bites],
        }
    }

    /// `model` with the shared values and the load of bite `bite` written in.
    pub(crate) fn model_for(&self, model: &Model, bite: usize) -> Model {
        let mut out = model.clone();
        for (coupling, (&stiffness, &damping)) in out
            .couplings
            .iter_mut()
            .zip(self.stiffness.iter().zip(&self.damping))
        {
            coupling.stiffness = stiffness;
            coupling.damping = damping;
        }
        let load = self.loads[bite];
        out.load.static_torque = load.static_torque_knm;
        out.load.rise_rate = load.rise_rate_per_s;
        out.load.onset = load.onset_s;
        out
    }

    /// The same values with `stiffness` instead.
    pub(crate) fn with_stiffness(&self, stiffness: &[f64]) -> LinearValues {
        LinearValues {
            stiffness: stiffness.to_vec(),
            ..self.clone()
        }
    }
}

/// An effect being fitted: which, where, its range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct EffectSlot {
    /// The effect.
    pub(crate) effect: Effect,
    /// Its coupling, or `None` for the measured channel.
    pub(crate) location: Option<usize>,
    /// Allowed parameter values.
    pub(crate) range: Range,
}

impl EffectSlot {
    /// `model` with this effect of size `value` applied.
    pub(crate) fn apply(&self, model: &Model, value: f64) -> Result<Model, ModelError> {
        self.effect.apply(model, self.location, value)
    }
}

/// The outcome of one fit.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Fitted {
    /// Calibrated linear quantities.
    pub(crate) linear: LinearValues,
    /// Fitted effect size (parameter units), when an effect was fitted.
    pub(crate) effect_value: Option<f64>,
    /// The fitted model of each bite (linear values written, effect applied).
    pub(crate) models: Vec<Model>,
    /// Sum of squared residuals over every bite, (kN*m)^2.
    pub(crate) cost: f64,
    /// Sum of squared residuals of each bite, (kN*m)^2.
    pub(crate) bite_costs: Vec<f64>,
    /// Simulated measured channel of each bite's model, kN*m.
    pub(crate) simulated: Vec<Vec<f64>>,
    /// Simulations of one bite spent.
    pub(crate) simulations: usize,
}

impl Fitted {
    /// Number of residuals (samples over every bite).
    pub(crate) fn samples(&self) -> usize {
        self.simulated.iter().map(Vec::len).sum()
    }

    /// RMS residual over every bite, kN*m.
    pub(crate) fn rmse(&self) -> f64 {
        (self.cost / self.samples().max(1) as f64).sqrt()
    }

    /// RMS residual of each bite, kN*m.
    pub(crate) fn bite_rmse(&self) -> Vec<f64> {
        self.bite_costs
            .iter()
            .zip(&self.simulated)
            .map(|(cost, s)| (cost / s.len().max(1) as f64).sqrt())
            .collect()
    }

    /// Bayesian information criterion with `parameters` fitted parameters: each bite's
    /// own noise level, `sum_b m_b ln(RSS_b / m_b) + k ln(m)` (Gaussian residuals).
    pub(crate) fn bic(&self, parameters: usize) -> f64 {
        let total = self.samples() as f64;
        let fit: f64 = self
            .bite_costs
            .iter()
            .zip(&self.simulated)
            .map(|(&cost, s)| {
                let m = s.len() as f64;
                m * (cost.max(f64::MIN_POSITIVE) / m).ln()
            })
            .sum();
        fit + parameters as f64 * total.ln()
    }
}

/// A model fitted to measured bites: the templates, the anchors of the parameters and
/// what is free. Counts the simulations it runs.
#[derive(Debug)]
pub(crate) struct Problem<'a> {
    bites: &'a [BiteRecord<'a>],
    anchor: LinearValues,
    effect: Option<(EffectSlot, f64)>,
    /// For hardening: its coupling and the twist (rad) at which the stiffness parameter
    /// is the tangent stiffness.
    tangent: Option<(usize, f64)>,
    /// RK4 steps per output sample of each bite.
    substeps: Vec<usize>,
    /// Divergence limit of each bite, kN*m.
    limits: Vec<f64>,
    /// Offset of each bite's residuals in the residual vector (and the total at the end).
    offsets: Vec<usize>,
    /// Simulations of one bite run so far.
    simulations: usize,
}

impl<'a> Problem<'a> {
    /// A problem around `anchor` (one load per bite), optionally with an effect starting
    /// at `effect_start`.
    pub(crate) fn new(
        bites: &'a [BiteRecord<'a>],
        anchor: LinearValues,
        effect: Option<(EffectSlot, f64)>,
    ) -> Result<Problem<'a>, ModelError> {
        let mut offsets = vec![0];
        for bite in bites {
            offsets.push(offsets.last().copied().unwrap_or(0) + bite.measured.len());
        }
        // The step must keep RK4 stable at the stiffest point the fit is likely to visit:
        // the effect at [`STIFFEST_EFFECT_FACTOR`] times its start (at most the top of its
        // range), stiffness and damping a little above their anchors. Beyond that a
        // trial may diverge; it is then cut short and refused.
        let mut stiffest = anchor.clone();
        for value in stiffest
            .stiffness
            .iter_mut()
            .chain(stiffest.damping.iter_mut())
        {
            *value *= 1.5;
        }
        let mut substeps = Vec::with_capacity(bites.len());
        let mut limits = Vec::with_capacity(bites.len());
        for (b, bite) in bites.iter().enumerate() {
            let base = stiffest.model_for(&bite.template, b);
            let stiffest_model = match effect {
                Some((slot, start)) => {
                    slot.apply(&base, (STIFFEST_EFFECT_FACTOR * start).min(slot.range.high))?
                }
                None => base,
            };
            let bound_hz = Simulator::new(&stiffest_model)?.frequency_bound_hz();
            let per_sample =
                SEARCH_STEPS_PER_FASTEST_PERIOD * bound_hz / bite.template.measurement.sample_rate;
            substeps.push(per_sample.ceil().clamp(1.0, MAX_SEARCH_SUBSTEPS) as usize);
            limits.push(
                DIVERGENCE_FACTOR * bite.measured.iter().fold(1.0_f64, |a, v| a.max(v.abs())),
            );
        }
        // Hardening: the coupling's stiffness parameter becomes its tangent at the
        // anchor's static twist under the largest load (the start decodes to itself).
        let mut anchor = anchor;
        let tangent = match effect {
            Some((slot, start)) if slot.effect == Effect::Hardening => slot.location.map(|i| {
                let largest_nm = anchor
                    .loads
                    .iter()
                    .fold(0.0_f64, |a, l| a.max(l.static_torque_knm))
                    * 1.0e3;
                let twist = largest_nm / anchor.stiffness[i];
                anchor.stiffness[i] += 3.0 * start * twist * twist;
                (i, twist)
            }),
            _ => None,
        };
        Ok(Problem {
            bites,
            anchor,
            effect,
            tangent,
            substeps,
            limits,
            offsets,
            simulations: 0,
        })
    }

    fn couplings(&self) -> usize {
        self.anchor.stiffness.len()
    }

    /// Parameters shared by the bites: stiffness and damping per coupling, the effect
    /// size when there is one.
    fn shared_count(&self) -> usize {
        2 * self.couplings() + usize::from(self.effect.is_some())
    }

    /// Number of fitted parameters: the shared ones, and static torque, rise rate and
    /// onset per bite.
    pub(crate) fn parameter_count(&self) -> usize {
        self.shared_count() + LOAD_PARAMETERS * self.bites.len()
    }

    /// Simulations of one bite run so far.
    pub(crate) fn simulations(&self) -> usize {
        self.simulations
    }

    /// Linear values and effect size at parameter vector `p` (`None` where a hardening
    /// larger than the tangent stiffness allows leaves no positive linear stiffness).
    fn decode(&self, p: &[f64]) -> Option<(LinearValues, Option<f64>)> {
        let n = self.couplings();
        let scale = |anchor: f64, q: f64| anchor * soft_bound(q, MAX_LOG_RATIO).exp();
        let scale_damping =
            |anchor: f64, q: f64| anchor * soft_bound(q, MAX_LOG_DAMPING_RATIO).exp();
        let mut stiffness: Vec<f64> = self
            .anchor
            .stiffness
            .iter()
            .zip(&p[..n])
            .map(|(&a, &q)| scale(a, q))
            .collect();
        let damping = self
            .anchor
            .damping
            .iter()
            .zip(&p[n..2 * n])
            .map(|(&a, &q)| scale_damping(a, q))
            .collect();
        let effect = self
            .effect
            .map(|(slot, start)| slot.range.squash(slot.range.unsquash(start) + p[2 * n]));
        if let (Some((coupling, twist)), Some(k3)) = (self.tangent, effect) {
            stiffness[coupling] -= 3.0 * k3 * twist * twist;
            if stiffness[coupling] <= 0.0 {
                return None;
            }
        }
        let at = self.shared_count();
        let loads = self
            .anchor
            .loads
            .iter()
            .zip(p[at..].chunks_exact(LOAD_PARAMETERS))
            .map(|(anchor, q)| BiteLoad {
                static_torque_knm: scale(anchor.static_torque_knm, q[0]),
                rise_rate_per_s: scale(anchor.rise_rate_per_s, q[1]),
                onset_s: (anchor.onset_s + q[2] * ONSET_UNIT_S).max(0.0),
            })
            .collect();
        Some((
            LinearValues {
                stiffness,
                damping,
                loads,
            },
            effect,
        ))
    }

    /// The model of bite `bite` for the decoded values.
    fn model_of(
        &self,
        linear: &LinearValues,
        effect: Option<f64>,
        bite: usize,
    ) -> Result<Model, ModelError> {
        let base = linear.model_for(&self.bites[bite].template, bite);
        match (self.effect, effect) {
            (Some((slot, _)), Some(value)) => slot.apply(&base, value),
            _ => Ok(base),
        }
    }

    /// Simulates bite `bite` of the decoded values into `out` (kN*m); `false` if the
    /// model is refused or the run diverged.
    fn simulate(
        &mut self,
        linear: &LinearValues,
        effect: Option<f64>,
        bite: usize,
        out: &mut [f64],
    ) -> bool {
        self.simulations += 1;
        let Ok(model) = self.model_of(linear, effect, bite) else {
            return false;
        };
        let Ok(simulator) = Simulator::new(&model) else {
            return false;
        };
        let simulator = simulator
            .with_substeps_per_sample(self.substeps[bite])
            .with_divergence_limit(self.limits[bite]);
        let mut state = simulator.initial_state();
        simulator.run_into(&mut state, out);
        out.iter().all(|v| v.is_finite())
    }

    /// Simulates bite `bite` at `p` into its block of `out` and subtracts the record.
    fn bite_residuals(
        &mut self,
        linear: &LinearValues,
        effect: Option<f64>,
        bite: usize,
        out: &mut [f64],
    ) -> bool {
        let block = &mut out[self.offsets[bite]..self.offsets[bite + 1]];
        if !self.simulate(linear, effect, bite, block) {
            return false;
        }
        for (o, y) in block.iter_mut().zip(self.bites[bite].measured) {
            *o -= y;
        }
        true
    }

    /// Levenberg-Marquardt from the anchors with [`FIT_SETTINGS`]; see
    /// [`Problem::solve_with`].
    pub(crate) fn solve(&mut self) -> Result<Option<Fitted>, ModelError> {
        self.solve_with(&FIT_SETTINGS)
    }

    /// Levenberg-Marquardt from the anchors; `None` when the point reached has no model
    /// (a hardening that leaves no positive linear stiffness; the start always has one,
    /// and only evaluated points are accepted, so this is a guard, not an outcome).
    pub(crate) fn solve_with(
        &mut self,
        settings: &LmSettings,
    ) -> Result<Option<Fitted>, ModelError> {
        let result = minimise(&vec![0.0; self.parameter_count()], settings, self);
        let Some((linear, effect_value)) = self.decode(&result.params) else {
            return Ok(None);
        };
        let mut models = Vec::with_capacity(self.bites.len());
        let mut simulated = Vec::with_capacity(self.bites.len());
        let mut bite_costs = Vec::with_capacity(self.bites.len());
        for b in 0..self.bites.len() {
            models.push(self.model_of(&linear, effect_value, b)?);
            let mut series = vec![0.0; self.bites[b].measured.len()];
            let cost = if self.simulate(&linear, effect_value, b, &mut series) {
                series
                    .iter()
                    .zip(self.bites[b].measured)
                    .map(|(s, y)| (s - y).powi(2))
                    .sum()
            } else {
                f64::INFINITY
            };
            simulated.push(series);
            bite_costs.push(cost);
        }
        Ok(Some(Fitted {
            linear,
            effect_value,
            models,
            cost: bite_costs.iter().sum(),
            bite_costs,
            simulated,
            simulations: self.simulations,
        }))
    }
}

impl Residuals for Problem<'_> {
    fn residual_count(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
    }

    fn evaluate(&mut self, p: &[f64], out: &mut [f64]) -> bool {
        let Some((linear, effect)) = self.decode(p) else {
            return false;
        };
        (0..self.bites.len()).all(|b| self.bite_residuals(&linear, effect, b, out))
    }

    /// Forward differences; a load column simulates only its own bite (the other
    /// bites' rows are zero).
    fn jacobian(&mut self, p: &[f64], r: &[f64], step: f64, jacobian: &mut DMatrix<f64>) -> bool {
        let shared = self.shared_count();
        let mut probe = p.to_vec();
        let mut shifted = vec![0.0; r.len()];
        for j in 0..p.len() {
            // Rows this column moves: every bite for a shared parameter, else its bite.
            let bites = if j < shared {
                0..self.bites.len()
            } else {
                let b = (j - shared) / LOAD_PARAMETERS;
                b..b + 1
            };
            let mut column_ok = false;
            for h in [step, -step] {
                probe[j] = p[j] + h;
                let Some((linear, effect)) = self.decode(&probe) else {
                    continue;
                };
                if bites
                    .clone()
                    .all(|b| self.bite_residuals(&linear, effect, b, &mut shifted))
                {
                    column_ok = true;
                    jacobian.column_mut(j).fill(0.0);
                    let rows = self.offsets[bites.start]..self.offsets[bites.end];
                    for i in rows {
                        jacobian[(i, j)] = (shifted[i] - r[i]) / h;
                    }
                    break;
                }
            }
            probe[j] = p[j];
            if !column_ok {
                return false;
            }
        }
        true
    }
}

/// `limit * tanh(q / limit)`: `q` near 0, never beyond +-`limit`, with a gradient
/// everywhere (a hard clamp would leave a fit stuck at the bound).
fn soft_bound(q: f64, limit: f64) -> f64 {
    limit * (q / limit).tanh()
}

/// Checks bite `b` (0-based, for the error) and returns `model` sampled on its grid:
/// its sample rate, its length.
pub(crate) fn bite_template(
    model: &Model,
    bite: &Measured<'_>,
    b: usize,
) -> Result<Model, DiscrepancyError> {
    let fail = |problem| DiscrepancyError::Bite { bite: b, problem };
    let fs = bite.sample_rate_hz;
    let m = bite.torque_knm.len();
    if !(fs.is_finite() && fs > 0.0) {
        return Err(fail(BiteProblem::SampleRate(fs)));
    }
    if m < MIN_SAMPLES {
        return Err(fail(BiteProblem::TooShort(m)));
    }
    if let Some(k) = bite.torque_knm.iter().position(|v| !v.is_finite()) {
        return Err(fail(BiteProblem::NotFinite(k)));
    }
    let mut template = model.clone();
    template.measurement.sample_rate = fs;
    template.measurement.duration = m as f64 / fs;
    template.validate("<model>")?;
    Ok(template)
}
