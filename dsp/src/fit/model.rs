//! Paper eq. (1) and the fit's public types: its parameters, the options, the result
//! and the errors of [`super::fit_eq1`].

use core::f64::consts::PI;

/// Number of eq. (1) parameters.
pub const PARAMS: usize = 10;

/// Options of [`fit_eq1`](super::fit_eq1); build with [`FitOptions::new`] and adjust fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Sample rate, Hz, finite and > 0.
    pub sample_rate_hz: f64,
    /// Fit only samples above zero (paper: gaps open when the torque crosses zero).
    pub positive_only: bool,
    /// Highest mode frequency the initialiser must resolve, Hz, in (0, 0.45 fs); sets
    /// the decimation of the pencil (decimated rate >= 4x this). Default 60 Hz.
    pub max_mode_hz: f64,
    /// Iteration limit, >= 1. Default 100.
    pub max_iterations: u32,
    /// Relative tolerance on the cost decrease and the step, in (0, 0.1). Default 1e-6:
    /// a relative cost change of 1e-6 at N samples moves the parameters by about
    /// sqrt(1e-6 N) of their standard error (0.02 at N = 500), far below the noise.
    pub tolerance: f64,
}

impl FitOptions {
    /// Defaults for a record sampled at `sample_rate_hz` (Hz).
    pub fn new(sample_rate_hz: f64) -> Self {
        Self {
            sample_rate_hz,
            positive_only: false,
            max_mode_hz: 60.0,
            max_iterations: 100,
            tolerance: 1e-6,
        }
    }
}

/// Why [`fit_eq1`](super::fit_eq1) gave no fit; setting variants name the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitError {
    /// `sample_rate_hz` is not finite and > 0.
    SampleRateHz,
    /// `max_mode_hz` is outside (0, 0.45 fs).
    MaxModeHz,
    /// `max_iterations` is 0.
    MaxIterations,
    /// `tolerance` is outside (0, 0.1).
    Tolerance,
    /// Too few samples (or too few above zero with `positive_only`).
    TooFewSamples,
    /// A sample is NaN or infinite.
    NonFinite,
    /// All samples are zero.
    Flat,
    /// The initialiser found fewer than two oscillating modes.
    ModesNotFound,
    /// A decomposition or the normal equations were singular, or the least squares
    /// too ill-conditioned to trust (its residual came out above the record's own).
    Singular,
    /// The iteration produced non-finite parameters or residual.
    Diverged,
}

impl core::fmt::Display for FitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FitError::SampleRateHz => "sample_rate_hz must be finite and > 0 Hz",
            FitError::MaxModeHz => "max_mode_hz must be in (0, 0.45 x the sample rate) Hz",
            FitError::MaxIterations => "max_iterations must be >= 1",
            FitError::Tolerance => "tolerance must be in (0, 0.1)",
            FitError::TooFewSamples => {
                "too few samples to fit (or too few above zero with positive_only)"
            }
            FitError::NonFinite => "a sample is NaN or infinite",
            FitError::Flat => "all samples are zero",
            FitError::ModesNotFound => "fewer than two oscillating modes found in the record",
            FitError::Singular => {
                "a decomposition or the normal equations were singular, or too ill-conditioned \
                 to trust"
            }
            FitError::Diverged => "the iteration produced non-finite parameters or residual",
        })
    }
}

impl core::error::Error for FitError {}

/// How the iteration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitStatus {
    /// The relative cost decrease or step fell below the tolerance.
    Converged,
    /// No step decreased the cost any more: a minimum at working precision.
    Stalled,
    /// `max_iterations` was reached first.
    MaxIterations,
}

/// Result of [`fit_eq1`](super::fit_eq1). Torques in the units of the samples (kN*m), f1 < f2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eq1Fit {
    /// a1..a10 in paper order (a5 < a6, both > 0).
    pub params: [f64; PARAMS],
    /// First natural frequency a5, Hz.
    pub f1_hz: f64,
    /// Second natural frequency a6, Hz.
    pub f2_hz: f64,
    /// Decay rate of the first mode a7, 1/s.
    pub decay1_per_s: f64,
    /// Decay rate of the second mode a8, 1/s.
    pub decay2_per_s: f64,
    /// Damping ratio of the first mode, a7 / sqrt(a7^2 + (2 pi a5)^2).
    pub zeta1: f64,
    /// Damping ratio of the second mode.
    pub zeta2: f64,
    /// Static torque a9.
    pub static_torque: f64,
    /// Load rise rate a10, 1/s.
    pub rise_per_s: f64,
    /// Peak of the fitted curve over the record divided by a9, when a9 > 0.
    pub taf: Option<f64>,
    /// RMS of the residual over the fitted samples.
    pub rms_residual: f64,
    /// Levenberg-Marquardt iterations done (the coarse pass's and every start's).
    pub iterations: u32,
    /// How the iteration ended.
    pub status: FitStatus,
    /// Number of samples fitted.
    pub samples_used: usize,
}

impl Eq1Fit {
    /// The fit of parameters `params` (paper order, in the record's units), with the
    /// fitted curve's `taf`, the residual's RMS and how the iteration went.
    pub(super) fn new(
        params: [f64; PARAMS],
        taf: Option<f64>,
        rms_residual: f64,
        iterations: u32,
        status: FitStatus,
        samples_used: usize,
    ) -> Eq1Fit {
        Eq1Fit {
            params,
            f1_hz: params[4],
            f2_hz: params[5],
            decay1_per_s: params[6],
            decay2_per_s: params[7],
            zeta1: damping_ratio(params[6], params[4]),
            zeta2: damping_ratio(params[7], params[5]),
            static_torque: params[8],
            rise_per_s: params[9],
            taf,
            rms_residual,
            iterations,
            status,
            samples_used,
        }
    }
}

/// Damping ratio of a mode decaying at `decay` (1/s) at `frequency` (Hz): `decay /
/// |decay + i 2 pi frequency|`, 0 for a mode that neither decays nor oscillates.
fn damping_ratio(decay: f64, frequency: f64) -> f64 {
    let norm = libm::hypot(decay, 2.0 * PI * frequency);
    if norm > 0.0 {
        decay / norm
    } else {
        0.0
    }
}

/// Evaluates eq. (1) with parameters `params` (paper order) at time `t_s` (s).
pub fn eq1(params: &[f64; PARAMS], t_s: f64) -> f64 {
    let [a1, a2, a3, a4, a5, a6, a7, a8, a9, a10] = *params;
    let (s5, c5) = libm::sincos(2.0 * PI * a5 * t_s);
    let (s6, c6) = libm::sincos(2.0 * PI * a6 * t_s);
    (a1 * c5 + a3 * s5) * libm::exp(-a7 * t_s)
        + (a2 * c6 + a4 * s6) * libm::exp(-a8 * t_s)
        + a9 * (1.0 - libm::exp(-a10 * t_s))
}
