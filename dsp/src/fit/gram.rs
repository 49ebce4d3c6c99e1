//! The Gram matrix [Phi D]^T [Phi D] of the basis at a nonlinear point: in closed
//! form from geometric power sums ([`gram_closed`], O(1) in the record length), or
//! summed sample by sample where a mask rules the closed form out ([`gram_direct`]).

use core::f64::consts::PI;
use nalgebra::Complex;

use super::record::{Data, Nonlinear, BASIS};
use super::recurrence::{BasisSteps, Rotor};

/// Factors of the basis functions apart from their power of t: Re and Im of z1^n and
/// z2^n (z = exp((-decay + i 2 pi f) dt)), the rise 1 - e^n and the load e^n
/// (e = exp(-a10 dt)). Indices into the factor product table of [`gram_closed`].
const RE1: usize = 0;
const RE2: usize = 1;
const IM1: usize = 2;
const IM2: usize = 3;
const RISE: usize = 4;
const LOAD: usize = 5;
const FACTORS: usize = 6;

/// Each basis function as (factor, power of t), in the order of the Gram matrix: u1,
/// u2, v1, v2, 1 - e10 (multiplying a1, a2, a3, a4, a9), then t u1, t v1, t u2, t v2,
/// t e10.
const BASIS_FACTORS: [(usize, usize); BASIS] = [
    (RE1, 0),
    (RE2, 0),
    (IM1, 0),
    (IM2, 0),
    (RISE, 0),
    (RE1, 1),
    (IM1, 1),
    (RE2, 1),
    (IM2, 1),
    (LOAD, 1),
];

/// `[sum n^k w^n for n in 0..count]` for k = 0, 1, 2 and each `w` of `ws`, by binary
/// splitting: O(log count) complex products and no division, so it stays accurate for w
/// near 1, where the closed forms of [`power_sums_closed`] cancel. All `ws` advance in
/// lockstep (same count, same bits): the lanes are independent, so their products
/// overlap instead of waiting on one another.
fn power_sums<const K: usize>(ws: &[Complex<f64>; K], count: usize) -> [[Complex<f64>; 3]; K] {
    let zero = Complex::new(0.0, 0.0);
    let mut sums = [[zero; 3]; K];
    // Invariant: sums over n in 0..m, powers = w^m.
    let mut powers = [Complex::new(1.0, 0.0); K];
    let mut m = 0_usize;
    for bit in (0..usize::BITS - count.leading_zeros()).rev() {
        if m > 0 {
            // [0, 2m) = [0, m) followed by [0, m) shifted by m:
            // sum (n + m)^k w^(n + m) = w^m (S_k + k m S_(k-1) + ...).
            let shift = m as f64;
            for (lane, power) in sums.iter_mut().zip(powers.iter_mut()) {
                let [s0, s1, s2] = *lane;
                *lane = [
                    s0 + *power * s0,
                    s1 + *power * (s1 + s0 * shift),
                    s2 + *power * (s2 + s1 * (2.0 * shift) + s0 * (shift * shift)),
                ];
                *power = *power * *power;
            }
            m *= 2;
        }
        if (count >> bit) & 1 == 1 {
            let index = m as f64;
            for ((lane, power), w) in sums.iter_mut().zip(powers.iter_mut()).zip(ws) {
                lane[0] += *power;
                lane[1] += *power * index;
                lane[2] += *power * (index * index);
                *power *= *w;
            }
            m += 1;
        }
    }
    sums
}

/// Smallest count |1 - w| for which [`power_sums_closed`] is used; below it binary
/// splitting takes over. The closed forms cancel as about eps / (count |1 - w|)^3;
/// the tests against direct sums (1e-12) still pass with 0.2, so 2 leaves a margin.
const CLOSED_FORM_MIN_SPREAD: f64 = 2.0;

/// `[sum n^k w^n for n in 0..count]` for k = 0, 1, 2 given `w_count` = w^count, from
/// the geometric-series identities (1 - w) S0 = 1 - W, (1 - w) S1 = S0 - 1 - (N - 1) W,
/// (1 - w) S2 = 2 S1 - S0 + 1 - (N - 1)^2 W (N = count, W = w^N): one complex division.
/// Falls back to [`power_sums`] when count |1 - w| < [`CLOSED_FORM_MIN_SPREAD`].
fn power_sums_closed(w: Complex<f64>, w_count: Complex<f64>, count: usize) -> [Complex<f64>; 3] {
    let one = Complex::new(1.0, 0.0);
    let gap = one - w;
    let gap_norm2 = gap.norm_sqr();
    let n = count as f64;
    // (Not finite w: either branch gives NaN, which the callers reject.)
    if gap_norm2 * n * n < CLOSED_FORM_MIN_SPREAD * CLOSED_FORM_MIN_SPREAD {
        let [sums] = power_sums(&[w], count);
        return sums;
    }
    // One division, not one per part.
    let inverse = gap.conj() * (1.0 / gap_norm2);
    let last = n - 1.0;
    let s0 = (one - w_count) * inverse;
    let s1 = (s0 - one - w_count * last) * inverse;
    let s2 = (s1 * 2.0 - s0 + one - w_count * (last * last)) * inverse;
    [s0, s1, s2]
}

/// Gram matrix [Phi D]^T [Phi D] over `count` samples `dt` apart, in closed form:
/// every product of two basis factors is the real or imaginary part of a sum of
/// n^k w^n (w a product of z1, z2, e, their conjugates and 1), which
/// [`power_sums_closed`] gives in O(1); the 6 x 6 x 3 table of factor products then
/// fills the 10 x 10 matrix. No pass over the samples.
pub(super) fn gram_closed(
    theta: &Nonlinear,
    steps: &BasisSteps,
    count: usize,
    dt: f64,
) -> [[f64; BASIS]; BASIS] {
    let n = count as f64;
    // exp((-decay + i 2 pi f) dt) (the step of `steps`) and its count-th power.
    let rotor = |step: &Rotor, decay: f64, frequency: f64| {
        let angle = 2.0 * PI * frequency * dt;
        let (s_count, c_count) = libm::sincos(angle * n);
        (
            Complex::new(step.step_re, step.step_im),
            Complex::new(c_count, s_count) * libm::exp(-decay * dt * n),
        )
    };
    let (z1, z1_count) = rotor(&steps.mode1, theta[2], theta[0]);
    let (z2, z2_count) = rotor(&steps.mode2, theta[3], theta[1]);
    let load = Complex::new(steps.load, 0.0);
    let load_count = Complex::new(libm::exp(-theta[4] * dt * n), 0.0);
    let sums = |w: Complex<f64>, w_count: Complex<f64>| power_sums_closed(w, w_count, count);
    let z11 = sums(z1 * z1, z1_count * z1_count);
    let z11c = sums(z1 * z1.conj(), z1_count * z1_count.conj());
    let z22 = sums(z2 * z2, z2_count * z2_count);
    let z22c = sums(z2 * z2.conj(), z2_count * z2_count.conj());
    let z12 = sums(z1 * z2, z1_count * z2_count);
    let z12c = sums(z1 * z2.conj(), z1_count * z2_count.conj());
    let z1e = sums(z1 * load, z1_count * load_count);
    let z1_alone = sums(z1, z1_count);
    let z2e = sums(z2 * load, z2_count * load_count);
    let z2_alone = sums(z2, z2_count);
    let ee = sums(load * load, load_count * load_count);
    let e = sums(load, load_count);
    // Sums of n^k for the constant: exact.
    let constant = [
        n,
        n * (n - 1.0) / 2.0,
        n * (n - 1.0) * (2.0 * n - 1.0) / 6.0,
    ];

    // table[x][y][k] = sum over n of n^k factor_x(n) factor_y(n).
    let mut table = [[[0.0; 3]; FACTORS]; FACTORS];
    let mut set = |x: usize, y: usize, k: usize, value: f64| {
        table[x][y][k] = value;
        table[y][x][k] = value;
    };
    for k in 0..3 {
        // Re a Re b = (Re ab + Re a conj b) / 2, Im a Im b = (Re a conj b - Re ab) / 2,
        // Re a Im b = (Im ab - Im a conj b) / 2, Im a Re b = (Im ab + Im a conj b) / 2.
        for (re_a, im_a, re_b, im_b, direct, conjugate) in [
            (RE1, IM1, RE1, IM1, z11[k], z11c[k]),
            (RE2, IM2, RE2, IM2, z22[k], z22c[k]),
            (RE1, IM1, RE2, IM2, z12[k], z12c[k]),
        ] {
            set(re_a, re_b, k, 0.5 * (direct.re + conjugate.re));
            set(im_a, im_b, k, 0.5 * (conjugate.re - direct.re));
            set(re_a, im_b, k, 0.5 * (direct.im - conjugate.im));
            set(im_a, re_b, k, 0.5 * (direct.im + conjugate.im));
        }
        for (re, im, with_load, alone) in [
            (RE1, IM1, z1e[k], z1_alone[k]),
            (RE2, IM2, z2e[k], z2_alone[k]),
        ] {
            set(re, LOAD, k, with_load.re);
            set(im, LOAD, k, with_load.im);
            set(re, RISE, k, alone.re - with_load.re);
            set(im, RISE, k, alone.im - with_load.im);
        }
        set(LOAD, LOAD, k, ee[k].re);
        set(RISE, LOAD, k, e[k].re - ee[k].re);
        set(RISE, RISE, k, constant[k] - 2.0 * e[k].re + ee[k].re);
    }
    let time_scale = [1.0, dt, dt * dt];
    let mut gram = [[0.0; BASIS]; BASIS];
    for (i, &(x, p)) in BASIS_FACTORS.iter().enumerate() {
        for (j, &(y, q)) in BASIS_FACTORS.iter().enumerate() {
            gram[i][j] = table[x][y][p + q] * time_scale[p + q];
        }
    }
    gram
}

/// Gram matrix [Phi D]^T [Phi D] summed sample by sample over the unmasked samples
/// (the `positive_only` case, where the closed form does not apply), the basis advanced
/// by `steps`.
pub(super) fn gram_direct(steps: &BasisSteps, data: &Data<'_>) -> [[f64; BASIS]; BASIS] {
    let dt = data.dt;
    let BasisSteps {
        mut mode1,
        mut mode2,
        load: load_step,
    } = *steps;
    let mut load = 1.0;
    let mut gram = [[0.0; BASIS]; BASIS];
    for (index, value) in data.values().enumerate() {
        let t = index as f64 * dt;
        let basis = [
            mode1.re,
            mode2.re,
            mode1.im,
            mode2.im,
            1.0 - load,
            t * mode1.re,
            t * mode1.im,
            t * mode2.re,
            t * mode2.im,
            t * load,
        ];
        mode1.advance();
        mode2.advance();
        load *= load_step;
        if data.positive_only && value <= 0.0 {
            continue;
        }
        for (row, &x) in gram.iter_mut().zip(basis.iter()) {
            for (entry, &y) in row.iter_mut().zip(basis.iter()) {
                *entry += x * y;
            }
        }
    }
    gram
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form_gram_matches_the_sample_sum() {
        let samples = [1.0; 777];
        for (theta, stride) in [
            ([11.99, 20.91, 22.17, 3.65, 36.7], 1),
            ([12.0, 12.001, 0.0, 1e-6, 0.5], 3),
            ([0.5, 40.0, -2.0, 60.0, 200.0], 2),
            // Slow decays and close frequencies: some sums by binary splitting, some
            // just above the closed-form threshold.
            ([3.0, 3.5, 0.01, 2.6, 2.0], 1),
            ([20.0, 20.0005, 1e-9, 0.0, 0.0], 1),
        ] {
            let data = Data::new(&samples, stride, 1.0, 1e-3 * stride as f64, true);
            let steps = BasisSteps::new(&theta, data.dt);
            let direct = gram_direct(&steps, &data);
            let closed = gram_closed(&theta, &steps, data.count(), data.dt);
            for i in 0..BASIS {
                for j in 0..BASIS {
                    let scale = libm::sqrt(direct[i][i] * direct[j][j]) + 1e-300;
                    let error = libm::fabs(closed[i][j] - direct[i][j]) / scale;
                    assert!(
                        error < 1e-11,
                        "{theta:?} [{i}][{j}]: {closed:?} vs {direct:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn closed_form_power_sums_match_the_direct_sum() {
        // Spreads count |1 - w| from below the threshold (binary splitting) to far
        // above, decaying, growing and unit-modulus w.
        for (w, count) in [
            (Complex::new(0.99, 0.05), 1001),
            (Complex::new(0.999, 0.0), 500),
            (Complex::new(0.996, 0.0), 500),
            (Complex::new(0.9999, 0.001), 777),
            (Complex::from_polar(1.0, 0.3), 300),
            (Complex::from_polar(1.004, -0.01), 500),
            (Complex::new(0.3, -0.6), 125),
            (Complex::new(1.0, 0.0), 64),
            (Complex::new(0.5, 0.5), 1),
            (Complex::new(0.5, 0.5), 0),
        ] {
            let expected = direct_power_sums(w, count);
            // w^count as gram_closed forms it: modulus and angle scaled separately.
            let w_count =
                Complex::from_polar(libm::pow(w.norm(), count as f64), w.arg() * count as f64);
            let sums = power_sums_closed(w, w_count, count);
            for k in 0..3 {
                // Relative to the sum of |terms|, the scale the direct sum itself has.
                let scale: f64 = (0..count)
                    .map(|n| libm::pow(n as f64, k as f64) * libm::pow(w.norm(), n as f64))
                    .sum();
                let error = (sums[k] - expected[k]).norm();
                assert!(
                    error <= 1e-12 * (scale + 1.0),
                    "{w} {count} k={k}: {:?} vs {:?}",
                    sums[k],
                    expected[k]
                );
            }
        }
    }

    /// sum w^n, sum n w^n, sum n^2 w^n over n < count, term by term.
    fn direct_power_sums(w: Complex<f64>, count: usize) -> [Complex<f64>; 3] {
        let mut sums = [Complex::new(0.0, 0.0); 3];
        let mut power = Complex::new(1.0, 0.0);
        for n in 0..count {
            let index = n as f64;
            sums[0] += power;
            sums[1] += power * index;
            sums[2] += power * (index * index);
            power *= w;
        }
        sums
    }

    #[test]
    fn power_sums_match_the_direct_sum() {
        let w = Complex::new(0.99, 0.05);
        for count in [0, 1, 2, 3, 7, 64, 1001] {
            let expected = direct_power_sums(w, count);
            let [sums, conjugate] = power_sums(&[w, w.conj()], count);
            for k in 0..3 {
                assert!((sums[k] - expected[k]).norm() <= 1e-12 * (expected[k].norm() + 1.0));
                assert!(
                    (conjugate[k] - expected[k].conj()).norm()
                        <= 1e-12 * (expected[k].norm() + 1.0)
                );
            }
        }
    }
}
