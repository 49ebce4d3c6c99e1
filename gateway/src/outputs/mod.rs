//! Outputs: the latest results, the register map that encodes them, and the tasks
//! that publish it: the PLC writer, the HMI Modbus server and the Prometheus metrics
//! (and the heartbeat's own task when there is no PLC).

pub(crate) mod heartbeat;
pub mod hmi_server;
pub mod metrics;
pub mod plc_writer;
pub mod publisher;
pub mod register_map;
pub mod results;
