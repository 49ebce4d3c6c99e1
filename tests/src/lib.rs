//! millgate's end-to-end tests across crates (`tests/`), and what every test of the
//! workspace shares:
//!
//! - [`kit`]: the test kit (scratch folders, the `millgate` binary and service, the
//!   demo's devices, the reference ramp and stand configurations, peers, brokers,
//!   hostile devices), used by `tests/tests`, `gateway/tests`, `gateway/benches` and
//!   the examples;
//! - [`experiments`]: the chatter experiments' harnesses, apart from test support: the
//!   detectors' race ([`experiments::chatter_eval`]) and the closed loop offline
//!   ([`experiments::chatter_loop`]: the online tandem mill and its automation with the
//!   gateway's own monitor fed each block, the runs of the README's closed-loop table;
//!   the real-time runs through the service are `tests/chatter_loop_e2e.rs` over
//!   Modbus and `tests/vcan.rs` over CAN, on `millgate_sim::devices::tandem_rig`).

pub mod experiments;
pub mod kit;
