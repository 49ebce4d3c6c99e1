//! Chatter synchronization metrics of n adjacent stands of a tandem cold mill.
//!
//! Early chatter shows as synchronization before the amplitude grows (domain notes 2):
//! `sigma_n <= sigma_min` and `K_mean >= K_max` over one window.
//!
//! - **principal frequency** per stand: largest magnitude bin in the chatter band,
//!   refined by parabolic interpolation through it and its two neighbours.
//! - **sigma_n** (Hz): RMS of the frequency differences of adjacent stands,
//!   `sqrt(sum (f[i+1] - f[i])^2 / (n - 1))`.
//! - **sigma_min** (Hz): the spectrum's frequency step.
//! - **K_mean**: mean Pearson correlation of the time signals of the n - 1 adjacent
//!   pairs (a constant signal has correlation 0).
//!
//! **FFT choice**: the caller hands in magnitude spectra (one slice per stand, bin k at
//! `k * frequency_step_hz`). The gateway plans a `rustfft` FFT once and calls
//! `process_with_scratch` per window (no allocation per call, any length, SIMD); this
//! crate stays FFT-agnostic and `no_std`, and firmware can use whatever FFT its chip
//! has. Window the signal before the FFT (e.g. Hann) to limit leakage.

use heapless::Vec;

/// Largest number of stands handled.
pub const MAX_STANDS: usize = 8;

/// Settings of a [`ChatterDetector`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChatterSettings {
    /// Lower edge of the chatter band, Hz, finite and >= 0.
    pub band_low_hz: f64,
    /// Upper edge of the chatter band, Hz, finite and > `band_low_hz`.
    pub band_high_hz: f64,
    /// Correlation threshold K_max (largest correlation of steady rolling), in [-1, 1].
    pub k_max: f64,
}

/// Invalid setting or input; the variant names the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChatterError {
    /// `band_low_hz` is not finite and >= 0.
    BandLowHz,
    /// `band_high_hz` is not finite and > `band_low_hz`.
    BandHighHz,
    /// `k_max` is not in [-1, 1].
    KMax,
    /// `frequency_step_hz` is not finite and > 0.
    FrequencyStepHz,
    /// Fewer than 2 or more than [`MAX_STANDS`] stands.
    StandCount,
    /// The spectra differ in length or the band has no interior bin in them.
    SpectrumLength,
    /// The signals differ in length or have fewer than 2 samples.
    SignalLength,
    /// A spectrum or signal value is NaN or infinite, or a magnitude is negative.
    NonFinite,
    /// Values so large that the energy or correlation overflows.
    Overflow,
}

impl core::fmt::Display for ChatterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ChatterError::BandLowHz => f.write_str("band_low_hz must be finite and >= 0 Hz"),
            ChatterError::BandHighHz => {
                f.write_str("band_high_hz must be finite and > band_low_hz")
            }
            ChatterError::KMax => f.write_str("k_max must be in [-1, 1]"),
            ChatterError::FrequencyStepHz => {
                f.write_str("frequency_step_hz must be finite and > 0 Hz")
            }
            ChatterError::StandCount => write!(f, "the stands must number 2..={MAX_STANDS}"),
            ChatterError::SpectrumLength => f.write_str(
                "the spectra differ in length or the chatter band has no interior bin in them",
            ),
            ChatterError::SignalLength => {
                f.write_str("the signals differ in length or have fewer than 2 samples")
            }
            ChatterError::NonFinite => f.write_str(
                "a spectrum or signal value is NaN or infinite, or a magnitude is negative",
            ),
            ChatterError::Overflow => {
                f.write_str("values so large that the energy or correlation overflows")
            }
        }
    }
}

impl core::error::Error for ChatterError {}

/// One stand's window: magnitude spectrum and time signal.
#[derive(Clone, Copy, Debug)]
pub struct StandWindow<'a> {
    /// Magnitude spectrum, bin k at `k * frequency_step_hz`, values >= 0.
    pub magnitude: &'a [f64],
    /// Vibration signal of the same window (any unit), same length for every stand.
    pub signal: &'a [f64],
}

/// Per-stand metrics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StandMetrics {
    /// Interpolated principal-mode frequency in the band, Hz.
    pub principal_hz: f64,
    /// Interpolated magnitude at the principal frequency (spectrum units).
    pub amplitude: f64,
    /// Sum of squared magnitudes over the band bins (spectrum units squared).
    pub band_energy: f64,
}

/// Synchronization metrics of one window.
#[derive(Clone, Debug, PartialEq)]
pub struct ChatterResult {
    /// Metrics per stand, in stand order.
    pub stands: Vec<StandMetrics, MAX_STANDS>,
    /// RMS difference of adjacent principal frequencies, Hz.
    pub sigma_n_hz: f64,
    /// Spectrum frequency step used as sigma_min, Hz.
    pub sigma_min_hz: f64,
    /// Mean Pearson correlation of adjacent stands' signals, in [-1, 1].
    pub k_mean: f64,
    /// `sigma_n <= sigma_min`.
    pub frequencies_locked: bool,
    /// `K_mean >= K_max`.
    pub correlated: bool,
    /// Both conditions: chatter is building up.
    pub synchronized: bool,
}

/// Validated chatter settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChatterDetector {
    settings: ChatterSettings,
}

impl ChatterDetector {
    /// Validates `settings`.
    pub fn new(settings: ChatterSettings) -> Result<Self, ChatterError> {
        if !(settings.band_low_hz.is_finite() && settings.band_low_hz >= 0.0) {
            return Err(ChatterError::BandLowHz);
        }
        if !(settings.band_high_hz.is_finite() && settings.band_high_hz > settings.band_low_hz) {
            return Err(ChatterError::BandHighHz);
        }
        if !(-1.0..=1.0).contains(&settings.k_max) {
            return Err(ChatterError::KMax);
        }
        Ok(Self { settings })
    }

    /// Metrics of one window over `stands` (2..=8, adjacent in rolling order).
    ///
    /// `frequency_step_hz` is the bin spacing of the spectra (sample rate / FFT length).
    pub fn evaluate(
        &self,
        stands: &[StandWindow<'_>],
        frequency_step_hz: f64,
    ) -> Result<ChatterResult, ChatterError> {
        if !(frequency_step_hz.is_finite() && frequency_step_hz > 0.0) {
            return Err(ChatterError::FrequencyStepHz);
        }
        if stands.len() < 2 || stands.len() > MAX_STANDS {
            return Err(ChatterError::StandCount);
        }
        let bins = stands[0].magnitude.len();
        let samples = stands[0].signal.len();
        if stands.iter().any(|s| s.magnitude.len() != bins) {
            return Err(ChatterError::SpectrumLength);
        }
        if samples < 2 || stands.iter().any(|s| s.signal.len() != samples) {
            return Err(ChatterError::SignalLength);
        }
        let low = libm::ceil(self.settings.band_low_hz / frequency_step_hz).max(1.0);
        let high = libm::floor(self.settings.band_high_hz / frequency_step_hz);
        // The band must hold a bin with two neighbours inside the spectrum.
        if low > high || high + 1.0 >= bins as f64 {
            return Err(ChatterError::SpectrumLength);
        }
        let band = low as usize..=high as usize;
        for stand in stands {
            if stand
                .magnitude
                .iter()
                .any(|m| !(m.is_finite() && *m >= 0.0))
                || stand.signal.iter().any(|v| !v.is_finite())
            {
                return Err(ChatterError::NonFinite);
            }
        }

        let mut metrics: Vec<StandMetrics, MAX_STANDS> = Vec::new();
        for stand in stands {
            let m = stand.magnitude;
            let (mut peak, mut band_energy) = (*band.start(), 0.0);
            for k in band.clone() {
                band_energy += m[k] * m[k];
                if m[k] > m[peak] {
                    peak = k;
                }
            }
            let (alpha, beta, gamma) = (m[peak - 1], m[peak], m[peak + 1]);
            let curvature = alpha - 2.0 * beta + gamma;
            let offset = if curvature < 0.0 {
                (0.5 * (alpha - gamma) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            let metric = StandMetrics {
                principal_hz: (peak as f64 + offset) * frequency_step_hz,
                amplitude: beta - 0.25 * (alpha - gamma) * offset,
                band_energy,
            };
            if !(metric.amplitude.is_finite() && band_energy.is_finite()) {
                return Err(ChatterError::Overflow);
            }
            // At most MAX_STANDS stands, checked above.
            let _ = metrics.push(metric);
        }

        let pairs = (stands.len() - 1) as f64;
        let mut sum_sq = 0.0;
        let mut sum_k = 0.0;
        for (i, pair) in stands.windows(2).enumerate() {
            let df = metrics[i + 1].principal_hz - metrics[i].principal_hz;
            sum_sq += df * df;
            sum_k += pearson(pair[0].signal, pair[1].signal);
        }
        let sigma_n_hz = libm::sqrt(sum_sq / pairs);
        let k_mean = sum_k / pairs;
        if !(sigma_n_hz.is_finite() && k_mean.is_finite()) {
            return Err(ChatterError::Overflow);
        }
        let frequencies_locked = sigma_n_hz <= frequency_step_hz;
        let correlated = k_mean >= self.settings.k_max;
        Ok(ChatterResult {
            stands: metrics,
            sigma_n_hz,
            sigma_min_hz: frequency_step_hz,
            k_mean,
            frequencies_locked,
            correlated,
            synchronized: frequencies_locked && correlated,
        })
    }
}

/// Pearson correlation of two equally long finite signals; 0 if either is constant.
///
/// Each signal is scaled by its peak magnitude first, so huge values do not overflow.
pub(crate) fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    if n < 2 {
        return 0.0;
    }
    let (x, y) = (&x[..n], &y[..n]);
    let peak = |s: &[f64]| s.iter().fold(0.0_f64, |m, v| m.max(libm::fabs(*v)));
    let (px, py) = (peak(x), peak(y));
    if px == 0.0 || py == 0.0 {
        return 0.0;
    }
    let mean_x = x.iter().map(|v| v / px).sum::<f64>() / n as f64;
    let mean_y = y.iter().map(|v| v / py).sum::<f64>() / n as f64;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        let dx = a / px - mean_x;
        let dy = b / py - mean_y;
        sxy += dx * dy;
        sxx += dx * dx;
        syy += dy * dy;
    }
    let denominator = libm::sqrt(sxx * syy);
    if denominator > 0.0 {
        (sxy / denominator).clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parabolic_peak_of_sampled_parabola_is_exact() {
        // Magnitudes 1 - (f - 10.3)^2 / 4 at 1 Hz bins: vertex 10.3 Hz, height 1.
        let mut magnitude = [0.0; 32];
        for (k, m) in magnitude.iter_mut().enumerate() {
            let d = k as f64 - 10.3;
            *m = (1.0 - d * d / 4.0).max(0.0);
        }
        let detector = ChatterDetector::new(ChatterSettings {
            band_low_hz: 5.0,
            band_high_hz: 20.0,
            k_max: 0.25,
        })
        .unwrap();
        let signal = [0.0, 1.0, 0.0, -1.0];
        let stand = StandWindow {
            magnitude: &magnitude,
            signal: &signal,
        };
        let result = detector.evaluate(&[stand, stand], 1.0).unwrap();
        assert!((result.stands[0].principal_hz - 10.3).abs() < 1e-12);
        assert!((result.stands[0].amplitude - 1.0).abs() < 1e-12);
        assert_eq!(result.sigma_n_hz, 0.0);
        assert!((result.k_mean - 1.0).abs() < 1e-12);
        assert!(result.synchronized);
    }

    #[test]
    fn pearson_of_opposite_and_constant_signals() {
        let a = [1.0, 2.0, 3.0, 4.0];
        let b = [4.0, 3.0, 2.0, 1.0];
        assert!((pearson(&a, &b) + 1.0).abs() < 1e-12);
        assert_eq!(pearson(&a, &[5.0; 4]), 0.0);
    }

    #[test]
    fn invalid_inputs_are_named() {
        let settings = ChatterSettings {
            band_low_hz: 5.0,
            band_high_hz: 20.0,
            k_max: 0.25,
        };
        assert_eq!(
            ChatterDetector::new(ChatterSettings {
                k_max: 2.0,
                ..settings
            }),
            Err(ChatterError::KMax)
        );
        let detector = ChatterDetector::new(settings).unwrap();
        let magnitude = [1.0; 8];
        let stand = StandWindow {
            magnitude: &magnitude,
            signal: &[0.0, 1.0],
        };
        // 20 Hz band edge beyond an 8-bin spectrum at 1 Hz.
        assert_eq!(
            detector.evaluate(&[stand, stand], 1.0),
            Err(ChatterError::SpectrumLength)
        );
        assert_eq!(
            detector.evaluate(&[stand], 1.0),
            Err(ChatterError::StandCount)
        );
    }
}
