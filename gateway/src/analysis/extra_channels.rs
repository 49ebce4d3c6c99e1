//! A driveline's extra channels (`drivelines[].extra_channels`: motor current, speed,
//! ...): each one's latest samples in a bounded ring, so that a bite's capture can
//! keep them over the bite window beside the torque.
//!
//! A ring holds the channel's samples since its last gap, at most
//! [`ExtraRing::capacity`], and dates them as the torque's are dated: the newest
//! sample at its block's receive time (the CAN kernel's timestamp), or at the time the
//! analysis handled the block when the reader gives none (a Modbus DAQ), the older ones
//! one sample period apart before it. A bite window's row `k` (the torque's `k`-th
//! sample) takes the ring's sample nearest in time; the channel shares the torque's
//! sample rate (the configuration refuses another), so the rows hold consecutive
//! samples of the channel, exactly as received.

use std::collections::VecDeque;
use std::time::SystemTime;

use crate::state::captures::{unix_ns, CaptureChannel, ChannelTiming};

/// One extra channel of a driveline: its latest samples.
#[derive(Debug)]
pub(super) struct ExtraRing {
    /// Name, unit, scale and offset, as a capture describes the channel.
    channel: CaptureChannel,
    /// Sample rate, Hz (the torque's).
    sample_rate_hz: f64,
    /// Most samples kept.
    capacity: usize,
    /// The samples since the last gap, oldest first.
    samples: VecDeque<f64>,
    /// Time of the newest sample, and whether it is a kernel timestamp.
    newest: Option<(SystemTime, bool)>,
}

impl ExtraRing {
    /// A ring for `channel` sampled at `sample_rate_hz`, keeping `capacity` samples
    /// (a bite window and the lead one channel may have on another).
    pub(super) fn new(channel: CaptureChannel, sample_rate_hz: f64, capacity: usize) -> Self {
        Self {
            channel,
            sample_rate_hz,
            capacity: capacity.max(1),
            samples: VecDeque::with_capacity(capacity.max(1)),
            newest: None,
        }
    }

    /// Keep `values`, the newest of which was received at `received` (handled now
    /// when `None`).
    pub(super) fn push(&mut self, values: &[f64], received: Option<SystemTime>) {
        let skip = values.len().saturating_sub(self.capacity);
        for &value in &values[skip..] {
            if self.samples.len() == self.capacity {
                self.samples.pop_front();
            }
            self.samples.push_back(value);
        }
        if !values.is_empty() {
            self.newest = Some((received.unwrap_or_else(SystemTime::now), received.is_some()));
        }
    }

    /// Samples were lost: what is kept no longer joins what comes next.
    pub(super) fn gap(&mut self) {
        self.samples.clear();
        self.newest = None;
    }

    /// Position (ring index, may lie outside the ring) of the sample nearest `time`.
    fn position_at(&self, time: SystemTime) -> Option<i64> {
        let (newest, _) = self.newest?;
        let newest_position = self.samples.len() as i64 - 1;
        let behind_s = match newest.duration_since(time) {
            Ok(behind) => behind.as_secs_f64(),
            Err(ahead) => -ahead.duration().as_secs_f64(),
        };
        Some(newest_position - (behind_s * self.sample_rate_hz).round() as i64)
    }

    /// Whether the ring holds the sample at `time` or a later one.
    pub(super) fn reaches(&self, time: SystemTime) -> bool {
        self.position_at(time)
            .is_some_and(|position| position < self.samples.len() as i64)
    }

    /// The channel over `rows` rows whose first is at `first_row_time`, one sample
    /// period apart: the samples it holds, NaN in the rows it does not.
    pub(super) fn capture(&self, first_row_time: SystemTime, rows: usize) -> CaptureChannel {
        let mut samples = vec![f64::NAN; rows];
        let mut timing = None;
        if let (Some(start), Some((newest, kernel_time))) =
            (self.position_at(first_row_time), self.newest)
        {
            let held = self.samples.len() as i64;
            let first_row = (-start).clamp(0, rows as i64) as usize;
            let end_row = (held - start).clamp(first_row as i64, rows as i64) as usize;
            for (row, sample) in samples.iter_mut().enumerate().take(end_row).skip(first_row) {
                *sample = self.samples[(start + row as i64) as usize];
            }
            if end_row > first_row {
                let behind = (held - 1 - (start + first_row as i64)) as f64 / self.sample_rate_hz;
                let first = newest
                    .checked_sub(std::time::Duration::from_secs_f64(behind))
                    .unwrap_or(std::time::UNIX_EPOCH);
                timing = Some(ChannelTiming {
                    first_sample_unix_ns: unix_ns(first),
                    sample_rate_hz: self.sample_rate_hz,
                    kernel_time,
                    first_row,
                    end_row,
                });
            }
        }
        CaptureChannel {
            samples,
            timing: Some(timing.unwrap_or(ChannelTiming {
                first_sample_unix_ns: unix_ns(first_row_time),
                sample_rate_hz: self.sample_rate_hz,
                kernel_time: false,
                first_row: 0,
                end_row: 0,
            })),
            ..self.channel.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, SystemTime, UNIX_EPOCH};

    use super::ExtraRing;
    use crate::state::captures::{unix_ns, CaptureChannel};

    fn ring(capacity: usize) -> ExtraRing {
        let channel = CaptureChannel {
            name: "motor_current".into(),
            unit: "A".into(),
            scale: 0.5,
            offset: 0.0,
            samples: Vec::new(),
            timing: None,
        };
        ExtraRing::new(channel, 1000.0, capacity)
    }

    /// `t0` plus `ms` milliseconds.
    fn at(ms: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(1_700_000_000) + Duration::from_millis(ms)
    }

    #[test]
    fn a_window_takes_the_samples_nearest_its_rows() {
        let mut ring = ring(100);
        // Samples 0..=49 (value = index), the newest received at 49 ms.
        let values: Vec<f64> = (0..50).map(f64::from).collect();
        ring.push(&values[..20], Some(at(19)));
        ring.push(&values[20..], Some(at(49)));
        // Rows at 10..=29 ms: samples 10..=29, the first at 10 ms.
        assert!(ring.reaches(at(29)));
        let captured = ring.capture(at(10), 20);
        assert_eq!(
            captured.samples,
            (10..30).map(f64::from).collect::<Vec<_>>()
        );
        let timing = captured.timing.unwrap();
        assert_eq!((timing.first_row, timing.end_row), (0, 20));
        assert_eq!(timing.first_sample_unix_ns, unix_ns(at(10)));
        assert!(timing.kernel_time);
        // A window running past the newest sample: not reached; its tail is missing.
        assert!(!ring.reaches(at(55)));
        let captured = ring.capture(at(40), 16);
        assert_eq!(
            captured.samples[..10],
            (40..50).map(f64::from).collect::<Vec<_>>()
        );
        assert!(captured.samples[10..].iter().all(|s| s.is_nan()));
        let timing = captured.timing.unwrap();
        assert_eq!((timing.first_row, timing.end_row), (0, 10));
    }

    #[test]
    fn the_ring_is_bounded_and_a_gap_empties_it() {
        let mut ring = ring(30);
        let values: Vec<f64> = (0..50).map(f64::from).collect();
        ring.push(&values, Some(at(49)));
        // Only samples 20..=49 are kept: rows before 20 ms are missing.
        let captured = ring.capture(at(15), 10);
        assert!(captured.samples[..5].iter().all(|s| s.is_nan()));
        assert_eq!(captured.samples[5..], [20.0, 21.0, 22.0, 23.0, 24.0]);
        let timing = captured.timing.unwrap();
        assert_eq!((timing.first_row, timing.end_row), (5, 10));
        assert_eq!(timing.first_sample_unix_ns, unix_ns(at(20)));
        ring.gap();
        assert!(!ring.reaches(at(0)));
        let captured = ring.capture(at(15), 10);
        assert!(captured.samples.iter().all(|s| s.is_nan()));
        assert_eq!(captured.timing.unwrap().end_row, 0);
    }
}
