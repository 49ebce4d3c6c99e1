//! Outputs: the latest results, the register map that encodes them, and the tasks
//! that publish it: the PLC writer, the HMI Modbus server and the Prometheus metrics
//! (and the heartbeat's own task when there is no PLC); the event history that keeps
//! them across restarts.

pub(crate) mod heartbeat;
pub mod history;
pub mod hmi_server;
pub mod metrics;
pub mod plc_writer;
pub mod publisher;
pub mod register_map;
pub mod results;
pub mod sparkplug;
