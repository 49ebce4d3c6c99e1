//! The decision: which effect, if any, the bites show, and when they cannot tell.
//!
//! The best candidate is named when its BIC beats the calibrated linear model's by more
//! than [`BIC_MARGIN`] ("very strong" evidence on the Kass-Raftery scale) *and* a linear
//! model refitted from the candidate's own linear quantities does not come within that
//! margin (so a candidate that merely helped the linear fit out of a local minimum is
//! not mistaken for an effect); otherwise `none`. When another candidate (a different
//! effect or location) comes within the margin of the best, the bites cannot tell them
//! apart: both are reported, with the further record that would separate them most
//! ([`tell_apart`]).

use serde::Serialize;

use crate::chain::Simulator;
use crate::model::Model;

use super::effects::Effect;
use super::model_fit::{BiteRecord, Fitted, Problem};
use super::search::FittedCandidate;
use super::DiscrepancyError;

/// BIC improvement a candidate needs over the linear model to be named, and the BIC
/// distance within which two candidates explain the bites equally.
pub const BIC_MARGIN: f64 = 10.0;

/// Static torques tried for a further bite, as multiples of the largest static torque
/// of the bites given.
pub(crate) const FURTHER_TORQUE_FACTORS: [f64; 3] = [0.35, 0.6, 1.5];

/// What the bites show.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// One effect explains the bites clearly best.
    Named,
    /// No effect beats the calibrated linear model.
    None,
    /// Two or more effects explain the bites equally (BIC within [`BIC_MARGIN`]).
    CannotTell,
}

keyed!(Verdict);

impl Verdict {
    /// The name used in JSON and reports.
    pub(crate) fn key(self) -> &'static str {
        match self {
            Verdict::Named => "named",
            Verdict::None => "none",
            Verdict::CannotTell => "cannot_tell",
        }
    }
}

/// A further record that would tell two candidates apart.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct FurtherRecord {
    /// Static torque of the further bite, kN*m.
    pub(crate) static_torque_knm: f64,
    /// The coupling whose torque to record (0-based).
    pub(crate) measured_coupling: usize,
    /// RMS difference of the two candidates' responses on that record, kN*m.
    pub(crate) difference_rms_knm: f64,
    /// That difference over the noise of the bites given.
    pub(crate) noise_multiple: f64,
    /// The advice in words.
    pub(crate) advice: String,
}

/// The decision and the linear model it was made against.
#[derive(Debug, Clone)]
pub(crate) struct Decision {
    /// What the bites show.
    pub(crate) verdict: Verdict,
    /// Index of the named (best) candidate, unless `none`.
    pub(crate) named: Option<usize>,
    /// Indices of the candidates within [`BIC_MARGIN`] of the best.
    pub(crate) rivals: Vec<usize>,
    /// The calibrated linear model (refitted from the best candidate when that did
    /// better).
    pub(crate) linear: Fitted,
    /// BIC of the calibrated linear model.
    pub(crate) bic_linear: f64,
    /// Simulations of one bite spent on the refit.
    pub(crate) simulations: usize,
}

/// Decides among `candidates` (best first) against the calibrated `linear` fit.
pub(crate) fn decide(
    bites: &[BiteRecord<'_>],
    candidates: &[FittedCandidate],
    linear: Fitted,
) -> Result<Decision, DiscrepancyError> {
    let linear_parameters = Problem::new(bites, linear.linear.clone(), None)?.parameter_count();
    let mut decision = Decision {
        verdict: Verdict::None,
        named: None,
        rivals: Vec::new(),
        bic_linear: linear.bic(linear_parameters),
        linear,
        simulations: 0,
    };
    let Some(best) = candidates.first() else {
        return Ok(decision);
    };
    if best.candidate.bic >= decision.bic_linear - BIC_MARGIN {
        return Ok(decision);
    }
    // Could the linear model alone get there from the candidate's values?
    let mut problem = Problem::new(bites, best.fit.linear.clone(), None)?;
    let refit = problem.solve()?;
    decision.simulations += problem.simulations();
    if let Some(refit) = refit.filter(|r| r.cost < decision.linear.cost) {
        decision.bic_linear = refit.bic(linear_parameters);
        decision.linear = refit;
    }
    if best.candidate.bic >= decision.bic_linear - BIC_MARGIN {
        return Ok(decision);
    }
    decision.named = Some(0);
    decision.rivals = (1..candidates.len())
        .filter(|&i| candidates[i].candidate.bic < best.candidate.bic + BIC_MARGIN)
        .collect();
    decision.verdict = if decision.rivals.is_empty() {
        Verdict::Named
    } else {
        Verdict::CannotTell
    };
    Ok(decision)
}

/// The further record on which `a` and `b` differ most: a bite at another static torque
/// ([`FURTHER_TORQUE_FACTORS`] of the largest given), or the torque of another coupling
/// at the largest static torque given. Both candidates' first-bite models are simulated
/// on it; `noise_rms` (kN*m) scales the difference.
pub(crate) fn tell_apart(
    a: &FittedCandidate,
    b: &FittedCandidate,
    noise_rms: f64,
) -> Result<Option<FurtherRecord>, DiscrepancyError> {
    let (Some(model_a), Some(model_b)) = (largest_load(&a.fit.models), largest_load(&b.fit.models))
    else {
        return Ok(None);
    };
    let static_knm = model_a.load.static_torque;
    let measured = model_a.measurement.coupling;
    let mut options: Vec<(f64, usize)> = FURTHER_TORQUE_FACTORS
        .iter()
        .map(|f| (f * static_knm, original_coupling(&a.candidate, measured)))
        .collect();
    let couplings =
        model_a.couplings.len() - usize::from(a.candidate.effect == Effect::ExtraInertia);
    for coupling in 0..couplings {
        if coupling != original_coupling(&a.candidate, measured) {
            options.push((static_knm, coupling));
        }
    }
    let mut best: Option<FurtherRecord> = None;
    for (torque, coupling) in options {
        let response =
            |fitted: &FittedCandidate, model: &Model| -> Result<Vec<f64>, DiscrepancyError> {
                let mut model = model.clone();
                model.load.static_torque = torque;
                model.measurement.coupling = model_coupling(&fitted.candidate, coupling);
                Ok(Simulator::new(&model)?.run().torque_knm)
            };
        let (ya, yb) = (response(a, model_a)?, response(b, model_b)?);
        let n = ya.len().min(yb.len()).max(1);
        let difference = (ya
            .iter()
            .zip(&yb)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        if best
            .as_ref()
            .is_none_or(|r| difference > r.difference_rms_knm)
        {
            let what = if coupling == original_coupling(&a.candidate, measured) {
                format!("a bite at {torque:.0} kN*m static torque")
            } else {
                format!("the torque of coupling {coupling} at {torque:.0} kN*m")
            };
            best = Some(FurtherRecord {
                static_torque_knm: torque,
                measured_coupling: coupling,
                difference_rms_knm: difference,
                noise_multiple: difference / noise_rms.max(f64::MIN_POSITIVE),
                advice: format!(
                    "record {what}: {} and {} differ there by {difference:.2} kN*m RMS \
                     ({:.1}x the noise)",
                    describe(&a.candidate.effect, a.candidate.location),
                    describe(&b.candidate.effect, b.candidate.location),
                    difference / noise_rms.max(f64::MIN_POSITIVE)
                ),
            });
        }
    }
    Ok(best)
}

/// The model of the bite with the largest static torque.
fn largest_load(models: &[Model]) -> Option<&Model> {
    models
        .iter()
        .max_by(|a, b| a.load.static_torque.total_cmp(&b.load.static_torque))
}

/// An effect and where, in words.
pub(crate) fn describe(effect: &Effect, location: Option<usize>) -> String {
    match location {
        Some(i) => format!("{effect} in coupling {i}"),
        None => effect.to_string(),
    }
}

/// The coupling of the given driveline that coupling `index` of a candidate's model is
/// (an extra inertia splits its coupling in two; the motor-side half keeps the index).
fn original_coupling(candidate: &super::search::Candidate, index: usize) -> usize {
    match (candidate.effect, candidate.location) {
        (Effect::ExtraInertia, Some(split)) if index > split => index - 1,
        _ => index,
    }
}

/// The coupling of a candidate's model that is coupling `index` of the given driveline.
fn model_coupling(candidate: &super::search::Candidate, index: usize) -> usize {
    match (candidate.effect, candidate.location) {
        (Effect::ExtraInertia, Some(split)) if index > split => index + 1,
        _ => index,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::simulate_with_noise;
    use crate::discrepancy::effects::Range;
    use crate::discrepancy::model_fit::{EffectSlot, LinearValues};
    use crate::discrepancy::search::Candidate;

    /// A 0.3 s bite of the adjusted Table 2 driveline with a 2 mrad gap in the spindle.
    fn record() -> (Model, Vec<f64>) {
        let mut model =
            Model::from_toml_str(include_str!("../../models/table2-adjusted.toml"), "t2").unwrap();
        model.measurement.duration = 0.3;
        let with_gap = Effect::Backlash.apply(&model, Some(1), 2.0e-3).unwrap();
        let y = simulate_with_noise(&with_gap, 0.5, 3).unwrap().torque_knm;
        (model, y)
    }

    /// The fit of `effect` in the spindle from the model's own values, as a candidate.
    fn candidate(bites: &[BiteRecord<'_>], effect: Effect, start: f64) -> FittedCandidate {
        let model = &bites[0].template;
        let slot = EffectSlot {
            effect,
            location: Some(1),
            range: Range {
                low: 1.0e-3 * start,
                high: 1.0e3 * start,
            },
        };
        let mut problem =
            Problem::new(bites, LinearValues::of(model, 1), Some((slot, start))).unwrap();
        let fit = problem.solve().unwrap().unwrap();
        FittedCandidate {
            candidate: Candidate {
                effect,
                location: Some(1),
                value: fit.effect_value.unwrap(),
                rmse: fit.rmse(),
                bite_rmse: fit.bite_rmse(),
                bic: fit.bic(problem.parameter_count()),
            },
            fit,
        }
    }

    #[test]
    fn a_rival_within_the_margin_makes_it_cannot_tell_with_a_further_record() {
        let (model, y) = record();
        let bites = [BiteRecord {
            template: model.clone(),
            measured: &y,
        }];
        let linear = Problem::new(&bites, LinearValues::of(&model, 1), None)
            .unwrap()
            .solve()
            .unwrap()
            .unwrap();
        let gap = candidate(&bites, Effect::Backlash, 1.0e-3);
        let hardening = candidate(&bites, Effect::Hardening, 3.0e11);
        assert!(gap.candidate.bic < hardening.candidate.bic - BIC_MARGIN);

        // As fitted: the gap alone explains the bite.
        let clear = [gap.clone(), hardening.clone()];
        let decision = decide(&bites, &clear, linear.clone()).unwrap();
        assert_eq!(decision.verdict, Verdict::Named);
        assert_eq!(decision.named, Some(0));
        assert!(decision.rivals.is_empty());

        // Were the hardening within the margin, the bite could not tell them apart.
        let mut close = hardening.clone();
        close.candidate.bic = gap.candidate.bic + 0.5 * BIC_MARGIN;
        let decision = decide(&bites, &[gap.clone(), close], linear.clone()).unwrap();
        assert_eq!(decision.verdict, Verdict::CannotTell);
        assert_eq!(decision.rivals, [1]);

        // Nothing beating the linear model by the margin: none.
        let mut weak = gap.clone();
        weak.candidate.bic = decision.bic_linear - 0.5 * BIC_MARGIN;
        let decision = decide(&bites, &[weak], linear).unwrap();
        assert_eq!(decision.verdict, Verdict::None);

        // The further record separates the two better than the bite given does.
        let given = (gap.fit.simulated[0]
            .iter()
            .zip(&hardening.fit.simulated[0])
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / y.len() as f64)
            .sqrt();
        let further = tell_apart(&gap, &hardening, 0.5).unwrap().unwrap();
        assert!(
            further.difference_rms_knm > given,
            "{further:?}, {given} on the bite given"
        );
        assert!(further.advice.contains("kN*m"), "{}", further.advice);
    }
}
