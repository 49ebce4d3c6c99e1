//! A driveline's samples to bite reports: the detector on the torque, each completed
//! window analysed (the transient, the eq. (1) fit, the wear index and the gap
//! observation against the model) and dated.

use std::sync::Arc;
use std::time::{Instant, SystemTime};

use millgate_dsp::bite::BiteEvent;
use millgate_dsp::transient::TransientResult;

use super::analyzer::DrivelineAnalyzer;
use super::capture::{before, BiteSamples};
use crate::analysis::bite_window::{analyze_window, WINDOW_CAPACITY};
use crate::analysis::context::BiteContext;
use crate::analysis::fatigue_ledger::LedgerBite;
use crate::analysis::gap_monitor::GapBite;
use crate::analysis::wear::WearEstimate;
use crate::state::captures::{BiteWindowAnalysis, CaptureRecord, CapturedBite, KeepClass};
use crate::state::time::UtcTime;

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
    /// When the reader handed over the block whose samples completed the window (its
    /// `Acquired::Samples::handed`), before it waited for and went through the
    /// analysis; for a window a gap ended, when the analysis took the gap up.
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
    /// degraded window, a bite without TAF or one not pooled (`context.gate`).
    pub gap: Option<GapBite>,
    /// The window's samples as analysed, when the driveline keeps captures.
    pub samples: Option<Arc<BiteSamples>>,
    /// The fatigue ledger after this bite, with `drivelines[].fatigue`.
    pub fatigue: Option<LedgerBite>,
    /// The process context when the window completed and whether the bite was pooled
    /// into the wear trend, with `drivelines[].context`.
    pub context: Option<BiteContext>,
}

impl BiteReport {
    /// The capture of this bite's window as the history keeps it, for the bite
    /// `bite` of its driveline kept as `keep`, with the bite's context; `None` when the driveline keeps no
    /// captures.
    pub fn capture(&self, bite: CapturedBite, keep: KeepClass) -> Option<CaptureRecord> {
        let samples = self.samples.as_ref()?;
        let context = self.context.map(|context| context.reading());
        Some(samples.record(&self.driveline_name, bite, keep, context))
    }
}

impl DrivelineAnalyzer {
    /// Process `values`, the last of which was received at `received` (when known),
    /// handed over by their reader at `handed`.
    pub(crate) fn samples(
        &mut self,
        values: &[f64],
        (received, handed): (Option<SystemTime>, Instant),
        reports: &mut Vec<BiteReport>,
    ) {
        self.captures.manual_samples(values, received);
        let last = received.unwrap_or_else(SystemTime::now);
        // Samples up to here are in the fatigue ledger: a bite's damage is what closed
        // up to the end of its window.
        let mut counted = 0;
        for (i, &value) in values.iter().enumerate() {
            if let Some(event) = self.detector.process(&mut self.state, value) {
                // The window's last sample is `later` before the block's last: dated
                // from its receive time, or (a Modbus DAQ) from now, as the extra
                // channels' samples are.
                let later = (values.len() - 1 - i) as f64 / self.sample_rate_hz;
                let time = before(last, later);
                if let Some(ledger) = &mut self.fatigue {
                    ledger.samples(&values[counted..=i], UtcTime::from_system(time).unix_ms());
                    counted = i + 1;
                }
                let dated = (Some(time), received.is_some());
                reports.extend(self.report(&event, dated, handed, None));
            }
        }
        if let Some(ledger) = &mut self.fatigue {
            ledger.samples(&values[counted..], UtcTime::from_system(last).unix_ms());
        }
    }

    /// `missed` samples were lost (an unknown number when `None`): a window the gap
    /// ends is reported.
    pub(crate) fn gap(&mut self, missed: Option<u64>, reports: &mut Vec<BiteReport>) {
        self.captures.manual_gap(missed);
        if let Some(ledger) = &mut self.fatigue {
            ledger.cut(UtcTime::now().unix_ms());
        }
        if let Some(event) = self.detector.gap(&mut self.state, missed.unwrap_or(0)) {
            reports.extend(self.report(&event, (None, false), Instant::now(), Some(missed)));
        }
    }

    /// The report of a completed window whose last sample was taken at
    /// `last_sample_time` (now when unknown), a time counted back from a kernel
    /// receive timestamp when `kernel_time`, completed by what was handed over at
    /// `window_complete`.
    fn report(
        &mut self,
        event: &BiteEvent<WINDOW_CAPACITY>,
        (last_sample_time, kernel_time): (Option<SystemTime>, bool),
        window_complete: Instant,
        ended_by_gap: Option<Option<u64>>,
    ) -> Option<BiteReport> {
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
        let time = before(
            last_sample_time.unwrap_or_else(SystemTime::now),
            after_trigger,
        );
        let unix_ms = UtcTime::from_system(time).unix_ms();
        let context = self
            .context
            .as_ref()
            .map(|tracker| tracker.at(window_complete));
        let pooled = context.is_none_or(|context| context.gate.pooled());
        let gap = self
            .gap
            .as_mut()
            .filter(|_| !degraded && pooled)
            .and_then(|gap| gap.observe(&event.window, &analysis.transient, transient, unix_ms));
        let samples = self.captures.bite_samples(
            event,
            self.window_analysis(event),
            time,
            kernel_time,
            ended_by_gap,
        );
        let fatigue = self
            .fatigue
            .as_mut()
            .map(|ledger| ledger.bite(unix_ms, degraded));
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
            fatigue,
            context,
        })
    }

    /// How `event`'s window is analysed: its trigger and baseline, and the settings.
    fn window_analysis(&self, event: &BiteEvent<WINDOW_CAPACITY>) -> BiteWindowAnalysis {
        BiteWindowAnalysis {
            trigger_index: event.trigger_index,
            baseline_knm: event.baseline_knm,
            onset_knm: self.onset_knm,
            period_lowpass_hz: self.transient.period_lowpass_hz,
            peak_lowpass_hz: self.transient.peak_lowpass_hz,
            settled_fraction: self.transient.settled_fraction,
            min_static_knm: self.transient.min_static_knm,
        }
    }

    /// Whether every extra channel has samples up to the end of `report`'s window
    /// (true without extra channels or captures).
    pub(crate) fn extras_reach_window_end(&self, report: &BiteReport) -> bool {
        self.captures
            .extras_reach_window_end(report.samples.as_deref())
    }

    /// Put the extra channels over `report`'s window into its capture (what the rings
    /// hold of it: missing rows are NaN).
    pub(crate) fn capture_extras(&self, report: &mut BiteReport) {
        self.captures.capture_extras(report.samples.as_mut());
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
}
