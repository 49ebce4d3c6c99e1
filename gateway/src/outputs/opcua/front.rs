//! The front door: the OPC UA listener clients connect to. Each connection is relayed
//! to async-opcua's own listener on loopback, with jobs async-opcua does not do:
//!
//! - a bound on connections (`max_connections`), shared fairly: a client (an IP
//!   address) holds at most half of them, the last free one is kept for a client with
//!   none yet, and when there is no room the connection idle longest (at least
//!   `EVICT_IDLE`, 10 s) is closed to make room (`admit`); else the new one is closed;
//! - a bound on what a connection costs the server: the relay stops reading a client
//!   with `MAX_IN_FLIGHT` (32) requests unanswered (async-opcua reads on and queues
//!   the answers without bound); where `none` is not a security mode, a channel
//!   without security carries `DISCOVERY_REQUESTS` (4) requests (discovery) and is
//!   closed;
//! - a check of the OPC UA TCP framing of what clients send ([`FrameScanner`]: the
//!   first message a Hello, known message and chunk types, sizes within the server's
//!   receive buffer); a stream that breaks it gets an `ERR` message and is closed, and
//!   is counted;
//! - what the server answers: the secure channel each connection opened (so a method
//!   call knows its client's address: the acknowledge guard; and async-opcua the
//!   client of each session: `SessionPeers`, `max_sessions_per_peer`) and the `ERR`
//!   messages it sent (a message its decoder refused), counted and logged.
//!
//! The relay copies bytes as they come; it never decodes or changes a message body.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio::task::JoinSet;

use crate::outputs::accept::AcceptFailures;
use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

use super::status::{count, OpcUaCounters};

/// Bytes of a message header the relay reads: type (3), chunk type (1), size (4) and
/// the first four bytes of the body (the secure channel id of OPN, MSG and CLO; the
/// error code of ERR).
pub const HEADER_LEN: usize = 12;
/// SecurityPolicy None (OPC 10000-7): the policy of an OPN that opens a channel
/// without security.
const POLICY_NONE: &[u8] = b"http://opcfoundation.org/UA/SecurityPolicy#None";
/// Bytes of an OPN the scanner reads: the header, the channel id, the policy URI's
/// length and as many of its bytes as the None URI has.
const OPN_PREFIX_LEN: usize = HEADER_LEN + 4 + POLICY_NONE.len();
/// Smallest Hello: header, five UInt32 fields and an empty endpoint URL.
const MIN_HELLO_LEN: u32 = 32;
/// Largest Hello: with an endpoint URL of 4096 bytes (OPC 10000-6, 7.1.2.3).
const MAX_HELLO_LEN: u32 = MIN_HELLO_LEN + 4096;
/// Read buffer of one direction of a relay.
const RELAY_BUFFER: usize = 64 * 1024;
/// Requests a connection may have unanswered: the relay stops reading the client
/// beyond, so a client that sends requests and never reads the answers waits
/// instead of growing async-opcua's send queue, which has no bound (round-4 audit,
/// finding 1). Above async-opcua's 20 publish requests pending per session.
const MAX_IN_FLIGHT: usize = 32;
/// Requests a channel without security may carry after its OPN where `none` is not
/// a security mode: discovery (GetEndpoints, FindServers) before a secure channel.
const DISCOVERY_REQUESTS: usize = 4;
/// A connection whose client sent nothing for this long may be closed to make room
/// for a new client when the server is full.
pub(crate) const EVICT_IDLE: Duration = Duration::from_secs(10);
/// How long the relay tries to write its closing ERR.
const WRITE_LIMIT: Duration = Duration::from_secs(1);

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
    /// An OPN of SecurityPolicy None (a channel without security).
    pub policy_none: bool,
}

impl Header {
    /// The last chunk of a client's request (a final OPN or MSG), which the server
    /// answers.
    fn is_request(&self) -> bool {
        matches!(&self.message_type, b"OPN" | b"MSG") && self.chunk_type == b'F'
    }

    /// The last chunk of the server's answer: a final or aborted OPN or MSG, an ERR.
    fn is_response(&self) -> bool {
        match &self.message_type {
            b"OPN" | b"MSG" => matches!(self.chunk_type, b'F' | b'A'),
            b"ERR" => true,
            _ => false,
        }
    }
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
    header: [u8; OPN_PREFIX_LEN],
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
            header: [0; OPN_PREFIX_LEN],
            header_filled: 0,
            rest: 0,
        }
    }

    /// Follow `bytes`; `on_header` gets each complete header. An error when a header
    /// breaks the framing (clients' direction only): the stream is then not to be
    /// relayed further.
    pub fn feed(
        &mut self,
        bytes: &[u8],
        mut on_header: impl FnMut(Header),
    ) -> Result<(), FrameError> {
        self.feed_until(bytes, |header| {
            on_header(header);
            false
        })
        .map(|_| ())
    }

    /// As [`feed`](Self::feed), but stops at the end of the first message whose
    /// header `on_header` answered `true` for: the bytes followed, the rest to be fed
    /// later.
    pub fn feed_until(
        &mut self,
        mut bytes: &[u8],
        mut on_header: impl FnMut(Header) -> bool,
    ) -> Result<usize, FrameError> {
        let total = bytes.len();
        let mut stop = false;
        while !bytes.is_empty() {
            if stop && self.rest == 0 && self.header_filled == 0 {
                break;
            }
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
                stop |= on_header(header);
            }
        }
        Ok(total - bytes.len())
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

    /// Bytes of the current message read as its header: [`HEADER_LEN`] (an OPN's
    /// [`OPN_PREFIX_LEN`], for its security policy), or less for a shorter message.
    fn header_len(&self) -> usize {
        let len = if &self.header[..3] == b"OPN" {
            OPN_PREFIX_LEN
        } else {
            HEADER_LEN
        };
        len.min(self.size().max(8) as usize)
    }

    fn header(&self) -> Header {
        let mut message_type = [0u8; 3];
        message_type.copy_from_slice(&self.header[..3]);
        let word = |at: usize| {
            u32::from_le_bytes([
                self.header[at],
                self.header[at + 1],
                self.header[at + 2],
                self.header[at + 3],
            ])
        };
        let first_word = if self.header_filled >= HEADER_LEN {
            word(8)
        } else {
            0
        };
        let policy_none = &message_type == b"OPN"
            && self.header_filled == OPN_PREFIX_LEN
            && word(HEADER_LEN) as usize == POLICY_NONE.len()
            && &self.header[HEADER_LEN + 4..] == POLICY_NONE;
        Header {
            message_type,
            chunk_type: self.header[3],
            size: self.size(),
            first_word,
            policy_none,
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

/// Who the client of each secure channel is, for async-opcua's sessions per client
/// (`max_sessions_per_peer`, the kept patch's `SessionClients`): async-opcua sees the
/// relays' loopback connections only. A refused CreateSession is counted and logged
/// (rate-limited).
pub(crate) struct SessionPeers {
    pub(crate) peers: Arc<ChannelPeers>,
    pub(crate) counters: Arc<OpcUaCounters>,
    pub(crate) problems: Mutex<WarnLimit>,
}

impl opcua::server::SessionClients for SessionPeers {
    fn client(&self, secure_channel_id: u32) -> Option<IpAddr> {
        self.peers.peer(secure_channel_id).map(|peer| peer.ip())
    }

    fn session_refused(&self, client: IpAddr) {
        count(&self.counters.sessions_refused);
        let suppressed = crate::lock(&self.problems).occurred(tokio::time::Instant::now());
        if let Some(suppressed) = suppressed {
            tracing::warn!(%client, suppressed, "OPC UA session refused: the client holds max_sessions_per_peer sessions");
        }
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
    /// Whether `none` is one of the security modes; if not, a channel without
    /// security carries discovery only ([`DISCOVERY_REQUESTS`]).
    pub(crate) none_allowed: bool,
    pub(crate) counters: Arc<OpcUaCounters>,
    pub(crate) peers: Arc<ChannelPeers>,
}

/// One open connection as the front door sees it.
#[derive(Debug)]
struct Live {
    peer: IpAddr,
    /// When the client last sent something, ms since the front door started.
    last_read: AtomicU64,
    /// Told when the connection is closed to make room.
    evict: Notify,
}

/// Whether a new connection from a peer may be served.
#[derive(Debug, PartialEq, Eq)]
enum Admission {
    /// A free slot.
    Free,
    /// After closing this connection, the idlest of those that may make room.
    Evict(u64),
    /// No room: why.
    Refused(&'static str),
}

/// Whether a connection from `peer` may be served among `live` at `now_ms`.
/// A peer holds at most half the slots; the last free slot is kept for a peer
/// with no connection yet; when there is no room, the connection idle longest
/// ([`EVICT_IDLE`] at least) makes room: the peer's own when it is at its limit.
fn admit(live: &HashMap<u64, Arc<Live>>, peer: IpAddr, max: usize, now_ms: u64) -> Admission {
    let mine = live.values().filter(|l| l.peer == peer).count();
    let per_peer = max.div_ceil(2);
    let at_peer_limit = mine >= per_peer;
    let full = live.len() >= max || (mine > 0 && live.len() + 1 >= max);
    if !full && !at_peer_limit {
        return Admission::Free;
    }
    let idlest = live
        .iter()
        .filter(|(_, l)| !at_peer_limit || l.peer == peer)
        .min_by_key(|(id, l)| (l.last_read.load(Ordering::Relaxed), **id));
    match idlest {
        Some((id, l))
            if now_ms.saturating_sub(l.last_read.load(Ordering::Relaxed))
                >= EVICT_IDLE.as_millis() as u64 =>
        {
            Admission::Evict(*id)
        }
        _ if at_peer_limit => Admission::Refused("this client holds half the connections"),
        _ => Admission::Refused("max_connections are open and busy"),
    }
}

impl FrontDoor {
    /// Relay connections until shutdown; an error when accepting fails for good.
    pub(crate) async fn run(self, mut shutdown: Shutdown) -> std::io::Result<()> {
        let started = Instant::now();
        let mut live: HashMap<u64, Arc<Live>> = HashMap::new();
        let mut next_id = 0u64;
        let mut relays = JoinSet::new();
        let mut refusals = WarnLimit::new(WARN_PERIOD);
        let mut evictions = WarnLimit::new(WARN_PERIOD);
        let mut accept_failures = AcceptFailures::default();
        let problems = Arc::new(Mutex::new(WarnLimit::new(WARN_PERIOD)));
        loop {
            let accepted = tokio::select! {
                accepted = self.listener.accept() => accepted,
                () = shutdown.recv() => break,
                Some(ended) = relays.join_next(), if !relays.is_empty() => {
                    if let Ok(id) = ended {
                        live.remove(&id);
                    }
                    continue;
                }
            };
            let Some((client, peer)) = accept_failures.check(accepted, "OPC UA server").await?
            else {
                continue;
            };
            let now_ms = started.elapsed().as_millis() as u64;
            match admit(&live, peer.ip(), self.max_connections, now_ms) {
                Admission::Free => {}
                Admission::Evict(id) => {
                    if let Some(evicted) = live.remove(&id) {
                        evicted.evict.notify_one();
                        count(&self.counters.evicted);
                        if let Some(suppressed) = evictions.occurred(tokio::time::Instant::now()) {
                            tracing::warn!(%peer, idle_peer = %evicted.peer, suppressed, "OPC UA server full: the idlest connection closed to make room");
                        }
                    }
                }
                Admission::Refused(why) => {
                    count(&self.counters.refused);
                    if let Some(suppressed) = refusals.occurred(tokio::time::Instant::now()) {
                        tracing::warn!(%peer, max = self.max_connections, why, suppressed, "OPC UA connection refused");
                    }
                    continue;
                }
            }
            count(&self.counters.connections);
            next_id += 1;
            let state = Arc::new(Live {
                peer: peer.ip(),
                last_read: AtomicU64::new(now_ms),
                evict: Notify::new(),
            });
            live.insert(next_id, Arc::clone(&state));
            let relay = Relay {
                peer,
                backend: self.backend,
                max_message: self.max_message,
                none_allowed: self.none_allowed,
                counters: Arc::clone(&self.counters),
                peers: Arc::clone(&self.peers),
                problems: Arc::clone(&problems),
                live: state,
                started,
                in_flight: AtomicUsize::new(0),
                answered: Notify::new(),
            };
            let (shutdown, id) = (shutdown.clone(), next_id);
            relays.spawn(async move {
                relay.run(client, shutdown).await;
                id
            });
        }
        relays.shutdown().await;
        Ok(())
    }
}

/// Why the relay closed a connection itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
enum Closing {
    /// The client broke the framing.
    #[error(transparent)]
    Framing(#[from] FrameError),
    /// More than discovery on a channel without security where `none` is not a
    /// security mode.
    #[error(
        "a channel without security carries only discovery here (security none is not configured)"
    )]
    DiscoveryOnly,
    /// Closed to make room for a new client.
    #[error("closed to make room for a new client: idle while the server was full")]
    Evicted,
}

impl Closing {
    fn status(self) -> opcua::types::StatusCode {
        use opcua::types::StatusCode;
        match self {
            Closing::Framing(error) => error.status(),
            Closing::DiscoveryOnly => StatusCode::BadSecurityPolicyRejected,
            Closing::Evicted => StatusCode::BadTcpServerTooBusy,
        }
    }
}

/// One client's connection, relayed.
struct Relay {
    peer: SocketAddr,
    backend: SocketAddr,
    max_message: u32,
    none_allowed: bool,
    counters: Arc<OpcUaCounters>,
    peers: Arc<ChannelPeers>,
    problems: Arc<Mutex<WarnLimit>>,
    live: Arc<Live>,
    started: Instant,
    /// Requests relayed to the server and not yet answered to the client.
    in_flight: AtomicUsize,
    /// Told when answers reached the client.
    answered: Notify,
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
                () = self.live.evict.notified() => Err(Closing::Evicted),
                () = shutdown.recv() => Ok(()),
            }
        };
        if let Err(closing) = ended {
            match closing {
                Closing::Framing(_) => count(&self.counters.malformed_frames),
                Closing::DiscoveryOnly => count(&self.counters.discovery_closed),
                Closing::Evicted => {}
            }
            let suppressed = crate::lock(&self.problems).occurred(tokio::time::Instant::now());
            match (closing, suppressed) {
                (Closing::Evicted, _) | (_, None) => {}
                (_, Some(suppressed)) => {
                    tracing::warn!(peer = %self.peer, error = %closing, suppressed, "OPC UA client closed");
                }
            }
            let message = error_message(closing.status(), &closing.to_string());
            let _ = tokio::time::timeout(WRITE_LIMIT, client.write_all(&message)).await;
        }
        self.peers.closed(self.peer);
    }

    /// Wait until the client has fewer than [`MAX_IN_FLIGHT`] requests unanswered.
    async fn room(&self) {
        while self.in_flight.load(Ordering::Acquire) >= MAX_IN_FLIGHT {
            self.answered.notified().await;
        }
    }

    /// Client to server, checked; `Err` when the client broke the framing or sent
    /// more than discovery on a channel without security where none is allowed.
    /// Reading stops while [`MAX_IN_FLIGHT`] requests are unanswered.
    async fn upstream(
        &self,
        from: &mut tokio::net::tcp::ReadHalf<'_>,
        to: &mut tokio::net::tcp::WriteHalf<'_>,
    ) -> Result<(), Closing> {
        let mut scanner = FrameScanner::client(self.max_message);
        let mut buffer = vec![0u8; RELAY_BUFFER];
        // Requests left on a channel without security where none is not allowed.
        let mut discovery: Option<usize> = None;
        loop {
            self.room().await;
            let read = match from.read(&mut buffer).await {
                Ok(0) | Err(_) => return Ok(()),
                Ok(read) => read,
            };
            let now_ms = self.started.elapsed().as_millis() as u64;
            self.live.last_read.store(now_ms, Ordering::Relaxed);
            let mut bytes = &buffer[..read];
            while !bytes.is_empty() {
                self.room().await;
                let mut beyond_discovery = false;
                let used = scanner.feed_until(bytes, |header| {
                    if header.policy_none && !self.none_allowed {
                        discovery = Some(DISCOVERY_REQUESTS);
                    }
                    if !header.is_request() {
                        return false;
                    }
                    if header.message_type == *b"MSG" {
                        match &mut discovery {
                            Some(0) => beyond_discovery = true,
                            Some(left) => *left -= 1,
                            None => {}
                        }
                    }
                    let in_flight = self.in_flight.fetch_add(1, Ordering::AcqRel) + 1;
                    beyond_discovery || in_flight >= MAX_IN_FLIGHT
                })?;
                if beyond_discovery {
                    return Err(Closing::DiscoveryOnly);
                }
                if to.write_all(&bytes[..used]).await.is_err() {
                    return Ok(());
                }
                bytes = &bytes[used..];
            }
        }
    }

    /// Server to client: the channels opened and the errors sent are noted, the
    /// answers delivered counted off.
    async fn downstream(
        &self,
        from: &mut tokio::net::tcp::ReadHalf<'_>,
        to: &mut tokio::net::tcp::WriteHalf<'_>,
    ) -> Result<(), Closing> {
        let mut scanner = FrameScanner::server();
        let mut buffer = vec![0u8; RELAY_BUFFER];
        loop {
            let read = match from.read(&mut buffer).await {
                Ok(0) | Err(_) => return Ok(()),
                Ok(read) => read,
            };
            let mut answers = 0;
            // The server's own framing is trusted; its headers are only noted.
            let _ = scanner.feed(&buffer[..read], |header| {
                if header.is_response() {
                    answers += 1;
                }
                match &header.message_type {
                    b"OPN" => self.peers.opened(header.first_word, self.peer),
                    b"ERR" => {
                        count(&self.counters.protocol_errors);
                        let status = opcua::types::StatusCode::from(header.first_word);
                        let suppressed =
                            crate::lock(&self.problems).occurred(tokio::time::Instant::now());
                        if let Some(suppressed) = suppressed {
                            tracing::warn!(peer = %self.peer, %status, suppressed, "the OPC UA server refused a client's message (ERR)");
                        }
                    }
                    _ => {}
                }
            });
            if to.write_all(&buffer[..read]).await.is_err() {
                return Ok(());
            }
            if answers > 0 {
                let _ = self
                    .in_flight
                    .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                        Some(n.saturating_sub(answers))
                    });
                self.answered.notify_one();
            }
        }
    }
}

/// An ERR message (OPC 10000-6, 7.1.2.5): the status code and a reason.
fn error_message(status: opcua::types::StatusCode, reason: &str) -> Vec<u8> {
    let size = (8 + 4 + 4 + reason.len()) as u32;
    let mut message = Vec::with_capacity(size as usize);
    message.extend_from_slice(b"ERRF");
    message.extend_from_slice(&size.to_le_bytes());
    message.extend_from_slice(&status.bits().to_le_bytes());
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
    fn feed_until_stops_at_the_end_of_the_message_asked() {
        let stream: Vec<u8> = [
            frame(b"HELF", 40, 0),
            frame(b"MSGF", 30, 7),
            frame(b"MSGF", 20, 7),
        ]
        .concat();
        let mut scanner = FrameScanner::client(65_535);
        let used = scanner
            .feed_until(&stream, |h| h.message_type == *b"MSG")
            .unwrap();
        assert_eq!(used, 70, "the Hello and the first MSG");
        let mut rest = Vec::new();
        let used = scanner
            .feed_until(&stream[used..], |h| {
                rest.push(h.size);
                false
            })
            .unwrap();
        assert_eq!((used, rest), (20, vec![20]));
    }

    #[test]
    fn an_opn_of_policy_none_is_told_apart() {
        let opn = |policy: &[u8]| {
            let mut body = 0u32.to_le_bytes().to_vec();
            body.extend_from_slice(&(policy.len() as u32).to_le_bytes());
            body.extend_from_slice(policy);
            body.resize(body.len() + 40, 0xFF);
            let mut message = b"OPNF".to_vec();
            message.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
            message.extend_from_slice(&body);
            [frame(b"HELF", 40, 0), message].concat()
        };
        let basic = b"http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256";
        for (stream, none) in [(opn(POLICY_NONE), true), (opn(basic), false)] {
            for split in 1..stream.len() {
                let mut scanner = FrameScanner::client(65_535);
                let mut seen = headers(&mut scanner, &stream[..split]).unwrap();
                seen.extend(headers(&mut scanner, &stream[split..]).unwrap());
                assert_eq!(seen[1].message_type, *b"OPN");
                assert_eq!(seen[1].policy_none, none, "split at {split}");
                assert_eq!(seen[1].size as usize, stream.len() - 40);
            }
        }
    }

    #[test]
    fn slots_are_shared_and_the_idlest_makes_room() {
        let ip = |last: u8| IpAddr::from([127, 0, 0, last]);
        let live_of = |conns: &[(u8, u64)]| -> HashMap<u64, Arc<Live>> {
            conns
                .iter()
                .enumerate()
                .map(|(id, &(peer, last_read))| {
                    let live = Live {
                        peer: ip(peer),
                        last_read: AtomicU64::new(last_read),
                        evict: Notify::new(),
                    };
                    (id as u64, Arc::new(live))
                })
                .collect()
        };
        let idle = EVICT_IDLE.as_millis() as u64;
        // Half of 4 per client; the last free slot for a client with none.
        assert_eq!(admit(&live_of(&[(2, 0)]), ip(2), 4, 0), Admission::Free);
        assert!(matches!(
            admit(&live_of(&[(2, 0), (2, 0)]), ip(2), 4, 0),
            Admission::Refused(_)
        ));
        assert!(matches!(
            admit(&live_of(&[(2, 0), (3, 0), (3, 0)]), ip(2), 4, 0),
            Admission::Refused(_)
        ));
        assert_eq!(
            admit(&live_of(&[(2, 0), (3, 0), (3, 0)]), ip(4), 4, 0),
            Admission::Free
        );
        // Full: the idlest, once idle long enough.
        let full = live_of(&[(2, 5), (2, 1), (3, 9), (4, 7)]);
        assert!(matches!(
            admit(&full, ip(5), 4, idle),
            Admission::Refused(_)
        ));
        assert_eq!(admit(&full, ip(5), 4, idle + 1), Admission::Evict(1));
        // A client at its limit makes room among its own.
        let own = live_of(&[(2, 5), (2, 3), (3, 0)]);
        assert_eq!(admit(&own, ip(2), 4, idle + 5), Admission::Evict(1));
    }

    #[test]
    fn error_messages_are_well_formed() {
        let error = FrameError::NoHello;
        let message = error_message(error.status(), &error.to_string());
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
