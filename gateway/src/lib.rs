#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod analysis;
pub mod cli;
pub mod exposition;
pub mod field;
pub mod history;
pub mod logging;
pub mod outputs;
pub mod records;
pub mod service;
pub mod shutdown;
pub mod state;
pub mod supervision;
#[cfg(test)]
mod testing;
mod warn_limit;

pub use service::{run, Service};

/// Lock a mutex whose data stays consistent even if a holder panicked (every
/// update in this crate is a whole-value assignment), recovering a poisoned lock.
pub(crate) fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}
