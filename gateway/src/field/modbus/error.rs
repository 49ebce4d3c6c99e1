//! The one error type of the gateway's Modbus clients (the DAQ reader over TCP or RTU,
//! the PLC writer): the network failed (connect, timeout, transport, a reply out of step), or
//! the device refused (a Modbus exception), kept apart.

use std::time::Duration;

use tokio_modbus::prelude::ExceptionCode;

/// A reply that decoded but does not answer its request: a faulty or hostile device.
/// The connection is out of step with it and is made again.
///
/// tokio-modbus 0.17's `Reader` and `Writer` methods only `debug_assert` these and
/// panic in a debug build, so the gateway calls `Client::call` itself and checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReplyMismatch {
    /// A read answered with another number of registers than requested.
    #[error("{answered} registers answered for {requested} requested")]
    Registers {
        /// Registers of the request.
        requested: u16,
        /// Registers of the reply.
        answered: usize,
    },
    /// A write's reply echoed another address or count than the request's.
    #[error(
        "write of {count} registers at {address} echoed as {echoed_count} at {echoed_address}"
    )]
    Echo {
        /// First register of the request.
        address: u16,
        /// Registers of the request.
        count: u16,
        /// First register the reply names.
        echoed_address: u16,
        /// Count the reply names.
        echoed_count: u16,
    },
    /// The reply is of another function than the request (tokio-modbus rejects this;
    /// kept so no reply can panic).
    #[error("reply of another function")]
    Function,
    /// A reply whose transaction id or unit no request in flight has (requests in
    /// flight on a `link::TcpLink`).
    #[error("reply for transaction {id} of unit {unit}, which no request in flight has")]
    Header {
        /// The reply's transaction id.
        id: u16,
        /// The reply's unit id.
        unit: u8,
    },
}

/// Why a request to a Modbus device got no usable answer.
#[derive(Debug, thiserror::Error)]
pub enum ModbusError {
    /// No TCP connection could be made, or the serial device could not be opened
    /// ("the network failed").
    #[error("cannot connect to {address}: {source}")]
    Connect {
        /// The device's `host:port`, or its serial device path.
        address: String,
        /// Refused, unreachable, unresolvable, no such device, busy, ...
        source: std::io::Error,
    },
    /// The device did not answer in time.
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    /// The connection failed or the reply could not be decoded.
    #[error("transport: {0}")]
    Transport(#[from] tokio_modbus::Error),
    /// The reply does not answer the request (another register count, another echo).
    #[error("reply does not match the request: {0}")]
    Mismatch(#[from] ReplyMismatch),
    /// The device answered with a Modbus exception ("the device refused": a wrong
    /// address, write-protected registers).
    #[error("device refused register {address}: {exception}")]
    Exception {
        /// The first register of the request.
        address: u16,
        /// The exception code the device answered with.
        #[source]
        exception: ExceptionCode,
    },
}

impl ModbusError {
    /// Whether the connection must be dropped and made again: the network failed. A
    /// refusal keeps it.
    pub(crate) fn needs_reconnect(&self) -> bool {
        !matches!(self, ModbusError::Exception { .. })
    }
}
