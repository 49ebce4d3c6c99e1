//! Modbus TCP field I/O: the DAQ reader task ([`reader::DaqReader`]) over the block
//! tracking of the acquisition layout ([`block`]), and the client both it and the PLC
//! writer use ([`client`]: connect, read and write within a timeout, replies checked)
//! with their one error type ([`ModbusError`]: the network failed, or the device
//! refused).

pub mod block;
pub mod client;
mod error;
pub mod reader;

pub use error::{ModbusError, ReplyMismatch};
pub use reader::{DaqError, DaqReader};
