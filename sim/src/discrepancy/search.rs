//! The candidate search: every effect at every location, fitted jointly with the
//! linear quantities from several starts, ranked by BIC.
//!
//! An effect and the linear quantities trade off (a gap delays the torque like a later
//! onset does; hardening stiffens like a larger stiffness does), so the cost has several
//! valleys, and the calibrated linear model may sit far from the truth because it had to
//! mimic the effect. A few short fits from spread-out sizes, from each anchor of the
//! calibration, find the deepest valleys for a fraction of a full fit each; the best of
//! them are fitted in full. Slots are fitted on worker threads.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use serde::Serialize;

use crate::model::Model;

use super::calibration::Anchor;
use super::effects::Effect;
use super::fit::{BiteRecord, EffectSlot, Fitted, LinearValues, Problem, FIT_SETTINGS};
use super::lm::LmSettings;
use super::DiscrepancyError;

/// Starting sizes tried per candidate and anchor before its fit.
pub const STARTS: usize = 5;

/// Full fits per candidate, from the best short fits.
const FULL_FITS: usize = 2;

/// Iterations of each short fit from a starting size.
const SHORT_ITERATIONS: usize = 6;

/// One fitted candidate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// The effect.
    pub effect: Effect,
    /// Its coupling, or null.
    pub location: Option<usize>,
    /// Fitted size, in the unit of the effect's parameter key.
    pub value: f64,
    /// RMS residual over every bite, kN*m.
    pub rmse: f64,
    /// RMS residual of each bite, kN*m.
    pub bite_rmse: Vec<f64>,
    /// Bayesian information criterion (lower is better).
    pub bic: f64,
}

/// A candidate fitted: what is reported and the fit behind it.
#[derive(Debug, Clone)]
pub struct FittedCandidate {
    /// What is reported.
    pub candidate: Candidate,
    /// The fit.
    pub fit: Fitted,
}

/// Every effect at every location of `reference` (the calibrated driveline at the
/// largest static torque of the bites), with its size range; `first_period_s` is the
/// first oscillation period (for the lag's range).
pub fn slots(reference: &Model, first_period_s: f64) -> Vec<EffectSlot> {
    Effect::ALL
        .iter()
        .flat_map(|&effect| {
            effect
                .locations(reference)
                .into_iter()
                .map(move |location| EffectSlot {
                    effect,
                    location,
                    range: effect.range(reference, location, first_period_s),
                })
        })
        .collect()
}

/// The linear values of `anchor` for a short fit of `slot` from `start`: for hardening
/// from an identified (tangent) stiffness, that coupling's stiffness lowered so that its
/// tangent `C + 3 k3 e^2` at the static twist `e = M / C` is the identified one (what
/// the loaded part shows is the tangent; the linear stiffness is lower).
fn adapted(anchor: &Anchor, slot: EffectSlot, start: f64) -> LinearValues {
    let values = &anchor.values;
    let (Effect::Hardening, Some(coupling), Some(bite)) =
        (slot.effect, slot.location, anchor.tangent_of_bite)
    else {
        return values.clone();
    };
    let tangent = values.stiffness[coupling];
    let torque_nm = values.loads[bite].static_torque_knm * 1.0e3;
    let excess = |c: f64| c + 3.0 * start * torque_nm * torque_nm / (c * c) - tangent;
    // excess is convex in C with its minimum at (6 k3 M^2)^(1/3); the linear stiffness
    // is the root above it (the one where hardening is the smaller part).
    let mut low = (6.0 * start * torque_nm * torque_nm).cbrt();
    let mut high = tangent;
    if !(low < high && excess(low) < 0.0) {
        return values.clone();
    }
    for _ in 0..60 {
        let middle = 0.5 * (low + high);
        if excess(middle) < 0.0 {
            low = middle;
        } else {
            high = middle;
        }
    }
    let mut stiffness = values.stiffness.clone();
    stiffness[coupling] = high;
    values.with_stiffness(&stiffness)
}

/// Fits every slot from every anchor on `threads` worker threads (at least 1);
/// `on_fitted(done, total, candidate)` hears each as it is done. Returns the candidates
/// best (lowest BIC) first and the simulations of one bite spent.
pub fn search(
    bites: &[BiteRecord<'_>],
    anchors: &[Anchor],
    slots: &[EffectSlot],
    threads: usize,
    mut on_fitted: impl FnMut(usize, usize, &Candidate),
) -> Result<(Vec<FittedCandidate>, usize), DiscrepancyError> {
    let next = AtomicUsize::new(0);
    let (sender, receiver) = mpsc::channel();
    let mut fitted = Vec::with_capacity(slots.len());
    let mut simulations = 0;
    let mut failure = None;
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, slots.len().max(1)) {
            let sender = sender.clone();
            let next = &next;
            scope.spawn(move || loop {
                let index = next.fetch_add(1, Ordering::Relaxed);
                let Some(&slot) = slots.get(index) else {
                    break;
                };
                if sender.send(fit_slot(bites, anchors, slot)).is_err() {
                    break;
                }
            });
        }
        drop(sender);
        for (done, outcome) in receiver.iter().enumerate() {
            match outcome {
                Ok((Some(candidate), spent)) => {
                    simulations += spent;
                    on_fitted(done + 1, slots.len(), &candidate.candidate);
                    fitted.push(candidate);
                }
                Ok((None, spent)) => simulations += spent,
                Err(error) => {
                    // Stop handing out slots; the workers finish the ones they have.
                    next.store(slots.len(), Ordering::Relaxed);
                    failure.get_or_insert(error);
                }
            }
        }
    });
    if let Some(error) = failure {
        return Err(error);
    }
    fitted.sort_by(|a, b| a.candidate.bic.total_cmp(&b.candidate.bic));
    Ok((fitted, simulations))
}

/// The best fit of one slot: short fits from every anchor and starting size, the
/// [`FULL_FITS`] best of them in full. Also the simulations spent.
fn fit_slot(
    bites: &[BiteRecord<'_>],
    anchors: &[Anchor],
    slot: EffectSlot,
) -> Result<(Option<FittedCandidate>, usize), DiscrepancyError> {
    let short = LmSettings {
        max_iterations: SHORT_ITERATIONS,
        ..FIT_SETTINGS
    };
    let mut simulations = 0;
    let mut shorts: Vec<Fitted> = Vec::new();
    for anchor in anchors {
        for start in slot.range.starts(STARTS) {
            let anchor = adapted(anchor, slot, start);
            let fit = Problem::new(bites, anchor, Some((slot, start)))?.solve_with(&short)?;
            simulations += fit.simulations;
            shorts.push(fit);
        }
    }
    shorts.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut best: Option<(Fitted, usize)> = None;
    for start in shorts.into_iter().take(FULL_FITS) {
        let size = start.effect_value.unwrap_or(slot.range.low);
        let mut problem = Problem::new(bites, start.linear, Some((slot, size)))?;
        let fit = problem.solve()?;
        simulations += fit.simulations;
        if best.as_ref().is_none_or(|(b, _)| fit.cost < b.cost) {
            best = Some((fit, problem.parameter_count()));
        }
    }
    let candidate = best.map(|(fit, parameters)| FittedCandidate {
        candidate: Candidate {
            effect: slot.effect,
            location: slot.location,
            value: fit.effect_value.unwrap_or(slot.range.low),
            rmse: fit.rmse(),
            bite_rmse: fit.bite_rmse(),
            bic: fit.bic(parameters),
        },
        fit,
    });
    Ok((candidate, simulations))
}
