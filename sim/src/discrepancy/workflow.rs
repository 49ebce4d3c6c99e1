//! The driver: runs the steps in order over the bites and assembles the [`Report`].

use std::collections::BTreeMap;

use millgate_dsp::noise::noise_rms;
use serde::{Serialize, Serializer};

use crate::model::Model;
use crate::wear_map::default_period_lowpass_hz;

use super::calibration::{self, Calibration};
use super::decision::{self, FurtherRecord, Verdict};
use super::effects::Effect;
use super::features::{self, Feature};
use super::model_fit::{self, BiteRecord, Fitted};
use super::search::{self, Candidate, FittedCandidate};
use super::windows::{self, BiteTiming, Disagreement};
use super::{DiscrepancyError, Measured, Progress, Step};

/// How the workflow runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Settings {
    /// Worker threads of the candidate search, >= 1 (default: the machine's cores).
    pub threads: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }
}

/// One bite's place in the result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BiteSummary {
    /// Time of the bite record's first sample, s.
    pub(crate) t0_s: f64,
    /// Samples in the bite record.
    pub(crate) samples: usize,
    /// White-noise RMS estimated from the bite, kN*m.
    pub(crate) noise_rms: f64,
    /// Fitted static torque, kN*m (of the extended model, or the linear one).
    pub(crate) static_torque_knm: f64,
    /// Fitted load rise rate, 1/s.
    pub(crate) rise_rate_per_s: f64,
    /// Fitted onset from the bite record's first sample, s.
    pub(crate) onset_s: f64,
    /// RMS residual of the calibrated linear model on this bite, kN*m.
    pub(crate) rmse_before: f64,
    /// RMS residual of the extended model on this bite, kN*m.
    pub(crate) rmse_after: f64,
}

/// The workflow's result; serialises to the documented JSON.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// How the linear model was calibrated.
    pub calibration: Calibration,
    /// White-noise RMS over every bite (RMS of the bites' estimates, by samples), kN*m.
    pub(crate) noise_rms: f64,
    /// Each bite: noise, fitted load, residuals.
    pub(crate) bites: Vec<BiteSummary>,
    /// Where the calibrated linear model departs from the bites.
    pub(crate) disagreement: Vec<Disagreement>,
    /// Transient features of each bite and of the calibrated linear model.
    pub(crate) features: Vec<Feature>,
    /// What the bites show.
    pub verdict: Verdict,
    /// The named effect (the best of the rivals when they cannot be told apart), or
    /// `none`.
    #[serde(serialize_with = "effect_or_none")]
    pub effect: Option<Effect>,
    /// Its coupling, or null.
    pub location: Option<usize>,
    /// Its fitted parameter(s), keyed with their unit.
    pub parameters: BTreeMap<&'static str, f64>,
    /// RMS residual of the calibrated linear model over every bite, kN*m.
    pub rmse_before: f64,
    /// RMS residual of the extended model (the linear one when `none`), kN*m.
    pub rmse_after: f64,
    /// BIC of the calibrated linear model.
    pub bic_linear: f64,
    /// Every candidate, best (lowest BIC) first.
    pub candidates: Vec<Candidate>,
    /// The other candidates within the BIC margin of the named one (empty unless
    /// `cannot_tell`).
    pub(crate) alternatives: Vec<Candidate>,
    /// The further record that would tell the best two apart, when they cannot be.
    pub(crate) tell_apart: Option<FurtherRecord>,
    /// Simulations of one bite run in all.
    pub simulations: usize,
    /// The series and models behind the report.
    #[serde(skip)]
    pub series: Series,
}

/// `None` as `"none"`, an effect as its key.
fn effect_or_none<S: Serializer>(
    effect: &Option<Effect>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(effect.map_or("none", Effect::key))
}

/// One bite and the models' responses on its time grid.
#[derive(Debug, Clone, Default)]
pub struct BiteSeries {
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// Measured torque, kN*m.
    pub measured: Vec<f64>,
    /// Calibrated linear model, kN*m.
    pub linear: Vec<f64>,
    /// Extended model (equal to `linear` when no effect is named), kN*m.
    pub extended: Vec<f64>,
}

/// The series and models behind a report.
#[derive(Debug, Clone, Default)]
pub struct Series {
    /// Each bite.
    pub bites: Vec<BiteSeries>,
    /// The calibrated linear model as fitted (with the first bite's load).
    pub linear_model: Option<Model>,
    /// The extended model (first bite's load), when an effect was named.
    pub extended_model: Option<Model>,
    /// The calibrated linear model to monitor against (first bite's load): the
    /// extended model's stiffness and damping with a nonlinear effect removed (a linear
    /// one, sensor lag or extra inertia, kept); the linear fit when no effect is named.
    /// Always `Some` in a report from [`run`] or [`run_with`] (`None` only in a
    /// `Series::default()`). The wear diagnosis monitors against it: set its `load` to
    /// the bite being monitored.
    pub calibrated_model: Option<Model>,
}

/// Runs the workflow on `bites` with `model` and the default [`Settings`]; see
/// [`run_with`].
pub fn run(
    bites: &[Measured],
    model: &Model,
    progress: impl FnMut(Progress),
) -> Result<Report, DiscrepancyError> {
    run_with(bites, model, &Settings::default(), progress)
}

/// Runs the workflow on `bites` (one or more records of the same driveline) with
/// `model` (its sample rate and duration are replaced by each bite's, its load is only
/// a start); `progress` hears each step and candidate.
///
/// ```no_run
/// use millgate_sim::discrepancy::{run, Measured};
/// let model = millgate_sim::model::Model::load("sim/models/table2-drawings.toml")?;
/// let torque: Vec<f64> = vec![0.0; 1200]; // a measured bite, kN*m at 2 kHz
/// let bite = Measured { t0_s: 0.0, sample_rate_hz: 2000.0, torque_knm: &torque };
/// let report = run(&[bite], &model, |_| {})?;
/// println!("{}", report.effect.map_or("none", |e| e.key()));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn run_with(
    bites: &[Measured],
    model: &Model,
    settings: &Settings,
    mut progress: impl FnMut(Progress),
) -> Result<Report, DiscrepancyError> {
    let records = bite_records(bites, model)?;
    let mut simulations = 0;

    progress(Progress::Step(Step::Noise));
    let noise: Vec<f64> = bites.iter().map(|b| noise_rms(b.torque_knm)).collect();

    progress(Progress::Step(Step::Calibration));
    let calibrated = calibration::calibrate(&records, &noise, &mut simulations)?;
    let f1 = loaded_first_mode_hz(&calibrated);

    progress(Progress::Step(Step::Disagreement));
    let (disagreement, features) = disagreements(bites, &calibrated.best, &noise, f1)?;

    progress(Progress::Step(Step::Search));
    let plans = search::plans(&records, &calibrated.anchors, 1.0 / f1);
    let (candidates, spent) = search::search(
        &records,
        &calibrated.anchors,
        &plans,
        settings.threads,
        |done, total, candidate| {
            progress(Progress::Candidate {
                done,
                total,
                effect: candidate.effect,
                location: candidate.location,
                rmse: candidate.rmse,
            });
        },
    )?;
    simulations += spent;

    progress(Progress::Step(Step::Decision));
    let decision = decision::decide(&records, &candidates, calibrated.best)?;
    simulations += decision.simulations;
    let findings = Findings {
        calibration: calibrated.calibration,
        noise,
        disagreement,
        features,
        candidates,
        decision,
        simulations,
    };
    report(bites, model, &records, findings)
}

/// What the steps found, for the report.
struct Findings {
    calibration: Calibration,
    /// Each bite's noise RMS, kN*m.
    noise: Vec<f64>,
    disagreement: Vec<Disagreement>,
    features: Vec<Feature>,
    /// Every candidate, best first.
    candidates: Vec<FittedCandidate>,
    decision: decision::Decision,
    /// Simulations of one bite run in all.
    simulations: usize,
}

/// The first natural frequency of the calibrated driveline, Hz: identified on the
/// loaded part of a bite, else the best linear model's.
fn loaded_first_mode_hz(calibrated: &calibration::Calibrated) -> f64 {
    calibrated
        .calibration
        .identified
        .iter()
        .find(|id| id.window == calibration::IdentificationWindow::Loaded)
        .map_or_else(
            || calibration::first_mode_hz(&calibrated.best.models[0]),
            |id| id.beta1_hz,
        )
}

/// Where the calibrated linear fit `linear` departs from each bite (windows above its
/// `noise`), and the bites' transient features against the model's; `f1` (Hz) sets
/// the period.
fn disagreements(
    bites: &[Measured],
    linear: &Fitted,
    noise: &[f64],
    f1: f64,
) -> Result<(Vec<Disagreement>, Vec<Feature>), DiscrepancyError> {
    let mut disagreement = Vec::new();
    let mut feature_list = Vec::new();
    let lowpass_hz = default_period_lowpass_hz(&linear.models[0])?;
    for (b, bite) in bites.iter().enumerate() {
        let fs = bite.sample_rate_hz;
        let y = bite.torque_knm;
        let onset_index = ((linear.linear.loads[b].onset_s * fs).ceil() as usize).min(y.len() - 1);
        let timing = BiteTiming {
            bite: b,
            t0_s: bite.t0_s,
            sample_rate_hz: fs,
            onset_index,
            period_samples: (fs / f1).round() as usize,
        };
        let simulated = &linear.simulated[b];
        disagreement.extend(windows::disagreements(y, simulated, noise[b], &timing));
        feature_list.extend(features::compare(
            b,
            y,
            simulated,
            fs,
            onset_index,
            lowpass_hz,
        ));
    }
    Ok((disagreement, feature_list))
}

/// The report of `findings` on `bites` with the handed `model`.
fn report(
    bites: &[Measured],
    model: &Model,
    records: &[BiteRecord<'_>],
    findings: Findings,
) -> Result<Report, DiscrepancyError> {
    let Findings {
        mut calibration,
        noise,
        disagreement,
        features,
        candidates,
        decision,
        simulations,
    } = findings;
    let pooled_noise = pooled_noise(bites, &noise);
    let named: Option<&FittedCandidate> = decision.named.map(|i| &candidates[i]);
    let tell_apart = match (named, decision.rivals.first()) {
        (Some(best), Some(&rival)) => decision::tell_apart(best, &candidates[rival], pooled_noise)?,
        _ => None,
    };
    let linear = &decision.linear;
    let after: &Fitted = named.map_or(linear, |c| &c.fit);
    let mut parameters = BTreeMap::new();
    if let Some(c) = named {
        parameters.insert(c.candidate.effect.parameter_key(), c.candidate.value);
    }
    let summaries = bite_summaries(bites, &noise, linear, after);
    let series = series(bites, linear, named, &records[0].template)?;
    calibration.adjustments = calibration::adjustments(model, &linear.linear);
    calibration.rmse = linear.rmse();
    Ok(Report {
        calibration,
        noise_rms: pooled_noise,
        bites: summaries,
        disagreement,
        features,
        verdict: decision.verdict,
        effect: named.map(|c| c.candidate.effect),
        location: named.and_then(|c| c.candidate.location),
        parameters,
        rmse_before: linear.rmse(),
        rmse_after: after.rmse(),
        bic_linear: decision.bic_linear,
        alternatives: decision
            .rivals
            .iter()
            .map(|&i| candidates[i].candidate.clone())
            .collect(),
        tell_apart,
        candidates: candidates.into_iter().map(|c| c.candidate).collect(),
        simulations,
        series,
    })
}

/// White-noise RMS over every bite: the RMS of the bites' estimates `noise`,
/// weighted by their samples, kN*m.
fn pooled_noise(bites: &[Measured], noise: &[f64]) -> f64 {
    let total_samples: usize = bites.iter().map(|b| b.torque_knm.len()).sum();
    (bites
        .iter()
        .zip(noise)
        .map(|(b, n)| n * n * b.torque_knm.len() as f64)
        .sum::<f64>()
        / total_samples as f64)
        .sqrt()
}

/// Each bite's noise, fitted load and residuals before (`linear`) and `after`.
fn bite_summaries(
    bites: &[Measured],
    noise: &[f64],
    linear: &Fitted,
    after: &Fitted,
) -> Vec<BiteSummary> {
    bites
        .iter()
        .enumerate()
        .map(|(b, bite)| {
            let load = after.linear.loads[b];
            let rmse = |fit: &Fitted| (fit.bite_costs[b] / bite.torque_knm.len() as f64).sqrt();
            BiteSummary {
                t0_s: bite.t0_s,
                samples: bite.torque_knm.len(),
                noise_rms: noise[b],
                static_torque_knm: load.static_torque_knm,
                rise_rate_per_s: load.rise_rate_per_s,
                onset_s: load.onset_s,
                rmse_before: rmse(linear),
                rmse_after: rmse(after),
            }
        })
        .collect()
}

/// The series behind the report: each bite measured, the calibrated linear model's and
/// the extended (the `named` candidate's) response; the models (first bite's load, on
/// the first bite's `template`).
fn series(
    bites: &[Measured],
    linear: &Fitted,
    named: Option<&FittedCandidate>,
    template: &Model,
) -> Result<Series, DiscrepancyError> {
    let after: &Fitted = named.map_or(linear, |c| &c.fit);
    Ok(Series {
        bites: bites
            .iter()
            .enumerate()
            .map(|(b, bite)| BiteSeries {
                t_s: (0..bite.torque_knm.len())
                    .map(|k| bite.t0_s + k as f64 / bite.sample_rate_hz)
                    .collect(),
                measured: bite.torque_knm.to_vec(),
                linear: linear.simulated[b].clone(),
                extended: after.simulated[b].clone(),
            })
            .collect(),
        linear_model: Some(linear.models[0].clone()),
        extended_model: named.map(|c| c.fit.models[0].clone()),
        calibrated_model: Some(match named {
            Some(c) => calibrated_linear(c, template)?,
            None => linear.models[0].clone(),
        }),
    })
}

/// Checks every bite and builds its record: the handed model sampled on the bite's grid.
fn bite_records<'a>(
    bites: &[Measured<'a>],
    model: &Model,
) -> Result<Vec<BiteRecord<'a>>, DiscrepancyError> {
    if bites.is_empty() {
        return Err(DiscrepancyError::NoBite);
    }
    let mut records = Vec::with_capacity(bites.len());
    for (b, bite) in bites.iter().enumerate() {
        records.push(BiteRecord {
            template: model_fit::bite_template(model, bite, b)?,
            measured: bite.torque_knm,
        });
    }
    Ok(records)
}

/// The calibrated linear model to monitor against: the candidate's fitted linear values
/// (first bite's load), with its effect applied when that effect is linear.
fn calibrated_linear(
    candidate: &FittedCandidate,
    template: &Model,
) -> Result<Model, DiscrepancyError> {
    let base = candidate.fit.linear.model_for(template, 0);
    let c = &candidate.candidate;
    Ok(if c.effect.is_linear() {
        c.effect.apply(&base, c.location, c.value)?
    } else {
        base
    })
}
