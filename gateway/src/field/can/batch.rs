//! [`SampleBatch`]: the values decoded from one batch of frames, grouped into one
//! [`Acquired::Samples`] message per channel, split by a gap where the kernel dropped
//! frames.

use std::time::SystemTime;

use crate::field::acquired::Acquired;

/// Samples of several frames grouped per channel, in arrival order, split where
/// frames were lost.
#[derive(Debug, Default)]
pub(crate) struct SampleBatch {
    /// Output of the last decode.
    pub(crate) pending: Vec<(usize, f64)>,
    /// Channel index -> values and the receive time of the last, channels in order
    /// of first appearance.
    per_channel: Vec<(usize, Vec<f64>, SystemTime)>,
    /// Messages already complete (samples before a gap, and the gap).
    ready: Vec<Acquired>,
}

impl SampleBatch {
    /// Moves `pending`, from a frame received at `received`, into the per-channel lists.
    pub(crate) fn collect(&mut self, received: SystemTime) {
        for (channel, value) in self.pending.drain(..) {
            match self
                .per_channel
                .iter_mut()
                .find(|(known, _, _)| *known == channel)
            {
                Some((_, values, last)) => {
                    values.push(value);
                    *last = received;
                }
                None => self.per_channel.push((channel, vec![value], received)),
            }
        }
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
                .map(|(channel, values, received)| Acquired::Samples {
                    channel,
                    values,
                    received: Some(received),
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

    #[test]
    fn batch_groups_per_channel_in_arrival_order() {
        let t = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let mut batch = SampleBatch::default();
        batch.pending.extend([(3, 1.0), (5, 10.0)]);
        batch.collect(t(1));
        batch.pending.extend([(3, 2.0), (5, 20.0)]);
        batch.collect(t(2));
        let messages: Vec<Acquired> = batch.drain().collect();
        assert_eq!(
            messages,
            vec![
                Acquired::Samples {
                    channel: 3,
                    values: vec![1.0, 2.0],
                    received: Some(t(2)),
                },
                Acquired::Samples {
                    channel: 5,
                    values: vec![10.0, 20.0],
                    received: Some(t(2)),
                },
            ]
        );
        assert_eq!(batch.drain().count(), 0);
    }

    #[test]
    fn kernel_drops_split_the_batch_with_a_gap() {
        let t = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let mut batch = SampleBatch::default();
        batch.pending.push((3, 1.0));
        batch.collect(t(1));
        batch.gap(&[3, 5]);
        batch.pending.extend([(3, 2.0), (5, 20.0)]);
        batch.collect(t(9));
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
                },
                gap(3),
                gap(5),
                Acquired::Samples {
                    channel: 3,
                    values: vec![2.0],
                    received: Some(t(9)),
                },
                Acquired::Samples {
                    channel: 5,
                    values: vec![20.0],
                    received: Some(t(9)),
                },
            ]
        );
    }
}
