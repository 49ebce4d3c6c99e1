//! The solver's settings and the ranges it accepts: limits, errors, input checks.

use core::fmt;

/// Largest order n of the characteristic values and tongues handled.
pub const MAX_ORDER: u8 = 10;

/// Largest |q| accepted.
pub const MAX_ABS_Q: f64 = 100.0;

/// Largest |a| (and |a - c^2|) accepted.
pub const MAX_ABS_A: f64 = 1.0e4;

/// Largest damping coefficient c accepted (per unit t).
pub const MAX_DAMPING: f64 = 10.0;

/// Largest relative change of the trace taken as rounding when it stops shrinking with
/// doubled steps (see `Mathieu::converged_trace`).
pub(super) const ROUNDING_FLOOR: f64 = 1.0e-9;

/// Why a Mathieu computation was refused or failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MathieuError {
    /// The order is outside 0..=10 for `a_n` or 1..=10 for `b_n` and tongues.
    Order,
    /// `q` is not finite or |q| > [`MAX_ABS_Q`].
    Q,
    /// `a` (or `a - c^2`) is not finite or its magnitude exceeds [`MAX_ABS_A`].
    A,
    /// The damping `c` is not finite or outside `0..=`[`MAX_DAMPING`].
    Damping,
    /// The monodromy trace did not converge within the step limit.
    NotConverged,
}

impl fmt::Display for MathieuError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MathieuError::Order => write!(
                f,
                "Mathieu order must be 0..={MAX_ORDER} for a_n and 1..={MAX_ORDER} for b_n"
            ),
            MathieuError::Q => write!(f, "Mathieu q must be finite with |q| <= {MAX_ABS_Q}"),
            MathieuError::A => write!(
                f,
                "Mathieu a (and a - c^2) must be finite with magnitude <= {MAX_ABS_A}"
            ),
            MathieuError::Damping => write!(
                f,
                "Mathieu damping c must be finite and in 0..={MAX_DAMPING}"
            ),
            MathieuError::NotConverged => write!(
                f,
                "Mathieu monodromy trace did not converge within the step limit"
            ),
        }
    }
}

impl core::error::Error for MathieuError {}

/// Solver settings: the Mathieu "coefficients", built once and shared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mathieu {
    pub(super) tolerance: f64,
    pub(super) max_steps: usize,
}

impl Default for Mathieu {
    /// Tolerance 1e-12 on the monodromy trace, at most 8192 Magnus steps per half period.
    fn default() -> Self {
        Mathieu {
            tolerance: 1.0e-12,
            max_steps: 8192,
        }
    }
}

pub(super) fn check_q(q: f64) -> Result<f64, MathieuError> {
    if q.is_finite() && q.abs() <= MAX_ABS_Q {
        Ok(q)
    } else {
        Err(MathieuError::Q)
    }
}

pub(super) fn check_a(a: f64) -> Result<f64, MathieuError> {
    if a.is_finite() && a.abs() <= MAX_ABS_A {
        Ok(a)
    } else {
        Err(MathieuError::A)
    }
}

pub(super) fn check_damping(c: f64) -> Result<f64, MathieuError> {
    if c.is_finite() && (0.0..=MAX_DAMPING).contains(&c) {
        Ok(c)
    } else {
        Err(MathieuError::Damping)
    }
}
