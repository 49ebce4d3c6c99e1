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

mod characteristic;
mod monodromy;
mod search;
mod settings;
mod tongues;

use characteristic::{count_below, undamped_edges, Class};
use settings::{check_a, check_damping, check_q};
pub use settings::{Mathieu, MathieuError, MAX_ABS_A, MAX_ABS_Q, MAX_DAMPING, MAX_ORDER};
use tongues::Edges;

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

impl Mathieu {
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

#[cfg(test)]
mod tests {
    use super::*;

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
    fn errors_name_their_range() {
        let m = Mathieu::default();
        assert_eq!(m.characteristic_a(11, 1.0), Err(MathieuError::Order));
        assert_eq!(m.characteristic_b(0, 1.0), Err(MathieuError::Order));
        assert_eq!(m.characteristic_a(1, 100.5), Err(MathieuError::Q));
        assert_eq!(m.exponent(f64::NAN, 1.0, 0.0), Err(MathieuError::A));
        assert_eq!(m.exponent(1.0, 1.0, -0.1), Err(MathieuError::Damping));
        let mut text = heapless::String::<128>::new();
        core::fmt::write(&mut text, format_args!("{}", MathieuError::Q)).unwrap();
        assert_eq!(text.as_str(), "Mathieu q must be finite with |q| <= 100");
    }
}
