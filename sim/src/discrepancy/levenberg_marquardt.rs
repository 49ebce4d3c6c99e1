//! A small dense Levenberg-Marquardt for the discrepancy workflow's model fits.
//!
//! Hand-rolled rather than taken from the `levenberg-marquardt` crate: that crate is
//! built on nalgebra 0.34 while the workspace uses 0.35 (two nalgebras in one build, and
//! no way to hand it our matrices), and our problems are tiny and specific: at most a
//! dozen parameters, every residual evaluation a full simulation, Jacobians by forward
//! differences, bounds handled by the caller's parametrisation. Marquardt's scaling
//! (`lambda * diag(J^T J)`) and Nielsen's damping update are the textbook choices.
//!
//! A finite-difference Jacobian costs one simulation per parameter, several times a
//! step's one, so between them the Jacobian is carried forward by Broyden's rank-one
//! update `J += (r_new - r - J s) s^T / (s^T s)` from every step taken (Madsen, Nielsen
//! and Tingleff, "Methods for non-linear least squares problems", 2004, sec. 3.4). It
//! is recomputed by differences when a step fails on an updated Jacobian (the update
//! may be what misled it) and after [`LmSettings::jacobian_refresh`] accepted steps.

use nalgebra::{DMatrix, DVector};

/// Settings of [`minimise`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LmSettings {
    /// Iteration limit (accepted or rejected steps), >= 1.
    pub(crate) max_iterations: usize,
    /// Stop when a step lowers the cost by less than this fraction of it.
    pub(crate) cost_tolerance: f64,
    /// Forward-difference step in parameter space.
    pub(crate) difference_step: f64,
    /// Largest change of any one parameter in one step (steps are scaled down to it),
    /// so trial points stay where the model can still be evaluated cheaply.
    pub(crate) max_step: f64,
    /// Accepted steps between finite-difference Jacobians, >= 1 (1: no Broyden
    /// updates).
    pub(crate) jacobian_refresh: usize,
}

impl Default for LmSettings {
    fn default() -> Self {
        LmSettings {
            max_iterations: 40,
            cost_tolerance: 1.0e-7,
            difference_step: 1.0e-6,
            max_step: 2.0,
            jacobian_refresh: 1,
        }
    }
}

/// Result of [`minimise`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LmResult {
    /// Parameters at the lowest cost found.
    pub(crate) params: Vec<f64>,
    /// Sum of squared residuals there.
    pub(crate) cost: f64,
}

/// A least-squares problem: a residual vector of fixed length and its Jacobian.
pub(crate) trait Residuals {
    /// Length of the residual vector.
    fn residual_count(&self) -> usize;

    /// Writes the residuals at `p` into `out` (length [`Residuals::residual_count`]); `false` when
    /// `p` cannot be evaluated (for example a simulation refused the model): such a
    /// point is treated as infinitely bad, so steps back off from it.
    fn evaluate(&mut self, p: &[f64], out: &mut [f64]) -> bool;

    /// Writes the Jacobian at `p` (residuals `r` there) into `jacobian` (residual_count x p.len());
    /// `false` when it cannot be formed.
    ///
    /// The default is forward differences of step `step` per column (backward where
    /// the forward point cannot be evaluated); problems whose residual blocks depend on
    /// few parameters override it to skip the zero blocks.
    fn jacobian(&mut self, p: &[f64], r: &[f64], step: f64, jacobian: &mut DMatrix<f64>) -> bool {
        let mut probe = p.to_vec();
        let mut shifted = vec![0.0; r.len()];
        for j in 0..p.len() {
            probe[j] = p[j] + step;
            if !self.evaluate(&probe, &mut shifted) {
                probe[j] = p[j] - step;
                if !self.evaluate(&probe, &mut shifted) {
                    return false;
                }
            }
            let h = probe[j] - p[j];
            for (i, (s, r)) in shifted.iter().zip(r).enumerate() {
                jacobian[(i, j)] = (s - r) / h;
            }
            probe[j] = p[j];
        }
        true
    }
}

/// A closure `residuals(p, out) -> bool` with `len` residuals, as a [`Residuals`].
pub(crate) struct FnResiduals<F> {
    /// Length of the residual vector.
    pub(crate) len: usize,
    /// The residual function (see [`Residuals::evaluate`]).
    pub(crate) function: F,
}

impl<F> std::fmt::Debug for FnResiduals<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FnResiduals")
            .field("len", &self.len)
            .finish_non_exhaustive()
    }
}

impl<F: FnMut(&[f64], &mut [f64]) -> bool> Residuals for FnResiduals<F> {
    fn residual_count(&self) -> usize {
        self.len
    }

    fn evaluate(&mut self, p: &[f64], out: &mut [f64]) -> bool {
        (self.function)(p, out)
    }
}

/// Minimises `sum residuals(p)^2` from `start`.
pub(crate) fn minimise(
    start: &[f64],
    settings: &LmSettings,
    problem: &mut impl Residuals,
) -> LmResult {
    let n = start.len();
    let m = problem.residual_count();
    let mut params = start.to_vec();
    let mut r = vec![0.0; m];
    let mut cost = if problem.evaluate(&params, &mut r) {
        sum_of_squares(&r)
    } else {
        f64::INFINITY
    };
    if n == 0 || !cost.is_finite() {
        return LmResult { params, cost };
    }
    let mut jacobian = DMatrix::<f64>::zeros(m, n);
    let mut trial_r = vec![0.0; m];
    let mut lambda = 1.0e-3;
    let mut nu = 2.0;
    // `None`: the Jacobian must be recomputed; `Some(k)`: it is k accepted steps old.
    let mut age: Option<usize> = None;
    for _ in 0..settings.max_iterations {
        if age.is_none_or(|k| k >= settings.jacobian_refresh.max(1)) {
            if !problem.jacobian(&params, &r, settings.difference_step, &mut jacobian) {
                break;
            }
            age = Some(0);
        }
        let jtj = jacobian.transpose() * &jacobian;
        let gradient = jacobian.transpose() * DVector::from_column_slice(&r);
        let mut system = jtj.clone();
        for j in 0..n {
            system[(j, j)] += lambda * jtj[(j, j)].max(1.0e-12);
        }
        let Some(mut step) = system.cholesky().map(|c| c.solve(&(-&gradient))) else {
            lambda *= nu;
            nu *= 2.0;
            continue;
        };
        let largest = step.amax();
        if largest > settings.max_step {
            step *= settings.max_step / largest;
        }
        let trial: Vec<f64> = params.iter().zip(step.iter()).map(|(p, s)| p + s).collect();
        let evaluated = problem.evaluate(&trial, &mut trial_r);
        let trial_cost = if evaluated {
            sum_of_squares(&trial_r)
        } else {
            f64::INFINITY
        };
        // Gain ratio: actual decrease over the decrease the linear model predicts.
        let predicted = step.dot(&(lambda * jtj.diagonal().component_mul(&step) - &gradient));
        let updated = age.is_some_and(|k| k > 0);
        if evaluated && settings.jacobian_refresh > 1 {
            broyden(&mut jacobian, &step, &r, &trial_r);
        }
        if trial_cost < cost {
            let decrease = cost - trial_cost;
            params = trial;
            std::mem::swap(&mut r, &mut trial_r);
            cost = trial_cost;
            age = if settings.jacobian_refresh > 1 {
                age.map(|k| k + 1)
            } else {
                None
            };
            let rho = if predicted > 0.0 {
                decrease / predicted
            } else {
                1.0
            };
            lambda *= (1.0_f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
            nu = 2.0;
            if decrease < settings.cost_tolerance * cost {
                break;
            }
        } else if updated {
            // The step may have failed on the updated Jacobian: recompute it and retry
            // with the same damping.
            age = None;
        } else {
            lambda *= nu;
            nu *= 2.0;
            if lambda > 1.0e12 {
                break;
            }
        }
    }
    LmResult { params, cost }
}

/// Broyden's rank-one update of `jacobian` from the step `step` that took the
/// residuals from `before` to `after`.
fn broyden(jacobian: &mut DMatrix<f64>, step: &DVector<f64>, before: &[f64], after: &[f64]) {
    let norm = step.norm_squared();
    if norm <= 0.0 {
        return;
    }
    let predicted = &*jacobian * step;
    let mismatch = DVector::from_iterator(
        after.len(),
        after
            .iter()
            .zip(before)
            .zip(predicted.iter())
            .map(|((a, b), p)| (a - b - p) / norm),
    );
    jacobian.ger(1.0, &mismatch, step, 1.0);
}

/// Sum of squares of `values`.
pub(crate) fn sum_of_squares(values: &[f64]) -> f64 {
    values.iter().map(|v| v * v).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_a_damped_exponential() {
        // y = 3 exp(-2 t) + 0.5, parameters (amplitude, log rate, offset).
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.05).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * (-2.0 * t).exp() + 0.5).collect();
        let mut problem = FnResiduals {
            len: t.len(),
            function: |p: &[f64], out: &mut [f64]| {
                for ((o, t), y) in out.iter_mut().zip(&t).zip(&y) {
                    *o = p[0] * (-p[1].exp() * t).exp() + p[2] - y;
                }
                true
            },
        };
        let result = minimise(&[1.0, 0.0, 0.0], &LmSettings::default(), &mut problem);
        assert!((result.params[0] - 3.0).abs() < 1e-5, "{result:?}");
        assert!((result.params[1].exp() - 2.0).abs() < 1e-5, "{result:?}");
        assert!((result.params[2] - 0.5).abs() < 1e-5, "{result:?}");
        assert!(result.cost < 1e-12);
    }

    #[test]
    fn backs_off_from_points_that_cannot_be_evaluated() {
        // Minimum of (p - 2)^2 with p > 1.5 refused: the fit must stay in the allowed
        // region and end at its edge side, never at a refused point.
        let mut problem = FnResiduals {
            len: 1,
            function: |p: &[f64], out: &mut [f64]| {
                out[0] = p[0] - 2.0;
                p[0] <= 1.5
            },
        };
        let result = minimise(&[0.0], &LmSettings::default(), &mut problem);
        assert!(result.params[0] <= 1.5);
        assert!(result.params[0] > 1.0, "{result:?}");
    }
}
