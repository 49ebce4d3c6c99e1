//! Outputs: the latest results, the register map that encodes them, and the tasks
//! that publish it: the PLC writer, the HMI Modbus server and the Prometheus metrics
//! (and the heartbeat's own task when there is no PLC); the event history that keeps
//! them across restarts; the maintenance web page; the OPC UA server (feature `opcua`).

pub(crate) mod accept;
pub(crate) mod heartbeat;
pub mod history;
pub mod hmi_server;
pub mod http_head;
pub mod metrics;
pub mod modbus_frame;
#[cfg(feature = "opcua")]
pub mod opcua;
pub mod plc_writer;
pub mod publisher;
pub mod register_map;
pub mod results;
pub mod sparkplug;
pub mod web;

/// How often the heartbeat moves when there is no PLC output (the PLC writer moves
/// it every write period otherwise).
pub fn heartbeat_period_without_plc() -> std::time::Duration {
    heartbeat::HEARTBEAT_WITHOUT_PLC
}
