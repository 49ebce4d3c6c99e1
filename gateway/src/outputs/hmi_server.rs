//! `ModbusServer`: serves the register map to HMIs and PLCs that poll.
//!
//! The map is readable with FC 03 (holding) and FC 04 (input) at the map's own
//! addresses (offset 0, independent of the PLC's `register_base`). Results are
//! read-only: only the documented command registers accept FC 06 / FC 16. A read
//! past the map, or a write that touches anything but a command register, gets
//! exception 02 (illegal data address); a bad command value or a malformed request
//! exception 03; other function codes exception 01. The framing and every answer are
//! in [`crate::outputs::modbus_frame`].
//!
//! Commands, handed to the analysis on its command channel: `command.acknowledge_alarms`
//! takes 0 (nothing) or 1 (clear latched alarms); `command.reset_wear_trend` takes a
//! bitmask of the first 16 drivelines (bit k = the k-th driveline in config order, 0 =
//! nothing) and refuses bits of drivelines that do not exist; `command.reset_wear` takes
//! a driveline's number (1-based, any count of drivelines). All read back 0. A command
//! the analysis cannot take now gets exception 06 (busy), and 04 while the gateway
//! stops. Only loopback clients may write them unless
//! `allow_remote_commands` is set (the registers need no authentication). The
//! history records who sent a command: the PLC when the client's address is the
//! configured PLC's, an HMI otherwise.
//!
//! Limits: at most `max_connections` clients at once (a further connection is
//! closed at once); a connection without a request for `idle_timeout` is closed, and
//! a request must arrive whole within [`FRAME_TIMEOUT`] (at most the idle timeout) of
//! its first byte, so a client trickling bytes (slowloris) holds a slot for seconds,
//! not forever. A stream that is not Modbus TCP is closed.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::ServerOutput;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio::task::JoinSet;

use crate::outputs::accept::AcceptFailures;
use crate::outputs::modbus_frame::{self, Policy, Reply, Served, MAX_FRAME_LEN};
use crate::shutdown::Shutdown;
use crate::state::commands::CommandOrigin;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Time a request may take from its first byte to its last.
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(5);

/// What the server has seen, for `/metrics`.
#[derive(Debug, Default)]
pub struct ServerCounters {
    connections: AtomicU64,
    refused: AtomicU64,
    idle_closed: AtomicU64,
    not_modbus: AtomicU64,
    requests: AtomicU64,
    exceptions: AtomicU64,
    broadcasts: AtomicU64,
}

/// A copy of [`ServerCounters`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServerCounts {
    /// Connections accepted and served.
    pub connections: u64,
    /// Connections closed at once: `max_connections` clients were connected.
    pub refused: u64,
    /// Connections closed for idling, or for a request not completed in time.
    pub idle_closed: u64,
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
    pub fn snapshot(&self) -> ServerCounts {
        let load = |counter: &AtomicU64| counter.load(Ordering::Relaxed);
        ServerCounts {
            connections: load(&self.connections),
            refused: load(&self.refused),
            idle_closed: load(&self.idle_closed),
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
pub fn exposure_warning(output: &ServerOutput) -> Option<String> {
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
pub struct ModbusServer {
    output: ServerOutput,
    served: Served,
    counters: Arc<ServerCounters>,
    plc_address: Option<String>,
}

impl ModbusServer {
    /// A server of `served` (its map, the board it encodes, where commands go) with
    /// the settings of `output`, counting into `counters`.
    pub fn new(output: ServerOutput, served: Served, counters: Arc<ServerCounters>) -> Self {
        Self {
            output,
            served,
            counters,
            plc_address: None,
        }
    }

    /// Commands from a client at the host of `plc_address` (`host:port`, the PLC
    /// output's) are recorded as the PLC's.
    pub fn with_plc_address(mut self, plc_address: Option<String>) -> Self {
        self.plc_address = plc_address;
        self
    }

    /// Serve on `listener` until shutdown; an error when accepting fails for good.
    pub async fn run(self, listener: TcpListener, mut shutdown: Shutdown) -> std::io::Result<()> {
        let local = listener.local_addr()?;
        tracing::info!(%local, max_connections = self.output.max_connections, "Modbus server listening");
        let slots = Arc::new(Semaphore::new(self.output.max_connections));
        let mut connections = JoinSet::new();
        let mut refusals = WarnLimit::new(WARN_PERIOD);
        let mut accept_failures = AcceptFailures::default();
        let plc_hosts: Vec<IpAddr> = match &self.plc_address {
            Some(address) => tokio::net::lookup_host(address.as_str())
                .await
                .map(|found| found.map(|a| a.ip()).collect())
                .unwrap_or_default(),
            None => Vec::new(),
        };
        loop {
            let accepted = tokio::select! {
                accepted = listener.accept() => accepted,
                () = shutdown.recv() => break,
                Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            };
            let Some((stream, peer)) = accept_failures.check(accepted, "Modbus server").await?
            else {
                continue;
            };
            let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
                count(&self.counters.refused);
                if let Some(suppressed) = refusals.occurred(tokio::time::Instant::now()) {
                    tracing::warn!(%peer, max = self.output.max_connections, suppressed, "Modbus server full, connection closed");
                }
                drop(stream);
                continue;
            };
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
            };
            let shutdown = shutdown.clone();
            connections.spawn(async move {
                connection.serve(stream, shutdown).await;
                drop(slot);
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
}

impl Connection {
    async fn serve(self, mut stream: TcpStream, mut shutdown: Shutdown) {
        let _ = stream.set_nodelay(true);
        tracing::debug!(peer = %self.peer, "HMI connected");
        let ended = tokio::select! {
            ended = self.requests(&mut stream) => ended,
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
        loop {
            // Answer every whole frame received so far.
            loop {
                match modbus_frame::frame_len(&buffer[..filled]) {
                    Ok(Some(len)) => {
                        let reply =
                            modbus_frame::respond(&self.served, self.policy, &buffer[..len]);
                        buffer.copy_within(len..filled, 0);
                        filled -= len;
                        frame_started = None;
                        match reply {
                            Reply::Send(bytes) => {
                                count(&self.counters.requests);
                                if modbus_frame::exception_code(&bytes).is_some() {
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
            let deadline = match (filled, frame_started) {
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
                    return if filled == 0 {
                        "idle"
                    } else {
                        "request not completed in time"
                    };
                }
                Ok(Ok(0)) => return "closed by the client",
                Ok(Ok(read)) => filled += read,
                Ok(Err(_)) => return "read failed",
            }
        }
    }
}
