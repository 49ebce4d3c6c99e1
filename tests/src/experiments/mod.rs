//! The chatter experiments' harnesses, apart from the test support: the race of
//! chatter detectors on the physical tandem model ([`chatter_eval`]) and the chatter
//! closed loop offline ([`chatter_loop`]). Their tests (`tests/tests/chatter_eval.rs`,
//! `tests/tests/chatter_loop.rs`) run the quick plans; the README's tables come from
//! the full ones (`tests/examples/chatter_loop.rs`, `CHATTER_EVAL=full`).

pub mod chatter_eval;
pub mod chatter_loop;
