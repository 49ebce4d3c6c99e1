//! `ModbusServer`: serves the register map to HMIs and PLCs that poll.
//!
//! The map is readable with FC 03 (holding) and FC 04 (input) at the map's own
//! addresses (offset 0, independent of the PLC's `register_base`). Results are
//! read-only: only the documented command registers accept FC 06 / FC 16. A read
//! past the map, or a write that touches anything but a command register, gets
//! exception 02 (illegal data address); a bad command value exception 03; other
//! function codes exception 01.
//!
//! Commands: `command.acknowledge_alarms` takes 0 (nothing) or 1 (clear latched
//! alarms); `command.reset_wear_trend` takes a bitmask of drivelines (bit k = the
//! k-th driveline in config order, 0 = nothing) and refuses bits of drivelines that
//! do not exist. Both read back 0. The history records who sent a command: the PLC
//! when the client's address is the configured PLC's, an HMI otherwise.

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

use millgate_config::ServerOutput;
use tokio::net::{TcpListener, TcpStream};
use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_modbus::server::tcp::Server;

use crate::outputs::history::events::CommandOrigin;
use crate::outputs::publisher::Publisher;
use crate::outputs::register_map::{Access, Field};
use crate::shutdown::Shutdown;

/// Largest register count of one read request (FC 03 / 04).
const MAX_READ_REGISTERS: u16 = 125;

/// Answer one request of `origin` against the published map. Pure apart from the
/// command side effects on `publisher`; the socket side is in [`ModbusServer::run`].
pub fn answer(
    publisher: &Publisher,
    request: &Request<'_>,
    origin: CommandOrigin,
) -> Result<Response, ExceptionCode> {
    match request {
        Request::ReadHoldingRegisters(address, count) => {
            read(publisher, *address, *count).map(Response::ReadHoldingRegisters)
        }
        Request::ReadInputRegisters(address, count) => {
            read(publisher, *address, *count).map(Response::ReadInputRegisters)
        }
        Request::WriteSingleRegister(address, value) => {
            write(publisher, *address, &[*value], origin)
                .map(|()| Response::WriteSingleRegister(*address, *value))
        }
        Request::WriteMultipleRegisters(address, values) => {
            let count = values.len() as u16;
            write(publisher, *address, values, origin)
                .map(|()| Response::WriteMultipleRegisters(*address, count))
        }
        _ => Err(ExceptionCode::IllegalFunction),
    }
}

fn read(publisher: &Publisher, address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
    if count == 0 || count > MAX_READ_REGISTERS {
        return Err(ExceptionCode::IllegalDataValue);
    }
    let words = publisher.words();
    let start = usize::from(address);
    words
        .get(start..start + usize::from(count))
        .map(<[u16]>::to_vec)
        .ok_or(ExceptionCode::IllegalDataAddress)
}

fn write(
    publisher: &Publisher,
    address: u16,
    values: &[u16],
    origin: CommandOrigin,
) -> Result<(), ExceptionCode> {
    let map = publisher.map();
    let mut commands = Vec::with_capacity(values.len());
    for (offset, &value) in values.iter().enumerate() {
        let target = address
            .checked_add(offset as u16)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        match map.find(target) {
            Some(register) if register.access == Access::ReadWrite => {
                commands.push((register.field, value))
            }
            _ => return Err(ExceptionCode::IllegalDataAddress),
        }
    }
    // Validate every value before acting on any, so a rejected request changes nothing.
    let drivelines = publisher.driveline_names().len();
    if commands
        .iter()
        .any(|(field, value)| !command_value_valid(*field, *value, drivelines))
    {
        return Err(ExceptionCode::IllegalDataValue);
    }
    for (field, value) in commands {
        match field {
            Field::AcknowledgeAlarms if value == 1 => {
                tracing::info!(by = origin.name(), peer = ?origin.peer(), "alarms acknowledged over Modbus");
                publisher.acknowledge_alarms(origin);
            }
            Field::ResetWearTrend if value != 0 => {
                tracing::info!(
                    drivelines = format!("{value:#b}"),
                    by = origin.name(),
                    peer = ?origin.peer(),
                    "wear trend reset over Modbus"
                );
                publisher.reset_wear_trend(value, origin);
            }
            _ => {}
        }
    }
    Ok(())
}

/// Whether `value` is a valid write to command register `field` in a map of
/// `drivelines` drivelines.
fn command_value_valid(field: Field, value: u16, drivelines: usize) -> bool {
    match field {
        Field::AcknowledgeAlarms => value <= 1,
        Field::ResetWearTrend => {
            let all = if drivelines >= 16 {
                u16::MAX
            } else {
                (1u16 << drivelines) - 1
            };
            value & !all == 0
        }
        _ => false,
    }
}

struct MapService {
    publisher: Arc<Publisher>,
    unit_id: u8,
    origin: CommandOrigin,
}

impl tokio_modbus::server::Service for MapService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, request: Self::Request) -> Self::Future {
        if !(matches!(request.slave, 0 | 255) || request.slave == self.unit_id) {
            return std::future::ready(Ok(None));
        }
        std::future::ready(answer(&self.publisher, &request.request, self.origin).map(Some))
    }
}

/// The gateway's Modbus TCP server.
#[derive(Debug)]
pub struct ModbusServer {
    output: ServerOutput,
    publisher: Arc<Publisher>,
    plc_address: Option<String>,
}

impl ModbusServer {
    /// A server of `publisher`'s map with the settings of `output`.
    pub fn new(output: ServerOutput, publisher: Arc<Publisher>) -> Self {
        Self {
            output,
            publisher,
            plc_address: None,
        }
    }

    /// Commands from a client at the host of `plc_address` (`host:port`, the PLC
    /// output's) are recorded as the PLC's.
    pub fn with_plc_address(mut self, plc_address: Option<String>) -> Self {
        self.plc_address = plc_address;
        self
    }

    /// Bind the configured address.
    pub async fn bind(&self) -> std::io::Result<TcpListener> {
        TcpListener::bind(self.output.bind).await
    }

    /// Serve on `listener` until shutdown.
    pub async fn run(self, listener: TcpListener, mut shutdown: Shutdown) -> std::io::Result<()> {
        let local = listener.local_addr()?;
        tracing::info!(%local, "Modbus server listening");
        let server = Server::new(listener);
        let plc_hosts: Vec<IpAddr> = match &self.plc_address {
            Some(address) => tokio::net::lookup_host(address.as_str())
                .await
                .map(|found| found.map(|a| a.ip()).collect())
                .unwrap_or_default(),
            None => Vec::new(),
        };
        let publisher = self.publisher;
        let unit_id = self.output.unit_id;
        let on_connected = |stream: TcpStream, peer: SocketAddr| {
            let origin = if plc_hosts.contains(&peer.ip()) {
                CommandOrigin::Plc(peer)
            } else {
                CommandOrigin::Hmi(peer)
            };
            let service = MapService {
                publisher: Arc::clone(&publisher),
                unit_id,
                origin,
            };
            async move {
                tracing::debug!(%peer, "HMI connected");
                Ok(Some((service, stream)))
            }
        };
        let on_process_error = |error| tracing::debug!(%error, "HMI connection ended");
        server
            .serve_until(&on_connected, on_process_error, async move {
                shutdown.recv().await
            })
            .await
            .map(|_| ())
    }
}
