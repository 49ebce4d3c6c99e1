//! A virtual PLC: a Modbus TCP server whose holding registers the gateway writes.

use std::future::Future;
use std::io;

use tokio::net::TcpListener;

use super::modbus_bank::{serve, RegisterBank, Running, ServeOptions, SharedBank, WriteRecord};

/// A virtual PLC with `holding_len` writable holding registers.
#[derive(Debug, Clone)]
pub struct VirtualPlc {
    bank: SharedBank,
}

impl VirtualPlc {
    /// A PLC with zeroed holding registers.
    pub fn new(holding_len: usize) -> Self {
        Self {
            bank: SharedBank::new(RegisterBank::new(0, holding_len, true)),
        }
    }

    /// This PLC recording the time and words of every write (see
    /// [`VirtualPlc::take_write_log`]).
    pub fn logging_writes(self) -> Self {
        self.bank.lock().write_log = Some(Vec::new());
        self
    }

    /// The writes recorded since the last call (empty unless logging: see
    /// [`VirtualPlc::logging_writes`]), oldest first.
    pub fn take_write_log(&self) -> Vec<WriteRecord> {
        self.bank.take_write_log()
    }

    /// The register bank, for inspection by tests and the demo.
    pub fn bank(&self) -> SharedBank {
        self.bank.clone()
    }

    /// A copy of the holding registers.
    pub fn holding(&self) -> Vec<u16> {
        self.bank.lock().holding.clone()
    }

    /// Bit `bit` (0 = least significant) of holding register `address`; false beyond
    /// the table.
    pub fn holding_bit(&self, address: usize, bit: u16) -> bool {
        self.bank
            .lock()
            .holding
            .get(address)
            .is_some_and(|word| word & (1 << bit) != 0)
    }

    /// Write requests served so far.
    pub fn writes(&self) -> u64 {
        self.bank.lock().writes
    }

    /// Serve on `listener` in the background until the handle is stopped.
    pub fn spawn(&self, listener: TcpListener, options: ServeOptions) -> Running {
        let plc = self.clone();
        Running::spawn(|stop| plc.run(listener, options, stop.wait()))
    }

    /// Serve until `shutdown` completes.
    pub(crate) async fn run(
        self,
        listener: TcpListener,
        options: ServeOptions,
        shutdown: impl Future<Output = ()> + Send + Sync + 'static,
    ) -> io::Result<()> {
        serve(listener, self.bank, options, shutdown).await
    }
}
