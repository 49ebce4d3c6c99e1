//! The Modbus outputs, mirroring `field/modbus/`: the [`register_map`] derived from
//! the catalogue, the [`plc_writer`] (FC 16 to the PLC, over `field::modbus::link`), the
//! `hmi_server` (reads and command registers), the [`frame`] codec they share, and the
//! heartbeat's own task when there is no PLC.

pub mod frame;
pub(crate) mod heartbeat;
pub(crate) mod hmi_server;
pub(crate) mod metrics;
pub mod plc_writer;
pub mod register_map;

/// How often the heartbeat moves when there is no PLC output (the PLC writer moves
/// it every write period otherwise).
pub fn heartbeat_period_without_plc() -> std::time::Duration {
    heartbeat::HEARTBEAT_WITHOUT_PLC
}
