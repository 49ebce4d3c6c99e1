//! Wear maps: torque amplification factor (TAF) and first-period shift of the simulated
//! bite transient over a grid of static torque and opened gap.
//!
//! For each grid point the model is copied with the load's static torque and one
//! coupling's backlash replaced, simulated from rest, and the measured torque analysed:
//! - `taf` = peak of the simulated measured torque / the grid point's static torque;
//! - periods come from [`millgate_dsp::transient::analyze`]: up-crossings of the
//!   oscillation about the fitted load-rise trend, low-passed above the second elastic
//!   mode (by default 1.5 x its frequency). In the measured spindle torque of the Table 2
//!   chain the second mode (21 Hz, the rolls swinging on the spindles, where the gap is)
//!   dominates the first by about 3:1, so the periods are those of the second mode; a
//!   filter between the modes cannot isolate the weak first mode without smearing the
//!   first period. The first period runs from the first up-crossing after the onset to
//!   the second, the second period to the third; `period_shift_s` = first - second. The
//!   weaker mode beats with the measured one, so even the linear chain shows a small
//!   shift: compare against the zero-gap row (the domain notes' wear index).
//!
//! The paper's signature: for a fixed gap, TAF rises as the static torque falls (the
//! gap is a larger share of the elastic twist), and the first period lengthens.

use millgate_dsp::transient::{analyze, TransientError, TransientSettings};

use crate::chain::Simulator;
use crate::modal::{self, ModalError};
use crate::model::{Model, ModelError};

/// Longest record (samples) the period analysis accepts.
pub(crate) const MAX_RECORD_SAMPLES: usize = 16_384;

/// Fraction of the record (from its end) averaged for the settled level.
const SETTLED_FRACTION: f64 = 0.3;

/// Which grid to compute and how.
#[derive(Debug, Clone, PartialEq)]
pub struct WearMapSpec {
    /// Static rolling torques, kN*m, each finite and > 0.
    pub static_torques_knm: Vec<f64>,
    /// Opened gaps (total dead-zone width), rad, each finite and >= 0; include 0 for the
    /// linear reference.
    pub backlashes_rad: Vec<f64>,
    /// Coupling whose gap is varied; the model's measured coupling when `None`.
    pub coupling: Option<usize>,
    /// Low-pass cut-off for period measurement, Hz, in (0, 0.45 sample rate); when
    /// `None`, 1.5 x the second elastic mode (1.5 x the first with one mode).
    pub period_lowpass_hz: Option<f64>,
}

/// One grid point of a wear map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WearMapRow {
    /// Static rolling torque, kN*m.
    pub static_torque_knm: f64,
    /// Opened gap of the varied coupling, rad.
    pub backlash_rad: f64,
    /// Peak / static torque of the measured channel.
    pub taf: f64,
    /// First oscillation period after the bite, s (`None` if too few crossings).
    pub first_period_s: Option<f64>,
    /// Second oscillation period, s.
    pub(crate) second_period_s: Option<f64>,
    /// First minus second period, s.
    pub period_shift_s: Option<f64>,
}

/// A computed wear map, rows ordered by gap, then static torque (as in the spec).
#[derive(Debug, Clone, PartialEq)]
pub struct WearMap {
    /// Name of the model it was computed for.
    pub model_name: String,
    /// Coupling whose gap was varied.
    pub coupling: usize,
    /// Grid points.
    pub rows: Vec<WearMapRow>,
}

/// Why a wear map could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum WearMapError {
    /// The model, or a grid point's copy of it, is invalid.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The modal analysis for the default low-pass failed.
    #[error("modal analysis: {0}")]
    Modal(#[from] ModalError),
    /// A grid value is out of range.
    #[error("wear map {key}: {value} is not allowed (must be {allowed})")]
    Grid {
        /// Which grid entry.
        key: String,
        /// The offending value.
        value: f64,
        /// The allowed range with its unit.
        allowed: &'static str,
    },
    /// The varied coupling does not exist.
    #[error("wear map coupling {coupling} is not allowed (must be 0 ..= {last})")]
    Coupling {
        /// Requested coupling.
        coupling: usize,
        /// Last coupling index of the model.
        last: usize,
    },
    /// The record is too long for the period analysis.
    #[error("record of {samples} samples is too long (at most {MAX_RECORD_SAMPLES})")]
    RecordTooLong {
        /// Samples in the model's record.
        samples: usize,
    },
    /// The transient analysis rejected its input.
    #[error("transient analysis: {0}")]
    Transient(TransientError),
}

impl WearMapSpec {
    /// A grid around the model's load: static torque 0.25 .. 1.5 x the model's in 6
    /// steps, gaps 0, 1, 2, 3, 4 mrad, on the measured coupling.
    pub fn around(model: &Model) -> WearMapSpec {
        let nominal = model.load.static_torque;
        WearMapSpec {
            static_torques_knm: (1..=6).map(|i| nominal * 0.25 * i as f64).collect(),
            backlashes_rad: (0..=4).map(|i| i as f64 * 1.0e-3).collect(),
            coupling: None,
            period_lowpass_hz: None,
        }
    }
}

/// Computes the wear map; `progress(done, total, row)` is called after each grid point.
pub fn wear_map(
    model: &Model,
    spec: &WearMapSpec,
    mut progress: impl FnMut(usize, usize, &WearMapRow),
) -> Result<WearMap, WearMapError> {
    model.validate("<model>")?;
    let last = model.couplings.len() - 1;
    let coupling = spec.coupling.unwrap_or(model.measurement.coupling);
    if coupling > last {
        return Err(WearMapError::Coupling { coupling, last });
    }
    for (index, &value) in spec.static_torques_knm.iter().enumerate() {
        if !(value.is_finite() && value > 0.0) {
            return Err(WearMapError::Grid {
                key: format!("static_torques_knm[{index}]"),
                value,
                allowed: "> 0 kN*m",
            });
        }
    }
    for (index, &value) in spec.backlashes_rad.iter().enumerate() {
        if !(value.is_finite() && value >= 0.0) {
            return Err(WearMapError::Grid {
                key: format!("backlashes_rad[{index}]"),
                value,
                allowed: ">= 0 rad",
            });
        }
    }
    let samples = model.sample_count();
    if samples > MAX_RECORD_SAMPLES {
        return Err(WearMapError::RecordTooLong { samples });
    }
    let settings = TransientSettings {
        sample_rate_hz: model.measurement.sample_rate,
        period_lowpass_hz: match spec.period_lowpass_hz {
            Some(cutoff) => cutoff,
            None => default_period_lowpass_hz(model)?,
        },
        peak_lowpass_hz: None,
        settled_fraction: SETTLED_FRACTION,
        min_static_knm: f64::MIN_POSITIVE,
        reference_shift_s: None,
    };
    let onset_index = ((model.load.onset * model.measurement.sample_rate).ceil() as usize)
        .min(samples.saturating_sub(1));

    let total = spec.static_torques_knm.len() * spec.backlashes_rad.len();
    let mut rows = Vec::with_capacity(total);
    let mut torque_knm = vec![0.0; samples];
    for &backlash_rad in &spec.backlashes_rad {
        for &static_torque_knm in &spec.static_torques_knm {
            let mut point = model.clone();
            point.load.static_torque = static_torque_knm;
            point.couplings[coupling].backlash = backlash_rad;
            let simulator = Simulator::new(&point)?;
            let mut state = simulator.initial_state();
            simulator.run_into(&mut state, &mut torque_knm);
            let peak = torque_knm[onset_index..]
                .iter()
                .fold(f64::NEG_INFINITY, |m, &v| m.max(v));
            let analysis = analyze::<MAX_RECORD_SAMPLES>(&torque_knm, onset_index, 0.0, &settings)
                .map_err(WearMapError::Transient)?;
            let row = WearMapRow {
                static_torque_knm,
                backlash_rad,
                taf: peak / static_torque_knm,
                first_period_s: analysis.first_period_s,
                second_period_s: analysis.second_period_s,
                period_shift_s: analysis.period_shift_s,
            };
            rows.push(row);
            progress(rows.len(), total, &row);
        }
    }
    Ok(WearMap {
        model_name: model.name.clone(),
        coupling,
        rows,
    })
}

/// The low-pass cut-off for period measurement on `model`'s measured torque: 1.5 x the
/// second elastic mode, Hz (1.5 x the first with a single mode), at most 0.4 x the
/// sample rate.
pub fn default_period_lowpass_hz(model: &Model) -> Result<f64, ModalError> {
    let modes = modal::modes(model)?;
    let elastic: Vec<f64> = modes.elastic_hz().collect();
    let cutoff = match elastic.as_slice() {
        [_, second, ..] => 1.5 * second,
        [first] => 1.5 * first,
        [] => 0.0,
    };
    Ok(cutoff.min(0.4 * model.measurement.sample_rate))
}

impl WearMap {
    /// CSV with header `static_torque_knm,backlash_rad,taf,first_period_s,
    /// second_period_s,period_shift_s,shift_over_linear_s`; missing periods (and the
    /// shift over linear without a zero-gap row) are empty fields.
    pub fn to_csv(&self) -> String {
        let mut csv = String::from(
            "static_torque_knm,backlash_rad,taf,first_period_s,second_period_s,period_shift_s,\
             shift_over_linear_s\n",
        );
        let optional = |value: Option<f64>| value.map_or(String::new(), |v| format!("{v:.6}"));
        for row in &self.rows {
            csv.push_str(&format!(
                "{},{},{:.6},{},{},{},{}\n",
                row.static_torque_knm,
                row.backlash_rad,
                row.taf,
                optional(row.first_period_s),
                optional(row.second_period_s),
                optional(row.period_shift_s),
                optional(self.shift_over_linear_s(row)),
            ));
        }
        csv
    }

    /// The distinct gaps in row order, rad.
    pub fn backlashes_rad(&self) -> Vec<f64> {
        let mut gaps: Vec<f64> = Vec::new();
        for row in &self.rows {
            if !gaps.contains(&row.backlash_rad) {
                gaps.push(row.backlash_rad);
            }
        }
        gaps
    }

    /// First-period shift of `row` over the zero-gap row at the same static torque, s:
    /// what the gap adds to the linear driveline's own shift (the quantity the gateway
    /// logs per bite). `None` without such a row or without both shifts.
    pub fn shift_over_linear_s(&self, row: &WearMapRow) -> Option<f64> {
        let linear = self
            .rows
            .iter()
            .find(|r| r.backlash_rad == 0.0 && r.static_torque_knm == row.static_torque_knm)?;
        Some(row.period_shift_s? - linear.period_shift_s?)
    }
}
