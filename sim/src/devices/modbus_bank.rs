//! A Modbus TCP server over an in-memory register bank: the wire side of the
//! virtual DAQ and the virtual PLC.
//!
//! The bank has input registers (FC 04, read-only) and holding registers (FC 03,
//! written with FC 06 / FC 16 when the bank allows it). Reads or writes outside a
//! table get exception 02 (illegal data address), other function codes exception 01.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::SystemTime;

use tokio::net::{TcpListener, TcpStream};
use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_modbus::server::tcp::Server;

/// Register tables of one virtual device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegisterBank {
    /// Input registers, FC 04.
    pub(crate) input: Vec<u16>,
    /// Holding registers, FC 03 / 06 / 16.
    pub holding: Vec<u16>,
    /// Whether clients may write holding registers.
    pub(crate) holding_writable: bool,
    /// Number of successful write requests (FC 06 / FC 16) served.
    pub(crate) writes: u64,
    /// When `Some`, every successful write is also recorded here with its time (a
    /// virtual PLC watched by a latency benchmark; whoever reads it drains it).
    pub(crate) write_log: Option<Vec<WriteRecord>>,
    /// When `Some`, every successful input-register read (FC 04) is also recorded
    /// here with its time and first word (a virtual DAQ watched by a latency
    /// benchmark: a block's first word is its sequence; whoever reads it drains it).
    pub(crate) read_log: Option<Vec<ReadRecord>>,
    /// Number of successful reads (FC 03 / FC 04) served.
    pub(crate) reads: u64,
}

/// One successful input-register read, as recorded in the read log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadRecord {
    /// When the server answered it.
    pub time: SystemTime,
    /// First register read.
    pub address: u16,
    /// The value of that register in the answer.
    pub first_word: u16,
}

/// One successful write to the holding registers, as recorded in the write log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WriteRecord {
    /// When the server applied it (the wall clock, as a PLC would stamp it).
    pub time: SystemTime,
    /// First register written.
    pub address: u16,
    /// The words written from `address` on.
    pub words: Vec<u16>,
}

impl RegisterBank {
    /// A bank of zeroed tables.
    pub(crate) fn new(input_len: usize, holding_len: usize, holding_writable: bool) -> Self {
        Self {
            input: vec![0; input_len],
            holding: vec![0; holding_len],
            holding_writable,
            writes: 0,
            write_log: None,
            read_log: None,
            reads: 0,
        }
    }

    fn read(table: &[u16], address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
        let start = usize::from(address);
        let end = start + usize::from(count);
        if count == 0 || count > 125 {
            return Err(ExceptionCode::IllegalDataValue);
        }
        table
            .get(start..end)
            .map(<[u16]>::to_vec)
            .ok_or(ExceptionCode::IllegalDataAddress)
    }

    fn write(&mut self, address: u16, words: &[u16]) -> Result<(), ExceptionCode> {
        if !self.holding_writable {
            return Err(ExceptionCode::IllegalFunction);
        }
        let start = usize::from(address);
        let target = self
            .holding
            .get_mut(start..start + words.len())
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        target.copy_from_slice(words);
        self.writes += 1;
        if let Some(log) = self.write_log.as_mut() {
            log.push(WriteRecord {
                time: SystemTime::now(),
                address,
                words: words.to_vec(),
            });
        }
        Ok(())
    }

    /// Answer one Modbus request against the bank.
    pub(crate) fn handle(&mut self, request: &Request<'_>) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadInputRegisters(address, count) => {
                let words = Self::read(&self.input, *address, *count)?;
                self.reads += 1;
                if let Some(log) = self.read_log.as_mut() {
                    log.push(ReadRecord {
                        time: SystemTime::now(),
                        address: *address,
                        first_word: words[0],
                    });
                }
                Ok(Response::ReadInputRegisters(words))
            }
            Request::ReadHoldingRegisters(address, count) => {
                let words = Self::read(&self.holding, *address, *count)?;
                self.reads += 1;
                Ok(Response::ReadHoldingRegisters(words))
            }
            Request::WriteSingleRegister(address, word) => self
                .write(*address, &[*word])
                .map(|()| Response::WriteSingleRegister(*address, *word)),
            Request::WriteMultipleRegisters(address, words) => {
                let count =
                    u16::try_from(words.len()).map_err(|_| ExceptionCode::IllegalDataValue)?;
                self.write(*address, words)
                    .map(|()| Response::WriteMultipleRegisters(*address, count))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// A register bank shared between the server task and the device logic.
#[derive(Debug, Clone)]
pub struct SharedBank(Arc<Mutex<RegisterBank>>);

impl SharedBank {
    /// Share `bank`.
    pub(crate) fn new(bank: RegisterBank) -> Self {
        Self(Arc::new(Mutex::new(bank)))
    }

    /// Lock the bank. A panic while holding the lock cannot leave the tables
    /// inconsistent (every update is a plain copy), so a poisoned lock is recovered.
    pub fn lock(&self) -> MutexGuard<'_, RegisterBank> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The writes recorded since the last call (empty unless logging: see
    /// [`RegisterBank::write_log`]), oldest first.
    pub(crate) fn take_write_log(&self) -> Vec<WriteRecord> {
        self.lock()
            .write_log
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// The reads recorded since the last call (empty unless logging: see
    /// `RegisterBank::read_log`), oldest first.
    pub fn take_read_log(&self) -> Vec<ReadRecord> {
        self.lock()
            .read_log
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }
}

/// How the server accepts clients.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServeOptions {
    /// Answer only this unit id (0 and 255 are always accepted, as TCP devices do).
    pub unit_id: u8,
    /// Accept one connection at a time and refuse others, as many small DAQs do.
    pub single_connection: bool,
}

impl Default for ServeOptions {
    /// Unit 1, any number of connections.
    fn default() -> Self {
        Self {
            unit_id: 1,
            single_connection: false,
        }
    }
}

/// A virtual device serving in the background, until [`Running::stop`].
#[derive(Debug)]
pub struct Running {
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<io::Result<()>>,
}

impl Running {
    /// Spawn `run`, handing it the future that completes when [`Running::stop`] is
    /// called (or the handle is dropped).
    pub(crate) fn spawn<F>(run: impl FnOnce(StopSignal) -> F) -> Self
    where
        F: Future<Output = io::Result<()>> + Send + 'static,
    {
        let (stop, stopped) = tokio::sync::oneshot::channel();
        let signal = StopSignal(stopped);
        Self {
            stop,
            task: tokio::spawn(run(signal)),
        }
    }

    /// Stop the device and wait for it; its serving error, if any.
    pub async fn stop(self) -> io::Result<()> {
        let _ = self.stop.send(());
        self.task.await.map_err(io::Error::other)?
    }
}

/// Completes when the owning [`Running`] is stopped or dropped.
#[derive(Debug)]
pub(crate) struct StopSignal(tokio::sync::oneshot::Receiver<()>);

impl StopSignal {
    /// Wait for the stop request.
    pub(crate) async fn wait(self) {
        let _ = self.0.await;
    }
}

struct BankService {
    bank: SharedBank,
    unit_id: u8,
    open_connections: Arc<AtomicUsize>,
}

impl Drop for BankService {
    fn drop(&mut self) {
        self.open_connections.fetch_sub(1, Ordering::SeqCst);
    }
}

impl tokio_modbus::server::Service for BankService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, request: Self::Request) -> Self::Future {
        let addressed_to_us = matches!(request.slave, 0 | 255) || request.slave == self.unit_id;
        if !addressed_to_us {
            // A gateway would answer 0x0B; a plain TCP device stays silent.
            return std::future::ready(Ok(None));
        }
        std::future::ready(self.bank.lock().handle(&request.request).map(Some))
    }
}

/// Serve `bank` on `listener` until `shutdown` completes.
pub(crate) async fn serve(
    listener: TcpListener,
    bank: SharedBank,
    options: ServeOptions,
    shutdown: impl Future<Output = ()> + Send + Sync + 'static,
) -> io::Result<()> {
    let open_connections = Arc::new(AtomicUsize::new(0));
    let server = Server::new(listener);
    let on_connected = |stream: TcpStream, peer: SocketAddr| {
        let bank = bank.clone();
        let open_connections = Arc::clone(&open_connections);
        async move {
            let already_open = open_connections.fetch_add(1, Ordering::SeqCst);
            if options.single_connection && already_open > 0 {
                open_connections.fetch_sub(1, Ordering::SeqCst);
                tracing::debug!(%peer, "refusing a second connection");
                return Ok(None);
            }
            let service = BankService {
                bank,
                unit_id: options.unit_id,
                open_connections,
            };
            Ok(Some((service, stream)))
        }
    };
    let on_process_error = |error| tracing::debug!(%error, "modbus connection ended");
    server
        .serve_until(&on_connected, on_process_error, shutdown)
        .await
        .map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_inside_tables_and_refuses_outside() {
        let mut bank = RegisterBank::new(4, 4, false);
        bank.input.copy_from_slice(&[1, 2, 3, 4]);
        assert_eq!(
            bank.handle(&Request::ReadInputRegisters(1, 2)),
            Ok(Response::ReadInputRegisters(vec![2, 3]))
        );
        assert_eq!(
            bank.handle(&Request::ReadInputRegisters(3, 2)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            bank.handle(&Request::WriteSingleRegister(0, 7)),
            Err(ExceptionCode::IllegalFunction)
        );
        assert_eq!(
            bank.handle(&Request::ReadCoils(0, 1)),
            Err(ExceptionCode::IllegalFunction)
        );
    }

    #[test]
    fn writable_holding_registers_take_writes() {
        let mut bank = RegisterBank::new(0, 4, true);
        let words = std::borrow::Cow::Owned(vec![9, 8]);
        assert_eq!(
            bank.handle(&Request::WriteMultipleRegisters(2, words)),
            Ok(Response::WriteMultipleRegisters(2, 2))
        );
        assert_eq!(bank.holding, vec![0, 0, 9, 8]);
        assert_eq!(bank.writes, 1);
        assert_eq!(bank.write_log, None, "no log unless asked for");
        bank.write_log = Some(Vec::new());
        let too_far = std::borrow::Cow::Owned(vec![1, 1]);
        assert_eq!(
            bank.handle(&Request::WriteMultipleRegisters(3, too_far)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        let before = SystemTime::now();
        bank.handle(&Request::WriteSingleRegister(1, 5)).unwrap();
        let log = bank.write_log.as_ref().unwrap();
        assert_eq!(log.len(), 1, "only the write that was applied: {log:?}");
        assert_eq!((log[0].address, log[0].words.as_slice()), (1, &[5][..]));
        assert!(log[0].time >= before);
    }

    #[test]
    fn input_reads_are_logged_with_their_first_word_when_asked() {
        let mut bank = RegisterBank::new(4, 0, false);
        bank.input = vec![7, 8, 9, 10];
        bank.handle(&Request::ReadInputRegisters(1, 2)).unwrap();
        assert_eq!(bank.read_log, None, "no log unless asked for");
        bank.read_log = Some(Vec::new());
        let before = SystemTime::now();
        assert!(bank.handle(&Request::ReadInputRegisters(3, 2)).is_err());
        bank.handle(&Request::ReadInputRegisters(2, 2)).unwrap();
        let log = bank.read_log.as_ref().unwrap();
        assert_eq!(log.len(), 1, "only the read that was answered: {log:?}");
        assert_eq!((log[0].address, log[0].first_word), (2, 9));
        assert!(log[0].time >= before);
    }
}
