//! The analyser of one driveline ([`DrivelineAnalyzer`]): built from the
//! configuration and the driveline's model, what it holds between bites, and its gap
//! pool and captures as the analysis task asks for them.

use std::path::Path;
use std::sync::Arc;
use std::time::{Instant, SystemTime};

use millgate_config::{Channel, Config, Driveline, DrivelineThresholds};
use millgate_dsp::transient::TransientSettings;

use super::capture::Captures;
use super::setup::{BiteSetup, ModelParts, WearDiagnosis};
use crate::analysis::bite_window::{Detector, DetectorState};
use crate::analysis::context::{ContextTracker, TagValue};
use crate::analysis::error::AnalysisError;
use crate::analysis::fatigue_ledger::{FatigueLedger, LedgerBite};
use crate::analysis::gap_estimate::GapObservation;
use crate::analysis::gap_monitor::{GapMapJob, GapMonitor};
use crate::analysis::wear::WearReference;
use crate::state::captures::CaptureRecord;
use crate::state::gap_maps::GapMaps;
use crate::state::results::GapResults;
use crate::state::time::UtcTime;

/// Bite detection and analysis of one driveline.
#[derive(Debug)]
pub(crate) struct DrivelineAnalyzer {
    /// Index of the driveline in the configuration.
    pub(super) index: usize,
    /// The driveline's name.
    pub(super) name: String,
    /// The torque channel's name.
    pub(super) channel_name: String,
    /// The torque channel's sample rate, Hz.
    pub(super) sample_rate_hz: f64,
    /// The bite detector.
    pub(super) detector: Detector,
    /// Its state.
    pub(super) state: DetectorState,
    /// The transient analysis settings.
    pub(super) transient: TransientSettings,
    /// TAF warning threshold.
    pub(super) taf_warning: f64,
    /// TAF alarm threshold (latched).
    pub(super) taf_alarm: f64,
    /// Rise above the baseline that marks the load onset for the fit, kN*m.
    pub(super) onset_knm: f64,
    /// The "metal in stand" trigger was high at its last value.
    trigger_high: bool,
    /// Linear references, when the driveline has a model file.
    pub(super) wear: Option<WearReference>,
    /// The gap diagnosis, when the driveline has a model file.
    pub(super) gap: Option<GapMonitor>,
    /// The maps to build, until the service takes the job.
    gap_job: Option<GapMapJob>,
    /// Why a driveline naming a model runs without wear diagnosis.
    wear_problem: Option<AnalysisError>,
    /// What is kept for the captures.
    pub(super) captures: Captures,
    /// The fatigue ledger, with `drivelines[].fatigue`.
    pub(super) fatigue: Option<FatigueLedger>,
    /// The process context at each bite and its gate, with `drivelines[].context`.
    pub(super) context: Option<ContextTracker>,
}

impl DrivelineAnalyzer {
    /// The analyser of driveline `index` measured on `torque`; its gap maps (when it
    /// has a model) are left to build as a [`GapMapJob`] with the cache in `cache_dir`.
    /// A model that does not load or does not fit the `wear` settings is not an error
    /// here: the driveline runs without wear diagnosis and [`Self::wear_problem`] says
    /// why.
    pub(crate) fn new(
        index: usize,
        driveline: &Driveline,
        torque: &Channel,
        cache_dir: &Path,
    ) -> Result<Self, AnalysisError> {
        let (parts, wear_problem) = ModelParts::of(index, driveline);
        let setup = BiteSetup::of(index, driveline, torque, parts.as_ref().map(|p| &p.model))?;
        let diagnosis = parts
            .zip(driveline.model.as_deref())
            .map(|model| WearDiagnosis::new(index, driveline, model, &setup, cache_dir))
            .transpose()?;
        let fatigue = driveline
            .fatigue
            .as_ref()
            .map(|settings| {
                FatigueLedger::new(
                    settings,
                    driveline.wear.horizon_days,
                    UtcTime::now().unix_ms(),
                )
            })
            .transpose()
            .map_err(|source| AnalysisError::FatigueGate { index, source })?;
        let (wear, gap, gap_job) = match diagnosis {
            Some(d) => (Some(d.wear), Some(d.gap), Some(d.gap_job)),
            None => (None, None, None),
        };
        Ok(Self {
            index,
            name: driveline.name.clone(),
            channel_name: torque.name.clone(),
            sample_rate_hz: torque.sample_rate_hz,
            state: setup.detector.joining_state(),
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
            captures: Captures::new(torque.sample_rate_hz),
            fatigue,
            context: None,
        })
    }

    /// Keep each bite window's samples for its capture (`[history]` with captures on),
    /// describing the torque channel as `torque`.
    /// With `extra` (the driveline's `extra_channels`), each kept in a ring of
    /// `ring_capacity` samples for the bites' captures.
    pub(crate) fn keep_captures(
        &mut self,
        torque: &Channel,
        extra: &[&Channel],
        ring_capacity: usize,
    ) {
        self.captures.keep(torque, extra, ring_capacity);
    }

    /// Start keeping the next `seconds` s of torque as a manual capture (a capture
    /// already running starts again), carrying the driveline's process context of now
    /// (with context tags, as its bites' captures carry theirs); false when captures
    /// are not kept.
    pub(crate) fn start_manual_capture(&mut self, seconds: f64) -> bool {
        let context = self
            .context
            .as_ref()
            .map(|tracker| tracker.reading(Instant::now()));
        self.captures.start_manual(seconds, context)
    }

    /// The manual capture, once its samples are all in.
    pub(crate) fn take_manual_capture(&mut self) -> Option<CaptureRecord> {
        self.captures.take_manual(&self.name)
    }

    /// Samples of extra channel `extra` (its position in `extra_channels`), the last
    /// received at `received` (when known).
    pub(crate) fn extra_samples(
        &mut self,
        extra: usize,
        values: &[f64],
        received: Option<SystemTime>,
    ) {
        self.captures.extra_samples(extra, values, received);
    }

    /// Samples of extra channel `extra` were lost.
    pub(crate) fn extra_gap(&mut self, extra: usize) {
        self.captures.extra_gap(extra);
    }

    /// Why the driveline runs without wear diagnosis although it names a model.
    pub(crate) fn wear_problem(&self) -> Option<&AnalysisError> {
        self.wear_problem.as_ref()
    }

    /// Why the driveline runs without wear diagnosis, taken (a reload refuses it).
    pub(crate) fn take_wear_problem(&mut self) -> Option<AnalysisError> {
        self.wear_problem.take()
    }

    /// The build of the gap maps, once (the service runs it off the analysis task).
    pub(crate) fn take_gap_map_job(&mut self) -> Option<GapMapJob> {
        self.gap_job.take()
    }

    /// Install the gap maps (or note they failed); returns the trend's estimate after
    /// the bites seen so far, to publish.
    pub(crate) fn set_gap_maps(&mut self, maps: Option<Arc<GapMaps>>) -> Option<GapResults> {
        self.gap.as_mut()?.set_maps(maps)
    }

    /// Continue the wear trend `saved` (its saved form, kept by the history) or, when
    /// there is none or it does not fit, fold `bites` in again (time ms since the epoch,
    /// measures; oldest first); returns the estimate to publish once the maps are ready.
    pub(crate) fn restore_gap_trend(
        &mut self,
        saved: Option<&str>,
        bites: Vec<(i64, GapObservation)>,
    ) -> Option<GapResults> {
        let monitor = self.gap.as_mut()?;
        if !saved.is_some_and(|saved| monitor.restore_trend(saved)) {
            monitor.restore_bites(bites);
        }
        monitor.results()
    }

    /// The wear trend's saved form, when the driveline has a model.
    pub(crate) fn gap_trend(&self) -> Option<String> {
        self.gap.as_ref().map(GapMonitor::saved)
    }

    /// Forget the wear trend's bites (the reset command).
    pub(crate) fn reset_gap_trend(&mut self) {
        if let Some(monitor) = &mut self.gap {
            monitor.reset();
        }
    }

    /// Warn and alarm at `thresholds`, and forecast the gap and the fatigue life up to
    /// `horizon_days`, from the next bite on (a reload); a latched
    /// alarm stays latched until acknowledged.
    pub(crate) fn set_thresholds(
        &mut self,
        (thresholds, horizon_days): (&DrivelineThresholds, f64),
    ) {
        self.taf_warning = thresholds.taf_warning;
        self.taf_alarm = thresholds.taf_alarm;
        if let Some(monitor) = &mut self.gap {
            if let Err(error) = monitor.set_thresholds(thresholds, horizon_days) {
                tracing::error!(driveline = %self.name, %error, "the gap forecast keeps its horizon");
            }
        }
        if let Some(ledger) = &mut self.fatigue {
            ledger.set_horizon_days(horizon_days);
        }
    }

    /// Continue the fatigue ledger `saved` (its saved form, kept by the history);
    /// returns its figures to publish, `None` without a ledger or when `saved` is not
    /// one (logged: the ledger starts at 0).
    pub(crate) fn restore_fatigue(&mut self, saved: &str) -> Option<LedgerBite> {
        let ledger = self.fatigue.as_mut()?;
        match ledger.restore(saved) {
            Ok(components) => {
                tracing::info!(driveline = %self.name, components, "fatigue ledger continued");
                Some(ledger.figures(UtcTime::now().unix_ms()))
            }
            Err(error) => {
                tracing::error!(driveline = %self.name, %error, "the saved fatigue ledger is not usable: the components' lives start at 0");
                None
            }
        }
    }

    /// The fatigue ledger's saved form, with a ledger.
    pub(crate) fn fatigue_saved(&self) -> Option<String> {
        self.fatigue.as_ref().map(FatigueLedger::saved)
    }

    /// Reset component `component` of the fatigue ledger (it was replaced): its name,
    /// the life it had used and the ledger's figures after; `None` without a ledger or
    /// such a component.
    pub(crate) fn reset_fatigue(&mut self, component: usize) -> Option<(String, f64, LedgerBite)> {
        let ledger = self.fatigue.as_mut()?;
        let now = UtcTime::now().unix_ms();
        let (name, used) = ledger.reset(component, now)?;
        Some((name, used, ledger.figures(now)))
    }

    /// Read the context tags of `driveline` (its `context` table, channels of
    /// `config`): each bite then carries the context of its time and is pooled only
    /// as [`BiteGate`](crate::state::context::BiteGate) says. The tags' channels.
    pub(crate) fn track_context(&mut self, driveline: &Driveline, config: &Config) -> Vec<usize> {
        self.context =
            ContextTracker::new(&driveline.context, config, driveline.pool_speed_range_mpm);
        self.context
            .as_ref()
            .map(|tracker| tracker.channels().collect())
            .unwrap_or_default()
    }

    /// A value of context channel `channel`, read at `now`.
    pub(crate) fn context_value(&mut self, channel: usize, value: TagValue, now: Instant) {
        if let Some(tracker) = &mut self.context {
            tracker.value(channel, value, now);
        }
    }

    /// Torque samples the detector must still take before it can hand a window over
    /// ([`millgate_dsp::bite::BiteDetector::samples_to_window_end`]).
    pub(crate) fn samples_to_window_end(&self) -> usize {
        self.detector.samples_to_window_end(&self.state)
    }

    /// "Metal in stand": a rising edge through 0.5 triggers a capture.
    pub(crate) fn trigger_value(&mut self, value: f64) {
        let high = value > 0.5;
        if high && !self.trigger_high {
            self.detector.trigger(&mut self.state);
        }
        self.trigger_high = high;
    }
}
