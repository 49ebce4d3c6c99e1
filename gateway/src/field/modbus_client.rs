//! What the gateway's Modbus TCP client tasks (the DAQ reader, the PLC writer) share:
//! connecting with a timeout (tokio-modbus has none).

use std::time::Duration;

use tokio::net::TcpStream;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::Slave;

/// Why a connection could not be made.
#[derive(Debug)]
pub(crate) enum ConnectError {
    /// No answer within the timeout.
    Timeout(Duration),
    /// Refused, unreachable, unresolvable, ...
    Io(std::io::Error),
}

/// Connect to `address` (`host:port`) within `timeout` and talk to `unit_id`.
pub(crate) async fn connect(
    address: &str,
    unit_id: u8,
    timeout: Duration,
) -> Result<Context, ConnectError> {
    let stream = tokio::time::timeout(timeout, TcpStream::connect(address))
        .await
        .map_err(|_| ConnectError::Timeout(timeout))?
        .map_err(ConnectError::Io)?;
    // Requests are small and frequent: do not let Nagle hold them back.
    let _ = stream.set_nodelay(true);
    Ok(tokio_modbus::client::tcp::attach_slave(
        stream,
        Slave(unit_id),
    ))
}
