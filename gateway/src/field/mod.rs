//! Field I/O: the reader tasks that turn DAQ register blocks (Modbus TCP or RTU) and CAN
//! frames (SocketCAN) into [`acquired::Acquired`] messages on the bounded channel to
//! analysis, with their counters and source health.

pub mod acquired;
pub(crate) mod backoff;
pub mod can;
pub mod counters;
pub(crate) mod metrics;
pub mod modbus;
pub mod quality;
pub mod source_health;
