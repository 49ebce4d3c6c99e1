//! The damped tongues: their edges as roots of the Hill determinant between the
//! undamped edges and a point inside, and the estimate that skips tongues too narrow
//! for the damping.

use core::f64::consts::PI;

use super::characteristic::terms_for;
use super::monodromy::half_period_trace;
use super::search::{brent, golden_peak};
use super::settings::{check_a, Mathieu, MathieuError};

/// A damped tongue `n` is taken as absent without a search when its undamped width `w`
/// gives `skip_factor(w / n) * w / (4 n) < c`. A narrow tongue's largest exponent is
/// `w / (4 n)` to first order (`|Delta| - 2 ~ pi^2 ((w/2)^2 - (a - mid)^2) / (4 n^2)`);
/// measured over orders 1..=10 and q up to 100 it is at most 1.13 times that for
/// `w / n < 0.1`, 1.5 for `w / n < 1`, and 3.74 for the widest (n = 6, q = 100). The
/// factor `1.3 + 2 w / n`, at most 8, stays above every measured ratio by 15% or more;
/// the unit test `skip_estimate_is_conservative` checks it over a grid.
fn skip_factor(width_per_order: f64) -> f64 {
    (1.3 + 2.0 * width_per_order).min(8.0)
}

/// Hill function of the damped equation `x'' + 2c x' + (a - 2q cos 2t) x = 0` at real
/// `a`: zero exactly where a solution with Floquet multiplier +1 (`odd = false`:
/// harmonics `e^{ikt}`, k even) or -1 (`odd = true`: k odd) exists, i.e. on the edges
/// of the damped tongues of even or odd order.
///
/// With `x = sum X_k e^{ikt}` the equation is `(k^2 - 2ick - a) X_k + q (X_{k-2} +
/// X_{k+2}) = 0`: a complex symmetric tridiagonal matrix over `|k| <= K`. Its
/// determinant, each row divided by `k^2 + sqrt(a^2 + 1)` (positive and smooth, so the
/// roots stay and the value stays bounded), is computed by the continuant recurrence.
/// Flipping `k -> -k` conjugates the matrix, so the determinant is real for real `a`
/// (its imaginary part is rounding). `K` follows the characteristic values' truncation
/// ([`terms_for`]). Without damping its roots are the characteristic values of the
/// parity (unit test `hill_roots_are_the_characteristic_values_without_damping`).
///
/// This is Hill's determinant, not the monodromy: it finds the damped edges in about a
/// microsecond per evaluation where a converged monodromy costs several, and it is
/// exact at the edges, where `acosh` makes the monodromy's exponent least precise.
fn hill_function(odd: bool, a: f64, q: f64, c: f64) -> f64 {
    let terms = terms_for(q, a.abs()) as i32;
    let k_max = if odd { 2 * terms - 1 } else { 2 * terms };
    let scale = libm::sqrt(a * a + 1.0);
    // Continuant D_j = d_j D_{j-1} - e_j^2 D_{j-2} on normalised rows (complex as pairs).
    let (mut previous, mut current) = ((0.0, 0.0), (1.0, 0.0));
    let mut last_weight = 0.0;
    let mut k = -k_max;
    while k <= k_max {
        let kf = f64::from(k);
        let weight = kf * kf + scale;
        let d = ((kf * kf - a) / weight, -2.0 * c * kf / weight);
        let e2 = if last_weight > 0.0 {
            q * q / (weight * last_weight)
        } else {
            0.0
        };
        let next = (
            d.0 * current.0 - d.1 * current.1 - e2 * previous.0,
            d.0 * current.1 + d.1 * current.0 - e2 * previous.1,
        );
        previous = current;
        current = next;
        last_weight = weight;
        k += 2;
    }
    current.0
}

impl Mathieu {
    /// Edges in `a - c^2` of damped tongue `order` >= 1, given its undamped edges; an
    /// edge not asked for is NaN.
    ///
    /// The edges are the roots of the Hill function ([`hill_function`]) of the
    /// tongue's parity inside the undamped tongue shifted by `c^2`; it has the sign of
    /// the tongue's ends outside the damped part and the other sign inside. The middle
    /// (where a narrow tongue peaks) usually has the inside sign; when it has not, a
    /// golden-section search for the peak of `|Delta|` (monodromy, the step count
    /// converged at the middle) finds an inside point or shows there is none (wide
    /// tongues at large q peak off centre).
    pub(super) fn damped_edges(
        &self,
        order: u8,
        q: f64,
        c: f64,
        (lo, hi): (f64, f64),
        edges: Edges,
    ) -> Result<Option<(f64, f64)>, MathieuError> {
        let width = hi - lo;
        if c == 0.0 {
            return Ok((width > 0.0).then_some((lo, hi)));
        }
        let per_order = width / f64::from(order);
        if width.is_nan() || width <= 0.0 || skip_factor(per_order) * per_order / 4.0 < c {
            return Ok(None);
        }
        check_a(lo)?;
        check_a(hi)?;
        let shift = c * c;
        let odd = order % 2 == 1;
        let f = |a: f64| -> Result<f64, MathieuError> { Ok(hill_function(odd, a, q, c)) };
        let outside = f(lo + shift)?.signum();
        let middle = 0.5 * (lo + hi);
        let inside = if f(middle + shift)?.signum() != outside {
            Some(middle)
        } else {
            let threshold = libm::cosh(c * PI);
            let steps = self.converged_trace(middle, q)?.1;
            let g = |a: f64| -> Result<f64, MathieuError> {
                Ok(0.5 * half_period_trace(a, q, steps).0.abs() - threshold)
            };
            match golden_peak(g, lo, hi)? {
                Some(peak) if f(peak + shift)?.signum() != outside => Some(peak),
                _ => None,
            }
        };
        let Some(inside) = inside else {
            return Ok(None);
        };
        let tolerance = 1.0e-13 * (1.0 + inside.abs());
        let lower = if edges == Edges::Upper {
            f64::NAN
        } else {
            brent(f, lo + shift, inside + shift, tolerance)? - shift
        };
        let upper = if edges == Edges::Lower {
            f64::NAN
        } else {
            brent(f, inside + shift, hi + shift, tolerance)? - shift
        };
        Ok(Some((lower, upper)))
    }

    /// Upper edge in `a - c^2` of damped tongue 0 (below `a_0`): the first root of the
    /// periodic Hill function, below `a_0 + c^2` (where it is negative: between that
    /// root and the next).
    fn tongue_zero_edge(&self, q: f64, c: f64, a0: f64) -> Result<f64, MathieuError> {
        if c == 0.0 {
            return Ok(a0);
        }
        let shift = c * c;
        let f = |a: f64| -> Result<f64, MathieuError> { Ok(hill_function(false, a, q, c)) };
        let upper = a0 + shift;
        let sign = f(upper)?.signum();
        let mut step = shift.max(1.0e-6);
        let mut lower = upper - step;
        while f(lower)?.signum() == sign {
            step *= 2.0;
            lower = check_a(upper - step)?;
        }
        Ok(brent(f, lower, upper, 1.0e-13 * (1.0 + a0.abs()))? - shift)
    }

    /// Damped edges in `a - c^2` of tongue `order` (0..=10) given its undamped edges;
    /// tongue 0's lower edge is `-inf`; an edge not asked for is NaN.
    pub(super) fn damped_any(
        &self,
        order: u8,
        q: f64,
        c: f64,
        undamped: (f64, f64),
        edges: Edges,
    ) -> Result<Option<(f64, f64)>, MathieuError> {
        if order == 0 {
            return Ok(Some((
                f64::NEG_INFINITY,
                self.tongue_zero_edge(q, c, undamped.1)?,
            )));
        }
        self.damped_edges(order, q, c, undamped, edges)
    }
}

/// Which edges of a damped tongue to compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Edges {
    Lower,
    Upper,
    Both,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mathieu::characteristic::undamped_edges;
    use crate::mathieu::monodromy::mu_from_trace;
    use crate::mathieu::MAX_DAMPING;

    #[test]
    fn hill_roots_are_the_characteristic_values_without_damping() {
        let m = Mathieu::default();
        for q in [-3.0, 0.2, 1.0, 8.0, 40.0] {
            for order in 0..=6_u8 {
                let odd = order % 2 == 1;
                let mut values = [m.characteristic_a(order, q).unwrap(), f64::NAN];
                if order > 0 {
                    values[1] = m.characteristic_b(order, q).unwrap();
                }
                // A step inside the tongue; tongues narrower than 1e-9 are not resolved.
                let width = (values[0] - values[1]).abs();
                if width < 1e-9 {
                    continue;
                }
                for value in values.into_iter().filter(|v| v.is_finite()) {
                    let step = (1e-7 * (1.0 + value.abs())).min(0.25 * width);
                    let (below, above) = (
                        hill_function(odd, value - step, q, 0.0),
                        hill_function(odd, value + step, q, 0.0),
                    );
                    assert!(below * above < 0.0, "order {order} q {q}: {below} {above}");
                }
            }
        }
    }

    #[test]
    fn skip_estimate_is_conservative() {
        // Wherever the estimate declares a damped tongue absent, the largest exponent
        // inside the undamped tongue (dense scan) is indeed below c. Tongues narrower
        // than 1e-3 are left out: their exponent (~1e-4 and less) drowns in the noise
        // of acosh near |Delta| = 2 (a trace error of 1e-12 reads as mu ~ 4e-7).
        let m = Mathieu::default();
        for order in 1..=10_u8 {
            for q in [0.05, 0.3, 1.0, 3.0, 8.0, 20.0, 40.0, 100.0] {
                let (lo, hi) = undamped_edges(order, q);
                let width = hi - lo;
                let per_order = width / f64::from(order);
                let c = skip_factor(per_order) * per_order / 4.0 * 1.0001;
                if c > MAX_DAMPING || width < 1e-3 {
                    continue;
                }
                let largest = (1..200)
                    .map(|k| lo + width * f64::from(k) / 200.0)
                    .map(|a| mu_from_trace(m.converged_trace(a, q).unwrap().0))
                    .fold(0.0, f64::max);
                assert!(largest < c, "order {order} q {q}: mu {largest} >= c {c}");
            }
        }
    }
}
