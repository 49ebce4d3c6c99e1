//! The model-discrepancy workflow: calibrate a linear driveline model to one or more
//! measured bite transients, find where and how the two still disagree, name the
//! physical effect the model lacks, add it, and show the residual shrink.
//!
//! Steps of [`run`] (one module each):
//! 1. **Noise** ([`millgate_dsp::noise`]): the white-noise RMS of each bite from its
//!    fourth differences.
//! 2. **Calibration** ([`calibration`], `identify`): align each bite (onset, static
//!    torque); identify beta1, beta2 on the part of each bite where the couplings stay
//!    loaded past their gaps, and the paper's way on the whole transient; turn the
//!    loaded-part frequencies into stiffness (eq. (2), every root, or a modal update for
//!    N masses); fit stiffness, damping and each bite's load by Levenberg-Marquardt from
//!    each start (`model_fit`, `levenberg_marquardt`). Inertias and the motor's controller are trusted.
//! 3. **Disagreement** (`windows`, `features`): residual windows above the noise
//!    and the transient features of record and model, per bite.
//! 4. **Candidate search** (`search`, `effects`): every effect at every location,
//!    fitted jointly with the stiffness, damping and loads from several starts, one model
//!    for every bite; ranked by BIC.
//! 5. **Decision** (`decision`): named, `none`, or cannot tell (two candidates within
//!    the BIC margin, with the further record that would tell them apart).
//!
//! `split` cuts a record holding several bites into one record per bite; [`report`]
//! writes the report folder (extended and calibrated models, plot, summary, JSON);
//! [`cases`] generates records with a hidden effect for testing, from the simulator.

/// `Display` and `Serialize` of the workflow's closed sets by their `key()` (the name in
/// JSON and reports), so each name is written once.
macro_rules! keyed {
    ($($name:ty),*) => {$(
        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.pad(self.key())
            }
        }

        impl serde::Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                serializer.serialize_str(self.key())
            }
        }
    )*};
}

pub mod calibration;
pub mod cases;
pub(crate) mod decision;
pub(crate) mod effects;
pub(crate) mod features;
pub(crate) mod identify;
pub(crate) mod levenberg_marquardt;
pub(crate) mod model_fit;
#[cfg(feature = "plot")]
pub mod report;
pub(crate) mod search;
pub(crate) mod split;
pub(crate) mod windows;
mod workflow;

use crate::modal::ModalError;
use crate::model::ModelError;

pub use decision::{Verdict, BIC_MARGIN};
pub use effects::Effect;
pub use split::split_bites;
pub use workflow::{run, run_with, BiteSeries, BiteSummary, Report, Series, Settings};

/// A measured bite: one channel sampled uniformly, from before the bite into its
/// settled part.
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// Time of the first sample, s.
    pub t0_s: f64,
    /// Sample rate, Hz, > 0.
    pub sample_rate_hz: f64,
    /// The measured torque, kN*m; at least [`MIN_SAMPLES`] finite values.
    pub torque_knm: &'a [f64],
}

/// Fewest samples a bite must have.
pub const MIN_SAMPLES: usize = 100;

/// Why the workflow could not run.
#[derive(Debug, thiserror::Error)]
pub enum DiscrepancyError {
    /// The model is not a valid driveline (or an extension of it failed to validate).
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The calibrated model's modes could not be computed.
    #[error(transparent)]
    Modal(#[from] ModalError),
    /// No bite was given.
    #[error("no measured bite given")]
    NoBite,
    /// A bite is too short, not finite or has no bite in it.
    #[error("measured bite {}: {problem}", bite + 1)]
    Bite {
        /// The bite, 0-based in the order given.
        bite: usize,
        /// What is wrong with it.
        problem: BiteProblem,
    },
    /// Calibration found no linear model at all: no stiffness start could be fitted.
    #[error("calibration: no stiffness start could be fitted")]
    NoStiffnessStart,
}

/// What is wrong with a measured bite.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum BiteProblem {
    /// The sample rate is not a positive number.
    #[error("sample rate {0} Hz is not > 0")]
    SampleRate(f64),
    /// Fewer than [`MIN_SAMPLES`] samples.
    #[error("{0} samples; at least {MIN_SAMPLES} are needed")]
    TooShort(usize),
    /// A sample (0-based) is NaN or infinite.
    #[error("sample {0} is not a finite number")]
    NotFinite(usize),
    /// No load step was found in the record.
    #[error("no bite found: the record does not look like a load step")]
    NoLoadStep,
}

/// A step of the workflow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Noise estimate.
    Noise,
    /// Calibration of the linear model.
    Calibration,
    /// Disagreement windows and features.
    Disagreement,
    /// Candidate search.
    Search,
    /// Decision.
    Decision,
}

keyed!(Step);

impl Step {
    /// The name shown in progress lines.
    pub(crate) fn key(self) -> &'static str {
        match self {
            Step::Noise => "noise",
            Step::Calibration => "calibration",
            Step::Disagreement => "disagreement",
            Step::Search => "search",
            Step::Decision => "decision",
        }
    }
}

/// What the workflow reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum Progress {
    /// A step started.
    Step(Step),
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
        /// Its RMS residual over every bite, kN*m.
        rmse: f64,
    },
}
