//! The chatter-band gain of one mill (`dsp::band_gain`): every common sample index
//! that all stands have is fed, as one frame, to per-stand Butterworth band-passes on
//! the chatter band and on the reference band; every hop the gain is chatter-band RMS
//! / reference-band RMS over `gain_window_s` of whole hops.
//!
//! The gain's hops fall on the same sample indices as the spectra's windows, so each
//! evaluation carries the gain of the window ending with it ([`GainReading`]), or none
//! while the gain's longer window refills after a restart. With `gain_thresholds` the
//! largest `gain[s] / threshold[s]` is the mill's gain ratio: 1 is the alarm level of
//! the band-gain detector, the default (it warned earliest at zero false alarms in the
//! tandem-model race, `tests/src/experiments/chatter_eval/`).

use millgate_dsp::band_gain::{BandGain, BandGainState, BandGainWindow};
use millgate_dsp::chatter::MAX_STANDS;

use super::align::Alignment;

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
    /// Each stand's `gain[s] / gain_thresholds[s]`, in the mill's order (the first
    /// `stands` entries; the rest 0); all 0 without thresholds. The weld hold judges
    /// each stand by its own level ([`super::SlowDown::stand_alarm_scale`]).
    pub stand_ratios: [f64; MAX_STANDS],
    /// Stands in [`Self::stand_ratios`] (0 without thresholds).
    pub stands: usize,
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
        let mut stand_ratios = [0.0; MAX_STANDS];
        let stands = if ratio.is_some() {
            for ((slot, gain), threshold) in
                stand_ratios.iter_mut().zip(&window.gain).zip(thresholds)
            {
                *slot = gain / threshold;
            }
            thresholds.len().min(MAX_STANDS)
        } else {
            0
        };
        Self {
            max_gain: window.max_gain(),
            max_band_rms: window.max_band_rms(),
            ratio,
            stand_ratios,
            stands,
        }
    }

    /// Each stand's gain ratio (empty without thresholds).
    pub fn stand_ratios(&self) -> &[f64] {
        &self.stand_ratios[..self.stands]
    }
}

/// The band gain of one mill, fed from the aligned stands.
#[derive(Debug)]
pub(super) struct GainTracker {
    band_gain: BandGain,
    state: BandGainState,
    /// Common index of the next frame for the band gain.
    next: i64,
    thresholds: Vec<f64>,
    /// The latest window's reading; `None` after a restart until a full one.
    reading: Option<GainReading>,
    /// The same window per stand.
    window: Option<BandGainWindow>,
}

impl GainTracker {
    /// The tracker of `band_gain` with per-stand alarm `thresholds` (may be empty).
    pub(super) fn new(band_gain: BandGain, thresholds: Vec<f64>) -> Self {
        Self {
            state: band_gain.state(),
            band_gain,
            next: 0,
            thresholds,
            reading: None,
            window: None,
        }
    }

    /// Judge by per-stand `thresholds` (a reload; may be empty): the latest window's
    /// reading too, so the next evaluation uses them.
    pub(super) fn set_thresholds(&mut self, thresholds: Vec<f64>) {
        self.thresholds = thresholds;
        self.reading = self
            .window
            .as_ref()
            .map(|window| GainReading::new(window, &self.thresholds));
    }

    /// The latest window's reading.
    pub(super) fn reading(&self) -> Option<GainReading> {
        self.reading
    }

    /// The latest window, per stand.
    pub(super) fn window(&self) -> Option<&BandGainWindow> {
        self.window.as_ref()
    }

    /// Start again at common index `start` (the next window's start, so the gain's
    /// hops end with the windows).
    pub(super) fn restart(&mut self, start: i64) {
        self.band_gain.reset(&mut self.state);
        self.next = start;
        self.reading = None;
        self.window = None;
    }

    /// Feed every frame all stands have and the rings still hold.
    pub(super) fn feed(&mut self, aligned: &Alignment) {
        let Some((earliest, latest)) = aligned.common_range() else {
            return;
        };
        let oldest_held = aligned.oldest_held(latest);
        if self.next < oldest_held {
            // Cannot happen while the lag check restarts the window in time; if it
            // did, the frames are gone: start the gain again rather than feed stale ones.
            self.restart(oldest_held);
        }
        let mut frame = [0.0; MAX_STANDS];
        let frame = &mut frame[..aligned.stands()];
        for index in self.next..earliest {
            for (stand, value) in frame.iter_mut().enumerate() {
                *value = aligned.sample(stand, index);
            }
            // The frame has one sample per stand, as the gain was built for.
            if let Ok(Some(window)) = self.band_gain.process(&mut self.state, frame) {
                self.reading = Some(GainReading::new(&window, &self.thresholds));
                self.window = Some(window);
            }
        }
        self.next = self.next.max(earliest);
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::super::testing::{monitor, sine, BLOCK, FS};
    use crate::analysis::chatter::{ChatterMonitor, ChatterUpdate};

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
}
