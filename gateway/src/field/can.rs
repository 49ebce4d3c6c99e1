//! `CanReader`: SocketCAN frames in, channel samples out.
//!
//! The reader opens one configured CAN interface with a CAN FD capable raw socket
//! (classic and FD frames both arrive), decodes each data frame with the DBC signal
//! layouts of the channels on that interface ([`CanDecoder`], pure and host-testable)
//! and sends [`Acquired::Samples`] over a bounded channel. Frames with an id no
//! channel uses, frames too short for their signals, remote and error frames are
//! counted in [`CanCounters`] and otherwise ignored.
//!
//! Frames are read in batches, up to 64 per `recvmmsg` call.
//!
//! **Kernel receive timestamps.** The socket is opened with `SO_TIMESTAMPNS`: every
//! frame is read together with the time the kernel queued it
//! (`CLOCK_REALTIME`), and each `Samples` message carries the timestamp of the frame
//! of its last value ([`Acquired::Samples::received`]), from which analysis dates
//! bites. The delay from that timestamp to the reader handling the frame is summed
//! per source (`millgate_can_receive_latency_seconds` on `/metrics`): it shows a
//! reader falling behind its socket. When the kernel delivers no timestamp (the
//! option refused, or absent from a message) the time the reader read the frame
//! stands in for it, and the frame is not counted in `kernel_timestamps`.
//!
//! **Kernel drops.** With `SO_RXQ_OVFL` each message also carries the socket's
//! count of frames the kernel dropped because the receive queue was full. When it
//! moves, the increase is added to `kernel_drops` and every channel of the source
//! gets an [`Acquired::Gap`] at that point: the dropped frames' ids are unknown, so
//! no channel may be joined across it.

use std::collections::HashMap;
use std::io::{self, IoSliceMut};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

pub use millgate_config::frame::{parse_frame, FrameKind, RawFrame, CANFD_MTU, CAN_MTU};
use millgate_config::signal::SignalLayout;
use millgate_config::{ChannelSource, Config};
use nix::sys::socket::{self as nix_socket, sockopt, ControlMessageOwned, MsgFlags};
use socketcan::{Socket, SocketOptions};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::sync::{mpsc, watch};

use crate::field::acquired::Acquired;
use crate::field::counters::SourceHealth;

/// `errno` EAFNOSUPPORT: the kernel has no `AF_CAN` address family.
const EAFNOSUPPORT: i32 = 97;
/// `errno` ENODEV: no network interface of that name.
const ENODEV: i32 = 19;
/// Most frames read by one `recvmmsg` call and decoded into one batch of
/// [`Acquired::Samples`] messages. Its headers are set up for every call (see
/// [`receive_batch`]), so a larger batch costs more per wake-up on a quiet bus; 64
/// already cuts the system calls of a backlog 64-fold.
const MAX_FRAMES_PER_BATCH: usize = 64;

/// Why a CAN reader could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    /// The configuration has no CAN source with this index.
    #[error("no CAN source with index {index}: the configuration has {count}")]
    NoSuchSource { index: usize, count: usize },
    /// The running kernel was built without SocketCAN (`socket(AF_CAN)` gives errno 97).
    #[error(
        "SocketCAN not available in this kernel (errno 97) for CAN interface `{interface}`; \
         run the vcan suite through scripts/uml-vcan"
    )]
    NoSocketCan { interface: String },
    /// The kernel has SocketCAN but no interface of that name (errno 19).
    #[error(
        "no such CAN interface `{interface}` (errno 19, ENODEV); create it, e.g. \
         `ip link add dev {interface} type vcan && ip link set up {interface}`"
    )]
    NoSuchInterface { interface: String },
    /// Any other failure to open or configure the socket.
    #[error("cannot open CAN interface `{interface}`: {source}")]
    Open {
        interface: String,
        #[source]
        source: io::Error,
    },
    /// Reading from an open socket failed (e.g. the interface went away).
    #[error("reading CAN interface `{interface}`: {source}")]
    Read {
        interface: String,
        #[source]
        source: io::Error,
    },
    /// The receiving end of the sample channel was dropped.
    #[error("CAN reader for `{interface}`: the sample channel is closed")]
    SamplesClosed { interface: String },
}

/// Frame counters of one [`CanReader`], shared with whoever monitors it.
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

/// Error-frame class bits in the CAN id and controller status bits in data[1]
/// (linux/can/error.h).
mod error_bits {
    pub const CRTL: u32 = 0x0004;
    pub const BUSOFF: u32 = 0x0040;
    pub const RESTARTED: u32 = 0x0100;
    pub const CRTL_RX_PASSIVE: u8 = 0x10;
    pub const CRTL_TX_PASSIVE: u8 = 0x20;
    pub const CRTL_ACTIVE: u8 = 0x40;
}

/// The bus state an error frame reports, if it reports one: bus off, error passive,
/// or back to error active (controller restarted or recovered).
pub fn bus_state_of_error_frame(class_bits: u32, data: &[u8]) -> Option<BusState> {
    use error_bits::*;
    let controller = if class_bits & CRTL != 0 {
        data.get(1).copied().unwrap_or(0)
    } else {
        0
    };
    if class_bits & BUSOFF != 0 {
        Some(BusState::BusOff)
    } else if controller & (CRTL_RX_PASSIVE | CRTL_TX_PASSIVE) != 0 {
        Some(BusState::Passive)
    } else if class_bits & RESTARTED != 0 || controller & CRTL_ACTIVE != 0 {
        Some(BusState::Active)
    } else {
        None
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
    /// The bus state last reported.
    pub bus_state: BusState,
}

impl CanCounters {
    /// Current values.
    pub fn snapshot(&self) -> CanCounts {
        CanCounts {
            frames: self.frames.load(Ordering::Relaxed),
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
            bus_state: BusState::from_code(self.bus_state.load(Ordering::Relaxed)),
        }
    }

    /// Count a frame read at `handled` with kernel timestamp `kernel` (if any).
    fn count_timestamp(&self, kernel: Option<SystemTime>, handled: SystemTime) {
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

    fn count_error_frame(&self, class_bits: u32, data: &[u8]) {
        self.error_frames.fetch_add(1, Ordering::Relaxed);
        let Some(state) = bus_state_of_error_frame(class_bits, data) else {
            return;
        };
        match state {
            BusState::Passive => self.error_passive.fetch_add(1, Ordering::Relaxed),
            BusState::BusOff => self.bus_off.fetch_add(1, Ordering::Relaxed),
            BusState::Active => 0,
        };
        self.bus_state.store(state.code(), Ordering::Relaxed);
    }

    fn count_data(&self, outcome: FrameOutcome) {
        let counter = match outcome {
            FrameOutcome::Decoded => &self.decoded,
            FrameOutcome::UnknownId => &self.unknown_id,
            FrameOutcome::BadLength => &self.bad_length,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// What [`CanDecoder::decode`] made of one data frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameOutcome {
    /// Every signal of the frame's channels was decoded.
    Decoded,
    /// No channel uses this id; nothing decoded.
    UnknownId,
    /// The frame is too short for at least one of its signals; nothing decoded, so
    /// the channels of one message stay sample-aligned.
    BadLength,
}

/// A configured channel carried by one CAN message.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ChannelSignal {
    channel: usize,
    layout: SignalLayout,
    /// The channel's own scale and offset, applied after the DBC's.
    scale: f64,
    offset: f64,
}

/// Signals of one message and the length they need.
#[derive(Debug, Clone, PartialEq)]
struct MessageSignals {
    signals: Vec<ChannelSignal>,
    /// Largest [`SignalLayout::bytes_needed`] among `signals`.
    bytes_needed: usize,
}

/// Pure frame decoder: (id, extended, payload) -> samples of the configured channels.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CanDecoder {
    /// Keyed by (identifier, extended).
    messages: HashMap<(u32, bool), MessageSignals>,
}

impl CanDecoder {
    /// Decoder for the channels of CAN source `source_index` of `config`.
    ///
    /// A source without channels gives a decoder that counts every frame as unknown.
    pub fn for_source(config: &Config, source_index: usize) -> Self {
        let mut decoder = CanDecoder::default();
        for (channel, settings) in config.channels.iter().enumerate() {
            if let ChannelSource::Can {
                source,
                signal_layout,
                ..
            } = &settings.source
            {
                if *source == source_index {
                    decoder.add(channel, *signal_layout, settings.scale, settings.offset);
                }
            }
        }
        decoder
    }

    /// Adds channel index `channel`, read from `layout` then scaled by the channel's
    /// `scale` and `offset` (1 and 0 for plain DBC values).
    pub fn add(&mut self, channel: usize, layout: SignalLayout, scale: f64, offset: f64) {
        let message = self
            .messages
            .entry((layout.frame_id, layout.extended))
            .or_insert_with(|| MessageSignals {
                signals: Vec::new(),
                bytes_needed: 0,
            });
        message.bytes_needed = message.bytes_needed.max(layout.bytes_needed());
        message.signals.push(ChannelSignal {
            channel,
            layout,
            scale,
            offset,
        });
    }

    /// Indices of the channels the decoder fills, in configuration order.
    pub fn channels(&self) -> Vec<usize> {
        let mut channels: Vec<usize> = self
            .messages
            .values()
            .flat_map(|message| message.signals.iter().map(|signal| signal.channel))
            .collect();
        channels.sort_unstable();
        channels.dedup();
        channels
    }

    /// Number of channels the decoder fills.
    pub fn channel_count(&self) -> usize {
        self.messages
            .values()
            .map(|message| message.signals.len())
            .sum()
    }

    /// Decodes data frame `frame_id`/`extended` with payload `data`, appending
    /// `(channel index, engineering value)` pairs to `samples` in configuration order.
    ///
    /// Appends nothing unless the outcome is [`FrameOutcome::Decoded`].
    pub fn decode(
        &self,
        frame_id: u32,
        extended: bool,
        data: &[u8],
        samples: &mut Vec<(usize, f64)>,
    ) -> FrameOutcome {
        let Some(message) = self.messages.get(&(frame_id, extended)) else {
            return FrameOutcome::UnknownId;
        };
        if data.len() < message.bytes_needed {
            return FrameOutcome::BadLength;
        }
        let start = samples.len();
        for signal in &message.signals {
            match signal.layout.decode(data) {
                Some(value) => samples.push((signal.channel, value * signal.scale + signal.offset)),
                None => {
                    // Unreachable once `bytes_needed` passed, unless a layout has an
                    // invalid size; then drop the whole frame, as for a short one.
                    samples.truncate(start);
                    return FrameOutcome::BadLength;
                }
            }
        }
        FrameOutcome::Decoded
    }
}

/// The ancillary data that came with one frame.
#[derive(Debug, Clone, Copy)]
struct Received {
    /// Bytes of the frame in its receive buffer.
    len: usize,
    /// `SCM_TIMESTAMPNS`: when the kernel queued the frame.
    kernel_time: Option<SystemTime>,
    /// `SO_RXQ_OVFL`: frames dropped by this socket since it opened.
    drops: Option<u32>,
}

/// Receive buffers for one batch of frames, allocated once per reader.
#[derive(Debug)]
struct ReceiveBuffers {
    /// One `struct canfd_frame` per slot.
    frames: Box<[[u8; CANFD_MTU]; MAX_FRAMES_PER_BATCH]>,
    /// What came with `frames[i]`, for the first `received.len()` slots.
    received: Vec<Received>,
}

impl ReceiveBuffers {
    fn new() -> Self {
        ReceiveBuffers {
            frames: Box::new([[0; CANFD_MTU]; MAX_FRAMES_PER_BATCH]),
            received: Vec::with_capacity(MAX_FRAMES_PER_BATCH),
        }
    }

    /// The frames of the last batch with their ancillary data, in arrival order.
    fn frames(&self) -> impl Iterator<Item = (&[u8], &Received)> + '_ {
        self.frames
            .iter()
            .zip(&self.received)
            .map(|(frame, received)| (frame.get(..received.len).unwrap_or_default(), received))
    }
}

/// Reads the frames queued on non-blocking socket `socket`, up to
/// [`MAX_FRAMES_PER_BATCH`], with their control messages, in one `recvmmsg` call.
///
/// One system call per batch rather than per frame: under User-Mode Linux (where the
/// vcan tests run) and some hypervisors a system call costs tens of microseconds,
/// more than decoding a frame. Fails with `WouldBlock` when no frame is queued;
/// otherwise returns how many were read, fewer than the maximum once the queue is
/// empty.
fn receive_batch(socket: &impl AsRawFd, buffers: &mut ReceiveBuffers) -> io::Result<usize> {
    let ReceiveBuffers { frames, received } = buffers;
    received.clear();
    // The headers hold raw pointers (not `Send`), so they live for this call only
    // and cannot be kept in the reader, which a spawned task owns.
    let control = nix::cmsg_space!(nix::sys::time::TimeSpec, u32);
    let mut headers =
        nix_socket::MultiHeaders::<()>::preallocate(MAX_FRAMES_PER_BATCH, Some(control));
    let mut slices = frames.each_mut().map(|frame| [IoSliceMut::new(frame)]);
    let messages = nix_socket::recvmmsg(
        socket.as_raw_fd(),
        &mut headers,
        slices.iter_mut(),
        MsgFlags::MSG_DONTWAIT,
        None,
    )
    .map_err(io::Error::from)?;
    for message in messages {
        let mut kernel_time = None;
        let mut drops = None;
        for control_message in message.cmsgs().map_err(io::Error::from)? {
            match control_message {
                ControlMessageOwned::ScmTimestampns(time) => {
                    let since_epoch = u64::try_from(time.tv_sec())
                        .ok()
                        .zip(u32::try_from(time.tv_nsec()).ok())
                        .map(|(s, ns)| Duration::new(s, ns));
                    kernel_time = since_epoch
                        .filter(|d| !d.is_zero())
                        .and_then(|d| UNIX_EPOCH.checked_add(d));
                }
                ControlMessageOwned::RxqOvfl(count) => drops = Some(count),
                _ => {}
            }
        }
        received.push(Received {
            len: message.bytes,
            kernel_time,
            drops,
        });
    }
    Ok(received.len())
}

/// Reads one SocketCAN interface and turns its frames into [`Acquired::Samples`].
#[derive(Debug)]
pub struct CanReader {
    interface: String,
    socket: AsyncFd<socketcan::CanFdSocket>,
    decoder: CanDecoder,
    /// Channels the decoder fills: each gets a gap when the kernel drops frames.
    channels: Vec<usize>,
    counters: Arc<CanCounters>,
    health: Option<Arc<SourceHealth>>,
    /// The socket's `SO_RXQ_OVFL` count at the last frame.
    drops_seen: u32,
}

impl CanReader {
    /// Opens the interface of CAN source `source_index` of `config` for the channels
    /// that use it.
    ///
    /// Fails with [`CanError::NoSocketCan`] on a kernel without SocketCAN and with
    /// [`CanError::NoSuchInterface`] when the interface does not exist.
    pub fn open(config: &Config, source_index: usize) -> Result<CanReader, CanError> {
        let source = config
            .can_sources
            .get(source_index)
            .ok_or(CanError::NoSuchSource {
                index: source_index,
                count: config.can_sources.len(),
            })?;
        let decoder = CanDecoder::for_source(config, source_index);
        CanReader::open_interface(&source.interface, decoder)
    }

    /// Opens `interface` with an explicit decoder (tests, tools). Must be called
    /// within a tokio runtime.
    ///
    /// Kernel receive timestamps (`SO_TIMESTAMPNS`) and drop counts (`SO_RXQ_OVFL`)
    /// are asked for; a kernel that refuses either is logged and the reader goes on
    /// without it (arrival times, no drop count).
    pub fn open_interface(interface: &str, decoder: CanDecoder) -> Result<CanReader, CanError> {
        check_socketcan(interface)?;
        let fail = |error| open_error(interface, error);
        let socket = socketcan::CanFdSocket::open(interface).map_err(fail)?;
        socket.set_nonblocking(true).map_err(fail)?;
        socket.set_error_filter_accept_all().map_err(fail)?;
        if let Err(error) = socket.set_recv_timestamp(true) {
            tracing::warn!(%interface, %error, "no kernel receive timestamps: frames dated on arrival");
        }
        if let Err(error) = nix_socket::setsockopt(&socket, sockopt::RxqOvfl, &1) {
            tracing::warn!(%interface, %error, "no kernel drop count (SO_RXQ_OVFL)");
        }
        // SAFETY: `register_with_interest` asks that the fd stay open and not be
        // replaced while registered. The `CanFdSocket` owns its fd and closes it only
        // when dropped, and the `AsyncFd` owns the socket, deregistering first.
        #[allow(unsafe_code)]
        let socket = unsafe { AsyncFd::register_with_interest(socket, Interest::READABLE) }
            .map_err(|error| fail(error.into_parts().1))?;
        let channels = decoder.channels();
        Ok(CanReader {
            interface: interface.to_owned(),
            socket,
            decoder,
            channels,
            counters: Arc::new(CanCounters::default()),
            health: None,
            drops_seen: 0,
        })
    }

    /// Report every batch of frames read to `health` (the source is then "ok"
    /// while frames arrive).
    pub fn with_health(mut self, health: Arc<SourceHealth>) -> Self {
        self.health = Some(health);
        self
    }

    /// Count into `counters` instead of the reader's own (a supervisor keeps one
    /// set per source across reopens).
    pub fn with_counters(mut self, counters: Arc<CanCounters>) -> Self {
        self.counters = counters;
        self
    }

    /// The reader's counters; they keep counting while [`Self::run`] runs.
    pub fn counters(&self) -> Arc<CanCounters> {
        Arc::clone(&self.counters)
    }

    /// Interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Reads frames until `shutdown` turns true (or its sender is dropped), sending
    /// each channel's samples, oldest first, to `samples`.
    ///
    /// Frames already queued in the socket are batched (up to 64 frames) into one
    /// `Samples` message per channel. A full `samples` channel makes the reader wait
    /// (the kernel socket buffer then absorbs the backlog; what it cannot hold is
    /// counted as kernel drops and marked as a gap).
    pub async fn run(
        mut self,
        samples: mpsc::Sender<Acquired>,
        mut shutdown: watch::Receiver<bool>,
    ) -> Result<(), CanError> {
        let mut batch = SampleBatch::default();
        let mut buffers = ReceiveBuffers::new();
        loop {
            if *shutdown.borrow_and_update() {
                return Ok(());
            }
            let mut ready = tokio::select! {
                changed = shutdown.changed() => {
                    if changed.is_err() {
                        return Ok(());
                    }
                    continue;
                }
                ready = self.socket.readable() => ready.map_err(|error| self.read_error(error))?,
            };
            let count = match ready.try_io(|socket| receive_batch(socket, &mut buffers)) {
                Ok(result) => result.map_err(|error| self.read_error(error))?,
                Err(_would_block) => continue,
            };
            if count < MAX_FRAMES_PER_BATCH {
                // A short batch emptied the queue: wait for the next readiness event
                // instead of spending a system call on an empty read. A frame queued
                // since then has already raised a new event, which this does not clear.
                ready.clear_ready();
            }
            drop(ready);
            // One clock reading per batch: outside a vDSO (User-Mode Linux, some
            // hypervisors) every reading is a system call, as costly as the read.
            let handled = SystemTime::now();
            for (frame, received) in buffers.frames() {
                self.handle(frame, received, handled, &mut batch);
            }
            if let Some(health) = &self.health {
                health.answered();
            }
            for message in batch.drain() {
                samples
                    .send(message)
                    .await
                    .map_err(|_| CanError::SamplesClosed {
                        interface: self.interface.clone(),
                    })?;
            }
        }
    }

    /// Counts and decodes one frame (`bytes`, with `received`) read at `handled` (the
    /// batch's clock reading).
    fn handle(
        &mut self,
        bytes: &[u8],
        received: &Received,
        handled: SystemTime,
        batch: &mut SampleBatch,
    ) {
        self.counters.frames.fetch_add(1, Ordering::Relaxed);
        self.counters.count_timestamp(received.kernel_time, handled);
        if let Some(drops) = received.drops {
            let new_drops = drops.wrapping_sub(self.drops_seen);
            if new_drops != 0 {
                self.drops_seen = drops;
                self.counters
                    .kernel_drops
                    .fetch_add(u64::from(new_drops), Ordering::Relaxed);
                tracing::warn!(interface = %self.interface, new_drops, "kernel dropped CAN frames");
                batch.gap(&self.channels);
            }
        }
        let Some(frame) = parse_frame(bytes) else {
            self.counters.bad_size.fetch_add(1, Ordering::Relaxed);
            return;
        };
        match frame.kind {
            FrameKind::Data => {
                let outcome =
                    self.decoder
                        .decode(frame.id, frame.extended, frame.data, &mut batch.pending);
                self.counters.count_data(outcome);
                batch.collect(received.kernel_time.unwrap_or(handled));
            }
            FrameKind::Remote => {
                self.counters.remote_frames.fetch_add(1, Ordering::Relaxed);
            }
            FrameKind::Error => {
                let state = bus_state_of_error_frame(frame.id, frame.data);
                if matches!(state, Some(BusState::Passive | BusState::BusOff)) {
                    tracing::warn!(interface = %self.interface, ?state, "CAN controller fault");
                }
                self.counters.count_error_frame(frame.id, frame.data);
            }
        }
    }

    fn read_error(&self, source: io::Error) -> CanError {
        CanError::Read {
            interface: self.interface.clone(),
            source,
        }
    }
}

/// Samples of several frames grouped per channel, in arrival order, split where
/// frames were lost.
#[derive(Debug, Default)]
struct SampleBatch {
    /// Output of the last decode.
    pending: Vec<(usize, f64)>,
    /// Channel index -> values and the receive time of the last, channels in order
    /// of first appearance.
    per_channel: Vec<(usize, Vec<f64>, SystemTime)>,
    /// Messages already complete (samples before a gap, and the gap).
    ready: Vec<Acquired>,
}

impl SampleBatch {
    /// Moves `pending`, from a frame received at `received`, into the per-channel lists.
    fn collect(&mut self, received: SystemTime) {
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
    fn gap(&mut self, channels: &[usize]) {
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
    fn drain(&mut self) -> impl Iterator<Item = Acquired> + '_ {
        self.close();
        self.ready.drain(..)
    }
}

/// Fails with [`CanError::NoSocketCan`] when the kernel has no `AF_CAN` sockets.
fn check_socketcan(interface: &str) -> Result<(), CanError> {
    let probe = socket2::Socket::new(
        socket2::Domain::from(socketcan::addr::AF_CAN),
        socket2::Type::RAW,
        Some(socket2::Protocol::from(socketcan::addr::CAN_RAW)),
    );
    match probe {
        Ok(_) => Ok(()),
        Err(error) => Err(open_error(interface, error)),
    }
}

/// Names the two errors an operator can act on; keeps the rest as is.
fn open_error(interface: &str, error: io::Error) -> CanError {
    let interface = interface.to_owned();
    match error.raw_os_error() {
        Some(EAFNOSUPPORT) => CanError::NoSocketCan { interface },
        Some(ENODEV) => CanError::NoSuchInterface { interface },
        _ => CanError::Open {
            interface,
            source: error,
        },
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn error_frames_tell_the_bus_state() {
        // Class bits and data[1] as in linux/can/error.h.
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x10, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Passive)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x20, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Passive)
        );
        assert_eq!(
            bus_state_of_error_frame(0x40, &[0; 8]),
            Some(BusState::BusOff)
        );
        assert_eq!(
            bus_state_of_error_frame(0x44, &[0, 0x10, 0, 0, 0, 0, 0, 0]),
            Some(BusState::BusOff)
        );
        assert_eq!(
            bus_state_of_error_frame(0x100, &[0; 8]),
            Some(BusState::Active)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x40, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Active)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x04, 0, 0, 0, 0, 0, 0]),
            None,
            "RX warning only"
        );
        assert_eq!(
            bus_state_of_error_frame(0x08, &[0; 8]),
            None,
            "protocol violation"
        );
    }

    use super::*;

    fn torque_layout(start_bit: u16) -> SignalLayout {
        SignalLayout {
            frame_id: 0x101,
            extended: false,
            frame_len: 8,
            start_bit,
            size: 16,
            little_endian: true,
            signed: true,
            factor: 0.01,
            offset: 0.0,
        }
    }

    fn decoder() -> CanDecoder {
        let mut decoder = CanDecoder::default();
        decoder.add(3, torque_layout(0), 1.0, 0.0);
        decoder.add(5, torque_layout(16), 2.0, 1.0);
        let oil_temp = SignalLayout {
            frame_id: 0x18ff_5a01,
            extended: true,
            frame_len: 8,
            start_bit: 0,
            size: 16,
            little_endian: true,
            signed: false,
            factor: 0.1,
            offset: -40.0,
        };
        decoder.add(7, oil_temp, 1.0, 0.0);
        decoder
    }

    #[test]
    fn decodes_channels_of_a_frame_in_order() {
        let mut samples = Vec::new();
        let outcome = decoder().decode(0x101, false, &[0x39, 0x30, 0xc3, 0xdd], &mut samples);
        assert_eq!(outcome, FrameOutcome::Decoded);
        assert_eq!(samples.len(), 2);
        assert_eq!(samples[0].0, 3);
        assert!((samples[0].1 - 123.45).abs() < 1e-9);
        assert_eq!(samples[1].0, 5);
        assert!((samples[1].1 - (-87.65 * 2.0 + 1.0)).abs() < 1e-9);
    }

    #[test]
    fn standard_and_extended_ids_are_distinct() {
        let decoder = decoder();
        let mut samples = Vec::new();
        let frame = [0x1d, 0x04, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            decoder.decode(0x18ff_5a01, false, &frame, &mut samples),
            FrameOutcome::UnknownId
        );
        assert_eq!(
            decoder.decode(0x101, true, &frame, &mut samples),
            FrameOutcome::UnknownId
        );
        assert!(samples.is_empty());
        assert_eq!(
            decoder.decode(0x18ff_5a01, true, &frame, &mut samples),
            FrameOutcome::Decoded
        );
        assert_eq!(samples.len(), 1);
        assert!((samples[0].1 - 65.3).abs() < 1e-9);
    }

    #[test]
    fn short_frame_decodes_nothing() {
        let mut samples = vec![(9, 9.0)];
        // Long enough for channel 3 (bytes 0..2) but not channel 5 (bytes 2..4).
        let outcome = decoder().decode(0x101, false, &[0x39, 0x30, 0xc3], &mut samples);
        assert_eq!(outcome, FrameOutcome::BadLength);
        assert_eq!(samples, vec![(9, 9.0)], "earlier samples stay, none added");
    }

    #[test]
    fn counts_channels() {
        assert_eq!(decoder().channel_count(), 3);
        assert_eq!(CanDecoder::default().channel_count(), 0);
    }

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

    #[test]
    fn errno_names_the_problem() {
        let no_can = open_error("vcan0", io::Error::from_raw_os_error(EAFNOSUPPORT));
        assert!(matches!(no_can, CanError::NoSocketCan { .. }));
        assert!(no_can
            .to_string()
            .contains("SocketCAN not available in this kernel (errno 97)"));
        let no_dev = open_error("can7", io::Error::from_raw_os_error(ENODEV));
        assert!(matches!(no_dev, CanError::NoSuchInterface { .. }));
        assert!(no_dev.to_string().contains("no such CAN interface `can7`"));
        let other = open_error("can0", io::Error::from_raw_os_error(1));
        assert!(matches!(other, CanError::Open { .. }));
    }
}
