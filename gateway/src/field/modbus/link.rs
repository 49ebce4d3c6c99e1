//! A Modbus TCP connection with requests in flight: up to `in_flight` requests (FC 03
//! and 04 reads, FC 16 writes) sent before their answers came, the MBAP transaction id
//! pairing each answer with its request. The PLC writer writes the register map over
//! it, and a DAQ reader whose source sets `requests_in_flight` above 1 reads its
//! blocks over it.
//!
//! Why not tokio-modbus's client, which the readers use otherwise: its `Context::call`
//! sends one request and waits for its answer (0.17.0 also clears its read buffer
//! before every request), so a burst of requests costs a round trip each: a burst of
//! bites changes one register block per driveline (13 FC 16 requests at 128
//! drivelines), a DAQ's block channels fall due together (8 reads). The Modbus TCP
//! implementation guide (v1.0b) lets a client send several requests before their
//! answers on one connection, each with its own transaction id, as many as the server
//! takes (its `NumberMaxOfServerTransaction`); a server that takes one at a time reads
//! the next from the stream when it has answered the last. Not every device's stack
//! does that (pymodbus 3.16's server answers the first of several in one segment at
//! most), so requests in flight are a setting, 1 by default.
//!
//! Every answer is checked before it is used (its header, its unit, its function, its
//! echo or register count), so no answer a device sends can panic the caller; an
//! answer that does not match a request in flight ends the exchange (the connection
//! is out of step and must be made again).

use std::collections::VecDeque;
use std::time::Duration;

use millgate_config::RegisterTable;
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio_modbus::prelude::ExceptionCode;

use super::client;
use super::error::{ModbusError, ReplyMismatch};

/// Bytes of the MBAP header: transaction id, protocol id, length, unit id.
const MBAP_HEADER_LEN: usize = 7;
/// Largest MBAP length field of an answer: the unit id and a 253-byte PDU.
const MAX_MBAP_LENGTH: u16 = 254;
/// Bytes of the largest request frame (an FC 16 of 123 registers).
const MAX_REQUEST_LEN: usize = MBAP_HEADER_LEN + 6 + 2 * MAX_WRITE;
/// FC 03, read holding registers.
const READ_HOLDING: u8 = 0x03;
/// FC 04, read input registers.
const READ_INPUT: u8 = 0x04;
/// FC 16, write multiple registers.
const WRITE_MULTIPLE: u8 = 0x10;
/// Most registers one FC 03 or 04 request reads.
const MAX_READ: u16 = 125;
/// Most registers one FC 16 request writes.
const MAX_WRITE: usize = 123;

/// One request of an [`TcpLink::exchange`].
#[derive(Debug, Clone, Copy)]
pub(crate) enum Request<'a> {
    /// Read `count` (at most 125) registers of a table from an address (FC 03 or 04).
    Read(RegisterTable, u16, u16),
    /// Write the words (at most 123) from an address (FC 16).
    Write(u16, &'a [u16]),
}

impl Request<'_> {
    /// The first register it names.
    fn address(&self) -> u16 {
        match *self {
            Request::Read(_, address, _) | Request::Write(address, _) => address,
        }
    }
}

/// A request's answer: a read's registers (none for a write), or the device's
/// refusal.
pub(crate) type Answer = Result<Vec<u16>, ExceptionCode>;

/// A Modbus TCP connection to one device (unit).
#[derive(Debug)]
pub(crate) struct TcpLink {
    stream: BufReader<TcpStream>,
    unit_id: u8,
    /// The transaction id of the next request.
    next_id: u16,
    /// How long an answer may take.
    timeout: Duration,
}

/// A request sent and not answered yet: its transaction id, function, first register,
/// register count and place in the exchange.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    id: u16,
    function: u8,
    address: u16,
    count: u16,
    index: usize,
}

fn io_error(source: std::io::Error) -> ModbusError {
    ModbusError::Transport(tokio_modbus::Error::Transport(source))
}

fn invalid(why: String) -> ModbusError {
    io_error(std::io::Error::new(std::io::ErrorKind::InvalidData, why))
}

impl TcpLink {
    /// Connect to `address` (`host:port`) within `timeout` and talk to `unit_id`,
    /// each answer awaited at most `timeout`.
    pub(crate) async fn connect(
        address: &str,
        unit_id: u8,
        timeout: Duration,
    ) -> Result<Self, ModbusError> {
        let stream = client::connect_tcp(address, timeout).await?;
        Ok(Self {
            stream: BufReader::with_capacity(8 * MAX_REQUEST_LEN, stream),
            unit_id,
            next_id: 0,
            timeout,
        })
    }

    /// Append the frame of `request` to `out`; returns what is in flight.
    fn frame(&mut self, out: &mut Vec<u8>, request: Request<'_>, index: usize) -> InFlight {
        let id = self.next_id;
        self.next_id = id.wrapping_add(1);
        let (function, address, count, words) = match request {
            Request::Read(RegisterTable::Holding, address, count) => {
                (READ_HOLDING, address, count.min(MAX_READ), &[][..])
            }
            Request::Read(RegisterTable::Input, address, count) => {
                (READ_INPUT, address, count.min(MAX_READ), &[][..])
            }
            Request::Write(address, words) => {
                let words = &words[..words.len().min(MAX_WRITE)];
                (WRITE_MULTIPLE, address, words.len() as u16, words)
            }
        };
        let data = if function == WRITE_MULTIPLE {
            1 + 2 * words.len()
        } else {
            0
        };
        let length = (1 + 5 + data) as u16;
        out.extend_from_slice(&id.to_be_bytes());
        out.extend_from_slice(&[0, 0]);
        out.extend_from_slice(&length.to_be_bytes());
        out.extend_from_slice(&[self.unit_id, function]);
        out.extend_from_slice(&address.to_be_bytes());
        out.extend_from_slice(&count.to_be_bytes());
        if function == WRITE_MULTIPLE {
            out.push((2 * words.len()) as u8);
            for word in words {
                out.extend_from_slice(&word.to_be_bytes());
            }
        }
        InFlight {
            id,
            function,
            address,
            count,
            index,
        }
    }

    async fn send(&mut self, bytes: &[u8]) -> Result<(), ModbusError> {
        let timeout = self.timeout;
        tokio::time::timeout(timeout, self.stream.get_mut().write_all(bytes))
            .await
            .map_err(|_| ModbusError::Timeout(timeout))?
            .map_err(io_error)
    }

    /// The next answer's frame, whole, within the timeout.
    async fn answer_frame(&mut self) -> Result<Vec<u8>, ModbusError> {
        let timeout = self.timeout;
        // Each answer acknowledged at once: a device whose stack holds small segments
        // until the last one is acknowledged (Nagle's algorithm, on by default in
        // many) sends the second answer of an exchange only then, and this end's
        // delayed ACK would wait up to 40 ms for data to ride on that, with requests
        // in flight, never comes (the load bench's virtual PLC: a write's answers
        // took 44 ms on the mean without this). The kernel leaves quick-ACK mode by
        // itself, so it is asked for before every answer.
        let _ = socket2::SockRef::from(self.stream.get_ref()).set_tcp_quickack(true);
        let read = async {
            let mut frame = vec![0; MBAP_HEADER_LEN];
            self.stream.read_exact(&mut frame).await.map_err(io_error)?;
            let protocol = u16::from_be_bytes([frame[2], frame[3]]);
            let length = u16::from_be_bytes([frame[4], frame[5]]);
            if protocol != 0 {
                return Err(invalid(format!(
                    "MBAP protocol id {protocol}, not 0 (Modbus)"
                )));
            }
            if !(2..=MAX_MBAP_LENGTH).contains(&length) {
                return Err(invalid(format!("MBAP length {length} outside 2..=254")));
            }
            frame.resize(6 + usize::from(length), 0);
            self.stream
                .read_exact(&mut frame[MBAP_HEADER_LEN..])
                .await
                .map_err(io_error)?;
            Ok(frame)
        };
        tokio::time::timeout(timeout, read)
            .await
            .map_err(|_| ModbusError::Timeout(timeout))?
    }

    /// The next answer, checked against the requests in `flight` (and taken off it),
    /// with the request it answers.
    async fn answer(
        &mut self,
        flight: &mut VecDeque<InFlight>,
    ) -> Result<(InFlight, Answer), ModbusError> {
        let frame = self.answer_frame().await?;
        let id = u16::from_be_bytes([frame[0], frame[1]]);
        let unit = frame[6];
        let at = flight
            .iter()
            .position(|request| request.id == id)
            .filter(|_| unit == self.unit_id)
            .ok_or(ReplyMismatch::Header { id, unit })?;
        let request = flight
            .remove(at)
            .unwrap_or_else(|| unreachable!("found above"));
        let pdu = &frame[MBAP_HEADER_LEN..];
        let answer = match *pdu {
            [function, code] if function == request.function | 0x80 => {
                Err(ExceptionCode::new(code))
            }
            [WRITE_MULTIPLE, a0, a1, c0, c1] if request.function == WRITE_MULTIPLE => {
                let (echoed_address, echoed_count) =
                    (u16::from_be_bytes([a0, a1]), u16::from_be_bytes([c0, c1]));
                if (echoed_address, echoed_count) != (request.address, request.count) {
                    return Err(ReplyMismatch::Echo {
                        address: request.address,
                        count: request.count,
                        echoed_address,
                        echoed_count,
                    }
                    .into());
                }
                Ok(Vec::new())
            }
            [function, bytes, ref data @ ..]
                if function == request.function && function != WRITE_MULTIPLE =>
            {
                if usize::from(bytes) != data.len() || data.len() != 2 * usize::from(request.count)
                {
                    return Err(ReplyMismatch::Registers {
                        requested: request.count,
                        answered: data.len() / 2,
                    }
                    .into());
                }
                Ok(data
                    .chunks_exact(2)
                    .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
                    .collect())
            }
            _ => return Err(ReplyMismatch::Function.into()),
        };
        Ok((request, answer))
    }

    /// Send `requests` in order, up to `in_flight` (at least 1) before their answers
    /// came, and give each one's answer, in the order of `requests`. With
    /// `stop_at_refusal`, no further request is sent once the device refused one (the
    /// answers of those in flight are still read, so the connection stays in step),
    /// and the answers end there. A transport error, a timeout or an answer that
    /// matches no request ends the exchange with that error.
    pub(crate) async fn exchange(
        &mut self,
        requests: &[Request<'_>],
        in_flight: usize,
        stop_at_refusal: bool,
    ) -> Result<Vec<Answer>, ModbusError> {
        let in_flight = in_flight.max(1);
        let mut flight = VecDeque::with_capacity(in_flight);
        let mut answers: Vec<Option<Answer>> = vec![None; requests.len()];
        let mut next = 0;
        let mut refused = false;
        let mut frames = Vec::with_capacity(in_flight.min(requests.len()) * MAX_REQUEST_LEN);
        loop {
            // Fill the window in one send.
            frames.clear();
            while !refused && flight.len() < in_flight && next < requests.len() {
                flight.push_back(self.frame(&mut frames, requests[next], next));
                next += 1;
            }
            if !frames.is_empty() {
                self.send(&frames).await?;
            }
            if flight.is_empty() {
                break;
            }
            let (request, answer) = self.answer(&mut flight).await?;
            refused |= stop_at_refusal && answer.is_err();
            answers[request.index] = Some(answer);
        }
        Ok(answers.into_iter().map_while(|answer| answer).collect())
    }

    /// Read `count` (at most 125) registers of `table` from `address` (FC 03 or 04).
    pub(crate) async fn read(
        &mut self,
        (table, address, count): (RegisterTable, u16, u16),
    ) -> Result<Vec<u16>, ModbusError> {
        let request = Request::Read(table, address, count);
        let answers = self.exchange(&[request], 1, false).await?;
        first_answer(&[request], answers)
    }

    /// Write each of `writes` (an address and at most 123 words) with FC 16, in order,
    /// up to `in_flight` requests sent before their answers came. When the device
    /// refuses one, no further request is sent, and the refusal is the error.
    pub(crate) async fn write(
        &mut self,
        writes: &[(u16, &[u16])],
        in_flight: usize,
    ) -> Result<(), ModbusError> {
        let requests: Vec<Request<'_>> = writes
            .iter()
            .map(|&(address, words)| Request::Write(address, words))
            .collect();
        let answers = self.exchange(&requests, in_flight, true).await?;
        match answers.iter().position(Result::is_err) {
            Some(at) => first_answer(&requests[at..], answers[at..].to_vec()).map(drop),
            None => Ok(()),
        }
    }
}

/// The first of `answers` (to `requests`) as a result: a refusal is the error naming
/// its request's first register.
fn first_answer(requests: &[Request<'_>], answers: Vec<Answer>) -> Result<Vec<u16>, ModbusError> {
    let (Some(request), Some(answer)) = (requests.first(), answers.into_iter().next()) else {
        return Err(ReplyMismatch::Function.into());
    };
    answer.map_err(|exception| ModbusError::Exception {
        address: request.address(),
        exception,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::net::TcpListener;

    /// A PLC on loopback that reads `expect` request bytes, then sends `answer` and
    /// keeps the connection open until the client hangs up.
    async fn plc(expect: usize, answer: Vec<u8>) -> String {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap().to_string();
        tokio::spawn(async move {
            let (mut socket, _) = listener.accept().await.unwrap();
            let mut request = vec![0; expect];
            socket.read_exact(&mut request).await.unwrap();
            socket.write_all(&answer).await.unwrap();
            let mut rest = Vec::new();
            let _ = socket.read_to_end(&mut rest).await;
        });
        address
    }

    /// A link (unit 1) to a PLC from [`plc`].
    async fn linked(expect: usize, answer: Vec<u8>) -> TcpLink {
        let address = plc(expect, answer).await;
        TcpLink::connect(&address, 1, Duration::from_secs(5))
            .await
            .unwrap()
    }

    /// The FC 16 answer frame of transaction `id`, unit 1.
    fn echo(id: u16, address: u16, count: u16) -> Vec<u8> {
        let mut frame = id.to_be_bytes().to_vec();
        frame.extend_from_slice(&[0, 0, 0, 6, 1, 0x10]);
        frame.extend_from_slice(&address.to_be_bytes());
        frame.extend_from_slice(&count.to_be_bytes());
        frame
    }

    /// Bytes of an FC 16 request of `count` registers.
    fn request_len(count: usize) -> usize {
        MBAP_HEADER_LEN + 6 + 2 * count
    }

    #[tokio::test]
    async fn answers_out_of_order_are_paired_by_their_transaction_ids() {
        let answer = [echo(1, 20, 2), echo(0, 10, 3)].concat();
        let mut link = linked(request_len(3) + request_len(2), answer).await;
        let writes: [(u16, &[u16]); 2] = [(10, &[1, 2, 3]), (20, &[4, 5])];
        link.write(&writes, 2).await.unwrap();
    }

    #[tokio::test]
    async fn a_wrong_echo_is_a_mismatch() {
        let mut link = linked(request_len(3), echo(0, 11, 3)).await;
        let writes: [(u16, &[u16]); 1] = [(10, &[1, 2, 3])];
        match link.write(&writes, 4).await {
            Err(ModbusError::Mismatch(ReplyMismatch::Echo { echoed_address, .. })) => {
                assert_eq!(echoed_address, 11)
            }
            other => panic!("expected an echo mismatch, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn an_answer_to_no_request_in_flight_ends_the_write() {
        let mut link = linked(request_len(1), echo(7, 10, 1)).await;
        let writes: [(u16, &[u16]); 1] = [(10, &[1])];
        let error = link.write(&writes, 1).await.unwrap_err();
        assert!(
            matches!(
                error,
                ModbusError::Mismatch(ReplyMismatch::Header { id: 7, unit: 1 })
            ),
            "{error:?}"
        );
        assert!(error.needs_reconnect());
    }

    #[tokio::test]
    async fn a_refusal_stops_the_sending_and_reads_the_answers_in_flight() {
        // Two requests in flight: the first refused (exception 02), the second
        // written; the third is never sent (the PLC reads two requests only).
        let mut refusal = 0u16.to_be_bytes().to_vec();
        refusal.extend_from_slice(&[0, 0, 0, 3, 1, 0x90, 0x02]);
        let answer = [refusal, echo(1, 20, 1)].concat();
        let mut link = linked(2 * request_len(1), answer).await;
        let writes: [(u16, &[u16]); 3] = [(10, &[1]), (20, &[2]), (30, &[3])];
        match link.write(&writes, 2).await {
            Err(ModbusError::Exception { address, exception }) => {
                assert_eq!(
                    (address, exception),
                    (10, ExceptionCode::IllegalDataAddress)
                );
            }
            other => panic!("expected the refusal, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn a_short_read_answer_is_a_mismatch_not_a_panic() {
        // FC 03 answer with 2 registers for 3 requested.
        let answer = vec![0, 0, 0, 0, 0, 7, 1, 3, 4, 0, 1, 0, 2];
        let mut link = linked(MBAP_HEADER_LEN + 5, answer).await;
        match link.read((RegisterTable::Holding, 0, 3)).await {
            Err(ModbusError::Mismatch(ReplyMismatch::Registers {
                requested: 3,
                answered: 2,
            })) => {}
            other => panic!("expected a mismatch, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn an_answer_that_is_not_modbus_tcp_is_a_transport_error() {
        // Protocol id 1.
        let mut link = linked(MBAP_HEADER_LEN + 5, vec![0, 0, 0, 1, 0, 3, 1, 3, 0]).await;
        let error = link.read((RegisterTable::Holding, 0, 1)).await.unwrap_err();
        assert!(matches!(error, ModbusError::Transport(_)), "{error:?}");
    }
}
