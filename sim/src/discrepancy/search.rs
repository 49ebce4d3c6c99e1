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

use super::effects::{Effect, Range};
use super::levenberg_marquardt::LmSettings;
use super::model_fit::{BiteRecord, EffectSlot, Fitted, LinearValues, Problem, FIT_SETTINGS};
use super::DiscrepancyError;

/// Starting sizes tried per candidate and anchor before its fit.
pub(crate) const STARTS: usize = 5;

/// Full fits per candidate, from the best short fits.
const FULL_FITS: usize = 3;

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
    pub(crate) bite_rmse: Vec<f64>,
    /// Bayesian information criterion (lower is better).
    pub bic: f64,
}

/// A candidate fitted: what is reported and the fit behind it.
#[derive(Debug, Clone)]
pub(crate) struct FittedCandidate {
    /// What is reported.
    pub(crate) candidate: Candidate,
    /// The fit.
    pub(crate) fit: Fitted,
}

/// One effect at one location to fit: its slot (the range the fit may use) and the
/// starting sizes from each anchor.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SlotPlan {
    /// The effect, its location, and the union of the anchors' ranges.
    pub(crate) slot: EffectSlot,
    /// Starting sizes per anchor ([`STARTS`] log-spaced over that anchor's range).
    pub(crate) starts: Vec<Vec<f64>>,
}

/// Every effect at every location, with its sizes relative to each anchor's driveline
/// at the largest static torque of the bites (an anchor may be far off: a misled
/// identification, a linear fit bent by the effect); `first_period_s` is the first
/// oscillation period (for the lag's range).
pub(crate) fn plans(
    bites: &[BiteRecord<'_>],
    anchors: &[LinearValues],
    first_period_s: f64,
) -> Vec<SlotPlan> {
    let drivelines: Vec<Model> = anchors
        .iter()
        .map(|values| {
            let largest = (0..values.loads.len())
                .max_by(|&a, &b| {
                    let load = |i: usize| values.loads[i].static_torque_knm;
                    load(a).total_cmp(&load(b))
                })
                .unwrap_or(0);
            values.model_for(&bites[largest].template, largest)
        })
        .collect();
    let Some(first) = drivelines.first() else {
        return Vec::new();
    };
    let mut plans = Vec::new();
    for &effect in &Effect::ALL {
        for location in effect.locations(first) {
            let ranges: Vec<Range> = drivelines
                .iter()
                .map(|d| effect.range(d, location, first_period_s))
                .collect();
            let union = Range {
                low: ranges.iter().map(|r| r.low).fold(f64::INFINITY, f64::min),
                high: ranges.iter().map(|r| r.high).fold(0.0, f64::max),
            };
            plans.push(SlotPlan {
                slot: EffectSlot {
                    effect,
                    location,
                    range: union,
                },
                starts: ranges.iter().map(|r| r.starts(STARTS)).collect(),
            });
        }
    }
    plans
}

/// Fits every planned slot from every anchor on `threads` worker threads (at least 1);
/// `on_fitted(done, total, candidate)` hears each as it is done. Returns the candidates
/// best (lowest BIC) first and the simulations of one bite spent.
pub(crate) fn search(
    bites: &[BiteRecord<'_>],
    anchors: &[LinearValues],
    plans: &[SlotPlan],
    threads: usize,
    mut on_fitted: impl FnMut(usize, usize, &Candidate),
) -> Result<(Vec<FittedCandidate>, usize), DiscrepancyError> {
    let next = AtomicUsize::new(0);
    let (sender, receiver) = mpsc::channel();
    let mut fitted = Vec::with_capacity(plans.len());
    let mut simulations = 0;
    let mut failure = None;
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, plans.len().max(1)) {
            let sender = sender.clone();
            let next = &next;
            scope.spawn(move || loop {
                let index = next.fetch_add(1, Ordering::Relaxed);
                let Some(plan) = plans.get(index) else {
                    break;
                };
                if sender.send(fit_slot(bites, anchors, plan)).is_err() {
                    break;
                }
            });
        }
        drop(sender);
        for (done, outcome) in receiver.iter().enumerate() {
            match outcome {
                Ok((Some(candidate), spent)) => {
                    simulations += spent;
                    on_fitted(done + 1, plans.len(), &candidate.candidate);
                    fitted.push(candidate);
                }
                Ok((None, spent)) => simulations += spent,
                Err(error) => {
                    // Stop handing out slots; the workers finish the ones they have.
                    next.store(plans.len(), Ordering::Relaxed);
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
    anchors: &[LinearValues],
    plan: &SlotPlan,
) -> Result<(Option<FittedCandidate>, usize), DiscrepancyError> {
    let slot = plan.slot;
    let short = LmSettings {
        max_iterations: SHORT_ITERATIONS,
        ..FIT_SETTINGS
    };
    let mut simulations = 0;
    let mut shorts: Vec<Fitted> = Vec::new();
    for (anchor, starts) in anchors.iter().zip(&plan.starts) {
        for &start in starts {
            let mut problem = Problem::new(bites, anchor.clone(), Some((slot, start)))?;
            let fit = problem.solve_with(&short)?;
            simulations += problem.simulations();
            shorts.extend(fit);
        }
    }
    shorts.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut best: Option<(Fitted, usize)> = None;
    for start in shorts.into_iter().take(FULL_FITS) {
        let size = start.effect_value.unwrap_or(slot.range.low);
        let mut problem = Problem::new(bites, start.linear, Some((slot, size)))?;
        let fit = problem.solve()?;
        simulations += problem.simulations();
        let Some(fit) = fit else { continue };
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
