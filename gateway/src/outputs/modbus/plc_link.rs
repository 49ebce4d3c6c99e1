//! The PLC writer's Modbus TCP connection: FC 16 writes with up to `in_flight`
//! requests sent before their answers came (the MBAP transaction id pairs each answer
//! with its request), and the FC 03 read-back of the bite counters.
//!
//! Why not tokio-modbus's client, which the DAQ readers use: its `Context::call` sends
//! one request and waits for its answer (0.17.0 also clears its read buffer before
//! every request), so a write of many blocks costs a round trip to the PLC each. A
//! burst of bites changes one block per driveline (13 requests at 128 drivelines), and
//! their round trips one after the other were a bite's `write` stage. The Modbus TCP
//! implementation guide (v1.0b) lets a client send several requests before their
//! answers on one connection, each with its own transaction id, as many as the server
//! takes (its `NumberMaxOfServerTransaction`); a server that takes one at a time reads
//! the next from the stream when it has answered the last. Not every device's stack
//! does that, so `requests_in_flight` is a setting of the PLC output, 1 by default:
//! one request at a time, as tokio-modbus sends them.
//!
//! Every answer is checked before it is used (its header, its unit, its function, its
//! echo), so no answer a PLC sends can panic the writer; an answer that does not
//! match a request in flight ends the connection (it is out of step).

use std::collections::VecDeque;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio_modbus::prelude::ExceptionCode;

use super::frame::{frame_len, MAX_FRAME_LEN, MBAP_HEADER_LEN};
use crate::field::modbus::{client, ModbusError, ReplyMismatch};

/// FC 03, read holding registers.
const READ_HOLDING: u8 = 0x03;
/// FC 16, write multiple registers.
const WRITE_MULTIPLE: u8 = 0x10;
/// Most registers one FC 03 request reads.
const MAX_READ: u16 = 125;
/// Most registers one FC 16 request writes.
const MAX_WRITE: usize = 123;

/// One Modbus TCP connection to the PLC.
#[derive(Debug)]
pub(crate) struct PlcLink {
    stream: BufReader<TcpStream>,
    unit_id: u8,
    /// The transaction id of the next request.
    next_id: u16,
    /// How long an answer may take.
    timeout: Duration,
}

/// A request sent and not answered yet.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    id: u16,
    function: u8,
    address: u16,
    count: u16,
}

/// What an answer said: done (a write's echo, or a read's registers), or the PLC's
/// refusal.
enum Answer {
    Done(Vec<u16>),
    Refused(ExceptionCode),
}

fn io_error(source: std::io::Error) -> ModbusError {
    ModbusError::Transport(tokio_modbus::Error::Transport(source))
}

impl PlcLink {
    /// Connect to `address` (`host:port`) within `timeout` and talk to `unit_id`,
    /// each answer awaited at most `timeout`.
    pub(crate) async fn connect(
        address: &str,
        unit_id: u8,
        timeout: Duration,
    ) -> Result<Self, ModbusError> {
        let stream = client::connect_tcp(address, timeout).await?;
        Ok(Self {
            stream: BufReader::with_capacity(4 * MAX_FRAME_LEN, stream),
            unit_id,
            next_id: 0,
            timeout,
        })
    }

    /// Append the frame of a request of `function` at `address` for `count`
    /// registers (with `words` for a write) to `out`; returns what is in flight.
    fn frame(
        &mut self,
        out: &mut Vec<u8>,
        (function, address, count): (u8, u16, u16),
        words: &[u16],
    ) -> InFlight {
        let id = self.next_id;
        self.next_id = id.wrapping_add(1);
        let data = if words.is_empty() {
            0
        } else {
            1 + 2 * words.len()
        };
        let length = (1 + 5 + data) as u16;
        out.extend_from_slice(&id.to_be_bytes());
        out.extend_from_slice(&[0, 0]);
        out.extend_from_slice(&length.to_be_bytes());
        out.extend_from_slice(&[self.unit_id, function]);
        out.extend_from_slice(&address.to_be_bytes());
        out.extend_from_slice(&count.to_be_bytes());
        if !words.is_empty() {
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
        // Each answer acknowledged at once: a PLC whose stack holds small segments
        // until the last one is acknowledged (Nagle's algorithm, on by default in
        // many) sends the second answer of a write only then, and this end's delayed
        // ACK would wait up to 40 ms for data to ride on that, with requests in
        // flight, never comes (the load bench's virtual PLC: a write's answers took
        // 44 ms on the mean without this). The kernel leaves quick-ACK mode by
        // itself, so it is asked for before every answer.
        let _ = socket2::SockRef::from(self.stream.get_ref()).set_tcp_quickack(true);
        let read = async {
            let mut frame = vec![0; MBAP_HEADER_LEN];
            self.stream.read_exact(&mut frame).await?;
            // The header is whole: checked here, its length read below.
            frame_len(&frame)
                .map_err(|error| std::io::Error::new(std::io::ErrorKind::InvalidData, error))?;
            let len = 6 + usize::from(u16::from_be_bytes([frame[4], frame[5]]));
            frame.resize(len, 0);
            self.stream
                .read_exact(&mut frame[MBAP_HEADER_LEN..])
                .await?;
            Ok::<_, std::io::Error>(frame)
        };
        tokio::time::timeout(timeout, read)
            .await
            .map_err(|_| ModbusError::Timeout(timeout))?
            .map_err(io_error)
    }

    /// The next answer, checked against the requests in `flight` (and taken off it).
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
                Answer::Refused(ExceptionCode::new(code))
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
                Answer::Done(Vec::new())
            }
            [READ_HOLDING, bytes, ref data @ ..] if request.function == READ_HOLDING => {
                if usize::from(bytes) != data.len() || data.len() != 2 * usize::from(request.count)
                {
                    return Err(ReplyMismatch::Registers {
                        requested: request.count,
                        answered: data.len() / 2,
                    }
                    .into());
                }
                let words = data
                    .chunks_exact(2)
                    .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
                    .collect();
                Answer::Done(words)
            }
            _ => return Err(ReplyMismatch::Function.into()),
        };
        Ok((request, answer))
    }

    /// Read `count` (at most 125) holding registers from `address` (FC 03).
    pub(crate) async fn read_holding(
        &mut self,
        address: u16,
        count: u16,
    ) -> Result<Vec<u16>, ModbusError> {
        let mut frame = Vec::with_capacity(MBAP_HEADER_LEN + 5);
        let request = self.frame(
            &mut frame,
            (READ_HOLDING, address, count.min(MAX_READ)),
            &[],
        );
        self.send(&frame).await?;
        let mut flight = VecDeque::from([request]);
        match self.answer(&mut flight).await? {
            (_, Answer::Done(words)) => Ok(words),
            (_, Answer::Refused(exception)) => Err(ModbusError::Exception { address, exception }),
        }
    }

    /// Write each of `writes` (an address and at most 123 words) with FC 16, in order,
    /// up to `in_flight` (at least 1) requests sent before their answers came. When
    /// the PLC refuses one, no further request is sent, the answers of those in flight
    /// are read (the connection stays in step), and the first refusal is the error.
    pub(crate) async fn write(
        &mut self,
        writes: &[(u16, &[u16])],
        in_flight: usize,
    ) -> Result<(), ModbusError> {
        let in_flight = in_flight.max(1);
        let mut flight = VecDeque::with_capacity(in_flight);
        let mut pending = writes.iter();
        let mut refused: Option<ModbusError> = None;
        let mut frames = Vec::with_capacity(in_flight * MAX_FRAME_LEN);
        loop {
            // Fill the window in one send.
            frames.clear();
            while refused.is_none() && flight.len() < in_flight {
                let Some(&(address, words)) = pending.next() else {
                    break;
                };
                let words = &words[..words.len().min(MAX_WRITE)];
                let count = words.len() as u16;
                flight.push_back(self.frame(&mut frames, (WRITE_MULTIPLE, address, count), words));
            }
            if !frames.is_empty() {
                self.send(&frames).await?;
            }
            if flight.is_empty() {
                return refused.map_or(Ok(()), Err);
            }
            if let (request, Answer::Refused(exception)) = self.answer(&mut flight).await? {
                refused.get_or_insert(ModbusError::Exception {
                    address: request.address,
                    exception,
                });
            }
        }
    }
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
    async fn linked(expect: usize, answer: Vec<u8>) -> PlcLink {
        let address = plc(expect, answer).await;
        PlcLink::connect(&address, 1, Duration::from_secs(5))
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
        match link.read_holding(0, 3).await {
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
        let error = link.read_holding(0, 1).await.unwrap_err();
        assert!(matches!(error, ModbusError::Transport(_)), "{error:?}");
    }
}
