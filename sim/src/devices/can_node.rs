//! A virtual CAN node: puts simulated channel values onto a SocketCAN interface.
//!
//! A [`CanMessage`] is one DBC message seen as a list of [`SignalLayout`]s; it encodes
//! a row of engineering values into frame bytes ([`SignalLayout::encode`]). A
//! [`CanNode`] owns a CAN FD capable raw socket and sends such rows, one frame each,
//! classic CAN for messages of up to 8 bytes and CAN FD above, optionally paced at a
//! fixed frame period. Unpaced rows go out in bursts, one `sendmmsg` call each: the
//! node is the test peer of the gateway's reader and shares its CPU, and under
//! User-Mode Linux a system call per frame would make the node, not the reader, the
//! bottleneck of the throughput figure.

use std::io::{self, IoSlice};
use std::os::fd::AsRawFd;
use std::time::Duration;

use millgate_config::frame::{data_frame, FrameBytes};
use millgate_config::signal::{FrameTooShort, SignalLayout};
use nix::errno::Errno;
use nix::sys::socket::{self as nix_socket, ControlMessage, MsgFlags, MultiHeaders};
use socketcan::Socket;
use tokio::time::Instant;

/// `errno` EAFNOSUPPORT: the kernel has no SocketCAN.
const EAFNOSUPPORT: i32 = 97;
/// Wait between retries of a write refused with ENOBUFS.
const TX_QUEUE_FULL_BACKOFF: Duration = Duration::from_millis(1);
/// Retries of one write refused with ENOBUFS before giving up (about 1 s).
const TX_QUEUE_FULL_RETRIES: u32 = 1000;
/// Largest payload of a CAN FD frame, bytes.
const FD_MAX_LEN: usize = 64;
/// Sleep only when this far ahead of the pacing schedule (tokio timers tick in ms).
const MIN_SLEEP: Duration = Duration::from_millis(1);
/// Frames of one unpaced burst (one `sendmmsg` call), after which the node yields to
/// other tasks: enough to save system calls and scheduler round trips, few enough
/// for a receive buffer (~200 frames).
const FRAMES_PER_BURST: usize = 32;

/// Why a virtual CAN node could not build or send a frame.
#[derive(Debug, thiserror::Error)]
pub enum CanNodeError {
    /// A message needs at least one signal.
    #[error("a CAN message needs at least one signal")]
    NoSignals,
    /// The signals given for one message do not share one frame id.
    #[error("signals of one CAN message must share its id: {first:#x} and {other:#x}")]
    MixedIds {
        /// The first signal's frame id.
        first: u32,
        /// Another signal's, different.
        other: u32,
    },
    /// The identifier does not fit its format (11 or 29 bits).
    #[error("CAN id {frame_id:#x} does not fit a {} identifier", if *.extended { "29-bit" } else { "11-bit" })]
    BadId {
        /// The identifier.
        frame_id: u32,
        /// 29-bit (extended) format when true, 11-bit otherwise.
        extended: bool,
    },
    /// Frame length beyond CAN FD's 64 bytes.
    #[error("CAN frame length {len} bytes exceeds 64")]
    TooLong {
        /// The requested length, bytes.
        len: usize,
    },
    /// A row does not have one value per signal.
    #[error("expected {expected} values for the message, got {got}")]
    WrongValueCount {
        /// Signals of the message.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A signal lies beyond the message length.
    #[error(transparent)]
    FrameTooShort(#[from] FrameTooShort),
    /// The interface could not be opened.
    #[error("cannot open CAN interface `{interface}`: {source}{}", if source.raw_os_error() == Some(EAFNOSUPPORT) { " (SocketCAN not available in this kernel; run scripts/uml-vcan)" } else { "" })]
    Open {
        /// The interface name.
        interface: String,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Sending a frame failed.
    #[error("writing to CAN interface `{interface}`: {source}")]
    Write {
        /// The interface name.
        interface: String,
        /// Why.
        #[source]
        source: io::Error,
    },
}

/// One DBC message: the signals it carries and the frame they go in.
#[derive(Debug, Clone, PartialEq)]
pub struct CanMessage {
    frame_id: u32,
    extended: bool,
    len: usize,
    signals: Vec<SignalLayout>,
}

impl CanMessage {
    /// A message from its signals' layouts, in the order rows will list values.
    ///
    /// All layouts must share one id and format; the frame length is the largest of
    /// their DBC `frame_len` and the bytes the signals need (at most 64).
    pub fn new(signals: Vec<SignalLayout>) -> Result<CanMessage, CanNodeError> {
        let first = signals.first().ok_or(CanNodeError::NoSignals)?;
        let (frame_id, extended) = (first.frame_id, first.extended);
        if let Some(other) = signals
            .iter()
            .find(|signal| (signal.frame_id, signal.extended) != (frame_id, extended))
        {
            return Err(CanNodeError::MixedIds {
                first: frame_id,
                other: other.frame_id,
            });
        }
        frame_identifier(frame_id, extended)?;
        let len = signals
            .iter()
            .map(|signal| usize::from(signal.frame_len).max(signal.bytes_needed()))
            .max()
            .unwrap_or(0);
        if len > FD_MAX_LEN {
            return Err(CanNodeError::TooLong { len });
        }
        Ok(CanMessage {
            frame_id,
            extended,
            len,
            signals,
        })
    }

    /// CAN identifier.
    pub fn frame_id(&self) -> u32 {
        self.frame_id
    }

    /// Payload for one value per signal, in engineering units; unused bits are 0.
    pub fn encode(&self, values: &[f64]) -> Result<Vec<u8>, CanNodeError> {
        if values.len() != self.signals.len() {
            return Err(CanNodeError::WrongValueCount {
                expected: self.signals.len(),
                got: values.len(),
            });
        }
        let mut data = vec![0_u8; self.len];
        for (signal, value) in self.signals.iter().zip(values) {
            signal.encode(*value, &mut data)?;
        }
        Ok(data)
    }

    /// The frame for one row of values: classic CAN up to 8 bytes, CAN FD above.
    pub fn frame(&self, values: &[f64]) -> Result<FrameBytes, CanNodeError> {
        let data = self.encode(values)?;
        data_frame(self.frame_id, self.extended, &data)
            .ok_or(CanNodeError::TooLong { len: data.len() })
    }
}

/// Checks that `frame_id` fits a 29-bit (`extended`) or 11-bit identifier.
fn frame_identifier(frame_id: u32, extended: bool) -> Result<(), CanNodeError> {
    let limit = if extended { 1 << 29 } else { 1 << 11 };
    if frame_id < limit {
        Ok(())
    } else {
        Err(CanNodeError::BadId { frame_id, extended })
    }
}

/// A simulated CAN device on one SocketCAN interface.
#[derive(Debug)]
pub struct CanNode {
    interface: String,
    socket: socketcan::CanFdSocket,
}

impl CanNode {
    /// Opens `interface` (e.g. `vcan0`) for sending classic and FD frames.
    pub fn open(interface: &str) -> Result<CanNode, CanNodeError> {
        let open = || {
            let socket = socketcan::CanFdSocket::open(interface)?;
            socket.set_nonblocking(true)?;
            Ok(socket)
        };
        let socket = open().map_err(|source| CanNodeError::Open {
            interface: interface.to_owned(),
            source,
        })?;
        Ok(CanNode {
            interface: interface.to_owned(),
            socket,
        })
    }

    /// Sends `frames` in order, as many per `sendmmsg` call as the socket takes,
    /// waiting out a full transmit queue (ENOBUFS) for up to ~1 s.
    pub async fn send_frames(&self, frames: &[FrameBytes]) -> Result<(), CanNodeError> {
        let mut sent = 0;
        let mut retries = 0;
        while let Some(rest) = frames.get(sent..).filter(|rest| !rest.is_empty()) {
            match self.send_some(rest) {
                Ok(count) => {
                    sent += count;
                    retries = 0;
                }
                Err(Errno::ENOBUFS | Errno::EAGAIN) if retries < TX_QUEUE_FULL_RETRIES => {
                    retries += 1;
                    tokio::time::sleep(TX_QUEUE_FULL_BACKOFF).await;
                }
                Err(errno) => {
                    return Err(CanNodeError::Write {
                        interface: self.interface.clone(),
                        source: errno.into(),
                    })
                }
            }
        }
        Ok(())
    }

    /// One `sendmmsg` call for `frames` (not empty): how many the kernel took.
    fn send_some(&self, frames: &[FrameBytes]) -> Result<usize, Errno> {
        let slices: Vec<[IoSlice<'_>; 1]> = frames
            .iter()
            .map(|frame| [IoSlice::new(frame.as_bytes())])
            .collect();
        let addresses = vec![None::<()>; frames.len()];
        let no_control: [ControlMessage<'_>; 0] = [];
        let mut headers = MultiHeaders::<()>::preallocate(frames.len(), None);
        let results = nix_socket::sendmmsg(
            self.socket.as_raw_fd(),
            &mut headers,
            &slices,
            addresses,
            no_control,
            MsgFlags::MSG_DONTWAIT,
        )?;
        Ok(results.count())
    }

    /// Encodes `values` (one per signal of `message`) and sends the frame.
    pub(crate) async fn send(
        &self,
        message: &CanMessage,
        values: &[f64],
    ) -> Result<(), CanNodeError> {
        self.send_frames(&[message.frame(values)?]).await
    }

    /// Sends one frame per row, `frame_period` apart on average (zero: as fast as
    /// the socket takes them, in bursts of 32 frames with a yield to other tasks
    /// after each). Returns the number of frames sent.
    ///
    /// Pacing follows an absolute schedule, so timer granularity (1 ms) causes
    /// short bursts but no drift in the average rate.
    pub async fn run<I>(
        &self,
        message: &CanMessage,
        rows: I,
        frame_period: Duration,
    ) -> Result<u64, CanNodeError>
    where
        I: IntoIterator,
        I::Item: AsRef<[f64]>,
    {
        if frame_period.is_zero() {
            return self.run_unpaced(message, rows).await;
        }
        let start = Instant::now();
        let mut sent: u64 = 0;
        for row in rows {
            self.send(message, row.as_ref()).await?;
            sent += 1;
            let due = start + frame_period.saturating_mul(u32::try_from(sent).unwrap_or(u32::MAX));
            if due > Instant::now() + MIN_SLEEP {
                tokio::time::sleep_until(due).await;
            } else if sent.is_multiple_of(FRAMES_PER_BURST as u64) {
                // Behind schedule: still let the other tasks in now and then.
                tokio::task::yield_now().await;
            }
        }
        Ok(sent)
    }

    /// [`Self::run`] without pacing. Reads no clock: under User-Mode Linux every
    /// reading is a system call.
    async fn run_unpaced<I>(&self, message: &CanMessage, rows: I) -> Result<u64, CanNodeError>
    where
        I: IntoIterator,
        I::Item: AsRef<[f64]>,
    {
        let mut burst = Vec::with_capacity(FRAMES_PER_BURST);
        let mut sent: u64 = 0;
        let mut rows = rows.into_iter().peekable();
        while rows.peek().is_some() {
            burst.clear();
            for row in rows.by_ref().take(FRAMES_PER_BURST) {
                burst.push(message.frame(row.as_ref())?);
            }
            self.send_frames(&burst).await?;
            sent += burst.len() as u64;
            tokio::task::yield_now().await;
        }
        Ok(sent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_config::frame::{parse_frame, CANFD_MTU, CAN_MTU};

    fn signal(frame_id: u32, extended: bool, frame_len: u8, start_bit: u16) -> SignalLayout {
        SignalLayout {
            frame_id,
            extended,
            frame_len,
            start_bit,
            size: 16,
            little_endian: true,
            signed: true,
            factor: 0.001,
            offset: 0.0,
        }
    }

    #[test]
    fn encodes_a_row_in_signal_order() {
        let message = CanMessage::new(vec![
            signal(0x200, false, 64, 8),
            signal(0x200, false, 64, 24),
        ])
        .expect("valid message");
        assert_eq!(message.len, 64);
        let data = message.encode(&[1.234, -0.5]).expect("two values");
        assert_eq!(&data[..5], &[0x00, 0xd2, 0x04, 0x0c, 0xfe]);
        assert!(data[5..].iter().all(|&byte| byte == 0));
    }

    #[test]
    fn picks_classic_or_fd_by_length() {
        for (id, extended, len, mtu) in [
            (0x101, false, 8, CAN_MTU),
            (0x18ff_5a01, true, 12, CANFD_MTU),
        ] {
            let message = CanMessage::new(vec![signal(id, extended, len, 0)]).expect("valid");
            let frame = message.frame(&[1.0]).expect("fits");
            assert_eq!(frame.as_bytes().len(), mtu);
            let parsed = parse_frame(frame.as_bytes()).expect("a raw frame");
            assert_eq!(
                (parsed.id, parsed.extended, parsed.data.len()),
                (id, extended, usize::from(len))
            );
        }
    }

    #[test]
    fn frame_length_covers_signals_beyond_the_declared_length() {
        let message = CanMessage::new(vec![signal(0x101, false, 2, 16)]).expect("valid");
        assert_eq!(message.len, 4);
    }

    #[test]
    fn rejects_bad_messages_and_rows() {
        assert!(matches!(
            CanMessage::new(Vec::new()),
            Err(CanNodeError::NoSignals)
        ));
        assert!(matches!(
            CanMessage::new(vec![
                signal(0x101, false, 8, 0),
                signal(0x102, false, 8, 16)
            ]),
            Err(CanNodeError::MixedIds {
                first: 0x101,
                other: 0x102
            })
        ));
        assert!(matches!(
            CanMessage::new(vec![signal(0x800, false, 8, 0)]),
            Err(CanNodeError::BadId { .. })
        ));
        assert!(matches!(
            CanMessage::new(vec![signal(0x101, false, 8, 512)]),
            Err(CanNodeError::TooLong { len: 66 })
        ));
        let message = CanMessage::new(vec![signal(0x101, false, 8, 0)]).expect("valid");
        assert!(matches!(
            message.encode(&[1.0, 2.0]),
            Err(CanNodeError::WrongValueCount {
                expected: 1,
                got: 2
            })
        ));
    }
}
