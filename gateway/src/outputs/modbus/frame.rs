//! Modbus TCP framing of the HMI server, written for the four function codes it
//! serves (03, 04, 06, 16): every field is checked before it is used, so no frame a
//! client sends can panic the server.
//!
//! Why not tokio-modbus's server: its request decoder (0.17.0, the latest release)
//! unpacks FC 15 coils without checking the byte count against the quantity (quantity
//! 16, byte count 0 panics: tokio-modbus issue #298), computes the FC 16 byte count as
//! `quantity * 2` in u16 (quantity >= 32768 overflows: a panic in debug builds), and
//! answers a malformed FC 16 by closing the connection instead of exception 03. A
//! filter in front of it would parse every frame twice and still leave the connection
//! handling (limits, idle time) to be wrapped; framing the four codes served takes
//! fewer lines than the filter would. Measured against it, this server answers as many
//! requests per second (`cargo bench -p millgate --bench hmi_server`).
//!
//! What a request gets, per the Modbus application protocol v1.1b3 and the TCP
//! implementation guide v1.0b:
//!
//! | request | answer |
//! |---|---|
//! | MBAP protocol id not 0, length < 2 or > 257 | no answer: the stream cannot be resynchronised, the connection is closed |
//! | unit 0 (broadcast) | no answer and no action, whatever the function: a broadcast write of a command over TCP is a misconfiguration, never acted on |
//! | a unit other than the server's and 255 | exception 0B (gateway target device failed to respond), as a Modbus gateway with nothing behind that unit, and pymodbus's server by default |
//! | FC 03 / 04, quantity 1..=125 | the registers, or exception 02 past the map |
//! | FC 03 / 04 with another quantity or PDU length | exception 03 |
//! | FC 06 / 16 on command registers | the echo, or 02 (not a command register), 03 (bad value) |
//! | FC 16, quantity 0 or > 123, byte count not 2 x quantity, PDU length not 6 + byte count | exception 03, connection kept |
//! | FC 06 / 16 from another host without `allow_remote_commands` | exception 01 |
//! | any other function code | exception 01 |

use std::sync::Arc;

use crate::outputs::modbus::register_map::{Access, Field, RegisterMap};
use crate::state::board::Board;
use crate::state::commands::{Command, CommandOrigin, CommandRefused, CommandSender};

/// Bytes of the MBAP header: transaction id, protocol id, length, unit id.
pub(crate) const MBAP_HEADER_LEN: usize = 7;
/// Largest MBAP length field accepted: the unit id and an FC 16 PDU of 125 registers
/// (257). The protocol's own limit is 254 (a 253-byte PDU); reading a little more
/// lets an FC 16 of 124 or 125 registers, over its 123-register limit, be answered
/// with exception 03 rather than by closing the connection.
pub(crate) const MAX_MBAP_LENGTH: usize = 257;
/// Largest Modbus TCP frame, bytes.
pub const MAX_FRAME_LEN: usize = 6 + MAX_MBAP_LENGTH;
/// Largest register count of one read request (FC 03 / 04).
pub(crate) const MAX_READ_REGISTERS: u16 = 125;
/// Largest register count of one FC 16 request.
pub const MAX_WRITE_REGISTERS: u16 = 123;
/// The unit id of a broadcast.
pub(crate) const BROADCAST_UNIT: u8 = 0;
/// The unit id a Modbus TCP device answers whatever its configured id (TCP guide).
pub(crate) const ANY_UNIT: u8 = 255;

/// A Modbus exception code the server answers with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exception {
    /// 01: the function is not served (or not allowed to this client).
    IllegalFunction = 0x01,
    /// 02: an address outside the map, or a write to a register that is not a command.
    IllegalDataAddress = 0x02,
    /// 03: a malformed request (quantity, byte count, length) or a bad command value.
    IllegalDataValue = 0x03,
    /// 04: the command cannot be carried out: the gateway is stopping.
    ServerDeviceFailure = 0x04,
    /// 06: the analysis has too many commands waiting; the client may try again.
    ServerDeviceBusy = 0x06,
    /// 0B: nothing answers behind this unit id.
    GatewayTargetFailedToRespond = 0x0B,
}

/// Why the bytes received cannot be Modbus TCP: the connection must be closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FramingError {
    /// The MBAP protocol id is not 0.
    #[error("MBAP protocol id {0}, not 0 (Modbus)")]
    ProtocolId(u16),
    /// The MBAP length field is outside 2..=257.
    #[error("MBAP length {0} outside 2..=257")]
    Length(u16),
}

/// The length of the frame at the start of `received`: `Ok(None)` while the header
/// or the body is incomplete, `Ok(Some(len))` once `received[..len]` is one whole
/// frame, an error when the header is not Modbus TCP.
pub fn frame_len(received: &[u8]) -> Result<Option<usize>, FramingError> {
    let Some(header) = received.get(..MBAP_HEADER_LEN) else {
        return Ok(None);
    };
    let protocol = u16::from_be_bytes([header[2], header[3]]);
    if protocol != 0 {
        return Err(FramingError::ProtocolId(protocol));
    }
    let length = u16::from_be_bytes([header[4], header[5]]);
    if !(2..=MAX_MBAP_LENGTH as u16).contains(&length) {
        return Err(FramingError::Length(length));
    }
    let len = 6 + usize::from(length);
    Ok((received.len() >= len).then_some(len))
}

/// Who sent a request and what the server allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Policy {
    /// The server's unit id (255 and it are answered).
    pub unit_id: u8,
    /// Whether this client may write command registers.
    pub commands_allowed: bool,
    /// Who the client is, as the history records its commands.
    pub origin: CommandOrigin,
}

/// What the server makes of one whole frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// Send these bytes back (a response or an exception).
    Send(Vec<u8>),
    /// A broadcast (unit 0): nothing is sent and nothing done.
    Broadcast,
}

impl Reply {
    /// The exception code of an exception reply.
    pub fn exception(&self) -> Option<u8> {
        match self {
            Reply::Send(bytes) => exception_code(bytes),
            Reply::Broadcast => None,
        }
    }
}

/// The exception code of a reply frame, `None` for a normal response.
pub(crate) fn exception_code(reply: &[u8]) -> Option<u8> {
    (reply.len() == MBAP_HEADER_LEN + 2 && reply[7] & 0x80 != 0).then(|| reply[8])
}

/// What the server answers from: its register map, the board the map encodes, and
/// where the command registers' writes go.
#[derive(Debug, Clone)]
pub struct Served {
    /// The register map served.
    pub map: Arc<RegisterMap>,
    /// The results it encodes.
    pub board: Arc<Board>,
    /// The analysis' commands.
    pub commands: CommandSender,
}

/// Answer one whole frame (`frame_len` said so) against the published map. Pure
/// apart from the commands sent to the analysis.
pub fn respond(served: &Served, policy: Policy, frame: &[u8]) -> Reply {
    let (header, pdu) = frame.split_at(MBAP_HEADER_LEN);
    let unit = header[6];
    if unit == BROADCAST_UNIT {
        return Reply::Broadcast;
    }
    let function = pdu[0];
    let answer = if unit != policy.unit_id && unit != ANY_UNIT {
        Err(Exception::GatewayTargetFailedToRespond)
    } else {
        answer(served, policy, function, &pdu[1..])
    };
    let body = match answer {
        Ok(data) => [&[function][..], &data].concat(),
        Err(exception) => vec![function | 0x80, exception as u8],
    };
    let mut reply = Vec::with_capacity(MBAP_HEADER_LEN + body.len());
    reply.extend_from_slice(&header[..4]);
    reply.extend_from_slice(&(body.len() as u16 + 1).to_be_bytes());
    reply.push(unit);
    reply.extend_from_slice(&body);
    Reply::Send(reply)
}

fn be(bytes: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([bytes[at], bytes[at + 1]])
}

/// The response data after the function code, or the exception.
fn answer(
    served: &Served,
    policy: Policy,
    function: u8,
    data: &[u8],
) -> Result<Vec<u8>, Exception> {
    match function {
        0x03 | 0x04 => {
            if data.len() != 4 {
                return Err(Exception::IllegalDataValue);
            }
            let (address, count) = (be(data, 0), be(data, 2));
            if count == 0 || count > MAX_READ_REGISTERS {
                return Err(Exception::IllegalDataValue);
            }
            let words = read(served, address, count)?;
            let mut response = vec![(2 * words.len()) as u8];
            response.extend(words.iter().flat_map(|word| word.to_be_bytes()));
            Ok(response)
        }
        0x06 => {
            if data.len() != 4 {
                return Err(Exception::IllegalDataValue);
            }
            if !policy.commands_allowed {
                return Err(Exception::IllegalFunction);
            }
            write(served, be(data, 0), &[be(data, 2)], policy.origin)?;
            Ok(data.to_vec())
        }
        0x10 => {
            if data.len() < 5 {
                return Err(Exception::IllegalDataValue);
            }
            let (address, count, byte_count) = (be(data, 0), be(data, 2), data[4]);
            if count == 0
                || count > MAX_WRITE_REGISTERS
                || usize::from(byte_count) != 2 * usize::from(count)
                || data.len() != 5 + usize::from(byte_count)
            {
                return Err(Exception::IllegalDataValue);
            }
            if !policy.commands_allowed {
                return Err(Exception::IllegalFunction);
            }
            let values: Vec<u16> = data[5..].chunks_exact(2).map(|w| be(w, 0)).collect();
            write(served, address, &values, policy.origin)?;
            Ok(data[..4].to_vec())
        }
        _ => Err(Exception::IllegalFunction),
    }
}

fn read(served: &Served, address: u16, count: u16) -> Result<Vec<u16>, Exception> {
    let words = served.map.encode(&served.board.results());
    let start = usize::from(address);
    words
        .get(start..start + usize::from(count))
        .map(<[u16]>::to_vec)
        .ok_or(Exception::IllegalDataAddress)
}

fn write(
    served: &Served,
    address: u16,
    values: &[u16],
    origin: CommandOrigin,
) -> Result<(), Exception> {
    let mut writes = Vec::with_capacity(values.len());
    for (offset, &value) in values.iter().enumerate() {
        let target = address
            .checked_add(offset as u16)
            .ok_or(Exception::IllegalDataAddress)?;
        match served.map.find(target) {
            Some(register) if register.access == Access::ReadWrite => {
                writes.push((register.field, value))
            }
            _ => return Err(Exception::IllegalDataAddress),
        }
    }
    // Validate every value before acting on any, so a rejected request changes nothing.
    let drivelines = served.board.driveline_names().len();
    let mills = served.board.results().tandem_mills.len();
    let components: Vec<usize> = served
        .board
        .fatigue_components()
        .iter()
        .map(Vec::len)
        .collect();
    let mut commands = Vec::new();
    for (field, value) in writes {
        if field == Field::ResetFatigue {
            commands.extend(reset_fatigue_of(value, &components, origin)?);
        } else {
            commands.extend(commands_of(field, value, (drivelines, mills), origin)?);
        }
    }
    for command in commands {
        served
            .commands
            .send(command)
            .map_err(|refused| match refused {
                CommandRefused::Busy => Exception::ServerDeviceBusy,
                CommandRefused::Stopped => Exception::ServerDeviceFailure,
            })?;
    }
    Ok(())
}

/// The command a write of `value` to `command.reset_fatigue` gives when the
/// drivelines' fatigue ledgers have `components` components (0 without a ledger):
/// the high byte the component's number, the low byte the driveline's (both 1-based);
/// none for 0, exception 03 for a driveline or component that does not exist.
fn reset_fatigue_of(
    value: u16,
    components: &[usize],
    origin: CommandOrigin,
) -> Result<Option<Command>, Exception> {
    if value == 0 {
        return Ok(None);
    }
    let [component, driveline] = value.to_be_bytes().map(usize::from);
    match components.get(driveline.wrapping_sub(1)) {
        Some(&count) if (1..=count).contains(&component) => Ok(Some(Command::ResetFatigue {
            driveline: driveline - 1,
            component: component - 1,
            origin,
        })),
        _ => Err(Exception::IllegalDataValue),
    }
}

/// The commands a write of `value` to command register `field` gives in a map of
/// `drivelines` drivelines and `mills` tandem mills (none for 0), or exception 03 for a
/// value it does not take.
fn commands_of(
    field: Field,
    value: u16,
    (drivelines, mills): (usize, usize),
    origin: CommandOrigin,
) -> Result<Vec<Command>, Exception> {
    match field {
        Field::AcknowledgeAlarms => match value {
            0 => Ok(Vec::new()),
            1 => Ok(vec![Command::AcknowledgeAlarms { origin }]),
            _ => Err(Exception::IllegalDataValue),
        },
        Field::ResetWearTrend => {
            let all = if drivelines >= 16 {
                u16::MAX
            } else {
                (1u16 << drivelines) - 1
            };
            if value & !all != 0 {
                return Err(Exception::IllegalDataValue);
            }
            Ok((0..16)
                .filter(|k| value & (1 << k) != 0)
                .map(|driveline| Command::ResetWear { driveline, origin })
                .collect())
        }
        Field::ResetWear => match usize::from(value) {
            0 => Ok(Vec::new()),
            number if number <= drivelines => Ok(vec![Command::ResetWear {
                driveline: number - 1,
                origin,
            }]),
            _ => Err(Exception::IllegalDataValue),
        },
        Field::ManualCapture => {
            let [seconds, number] = value.to_be_bytes();
            let seconds = if seconds == 0 {
                MANUAL_CAPTURE_DEFAULT_S
            } else {
                u16::from(seconds)
            };
            match usize::from(number) {
                0 if value == 0 => Ok(Vec::new()),
                number if (1..=drivelines).contains(&number) => Ok(vec![Command::CaptureTorque {
                    driveline: number - 1,
                    seconds,
                    origin,
                }]),
                // After the drivelines, the tandem mills: their stands.
                number if (drivelines + 1..=drivelines + mills).contains(&number) => {
                    Ok(vec![Command::CaptureStands {
                        mill: number - drivelines - 1,
                        seconds,
                        origin,
                    }])
                }
                _ => Err(Exception::IllegalDataValue),
            }
        }
        _ => Err(Exception::IllegalDataAddress),
    }
}

/// Seconds of a manual capture whose command leaves them 0.
pub(crate) const MANUAL_CAPTURE_DEFAULT_S: u16 = 10;

#[cfg(test)]
mod tests {
    use super::*;

    fn demo_config() -> millgate_config::Config {
        millgate_config::from_toml_str(
            include_str!("../../../../config/examples/demo.toml"),
            "demo.toml",
            // The demo's driveline model is named relative to the examples folder.
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples")),
        )
        .unwrap()
    }

    fn board() -> Arc<Board> {
        let config = demo_config();
        let health = vec![Arc::new(crate::field::source_health::SourceHealth::new(
            std::time::Duration::from_secs(1),
            std::time::Duration::from_secs(5),
        ))];
        Arc::new(Board::new(&config, health))
    }

    /// What a server of the demo's map answers from, and the analysis' end of its
    /// commands.
    fn served() -> (Served, crate::state::commands::CommandReceiver) {
        let board = board();
        let map = Arc::new(RegisterMap::new(&demo_config()));
        let (commands, receiver) = crate::state::commands::channel();
        let served = Served {
            map,
            board,
            commands,
        };
        (served, receiver)
    }

    const POLICY: Policy = Policy {
        unit_id: 1,
        commands_allowed: true,
        origin: CommandOrigin::Local,
    };

    /// A frame with transaction id 0x1234 for `unit` carrying `pdu`.
    fn frame(unit: u8, pdu: &[u8]) -> Vec<u8> {
        let mut frame = vec![0x12, 0x34, 0, 0];
        frame.extend(((pdu.len() + 1) as u16).to_be_bytes());
        frame.push(unit);
        frame.extend_from_slice(pdu);
        frame
    }

    fn reply(frame: &[u8]) -> Reply {
        assert_eq!(frame_len(frame), Ok(Some(frame.len())));
        respond(&served().0, POLICY, frame)
    }

    #[test]
    fn fc15_quantity_16_byte_count_0_is_exception_01_not_a_panic() {
        // 00 01 00 00 00 07 01 0f 00 00 00 10 00: the frame that panicked tokio-modbus.
        let bytes = [
            0x00, 0x01, 0x00, 0x00, 0x00, 0x07, 0x01, 0x0f, 0x00, 0x00, 0x00, 0x10, 0x00,
        ];
        assert_eq!(
            reply(&bytes),
            Reply::Send(vec![0x00, 0x01, 0, 0, 0, 3, 1, 0x8f, 0x01])
        );
    }

    #[test]
    fn malformed_fc16_is_exception_03() {
        let acknowledge = [0x00, 0x08];
        for pdu in [
            // quantity 0, byte count 0
            vec![0x10, 0x00, 0x08, 0x00, 0x00, 0x00],
            // quantity 124
            [&[0x10, 0x00, 0x08, 0x00, 124, 248][..], &[0u8; 248]].concat(),
            // byte count 4 for quantity 1
            vec![0x10, 0x00, 0x08, 0x00, 0x01, 0x04, 0x00, 0x01, 0x00, 0x00],
            // byte count 2 but 4 data bytes
            vec![0x10, 0x00, 0x08, 0x00, 0x01, 0x02, 0x00, 0x01, 0x00, 0x00],
            // quantity 0x8000 (overflowed tokio-modbus's u16 byte count)
            vec![0x10, 0x00, 0x08, 0x80, 0x00, 0x00],
            // truncated
            vec![0x10, 0x00],
        ] {
            assert_eq!(reply(&frame(1, &pdu)).exception(), Some(0x03), "{pdu:02x?}");
        }
        // The well-formed write is acknowledged.
        let good = [&[0x10][..], &acknowledge, &[0x00, 0x01, 0x02, 0x00, 0x01]].concat();
        assert_eq!(
            reply(&frame(1, &good)),
            Reply::Send(frame(1, &[0x10, 0x00, 0x08, 0x00, 0x01]))
        );
    }

    #[test]
    fn unit_ids_broadcast_and_others() {
        let read = [0x03, 0x00, 0x00, 0x00, 0x01];
        assert_eq!(reply(&frame(0, &read)), Reply::Broadcast);
        // A broadcast acknowledge is not acted on.
        let (served, mut commands) = served();
        let ack = frame(0, &[0x06, 0x00, 0x08, 0x00, 0x01]);
        assert_eq!(respond(&served, POLICY, &ack), Reply::Broadcast);
        assert!(commands.try_recv().is_err(), "broadcast ignored");
        assert_eq!(reply(&frame(7, &read)).exception(), Some(0x0B));
        assert_eq!(reply(&frame(255, &read)).exception(), None);
        assert_eq!(reply(&frame(1, &read)).exception(), None);
    }

    #[test]
    fn reads_and_their_limits() {
        let Reply::Send(bytes) = reply(&frame(1, &[0x04, 0x00, 0x00, 0x00, 0x02])) else {
            panic!("a reply");
        };
        assert_eq!(&bytes[..9], &[0x12, 0x34, 0, 0, 0, 7, 1, 0x04, 4]);
        for pdu in [
            vec![0x03, 0x00, 0x00, 0x00, 0x00],
            vec![0x03, 0x00, 0x00, 0x00, 126],
            vec![0x03, 0x00, 0x00, 0x00],
            vec![0x03, 0x00, 0x00, 0x00, 0x01, 0x00],
        ] {
            assert_eq!(reply(&frame(1, &pdu)).exception(), Some(0x03), "{pdu:02x?}");
        }
        assert_eq!(
            reply(&frame(1, &[0x03, 0xff, 0xff, 0x00, 0x02])).exception(),
            Some(0x02)
        );
        assert_eq!(
            reply(&frame(1, &[0x01, 0, 0, 0, 1])).exception(),
            Some(0x01)
        );
        assert_eq!(reply(&frame(1, &[0x81])).exception(), Some(0x01));
    }

    #[test]
    fn commands_from_clients_not_allowed_are_exception_01() {
        let (served, mut commands) = served();
        let remote = Policy {
            unit_id: 1,
            commands_allowed: false,
            origin: CommandOrigin::Local,
        };
        let ack = frame(1, &[0x06, 0x00, 0x08, 0x00, 0x01]);
        assert_eq!(respond(&served, remote, &ack).exception(), Some(0x01));
        assert!(commands.try_recv().is_err(), "no command sent");
        // Reads are served.
        let read = frame(1, &[0x03, 0x00, 0x00, 0x00, 0x01]);
        assert_eq!(respond(&served, remote, &read).exception(), None);
    }

    #[test]
    fn a_fatigue_reset_names_a_component_of_a_driveline_with_a_ledger() {
        let origin = CommandOrigin::Local;
        // Driveline 1 without a ledger, driveline 2 with three components.
        let reset = |value| reset_fatigue_of(value, &[0, 3], origin);
        assert_eq!(reset(0), Ok(None));
        assert_eq!(
            reset(0x0302),
            Ok(Some(Command::ResetFatigue {
                driveline: 1,
                component: 2,
                origin
            }))
        );
        for refused in [0x0101, 0x0402, 0x0002, 0x0103, 0x0100] {
            assert_eq!(
                reset(refused),
                Err(Exception::IllegalDataValue),
                "{refused:#06x}"
            );
        }
    }

    #[test]
    fn a_manual_capture_past_the_drivelines_numbers_a_tandem_mill() {
        let origin = CommandOrigin::Local;
        let capture = |value| commands_of(Field::ManualCapture, value, (1, 2), origin);
        assert_eq!(
            capture(0x0302),
            Ok(vec![Command::CaptureStands {
                mill: 0,
                seconds: 3,
                origin
            }])
        );
        assert_eq!(
            capture(0x0003),
            Ok(vec![Command::CaptureStands {
                mill: 1,
                seconds: MANUAL_CAPTURE_DEFAULT_S,
                origin
            }])
        );
        assert_eq!(capture(0x0304), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn command_writes_become_commands_in_order_or_exceptions() {
        let (served, mut commands) = served();
        // Acknowledge (8), the bitmask reset of driveline 1 (9), the numbered reset of
        // driveline 1 (10) in one FC 16.
        let write = frame(1, &[0x10, 0x00, 0x08, 0x00, 0x03, 0x06, 0, 1, 0, 1, 0, 1]);
        assert_eq!(respond(&served, POLICY, &write).exception(), None);
        let origin = CommandOrigin::Local;
        let mut received = Vec::new();
        while let Ok(command) = commands.try_recv() {
            received.push(command);
        }
        assert_eq!(
            received,
            [
                Command::AcknowledgeAlarms { origin },
                Command::ResetWear {
                    driveline: 0,
                    origin
                },
                Command::ResetWear {
                    driveline: 0,
                    origin
                },
            ]
        );
        // A manual capture (11): 3 s of driveline 1; the high byte 0 is 10 s.
        for (pdu, seconds) in [
            ([0x06, 0x00, 0x0B, 0x03, 0x01], 3),
            ([0x06, 0x00, 0x0B, 0x00, 0x01], MANUAL_CAPTURE_DEFAULT_S),
        ] {
            assert_eq!(respond(&served, POLICY, &frame(1, &pdu)).exception(), None);
            assert_eq!(
                commands.try_recv().ok(),
                Some(Command::CaptureTorque {
                    driveline: 0,
                    seconds,
                    origin
                })
            );
        }
        // The demo has one driveline: number 2 and bit 1 do not exist, a capture needs
        // a driveline; nothing is sent.
        for pdu in [
            [0x06, 0x00, 0x0A, 0x00, 0x02],
            [0x06, 0x00, 0x09, 0x00, 0x02],
            [0x06, 0x00, 0x08, 0x00, 0x02],
            [0x06, 0x00, 0x0B, 0x00, 0x02],
            [0x06, 0x00, 0x0B, 0x05, 0x00],
        ] {
            assert_eq!(
                respond(&served, POLICY, &frame(1, &pdu)).exception(),
                Some(0x03)
            );
        }
        assert!(commands.try_recv().is_err());
        // A full queue is "busy" (06), a stopped analysis "failure" (04).
        let ack = frame(1, &[0x06, 0x00, 0x08, 0x00, 0x01]);
        for _ in 0..crate::state::commands::COMMAND_QUEUE {
            assert_eq!(respond(&served, POLICY, &ack).exception(), None);
        }
        assert_eq!(respond(&served, POLICY, &ack).exception(), Some(0x06));
        drop(commands);
        assert_eq!(respond(&served, POLICY, &ack).exception(), Some(0x04));
    }

    #[test]
    fn framing_waits_for_whole_frames_and_refuses_what_is_not_modbus() {
        let whole = frame(1, &[0x03, 0x00, 0x00, 0x00, 0x01]);
        for cut in 0..whole.len() {
            assert_eq!(frame_len(&whole[..cut]), Ok(None), "{cut} bytes");
        }
        let two = [whole.clone(), whole.clone()].concat();
        assert_eq!(frame_len(&two), Ok(Some(whole.len())));
        assert_eq!(
            frame_len(b"GET / HTTP/1.1\r\n"),
            Err(FramingError::ProtocolId(0x5420))
        );
        assert_eq!(
            frame_len(&[0, 1, 0, 0, 0, 1, 1]),
            Err(FramingError::Length(1))
        );
        assert_eq!(
            frame_len(&[0, 1, 0, 0, 1, 2, 1]),
            Err(FramingError::Length(258))
        );
    }
}
