//! Characteristic values: the four DLMF 28.4 recurrence classes as symmetric
//! tridiagonal matrices, Sturm counts of their LDL^T pivots and the safeguarded Newton
//! search for an eigenvalue by its index.

use core::f64::consts::SQRT_2;

use super::settings::ROUNDING_FLOOR;

/// Terms kept per recurrence class: Fourier orders up to 64. At |q| = 100 the first six
/// eigenvalues of each class need 18 (golden.py's size study); 32 leaves a wide margin.
pub(super) const TERMS: usize = 32;

/// Iteration cap of the safeguarded eigenvalue search (bisection alone needs ~60).
const MAX_EIGEN_ITERATIONS: usize = 200;

/// The four parity/period classes of the DLMF 28.4 recurrences.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Class {
    /// `a_2m`: coefficients A_0, A_2, ...; period pi, even.
    EvenA,
    /// `a_2m+1`: A_1, A_3, ...; period 2 pi, even.
    OddA,
    /// `b_2m+1`: B_1, B_3, ...; period 2 pi, odd.
    OddB,
    /// `b_2m+2`: B_2, B_4, ...; period pi, odd.
    EvenB,
}

pub(super) const CLASSES: [Class; 4] = [Class::EvenA, Class::OddA, Class::OddB, Class::EvenB];

impl Class {
    /// Diagonal entry `i` of the symmetric class matrix at `q`.
    fn diagonal(self, q: f64, i: usize) -> f64 {
        let order = match self {
            Class::EvenA => 2 * i,
            Class::OddA | Class::OddB => 2 * i + 1,
            Class::EvenB => 2 * i + 2,
        } as f64;
        let square = order * order;
        match (self, i) {
            (Class::OddA, 0) => square + q,
            (Class::OddB, 0) => square - q,
            _ => square,
        }
    }

    /// The `k`-th smallest diagonal entry: they increase from row 1 on; only row 0 of
    /// the odd classes (`1 +- q`) may fall among the others.
    fn kth_diagonal(self, q: f64, k: usize) -> f64 {
        let first = self.diagonal(q, 0);
        // Rows 1.. below row 0, at most k + 1 of interest.
        let below = (1..=k + 1)
            .take_while(|&i| self.diagonal(q, i) < first)
            .count();
        if k < below {
            self.diagonal(q, k + 1)
        } else if k == below {
            first
        } else {
            self.diagonal(q, k)
        }
    }

    /// Square of the off-diagonal entry joining rows `i - 1` and `i` (`i >= 1`): q^2,
    /// except `2 q^2` in the `a_2m` class, whose first row is scaled by sqrt(2) to make
    /// the matrix symmetric (DLMF 28.4.5 has `2 A_0` in the second equation).
    fn off_squared(self, q: f64, i: usize) -> f64 {
        if self == Class::EvenA && i == 1 {
            2.0 * q * q
        } else {
            q * q
        }
    }

    /// The class and index within it of `a_n`.
    pub(super) fn of_a(order: u8) -> (Class, usize) {
        let index = usize::from(order / 2);
        if order.is_multiple_of(2) {
            (Class::EvenA, index)
        } else {
            (Class::OddA, index)
        }
    }

    /// The class and index within it of `b_n`, `n >= 1`.
    pub(super) fn of_b(order: u8) -> (Class, usize) {
        let index = usize::from((order - 1) / 2);
        if order % 2 == 1 {
            (Class::OddB, index)
        } else {
            (Class::EvenB, index)
        }
    }

    /// Sturm count: the number of eigenvalues below `x` of the class matrix truncated
    /// at `terms`, as the number of negative LDL^T pivots of `T - x I`.
    pub(super) fn count(self, q: f64, x: f64, terms: usize) -> usize {
        let pivot_min = pivot_min(q);
        let mut count = 0;
        let mut pivot = 1.0;
        for i in 0..terms {
            let value = if i == 0 {
                self.diagonal(q, 0) - x
            } else {
                self.diagonal(q, i) - x - self.off_squared(q, i) / pivot
            };
            pivot = guard(value, pivot_min);
            count += usize::from(pivot < 0.0);
        }
        count
    }

    /// The Sturm count and `det / det'` of `T - x I` (the Newton correction; NaN where
    /// the pivots overflow), from one pivot pass that also differentiates the pivots in
    /// `x`.
    fn newton_pass(self, q: f64, x: f64, terms: usize) -> (usize, f64) {
        let pivot_min = pivot_min(q);
        let mut count = 0;
        // 1 / pivot and the pivot's derivative in x: one division per row.
        let mut inverse = 0.0;
        let mut derivative = 0.0;
        let mut log_derivative = 0.0;
        for i in 0..terms {
            let (value, slope) = if i == 0 {
                (self.diagonal(q, 0) - x, -1.0)
            } else {
                let e2 = self.off_squared(q, i);
                (
                    self.diagonal(q, i) - x - e2 * inverse,
                    -1.0 + e2 * derivative * inverse * inverse,
                )
            };
            let pivot = guard(value, pivot_min);
            inverse = 1.0 / pivot;
            derivative = slope;
            count += usize::from(pivot < 0.0);
            log_derivative += derivative * inverse;
        }
        // At (or within rounding of) an eigenvalue of a leading block the pivots
        // overflow: no Newton step then (NaN makes the caller bisect).
        let correction = if log_derivative.is_finite() && log_derivative != 0.0 {
            1.0 / log_derivative
        } else {
            f64::NAN
        };
        (count, correction)
    }

    /// Eigenvalue `index` (0 = smallest) of the class matrix at `q`.
    ///
    /// Weyl's inequality brackets it: the off-diagonal part has spectral norm at most
    /// `2 sqrt(2) |q|`, so eigenvalue k lies within that of the k-th smallest diagonal
    /// entry. Bisection on the Sturm count isolates it (exactly one eigenvalue in the
    /// bracket), then Newton steps on the determinant converge, each step kept in the
    /// bracket (a bisection otherwise), until the step stops shrinking at rounding.
    pub(super) fn eigenvalue(self, q: f64, index: usize) -> f64 {
        let centre = self.kth_diagonal(q, index);
        let spread = 2.0 * SQRT_2 * q.abs() * (1.0 + 1.0e-12) + 1.0e-12 * (1.0 + centre.abs());
        let mut lo = centre - spread;
        let mut hi = centre + spread;
        let terms = terms_for(q, hi);
        let mut count_lo = self.count(q, lo, terms);
        let mut count_hi = self.count(q, hi, terms);
        let mut x = 0.5 * (lo + hi);
        let mut last_step = f64::INFINITY;
        for _ in 0..MAX_EIGEN_ITERATIONS {
            let (count, correction) = self.newton_pass(q, x, terms);
            if count > index {
                hi = x;
                count_hi = count;
            } else {
                lo = x;
                count_lo = count;
            }
            let scale = 1.0 + x.abs();
            if hi - lo <= 4.0 * f64::EPSILON * scale {
                return 0.5 * (lo + hi);
            }
            let newton = x - correction;
            let isolated = count_lo == index && count_hi == index + 1;
            let step = (newton - x).abs();
            // Quadratic convergence ends at rounding: the step stops shrinking (early
            // steps may grow; only a tiny step that stalls counts). The root may sit
            // on a bracket end, so a converged step is not required to be inside.
            let stalled = step >= last_step && step <= ROUNDING_FLOOR * scale;
            if isolated && (step <= 8.0 * f64::EPSILON * scale || stalled) {
                return newton.clamp(lo, hi);
            }
            if isolated && newton > lo && newton < hi {
                last_step = step;
                x = newton;
            } else {
                x = 0.5 * (lo + hi);
            }
        }
        x
    }
}

/// Smallest pivot magnitude: a zero pivot is replaced by `-pivot_min` (as LAPACK's
/// dstebz does).
fn pivot_min(q: f64) -> f64 {
    f64::MIN_POSITIVE * (1.0 + 2.0 * q * q)
}

fn guard(pivot: f64, pivot_min: f64) -> f64 {
    if pivot.abs() < pivot_min {
        -pivot_min
    } else {
        pivot
    }
}

/// Terms per class that resolve every eigenvalue below `x` at `q` to rounding: the
/// eigenvector's coefficients decay by about `q / (2m)^2` per term once `(2m)^2`
/// exceeds `x + 2|q|`; ten terms past that, plus `sqrt|q|` for the slow start of the
/// decay at large |q|, are enough (at |q| = 100 the size study in golden.py needs 18
/// for the first six eigenvalues; this gives 28). The unit test
/// `adaptive_truncation_matches_the_full_matrix` compares with all 32.
pub(super) fn terms_for(q: f64, x: f64) -> usize {
    let onset = libm::sqrt(x.max(0.0) + 4.0 * q.abs()) / 2.0;
    let terms = onset + 10.0 + libm::sqrt(q.abs());
    (libm::ceil(terms) as usize).clamp(12, TERMS)
}

/// Number of characteristic values (`a_n` and `b_n` together) below `x` at `q`.
pub(super) fn count_below(q: f64, x: f64) -> usize {
    let terms = terms_for(q, x);
    CLASSES.iter().map(|class| class.count(q, x, terms)).sum()
}

/// Edges `(lower, upper)` of undamped tongue `order` at `q`; tongue 0 has lower edge
/// `-inf` and upper edge `a_0`.
pub(super) fn undamped_edges(order: u8, q: f64) -> (f64, f64) {
    let (a_class, a_index) = Class::of_a(order);
    let a_n = a_class.eigenvalue(q, a_index);
    if order == 0 {
        return (f64::NEG_INFINITY, a_n);
    }
    let (b_class, b_index) = Class::of_b(order);
    let b_n = b_class.eigenvalue(q, b_index);
    (a_n.min(b_n), a_n.max(b_n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mathieu::Mathieu;

    #[test]
    fn classes_order_as_the_merged_sequence() {
        // q > 0: a0 < b1 < a1 < b2 < a2 < b3 < a3.
        let m = Mathieu::default();
        let q = 2.0;
        let values = [
            m.characteristic_a(0, q).unwrap(),
            m.characteristic_b(1, q).unwrap(),
            m.characteristic_a(1, q).unwrap(),
            m.characteristic_b(2, q).unwrap(),
            m.characteristic_a(2, q).unwrap(),
            m.characteristic_b(3, q).unwrap(),
            m.characteristic_a(3, q).unwrap(),
        ];
        assert!(values.windows(2).all(|w| w[0] < w[1]), "{values:?}");
        for (k, &v) in values.iter().enumerate() {
            assert_eq!(count_below(q, v - 1e-9), k);
            assert_eq!(count_below(q, v + 1e-9), k + 1);
        }
    }

    #[test]
    fn adaptive_truncation_matches_the_full_matrix() {
        for q in [-100.0, -7.0, 0.01, 0.4, 3.0, 30.0, 100.0] {
            for class in CLASSES {
                for index in 0..6 {
                    let value = class.eigenvalue(q, index);
                    // Full-size Sturm counts just around it.
                    let step = 1e-13 * (1.0 + value.abs());
                    assert_eq!(class.count(q, value - step, TERMS), index, "{class:?} {q}");
                    assert_eq!(
                        class.count(q, value + step, TERMS),
                        index + 1,
                        "{class:?} {q}"
                    );
                }
            }
        }
    }
}
