//! The monodromy trace of the undamped equation: fundamental solutions over half a
//! period by the sixth-order Magnus method, step doubling to the tolerance, and the
//! growth exponent `mu` from the trace.

use core::f64::consts::PI;

use super::characteristic::count_below;
use super::settings::{Mathieu, MathieuError, MAX_ORDER, ROUNDING_FLOOR};

/// Steps between exact recomputations of the rotating phasor of `cos 2t`.
const RESYNC_STEPS: usize = 16;

/// Gauss-Legendre nodes of the Magnus step, as fractions of the step.
const NODE_OFFSET: f64 = 0.387_298_334_620_741_7; // sqrt(15) / 10

/// `mu = ln |largest multiplier| / pi` from the monodromy trace of the undamped
/// equation (multipliers solve `l^2 - Delta l + 1 = 0`).
pub(super) fn mu_from_trace(trace: f64) -> f64 {
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
pub(super) fn half_period_trace(a: f64, q: f64, steps: usize) -> (f64, f64) {
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

impl Mathieu {
    /// Monodromy trace `Delta(a, q)` over one period pi of the undamped equation and
    /// the step count that gave it, converged by step doubling until the finer value's
    /// estimated error (the change / 63) is within the tolerance relative to the terms
    /// summed (>= 2, larger where they cancel), or until the change stops shrinking
    /// below 1e-9 of them (rounding, not truncation, is left).
    pub(super) fn converged_trace(&self, a: f64, q: f64) -> Result<(f64, usize), MathieuError> {
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
    pub(super) fn undamped_mu(&self, a: f64, q: f64) -> Result<f64, MathieuError> {
        let count = count_below(q, a);
        if count % 2 == 1 && count <= 2 * usize::from(MAX_ORDER) + 1 {
            return Ok(0.0);
        }
        Ok(mu_from_trace(self.converged_trace(a, q)?.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
            let trace = m.converged_trace(a, 0.0).unwrap().0;
            assert!(
                (trace - expected).abs() < 1e-12 * expected.abs().max(1.0),
                "{a}"
            );
        }
    }
}
