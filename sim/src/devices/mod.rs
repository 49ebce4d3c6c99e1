//! Virtual field devices, the peers the gateway is tested and demonstrated against:
//! a Modbus TCP DAQ streaming simulated channels ([`virtual_daq`]), a PLC whose
//! holding registers the gateway writes ([`virtual_plc`]), a CAN node sending DBC
//! messages on a SocketCAN interface ([`can_node`]), the Modbus server they share
//! ([`modbus_bank`]), the demo's rig built from them ([`demo`], its tandem mill [`demo_tandem`]), and the chatter
//! closed loop's real-time rig ([`tandem_rig`]: the online tandem mill streamed to the
//! field, the mill PLC obeying the gateway's slow-down request).
//!
//! Behind the `devices` feature (default): they need tokio, tokio-modbus, socketcan
//! and nix, which the physics does not.

pub mod can_node;
pub mod demo;
pub mod demo_tandem;
pub mod modbus_bank;
pub mod tandem_rig;
pub mod virtual_daq;
pub mod virtual_plc;
