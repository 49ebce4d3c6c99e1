//! The front door: the OPC UA listener clients connect to. Each connection is relayed
//! to async-opcua's own listener on loopback, with three jobs async-opcua does not do:
//!
//! - a bound on connections (`max_connections`; a further one is closed at once);
//! - a check of the OPC UA TCP framing of what clients send ([`FrameScanner`]: the
//!   first message a Hello, known message and chunk types, sizes within the server's
//!   receive buffer); a stream that breaks it gets an `ERR` message and is closed, and
//!   is counted;
//! - what the server answers: the secure channel each connection opened (so a method
//!   call knows its client's address: the acknowledge guard) and the `ERR` messages it
//!   sent (a message its decoder refused), counted and logged.
//!
//! The relay copies bytes as they come; it never decodes or changes a message body.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio::task::JoinSet;

use crate::outputs::accept::AcceptFailures;
use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

use super::status::{count, OpcUaCounters};

/// Bytes of a message header the relay reads: type (3), chunk type (1), size (4) and
/// the first four bytes of the body (the secure channel id of OPN, MSG and CLO; the
/// error code of ERR).
pub const HEADER_LEN: usize = 12;
/// Smallest Hello: header, five UInt32 fields and an empty endpoint URL.
const MIN_HELLO_LEN: u32 = 32;
/// Largest Hello: with an endpoint URL of 4096 bytes (OPC 10000-6, 7.1.2.3).
const MAX_HELLO_LEN: u32 = MIN_HELLO_LEN + 4096;
/// Read buffer of one direction of a relay.
const RELAY_BUFFER: usize = 64 * 1024;

/// An OPC UA TCP message header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// `HEL`, `ACK`, `ERR`, `OPN`, `MSG`, `CLO`, `RHE`.
    pub message_type: [u8; 3],
    /// `F` (final), `C` (continued), `A` (abort).
    pub chunk_type: u8,
    /// The whole message's size, header included.
    pub size: u32,
    /// The body's first UInt32: the secure channel id (OPN, MSG, CLO), the error code
    /// (ERR), the protocol version (HEL, ACK).
    pub first_word: u32,
}

/// Why a client's stream is not OPC UA TCP.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The first message is not a Hello.
    #[error("the first message is not a Hello (HEL)")]
    NoHello,
    /// A message type a client never sends (or a second Hello).
    #[error("message type {0:?} is not one a client sends here")]
    MessageType([u8; 3]),
    /// A chunk type other than F, C or A (or C/A where only F is allowed).
    #[error("chunk type 0x{0:02x} is not allowed")]
    ChunkType(u8),
    /// A size below a header or above the receive buffer.
    #[error("message size {size} is out of range (allowed {min}..={max})")]
    Size {
        /// The size read.
        size: u32,
        /// Smallest allowed.
        min: u32,
        /// Largest allowed.
        max: u32,
    },
}

impl FrameError {
    /// The status code of the ERR message sent back (OPC 10000-6, 7.1.5).
    fn status(self) -> opcua::types::StatusCode {
        use opcua::types::StatusCode;
        match self {
            FrameError::Size { .. } => StatusCode::BadTcpMessageTooLarge,
            _ => StatusCode::BadTcpMessageTypeInvalid,
        }
    }
}

/// Follows the message boundaries of one direction of an OPC UA TCP stream, byte
/// chunk by byte chunk, and checks each header when `check` (a client's direction):
/// pure, no I/O (the fuzz harness feeds it arbitrary bytes).
#[derive(Debug)]
pub struct FrameScanner {
    check: Option<u32>,
    seen_hello: bool,
    header: [u8; HEADER_LEN],
    header_filled: usize,
    /// Bytes of the current message still to come after its header.
    rest: usize,
}

impl FrameScanner {
    /// A scanner of what a client sends, allowing messages up to `max_message` bytes
    /// (the server's receive buffer).
    pub fn client(max_message: u32) -> Self {
        Self::new(Some(max_message))
    }

    /// A scanner of what the server sends (headers reported, not checked).
    pub fn server() -> Self {
        Self::new(None)
    }

    fn new(check: Option<u32>) -> Self {
        Self {
            check,
            seen_hello: false,
            header: [0; HEADER_LEN],
            header_filled: 0,
            rest: 0,
        }
    }

    /// Follow `bytes`; `on_header` gets each complete header. An error when a header
    /// breaks the framing (clients' direction only): the stream is then not to be
    /// relayed further.
    pub fn feed(
        &mut self,
        mut bytes: &[u8],
        mut on_header: impl FnMut(Header),
    ) -> Result<(), FrameError> {
        while !bytes.is_empty() {
            if self.rest > 0 {
                let skip = self.rest.min(bytes.len());
                self.rest -= skip;
                bytes = &bytes[skip..];
                continue;
            }
            // The type, chunk type and size first; then as much of the body's first
            // word as the message holds.
            let wanted = if self.header_filled < 8 {
                8
            } else {
                self.header_len()
            };
            let take = (wanted - self.header_filled).min(bytes.len());
            self.header[self.header_filled..self.header_filled + take]
                .copy_from_slice(&bytes[..take]);
            self.header_filled += take;
            bytes = &bytes[take..];
            if self.header_filled == 8 && take > 0 {
                if let Some(max) = self.check {
                    self.check_header(max)?;
                }
            }
            if self.header_filled >= 8 && self.header_filled == self.header_len() {
                let header = self.header();
                self.rest = (header.size as usize).saturating_sub(self.header_filled);
                self.header_filled = 0;
                on_header(header);
            }
        }
        Ok(())
    }

    /// The size field of the header being read (its first eight bytes are in).
    fn size(&self) -> u32 {
        u32::from_le_bytes([
            self.header[4],
            self.header[5],
            self.header[6],
            self.header[7],
        ])
    }

    /// Bytes of the current message read as its header: [`HEADER_LEN`], or less for a
    /// message shorter than that.
    fn header_len(&self) -> usize {
        HEADER_LEN.min(self.size().max(8) as usize)
    }

    fn header(&self) -> Header {
        let mut message_type = [0u8; 3];
        message_type.copy_from_slice(&self.header[..3]);
        let first_word = if self.header_filled == HEADER_LEN {
            u32::from_le_bytes([
                self.header[8],
                self.header[9],
                self.header[10],
                self.header[11],
            ])
        } else {
            0
        };
        Header {
            message_type,
            chunk_type: self.header[3],
            size: self.size(),
            first_word,
        }
    }

    fn check_header(&mut self, max: u32) -> Result<(), FrameError> {
        let size = self.size();
        let mut type_ = [0u8; 3];
        type_.copy_from_slice(&self.header[..3]);
        let chunk = self.header[3];
        let (min, max) = match &type_ {
            b"HEL" if !self.seen_hello => (MIN_HELLO_LEN, MAX_HELLO_LEN.min(max)),
            _ if !self.seen_hello => return Err(FrameError::NoHello),
            b"OPN" | b"MSG" | b"CLO" => (HEADER_LEN as u32, max),
            _ => return Err(FrameError::MessageType(type_)),
        };
        let chunk_allowed = match &type_ {
            b"MSG" | b"OPN" => matches!(chunk, b'F' | b'C' | b'A'),
            _ => chunk == b'F',
        };
        if !chunk_allowed {
            return Err(FrameError::ChunkType(chunk));
        }
        if !(min..=max).contains(&size) {
            return Err(FrameError::Size { size, min, max });
        }
        self.seen_hello = true;
        Ok(())
    }
}

/// The client address of each open secure channel (by its id), as the relays saw the
/// server open them.
#[derive(Debug, Default)]
pub(crate) struct ChannelPeers(Mutex<HashMap<u32, SocketAddr>>);

impl ChannelPeers {
    /// The client of secure channel `channel`; `None` for a channel opened around the
    /// front door (a process on this host at the server's loopback listener).
    pub(crate) fn peer(&self, channel: u32) -> Option<SocketAddr> {
        crate::lock(&self.0).get(&channel).copied()
    }

    fn opened(&self, channel: u32, peer: SocketAddr) {
        crate::lock(&self.0).insert(channel, peer);
    }

    fn closed(&self, peer: SocketAddr) {
        crate::lock(&self.0).retain(|_, p| *p != peer);
    }
}

/// The front door's settings and shared state.
pub(crate) struct FrontDoor {
    pub(crate) listener: TcpListener,
    /// async-opcua's loopback listener.
    pub(crate) backend: SocketAddr,
    pub(crate) max_connections: usize,
    /// Largest message a client may send (the server's receive buffer).
    pub(crate) max_message: u32,
    pub(crate) counters: Arc<OpcUaCounters>,
    pub(crate) peers: Arc<ChannelPeers>,
}

impl FrontDoor {
    /// Relay connections until shutdown; an error when accepting fails for good.
    pub(crate) async fn run(self, mut shutdown: Shutdown) -> std::io::Result<()> {
        let slots = Arc::new(Semaphore::new(self.max_connections));
        let mut relays = JoinSet::new();
        let mut refusals = WarnLimit::new(WARN_PERIOD);
        let mut accept_failures = AcceptFailures::default();
        let problems = Arc::new(Mutex::new(WarnLimit::new(WARN_PERIOD)));
        loop {
            let accepted = tokio::select! {
                accepted = self.listener.accept() => accepted,
                () = shutdown.recv() => break,
                Some(_) = relays.join_next(), if !relays.is_empty() => continue,
            };
            let Some((client, peer)) = accept_failures.check(accepted, "OPC UA server").await?
            else {
                continue;
            };
            let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
                count(&self.counters.refused);
                if let Some(suppressed) = refusals.occurred(tokio::time::Instant::now()) {
                    tracing::warn!(%peer, max = self.max_connections, suppressed, "OPC UA server full, connection closed");
                }
                continue;
            };
            count(&self.counters.connections);
            let relay = Relay {
                peer,
                backend: self.backend,
                max_message: self.max_message,
                counters: Arc::clone(&self.counters),
                peers: Arc::clone(&self.peers),
                problems: Arc::clone(&problems),
            };
            let shutdown = shutdown.clone();
            relays.spawn(async move {
                relay.run(client, shutdown).await;
                drop(slot);
            });
        }
        relays.shutdown().await;
        Ok(())
    }
}

/// One client's connection, relayed.
struct Relay {
    peer: SocketAddr,
    backend: SocketAddr,
    max_message: u32,
    counters: Arc<OpcUaCounters>,
    peers: Arc<ChannelPeers>,
    problems: Arc<Mutex<WarnLimit>>,
}

impl Relay {
    async fn run(self, mut client: TcpStream, mut shutdown: Shutdown) {
        let _ = client.set_nodelay(true);
        let mut server = match TcpStream::connect(self.backend).await {
            Ok(server) => server,
            Err(error) => {
                tracing::error!(%error, backend = %self.backend, "OPC UA relay cannot reach the server");
                return;
            }
        };
        let _ = server.set_nodelay(true);
        let ended = {
            let (mut client_read, mut client_write) = client.split();
            let (mut server_read, mut server_write) = server.split();
            tokio::select! {
                ended = self.upstream(&mut client_read, &mut server_write) => ended,
                ended = self.downstream(&mut server_read, &mut client_write) => ended,
                () = shutdown.recv() => Ok(()),
            }
        };
        if let Err(error) = ended {
            count(&self.counters.malformed_frames);
            let suppressed = crate::lock(&self.problems).occurred(tokio::time::Instant::now());
            if let Some(suppressed) = suppressed {
                tracing::warn!(peer = %self.peer, %error, suppressed, "OPC UA client sent what is not OPC UA TCP, closed");
            }
            let _ = client.write_all(&error_message(error)).await;
        }
        self.peers.closed(self.peer);
    }

    /// Client to server, checked; `Err` when the client broke the framing.
    async fn upstream(
        &self,
        from: &mut tokio::net::tcp::ReadHalf<'_>,
        to: &mut tokio::net::tcp::WriteHalf<'_>,
    ) -> Result<(), FrameError> {
        let mut scanner = FrameScanner::client(self.max_message);
        let mut buffer = vec![0u8; RELAY_BUFFER];
        loop {
            let read = match from.read(&mut buffer).await {
                Ok(0) | Err(_) => return Ok(()),
                Ok(read) => read,
            };
            scanner.feed(&buffer[..read], |_| {})?;
            if to.write_all(&buffer[..read]).await.is_err() {
                return Ok(());
            }
        }
    }

    /// Server to client: the channels opened and the errors sent are noted.
    async fn downstream(
        &self,
        from: &mut tokio::net::tcp::ReadHalf<'_>,
        to: &mut tokio::net::tcp::WriteHalf<'_>,
    ) -> Result<(), FrameError> {
        let mut scanner = FrameScanner::server();
        let mut buffer = vec![0u8; RELAY_BUFFER];
        loop {
            let read = match from.read(&mut buffer).await {
                Ok(0) | Err(_) => return Ok(()),
                Ok(read) => read,
            };
            // The server's own framing is trusted; its headers are only noted.
            let _ = scanner.feed(&buffer[..read], |header| match &header.message_type {
                b"OPN" => self.peers.opened(header.first_word, self.peer),
                b"ERR" => {
                    count(&self.counters.protocol_errors);
                    let status = opcua::types::StatusCode::from(header.first_word);
                    tracing::warn!(peer = %self.peer, %status, "the OPC UA server refused a client's message (ERR)");
                }
                _ => {}
            });
            if to.write_all(&buffer[..read]).await.is_err() {
                return Ok(());
            }
        }
    }
}

/// An ERR message for `error` (OPC 10000-6, 7.1.2.5): the status code and a reason.
fn error_message(error: FrameError) -> Vec<u8> {
    let reason = error.to_string();
    let size = (8 + 4 + 4 + reason.len()) as u32;
    let mut message = Vec::with_capacity(size as usize);
    message.extend_from_slice(b"ERRF");
    message.extend_from_slice(&size.to_le_bytes());
    message.extend_from_slice(&error.status().bits().to_le_bytes());
    message.extend_from_slice(&(reason.len() as u32).to_le_bytes());
    message.extend_from_slice(reason.as_bytes());
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(kind: &[u8; 4], size: u32, first_word: u32) -> Vec<u8> {
        let mut bytes = kind.to_vec();
        bytes.extend_from_slice(&size.to_le_bytes());
        bytes.extend_from_slice(&first_word.to_le_bytes());
        bytes.resize(size as usize, 0xAA);
        bytes
    }

    fn headers(scanner: &mut FrameScanner, bytes: &[u8]) -> Result<Vec<Header>, FrameError> {
        let mut seen = Vec::new();
        scanner.feed(bytes, |h| seen.push(h))?;
        Ok(seen)
    }

    #[test]
    fn follows_messages_split_anywhere() {
        let stream: Vec<u8> = [
            frame(b"HELF", 40, 0),
            frame(b"OPNF", 132, 7),
            frame(b"MSGC", 20, 7),
            frame(b"MSGF", 12, 7),
        ]
        .concat();
        for split in 1..stream.len() {
            let mut scanner = FrameScanner::client(65_535);
            let mut seen = headers(&mut scanner, &stream[..split]).unwrap();
            seen.extend(headers(&mut scanner, &stream[split..]).unwrap());
            let summary: Vec<_> = seen
                .iter()
                .map(|h| (h.message_type, h.chunk_type, h.size, h.first_word))
                .collect();
            assert_eq!(
                summary,
                [
                    (*b"HEL", b'F', 40, 0),
                    (*b"OPN", b'F', 132, 7),
                    (*b"MSG", b'C', 20, 7),
                    (*b"MSG", b'F', 12, 7)
                ],
                "split at {split}"
            );
        }
    }

    #[test]
    fn refuses_what_a_client_does_not_send() {
        let check = |bytes: &[u8]| headers(&mut FrameScanner::client(65_535), bytes);
        assert_eq!(check(b"GET / HTTP/1.1\r\n"), Err(FrameError::NoHello));
        let hello = frame(b"HELF", 40, 0);
        let after_hello = |next: Vec<u8>| check(&[hello.clone(), next].concat());
        assert_eq!(
            after_hello(frame(b"HELF", 40, 0)),
            Err(FrameError::MessageType(*b"HEL"))
        );
        assert_eq!(
            after_hello(frame(b"ACKF", 28, 0)),
            Err(FrameError::MessageType(*b"ACK"))
        );
        assert_eq!(
            after_hello(frame(b"CLOC", 16, 0)),
            Err(FrameError::ChunkType(b'C'))
        );
        assert_eq!(
            after_hello(frame(b"MSGF", 70_000, 0)),
            Err(FrameError::Size {
                size: 70_000,
                min: 12,
                max: 65_535
            })
        );
        assert_eq!(
            check(&frame(b"HELF", 16, 0)),
            Err(FrameError::Size {
                size: 16,
                min: MIN_HELLO_LEN,
                max: MAX_HELLO_LEN
            })
        );
    }

    #[test]
    fn error_messages_are_well_formed() {
        let message = error_message(FrameError::NoHello);
        let mut scanner = FrameScanner::server();
        let seen = headers(&mut scanner, &message).unwrap();
        assert_eq!(seen.len(), 1);
        assert_eq!(seen[0].message_type, *b"ERR");
        assert_eq!(seen[0].size as usize, message.len());
        assert_eq!(
            seen[0].first_word,
            opcua::types::StatusCode::BadTcpMessageTypeInvalid.bits()
        );
    }
}
