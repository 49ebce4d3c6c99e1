//! One driveline's bites: detection on its torque channel (and its "metal in stand"
//! trigger), the window analysis, the wear index against its model, and the results
//! published for the register map.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use millgate_config::{Channel, Driveline};
use millgate_dsp::bite::{BiteEvent, BiteSettings};
use millgate_dsp::transient::{TransientQuality, TransientResult, TransientSettings};
use millgate_sim::model::Model;

use super::bite_window::{
    analyze_window, Detector, DetectorState, PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY,
};
use super::error::AnalysisError;
use super::extra_channels::ExtraRing;
use super::gap_estimate::{GapEstimate, GapObservation};
use super::gap_monitor::{GapBite, GapMapJob, GapMonitor};
use super::simulated_bite::BiteSimulator;
use super::wear::{self, WearEstimate, WearReference};
use crate::state::board::Board;
use crate::state::captures::{
    unix_ns, BiteWindowAnalysis, CaptureChannel, CaptureGap, CaptureKind, CaptureRecord,
    CapturedBite, KeepClass,
};
use crate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, BiteRecord, HistoryEvent, PooledBite, StateRecord,
    SubjectResults, WearState,
};
use crate::state::gap_maps::{GapMapSpec, GapMaps};
use crate::state::results::DrivelineResults;
use crate::state::time::UtcTime;

/// Low-pass cut-off for period measurement of a driveline without a model, Hz: keeps
/// the first modes (10-30 Hz, domain notes 1.3) and removes measurement noise above
/// them. With a model the wear map's cut-off is used (1.5 x its second mode), so
/// measured period shifts compare with the maps.
const PERIOD_LOWPASS_HZ: f64 = 40.0;
/// Peak low-pass cut-off over the period cut-off of a driveline with a model (3x its
/// second mode): the oscillation's peak passes (a 21 Hz mode loses 1% of its amplitude),
/// noise is cut to a quarter at 2 kHz, and the maps are analysed alike.
const PEAK_OVER_PERIOD_CUTOFF: f64 = 2.0;

/// One analysed bite, as printed by the demo and logged by the service.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteReport {
    /// Index of the driveline in the configuration.
    pub driveline: usize,
    /// The driveline's name.
    pub driveline_name: String,
    /// The torque channel's name.
    pub channel_name: String,
    /// Index of the trigger sample in the channel's stream since start.
    pub trigger_sample: u64,
    /// Wall-clock time of the trigger: counted back from the receive time of the
    /// window's last sample when the reader gave one (CAN kernel timestamps), else
    /// from when the block that completed the window was handled here (its last
    /// sample taken then, the window's last one period by period before it).
    pub time: SystemTime,
    /// When the window's last sample was handed to analysis (before the analysis ran).
    pub window_complete: Instant,
    /// Static torque, peak, TAF and periods.
    pub transient: TransientResult,
    /// Natural frequencies from the eq. (1) fit, Hz, when it converged to frequencies
    /// the window resolves (above one cycle in the fitted record, below Nyquist).
    pub beta_hz: Option<(f64, f64)>,
    /// The first mode's damping ratio of that fit, with `beta_hz`.
    pub first_mode_damping: Option<f64>,
    /// The window had gaps, NaN or saturated samples.
    pub degraded: bool,
    /// TAF-ratio wear index against the linear reference; `None` without a driveline
    /// model or when the bite has no TAF.
    pub wear: Option<WearEstimate>,
    /// The bite's gap observation and the gap estimates; `None` without a model, for a
    /// degraded window or a bite without TAF.
    pub gap: Option<GapBite>,
    /// The window's samples as analysed, when the driveline keeps captures.
    pub samples: Option<Arc<BiteSamples>>,
}

/// A bite window's samples as the analysis read them: what its capture keeps.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteSamples {
    /// The torque channel with the window's samples.
    pub torque: CaptureChannel,
    /// Time of the window's first sample.
    pub first_sample: SystemTime,
    /// That time is counted back from a CAN kernel receive timestamp.
    pub kernel_time: bool,
    /// A gap ended the window (the capture's end).
    pub gap: Option<CaptureGap>,
    /// Trigger, baseline and the settings it was analysed with.
    pub analysis: BiteWindowAnalysis,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// The driveline's extra channels over the window, row for row with the torque
    /// (filled when the bite is released to the history).
    pub extra: Vec<CaptureChannel>,
}

/// Bite detection and analysis of one driveline.
#[derive(Debug)]
pub(super) struct DrivelineAnalyzer {
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
    /// The gap diagnosis, when the driveline has a model file.
    gap: Option<GapMonitor>,
    /// The maps to build, until the service takes the job.
    gap_job: Option<GapMapJob>,
    /// Why a driveline naming a model runs without wear diagnosis.
    wear_problem: Option<AnalysisError>,
    /// The torque channel as a capture describes it, when captures are kept.
    capture: Option<CaptureChannel>,
    /// A manual capture being taken (`Command::CaptureTorque`).
    manual: Option<ManualCapture>,
    /// The extra channels' latest samples, when captures are kept.
    extras: Vec<ExtraRing>,
}

/// How one driveline's bites are detected and analysed, from its configuration and
/// model: shared by the service, the wear references and gap maps (simulated bites
/// analysed like measured ones) and `millgate wear`.
#[derive(Debug, Clone, Copy)]
pub struct BiteSetup {
    /// The bite detector.
    pub detector: Detector,
    /// The transient analysis settings.
    pub transient: TransientSettings,
    /// Rise above the baseline that marks the load onset for the fit, kN*m.
    pub onset_knm: f64,
    /// Capture before the trigger, s.
    pub pre_trigger_s: f64,
}

impl BiteSetup {
    /// The setup of driveline `index` called `name` with capture settings `bite`,
    /// measured at `fs` Hz, whose samples saturate at or beyond `saturation_knm` (low,
    /// high; kN*m); with its `model` the analysis low-passes periods at 1.5x the
    /// model's second mode (the wear maps' cut-off) and the peak at twice that, so that
    /// noise does not raise the TAF the gap is estimated from.
    pub fn new(
        index: usize,
        name: &str,
        bite: &millgate_config::BiteSettings,
        fs: f64,
        saturation_knm: (f64, f64),
        model: Option<&Model>,
    ) -> Result<Self, AnalysisError> {
        let post_trigger_samples = (bite.post_trigger_s * fs).round() as usize;
        let pre_trigger_samples = (bite.pre_trigger_s * fs).round() as usize;
        if pre_trigger_samples > PRE_TRIGGER_CAPACITY
            || post_trigger_samples > WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
        {
            return Err(AnalysisError::BiteWindow {
                index,
                pre_trigger_s: bite.pre_trigger_s,
                post_trigger_s: bite.post_trigger_s,
                sample_rate_hz: fs,
                pre_samples: pre_trigger_samples,
                post_samples: post_trigger_samples,
            });
        }
        // The readers already turn saturated samples into gaps; the detector marks any
        // that reach it (a window with one is degraded, its values not published).
        let (low, high) = saturation_knm;
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
        let detector = Detector::new(settings)
            .map_err(|source| AnalysisError::BiteSettings { index, source })?;
        let mut transient = TransientSettings {
            sample_rate_hz: fs,
            period_lowpass_hz: PERIOD_LOWPASS_HZ.min(0.4 * fs),
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: bite.threshold_knm / 2.0,
            reference_shift_s: None,
        };
        if let Some(model) = model {
            match millgate_sim::wear_map::default_period_lowpass_hz(model) {
                Ok(cutoff) if cutoff > 0.0 => {
                    transient.period_lowpass_hz = cutoff.min(0.4 * fs);
                    transient.peak_lowpass_hz =
                        Some((PEAK_OVER_PERIOD_CUTOFF * cutoff).min(0.4 * fs));
                }
                Ok(_) => {}
                Err(error) => tracing::warn!(
                    driveline = %name,
                    %error,
                    cutoff_hz = transient.period_lowpass_hz,
                    "no modes of the model: periods measured with the default cut-off"
                ),
            }
        }
        Ok(Self {
            detector,
            transient,
            onset_knm: 0.1 * bite.threshold_knm,
            pre_trigger_s: bite.pre_trigger_s,
        })
    }

    /// Bites of `model` simulated and analysed with this setup.
    pub fn simulator(&self, model: &Model) -> BiteSimulator {
        BiteSimulator::new(model, self.detector, self.transient, self.pre_trigger_s)
    }
}

/// The driveline's model and what is built from it, or the problem that keeps the
/// wear diagnosis off.
struct ModelParts {
    model: Model,
    spec: GapMapSpec,
}

fn model_parts(
    index: usize,
    driveline: &Driveline,
    path: &Path,
) -> Result<ModelParts, AnalysisError> {
    let model = Model::load(path).map_err(|source| AnalysisError::Model { index, source })?;
    let spec = GapMapSpec::new(index, &driveline.wear, &model, driveline.bite.threshold_knm)
        .map_err(|source| AnalysisError::GapMaps {
            index,
            source: Box::new(source),
        })?;
    Ok(ModelParts { model, spec })
}

impl DrivelineAnalyzer {
    /// The analyser of driveline `index` measured on `torque`; its gap maps (when it
    /// has a model) are left to build as a [`GapMapJob`] with the cache in `cache_dir`.
    /// A model that does not load or does not fit the `wear` settings is not an error
    /// here: the driveline runs without wear diagnosis and [`Self::wear_problem`] says
    /// why.
    pub(super) fn new(
        index: usize,
        driveline: &Driveline,
        torque: &Channel,
        cache_dir: &Path,
    ) -> Result<Self, AnalysisError> {
        let parts = driveline
            .model
            .as_ref()
            .map(|path| model_parts(index, driveline, path));
        let (parts, wear_problem) = match parts {
            Some(Ok(parts)) => (Some(parts), None),
            Some(Err(problem)) => {
                tracing::error!(driveline = %driveline.name, %problem, "no wear diagnosis");
                (None, Some(problem))
            }
            None => (None, None),
        };
        // The ends of the channel's raw range (field::quality, as the readers use).
        let limits = crate::field::quality::saturation_limits(torque);
        let setup = BiteSetup::new(
            index,
            &driveline.name,
            &driveline.bite,
            torque.sample_rate_hz,
            (limits.low, limits.high),
            parts.as_ref().map(|p| &p.model),
        )?;
        let mut wear = None;
        let mut gap = None;
        let mut gap_job = None;
        if let (Some(parts), Some(path)) = (parts, &driveline.model) {
            let simulator = setup.simulator(&parts.model);
            let mut reference = WearReference::new(simulator.clone());
            // Simulate the model's own load level now: a model that cannot give a
            // reference is reported at start, not at the first bite.
            match reference.reference(parts.model.load.static_torque) {
                Ok(reference) => tracing::info!(
                    driveline = %driveline.name,
                    period_lowpass_hz = setup.transient.period_lowpass_hz,
                    peak_lowpass_hz = ?setup.transient.peak_lowpass_hz,
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
            wear = Some(reference);
            gap = Some(GapMonitor::new(
                &driveline.thresholds,
                driveline.wear.pool_bites,
            ));
            gap_job = Some(GapMapJob::new(
                index,
                &driveline.name,
                path,
                simulator,
                parts.spec,
                cache_dir,
            ));
        }
        Ok(Self {
            index,
            name: driveline.name.clone(),
            channel_name: torque.name.clone(),
            sample_rate_hz: torque.sample_rate_hz,
            state: setup.detector.state(),
            detector: setup.detector,
            transient: setup.transient,
            taf_warning: driveline.thresholds.taf_warning,
            taf_alarm: driveline.thresholds.taf_alarm,
            onset_knm: setup.onset_knm,
            trigger_high: false,
            wear,
            gap,
            gap_job,
            wear_problem,
            capture: None,
            manual: None,
            extras: Vec::new(),
        })
    }

    /// Start keeping the next `seconds` s of torque as a manual capture (a capture
    /// already running starts again); false when captures are not kept.
    pub(super) fn start_manual_capture(&mut self, seconds: f64) -> bool {
        if self.capture.is_none() {
            return false;
        }
        self.manual = Some(ManualCapture {
            remaining: (seconds * self.sample_rate_hz).ceil().max(1.0) as usize,
            samples: Vec::new(),
            first_sample: None,
            kernel_time: false,
            gaps: Vec::new(),
        });
        true
    }

    /// The manual capture, once its samples are all in.
    pub(super) fn take_manual_capture(&mut self) -> Option<CaptureRecord> {
        if self.manual.as_ref()?.remaining > 0 {
            return None;
        }
        let manual = self.manual.take()?;
        let torque = self.capture.as_ref()?;
        Some(CaptureRecord {
            kind: CaptureKind::Manual,
            subject: self.name.clone(),
            bite: None,
            first_sample_unix_ns: unix_ns(manual.first_sample.unwrap_or(UNIX_EPOCH)),
            kernel_time: manual.kernel_time,
            sample_rate_hz: self.sample_rate_hz,
            channels: vec![CaptureChannel {
                samples: manual.samples,
                ..torque.clone()
            }],
            gaps: manual.gaps,
            analysis: None,
            episode: None,
            keep: KeepClass::Important,
        })
    }

    /// Keep each bite window's samples for its capture (`[history]` with captures on),
    /// describing the torque channel as `torque`.
    /// With `extra` (the driveline's `extra_channels`), each kept in a ring of
    /// `ring_capacity` samples for the bites' captures.
    pub(super) fn keep_captures(
        &mut self,
        torque: &Channel,
        extra: &[&Channel],
        ring_capacity: usize,
    ) {
        let describe = |channel: &Channel| CaptureChannel {
            name: channel.name.clone(),
            unit: channel.unit.clone(),
            scale: channel.scale,
            offset: channel.offset,
            samples: Vec::new(),
            timing: None,
        };
        self.capture = Some(describe(torque));
        self.extras = extra
            .iter()
            .map(|channel| ExtraRing::new(describe(channel), channel.sample_rate_hz, ring_capacity))
            .collect();
    }

    /// Samples of extra channel `extra` (its position in `extra_channels`), the last
    /// received at `received` (when known).
    pub(super) fn extra_samples(
        &mut self,
        extra: usize,
        values: &[f64],
        received: Option<SystemTime>,
    ) {
        if let Some(ring) = self.extras.get_mut(extra) {
            ring.push(values, received);
        }
    }

    /// Samples of extra channel `extra` were lost.
    pub(super) fn extra_gap(&mut self, extra: usize) {
        if let Some(ring) = self.extras.get_mut(extra) {
            ring.gap();
        }
    }

    /// Whether every extra channel has samples up to the end of `report`'s window
    /// (true without extra channels or captures).
    pub(super) fn extras_reach_window_end(&self, report: &BiteReport) -> bool {
        let Some(samples) = &report.samples else {
            return true;
        };
        let rows = samples.torque.samples.len().saturating_sub(1);
        let end =
            samples.first_sample + Duration::from_secs_f64(rows as f64 / samples.sample_rate_hz);
        self.extras.iter().all(|ring| ring.reaches(end))
    }

    /// Put the extra channels over `report`'s window into its capture (what the rings
    /// hold of it: missing rows are NaN, see [`ExtraRing::capture`]).
    pub(super) fn capture_extras(&self, report: &mut BiteReport) {
        if self.extras.is_empty() {
            return;
        }
        if let Some(samples) = report.samples.as_mut() {
            let samples = Arc::make_mut(samples);
            let rows = samples.torque.samples.len();
            samples.extra = self
                .extras
                .iter()
                .map(|ring| ring.capture(samples.first_sample, rows))
                .collect();
        }
    }

    /// Why the driveline runs without wear diagnosis although it names a model.
    pub(super) fn wear_problem(&self) -> Option<&AnalysisError> {
        self.wear_problem.as_ref()
    }

    /// The build of the gap maps, once (the service runs it off the analysis task).
    pub(super) fn take_gap_map_job(&mut self) -> Option<GapMapJob> {
        self.gap_job.take()
    }

    /// Install the gap maps (or note they failed); returns the pooled estimate of the
    /// bites seen so far, to publish.
    pub(super) fn set_gap_maps(&mut self, maps: Option<Arc<GapMaps>>) -> Option<GapEstimate> {
        self.gap.as_mut()?.set_maps(maps)
    }

    /// Replace the gap pool by `observations` (oldest first; restored from history).
    pub(super) fn restore_gap_pool(
        &mut self,
        observations: Vec<GapObservation>,
    ) -> Option<GapEstimate> {
        self.gap.as_mut()?.restore(observations)
    }

    /// The gap pool's saved form, when the driveline has a model.
    pub(super) fn gap_pool(&self) -> Option<Vec<GapObservation>> {
        self.gap.as_ref().map(GapMonitor::observations)
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

    /// The report of a completed window whose last sample was taken at
    /// `last_sample_time` (now when unknown), a time counted back from a kernel
    /// receive timestamp when `kernel_time`.
    fn report(
        &mut self,
        event: &BiteEvent<WINDOW_CAPACITY>,
        last_sample_time: Option<SystemTime>,
        kernel_time: bool,
        ended_by_gap: Option<Option<u64>>,
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
                tracing::warn!(driveline = %self.name, %error, "bite window not analysable");
                return None;
            }
        };
        // The last window sample is `len - 1 - trigger_index` samples after the trigger.
        let after_trigger =
            (event.window.len() - 1 - event.trigger_index) as f64 / self.sample_rate_hz;
        let degraded = !event.quality.is_good();
        let transient = &self.transient;
        let gap = self
            .gap
            .as_mut()
            .filter(|_| !degraded)
            .and_then(|gap| gap.observe(&event.window, &analysis.transient, transient));
        let time = before(
            last_sample_time.unwrap_or_else(SystemTime::now),
            after_trigger,
        );
        let samples = self.capture.as_ref().map(|torque| {
            Arc::new(BiteSamples {
                torque: CaptureChannel {
                    samples: event.window.to_vec(),
                    ..torque.clone()
                },
                first_sample: before(time, event.trigger_index as f64 / self.sample_rate_hz),
                kernel_time,
                gap: ended_by_gap.map(|missed_samples| CaptureGap {
                    before_sample: event.window.len(),
                    missed_samples,
                }),
                analysis: BiteWindowAnalysis {
                    trigger_index: event.trigger_index,
                    baseline_knm: event.baseline_knm,
                    onset_knm: self.onset_knm,
                    period_lowpass_hz: self.transient.period_lowpass_hz,
                    peak_lowpass_hz: self.transient.peak_lowpass_hz,
                    settled_fraction: self.transient.settled_fraction,
                    min_static_knm: self.transient.min_static_knm,
                },
                sample_rate_hz: self.sample_rate_hz,
                extra: Vec::new(),
            })
        });
        Some(BiteReport {
            driveline: self.index,
            driveline_name: self.name.clone(),
            channel_name: self.channel_name.clone(),
            trigger_sample: event.trigger_sample,
            time,
            window_complete,
            transient: analysis.transient,
            beta_hz: analysis.natural_frequencies_hz(),
            first_mode_damping: analysis.first_mode_damping(),
            degraded,
            wear: self.wear_estimate(&analysis.transient),
            gap,
            samples,
        })
    }

    /// Process `values`, the last of which was received at `received` (when known).
    pub(super) fn samples(
        &mut self,
        values: &[f64],
        received: Option<SystemTime>,
        reports: &mut Vec<BiteReport>,
    ) {
        if let Some(manual) = self.manual.as_mut() {
            if manual.first_sample.is_none() {
                // The first sample's time: the last's, or now's without one (a
                // Modbus DAQ), moved back over the block.
                let last = received.unwrap_or_else(SystemTime::now);
                let span = values.len().saturating_sub(1) as f64 / self.sample_rate_hz;
                manual.first_sample = Some(before(last, span));
                manual.kernel_time = received.is_some();
            }
            let take = manual.remaining.min(values.len());
            manual.samples.extend_from_slice(&values[..take]);
            manual.remaining -= take;
        }
        for (i, &value) in values.iter().enumerate() {
            if let Some(event) = self.detector.process(&mut self.state, value) {
                // The window's last sample is `later` before the block's last: dated
                // from its receive time, or (a Modbus DAQ) from now, as the extra
                // channels' samples are.
                let later = (values.len() - 1 - i) as f64 / self.sample_rate_hz;
                let last = received.unwrap_or_else(SystemTime::now);
                let time = before(last, later);
                reports.extend(self.report(&event, Some(time), received.is_some(), None));
            }
        }
    }

    pub(super) fn gap(&mut self, missed: Option<u64>, reports: &mut Vec<BiteReport>) {
        if let Some(manual) = self.manual.as_mut().filter(|m| !m.samples.is_empty()) {
            manual.gaps.push(CaptureGap {
                before_sample: manual.samples.len(),
                missed_samples: missed,
            });
        }
        if let Some(event) = self.detector.gap(&mut self.state, missed.unwrap_or(0)) {
            reports.extend(self.report(&event, None, false, Some(missed)));
        }
    }

    /// Record `report`, a bite of this driveline, in the published results and the
    /// history (the bite, and its warning and alarm changes).
    ///
    /// A degraded bite (its window held a gap, a saturated or a non-finite sample) is
    /// counted and dated, and flagged degraded, but its values are not valid: they are
    /// published with their quality bits clear (registers 0), raise no TAF warning or
    /// alarm, and do not move the wear trend. Nothing computed from data that cannot be
    /// trusted reads as a result.
    pub(super) fn publish(&self, board: &Board, report: &BiteReport) {
        board.update_recorded(|results, events| {
            let driveline = &mut results.drivelines[report.driveline];
            let (was_warning, was_alarm) = (driveline.taf_warning, driveline.taf_alarm);
            let time = UtcTime::from_system(report.time);
            let t = &report.transient;
            let valid = !report.degraded;
            let trusted = |value: Option<f64>| value.filter(|_| valid);
            driveline.bite_counter = driveline.bite_counter.wrapping_add(1);
            driveline.degraded_bites = driveline
                .degraded_bites
                .wrapping_add(u32::from(report.degraded));
            driveline.last_bite_unix_ms = Some(time.unix_ms());
            window_figures(driveline, report, valid);
            driveline.last_bite_degraded = report.degraded;
            let taf = trusted(t.taf);
            driveline.taf_warning = taf.is_some_and(|taf| taf >= self.taf_warning);
            driveline.taf_alarm |= taf.is_some_and(|taf| taf >= self.taf_alarm);
            driveline.wear_index = trusted(report.wear.map(|wear| wear.index));
            if let Some(index) = driveline.wear_index {
                driveline.wear_trend = Some(wear::next_trend(driveline.wear_trend, index));
            }
            let gap = report
                .gap
                .and_then(|gap| Some((self.gap.as_ref()?, gap.pooled?)));
            let mut gap_alarms = Vec::new();
            if let Some((monitor, estimate)) = gap {
                let subject = (report.driveline_name.as_str(), time);
                monitor.publish(driveline, &estimate, subject, &mut gap_alarms);
            }
            driveline.restored = false;
            let record = bite_record(
                report,
                driveline,
                gap.map(|(monitor, estimate)| monitor.verdict(&estimate)),
            );
            let bite = CapturedBite {
                counter: driveline.bite_counter,
                time,
            };
            let raised_gap_alarm = gap_alarms.iter().any(|event| {
                matches!(event, HistoryEvent::Alarm(a) if a.kind == AlarmKind::GapAlarm && a.event == AlarmEvent::Raised)
            });
            let keep = if taf.is_some_and(|taf| taf >= self.taf_alarm) || raised_gap_alarm {
                KeepClass::Important
            } else if driveline.taf_warning || driveline.gap_warning {
                KeepClass::Warning
            } else {
                KeepClass::Ordinary
            };
            let capture = report.capture(bite, keep);
            events.push(match capture {
                Some(capture) => HistoryEvent::CapturedBite(Box::new(record), Box::new(capture)),
                None => HistoryEvent::Bite(Box::new(record)),
            });
            let alarm = |kind, event, value, threshold| {
                HistoryEvent::Alarm(AlarmRecord {
                    time,
                    subject: report.driveline_name.clone(),
                    kind,
                    event,
                    origin: None,
                    value,
                    threshold: Some(threshold),
                })
            };
            if driveline.taf_warning != was_warning {
                let event = if driveline.taf_warning {
                    AlarmEvent::Raised
                } else {
                    AlarmEvent::Cleared
                };
                events.push(alarm(AlarmKind::TafWarning, event, t.taf, self.taf_warning));
            }
            if driveline.taf_alarm && !was_alarm {
                events.push(alarm(
                    AlarmKind::TafAlarm,
                    AlarmEvent::Raised,
                    t.taf,
                    self.taf_alarm,
                ));
            }
            events.extend(gap_alarms);
        });
    }

    /// Record `estimate` (from maps just installed or a restored pool) in the results,
    /// with the alarm events it makes.
    pub(super) fn publish_gap(&self, board: &Board, estimate: &GapEstimate) {
        if let Some(monitor) = &self.gap {
            board.update_recorded(|results, events| {
                let time = UtcTime::now();
                let driveline = &mut results.drivelines[self.index];
                monitor.publish(driveline, estimate, (self.name.as_str(), time), events);
                events.push(HistoryEvent::State(StateRecord {
                    time,
                    subject: self.name.clone(),
                    results: SubjectResults::Driveline(driveline.clone()),
                }));
            });
        }
    }

    /// Empty the gap pool (the reset command).
    pub(super) fn reset_gap_pool(&mut self) {
        if let Some(monitor) = &mut self.gap {
            monitor.reset();
        }
    }

    /// "Metal in stand": a rising edge through 0.5 triggers a capture.
    pub(super) fn trigger_value(&mut self, value: f64) {
        let high = value > 0.5;
        if high && !self.trigger_high {
            self.detector.trigger(&mut self.state);
        }
        self.trigger_high = high;
    }
}

/// What `report`'s window measured, as figures of `driveline`: its torques, TAF,
/// periods and natural frequencies, each only while `valid` (a degraded window's are
/// no values where they are published; the bite's row keeps them).
fn window_figures(driveline: &mut DrivelineResults, report: &BiteReport, valid: bool) {
    let t = &report.transient;
    let trusted = |value: Option<f64>| value.filter(|_| valid);
    driveline.static_torque_knm = trusted(Some(t.static_torque_knm));
    driveline.peak_torque_knm = trusted(Some(t.peak_torque_knm));
    driveline.taf = trusted(t.taf);
    driveline.first_period_s = trusted(t.first_period_s);
    driveline.first_period_shift_s = trusted(t.period_shift_s);
    driveline.beta1_hz = trusted(report.beta_hz.map(|(beta1, _)| beta1));
    driveline.beta2_hz = trusted(report.beta_hz.map(|(_, beta2)| beta2));
    driveline.first_mode_damping = trusted(report.first_mode_damping);
}

/// The history's record of `report` with the driveline's published `state` after it
/// and, when the bite gave a gap estimate, its verdict (what the analysis records;
/// benches store the same).
pub fn bite_record(
    report: &BiteReport,
    state: &DrivelineResults,
    gap_state: Option<WearState>,
) -> BiteRecord {
    let t = &report.transient;
    let reference = report.wear.map(|wear| wear.reference);
    let mut figures = state.clone();
    window_figures(&mut figures, report, true);
    figures.gap = figures.gap.filter(|_| gap_state.is_some());
    BiteRecord {
        driveline: report.driveline_name.clone(),
        channel: report.channel_name.clone(),
        time: UtcTime::from_system(report.time),
        figures,
        second_period_s: t.second_period_s,
        quality: match t.quality {
            TransientQuality::Good => "good",
            TransientQuality::FewCrossings => "few_crossings",
            TransientQuality::LowStatic => "low_static",
        },
        reference_taf: reference.map(|r| r.taf),
        reference_level_knm: reference.map(|r| r.level_knm),
        shift_over_linear_s: report.wear.and_then(|wear| wear.shift_excess_s),
        gap_state,
        pooled: report.gap.map(|gap| {
            let o = gap.observation;
            PooledBite {
                static_torque_knm: o.static_torque_knm,
                taf: o.taf,
                taf_sigma: o.taf_sigma,
                period_shift_s: o.period_shift_s,
                period_shift_sigma_s: o.period_shift_sigma_s,
            }
        }),
        state: state.clone(),
    }
}

impl BiteReport {
    /// The capture of this bite's window as the history keeps it, for the bite
    /// `bite` of its driveline kept as `keep`; `None` when the driveline keeps no
    /// captures.
    pub fn capture(&self, bite: CapturedBite, keep: KeepClass) -> Option<CaptureRecord> {
        let samples = self.samples.as_ref()?;
        Some(CaptureRecord {
            kind: CaptureKind::Bite,
            subject: self.driveline_name.clone(),
            bite: Some(bite),
            first_sample_unix_ns: unix_ns(samples.first_sample),
            kernel_time: samples.kernel_time,
            sample_rate_hz: samples.sample_rate_hz,
            channels: std::iter::once(&samples.torque)
                .chain(&samples.extra)
                .cloned()
                .collect(),
            gaps: samples.gap.into_iter().collect(),
            analysis: Some(samples.analysis),
            episode: None,
            keep,
        })
    }
}

/// A manual capture of a driveline's torque while it is being taken.
#[derive(Debug)]
struct ManualCapture {
    /// Samples still to take.
    remaining: usize,
    /// The samples taken.
    samples: Vec<f64>,
    /// Time of the first sample.
    first_sample: Option<SystemTime>,
    /// Whether that time is the kernel's (CAN).
    kernel_time: bool,
    /// Where data was lost.
    gaps: Vec<CaptureGap>,
}

/// `time` moved back by `seconds` (>= 0), saturating at the Unix epoch.
fn before(time: SystemTime, seconds: f64) -> SystemTime {
    time.checked_sub(std::time::Duration::from_secs_f64(seconds.max(0.0)))
        .unwrap_or(UNIX_EPOCH)
}
