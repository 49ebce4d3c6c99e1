//! Fitting a model to a measured record: the parametrisation shared by the linear
//! calibration and every candidate effect, and the residual it minimises.
//!
//! Parameters live in a space where the fit is well scaled and the bounds hold by
//! construction, smoothly (a clamp would stall the fit at a bound): `ln(value /
//! anchor)` for stiffness, damping, static torque and rise rate, squashed by a tanh
//! into a factor 10 (100 for damping) of the anchor; the logit of the effect size's
//! position between the logarithms of its range's ends; and `(onset - anchor) / 1 ms`
//! for the onset. The integration step is fixed for a whole
//! fit (from the anchor model with the effect at the top of its range), so the
//! residual is a smooth function of the parameters and forward differences work.

use crate::chain::Simulator;
use crate::model::{Model, ModelError};

use super::effects::{Effect, Range};
use super::lm::{minimise, LmSettings};

/// Onset parameter unit, s.
const ONSET_UNIT_S: f64 = 1.0e-3;

/// RK4 steps per period of the fastest motion during the search. RK4 is stable up to
/// 2.78 / (2 pi) = 0.44 periods per step, so 15 steps leave a 6.6x margin and resolve
/// the stick-slip transitions of friction (whose slope sets the fastest motion); the slow
/// modes that the record shows get hundreds of steps per period anyway. (The simulator's
/// own choice, 50, buys accuracy for the fastest motion, which here is a heavily damped
/// or stiff one that the record does not resolve.)
const SEARCH_STEPS_PER_FASTEST_PERIOD: f64 = 15.0;

/// Cap on RK4 steps per output sample during the search.
const MAX_SEARCH_SUBSTEPS: f64 = 24.0;

/// A simulation is abandoned once its output exceeds this multiple of the record's
/// largest |value|: no model that far off can win, and unstable trials end early.
const DIVERGENCE_FACTOR: f64 = 20.0;

/// Largest |ln ratio| a stiffness, static torque or rise rate may move from its anchor
/// in one fit (a factor of 10): drawings are wrong by tens of percent, seldom by 10x.
pub const MAX_LOG_RATIO: f64 = std::f64::consts::LN_10;

/// Largest |ln ratio| a damping may move from its anchor (a factor of 100): model
/// damping is often a guess.
const MAX_LOG_DAMPING_RATIO: f64 = 2.0 * std::f64::consts::LN_10;

/// Values of the linear model's calibrated quantities.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearValues {
    /// Coupling stiffness, N*m/rad, one per coupling.
    pub stiffness: Vec<f64>,
    /// Coupling damping, N*m*s/rad, one per coupling (> 0).
    pub damping: Vec<f64>,
    /// Static rolling torque, kN*m.
    pub static_torque_knm: f64,
    /// Load rise rate, 1/s.
    pub rise_rate_per_s: f64,
    /// Onset of the load rise from the record's first sample, s.
    pub onset_s: f64,
}

impl LinearValues {
    /// The values written in `model`; a zero damping becomes a small positive one so
    /// its logarithm exists (1e-6 of the stiffness, s).
    pub fn of(model: &Model) -> LinearValues {
        LinearValues {
            stiffness: model.couplings.iter().map(|c| c.stiffness).collect(),
            damping: model
                .couplings
                .iter()
                .map(|c| c.damping.max(1.0e-6 * c.stiffness))
                .collect(),
            static_torque_knm: model.load.static_torque.max(1.0e-3),
            rise_rate_per_s: model.load.rise_rate,
            onset_s: model.load.onset,
        }
    }

    /// `model` with these values written in.
    pub fn write_into(&self, model: &Model) -> Model {
        let mut out = model.clone();
        for (coupling, (&stiffness, &damping)) in out
            .couplings
            .iter_mut()
            .zip(self.stiffness.iter().zip(&self.damping))
        {
            coupling.stiffness = stiffness;
            coupling.damping = damping;
        }
        out.load.static_torque = self.static_torque_knm;
        out.load.rise_rate = self.rise_rate_per_s;
        out.load.onset = self.onset_s;
        out
    }
}

/// An effect being fitted: which, where, its range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EffectSlot {
    /// The effect.
    pub effect: Effect,
    /// Its coupling, or `None` for the measured channel.
    pub location: Option<usize>,
    /// Allowed parameter values.
    pub range: Range,
}

/// The outcome of one fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    /// Calibrated linear quantities.
    pub linear: LinearValues,
    /// Fitted effect size (parameter units), when an effect was fitted.
    pub effect_value: Option<f64>,
    /// The fitted model (linear values written, effect applied).
    pub model: Model,
    /// Sum of squared residuals, (kN*m)^2.
    pub cost: f64,
    /// Simulated measured channel of `model`, kN*m.
    pub simulated: Vec<f64>,
    /// Simulations spent.
    pub evaluations: usize,
}

/// A model fitted to one measured record: the template (masses, motor, measurement
/// grid), the anchors of the parameters and what is free.
#[derive(Debug)]
pub struct Problem<'a> {
    template: &'a Model,
    measured: &'a [f64],
    anchor: LinearValues,
    effect: Option<(EffectSlot, f64)>,
    substeps: usize,
    divergence_limit_knm: f64,
}

impl<'a> Problem<'a> {
    /// A problem around `anchor`, optionally with an effect starting at `effect_start`.
    ///
    /// `template` must already sample at the record's rate and length.
    pub fn new(
        template: &'a Model,
        measured: &'a [f64],
        anchor: LinearValues,
        effect: Option<(EffectSlot, f64)>,
    ) -> Result<Problem<'a>, ModelError> {
        let mut problem = Problem {
            template,
            measured,
            anchor,
            effect,
            substeps: 1,
            divergence_limit_knm: DIVERGENCE_FACTOR
                * measured.iter().fold(1.0_f64, |a, v| a.max(v.abs())),
        };
        // The step must keep RK4 stable at the stiffest point the fit is likely to visit:
        // the effect at the top of its range, stiffness and damping a little above their
        // anchors. Beyond that a trial may diverge; it is then cut short and refused.
        let mut stiffest = problem.anchor.clone();
        for value in stiffest
            .stiffness
            .iter_mut()
            .chain(stiffest.damping.iter_mut())
        {
            *value *= 1.5;
        }
        let base = stiffest.write_into(template);
        let stiffest_model = match effect {
            Some((slot, _)) => slot.effect.apply(&base, slot.location, slot.range.high)?,
            None => base,
        };
        let bound_hz = Simulator::new(&stiffest_model)?.frequency_bound_hz();
        let per_sample =
            SEARCH_STEPS_PER_FASTEST_PERIOD * bound_hz / template.measurement.sample_rate;
        problem.substeps = per_sample.ceil().clamp(1.0, MAX_SEARCH_SUBSTEPS) as usize;
        Ok(problem)
    }

    fn couplings(&self) -> usize {
        self.anchor.stiffness.len()
    }

    /// Number of fitted parameters: stiffness and damping per coupling, static torque,
    /// rise rate, onset, and the effect size when there is one.
    pub fn parameter_count(&self) -> usize {
        2 * self.couplings() + 3 + usize::from(self.effect.is_some())
    }

    /// Linear values and effect size at parameter vector `p`.
    fn decode(&self, p: &[f64]) -> (LinearValues, Option<f64>) {
        let n = self.couplings();
        let scale = |anchor: f64, q: f64| anchor * soft_bound(q, MAX_LOG_RATIO).exp();
        let scale_damping =
            |anchor: f64, q: f64| anchor * soft_bound(q, MAX_LOG_DAMPING_RATIO).exp();
        let stiffness = self
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
        let at = 2 * n;
        let linear = LinearValues {
            stiffness,
            damping,
            static_torque_knm: scale(self.anchor.static_torque_knm, p[at]),
            rise_rate_per_s: scale(self.anchor.rise_rate_per_s, p[at + 1]),
            onset_s: (self.anchor.onset_s + p[at + 2] * ONSET_UNIT_S).max(0.0),
        };
        let effect = self
            .effect
            .map(|(slot, start)| slot.range.squash(slot.range.unsquash(start) + p[at + 3]));
        (linear, effect)
    }

    /// The model at parameter vector `p`.
    fn model_at(&self, p: &[f64]) -> Result<(Model, LinearValues, Option<f64>), ModelError> {
        let (linear, effect) = self.decode(p);
        let base = linear.write_into(self.template);
        let model = match (self.effect, effect) {
            (Some((slot, _)), Some(value)) => slot.effect.apply(&base, slot.location, value)?,
            _ => base,
        };
        Ok((model, linear, effect))
    }

    /// Simulates the model at `p` into `out` (kN*m); `false` if the model is refused.
    fn simulate(&self, p: &[f64], out: &mut [f64]) -> bool {
        let Ok((model, _, _)) = self.model_at(p) else {
            return false;
        };
        let Ok(simulator) = Simulator::new(&model) else {
            return false;
        };
        let simulator = simulator
            .with_substeps_per_sample(self.substeps)
            .with_divergence_limit(self.divergence_limit_knm);
        let mut state = simulator.initial_state();
        simulator.run_into(&mut state, out);
        out.iter().all(|v| v.is_finite())
    }

    /// Levenberg-Marquardt from the anchors with the default settings.
    pub fn solve(&self) -> Result<Fitted, ModelError> {
        self.solve_with(&LmSettings::default())
    }

    /// Levenberg-Marquardt from the anchors.
    pub fn solve_with(&self, settings: &LmSettings) -> Result<Fitted, ModelError> {
        let m = self.measured.len();
        let result = minimise(&vec![0.0; self.parameter_count()], m, settings, |p, out| {
            if !self.simulate(p, out) {
                return false;
            }
            for (o, y) in out.iter_mut().zip(self.measured) {
                *o -= y;
            }
            true
        });
        let (model, linear, effect_value) = self.model_at(&result.params)?;
        let mut simulated = vec![0.0; m];
        self.simulate(&result.params, &mut simulated);
        Ok(Fitted {
            linear,
            effect_value,
            model,
            cost: result.cost,
            simulated,
            evaluations: result.evaluations + 1,
        })
    }
}

/// `limit * tanh(q / limit)`: `q` near 0, never beyond +-`limit`, with a gradient
/// everywhere (a hard clamp would leave a fit stuck at the bound).
fn soft_bound(q: f64, limit: f64) -> f64 {
    limit * (q / limit).tanh()
}
