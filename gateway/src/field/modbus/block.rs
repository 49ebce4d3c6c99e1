//! One block channel of a DAQ in the millgate acquisition layout: the block sequence
//! tracked (new, same, lost blocks, a restart, a stall) and the samples passed on,
//! saturated ones as gaps.

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::layout;
use millgate_config::{Channel, RegisterTable, Scaling};

use crate::field::acquired::Acquired;
use crate::field::counters::ChannelCounters;
use crate::field::quality::{self, SaturationLimits};
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Block periods a sequence may stand still before the stall is counted.
const STALL_BLOCK_PERIODS: u32 = 3;

#[derive(Debug)]
pub(super) struct BlockChannel {
    pub(super) channel: usize,
    pub(super) table: RegisterTable,
    pub(super) base: u16,
    scaling: Scaling,
    sample_rate_hz: f64,
    limits: SaturationLimits,
    /// Sequence, time it was first seen and sample count of the last new block.
    last: Option<(u16, Instant, u16)>,
    /// The sequence has stood still past [`STALL_BLOCK_PERIODS`] (counted once).
    stalled: bool,
    /// One warning per period for restarts: a sequence running backwards restarts
    /// at every block (each counted).
    restart_warnings: WarnLimit,
    pub(super) counters: Arc<ChannelCounters>,
}

/// What one block read brought.
#[derive(Debug, PartialEq)]
pub(super) enum BlockNews {
    /// The block already seen.
    Same,
    /// A new block: the messages for analysis.
    New(Vec<Acquired>),
}

impl BlockChannel {
    /// Channel `channel` (`spec`) read as a block of `table` at `base`, counting into
    /// `counters`.
    pub(super) fn new(
        (channel, spec): (usize, &Channel),
        table: RegisterTable,
        base: u16,
        counters: Arc<ChannelCounters>,
    ) -> Self {
        Self {
            channel,
            table,
            base,
            scaling: spec.scaling(),
            sample_rate_hz: spec.sample_rate_hz,
            limits: quality::saturation_limits(spec),
            last: None,
            stalled: false,
            restart_warnings: WarnLimit::new(WARN_PERIOD),
            counters,
        }
    }
}

impl BlockChannel {
    /// What a block read at `now` brings: `Same` when it is the block already seen
    /// (counting a stall once it stands still past [`STALL_BLOCK_PERIODS`]), else the
    /// messages: an optional gap (lost blocks, or a DAQ restart), then the samples,
    /// saturated ones replaced by gaps, handed over at `now`.
    pub(super) fn accept(&mut self, sequence: u16, raw: &[u16], now: Instant) -> BlockNews {
        let count = raw.len() as u16;
        let mut messages = Vec::with_capacity(2);
        if let Some((last_sequence, last_time, last_count)) = self.last {
            let advance = layout::sequence_advance(last_sequence, sequence);
            let elapsed = now.saturating_duration_since(last_time);
            let block_period = self.block_period(last_count);
            if advance == 0 {
                if !self.stalled && elapsed > block_period * STALL_BLOCK_PERIODS {
                    self.stalled = true;
                    self.counters.stall();
                }
                return BlockNews::Same;
            }
            let by_time = (elapsed.as_secs_f64() / block_period.as_secs_f64()).round() as u64;
            if u64::from(advance) <= by_time + 2 {
                if advance > 1 {
                    let missed_blocks = u64::from(advance - 1);
                    self.counters.missed(missed_blocks);
                    messages.push(Acquired::Gap {
                        channel: self.channel,
                        missed_samples: Some(missed_blocks * u64::from(count)),
                    });
                }
            } else {
                // Backwards, or further than the clock allows: the DAQ restarted (its
                // sequence began anew) or replays old blocks. What was lost is not
                // known from the sequence; the clock estimates it for the analysis's
                // sample count, and it is not counted as lost blocks.
                self.counters.restart();
                let at = tokio::time::Instant::from_std(now);
                if let Some(suppressed) = self.restart_warnings.occurred(at) {
                    tracing::warn!(
                        channel = self.channel,
                        from = last_sequence,
                        to = sequence,
                        suppressed,
                        "DAQ block sequence restarted"
                    );
                }
                messages.push(Acquired::Gap {
                    channel: self.channel,
                    missed_samples: Some(by_time.saturating_sub(1) * u64::from(count)),
                });
            }
        }
        self.last = Some((sequence, now, count));
        self.stalled = false;
        self.counters.block(raw.len());
        let values = layout::Block { sequence, raw }
            .values(self.scaling)
            .collect();
        let saturated = quality::split_saturated(
            &self.limits,
            self.channel,
            values,
            (None, now),
            &mut messages,
        );
        self.counters.saturated(saturated);
        BlockNews::New(messages)
    }

    /// Duration of a block of `count` samples.
    fn block_period(&self, count: u16) -> Duration {
        Duration::from_secs_f64(f64::from(count.max(1)) / self.sample_rate_hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel() -> BlockChannel {
        BlockChannel {
            channel: 3,
            table: RegisterTable::Input,
            base: 0,
            scaling: Scaling::new(1.0, 0.0),
            sample_rate_hz: 1000.0,
            limits: quality::SaturationLimits {
                low: -32767.0,
                high: 32767.0,
            },
            last: None,
            stalled: false,
            restart_warnings: WarnLimit::new(WARN_PERIOD),
            counters: Arc::default(),
        }
    }

    fn messages(news: BlockNews) -> Vec<Acquired> {
        match news {
            BlockNews::New(messages) => messages,
            BlockNews::Same => panic!("expected a new block"),
        }
    }

    #[test]
    fn repeated_block_is_ignored_and_gap_is_marked() {
        let mut block = channel();
        let t0 = Instant::now();
        assert_eq!(messages(block.accept(10, &[1, 2], t0)).len(), 1);
        assert_eq!(
            block.accept(10, &[1, 2], t0),
            BlockNews::Same,
            "same block twice"
        );
        let read = t0 + Duration::from_millis(6);
        let messages = messages(block.accept(13, &[3, 4], read));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(4)
            }
        );
        assert_eq!(
            messages[1],
            Acquired::Samples {
                channel: 3,
                values: vec![3.0, 4.0],
                received: None,
                handed: read,
            }
        );
        let counters = block.counters.snapshot();
        assert_eq!((counters.blocks_read, counters.blocks_missed), (2, 2));
    }

    #[test]
    fn sequence_wrap_is_continuous() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(65535, &[1], t0);
        let messages = messages(block.accept(0, &[2], t0 + Duration::from_millis(1)));
        assert_eq!(messages.len(), 1, "65535 -> 0 is the next block");
    }

    #[test]
    fn restarted_daq_gap_is_estimated_from_time() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(5000, &[0; 100], t0);
        // The DAQ restarted: its sequence began again at 1, 2 s later (20 blocks).
        let messages = messages(block.accept(1, &[0; 100], t0 + Duration::from_secs(2)));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(1900)
            }
        );
        let counters = block.counters.snapshot();
        assert_eq!((counters.sequence_restarts, counters.blocks_missed), (1, 0));
    }

    #[test]
    fn a_sequence_going_backwards_is_a_restart_not_lost_blocks() {
        let mut block = channel();
        let t0 = Instant::now();
        block.accept(5000, &[0; 100], t0);
        // One block period later the sequence is 100 behind: the wrapping jump of
        // 65 436 counted 101 missed blocks before.
        let messages = messages(block.accept(4900, &[7; 100], t0 + Duration::from_millis(100)));
        assert_eq!(
            messages[0],
            Acquired::Gap {
                channel: 3,
                missed_samples: Some(0)
            },
            "a gap: the detector restarts"
        );
        assert!(matches!(messages[1], Acquired::Samples { .. }));
        let counters = block.counters.snapshot();
        assert_eq!(counters.sequence_restarts, 1);
        assert_eq!(counters.blocks_missed, 0);
        // It goes on from there as usual.
        let next = messages_of(&mut block, 4901, t0 + Duration::from_millis(200));
        assert_eq!(next.len(), 1);
    }

    /// Issue 30, finding 10: a sequence running backwards logged a warning per block
    /// (20 a second); every restart is still counted, one warning per 10 s.
    #[test]
    fn a_sequence_running_backwards_warns_once_per_period() {
        let mut block = channel();
        let t0 = Instant::now();
        for k in 0..200u16 {
            let at = t0 + Duration::from_millis(100 * u64::from(k));
            block.accept(60_000 - k, &[0; 100], at);
        }
        assert_eq!(block.counters.snapshot().sequence_restarts, 199);
        // 19.9 s of restarts: logged at 0.1 s and 10.1 s (with the 99 between), the
        // 98 after it suppressed until the next line.
        let later = tokio::time::Instant::from_std(t0 + Duration::from_secs(30));
        assert_eq!(block.restart_warnings.occurred(later), Some(98));
    }

    fn messages_of(block: &mut BlockChannel, sequence: u16, at: Instant) -> Vec<Acquired> {
        messages(block.accept(sequence, &[0; 100], at))
    }

    #[test]
    fn a_frozen_sequence_is_counted_once_per_stall() {
        let mut block = channel();
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        block.accept(10, &[0; 100], t0);
        // Block period 100 ms: still within three periods, no stall yet.
        assert_eq!(block.accept(10, &[0; 100], t0 + ms(250)), BlockNews::Same);
        assert_eq!(block.counters.snapshot().sequence_stalls, 0);
        for later in [350, 500, 2000] {
            assert_eq!(block.accept(10, &[0; 100], t0 + ms(later)), BlockNews::Same);
        }
        assert_eq!(block.counters.snapshot().sequence_stalls, 1);
        // Moving again, then frozen again: a second stall.
        messages_of(&mut block, 11, t0 + ms(2100));
        block.accept(11, &[0; 100], t0 + ms(2500));
        assert_eq!(block.counters.snapshot().sequence_stalls, 2);
    }

    #[test]
    fn saturated_samples_become_gaps_and_are_counted() {
        let mut block = channel();
        let t0 = Instant::now();
        let raw = [100, 32767, 32767, (-32768i16) as u16, 5];
        let messages = messages(block.accept(1, &raw, t0));
        assert_eq!(
            messages,
            [
                Acquired::Samples {
                    channel: 3,
                    values: vec![100.0],
                    received: None,
                    handed: t0
                },
                Acquired::Gap {
                    channel: 3,
                    missed_samples: Some(3)
                },
                Acquired::Samples {
                    channel: 3,
                    values: vec![5.0],
                    received: None,
                    handed: t0
                },
            ]
        );
        assert_eq!(block.counters.snapshot().saturated_samples, 3);
    }
}
