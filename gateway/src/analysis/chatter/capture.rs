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

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::{Config, TandemMill};

use super::align::MAX_STAND_LAG_S;
use super::monitor::ChatterMonitor;
use crate::state::captures::{
    unix_ns, CaptureChannel, CaptureGap, CaptureKind, CaptureRecord, ChatterEpisode, KeepClass,
};

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
}

/// A capture being taken.
#[derive(Debug)]
struct Episode {
    /// Common index of the capture's first sample.
    start: i64,
    /// Window end that raised the warning.
    warning_end: i64,
    /// Window end that cleared it.
    cleared_end: Option<i64>,
    /// Common index one past the capture's last sample, as known so far.
    end: i64,
    /// Per stand, the samples from `start` on.
    samples: Vec<Vec<f64>>,
    first_sample: SystemTime,
    kernel_time: bool,
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
                .map(|&c| {
                    let channel = &config.channels[c];
                    CaptureChannel {
                        name: channel.name.clone(),
                        unit: channel.unit.clone(),
                        scale: channel.scale,
                        offset: channel.offset,
                        samples: Vec::new(),
                    }
                })
                .collect(),
            rings: vec![vec![0.0; ring.max(1) as usize]; mill.stands.len()],
            next: vec![None; mill.stands.len()],
            valid_from: 0,
            clock: None,
            episode: None,
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
    ) -> Option<CaptureRecord> {
        let ring = self.rings.get_mut(stand)?;
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
        let episode = self.episode.as_mut()?;
        let kept = &mut episode.samples[stand];
        for (index, &value) in (first..).zip(values) {
            // In order, no repeats, nothing past the end.
            if index == episode.start + kept.len() as i64 && index < episode.end {
                kept.push(value);
            }
        }
        self.finish_when_complete()
    }

    /// Samples were lost (`missed` of them when known), or a stand moved on the axis:
    /// nothing before the stands' latest sample is kept, and a capture being taken
    /// ends there with the gap marked.
    pub(super) fn lost(&mut self, missed: Option<u64>) -> Option<CaptureRecord> {
        self.valid_from = self.next.iter().flatten().copied().max().unwrap_or(0);
        let episode = self.episode.take()?;
        let complete = episode.samples.iter().map(Vec::len).min().unwrap_or(0);
        let gap = CaptureGap {
            before_sample: complete,
            missed_samples: missed,
        };
        Some(self.record(episode, complete, vec![gap]))
    }

    /// The monitor's latest window, ending at common index `window_end`, left the
    /// warning at `warning`: a raised warning starts a capture, a cleared one sets its
    /// end. Returns the capture when this completed it.
    pub(super) fn warning(&mut self, warning: bool, window_end: i64) -> Option<CaptureRecord> {
        match (&mut self.episode, warning) {
            (None, true) => self.start(window_end),
            (Some(episode), false) if episode.cleared_end.is_none() => {
                episode.cleared_end = Some(window_end);
                episode.end = episode.end.min(window_end + self.after);
            }
            _ => {}
        }
        self.finish_when_complete()
    }

    /// Start a capture for the warning raised by the window ending at `window_end`.
    fn start(&mut self, window_end: i64) {
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
        let (first_sample, kernel_time) = match self.clock {
            Some((index, time, kernel)) => {
                let seconds = (index - start) as f64 / self.sample_rate_hz;
                (shifted(time, -seconds), kernel)
            }
            None => (SystemTime::now(), false),
        };
        tracing::info!(mill = %self.mill, "chatter episode capture started");
        self.episode = Some(Episode {
            start,
            warning_end: window_end,
            cleared_end: None,
            end: start + self.max,
            samples,
            first_sample,
            kernel_time,
        });
    }

    /// The capture, once every stand has its samples up to the end.
    fn finish_when_complete(&mut self) -> Option<CaptureRecord> {
        let episode = self.episode.as_ref()?;
        let length = episode.end - episode.start;
        if episode
            .samples
            .iter()
            .any(|kept| (kept.len() as i64) < length)
        {
            return None;
        }
        let episode = self.episode.take()?;
        Some(self.record(episode, length as usize, Vec::new()))
    }

    /// The record of `episode`'s first `length` samples per stand.
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
            kind: CaptureKind::Chatter,
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
            episode: Some(ChatterEpisode {
                warning_sample: index(episode.warning_end),
                cleared_sample: cleared.map(index),
                window_samples: self.window as usize,
                hop_samples: self.hop as usize,
                cut,
            }),
            keep: KeepClass::Important,
        }
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
