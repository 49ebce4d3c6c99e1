//! [`SampleBatch`]: the values decoded from one batch of frames, grouped into one
//! [`Acquired::Samples`] message per channel, split by a gap where the kernel dropped
//! frames or a signal's value lay at the end of its raw range (saturated or "not
//! available": [`crate::field::quality`]); each value counted in its channel's
//! [`ChannelCounters`].

use std::sync::Arc;
use std::time::{Instant, SystemTime};

use crate::field::acquired::Acquired;
use crate::field::counters::ChannelCounters;
use crate::field::quality::SaturationLimits;

/// Samples of several frames grouped per channel, in arrival order, split where
/// frames were lost.
#[derive(Debug, Default)]
pub(crate) struct SampleBatch {
    /// Output of the last decode.
    pub(crate) pending: Vec<(usize, f64)>,
    /// Channel index -> values, the receive time of the last and when its batch was
    /// read (handed over), channels in order of first appearance.
    per_channel: Vec<(usize, Vec<f64>, SystemTime, Instant)>,
    /// Messages already complete (samples before a gap, and the gap).
    ready: Vec<Acquired>,
    /// Saturation limits of the channels that have any, by channel index.
    limits: Vec<(usize, SaturationLimits)>,
}

impl SampleBatch {
    /// A batch whose channels saturate at `limits` (channel index, limits).
    pub(crate) fn new(limits: Vec<(usize, SaturationLimits)>) -> Self {
        Self {
            limits,
            ..Self::default()
        }
    }

    fn saturated(&self, channel: usize, value: f64) -> bool {
        self.limits
            .iter()
            .any(|(known, limits)| *known == channel && limits.saturated(value))
    }

    /// Moves `pending`, from a frame received at `received` in a batch read at
    /// `handed`, into the per-channel lists; a saturated value closes its channel's
    /// samples and becomes a one-sample gap. Each value counts, in `counters` (indexed
    /// by channel), as a frame read and a sample of its channel (one signal a channel:
    /// one value a frame), a saturated one also as a saturated sample (as a Modbus
    /// block's samples count). Returns the number of saturated values.
    pub(crate) fn collect(
        &mut self,
        (received, handed): (SystemTime, Instant),
        counters: &[Arc<ChannelCounters>],
    ) -> u64 {
        let mut saturated = 0;
        let pending = std::mem::take(&mut self.pending);
        for &(channel, value) in &pending {
            let counted = counters.get(channel);
            if let Some(counted) = counted {
                counted.block(1);
            }
            if self.saturated(channel, value) {
                saturated += 1;
                if let Some(counted) = counted {
                    counted.saturated(1);
                }
                if let Some(at) = self.per_channel.iter().position(|(c, ..)| *c == channel) {
                    let (channel, values, received, handed) = self.per_channel.remove(at);
                    self.ready.push(Acquired::Samples {
                        channel,
                        values,
                        received: Some(received),
                        handed,
                    });
                }
                self.ready.push(Acquired::Gap {
                    channel,
                    missed_samples: Some(1),
                });
                continue;
            }
            match self
                .per_channel
                .iter_mut()
                .find(|(known, ..)| *known == channel)
            {
                Some((_, values, last, last_handed)) => {
                    values.push(value);
                    *last = received;
                    *last_handed = handed;
                }
                None => self
                    .per_channel
                    .push((channel, vec![value], received, handed)),
            }
        }
        self.pending = pending;
        self.pending.clear();
        saturated
    }

    /// Frames were lost here: close the samples so far and mark a gap on `channels`.
    pub(crate) fn gap(&mut self, channels: &[usize]) {
        self.close();
        self.ready
            .extend(channels.iter().map(|&channel| Acquired::Gap {
                channel,
                missed_samples: None,
            }));
    }

    fn close(&mut self) {
        self.ready.extend(
            self.per_channel
                .drain(..)
                .map(|(channel, values, received, handed)| Acquired::Samples {
                    channel,
                    values,
                    received: Some(received),
                    handed,
                }),
        );
    }

    /// The messages in order (one `Samples` per channel between gaps), emptying the
    /// batch.
    pub(crate) fn drain(&mut self) -> impl Iterator<Item = Acquired> + '_ {
        self.close();
        self.ready.drain(..)
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, UNIX_EPOCH};

    use super::*;
    use crate::field::counters::ChannelCountersSnapshot;

    /// The receive time `ms` after the epoch, in a batch read at `handed`.
    fn at(ms: u64, handed: Instant) -> (SystemTime, Instant) {
        (UNIX_EPOCH + Duration::from_millis(ms), handed)
    }

    #[test]
    fn batch_groups_per_channel_in_arrival_order() {
        let t = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let handed = Instant::now();
        let mut batch = SampleBatch::default();
        batch.pending.extend([(3, 1.0), (5, 10.0)]);
        batch.collect(at(1, handed), &[]);
        batch.pending.extend([(3, 2.0), (5, 20.0)]);
        batch.collect(at(2, handed), &[]);
        let messages: Vec<Acquired> = batch.drain().collect();
        assert_eq!(
            messages,
            vec![
                Acquired::Samples {
                    channel: 3,
                    values: vec![1.0, 2.0],
                    received: Some(t(2)),
                    handed,
                },
                Acquired::Samples {
                    channel: 5,
                    values: vec![10.0, 20.0],
                    received: Some(t(2)),
                    handed,
                },
            ]
        );
        assert_eq!(batch.drain().count(), 0);
    }

    #[test]
    fn a_saturated_value_becomes_a_gap_on_its_channel_only() {
        let t = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let handed = Instant::now();
        let limits = SaturationLimits {
            low: -327.67,
            high: 327.67,
        };
        let mut batch = SampleBatch::new(vec![(3, limits)]);
        batch.pending.extend([(3, 1.0), (5, 400.0)]);
        assert_eq!(
            batch.collect(at(1, handed), &[]),
            0,
            "channel 5 has no limits"
        );
        batch.pending.extend([(3, 327.67), (5, 401.0)]);
        assert_eq!(batch.collect(at(2, handed), &[]), 1);
        batch.pending.push((3, 2.0));
        batch.collect(at(3, handed), &[]);
        let messages: Vec<Acquired> = batch.drain().collect();
        assert_eq!(
            messages,
            vec![
                Acquired::Samples {
                    channel: 3,
                    values: vec![1.0],
                    received: Some(t(1)),
                    handed,
                },
                Acquired::Gap {
                    channel: 3,
                    missed_samples: Some(1),
                },
                Acquired::Samples {
                    channel: 5,
                    values: vec![400.0, 401.0],
                    received: Some(t(2)),
                    handed,
                },
                Acquired::Samples {
                    channel: 3,
                    values: vec![2.0],
                    received: Some(t(3)),
                    handed,
                },
            ]
        );
    }

    #[test]
    fn decoded_frames_count_per_channel() {
        use crate::field::can::decode::tests::torque_layout;
        use crate::field::can::{CanDecoder, FrameOutcome};

        // Message 0x101: channel 3 an Intel i16 at bits 0..16, channel 5 one at 16..32,
        // 0.01 a count; channel 3 saturates at the raw ends (+-327.67).
        let mut decoder = CanDecoder::default();
        decoder.add(3, torque_layout(0), 1.0, 0.0);
        decoder.add(5, torque_layout(16), 1.0, 0.0);
        let limits = SaturationLimits {
            low: -327.67,
            high: 327.67,
        };
        let counters: Vec<Arc<ChannelCounters>> = (0..6).map(|_| Arc::default()).collect();
        let mut batch = SampleBatch::new(vec![(3, limits)]);
        let handed = Instant::now();
        // Four frames of 0x101 (the second with channel 3 at 0x7fff: saturated), one of
        // an id no channel uses, one too short for channel 5.
        let frames: [(u32, &[u8]); 6] = [
            (0x101, &[0x39, 0x30, 0x01, 0x00]),
            (0x101, &[0xff, 0x7f, 0x02, 0x00]),
            (0x200, &[0x01, 0x02, 0x03, 0x04]),
            (0x101, &[0x00, 0x01, 0x03, 0x00]),
            (0x101, &[0x00, 0x01]),
            (0x101, &[0x00, 0x02, 0x04, 0x00]),
        ];
        let mut saturated = 0;
        for (ms, (id, data)) in (0..).zip(frames) {
            let outcome = decoder.decode(id, false, data, &mut batch.pending);
            assert_eq!(
                outcome == FrameOutcome::Decoded,
                id == 0x101 && data.len() == 4
            );
            saturated += batch.collect(at(ms, handed), &counters);
        }
        assert_eq!(saturated, 1);
        let count = |channel: usize| counters[channel].snapshot();
        for channel in [3, 5] {
            assert_eq!(count(channel).blocks_read, 4, "channel {channel}");
            assert_eq!(count(channel).samples, 4, "channel {channel}");
        }
        assert_eq!(count(3).saturated_samples, 1);
        assert_eq!(count(5).saturated_samples, 0);
        for channel in [0, 1, 2, 4] {
            assert_eq!(count(channel), ChannelCountersSnapshot::default());
        }
        // The counts match what the batch hands on: 3 + 4 values and channel 3's gap.
        let messages: Vec<Acquired> = batch.drain().collect();
        let values = |channel| -> usize {
            messages
                .iter()
                .filter_map(|message| match message {
                    Acquired::Samples {
                        channel: c, values, ..
                    } if *c == channel => Some(values.len()),
                    _ => None,
                })
                .sum()
        };
        assert_eq!((values(3), values(5)), (3, 4));
    }

    #[test]
    fn kernel_drops_split_the_batch_with_a_gap() {
        let t = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let handed = Instant::now();
        let mut batch = SampleBatch::default();
        batch.pending.push((3, 1.0));
        batch.collect(at(1, handed), &[]);
        batch.gap(&[3, 5]);
        batch.pending.extend([(3, 2.0), (5, 20.0)]);
        batch.collect(at(9, handed), &[]);
        let messages: Vec<Acquired> = batch.drain().collect();
        let gap = |channel| Acquired::Gap {
            channel,
            missed_samples: None,
        };
        assert_eq!(
            messages,
            vec![
                Acquired::Samples {
                    channel: 3,
                    values: vec![1.0],
                    received: Some(t(1)),
                    handed,
                },
                gap(3),
                gap(5),
                Acquired::Samples {
                    channel: 3,
                    values: vec![2.0],
                    received: Some(t(9)),
                    handed,
                },
                Acquired::Samples {
                    channel: 5,
                    values: vec![20.0],
                    received: Some(t(9)),
                    handed,
                },
            ]
        );
    }
}
