//! The analysis task: samples in, bite results out. Only synchronous `dsp` code
//! runs on the samples; this module routes them and keeps per-driveline state.

pub mod chatter_monitor;
pub mod wear;

use std::sync::Arc;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use millgate_config::{Channel, Config, Driveline};
use millgate_dsp::bite::{BiteDetector, BiteDetectorState, BiteEvent, BiteSettings};
use millgate_dsp::fit::{fit_eq1, Eq1Fit, FitError, FitOptions, FitStatus};
use millgate_dsp::transient::{self, TransientError, TransientResult, TransientSettings};
use tokio::sync::{broadcast, mpsc};

use crate::field::acquired::Acquired;
use crate::outputs::publisher::Publisher;
use wear::{WearEstimate, WearReference};

/// Window capacity of a bite, samples (pre + post trigger): 1 s at 2 kHz.
pub const WINDOW_CAPACITY: usize = 2048;
/// Largest pre-trigger history, samples.
pub const PRE_TRIGGER_CAPACITY: usize = 256;

/// The bite detector of every driveline (and of its wear reference).
pub type Detector = BiteDetector<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;
type DetectorState = BiteDetectorState<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>;

/// Low-pass cut-off for period measurement of a driveline without a model, Hz: keeps
/// the first modes (10-30 Hz, domain notes 1.3) and removes measurement noise above
/// them. With a model the wear map's cut-off is used (1.5 x its second mode), so
/// measured period shifts compare with the maps.
const PERIOD_LOWPASS_HZ: f64 = 40.0;

/// What one bite window gives: the transient measures and the eq. (1) fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowAnalysis {
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
    let transient =
        transient::analyze::<WINDOW_CAPACITY>(window, trigger_index, baseline_knm, settings)?;
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

/// A driveline's configuration that the dsp code cannot take.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// A tandem mill the chatter monitor cannot be built for.
    #[error(transparent)]
    Chatter(#[from] chatter_monitor::ChatterSetupError),
    #[error("drivelines[{index}].bite: {problem}")]
    Bite { index: usize, problem: String },
    /// The driveline's model file (for the wear index) is not a valid model.
    #[error("drivelines[{index}].model: {source}")]
    Model {
        index: usize,
        #[source]
        source: millgate_sim::model::ModelError,
    },
}

/// One analysed bite, as printed by the demo and logged by the service.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteReport {
    pub driveline: usize,
    pub driveline_name: String,
    pub channel_name: String,
    /// Index of the trigger sample in the channel's stream since start.
    pub trigger_sample: u64,
    /// Wall-clock time of the trigger: counted back from the receive time of the
    /// window's last sample when the reader gave one (CAN kernel timestamps), else
    /// from when the window completed here.
    pub time: SystemTime,
    /// When the window's last sample was handed to analysis (before the analysis ran).
    pub window_complete: Instant,
    pub transient: TransientResult,
    /// Natural frequencies from the eq. (1) fit, Hz, when it converged.
    pub beta_hz: Option<(f64, f64)>,
    /// The window had gaps, NaN or saturated samples.
    pub degraded: bool,
    /// Wear measures against the linear reference; `None` without a driveline model
    /// or when the bite has no TAF.
    pub wear: Option<WearEstimate>,
}

/// Bite detection and analysis of one driveline.
struct DrivelineAnalyzer {
    index: usize,
    name: String,
    channel_name: String,
    sample_rate_hz: f64,
    detector: Detector,
    state: DetectorState,
    transient: TransientSettings,
    taf_warning: f64,
    taf_alarm: f64,
    /// Rise above the baseline that marks the load onset for the fit, kN*m.
    onset_knm: f64,
    trigger_high: bool,
    /// Linear references, when the driveline has a model file.
    wear: Option<WearReference>,
}

impl DrivelineAnalyzer {
    fn new(index: usize, driveline: &Driveline, torque: &Channel) -> Result<Self, AnalysisError> {
        let fs = torque.sample_rate_hz;
        let bite = driveline.bite;
        let problem = |problem: String| AnalysisError::Bite { index, problem };
        let post_trigger_samples = (bite.post_trigger_s * fs).round() as usize;
        let pre_trigger_samples = (bite.pre_trigger_s * fs).round() as usize;
        if pre_trigger_samples > PRE_TRIGGER_CAPACITY
            || post_trigger_samples > WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
        {
            return Err(problem(format!(
                "pre_trigger_s {} and post_trigger_s {} at {fs} Hz need {pre_trigger_samples} + \
                 {post_trigger_samples} samples (at most {PRE_TRIGGER_CAPACITY} + {})",
                bite.pre_trigger_s,
                bite.post_trigger_s,
                WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
            )));
        }
        // i16 samples: the ends of the raw range are saturation.
        let raw_limit = |raw: i16| f64::from(raw) * torque.scale + torque.offset;
        let (low, high) = (raw_limit(i16::MIN + 1), raw_limit(i16::MAX));
        let settings = BiteSettings {
            threshold_knm: bite.threshold_knm,
            rearm_knm: bite.threshold_knm / 2.0,
            holdoff_samples: post_trigger_samples as u32,
            // Baseline time constant 0.5 s: follows a drifting zero, not a bite.
            baseline_alpha: 1.0 / (0.5 * fs).max(1.0),
            saturation_low_knm: low.min(high),
            saturation_high_knm: low.max(high),
            post_trigger_samples,
        };
        let detector = Detector::new(settings).map_err(|e| problem(format!("{e:?}")))?;
        let mut transient = TransientSettings {
            sample_rate_hz: fs,
            period_lowpass_hz: PERIOD_LOWPASS_HZ.min(0.4 * fs),
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: bite.threshold_knm / 2.0,
            reference_shift_s: None,
        };
        let onset_knm = 0.1 * bite.threshold_knm;
        let wear = match &driveline.model {
            Some(path) => {
                let model = millgate_sim::model::Model::load(path)
                    .map_err(|source| AnalysisError::Model { index, source })?;
                match millgate_sim::wear_map::default_period_lowpass_hz(&model) {
                    Ok(cutoff) if cutoff > 0.0 => {
                        transient.period_lowpass_hz = cutoff.min(0.4 * fs);
                    }
                    Ok(_) => {}
                    Err(error) => tracing::warn!(
                        driveline = %driveline.name,
                        %error,
                        cutoff_hz = transient.period_lowpass_hz,
                        "no modes of the model: periods measured with the default cut-off"
                    ),
                }
                let mut wear =
                    WearReference::new(&model, detector, transient, onset_knm, bite.pre_trigger_s);
                // Simulate the model's own load level now: a model that cannot give a
                // reference is reported at start, not at the first bite.
                match wear.reference(model.load.static_torque) {
                    Ok(reference) => tracing::info!(
                        driveline = %driveline.name,
                        period_lowpass_hz = transient.period_lowpass_hz,
                        level_knm = reference.level_knm,
                        reference_taf = reference.taf,
                        reference_shift_s = ?reference.period_shift_s,
                        "linear wear reference"
                    ),
                    Err(error) => tracing::warn!(
                        driveline = %driveline.name,
                        %error,
                        "no linear wear reference at the model's load"
                    ),
                }
                Some(wear)
            }
            None => None,
        };
        Ok(Self {
            index,
            name: driveline.name.clone(),
            channel_name: torque.name.clone(),
            sample_rate_hz: fs,
            state: detector.state(),
            detector,
            transient,
            taf_warning: driveline.thresholds.taf_warning,
            taf_alarm: driveline.thresholds.taf_alarm,
            onset_knm,
            trigger_high: false,
            wear,
        })
    }

    /// Wear measures of an analysed bite, when the driveline has a model.
    fn wear_estimate(&mut self, transient: &TransientResult) -> Option<WearEstimate> {
        let wear = self.wear.as_mut()?;
        let taf = transient.taf?;
        match wear.estimate(transient.static_torque_knm, taf, transient.period_shift_s) {
            Ok(estimate) => estimate,
            Err(error) => {
                tracing::warn!(driveline = %self.name, %error, "no wear index for this bite");
                None
            }
        }
    }

    /// The report of a completed window whose last sample was received at
    /// `last_sample_time` (now when unknown).
    fn report(
        &mut self,
        event: &BiteEvent<WINDOW_CAPACITY>,
        last_sample_time: Option<SystemTime>,
    ) -> Option<BiteReport> {
        let window_complete = Instant::now();
        let result = analyze_window(
            &event.window,
            event.trigger_index,
            event.baseline_knm,
            self.onset_knm,
            &self.transient,
        );
        let analysis = match result {
            Ok(analysis) => analysis,
            Err(error) => {
                tracing::warn!(driveline = %self.name, ?error, "bite window not analysable");
                return None;
            }
        };
        // The last window sample is `len - 1 - trigger_index` samples after the trigger.
        let after_trigger =
            (event.window.len() - 1 - event.trigger_index) as f64 / self.sample_rate_hz;
        Some(BiteReport {
            driveline: self.index,
            driveline_name: self.name.clone(),
            channel_name: self.channel_name.clone(),
            trigger_sample: event.trigger_sample,
            time: before(
                last_sample_time.unwrap_or_else(SystemTime::now),
                after_trigger,
            ),
            window_complete,
            transient: analysis.transient,
            beta_hz: analysis.good_fit().map(|fit| (fit.f1_hz, fit.f2_hz)),
            degraded: !event.quality.is_good(),
            wear: self.wear_estimate(&analysis.transient),
        })
    }

    /// Process `values`, the last of which was received at `received` (when known).
    fn samples(
        &mut self,
        values: &[f64],
        received: Option<SystemTime>,
        reports: &mut Vec<BiteReport>,
    ) {
        for (i, &value) in values.iter().enumerate() {
            if let Some(event) = self.detector.process(&mut self.state, value) {
                let later = (values.len() - 1 - i) as f64 / self.sample_rate_hz;
                let time = received.map(|last| before(last, later));
                reports.extend(self.report(&event, time));
            }
        }
    }

    fn gap(&mut self, missed: Option<u64>, reports: &mut Vec<BiteReport>) {
        if let Some(event) = self.detector.gap(&mut self.state, missed.unwrap_or(0)) {
            reports.extend(self.report(&event, None));
        }
    }

    /// "Metal in stand": a rising edge through 0.5 triggers a capture.
    fn trigger_value(&mut self, value: f64) {
        let high = value > 0.5;
        if high && !self.trigger_high {
            self.detector.trigger(&mut self.state);
        }
        self.trigger_high = high;
    }
}

/// `time` moved back by `seconds` (>= 0), saturating at the Unix epoch.
fn before(time: SystemTime, seconds: f64) -> SystemTime {
    time.checked_sub(std::time::Duration::from_secs_f64(seconds.max(0.0)))
        .unwrap_or(UNIX_EPOCH)
}

/// Record a bite in the published results.
fn publish(publisher: &Publisher, report: &BiteReport, taf_warning: f64, taf_alarm: f64) {
    publisher.update(|results| {
        let driveline = &mut results.drivelines[report.driveline];
        let t = &report.transient;
        driveline.bite_counter = driveline.bite_counter.wrapping_add(1);
        driveline.last_bite_unix_s = report
            .time
            .duration_since(UNIX_EPOCH)
            .ok()
            .and_then(|d| u32::try_from(d.as_secs()).ok());
        driveline.static_torque_knm = Some(t.static_torque_knm);
        driveline.peak_torque_knm = Some(t.peak_torque_knm);
        driveline.taf = t.taf;
        driveline.first_period_shift_s = t.period_shift_s;
        driveline.beta1_hz = report.beta_hz.map(|(beta1, _)| beta1);
        driveline.beta2_hz = report.beta_hz.map(|(_, beta2)| beta2);
        driveline.last_bite_degraded = report.degraded;
        driveline.warning = t.taf.is_some_and(|taf| taf >= taf_warning);
        driveline.alarm |= t.taf.is_some_and(|taf| taf >= taf_alarm);
        driveline.wear_index = report.wear.map(|wear| wear.index);
        if let (Some(index), false) = (driveline.wear_index, report.degraded) {
            driveline.wear_trend = Some(wear::next_trend(driveline.wear_trend, index));
        }
    });
}

/// The analysis task: consumes samples until every reader has hung up.
pub struct Analysis {
    drivelines: Vec<DrivelineAnalyzer>,
    /// Per channel: the drivelines whose torque it is.
    by_torque: Vec<Vec<usize>>,
    /// Per channel: the drivelines it triggers.
    by_trigger: Vec<Vec<usize>>,
    publisher: Arc<Publisher>,
    bites: broadcast::Sender<BiteReport>,
    /// Chatter monitors of the tandem mills.
    chatter: chatter_monitor::ChatterAnalysis,
}

impl Analysis {
    /// Analysers for every driveline and chatter monitors for every tandem mill of
    /// `config`.
    pub fn new(
        config: &Config,
        publisher: Arc<Publisher>,
        bites: broadcast::Sender<BiteReport>,
    ) -> Result<Self, AnalysisError> {
        let mut by_torque = vec![Vec::new(); config.channels.len()];
        let mut by_trigger = vec![Vec::new(); config.channels.len()];
        let mut drivelines = Vec::new();
        for (index, driveline) in config.drivelines.iter().enumerate() {
            let torque = &config.channels[driveline.torque];
            drivelines.push(DrivelineAnalyzer::new(index, driveline, torque)?);
            by_torque[driveline.torque].push(index);
            if let Some(trigger) = driveline.metal_in_stand {
                by_trigger[trigger].push(index);
            }
        }
        let chatter = chatter_monitor::ChatterAnalysis::new(config, Arc::clone(&publisher))?;
        Ok(Self {
            drivelines,
            by_torque,
            by_trigger,
            publisher,
            bites,
            chatter,
        })
    }

    /// Handle one message from a reader; returns the bites it completed.
    pub fn handle(&mut self, message: Acquired) -> Vec<BiteReport> {
        self.chatter.handle(&message);
        let mut reports = Vec::new();
        match message {
            Acquired::Samples {
                channel,
                values,
                received,
            } => {
                for &d in &self.by_torque[channel] {
                    self.drivelines[d].samples(&values, received, &mut reports);
                }
            }
            Acquired::Gap {
                channel,
                missed_samples,
            } => {
                for &d in &self.by_torque[channel] {
                    self.drivelines[d].gap(missed_samples, &mut reports);
                }
            }
            Acquired::ProcessValue { channel, value } => {
                for &d in &self.by_trigger[channel] {
                    self.drivelines[d].trigger_value(value);
                }
            }
        }
        for report in &reports {
            let analyzer = &self.drivelines[report.driveline];
            publish(
                &self.publisher,
                report,
                analyzer.taf_warning,
                analyzer.taf_alarm,
            );
            tracing::info!(
                driveline = %report.driveline_name,
                static_knm = report.transient.static_torque_knm,
                peak_knm = report.transient.peak_torque_knm,
                taf = ?report.transient.taf,
                beta_hz = ?report.beta_hz,
                degraded = report.degraded,
                wear_index = ?report.wear.map(|wear| wear.index),
                shift_over_linear_s = ?report.wear.and_then(|wear| wear.shift_excess_s),
                "bite"
            );
            // Nobody listening is fine: the demo and tests subscribe, the service need not.
            let _ = self.bites.send(report.clone());
        }
        reports
    }

    /// Run until every sender of `samples` is dropped.
    pub async fn run(mut self, mut samples: mpsc::Receiver<Acquired>) {
        while let Some(message) = samples.recv().await {
            self.handle(message);
        }
    }
}
