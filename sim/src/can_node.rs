//! A virtual CAN node: puts simulated channel values onto a SocketCAN interface.
//!
//! A [`CanMessage`] is one DBC message seen as a list of [`SignalLayout`]s; it encodes
//! a row of engineering values into frame bytes ([`SignalLayout::encode`]). A
//! [`CanNode`] owns a CAN FD capable raw socket and sends such rows, one frame each,
//! classic CAN for messages of up to 8 bytes and CAN FD above, optionally paced at a
//! fixed frame period.

use std::io;
use std::time::Duration;

use millgate_config::signal::{FrameTooShort, SignalLayout};
use socketcan::{CanAnyFrame, CanDataFrame, CanFdFrame, EmbeddedFrame, ExtendedId, Id, StandardId};
use tokio::time::Instant;

/// `errno` EAFNOSUPPORT: the kernel has no SocketCAN.
const EAFNOSUPPORT: i32 = 97;
/// `errno` ENOBUFS: the interface's transmit queue is full.
const ENOBUFS: i32 = 105;
/// Wait between retries of a write refused with ENOBUFS.
const TX_QUEUE_FULL_BACKOFF: Duration = Duration::from_millis(1);
/// Retries of one write refused with ENOBUFS before giving up (about 1 s).
const TX_QUEUE_FULL_RETRIES: u32 = 1000;
/// Largest payload of a classic CAN frame, bytes.
const CLASSIC_MAX_LEN: usize = 8;
/// Largest payload of a CAN FD frame, bytes.
const FD_MAX_LEN: usize = 64;
/// Sleep only when this far ahead of the pacing schedule (tokio timers tick in ms).
const MIN_SLEEP: Duration = Duration::from_millis(1);
/// Frames sent back to back before yielding to other tasks when not sleeping: enough
/// to save scheduler round trips, few enough for a receive buffer (~200 frames).
const FRAMES_PER_YIELD: u64 = 32;

/// Why a virtual CAN node could not build or send a frame.
#[derive(Debug, thiserror::Error)]
pub enum CanNodeError {
    /// A message needs at least one signal.
    #[error("a CAN message needs at least one signal")]
    NoSignals,
    /// The signals given for one message do not share one frame id.
    #[error("signals of one CAN message must share its id: {first:#x} and {other:#x}")]
    MixedIds { first: u32, other: u32 },
    /// The identifier does not fit its format (11 or 29 bits).
    #[error("CAN id {frame_id:#x} does not fit a {} identifier", if *.extended { "29-bit" } else { "11-bit" })]
    BadId { frame_id: u32, extended: bool },
    /// Frame length beyond CAN FD's 64 bytes.
    #[error("CAN frame length {len} bytes exceeds 64")]
    TooLong { len: usize },
    /// A row does not have one value per signal.
    #[error("expected {expected} values for the message, got {got}")]
    WrongValueCount { expected: usize, got: usize },
    /// A signal lies beyond the message length.
    #[error(transparent)]
    FrameTooShort(#[from] FrameTooShort),
    /// The interface could not be opened.
    #[error("cannot open CAN interface `{interface}`: {source}{}", if source.raw_os_error() == Some(EAFNOSUPPORT) { " (SocketCAN not available in this kernel; run scripts/uml-vcan)" } else { "" })]
    Open {
        interface: String,
        #[source]
        source: io::Error,
    },
    /// Sending a frame failed.
    #[error("writing to CAN interface `{interface}`: {source}")]
    Write {
        interface: String,
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

    /// Frame payload length, bytes (0..=64).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True for a message without payload bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
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
    pub fn frame(&self, values: &[f64]) -> Result<CanAnyFrame, CanNodeError> {
        let data = self.encode(values)?;
        build_frame(self.frame_id, self.extended, &data)
    }
}

/// A frame with this id and payload: classic CAN up to 8 bytes, CAN FD above.
///
/// Also used by tests to send frames no DBC describes (unknown ids, short frames).
pub fn build_frame(
    frame_id: u32,
    extended: bool,
    data: &[u8],
) -> Result<CanAnyFrame, CanNodeError> {
    let id = frame_identifier(frame_id, extended)?;
    let frame = if data.len() <= CLASSIC_MAX_LEN {
        CanDataFrame::new(id, data).map(CanAnyFrame::Normal)
    } else {
        CanFdFrame::new(id, data).map(CanAnyFrame::Fd)
    };
    frame.ok_or(CanNodeError::TooLong { len: data.len() })
}

fn frame_identifier(frame_id: u32, extended: bool) -> Result<Id, CanNodeError> {
    let id = if extended {
        ExtendedId::new(frame_id).map(Id::Extended)
    } else {
        u16::try_from(frame_id)
            .ok()
            .and_then(StandardId::new)
            .map(Id::Standard)
    };
    id.ok_or(CanNodeError::BadId { frame_id, extended })
}

/// A simulated CAN device on one SocketCAN interface.
#[derive(Debug)]
pub struct CanNode {
    interface: String,
    socket: socketcan::tokio::CanFdSocket,
}

impl CanNode {
    /// Opens `interface` (e.g. `vcan0`) for sending classic and FD frames.
    pub fn open(interface: &str) -> Result<CanNode, CanNodeError> {
        let socket = socketcan::tokio::CanFdSocket::open(interface).map_err(|source| {
            CanNodeError::Open {
                interface: interface.to_owned(),
                source,
            }
        })?;
        Ok(CanNode {
            interface: interface.to_owned(),
            socket,
        })
    }

    /// Sends one frame, waiting out a full transmit queue (ENOBUFS) for up to ~1 s.
    pub async fn send_frame(&self, frame: &CanAnyFrame) -> Result<(), CanNodeError> {
        let mut retries = 0;
        loop {
            match self.socket.write_frame(frame).await {
                Ok(()) => return Ok(()),
                Err(error)
                    if error.raw_os_error() == Some(ENOBUFS) && retries < TX_QUEUE_FULL_RETRIES =>
                {
                    retries += 1;
                    tokio::time::sleep(TX_QUEUE_FULL_BACKOFF).await;
                }
                Err(source) => {
                    return Err(CanNodeError::Write {
                        interface: self.interface.clone(),
                        source,
                    })
                }
            }
        }
    }

    /// Encodes `values` (one per signal of `message`) and sends the frame.
    pub async fn send(&self, message: &CanMessage, values: &[f64]) -> Result<(), CanNodeError> {
        self.send_frame(&message.frame(values)?).await
    }

    /// Sends one frame per row, `frame_period` apart on average (zero: as fast as
    /// the socket takes them, yielding to other tasks every 32 frames). Returns the
    /// number of frames sent.
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
        let start = Instant::now();
        let mut sent: u64 = 0;
        for row in rows {
            self.send(message, row.as_ref()).await?;
            sent += 1;
            let due = start + frame_period.saturating_mul(u32::try_from(sent).unwrap_or(u32::MAX));
            let now = Instant::now();
            if due > now + MIN_SLEEP {
                tokio::time::sleep_until(due).await;
            } else if sent.is_multiple_of(FRAMES_PER_YIELD) {
                tokio::task::yield_now().await;
            }
        }
        Ok(sent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use socketcan::Frame;

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
        assert_eq!(message.len(), 64);
        let data = message.encode(&[1.234, -0.5]).expect("two values");
        assert_eq!(&data[..5], &[0x00, 0xd2, 0x04, 0x0c, 0xfe]);
        assert!(data[5..].iter().all(|&byte| byte == 0));
    }

    #[test]
    fn picks_classic_or_fd_by_length() {
        let classic = CanMessage::new(vec![signal(0x101, false, 8, 0)]).expect("valid");
        match classic.frame(&[1.0]).expect("fits") {
            CanAnyFrame::Normal(frame) => {
                assert_eq!(frame.raw_id(), 0x101);
                assert_eq!(frame.data().len(), 8);
            }
            other => panic!("expected a classic frame, got {other:?}"),
        }
        let fd = CanMessage::new(vec![signal(0x18ff_5a01, true, 12, 0)]).expect("valid");
        match fd.frame(&[1.0]).expect("fits") {
            CanAnyFrame::Fd(frame) => {
                assert!(frame.is_extended());
                assert_eq!(frame.raw_id(), 0x18ff_5a01);
                assert_eq!(frame.data().len(), 12);
            }
            other => panic!("expected an FD frame, got {other:?}"),
        }
    }

    #[test]
    fn frame_length_covers_signals_beyond_the_declared_length() {
        let message = CanMessage::new(vec![signal(0x101, false, 2, 16)]).expect("valid");
        assert_eq!(message.len(), 4);
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
        assert!(matches!(
            build_frame(0x101, false, &[0; 65]),
            Err(CanNodeError::TooLong { len: 65 })
        ));
    }
}
