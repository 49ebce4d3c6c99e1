//! Levenberg-Marquardt fit of the bite transient, paper eq. (1) (corrected form).
//!
//! ```text
//! F(t) = (a1 cos(2 pi a5 t) + a3 sin(2 pi a5 t)) exp(-a7 t)
//!      + (a2 cos(2 pi a6 t) + a4 sin(2 pi a6 t)) exp(-a8 t)
//!      + a9 (1 - exp(-a10 t))
//! ```
//!
//! t is time from the first sample handed in. The model is linear in a1, a2, a3, a4,
//! a9 once a5, a6, a7, a8, a10 are fixed, so the fit is by variable projection
//! (Golub-Pereyra, with Kaufman's Jacobian): Levenberg-Marquardt iterates over the five
//! nonlinear parameters only, and every point it visits has its linear parameters
//! solved exactly by least squares. That needs fewer iterations than plain LM over all
//! ten, and each iteration is cheaper:
//!
//! - the Gram matrix of the basis (the five model columns and the five columns their
//!   derivatives span) is a sum of damped complex exponentials times t^k, whose
//!   geometric-series closed form costs O(1) (binary splitting, O(log N), where the
//!   closed form would cancel);
//! - the only pass over the samples projects the residual on those ten columns (the
//!   exponentials and sines advanced by complex recurrences, one multiplication per
//!   sample and mode, no transcendental call per sample; even and odd samples in two
//!   independent lanes, and the t-weighted sums from running sums without a product
//!   by t).
//!
//! It is hand-rolled because no crate offers Levenberg-Marquardt or variable projection
//! without heap: everything lives on fixed-size arrays and nalgebra matrices (5x5
//! Cholesky solves on plain arrays), the N x 10 Jacobian is never stored.
//!
//! Initialisation needs no user guess: [`crate::pencil::poles`] gives the poles, a
//! linear least-squares fit over all candidate poles picks the two oscillating modes of
//! largest energy and the load exponential (a10), tried against two fixed rates. A
//! coarse pass on every `decimation`-th sample converges cheaply; the full record then
//! needs two or three iterations. All work is done on data scaled to a peak of 1, so
//! huge inputs do not overflow.

use crate::linalg::{peak_magnitude, Cholesky5};
use crate::pencil::{self, MIN_DECIMATED_SAMPLES};
use core::f64::consts::PI;
use nalgebra::{Complex, SMatrix, SVector};

/// Number of eq. (1) parameters.
pub const PARAMS: usize = 10;

/// Options of [`fit_eq1`]; build with [`FitOptions::new`] and adjust fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Sample rate, Hz, finite and > 0.
    pub sample_rate_hz: f64,
    /// Fit only samples above zero (paper: gaps open when the torque crosses zero).
    pub positive_only: bool,
    /// Highest mode frequency the initialiser must resolve, Hz, in (0, 0.45 fs); sets
    /// the decimation of the pencil (decimated rate >= 4x this). Default 60 Hz.
    pub max_mode_hz: f64,
    /// Iteration limit, >= 1. Default 100.
    pub max_iterations: u32,
    /// Relative tolerance on the cost decrease and the step, in (0, 0.1). Default 1e-6:
    /// a relative cost change of 1e-6 at N samples moves the parameters by about
    /// sqrt(1e-6 N) of their standard error (0.02 at N = 500), far below the noise.
    pub tolerance: f64,
}

impl FitOptions {
    /// Defaults for a record sampled at `sample_rate_hz` (Hz).
    pub fn new(sample_rate_hz: f64) -> Self {
        Self {
            sample_rate_hz,
            positive_only: false,
            max_mode_hz: 60.0,
            max_iterations: 100,
            tolerance: 1e-6,
        }
    }
}

/// Why [`fit_eq1`] gave no fit; setting variants name the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitError {
    /// `sample_rate_hz` is not finite and > 0.
    SampleRateHz,
    /// `max_mode_hz` is outside (0, 0.45 fs).
    MaxModeHz,
    /// `max_iterations` is 0.
    MaxIterations,
    /// `tolerance` is outside (0, 0.1).
    Tolerance,
    /// Too few samples (or too few above zero with `positive_only`).
    TooFewSamples,
    /// A sample is NaN or infinite.
    NonFinite,
    /// All samples are zero.
    Flat,
    /// The initialiser found fewer than two oscillating modes.
    ModesNotFound,
    /// A decomposition or the normal equations were singular.
    Singular,
    /// The iteration produced non-finite parameters.
    Diverged,
}

/// How the iteration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitStatus {
    /// The relative cost decrease or step fell below the tolerance.
    Converged,
    /// No step decreased the cost any more: a minimum at working precision.
    Stalled,
    /// `max_iterations` was reached first.
    MaxIterations,
}

/// Result of [`fit_eq1`]. Torques in the units of the samples (kN*m), f1 < f2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eq1Fit {
    /// a1..a10 in paper order (a5 < a6, both > 0).
    pub params: [f64; PARAMS],
    /// First natural frequency a5, Hz.
    pub f1_hz: f64,
    /// Second natural frequency a6, Hz.
    pub f2_hz: f64,
    /// Decay rate of the first mode a7, 1/s.
    pub decay1_per_s: f64,
    /// Decay rate of the second mode a8, 1/s.
    pub decay2_per_s: f64,
    /// Damping ratio of the first mode, a7 / sqrt(a7^2 + (2 pi a5)^2).
    pub zeta1: f64,
    /// Damping ratio of the second mode.
    pub zeta2: f64,
    /// Static torque a9.
    pub static_torque: f64,
    /// Load rise rate a10, 1/s.
    pub rise_per_s: f64,
    /// Peak of the fitted curve over the record divided by a9, when a9 > 0.
    pub taf: Option<f64>,
    /// RMS of the residual over the fitted samples.
    pub rms_residual: f64,
    /// Levenberg-Marquardt iterations done.
    pub iterations: u32,
    /// How the iteration ended.
    pub status: FitStatus,
    /// Number of samples fitted.
    pub samples_used: usize,
}

/// Evaluates eq. (1) with parameters `params` (paper order) at time `t_s` (s).
pub fn eq1(params: &[f64; PARAMS], t_s: f64) -> f64 {
    let [a1, a2, a3, a4, a5, a6, a7, a8, a9, a10] = *params;
    let (s5, c5) = libm::sincos(2.0 * PI * a5 * t_s);
    let (s6, c6) = libm::sincos(2.0 * PI * a6 * t_s);
    (a1 * c5 + a3 * s5) * libm::exp(-a7 * t_s)
        + (a2 * c6 + a4 * s6) * libm::exp(-a8 * t_s)
        + a9 * (1.0 - libm::exp(-a10 * t_s))
}

/// exp((-decay + i 2 pi f) t) advanced sample by sample.
#[derive(Clone, Copy)]
struct Rotor {
    re: f64,
    im: f64,
    step_re: f64,
    step_im: f64,
}

impl Rotor {
    fn new(decay_per_s: f64, frequency_hz: f64, dt: f64) -> Self {
        let (s, c) = libm::sincos(2.0 * PI * frequency_hz * dt);
        let m = libm::exp(-decay_per_s * dt);
        Self {
            re: 1.0,
            im: 0.0,
            step_re: m * c,
            step_im: m * s,
        }
    }

    #[inline(always)]
    fn advance(&mut self) {
        let re = self.re * self.step_re - self.im * self.step_im;
        self.im = self.re * self.step_im + self.im * self.step_re;
        self.re = re;
    }
}

/// The record as fitted: every `stride`-th sample times `inverse_scale` (peak
/// magnitude 1), `dt` seconds apart.
struct Data<'a> {
    samples: &'a [f64],
    stride: usize,
    inverse_scale: f64,
    dt: f64,
    positive_only: bool,
}

impl Data<'_> {
    /// The samples used, scaled.
    fn values(&self) -> impl Iterator<Item = f64> + '_ {
        self.samples
            .iter()
            .step_by(self.stride)
            .map(|v| v * self.inverse_scale)
    }

    /// Number of samples in the residual (after the stride and the positive mask).
    fn used(&self) -> usize {
        self.values()
            .filter(|v| !self.positive_only || *v > 0.0)
            .count()
    }

    /// Number of samples after the stride (masked ones included).
    fn count(&self) -> usize {
        self.samples.len().div_ceil(self.stride)
    }

    /// Duration covered, s.
    fn duration_s(&self) -> f64 {
        self.count() as f64 * self.dt
    }
}

/// Nonlinear parameters a5, a6, a7, a8, a10 (the LM unknowns), in that order.
type Nonlinear = [f64; 5];
/// Linear parameters a1, a2, a3, a4, a9 (solved exactly at every nonlinear point).
type Linear = [f64; 5];
/// Paper index (0-based) of each nonlinear parameter.
const NONLINEAR_INDEX: [usize; 5] = [4, 5, 6, 7, 9];
/// Paper index (0-based) of each linear parameter.
const LINEAR_INDEX: [usize; 5] = [0, 1, 2, 3, 8];
/// Basis functions per sample: the 5 columns of Phi (model = Phi c), then the 5
/// derivative columns D (t u1, t v1, t u2, t v2, t e10) that span dPhi/dtheta c.
const BASIS: usize = 10;

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
    let inverse = gap.conj() / gap_norm2;
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
fn gram_closed(theta: &Nonlinear, count: usize, dt: f64) -> [[f64; BASIS]; BASIS] {
    let n = count as f64;
    // exp((-decay + i 2 pi f) dt) and its count-th power.
    let rotor = |decay: f64, frequency: f64| {
        let angle = 2.0 * PI * frequency * dt;
        let (s, c) = libm::sincos(angle);
        let (s_count, c_count) = libm::sincos(angle * n);
        (
            Complex::new(c, s) * libm::exp(-decay * dt),
            Complex::new(c_count, s_count) * libm::exp(-decay * dt * n),
        )
    };
    let (z1, z1_count) = rotor(theta[2], theta[0]);
    let (z2, z2_count) = rotor(theta[3], theta[1]);
    let load = Complex::new(libm::exp(-theta[4] * dt), 0.0);
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
/// (the `positive_only` case, where the closed form does not apply).
fn gram_direct(theta: &Nonlinear, data: &Data<'_>) -> [[f64; BASIS]; BASIS] {
    let dt = data.dt;
    let mut mode1 = Rotor::new(theta[2], theta[0], dt);
    let mut mode2 = Rotor::new(theta[3], theta[1], dt);
    let load_step = libm::exp(-theta[4] * dt);
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

/// Two f64 lanes with element-wise arithmetic: the even and the odd samples of a pass,
/// advanced side by side. Independent lanes halve the recurrences' dependency chains
/// and let the compiler use 2-wide vector instructions (SSE2 on baseline x86-64).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Pair([f64; 2]);

impl Pair {
    /// Both lanes `value`.
    const fn splat(value: f64) -> Self {
        Self([value, value])
    }

    /// Sum of the two lanes.
    fn total(self) -> f64 {
        self.0[0] + self.0[1]
    }
}

impl core::ops::Add for Pair {
    type Output = Self;
    #[inline(always)]
    fn add(self, other: Self) -> Self {
        Self([self.0[0] + other.0[0], self.0[1] + other.0[1]])
    }
}

impl core::ops::Sub for Pair {
    type Output = Self;
    #[inline(always)]
    fn sub(self, other: Self) -> Self {
        Self([self.0[0] - other.0[0], self.0[1] - other.0[1]])
    }
}

impl core::ops::Mul for Pair {
    type Output = Self;
    #[inline(always)]
    fn mul(self, other: Self) -> Self {
        Self([self.0[0] * other.0[0], self.0[1] * other.0[1]])
    }
}

impl core::ops::AddAssign for Pair {
    #[inline(always)]
    fn add_assign(&mut self, other: Self) {
        *self = *self + other;
    }
}

/// A [`Rotor`] split over two lanes: lane l holds z^(2m + l) at step m, and both lanes
/// advance by z^2, so consecutive samples no longer wait on each other.
#[derive(Clone, Copy)]
struct PairRotor {
    re: Pair,
    im: Pair,
    step_re: Pair,
    step_im: Pair,
}

impl PairRotor {
    /// Lanes started at `start` and `start` z (z the step of `rotor`).
    fn new(rotor: Rotor, start_re: f64, start_im: f64) -> Self {
        let (sr, si) = (rotor.step_re, rotor.step_im);
        Self {
            re: Pair([start_re, start_re * sr - start_im * si]),
            im: Pair([start_im, start_re * si + start_im * sr]),
            step_re: Pair::splat(sr * sr - si * si),
            step_im: Pair::splat(2.0 * sr * si),
        }
    }

    #[inline(always)]
    fn advance(&mut self) {
        let re = self.re * self.step_re - self.im * self.step_im;
        self.im = self.re * self.step_im + self.im * self.step_re;
        self.re = re;
    }
}

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
    /// is not fitted (0 instead).
    #[inline(always)]
    fn step(&mut self, values: Pair, keep: Option<[bool; 2]>) {
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
        let [c1, c2, c3, c4, c9] = self.reference;
        let model = c1 * u1 + c2 * u2 + c3 * v1 + c4 * v2 + c9 * (Pair::splat(1.0) - e10);
        let mut residual = values - model;
        if let Some(keep) = keep {
            for (r, keep) in residual.0.iter_mut().zip(keep) {
                if !keep {
                    *r = 0.0;
                }
            }
        }
        self.squares += residual * residual;
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

/// One pass over the record with a reference linear part `reference`: the residual
/// r0 = y - Phi(theta) reference, its sum of squares and its projections [Phi D]^T r0.
/// Working on r0 rather than y keeps the cost free of cancellation near the optimum
/// (cost = |r0|^2 - correction, both small), so exact records converge to full precision.
///
/// Even and odd samples run in two lanes ([`Pair`]). The t-weighted sums use no
/// multiplication by t: with P_m the running sum of a_j over the first m steps of a lane
/// and Q the sum of those P_m, sum over m of m a_m = (M - 1) P_M - Q (M steps).
fn project(theta: &Nonlinear, reference: &Linear, data: &Data<'_>) -> (f64, [f64; BASIS]) {
    let dt = data.dt;
    let load_step = libm::exp(-theta[4] * dt);
    let zero = Pair::splat(0.0);
    let mut state = Projection {
        mode1: PairRotor::new(Rotor::new(theta[2], theta[0], dt), 1.0, 0.0),
        mode2: PairRotor::new(Rotor::new(theta[3], theta[1], dt), 1.0, 0.0),
        load: Pair([1.0, load_step]),
        load_step: Pair::splat(load_step * load_step),
        reference: reference.map(Pair::splat),
        squares: zero,
        running: [zero; 6],
        nested: [zero; 5],
        steps: 0,
    };
    let (stride, scale) = (data.stride, data.inverse_scale);
    let chunks = data.samples.chunks_exact(2 * stride);
    let rest = chunks.remainder();
    let pairs = chunks.map(|c| Pair([c[0] * scale, c[stride] * scale]));
    if data.positive_only {
        for values in pairs {
            state.step(values, Some(values.0.map(|v| v > 0.0)));
        }
    } else {
        for values in pairs {
            state.step(values, None);
        }
    }
    if !rest.is_empty() {
        // The last one or two samples; an empty odd lane is masked.
        let odd = rest.get(stride);
        let values = Pair([rest[0] * scale, odd.map_or(0.0, |v| v * scale)]);
        let fitted = |v: f64| !data.positive_only || v > 0.0;
        state.step(
            values,
            Some([fitted(values.0[0]), odd.is_some() && fitted(values.0[1])]),
        );
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
        let per_lane = Pair::splat(2.0) * (Pair::splat(last) * p - q) + Pair([0.0, 1.0]) * p;
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
    (squares.total(), projections)
}

/// Largest ratio of |r0|^2 to the cost accepted in [`evaluate`]: 4 of 16 digits lost.
const MAX_CANCELLATION: f64 = 1e4;

/// The variable-projection problem at one nonlinear point.
#[derive(Clone, Copy)]
struct Evaluation {
    theta: Nonlinear,
    /// Least-squares linear parameters at `theta`.
    linear: Linear,
    /// min over the linear parameters of sum(r^2).
    cost: f64,
    gram: [[f64; BASIS]; BASIS],
    /// Cholesky factor of Phi^T Phi (the top left 5 x 5 of `gram`).
    phi_gram: Cholesky5,
    /// D^T r at the optimal linear parameters.
    derivative_projections: [f64; 5],
}

/// Solves the linear least squares at `theta`, starting from `reference` (any linear
/// parameters; the previous solution makes the cost most accurate).
fn evaluate(theta: Nonlinear, reference: &Linear, data: &Data<'_>) -> Option<Evaluation> {
    let gram = if data.positive_only {
        gram_direct(&theta, data)
    } else {
        gram_closed(&theta, data.count(), data.dt)
    };
    let phi_gram = Cholesky5::new(&SMatrix::<f64, 5, 5>::from_fn(|i, j| gram[i][j]))?;
    let mut reference = *reference;
    // A reference far from the solution (the first point, or a step that changed the
    // basis a lot) leaves a cost that is a small difference of large numbers: then
    // one more pass from the solution just found.
    let mut attempts = 0;
    let (linear, cost, correction, projections) = loop {
        let (squares, projections) = project(&theta, &reference, data);
        let phi_projections = SVector::<f64, 5>::from_fn(|i, _| projections[i]);
        let correction = phi_gram.solve(&phi_projections);
        let mut linear = reference;
        for (l, d) in linear.iter_mut().zip(correction.iter()) {
            *l += d;
        }
        let cost = squares - phi_projections.dot(&correction);
        attempts += 1;
        if attempts >= 3 || !cost.is_finite() || cost * MAX_CANCELLATION >= squares {
            break (linear, cost.max(0.0), correction, projections);
        }
        reference = linear;
    };
    // D^T r = D^T r0 - D^T Phi correction.
    let mut derivative_projections = [0.0; 5];
    for (k, out) in derivative_projections.iter_mut().enumerate() {
        *out = projections[5 + k] - (0..5).map(|j| gram[5 + k][j] * correction[j]).sum::<f64>();
    }
    let finite = cost.is_finite()
        && linear.iter().all(|v| v.is_finite())
        && derivative_projections.iter().all(|v| v.is_finite());
    finite.then_some(Evaluation {
        theta,
        linear,
        cost,
        gram,
        phi_gram,
        derivative_projections,
    })
}

/// Kaufman's variable-projection normal equations at `point`: the Jacobian of the
/// projected residual is approximated by P_perp J_N, J_N = D M the Jacobian of the
/// model in the nonlinear parameters at fixed linear ones, so
/// J^T J = M^T (D^T D) M - (Phi^T D M)^T (Phi^T Phi)^-1 (Phi^T D M) and J^T r = M^T D^T r.
fn normal_equations(point: &Evaluation) -> (SMatrix<f64, 5, 5>, SVector<f64, 5>) {
    let [c1, c2, c3, c4, c9] = point.linear;
    let w = 2.0 * PI;
    // dModel/dtheta = D M; rows of M: t u1, t v1, t u2, t v2, t e10.
    #[rustfmt::skip]
    let mixing = SMatrix::<f64, 5, 5>::from_row_slice(&[
        w * c3, 0.0,    -c1, 0.0, 0.0,
        -w * c1, 0.0,   -c3, 0.0, 0.0,
        0.0,    w * c4, 0.0, -c2, 0.0,
        0.0,   -w * c2, 0.0, -c4, 0.0,
        0.0,    0.0,    0.0, 0.0, c9,
    ]);
    let g = &point.gram;
    let cross = SMatrix::<f64, 5, 5>::from_fn(|i, j| g[i][5 + j]) * mixing;
    let derivative_gram = SMatrix::<f64, 5, 5>::from_fn(|i, j| g[5 + i][5 + j]);
    let projected = point.phi_gram.solve_matrix(&cross);
    let jtj = mixing.transpose() * derivative_gram * mixing - cross.transpose() * projected;
    let jtr = mixing.transpose() * SVector::<f64, 5>::from(point.derivative_projections);
    (jtj, jtr)
}

/// Solves the damped normal equations; `None` if Cholesky fails.
fn damped_step(
    jtj: &SMatrix<f64, 5, 5>,
    jtr: &SVector<f64, 5>,
    lambda: f64,
) -> Option<SVector<f64, 5>> {
    let max_diag = jtj.diagonal().max();
    let floor = max_diag * 1e-15 + f64::MIN_POSITIVE;
    let mut a = *jtj;
    for i in 0..5 {
        a[(i, i)] += lambda * a[(i, i)].max(floor);
    }
    let delta = Cholesky5::new(&a)?.solve(jtr);
    delta.iter().all(|d| d.is_finite()).then_some(delta)
}

/// Start of the iteration chosen from the pencil poles.
#[derive(Clone, Copy)]
struct Guess {
    /// a5, a6, a7, a8, a10.
    theta: Nonlinear,
    /// Whether a10 is a load pole of the pencil (else the default 10 / T, T the record
    /// length).
    rise_from_pencil: bool,
}

/// Chooses the initial a5..a8 and a10 from the pencil poles.
fn initial_guess(data: &Data<'_>, poles: &[pencil::Pole]) -> Result<Guess, FitError> {
    const MAX_BASIS: usize = 1 + pencil::MODEL_ORDER;
    let dt = data.dt;
    let duration = data.duration_s();
    // Basis slot -> (pole index, is sine); slot 0 is the constant.
    let mut rotors = [Rotor::new(0.0, 0.0, dt); pencil::MODEL_ORDER];
    let mut slots: heapless::Vec<(usize, bool), MAX_BASIS> = heapless::Vec::new();
    let _ = slots.push((usize::MAX, false));
    for (k, pole) in poles.iter().enumerate() {
        rotors[k] = Rotor::new(pole.decay_per_s, pole.frequency_hz, dt);
        if pole.frequency_hz > 0.0 {
            let _ = slots.push((k, false));
            let _ = slots.push((k, true));
        } else if pole.decay_per_s * duration > 0.5 {
            // Slower real poles are indistinguishable from the constant: dropped.
            let _ = slots.push((k, false));
        }
    }
    let mut ata = [[0.0_f64; MAX_BASIS]; MAX_BASIS];
    let mut atb = [0.0_f64; MAX_BASIS];
    for value in data.values() {
        let mut basis = [0.0_f64; MAX_BASIS];
        for (slot, &(k, sine)) in basis.iter_mut().zip(slots.iter()) {
            *slot = match (k, sine) {
                (usize::MAX, _) => 1.0,
                (k, false) => rotors[k].re,
                (k, true) => rotors[k].im,
            };
        }
        for rotor in rotors.iter_mut().take(poles.len()) {
            rotor.advance();
        }
        if data.positive_only && value <= 0.0 {
            continue;
        }
        for a in 0..slots.len() {
            atb[a] += basis[a] * value;
            // Upper triangle only; mirrored below.
            for b in a..slots.len() {
                ata[a][b] += basis[a] * basis[b];
            }
        }
    }
    let used = slots.len();
    let a = SMatrix::<f64, MAX_BASIS, MAX_BASIS>::from_fn(|i, j| {
        if i < used && j < used {
            ata[i.min(j)][i.max(j)]
        } else if i == j {
            1.0
        } else {
            0.0
        }
    });
    let b = SVector::<f64, MAX_BASIS>::from_fn(|i, _| if i < used { atb[i] } else { 0.0 });
    let coefficients = a.lu().solve(&b).ok_or(FitError::Singular)?;
    let constant = coefficients[0];

    // Energy of each oscillating candidate over the record; best two kept.
    let mut best: [(f64, usize); 2] = [(-1.0, usize::MAX); 2];
    let mut load: Option<(f64, f64)> = None;
    let mut slot = 1;
    while slot < used {
        let (k, _) = slots[slot];
        let pole = poles[k];
        if pole.frequency_hz > 0.0 {
            let (c, s) = (coefficients[slot], coefficients[slot + 1]);
            let rate = 2.0 * pole.decay_per_s;
            let weight = if libm::fabs(rate * duration) < 1e-9 {
                duration
            } else {
                (1.0 - libm::exp(-rate * duration)) / rate
            };
            let energy = (c * c + s * s) * weight;
            if energy.is_finite() {
                if energy > best[0].0 {
                    best[1] = best[0];
                    best[0] = (energy, k);
                } else if energy > best[1].0 {
                    best[1] = (energy, k);
                }
            }
            slot += 2;
        } else {
            // The load term is -a9 exp(-a10 t): opposite sign to the constant.
            let c = coefficients[slot];
            if c * constant < 0.0 && load.is_none_or(|(m, _)| libm::fabs(c) > m) {
                load = Some((libm::fabs(c), pole.decay_per_s));
            }
            slot += 1;
        }
    }
    if best[1].1 == usize::MAX {
        return Err(FitError::ModesNotFound);
    }
    let (first, second) = if poles[best[0].1].frequency_hz <= poles[best[1].1].frequency_hz {
        (poles[best[0].1], poles[best[1].1])
    } else {
        (poles[best[1].1], poles[best[0].1])
    };
    let rise = load.map_or(10.0 / duration, |(_, decay)| decay);
    Ok(Guess {
        theta: [
            first.frequency_hz,
            second.frequency_hz,
            first.decay_per_s,
            second.decay_per_s,
            rise,
        ],
        rise_from_pencil: load.is_some(),
    })
}

/// Puts both frequencies positive and mode 1 below mode 2.
fn canonical(mut p: [f64; PARAMS]) -> [f64; PARAMS] {
    // cos(-x) = cos x, sin(-x) = -sin x.
    if p[4] < 0.0 {
        p[4] = -p[4];
        p[2] = -p[2];
    }
    if p[5] < 0.0 {
        p[5] = -p[5];
        p[3] = -p[3];
    }
    if p[4] > p[5] {
        p.swap(0, 1);
        p.swap(2, 3);
        p.swap(4, 5);
        p.swap(6, 7);
    }
    p
}

/// Evaluates `guess` with a10 at 8 / T and 24 / T (T the record length), and as
/// guessed when the pencil found a load pole, and returns the best. The pencil's real
/// poles are the least reliable of its output, and a start with a10 far above the truth
/// costs many rejected steps; the variable-projection cost is smooth and unimodal in
/// a10, so a few trials suffice. (Without a load pole the guess is 10 / T, too close to
/// 8 / T to be worth its own evaluation.)
fn best_rise(guess: Guess, data: &Data<'_>) -> Option<Evaluation> {
    let duration = data.duration_s();
    let theta = guess.theta;
    let pencil_rise = guess.rise_from_pencil.then_some(theta[4]);
    let mut best: Option<Evaluation> = None;
    for rise in pencil_rise
        .into_iter()
        .chain([8.0 / duration, 24.0 / duration])
    {
        let mut trial = theta;
        trial[4] = rise;
        let reference = best.map_or([0.0; 5], |b| b.linear);
        if let Some(candidate) = evaluate(trial, &reference, data) {
            if best.is_none_or(|b| candidate.cost < b.cost) {
                best = Some(candidate);
            }
        }
    }
    best
}

/// Tolerance of the coarse pass, which only initialises the full one.
const COARSE_TOLERANCE: f64 = 1e-3;

/// Fits eq. (1) to `samples` (uniform at `options.sample_rate_hz`, t = 0 at the first).
///
/// Needs at least [`MIN_DECIMATED_SAMPLES`] samples and two oscillating modes in the
/// record. No heap is used; the cost is O(N) per iteration with a small constant.
///
/// ```
/// use millgate_dsp::fit::{eq1, fit_eq1, FitOptions};
/// let table1 = [-147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7];
/// let samples: Vec<f64> = (0..500).map(|i| eq1(&table1, i as f64 / 1000.0)).collect();
/// let fit = fit_eq1(&samples, &FitOptions::new(1000.0)).unwrap();
/// assert!((fit.f1_hz - 11.99).abs() < 1e-6 && (fit.f2_hz - 20.91).abs() < 1e-6);
/// ```
pub fn fit_eq1(samples: &[f64], options: &FitOptions) -> Result<Eq1Fit, FitError> {
    let rate = options.sample_rate_hz;
    if !(rate.is_finite() && rate > 0.0) {
        return Err(FitError::SampleRateHz);
    }
    if !(options.max_mode_hz > 0.0 && options.max_mode_hz < 0.45 * rate) {
        return Err(FitError::MaxModeHz);
    }
    if options.max_iterations == 0 {
        return Err(FitError::MaxIterations);
    }
    if !(options.tolerance > 0.0 && options.tolerance < 0.1) {
        return Err(FitError::Tolerance);
    }
    if samples.len() < MIN_DECIMATED_SAMPLES {
        return Err(FitError::TooFewSamples);
    }
    let (scale, finite) = peak_magnitude(samples);
    if !finite {
        return Err(FitError::NonFinite);
    }
    if scale == 0.0 {
        return Err(FitError::Flat);
    }
    let used = if options.positive_only {
        samples.iter().filter(|&&v| v > 0.0).count()
    } else {
        samples.len()
    };
    if used < 2 * PARAMS {
        return Err(FitError::TooFewSamples);
    }

    let dt = 1.0 / rate;
    let decimation = (samples.len() / (2 * MIN_DECIMATED_SAMPLES))
        .min((rate / (4.0 * options.max_mode_hz)) as usize)
        .max(1);
    let poles = pencil::poles(samples, rate, decimation).map_err(|e| match e {
        pencil::PencilError::TooFewSamples => FitError::TooFewSamples,
        _ => FitError::Singular,
    })?;

    // Coarse pass: every `stride`-th sample (stride <= the pencil's decimation, so the
    // modes stay well below the coarse Nyquist rate) converges cheaply; the full record
    // then needs only a few iterations.
    let coarse = Data {
        samples,
        stride: decimation,
        inverse_scale: 1.0 / scale,
        dt: dt * decimation as f64,
        positive_only: options.positive_only,
    };
    let full = Data {
        stride: 1,
        dt,
        ..coarse
    };
    let coarse_used = coarse.used();
    let (start, coarse_iterations) = if decimation > 1 && coarse_used >= 4 * PARAMS {
        let initial = initial_guess(&coarse, &poles)?;
        let initial = best_rise(initial, &coarse).ok_or(FitError::Singular)?;
        // The coarse optimum differs from the full one by the noise anyway (a relative
        // cost of about PARAMS / coarse_used): converging it further is wasted.
        let coarse_options = FitOptions {
            tolerance: options.tolerance.max(COARSE_TOLERANCE),
            ..*options
        };
        let (point, _, iterations, _) =
            levenberg_marquardt(initial, &coarse, coarse_used, &coarse_options)?;
        ((point.theta, point.linear), iterations)
    } else {
        ((initial_guess(&full, &poles)?.theta, [0.0; 5]), 0)
    };
    let start = evaluate(start.0, &start.1, &full).ok_or(FitError::Singular)?;
    let (point, rms, iterations, status) = levenberg_marquardt(start, &full, used, options)?;
    let iterations = iterations + coarse_iterations;
    let mut params = [0.0; PARAMS];
    for (&index, value) in NONLINEAR_INDEX.iter().zip(point.theta) {
        params[index] = value;
    }
    for (&index, value) in LINEAR_INDEX.iter().zip(point.linear) {
        params[index] = value;
    }
    let mut params = canonical(params);
    for index in [0, 1, 2, 3, 8] {
        params[index] *= scale;
    }
    if params.iter().any(|v| !v.is_finite()) {
        return Err(FitError::Diverged);
    }
    let zeta = |decay: f64, frequency: f64| {
        let norm = libm::hypot(decay, 2.0 * PI * frequency);
        if norm > 0.0 {
            decay / norm
        } else {
            0.0
        }
    };
    let taf = fitted_peak(&params, samples.len(), dt)
        .filter(|_| params[8] > 0.0)
        .map(|peak| peak / params[8])
        .filter(|v| v.is_finite());
    Ok(Eq1Fit {
        params,
        f1_hz: params[4],
        f2_hz: params[5],
        decay1_per_s: params[6],
        decay2_per_s: params[7],
        zeta1: zeta(params[6], params[4]),
        zeta2: zeta(params[7], params[5]),
        static_torque: params[8],
        rise_per_s: params[9],
        taf,
        rms_residual: rms * scale,
        iterations,
        status,
        samples_used: used,
    })
}

/// Largest value of the fitted curve over `len` samples, by the same recurrences.
/// Each mode is one rotor started at its complex amplitude (a1 - i a3 for mode 1, so
/// its real part is a1 u1 + a3 v1) and the load term is advanced as a9 e10 directly;
/// even and odd samples run in the two lanes of a [`Pair`].
fn fitted_peak(p: &[f64; PARAMS], len: usize, dt: f64) -> Option<f64> {
    let mut mode1 = PairRotor::new(Rotor::new(p[6], p[4], dt), p[0], -p[2]);
    let mut mode2 = PairRotor::new(Rotor::new(p[7], p[5], dt), p[1], -p[3]);
    let load_step = libm::exp(-p[9] * dt);
    let mut load = Pair([p[8], p[8] * load_step]);
    let load_step = Pair::splat(load_step * load_step);
    let static_torque = Pair::splat(p[8]);
    let mut peak = [f64::NEG_INFINITY; 2];
    let mut value = || {
        let value = mode1.re + mode2.re + (static_torque - load);
        mode1.advance();
        mode2.advance();
        load = load * load_step;
        value.0
    };
    for _ in 0..len / 2 {
        for (peak, lane) in peak.iter_mut().zip(value()) {
            // A comparison, not f64::max: its NaN handling costs a branch per sample.
            if lane > *peak {
                *peak = lane;
            }
        }
    }
    if len % 2 == 1 {
        // The last sample is in the even lane.
        let [last, _] = value();
        if last > peak[0] {
            peak[0] = last;
        }
    }
    let peak = if peak[1] > peak[0] { peak[1] } else { peak[0] };
    peak.is_finite().then_some(peak)
}

/// Levenberg-Marquardt over the nonlinear parameters with the linear ones projected
/// out; returns (point, rms residual, iterations, status) in scaled units.
fn levenberg_marquardt(
    start: Evaluation,
    data: &Data<'_>,
    used: usize,
    options: &FitOptions,
) -> Result<(Evaluation, f64, u32, FitStatus), FitError> {
    const LAMBDA_MAX: f64 = 1e12;
    let mut point = start;
    let mut lambda = 1e-3;
    let mut status = FitStatus::MaxIterations;
    let mut iterations = 0;
    'outer: while iterations < options.max_iterations {
        iterations += 1;
        if point.cost == 0.0 {
            status = FitStatus::Converged;
            break;
        }
        let (jtj, jtr) = normal_equations(&point);
        loop {
            let Some(delta) = damped_step(&jtj, &jtr, lambda) else {
                lambda *= 10.0;
                if lambda > LAMBDA_MAX {
                    return Err(FitError::Singular);
                }
                continue;
            };
            // Near Gauss-Newton (small lambda), delta . J^T r estimates twice the cost
            // decrease the step can bring: when negligible, stop without another pass.
            let gain = delta.dot(&jtr);
            if lambda <= 1e-2 && gain <= options.tolerance * point.cost {
                status = FitStatus::Converged;
                break 'outer;
            }
            let mut trial = point.theta;
            for (p, d) in trial.iter_mut().zip(delta.iter()) {
                *p += d;
            }
            let candidate = evaluate(trial, &point.linear, data);
            if let Some(candidate) = candidate.filter(|c| c.cost < point.cost) {
                let decrease = (point.cost - candidate.cost) / point.cost;
                let small_step = delta
                    .iter()
                    .zip(trial.iter())
                    .all(|(d, p)| libm::fabs(*d) <= options.tolerance * (libm::fabs(*p) + 1e-6));
                point = candidate;
                lambda = (lambda / 3.0).max(1e-12);
                if decrease <= options.tolerance || small_step {
                    status = FitStatus::Converged;
                    break 'outer;
                }
                break;
            }
            lambda *= 10.0;
            if lambda > LAMBDA_MAX {
                status = FitStatus::Stalled;
                break 'outer;
            }
        }
    }
    let rms = libm::sqrt(point.cost / used as f64);
    Ok((point, rms, iterations, status))
}

#[cfg(test)]
mod tests {
    use super::*;

    const TABLE1: [f64; PARAMS] = [
        -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
    ];

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
            let data = Data {
                samples: &samples,
                stride,
                inverse_scale: 1.0,
                dt: 1e-3 * stride as f64,
                positive_only: true,
            };
            let direct = gram_direct(&theta, &data);
            let closed = gram_closed(&theta, data.count(), data.dt);
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
                let data = Data {
                    samples: &samples[..len],
                    stride,
                    inverse_scale: 1.0 / 300.0,
                    dt: 1e-3 * stride as f64,
                    positive_only,
                };
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
                let (found_squares, found) = project(&theta, &reference, &data);
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

    #[test]
    fn fitted_peak_matches_eq1_sample_by_sample() {
        let params = TABLE1;
        let dt = 1e-3;
        let expected = (0..500)
            .map(|i| eq1(&params, i as f64 * dt))
            .fold(f64::NEG_INFINITY, f64::max);
        let peak = fitted_peak(&params, 500, dt).unwrap();
        assert!(
            libm::fabs(peak - expected) <= 1e-10 * expected,
            "{peak} vs {expected}"
        );
        // A short record ends before the overshoot: the peak is its last sample.
        let expected = (0..11)
            .map(|i| eq1(&params, i as f64 * dt))
            .fold(f64::NEG_INFINITY, f64::max);
        let peak = fitted_peak(&params, 11, dt).unwrap();
        assert!(libm::fabs(peak - expected) <= 1e-10 * libm::fabs(expected));
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
