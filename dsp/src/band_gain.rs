//! Chatter-band RMS and chatter-band gain of the n stands of a tandem mill, streamed
//! sample by sample over overlapping windows.
//!
//! Per stand two 8th-order Butterworth band-passes (4th-order high-pass then 4th-order
//! low-pass): the **chatter band** (third-octave chatter, e.g. 100-300 Hz) and a
//! **reference band** above it (e.g. 450-900 Hz, where the work-roll modes answer the
//! same roll-gap force noise but the strip's tension loop adds nothing). Every hop the
//! mean squares of the last window (a whole number of hops) give per stand:
//!
//! - **band RMS**: the RMS of the chatter band (what mills alarm on);
//! - **gain**: chatter-band RMS / reference-band RMS.
//!
//! **Why the gain.** Near the critical speed the chatter band's variance grows like
//! `1 / |alpha|` (alpha the real part of the rightmost characteristic root), for any
//! level of the forces that drive it; the reference band's does not. The band RMS
//! carries the unknown excitation level (it varies by a factor of 2 either way with
//! strip, lubrication and roll condition), so an RMS alarm set at zero false alarms on
//! the noisiest stable rolling fires late on a quiet mill. The gain divides that level
//! out: it is the loop's amplification of the chatter band. The assumption: the
//! reference band is driven by the same broadband roll-gap forces (true of the
//! `sim::tandem` model; on a mill check that no gear-mesh or bearing line dominates it).
//!
//! Coefficients ([`BandGain`]) are split from state ([`BandGainState`]); no heap. The
//! first hop after [`BandGain::state`] or [`BandGain::reset`] lets the filters settle
//! and is not counted.

use heapless::Vec;

use crate::chatter::MAX_STANDS;
use crate::filter::{BiquadState, Cascade, FilterError};

/// Most hops in a window.
pub const MAX_WINDOW_HOPS: usize = 16;

/// Settings of a [`BandGain`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandGainSettings {
    /// Sample rate of every stand, Hz, finite and > 0.
    pub sample_rate_hz: f64,
    /// Chatter band, Hz: low > 0, high > low, high below half the sample rate.
    pub chatter_band_hz: (f64, f64),
    /// Reference band, Hz: same rules as the chatter band.
    pub reference_band_hz: (f64, f64),
    /// Samples per hop (one window ends every hop), >= 8.
    pub hop_samples: usize,
    /// Hops per window, 1 ..= [`MAX_WINDOW_HOPS`] (2: windows overlap by half).
    pub window_hops: usize,
    /// Number of stands, 1 ..= [`MAX_STANDS`].
    pub stands: usize,
}

/// Invalid settings or input; the variant names the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BandGainError {
    /// `sample_rate_hz` is not finite and > 0.
    SampleRateHz,
    /// `chatter_band_hz` is not an ordered band inside (0, sample rate / 2).
    ChatterBandHz,
    /// `reference_band_hz` is not an ordered band inside (0, sample rate / 2).
    ReferenceBandHz,
    /// `hop_samples` is below 8.
    HopSamples,
    /// `window_hops` is not in 1 ..= [`MAX_WINDOW_HOPS`].
    WindowHops,
    /// `stands` is not in 1 ..= [`MAX_STANDS`], or a frame has another length.
    Stands,
}

impl core::fmt::Display for BandGainError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BandGainError::SampleRateHz => "sample_rate_hz must be finite and > 0",
            BandGainError::ChatterBandHz => {
                "chatter_band_hz must be low < high, both > 0 and below half the sample rate"
            }
            BandGainError::ReferenceBandHz => {
                "reference_band_hz must be low < high, both > 0 and below half the sample rate"
            }
            BandGainError::HopSamples => "hop_samples must be >= 8",
            BandGainError::WindowHops => "window_hops must be 1 ..= 16",
            BandGainError::Stands => "stands must be 1 ..= 8, one sample per stand per frame",
        })
    }
}

impl core::error::Error for BandGainError {}

/// One band-pass: high-pass then low-pass, each 4th-order Butterworth.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BandPass {
    high: Cascade<2>,
    low: Cascade<2>,
}

/// State of one [`BandPass`].
type BandPassState = [[BiquadState; 2]; 2];

impl BandPass {
    fn new(band_hz: (f64, f64), sample_rate_hz: f64) -> Result<Self, FilterError> {
        // NaN edges fail in the filters' own checks below.
        if band_hz.0 >= band_hz.1 {
            return Err(FilterError::CutoffHz);
        }
        Ok(Self {
            high: Cascade::butterworth_highpass(band_hz.0, sample_rate_hz)?,
            low: Cascade::butterworth_lowpass(band_hz.1, sample_rate_hz)?,
        })
    }

    #[inline]
    fn process(&self, state: &mut BandPassState, x: f64) -> f64 {
        let [high, low] = state;
        self.low.process(low, self.high.process(high, x))
    }
}

/// Validated band-gain coefficients.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandGain {
    settings: BandGainSettings,
    chatter: BandPass,
    reference: BandPass,
}

/// One stand's running state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct StandState {
    chatter: BandPassState,
    reference: BandPassState,
    /// Sums of squares over the current hop: chatter, reference.
    current: [f64; 2],
    /// The same over the last completed hops, a ring indexed by hop count.
    hops: [[f64; 2]; MAX_WINDOW_HOPS],
    /// Last chatter-band sample.
    band_sample: f64,
}

/// What [`BandGain::process`] mutates.
#[derive(Clone, Debug, PartialEq)]
pub struct BandGainState {
    stands: Vec<StandState, MAX_STANDS>,
    /// Samples into the current hop.
    in_hop: usize,
    /// Hops completed since the reset (the first settles the filters).
    hops: usize,
}

/// Per-stand figures of one window.
#[derive(Clone, Debug, PartialEq)]
pub struct BandGainWindow {
    /// Chatter-band RMS per stand (input units).
    pub band_rms: Vec<f64, MAX_STANDS>,
    /// Reference-band RMS per stand (input units).
    pub(crate) reference_rms: Vec<f64, MAX_STANDS>,
    /// Chatter-band RMS / reference-band RMS per stand (0 when the reference is 0).
    pub gain: Vec<f64, MAX_STANDS>,
}

impl BandGainWindow {
    /// The largest band RMS of any stand.
    pub fn max_band_rms(&self) -> f64 {
        self.band_rms.iter().fold(0.0, |m, &v| m.max(v))
    }

    /// The largest gain of any stand.
    pub fn max_gain(&self) -> f64 {
        self.gain.iter().fold(0.0, |m, &v| m.max(v))
    }
}

impl BandGain {
    /// Validates `settings`.
    pub fn new(settings: BandGainSettings) -> Result<Self, BandGainError> {
        let fs = settings.sample_rate_hz;
        if !(fs.is_finite() && fs > 0.0) {
            return Err(BandGainError::SampleRateHz);
        }
        if settings.hop_samples < 8 {
            return Err(BandGainError::HopSamples);
        }
        if settings.window_hops == 0 || settings.window_hops > MAX_WINDOW_HOPS {
            return Err(BandGainError::WindowHops);
        }
        if settings.stands == 0 || settings.stands > MAX_STANDS {
            return Err(BandGainError::Stands);
        }
        let chatter = BandPass::new(settings.chatter_band_hz, fs)
            .map_err(|_| BandGainError::ChatterBandHz)?;
        let reference = BandPass::new(settings.reference_band_hz, fs)
            .map_err(|_| BandGainError::ReferenceBandHz)?;
        Ok(Self {
            settings,
            chatter,
            reference,
        })
    }

    /// A fresh state.
    pub fn state(&self) -> BandGainState {
        let mut stands = Vec::new();
        for _ in 0..self.settings.stands {
            // At most MAX_STANDS stands, checked in `new`.
            let _ = stands.push(StandState::default());
        }
        BandGainState {
            stands,
            in_hop: 0,
            hops: 0,
        }
    }

    /// Forget the history (after a gap): filters restart and settle for a hop.
    pub fn reset(&self, state: &mut BandGainState) {
        *state = self.state();
    }

    /// One frame: the sample of every stand taken at the same instant, in stand order.
    /// Returns the window that ends with this frame, every hop once a window of hops
    /// after the settling one is in.
    pub fn process(
        &self,
        state: &mut BandGainState,
        frame: &[f64],
    ) -> Result<Option<BandGainWindow>, BandGainError> {
        if frame.len() != state.stands.len() {
            return Err(BandGainError::Stands);
        }
        for (stand, &x) in state.stands.iter_mut().zip(frame) {
            // A NaN or infinite sample would poison the filters: treat it as 0.
            let x = if x.is_finite() { x } else { 0.0 };
            let band = self.chatter.process(&mut stand.chatter, x);
            let reference = self.reference.process(&mut stand.reference, x);
            stand.band_sample = band;
            stand.current[0] += band * band;
            stand.current[1] += reference * reference;
        }
        state.in_hop += 1;
        if state.in_hop < self.settings.hop_samples {
            return Ok(None);
        }
        state.in_hop = 0;
        state.hops += 1;
        let hops = self.settings.window_hops;
        // The first hop settles the filters and is not kept.
        let kept = state.hops - 1;
        let complete = kept >= hops;
        let count = (hops * self.settings.hop_samples) as f64;
        let mut window = BandGainWindow {
            band_rms: Vec::new(),
            reference_rms: Vec::new(),
            gain: Vec::new(),
        };
        for stand in state.stands.iter_mut() {
            if kept > 0 {
                stand.hops[(kept - 1) % MAX_WINDOW_HOPS] = stand.current;
            }
            stand.current = [0.0; 2];
            if complete {
                let (mut band, mut reference) = (0.0, 0.0);
                for back in 0..hops {
                    let [b, r] = stand.hops[(kept - 1 - back) % MAX_WINDOW_HOPS];
                    band += b;
                    reference += r;
                }
                let band = libm::sqrt(band / count);
                let reference = libm::sqrt(reference / count);
                let gain = if reference > 0.0 {
                    band / reference
                } else {
                    0.0
                };
                // At most MAX_STANDS entries, as `stands`.
                let _ = window.band_rms.push(band);
                let _ = window.reference_rms.push(reference);
                let _ = window.gain.push(gain);
            }
        }
        Ok(complete.then_some(window))
    }

    /// The chatter-band-passed sample of `stand` from the last frame (0 before any).
    pub fn band_sample(&self, state: &BandGainState, stand: usize) -> f64 {
        state.stands.get(stand).map_or(0.0, |s| s.band_sample)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::TAU;

    fn settings() -> BandGainSettings {
        BandGainSettings {
            sample_rate_hz: 2500.0,
            chatter_band_hz: (100.0, 300.0),
            reference_band_hz: (450.0, 900.0),
            hop_samples: 625,
            window_hops: 2,
            stands: 2,
        }
    }

    #[test]
    fn sines_in_each_band_give_their_rms_and_ratio() {
        let detector = BandGain::new(settings()).unwrap();
        let mut state = detector.state();
        let mut last = None;
        for k in 0..10_000 {
            let t = k as f64 / 2500.0;
            // Stand 0: 2.0 peak at 180 Hz and 0.5 peak at 650 Hz; stand 1: only 650 Hz.
            let chatter = 2.0 * libm::sin(TAU * 180.0 * t);
            let reference = 0.5 * libm::sin(TAU * 650.0 * t);
            if let Some(w) = detector
                .process(&mut state, &[chatter + reference, reference])
                .unwrap()
            {
                last = Some(w);
            }
        }
        let w = last.unwrap();
        let rms = |peak: f64| peak / libm::sqrt(2.0);
        assert!((w.band_rms[0] - rms(2.0)).abs() < 0.02 * rms(2.0), "{w:?}");
        assert!(
            (w.reference_rms[0] - rms(0.5)).abs() < 0.02 * rms(0.5),
            "{w:?}"
        );
        assert!((w.gain[0] - 4.0).abs() < 0.1, "{w:?}");
        assert!(w.band_rms[1] < 0.01 && w.gain[1] < 0.02, "{w:?}");
        assert!((w.max_gain() - w.gain[0]).abs() < 1e-12);
    }

    #[test]
    fn long_windows_average_their_hops() {
        // A chatter-band sine whose amplitude doubles after 8 hops: a window of 4 hops
        // sees the new RMS 4 hops later, and the mean square in between.
        let detector = BandGain::new(BandGainSettings {
            window_hops: 4,
            ..settings()
        })
        .unwrap();
        let mut state = detector.state();
        let mut windows: Vec<f64, 16> = Vec::new();
        for k in 0..(12 * 625) {
            let amplitude = if k < 8 * 625 { 1.0 } else { 2.0 };
            let x = amplitude * libm::sin(TAU * 180.0 * k as f64 / 2500.0);
            if let Some(w) = detector.process(&mut state, &[x, 0.0]).unwrap() {
                windows.push(w.band_rms[0]).unwrap();
            }
        }
        // Hops 1-4 fill the first window (after hop 0 settles): windows end at hops
        // 5..=12; the step at hop 8 is in the windows ending at hops 9-12.
        assert_eq!(windows.len(), 8);
        let rms = |mean_square: f64| libm::sqrt(mean_square / 2.0);
        assert!((windows[3] - rms(1.0)).abs() < 0.02, "{windows:?}");
        assert!((windows[5] - rms(2.5)).abs() < 0.05, "{windows:?}");
        assert!((windows[7] - rms(4.0)).abs() < 0.05, "{windows:?}");
    }

    #[test]
    fn first_window_after_two_hops_and_the_settling_one() {
        let detector = BandGain::new(settings()).unwrap();
        let mut state = detector.state();
        let first =
            (0..5000).position(|_| detector.process(&mut state, &[1.0, 1.0]).unwrap().is_some());
        assert_eq!(first, Some(3 * 625 - 1));
        assert_eq!(
            detector.process(&mut state, &[1.0]),
            Err(BandGainError::Stands)
        );
    }

    #[test]
    fn invalid_settings_are_named() {
        let bad = |change: fn(&mut BandGainSettings)| {
            let mut s = settings();
            change(&mut s);
            BandGain::new(s).err()
        };
        assert_eq!(
            bad(|s| s.sample_rate_hz = 0.0),
            Some(BandGainError::SampleRateHz)
        );
        assert_eq!(
            bad(|s| s.chatter_band_hz = (300.0, 100.0)),
            Some(BandGainError::ChatterBandHz)
        );
        assert_eq!(
            bad(|s| s.reference_band_hz = (450.0, 1300.0)),
            Some(BandGainError::ReferenceBandHz)
        );
        assert_eq!(bad(|s| s.hop_samples = 4), Some(BandGainError::HopSamples));
        assert_eq!(bad(|s| s.window_hops = 17), Some(BandGainError::WindowHops));
        assert_eq!(bad(|s| s.stands = 9), Some(BandGainError::Stands));
    }
}
