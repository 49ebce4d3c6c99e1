//! The model-discrepancy workflow: calibrate a linear driveline model to a measured bite
//! transient, find where and how the two still disagree, name the physical effect the
//! model lacks, add it, and show the residual shrink.
//!
//! Steps of [`run`]:
//! 1. **Noise**: the white-noise RMS of the record from its fourth differences
//!    ([`features::noise_rms`]).
//! 2. **Calibration, the paper's way**: align the model's response in time and scale
//!    (onset, static torque); identify beta1, beta2 by the eq. (1) fit of dsp; turn them
//!    into coupling stiffness (eq. (2) for three masses, every root; a regularised
//!    least-squares modal update for N masses; the drawing values are tried too);
//!    from each, fit stiffness, damping, static torque, rise rate and onset by
//!    Levenberg-Marquardt on the whole record, and keep the best. Inertias and the
//!    motor's controller are trusted.
//! 3. **Disagreement**: residual windows above the noise and the transient features
//!    (TAF, periods, frequencies, decays, asymmetry, delay) of record and model.
//! 4. **Candidate search**: every effect of [`Effect::ALL`] at every location, its size
//!    started from the best of a few log-spaced values, then fitted jointly with the
//!    linear quantities; ranked by BIC = m ln(RSS / m) + k ln(m) (m samples, k fitted
//!    parameters).
//! 5. **Decision**: the best candidate is named when its BIC beats the calibrated linear
//!    model's by more than [`BIC_MARGIN`] ("very strong" evidence on the Kass-Raftery
//!    scale) *and* a linear model refitted from the candidate's own linear quantities
//!    does not come within that margin (so a candidate that merely helped the linear
//!    fit out of a local minimum is not mistaken for an effect); otherwise `none`.

pub mod cases;
pub mod effects;
pub mod features;
pub mod fit;
pub mod lm;
#[cfg(feature = "plot")]
pub mod report;

use std::collections::BTreeMap;

use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_dsp::stiffness::{inverse, Inertias, NaturalFrequencies, Stiffness};
use serde::Serialize;

use crate::chain::Simulator;
use crate::modal::{self, ModalError};
use crate::model::{Model, ModelError};
use crate::wear_map::default_period_lowpass_hz;

pub use effects::Effect;
use features::{Disagreement, Feature};
use fit::{EffectSlot, Fitted, LinearValues, Problem};
use lm::LmSettings;

/// BIC improvement a candidate needs over the linear model to be named.
pub const BIC_MARGIN: f64 = 10.0;

/// Starting sizes tried per candidate before its fit.
const STARTS: usize = 5;

/// Full fits per candidate, from the best short fits.
const FULL_FITS: usize = 2;

/// Iterations of each short fit from a starting size.
const SHORT_ITERATIONS: usize = 6;

/// A measured record: one channel sampled uniformly.
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// Time of the first sample, s.
    pub t0_s: f64,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// The measured torque, kN*m.
    pub torque_knm: &'a [f64],
}

/// Why the workflow could not run.
#[derive(Debug, thiserror::Error)]
pub enum DiscrepancyError {
    /// The model is not a valid driveline (or an extension of it failed to validate).
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The calibrated model's modes could not be computed.
    #[error(transparent)]
    Modal(#[from] ModalError),
    /// The record is too short, not finite or has no bite in it.
    #[error("measured record: {0}")]
    Record(String),
}

/// What the workflow reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum Progress {
    /// A step started: `noise`, `calibration`, `disagreement`, `search`, `decision`.
    Step(&'static str),
    /// A candidate was fitted: `done` of `total`.
    Candidate {
        /// Candidates fitted so far.
        done: usize,
        /// Candidates in all.
        total: usize,
        /// The effect.
        effect: Effect,
        /// Its coupling.
        location: Option<usize>,
        /// Its RMS residual, kN*m.
        rmse: f64,
    },
}

/// One adjusted quantity of the calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Adjustment {
    /// Model key, e.g. `coupling[0].stiffness`.
    pub key: String,
    /// Unit of the values.
    pub unit: &'static str,
    /// Value in the given model.
    pub model: f64,
    /// Calibrated value.
    pub calibrated: f64,
    /// Change, percent of the model value (null when the model value is 0).
    pub change_percent: Option<f64>,
}

/// One stiffness start of the calibration and how well it fitted.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StiffnessTrial {
    /// Where it came from: `eq2`, `modal_update` or `model`.
    pub source: &'static str,
    /// Starting coupling stiffness, N*m/rad.
    pub start: Vec<f64>,
    /// RMS residual after the linear fit from it, kN*m.
    pub rmse: f64,
}

/// Natural frequencies identified by the eq. (1) fit on one part of the record.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Identification {
    /// `transient` (from the bite) or `settled` (from two model periods later).
    pub window: &'static str,
    /// Start of the fitted part from the record's first sample, s.
    pub t_start_s: f64,
    /// First natural frequency, Hz.
    pub beta1_hz: f64,
    /// Second natural frequency, Hz.
    pub beta2_hz: f64,
}

/// The calibrated linear model and how it was reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    /// First natural frequency identified on the whole transient (the paper's way), Hz.
    pub beta1_hz: Option<f64>,
    /// Second natural frequency identified on the whole transient, Hz.
    pub beta2_hz: Option<f64>,
    /// Every identification made.
    pub identified: Vec<Identification>,
    /// The stiffness starts tried, best first.
    pub stiffness_trials: Vec<StiffnessTrial>,
    /// Every calibrated quantity against the model's value.
    pub adjustments: Vec<Adjustment>,
    /// RMS residual of the calibrated linear model, kN*m.
    pub rmse: f64,
}

/// One fitted candidate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// The effect.
    pub effect: Effect,
    /// Its coupling, or null.
    pub location: Option<usize>,
    /// Fitted size, in the unit of the effect's parameter key.
    pub value: f64,
    /// RMS residual, kN*m.
    pub rmse: f64,
    /// Bayesian information criterion (lower is better).
    pub bic: f64,
}

/// The workflow's result; serialises to the documented JSON.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// How the linear model was calibrated.
    pub calibration: Calibration,
    /// White-noise RMS estimated from the record, kN*m.
    pub noise_rms: f64,
    /// Where the calibrated linear model departs from the record.
    pub disagreement: Vec<Disagreement>,
    /// Transient features of the record and of the calibrated linear model.
    pub features: Vec<Feature>,
    /// The named effect's key, or `none`.
    pub effect: &'static str,
    /// Its coupling, or null.
    pub location: Option<usize>,
    /// Its fitted parameter(s), keyed with their unit.
    pub parameters: BTreeMap<&'static str, f64>,
    /// RMS residual of the calibrated linear model, kN*m.
    pub rmse_before: f64,
    /// RMS residual of the extended model (the linear one when `none`), kN*m.
    pub rmse_after: f64,
    /// BIC of the calibrated linear model.
    pub bic_linear: f64,
    /// Every candidate, best (lowest BIC) first.
    pub candidates: Vec<Candidate>,
    /// Simulations run in all.
    pub simulations: usize,
    /// The series behind the report.
    #[serde(skip)]
    pub series: Series,
}

/// The record and the models' responses on its time grid.
#[derive(Debug, Clone, Default)]
pub struct Series {
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// Measured torque, kN*m.
    pub measured: Vec<f64>,
    /// Calibrated linear model, kN*m.
    pub linear: Vec<f64>,
    /// Extended model (equal to `linear` when no effect is named), kN*m.
    pub extended: Vec<f64>,
    /// The calibrated linear model.
    pub linear_model: Option<Model>,
    /// The extended model, when an effect was named.
    pub extended_model: Option<Model>,
}

/// Runs the workflow on `measured` with `model` (the model's sample rate and duration
/// are replaced by the record's); `progress` hears each step and candidate.
pub fn run(
    measured: &Measured,
    model: &Model,
    mut progress: impl FnMut(Progress),
) -> Result<Report, DiscrepancyError> {
    let y = measured.torque_knm;
    let fs = measured.sample_rate_hz;
    let m = y.len();
    if !(fs.is_finite() && fs > 0.0) {
        return Err(DiscrepancyError::Record(format!(
            "sample rate {fs} Hz is not > 0"
        )));
    }
    if m < 100 {
        return Err(DiscrepancyError::Record(format!(
            "{m} samples; at least 100 are needed"
        )));
    }
    if let Some(k) = y.iter().position(|v| !v.is_finite()) {
        return Err(DiscrepancyError::Record(format!(
            "sample {k} is not a finite number"
        )));
    }
    let mut template = model.clone();
    template.measurement.sample_rate = fs;
    template.measurement.duration = m as f64 / fs;
    template.validate("<model>")?;
    let mut simulations = 0;

    progress(Progress::Step("noise"));
    let noise = features::noise_rms(y);

    progress(Progress::Step("calibration"));
    let Calibrated {
        calibration,
        best: linear,
        anchors,
    } = calibrate(&template, y, &mut simulations)?;
    let f1 = calibration
        .beta1_hz
        .unwrap_or_else(|| first_mode_hz(&linear.model));
    let onset_index = ((linear.linear.onset_s * fs).ceil() as usize).min(m - 1);

    progress(Progress::Step("disagreement"));
    let period_samples = (fs / f1).round() as usize;
    let disagreement = features::disagreements(
        y,
        &linear.simulated,
        noise,
        measured.t0_s,
        fs,
        onset_index,
        period_samples,
    );
    let feature_list = features::compare(
        y,
        &linear.simulated,
        fs,
        onset_index,
        default_period_lowpass_hz(&linear.model)?,
    );

    progress(Progress::Step("search"));
    let slots: Vec<(Effect, Option<usize>)> = Effect::ALL
        .iter()
        .flat_map(|&e| e.locations(&linear.model).into_iter().map(move |l| (e, l)))
        .collect();
    let total = slots.len();
    let bic = |cost: f64, k: usize| m as f64 * (cost / m as f64).ln() + k as f64 * (m as f64).ln();
    let linear_k = Problem::new(&template, y, linear.linear.clone(), None)?.parameter_count();
    let mut fitted: Vec<(Candidate, Fitted)> = Vec::with_capacity(total);
    for (done, (effect, location)) in slots.into_iter().enumerate() {
        // Sizes relative to the given model: the calibrated one may be distorted by the
        // very effect being looked for.
        let range = effect.range(&template, location, 1.0 / f1);
        let slot = EffectSlot {
            effect,
            location,
            range,
        };
        let mut fit: Option<Fitted> = None;
        let mut k = 0;
        for (start, anchor) in best_starts(&template, y, &anchors, slot, &mut simulations)? {
            let problem = Problem::new(&template, y, anchor, Some((slot, start)))?;
            k = problem.parameter_count();
            let full = problem.solve()?;
            simulations += full.evaluations;
            if fit.as_ref().is_none_or(|f| full.cost < f.cost) {
                fit = Some(full);
            }
        }
        let Some(fit) = fit else { continue };
        let candidate = Candidate {
            effect,
            location,
            value: fit.effect_value.unwrap_or(range.low),
            rmse: (fit.cost / m as f64).sqrt(),
            bic: bic(fit.cost, k),
        };
        progress(Progress::Candidate {
            done: done + 1,
            total,
            effect,
            location,
            rmse: candidate.rmse,
        });
        fitted.push((candidate, fit));
    }
    fitted.sort_by(|a, b| a.0.bic.total_cmp(&b.0.bic));

    progress(Progress::Step("decision"));
    let mut linear = linear;
    let mut bic_linear = bic(linear.cost, linear_k);
    let mut named = None;
    if let Some((best, fit)) = fitted.first() {
        if best.bic < bic_linear - BIC_MARGIN {
            // Could the linear model alone get there from the candidate's values?
            let refit = Problem::new(&template, y, fit.linear.clone(), None)?.solve()?;
            simulations += refit.evaluations;
            if refit.cost < linear.cost {
                linear = refit;
                bic_linear = bic(linear.cost, linear_k);
            }
            if best.bic < bic_linear - BIC_MARGIN {
                named = Some((best.clone(), fit.clone()));
            }
        }
    }

    let rmse_before = (linear.cost / m as f64).sqrt();
    let t_s: Vec<f64> = (0..m).map(|k| measured.t0_s + k as f64 / fs).collect();
    let mut parameters = BTreeMap::new();
    let (effect, location, rmse_after, extended, extended_model) = match &named {
        Some((candidate, fit)) => {
            parameters.insert(candidate.effect.parameter_key(), candidate.value);
            (
                candidate.effect.key(),
                candidate.location,
                candidate.rmse,
                fit.simulated.clone(),
                Some(fit.model.clone()),
            )
        }
        None => ("none", None, rmse_before, linear.simulated.clone(), None),
    };
    let mut calibration = calibration;
    calibration.adjustments = adjustments(model, &linear.linear);
    calibration.rmse = rmse_before;
    Ok(Report {
        calibration,
        noise_rms: noise,
        disagreement,
        features: feature_list,
        effect,
        location,
        parameters,
        rmse_before,
        rmse_after,
        bic_linear,
        candidates: fitted.into_iter().map(|(c, _)| c).collect(),
        simulations,
        series: Series {
            t_s,
            measured: y.to_vec(),
            linear: linear.simulated.clone(),
            extended,
            linear_model: Some(linear.model),
            extended_model,
        },
    })
}

/// Fits the linear model: alignment, identification, stiffness starts, LM from each.
///
/// Returns the calibration, the best linear fit and the prior: the model's own values
/// aligned in onset and static torque (a second anchor for the candidate search, for
/// when the effect pulled the linear fit far from the truth).
fn calibrate(
    template: &Model,
    y: &[f64],
    simulations: &mut usize,
) -> Result<Calibrated, DiscrepancyError> {
    let fs = template.measurement.sample_rate;
    let mut prior = LinearValues::of(template);
    let (onset_s, scale) = align(template, y)?;
    *simulations += 1;
    prior.onset_s = onset_s;
    prior.static_torque_knm = (prior.static_torque_knm * scale).max(1.0e-3);

    // The paper identifies on the whole transient. A gap that closes after the bite
    // biases that; once the first swings are over the gaps stay closed, so the settled
    // part (from two periods of the model's first mode after the bite) is identified too.
    let onset_index = ((onset_s * fs).ceil() as usize).min(y.len() - 1);
    let settled_index = onset_index + (2.0 * fs / first_mode_hz(template)).round() as usize;
    let mut identified = Vec::new();
    for (window, from) in [("transient", onset_index), ("settled", settled_index)] {
        if let Some(fit) = y
            .get(from..)
            .and_then(|part| fit_eq1(part, &FitOptions::new(fs)).ok())
        {
            identified.push(Identification {
                window,
                t_start_s: from as f64 / fs,
                beta1_hz: fit.f1_hz,
                beta2_hz: fit.f2_hz,
            });
        }
    }

    let mut starts: Vec<(&'static str, Vec<f64>)> = Vec::new();
    for id in &identified {
        let betas = [id.beta1_hz, id.beta2_hz];
        if template.masses.len() == 3 {
            // A root more than 10x from the drawings is not a stiffness error but a
            // sign the identification was misled (a gap or a third mode in the record).
            let plausible = |root: &Vec<f64>| {
                root.iter()
                    .zip(&prior.stiffness)
                    .all(|(c, d)| (c / d).ln().abs() <= fit::MAX_LOG_RATIO)
            };
            starts.extend(
                eq2_roots(template, &prior.stiffness, &betas)
                    .into_iter()
                    .filter(plausible)
                    .map(|root| ("eq2", root)),
            );
        } else if let Some(stiffness) = modal_update(template, &prior.stiffness, &betas) {
            starts.push(("modal_update", stiffness));
        }
    }
    starts.push(("model", prior.stiffness.clone()));

    let mut fits: Vec<(StiffnessTrial, Fitted)> = Vec::with_capacity(starts.len());
    for (source, stiffness) in starts {
        let mut start = prior.clone();
        start.stiffness = stiffness.clone();
        let fit = Problem::new(template, y, start, None)?.solve()?;
        *simulations += fit.evaluations;
        let trial = StiffnessTrial {
            source,
            start: stiffness,
            rmse: (fit.cost / y.len() as f64).sqrt(),
        };
        fits.push((trial, fit));
    }
    fits.sort_by(|a, b| a.1.cost.total_cmp(&b.1.cost));
    let mut anchors: Vec<LinearValues> =
        fits.iter().take(2).map(|(_, f)| f.linear.clone()).collect();
    anchors.push(prior);
    let (trials, mut fitted): (Vec<StiffnessTrial>, Vec<Fitted>) = fits.into_iter().unzip();
    if fitted.is_empty() {
        return Err(DiscrepancyError::Record("no calibration start".into()));
    }
    let best = fitted.swap_remove(0);
    Ok(Calibrated {
        calibration: Calibration {
            beta1_hz: identified.first().map(|id| id.beta1_hz),
            beta2_hz: identified.first().map(|id| id.beta2_hz),
            identified,
            stiffness_trials: trials,
            adjustments: Vec::new(),
            rmse: (best.cost / y.len() as f64).sqrt(),
        },
        best,
        anchors,
    })
}

/// What [`calibrate`] found.
struct Calibrated {
    calibration: Calibration,
    /// The best linear fit.
    best: Fitted,
    /// Linear values to start the candidate search from: the two best linear fits and
    /// the model's own values aligned in onset and static torque (for when an effect
    /// pulled every linear fit far from the truth).
    anchors: Vec<LinearValues>,
}

/// Every (C12, C23) root of eq. (2) for the identified `betas` (Hz), nearest `drawing`
/// first; none when the frequencies admit no positive stiffness.
fn eq2_roots(template: &Model, drawing: &[f64], betas: &[f64; 2]) -> Vec<Vec<f64>> {
    let q = Inertias {
        q1_kgm2: template.masses[0].inertia,
        q2_kgm2: template.masses[1].inertia,
        q3_kgm2: template.masses[2].inertia,
    };
    let drawing = Stiffness {
        c12_nm_per_rad: drawing[0],
        c23_nm_per_rad: drawing[1],
    };
    let beta = NaturalFrequencies {
        beta1_hz: betas[0],
        beta2_hz: betas[1],
    };
    inverse(&q, &beta, Some(&drawing)).map_or_else(
        |_| Vec::new(),
        |roots| {
            roots
                .iter()
                .map(|r| vec![r.c12_nm_per_rad, r.c23_nm_per_rad])
                .collect()
        },
    )
}

/// Onset (s) and load scale that best align the model's response with the record.
///
/// Before the bite the chain is at rest, so the response to a load starting at `o` is
/// the response to a load starting at 0 delayed by `o`; and a linear chain's response
/// is proportional to the static load. One simulation from onset 0 is shifted over
/// every sample and scaled by least squares.
fn align(template: &Model, y: &[f64]) -> Result<(f64, f64), DiscrepancyError> {
    let fs = template.measurement.sample_rate;
    let mut at_zero = template.clone();
    at_zero.load.onset = 0.0;
    let response = Simulator::new(&at_zero)?.run().torque_knm;
    let m = y.len();
    let mut best = (f64::INFINITY, 0, 1.0);
    for shift in 0..m / 2 {
        let mut dot = 0.0;
        let mut energy = 0.0;
        for k in shift..m {
            dot += response[k - shift] * y[k];
            energy += response[k - shift] * response[k - shift];
        }
        if energy <= 0.0 {
            continue;
        }
        let scale = dot / energy;
        let cost: f64 = (0..m)
            .map(|k| {
                let model = if k >= shift {
                    scale * response[k - shift]
                } else {
                    0.0
                };
                (y[k] - model).powi(2)
            })
            .sum();
        if cost < best.0 {
            best = (cost, shift, scale);
        }
    }
    if !best.0.is_finite() || best.2 <= 0.0 {
        return Err(DiscrepancyError::Record(
            "no bite found: the record does not look like a load step".into(),
        ));
    }
    Ok((best.1 as f64 / fs, best.2))
}

/// Weight of the pull towards the drawing stiffness in the modal update: small, so the
/// identified frequencies are met (to ~0.1%) and the drawings only choose among the
/// stiffness sets that meet them.
const REGULARISATION: f64 = 0.01;

/// Least-squares modal update for N masses: stiffness that gives the two identified
/// frequencies as the first two elastic modes, regularised towards the drawing values
/// (weight [`REGULARISATION`] on each ln(C / C_drawing)), by Levenberg-Marquardt.
fn modal_update(template: &Model, drawing: &[f64], identified_hz: &[f64; 2]) -> Option<Vec<f64>> {
    let mass = modal::mass_matrix(template);
    let frequencies = |p: &[f64]| -> Option<Vec<f64>> {
        let stiffness: Vec<f64> = drawing.iter().zip(p).map(|(c, q)| c * q.exp()).collect();
        let k = modal::chain_matrix(&stiffness);
        let modes = modal::solve(&mass, &k).ok()?;
        let elastic: Vec<f64> = modes.elastic_hz().take(2).collect();
        (elastic.len() == 2).then_some(elastic)
    };
    let n = drawing.len();
    let result = lm::minimise(
        &vec![0.0; n],
        2 + n,
        &lm::LmSettings::default(),
        |p, out| {
            let Some(f) = frequencies(p) else {
                return false;
            };
            out[0] = f[0] / identified_hz[0] - 1.0;
            out[1] = f[1] / identified_hz[1] - 1.0;
            for (o, q) in out[2..].iter_mut().zip(p) {
                *o = REGULARISATION * q;
            }
            true
        },
    );
    result.cost.is_finite().then(|| {
        drawing
            .iter()
            .zip(&result.params)
            .map(|(c, q)| c * q.exp())
            .collect()
    })
}

/// The [`FULL_FITS`] best of short joint fits from each of the effect's log-spaced
/// starting sizes and each linear anchor: their effect sizes and linear values.
///
/// An effect and the linear quantities trade off (a gap delays the torque like a later
/// onset does; hardening stiffens like a larger stiffness does), so the cost has several
/// valleys, and the calibrated linear model may sit far from the truth because it had to
/// mimic the effect. A few short fits from spread-out sizes, from the calibrated and the
/// model's own values, find the deepest valleys for a fraction of a full fit each.
fn best_starts(
    template: &Model,
    y: &[f64],
    anchors: &[LinearValues],
    slot: EffectSlot,
    simulations: &mut usize,
) -> Result<Vec<(f64, LinearValues)>, ModelError> {
    let short = LmSettings {
        max_iterations: SHORT_ITERATIONS,
        ..LmSettings::default()
    };
    let mut fits: Vec<Fitted> = Vec::new();
    for anchor in anchors {
        for start in slot.range.starts(STARTS) {
            let problem = Problem::new(template, y, anchor.clone(), Some((slot, start)))?;
            let fit = problem.solve_with(&short)?;
            *simulations += fit.evaluations;
            fits.push(fit);
        }
    }
    fits.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    Ok(fits
        .into_iter()
        .take(FULL_FITS)
        .map(|fit| (fit.effect_value.unwrap_or(slot.range.low), fit.linear))
        .collect())
}

/// First elastic natural frequency of `model`, Hz (1 Hz if none is found).
fn first_mode_hz(model: &Model) -> f64 {
    modal::modes(model)
        .ok()
        .and_then(|m| m.elastic_hz().next())
        .unwrap_or(1.0)
}

/// Every calibrated quantity against the value in `model`.
fn adjustments(model: &Model, calibrated: &LinearValues) -> Vec<Adjustment> {
    let entry = |key: String, unit, before: f64, after: f64| Adjustment {
        key,
        unit,
        model: before,
        calibrated: after,
        change_percent: (before != 0.0).then(|| 100.0 * (after / before - 1.0)),
    };
    let mut list = Vec::new();
    for (i, c) in model.couplings.iter().enumerate() {
        list.push(entry(
            format!("coupling[{i}].stiffness"),
            "N*m/rad",
            c.stiffness,
            calibrated.stiffness[i],
        ));
    }
    for (i, c) in model.couplings.iter().enumerate() {
        list.push(entry(
            format!("coupling[{i}].damping"),
            "N*m*s/rad",
            c.damping,
            calibrated.damping[i],
        ));
    }
    list.push(entry(
        "load.static_torque".into(),
        "kN*m",
        model.load.static_torque,
        calibrated.static_torque_knm,
    ));
    list.push(entry(
        "load.rise_rate".into(),
        "1/s",
        model.load.rise_rate,
        calibrated.rise_rate_per_s,
    ));
    list.push(entry(
        "load.onset".into(),
        "s",
        model.load.onset,
        calibrated.onset_s,
    ));
    list
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Coupling, Mass};

    /// A four-mass chain: eq. (2) does not apply, the modal update does.
    fn four_masses(stiffness: [f64; 3]) -> Model {
        let mut model =
            Model::from_toml_str(include_str!("../../models/table2-adjusted.toml"), "t2").unwrap();
        model.masses = [46.7e3, 11.85e3, 4.0e3, 2.48e3]
            .iter()
            .enumerate()
            .map(|(i, &inertia)| Mass {
                name: format!("m{i}"),
                inertia,
            })
            .collect();
        model.couplings = stiffness
            .iter()
            .map(|&c| Coupling::linear("c", c, 1.0e4))
            .collect();
        model
    }

    fn elastic_modes(model: &Model) -> Vec<f64> {
        modal::modes(model).unwrap().elastic_hz().collect()
    }

    #[test]
    fn modal_update_moves_drawing_stiffness_to_the_identified_frequencies() {
        let truth = four_masses([68.77e6, 60.0e6, 32.81e6]);
        let drawings = four_masses([214.1e6, 80.0e6, 30.68e6]);
        let target = elastic_modes(&truth);
        let start = drawings
            .couplings
            .iter()
            .map(|c| c.stiffness)
            .collect::<Vec<_>>();
        assert!((elastic_modes(&drawings)[0] / target[0] - 1.0).abs() > 0.1);
        let updated = modal_update(&drawings, &start, &[target[0], target[1]]).unwrap();
        let mut model = drawings.clone();
        for (coupling, c) in model.couplings.iter_mut().zip(&updated) {
            coupling.stiffness = *c;
        }
        let got = elastic_modes(&model);
        for k in 0..2 {
            assert!(
                (got[k] / target[k] - 1.0).abs() < 0.01,
                "{got:?} vs {target:?}"
            );
        }
    }
}
