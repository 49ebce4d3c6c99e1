//! One bite window's analysis, shared by the service's drivelines, their wear
//! references and `millgate analyze`: the detector's capacities, the transient
//! measures and the eq. (1) fit from the load onset.

use millgate_dsp::bite::{BiteDetector, BiteDetectorState};
use millgate_dsp::fit::{fit_eq1, Eq1Fit, FitError, FitOptions, FitStatus};
use millgate_dsp::transient::{self, TransientError, TransientResult, TransientSettings};

/// Window capacity of a bite, samples (pre + post trigger): 1 s at 2 kHz.
pub const WINDOW_CAPACITY: usize = 2048;
/// Largest pre-trigger history, samples.
pub const PRE_TRIGGER_CAPACITY: usize = 256;

/// The bite detector of every driveline (and of its wear reference).
pub type Detector = BiteDetector<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;
pub(crate) type DetectorState = BiteDetectorState<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;

/// What one bite window gives: the transient measures and the eq. (1) fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowAnalysis {
    /// Static torque, peak, TAF and periods of the window.
    pub transient: TransientResult,
    /// The fit of eq. (1) from the load onset on (t = 0 at `fit_start_index`).
    pub fit: Result<Eq1Fit, FitError>,
    /// Index in the window where the fitted record starts (the load onset).
    pub fit_start_index: usize,
}

impl WindowAnalysis {
    /// The fit, when it converged (or stalled at a minimum): the natural
    /// frequencies are then trustworthy.
    pub fn good_fit(&self) -> Option<&Eq1Fit> {
        self.fit
            .as_ref()
            .ok()
            .filter(|fit| matches!(fit.status, FitStatus::Converged | FitStatus::Stalled))
    }
}

/// The transient measures of one window (kN*m) whose bite was detected at
/// `window[trigger_index]`: what [`analyze_window`] gives without the fit (the wear
/// maps need only these).
pub fn window_transient(
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
pub fn analyze_window(
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
    })
}
