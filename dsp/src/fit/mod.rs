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
//! needs two or three iterations on a record eq. (1) describes (Table 1's); a
//! driveline's bite, whose residual stays large (eq. (1) lacks the speed controller),
//! took 15 to 68 in all, median 20.5, on the simulated bites of docs/measured.md, the
//! tail sped up by the secant term of `levenberg_marquardt`. Where the fit ends with a
//! mode more than a factor 2 from the pencil's, it starts again on the full record
//! without the coarse pass and keeps the lower residual (see `far_from_start`). All work is done on data scaled to
//! a peak of 1, so huge inputs do not overflow, and a point whose least-squares cost
//! comes out above the record's own energy (what all-zero linear parameters leave: a
//! basis that grows by e^100 and more over the record leaves the solve no correct
//! digit) is rejected, so the fit never returns a residual larger than the record.
//!
//! The files follow those steps: `model` (eq. (1) and the public types), `record` (the
//! record as fitted, the nonlinear/linear split), `initial_guess` (pencil poles to a start),
//! `levenberg_marquardt` (the iteration, and the linear solve at each point it
//! visits), `gram` (the basis Gram matrix in closed form), `projection` (the one pass
//! over the samples per point) and `recurrence` (the rotors and two-lane arithmetic
//! they share).

mod gram;
mod initial_guess;
mod levenberg_marquardt;
mod model;
mod projection;
mod record;
mod recurrence;

use crate::linalg::{peak_magnitude, Precision};
use crate::pencil::{self, MIN_DECIMATED_SAMPLES};
use initial_guess::{best_rise, initial_guess};
use levenberg_marquardt::{evaluate, levenberg_marquardt, Evaluation, Pass, Solution};
pub use model::{eq1, Eq1Fit, FitError, FitOptions, FitStatus, PARAMS};
use record::{Data, Nonlinear, LINEAR_INDEX, NONLINEAR_INDEX};
use recurrence::{Pair, PairRotor, Rotor};

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
    check_options(options)?;
    let (scale, used) = check_samples(samples, options.positive_only)?;
    let rate = options.sample_rate_hz;
    let dt = 1.0 / rate;
    let decimation = (samples.len() / (2 * MIN_DECIMATED_SAMPLES))
        .min((rate / (4.0 * options.max_mode_hz)) as usize)
        .max(1);
    // The start's poles to a relative 1e-6, not to rounding: the iteration refines them.
    let poles = pencil::poles_at_scale(samples, rate, decimation, scale, Precision::Start)
        .map_err(|e| match e {
            pencil::PencilError::TooFewSamples => FitError::TooFewSamples,
            _ => FitError::Singular,
        })?;
    let full = Data::new(samples, 1, 1.0 / scale, dt, options.positive_only);
    let (start, coarse) = starting_point(samples, &full, &poles, decimation, scale, options)?;
    let (mut point, mut rms, mut iterations, mut status) =
        levenberg_marquardt(start, &full, used, options, Pass::Full)?;
    if let Some(coarse) = coarse {
        iterations += coarse.iterations;
        // The coarse pass can carry a mode out of the pencil's basin (through 0 Hz on
        // simulated bites of the Table 2 driveline, into a slow exponential that takes
        // up the speed controller's response): a second start on the full
        // record itself, the lower cost kept.
        if far_from_start(&point.theta, &coarse.guess) {
            if let Ok((second, second_rms, second_iterations, second_status)) =
                full_record_start(&full, &poles)
                    .and_then(|start| levenberg_marquardt(start, &full, used, options, Pass::Full))
            {
                iterations += second_iterations;
                if second.cost < point.cost {
                    (point, rms, status) = (second, second_rms, second_status);
                }
            }
        }
    }
    let params = unscaled_params(&point, scale);
    // The residual is at most the record's (evaluate rejects a cost above its
    // energy), so in the record's units it overflows only for a record within a few
    // ulps of f64::MAX.
    let rms_residual = rms * scale;
    if params.iter().any(|v| !v.is_finite()) || !rms_residual.is_finite() {
        return Err(FitError::Diverged);
    }
    let taf = fitted_peak(&params, samples.len(), dt)
        .filter(|_| params[8] > 0.0)
        .map(|peak| peak / params[8])
        .filter(|v| v.is_finite());
    Ok(Eq1Fit::new(
        params,
        taf,
        rms_residual,
        iterations,
        status,
        used,
    ))
}

/// Checks the options, field by field in their order.
fn check_options(options: &FitOptions) -> Result<(), FitError> {
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
    Ok(())
}

/// The record's peak magnitude (the fit's scale) and the number of samples fitted
/// (those above zero with `positive_only`), once the record is long enough, finite and
/// not all zero.
fn check_samples(samples: &[f64], positive_only: bool) -> Result<(f64, usize), FitError> {
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
    let used = if positive_only {
        samples.iter().filter(|&&v| v > 0.0).count()
    } else {
        samples.len()
    };
    if used < 2 * PARAMS {
        return Err(FitError::TooFewSamples);
    }
    Ok((scale, used))
}

/// The coarse pass that found the full record's starting point.
#[derive(Clone, Copy)]
struct CoarsePass {
    /// Where it started: the pencil's modes and the best load rate.
    guess: Nonlinear,
    /// Its iterations.
    iterations: u32,
}

/// The full record's starting point from the pencil `poles`, and the coarse pass that
/// found it, if one did.
///
/// Coarse pass: every `decimation`-th sample (at most the pencil's decimation, so the
/// modes stay well below the coarse Nyquist rate) converges cheaply; the full record
/// then needs only a few iterations. A record too short for it starts from the
/// initial guess on the full record.
fn starting_point(
    samples: &[f64],
    full: &Data<'_>,
    poles: &[pencil::Pole],
    decimation: usize,
    scale: f64,
    options: &FitOptions,
) -> Result<(Evaluation, Option<CoarsePass>), FitError> {
    let dt = full.dt;
    let coarse = Data::new(
        samples,
        decimation,
        1.0 / scale,
        dt * decimation as f64,
        options.positive_only,
    );
    let coarse_used = coarse.used();
    let (start, coarse_pass) = if decimation > 1 && coarse_used >= 4 * PARAMS {
        let initial = initial_guess(&coarse, poles)?;
        let initial = best_rise(initial, &coarse).ok_or(FitError::Singular)?;
        // The coarse optimum differs from the full one by the noise anyway (a relative
        // cost of about PARAMS / coarse_used): converging it further is wasted.
        let coarse_options = FitOptions {
            tolerance: options.tolerance.max(COARSE_TOLERANCE),
            ..*options
        };
        let (point, _, iterations, _) =
            levenberg_marquardt(initial, &coarse, coarse_used, &coarse_options, Pass::Coarse)?;
        let pass = CoarsePass {
            guess: initial.theta,
            iterations,
        };
        (point.theta, Some(pass))
    } else {
        (initial_guess(full, poles)?.theta, None)
    };
    let start = evaluate(start, full).ok_or(FitError::Singular)?;
    Ok((start, coarse_pass))
}

/// The start on the full record itself, without a coarse pass: the pencil's modes
/// and the best load rate, chosen on the full record.
fn full_record_start(full: &Data<'_>, poles: &[pencil::Pole]) -> Result<Evaluation, FitError> {
    best_rise(initial_guess(full, poles)?, full).ok_or(FitError::Singular)
}

/// Farthest a fitted mode's frequency may end from its start's, as a factor either
/// way, before the fit counts as gone [`far_from_start`]. The fits of the simulated
/// Table 2 bites that ended in the right minimum moved their first mode by a factor
/// 0.68 to 1.37 from the pencil's; the two that did not crossed 0 Hz.
const FAR_FROM_START: f64 = 2.0;

/// Whether either mode's frequency (a5, a6 of `end`) ended outside [1/2, 2] times its
/// start's (a5, a6 of `start`, both > 0), through 0 Hz included; also true for NaN.
fn far_from_start(end: &Nonlinear, start: &Nonlinear) -> bool {
    (0..2).any(|k| !(end[k] >= start[k] / FAR_FROM_START && end[k] <= start[k] * FAR_FROM_START))
}

/// The parameters a1..a10 of `point` in canonical order, in the record's units.
fn unscaled_params(point: &Solution, scale: f64) -> [f64; PARAMS] {
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
    params
}

/// Pairs of samples between two checks of [`fitted_peak`]'s bound.
const PEAK_CHECK_PAIRS: usize = 16;

/// Largest value of the fitted curve over `len` samples, by the same recurrences.
/// Each mode is one rotor started at its complex amplitude (a1 - i a3 for mode 1, so
/// its real part is a1 u1 + a3 v1) and the load term is advanced as a9 e10 directly;
/// even and odd samples run in the two lanes of a [`Pair`].
///
/// The scan stops early once no later sample can exceed the peak so far: with both
/// decays and a10 >= 0 the rotors' moduli (the modes' envelopes) only shrink and the
/// rise term stays below max(a9, its value now), so their sum bounds every later
/// sample. The peak of a transient comes in its first periods: at 2000 samples of
/// Table 1 the scan took 7 k instructions instead of 27 k (callgrind).
fn fitted_peak(p: &[f64; PARAMS], len: usize, dt: f64) -> Option<f64> {
    let mut mode1 = PairRotor::new(Rotor::new(p[6], p[4], dt), p[0], -p[2]);
    let mut mode2 = PairRotor::new(Rotor::new(p[7], p[5], dt), p[1], -p[3]);
    let load_step = libm::exp(-p[9] * dt);
    let mut load = Pair::new(p[8], p[8] * load_step);
    let load_step = Pair::splat(load_step * load_step);
    let static_torque = Pair::splat(p[8]);
    // Envelopes that only shrink (NaN compares false: no early stop).
    let bounded = p[6] >= 0.0 && p[7] >= 0.0 && p[9] >= 0.0;
    let mut peak = [f64::NEG_INFINITY; 2];
    let mut pairs = len / 2;
    while pairs > 0 {
        let block = pairs.min(PEAK_CHECK_PAIRS);
        for _ in 0..block {
            let value = mode1.re + mode2.re + (static_torque - load);
            mode1.advance();
            mode2.advance();
            load = load * load_step;
            for (peak, lane) in peak.iter_mut().zip(value.lanes()) {
                // A comparison, not f64::max: its NaN handling costs a branch per sample.
                if lane > *peak {
                    *peak = lane;
                }
            }
        }
        pairs -= block;
        if bounded
            && pairs > 0
            && bound(&mode1, &mode2, static_torque - load, p[8]) < peak[0].max(peak[1])
        {
            // The last sample of an odd record is beyond the bound too.
            return finite_peak(peak);
        }
    }
    if len % 2 == 1 {
        // The last sample is in the even lane.
        let [last, _] = (mode1.re + mode2.re + (static_torque - load)).lanes();
        if last > peak[0] {
            peak[0] = last;
        }
    }
    finite_peak(peak)
}

/// The larger lane of `peak`, when finite.
fn finite_peak(peak: [f64; 2]) -> Option<f64> {
    let peak = if peak[1] > peak[0] { peak[1] } else { peak[0] };
    peak.is_finite().then_some(peak)
}

/// Upper bound of every later sample of [`fitted_peak`]'s curve (non-negative decays
/// and load rate): the rotors' moduli plus the larger of a9 and the rise term now,
/// raised by a relative 1e-9 for the recurrences' rounding.
fn bound(mode1: &PairRotor, mode2: &PairRotor, rise: Pair, static_torque: f64) -> f64 {
    let modulus = |rotor: &PairRotor| {
        let squares = rotor.re * rotor.re + rotor.im * rotor.im;
        let [even, odd] = squares.lanes();
        libm::sqrt(even.max(odd))
    };
    let [even, odd] = rise.lanes();
    let envelope = modulus(mode1) + modulus(mode2);
    let rise = static_torque.max(even).max(odd);
    envelope + rise + 1e-9 * (envelope + libm::fabs(rise))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) const TABLE1: [f64; PARAMS] = [
        -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
    ];

    /// Fill `samples` with Table 1's transient sampled at `rate` plus deterministic
    /// uniform noise of RMS about 2% of a9 (an LCG continued from `state`).
    pub(crate) fn noisy_table1(samples: &mut [f64], rate: f64, state: &mut u64) {
        for (i, v) in samples.iter_mut().enumerate() {
            *state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            let uniform = (*state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            *v = eq1(&TABLE1, i as f64 / rate) + 7.8 * uniform;
        }
    }

    /// A record of a constant has no oscillating mode: the pencil's two "modes" are
    /// noise of the rounding, one at times growing e^188 over the record, and the
    /// solve on such a basis lost every digit (a "converged" residual 1e74 times the
    /// record's, infinite on a record of 1e300: issue 28). A fit may fail here, but
    /// its residual is never above the record's RMS.
    #[test]
    fn constant_records_give_no_residual_above_the_record() {
        let mut fitted = 0;
        for value in [1.0, 1e300] {
            for len in 20..400 {
                for positive_only in [false, true] {
                    let samples = [value; 400];
                    let options = FitOptions {
                        positive_only,
                        ..FitOptions::new(1000.0)
                    };
                    if let Ok(fit) = fit_eq1(&samples[..len], &options) {
                        fitted += 1;
                        assert!(
                            fit.rms_residual <= value * (1.0 + 1e-6),
                            "{len} samples of {value} (positive only: {positive_only}): \
                             residual {}",
                            fit.rms_residual
                        );
                    }
                }
            }
        }
        // Not all refused: the guard rejects lost solves, not constant records.
        assert!(fitted > 100, "{fitted} fits");
    }

    /// The coarse pass's last step taken without its pass ([`Pass::Coarse`]) against
    /// the coarse pass run to its tolerance with every step evaluated ([`Pass::Full`]),
    /// on noisy Table 1 records of 500 and 2000 samples: the coarse run ends earlier,
    /// its point is within the coarse record's noise of the other's, and the full
    /// record converges to the same point from either start.
    #[test]
    fn coarse_last_step_without_its_pass_reaches_the_same_fit() {
        let mut state = 0x5851_f42d_4c95_7f2d_u64;
        let mut skipped = 0;
        for len in [500, 2000] {
            for _ in 0..10 {
                let mut samples = [0.0_f64; 2000];
                let rate = len as f64 / 0.5;
                noisy_table1(&mut samples[..len], rate, &mut state);
                let samples = &samples[..len];
                let options = FitOptions::new(rate);
                let (scale, _) = peak_magnitude(samples);
                let decimation = (len / (2 * MIN_DECIMATED_SAMPLES))
                    .min((rate / (4.0 * options.max_mode_hz)) as usize);
                let poles =
                    pencil::poles_at_scale(samples, rate, decimation, scale, Precision::Start)
                        .unwrap();
                let dt = 1.0 / rate;
                let coarse = Data::new(
                    samples,
                    decimation,
                    1.0 / scale,
                    dt * decimation as f64,
                    false,
                );
                let full = Data::new(samples, 1, 1.0 / scale, dt, false);
                let start = best_rise(initial_guess(&coarse, &poles).unwrap(), &coarse).unwrap();
                let coarse_options = FitOptions {
                    tolerance: COARSE_TOLERANCE,
                    ..options
                };
                let run = |pass| {
                    levenberg_marquardt(start, &coarse, coarse.used(), &coarse_options, pass)
                        .unwrap()
                };
                let (quick, _, quick_iterations, _) = run(Pass::Coarse);
                let (verified, _, verified_iterations, _) = run(Pass::Full);
                assert!(quick_iterations <= verified_iterations);
                if quick_iterations < verified_iterations {
                    skipped += 1;
                    // The point reached without the last pass is within the coarse
                    // record's noise (a relative cost of PARAMS / samples used) of
                    // the coarse optimum every step of which was evaluated.
                    let checked = evaluate(quick.theta, &coarse).unwrap();
                    let noise = PARAMS as f64 / coarse.used() as f64;
                    assert!(
                        checked.cost <= verified.cost * (1.0 + noise),
                        "{len}: {} vs {}",
                        checked.cost,
                        verified.cost
                    );
                }
                let finish = |theta| {
                    let start = evaluate(theta, &full).unwrap();
                    levenberg_marquardt(start, &full, len, &options, Pass::Full)
                        .unwrap()
                        .0
                };
                let (from_quick, from_verified) = (finish(quick.theta), finish(verified.theta));
                for k in 0..5 {
                    let (a, b) = (from_quick.theta[k], from_verified.theta[k]);
                    assert!(
                        libm::fabs(a - b) <= 1e-5 * libm::fabs(b),
                        "{len} theta {k}: {a} vs {b}"
                    );
                }
            }
        }
        // The rule is not dead: it ends the coarse pass early on these records.
        assert!(skipped >= 10, "{skipped} of 20 coarse passes ended early");
    }

    /// The scan's early stop against the full scan: peaks early and late, a negative
    /// a9, slow and undamped modes, growing ones (no early stop), odd lengths.
    #[test]
    fn fitted_peak_stops_early_only_past_the_peak() {
        let dt = 1e-3;
        let mut cases = [TABLE1; 8];
        // Slow rise: the peak is the last sample.
        cases[1][9] = 0.5;
        // Negative static torque.
        cases[2][8] = -112.0;
        // Undamped mode 2: the bound never falls below the peak.
        cases[3][7] = 0.0;
        // Growing mode 1: no early stop.
        cases[4][6] = -3.0;
        // A late beat of two close modes.
        cases[5][4] = 20.0;
        cases[5][6] = 0.5;
        cases[5][7] = 0.5;
        // Tiny oscillations on a fast rise: the peak is late, near a9.
        cases[6][0] = 1e-3;
        cases[6][1] = -1e-3;
        cases[6][9] = 200.0;
        // A load that falls (a9 < 0) with slow oscillations.
        cases[7][8] = -5.0;
        cases[7][6] = 1.0;
        for params in cases {
            for len in [11, 64, 499, 500, 2001] {
                let expected = (0..len)
                    .map(|i| eq1(&params, i as f64 * dt))
                    .fold(f64::NEG_INFINITY, f64::max);
                let peak = fitted_peak(&params, len, dt).unwrap();
                assert!(
                    libm::fabs(peak - expected) <= 1e-10 * libm::fabs(expected),
                    "{params:?} {len}: {peak} vs {expected}"
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
}
