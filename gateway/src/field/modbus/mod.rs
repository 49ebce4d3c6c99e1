//! Modbus field I/O: the DAQ reader task ([`reader::DaqReader`]) over the block
//! tracking of the acquisition layout (`block`), the client it uses ([`client`]:
//! connect, read within a timeout, replies checked), the TCP link with requests in
//! flight that the PLC writer and a reader whose source asks for it use (`link`),
//! and their one error type ([`ModbusError`]: the network failed, or the device
//! refused). A source on a serial line (Modbus RTU) is opened by `rtu.rs`, which also
//! keeps the silence between frames; reads are the same.

pub(crate) mod block;
pub mod client;
mod error;
pub(crate) mod link;
pub(crate) mod reader;
pub(crate) mod rtu;

pub use error::{ModbusError, ReplyMismatch};
pub use reader::{DaqReader, NewChannels};
