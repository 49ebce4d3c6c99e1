//! `ModbusServer`: serves the register map to HMIs and PLCs that poll.
//!
//! The map is readable with FC 03 (holding) and FC 04 (input) at the map's own
//! addresses (offset 0, independent of the PLC's `register_base`). Results are
//! read-only: only the documented command registers accept FC 06 / FC 16. A read
//! past the map, or a write that touches anything but a command register, gets
//! exception 02 (illegal data address); a bad command value or a malformed request
//! exception 03; other function codes exception 01. The framing and every answer are
//! in [`crate::outputs::modbus::frame`].
//!
//! Commands, handed to the analysis on its command channel: `command.acknowledge_alarms`
//! takes 0 (nothing) or 1 (clear latched alarms); `command.reset_wear_trend` takes a
//! bitmask of the first 16 drivelines (bit k = the k-th driveline in config order, 0 =
//! nothing) and refuses bits of drivelines that do not exist; `command.reset_wear` takes
//! a driveline's number (1-based, any count of drivelines); `command.manual_capture`
//! takes seconds * 256 + a driveline's number (both 1..=255; 0 seconds: 10 s) and keeps
//! the next seconds of its torque as a capture of kind `manual`; `command.reset_fatigue`
//! takes a fatigue component's number * 256 + its driveline's number (both 1-based) and
//! refuses a driveline without a ledger or a component it does not have. All read back 0. A command
//! the analysis cannot take now gets exception 06 (busy), and 04 while the gateway
//! stops. Only loopback clients may write them unless
//! `allow_remote_commands` is set (the registers need no authentication). The
//! history records who sent a command: the PLC when the client's address is the
//! configured PLC's, an HMI otherwise.
//!
//! Limits: at most `max_connections` clients at once and `max_connections_per_peer`
//! from one address. A connection beyond the address' limit takes the place of that
//! address' own connection idle longest; one beyond `max_connections` takes the place
//! of the connection idle longest, one that never sent a request first (evicted,
//! counted); it is closed at once only when every connection is inside a request. So
//! idle connections, however many, never lock an HMI out. A connection without a
//! request for `idle_timeout` is closed, one that sent no request within
//! [`FIRST_REQUEST_TIMEOUT`] (at most the idle timeout) sooner, and a request must
//! arrive whole within [`FRAME_TIMEOUT`] (at most the idle timeout) of its first byte,
//! so a client trickling bytes (slowloris) holds a slot for seconds, not forever. A
//! stream that is not Modbus TCP is closed.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::ServerOutput;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio::task::JoinSet;
use tokio::time::Instant;

use crate::outputs::accept::AcceptFailures;
use crate::outputs::modbus::frame::{self, Policy, Reply, Served, MAX_FRAME_LEN};
use crate::shutdown::Shutdown;
use crate::state::commands::CommandOrigin;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Time a request may take from its first byte to its last.
pub(crate) const FRAME_TIMEOUT: Duration = Duration::from_secs(5);
/// Time a new connection has for its first request (at most the idle timeout): a
/// client that connects and stays silent holds a slot this long, not the idle time.
pub(crate) const FIRST_REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// What the server has seen, for `/metrics`.
#[derive(Debug, Default)]
pub(crate) struct ServerCounters {
    connections: AtomicU64,
    refused: AtomicU64,
    evicted: AtomicU64,
    idle_closed: AtomicU64,
    silent_closed: AtomicU64,
    not_modbus: AtomicU64,
    requests: AtomicU64,
    exceptions: AtomicU64,
    broadcasts: AtomicU64,
}

/// A copy of [`ServerCounters`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct ServerCounts {
    /// Connections accepted and served.
    pub connections: u64,
    /// Connections closed at once: the server was full and every connection was
    /// inside a request.
    pub refused: u64,
    /// Idle connections closed to make room for a new one (the server or the
    /// client's address at its limit).
    pub evicted: u64,
    /// Connections closed for idling, or for a request not completed in time.
    pub idle_closed: u64,
    /// Of those, connections that never sent a request (closed after
    /// [`FIRST_REQUEST_TIMEOUT`]).
    pub silent_closed: u64,
    /// Connections closed because the stream was not Modbus TCP.
    pub not_modbus: u64,
    /// Requests answered (responses and exceptions).
    pub requests: u64,
    /// Of those, exception responses.
    pub exceptions: u64,
    /// Broadcast requests (unit 0), never answered nor acted on.
    pub broadcasts: u64,
}

impl ServerCounters {
    /// Current values.
    pub(crate) fn snapshot(&self) -> ServerCounts {
        let load = |counter: &AtomicU64| counter.load(Ordering::Relaxed);
        ServerCounts {
            connections: load(&self.connections),
            refused: load(&self.refused),
            evicted: load(&self.evicted),
            idle_closed: load(&self.idle_closed),
            silent_closed: load(&self.silent_closed),
            not_modbus: load(&self.not_modbus),
            requests: load(&self.requests),
            exceptions: load(&self.exceptions),
            broadcasts: load(&self.broadcasts),
        }
    }
}

fn count(counter: &AtomicU64) {
    counter.fetch_add(1, Ordering::Relaxed);
}

/// The warning for a server whose bind address reaches other hosts, `None` on a
/// loopback bind. `millgate check` prints it and the service logs it at start.
pub(crate) fn exposure_warning(output: &ServerOutput) -> Option<String> {
    if output.bind.ip().is_loopback() {
        return None;
    }
    Some(if output.allow_remote_commands {
        format!(
            "outputs.server.bind: {} accepts clients from other hosts and \
             outputs.server.allow_remote_commands = true lets any of them write the command \
             registers (acknowledge alarms, reset wear trends) without authentication",
            output.bind
        )
    } else {
        format!(
            "outputs.server.bind: {} accepts clients from other hosts: they may read the \
             map; their command writes are refused (exception 01) unless \
             outputs.server.allow_remote_commands = true",
            output.bind
        )
    })
}

/// The gateway's Modbus TCP server.
#[derive(Debug)]
pub(crate) struct ModbusServer {
    output: ServerOutput,
    served: Served,
    counters: Arc<ServerCounters>,
    plc_address: Option<String>,
}

impl ModbusServer {
    /// A server of `served` (its map, the board it encodes, where commands go) with
    /// the settings of `output`, counting into `counters`.
    pub(crate) fn new(output: ServerOutput, served: Served, counters: Arc<ServerCounters>) -> Self {
        Self {
            output,
            served,
            counters,
            plc_address: None,
        }
    }

    /// Commands from a client at the host of `plc_address` (`host:port`, the PLC
    /// output's) are recorded as the PLC's.
    pub(crate) fn with_plc_address(mut self, plc_address: Option<String>) -> Self {
        self.plc_address = plc_address;
        self
    }

    /// Serve on `listener` until shutdown; an error when accepting fails for good.
    pub(crate) async fn run(
        self,
        listener: TcpListener,
        mut shutdown: Shutdown,
    ) -> std::io::Result<()> {
        let local = listener.local_addr()?;
        tracing::info!(%local, max_connections = self.output.max_connections, "Modbus server listening");
        let mut open = OpenConnections::new(
            self.output.max_connections,
            self.output.max_connections_per_peer,
        );
        let mut connections = JoinSet::new();
        let mut refusals = WarnLimit::new(WARN_PERIOD);
        let mut evictions = WarnLimit::new(WARN_PERIOD);
        let mut accept_failures = AcceptFailures::default();
        let plc_hosts: Vec<IpAddr> = match &self.plc_address {
            Some(address) => tokio::net::lookup_host(address.as_str())
                .await
                .map(|found| found.map(|a| a.ip()).collect())
                .unwrap_or_default(),
            None => Vec::new(),
        };
        let mut next_id = 0u64;
        loop {
            let accepted = tokio::select! {
                accepted = listener.accept() => accepted,
                () = shutdown.recv() => break,
                Some(ended) = connections.join_next(), if !connections.is_empty() => {
                    if let Ok(id) = ended {
                        open.remove(id);
                    }
                    continue;
                }
            };
            let Some((stream, peer)) = accept_failures.check(accepted, "Modbus server").await?
            else {
                continue;
            };
            match open.admit(peer.ip()) {
                Admission::Admitted => {}
                Admission::Evicted(evicted) => {
                    count(&self.counters.evicted);
                    evicted.evict();
                    if let Some(suppressed) = evictions.occurred(Instant::now()) {
                        tracing::warn!(%peer, max = self.output.max_connections, max_per_peer = self.output.max_connections_per_peer, suppressed, "Modbus server (or this address) at its limit: the connection idle longest closed for the new one");
                    }
                }
                Admission::Refused => {
                    count(&self.counters.refused);
                    if let Some(suppressed) = refusals.occurred(Instant::now()) {
                        tracing::warn!(%peer, max = self.output.max_connections, suppressed, "Modbus server full, every connection inside a request: connection closed");
                    }
                    drop(stream);
                    continue;
                }
            }
            let activity = Arc::new(Activity::default());
            next_id += 1;
            let id = next_id;
            open.insert(id, peer.ip(), Arc::clone(&activity));
            count(&self.counters.connections);
            let connection = Connection {
                served: self.served.clone(),
                counters: Arc::clone(&self.counters),
                policy: Policy {
                    unit_id: self.output.unit_id,
                    commands_allowed: self.output.allow_remote_commands || peer.ip().is_loopback(),
                    origin: if plc_hosts.contains(&peer.ip()) {
                        CommandOrigin::Plc(peer)
                    } else {
                        CommandOrigin::Hmi(peer)
                    },
                },
                idle_timeout: self.output.idle_timeout,
                peer,
                activity,
            };
            let shutdown = shutdown.clone();
            connections.spawn(async move {
                connection.serve(stream, shutdown).await;
                id
            });
        }
        connections.shutdown().await;
        Ok(())
    }
}

/// One client's connection.
struct Connection {
    served: Served,
    counters: Arc<ServerCounters>,
    policy: Policy,
    idle_timeout: Duration,
    peer: SocketAddr,
    activity: Arc<Activity>,
}

/// What the accept loop knows of one connection's activity, to choose whom to evict.
#[derive(Debug)]
struct Activity {
    /// When it last completed a request (or connected).
    last: std::sync::Mutex<Instant>,
    /// It has sent a request.
    requested: AtomicBool,
    /// Part of a request has arrived: not idle, not to be evicted.
    in_request: AtomicBool,
    /// Set by the accept loop to close it.
    evicted: Notify,
}

impl Default for Activity {
    fn default() -> Self {
        Self {
            last: std::sync::Mutex::new(Instant::now()),
            requested: AtomicBool::new(false),
            in_request: AtomicBool::new(false),
            evicted: Notify::new(),
        }
    }
}

impl Activity {
    fn last(&self) -> Instant {
        *self
            .last
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// A request answered.
    fn answered(&self) {
        *self
            .last
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Instant::now();
        self.requested.store(true, Ordering::Relaxed);
    }

    /// Close the connection (its task ends at once).
    fn evict(&self) {
        self.evicted.notify_one();
    }
}

/// Whether a new connection may be served.
#[derive(Debug)]
enum Admission {
    /// There is room.
    Admitted,
    /// There is room once this connection, idle longest, is closed.
    Evicted(Arc<Activity>),
    /// Every connection that could make room is inside a request.
    Refused,
}

/// The connections being served, by id, with their peer's address.
#[derive(Debug)]
struct OpenConnections {
    max: usize,
    max_per_peer: usize,
    open: Vec<(u64, IpAddr, Arc<Activity>)>,
}

impl OpenConnections {
    fn new(max: usize, max_per_peer: usize) -> Self {
        Self {
            max,
            max_per_peer: max_per_peer.clamp(1, max.max(1)),
            open: Vec::with_capacity(max),
        }
    }

    /// Whether a connection from `peer` may be served, and whom it evicts: at the
    /// peer's limit, the peer's own connection idle longest; with the server full,
    /// a connection that never sent a request (the oldest), else the one idle
    /// longest. An evicted connection leaves the list at once.
    fn admit(&mut self, peer: IpAddr) -> Admission {
        let own = self.open.iter().filter(|(_, ip, _)| *ip == peer).count();
        let victim = if own >= self.max_per_peer {
            self.idle_longest(|ip| ip == peer)
        } else if self.open.len() >= self.max {
            self.idle_longest(|_| true)
        } else {
            return Admission::Admitted;
        };
        match victim {
            Some(index) => Admission::Evicted(self.open.swap_remove(index).2),
            None => Admission::Refused,
        }
    }

    /// The index of the connection of a peer `of` that is not inside a request and
    /// has (never requested, idle longest) first.
    fn idle_longest(&self, of: impl Fn(IpAddr) -> bool) -> Option<usize> {
        self.open
            .iter()
            .enumerate()
            .filter(|(_, (_, ip, activity))| {
                of(*ip) && !activity.in_request.load(Ordering::Relaxed)
            })
            .min_by_key(|(_, (_, _, activity))| {
                (activity.requested.load(Ordering::Relaxed), activity.last())
            })
            .map(|(index, _)| index)
    }

    fn insert(&mut self, id: u64, peer: IpAddr, activity: Arc<Activity>) {
        self.open.push((id, peer, activity));
    }

    /// The connection `id` ended (it may have been evicted already).
    fn remove(&mut self, id: u64) {
        self.open.retain(|(open, _, _)| *open != id);
    }
}

impl Connection {
    async fn serve(self, mut stream: TcpStream, mut shutdown: Shutdown) {
        let _ = stream.set_nodelay(true);
        tracing::debug!(peer = %self.peer, "HMI connected");
        let ended = tokio::select! {
            ended = self.requests(&mut stream) => ended,
            () = self.activity.evicted.notified() => "evicted for a new connection",
            () = shutdown.recv() => "server stopping",
        };
        tracing::debug!(peer = %self.peer, ended, "HMI connection ended");
    }

    /// Answer requests until the client leaves, idles, or sends what is not Modbus.
    async fn requests(&self, stream: &mut TcpStream) -> &'static str {
        let mut buffer = [0u8; 2 * MAX_FRAME_LEN];
        let mut filled = 0;
        let mut frame_started: Option<tokio::time::Instant> = None;
        let frame_timeout = FRAME_TIMEOUT.min(self.idle_timeout);
        let first_request_timeout = FIRST_REQUEST_TIMEOUT.min(self.idle_timeout);
        loop {
            // Answer every whole frame received so far.
            loop {
                match frame::frame_len(&buffer[..filled]) {
                    Ok(Some(len)) => {
                        let reply = frame::respond(&self.served, self.policy, &buffer[..len]);
                        buffer.copy_within(len..filled, 0);
                        filled -= len;
                        frame_started = None;
                        self.activity.answered();
                        match reply {
                            Reply::Send(bytes) => {
                                count(&self.counters.requests);
                                if frame::exception_code(&bytes).is_some() {
                                    count(&self.counters.exceptions);
                                }
                                if stream.write_all(&bytes).await.is_err() {
                                    return "write failed";
                                }
                            }
                            Reply::Broadcast => count(&self.counters.broadcasts),
                        }
                    }
                    Ok(None) => break,
                    Err(error) => {
                        count(&self.counters.not_modbus);
                        tracing::debug!(peer = %self.peer, %error, "not Modbus TCP, closing");
                        return "not Modbus TCP";
                    }
                }
            }
            // Idle: the idle timeout from now. Inside a request: its deadline runs from
            // its first byte, however slowly the rest trickles in.
            let requested = self.activity.requested.load(Ordering::Relaxed);
            self.activity
                .in_request
                .store(filled > 0, Ordering::Relaxed);
            let deadline = match (filled, frame_started) {
                (0, _) if !requested => {
                    frame_started = None;
                    self.activity.last() + first_request_timeout
                }
                (0, _) => {
                    frame_started = None;
                    tokio::time::Instant::now() + self.idle_timeout
                }
                (_, Some(started)) => started + frame_timeout,
                (_, None) => {
                    let now = tokio::time::Instant::now();
                    frame_started = Some(now);
                    now + frame_timeout
                }
            };
            match tokio::time::timeout_at(deadline, stream.read(&mut buffer[filled..])).await {
                Err(_) => {
                    count(&self.counters.idle_closed);
                    return match (filled, requested) {
                        (0, false) => {
                            count(&self.counters.silent_closed);
                            "no request"
                        }
                        (0, true) => "idle",
                        _ => "request not completed in time",
                    };
                }
                Ok(Ok(0)) => return "closed by the client",
                Ok(Ok(read)) => filled += read,
                Ok(Err(_)) => return "read failed",
            }
        }
    }
}
