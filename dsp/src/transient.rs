//! Transient analysis of one bite window: static torque, peak, TAF and oscillation periods.
//!
//! Estimators (all torques relative to the baseline handed in, kN*m; t = 0 at the trigger
//! sample):
//! - **static torque**: mean of the last `settled_fraction` of the window. Simple and
//!   unbiased once the fast mode has decayed; the residual of a slow mode averages out
//!   over several of its periods. When an eq. (1) fit is available its `a9` is the
//!   better estimate (see [`crate::fit`]).
//! - **peak torque**: maximum after the trigger of the signal low-passed at
//!   `peak_lowpass_hz` (zero-phase, so the peak is not delayed; set it 2-3x above the
//!   highest driveline mode to remove noise without cutting the peak), or of the raw
//!   samples when `None`.
//! - **TAF** = peak / static, `None` when the static torque is below `min_static_knm`.
//! - **periods**, measured on the oscillation *about the rising load*, not about the
//!   final level:
//!   1. *Trend.* The load rise M (1 - exp(-r t)) drives a linear driveline into a
//!      forced response of the same form, `a + b exp(-r t)` (any onset delay is absorbed
//!      in `b`), on which the free oscillations ride. That trend is fitted to the samples
//!      from the trigger to the end by least squares: `a`, `b` in closed form for each
//!      `r`, and `r` by a 1-D search (log grid, then Brent's method) over
//!      [1 / window length, 2 pi `period_lowpass_hz`] 1/s. When the load rises in tens of
//!      milliseconds, as in the paper (27 ms against an 83 ms first period), the signal
//!      mean is still moving during the first oscillation: crossings of the *final*
//!      level then skip or add half-cycles and the first period is meaningless.
//!   2. *Filter.* The detrended samples (from the trigger on) are low-passed at
//!      `period_lowpass_hz` (second-order Butterworth run forward and backward: zero
//!      phase, so crossings are not delayed). Set the cut-off above the mode whose
//!      periods are wanted and below the next one; the periods are those of the
//!      dominant oscillation left by the filter. Two modes closer than ~1 / (window
//!      length) cannot be split by a filter without smearing the first period, so a
//!      weaker mode under a stronger one beats and biases the shift; that bias is what
//!      `reference_shift_s` (the linear model's shift) removes.
//!   3. *Crossings.* Up-crossings of zero by the filtered oscillation, linearly
//!      interpolated between samples. The first is reported as `rise_time_s`; the first
//!      period runs from it to the second up-crossing, the second period to the third.
//!      For a linear driveline both equal the period of the dominant mode; with an open
//!      gap the coupling is soft while the gap closes and the first period is longer.
//! - **first-period shift** = first - second period, and minus a linear-model reference
//!   shift when one is given: the wear index of the domain notes (section 1.3).

use core::f64::consts::{FRAC_1_SQRT_2, PI};

use crate::filter::Biquad;

/// Settings of [`analyze`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransientSettings {
    /// Sample rate, Hz, finite and > 0.
    pub sample_rate_hz: f64,
    /// Cut-off of the low-pass used for period measurement, Hz, in (0, 0.45 fs).
    pub period_lowpass_hz: f64,
    /// Cut-off of the low-pass applied before taking the peak, Hz, in (0, 0.45 fs), or
    /// `None` for the raw peak.
    pub peak_lowpass_hz: Option<f64>,
    /// Fraction of the window (from its end) averaged for the static torque, in (0, 1].
    pub settled_fraction: f64,
    /// Smallest static torque for which TAF is computed, kN*m, finite and > 0.
    pub min_static_knm: f64,
    /// First-period shift of the linear model, s, to compare against (finite) or `None`.
    pub reference_shift_s: Option<f64>,
}

/// Invalid setting or input of [`analyze`]; the variant names the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransientError {
    /// `sample_rate_hz` is not finite and > 0.
    SampleRateHz,
    /// `period_lowpass_hz` is outside (0, 0.45 fs).
    PeriodLowpassHz,
    /// `peak_lowpass_hz` is outside (0, 0.45 fs).
    PeakLowpassHz,
    /// `settled_fraction` is outside (0, 1].
    SettledFraction,
    /// `min_static_knm` is not finite and > 0.
    MinStaticKnm,
    /// `reference_shift_s` is not finite.
    ReferenceShiftS,
    /// The window has fewer than 4 samples after the trigger, or more than `N` samples.
    WindowLength,
    /// `trigger_index` is not inside the window.
    TriggerIndex,
    /// `baseline_knm` or a window sample is NaN or infinite, or so large that the
    /// static level or the peak overflows.
    NonFinite,
}

impl core::fmt::Display for TransientError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            TransientError::SampleRateHz => "sample_rate_hz must be finite and > 0 Hz",
            TransientError::PeriodLowpassHz => "period_lowpass_hz must be in (0, 0.45 x the sample rate) Hz",
            TransientError::PeakLowpassHz => "peak_lowpass_hz must be in (0, 0.45 x the sample rate) Hz",
            TransientError::SettledFraction => "settled_fraction must be in (0, 1]",
            TransientError::MinStaticKnm => "min_static_knm must be finite and > 0 kN*m",
            TransientError::ReferenceShiftS => "reference_shift_s must be finite",
            TransientError::WindowLength => "the window needs at least 4 samples after the trigger and at most its capacity",
            TransientError::TriggerIndex => "trigger_index is not inside the window",
            TransientError::NonFinite => "the baseline or a window sample is NaN or infinite, or so large that the static level or the peak overflows",
        })
    }
}

impl core::error::Error for TransientError {}

/// Quality of a [`TransientResult`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransientQuality {
    /// All quantities were measured.
    Good,
    /// Fewer than three up-crossings of the oscillation about the trend: periods missing.
    FewCrossings,
    /// Static torque below `min_static_knm`: TAF and periods not measured.
    LowStatic,
}

/// Result of [`analyze`]; torques in kN*m relative to the baseline, times in s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransientResult {
    /// Settled torque, kN*m.
    pub static_torque_knm: f64,
    /// Peak torque after the trigger, kN*m.
    pub peak_torque_knm: f64,
    /// Time of the peak after the trigger sample, s.
    pub peak_time_s: f64,
    /// Torque amplification factor peak / static, when the static torque is large enough.
    pub taf: Option<f64>,
    /// Time after the trigger of the first up-crossing of the oscillation about the load
    /// trend, s: where the first period starts.
    pub rise_time_s: Option<f64>,
    /// First oscillation period after the bite, s.
    pub first_period_s: Option<f64>,
    /// Second oscillation period, s.
    pub second_period_s: Option<f64>,
    /// First minus second period, s.
    pub period_shift_s: Option<f64>,
    /// Period shift minus the reference (linear model) shift, s.
    pub shift_excess_s: Option<f64>,
    /// Quality of the measurement.
    pub quality: TransientQuality,
}

/// Zero-phase second-order Butterworth low-pass of `data` in place (the caller has
/// checked `cutoff_hz` against the sample rate, so the section always exists).
fn lowpass_filtfilt(data: &mut [f64], cutoff_hz: f64, sample_rate_hz: f64) {
    if let Ok(section) = Biquad::lowpass(cutoff_hz, sample_rate_hz, FRAC_1_SQRT_2) {
        section.filtfilt(data);
    }
}

/// Load-rise trend `level + amplitude * exp(-rate * t)` of the samples after the trigger.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LoadTrend {
    /// Level the trend tends to, kN*m.
    level: f64,
    /// Trend at t = 0 minus `level`, kN*m.
    amplitude: f64,
    /// exp(-rate / sample rate): the exponential's ratio from one sample to the next.
    ratio: f64,
}

/// Points of the log grid of rates searched before the refinement ([`brent_minimum`]).
const TREND_GRID: usize = 48;
/// Most residuals [`brent_minimum`] evaluates (a golden section alone would shrink the
/// bracket by 0.618^40, about 4e-9, in as many).
const TREND_REFINE: usize = 40;
/// Relative tolerance of [`brent_minimum`] on log(rate): about the square root of the
/// double's precision, below which a minimum's residual no longer tells points apart.
const TREND_TOLERANCE: f64 = 3e-8;
/// Absolute tolerance of [`brent_minimum`] near log(rate) = 0.
const TREND_TOLERANCE_ABS: f64 = 1e-10;

impl LoadTrend {
    /// Least-squares fit to `samples - baseline_knm` (spacing `dt` s) for rates in
    /// [1 / (samples.len() dt), 2 pi `cutoff_hz`] 1/s; the plain mean when no rate in that
    /// range separates from a constant (e.g. a flat or very short record).
    fn fit(samples: &[f64], baseline_knm: f64, dt: f64, cutoff_hz: f64) -> Self {
        let count = samples.len() as f64;
        let mean = samples.iter().map(|v| v - baseline_knm).sum::<f64>() / count;
        // The centred samples' sum of squares does not depend on the rate.
        let offset = baseline_knm + mean;
        let sum_yy: f64 = samples.iter().map(|v| (v - offset) * (v - offset)).sum();
        let flat = Self {
            level: mean,
            amplitude: 0.0,
            ratio: 1.0,
        };
        let rate_low = 1.0 / (count * dt);
        let rate_high = 2.0 * PI * cutoff_hz;
        if rate_high.is_nan() || rate_high <= rate_low {
            return flat;
        }
        // Work on log(rate): the grid and the bracket are uniform in it.
        let (log_low, log_high) = (libm::log(rate_low), libm::log(rate_high));
        let step = (log_high - log_low) / (TREND_GRID - 1) as f64;
        let cost = |log_rate: f64| Self::solve(samples, offset, mean, sum_yy, dt, log_rate);
        let mut best: Option<(usize, f64)> = None;
        for index in 0..TREND_GRID {
            if let Some((_, residual)) = cost(log_low + step * index as f64) {
                if best.is_none_or(|(_, r)| residual < r) {
                    best = Some((index, residual));
                }
            }
        }
        let Some((index, _)) = best else {
            return flat;
        };
        // Brent's minimisation inside the grid neighbours of the best point.
        let low = log_low + step * index.saturating_sub(1) as f64;
        let high = log_low + step * (index + 1).min(TREND_GRID - 1) as f64;
        let residual = |log_rate: f64| cost(log_rate).map_or(f64::INFINITY, |(_, r)| r);
        let log_rate = brent_minimum(residual, low, high);
        match cost(log_rate) {
            Some((trend, _)) if trend.level.is_finite() && trend.amplitude.is_finite() => trend,
            _ => flat,
        }
    }

    /// The trend fitted to the moving average of `samples - baseline_knm` over one
    /// oscillation period `period_s` (s), which cancels that oscillation but keeps the
    /// trend's form: the average of `a + b q^k` over k = j .. j + L - 1 is
    /// `a + b q^j (1 - q^L) / (L (1 - q))`. `None` if fewer than 4 averages fit in the
    /// record. `scratch` (at least `samples.len()` long) holds the averages.
    fn fit_averaged(
        samples: &[f64],
        baseline_knm: f64,
        dt: f64,
        cutoff_hz: f64,
        period_s: f64,
        scratch: &mut [f64],
    ) -> Option<Self> {
        let length = libm::round(period_s / dt);
        if !(length >= 2.0 && length <= (samples.len() - 4) as f64) {
            return None;
        }
        let length = length as usize;
        let averages = samples.len() - length + 1;
        let mut sum: f64 = samples[..length].iter().map(|v| v - baseline_knm).sum();
        scratch[0] = sum / length as f64;
        for j in 1..averages {
            sum += samples[j + length - 1] - samples[j - 1];
            scratch[j] = sum / length as f64;
        }
        let averaged = Self::fit(&scratch[..averages], 0.0, dt, cutoff_hz);
        let ratio = averaged.ratio;
        let gain = if ratio < 1.0 {
            (1.0 - libm::pow(ratio, length as f64)) / (length as f64 * (1.0 - ratio))
        } else {
            1.0
        };
        Some(Self {
            level: averaged.level,
            amplitude: averaged.amplitude / gain,
            ratio,
        })
    }

    /// Closed-form least squares of the level and amplitude at rate exp(`log_rate`):
    /// the trend and its residual sum of squares, `None` when the exponential is
    /// indistinguishable from a constant over the record. `offset` is the baseline plus
    /// `mean` (the samples' mean above it), `sum_yy` the centred samples' sum of squares.
    ///
    /// Centred regression on e_k = ratio^k: slope = sum(y_c e) / sum(e_c^2). The sums of
    /// e and e^2 are geometric series, taken in closed form (`expm1` keeps a ratio near
    /// 1 exact); only sum(y_c e) runs over the samples ([`weighted_sum`]), and it stops
    /// where ratio^k has fallen below 2^-64 of the first weight. The search calls this
    /// about 90 times per fit, so it is most of a bite's analysis.
    fn solve(
        samples: &[f64],
        offset: f64,
        mean: f64,
        sum_yy: f64,
        dt: f64,
        log_rate: f64,
    ) -> Option<(Self, f64)> {
        let step = libm::exp(log_rate) * dt;
        let ratio = libm::exp(-step);
        let count = samples.len() as f64;
        let sum_e = libm::expm1(-step * count) / libm::expm1(-step);
        let sum_ee = libm::expm1(-2.0 * step * count) / libm::expm1(-2.0 * step);
        let spread = sum_ee - sum_e * sum_e / count;
        if spread.is_nan() || spread <= 1e-9 * count {
            return None;
        }
        // ratio^k < 2^-64 from k = 64 ln 2 / step on (also for an infinite step).
        let terms = libm::ceil(WEIGHT_FLOOR_LN / step);
        let terms = if terms < count {
            terms as usize
        } else {
            samples.len()
        };
        let sum_ye = weighted_sum(&samples[..terms], offset, ratio);
        let amplitude = sum_ye / spread;
        let level = mean - amplitude * sum_e / count;
        let residual = (sum_yy - amplitude * sum_ye).max(0.0);
        Some((
            Self {
                level,
                amplitude,
                ratio,
            },
            residual,
        ))
    }
}

/// The minimum of `f` on [`low`, `high`] by Brent's method (R. P. Brent, *Algorithms for
/// Minimization without Derivatives*, 1973, ch. 5): a parabola through the three best
/// points where it steps inside the bracket and shrinks it fast enough, a golden-section
/// step otherwise. On the trend's residual, smooth in log(rate), it takes about a third
/// of the golden section's evaluations for the same point. Written out here because the
/// crate has no heap and no `std`; the optimisers of the crates we know need one or the
/// other. `f` may give infinity (no trend at that rate): the parabola is then skipped.
fn brent_minimum(mut f: impl FnMut(f64) -> f64, low: f64, high: f64) -> f64 {
    // 1 - 1 / golden ratio: the golden section's step into the larger part.
    let golden = 0.5 * (3.0 - libm::sqrt(5.0));
    let (mut a, mut b) = (low, high);
    let mut x = a + golden * (b - a);
    let (mut w, mut v) = (x, x);
    let mut fx = f(x);
    let (mut fw, mut fv) = (fx, fx);
    // The last step and the one before it.
    let (mut step, mut previous) = (0.0_f64, 0.0_f64);
    for _ in 0..TREND_REFINE {
        let middle = 0.5 * (a + b);
        let tolerance = TREND_TOLERANCE * libm::fabs(x) + TREND_TOLERANCE_ABS;
        if libm::fabs(x - middle) <= 2.0 * tolerance - 0.5 * (b - a) {
            break;
        }
        let mut golden_step = true;
        if libm::fabs(previous) > tolerance && fx.is_finite() && fw.is_finite() && fv.is_finite() {
            let r = (x - w) * (fx - fv);
            let q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            let mut q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            }
            q = libm::fabs(q);
            // Inside the bracket, and less than half the step before last.
            if libm::fabs(p) < libm::fabs(0.5 * q * previous) && p > q * (a - x) && p < q * (b - x)
            {
                previous = step;
                step = p / q;
                let u = x + step;
                if u - a < 2.0 * tolerance || b - u < 2.0 * tolerance {
                    step = libm::copysign(tolerance, middle - x);
                }
                golden_step = false;
            }
        }
        if golden_step {
            previous = if x >= middle { a - x } else { b - x };
            step = golden * previous;
        }
        let u = if libm::fabs(step) >= tolerance {
            x + step
        } else {
            x + libm::copysign(tolerance, step)
        };
        let fu = f(u);
        if fu <= fx {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    x
}

/// ln(2^64): the trend's weights below 2^-64 of the first are left out of its sums.
const WEIGHT_FLOOR_LN: f64 = 64.0 * core::f64::consts::LN_2;

/// Sum of `(values[k] - offset) * ratio^k`, in [`LANES`] interleaved lanes so that the
/// multiplications by the ratio and the additions do not wait on one another.
fn weighted_sum(values: &[f64], offset: f64, ratio: f64) -> f64 {
    let mut weights = [1.0; LANES];
    for lane in 1..LANES {
        weights[lane] = weights[lane - 1] * ratio;
    }
    let stride = weights[LANES - 1] * ratio;
    let mut sums = [0.0_f64; LANES];
    let mut chunks = values.chunks_exact(LANES);
    for chunk in &mut chunks {
        for lane in 0..LANES {
            sums[lane] += (chunk[lane] - offset) * weights[lane];
            weights[lane] *= stride;
        }
    }
    let tail: f64 = chunks
        .remainder()
        .iter()
        .zip(weights)
        .map(|(value, weight)| (value - offset) * weight)
        .sum();
    sums.iter().sum::<f64>() + tail
}

/// Lanes of [`weighted_sum`]: enough independent chains to keep two floating-point
/// units busy through their latency.
const LANES: usize = 8;

/// Up-crossings of zero (s after the first sample, at most three, and how many) by
/// `samples - baseline_knm - trend`, low-passed at `cutoff_hz` into `scratch`.
fn crossings_about(
    samples: &[f64],
    baseline_knm: f64,
    trend: &LoadTrend,
    scratch: &mut [f64],
    rate: f64,
    cutoff_hz: f64,
) -> ([f64; 3], usize) {
    let oscillation = &mut scratch[..samples.len()];
    let mut decay = 1.0;
    for (out, &value) in oscillation.iter_mut().zip(samples) {
        *out = value - baseline_knm - (trend.level + trend.amplitude * decay);
        decay *= trend.ratio;
    }
    lowpass_filtfilt(oscillation, cutoff_hz, rate);
    let dt = 1.0 / rate;
    let mut crossings = [0.0_f64; 3];
    let mut found = 0;
    let mut previous = oscillation[0];
    for (offset, &current) in oscillation[1..].iter().enumerate() {
        if previous < 0.0 && current >= 0.0 {
            let fraction = previous / (previous - current);
            crossings[found] = (offset as f64 + fraction) * dt;
            found += 1;
            if found == crossings.len() {
                break;
            }
        }
        previous = current;
    }
    (crossings, found)
}

fn check_cutoff(cutoff: f64, rate: f64, error: TransientError) -> Result<f64, TransientError> {
    if cutoff.is_finite() && cutoff > 0.0 && cutoff < 0.45 * rate {
        Ok(cutoff)
    } else {
        Err(error)
    }
}

/// Analyses one window (kN*m) whose trigger sample is `window[trigger_index]`.
///
/// `N` is the capacity of the internal filter buffer (`window.len() <= N`); no heap is
/// used. `baseline_knm` is subtracted from every sample (use the detector's baseline).
///
/// ```
/// use millgate_dsp::transient::{analyze, TransientSettings};
/// let fs = 1000.0;
/// let window: Vec<f64> = (0..800)
///     .map(|i| {
///         let t = i as f64 / fs;
///         // Load rising at 36.7/s (paper Table 1) with a lightly damped 10 Hz oscillation.
///         100.0 * (1.0 - (-36.7 * t).exp())
///             + 20.0 * (-10.0 * t).exp() * (2.0 * std::f64::consts::PI * 10.0 * t + 2.0).sin()
///     })
///     .collect();
/// let settings = TransientSettings {
///     sample_rate_hz: fs, period_lowpass_hz: 40.0, peak_lowpass_hz: None,
///     settled_fraction: 0.3, min_static_knm: 1.0, reference_shift_s: None,
/// };
/// let result = analyze::<1024>(&window, 0, 0.0, &settings).unwrap();
/// assert!((result.static_torque_knm - 100.0).abs() < 0.5);
/// assert!((result.first_period_s.unwrap() - 0.1).abs() < 0.005);
/// assert!((result.second_period_s.unwrap() - 0.1).abs() < 0.005);
/// ```
pub fn analyze<const N: usize>(
    window: &[f64],
    trigger_index: usize,
    baseline_knm: f64,
    settings: &TransientSettings,
) -> Result<TransientResult, TransientError> {
    let cutoffs = check_settings(settings)?;
    check_window::<N>(window, trigger_index, baseline_knm)?;
    let rate = settings.sample_rate_hz;
    let mut buffer = [0.0_f64; N];
    let data = &mut buffer[..window.len()];
    for (out, &value) in data.iter_mut().zip(window) {
        *out = value - baseline_knm;
    }
    let static_torque_knm = settled_mean(data, settings.settled_fraction, trigger_index);
    let (peak_offset, peak_torque_knm) = peak_after(data, trigger_index, cutoffs.peak, rate);
    if !static_torque_knm.is_finite() || !peak_torque_knm.is_finite() {
        // Samples near f64::MAX overflow the mean or the filter.
        return Err(TransientError::NonFinite);
    }
    let dt = 1.0 / rate;
    let mut result = TransientResult {
        static_torque_knm,
        peak_torque_knm,
        peak_time_s: peak_offset as f64 * dt,
        taf: None,
        rise_time_s: None,
        first_period_s: None,
        second_period_s: None,
        period_shift_s: None,
        shift_excess_s: None,
        quality: TransientQuality::LowStatic,
    };
    if static_torque_knm < settings.min_static_knm {
        return Ok(result);
    }
    let taf = peak_torque_knm / static_torque_knm;
    result.taf = taf.is_finite().then_some(taf);
    let scratch = &mut data[trigger_index..];
    let (crossings, found) = oscillation_crossings(
        &window[trigger_index..],
        baseline_knm,
        scratch,
        rate,
        cutoffs.period,
    );
    set_periods(&mut result, crossings, found, settings.reference_shift_s);
    Ok(result)
}

/// The checked low-pass cutoffs of the settings, Hz.
struct Cutoffs {
    period: f64,
    peak: Option<f64>,
}

/// Checks the settings, field by field in their order.
fn check_settings(settings: &TransientSettings) -> Result<Cutoffs, TransientError> {
    let rate = settings.sample_rate_hz;
    if !(rate.is_finite() && rate > 0.0) {
        return Err(TransientError::SampleRateHz);
    }
    let period = check_cutoff(
        settings.period_lowpass_hz,
        rate,
        TransientError::PeriodLowpassHz,
    )?;
    let peak = match settings.peak_lowpass_hz {
        Some(cutoff) => Some(check_cutoff(cutoff, rate, TransientError::PeakLowpassHz)?),
        None => None,
    };
    if !(settings.settled_fraction > 0.0 && settings.settled_fraction <= 1.0) {
        return Err(TransientError::SettledFraction);
    }
    if !(settings.min_static_knm.is_finite() && settings.min_static_knm > 0.0) {
        return Err(TransientError::MinStaticKnm);
    }
    if settings.reference_shift_s.is_some_and(|s| !s.is_finite()) {
        return Err(TransientError::ReferenceShiftS);
    }
    Ok(Cutoffs { period, peak })
}

/// Checks the window: at most `N` finite samples, at least 4 from the trigger on.
fn check_window<const N: usize>(
    window: &[f64],
    trigger_index: usize,
    baseline_knm: f64,
) -> Result<(), TransientError> {
    if window.len() > N {
        return Err(TransientError::WindowLength);
    }
    if trigger_index >= window.len() {
        return Err(TransientError::TriggerIndex);
    }
    if window.len() - trigger_index < 4 {
        return Err(TransientError::WindowLength);
    }
    if !baseline_knm.is_finite() || window.iter().any(|v| !v.is_finite()) {
        return Err(TransientError::NonFinite);
    }
    Ok(())
}

/// Static torque: the mean of the settled tail (`settled_fraction` of the window, at
/// least one sample, none before the trigger).
fn settled_mean(data: &[f64], settled_fraction: f64, trigger_index: usize) -> f64 {
    let len = data.len();
    let tail = ((len as f64 * settled_fraction) as usize).clamp(1, len - trigger_index);
    data[len - tail..].iter().sum::<f64>() / tail as f64
}

/// The peak after the trigger (its offset from the trigger and its value), on the
/// signal low-passed at `cutoff_hz` in place when given.
fn peak_after(
    data: &mut [f64],
    trigger_index: usize,
    cutoff_hz: Option<f64>,
    rate: f64,
) -> (usize, f64) {
    if let Some(cutoff) = cutoff_hz {
        lowpass_filtfilt(data, cutoff, rate);
    }
    data[trigger_index..]
        .iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |best, (i, &v)| {
            if v > best.1 {
                (i, v)
            } else {
                best
            }
        })
}

/// Up-crossings of the oscillation about the fitted load-rise trend in `post` (the
/// window from the trigger on): a first pass on the raw samples gives the period, the
/// second fits the trend to their one-period moving average, where the oscillation no
/// longer pulls it.
fn oscillation_crossings(
    post: &[f64],
    baseline_knm: f64,
    scratch: &mut [f64],
    rate: f64,
    cutoff_hz: f64,
) -> ([f64; 3], usize) {
    let dt = 1.0 / rate;
    let raw_trend = LoadTrend::fit(post, baseline_knm, dt, cutoff_hz);
    let (crossings, found) =
        crossings_about(post, baseline_knm, &raw_trend, scratch, rate, cutoff_hz);
    if found < 2 {
        return (crossings, found);
    }
    let period_s = (crossings[found - 1] - crossings[0]) / (found - 1) as f64;
    match LoadTrend::fit_averaged(post, baseline_knm, dt, cutoff_hz, period_s, scratch) {
        Some(trend) => crossings_about(post, baseline_knm, &trend, scratch, rate, cutoff_hz),
        None => (crossings, found),
    }
}

/// The rise time, periods and shift from the first `found` up-crossings (s), and the
/// quality they allow.
fn set_periods(
    result: &mut TransientResult,
    crossings: [f64; 3],
    found: usize,
    reference_shift_s: Option<f64>,
) {
    result.rise_time_s = (found >= 1).then_some(crossings[0]);
    if found < 3 {
        result.quality = TransientQuality::FewCrossings;
        if found == 2 {
            result.first_period_s = Some(crossings[1] - crossings[0]);
        }
        return;
    }
    let first = crossings[1] - crossings[0];
    let second = crossings[2] - crossings[1];
    let shift = first - second;
    result.first_period_s = Some(first);
    result.second_period_s = Some(second);
    result.period_shift_s = Some(shift);
    result.shift_excess_s = reference_shift_s.map(|reference| shift - reference);
    result.quality = TransientQuality::Good;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> TransientSettings {
        TransientSettings {
            sample_rate_hz: 1000.0,
            period_lowpass_hz: 40.0,
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: 1.0,
            reference_shift_s: Some(0.0),
        }
    }

    /// The trend's least squares at one rate by the plain sums over every sample, as
    /// written in the regression (the oracle for [`LoadTrend::solve`]'s closed forms).
    fn solve_directly(samples: &[f64], dt: f64, log_rate: f64) -> Option<(LoadTrend, f64)> {
        let count = samples.len() as f64;
        let mean = samples.iter().sum::<f64>() / count;
        let ratio = libm::exp(-libm::exp(log_rate) * dt);
        let (mut sum_e, mut sum_ee, mut sum_ye, mut sum_yy) = (0.0, 0.0, 0.0, 0.0);
        let mut e = 1.0;
        for &value in samples {
            let centred = value - mean;
            sum_e += e;
            sum_ee += e * e;
            sum_ye += centred * e;
            sum_yy += centred * centred;
            e *= ratio;
        }
        let spread = sum_ee - sum_e * sum_e / count;
        if spread <= 1e-9 * count {
            return None;
        }
        let amplitude = sum_ye / spread;
        let trend = LoadTrend {
            level: mean - amplitude * sum_e / count,
            amplitude,
            ratio,
        };
        Some((trend, (sum_yy - amplitude * sum_ye).max(0.0)))
    }

    #[test]
    fn the_trends_closed_form_sums_match_the_plain_sums() {
        // A load rise with an oscillation riding on it, 1 kHz, records of several lengths
        // (a multiple of the four lanes and not), rates from below 1 / record length to
        // where the weights vanish within a few samples.
        for length in [7_usize, 64, 333, 800] {
            let dt = 1e-3;
            let mut record = [0.0_f64; 800];
            for (k, v) in record[..length].iter_mut().enumerate() {
                let t = k as f64 * dt;
                *v = 120.0 - 80.0 * libm::exp(-37.0 * t) + 9.0 * libm::sin(2.0 * PI * 12.0 * t);
            }
            let samples = &record[..length];
            let count = length as f64;
            let mean = samples.iter().sum::<f64>() / count;
            let sum_yy: f64 = samples.iter().map(|v| (v - mean) * (v - mean)).sum();
            for step in 0..60 {
                let log_rate = libm::log(0.2 / (count * dt)) + 0.2 * step as f64;
                let fast = LoadTrend::solve(samples, mean, mean, sum_yy, dt, log_rate);
                let plain = solve_directly(samples, dt, log_rate);
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
                match (fast, plain) {
                    (Some((fast, fast_residual)), Some((plain, plain_residual))) => assert!(
                        close(fast.level, plain.level)
                            && close(fast.amplitude, plain.amplitude)
                            && fast.ratio == plain.ratio
                            && close(fast_residual, plain_residual),
                        "length {length}, log rate {log_rate}: {fast:?} {fast_residual} \
                         against {plain:?} {plain_residual}"
                    ),
                    (None, None) => {}
                    (fast, plain) => {
                        panic!("length {length}, log rate {log_rate}: {fast:?} against {plain:?}")
                    }
                }
            }
        }
    }

    #[test]
    fn the_trends_rate_is_its_residuals_minimum() {
        // The refinement against a scan of 20 001 rates over the whole search range:
        // the fitted rate's residual is the scan's least, to rounding, on records whose
        // oscillation rides a fast, a slow or no load rise, at 1 and 2 kHz.
        for (rise, dt, length) in [(37.0, 1e-3, 800), (3.0, 5e-4, 1500), (0.0, 5e-4, 1200)] {
            let record: [f64; 1500] = core::array::from_fn(|k| {
                let t = k as f64 * dt;
                120.0 - 80.0 * libm::exp(-rise * t) + 9.0 * libm::sin(2.0 * PI * 12.0 * t)
            });
            let samples = &record[..length];
            let trend = LoadTrend::fit(samples, 0.0, dt, 40.0);
            let residual_at = |log_rate: f64| solve_directly(samples, dt, log_rate).map(|(_, r)| r);
            let fitted = residual_at(libm::log(-libm::log(trend.ratio) / dt)).unwrap();
            let (low, high) = (
                libm::log(1.0 / (length as f64 * dt)),
                libm::log(2.0 * PI * 40.0),
            );
            let scanned = (0..=20_000)
                .filter_map(|k| residual_at(low + (high - low) * k as f64 / 20_000.0))
                .fold(f64::INFINITY, f64::min);
            assert!(
                fitted <= scanned * (1.0 + 1e-9),
                "rise {rise}: residual {fitted} at the fitted rate, {scanned} scanned"
            );
        }
    }

    #[test]
    fn brents_method_finds_a_minimum_in_fewer_evaluations_than_the_golden_section() {
        // A smooth minimum, one beside a region without a value (infinity): far fewer
        // evaluations than the golden section's 41. A minimum at an end of the bracket
        // (golden steps all the way, the parabola stepping outside): no more.
        type Case = (fn(f64) -> f64, f64, usize);
        let cases: [Case; 3] = [
            (
                |x| libm::cosh(x - 1.3) + 0.1 * (x - 1.3),
                1.3 - libm::asinh(0.1),
                15,
            ),
            (
                |x| {
                    if x < 1.0 {
                        f64::INFINITY
                    } else {
                        (x - 1.2) * (x - 1.2)
                    }
                },
                1.2,
                15,
            ),
            (libm::exp, 0.5, TREND_REFINE + 1),
        ];
        for (f, minimum, most) in cases {
            let mut evaluations = 0;
            let x = brent_minimum(
                |x| {
                    evaluations += 1;
                    f(x)
                },
                0.5,
                2.5,
            );
            assert!(
                libm::fabs(x - minimum) < 1e-6 && evaluations <= most,
                "{x} against {minimum}, {evaluations} evaluations"
            );
        }
    }

    #[test]
    fn chirped_first_period_gives_positive_shift() {
        // First cycle at 8 Hz (0.125 s), then 10 Hz: shift = 0.025 s.
        let fs = 1000.0;
        let mut window = [0.0_f64; 800];
        let mut phase = 0.0;
        for (i, v) in window.iter_mut().enumerate() {
            let t = i as f64 / fs;
            // Up-crossings at phase pi/2 + 2 pi k: the first period (to 5 pi / 2) is slow.
            let f = if phase < 2.5 * PI { 8.0 } else { 10.0 };
            *v = 50.0 - 30.0 * libm::cos(phase) * libm::exp(-2.0 * t);
            phase += 2.0 * PI * f / fs;
        }
        let result = analyze::<1024>(&window, 0, 0.0, &settings()).unwrap();
        assert_eq!(result.quality, TransientQuality::Good);
        let shift = result.period_shift_s.unwrap();
        // The 40 Hz zero-phase filter spreads part of the stretch into the second period.
        assert!(
            shift > 0.55 * 0.025 && shift < 0.025 + 0.003,
            "shift {shift}"
        );
        assert_eq!(result.shift_excess_s, result.period_shift_s);
    }

    #[test]
    fn bad_inputs_are_named() {
        let window = [1.0, 2.0, f64::NAN, 3.0, 4.0];
        assert_eq!(
            analyze::<8>(&window, 0, 0.0, &settings()),
            Err(TransientError::NonFinite)
        );
        assert_eq!(
            analyze::<4>(&[0.0; 5], 0, 0.0, &settings()),
            Err(TransientError::WindowLength)
        );
        assert_eq!(
            analyze::<8>(&[0.0; 5], 5, 0.0, &settings()),
            Err(TransientError::TriggerIndex)
        );
        let bad = TransientSettings {
            period_lowpass_hz: 600.0,
            ..settings()
        };
        assert_eq!(
            analyze::<8>(&[0.0; 5], 0, 0.0, &bad),
            Err(TransientError::PeriodLowpassHz)
        );
    }

    #[test]
    fn zero_static_reports_low_static() {
        let result = analyze::<64>(&[0.0; 64], 3, 0.0, &settings()).unwrap();
        assert_eq!(result.quality, TransientQuality::LowStatic);
        assert_eq!(result.taf, None);
    }
}
