//! One-dimensional searches on `no_std`: Brent's root finder and a golden-section
//! search for a positive value.

use super::settings::MathieuError;

/// Iteration cap of the golden-section and Brent searches.
const MAX_SEARCH_ITERATIONS: usize = 200;

/// Brent's root finder on `[lo, hi]` with `f(lo)`, `f(hi)` of opposite signs (or zero).
///
/// Hand-rolled: no `no_std` crate without heap offers it. Stops when the bracket is
/// below `tolerance` (absolute).
pub(super) fn brent(
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

/// A point of `(lo, hi)` where `g > 0`, by golden-section search for the peak of a
/// unimodal `g`, stopping at the first positive value; `None` when the peak is <= 0.
pub(super) fn golden_peak(
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
