//! The DAQ reader's Modbus client: connecting over TCP with a timeout (tokio-modbus
//! has none; a serial line is opened by `rtu.rs`), and reads within a timeout that
//! check the reply answers the request, over TCP or RTU alike ([`ModbusError`] for
//! all, which the TCP link with requests in flight, `link.rs`, shares).

use std::time::Duration;

use millgate_config::RegisterTable;
use tokio::net::TcpStream;
use tokio_modbus::client::{Client, Context};
use tokio_modbus::prelude::{ExceptionCode, Request, Response, Slave};

use super::error::{ModbusError, ReplyMismatch};

/// Connect to `address` (`host:port`) within `timeout` and talk to `unit_id`.
pub(crate) async fn connect(
    address: &str,
    unit_id: u8,
    timeout: Duration,
) -> Result<Context, ModbusError> {
    let stream = connect_tcp(address, timeout).await?;
    Ok(tokio_modbus::client::tcp::attach_slave(
        stream,
        Slave(unit_id),
    ))
}

/// A TCP connection to the Modbus device at `address` (`host:port`), made within
/// `timeout` (the DAQ reader's and the PLC writer's).
pub(crate) async fn connect_tcp(
    address: &str,
    timeout: Duration,
) -> Result<TcpStream, ModbusError> {
    let stream = tokio::time::timeout(timeout, TcpStream::connect(address))
        .await
        .map_err(|_| ModbusError::Timeout(timeout))?
        .map_err(|source| ModbusError::Connect {
            address: address.to_owned(),
            source,
        })?;
    // Requests are small and frequent: do not let Nagle hold them back.
    let _ = stream.set_nodelay(true);
    Ok(stream)
}

/// What a checked request gives: the transport's error, the reply's mismatch, or the
/// device's answer (its data, or the exception it refused the request with).
type Checked<T> = Result<Result<T, ExceptionCode>, ModbusError>;

/// Read `count` registers of `table` from `address` within `timeout`.
pub async fn read(
    context: &mut Context,
    (table, address, count): (RegisterTable, u16, u16),
    timeout: Duration,
) -> Result<Vec<u16>, ModbusError> {
    let request = read_registers(context, table, address, count);
    let reply = tokio::time::timeout(timeout, request)
        .await
        .map_err(|_| ModbusError::Timeout(timeout))??;
    reply.map_err(|exception| ModbusError::Exception { address, exception })
}

/// Read `count` registers of `table` from `address` (FC 03 or 04); a reply with
/// another count is a [`ReplyMismatch`], never a panic.
async fn read_registers(
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
            Err(ModbusError::Mismatch(mismatch)) => assert_eq!(
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
}
