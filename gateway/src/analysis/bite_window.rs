//! One bite window's analysis, shared by the service's drivelines, their wear
//! references and `millgate analyze`: the detector's capacities, the transient
//! measures and the eq. (1) fit from the load onset.

use millgate_dsp::bite::{BiteDetector, BiteDetectorState};
use millgate_dsp::fit::{fit_eq1, Eq1Fit, FitError, FitOptions, FitStatus};
use millgate_dsp::transient::{self, TransientError, TransientResult, TransientSettings};

/// Window capacity of a bite, samples (pre + post trigger): 1 s at 2 kHz.
pub(crate) const WINDOW_CAPACITY: usize = 2048;
/// Largest pre-trigger history, samples.
pub(crate) const PRE_TRIGGER_CAPACITY: usize = 256;

/// The bite detector of every driveline (and of its wear reference).
pub(crate) type Detector = BiteDetector<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;
pub(crate) type DetectorState = BiteDetectorState<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;

/// What one bite window gives: the transient measures and the eq. (1) fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WindowAnalysis {
    /// Static torque, peak, TAF and periods of the window.
    pub transient: TransientResult,
    /// The fit of eq. (1) from the load onset on (t = 0 at `fit_start_index`).
    pub fit: Result<Eq1Fit, FitError>,
    /// Index in the window where the fitted record starts (the load onset).
    pub fit_start_index: usize,
    /// The sample rate the window was taken at, Hz.
    pub sample_rate_hz: f64,
}

impl WindowAnalysis {
    /// The fit, when it converged (or stalled at a minimum): the natural
    /// frequencies are then trustworthy.
    pub(crate) fn good_fit(&self) -> Option<&Eq1Fit> {
        self.fit
            .as_ref()
            .ok()
            .filter(|fit| matches!(fit.status, FitStatus::Converged | FitStatus::Stalled))
    }

    /// The natural frequencies (beta1, beta2), Hz, of a [good fit](Self::good_fit)
    /// when both lie in the band the record can resolve, [`Self::resolvable_hz`]: a
    /// fit that puts a mode above Nyquist or slower than one cycle in the record has
    /// fitted noise or a gap's edge, and its frequencies are no measurement.
    pub(crate) fn natural_frequencies_hz(&self) -> Option<(f64, f64)> {
        let fit = self.good_fit()?;
        let (low, high) = self.resolvable_hz(fit.samples_used);
        let resolvable = |f: f64| f >= low && f < high;
        (resolvable(fit.f1_hz) && resolvable(fit.f2_hz)).then_some((fit.f1_hz, fit.f2_hz))
    }

    /// The first mode's damping ratio of the eq. (1) fit, given with its natural
    /// frequencies ([`Self::natural_frequencies_hz`]).
    pub(crate) fn first_mode_damping(&self) -> Option<f64> {
        self.natural_frequencies_hz()?;
        self.good_fit().map(|fit| fit.zeta1)
    }

    /// The frequencies a record of `samples` resolves, Hz: from one cycle in the record
    /// (fs / samples) up to, not including, Nyquist (fs / 2).
    pub(crate) fn resolvable_hz(&self, samples: usize) -> (f64, f64) {
        let fs = self.sample_rate_hz;
        (fs / samples.max(1) as f64, fs / 2.0)
    }
}

/// The transient measures of one window (kN*m) whose bite was detected at
/// `window[trigger_index]`: what [`analyze_window`] gives without the fit (the wear
/// maps need only these).
pub(crate) fn window_transient(
    window: &[f64],
    trigger_index: usize,
    baseline_knm: f64,
    settings: &TransientSettings,
) -> Result<TransientResult, TransientError> {
    transient::analyze::<WINDOW_CAPACITY>(window, trigger_index, baseline_knm, settings)
}

/// Analyse one window (kN*m) whose bite was detected at `window[trigger_index]`:
/// the transient measures (static torque, peak, TAF, periods) and the eq. (1) fit.
///
/// The fit starts at the load onset, found by walking back from the trigger while
/// the torque stays above the baseline by more than `onset_knm`, so that eq. (1)'s
/// t = 0 is the start of the load rise, as in the paper's Table 1 record.
pub(crate) fn analyze_window(
    window: &[f64],
    trigger_index: usize,
    baseline_knm: f64,
    onset_knm: f64,
    settings: &TransientSettings,
) -> Result<WindowAnalysis, TransientError> {
    let transient = window_transient(window, trigger_index, baseline_knm, settings)?;
    let fit_start_index = window[..=trigger_index.min(window.len().saturating_sub(1))]
        .iter()
        .rposition(|&x| x - baseline_knm <= onset_knm)
        .unwrap_or(0);
    let record: Vec<f64> = window[fit_start_index..]
        .iter()
        .map(|&x| x - baseline_knm)
        .collect();
    let fit = fit_eq1(&record, &FitOptions::new(settings.sample_rate_hz));
    Ok(WindowAnalysis {
        transient,
        fit,
        fit_start_index,
        sample_rate_hz: settings.sample_rate_hz,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_dsp::fit::eq1;
    use millgate_dsp::transient::TransientSettings;

    const FS: f64 = 2000.0;

    fn settings() -> TransientSettings {
        TransientSettings {
            sample_rate_hz: FS,
            period_lowpass_hz: 40.0,
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: 1.0,
            reference_shift_s: None,
        }
    }

    /// A window of eq. (1) with the paper's Table 1 frequencies, 0.6 s at 2 kHz.
    fn window() -> Vec<f64> {
        let params = [-60.0, -20.0, 10.0, 5.0, 12.03, 21.09, 6.0, 3.0, 112.0, 40.0];
        (0..1200).map(|k| eq1(&params, f64::from(k) / FS)).collect()
    }

    #[test]
    fn natural_frequencies_of_a_bite_within_the_band_are_kept() {
        let analysis = analyze_window(&window(), 0, 0.0, 1.0, &settings()).unwrap();
        let (beta1, beta2) = analysis.natural_frequencies_hz().unwrap();
        assert!((beta1 - 12.03).abs() < 0.05 && (beta2 - 21.09).abs() < 0.05);
        assert_eq!(analysis.resolvable_hz(1200), (FS / 1200.0, FS / 2.0));
    }

    #[test]
    fn a_fit_beyond_nyquist_or_below_one_cycle_gives_no_natural_frequencies() {
        let mut analysis = analyze_window(&window(), 0, 0.0, 1.0, &settings()).unwrap();
        let good = *analysis.good_fit().unwrap();
        let samples = good.samples_used;
        // What the outage run of issue 30 published: beta2 far above Nyquist, beta1 of
        // a period longer than the record.
        for (f1_hz, f2_hz) in [
            (12.0, 361_859.0),
            (12.0, FS / 2.0),
            (0.04, 21.0),
            (0.99 * FS / samples as f64, 21.0),
        ] {
            analysis.fit = Ok(millgate_dsp::fit::Eq1Fit {
                f1_hz,
                f2_hz,
                ..good
            });
            assert!(analysis.good_fit().is_some());
            assert_eq!(analysis.natural_frequencies_hz(), None, "{f1_hz}, {f2_hz}");
        }
    }
}
