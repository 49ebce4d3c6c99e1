//! [`EpisodeRecorder`]: one tandem mill's chatter-episode captures. Every stand's
//! samples go through a ring on the monitor's common sample axis (sized from
//! `capture_before_s`, allocated once); when the warning is raised the ring's last
//! `capture_before_s` start the capture, rounded up to whole hops plus one DAQ block
//! ([`ANCHOR_BLOCK`]): a monitor reading the capture (`millgate chatter --input`)
//! anchors its stands on their first block and starts its windows after it, so its
//! windows then fall on the gateway's, and it warns at the same window. The capture
//! then grows until `capture_after_s` after
//! the window that cleared the warning, or until `capture_max_s` (cut, and marked so).
//! Samples lost on a stand, or a stand re-anchored on the axis, end the capture there
//! (the gap marked). The finished capture goes to the history as a
//! [`CaptureRecord`] of kind `chatter`, kept longest; nothing here waits.
//!
//! On request (`Command::CaptureStands`) the recorder also keeps the stands' next
//! seconds, from the most advanced stand's next sample on, as a capture of kind
//! `manual` (stable rolling for `millgate chatter commission --db`).

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::{Config, TandemMill};

use super::align::MAX_STAND_LAG_S;
use super::monitor::ChatterMonitor;
use crate::state::captures::{
    unix_ns, CaptureChannel, CaptureGap, CaptureKind, CaptureRecord, ChatterEpisode, KeepClass,
};
use crate::state::context::ContextReading;

/// Samples a capture holds before its first whole hop: the largest DAQ block
/// ([`millgate_config::layout::MAX_BLOCK_SAMPLES`]), the block `millgate chatter` feeds
/// its monitor and anchors the stands on (see the module docs).
pub const ANCHOR_BLOCK: usize = millgate_config::layout::MAX_BLOCK_SAMPLES as usize;

/// One mill's episode captures (see the module docs).
#[derive(Debug)]
pub(super) struct EpisodeRecorder {
    mill: String,
    sample_rate_hz: f64,
    window: i64,
    hop: i64,
    /// Samples kept before the warning, after it clears, at most in all.
    before: i64,
    after: i64,
    max: i64,
    /// The stands' channels as a capture describes them (no samples).
    channels: Vec<CaptureChannel>,
    /// Per stand, the latest samples by common index modulo the ring's length.
    rings: Vec<Vec<f64>>,
    /// Per stand, the common index one past its latest sample.
    next: Vec<Option<i64>>,
    /// Samples before this common index are not kept (lost data or a re-anchoring
    /// since).
    valid_from: i64,
    /// The latest sample handed over: its common index, when it was taken, and
    /// whether that time is the kernel's.
    clock: Option<(i64, SystemTime, bool)>,
    episode: Option<Episode>,
    /// A manual capture of the stands being taken (`Command::CaptureStands`).
    manual: Option<Episode>,
}

/// A capture being taken.
#[derive(Debug)]
struct Episode {
    /// Common index of the capture's first sample.
    start: i64,
    /// Window end that raised the warning (`None`: a manual capture).
    warning_end: Option<i64>,
    /// Window end that cleared it.
    cleared_end: Option<i64>,
    /// Common index one past the capture's last sample, as known so far.
    end: i64,
    /// Per stand, the samples from `start` on.
    samples: Vec<Vec<f64>>,
    first_sample: SystemTime,
    kernel_time: bool,
    /// The mill's process context when it started.
    context: Option<ContextReading>,
}

impl EpisodeRecorder {
    /// The recorder of `config.tandem_mills[index]`, whose monitor is `monitor`.
    pub(super) fn new(config: &Config, index: usize, monitor: &ChatterMonitor) -> Self {
        let mill: &TandemMill = &config.tandem_mills[index];
        let fs = mill
            .stands
            .first()
            .map_or(0.0, |&c| config.channels[c].sample_rate_hz);
        let samples = |seconds: f64| (seconds * fs).ceil() as i64;
        let (window, hop) = (
            monitor.window_samples() as i64,
            monitor.hop_samples() as i64,
        );
        let before = samples(mill.capture_before_s);
        // The pre-trigger part rounded up to whole hops, and the stands' spread on the
        // axis: at most the largest lag, a window and a hop (how far a stand may run
        // ahead of the window that raised the warning).
        let ring = ANCHOR_BLOCK as i64 + (before + hop) + window + hop + samples(MAX_STAND_LAG_S);
        Self {
            mill: mill.name.clone(),
            sample_rate_hz: fs,
            window,
            hop,
            before,
            after: samples(mill.capture_after_s),
            max: samples(mill.capture_max_s),
            channels: mill
                .stands
                .iter()
                .map(|&c| CaptureChannel::described(&config.channels[c]))
                .collect(),
            rings: vec![vec![0.0; ring.max(1) as usize]; mill.stands.len()],
            next: vec![None; mill.stands.len()],
            valid_from: 0,
            clock: None,
            episode: None,
            manual: None,
        }
    }

    /// `values` of stand `stand` were handed to the monitor, the last at common index
    /// `next - 1`, taken at `received` (when the reader knows; else now). Returns the
    /// capture when this completed it.
    pub(super) fn samples(
        &mut self,
        stand: usize,
        next: i64,
        values: &[f64],
        received: Option<SystemTime>,
    ) -> Vec<CaptureRecord> {
        let Some(ring) = self.rings.get_mut(stand) else {
            return Vec::new();
        };
        let first = next - values.len() as i64;
        let len = ring.len() as i64;
        for (index, &value) in (first..).zip(values) {
            ring[index.rem_euclid(len) as usize] = value;
        }
        if self.next[stand].is_none() {
            // A stand's first samples: the ring holds nothing of it before them.
            self.valid_from = self.valid_from.max(first);
        }
        self.next[stand] = Some(next);
        self.clock = Some((
            next - 1,
            received.unwrap_or_else(SystemTime::now),
            received.is_some(),
        ));
        for capture in [&mut self.episode, &mut self.manual].into_iter().flatten() {
            let kept = &mut capture.samples[stand];
            for (index, &value) in (first..).zip(values) {
                // In order, no repeats, nothing past the end.
                if index == capture.start + kept.len() as i64 && index < capture.end {
                    kept.push(value);
                }
            }
        }
        let mut done: Vec<CaptureRecord> = self.finish_when_complete().into_iter().collect();
        if self.manual.as_ref().is_some_and(Episode::complete) {
            done.extend(self.manual.take().map(|manual| {
                let length = (manual.end - manual.start) as usize;
                self.record(manual, length, Vec::new())
            }));
        }
        done
    }

    /// Keep the stands' next `seconds` s as a capture of kind `manual` (a manual
    /// capture already running starts again), in the mill's `context`.
    pub(super) fn start_manual(&mut self, seconds: f64, context: Option<ContextReading>) {
        let start = self.next.iter().flatten().copied().max().unwrap_or(0);
        let (first_sample, kernel_time) = self.time_of(start);
        self.manual = Some(Episode {
            start,
            warning_end: None,
            cleared_end: None,
            end: start + (seconds * self.sample_rate_hz).ceil().max(1.0) as i64,
            samples: vec![Vec::new(); self.rings.len()],
            first_sample,
            kernel_time,
            context,
        });
    }

    /// When the sample at common index `index` was taken (from the latest sample's
    /// time), and whether that is the kernel's time.
    fn time_of(&self, index: i64) -> (SystemTime, bool) {
        match self.clock {
            Some((latest, time, kernel)) => {
                let seconds = (index - latest) as f64 / self.sample_rate_hz;
                (shifted(time, seconds), kernel)
            }
            None => (SystemTime::now(), false),
        }
    }

    /// Samples were lost (`missed` of them when known), or a stand moved on the axis:
    /// nothing before the stands' latest sample is kept, and a capture being taken
    /// ends there with the gap marked.
    pub(super) fn lost(&mut self, missed: Option<u64>) -> Vec<CaptureRecord> {
        self.valid_from = self.next.iter().flatten().copied().max().unwrap_or(0);
        [self.episode.take(), self.manual.take()]
            .into_iter()
            .flatten()
            .map(|capture| {
                let complete = capture.samples.iter().map(Vec::len).min().unwrap_or(0);
                let gap = CaptureGap {
                    before_sample: complete,
                    missed_samples: missed,
                };
                self.record(capture, complete, vec![gap])
            })
            .collect()
    }

    /// The monitor's latest window, ending at common index `window_end`, left the
    /// warning at `warning`: a raised warning starts a capture (in the mill's
    /// `context`), a cleared one sets its end. Returns the capture when this completed
    /// it.
    pub(super) fn warning(
        &mut self,
        warning: bool,
        window_end: i64,
        context: Option<ContextReading>,
    ) -> Option<CaptureRecord> {
        match (&mut self.episode, warning) {
            (None, true) => self.start(window_end, context),
            (Some(episode), false) if episode.cleared_end.is_none() => {
                episode.cleared_end = Some(window_end);
                episode.end = episode.end.min(window_end + self.after);
            }
            _ => {}
        }
        self.finish_when_complete()
    }

    /// Start a capture for the warning raised by the window ending at `window_end`.
    fn start(&mut self, window_end: i64, context: Option<ContextReading>) {
        let latest = self.next.iter().flatten().copied().max().unwrap_or(0);
        let held_from = latest - self.rings[0].len() as i64;
        let lower = self.valid_from.max(held_from);
        let lead = ANCHOR_BLOCK as i64;
        let hops = ((self.before + self.hop - 1) / self.hop)
            .min((window_end - lead - lower).div_euclid(self.hop))
            .max(0);
        let start = (window_end - hops * self.hop - lead).max(lower.min(window_end));
        let samples = self
            .rings
            .iter()
            .zip(&self.next)
            .map(|(ring, next)| {
                let len = ring.len() as i64;
                (start..next.unwrap_or(start).max(start))
                    .map(|index| ring[index.rem_euclid(len) as usize])
                    .collect()
            })
            .collect();
        let (first_sample, kernel_time) = self.time_of(start);
        tracing::info!(mill = %self.mill, "chatter episode capture started");
        self.episode = Some(Episode {
            start,
            warning_end: Some(window_end),
            cleared_end: None,
            end: start + self.max,
            samples,
            first_sample,
            kernel_time,
            context,
        });
    }

    /// The capture, once every stand has its samples up to the end.
    fn finish_when_complete(&mut self) -> Option<CaptureRecord> {
        if !self.episode.as_ref()?.complete() {
            return None;
        }
        let episode = self.episode.take()?;
        let length = (episode.end - episode.start) as usize;
        Some(self.record(episode, length, Vec::new()))
    }

    /// The record of `episode`'s first `length` samples per stand (a chatter episode,
    /// or a manual capture).
    fn record(&self, episode: Episode, length: usize, gaps: Vec<CaptureGap>) -> CaptureRecord {
        let index = |end: i64| usize::try_from(end - episode.start).unwrap_or(0);
        let cleared = episode
            .cleared_end
            .filter(|&cleared| index(cleared) <= length);
        let cut = gaps.is_empty()
            && episode
                .cleared_end
                .is_none_or(|cleared| cleared + self.after > episode.start + self.max);
        CaptureRecord {
            kind: if episode.warning_end.is_some() {
                CaptureKind::Chatter
            } else {
                CaptureKind::Manual
            },
            subject: self.mill.clone(),
            bite: None,
            first_sample_unix_ns: unix_ns(episode.first_sample),
            kernel_time: episode.kernel_time,
            sample_rate_hz: self.sample_rate_hz,
            channels: self
                .channels
                .iter()
                .zip(episode.samples)
                .map(|(channel, mut samples)| {
                    samples.truncate(length);
                    CaptureChannel {
                        samples,
                        ..channel.clone()
                    }
                })
                .collect(),
            gaps,
            analysis: None,
            episode: episode.warning_end.map(|warning_end| ChatterEpisode {
                warning_sample: index(warning_end),
                cleared_sample: cleared.map(index),
                window_samples: self.window as usize,
                hop_samples: self.hop as usize,
                cut,
            }),
            keep: KeepClass::Important,
            context: episode.context,
        }
    }
}

impl Episode {
    /// Every stand has its samples up to the end.
    fn complete(&self) -> bool {
        let length = self.end - self.start;
        self.samples.iter().all(|kept| kept.len() as i64 >= length)
    }
}

/// `time` moved by `seconds` (either sign), saturating at the Unix epoch.
fn shifted(time: SystemTime, seconds: f64) -> SystemTime {
    let by = Duration::from_secs_f64(seconds.abs());
    let moved = if seconds >= 0.0 {
        time.checked_add(by)
    } else {
        time.checked_sub(by)
    };
    moved.unwrap_or(UNIX_EPOCH).max(UNIX_EPOCH)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FS: f64 = 2500.0;
    const BLOCK: usize = 120;

    /// Two stands at 2500 Hz, window 0.5 s (hop 625), 0.2 s before, 0.1 s after,
    /// at most 1 s.
    fn recorder() -> EpisodeRecorder {
        let mut text = String::from(
            "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
        );
        for s in 0..2 {
            text += &format!(
                "[[channels]]\nname = \"s{s}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
                 scale = 0.5\nsample_rate_hz = {FS}\n\
                 source = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
                s * 122
            );
        }
        text += "[[tandem_mills]]\nname = \"TCM\"\nstands = [\"s0\", \"s1\"]\n\
                 chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
                 gain_thresholds = [1.0, 1.0]\ncapture_before_s = 0.2\n\
                 capture_after_s = 0.1\ncapture_max_s = 1.0\n";
        let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
            .expect("test config");
        let monitor = ChatterMonitor::new(&config, 0).expect("monitor");
        EpisodeRecorder::new(&config, 0, &monitor)
    }

    /// Stand `stand`'s sample at common index `index`: tells both apart.
    fn value(stand: usize, index: i64) -> f64 {
        stand as f64 * 1e6 + index as f64
    }

    /// Blocks `blocks` (both stands each), the captures they completed.
    fn feed(recorder: &mut EpisodeRecorder, blocks: std::ops::Range<i64>) -> Vec<CaptureRecord> {
        let mut done = Vec::new();
        for b in blocks {
            for stand in 0..2 {
                let first = b * BLOCK as i64;
                let values: Vec<f64> = (first..first + BLOCK as i64)
                    .map(|i| value(stand, i))
                    .collect();
                done.extend(recorder.samples(stand, first + BLOCK as i64, &values, None));
            }
        }
        done
    }

    fn check_samples(capture: &CaptureRecord, start: i64) {
        for (stand, channel) in capture.channels.iter().enumerate() {
            assert_eq!(channel.name, format!("s{stand}"));
            assert_eq!(channel.scale, 0.5);
            for (k, &sample) in channel.samples.iter().enumerate() {
                assert_eq!(sample, value(stand, start + k as i64), "stand {stand}, {k}");
            }
        }
    }

    #[test]
    fn an_episode_spans_whole_hops_and_a_block_before_the_warning_to_after_it_clears() {
        let mut recorder = recorder();
        assert!(feed(&mut recorder, 0..30).is_empty());
        // Raised by the window ending at 3000 (the stands are at 3600).
        assert!(recorder.warning(true, 3000, None).is_none());
        assert!(feed(&mut recorder, 30..36).is_empty());
        assert!(recorder.warning(false, 4250, None).is_none());
        // 0.1 s after: up to 4500, in with block 37 (4440..4560).
        assert!(feed(&mut recorder, 36..37).is_empty());
        let done = feed(&mut recorder, 37..38);
        assert_eq!(done.len(), 1, "complete once every stand reached the end");
        let capture = &done[0];
        // 500 samples before, rounded up to a hop (625), and the anchoring block.
        let start = 3000 - 625 - ANCHOR_BLOCK as i64;
        assert_eq!(capture.kind, CaptureKind::Chatter);
        assert_eq!(capture.keep, KeepClass::Important);
        assert_eq!(capture.subject, "TCM");
        assert_eq!(capture.samples() as i64, 4500 - start);
        assert!(capture.gaps.is_empty());
        check_samples(capture, start);
        assert_eq!(
            capture.episode,
            Some(ChatterEpisode {
                warning_sample: (3000 - start) as usize,
                cleared_sample: Some((4250 - start) as usize),
                window_samples: 1250,
                hop_samples: 625,
                cut: false,
            })
        );
        // A second episode is captured on its own.
        assert!(recorder.warning(true, 5000, None).is_none());
        assert!(feed(&mut recorder, 41..60).is_empty());
    }

    #[test]
    fn an_episode_longer_than_the_maximum_is_cut_and_says_so() {
        let mut recorder = recorder();
        feed(&mut recorder, 0..30);
        recorder.warning(true, 3000, None);
        let done = feed(&mut recorder, 30..60);
        assert_eq!(done.len(), 1);
        let start = 3000 - 625 - ANCHOR_BLOCK as i64;
        assert_eq!(done[0].samples(), 2500, "capture_max_s = 1 s");
        check_samples(&done[0], start);
        let episode = done[0].episode.expect("episode");
        assert!(episode.cut);
        assert_eq!(episode.cleared_sample, None);
        // Clearing later starts nothing, finishes nothing.
        assert!(recorder.warning(false, 7000, None).is_none());
    }

    #[test]
    fn lost_samples_end_the_capture_with_the_gap_marked_and_nothing_older_is_kept() {
        let mut recorder = recorder();
        feed(&mut recorder, 0..30);
        recorder.warning(true, 3000, None);
        feed(&mut recorder, 30..33);
        let capture = recorder
            .lost(Some(7))
            .pop()
            .expect("the capture ends at the gap");
        let start = 3000 - 625 - ANCHOR_BLOCK as i64;
        assert_eq!(capture.samples() as i64, 33 * BLOCK as i64 - start);
        assert_eq!(
            capture.gaps,
            vec![CaptureGap {
                before_sample: capture.samples(),
                missed_samples: Some(7),
            }]
        );
        assert!(!capture.episode.expect("episode").cut);
        check_samples(&capture, start);
        // A warning soon after the gap: the capture starts after it, still on the
        // hop grid of the warning window (whole hops and the block).
        feed(&mut recorder, 33..50);
        recorder.warning(true, 5500, None);
        // The stands are at 6000, past 5500 + 250: complete at once.
        let done: Vec<_> = recorder.warning(false, 5500, None).into_iter().collect();
        let start = 5500 - 625 - ANCHOR_BLOCK as i64;
        assert!(start >= 33 * BLOCK as i64);
        assert_eq!(done.len(), 1);
        check_samples(&done[0], start);
        // Only 625 + 120 samples since the gap at 3960: the pre-trigger part is cut
        // to them (no hop before 5500 - 120 - 625 = 4755 would fit after 3960 + 625).
        let mut recorder = self::recorder();
        feed(&mut recorder, 0..30);
        recorder.lost(None);
        feed(&mut recorder, 30..36);
        recorder.warning(true, 4320, None);
        assert!(recorder.warning(false, 4320, None).is_none());
        let done = feed(&mut recorder, 36..40);
        assert_eq!(done.len(), 1);
        let episode = done[0].episode.expect("episode");
        assert_eq!(
            episode.warning_sample, ANCHOR_BLOCK,
            "no whole hop after the gap"
        );
        check_samples(&done[0], 4320 - ANCHOR_BLOCK as i64);
    }
}
