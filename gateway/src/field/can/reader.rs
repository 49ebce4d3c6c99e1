//! [`CanReader`]: the task that reads one SocketCAN interface, counts and decodes its
//! frames and sends the samples to analysis.

use std::io;
use std::sync::Arc;
use std::time::{Instant, SystemTime};

use millgate_config::frame::{parse_frame, FrameKind};
use millgate_config::Config;
use tokio::io::unix::AsyncFd;
use tokio::sync::{mpsc, watch};

use super::batch::SampleBatch;
use super::decode::{bus_state_of_error_frame, CanDecoder, FrameOutcome};
use super::error::CanError;
use super::socket::{open_socket, receive_batch, ReceiveBuffers, Received, MAX_FRAMES_PER_BATCH};
use crate::field::acquired::Acquired;
use crate::field::counters::{BusState, CanCounters, ChannelCounters};
use crate::field::source_health::SourceHealth;

/// Reads one SocketCAN interface and turns its frames into [`Acquired::Samples`].
#[derive(Debug)]
pub struct CanReader {
    interface: String,
    socket: AsyncFd<socketcan::CanFdSocket>,
    decoder: CanDecoder,
    /// Channels the decoder fills: each gets a gap when the kernel drops frames.
    channels: Vec<usize>,
    counters: Arc<CanCounters>,
    /// Per channel, indexed like `config.channels` (only the decoder's are counted).
    channel_counters: Vec<Arc<ChannelCounters>>,
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
        let socket = open_socket(interface)?;
        let channels = decoder.channels();
        let channel_counters = match channels.last() {
            Some(&last) => (0..=last).map(|_| Arc::default()).collect(),
            None => Vec::new(),
        };
        Ok(CanReader {
            interface: interface.to_owned(),
            socket,
            decoder,
            channels,
            counters: Arc::new(CanCounters::default()),
            channel_counters,
            health: None,
            drops_seen: 0,
        })
    }

    /// Report every batch of frames read to `health` (the source is then "ok"
    /// while frames arrive).
    pub(crate) fn with_health(mut self, health: Arc<SourceHealth>) -> Self {
        self.health = Some(health);
        self
    }

    /// Count into `counters` instead of the reader's own (a supervisor keeps one
    /// set per source across reopens).
    pub(crate) fn with_counters(mut self, counters: Arc<CanCounters>) -> Self {
        self.counters = counters;
        self
    }

    /// Count per channel into `counters`, indexed like `config.channels`, instead of
    /// the reader's own (the service's, shown on `/metrics`).
    pub(crate) fn with_channel_counters(mut self, counters: Vec<Arc<ChannelCounters>>) -> Self {
        self.channel_counters = counters;
        self
    }

    /// The reader's counters; they keep counting while [`Self::run`] runs.
    pub fn counters(&self) -> Arc<CanCounters> {
        Arc::clone(&self.counters)
    }

    /// The counters of channel index `channel` (the reader's own unless
    /// the service gave it the acquisition's), if the reader counts it: a frame
    /// that gave the channel a value counts as a block read and a sample, its value
    /// saturated also as a saturated sample; a frame of its message too short for its
    /// signals, or a read that failed, as an error. They keep counting while
    /// [`Self::run`] runs.
    pub fn channel_counters(&self, channel: usize) -> Option<Arc<ChannelCounters>> {
        self.channel_counters.get(channel).cloned()
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
        let mut batch = SampleBatch::new(self.decoder.saturation_limits());
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
            // The monotonic clock too, for the latencies measured from the hand-over
            // (`Acquired::Samples::handed`): the wall clock may step.
            let handed = Instant::now();
            for (frame, received) in buffers.frames() {
                self.handle(frame, received, (handled, handed), &mut batch);
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

    /// Counts and decodes one frame (`bytes`, with `received`) read at `handled`, in a
    /// batch handed over at `handed` (the batch's clock readings). The frame is counted
    /// last, once what it is has been counted: a snapshot that holds it holds that too
    /// ([`CanCounters::count_frame`]).
    fn handle(
        &mut self,
        bytes: &[u8],
        received: &Received,
        clock: (SystemTime, Instant),
        batch: &mut SampleBatch,
    ) {
        self.classify(bytes, received, clock, batch);
        self.counters.count_frame();
    }

    /// [`Self::handle`] but the frame's own count.
    fn classify(
        &mut self,
        bytes: &[u8],
        received: &Received,
        (handled, handed): (SystemTime, Instant),
        batch: &mut SampleBatch,
    ) {
        self.counters.count_timestamp(received.kernel_time, handled);
        if let Some(drops) = received.drops {
            let new_drops = drops.wrapping_sub(self.drops_seen);
            if new_drops != 0 {
                self.drops_seen = drops;
                self.counters.count_kernel_drops(new_drops);
                tracing::warn!(interface = %self.interface, new_drops, "kernel dropped CAN frames");
                batch.gap(&self.channels);
            }
        }
        let Some(frame) = parse_frame(bytes) else {
            self.counters.count_bad_size();
            return;
        };
        match frame.kind {
            FrameKind::Data => {
                let outcome =
                    self.decoder
                        .decode(frame.id, frame.extended, frame.data, &mut batch.pending);
                match outcome {
                    FrameOutcome::Decoded => self.counters.count_decoded(),
                    FrameOutcome::UnknownId => self.counters.count_unknown_id(),
                    FrameOutcome::BadLength => {
                        self.counters.count_bad_length();
                        self.count_errors(self.decoder.channels_of(frame.id, frame.extended));
                    }
                }
                let saturated = batch.collect(
                    (received.kernel_time.unwrap_or(handled), handed),
                    &self.channel_counters,
                );
                if saturated > 0 {
                    self.counters.count_saturated(saturated);
                }
            }
            FrameKind::Remote => {
                self.counters.count_remote_frame();
            }
            FrameKind::Error => {
                let state = bus_state_of_error_frame(frame.id, frame.data);
                if matches!(state, Some(BusState::Passive | BusState::BusOff)) {
                    tracing::warn!(interface = %self.interface, ?state, "CAN controller fault");
                }
                self.counters.count_error_frame(state);
            }
        }
    }

    /// Count an error on each of `channels`.
    fn count_errors(&self, channels: impl IntoIterator<Item = usize>) {
        for channel in channels {
            if let Some(counters) = self.channel_counters.get(channel) {
                counters.error();
            }
        }
    }

    /// A failed read of the interface, counted as an error on each channel of the
    /// source (as a Modbus transport error on the channels it read).
    fn read_error(&self, source: io::Error) -> CanError {
        self.count_errors(self.channels.iter().copied());
        CanError::Read {
            interface: self.interface.clone(),
            source,
        }
    }
}
