//! Mathieu equation `x'' + 2c x' + (a - 2q cos 2t) x = 0`: characteristic values,
//! Floquet growth exponent and the instability tongues of the Ince-Strutt diagram.
//!
//! A rod between two rolling stands whose tension pulsates reduces to this equation per
//! bending mode (domain notes 3): `a = 4 w^2 / Theta^2`, `q` proportional to the
//! pulsation amplitude, `c = zeta sqrt(a)` from the modal damping ratio, time `t` in
//! units of `Theta t_s / 2`. This module knows nothing of rods; it answers, for any
//! `(a, q, c)`:
//!
//! - **characteristic values** `a_n(q)` (n = 0..=10) and `b_n(q)` (n = 1..=10), the
//!   edges of the undamped tongues, for |q| <= 100, to about 1e-13 relative (better than
//!   1e-10 is what the golden test demands). The DLMF 28.4 recurrences split into four
//!   symmetric tridiagonal matrices, one per parity/period class (`a_2m`, `a_2m+1`,
//!   `b_2m+1`, `b_2m+2`), truncated at 12..=32 terms each by `|q|` and the value
//!   sought (the truncation is checked against all 32). The eigenvalue is chosen by its
//!   index in its class, never as "the one nearest n^2" (which jumps branches at large
//!   q): a Sturm count of the LDL^T pivots isolates it, then Newton steps on the
//!   determinant (its logarithmic derivative comes out of the same pivot pass) finish it,
//!   each step kept inside the isolating bracket.
//! - the **growth exponent** per unit `t`: with `x = exp(-c t) y`, `y'' + (a - c^2 -
//!   2q cos 2t) y = 0`, so the exponent is `mu(a - c^2, q) - c`, where `mu = ln |largest
//!   Floquet multiplier| / pi` of the undamped equation. `mu` is 0 wherever `a - c^2`
//!   lies in a stable gap (decided by the Sturm counts, no integration). Inside a
//!   tongue the monodromy trace `Delta = y1(pi) + y2'(pi)` comes from the fundamental
//!   solutions over half a period (the coefficient is even, so `Delta = 2 (y1 y2' +
//!   y1' y2)(pi / 2)`), integrated by the sixth-order Magnus method on Gauss-Legendre
//!   nodes, whose step `exp(Omega)` is exact for a frozen coefficient, so fast
//!   oscillation costs no steps. The step count doubles until the finer trace's
//!   estimated error (the change / 63) is within the tolerance; then
//!   `mu = acosh(|Delta| / 2) / pi`.
//! - the **tongues**: tongue `n >= 1` lies between `a_n(q)` and `b_n(q)`; "tongue 0" is
//!   the region below `a_0(q)`. With damping the unstable set of tongue n shrinks to
//!   where `|Delta(a - c^2, q)| > 2 cosh(c pi)`. Its edges are where the damped equation
//!   has a solution with multiplier +1 or -1: the real roots of its Hill determinant
//!   (a complex tridiagonal continuant, real on the real axis; `hill_function`),
//!   found by Brent's method between the undamped edges (shifted by `c^2`) and a point
//!   inside (the middle, or the peak of `|Delta|` by golden section when the tongue is
//!   wide). Tongues too narrow for the damping are skipped by an estimate checked over a
//!   grid. [`Mathieu::locate`] gives the nearest tongue (damped, when `c > 0`) and the
//!   signed distance in `a` to its nearest edge, visiting only tongues that could be
//!   nearer than the best found.
//!
//! Everything is stack-only (`no_std`, no heap). Nothing is streamed, so there is no
//! state: a [`Mathieu`] holds the solver's tolerance and step limit, built once.
//!
//! ```
//! use millgate_dsp::mathieu::Mathieu;
//! let mathieu = Mathieu::default();
//! // Abramowitz and Stegun Table 20.1, q = 1.
//! assert!((mathieu.characteristic_a(1, 1.0).unwrap() - 1.85910807).abs() < 1e-8);
//! // Inside the principal tongue: grows without damping, decays with enough of it.
//! assert!(mathieu.exponent(1.0, 0.4, 0.0).unwrap() > 0.19);
//! assert!(mathieu.exponent(1.0, 0.4, 0.3).unwrap() < 0.0);
//! let location = mathieu.locate(1.0, 0.4, 0.0).unwrap();
//! assert_eq!((location.order, location.inside), (1, true));
//! ```

use core::f64::consts::{PI, SQRT_2};
use core::fmt;

/// Largest order n of the characteristic values and tongues handled.
pub const MAX_ORDER: u8 = 10;

/// Largest |q| accepted.
pub const MAX_ABS_Q: f64 = 100.0;

/// Largest |a| (and |a - c^2|) accepted.
pub const MAX_ABS_A: f64 = 1.0e4;

/// Largest damping coefficient c accepted (per unit t).
pub const MAX_DAMPING: f64 = 10.0;

/// Terms kept per recurrence class: Fourier orders up to 64. At |q| = 100 the first six
/// eigenvalues of each class need 18 (golden.py's size study); 32 leaves a wide margin.
const TERMS: usize = 32;

/// Iteration cap of the safeguarded eigenvalue search (bisection alone needs ~60).
const MAX_EIGEN_ITERATIONS: usize = 200;

/// Iteration cap of the golden-section and Brent searches.
const MAX_SEARCH_ITERATIONS: usize = 200;

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

/// Largest relative change of the trace taken as rounding when it stops shrinking with
/// doubled steps (see [`Mathieu::trace`]).
const ROUNDING_FLOOR: f64 = 1.0e-9;

/// Steps between exact recomputations of the rotating phasor of `cos 2t`.
const RESYNC_STEPS: usize = 16;

/// Gauss-Legendre nodes of the Magnus step, as fractions of the step.
const NODE_OFFSET: f64 = 0.387_298_334_620_741_7; // sqrt(15) / 10

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
    /// The tolerance is not in `1e-14..=1e-6` or the step limit is below 64.
    Settings,
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
            MathieuError::Settings => write!(
                f,
                "Mathieu solver tolerance must be in 1e-14..=1e-6 and the step limit >= 64"
            ),
            MathieuError::NotConverged => write!(
                f,
                "Mathieu monodromy trace did not converge within the step limit"
            ),
        }
    }
}

impl core::error::Error for MathieuError {}

/// Where a point of the Ince-Strutt plane lies relative to the nearest tongue.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TongueLocation {
    /// Order of the nearest tongue, 0..=10 (0: the region below `a_0(q)`, unstable
    /// without damping).
    pub order: u8,
    /// True when the point is inside it (unstable).
    pub inside: bool,
    /// Signed distance in `a` to that tongue's nearest edge at the same `q` (and `c`):
    /// positive outside (stable), negative inside. Above tongue 10 it is the distance
    /// to tongue 10's upper edge (higher tongues are not resolved).
    pub distance: f64,
}

/// Solver settings: the Mathieu "coefficients", built once and shared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mathieu {
    tolerance: f64,
    max_steps: usize,
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

/// The four parity/period classes of the DLMF 28.4 recurrences.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Class {
    /// `a_2m`: coefficients A_0, A_2, ...; period pi, even.
    EvenA,
    /// `a_2m+1`: A_1, A_3, ...; period 2 pi, even.
    OddA,
    /// `b_2m+1`: B_1, B_3, ...; period 2 pi, odd.
    OddB,
    /// `b_2m+2`: B_2, B_4, ...; period pi, odd.
    EvenB,
}

const CLASSES: [Class; 4] = [Class::EvenA, Class::OddA, Class::OddB, Class::EvenB];

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
    fn of_a(order: u8) -> (Class, usize) {
        let index = usize::from(order / 2);
        if order.is_multiple_of(2) {
            (Class::EvenA, index)
        } else {
            (Class::OddA, index)
        }
    }

    /// The class and index within it of `b_n`, `n >= 1`.
    fn of_b(order: u8) -> (Class, usize) {
        let index = usize::from((order - 1) / 2);
        if order % 2 == 1 {
            (Class::OddB, index)
        } else {
            (Class::EvenB, index)
        }
    }

    /// Sturm count: the number of eigenvalues below `x` of the class matrix truncated
    /// at `terms`, as the number of negative LDL^T pivots of `T - x I`.
    fn count(self, q: f64, x: f64, terms: usize) -> usize {
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
    fn eigenvalue(self, q: f64, index: usize) -> f64 {
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
fn terms_for(q: f64, x: f64) -> usize {
    let onset = libm::sqrt(x.max(0.0) + 4.0 * q.abs()) / 2.0;
    let terms = onset + 10.0 + libm::sqrt(q.abs());
    (libm::ceil(terms) as usize).clamp(12, TERMS)
}

/// Number of characteristic values (`a_n` and `b_n` together) below `x` at `q`.
fn count_below(q: f64, x: f64) -> usize {
    let terms = terms_for(q, x);
    CLASSES.iter().map(|class| class.count(q, x, terms)).sum()
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

/// `mu = ln |largest multiplier| / pi` from the monodromy trace of the undamped
/// equation (multipliers solve `l^2 - Delta l + 1 = 0`).
fn mu_from_trace(trace: f64) -> f64 {
    let half = 0.5 * trace.abs();
    if half <= 1.0 {
        0.0
    } else {
        libm::acosh(half) / PI
    }
}

/// A traceless 2x2 matrix `[[p, u], [v, -p]]`: every Magnus term of `y'' = -w y` is one.
#[derive(Clone, Copy, Debug)]
struct Traceless {
    p: f64,
    u: f64,
    v: f64,
}

impl Traceless {
    fn commutator(self, other: Traceless) -> Traceless {
        Traceless {
            p: self.u * other.v - other.u * self.v,
            u: 2.0 * (self.p * other.u - other.p * self.u),
            v: 2.0 * (other.p * self.v - self.p * other.v),
        }
    }

    fn scaled_sum(terms: &[(f64, Traceless)]) -> Traceless {
        terms.iter().fold(
            Traceless {
                p: 0.0,
                u: 0.0,
                v: 0.0,
            },
            |acc, &(k, m)| Traceless {
                p: acc.p + k * m.p,
                u: acc.u + k * m.u,
                v: acc.v + k * m.v,
            },
        )
    }

    /// `exp(self)` as a row-major 2x2: `cosh(s) I + sinh(s) / s * self`, `s^2 = -det`.
    fn exp(self) -> [f64; 4] {
        let s2 = self.p * self.p + self.u * self.v;
        let (cosh, sinhc) = if s2.abs() < 1.0e-6 {
            // Taylor series in s^2: the error term s^8 / 8! is below 1e-52.
            let s4 = s2 * s2;
            (
                1.0 + s2 / 2.0 + s4 / 24.0 + s4 * s2 / 720.0,
                1.0 + s2 / 6.0 + s4 / 120.0 + s4 * s2 / 5040.0,
            )
        } else if s2 > 0.0 {
            let s = libm::sqrt(s2);
            let em1 = libm::expm1(s);
            let e = 1.0 + em1;
            (0.5 * (e + 1.0 / e), 0.5 * (em1 + em1 / e) / s)
        } else {
            let s = libm::sqrt(-s2);
            let (sin, cos) = libm::sincos(s);
            (cos, sin / s)
        };
        [
            cosh + sinhc * self.p,
            sinhc * self.u,
            sinhc * self.v,
            cosh - sinhc * self.p,
        ]
    }
}

/// Monodromy trace over one period pi of `y'' + (a - 2q cos 2t) y = 0`, from the
/// fundamental solutions over `[0, pi/2]` with `steps` sixth-order Magnus steps, and
/// the magnitude of the terms it sums (`2 (|y1 y2'| + |y1' y2|)`, >= 2): rounding
/// errors scale with it, not with the trace, where the two terms cancel.
///
/// Magnus step (Blanes, Casas and Ros 2000) with `A_i = A(t + c_i h)` at the
/// Gauss-Legendre nodes `c = 1/2 -+ sqrt(15)/10, 1/2`: `a1 = h A2`,
/// `a2 = sqrt(15) h / 3 (A3 - A1)`, `a3 = 10 h / 3 (A3 - 2 A2 + A1)`, `C1 = [a1, a2]`,
/// `C2 = -[a1, 2 a3 + C1] / 60`, `Omega = a1 + a3 / 12 + [-20 a1 - a3 + C1, a2 + C2] / 240`.
fn half_period_trace(a: f64, q: f64, steps: usize) -> (f64, f64) {
    let h = 0.5 * PI / steps as f64;
    // cos 2t at the nodes: the step start's phasor (rotated step by step, recomputed
    // every RESYNC_STEPS steps so rounding cannot build up) times the nodes' offsets.
    let offsets = [0.5 - NODE_OFFSET, 0.5, 0.5 + NODE_OFFSET].map(|c| libm::sincos(2.0 * c * h));
    let sqrt15_h_3 = libm::sqrt(15.0) * h / 3.0;
    let ten_h_3 = 10.0 * h / 3.0;
    // Fundamental matrix, row-major: [y1, y2; y1', y2'].
    let mut y = [1.0, 0.0, 0.0, 1.0];
    let (sin_step, cos_step) = libm::sincos(2.0 * h);
    let (mut sin0, mut cos0) = (0.0, 1.0);
    for k in 0..steps {
        if k % RESYNC_STEPS == 0 {
            (sin0, cos0) = libm::sincos(2.0 * k as f64 * h);
        }
        let w = offsets.map(|(sin, cos)| a - 2.0 * q * (cos0 * cos - sin0 * sin));
        let alpha1 = Traceless {
            p: 0.0,
            u: h,
            v: -h * w[1],
        };
        let alpha2 = Traceless {
            p: 0.0,
            u: 0.0,
            v: -sqrt15_h_3 * (w[2] - w[0]),
        };
        let alpha3 = Traceless {
            p: 0.0,
            u: 0.0,
            v: -ten_h_3 * (w[2] - 2.0 * w[1] + w[0]),
        };
        let c1 = alpha1.commutator(alpha2);
        let c2 = alpha1.commutator(Traceless::scaled_sum(&[(2.0, alpha3), (1.0, c1)]));
        let c2 = Traceless::scaled_sum(&[(-1.0 / 60.0, c2)]);
        let left = Traceless::scaled_sum(&[(-20.0, alpha1), (-1.0, alpha3), (1.0, c1)]);
        let right = Traceless::scaled_sum(&[(1.0, alpha2), (1.0, c2)]);
        let omega = Traceless::scaled_sum(&[
            (1.0, alpha1),
            (1.0 / 12.0, alpha3),
            (1.0 / 240.0, left.commutator(right)),
        ]);
        let e = omega.exp();
        y = [
            e[0] * y[0] + e[1] * y[2],
            e[0] * y[1] + e[1] * y[3],
            e[2] * y[0] + e[3] * y[2],
            e[2] * y[1] + e[3] * y[3],
        ];
        (sin0, cos0) = (
            sin0 * cos_step + cos0 * sin_step,
            cos0 * cos_step - sin0 * sin_step,
        );
    }
    let (first, second) = (y[0] * y[3], y[2] * y[1]);
    (2.0 * (first + second), 2.0 * (first.abs() + second.abs()))
}

/// First step count tried: more for a fast or strongly varying coefficient (the
/// sixth-order error grows with `|q|`; a frozen `a` is integrated exactly).
fn initial_steps(a: f64, q: f64) -> usize {
    let estimate = 4.0 * (2.0 + libm::sqrt(a.abs() + 2.0 * q.abs()));
    (estimate as usize).next_power_of_two().max(8)
}

fn check_q(q: f64) -> Result<f64, MathieuError> {
    if q.is_finite() && q.abs() <= MAX_ABS_Q {
        Ok(q)
    } else {
        Err(MathieuError::Q)
    }
}

fn check_a(a: f64) -> Result<f64, MathieuError> {
    if a.is_finite() && a.abs() <= MAX_ABS_A {
        Ok(a)
    } else {
        Err(MathieuError::A)
    }
}

fn check_damping(c: f64) -> Result<f64, MathieuError> {
    if c.is_finite() && (0.0..=MAX_DAMPING).contains(&c) {
        Ok(c)
    } else {
        Err(MathieuError::Damping)
    }
}

/// Edges `(lower, upper)` of undamped tongue `order` at `q`; tongue 0 has lower edge
/// `-inf` and upper edge `a_0`.
fn undamped_edges(order: u8, q: f64) -> (f64, f64) {
    let (a_class, a_index) = Class::of_a(order);
    let a_n = a_class.eigenvalue(q, a_index);
    if order == 0 {
        return (f64::NEG_INFINITY, a_n);
    }
    let (b_class, b_index) = Class::of_b(order);
    let b_n = b_class.eigenvalue(q, b_index);
    (a_n.min(b_n), a_n.max(b_n))
}

/// Keeps the outside location at `distance` (>= 0) when it is nearer than `best`.
fn nearer(best: &mut Option<TongueLocation>, order: u8, distance: f64) {
    if best.is_none_or(|b| distance < b.distance) {
        *best = Some(TongueLocation {
            order,
            inside: false,
            distance,
        });
    }
}

/// Brent's root finder on `[lo, hi]` with `f(lo)`, `f(hi)` of opposite signs (or zero).
///
/// Hand-rolled: no `no_std` crate without heap offers it. Stops when the bracket is
/// below `tolerance` (absolute).
fn brent(
    mut f: impl FnMut(f64) -> Result<f64, MathieuError>,
    lo: f64,
    hi: f64,
    tolerance: f64,
) -> Result<f64, MathieuError> {
    let (mut a, mut b) = (lo, hi);
    let (mut fa, mut fb) = (f(a)?, f(b)?);
    if fa == 0.0 {
        return Ok(a);
    }
    if fb == 0.0 {
        return Ok(b);
    }
    let (mut c, mut fc) = (a, fa);
    let mut d = b - a;
    let mut e = d;
    for _ in 0..MAX_SEARCH_ITERATIONS {
        if (fb > 0.0) == (fc > 0.0) {
            c = a;
            fc = fa;
            d = b - a;
            e = d;
        }
        if fc.abs() < fb.abs() {
            a = b;
            b = c;
            c = a;
            fa = fb;
            fb = fc;
            fc = fa;
        }
        let tol = 2.0 * f64::EPSILON * b.abs() + 0.5 * tolerance;
        let m = 0.5 * (c - b);
        if m.abs() <= tol || fb == 0.0 {
            return Ok(b);
        }
        if e.abs() >= tol && fa.abs() > fb.abs() {
            let s = fb / fa;
            let (mut p, mut r) = if a == c {
                (2.0 * m * s, 1.0 - s)
            } else {
                let qq = fa / fc;
                let r = fb / fc;
                (
                    s * (2.0 * m * qq * (qq - r) - (b - a) * (r - 1.0)),
                    (qq - 1.0) * (r - 1.0) * (s - 1.0),
                )
            };
            if p > 0.0 {
                r = -r;
            } else {
                p = -p;
            }
            if 2.0 * p < (3.0 * m * r - (tol * r).abs()).min((e * r).abs()) {
                e = d;
                d = p / r;
            } else {
                d = m;
                e = d;
            }
        } else {
            d = m;
            e = d;
        }
        a = b;
        fa = fb;
        b += if d.abs() > tol { d } else { tol.copysign(m) };
        fb = f(b)?;
    }
    Ok(b)
}

impl Mathieu {
    /// Solver with `tolerance` on the monodromy trace (relative to the terms summed,
    /// see [`Mathieu::trace`]; `1e-14..=1e-6`) and at most `max_steps` Magnus steps per half period (>= 64).
    pub fn new(tolerance: f64, max_steps: usize) -> Result<Mathieu, MathieuError> {
        if !(1.0e-14..=1.0e-6).contains(&tolerance) || max_steps < 64 {
            return Err(MathieuError::Settings);
        }
        Ok(Mathieu {
            tolerance,
            max_steps,
        })
    }

    /// Characteristic value `a_n(q)`, `n` in 0..=10, |q| <= 100.
    pub fn characteristic_a(&self, order: u8, q: f64) -> Result<f64, MathieuError> {
        let q = check_q(q)?;
        if order > MAX_ORDER {
            return Err(MathieuError::Order);
        }
        let (class, index) = Class::of_a(order);
        Ok(class.eigenvalue(q, index))
    }

    /// Characteristic value `b_n(q)`, `n` in 1..=10, |q| <= 100.
    pub fn characteristic_b(&self, order: u8, q: f64) -> Result<f64, MathieuError> {
        let q = check_q(q)?;
        if order == 0 || order > MAX_ORDER {
            return Err(MathieuError::Order);
        }
        let (class, index) = Class::of_b(order);
        Ok(class.eigenvalue(q, index))
    }

    /// Monodromy trace `Delta(a, q)` over one period pi of the undamped equation,
    /// converged by step doubling until the finer value's estimated error (the change
    /// / 63) is within the tolerance relative to the terms summed (>= 2,
    /// larger where they cancel), or until the change stops shrinking below 1e-9 of
    /// them (rounding, not truncation, is left).
    pub fn trace(&self, a: f64, q: f64) -> Result<f64, MathieuError> {
        let a = check_a(a)?;
        let q = check_q(q)?;
        Ok(self.converged_trace(a, q)?.0)
    }

    /// The converged trace and the step count that gave it.
    fn converged_trace(&self, a: f64, q: f64) -> Result<(f64, usize), MathieuError> {
        let mut steps = initial_steps(a, q).min(self.max_steps / 2);
        let (mut coarse, _) = half_period_trace(a, q, steps);
        let mut previous_change = f64::INFINITY;
        while 2 * steps <= self.max_steps {
            steps *= 2;
            let (fine, magnitude) = half_period_trace(a, q, steps);
            let change = (fine - coarse).abs();
            // Sixth order: the finer value's error is about change / 63. Converged, or
            // stalled at the rounding floor: truncation shrinks 64-fold per doubling
            // while rounding (~1e-12 relative over 1e3 steps) does not.
            if change <= 63.0 * self.tolerance * magnitude
                || (change > 0.25 * previous_change && change <= ROUNDING_FLOOR * magnitude)
            {
                return Ok((fine, steps));
            }
            previous_change = change;
            coarse = fine;
        }
        Err(MathieuError::NotConverged)
    }

    /// `mu(a, q) = ln |largest multiplier| / pi` of the undamped equation (>= 0): 0 in
    /// the stable gaps below tongue 10 (Sturm counts, no integration), else from the
    /// trace.
    fn undamped_mu(&self, a: f64, q: f64) -> Result<f64, MathieuError> {
        let count = count_below(q, a);
        if count % 2 == 1 && count <= 2 * usize::from(MAX_ORDER) + 1 {
            return Ok(0.0);
        }
        Ok(mu_from_trace(self.converged_trace(a, q)?.0))
    }

    /// Growth exponent per unit `t` of `x'' + 2c x' + (a - 2q cos 2t) x = 0`:
    /// `ln |largest Floquet multiplier| / pi`; > 0 means unstable.
    ///
    /// `|a| <= 1e4`, `|q| <= 100`, `0 <= c <= 10`. Equals `mu(a - c^2, q) - c`, so `-c`
    /// at every stable point of the undamped plane.
    pub fn exponent(&self, a: f64, q: f64, c: f64) -> Result<f64, MathieuError> {
        check_a(a)?;
        let q = check_q(q)?;
        let c = check_damping(c)?;
        let shifted = check_a(a - c * c)?;
        Ok(self.undamped_mu(shifted, q)? - c)
    }

    /// Edges in `a` of the damped tongue `order` (1..=10) at `q` and damping `c`: the
    /// interval where the exponent is > 0, or `None` when damping closes it.
    ///
    /// With `c = 0` these are the characteristic values `min/max(a_n, b_n)`.
    pub fn damped_tongue(
        &self,
        order: u8,
        q: f64,
        c: f64,
    ) -> Result<Option<(f64, f64)>, MathieuError> {
        let q = check_q(q)?;
        let c = check_damping(c)?;
        if order == 0 || order > MAX_ORDER {
            return Err(MathieuError::Order);
        }
        let shift = c * c;
        Ok(self
            .damped_edges(order, q, c, undamped_edges(order, q), Edges::Both)?
            .map(|(lo, hi)| (lo + shift, hi + shift)))
    }

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
    fn damped_edges(
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
    fn damped_any(
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

    /// The tongue nearest to `(a, q)` with damping `c`, and the signed distance in `a`
    /// to its nearest edge (negative inside).
    ///
    /// With `c = 0` only characteristic values are needed; with damping the damped
    /// edges of the neighbouring tongues are searched (only the edge facing the
    /// point), skipping tongues too far to be nearer than one already found.
    pub fn locate(&self, a: f64, q: f64, c: f64) -> Result<TongueLocation, MathieuError> {
        check_a(a)?;
        let q = check_q(q)?;
        let c = check_damping(c)?;
        let x = check_a(a - c * c)?;
        let count = count_below(q, x);
        let top = usize::from(MAX_ORDER);
        // The tongue containing x (count even) or the one just below (count odd).
        let start = (count / 2).min(top) as u8;
        let containing = count.is_multiple_of(2) && count / 2 <= top;
        let mut best: Option<TongueLocation> = None;
        // Downward: the containing (or next lower) tongue first.
        for order in (0..=start).rev() {
            let undamped = undamped_edges(order, q);
            if order < start && best.is_some_and(|b| x - undamped.1 >= b.distance) {
                break;
            }
            let edges = if containing && order == start {
                Edges::Both
            } else {
                Edges::Upper
            };
            let Some((lo, hi)) = self.damped_any(order, q, c, undamped, edges)? else {
                continue;
            };
            if x > lo && x < hi {
                return Ok(TongueLocation {
                    order,
                    inside: true,
                    distance: -(x - lo).min(hi - x),
                });
            }
            if x >= hi {
                nearer(&mut best, order, x - hi);
                break;
            }
            // x lies below the damped part of its own undamped tongue: an edge above.
            nearer(&mut best, order, lo - x);
        }
        // Upward, while a tongue could still be nearer than the best so far.
        for order in start + 1..=MAX_ORDER {
            let undamped = undamped_edges(order, q);
            if best.is_some_and(|b| undamped.0 - x >= b.distance) {
                break;
            }
            if let Some((lo, _)) = self.damped_any(order, q, c, undamped, Edges::Lower)? {
                nearer(&mut best, order, lo - x);
                break;
            }
        }
        // Tongue 0 always has a damped part, so something was found.
        Ok(best.unwrap_or(TongueLocation {
            order: 0,
            inside: false,
            distance: f64::INFINITY,
        }))
    }
}

/// Which edges of a damped tongue to compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edges {
    Lower,
    Upper,
    Both,
}

/// A point of `(lo, hi)` where `g > 0`, by golden-section search for the peak of a
/// unimodal `g`, stopping at the first positive value; `None` when the peak is <= 0.
fn golden_peak(
    mut g: impl FnMut(f64) -> Result<f64, MathieuError>,
    lo: f64,
    hi: f64,
) -> Result<Option<f64>, MathieuError> {
    let ratio = 0.5 * (libm::sqrt(5.0) - 1.0);
    let (mut left, mut right) = (lo, hi);
    let mut x1 = right - ratio * (right - left);
    let mut x2 = left + ratio * (right - left);
    let (mut g1, mut g2) = (g(x1)?, g(x2)?);
    for _ in 0..MAX_SEARCH_ITERATIONS {
        if g1 > 0.0 {
            return Ok(Some(x1));
        }
        if g2 > 0.0 {
            return Ok(Some(x2));
        }
        if right - left <= 1.0e-10 * (1.0 + right.abs()) {
            break;
        }
        if g1 > g2 {
            right = x2;
            x2 = x1;
            g2 = g1;
            x1 = right - ratio * (right - left);
            g1 = g(x1)?;
        } else {
            left = x1;
            x1 = x2;
            g1 = g2;
            x2 = left + ratio * (right - left);
            g2 = g(x2)?;
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn negative_q_swaps_odd_orders() {
        let m = Mathieu::default();
        for n in 1..=MAX_ORDER {
            let (a_neg, b_neg) = (
                m.characteristic_a(n, -3.0).unwrap(),
                m.characteristic_b(n, -3.0).unwrap(),
            );
            let (a_pos, b_pos) = (
                m.characteristic_a(n, 3.0).unwrap(),
                m.characteristic_b(n, 3.0).unwrap(),
            );
            if n % 2 == 1 {
                assert!((a_neg - b_pos).abs() < 1e-12 && (b_neg - a_pos).abs() < 1e-12);
            } else {
                assert!((a_neg - a_pos).abs() < 1e-12 && (b_neg - b_pos).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn trace_is_the_closed_form_without_pulsation() {
        // q = 0: Delta = 2 cos(pi sqrt(a)), or 2 cosh(pi sqrt(-a)).
        let m = Mathieu::default();
        for a in [-4.0, -0.3, 0.25, 1.0, 2.7, 30.0] {
            let expected = if a >= 0.0 {
                2.0 * libm::cos(PI * libm::sqrt(a))
            } else {
                2.0 * libm::cosh(PI * libm::sqrt(-a))
            };
            let trace = m.trace(a, 0.0).unwrap();
            assert!(
                (trace - expected).abs() < 1e-12 * expected.abs().max(1.0),
                "{a}"
            );
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
                    .map(|a| mu_from_trace(m.trace(a, q).unwrap()))
                    .fold(0.0, f64::max);
                assert!(largest < c, "order {order} q {q}: mu {largest} >= c {c}");
            }
        }
    }

    #[test]
    fn errors_name_their_range() {
        let m = Mathieu::default();
        assert_eq!(m.characteristic_a(11, 1.0), Err(MathieuError::Order));
        assert_eq!(m.characteristic_b(0, 1.0), Err(MathieuError::Order));
        assert_eq!(m.characteristic_a(1, 100.5), Err(MathieuError::Q));
        assert_eq!(m.exponent(f64::NAN, 1.0, 0.0), Err(MathieuError::A));
        assert_eq!(m.exponent(1.0, 1.0, -0.1), Err(MathieuError::Damping));
        assert_eq!(Mathieu::new(0.0, 100), Err(MathieuError::Settings));
        let mut text = heapless::String::<128>::new();
        core::fmt::write(&mut text, format_args!("{}", MathieuError::Q)).unwrap();
        assert_eq!(text.as_str(), "Mathieu q must be finite with |q| <= 100");
    }
}
