//! One block channel of a DAQ in the millgate acquisition layout: the block sequence
//! tracked (new, same, lost blocks, a restart, a stall), the samples passed on,
//! saturated ones as gaps, and when the channel is next worth reading.
//!
//! A DAQ writes a channel's next block one block period after the last. Reading the
//! channel at every poll reads each block several times (three times for a 50 ms block
//! polled every 16 ms); instead a channel is read when its next block is due
//! ([`ReadSchedule`]). Once a block was found within a poll period of its coming (a
//! read a poll period before did not find it), the next read comes a block period
//! after the read that found it, less [`CREEP_DIVISOR`]'s share of the period, and
//! when the block is not there yet, again a poll period later. So the reads creep
//! earlier block by block until one comes before the block, which sets them back a poll
//! period: a little over one read a block, each block read within a poll period of its
//! coming, as with a read at every poll. Until a block was found that way (the first
//! block, or after a read made late), the channel is read every poll period. A block
//! that comes late is found by the reads a poll period apart; a DAQ whose clock runs up
//! to 1/[`CREEP_DIVISOR`] fast is followed. Each read is within a block period of the
//! last, so while the DAQ keeps its rate no block is overwritten unread; a DAQ faster
//! than that (a configured sample rate above the DAQ's) loses a block, which is counted
//! (`blocks_missed`, a gap) and reads the channel every poll period for
//! [`EVERY_POLL_AFTER_LOSS`] block periods.

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

/// Block periods a channel is read every poll period after it lost a block.
const EVERY_POLL_AFTER_LOSS: u32 = 64;

/// The next read comes a block period less this share of it after the last new block
/// was found (3.1 ms for a 50 ms block).
const CREEP_DIVISOR: u32 = 16;

/// A read due within this share of a block period is made now (0.8 ms for a 50 ms
/// block): the channels of one DAQ, whose blocks come together, are read together.
const EARLY_DIVISOR: u32 = 64;

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
    /// When the channel is next read.
    schedule: ReadSchedule,
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
    /// Channel `channel` (`spec`) read as a block of `table` at `base` on a source
    /// polled every `poll_period`, counting into `counters`.
    pub(super) fn new(
        (channel, spec): (usize, &Channel),
        (table, base): (RegisterTable, u16),
        poll_period: Duration,
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
            schedule: ReadSchedule::new(poll_period),
            stalled: false,
            restart_warnings: WarnLimit::new(WARN_PERIOD),
            counters,
        }
    }
}

impl BlockChannel {
    /// When the channel is next read (`None`: at once).
    pub(super) fn next_read(&self) -> Option<Instant> {
        self.schedule.next_read
    }

    /// Whether a read at `now` is due (or due so soon that it is made with this one).
    pub(super) fn due(&self, now: Instant) -> bool {
        let early = self.block_period(self.samples()) / EARLY_DIVISOR;
        self.schedule.next_read.is_none_or(|at| now + early >= at)
    }

    /// A read at `now` failed: the next a poll period later.
    pub(super) fn failed(&mut self, now: Instant) {
        self.schedule.failed(now);
    }

    /// Samples of the last block (of the largest a block can hold before the first).
    fn samples(&self) -> u16 {
        self.last
            .map_or(layout::MAX_BLOCK_SAMPLES, |(_, _, count)| count)
    }

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
                self.schedule.same(now);
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
                    self.schedule.lost(now, block_period);
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
        self.schedule.new_block(now, self.block_period(count));
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

/// When a block channel is next read (the module's docs).
#[derive(Debug)]
struct ReadSchedule {
    /// The source's poll period: the time between reads while a block is awaited.
    poll_period: Duration,
    /// When the channel is next read (`None`: at once).
    next_read: Option<Instant>,
    /// The last read that found the block already seen, since the last new one.
    same_at: Option<Instant>,
    /// The last new block was found within a poll period (and a half) of a read that
    /// did not find it, and the reads since kept to the schedule: when the next block
    /// comes is known.
    in_phase: bool,
    /// Until when the channel is read every poll period, after a lost block.
    every_poll_until: Option<Instant>,
}

impl ReadSchedule {
    fn new(poll_period: Duration) -> Self {
        Self {
            poll_period,
            next_read: None,
            same_at: None,
            in_phase: false,
            every_poll_until: None,
        }
    }

    /// A read at `now` failed: again a poll period later.
    fn failed(&mut self, now: Instant) {
        self.next_read = Some(now + self.poll_period);
    }

    /// A read at `now` found that blocks of `block_period` were lost: a read every
    /// poll period for [`EVERY_POLL_AFTER_LOSS`] block periods.
    fn lost(&mut self, now: Instant, block_period: Duration) {
        self.every_poll_until = Some(now + block_period * EVERY_POLL_AFTER_LOSS);
    }

    /// A read at `now` found the block already seen: again a poll period later.
    fn same(&mut self, now: Instant) {
        self.same_at = Some(now);
        self.next_read = Some(now + self.poll_period);
    }

    /// A read at `now` found a new block of `block_period`.
    fn new_block(&mut self, now: Instant, block_period: Duration) {
        let creep = block_period / CREEP_DIVISOR;
        let between_reads = self
            .same_at
            .is_some_and(|same| now.saturating_duration_since(same) <= self.poll_period * 3 / 2);
        let on_schedule = self.in_phase && self.next_read.is_some_and(|at| now <= at + creep);
        self.in_phase = between_reads || on_schedule;
        self.same_at = None;
        let every_poll = self.every_poll_until.is_some_and(|until| now < until);
        let wait = if self.in_phase && !every_poll {
            block_period - creep
        } else {
            self.poll_period
        };
        self.next_read = Some(now + wait);
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
            schedule: ReadSchedule::new(Duration::from_millis(20)),
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
    fn a_channel_is_read_when_its_next_block_is_due_once_one_was_found_as_it_came() {
        let mut block = channel();
        let t0 = Instant::now();
        let us = |us: u64| t0 + Duration::from_micros(us);
        assert!(block.due(t0), "nothing read yet");
        // The first block: when it came is not known, the next read a poll period
        // (20 ms) later.
        messages_of(&mut block, 1, t0);
        assert_eq!(block.next_read(), Some(us(20_000)));
        assert_eq!(block.accept(1, &[0; 100], us(20_000)), BlockNews::Same);
        assert_eq!(block.next_read(), Some(us(40_000)));
        // Found a poll period after a read that did not find it: the next read a block
        // period (100 ms) less its 16th later, made from 1.5625 ms before (the 64th)
        // with the reads due then.
        messages_of(&mut block, 2, us(40_000));
        assert_eq!(block.next_read(), Some(us(133_750)));
        assert!(!block.due(us(132_180)));
        assert!(block.due(us(132_190)));
        // Not there yet: again a poll period later; found then, and at the read after.
        assert_eq!(block.accept(2, &[0; 100], us(133_750)), BlockNews::Same);
        assert_eq!(block.next_read(), Some(us(153_750)));
        messages_of(&mut block, 3, us(153_750));
        assert_eq!(block.next_read(), Some(us(247_500)));
        messages_of(&mut block, 4, us(247_500));
        assert_eq!(block.next_read(), Some(us(341_250)));
        // A read made more than the creep (6.25 ms) late: when the block came is not
        // known any more, a read every poll period until it is.
        messages_of(&mut block, 5, us(350_000));
        assert_eq!(block.next_read(), Some(us(370_000)));
        // A failed read: again a poll period later.
        block.failed(us(370_100));
        assert_eq!(block.next_read(), Some(us(390_100)));
    }

    #[test]
    fn a_lost_block_reads_the_channel_every_poll_period_for_a_while() {
        let mut block = channel();
        let t0 = Instant::now();
        let ms = |ms: u64| t0 + Duration::from_millis(ms);
        messages_of(&mut block, 1, t0);
        block.accept(1, &[0; 100], ms(20));
        messages_of(&mut block, 2, ms(40));
        assert_eq!(block.next_read(), Some(t0 + Duration::from_micros(133_750)));
        // A DAQ faster than its configured rate: block 3 overwritten by 4 at 134 ms.
        messages_of(&mut block, 4, ms(134));
        assert_eq!(block.counters.snapshot().blocks_missed, 1);
        // Every poll period for 64 block periods (6.4 s), new block or not.
        for k in 1..320 {
            let at = ms(134 + 20 * k);
            assert_eq!(block.next_read(), Some(at), "{} ms after the loss", 20 * k);
            messages_of(&mut block, 4 + k as u16, at);
        }
        assert_eq!(block.counters.snapshot().blocks_missed, 1);
        // Then a block period less its 16th after a new block again.
        messages_of(&mut block, 400, ms(6540));
        assert_eq!(
            block.next_read(),
            Some(ms(6540) + Duration::from_micros(93_750))
        );
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
