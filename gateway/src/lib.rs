//! millgate: the edge gateway's library. The `millgate` binary only parses the
//! command line and calls into it; [`service::run`] is the service.

pub mod analysis;
pub mod can;
pub mod chatter;
pub mod check;
pub mod daq;
pub mod demo;
pub mod export;
pub mod health;
pub mod metrics;
mod modbus_client;
pub mod offline;
pub mod plc;
pub mod publish;
pub mod registers;
pub mod results;
pub mod rodcmd;
pub mod samples;
pub mod server;
pub mod service;
pub mod shutdown;
pub mod simcmd;
pub mod wear;

pub use service::{run, Service};

/// Lock a mutex whose data stays consistent even if a holder panicked (every
/// update in this crate is a whole-value assignment), recovering a poisoned lock.
pub(crate) fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}
