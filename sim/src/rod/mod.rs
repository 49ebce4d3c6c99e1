//! Rod mills: parametric stability of the rod between stands, pass by pass (domain
//! notes 3, the paper's third problem).
//!
//! The rod between two stands of a reducing-sizing mill is a beam under tension. When
//! the tension pulsates at `Theta` the span's bending mode `m` obeys a damped Mathieu
//! equation ([`beam`]); it grows when `(a, q)` lies inside a damped instability tongue
//! ([`millgate_dsp::mathieu`]). The pulsation comes from
//!
//! - **torsional modes of the drive** in which the span's two stands swing by
//!   different amounts: the drive's modal analysis in the pass's configuration (a tree
//!   of gear stages, `tree`) gives each mode's unit-norm shape; its
//!   participation in a span is `|phi_up - phi_down| / sqrt(2)` (1 when the two stands
//!   swing fully against each other, as stands 1 and 2 do at 31.8 Hz in Table 3);
//! - **roll eccentricity** of either stand, at 1x and 2x its roll speed.
//!
//! Every source's amplitude is `P = epsilon * weight * (P_E + T0)` (weight: the
//! participation, or 1 for eccentricity), `epsilon` configurable.
//!
//! Layers: [`mill::RodMill`] (the validated mill file with its drive, spans, modulus
//! table and each configuration's modes and finishing-speed range),
//! [`schedule`] (the pass CSV), [`check::PassSetup`] (one pass, everything that does
//! not depend on the finishing speed, including the speed bands to avoid, computed
//! once) and [`check::PassSetup::evaluate`] (the operating points at one finishing
//! speed: cheap, for a service that re-evaluates when the PLC's speed changes);
//! [`check::check_schedule`] runs a whole schedule offline. [`plot`] draws the
//! Ince-Strutt diagram and Campbell charts.

pub mod beam;
pub mod check;
pub mod mill;
#[cfg(feature = "plot")]
pub mod plot;
pub mod report;
pub mod schedule;

use millgate_dsp::mathieu::MathieuError;

use crate::model::ModelError;

/// Why a mill, schedule or pass could not be used. Every variant names where: the
/// file (and line or key) or the pass.
#[derive(Debug, thiserror::Error)]
pub enum RodError {
    /// The mill file or its drive model cannot be read, is malformed, or has a value
    /// out of range (file, line or key, allowed range).
    #[error(transparent)]
    File(#[from] ModelError),
    /// A schedule row is malformed or out of range.
    #[error("{file}:{line}: {key}: {message}")]
    Schedule {
        /// The schedule file as given.
        file: String,
        /// 1-based line.
        line: usize,
        /// Column name (or `(row)` for the row's shape).
        key: String,
        /// What is wrong and what is allowed.
        message: String,
    },
    /// A pass asks for something the mill cannot do.
    #[error("{origin}: {key}: {value} is not allowed (must be {allowed})")]
    Pass {
        /// Where the pass comes from (`passes.csv:3`, or a service's label).
        origin: String,
        /// The pass's field at fault.
        key: String,
        /// The offending value.
        value: String,
        /// What is allowed, with its unit.
        allowed: String,
    },
    /// The stability computation failed (a Mathieu parameter out of its range).
    #[error("{origin}: {what}: {source}")]
    Mathieu {
        /// The pass.
        origin: String,
        /// The span, mode and source being computed.
        what: String,
        /// What the Mathieu solver refused.
        source: MathieuError,
    },
}
