//! [`ChatterMonitor`]: one tandem mill's sliding windows, built from its configuration;
//! each message of a stand's samples goes through the alignment (`align`),
//! the band gain (`gain`) and, every hop, the spectra (`spectra`).
//!
//! **Window and hop.** Every hop of half a window (`window_s / 2`, so windows overlap by
//! half, the usual choice for Hann windows) the window of `N = round(window_s * fs)`
//! samples that ends at the same sample on every stand is analysed.
//!
//! **Restarts.** A gap on any stand, a stand falling more than
//! [`super::MAX_STAND_LAG_S`] behind the others, or a change of a stand's anchor
//! invalidates the mill's values (flag "source stale") and restarts the window: the
//! next evaluation uses only samples taken after the restart on every stand, and the
//! gain's filters restart.
//!
//! **Product groups.** A mill with `product_groups` is judged by the thresholds of the
//! group holding the product given to [`ChatterMonitor::use_product`] (the PLC's, at
//! the time of the samples), by the mill's `gain_thresholds` for any other product or
//! none. A change of group applies to the latest window's reading at once and to
//! every window from then on (a window that spans the change is judged wholly by the
//! new group's thresholds); the windows and filters run on.

use std::time::Instant;

use millgate_config::{ChatterDetectorKind, Config, TandemMill};
use millgate_dsp::band_gain::{
    BandGain, BandGainError, BandGainSettings, BandGainWindow, MAX_WINDOW_HOPS,
};
use millgate_dsp::chatter::{ChatterError, ChatterResult};

use super::align::{Alignment, Realigned, RestartCause};
use super::gain::{GainReading, GainTracker};
use super::spectra::{Spectra, SpectraError};
use super::verdict::{self, SlowDown, Verdict, WeldHold};

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

/// Sliding-window chatter monitor of one tandem mill (see the module docs).
pub struct ChatterMonitor {
    name: String,
    kind: ChatterDetectorKind,
    /// The slow-down request's release level and hold, from the configuration.
    slow_down: SlowDown,
    sample_rate_hz: f64,
    window: usize,
    hop: usize,
    aligned: Alignment,
    spectra: Spectra,
    gain: GainTracker,
    evaluations: u64,
    /// The mill's entry as last applied: its `gain_thresholds` and `product_groups`
    /// judge.
    settings: TandemMill,
    /// The product the thresholds follow ([`Self::use_product`]).
    product: Option<u32>,
    /// The group of `product` in `settings` (`None`: the mill's thresholds).
    group: Option<usize>,
}

// By hand: the rings, FFT plans and buffers are not worth printing.
impl std::fmt::Debug for ChatterMonitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChatterMonitor")
            .field("name", &self.name)
            .field("stands", &self.aligned.stands())
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
        let n = mill.stands.len();
        let (low_hz, high_hz) = mill.chatter_band_hz;
        let spectra =
            Spectra::new(n, fs, window, mill.chatter_band_hz, mill.k_max).map_err(|error| {
                match error {
                    SpectraError::Detector(source) => ChatterSetupError::Detector {
                        index,
                        mill: mill.name.clone(),
                        source,
                    },
                    SpectraError::BandTooNarrow { step_hz } => {
                        ChatterSetupError::WindowTooShortForBand {
                            index,
                            mill: mill.name.clone(),
                            window_s: mill.window_s,
                            step_hz,
                            low_hz,
                            high_hz,
                        }
                    }
                }
            })?;
        let hop = (window / 2).max(1);
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
            kind: mill.detector,
            slow_down: slow_down_of(mill),
            sample_rate_hz: fs,
            window,
            hop,
            aligned: Alignment::new(n, fs, window, hop),
            spectra,
            gain: GainTracker::new(band_gain, mill.gain_thresholds.clone()),
            evaluations: 0,
            settings: mill.clone(),
            product: None,
            group: None,
        })
    }

    /// Judge by `mill`'s thresholds from the next window on (a reload): its
    /// `gain_thresholds`, the slow-down request's release level and hold and the weld
    /// hold. The windows, filters and detector run on as they are (what changes them
    /// needs a restart, `service::reload`).
    pub fn set_thresholds(&mut self, mill: &TandemMill) {
        self.slow_down = slow_down_of(mill);
        self.settings = mill.clone();
        self.group = self
            .product
            .and_then(|product| self.settings.product_group(product));
        self.gain
            .set_thresholds(self.settings.thresholds_of(self.group).to_vec());
    }

    /// Judge by the thresholds of `product` (the PLC's product code; `None`: no valid
    /// and fresh one) from now on: its product group's, or the mill's when no group
    /// holds it (see the module docs). Returns the group in use.
    pub fn use_product(&mut self, product: Option<u32>) -> Option<usize> {
        self.product = product;
        let group = product.and_then(|product| self.settings.product_group(product));
        if group != self.group {
            self.group = group;
            self.gain
                .set_thresholds(self.settings.thresholds_of(group).to_vec());
        }
        group
    }

    /// The product group whose thresholds judge (index in the mill's
    /// `product_groups`); `None`: the mill's `gain_thresholds`.
    pub fn thresholds_group(&self) -> Option<usize> {
        self.group
    }

    /// The name of [`Self::thresholds_group`], when a group's thresholds judge.
    pub fn thresholds_group_name(&self) -> Option<&str> {
        self.group
            .map(|group| self.settings.product_groups[group].name.as_str())
    }

    /// The thresholds that judge now, per stand: [`Self::thresholds_group`]'s, or the
    /// mill's `gain_thresholds`.
    pub fn thresholds(&self) -> &[f64] {
        self.settings.thresholds_of(self.group)
    }

    /// Whether the mill has product groups (then a missing product is a fallback).
    pub fn has_product_groups(&self) -> bool {
        !self.settings.product_groups.is_empty()
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
        self.spectra.frequency_step_hz()
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
        self.gain.reading()
    }

    /// The band gain's window behind [`Self::gain`], per stand.
    pub fn gain_window(&self) -> Option<&BandGainWindow> {
        self.gain.window()
    }

    /// Common sample index one past the last window evaluated (the first sample
    /// anchors the axis at 0 when all stands start together).
    pub fn last_window_end(&self) -> i64 {
        self.aligned.next_end() - self.hop as i64
    }

    /// Common index one past stand `stand`'s latest sample (on the axis of
    /// [`Self::last_window_end`]), once the stand is anchored.
    pub(crate) fn stand_next_index(&self, stand: usize) -> Option<i64> {
        self.aligned.stand_next_index(stand)
    }

    /// The configured detector's verdict on one update: moves `slow_down` and returns
    /// the warning and alarm of this window (see [`super::ChatterAnalysis`]); both
    /// false for a restart or a window that could not be evaluated.
    pub fn judge(&self, change: &ChatterUpdate, slow_down: &mut SlowDown) -> Verdict {
        let evaluated = match change {
            ChatterUpdate::Evaluated(result) => Some(result),
            ChatterUpdate::Failed(_) | ChatterUpdate::Restarted(_) => None,
        };
        verdict::judge(self.kind, self.gain(), self.hop_s(), evaluated, slow_down)
    }

    /// The configured detector's alarm figure for an evaluation with `result`,
    /// relative to its alarm level (>= 1: alarm): the gain ratio, or for the paper's
    /// detector 1 when synchronized, the release level when only the frequencies
    /// lock (it holds a slow-down request), else 0. `None` when the figure is not
    /// available (no gain window yet, or no thresholds).
    pub fn alarm_level(&self, result: &ChatterResult) -> Option<f64> {
        verdict::alarm_level(self.kind, self.gain(), self.slow_down.release(), result)
    }

    /// A fresh slow-down request with the mill's release level and hold.
    pub fn slow_down(&self) -> SlowDown {
        self.slow_down.fresh()
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
        if values.is_empty() || stand >= self.aligned.stands() {
            return None;
        }
        match self.aligned.push(stand, values, arrival) {
            Realigned::Same => {}
            // A stand's first samples (at start, or after a gap that already
            // restarted the window): nothing valid is lost.
            Realigned::First => self.restart(),
            Realigned::Changed => {
                self.restart();
                return Some(ChatterUpdate::Restarted(RestartCause::Realigned { stand }));
            }
        }
        if let Some(cause) = self.aligned.check_lag() {
            self.restart();
            return Some(ChatterUpdate::Restarted(cause));
        }
        self.gain.feed(&self.aligned);
        let end = self.aligned.take_due_window()?;
        Some(match self.spectra.evaluate(&self.aligned, end) {
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
        if stand >= self.aligned.stands() {
            return None;
        }
        self.aligned.gap(stand, missed);
        self.restart();
        Some(ChatterUpdate::Restarted(RestartCause::Gap { stand }))
    }

    /// Forget the window: the next one starts after every stand's latest sample.
    /// The band gain restarts with the next window, so its hops end with the windows.
    fn restart(&mut self) {
        let start = self.aligned.restart();
        self.gain.restart(start);
    }
}

/// A fresh slow-down request with `mill`'s release level, hold and weld hold.
fn slow_down_of(mill: &TandemMill) -> SlowDown {
    SlowDown::with_weld_hold(
        mill.slow_down_release,
        mill.slow_down_hold_s,
        match mill.detector {
            ChatterDetectorKind::BandGain => WeldHold {
                settle_s: mill.weld_settle_s,
                alarm_factor: mill.weld_alarm_factor,
            },
            // The paper's figure has no level above its alarm (`verdict`).
            ChatterDetectorKind::Paper => WeldHold::NONE,
        },
    )
}
