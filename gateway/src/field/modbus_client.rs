//! What the gateway's Modbus TCP client tasks (the DAQ reader, the PLC writer) share:
//! connecting with a timeout (tokio-modbus has none), and reads and writes that check
//! the reply answers the request.

use std::borrow::Cow;
use std::time::Duration;

use millgate_config::RegisterTable;
use tokio::net::TcpStream;
use tokio_modbus::client::{Client, Context};
use tokio_modbus::prelude::{ExceptionCode, Request, Response, Slave};

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

/// A reply that decoded but does not answer its request: a faulty or hostile device.
/// The connection is out of step with it and is made again.
///
/// tokio-modbus 0.17's `Reader` and `Writer` methods only `debug_assert` these and
/// panic in a debug build, so the gateway calls [`Client::call`] itself and checks.
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
}

/// What a checked request gives: the transport's error, the reply's mismatch, or the
/// device's answer (its data, or the exception it refused the request with).
pub type Checked<T> = Result<Result<T, ExceptionCode>, CheckedError>;

/// Why a checked request got no usable answer.
#[derive(Debug, thiserror::Error)]
pub enum CheckedError {
    /// The connection failed or the reply could not be decoded.
    #[error(transparent)]
    Transport(#[from] tokio_modbus::Error),
    /// The reply does not answer the request.
    #[error(transparent)]
    Mismatch(#[from] ReplyMismatch),
}

/// Read `count` registers of `table` from `address` (FC 03 or 04); a reply with
/// another count is a [`ReplyMismatch`], never a panic.
pub async fn read_registers(
    context: &mut Context,
    table: RegisterTable,
    address: u16,
    count: u16,
) -> Checked<Vec<u16>> {
    let request = match table {
        RegisterTable::Input => Request::ReadInputRegisters(address, count),
        RegisterTable::Holding => Request::ReadHoldingRegisters(address, count),
    };
    let words = match context.call(request).await? {
        Ok(Response::ReadInputRegisters(words)) if table == RegisterTable::Input => words,
        Ok(Response::ReadHoldingRegisters(words)) if table == RegisterTable::Holding => words,
        Ok(_) => return Err(ReplyMismatch::Function.into()),
        Err(exception) => return Ok(Err(exception)),
    };
    if words.len() != usize::from(count) {
        return Err(ReplyMismatch::Registers {
            requested: count,
            answered: words.len(),
        }
        .into());
    }
    Ok(Ok(words))
}

/// Write `words` (at most 123) from `address` (FC 16); a reply echoing another
/// address or count is a [`ReplyMismatch`], never a panic.
pub async fn write_registers(context: &mut Context, address: u16, words: &[u16]) -> Checked<()> {
    let count = words.len() as u16;
    let request = Request::WriteMultipleRegisters(address, Cow::Borrowed(words));
    match context.call(request).await? {
        Ok(Response::WriteMultipleRegisters(echoed_address, echoed_count)) => {
            if (echoed_address, echoed_count) == (address, count) {
                Ok(Ok(()))
            } else {
                Err(ReplyMismatch::Echo {
                    address,
                    count,
                    echoed_address,
                    echoed_count,
                }
                .into())
            }
        }
        Ok(_) => Err(ReplyMismatch::Function.into()),
        Err(exception) => Ok(Err(exception)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncWriteExt;

    /// A client whose device has already sent `reply` (for transaction 0, the
    /// client's first) and hung up.
    async fn client_answered(reply: &[u8]) -> Context {
        let (client_io, mut device_io) = tokio::io::duplex(1024);
        device_io.write_all(reply).await.unwrap();
        // Keep the device's end open until the reply was read: leak it to the test.
        std::mem::forget(device_io);
        tokio_modbus::client::tcp::attach_slave(client_io, Slave(1))
    }

    #[tokio::test]
    async fn a_read_answered_with_fewer_registers_is_a_mismatch_not_a_panic() {
        // FC 04 reply with 2 registers (byte count 4) to a request for 3 (tokio-modbus's
        // Reader panicked on this in a debug build).
        let reply = [0, 0, 0, 0, 0, 7, 1, 4, 4, 0, 1, 0, 2];
        let mut context = client_answered(&reply).await;
        let read = read_registers(&mut context, RegisterTable::Input, 0, 3).await;
        match read {
            Err(CheckedError::Mismatch(mismatch)) => assert_eq!(
                mismatch,
                ReplyMismatch::Registers {
                    requested: 3,
                    answered: 2
                }
            ),
            other => panic!("expected a mismatch, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn a_read_of_the_other_table_or_the_right_count_is_checked() {
        let reply = [0, 0, 0, 0, 0, 7, 1, 3, 4, 0, 1, 0, 2];
        let mut context = client_answered(&reply).await;
        let read = read_registers(&mut context, RegisterTable::Holding, 0, 2).await;
        assert_eq!(read.unwrap().unwrap(), [1, 2]);
    }

    #[tokio::test]
    async fn a_write_echoed_with_another_count_is_a_mismatch_not_a_panic() {
        // FC 16 reply echoing address 0, count 1 to a write of 2 registers at 0.
        let reply = [0, 0, 0, 0, 0, 6, 1, 16, 0, 0, 0, 1];
        let mut context = client_answered(&reply).await;
        let written = write_registers(&mut context, 0, &[7, 8]).await;
        match written {
            Err(CheckedError::Mismatch(mismatch)) => assert_eq!(
                mismatch,
                ReplyMismatch::Echo {
                    address: 0,
                    count: 2,
                    echoed_address: 0,
                    echoed_count: 1
                }
            ),
            other => panic!("expected a mismatch, got {other:?}"),
        }
    }
}
