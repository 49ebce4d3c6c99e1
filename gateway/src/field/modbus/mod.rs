//! Modbus field I/O: the DAQ reader task ([`reader::DaqReader`]) over the block
//! tracking of the acquisition layout (`block`), and the client both it and the PLC
//! writer use ([`client`]: connect, read and write within a timeout, replies checked)
//! with their one error type ([`ModbusError`]: the network failed, or the device
//! refused). A source on a serial line (Modbus RTU) is opened by `rtu.rs`, which also
//! keeps the silence between frames; reads and writes are the same.

pub(crate) mod block;
pub mod client;
mod error;
pub(crate) mod reader;
pub(crate) mod rtu;

pub use error::{ModbusError, ReplyMismatch};
pub use reader::{DaqReader, NewChannels};
