//! The record as the fit works on it, and the split of the eq. (1) parameters into the
//! nonlinear ones (iterated) and the linear ones (solved at each point).

use super::recurrence::Pair;

/// The record as fitted: every `stride`-th sample times `inverse_scale` (peak
/// magnitude 1), `dt` seconds apart.
pub(super) struct Data<'a> {
    pub(super) samples: &'a [f64],
    pub(super) stride: usize,
    pub(super) inverse_scale: f64,
    pub(super) dt: f64,
    pub(super) positive_only: bool,
    /// Sum of the squares of the fitted values (scaled, masked ones out): the cost of
    /// all-zero linear parameters, so no least-squares cost can exceed it.
    pub(super) energy: f64,
}

impl<'a> Data<'a> {
    /// The record `samples` as fitted (see the fields), its energy summed here.
    pub(super) fn new(
        samples: &'a [f64],
        stride: usize,
        inverse_scale: f64,
        dt: f64,
        positive_only: bool,
    ) -> Self {
        let mut data = Self {
            samples,
            stride,
            inverse_scale,
            dt,
            positive_only,
            energy: 0.0,
        };
        // Four partial sums, so the additions are not one chain each waiting on the
        // last; chunks, not the strided iterator, on the full record.
        let mut sums = [0.0_f64; 4];
        let square = |v: f64| {
            let v = v * inverse_scale;
            if positive_only && v <= 0.0 {
                0.0
            } else {
                v * v
            }
        };
        if stride == 1 {
            let chunks = samples.chunks_exact(4);
            for (sum, &v) in sums.iter_mut().zip(chunks.remainder()) {
                *sum += square(v);
            }
            for chunk in chunks {
                for (sum, &v) in sums.iter_mut().zip(chunk) {
                    *sum += square(v);
                }
            }
        } else {
            for (index, &v) in samples.iter().step_by(stride).enumerate() {
                sums[index % 4] += square(v);
            }
        }
        data.energy = (sums[0] + sums[1]) + (sums[2] + sums[3]);
        data
    }

    /// The samples used, scaled.
    pub(super) fn values(&self) -> impl Iterator<Item = f64> + '_ {
        self.samples
            .iter()
            .step_by(self.stride)
            .map(|v| v * self.inverse_scale)
    }

    /// The samples used, scaled, as (even, odd) pairs for the two lanes of a [`Pair`]:
    /// the whole pairs, and the last sample or two with the lanes to keep (an empty odd
    /// lane and, with `positive_only`, samples not above zero masked), if any remain.
    /// The whole pairs' mask is the caller's (`values > 0` lane by lane with
    /// `positive_only`), so a pass without it tests nothing per pair.
    pub(super) fn pairs(&self) -> (impl Iterator<Item = Pair> + '_, Option<(Pair, [bool; 2])>) {
        let (stride, scale) = (self.stride, self.inverse_scale);
        let chunks = self.samples.chunks_exact(2 * stride);
        let rest = chunks.remainder();
        let tail = (!rest.is_empty()).then(|| {
            let odd = rest.get(stride);
            let (even, odd_value) = (rest[0] * scale, odd.map_or(0.0, |v| v * scale));
            let fitted = |v: f64| !self.positive_only || v > 0.0;
            (
                Pair::new(even, odd_value),
                [fitted(even), odd.is_some() && fitted(odd_value)],
            )
        });
        let pairs = chunks.map(move |c| Pair::new(c[0] * scale, c[stride] * scale));
        (pairs, tail)
    }

    /// Number of samples in the residual (after the stride and the positive mask).
    pub(super) fn used(&self) -> usize {
        if !self.positive_only {
            return self.count();
        }
        self.values().filter(|v| *v > 0.0).count()
    }

    /// Number of samples after the stride (masked ones included).
    pub(super) fn count(&self) -> usize {
        self.samples.len().div_ceil(self.stride)
    }

    /// Duration covered, s.
    pub(super) fn duration_s(&self) -> f64 {
        self.count() as f64 * self.dt
    }
}

/// Nonlinear parameters a5, a6, a7, a8, a10 (the LM unknowns), in that order.
pub(super) type Nonlinear = [f64; 5];
/// Linear parameters a1, a2, a3, a4, a9 (solved exactly at every nonlinear point).
pub(super) type Linear = [f64; 5];
/// Paper index (0-based) of each nonlinear parameter.
pub(super) const NONLINEAR_INDEX: [usize; 5] = [4, 5, 6, 7, 9];
/// Paper index (0-based) of each linear parameter.
pub(super) const LINEAR_INDEX: [usize; 5] = [0, 1, 2, 3, 8];
/// Basis functions per sample: the 5 columns of Phi (model = Phi c), then the 5
/// derivative columns D (t u1, t v1, t u2, t v2, t e10) that span dPhi/dtheta c.
pub(super) const BASIS: usize = 10;
