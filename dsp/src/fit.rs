//! Levenberg-Marquardt fit of the bite transient, paper eq. (1) (corrected form).
//!
//! ```text
//! F(t) = (a1 cos(2 pi a5 t) + a3 sin(2 pi a5 t)) exp(-a7 t)
//!      + (a2 cos(2 pi a6 t) + a4 sin(2 pi a6 t)) exp(-a8 t)
//!      + a9 (1 - exp(-a10 t))
//! ```
//!
//! t is time from the first sample handed in. The fit is hand-rolled because no crate
//! offers Levenberg-Marquardt without heap: J^T J (10x10) and J^T r are accumulated
//! sample by sample (the N x 10 Jacobian is never stored), the damped normal equations
//! `(J^T J + lambda diag(J^T J)) delta = J^T r` (Marquardt scaling) are solved by
//! Cholesky on fixed-size matrices. The exponentials and sines are advanced by complex
//! recurrences (one multiplication per sample and mode), so an iteration costs no
//! transcendental call per sample.
//!
//! Initialisation needs no user guess: [`crate::pencil::poles`] gives the poles, a
//! linear least-squares fit over all candidate poles picks the two oscillating modes of
//! largest energy, the constant (a9) and the load exponential (a10); a linear solve
//! then sets a1..a4 and a9 for those poles. All work is done on data scaled to a peak
//! of 1, so huge inputs do not overflow.

use crate::pencil::{self, MIN_DECIMATED_SAMPLES};
use core::f64::consts::PI;
use nalgebra::{SMatrix, SVector};

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

    /// Duration covered, s.
    fn duration_s(&self) -> f64 {
        self.samples.len().div_ceil(self.stride) as f64 * self.dt
    }
}

/// Normal equations of one parameter vector.
struct Normal {
    jtj: [[f64; PARAMS]; PARAMS],
    jtr: [f64; PARAMS],
    cost: f64,
}

/// Samples per block of Jacobian rows: the products are summed over a block before
/// they touch J^T J, so the 10x10 accumulator is loaded and stored once per block.
const BLOCK: usize = 16;

/// Accumulates J^T J (upper triangle), J^T r and the cost sum(r^2) at `p`.
fn accumulate(p: &[f64; PARAMS], data: &Data<'_>) -> Normal {
    let [a1, a2, a3, a4, a5, a6, a7, a8, a9, a10] = *p;
    let dt = data.dt;
    let mut mode1 = Rotor::new(a7, a5, dt);
    let mut mode2 = Rotor::new(a8, a6, dt);
    let load_step = libm::exp(-a10 * dt);
    let mut load = 1.0;
    let mut jtj = [[0.0; PARAMS]; PARAMS];
    let mut jtr = [0.0; PARAMS];
    let mut cost = 0.0;
    let mut jacobian = [[0.0_f64; BLOCK]; PARAMS];
    let mut residuals = [0.0_f64; BLOCK];
    let mut values = data.values();
    let mut index = 0_usize;
    loop {
        let mut filled = 0;
        for (k, value) in values.by_ref().take(BLOCK).enumerate() {
            filled = k + 1;
            let t = index as f64 * dt;
            index += 1;
            let (u1, v1, u2, v2, e10) = (mode1.re, mode1.im, mode2.re, mode2.im, load);
            mode1.advance();
            mode2.advance();
            load *= load_step;
            // A masked sample contributes a zero row.
            let weight = if data.positive_only && value <= 0.0 {
                0.0
            } else {
                1.0
            };
            let m1 = a1 * u1 + a3 * v1;
            let m2 = a2 * u2 + a4 * v2;
            let q1 = a3 * u1 - a1 * v1;
            let q2 = a4 * u2 - a2 * v2;
            let w = 2.0 * PI * t * weight;
            residuals[k] = weight * (value - (m1 + m2 + a9 * (1.0 - e10)));
            jacobian[0][k] = weight * u1;
            jacobian[1][k] = weight * u2;
            jacobian[2][k] = weight * v1;
            jacobian[3][k] = weight * v2;
            jacobian[4][k] = w * q1;
            jacobian[5][k] = w * q2;
            jacobian[6][k] = -t * weight * m1;
            jacobian[7][k] = -t * weight * m2;
            jacobian[8][k] = weight * (1.0 - e10);
            jacobian[9][k] = weight * a9 * t * e10;
        }
        if filled == 0 {
            break;
        }
        // A short last block: zero the unused tail so it adds nothing.
        for k in filled..BLOCK {
            residuals[k] = 0.0;
            for row in jacobian.iter_mut() {
                row[k] = 0.0;
            }
        }
        cost += dot(&residuals, &residuals);
        for a in 0..PARAMS {
            jtr[a] += dot(&jacobian[a], &residuals);
            for b in a..PARAMS {
                jtj[a][b] += dot(&jacobian[a], &jacobian[b]);
            }
        }
        if filled < BLOCK {
            break;
        }
    }
    Normal { jtj, jtr, cost }
}

/// Dot product of two blocks (fixed length: the compiler vectorizes it).
#[inline(always)]
fn dot(x: &[f64; BLOCK], y: &[f64; BLOCK]) -> f64 {
    let mut lanes = [0.0_f64; 4];
    for (xs, ys) in x.chunks_exact(4).zip(y.chunks_exact(4)) {
        for lane in 0..4 {
            lanes[lane] += xs[lane] * ys[lane];
        }
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
}

/// Solves the damped normal equations; `None` if Cholesky fails.
fn damped_step(normal: &Normal, lambda: f64) -> Option<[f64; PARAMS]> {
    let max_diag = (0..PARAMS).fold(0.0_f64, |m, i| m.max(normal.jtj[i][i]));
    let floor = max_diag * 1e-15 + f64::MIN_POSITIVE;
    let a = SMatrix::<f64, PARAMS, PARAMS>::from_fn(|i, j| {
        let (lo, hi) = if i <= j { (i, j) } else { (j, i) };
        let value = normal.jtj[lo][hi];
        if i == j {
            value + lambda * value.max(floor)
        } else {
            value
        }
    });
    let b = SVector::<f64, PARAMS>::from_fn(|i, _| normal.jtr[i]);
    let delta = a.cholesky()?.solve(&b);
    let mut out = [0.0; PARAMS];
    for (o, d) in out.iter_mut().zip(delta.iter()) {
        if !d.is_finite() {
            return None;
        }
        *o = *d;
    }
    Some(out)
}

/// Linear least squares for a1..a4 and a9 with a5..a8, a10 fixed (one exact step).
fn solve_linear(p: &mut [f64; PARAMS], data: &Data<'_>) -> bool {
    const LINEAR: [usize; 5] = [0, 1, 2, 3, 8];
    let normal = accumulate(p, data);
    let a = SMatrix::<f64, 5, 5>::from_fn(|i, j| {
        let (lo, hi) = (LINEAR[i.min(j)], LINEAR[i.max(j)]);
        normal.jtj[lo][hi]
    });
    let b = SVector::<f64, 5>::from_fn(|i, _| normal.jtr[LINEAR[i]]);
    let Some(delta) = a.lu().solve(&b) else {
        return false;
    };
    for (k, &index) in LINEAR.iter().enumerate() {
        p[index] += delta[k];
    }
    delta.iter().all(|d| d.is_finite())
}

/// Chooses the initial a5..a8, a10 and a9 from the pencil poles.
fn initial_guess(data: &Data<'_>, poles: &[pencil::Pole]) -> Result<[f64; PARAMS], FitError> {
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
            for b in 0..slots.len() {
                ata[a][b] += basis[a] * basis[b];
            }
        }
    }
    let used = slots.len();
    let a = SMatrix::<f64, MAX_BASIS, MAX_BASIS>::from_fn(|i, j| {
        if i < used && j < used {
            ata[i][j]
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
    let mut p = [0.0; PARAMS];
    p[4] = first.frequency_hz;
    p[5] = second.frequency_hz;
    p[6] = first.decay_per_s;
    p[7] = second.decay_per_s;
    p[9] = rise;
    if !solve_linear(&mut p, data) {
        return Err(FitError::Singular);
    }
    Ok(p)
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
    let mut scale = 0.0_f64;
    for &value in samples {
        if !value.is_finite() {
            return Err(FitError::NonFinite);
        }
        scale = scale.max(libm::fabs(value));
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
    let start = if decimation > 1 && coarse_used >= 4 * PARAMS {
        let initial = initial_guess(&coarse, &poles)?;
        levenberg_marquardt(initial, &coarse, coarse_used, options)?
    } else {
        let initial = initial_guess(&full, &poles)?;
        (initial, 0.0, 0, FitStatus::Converged)
    };
    let (params, rms, iterations, status) = levenberg_marquardt(start.0, &full, used, options)?;
    let iterations = iterations + start.2;
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
fn fitted_peak(p: &[f64; PARAMS], len: usize, dt: f64) -> Option<f64> {
    let mut mode1 = Rotor::new(p[6], p[4], dt);
    let mut mode2 = Rotor::new(p[7], p[5], dt);
    let load_step = libm::exp(-p[9] * dt);
    let mut load = 1.0;
    let mut peak = f64::NEG_INFINITY;
    for _ in 0..len {
        let value = p[0] * mode1.re
            + p[2] * mode1.im
            + p[1] * mode2.re
            + p[3] * mode2.im
            + p[8] * (1.0 - load);
        peak = peak.max(value);
        mode1.advance();
        mode2.advance();
        load *= load_step;
    }
    peak.is_finite().then_some(peak)
}

/// Damped Gauss-Newton iteration; returns (params, rms residual, iterations, status)
/// in scaled units.
fn levenberg_marquardt(
    mut params: [f64; PARAMS],
    data: &Data<'_>,
    used: usize,
    options: &FitOptions,
) -> Result<([f64; PARAMS], f64, u32, FitStatus), FitError> {
    const LAMBDA_MAX: f64 = 1e12;
    let mut normal = accumulate(&params, data);
    if !normal.cost.is_finite() {
        return Err(FitError::Diverged);
    }
    let mut lambda = 1e-3;
    let mut status = FitStatus::MaxIterations;
    let mut iterations = 0;
    'outer: while iterations < options.max_iterations {
        iterations += 1;
        if normal.cost == 0.0 {
            status = FitStatus::Converged;
            break;
        }
        loop {
            let Some(delta) = damped_step(&normal, lambda) else {
                lambda *= 10.0;
                if lambda > LAMBDA_MAX {
                    return Err(FitError::Singular);
                }
                continue;
            };
            // Near Gauss-Newton (small lambda), delta . J^T r estimates twice the cost
            // decrease the step can bring: when negligible, stop without another pass.
            let gain: f64 = delta
                .iter()
                .zip(normal.jtr.iter())
                .map(|(d, g)| d * g)
                .sum();
            if lambda <= 1e-2 && gain <= options.tolerance * normal.cost {
                status = FitStatus::Converged;
                break 'outer;
            }
            let mut trial = params;
            for (p, d) in trial.iter_mut().zip(delta.iter()) {
                *p += d;
            }
            let candidate = accumulate(&trial, data);
            if candidate.cost.is_finite() && candidate.cost < normal.cost {
                let decrease = (normal.cost - candidate.cost) / normal.cost;
                let small_step = delta
                    .iter()
                    .zip(trial.iter())
                    .all(|(d, p)| libm::fabs(*d) <= options.tolerance * (libm::fabs(*p) + 1e-6));
                params = trial;
                normal = candidate;
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
    let rms = libm::sqrt(normal.cost / used as f64);
    Ok((params, rms, iterations, status))
}
