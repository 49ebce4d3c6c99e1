//! Transient analysis of one bite window: static torque, peak, TAF and oscillation periods.
//!
//! Estimators (all torques relative to the baseline handed in, kN*m):
//! - **static torque**: mean of the last `settled_fraction` of the window. Simple and
//!   unbiased once the fast mode has decayed; the residual of a slow mode averages out
//!   over several of its periods. When an eq. (1) fit is available its `a9` is the
//!   better estimate (see [`crate::fit`]).
//! - **peak torque**: maximum after the trigger of the signal low-passed at
//!   `peak_lowpass_hz` (zero-phase, so the peak is not delayed; set it 2-3x above the
//!   highest driveline mode to remove noise without cutting the peak), or of the raw
//!   samples when `None`.
//! - **TAF** = peak / static, `None` when the static torque is below `min_static_knm`.
//! - **periods**: up-crossings of the static level by the signal low-passed at
//!   `period_lowpass_hz` (zero-phase second-order Butterworth run forward and
//!   backward), linearly interpolated between samples. The first up-crossing is the
//!   load rise itself; the first period runs to the second up-crossing, the second
//!   period to the third.
//! - **first-period shift** = first - second period, and minus a linear-model reference
//!   shift when one is given: the wear index of the domain notes (section 1.3).

use core::f64::consts::{PI, SQRT_2};

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

/// Quality of a [`TransientResult`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransientQuality {
    /// All quantities were measured.
    Good,
    /// Fewer than three up-crossings of the static level: periods missing.
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
    /// Time of the first up-crossing of the static level after the trigger, s.
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

/// Second-order Butterworth low-pass, direct form I.
#[derive(Clone, Copy)]
struct Biquad {
    b0: f64,
    b1: f64,
    b2: f64,
    a1: f64,
    a2: f64,
}

impl Biquad {
    fn lowpass(cutoff_hz: f64, sample_rate_hz: f64) -> Self {
        let k = libm::tan(PI * cutoff_hz / sample_rate_hz);
        let norm = 1.0 / (1.0 + SQRT_2 * k + k * k);
        let b0 = k * k * norm;
        Self {
            b0,
            b1: 2.0 * b0,
            b2: b0,
            a1: 2.0 * (k * k - 1.0) * norm,
            a2: (1.0 - SQRT_2 * k + k * k) * norm,
        }
    }

    /// Zero-phase filtering in place: forward then backward, each started in the steady
    /// state of its first input sample (unit DC gain) to avoid start-up transients.
    fn filtfilt(&self, data: &mut [f64]) {
        self.run(data.iter_mut());
        self.run(data.iter_mut().rev());
    }

    fn run<'a>(&self, mut samples: impl Iterator<Item = &'a mut f64>) {
        let Some(first) = samples.next() else {
            return;
        };
        let (mut x1, mut x2, mut y1, mut y2) = (*first, *first, *first, *first);
        for sample in samples {
            let x = *sample;
            let y = self.b0 * x + self.b1 * x1 + self.b2 * x2 - self.a1 * y1 - self.a2 * y2;
            x2 = x1;
            x1 = x;
            y2 = y1;
            y1 = y;
            *sample = y;
        }
    }
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
/// let window: Vec<f64> = (0..500)
///     .map(|i| {
///         let t = i as f64 / fs;
///         100.0 * (1.0 - (-40.0 * t).exp() * (2.0 * std::f64::consts::PI * 10.0 * t).cos())
///     })
///     .collect();
/// let settings = TransientSettings {
///     sample_rate_hz: fs, period_lowpass_hz: 40.0, peak_lowpass_hz: None,
///     settled_fraction: 0.3, min_static_knm: 1.0, reference_shift_s: None,
/// };
/// let result = analyze::<512>(&window, 0, 0.0, &settings).unwrap();
/// assert!((result.static_torque_knm - 100.0).abs() < 0.5);
/// assert!((result.first_period_s.unwrap() - 0.1).abs() < 0.005);
/// ```
pub fn analyze<const N: usize>(
    window: &[f64],
    trigger_index: usize,
    baseline_knm: f64,
    settings: &TransientSettings,
) -> Result<TransientResult, TransientError> {
    let rate = settings.sample_rate_hz;
    if !(rate.is_finite() && rate > 0.0) {
        return Err(TransientError::SampleRateHz);
    }
    let period_cutoff = check_cutoff(
        settings.period_lowpass_hz,
        rate,
        TransientError::PeriodLowpassHz,
    )?;
    let peak_cutoff = match settings.peak_lowpass_hz {
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

    let len = window.len();
    let mut buffer = [0.0_f64; N];
    let data = &mut buffer[..len];
    for (out, &value) in data.iter_mut().zip(window) {
        *out = value - baseline_knm;
    }

    // Static torque: mean of the settled tail (raw samples).
    let tail = ((len as f64 * settings.settled_fraction) as usize).clamp(1, len - trigger_index);
    let static_torque_knm = data[len - tail..].iter().sum::<f64>() / tail as f64;

    // Peak after the trigger, optionally on the smoothed signal.
    if let Some(cutoff) = peak_cutoff {
        Biquad::lowpass(cutoff, rate).filtfilt(data);
    }
    let (peak_offset, peak_torque_knm) =
        data[trigger_index..]
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (i, &v)| {
                if v > best.1 {
                    (i, v)
                } else {
                    best
                }
            });
    if !static_torque_knm.is_finite() || !peak_torque_knm.is_finite() {
        // Samples near f64::MAX overflow the mean or the filter.
        return Err(TransientError::NonFinite);
    }
    let dt = 1.0 / rate;
    let peak_time_s = peak_offset as f64 * dt;

    let finite_or_none = |v: f64| if v.is_finite() { Some(v) } else { None };
    let mut result = TransientResult {
        static_torque_knm,
        peak_torque_knm,
        peak_time_s,
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
    result.taf = finite_or_none(peak_torque_knm / static_torque_knm);

    // Periods from up-crossings of the static level on the low-passed signal.
    for (out, &value) in data.iter_mut().zip(window) {
        *out = value - baseline_knm;
    }
    Biquad::lowpass(period_cutoff, rate).filtfilt(data);
    let mut crossings = [0.0_f64; 3];
    let mut found = 0;
    let mut previous = data[trigger_index] - static_torque_knm;
    for (offset, &value) in data[trigger_index + 1..].iter().enumerate() {
        let current = value - static_torque_knm;
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
    result.rise_time_s = (found >= 1).then_some(crossings[0]);
    if found < 3 {
        result.quality = TransientQuality::FewCrossings;
        if found == 2 {
            result.first_period_s = Some(crossings[1] - crossings[0]);
        }
        return Ok(result);
    }
    let first = crossings[1] - crossings[0];
    let second = crossings[2] - crossings[1];
    let shift = first - second;
    result.first_period_s = Some(first);
    result.second_period_s = Some(second);
    result.period_shift_s = Some(shift);
    result.shift_excess_s = settings
        .reference_shift_s
        .map(|reference| shift - reference);
    result.quality = TransientQuality::Good;
    Ok(result)
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

    #[test]
    fn filter_has_unit_dc_gain_and_cuts_high_frequency() {
        let filter = Biquad::lowpass(10.0, 1000.0);
        let mut constant = [5.0; 200];
        filter.filtfilt(&mut constant);
        assert!(constant.iter().all(|v| (v - 5.0).abs() < 1e-9));
        let mut fast = [0.0; 400];
        for (i, v) in fast.iter_mut().enumerate() {
            *v = libm::sin(2.0 * PI * 200.0 * i as f64 / 1000.0);
        }
        filter.filtfilt(&mut fast);
        assert!(fast[100..300].iter().all(|v| v.abs() < 0.01));
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
        assert!((shift - 0.025).abs() < 0.003, "shift {shift}");
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
