//! Levenberg-Marquardt over the nonlinear parameters with the linear ones projected
//! out (variable projection, Kaufman's Jacobian): [`evaluate`] solves the linear
//! least squares at a point, [`levenberg_marquardt`] iterates.

use core::f64::consts::PI;
use nalgebra::{SMatrix, SVector};

use super::gram::{gram_closed, gram_direct};
use super::model::{FitError, FitOptions, FitStatus};
use super::projection::project;
use super::record::{Data, Linear, Nonlinear, BASIS};
use crate::linalg::Cholesky5;

/// Largest ratio of |r0|^2 to the cost accepted in [`evaluate`] from a pass with a
/// reference: 4 of 16 digits lost.
const MAX_CANCELLATION: f64 = 1e4;

/// Largest ratio of the record's energy to the cost accepted in [`evaluate`] from its
/// first pass, on the record itself: 6 of 16 digits lost, 10 left, where the iteration
/// compares costs to its tolerance (1e-6 by default). A residual of 0.1% of the record
/// and more passes; an exact record (a residual of rounding) takes a second pass.
const MAX_RECORD_CANCELLATION: f64 = 1e6;

/// Relative excess of a cost over the record's energy put down to rounding in
/// [`evaluate`]: far above what 4 lost digits leave, far below a lost solve.
const MAX_ENERGY_EXCESS: f64 = 1e-9;

/// The variable-projection problem at one nonlinear point.
#[derive(Clone, Copy)]
pub(super) struct Evaluation {
    pub(super) theta: Nonlinear,
    /// Least-squares linear parameters at `theta`.
    pub(super) linear: Linear,
    /// min over the linear parameters of sum(r^2).
    pub(super) cost: f64,
    pub(super) gram: [[f64; BASIS]; BASIS],
    /// Cholesky factor of Phi^T Phi (the top left 5 x 5 of `gram`).
    pub(super) phi_gram: Cholesky5,
    /// D^T r at the optimal linear parameters.
    pub(super) derivative_projections: [f64; 5],
}

/// Solves the linear least squares at `theta`; `None` when the basis is singular or
/// the solve cannot be trusted (a non-finite result, or a cost above the record's
/// energy).
pub(super) fn evaluate(theta: Nonlinear, data: &Data<'_>) -> Option<Evaluation> {
    let gram = if data.positive_only {
        gram_direct(&theta, data)
    } else {
        gram_closed(&theta, data.count(), data.dt)
    };
    let phi_gram = Cholesky5::new(&SMatrix::<f64, 5, 5>::from_fn(|i, j| gram[i][j]))?;
    // The first pass projects the record itself (no model to evaluate). Where that
    // leaves the cost a small difference of large numbers (a residual far below the
    // record), one more pass from the solution just found, on the residual.
    let mut reference = [0.0; 5];
    let mut attempts = 0;
    let (linear, cost, correction, projections) = loop {
        let (squares, projections) = if attempts == 0 {
            project::<false>(&theta, &reference, data)
        } else {
            project::<true>(&theta, &reference, data)
        };
        let phi_projections = SVector::<f64, 5>::from_fn(|i, _| projections[i]);
        let correction = phi_gram.solve(&phi_projections);
        let mut linear = reference;
        for (l, d) in linear.iter_mut().zip(correction.iter()) {
            *l += d;
        }
        let cost = squares - phi_projections.dot(&correction);
        let limit = if attempts == 0 {
            MAX_RECORD_CANCELLATION
        } else {
            MAX_CANCELLATION
        };
        attempts += 1;
        if attempts >= 3 || !cost.is_finite() || cost * limit >= squares {
            break (linear, cost.max(0.0), correction, projections);
        }
        reference = linear;
    };
    // D^T r = D^T r0 - D^T Phi correction.
    let mut derivative_projections = [0.0; 5];
    for (k, out) in derivative_projections.iter_mut().enumerate() {
        *out = projections[5 + k] - (0..5).map(|j| gram[5 + k][j] * correction[j]).sum::<f64>();
    }
    // No least-squares cost exceeds the record's energy (the cost of all-zero linear
    // parameters), but for rounding: above it, the basis was too ill-conditioned for
    // the solve (a growing mode, e^188 over a record of ones, gave a "converged" fit
    // with a residual 1e9 times the record's, and a non-finite one on a record of
    // 1e300: issue 28).
    let trusted = cost <= data.energy * (1.0 + MAX_ENERGY_EXCESS)
        && linear.iter().all(|v| v.is_finite())
        && derivative_projections.iter().all(|v| v.is_finite());
    trusted.then_some(Evaluation {
        theta,
        linear,
        cost,
        gram,
        phi_gram,
        derivative_projections,
    })
}

/// Kaufman's variable-projection normal equations at `point`: the Jacobian of the
/// projected residual is approximated by P_perp J_N, J_N = D M the Jacobian of the
/// model in the nonlinear parameters at fixed linear ones, so
/// J^T J = M^T (D^T D) M - (Phi^T D M)^T (Phi^T Phi)^-1 (Phi^T D M) and J^T r = M^T D^T r.
fn normal_equations(point: &Evaluation) -> (SMatrix<f64, 5, 5>, SVector<f64, 5>) {
    let [c1, c2, c3, c4, c9] = point.linear;
    let w = 2.0 * PI;
    // dModel/dtheta = D M; rows of M: t u1, t v1, t u2, t v2, t e10.
    #[rustfmt::skip]
    let mixing = SMatrix::<f64, 5, 5>::from_row_slice(&[
        w * c3, 0.0,    -c1, 0.0, 0.0,
        -w * c1, 0.0,   -c3, 0.0, 0.0,
        0.0,    w * c4, 0.0, -c2, 0.0,
        0.0,   -w * c2, 0.0, -c4, 0.0,
        0.0,    0.0,    0.0, 0.0, c9,
    ]);
    let g = &point.gram;
    let cross = SMatrix::<f64, 5, 5>::from_fn(|i, j| g[i][5 + j]) * mixing;
    let derivative_gram = SMatrix::<f64, 5, 5>::from_fn(|i, j| g[5 + i][5 + j]);
    let projected = point.phi_gram.solve_matrix(&cross);
    let jtj = mixing.transpose() * derivative_gram * mixing - cross.transpose() * projected;
    let jtr = mixing.transpose() * SVector::<f64, 5>::from(point.derivative_projections);
    (jtj, jtr)
}

/// Solves the damped normal equations; `None` if Cholesky fails.
fn damped_step(
    jtj: &SMatrix<f64, 5, 5>,
    jtr: &SVector<f64, 5>,
    lambda: f64,
) -> Option<SVector<f64, 5>> {
    let max_diag = jtj.diagonal().max();
    let floor = max_diag * 1e-15 + f64::MIN_POSITIVE;
    let mut a = *jtj;
    for i in 0..5 {
        a[(i, i)] += lambda * a[(i, i)].max(floor);
    }
    let delta = Cholesky5::new(&a)?.solve(jtr);
    delta.iter().all(|d| d.is_finite()).then_some(delta)
}

/// Levenberg-Marquardt over the nonlinear parameters with the linear ones projected
/// out; returns (point, rms residual, iterations, status) in scaled units.
pub(super) fn levenberg_marquardt(
    start: Evaluation,
    data: &Data<'_>,
    used: usize,
    options: &FitOptions,
) -> Result<(Evaluation, f64, u32, FitStatus), FitError> {
    const LAMBDA_MAX: f64 = 1e12;
    let mut point = start;
    let mut lambda = 1e-3;
    let mut status = FitStatus::MaxIterations;
    let mut iterations = 0;
    'outer: while iterations < options.max_iterations {
        iterations += 1;
        if point.cost == 0.0 {
            status = FitStatus::Converged;
            break;
        }
        let (jtj, jtr) = normal_equations(&point);
        loop {
            let Some(delta) = damped_step(&jtj, &jtr, lambda) else {
                lambda *= 10.0;
                if lambda > LAMBDA_MAX {
                    return Err(FitError::Singular);
                }
                continue;
            };
            // Near Gauss-Newton (small lambda), delta . J^T r estimates twice the cost
            // decrease the step can bring: when negligible, stop without another pass.
            let gain = delta.dot(&jtr);
            if lambda <= 1e-2 && gain <= options.tolerance * point.cost {
                status = FitStatus::Converged;
                break 'outer;
            }
            let mut trial = point.theta;
            for (p, d) in trial.iter_mut().zip(delta.iter()) {
                *p += d;
            }
            let candidate = evaluate(trial, data);
            if let Some(candidate) = candidate.filter(|c| c.cost < point.cost) {
                let decrease = (point.cost - candidate.cost) / point.cost;
                let small_step = delta
                    .iter()
                    .zip(trial.iter())
                    .all(|(d, p)| libm::fabs(*d) <= options.tolerance * (libm::fabs(*p) + 1e-6));
                point = candidate;
                lambda = (lambda / 3.0).max(1e-12);
                if decrease <= options.tolerance || small_step {
                    status = FitStatus::Converged;
                    break 'outer;
                }
                break;
            }
            lambda *= 10.0;
            if lambda > LAMBDA_MAX {
                status = FitStatus::Stalled;
                break 'outer;
            }
        }
    }
    let rms = libm::sqrt(point.cost / used as f64);
    Ok((point, rms, iterations, status))
}
