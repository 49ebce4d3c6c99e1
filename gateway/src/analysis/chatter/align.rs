//! The stands' samples on one common axis: per stand a ring buffer (allocated once) and
//! a sample count anchored against arrival times, the window grid every stand must
//! reach, and the restarts when data is lost or a stand falls behind.
//!
//! A reader hands over samples without time stamps, so every stand counts its samples;
//! a gap with a known number of missed samples advances the count. The stands of one
//! mill must be sampled on one clock (one DAQ, or DAQs sharing sample clock and block
//! grid). Where each stand's count starts is checked against arrival times: the
//! earliest arrival of a sample, less its count over the sample rate, estimates when
//! the stand's first sample was taken; the difference to the mill's reference (the
//! earliest such estimate of any stand) is rounded to whole blocks (the length of the
//! stand's first message) and added to the count. This catches a stand whose first block was one newer than the others' (the
//! DAQ published between two reads of one poll) and re-anchors a stand after a gap of
//! unknown length.
//!
//! Arrival times jitter (the reader's and the analysis' scheduling, a source sending in
//! bursts), so they place a stand no finer than [`MIN_ANCHOR_STEP_S`]: the rounding
//! step is the first message's length in whole messages of at least that long. A DAQ
//! block of 120 samples at 2.5 kHz (48 ms) is one step; a CAN reader's few frames are
//! many, so their jitter does not move the stand and restart the window.

use std::time::Instant;

/// Largest lag of one stand behind the most advanced one, s: more means its source
/// has stopped delivering, and the mill's values are flagged and the window restarted.
pub const MAX_STAND_LAG_S: f64 = 0.5;

/// Shortest step by which arrival times move a stand on the common axis, s (see the
/// module docs).
pub(super) const MIN_ANCHOR_STEP_S: f64 = 0.02;

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

/// What anchoring a message did to its stand's place on the common axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Realigned {
    /// Unchanged.
    Same,
    /// The stand's first samples (at start, or after a gap of unknown length).
    First,
    /// The stand moved on the common axis.
    Changed,
}

/// Where a stand's sample count sits on the mill's common sample axis.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    /// Earliest (arrival time - samples counted / fs) seen, s since the mill's epoch.
    origin_s: f64,
    /// The rounding step, samples: the length of the first message after anchoring,
    /// in whole messages of at least [`MIN_ANCHOR_STEP_S`].
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

/// The stands of one mill on a common sample axis, and the grid of windows of
/// `window` samples every `hop` samples on it.
#[derive(Debug)]
pub(super) struct Alignment {
    sample_rate_hz: f64,
    window: usize,
    hop: usize,
    max_lag: i64,
    stands: Vec<StandStream>,
    /// Windows may only start at or after this common index.
    valid_from: i64,
    /// Common index one past the next window's last sample.
    next_end: i64,
    epoch: Option<Instant>,
    /// The earliest origin of any stand, s since the epoch: the stands' offsets are
    /// rounded against it.
    reference_origin_s: Option<f64>,
    lagging: Option<usize>,
}

impl Alignment {
    /// `stands` streams at `sample_rate_hz`, windows of `window` samples every `hop`.
    pub(super) fn new(stands: usize, sample_rate_hz: f64, window: usize, hop: usize) -> Self {
        let max_lag = (MAX_STAND_LAG_S * sample_rate_hz).ceil() as i64;
        // Room for a full window, a hop of slack and the largest allowed lag.
        let ring_len = window + hop + max_lag as usize;
        Self {
            sample_rate_hz,
            window,
            hop,
            max_lag,
            stands: (0..stands)
                .map(|_| StandStream {
                    ring: vec![0.0; ring_len],
                    counted: 0,
                    anchor: None,
                })
                .collect(),
            valid_from: 0,
            next_end: window as i64,
            epoch: None,
            reference_origin_s: None,
            lagging: None,
        }
    }

    /// Number of stands.
    pub(super) fn stands(&self) -> usize {
        self.stands.len()
    }

    /// Common index one past the next window's last sample.
    pub(super) fn next_end(&self) -> i64 {
        self.next_end
    }

    /// Common index one past stand `stand`'s latest sample, once anchored.
    pub(super) fn stand_next_index(&self, stand: usize) -> Option<i64> {
        self.stands.get(stand)?.next_index()
    }

    /// Stand `stand`'s sample at common index `index` (still in its ring).
    pub(super) fn sample(&self, stand: usize, index: i64) -> f64 {
        self.stands[stand].sample(index)
    }

    /// Store samples of `stand` that arrived at `arrival`, after anchoring them.
    pub(super) fn push(&mut self, stand: usize, values: &[f64], arrival: Instant) -> Realigned {
        let realigned = self.anchor(stand, values.len(), arrival);
        let stream = &mut self.stands[stand];
        let start = stream.next_index().unwrap_or(0);
        let ring_len = stream.ring.len() as i64;
        for (index, &value) in (start..).zip(values) {
            stream.ring[index.rem_euclid(ring_len) as usize] = value;
        }
        stream.counted += values.len() as i64;
        realigned
    }

    /// `missed` samples (when known) were lost on `stand`: the count moves past them;
    /// an unknown gap drops the stand's anchor (re-anchored from its next samples).
    /// The caller restarts the window.
    pub(super) fn gap(&mut self, stand: usize, missed: Option<u64>) {
        let stream = &mut self.stands[stand];
        match missed.and_then(|m| i64::try_from(m).ok()) {
            Some(missed) => stream.counted = stream.counted.saturating_add(missed),
            None => {
                stream.anchor = None;
                stream.counted = 0;
            }
        }
    }

    /// Update the stand's anchor with a message of `len` samples arriving at
    /// `arrival` (before they are counted).
    fn anchor(&mut self, stand: usize, len: usize, arrival: Instant) -> Realigned {
        let epoch = *self.epoch.get_or_insert(arrival);
        let fs = self.sample_rate_hz;
        let stream = &mut self.stands[stand];
        let through = (stream.counted + len as i64) as f64 / fs;
        let origin_s = arrival.saturating_duration_since(epoch).as_secs_f64() - through;
        let previous = stream.anchor;
        let block = previous.map_or_else(|| anchor_step(len, fs), |a| a.block);
        let origin_s = previous.map_or(origin_s, |a| a.origin_s.min(origin_s));
        // The earliest origin of any stand: when every stand's first messages came
        // late (a busy start) and later ones on time, each origin falls by the same
        // amount and so does the reference, and no stand moves against the others.
        let reference = self
            .reference_origin_s
            .map_or(origin_s, |r| r.min(origin_s));
        self.reference_origin_s = Some(reference);
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
    /// Returns the common index the next window starts at.
    pub(super) fn restart(&mut self) -> i64 {
        let latest = self
            .stands
            .iter()
            .filter_map(StandStream::next_index)
            .max()
            .unwrap_or(0);
        self.valid_from = self.valid_from.max(latest);
        self.next_end = self.next_end.max(self.valid_from + self.window as i64);
        self.next_end - self.window as i64
    }

    /// The earliest and the latest next index over the stands, once every stand is
    /// anchored: the samples `..earliest` are in on every stand.
    pub(super) fn common_range(&self) -> Option<(i64, i64)> {
        let mut earliest = i64::MAX;
        let mut latest = i64::MIN;
        for stream in &self.stands {
            let next = stream.next_index()?;
            earliest = earliest.min(next);
            latest = latest.max(next);
        }
        Some((earliest, latest))
    }

    /// Oldest common index the rings still hold when the most advanced stand is at
    /// `latest`.
    pub(super) fn oldest_held(&self, latest: i64) -> i64 {
        latest - self.stands[0].ring.len() as i64
    }

    /// Restart once when a stand falls too far behind; clears when it catches up.
    pub(super) fn check_lag(&mut self) -> Option<RestartCause> {
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
        Some(RestartCause::Lagging { stand })
    }

    /// End of the window to evaluate now, if every stand has it; the grid then moves
    /// on by a hop.
    pub(super) fn take_due_window(&mut self) -> Option<i64> {
        let (earliest, latest) = self.common_range()?;
        if earliest < self.next_end {
            return None;
        }
        // The newest window on the hop grid that every stand has; the most advanced
        // stand's ring must still hold its start.
        let hop = self.hop as i64;
        let end = self.next_end + (earliest - self.next_end) / hop * hop;
        if self.oldest_held(latest) > end - self.window as i64 {
            return None;
        }
        self.next_end = end + hop;
        Some(end)
    }
}

/// The anchoring step of a stand whose first message has `len` samples at `fs` Hz:
/// whole messages, at least [`MIN_ANCHOR_STEP_S`] long.
fn anchor_step(len: usize, fs: f64) -> i64 {
    let len = (len as i64).max(1);
    let messages = (MIN_ANCHOR_STEP_S * fs / len as f64).ceil().max(1.0) as i64;
    len * messages
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::super::testing::{monitor, sine, BLOCK, FS};
    use super::*;
    use crate::analysis::chatter::ChatterUpdate;

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
    fn every_stand_late_at_first_then_on_time_is_not_realigned() {
        // The first ten polls of both stands come 40 ms late (a busy start: more than
        // half a 48 ms block), the rest on time: the stands keep their places against
        // each other, and the window runs on without a restart.
        let mut monitor = monitor(2);
        let signal = sine(180.0, 0.0, 1.0, 0..40 * BLOCK);
        let period = Duration::from_secs_f64(BLOCK as f64 / FS);
        let t0 = Instant::now();
        let mut evaluated = 0;
        for b in 0..40 {
            let late = if b < 10 {
                Duration::from_millis(40)
            } else {
                Duration::ZERO
            };
            let at = t0 + period * (b as u32 + 1) + late;
            for s in 0..2 {
                match monitor.samples(s, &signal[b * BLOCK..(b + 1) * BLOCK], at) {
                    Some(ChatterUpdate::Restarted(cause)) => panic!("block {b}: {cause}"),
                    Some(ChatterUpdate::Evaluated(r)) => {
                        assert!(r.k_mean > 0.95, "block {b}: K_mean {}", r.k_mean);
                        evaluated += 1;
                    }
                    _ => {}
                }
            }
        }
        assert!(evaluated > 0);
    }

    #[test]
    fn small_messages_with_jittery_arrivals_are_not_realigned() {
        // A CAN reader's messages of 4 samples (1.6 ms), the first read 5 ms late and
        // the others up to 3 ms late: the stands share every frame, nothing moves.
        let mut monitor = monitor(2);
        let signal = sine(50.0, 0.0, 1.0, 0..4000);
        let t0 = Instant::now();
        let mut evaluated = 0;
        for (m, values) in signal.chunks(4).enumerate() {
            let late_us = if m == 0 {
                5000
            } else {
                (m as u64 * 7919) % 3000
            };
            let at = t0
                + Duration::from_secs_f64((m + 1) as f64 * 4.0 / FS)
                + Duration::from_micros(late_us);
            for s in 0..2 {
                match monitor.samples(s, values, at) {
                    Some(ChatterUpdate::Restarted(cause)) if m > 0 => {
                        panic!("message {m}: restarted ({cause})")
                    }
                    Some(ChatterUpdate::Evaluated(_)) => evaluated += 1,
                    _ => {}
                }
            }
        }
        assert!(evaluated > 0);
        assert_eq!(anchor_step(4, FS), 52);
        assert_eq!(anchor_step(BLOCK, FS), BLOCK as i64);
    }
}
