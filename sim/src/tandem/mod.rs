//! A physical tandem cold mill for chatter studies (domain note `chatter-model.md`):
//! per stand the top half of the vertical roll stack, the roll-gap force and forward
//! slip linearised about a pass schedule, interstand tension driven by mass flow and
//! thickness carried between stands with the transport delay; excitation, a speed ramp
//! and accelerometers on the backup-roll chocks; the characteristic roots, the critical
//! speed and the ground truth of a run (onset, developed chatter).
//!
//! - `schedule`: the pass schedule file (TOML).
//! - [`rollgap`]: quasi-static roll gap (Hill, Hitchcock, Bland-Ford) and its partials.
//! - `linear`: the linearised mill, `x' = A(s) x + delayed terms + inputs`.
//! - [`roots`]: characteristic roots with the delays, the critical speed.
//! - [`simulate`]: time simulation with excitation, a speed ramp and accelerometers.
//! - [`truth`]: the ground truth of a run: critical speed, onset, developed chatter.
//! - [`control`]: the mill's speed automation obeying a chatter slow-down request.
//! - [`online`]: the mill simulated one PLC cycle at a time, its speed set by the
//!   automation while it runs (the closed loop's plant).

pub mod control;
pub(crate) mod linear;
pub mod online;
pub mod rollgap;
pub mod roots;
pub(crate) mod schedule;
pub mod simulate;
pub mod truth;

pub use linear::TandemMill;
pub use schedule::PassSchedule;
