//! Streaming detector of metal biting (step load onset) on one torque channel.
//!
//! The detector is split into coefficients ([`BiteDetector`], built once from validated
//! [`BiteSettings`]) and state ([`BiteDetectorState`], mutated per sample).
//!
//! - **Baseline**: exponential moving average of the idle samples (samples that are not
//!   a rise above the baseline by the threshold, while armed). A fall below it by the
//!   threshold or more resets it to that level at once (it was a loaded level, e.g.
//!   after a start mid-bar; zero drift is far slower) and makes it track 50x faster for
//!   one time constant while the torque settles. It follows a drifting
//!   zero and falls quickly enough after a restart in a loaded state.
//! - **Onset**: a finite sample at or above `baseline + threshold_knm`, or an external
//!   trigger ([`BiteDetector::trigger`], e.g. the PLC's "metal in stand" bit) which makes
//!   the next processed sample the trigger sample.
//! - **Window**: up to `PRE` contiguous samples before the trigger (fewer right after a
//!   start or a gap) followed by `post_trigger_samples` samples from the trigger on,
//!   stored in a `heapless::Vec<f64, N>`; `PRE + post_trigger_samples <= N`.
//! - **Dead time**: after an event the detector re-arms only when `holdoff_samples` have
//!   passed *and* the torque has come back within `rearm_knm` of the baseline.
//! - **Data gaps** ([`BiteDetector::gap`]): a gap clears the pre-trigger history (the
//!   window never joins samples across a gap). A gap during a capture **ends the capture
//!   early**: the event is emitted at once with the samples before the gap and
//!   `quality.gap = true`. After a gap no trigger fires (level or external) until
//!   `PRE` usable samples in a row have stayed below the threshold: data resuming while
//!   the mill is loaded (a bite that began in the gap) is no onset, and a bite after a
//!   gap has a whole pre-trigger of fresh data.
//! - **Bad samples**: a non-finite sample is stored as the previous stored value (the
//!   baseline for the first one) and sets `quality.non_finite`; a sample at or beyond
//!   the saturation limits sets `quality.saturated`. Neither ever triggers by itself
//!   unless it is a saturated value above the threshold, and neither sets, moves or
//!   resets the baseline or re-arms the detector: coming back from full scale is not
//!   a rise from it.

use heapless::{HistoryBuf, Vec};

/// Settings of a [`BiteDetector`]; torque in kN*m, lengths in samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiteSettings {
    /// Rise above the baseline that marks a bite, kN*m, finite and > 0.
    pub threshold_knm: f64,
    /// Distance to the baseline under which the detector re-arms, kN*m, finite, > 0.
    pub rearm_knm: f64,
    /// Minimum number of samples after an event before re-arming, any value.
    pub holdoff_samples: u32,
    /// Baseline EMA coefficient per idle sample, in (0, 1]; time constant ~ 1/alpha samples.
    pub baseline_alpha: f64,
    /// Samples at or below this value are saturated, kN*m (may be -inf).
    pub saturation_low_knm: f64,
    /// Samples at or above this value are saturated, kN*m (may be +inf), > low.
    pub saturation_high_knm: f64,
    /// Window length from the trigger sample on, samples, in `1..=N - PRE`.
    pub post_trigger_samples: usize,
}

/// The [`BiteSettings`] field (or capacity) that failed validation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BiteSettingsError {
    /// `threshold_knm` is not finite and > 0.
    ThresholdKnm,
    /// `rearm_knm` is not finite and > 0.
    RearmKnm,
    /// `baseline_alpha` is not in (0, 1].
    BaselineAlpha,
    /// The saturation limits are NaN or `low >= high`.
    SaturationLimits,
    /// `post_trigger_samples` is 0 or exceeds `N - PRE`.
    PostTriggerSamples,
}

impl core::fmt::Display for BiteSettingsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BiteSettingsError::ThresholdKnm => "threshold_knm must be finite and > 0 kN*m",
            BiteSettingsError::RearmKnm => "rearm_knm must be finite and > 0 kN*m",
            BiteSettingsError::BaselineAlpha => "baseline_alpha must be in (0, 1]",
            BiteSettingsError::SaturationLimits => "the saturation limits must not be NaN and low must be below high",
            BiteSettingsError::PostTriggerSamples => "post_trigger_samples must be in 1..=N - PRE (the window capacity less the pre-trigger history)",
        })
    }
}

impl core::error::Error for BiteSettingsError {}

/// What started a capture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriggerSource {
    /// The torque rose above the baseline by the threshold.
    Level,
    /// [`BiteDetector::trigger`] was called (external signal).
    External,
}

/// Quality flags of a captured window; `Quality::default()` is good.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Quality {
    /// A NaN or infinite sample lies in the window (stored as the previous value).
    pub non_finite: bool,
    /// A sample at or beyond the saturation limits lies in the window.
    pub saturated: bool,
    /// A data gap ended the capture early: the window is shorter than requested.
    pub gap: bool,
}

impl Quality {
    /// True when no flag is set.
    pub fn is_good(&self) -> bool {
        !(self.non_finite || self.saturated || self.gap)
    }
}

/// One captured bite: pre-trigger and post-trigger torque samples, kN*m.
#[derive(Clone, Debug, PartialEq)]
pub struct BiteEvent<const N: usize> {
    /// Window samples, kN*m, oldest first, contiguous (never across a gap).
    pub window: Vec<f64, N>,
    /// Index of the trigger sample inside `window`.
    pub trigger_index: usize,
    /// Absolute index of the trigger sample since the state was created (gaps count).
    pub trigger_sample: u64,
    /// Baseline at the trigger, kN*m.
    pub baseline_knm: f64,
    /// What started the capture.
    pub source: TriggerSource,
    /// Quality flags.
    pub quality: Quality,
}

/// How much faster the baseline tracks right after it was reset by a fall.
const FAST_BASELINE_FACTOR: f64 = 50.0;

/// Validated coefficients of a bite detector with `PRE` pre-trigger and `N` window capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiteDetector<const PRE: usize, const N: usize> {
    settings: BiteSettings,
}

/// One input sample as the detector sees it.
#[derive(Clone, Copy, Debug)]
struct Sample {
    /// Its index since the state was created.
    index: u64,
    torque_knm: f64,
    finite: bool,
    /// Finite and not saturated.
    usable: bool,
    /// The value kept in the history and window (the last stored one for a
    /// non-finite sample).
    stored: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Armed,
    Capturing,
    Dead,
}

/// Mutable state of one channel; create with [`BiteDetector::state`].
#[derive(Clone, Debug)]
pub struct BiteDetectorState<const PRE: usize, const N: usize> {
    phase: Phase,
    baseline_knm: f64,
    baseline_valid: bool,
    history: HistoryBuf<f64, PRE>,
    window: Vec<f64, N>,
    trigger_index: usize,
    trigger_sample: u64,
    trigger_baseline_knm: f64,
    source: TriggerSource,
    external_pending: bool,
    last_stored_knm: f64,
    sample_index: u64,
    window_start: u64,
    last_non_finite: Option<u64>,
    last_saturated: Option<u64>,
    dead_remaining: u32,
    fast_baseline_remaining: u32,
    /// Usable samples below the threshold still needed, in a row, before a trigger
    /// may fire after a gap (0: none).
    resync_remaining: u32,
}

impl<const PRE: usize, const N: usize> BiteDetectorState<PRE, N> {
    /// Current baseline, kN*m (0 before the first finite sample).
    pub fn baseline_knm(&self) -> f64 {
        self.baseline_knm
    }

    /// True while the detector waits for a bite.
    pub fn is_armed(&self) -> bool {
        self.phase == Phase::Armed
    }

    /// True after a gap until a whole pre-trigger of usable samples below the
    /// threshold has come: no trigger fires meanwhile.
    pub fn is_resyncing(&self) -> bool {
        self.resync_remaining > 0
    }

    /// Absolute index of the next sample.
    pub fn sample_index(&self) -> u64 {
        self.sample_index
    }

    /// True while a window is being captured (a gap ends it, and hands it over).
    pub fn is_capturing(&self) -> bool {
        self.phase == Phase::Capturing
    }
}

impl<const PRE: usize, const N: usize> BiteDetector<PRE, N> {
    /// Validates `settings` against the capacities `PRE` and `N`.
    ///
    /// ```
    /// use millgate_dsp::bite::{BiteDetector, BiteSettings};
    /// let settings = BiteSettings {
    ///     threshold_knm: 20.0, rearm_knm: 10.0, holdoff_samples: 100,
    ///     baseline_alpha: 1e-3, saturation_low_knm: -1000.0, saturation_high_knm: 1000.0,
    ///     post_trigger_samples: 300,
    /// };
    /// let detector = BiteDetector::<50, 400>::new(settings).unwrap();
    /// let mut state = detector.state();
    /// let mut events = 0;
    /// for i in 0..2000 {
    ///     let torque = if i >= 500 && i < 1500 { 100.0 } else { 0.0 };
    ///     if let Some(event) = detector.process(&mut state, torque) {
    ///         assert_eq!(event.trigger_sample, 500);
    ///         assert_eq!(event.trigger_index, 50);
    ///         events += 1;
    ///     }
    /// }
    /// assert_eq!(events, 1);
    /// ```
    pub fn new(settings: BiteSettings) -> Result<Self, BiteSettingsError> {
        let finite_positive = |v: f64| v.is_finite() && v > 0.0;
        if !finite_positive(settings.threshold_knm) {
            return Err(BiteSettingsError::ThresholdKnm);
        }
        if !finite_positive(settings.rearm_knm) {
            return Err(BiteSettingsError::RearmKnm);
        }
        if !(settings.baseline_alpha > 0.0 && settings.baseline_alpha <= 1.0) {
            return Err(BiteSettingsError::BaselineAlpha);
        }
        let (low, high) = (settings.saturation_low_knm, settings.saturation_high_knm);
        if low.is_nan() || high.is_nan() || low >= high {
            return Err(BiteSettingsError::SaturationLimits);
        }
        if settings.post_trigger_samples == 0 || PRE >= N || settings.post_trigger_samples > N - PRE
        {
            return Err(BiteSettingsError::PostTriggerSamples);
        }
        Ok(Self { settings })
    }

    /// The validated settings.
    pub fn settings(&self) -> &BiteSettings {
        &self.settings
    }

    /// Samples of fast tracking after a baseline reset: one slow time constant.
    fn fast_baseline_samples(&self) -> u32 {
        libm::fmin(1.0 / self.settings.baseline_alpha, f64::from(u32::MAX)) as u32
    }

    /// A fresh, armed state with no baseline yet, for a record that begins where its
    /// author cut it (a file: its first samples are taken as what came before a bite).
    /// A live stream joined while the mill runs starts with [`Self::joining_state`].
    pub fn state(&self) -> BiteDetectorState<PRE, N> {
        BiteDetectorState {
            phase: Phase::Armed,
            baseline_knm: 0.0,
            baseline_valid: false,
            history: HistoryBuf::new(),
            window: Vec::new(),
            trigger_index: 0,
            trigger_sample: 0,
            trigger_baseline_knm: 0.0,
            source: TriggerSource::Level,
            external_pending: false,
            last_stored_knm: 0.0,
            sample_index: 0,
            window_start: 0,
            last_non_finite: None,
            last_saturated: None,
            dead_remaining: 0,
            fast_baseline_remaining: 0,
            resync_remaining: 0,
        }
    }

    /// A fresh state for a live stream joined while the mill runs (what came before
    /// its first sample is unknown): as after a [gap](Self::gap), no trigger fires
    /// until a whole pre-trigger of usable samples below the threshold has come. A
    /// stream that starts during a bite's rise has not seen the onset, and its window
    /// would have no pre-trigger to measure from.
    pub fn joining_state(&self) -> BiteDetectorState<PRE, N> {
        let mut state = self.state();
        state.resync_remaining = PRE.max(1) as u32;
        state
    }

    /// External trigger: the next processed sample becomes the trigger sample.
    ///
    /// Returns false (and does nothing) when the detector is not armed, or is armed
    /// but still waiting for a whole pre-trigger after a gap.
    pub fn trigger(&self, state: &mut BiteDetectorState<PRE, N>) -> bool {
        if state.phase == Phase::Armed && state.resync_remaining == 0 {
            state.external_pending = true;
            true
        } else {
            false
        }
    }

    /// Declares `missing_samples` lost samples (a data gap) before the next sample.
    ///
    /// Clears the pre-trigger history and holds triggers off until `PRE` usable samples
    /// in a row have stayed below the threshold (data resuming mid-bite is no onset).
    /// During a capture, returns the event cut at the gap with `quality.gap` set. The
    /// absolute sample index advances by `missing_samples`.
    pub fn gap(
        &self,
        state: &mut BiteDetectorState<PRE, N>,
        missing_samples: u64,
    ) -> Option<BiteEvent<N>> {
        let event = if state.phase == Phase::Capturing {
            let mut event = self.finish(state);
            event.quality.gap = true;
            Some(event)
        } else {
            None
        };
        state.history.clear();
        state.external_pending = false;
        state.resync_remaining = PRE.max(1) as u32;
        state.sample_index = state.sample_index.saturating_add(missing_samples);
        state.window_start = state.sample_index;
        event
    }

    /// Processes one torque sample (kN*m); returns an event when a window completes.
    #[inline]
    pub fn process(
        &self,
        state: &mut BiteDetectorState<PRE, N>,
        torque_knm: f64,
    ) -> Option<BiteEvent<N>> {
        let sample = self.classify(state, torque_knm);
        match state.phase {
            Phase::Armed => self.armed(state, sample),
            Phase::Capturing => {
                // The capacity check in `new` guarantees room; a full window hands back.
                if state.window.push(sample.stored).is_err() {
                    return Some(self.finish(state));
                }
                self.maybe_finish(state)
            }
            Phase::Dead => {
                self.dead(state, sample);
                None
            }
        }
    }

    /// Counts the sample, flags it (non-finite, saturated), sets the first baseline
    /// from it when usable, and chooses the value stored for it.
    #[inline]
    fn classify(&self, state: &mut BiteDetectorState<PRE, N>, torque_knm: f64) -> Sample {
        let index = state.sample_index;
        state.sample_index = index.wrapping_add(1);
        let finite = torque_knm.is_finite();
        let saturated = finite
            && (torque_knm <= self.settings.saturation_low_knm
                || torque_knm >= self.settings.saturation_high_knm);
        // A saturated sample says only that the torque is beyond a limit: it never
        // sets or moves the baseline, nor re-arms the detector.
        let usable = finite && !saturated;
        if !finite {
            state.last_non_finite = Some(index);
        } else if saturated {
            state.last_saturated = Some(index);
        }
        if usable && !state.baseline_valid {
            state.baseline_knm = torque_knm;
            state.baseline_valid = true;
        }
        let stored = if finite {
            torque_knm
        } else if state.history.is_empty() && state.phase != Phase::Capturing {
            state.baseline_knm
        } else {
            state.last_stored_knm
        };
        state.last_stored_knm = stored;
        Sample {
            index,
            torque_knm,
            finite,
            usable,
            stored,
        }
    }

    /// Armed: a rise by the threshold (or a pending external trigger) starts a
    /// capture; otherwise the baseline follows a usable sample and the pre-trigger
    /// history keeps it.
    #[inline]
    fn armed(&self, state: &mut BiteDetectorState<PRE, N>, sample: Sample) -> Option<BiteEvent<N>> {
        let above = sample.finite
            && state.baseline_valid
            && sample.torque_knm - state.baseline_knm >= self.settings.threshold_knm;
        if state.resync_remaining > 0 {
            // After a gap: only a whole pre-trigger of usable samples below the
            // threshold, in a row, makes the next rise an onset.
            state.resync_remaining = if sample.usable && !above {
                state.resync_remaining - 1
            } else {
                PRE.max(1) as u32
            };
            if above {
                state.history.clear();
                return None;
            }
        }
        if above || state.external_pending {
            self.start(state, sample.index, sample.stored, above);
            return self.maybe_finish(state);
        }
        if sample.usable {
            self.track_baseline(state, sample.torque_knm);
        }
        if state.history.is_empty() {
            state.window_start = sample.index;
        } else if state.history.is_full() {
            state.window_start = state.window_start.wrapping_add(1);
        }
        state.history.write(sample.stored);
        None
    }

    /// Moves the baseline towards a usable idle sample `torque_knm`.
    #[inline]
    fn track_baseline(&self, state: &mut BiteDetectorState<PRE, N>, torque_knm: f64) {
        if state.baseline_knm - torque_knm >= self.settings.threshold_knm {
            // A fall below the baseline by a whole threshold: the baseline was a
            // loaded level (start mid-bar), not the zero. Zero drift is far slower
            // than that, so take the new level at once and track fast for one slow
            // time constant while the torque settles.
            state.baseline_knm = torque_knm;
            state.fast_baseline_remaining = self.fast_baseline_samples();
        } else {
            let alpha = if state.fast_baseline_remaining > 0 {
                state.fast_baseline_remaining -= 1;
                libm::fmin(1.0, FAST_BASELINE_FACTOR * self.settings.baseline_alpha)
            } else {
                self.settings.baseline_alpha
            };
            state.baseline_knm += alpha * (torque_knm - state.baseline_knm);
        }
    }

    /// Dead time after a capture: re-armed once it is over and a usable sample is back
    /// near the baseline.
    #[inline]
    fn dead(&self, state: &mut BiteDetectorState<PRE, N>, sample: Sample) {
        state.dead_remaining = state.dead_remaining.saturating_sub(1);
        if state.dead_remaining == 0
            && sample.usable
            && libm::fabs(sample.torque_knm - state.baseline_knm) <= self.settings.rearm_knm
        {
            state.phase = Phase::Armed;
            state.history.clear();
            state.history.write(sample.stored);
            state.window_start = sample.index;
        }
    }

    /// Processes a slice of samples, calling `on_event` for every completed window.
    pub fn block<F: FnMut(BiteEvent<N>)>(
        &self,
        state: &mut BiteDetectorState<PRE, N>,
        samples_knm: &[f64],
        mut on_event: F,
    ) {
        for &sample in samples_knm {
            if let Some(event) = self.process(state, sample) {
                on_event(event);
            }
        }
    }

    /// The fewest samples after which [`Self::process`] can hand a window over: the
    /// rest of the window being captured, or, while none is, the post-trigger samples
    /// a trigger needs (its own sample and the rest). A caller that has fewer to give
    /// knows no window completes with them (but a gap ends one being captured).
    pub fn samples_to_window_end(&self, state: &BiteDetectorState<PRE, N>) -> usize {
        match state.phase {
            Phase::Capturing => self
                .settings
                .post_trigger_samples
                .saturating_sub(state.window.len() - state.trigger_index),
            Phase::Armed | Phase::Dead => self.settings.post_trigger_samples,
        }
    }

    fn start(&self, state: &mut BiteDetectorState<PRE, N>, index: u64, stored: f64, level: bool) {
        state.window.clear();
        if state.history.is_empty() {
            state.window_start = index;
        }
        for &value in state.history.oldest_ordered() {
            // PRE < N: always fits.
            let _ = state.window.push(value);
        }
        state.trigger_index = state.window.len();
        let _ = state.window.push(stored);
        state.trigger_sample = index;
        state.trigger_baseline_knm = state.baseline_knm;
        state.source = if level {
            TriggerSource::Level
        } else {
            TriggerSource::External
        };
        state.external_pending = false;
        state.phase = Phase::Capturing;
    }

    fn maybe_finish(&self, state: &mut BiteDetectorState<PRE, N>) -> Option<BiteEvent<N>> {
        if state.window.len() - state.trigger_index >= self.settings.post_trigger_samples {
            Some(self.finish(state))
        } else {
            None
        }
    }

    fn finish(&self, state: &mut BiteDetectorState<PRE, N>) -> BiteEvent<N> {
        let start = state.window_start;
        let in_window = |at: Option<u64>| at.is_some_and(|i| i >= start);
        let quality = Quality {
            non_finite: in_window(state.last_non_finite),
            saturated: in_window(state.last_saturated),
            gap: false,
        };
        state.phase = Phase::Dead;
        state.dead_remaining = self.settings.holdoff_samples;
        state.history.clear();
        BiteEvent {
            window: core::mem::take(&mut state.window),
            trigger_index: state.trigger_index,
            trigger_sample: state.trigger_sample,
            baseline_knm: state.trigger_baseline_knm,
            source: state.source,
            quality,
        }
    }
}
