//! A small dense Levenberg-Marquardt for the discrepancy workflow's model fits.
//!
//! Hand-rolled rather than taken from the `levenberg-marquardt` crate: that crate is
//! built on nalgebra 0.34 while the workspace uses 0.35 (two nalgebras in one build, and
//! no way to hand it our matrices), and our problems are tiny and specific: at most a
//! dozen parameters, every residual evaluation a full simulation, Jacobians by forward
//! differences, bounds handled by the caller's parametrisation. Marquardt's scaling
//! (`lambda * diag(J^T J)`) and Nielsen's damping update are the textbook choices.

use nalgebra::{DMatrix, DVector};

/// Settings of [`minimise`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmSettings {
    /// Iteration limit (accepted or rejected steps), >= 1.
    pub max_iterations: usize,
    /// Stop when a step lowers the cost by less than this fraction of it.
    pub cost_tolerance: f64,
    /// Forward-difference step in parameter space.
    pub difference_step: f64,
    /// Largest change of any one parameter in one step (steps are scaled down to it),
    /// so trial points stay where the model can still be evaluated cheaply.
    pub max_step: f64,
}

impl Default for LmSettings {
    fn default() -> Self {
        LmSettings {
            max_iterations: 40,
            cost_tolerance: 1.0e-7,
            difference_step: 1.0e-6,
            max_step: 2.0,
        }
    }
}

/// Result of [`minimise`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmResult {
    /// Parameters at the lowest cost found.
    pub params: Vec<f64>,
    /// Sum of squared residuals there.
    pub cost: f64,
    /// Residual evaluations spent (each one simulation for the workflow's problems).
    pub evaluations: usize,
}

/// Minimises `sum residuals(p)^2` from `start`.
///
/// `residuals(p, out)` writes the residual vector (fixed length `m`) into `out` and
/// returns `false` when `p` cannot be evaluated (for example a simulation refused the
/// model): such a point is treated as infinitely bad, so steps back off from it.
pub fn minimise<F>(start: &[f64], m: usize, settings: &LmSettings, mut residuals: F) -> LmResult
where
    F: FnMut(&[f64], &mut [f64]) -> bool,
{
    let n = start.len();
    let mut params = start.to_vec();
    let mut r = vec![0.0; m];
    let mut evaluations = 1;
    let mut cost = if residuals(&params, &mut r) {
        sum_of_squares(&r)
    } else {
        f64::INFINITY
    };
    if n == 0 || !cost.is_finite() {
        return LmResult {
            params,
            cost,
            evaluations,
        };
    }
    let mut jacobian = DMatrix::<f64>::zeros(m, n);
    let mut probe = params.clone();
    let mut shifted = vec![0.0; m];
    let mut trial_r = vec![0.0; m];
    let mut lambda = 1.0e-3;
    let mut nu = 2.0;
    let mut fresh_jacobian = false;
    for _ in 0..settings.max_iterations {
        if !fresh_jacobian {
            for j in 0..n {
                probe.copy_from_slice(&params);
                probe[j] += settings.difference_step;
                evaluations += 1;
                if !residuals(&probe, &mut shifted) {
                    probe[j] = params[j] - settings.difference_step;
                    evaluations += 1;
                    if !residuals(&probe, &mut shifted) {
                        return LmResult {
                            params,
                            cost,
                            evaluations,
                        };
                    }
                }
                let h = probe[j] - params[j];
                for i in 0..m {
                    jacobian[(i, j)] = (shifted[i] - r[i]) / h;
                }
            }
            fresh_jacobian = true;
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
        evaluations += 1;
        let trial_cost = if residuals(&trial, &mut trial_r) {
            sum_of_squares(&trial_r)
        } else {
            f64::INFINITY
        };
        // Gain ratio: actual decrease over the decrease the linear model predicts.
        let predicted = step.dot(&(lambda * jtj.diagonal().component_mul(&step) - &gradient));
        if trial_cost < cost {
            let decrease = cost - trial_cost;
            params = trial;
            std::mem::swap(&mut r, &mut trial_r);
            cost = trial_cost;
            fresh_jacobian = false;
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
        } else {
            lambda *= nu;
            nu *= 2.0;
            if lambda > 1.0e12 {
                break;
            }
        }
    }
    LmResult {
        params,
        cost,
        evaluations,
    }
}

/// Sum of squares of `values`.
pub fn sum_of_squares(values: &[f64]) -> f64 {
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
        let result = minimise(
            &[1.0, 0.0, 0.0],
            t.len(),
            &LmSettings::default(),
            |p, out| {
                for ((o, t), y) in out.iter_mut().zip(&t).zip(&y) {
                    *o = p[0] * (-p[1].exp() * t).exp() + p[2] - y;
                }
                true
            },
        );
        assert!((result.params[0] - 3.0).abs() < 1e-5, "{result:?}");
        assert!((result.params[1].exp() - 2.0).abs() < 1e-5, "{result:?}");
        assert!((result.params[2] - 0.5).abs() < 1e-5, "{result:?}");
        assert!(result.cost < 1e-12);
    }

    #[test]
    fn backs_off_from_points_that_cannot_be_evaluated() {
        // Minimum of (p - 2)^2 with p > 1.5 refused: the fit must stay in the allowed
        // region and end at its edge side, never at a refused point.
        let result = minimise(&[0.0], 1, &LmSettings::default(), |p, out| {
            out[0] = p[0] - 2.0;
            p[0] <= 1.5
        });
        assert!(result.params[0] <= 1.5);
        assert!(result.params[0] > 1.0, "{result:?}");
    }
}
