//! Chatter monitoring of one tandem mill: aligned sliding windows of the stands'
//! vibration, their spectra, and the synchronization conditions of `dsp::chatter`.
//!
//! **Window and hop.** Each stand keeps a ring buffer (allocated once) of its latest
//! samples. Every hop of half a window (`window_s / 2`, so windows overlap by half,
//! the usual choice for Hann windows) the window of `N = round(window_s * fs)`
//! samples that ends at the same sample on every stand is analysed.
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
//!
//! **Alignment.** A reader hands over samples without time stamps, so every stand
//! counts its samples; a gap with a known number of missed samples advances the
//! count. The stands of one mill must be sampled on one clock (one DAQ, or DAQs
//! sharing sample clock and block grid). Where each stand's count starts is
//! checked against arrival times: the earliest arrival of a sample, less its count
//! over the sample rate, estimates when the stand's first sample was taken; the
//! difference to the mill's reference is rounded to whole blocks (the length of
//! the stand's first message) and added to the count. This catches a stand whose
//! first block was one newer than the others' (the DAQ published between two reads
//! of one poll) and re-anchors a stand after a gap of unknown length.
//!
//! **Chatter-band gain.** Every common sample index that all stands have is also fed,
//! as one frame, to `dsp::band_gain` (per stand a chatter-band and a reference-band
//! Butterworth band-pass; `gain_window_s` of whole hops). Its hops fall on the same
//! sample indices as the spectra's windows, so each evaluation carries the gain of the
//! window ending with it ([`ChatterMonitor::gain`]), or none while the gain's longer
//! window refills after a restart. With `gain_thresholds` the largest
//! `gain[s] / threshold[s]` is the mill's gain ratio: 1 is the alarm level of the
//! band-gain detector, the default (it warned earliest at zero false alarms in the
//! tandem-model race, `tests/src/chatter_eval.rs`).
//!
//! **Restarts.** A gap on any stand, a stand falling more than [`MAX_STAND_LAG_S`]
//! behind the others, or a change of a stand's anchor invalidates the mill's values
//! (flag "source stale") and restarts the window: the next evaluation uses only
//! samples taken after the restart on every stand, and the gain's filters restart.
//!
//! **Slow-down request** ([`SlowDown`]): set by the configured detector's alarm
//! (gain ratio >= 1, or both synchronization conditions), cleared only after the
//! alarm figure stayed below `slow_down_release` for `slow_down_hold_s` of trusted
//! windows. A restart or an unevaluable window neither sets nor clears it: it holds,
//! and the time below the release level starts again (the mill is not sped up on data
//! the gateway cannot read; the stale bit tells the PLC why).

use std::sync::Arc;
use std::time::Instant;

use millgate_config::{ChatterDetectorKind, Config, TandemMill};
use millgate_dsp::band_gain::{
    BandGain, BandGainError, BandGainSettings, BandGainState, BandGainWindow, MAX_WINDOW_HOPS,
};
use millgate_dsp::chatter::{
    ChatterDetector, ChatterError, ChatterResult, ChatterSettings, StandWindow, MAX_STANDS,
};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, ChatterWindow, EndedBy, HistoryEvent,
};
use crate::state::results::TandemMillResults;
use crate::state::time::UtcTime;

/// Largest lag of one stand behind the most advanced one, s: more means its source
/// has stopped delivering, and the mill's values are flagged and the window restarted.
pub const MAX_STAND_LAG_S: f64 = 0.5;

/// Fewest samples in a window.
pub const MIN_WINDOW_SAMPLES: usize = 16;

/// A tandem mill the monitor cannot be built for. Each message starts with the key at
/// fault (`tandem_mills[0].window_s`), as the configuration's own problems do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChatterSetupError {
    /// The window holds fewer than [`MIN_WINDOW_SAMPLES`] samples.
    #[error(
        "tandem_mills[{index}].window_s: {window_s} s at {sample_rate_hz} Hz gives {samples} \
         samples, at least {MIN_WINDOW_SAMPLES} are needed (tandem mill \"{mill}\")"
    )]
    WindowTooShort {
        /// Index of the mill in the configuration.
        index: usize,
        /// The mill's name.
        mill: String,
        /// Configured window, s.
        window_s: f64,
        /// Sample rate of the stands, Hz.
        sample_rate_hz: f64,
        /// Samples in that window.
        samples: usize,
    },
    /// The window's frequency step (1 / `window_s`) is too coarse for the chatter band:
    /// no spectrum bin with a neighbour on each side falls inside it.
    #[error(
        "tandem_mills[{index}].window_s: {window_s} s is too short for the chatter band \
         {low_hz}..{high_hz} Hz: its frequency step {step_hz} Hz leaves no spectrum bin \
         inside the band with a neighbour on each side (tandem mill \"{mill}\")"
    )]
    WindowTooShortForBand {
        /// Index of the mill in the configuration.
        index: usize,
        /// The mill's name.
        mill: String,
        /// Configured window, s.
        window_s: f64,
        /// Spectrum frequency step, Hz.
        step_hz: f64,
        /// Lower edge of the chatter band, Hz.
        low_hz: f64,
        /// Upper edge of the chatter band, Hz.
        high_hz: f64,
    },
    /// `gain_window_s` is not a whole number of hops (half of `window_s`) in
    /// 1..=[`MAX_WINDOW_HOPS`].
    #[error(
        "tandem_mills[{index}].gain_window_s: {gain_window_s} s is not allowed (must be 1 to \
         {MAX_WINDOW_HOPS} whole hops of window_s / 2 = {hop_s} s; tandem mill \"{mill}\")"
    )]
    GainWindow {
        /// Index of the mill in the configuration.
        index: usize,
        /// The mill's name.
        mill: String,
        /// Configured gain window, s.
        gain_window_s: f64,
        /// The monitor's hop, s.
        hop_s: f64,
    },
    /// The chatter-band gain refused the mill's settings (bands, sample rate).
    #[error("tandem_mills[{index}]: band gain: {source} (tandem mill \"{mill}\")")]
    BandGain {
        /// Index of the mill in the configuration.
        index: usize,
        /// The mill's name.
        mill: String,
        /// What the band gain refused.
        #[source]
        source: BandGainError,
    },
    /// The chatter detector refused the mill's settings.
    #[error("tandem_mills[{index}]: {source} (tandem mill \"{mill}\")")]
    Detector {
        /// Index of the mill in the configuration.
        index: usize,
        /// The mill's name.
        mill: String,
        /// What the detector refused.
        #[source]
        source: ChatterError,
    },
}

/// Why the mill's window restarted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartCause {
    /// The reader reported lost samples on this stand.
    Gap {
        /// Index of the stand in the mill.
        stand: usize,
    },
    /// This stand fell more than [`MAX_STAND_LAG_S`] behind the others.
    Lagging {
        /// Index of the stand in the mill.
        stand: usize,
    },
    /// This stand's sample count was re-anchored against the arrival times.
    Realigned {
        /// Index of the stand in the mill.
        stand: usize,
    },
}

impl std::fmt::Display for RestartCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RestartCause::Gap { stand } => write!(f, "samples lost on stand {stand}"),
            RestartCause::Lagging { stand } => write!(
                f,
                "stand {stand} fell more than {MAX_STAND_LAG_S} s behind the others"
            ),
            RestartCause::Realigned { stand } => {
                write!(f, "stand {stand} re-anchored against the arrival times")
            }
        }
    }
}

/// What one message to the monitor changed.
// The result (about 240 bytes) is moved once per window; boxing it would allocate
// on every window instead.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum ChatterUpdate {
    /// A window was evaluated.
    Evaluated(ChatterResult),
    /// A window was complete but its data could not be evaluated (NaN, overflow).
    Failed(ChatterError),
    /// The window restarted; the values are invalid until the next evaluation.
    Restarted(RestartCause),
}

/// What anchoring a message did to its stand's place on the common axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Realigned {
    Same,
    First,
    Changed,
}

/// Where a stand's sample count sits on the mill's common sample axis.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    /// Earliest (arrival time - samples counted / fs) seen, s since the mill's epoch.
    origin_s: f64,
    /// Samples per block: the length of the first message after anchoring.
    block: i64,
    /// Added to the count to give the common sample index.
    offset: i64,
}

/// One stand's ring buffer and position.
#[derive(Debug)]
struct StandStream {
    ring: Vec<f64>,
    /// Samples counted since the anchor (known missed samples included).
    counted: i64,
    anchor: Option<Anchor>,
}

impl StandStream {
    /// Common index of the next sample, once anchored.
    fn next_index(&self) -> Option<i64> {
        self.anchor.map(|a| self.counted + a.offset)
    }

    fn sample(&self, index: i64) -> f64 {
        self.ring[index.rem_euclid(self.ring.len() as i64) as usize]
    }
}

/// The chatter-band gain of the window that ended with the latest evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GainReading {
    /// The largest chatter-band gain of any stand (chatter-band RMS / reference-band RMS).
    pub max_gain: f64,
    /// The largest chatter-band RMS of any stand, in the stand channels' unit.
    pub max_band_rms: f64,
    /// The largest `gain[s] / gain_thresholds[s]` (>= 1: the band-gain alarm) and the
    /// stand (index in the mill) it belongs to; `None` without thresholds.
    pub ratio: Option<(f64, usize)>,
}

impl GainReading {
    /// The reading of one band-gain window against per-stand `thresholds` (empty: no
    /// ratio).
    pub fn new(window: &BandGainWindow, thresholds: &[f64]) -> Self {
        let ratio = (thresholds.len() == window.gain.len() && !thresholds.is_empty()).then(|| {
            window
                .gain
                .iter()
                .zip(thresholds)
                .map(|(gain, threshold)| gain / threshold)
                .enumerate()
                .fold((f64::NEG_INFINITY, 0), |best, (stand, ratio)| {
                    if ratio > best.0 {
                        (ratio, stand)
                    } else {
                        best
                    }
                })
        });
        Self {
            max_gain: window.max_gain(),
            max_band_rms: window.max_band_rms(),
            ratio,
        }
    }
}

/// The configured detector's bits after one update ([`ChatterMonitor::judge`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Verdict {
    /// The detector's warning in this window (not latched).
    pub warning: bool,
    /// The detector's alarm condition in this window (the published bit latches it).
    pub alarm: bool,
    /// The slow-down request after this update.
    pub slow_down: bool,
}

/// The slow-down request of one mill, with hysteresis (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowDown {
    release: f64,
    hold_s: f64,
    requested: bool,
    /// Time the alarm figure has stayed below the release level while requested, s.
    below_s: f64,
}

impl SlowDown {
    /// Not requested; clears after `hold_s` below `release` (a fraction of the alarm
    /// level, 0..1).
    pub fn new(release: f64, hold_s: f64) -> Self {
        Self {
            release,
            hold_s,
            requested: false,
            below_s: 0.0,
        }
    }

    /// Whether the slow-down is requested.
    pub fn requested(&self) -> bool {
        self.requested
    }

    /// One trusted window: `level` is the alarm figure relative to its alarm level
    /// (1 = alarm), `step_s` the time since the previous window. Returns the request.
    pub fn window(&mut self, level: f64, step_s: f64) -> bool {
        if level >= 1.0 {
            self.requested = true;
            self.below_s = 0.0;
        } else if self.requested {
            if level < self.release {
                self.below_s += step_s;
                if self.below_s >= self.hold_s {
                    self.requested = false;
                    self.below_s = 0.0;
                }
            } else {
                self.below_s = 0.0;
            }
        }
        self.requested
    }

    /// A window that could not be trusted: the request holds, the time below the
    /// release level starts again.
    pub fn untrusted(&mut self) {
        self.below_s = 0.0;
    }
}

/// Sliding-window chatter monitor of one tandem mill (see the module docs).
pub struct ChatterMonitor {
    name: String,
    detector: ChatterDetector,
    kind: ChatterDetectorKind,
    band_gain: BandGain,
    gain_state: BandGainState,
    /// Common index of the next frame for the band gain.
    gain_next: i64,
    gain_thresholds: Vec<f64>,
    /// The band gain's latest window; `None` after a restart until a full one.
    gain: Option<GainReading>,
    /// The same window per stand.
    gain_window: Option<BandGainWindow>,
    /// The slow-down request's release level and hold, from the configuration.
    slow_down: SlowDown,
    sample_rate_hz: f64,
    window: usize,
    hop: usize,
    max_lag: i64,
    stands: Vec<StandStream>,
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
    /// Windows may only start at or after this common index.
    valid_from: i64,
    /// Common index one past the next window's last sample.
    next_end: i64,
    epoch: Option<Instant>,
    reference_origin_s: Option<f64>,
    lagging: Option<usize>,
    evaluations: u64,
}

// By hand: the FFT plans (`dyn Fft`) have no Debug; the buffers are not worth printing.
impl std::fmt::Debug for ChatterMonitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChatterMonitor")
            .field("name", &self.name)
            .field("stands", &self.stands.len())
            .field("window", &self.window)
            .field("hop", &self.hop)
            .field("evaluations", &self.evaluations)
            .finish_non_exhaustive()
    }
}

impl ChatterMonitor {
    /// The monitor of `config.tandem_mills[index]`.
    pub fn new(config: &Config, index: usize) -> Result<Self, ChatterSetupError> {
        let mill: &TandemMill = &config.tandem_mills[index];
        // The configuration checked that all stands share one sample rate.
        let fs = mill
            .stands
            .first()
            .map_or(0.0, |&c| config.channels[c].sample_rate_hz);
        let window = (mill.window_s * fs).round() as usize;
        if window < MIN_WINDOW_SAMPLES {
            return Err(ChatterSetupError::WindowTooShort {
                index,
                mill: mill.name.clone(),
                window_s: mill.window_s,
                sample_rate_hz: fs,
                samples: window,
            });
        }
        let (low_hz, high_hz) = mill.chatter_band_hz;
        let detector = ChatterDetector::new(ChatterSettings {
            band_low_hz: low_hz,
            band_high_hz: high_hz,
            k_max: mill.k_max,
        })
        .map_err(|source| ChatterSetupError::Detector {
            index,
            mill: mill.name.clone(),
            source,
        })?;
        let bins = window / 2 + 1;
        let step_hz = fs / window as f64;
        let low_bin = (low_hz / step_hz).ceil().max(1.0) as usize;
        let high_bin = (high_hz / step_hz).floor() as usize;
        // The same check as the detector's: a band bin with two neighbours.
        if low_bin > high_bin || high_bin + 1 >= bins {
            return Err(ChatterSetupError::WindowTooShortForBand {
                index,
                mill: mill.name.clone(),
                window_s: mill.window_s,
                step_hz,
                low_hz,
                high_hz,
            });
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
        let hop = (window / 2).max(1);
        let max_lag = (MAX_STAND_LAG_S * fs).ceil() as i64;
        // Room for a full window, a hop of slack and the largest allowed lag.
        let ring_len = window + hop + max_lag as usize;
        let stands = mill
            .stands
            .iter()
            .map(|_| StandStream {
                ring: vec![0.0; ring_len],
                counted: 0,
                anchor: None,
            })
            .collect();
        let n = mill.stands.len();
        let hop_s = hop as f64 / fs;
        let window_hops = (mill.gain_window_s / hop_s).round();
        if !((1.0..=MAX_WINDOW_HOPS as f64).contains(&window_hops)
            && (window_hops * hop_s - mill.gain_window_s).abs() <= 1e-6 * mill.gain_window_s)
        {
            return Err(ChatterSetupError::GainWindow {
                index,
                mill: mill.name.clone(),
                gain_window_s: mill.gain_window_s,
                hop_s,
            });
        }
        let band_gain = BandGain::new(BandGainSettings {
            sample_rate_hz: fs,
            chatter_band_hz: mill.chatter_band_hz,
            reference_band_hz: mill.reference_band_hz,
            hop_samples: hop,
            window_hops: window_hops as usize,
            stands: n,
        })
        .map_err(|source| ChatterSetupError::BandGain {
            index,
            mill: mill.name.clone(),
            source,
        })?;
        Ok(Self {
            name: mill.name.clone(),
            detector,
            kind: mill.detector,
            gain_state: band_gain.state(),
            band_gain,
            gain_next: 0,
            gain_thresholds: mill.gain_thresholds.clone(),
            gain: None,
            gain_window: None,
            slow_down: SlowDown::new(mill.slow_down_release, mill.slow_down_hold_s),
            sample_rate_hz: fs,
            window,
            hop,
            max_lag,
            stands,
            forward,
            inverse,
            hann,
            magnitude_scale,
            band_bins: (low_bin, high_bin),
            buffer: vec![Complex::new(0.0, 0.0); window],
            scratch: vec![Complex::new(0.0, 0.0); scratch_len],
            magnitudes: vec![0.0; n * bins],
            band_signals: vec![0.0; n * window],
            valid_from: 0,
            next_end: window as i64,
            epoch: None,
            reference_origin_s: None,
            lagging: None,
            evaluations: 0,
        })
    }

    /// The mill's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Samples per window.
    pub fn window_samples(&self) -> usize {
        self.window
    }

    /// Samples per hop (half a window).
    pub fn hop_samples(&self) -> usize {
        self.hop
    }

    /// Spectrum frequency step, Hz (sigma_min).
    pub fn frequency_step_hz(&self) -> f64 {
        self.sample_rate_hz / self.window as f64
    }

    /// Windows evaluated since start.
    pub fn evaluations(&self) -> u64 {
        self.evaluations
    }

    /// Time between evaluations, s.
    pub fn hop_s(&self) -> f64 {
        self.hop as f64 / self.sample_rate_hz
    }

    /// The detector that raises the alarm and the slow-down request.
    pub fn detector(&self) -> ChatterDetectorKind {
        self.kind
    }

    /// The chatter-band gain of the window that ended with the latest evaluation;
    /// `None` while its window refills after a restart.
    pub fn gain(&self) -> Option<GainReading> {
        self.gain
    }

    /// The band gain's window behind [`Self::gain`], per stand.
    pub fn gain_window(&self) -> Option<&BandGainWindow> {
        self.gain_window.as_ref()
    }

    /// Common sample index one past the last window evaluated (the first sample
    /// anchors the axis at 0 when all stands start together).
    pub fn last_window_end(&self) -> i64 {
        self.next_end - self.hop as i64
    }

    /// The configured detector's verdict on one update: moves `slow_down` and returns
    /// the warning and alarm of this window (see [`ChatterAnalysis`]); both false for
    /// a restart or a window that could not be evaluated.
    pub fn judge(&self, change: &ChatterUpdate, slow_down: &mut SlowDown) -> Verdict {
        let ChatterUpdate::Evaluated(result) = change else {
            slow_down.untrusted();
            return Verdict {
                warning: false,
                alarm: false,
                slow_down: slow_down.requested(),
            };
        };
        match self.alarm_level(result) {
            Some(level) => {
                slow_down.window(level, self.hop_s());
            }
            None => slow_down.untrusted(),
        }
        let (warning, alarm) = match self.kind {
            ChatterDetectorKind::BandGain => {
                let ratio = self.gain.and_then(|g| g.ratio).map(|(ratio, _)| ratio);
                (
                    ratio.is_some_and(|r| r >= slow_down.release),
                    ratio.is_some_and(|r| r >= 1.0),
                )
            }
            ChatterDetectorKind::Paper => (result.frequencies_locked, result.synchronized),
        };
        Verdict {
            warning,
            alarm,
            slow_down: slow_down.requested(),
        }
    }

    /// The configured detector's alarm figure for an evaluation with `result`,
    /// relative to its alarm level (>= 1: alarm): the gain ratio, or for the paper's
    /// detector 1 when synchronized, the release level when only the frequencies
    /// lock (it holds a slow-down request), else 0. `None` when the figure is not
    /// available (no gain window yet, or no thresholds).
    pub fn alarm_level(&self, result: &ChatterResult) -> Option<f64> {
        match self.kind {
            ChatterDetectorKind::BandGain => self.gain.and_then(|g| g.ratio).map(|(r, _)| r),
            ChatterDetectorKind::Paper => Some(if result.synchronized {
                1.0
            } else if result.frequencies_locked {
                self.slow_down.release
            } else {
                0.0
            }),
        }
    }

    /// A fresh slow-down request with the mill's release level and hold.
    pub fn slow_down(&self) -> SlowDown {
        SlowDown::new(self.slow_down.release, self.slow_down.hold_s)
    }

    /// Samples of stand `stand` (index in the mill's `stands`), oldest first, that
    /// arrived at `arrival`. Returns what changed: a restart, or an evaluation when
    /// this completed a hop on every stand.
    pub fn samples(
        &mut self,
        stand: usize,
        values: &[f64],
        arrival: Instant,
    ) -> Option<ChatterUpdate> {
        if values.is_empty() || stand >= self.stands.len() {
            return None;
        }
        let realigned = self.anchor(stand, values.len(), arrival);
        let stream = &mut self.stands[stand];
        let start = stream.next_index().unwrap_or(0);
        let ring_len = stream.ring.len() as i64;
        for (index, &value) in (start..).zip(values) {
            stream.ring[index.rem_euclid(ring_len) as usize] = value;
        }
        stream.counted += values.len() as i64;
        match realigned {
            Realigned::Same => {}
            // A stand's first samples (at start, or after a gap that already
            // restarted the window): nothing valid is lost.
            Realigned::First => self.restart(),
            Realigned::Changed => {
                self.restart();
                return Some(ChatterUpdate::Restarted(RestartCause::Realigned { stand }));
            }
        }
        if let Some(cause) = self.check_lag() {
            return Some(ChatterUpdate::Restarted(cause));
        }
        self.feed_band_gain();
        let end = self.due_window_end()?;
        self.next_end = end + self.hop as i64;
        Some(match self.evaluate(end) {
            Ok(result) => {
                self.evaluations += 1;
                ChatterUpdate::Evaluated(result)
            }
            Err(error) => ChatterUpdate::Failed(error),
        })
    }

    /// Samples were lost on stand `stand`: `missed` of them when known. Restarts the
    /// window; an unknown gap also drops the stand's anchor (it is re-anchored from
    /// the arrival of its next samples).
    pub fn gap(&mut self, stand: usize, missed: Option<u64>) -> Option<ChatterUpdate> {
        let stream = self.stands.get_mut(stand)?;
        match missed.and_then(|m| i64::try_from(m).ok()) {
            Some(missed) => stream.counted = stream.counted.saturating_add(missed),
            None => {
                stream.anchor = None;
                stream.counted = 0;
            }
        }
        self.restart();
        Some(ChatterUpdate::Restarted(RestartCause::Gap { stand }))
    }

    /// Update the stand's anchor with a message of `len` samples arriving at
    /// `arrival` (before they are counted).
    fn anchor(&mut self, stand: usize, len: usize, arrival: Instant) -> Realigned {
        let epoch = *self.epoch.get_or_insert(arrival);
        let fs = self.sample_rate_hz;
        let stream = &mut self.stands[stand];
        let through = (stream.counted + len as i64) as f64 / fs;
        let origin_s = arrival.saturating_duration_since(epoch).as_secs_f64() - through;
        let reference = *self.reference_origin_s.get_or_insert(origin_s);
        let previous = stream.anchor;
        let block = previous.map_or(len as i64, |a| a.block).max(1);
        let origin_s = previous.map_or(origin_s, |a| a.origin_s.min(origin_s));
        let blocks = ((origin_s - reference) * fs / block as f64).round() as i64;
        let offset = blocks * block;
        stream.anchor = Some(Anchor {
            origin_s,
            block,
            offset,
        });
        match previous {
            None => Realigned::First,
            Some(old) if old.offset == offset => Realigned::Same,
            Some(_) => Realigned::Changed,
        }
    }

    /// Forget the window: the next one starts after every stand's latest sample.
    /// The band gain restarts with the next window, so its hops end with the windows.
    fn restart(&mut self) {
        let latest = self
            .stands
            .iter()
            .filter_map(StandStream::next_index)
            .max()
            .unwrap_or(0);
        self.valid_from = self.valid_from.max(latest);
        self.next_end = self.next_end.max(self.valid_from + self.window as i64);
        self.band_gain.reset(&mut self.gain_state);
        self.gain_next = self.next_end - self.window as i64;
        self.gain = None;
        self.gain_window = None;
    }

    /// Feed the band gain every frame all stands have and the rings still hold.
    fn feed_band_gain(&mut self) {
        let mut earliest = i64::MAX;
        let mut latest = i64::MIN;
        for stream in &self.stands {
            let Some(next) = stream.next_index() else {
                return;
            };
            earliest = earliest.min(next);
            latest = latest.max(next);
        }
        let oldest_held = latest - self.stands[0].ring.len() as i64;
        if self.gain_next < oldest_held {
            // Cannot happen while the lag check restarts the window in time; if it
            // did, the frames are gone: start the gain again rather than feed stale ones.
            self.band_gain.reset(&mut self.gain_state);
            self.gain = None;
            self.gain_window = None;
            self.gain_next = oldest_held;
        }
        let mut frame = [0.0; MAX_STANDS];
        let frame = &mut frame[..self.stands.len()];
        for index in self.gain_next..earliest {
            for (value, stream) in frame.iter_mut().zip(&self.stands) {
                *value = stream.sample(index);
            }
            // The frame has one sample per stand, as the gain was built for.
            if let Ok(Some(window)) = self.band_gain.process(&mut self.gain_state, frame) {
                self.gain = Some(GainReading::new(&window, &self.gain_thresholds));
                self.gain_window = Some(window);
            }
        }
        self.gain_next = self.gain_next.max(earliest);
    }

    /// Restart once when a stand falls too far behind; clears when it catches up.
    fn check_lag(&mut self) -> Option<RestartCause> {
        let indices = self.stands.iter().map(StandStream::next_index);
        let latest = indices.clone().flatten().max()?;
        let (stand, earliest) = indices
            .enumerate()
            .filter_map(|(s, i)| i.map(|i| (s, i)))
            .min_by_key(|&(_, i)| i)?;
        if latest - earliest <= self.max_lag {
            self.lagging = None;
            return None;
        }
        if self.lagging.replace(stand).is_some() {
            return None;
        }
        self.restart();
        Some(RestartCause::Lagging { stand })
    }

    /// End of the window to evaluate now, if every stand has it.
    fn due_window_end(&mut self) -> Option<i64> {
        let mut earliest = i64::MAX;
        let mut latest = i64::MIN;
        for stream in &self.stands {
            let next = stream.next_index()?;
            earliest = earliest.min(next);
            latest = latest.max(next);
        }
        if earliest < self.next_end {
            return None;
        }
        // The newest window on the hop grid that every stand has; the most advanced
        // stand's ring must still hold its start.
        let hop = self.hop as i64;
        let end = self.next_end + (earliest - self.next_end) / hop * hop;
        let ring_len = self.stands[0].ring.len() as i64;
        (latest - ring_len <= end - self.window as i64).then_some(end)
    }

    /// Spectra and band signals of the window ending at `end`, then the detector.
    fn evaluate(&mut self, end: i64) -> Result<ChatterResult, ChatterError> {
        let n = self.window;
        let bins = n / 2 + 1;
        let start = end - n as i64;
        let (low, high) = self.band_bins;
        for (s, stream) in self.stands.iter().enumerate() {
            let mean = (start..end).map(|i| stream.sample(i)).sum::<f64>() / n as f64;
            for ((slot, i), w) in self.buffer.iter_mut().zip(start..end).zip(&self.hann) {
                *slot = Complex::new((stream.sample(i) - mean) * w, 0.0);
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
        let count = self.stands.len();
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

/// Every tandem mill's monitor, fed by the analysis task; results go to the
/// register map (PLC writes, HMI server) and `/metrics`.
///
/// Published per mill after each evaluation: sigma_n, K_mean, the chatter frequency
/// (mean of the stands' principal frequencies), the chatter-band gain, band RMS and
/// gain ratio with its stand, and the configured detector's bits: warning (band gain:
/// gain ratio >= `slow_down_release` in this window; paper: sigma_n <= sigma_min),
/// alarm (band gain: ratio >= 1; paper: both conditions; latched until acknowledged,
/// like the driveline alarms) and the slow-down request ([`SlowDown`]). A restart
/// clears the values and sets "source stale" until the next full window.
#[derive(Debug)]
pub struct ChatterAnalysis {
    monitors: Vec<ChatterMonitor>,
    /// Per mill, the slow-down request.
    slow_downs: Vec<SlowDown>,
    /// Per channel: the (mill, stand) pairs it feeds.
    by_channel: Vec<Vec<(usize, usize)>>,
    board: Arc<Board>,
}

impl ChatterAnalysis {
    /// Monitors for every tandem mill of `config`.
    pub fn new(config: &Config, board: Arc<Board>) -> Result<Self, ChatterSetupError> {
        let mut by_channel = vec![Vec::new(); config.channels.len()];
        let mut monitors = Vec::new();
        for (m, mill) in config.tandem_mills.iter().enumerate() {
            monitors.push(ChatterMonitor::new(config, m)?);
            for (s, &channel) in mill.stands.iter().enumerate() {
                by_channel[channel].push((m, s));
            }
        }
        Ok(Self {
            slow_downs: monitors.iter().map(ChatterMonitor::slow_down).collect(),
            monitors,
            by_channel,
            board,
        })
    }

    /// The monitors, in config order.
    pub fn monitors(&self) -> &[ChatterMonitor] {
        &self.monitors
    }

    /// Route one reader message to the mills whose stand it is, and publish what
    /// changed.
    pub fn handle(&mut self, message: &Acquired) {
        let channel = match message {
            Acquired::Samples { channel, .. } | Acquired::Gap { channel, .. } => *channel,
            Acquired::ProcessValue { .. } => return,
        };
        let Some(stands) = self.by_channel.get(channel) else {
            return;
        };
        let now = Instant::now();
        for &(mill, stand) in stands {
            let monitor = &mut self.monitors[mill];
            let change = match message {
                Acquired::Samples { values, .. } => monitor.samples(stand, values, now),
                Acquired::Gap { missed_samples, .. } => monitor.gap(stand, *missed_samples),
                Acquired::ProcessValue { .. } => None,
            };
            if let Some(change) = change {
                publish(
                    &self.board,
                    mill,
                    monitor,
                    &mut self.slow_downs[mill],
                    &change,
                );
            }
        }
    }
}

/// Record one monitor update in the published results, and in the history the
/// chatter episodes (from the warning condition set to it cleared) and the alarm.
fn publish(
    board: &Board,
    mill: usize,
    monitor: &ChatterMonitor,
    slow_down: &mut SlowDown,
    change: &ChatterUpdate,
) {
    let name = monitor.name();
    let was_requested = slow_down.requested();
    let verdict = monitor.judge(change, slow_down);
    if verdict.slow_down != was_requested {
        tracing::warn!(
            mill = %name,
            requested = slow_down.requested(),
            "chatter slow-down request changed"
        );
    }
    board.update_recorded(|results, events| {
        let Some(published) = results.tandem_mills.get_mut(mill) else {
            return;
        };
        let was_flagged = published.source_stale;
        let (was_warning, was_alarm) = (published.chatter_warning, published.chatter_alarm);
        match change {
            ChatterUpdate::Evaluated(result) => {
                published.evaluations = monitor.evaluations();
                published.sigma_n_hz = Some(result.sigma_n_hz);
                published.k_mean = Some(result.k_mean);
                published.chatter_frequency_hz = chatter_frequency_hz(result);
                let gain = monitor.gain();
                published.chatter_gain = gain.map(|g| g.max_gain);
                published.band_rms_max = gain.map(|g| g.max_band_rms);
                published.gain_ratio = gain.and_then(|g| g.ratio).map(|(ratio, _)| ratio);
                published.worst_stand = gain.and_then(|g| g.ratio).map(|(_, stand)| stand);
                let Verdict { warning, alarm, .. } = verdict;
                published.chatter_warning = warning;
                if alarm && !published.chatter_alarm {
                    tracing::warn!(
                        mill = %name,
                        detector = ?monitor.detector(),
                        gain_ratio = ?published.gain_ratio,
                        stand = ?published.worst_stand,
                        sigma_n_hz = result.sigma_n_hz,
                        k_mean = result.k_mean,
                        frequency_hz = ?published.chatter_frequency_hz,
                        "chatter alarm"
                    );
                }
                published.chatter_alarm |= alarm;
                published.source_stale = false;
                if was_flagged {
                    tracing::info!(mill = %name, "chatter window complete again");
                }
            }
            ChatterUpdate::Failed(error) => {
                if published.k_mean.is_some() {
                    tracing::warn!(mill = %name, %error, "chatter window not evaluable");
                }
                clear(published);
            }
            ChatterUpdate::Restarted(cause) => {
                if !was_flagged {
                    tracing::warn!(mill = %name, %cause, "chatter window restarted, values invalid");
                }
                clear(published);
                published.source_stale = true;
            }
        }
        published.slow_down_request = verdict.slow_down;
        record_episode(events, name, change, (was_warning, was_alarm), published);
    });
}

/// The history events of one update: an episode starts, goes on or ends with the
/// warning condition (a window restart ends it too); the alarm is recorded when it
/// latches.
fn record_episode(
    events: &mut Vec<HistoryEvent>,
    mill: &str,
    change: &ChatterUpdate,
    (was_warning, was_alarm): (bool, bool),
    published: &TandemMillResults,
) {
    let time = UtcTime::now();
    let window = match change {
        ChatterUpdate::Evaluated(result) => Some(ChatterWindow {
            sigma_n_hz: result.sigma_n_hz,
            k_mean: result.k_mean,
            frequency_hz: published.chatter_frequency_hz,
            synchronized: result.synchronized,
        }),
        _ => None,
    };
    match (was_warning, published.chatter_warning, window) {
        (false, true, Some(window)) => events.push(HistoryEvent::ChatterStarted {
            time,
            mill: mill.to_owned(),
            window,
        }),
        (true, true, Some(window)) => events.push(HistoryEvent::ChatterWindow {
            mill: mill.to_owned(),
            window,
        }),
        (true, false, window) => events.push(HistoryEvent::ChatterEnded {
            time,
            mill: mill.to_owned(),
            ended_by: if window.is_some() {
                EndedBy::Analysis
            } else {
                EndedBy::WindowRestart
            },
        }),
        _ => {}
    }
    let alarm = |kind, event| {
        HistoryEvent::Alarm(AlarmRecord {
            time,
            subject: mill.to_owned(),
            kind,
            event,
            origin: None,
            value: published.gain_ratio.or(published.k_mean),
            threshold: None,
        })
    };
    if published.chatter_warning != was_warning {
        let event = if published.chatter_warning {
            AlarmEvent::Raised
        } else {
            AlarmEvent::Cleared
        };
        events.push(alarm(AlarmKind::ChatterWarning, event));
    }
    if published.chatter_alarm && !was_alarm {
        events.push(alarm(AlarmKind::ChatterAlarm, AlarmEvent::Raised));
    }
}

/// Values invalid: never a frozen old value.
fn clear(published: &mut TandemMillResults) {
    published.sigma_n_hz = None;
    published.k_mean = None;
    published.chatter_frequency_hz = None;
    published.chatter_gain = None;
    published.gain_ratio = None;
    published.band_rms_max = None;
    published.worst_stand = None;
    published.chatter_warning = false;
}

#[cfg(test)]
mod tests {
    use std::f64::consts::TAU;
    use std::time::Duration;

    use super::*;

    const FS: f64 = 2500.0;
    /// Samples per simulated DAQ block: 48 ms.
    const BLOCK: usize = 120;

    /// A mill of `stands` stands at 2500 Hz, band 100-300 Hz, window 0.5 s.
    fn monitor(stands: usize) -> ChatterMonitor {
        let mut text = String::from(
            "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
        );
        for s in 0..stands {
            text += &format!(
                "[[channels]]\nname = \"s{s}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
                 sample_rate_hz = {FS}\nsource = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
                s * 122
            );
        }
        let names: Vec<String> = (0..stands).map(|s| format!("\"s{s}\"")).collect();
        // Thresholds 1, 2, 3, ...: the ratio of stand s is its gain / (s + 1).
        let thresholds: Vec<String> = (1..=stands).map(|s| format!("{s}.0")).collect();
        text += &format!(
            "[[tandem_mills]]\nname = \"TCM\"\nstands = [{}]\nchatter_band_hz = [100.0, 300.0]\n\
             window_s = 0.5\nk_max = 0.25\ngain_thresholds = [{}]\n",
            names.join(", "),
            thresholds.join(", ")
        );
        let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
            .expect("test config");
        ChatterMonitor::new(&config, 0).expect("monitor")
    }

    fn sine(f_hz: f64, phase: f64, amplitude: f64, samples: std::ops::Range<usize>) -> Vec<f64> {
        samples
            .map(|k| amplitude * (TAU * f_hz * k as f64 / FS + phase).sin())
            .collect()
    }

    /// Feed `signals` (one per stand) block by block, all stands of a block arriving
    /// at the same instant, one block period apart; the evaluations in order.
    fn feed(monitor: &mut ChatterMonitor, signals: &[Vec<f64>], t0: Instant) -> Vec<ChatterResult> {
        let mut results = Vec::new();
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        for (b, start) in (0..signals[0].len()).step_by(BLOCK).enumerate() {
            let arrival = t0 + period * b as u32;
            for (s, signal) in signals.iter().enumerate() {
                let end = (start + BLOCK).min(signal.len());
                if let Some(ChatterUpdate::Evaluated(r)) =
                    monitor.samples(s, &signal[start..end], arrival)
                {
                    results.push(r);
                }
            }
        }
        results
    }

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
        let usable = 12_000 - BLOCK;
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

    #[test]
    fn gap_restarts_the_window_and_flags_until_a_full_one() {
        let mut monitor = monitor(2);
        let t0 = Instant::now();
        let signal = sine(180.0, 0.0, 1.0, 0..40 * BLOCK);
        let block = |b: usize| &signal[b * BLOCK..(b + 1) * BLOCK];
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        let mut evaluated_at = Vec::new();
        for b in 0..40 {
            let arrival = t0 + period * b as u32;
            if b == 15 {
                assert_eq!(
                    monitor.gap(1, Some(BLOCK as u64)),
                    Some(ChatterUpdate::Restarted(RestartCause::Gap { stand: 1 }))
                );
            }
            for s in 0..2 {
                // Stand 1 loses block 14: the gap above says so.
                if s == 1 && b == 14 {
                    continue;
                }
                if let Some(ChatterUpdate::Evaluated(_)) = monitor.samples(s, block(b), arrival) {
                    evaluated_at.push(b);
                }
            }
        }
        // Block 0 anchors; windows of 1250 from sample 120 end in block 11, then
        // every 625 samples (block 16 would be next). The gap at block 15 restarts
        // at sample 1800: windows end at 3050 (block 25), 3675 (30), 4300 (35).
        assert_eq!(evaluated_at, [11, 25, 30, 35]);
    }

    #[test]
    fn stand_that_stops_is_flagged_once() {
        let mut monitor = monitor(2);
        let t0 = Instant::now();
        let signal = sine(180.0, 0.0, 1.0, 0..40 * BLOCK);
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        let mut restarts = Vec::new();
        for b in 0..40 {
            for s in 0..2 {
                if s == 1 && b >= 5 {
                    continue;
                }
                let values = &signal[b * BLOCK..(b + 1) * BLOCK];
                if let Some(ChatterUpdate::Restarted(cause)) =
                    monitor.samples(s, values, t0 + period * b as u32)
                {
                    restarts.push((b, cause));
                }
            }
        }
        let lagging: Vec<_> = restarts
            .iter()
            .filter(|(_, c)| matches!(c, RestartCause::Lagging { .. }))
            .collect();
        assert_eq!(lagging.len(), 1, "{restarts:?}");
        // 0.5 s = 1250 samples: the lag passes that at the 11th block after the stop.
        assert_eq!(
            *lagging[0],
            (5 + 1250 / BLOCK, RestartCause::Lagging { stand: 1 })
        );
    }

    #[test]
    fn stand_starting_one_block_late_is_realigned_from_arrival_times() {
        // A shared chatter line at a frequency where a one-block (48 ms) shift turns
        // the phase by half a turn: misaligned stands would anti-correlate.
        let f_hz = 197.0 + 11.0 / 12.0;
        let mut monitor = monitor(2);
        let signal = sine(f_hz, 0.0, 1.0, 0..60 * BLOCK);
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        let poll = Duration::from_millis(20);
        let t0 = Instant::now();
        // DAQ block b is published at t0 + b * period; a poll every 20 ms reads the
        // newest block of each stand. At the first poll block 1 of stand 1 is already
        // out when it is read (published between the two reads), block 0 for stand 0.
        // DAQ block b is published at t0 + b * period; a poll every 20 ms reads the
        // newest block of each stand. The first poll reads stand 0 just before block 1
        // is published and stand 1 just after: stand 1 starts one block ahead.
        let mut last = [None, None];
        let mut results = Vec::new();
        for p in 0..140u32 {
            let at = t0 + period - Duration::from_micros(100) + poll * p;
            let newest = ((at - t0).as_nanos() / period.as_nanos()) as usize;
            for (s, last) in last.iter_mut().enumerate() {
                let (block, at) = if p == 0 && s == 1 {
                    (1, at + Duration::from_micros(200))
                } else {
                    (newest, at)
                };
                if last.is_some_and(|l| l >= block) {
                    continue;
                }
                *last = Some(block);
                let values = &signal[block * BLOCK..(block + 1) * BLOCK];
                if let Some(ChatterUpdate::Evaluated(r)) = monitor.samples(s, values, at) {
                    results.push(r);
                }
            }
        }
        let r = results.last().expect("evaluations after realignment");
        assert!(r.k_mean > 0.95, "K_mean {}", r.k_mean);
        assert!(r.synchronized);
    }

    #[test]
    fn gain_is_the_band_to_reference_rms_ratio_of_each_window() {
        let mut monitor = monitor(2);
        let hop_s = monitor.hop_s();
        // Chatter-band line A = 2.0 at 180 Hz, reference-band line B = 0.5 at 620 Hz:
        // the Butterworth band-passes pass each (gain within 1% of 1 there), so the
        // gain is A / B = 4 and the band RMS A / sqrt 2. Stand 1 has half the chatter.
        let line = |a: f64| -> Vec<f64> {
            sine(180.0, 0.2, a, 0..20_000)
                .iter()
                .zip(sine(620.0, 1.0, 0.5, 0..20_000))
                .map(|(x, y)| x + y)
                .collect()
        };
        let t0 = Instant::now();
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        let signals = [line(2.0), line(1.0)];
        let mut readings = Vec::new();
        let mut evaluations = 0;
        let mut last_result = None;
        for (b, start) in (0..20_000 - BLOCK).step_by(BLOCK).enumerate() {
            for (s, signal) in signals.iter().enumerate() {
                let update =
                    monitor.samples(s, &signal[start..start + BLOCK], t0 + period * b as u32);
                if let Some(ChatterUpdate::Evaluated(result)) = update {
                    evaluations += 1;
                    readings.push(monitor.gain());
                    last_result = Some(result);
                }
            }
        }
        // The first evaluations come before the 2 s gain window (8 hops after a
        // settling hop) is full: no reading, never a partial one. The spectra's first
        // window (2 hops) ends with evaluation 0, the gain's first with number 9 - 2.
        let first = readings
            .iter()
            .position(Option::is_some)
            .expect("a gain reading");
        assert_eq!(first, (2.0 / hop_s) as usize + 1 - 2, "{readings:?}");
        assert!(readings[first..].iter().all(Option::is_some));
        assert_eq!(readings.len(), evaluations);
        let last = readings.last().copied().flatten().expect("reading");
        assert!((last.max_gain - 4.0).abs() < 0.04 * 4.0, "{last:?}");
        assert!(
            (last.max_band_rms - 2.0 / 2f64.sqrt()).abs() < 0.03,
            "{last:?}"
        );
        // Thresholds 1 and 2: stand 0's ratio 4, stand 1's (gain 2) / 2 = 1.
        let (ratio, stand) = last.ratio.expect("ratio");
        assert_eq!(stand, 0);
        assert!((ratio - 4.0).abs() < 0.16, "{ratio}");
        let result = last_result.expect("an evaluation");
        assert_eq!(monitor.alarm_level(&result), Some(ratio));

        // A gap restarts the gain too: no reading until its window refilled.
        monitor.gap(0, Some(BLOCK as u64));
        assert_eq!(monitor.gain(), None);
    }

    #[test]
    fn gain_window_must_be_whole_hops() {
        let text = "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\n\
                    poll_period_ms = 20\n[[channels]]\nname = \"a\"\nkind = \"acceleration\"\n\
                    unit = \"g\"\nsample_rate_hz = 2500.0\nsource = { modbus = \"daq\", table = \"input\", block = 0 }\n\
                    [[channels]]\nname = \"b\"\nkind = \"acceleration\"\nunit = \"g\"\n\
                    sample_rate_hz = 2500.0\nsource = { modbus = \"daq\", table = \"input\", block = 122 }\n\
                    [[tandem_mills]]\nname = \"TCM\"\nstands = [\"a\", \"b\"]\n\
                    chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
                    gain_thresholds = [1.0, 1.0]\n";
        for (gain_window_s, accepted) in [
            (2.0, true),
            (0.25, true),
            (4.0, true),
            (1.1, false),
            (4.25, false),
        ] {
            let text = format!("{text}gain_window_s = {gain_window_s}\n");
            let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
                .expect("valid configuration");
            match ChatterMonitor::new(&config, 0) {
                Ok(_) => assert!(accepted, "{gain_window_s} s accepted"),
                Err(error) => {
                    assert!(!accepted, "{gain_window_s} s: {error}");
                    assert_eq!(
                        error.to_string(),
                        format!(
                            "tandem_mills[0].gain_window_s: {gain_window_s} s is not allowed (must be 1 \
                             to 16 whole hops of window_s / 2 = 0.25 s; tandem mill \"TCM\")"
                        )
                    );
                }
            }
        }
    }

    #[test]
    fn slow_down_request_has_hysteresis_and_holds_through_untrusted_data() {
        let mut slow_down = SlowDown::new(0.8, 1.0);
        let step = 0.25;
        // Below the alarm level: nothing requested, however long.
        for level in [0.5, 0.9, 0.99, 0.0] {
            assert!(!slow_down.window(level, step));
        }
        assert!(slow_down.window(1.0, step), "set at the alarm level");
        // Between release and alarm the request holds indefinitely.
        for _ in 0..20 {
            assert!(slow_down.window(0.85, step));
        }
        // Below release: cleared after 1 s = 4 windows, not before.
        for _ in 0..3 {
            assert!(slow_down.window(0.5, step));
        }
        // Untrusted data restarts the time below release.
        slow_down.untrusted();
        for _ in 0..3 {
            assert!(slow_down.window(0.5, step));
        }
        // A window back above release restarts it as well.
        assert!(slow_down.window(0.8, step));
        for _ in 0..3 {
            assert!(slow_down.window(0.79, step));
        }
        assert!(
            !slow_down.window(0.79, step),
            "cleared after 4 windows below"
        );
        assert!(!slow_down.requested());
    }
}
