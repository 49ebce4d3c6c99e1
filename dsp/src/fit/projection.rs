//! The one pass over the samples per evaluated point: the residual against a
//! reference linear part, its sum of squares and its projections on the basis.

use super::record::{Data, Linear, BASIS};
use super::recurrence::{BasisSteps, Pair, PairRotor};

/// Accumulators of [`project`]: even and odd samples in the two lanes of each [`Pair`].
struct Projection {
    mode1: PairRotor,
    mode2: PairRotor,
    load: Pair,
    load_step: Pair,
    /// Reference linear parameters c1, c2, c3, c4, c9, in both lanes.
    reference: [Pair; 5],
    squares: Pair,
    /// Running sums P of r0 times u1, u2, v1, v2, 1, e10.
    running: [Pair; 6],
    /// Sums Q of the running sums of r0 times u1, v1, u2, v2, e10, each taken before
    /// the step adds to it.
    nested: [Pair; 5],
    /// Steps taken (pairs of samples).
    steps: usize,
}

impl Projection {
    /// Takes the next pair of samples; `keep` (when given) masks lanes whose residual
    /// is not fitted (0 instead). Without `REFERENCED` the residual is the record
    /// itself (a reference of zero, no model evaluated and no squares summed).
    #[inline(always)]
    fn step<const REFERENCED: bool>(&mut self, values: Pair, keep: Option<[bool; 2]>) {
        let (u1, v1, u2, v2, e10) = (
            self.mode1.re,
            self.mode1.im,
            self.mode2.re,
            self.mode2.im,
            self.load,
        );
        self.mode1.advance();
        self.mode2.advance();
        self.load = self.load * self.load_step;
        let mut residual = if REFERENCED {
            let [c1, c2, c3, c4, c9] = self.reference;
            values - (c1 * u1 + c2 * u2 + c3 * v1 + c4 * v2 + c9 * (Pair::splat(1.0) - e10))
        } else {
            values
        };
        if let Some(keep) = keep {
            residual = residual.masked(keep);
        }
        if REFERENCED {
            self.squares += residual * residual;
        }
        let running = &mut self.running;
        for (q, p) in self
            .nested
            .iter_mut()
            .zip([running[0], running[2], running[1], running[3], running[5]])
        {
            *q += p;
        }
        running[0] += residual * u1;
        running[1] += residual * u2;
        running[2] += residual * v1;
        running[3] += residual * v2;
        running[4] += residual;
        running[5] += residual * e10;
        self.steps += 1;
    }
}

/// One pass over the record (the basis advanced by `steps`) with a reference linear
/// part `reference`: the residual r0 = y - Phi(theta) reference, its sum of squares and
/// its projections [Phi D]^T r0.
/// Working on r0 rather than y keeps the cost free of cancellation near the optimum
/// (cost = |r0|^2 - correction, both small), so exact records converge to full precision.
/// Without `REFERENCED`, r0 is the record y itself (`reference` is not read) and its
/// sum of squares is the record's energy, known beforehand: the pass evaluates no model,
/// a third fewer operations per sample.
///
/// Even and odd samples run in two lanes ([`Pair`]). The t-weighted sums use no
/// multiplication by t: with P_m the running sum of a_j over the first m steps of a lane
/// and Q the sum of those P_m, sum over m of m a_m = (M - 1) P_M - Q (M steps).
// Inlined into `evaluate`, its only caller, as when both were one file: kept apart (in
// another codegen unit) the fit ran 12% more instructions (valgrind, 760 k against
// 697 k per fit of 2000 samples).
#[inline]
pub(super) fn project<const REFERENCED: bool>(
    steps: &BasisSteps,
    reference: &Linear,
    data: &Data<'_>,
) -> (f64, [f64; BASIS]) {
    let dt = data.dt;
    let load_step = steps.load;
    let zero = Pair::splat(0.0);
    let mut state = Projection {
        mode1: PairRotor::new(steps.mode1, 1.0, 0.0),
        mode2: PairRotor::new(steps.mode2, 1.0, 0.0),
        load: Pair::new(1.0, load_step),
        load_step: Pair::splat(load_step * load_step),
        reference: reference.map(Pair::splat),
        squares: zero,
        running: [zero; 6],
        nested: [zero; 5],
        steps: 0,
    };
    let (pairs, tail) = data.pairs();
    if data.positive_only {
        for values in pairs {
            state.step::<REFERENCED>(values, Some(values.lanes().map(|v| v > 0.0)));
        }
    } else {
        for values in pairs {
            state.step::<REFERENCED>(values, None);
        }
    }
    if let Some((values, keep)) = tail {
        state.step::<REFERENCED>(values, Some(keep));
    }
    let Projection {
        squares,
        running,
        nested,
        steps,
        ..
    } = state;
    // Sample n = 2m + l of lane l: sum n a_n = sum over lanes of 2 (sum m a) + l P.
    let last = steps.saturating_sub(1) as f64;
    let weighted = |p: Pair, q: Pair| {
        let per_lane = Pair::splat(2.0) * (Pair::splat(last) * p - q) + Pair::new(0.0, 1.0) * p;
        dt * per_lane.total()
    };
    let projections = [
        running[0].total(),
        running[1].total(),
        running[2].total(),
        running[3].total(),
        running[4].total() - running[5].total(),
        weighted(running[0], nested[0]),
        weighted(running[2], nested[1]),
        weighted(running[1], nested[2]),
        weighted(running[3], nested[3]),
        weighted(running[5], nested[4]),
    ];
    let squares = if REFERENCED {
        squares.total()
    } else {
        data.energy
    };
    (squares, projections)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::eq1;
    use crate::fit::tests::TABLE1;
    use core::f64::consts::PI;

    #[test]
    fn project_matches_the_direct_sums() {
        let theta = [11.99, 20.91, 22.17, 3.65, 36.7];
        let reference = [-1.3, 0.8, 1.7, -0.3, 1.0];
        // A transient with noise-like wiggle, crossing zero so the mask matters.
        let samples: [f64; 203] = core::array::from_fn(|i| {
            let t = i as f64 * 1e-3;
            eq1(&TABLE1, t) - 60.0 + 9.0 * libm::sin(0.37 * i as f64 * i as f64)
        });
        // Odd and even counts after the stride, a tail of one and of two samples.
        for (len, stride) in [(203, 1), (202, 1), (203, 3), (202, 4), (201, 4), (30, 7)] {
            for positive_only in [false, true] {
                let data = Data::new(
                    &samples[..len],
                    stride,
                    1.0 / 300.0,
                    1e-3 * stride as f64,
                    positive_only,
                );
                let mut squares = 0.0;
                let mut expected = [0.0; BASIS];
                for (n, value) in data.values().enumerate() {
                    if positive_only && value <= 0.0 {
                        continue;
                    }
                    let t = n as f64 * data.dt;
                    let (s1, c1) = libm::sincos(2.0 * PI * theta[0] * t);
                    let (s2, c2) = libm::sincos(2.0 * PI * theta[1] * t);
                    let (m1, m2) = (libm::exp(-theta[2] * t), libm::exp(-theta[3] * t));
                    let load = libm::exp(-theta[4] * t);
                    let basis = [
                        m1 * c1,
                        m2 * c2,
                        m1 * s1,
                        m2 * s2,
                        1.0 - load,
                        t * m1 * c1,
                        t * m1 * s1,
                        t * m2 * c2,
                        t * m2 * s2,
                        t * load,
                    ];
                    let model: f64 = reference.iter().zip(&basis[..5]).map(|(c, b)| c * b).sum();
                    let residual = value - model;
                    squares += residual * residual;
                    for (sum, b) in expected.iter_mut().zip(basis) {
                        *sum += residual * b;
                    }
                }
                let steps = BasisSteps::new(&theta, data.dt);
                let (found_squares, found) = project::<true>(&steps, &reference, &data);
                let label = (len, stride, positive_only);
                assert!(
                    libm::fabs(found_squares - squares) <= 1e-12 * squares,
                    "{label:?}: {found_squares} vs {squares}"
                );
                let scale = libm::sqrt(squares * data.count() as f64);
                for (x, y) in found.iter().zip(expected) {
                    assert!(
                        libm::fabs(x - y) <= 1e-12 * scale,
                        "{label:?}: {found:?} vs {expected:?}"
                    );
                }
                // The record's own projections: those of a zero reference.
                let (record_squares, record) = project::<false>(&steps, &reference, &data);
                let (zero_squares, zero) = project::<true>(&steps, &[0.0; 5], &data);
                assert!(libm::fabs(record_squares - zero_squares) <= 1e-12 * zero_squares);
                for (x, y) in record.iter().zip(zero) {
                    assert!(
                        libm::fabs(x - y) <= 1e-12 * scale,
                        "{label:?}: {record:?} vs {zero:?}"
                    );
                }
            }
        }
    }
}
