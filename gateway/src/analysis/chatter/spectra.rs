//! The spectra of one window and the paper's synchronization conditions
//! (`dsp::chatter`): sigma_n, sigma_min, K_mean.
//!
//! **Spectrum.** Per stand: mean removed, Hann window, forward FFT of length `N`
//! (planned once with `rustfft`, run with `process_with_scratch`, no allocation per
//! window). Magnitudes are scaled by `2 / sum(hann)`, so a sine of peak `A` shows as
//! `A`. The frequency step `fs / N = 1 / window_s` is sigma_min.
//!
//! **Correlation signal.** K_mean is computed on each stand's chatter-band content:
//! the windowed spectrum with every bin outside the band zeroed, transformed back
//! (inverse FFT, also planned once). Vibration outside the band (roll eccentricity,
//! drive harmonics common to all stands) then cannot pass for synchronization.

use std::sync::Arc;

use millgate_dsp::chatter::{
    ChatterDetector, ChatterError, ChatterResult, ChatterSettings, StandWindow, MAX_STANDS,
};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use super::align::Alignment;

/// Why the spectra cannot be set up for a window and band.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum SpectraError {
    /// No spectrum bin with a neighbour on each side falls inside the band.
    BandTooNarrow {
        /// The spectrum's frequency step, Hz.
        step_hz: f64,
    },
    /// The detector refused the settings.
    Detector(ChatterError),
}

/// FFT plans, buffers and the detector of one mill's windows.
pub(super) struct Spectra {
    detector: ChatterDetector,
    sample_rate_hz: f64,
    window: usize,
    forward: Arc<dyn Fft<f64>>,
    inverse: Arc<dyn Fft<f64>>,
    hann: Vec<f64>,
    magnitude_scale: f64,
    /// Bins kept for the correlation signal (the chatter band), inclusive.
    band_bins: (usize, usize),
    buffer: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    /// `stands * bins` magnitudes, one spectrum after another.
    magnitudes: Vec<f64>,
    /// `stands * window` band-limited signals.
    band_signals: Vec<f64>,
}

// By hand: the FFT plans (`dyn Fft`) have no Debug; the buffers are not worth printing.
impl std::fmt::Debug for Spectra {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spectra")
            .field("window", &self.window)
            .field("band_bins", &self.band_bins)
            .finish_non_exhaustive()
    }
}

impl Spectra {
    /// Spectra of `stands` stands over windows of `window` samples at
    /// `sample_rate_hz`, the chatter band `band_hz` and the paper's `k_max`.
    pub(super) fn new(
        stands: usize,
        sample_rate_hz: f64,
        window: usize,
        band_hz: (f64, f64),
        k_max: f64,
    ) -> Result<Self, SpectraError> {
        let (low_hz, high_hz) = band_hz;
        let detector = ChatterDetector::new(ChatterSettings {
            band_low_hz: low_hz,
            band_high_hz: high_hz,
            k_max,
        })
        .map_err(SpectraError::Detector)?;
        let bins = window / 2 + 1;
        let step_hz = sample_rate_hz / window as f64;
        let low_bin = (low_hz / step_hz).ceil().max(1.0) as usize;
        let high_bin = (high_hz / step_hz).floor() as usize;
        // The same check as the detector's: a band bin with two neighbours.
        if low_bin > high_bin || high_bin + 1 >= bins {
            return Err(SpectraError::BandTooNarrow { step_hz });
        }
        let mut planner = FftPlanner::new();
        let forward = planner.plan_fft_forward(window);
        let inverse = planner.plan_fft_inverse(window);
        let scratch_len = forward
            .get_inplace_scratch_len()
            .max(inverse.get_inplace_scratch_len());
        let hann: Vec<f64> = (0..window)
            .map(|k| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / window as f64).cos())
            .collect();
        let magnitude_scale = 2.0 / hann.iter().sum::<f64>();
        Ok(Self {
            detector,
            sample_rate_hz,
            window,
            forward,
            inverse,
            hann,
            magnitude_scale,
            band_bins: (low_bin, high_bin),
            buffer: vec![Complex::new(0.0, 0.0); window],
            scratch: vec![Complex::new(0.0, 0.0); scratch_len],
            magnitudes: vec![0.0; stands * bins],
            band_signals: vec![0.0; stands * window],
        })
    }

    /// Spectrum frequency step, Hz (sigma_min).
    pub(super) fn frequency_step_hz(&self) -> f64 {
        self.sample_rate_hz / self.window as f64
    }

    /// Spectra and band signals of the window ending at `end` on `aligned`, then the
    /// detector.
    pub(super) fn evaluate(
        &mut self,
        aligned: &Alignment,
        end: i64,
    ) -> Result<ChatterResult, ChatterError> {
        let n = self.window;
        let bins = n / 2 + 1;
        let start = end - n as i64;
        let (low, high) = self.band_bins;
        let count = aligned.stands();
        for s in 0..count {
            let mean = (start..end).map(|i| aligned.sample(s, i)).sum::<f64>() / n as f64;
            for ((slot, i), w) in self.buffer.iter_mut().zip(start..end).zip(&self.hann) {
                *slot = Complex::new((aligned.sample(s, i) - mean) * w, 0.0);
            }
            self.forward
                .process_with_scratch(&mut self.buffer, &mut self.scratch);
            for (m, c) in self.magnitudes[s * bins..(s + 1) * bins]
                .iter_mut()
                .zip(&self.buffer)
            {
                *m = c.norm() * self.magnitude_scale;
            }
            // Keep the band and its mirror image: a real band-limited signal.
            for (k, c) in self.buffer.iter_mut().enumerate() {
                let folded = k.min(n - k);
                if !(low..=high).contains(&folded) {
                    *c = Complex::new(0.0, 0.0);
                }
            }
            self.inverse
                .process_with_scratch(&mut self.buffer, &mut self.scratch);
            for (v, c) in self.band_signals[s * n..(s + 1) * n]
                .iter_mut()
                .zip(&self.buffer)
            {
                *v = c.re / n as f64;
            }
        }
        let empty = StandWindow {
            magnitude: &[],
            signal: &[],
        };
        let mut windows = [empty; MAX_STANDS];
        for (s, window) in windows.iter_mut().enumerate().take(count) {
            *window = StandWindow {
                magnitude: &self.magnitudes[s * bins..(s + 1) * bins],
                signal: &self.band_signals[s * n..(s + 1) * n],
            };
        }
        let windows = windows.get(..count).ok_or(ChatterError::StandCount)?;
        self.detector.evaluate(windows, self.frequency_step_hz())
    }
}

/// Mean of the stands' principal frequencies, Hz: the published chatter frequency.
pub fn chatter_frequency_hz(result: &ChatterResult) -> Option<f64> {
    let count = result.stands.len();
    (count > 0).then(|| result.stands.iter().map(|s| s.principal_hz).sum::<f64>() / count as f64)
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::super::testing::{feed, monitor, sine};

    #[test]
    fn pure_sine_frequency_within_interpolation_accuracy() {
        let step = monitor(2).frequency_step_hz();
        assert_eq!(step, 2.0);
        let mut worst: f64 = 0.0;
        // Across a bin: on a bin, a quarter and half way between bins.
        for f_hz in [150.0, 150.5, 151.0, 187.3, 222.9, 280.75] {
            let mut monitor = monitor(2);
            assert_eq!(
                (monitor.window_samples(), monitor.hop_samples()),
                (1250, 625)
            );
            let signal = sine(f_hz, 0.3, 2.0, 0..3000);
            let results = feed(&mut monitor, &[signal.clone(), signal], Instant::now());
            let r = results.last().expect("one window");
            for stand in &r.stands {
                let error = stand.principal_hz - f_hz;
                worst = worst.max(error.abs());
                assert!(
                    error.abs() <= 0.1 * step,
                    "{f_hz} Hz: found {}",
                    stand.principal_hz
                );
                assert!((stand.amplitude - 2.0).abs() < 0.2, "{stand:?}");
            }
            assert!(r.sigma_n_hz < 1e-9 && r.frequencies_locked);
            assert!((r.k_mean - 1.0).abs() < 1e-9, "{}", r.k_mean);
        }
        println!("worst interpolated frequency error {worst:.4} Hz at a {step} Hz step");
    }

    #[test]
    fn one_evaluation_per_hop_on_aligned_windows() {
        let mut monitor = monitor(3);
        let signals: Vec<Vec<f64>> = [160.0, 200.0, 240.0]
            .iter()
            .map(|&f| sine(f, 0.0, 1.0, 0..12_000))
            .collect();
        let results = feed(&mut monitor, &signals, Instant::now());
        // The first block of each stand anchors it and is not used; then every 625
        // samples a window of 1250 ends.
        let usable = 12_000 - super::super::testing::BLOCK;
        assert_eq!(results.len(), (usable - 1250) / 625 + 1);
        assert_eq!(monitor.evaluations(), results.len() as u64);
        let r = results.last().unwrap();
        let sigma = ((40.0f64.powi(2) * 2.0) / 2.0).sqrt();
        assert!((r.sigma_n_hz - sigma).abs() < 0.2, "{}", r.sigma_n_hz);
        assert!(!r.frequencies_locked && !r.correlated && !r.synchronized);
        assert!(r.k_mean.abs() < 0.05, "{}", r.k_mean);
    }

    #[test]
    fn common_vibration_outside_the_band_is_not_correlation() {
        let mut monitor = monitor(2);
        // Independent chatter-band lines under a large common 20 Hz roll vibration.
        let common = sine(20.0, 0.0, 10.0, 0..5000);
        let signals: Vec<Vec<f64>> = [(150.0, 0.0), (260.0, 1.0)]
            .iter()
            .map(|&(f, p)| {
                let own = sine(f, p, 1.0, 0..5000);
                own.iter().zip(&common).map(|(a, b)| a + b).collect()
            })
            .collect();
        let r = feed(&mut monitor, &signals, Instant::now()).pop().unwrap();
        assert!(r.k_mean.abs() < 0.05, "K_mean {}", r.k_mean);
        assert!((r.stands[0].principal_hz - 150.0).abs() < 0.2);
        assert!((r.stands[1].principal_hz - 260.0).abs() < 0.2);
    }
}
