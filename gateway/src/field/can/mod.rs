//! The CAN reader: SocketCAN frames in, channel samples out.
//!
//! The reader opens one configured CAN interface with a CAN FD capable raw socket
//! (classic and FD frames both arrive), decodes each data frame with the DBC signal
//! layouts of the channels on that interface ([`CanDecoder`], pure and host-testable)
//! and sends [`Acquired::Samples`] over a bounded channel. Frames with an id no
//! channel uses, frames too short for their signals, remote and error frames are
//! counted in [`CanCounters`](crate::field::counters::CanCounters) and otherwise ignored.
//! Each channel counts its frames, samples, saturated samples and errors in its
//! [`ChannelCounters`](crate::field::counters::ChannelCounters), as a Modbus channel
//! does ([`ChannelCountersSnapshot`](crate::field::counters::ChannelCountersSnapshot)
//! says which stay 0).
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
//!
//! The work is split by job: `decode` (frame -> channel values, pure), `batch`
//! (values of a batch of frames -> [`Acquired`] messages), `socket` (opening the
//! interface, reading a batch of frames with their kernel timestamps and drop counts
//! in one `recvmmsg`), `reader` (the [`CanReader`] task) and `supervisor`
//! (reopening an interface that went away, for the service).

pub(crate) mod batch;
pub(crate) mod decode;
mod error;
pub(crate) mod reader;
pub(crate) mod socket;
pub(crate) mod supervisor;

pub use decode::{CanDecoder, FrameOutcome};
pub use error::CanError;
pub use reader::CanReader;

#[cfg(doc)]
use crate::field::acquired::Acquired;
