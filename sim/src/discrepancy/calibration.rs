//! Calibration of the linear model to the measured bites.
//!
//! 1. **Alignment**: per bite, the onset and load scale that best line the model's
//!    response up with the record (`align`).
//! 2. **Identification**: per bite, beta1 and beta2 from the part where the couplings
//!    stay loaded (`identify::loaded_modes`), which a gap, friction or a sensor lag
//!    do not bias, and by the paper's eq. (1) fit on the whole transient (reported; a
//!    gap biases it).
//! 3. **Stiffness starts**: every root of eq. (2) for each identification (three
//!    masses), or a regularised modal update (N masses), within a factor
//!    of 10 (`MAX_LOG_RATIO`) of the drawings; the model's own
//!    stiffness; and the best points of a global search over stiffness within a factor
//!    [`GRID_FACTOR`] of the drawings (`grid_starts`), for when no identification
//!    gives a root (a coupling stuck by friction leaves one mode in the loaded part).
//! 4. **Linear fits**: stiffness, damping, and every bite's static torque, rise rate and
//!    onset by Levenberg-Marquardt from each start (loads re-aligned to it); the best is
//!    the calibrated linear model. Inertias and the motor's controller are trusted.
//!
//! What it hands the candidate search (`Calibrated::anchors`): the identified
//! stiffness with its fits' loads, and the best linear fit. A linear fit to a record
//! with a gap bends its stiffness to mimic the gap; the loaded part's stiffness does not.

use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_dsp::stiffness::{inverse, Inertias, NaturalFrequencies, Stiffness};
use serde::Serialize;

use crate::chain::Simulator;
use crate::modal;
use crate::model::Model;

use super::identify;
use super::levenberg_marquardt::{self, FnResiduals};
use super::model_fit::{self, BiteLoad, BiteRecord, Fitted, LinearValues, Problem};
use super::{BiteProblem, DiscrepancyError};

/// Two stiffness starts closer than this (largest |ln ratio| over the couplings) are one.
const SAME_START: f64 = 0.03;

/// Where an identification of beta1, beta2 was made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IdentificationWindow {
    /// The whole transient from the bite, by the eq. (1) fit (the paper's way).
    Transient,
    /// The part where the record stays loaded past every gap, by a damped-mode fit.
    Loaded,
}

/// Natural frequencies identified on one part of one bite.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Identification {
    /// The bite, 0-based in the order given.
    pub bite: usize,
    /// Which part.
    pub window: IdentificationWindow,
    /// Start of the fitted part from the bite record's first sample, s.
    pub t_start_s: f64,
    /// First natural frequency, Hz.
    pub beta1_hz: f64,
    /// Second natural frequency, Hz.
    pub beta2_hz: f64,
}

/// Where a stiffness start came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrialSource {
    /// A root of eq. (2) for identified frequencies (three masses).
    Eq2,
    /// A modal update to identified frequencies (any number of masses).
    ModalUpdate,
    /// The stiffness written in the model (the drawings).
    Model,
    /// A minimum of the global search over stiffness around the drawings.
    Grid,
}

impl IdentificationWindow {
    /// The name used in JSON and reports.
    pub(crate) fn key(self) -> &'static str {
        match self {
            IdentificationWindow::Transient => "transient",
            IdentificationWindow::Loaded => "loaded",
        }
    }
}

impl TrialSource {
    /// The name used in JSON and reports.
    pub(crate) fn key(self) -> &'static str {
        match self {
            TrialSource::Eq2 => "eq2",
            TrialSource::ModalUpdate => "modal_update",
            TrialSource::Model => "model",
            TrialSource::Grid => "grid",
        }
    }
}

keyed!(IdentificationWindow, TrialSource);

/// One stiffness start of the calibration and how well it fitted.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StiffnessTrial {
    /// Where it came from.
    pub source: TrialSource,
    /// The identification it was computed from (index into
    /// [`Calibration::identified`]), or null.
    pub identification: Option<usize>,
    /// Starting coupling stiffness, N*m/rad.
    pub start: Vec<f64>,
    /// RMS residual after the linear fit from it, kN*m.
    pub rmse: f64,
}

/// One adjusted quantity of the calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Adjustment {
    /// Model key, e.g. `coupling[0].stiffness`.
    pub(crate) key: String,
    /// The bite, for a load quantity; null for the driveline's own.
    pub(crate) bite: Option<usize>,
    /// Unit of the values.
    pub(crate) unit: &'static str,
    /// Value in the given model.
    pub(crate) model: f64,
    /// Calibrated value.
    pub(crate) calibrated: f64,
    /// Change, percent of the model value (null when the model value is 0).
    pub(crate) change_percent: Option<f64>,
}

/// The calibrated linear model and how it was reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    /// First natural frequency identified on the first bite's whole transient (the
    /// paper's way), Hz.
    pub(crate) beta1_hz: Option<f64>,
    /// Second natural frequency identified on the first bite's whole transient, Hz.
    pub(crate) beta2_hz: Option<f64>,
    /// Every identification made.
    pub identified: Vec<Identification>,
    /// The stiffness starts tried, best first.
    pub stiffness_trials: Vec<StiffnessTrial>,
    /// Every calibrated quantity against the model's value.
    pub(crate) adjustments: Vec<Adjustment>,
    /// RMS residual of the calibrated linear model over every bite, kN*m.
    pub(crate) rmse: f64,
}

/// What [`calibrate`] found.
#[derive(Debug, Clone)]
pub(crate) struct Calibrated {
    /// The calibration as reported (adjustments filled in by the caller).
    pub(crate) calibration: Calibration,
    /// The best linear fit.
    pub(crate) best: Fitted,
    /// Where to start the candidate search from: the identified stiffness (up to
    /// [`IDENTIFIED_ANCHORS`] starts, loaded part first) with their fits' loads and
    /// damping, and the best linear fit.
    pub(crate) anchors: Vec<LinearValues>,
}

/// Identified stiffness starts handed to the candidate search, at most.
pub(crate) const IDENTIFIED_ANCHORS: usize = 2;

/// Calibrates the linear model to `bites` (each with its noise RMS, kN*m).
pub(crate) fn calibrate(
    bites: &[BiteRecord<'_>],
    noise_rms: &[f64],
    simulations: &mut usize,
) -> Result<Calibrated, DiscrepancyError> {
    let template = &bites[0].template;
    let prior = aligned(bites, &LinearValues::of(template, bites.len()), simulations)?;
    let identified = identifications(bites, &prior, noise_rms);
    let starts = stiffness_starts(bites, &prior, &identified, simulations)?;
    let fits = fitted_starts(bites, &prior, starts, simulations)?;
    let Some((_, best, _)) = fits.first() else {
        return Err(DiscrepancyError::NoStiffnessStart);
    };
    let best = best.clone();
    let mut anchors = identified_anchors(&fits, &identified);
    anchors.push(best.linear.clone());
    let transient = identified
        .iter()
        .find(|id| id.window == IdentificationWindow::Transient && id.bite == 0);
    Ok(Calibrated {
        calibration: Calibration {
            beta1_hz: transient.map(|id| id.beta1_hz),
            beta2_hz: transient.map(|id| id.beta2_hz),
            identified,
            stiffness_trials: fits.into_iter().map(|(t, _, _)| t).collect(),
            adjustments: Vec::new(),
            rmse: best.rmse(),
        },
        best,
        anchors,
    })
}

/// A start of the stiffness fit: where it comes from, the identification it was
/// computed from (index), the stiffness of each coupling (N*m/rad).
type Start = (TrialSource, Option<usize>, Vec<f64>);

/// A fitted start: its trial as reported, the fit, the start's stiffness.
type FittedStart = (StiffnessTrial, Fitted, Vec<f64>);

/// The natural frequencies identified in each bite (aligned by `prior`): eq. (1) on
/// the transient from the onset, and the loaded part's modes (with the bite's noise
/// RMS, kN*m).
fn identifications(
    bites: &[BiteRecord<'_>],
    prior: &LinearValues,
    noise_rms: &[f64],
) -> Vec<Identification> {
    let mut identified = Vec::new();
    for (b, bite) in bites.iter().enumerate() {
        let fs = bite.template.measurement.sample_rate;
        let onset_index =
            ((prior.loads[b].onset_s * fs).ceil() as usize).min(bite.measured.len() - 1);
        if let Ok(fit) = fit_eq1(&bite.measured[onset_index..], &FitOptions::new(fs)) {
            identified.push(Identification {
                bite: b,
                window: IdentificationWindow::Transient,
                t_start_s: onset_index as f64 / fs,
                beta1_hz: fit.f1_hz,
                beta2_hz: fit.f2_hz,
            });
        }
        if let Some((start, fit)) =
            identify::loaded_modes(bite.measured, fs, onset_index, noise_rms[b])
        {
            identified.push(Identification {
                bite: b,
                window: IdentificationWindow::Loaded,
                t_start_s: start as f64 / fs,
                beta1_hz: fit.natural_hz[0],
                beta2_hz: fit.natural_hz[1],
            });
        }
    }
    identified
}

/// The distinct stiffness starts: each identification's roots (eq. (2) for three
/// masses, a modal update otherwise; loaded part first, implausible roots left out),
/// the drawings, then a grid; a start within [`SAME_START`] of an earlier one is left
/// out.
fn stiffness_starts(
    bites: &[BiteRecord<'_>],
    prior: &LinearValues,
    identified: &[Identification],
    simulations: &mut usize,
) -> Result<Vec<Start>, DiscrepancyError> {
    let template = &bites[0].template;
    let drawings: Vec<f64> = template.couplings.iter().map(|c| c.stiffness).collect();
    let mut starts: Vec<Start> = Vec::new();
    let mut add = |source, identification, stiffness: Vec<f64>| {
        let same = |other: &Vec<f64>| {
            other
                .iter()
                .zip(&stiffness)
                .all(|(a, b)| (a / b).ln().abs() < SAME_START)
        };
        if !starts.iter().any(|(_, _, s)| same(s)) {
            starts.push((source, identification, stiffness));
        }
    };
    // Loaded-part identifications first: where two starts coincide, the loaded one is
    // kept and named.
    let mut order: Vec<usize> = (0..identified.len()).collect();
    order.sort_by_key(|&i| identified[i].window != IdentificationWindow::Loaded);
    for index in order {
        let id = &identified[index];
        let betas = [id.beta1_hz, id.beta2_hz];
        // A root more than 10x from the drawings is not a stiffness error but a sign
        // the identification was misled.
        let plausible = |root: &Vec<f64>| {
            root.iter()
                .zip(&drawings)
                .all(|(c, d)| (c / d).ln().abs() <= model_fit::MAX_LOG_RATIO)
        };
        if template.masses.len() == 3 {
            for root in eq2_roots(template, &drawings, &betas) {
                if plausible(&root) {
                    add(TrialSource::Eq2, Some(index), root);
                }
            }
        } else if let Some(root) = modal_update(template, &drawings, &betas) {
            if plausible(&root) {
                add(TrialSource::ModalUpdate, Some(index), root);
            }
        }
    }
    add(TrialSource::Model, None, drawings.clone());
    for stiffness in grid_starts(bites, prior, simulations)? {
        add(TrialSource::Grid, None, stiffness);
    }
    Ok(starts)
}

/// Each start fitted (aligned by `prior` first), best (lowest cost) first; starts
/// whose fit fails are left out.
fn fitted_starts(
    bites: &[BiteRecord<'_>],
    prior: &LinearValues,
    starts: Vec<Start>,
    simulations: &mut usize,
) -> Result<Vec<FittedStart>, DiscrepancyError> {
    let mut fits: Vec<FittedStart> = Vec::with_capacity(starts.len());
    for (source, identification, stiffness) in starts {
        let start = aligned(bites, &prior.with_stiffness(&stiffness), simulations)?;
        let mut problem = Problem::new(bites, start, None)?;
        let fit = problem.solve()?;
        *simulations += problem.simulations();
        let Some(fit) = fit else { continue };
        let trial = StiffnessTrial {
            source,
            identification,
            start: stiffness.clone(),
            rmse: fit.rmse(),
        };
        fits.push((trial, fit, stiffness));
    }
    fits.sort_by(|a, b| a.1.cost.total_cmp(&b.1.cost));
    Ok(fits)
}

/// Identified stiffness: from the loaded part if any (a gap biases the whole
/// transient's), each distinct start with its fit's loads and damping, best-fitting
/// first (`fits` are sorted), at most [`IDENTIFIED_ANCHORS`]; the two roots of eq. (2)
/// can fit a record with an effect about equally, so both are kept.
fn identified_anchors(fits: &[FittedStart], identified: &[Identification]) -> Vec<LinearValues> {
    let mut anchors: Vec<LinearValues> = Vec::new();
    for window in [
        IdentificationWindow::Loaded,
        IdentificationWindow::Transient,
    ] {
        for (trial, fit, stiffness) in fits {
            let Some(i) = trial.identification else {
                continue;
            };
            if identified[i].window == window && anchors.len() < IDENTIFIED_ANCHORS {
                anchors.push(fit.linear.with_stiffness(stiffness));
            }
        }
        if !anchors.is_empty() {
            break;
        }
    }
    anchors
}

/// `values` with every bite's onset and static torque aligned to its record (the rise
/// rate kept): the linear model's response under `values`' stiffness, shifted and scaled.
fn aligned(
    bites: &[BiteRecord<'_>],
    values: &LinearValues,
    simulations: &mut usize,
) -> Result<LinearValues, DiscrepancyError> {
    let mut out = values.clone();
    for (b, bite) in bites.iter().enumerate() {
        let model = values.model_for(&bite.template, b);
        *simulations += 1;
        out.loads[b] = aligned_load(&model, bite.measured)?
            .ok_or(DiscrepancyError::Bite {
                bite: b,
                problem: BiteProblem::NoLoadStep,
            })?
            .0;
    }
    Ok(out)
}

/// The load of `model` (its rise rate kept) whose response best lines up with the
/// record `y` ([`align`]), and the remaining sum of squares, (kN*m)^2; `None` when the
/// record is not a load step.
fn aligned_load(model: &Model, y: &[f64]) -> Result<Option<(BiteLoad, f64)>, DiscrepancyError> {
    Ok(align(model, y)?.map(|(onset_s, scale, cost)| {
        let load = BiteLoad {
            static_torque_knm: (model.load.static_torque * scale).max(1.0e-3),
            rise_rate_per_s: model.load.rise_rate,
            onset_s,
        };
        (load, cost)
    }))
}

/// A model's response to one measured bite, as the calibration first aligns it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AlignedResponse {
    /// The bite's static torque as the alignment measures it, kN*m.
    pub(crate) static_torque_knm: f64,
    /// The load's onset after the record's first sample, s.
    pub(crate) onset_s: f64,
    /// RMS of the record minus the response, kN*m: the discrepancy left.
    pub(crate) residual_rms_knm: f64,
    /// The simulated torque on the record's sample grid, kN*m.
    pub(crate) torque_knm: Vec<f64>,
}

/// The response of `model` (unchanged: its stiffness, damping and rise rate) to the
/// measured bite `bite`: the model sampled on the bite's grid, its onset and static
/// torque aligned to the record as the calibration's first step does (`align`), and
/// simulated. `None` when the record is not a load step. What `millgate discrepancy`
/// starts from, for one bite, shown beside the record.
pub fn aligned_response(
    model: &Model,
    bite: &super::Measured<'_>,
) -> Result<Option<AlignedResponse>, DiscrepancyError> {
    let template = model_fit::bite_template(model, bite, 0)?;
    let Some((load, cost)) = aligned_load(&template, bite.torque_knm)? else {
        return Ok(None);
    };
    let loaded = LinearValues {
        loads: vec![load],
        ..LinearValues::of(&template, 1)
    }
    .model_for(&template, 0);
    let torque_knm = Simulator::new(&loaded)?.run().torque_knm;
    Ok(Some(AlignedResponse {
        static_torque_knm: load.static_torque_knm,
        onset_s: load.onset_s,
        residual_rms_knm: (cost / bite.torque_knm.len() as f64).sqrt(),
        torque_knm,
    }))
}

/// Onset (s), load scale and the remaining sum of squares ((kN*m)^2) of the best
/// alignment of `model`'s response with the record `y`; `None` when no positive scale
/// fits (the record is not a load step).
///
/// Before the bite the chain is at rest, so the response to a load starting at `o` is
/// the response to a load starting at 0 delayed by `o`; and a linear chain's response
/// is proportional to the static load. One simulation from onset 0 is shifted over
/// every sample and scaled by least squares.
pub(crate) fn align(model: &Model, y: &[f64]) -> Result<Option<(f64, f64, f64)>, DiscrepancyError> {
    let fs = model.measurement.sample_rate;
    let mut at_zero = model.clone();
    at_zero.load.onset = 0.0;
    let response = Simulator::new(&at_zero)?.run().torque_knm;
    let m = y.len().min(response.len());
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
    Ok((best.0.is_finite() && best.2 > 0.0).then(|| (best.1 as f64 / fs, best.2, best.0)))
}

/// Grid points per coupling of the global stiffness search.
pub(crate) const GRID_POINTS: usize = 9;
/// The global search spans the drawing stiffness divided and multiplied by this.
pub const GRID_FACTOR: f64 = 5.0;
/// Couplings up to which the global search runs (GRID_POINTS^couplings points).
pub(crate) const GRID_MAX_COUPLINGS: usize = 3;
/// Minima of the global search kept as starts.
const GRID_STARTS: usize = 2;

/// The global stiffness search: every combination of [`GRID_POINTS`] log-spaced
/// factors in `1/GRID_FACTOR ..= GRID_FACTOR` on each coupling's drawing stiffness
/// (`prior`), each scored by the linear response aligned to every bite (one simulation
/// per bite, see [`align`]); the [`GRID_STARTS`] best points that are not grid
/// neighbours of a better one. Skipped beyond [`GRID_MAX_COUPLINGS`] couplings.
fn grid_starts(
    bites: &[BiteRecord<'_>],
    prior: &LinearValues,
    simulations: &mut usize,
) -> Result<Vec<Vec<f64>>, DiscrepancyError> {
    let n = prior.stiffness.len();
    if n > GRID_MAX_COUPLINGS {
        return Ok(Vec::new());
    }
    let factor = |k: usize| GRID_FACTOR.powf(2.0 * k as f64 / (GRID_POINTS - 1) as f64 - 1.0);
    let mut scored: Vec<(f64, Vec<usize>)> = Vec::new();
    for index in 0..GRID_POINTS.pow(n as u32) {
        let point: Vec<usize> = (0..n)
            .map(|i| index / GRID_POINTS.pow(i as u32) % GRID_POINTS)
            .collect();
        let stiffness: Vec<f64> = prior
            .stiffness
            .iter()
            .zip(&point)
            .map(|(c, &k)| c * factor(k))
            .collect();
        let values = prior.with_stiffness(&stiffness);
        let mut cost = 0.0;
        for (b, bite) in bites.iter().enumerate() {
            *simulations += 1;
            cost += align(&values.model_for(&bite.template, b), bite.measured)?
                .map_or(f64::INFINITY, |(_, _, c)| c);
        }
        scored.push((cost, point));
    }
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut kept: Vec<&Vec<usize>> = Vec::new();
    for (cost, point) in &scored {
        let neighbour =
            |other: &&Vec<usize>| other.iter().zip(point).all(|(a, b)| a.abs_diff(*b) <= 1);
        if cost.is_finite() && !kept.iter().any(neighbour) {
            kept.push(point);
        }
        if kept.len() == GRID_STARTS {
            break;
        }
    }
    Ok(kept
        .into_iter()
        .map(|point| {
            prior
                .stiffness
                .iter()
                .zip(point)
                .map(|(c, &k)| c * factor(k))
                .collect()
        })
        .collect())
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
    let mut problem = FnResiduals {
        len: 2 + n,
        function: |p: &[f64], out: &mut [f64]| {
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
    };
    let result = levenberg_marquardt::minimise(
        &vec![0.0; n],
        &levenberg_marquardt::LmSettings::default(),
        &mut problem,
    );
    result.cost.is_finite().then(|| {
        drawing
            .iter()
            .zip(&result.params)
            .map(|(c, q)| c * q.exp())
            .collect()
    })
}

/// First elastic natural frequency of `model`, Hz (1 Hz if none is found).
pub(crate) fn first_mode_hz(model: &Model) -> f64 {
    modal::modes(model)
        .ok()
        .and_then(|m| m.elastic_hz().next())
        .unwrap_or(1.0)
}

/// Every calibrated quantity against the value in `model`.
pub(crate) fn adjustments(model: &Model, calibrated: &LinearValues) -> Vec<Adjustment> {
    let entry = |key: &str, bite, unit, before: f64, after: f64| Adjustment {
        key: key.to_owned(),
        bite,
        unit,
        model: before,
        calibrated: after,
        change_percent: (before != 0.0).then(|| 100.0 * (after / before - 1.0)),
    };
    let mut list = Vec::new();
    for (i, c) in model.couplings.iter().enumerate() {
        list.push(entry(
            &format!("coupling[{i}].stiffness"),
            None,
            "N*m/rad",
            c.stiffness,
            calibrated.stiffness[i],
        ));
    }
    for (i, c) in model.couplings.iter().enumerate() {
        list.push(entry(
            &format!("coupling[{i}].damping"),
            None,
            "N*m*s/rad",
            c.damping,
            calibrated.damping[i],
        ));
    }
    for (b, load) in calibrated.loads.iter().enumerate() {
        list.push(entry(
            "load.static_torque",
            Some(b),
            "kN*m",
            model.load.static_torque,
            load.static_torque_knm,
        ));
        list.push(entry(
            "load.rise_rate",
            Some(b),
            "1/s",
            model.load.rise_rate,
            load.rise_rate_per_s,
        ));
        list.push(entry(
            "load.onset",
            Some(b),
            "s",
            model.load.onset,
            load.onset_s,
        ));
    }
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

    #[test]
    fn the_aligned_response_finds_a_simulated_bites_load_and_leaves_no_residual() {
        // A bite simulated by the model itself at a load the model file does not hold:
        // the response must find that load and explain the record to rounding.
        let mut model =
            Model::from_toml_str(include_str!("../../models/table2-adjusted.toml"), "t2").unwrap();
        let handed = model.clone();
        model.load.static_torque *= 1.7;
        model.load.onset = 0.05;
        let record = Simulator::new(&model).unwrap().run().torque_knm;
        let bite = super::super::Measured {
            t0_s: 0.0,
            sample_rate_hz: model.measurement.sample_rate,
            torque_knm: &record,
        };
        let response = aligned_response(&handed, &bite).unwrap().unwrap();
        assert_eq!(response.torque_knm.len(), record.len());
        let relative = response.static_torque_knm / model.load.static_torque - 1.0;
        assert!(relative.abs() < 1e-3, "static torque off by {relative}");
        let step = 1.0 / model.measurement.sample_rate;
        assert!(
            (response.onset_s - 0.05).abs() <= step,
            "{}",
            response.onset_s
        );
        let peak = record.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!(
            response.residual_rms_knm < 1e-3 * peak,
            "{}",
            response.residual_rms_knm
        );
        // A record without torque is no load step.
        let flat = vec![0.0; record.len()];
        let flat = super::super::Measured {
            torque_knm: &flat,
            ..bite
        };
        assert_eq!(aligned_response(&handed, &flat).unwrap(), None);
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
