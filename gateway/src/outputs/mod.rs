//! Outputs: the register map and the tasks that publish the board's results: the PLC
//! writer, the HMI Modbus server, the Prometheus metrics (and the heartbeat's own task
//! when there is no PLC), the event history that keeps them across restarts, the
//! Sparkplug B edge node, the maintenance web page and the OPC UA server (feature
//! `opcua`). Each names the figures as the catalogue does
//! ([`crate::state::catalogue`]); `figures` renders the table of every output's name
//! and type for each figure. Each writes its own counters' `/metrics` families (the
//! `metrics.rs` beside it), which `metrics` serves.

pub(crate) mod accept;
pub(crate) mod figures;
pub(crate) mod http;
pub(crate) mod metrics;
pub mod modbus;
// The OPC UA server; built without the `opcua` feature, its stand-in
// (`opcua_not_built.rs`: the same names, refusing `[outputs.opcua]`).
#[cfg_attr(not(feature = "opcua"), path = "opcua_not_built.rs")]
pub mod opcua;
pub mod sparkplug;
pub(crate) mod web;
