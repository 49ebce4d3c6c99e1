//! Acquisition counters, shared by the reader tasks (which count) with the register
//! map and `/metrics` (which read snapshots): per channel ([`ChannelCounters`]) and per
//! CAN source ([`CanCounters`]), gathered with the sources' health in [`Acquisition`].

use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use super::source_health::SourceHealth;

/// Where the acquisition counters come from: per channel, per source (in the order of
/// `Config::sources`) and per CAN source.
#[derive(Debug, Clone)]
pub struct Acquisition {
    /// Per channel, indexed like `config.channels`.
    pub counters: Vec<Arc<ChannelCounters>>,
    /// Per source.
    pub health: Vec<Arc<SourceHealth>>,
    /// Per CAN source.
    pub can: Vec<Arc<CanCounters>>,
}

/// Per-channel acquisition counters. Monotonic; read with [`ChannelCounters::snapshot`].
#[derive(Debug, Default)]
pub struct ChannelCounters {
    blocks_read: AtomicU64,
    blocks_missed: AtomicU64,
    samples: AtomicU64,
    timeouts: AtomicU64,
    errors: AtomicU64,
    saturated_samples: AtomicU64,
    sequence_restarts: AtomicU64,
    sequence_stalls: AtomicU64,
}

/// A copy of [`ChannelCounters`] at one moment.
///
/// A CAN channel counts a frame that gave it a value as a block read and a sample (one
/// signal a channel: one value a frame), saturated or not; a frame of its message too
/// short for the message's signals, and a failed read of its interface, as an error.
/// Its `blocks_missed`, `timeouts`, `sequence_restarts` and `sequence_stalls` stay 0:
/// CAN has no requests, and frames the kernel dropped cannot be told per channel (their
/// ids are lost; they are counted per source, [`CanCounts::kernel_drops`], and a gap on
/// every channel of the source).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChannelCountersSnapshot {
    /// New blocks (or CAN frames) decoded.
    pub blocks_read: u64,
    /// Blocks lost between two reads, from sequence-number gaps.
    pub blocks_missed: u64,
    /// Samples passed on to analysis.
    pub samples: u64,
    /// Requests that got no answer in time.
    pub timeouts: u64,
    /// Transport errors, device exceptions and malformed replies (CAN: frames too short
    /// for their signals, failed reads).
    pub errors: u64,
    /// Samples at the converter's limits, replaced by gaps.
    pub saturated_samples: u64,
    /// Block sequences that went backwards or jumped further than the time elapsed:
    /// DAQ restarts.
    pub sequence_restarts: u64,
    /// Times the block sequence stood still for three block periods while the DAQ
    /// answered (a frozen DAQ).
    pub sequence_stalls: u64,
}

impl ChannelCounters {
    pub(crate) fn block(&self, samples: usize) {
        self.blocks_read.fetch_add(1, Ordering::Relaxed);
        self.samples.fetch_add(samples as u64, Ordering::Relaxed);
    }

    pub(crate) fn missed(&self, blocks: u64) {
        self.blocks_missed.fetch_add(blocks, Ordering::Relaxed);
    }

    pub(crate) fn timeout(&self) {
        self.timeouts.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn error(&self) {
        self.errors.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn saturated(&self, samples: u64) {
        self.saturated_samples.fetch_add(samples, Ordering::Relaxed);
    }

    pub(crate) fn restart(&self) {
        self.sequence_restarts.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn stall(&self) {
        self.sequence_stalls.fetch_add(1, Ordering::Relaxed);
    }

    /// Current values.
    pub fn snapshot(&self) -> ChannelCountersSnapshot {
        ChannelCountersSnapshot {
            blocks_read: self.blocks_read.load(Ordering::Relaxed),
            blocks_missed: self.blocks_missed.load(Ordering::Relaxed),
            samples: self.samples.load(Ordering::Relaxed),
            timeouts: self.timeouts.load(Ordering::Relaxed),
            errors: self.errors.load(Ordering::Relaxed),
            saturated_samples: self.saturated_samples.load(Ordering::Relaxed),
            sequence_restarts: self.sequence_restarts.load(Ordering::Relaxed),
            sequence_stalls: self.sequence_stalls.load(Ordering::Relaxed),
        }
    }
}

/// Frame counters of one [`CanReader`](crate::field::can::CanReader), shared with whoever monitors it.
#[derive(Debug, Default)]
pub struct CanCounters {
    frames: AtomicU64,
    decoded: AtomicU64,
    unknown_id: AtomicU64,
    bad_length: AtomicU64,
    remote_frames: AtomicU64,
    error_frames: AtomicU64,
    error_passive: AtomicU64,
    bus_off: AtomicU64,
    /// Frames the kernel dropped (socket receive queue full), from `SO_RXQ_OVFL`.
    kernel_drops: AtomicU64,
    /// Frames that carried a kernel receive timestamp.
    kernel_timestamps: AtomicU64,
    /// Sum of (handled - kernel timestamp) over those frames, ns.
    receive_latency_ns: AtomicU64,
    /// Largest such delay, ns.
    receive_latency_max_ns: AtomicU64,
    /// Reads of a length that is neither a classic nor an FD frame.
    bad_size: AtomicU64,
    /// Signal values at the end of their raw range, replaced by gaps.
    saturated_samples: AtomicU64,
    /// [`BusState`] as its code, from the last error frame that told it.
    bus_state: AtomicU8,
}

/// The controller's fault confinement state, as the last error frame told it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum BusState {
    /// Error active: normal operation (also the state before any error frame).
    #[default]
    Active,
    /// Error passive: an error counter passed 127; the node may still talk.
    Passive,
    /// Bus off: the controller left the bus until it is restarted.
    BusOff,
}

impl BusState {
    /// Metrics encoding: 0 active, 1 passive, 2 bus off.
    pub fn code(self) -> u8 {
        match self {
            BusState::Active => 0,
            BusState::Passive => 1,
            BusState::BusOff => 2,
        }
    }

    fn from_code(code: u8) -> Self {
        match code {
            1 => BusState::Passive,
            2 => BusState::BusOff,
            _ => BusState::Active,
        }
    }
}

/// A copy of [`CanCounters`] at one instant. All counts are since the reader opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CanCounts {
    /// Every frame received: data, remote and error.
    pub frames: u64,
    /// Data frames decoded into samples.
    pub decoded: u64,
    /// Data frames whose id no configured channel uses.
    pub unknown_id: u64,
    /// Data frames of a known id too short for its signals.
    pub bad_length: u64,
    /// Remote (RTR) frames.
    pub remote_frames: u64,
    /// Error frames reported by the controller.
    pub error_frames: u64,
    /// Error frames reporting error passive (RX or TX).
    pub error_passive: u64,
    /// Error frames reporting bus off.
    pub bus_off: u64,
    /// Frames the kernel dropped because the socket's receive queue was full.
    pub kernel_drops: u64,
    /// Frames that carried a kernel receive timestamp (the others are dated by
    /// the reader's clock).
    pub kernel_timestamps: u64,
    /// Sum over `kernel_timestamps` frames of the delay from the kernel timestamp to
    /// the reader handling the frame, ns.
    pub receive_latency_sum_ns: u64,
    /// Largest such delay, ns.
    pub receive_latency_max_ns: u64,
    /// Reads whose length was neither a classic nor an FD frame.
    pub bad_size: u64,
    /// Signal values at the end of their raw range (saturated, or "not available"),
    /// passed on as gaps, not as values.
    pub saturated_samples: u64,
    /// The bus state last reported.
    pub bus_state: BusState,
}

impl CanCounters {
    /// Current values: every count made for the frames in `frames` (read first; a
    /// frame is counted after the rest of its counts), and perhaps some of the next
    /// frame's.
    pub fn snapshot(&self) -> CanCounts {
        CanCounts {
            frames: self.frames.load(Ordering::Acquire),
            decoded: self.decoded.load(Ordering::Relaxed),
            unknown_id: self.unknown_id.load(Ordering::Relaxed),
            bad_length: self.bad_length.load(Ordering::Relaxed),
            remote_frames: self.remote_frames.load(Ordering::Relaxed),
            error_frames: self.error_frames.load(Ordering::Relaxed),
            error_passive: self.error_passive.load(Ordering::Relaxed),
            bus_off: self.bus_off.load(Ordering::Relaxed),
            kernel_drops: self.kernel_drops.load(Ordering::Relaxed),
            kernel_timestamps: self.kernel_timestamps.load(Ordering::Relaxed),
            receive_latency_sum_ns: self.receive_latency_ns.load(Ordering::Relaxed),
            receive_latency_max_ns: self.receive_latency_max_ns.load(Ordering::Relaxed),
            bad_size: self.bad_size.load(Ordering::Relaxed),
            saturated_samples: self.saturated_samples.load(Ordering::Relaxed),
            bus_state: BusState::from_code(self.bus_state.load(Ordering::Relaxed)),
        }
    }

    /// Count a frame read at `handled` with kernel timestamp `kernel` (if any).
    pub(crate) fn count_timestamp(&self, kernel: Option<SystemTime>, handled: SystemTime) {
        let Some(kernel) = kernel else {
            return;
        };
        // A kernel clock ahead of ours (it is the same clock) counts as no delay.
        let delay = handled.duration_since(kernel).unwrap_or(Duration::ZERO);
        let delay_ns = u64::try_from(delay.as_nanos()).unwrap_or(u64::MAX);
        self.kernel_timestamps.fetch_add(1, Ordering::Relaxed);
        self.receive_latency_ns
            .fetch_add(delay_ns, Ordering::Relaxed);
        self.receive_latency_max_ns
            .fetch_max(delay_ns, Ordering::Relaxed);
    }

    /// Count a frame of any kind, after what it counted besides: released, so that a
    /// [`Self::snapshot`] that sees it sees those counts as well.
    pub(crate) fn count_frame(&self) {
        self.frames.fetch_add(1, Ordering::Release);
    }

    /// Count a data frame decoded into samples.
    pub(crate) fn count_decoded(&self) {
        self.decoded.fetch_add(1, Ordering::Relaxed);
    }

    /// Count a data frame whose id no channel uses.
    pub(crate) fn count_unknown_id(&self) {
        self.unknown_id.fetch_add(1, Ordering::Relaxed);
    }

    /// Count a data frame too short for its signals.
    pub(crate) fn count_bad_length(&self) {
        self.bad_length.fetch_add(1, Ordering::Relaxed);
    }

    /// Count a remote (RTR) frame.
    pub(crate) fn count_remote_frame(&self) {
        self.remote_frames.fetch_add(1, Ordering::Relaxed);
    }

    /// Count a read of a length that is neither a classic nor an FD frame.
    pub(crate) fn count_bad_size(&self) {
        self.bad_size.fetch_add(1, Ordering::Relaxed);
    }

    /// Count `samples` saturated signal values.
    pub(crate) fn count_saturated(&self, samples: u64) {
        self.saturated_samples.fetch_add(samples, Ordering::Relaxed);
    }

    /// Count `frames` the kernel dropped.
    pub(crate) fn count_kernel_drops(&self, frames: u32) {
        self.kernel_drops
            .fetch_add(u64::from(frames), Ordering::Relaxed);
    }

    /// Count an error frame, and the bus state it reports when it reports one.
    pub(crate) fn count_error_frame(&self, state: Option<BusState>) {
        self.error_frames.fetch_add(1, Ordering::Relaxed);
        let Some(state) = state else {
            return;
        };
        match state {
            BusState::Passive => self.error_passive.fetch_add(1, Ordering::Relaxed),
            BusState::BusOff => self.bus_off.fetch_add(1, Ordering::Relaxed),
            BusState::Active => 0,
        };
        self.bus_state.store(state.code(), Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use std::time::UNIX_EPOCH;

    use super::*;

    #[test]
    fn receive_latency_is_summed_from_kernel_timestamps() {
        let counters = CanCounters::default();
        let kernel = UNIX_EPOCH + Duration::from_secs(1_000);
        counters.count_timestamp(Some(kernel), kernel + Duration::from_micros(300));
        counters.count_timestamp(Some(kernel), kernel + Duration::from_micros(100));
        counters.count_timestamp(None, kernel);
        // A kernel timestamp after the read (clock stepped): no negative delay.
        counters.count_timestamp(Some(kernel + Duration::from_secs(1)), kernel);
        let counts = counters.snapshot();
        assert_eq!(counts.kernel_timestamps, 3);
        assert_eq!(counts.receive_latency_sum_ns, 400_000);
        assert_eq!(counts.receive_latency_max_ns, 300_000);
    }
}
