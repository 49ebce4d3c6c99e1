//! Raw SocketCAN frames: the bytes a `CAN_RAW` socket reads and writes.
//!
//! A read or write is one `struct can_frame` ([`CAN_MTU`] bytes, up to 8 payload
//! bytes) or `struct canfd_frame` ([`CANFD_MTU`] bytes, up to 64), in native byte
//! order (linux/can.h): `can_id` (identifier plus the extended, remote and error
//! flags), the payload length, flags and reserved bytes, then the payload from byte
//! 8. The gateway parses what it reads with [`parse_frame`]; the simulator's CAN node
//! lays out what it writes with [`data_frame`].

/// Size of a classic CAN frame on a raw socket (`struct can_frame`), bytes.
pub const CAN_MTU: usize = 16;
/// Size of a CAN FD frame on a raw socket (`struct canfd_frame`), bytes.
pub const CANFD_MTU: usize = 72;
/// `can_id` flag bits and masks (linux/can.h).
const CAN_EFF_FLAG: u32 = 0x8000_0000;
const CAN_RTR_FLAG: u32 = 0x4000_0000;
const CAN_ERR_FLAG: u32 = 0x2000_0000;
const CAN_EFF_MASK: u32 = 0x1fff_ffff;
const CAN_SFF_MASK: u32 = 0x0000_07ff;

/// What a raw CAN socket frame is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// A data frame (classic or FD).
    Data,
    /// A remote transmission request.
    Remote,
    /// An error frame reported by the controller; its id holds the error class bits.
    Error,
}

/// A frame as read from a raw CAN socket, borrowed from the read buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawFrame<'a> {
    /// Data, remote or error frame.
    pub kind: FrameKind,
    /// Identifier (11 or 29 bits) for data and remote frames; error class bits for
    /// error frames.
    pub id: u32,
    /// 29-bit identifier.
    pub extended: bool,
    /// Payload: `len` bytes (at most 8 for classic, 64 for FD frames).
    pub data: &'a [u8],
}

/// Parses the bytes of one read from a raw CAN socket: a `struct can_frame`
/// ([`CAN_MTU`] bytes) or `struct canfd_frame` ([`CANFD_MTU`] bytes), native byte
/// order. `None` for any other length.
///
/// ```
/// use millgate_config::frame::{parse_frame, FrameKind};
/// let mut bytes = [0u8; 16];
/// bytes[..4].copy_from_slice(&0x101u32.to_ne_bytes());
/// bytes[4] = 2;
/// bytes[8..10].copy_from_slice(&[0x39, 0x30]);
/// let frame = parse_frame(&bytes).unwrap();
/// assert_eq!((frame.kind, frame.id, frame.extended), (FrameKind::Data, 0x101, false));
/// assert_eq!(frame.data, &[0x39, 0x30]);
/// ```
pub fn parse_frame(bytes: &[u8]) -> Option<RawFrame<'_>> {
    let max_len = match bytes.len() {
        CAN_MTU => 8,
        CANFD_MTU => 64,
        _ => return None,
    };
    let can_id = u32::from_ne_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    let len = usize::from(bytes[4]).min(max_len);
    let data = &bytes[8..8 + len];
    let extended = can_id & CAN_EFF_FLAG != 0;
    let (kind, id) = if can_id & CAN_ERR_FLAG != 0 {
        (FrameKind::Error, can_id & CAN_EFF_MASK)
    } else {
        let mask = if extended { CAN_EFF_MASK } else { CAN_SFF_MASK };
        let kind = if can_id & CAN_RTR_FLAG != 0 {
            FrameKind::Remote
        } else {
            FrameKind::Data
        };
        (kind, can_id & mask)
    };
    Some(RawFrame {
        kind,
        id,
        extended,
        data,
    })
}

/// A data frame laid out for a write to a raw CAN socket.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameBytes {
    bytes: [u8; CANFD_MTU],
    len: usize,
}

impl FrameBytes {
    /// The bytes to write: [`CAN_MTU`] of them for a classic frame, [`CANFD_MTU`]
    /// for an FD frame.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or_default()
    }
}

/// Lays out a data frame with identifier `id` (29-bit if `extended`) and payload
/// `data`: classic CAN for up to 8 bytes, CAN FD above. `None` when the identifier
/// does not fit its format or the payload exceeds 64 bytes.
///
/// ```
/// use millgate_config::frame::{data_frame, parse_frame, FrameKind, CAN_MTU};
/// let frame = data_frame(0x101, false, &[0x39, 0x30]).unwrap();
/// assert_eq!(frame.as_bytes().len(), CAN_MTU);
/// let parsed = parse_frame(frame.as_bytes()).unwrap();
/// assert_eq!((parsed.kind, parsed.id, parsed.data), (FrameKind::Data, 0x101, &[0x39, 0x30][..]));
/// ```
pub fn data_frame(id: u32, extended: bool, data: &[u8]) -> Option<FrameBytes> {
    let (mask, flag) = if extended {
        (CAN_EFF_MASK, CAN_EFF_FLAG)
    } else {
        (CAN_SFF_MASK, 0)
    };
    if id & !mask != 0 {
        return None;
    }
    let len = if data.len() <= 8 {
        CAN_MTU
    } else if data.len() <= 64 {
        CANFD_MTU
    } else {
        return None;
    };
    let mut bytes = [0; CANFD_MTU];
    bytes[..4].copy_from_slice(&(id | flag).to_ne_bytes());
    bytes[4] = u8::try_from(data.len()).ok()?;
    bytes[8..8 + data.len()].copy_from_slice(data);
    Some(FrameBytes { bytes, len })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A raw frame as the kernel lays it out: can_id (native endian), len, flags,
    /// two reserved bytes, data.
    fn raw(can_id: u32, len: u8, data: &[u8], mtu: usize) -> Vec<u8> {
        let mut bytes = vec![0u8; mtu];
        bytes[..4].copy_from_slice(&can_id.to_ne_bytes());
        bytes[4] = len;
        bytes[8..8 + data.len()].copy_from_slice(data);
        bytes
    }

    #[test]
    fn raw_frames_parse_by_kind() {
        let classic = raw(0x101, 4, &[1, 2, 3, 4], CAN_MTU);
        let frame = parse_frame(&classic).unwrap();
        assert_eq!(
            (frame.kind, frame.id, frame.extended, frame.data),
            (FrameKind::Data, 0x101, false, &[1u8, 2, 3, 4][..])
        );
        let extended = raw(0x18ff_5a01 | CAN_EFF_FLAG, 2, &[0x1d, 0x04], CAN_MTU);
        let frame = parse_frame(&extended).unwrap();
        assert_eq!((frame.id, frame.extended), (0x18ff_5a01, true));
        let remote = raw(0x101 | CAN_RTR_FLAG, 0, &[], CAN_MTU);
        assert_eq!(parse_frame(&remote).unwrap().kind, FrameKind::Remote);
        let error = raw(
            0x44 | CAN_ERR_FLAG,
            8,
            &[0, 0x10, 0, 0, 0, 0, 0, 0],
            CAN_MTU,
        );
        let frame = parse_frame(&error).unwrap();
        assert_eq!((frame.kind, frame.id), (FrameKind::Error, 0x44));
        assert_eq!(frame.data, &[0, 0x10, 0, 0, 0, 0, 0, 0]);
        let fd = raw(0x102, 64, &[7; 64], CANFD_MTU);
        assert_eq!(parse_frame(&fd).unwrap().data, &[7u8; 64][..]);
        // A length byte beyond the frame's capacity is clamped, never read past.
        let bogus = raw(0x101, 200, &[], CAN_MTU);
        assert_eq!(parse_frame(&bogus).unwrap().data.len(), 8);
        assert_eq!(parse_frame(&classic[..15]), None);
    }

    #[test]
    fn data_frames_parse_back() {
        let fd_payload: Vec<u8> = (0..64).collect();
        for (id, extended, data) in [
            (0x7ff, false, &[][..]),
            (0x101, false, &[1, 2, 3, 4, 5, 6, 7, 8][..]),
            (0x1abc_def0, true, &[9][..]),
            (0x200, false, &fd_payload[..9]),
            (0x1fff_ffff, true, &fd_payload[..]),
        ] {
            let frame = data_frame(id, extended, data).expect("valid frame");
            let expected_len = if data.len() <= 8 { CAN_MTU } else { CANFD_MTU };
            assert_eq!(frame.as_bytes().len(), expected_len, "{id:#x}");
            let parsed = parse_frame(frame.as_bytes()).expect("parses");
            assert_eq!(
                parsed,
                RawFrame {
                    kind: FrameKind::Data,
                    id,
                    extended,
                    data,
                }
            );
        }
    }

    #[test]
    fn data_frame_refuses_what_cannot_be_sent() {
        assert_eq!(data_frame(0x800, false, &[]), None, "12-bit standard id");
        assert_eq!(
            data_frame(0x2000_0000, true, &[]),
            None,
            "30-bit extended id"
        );
        assert_eq!(data_frame(0x100, false, &[0; 65]), None, "65 bytes");
    }
}
