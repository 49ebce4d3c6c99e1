//! The experiments' harnesses, apart from the test support: the race of chatter
//! detectors on the physical tandem model ([`chatter_eval`]), the chatter closed loop
//! offline ([`chatter_loop`]), per-product chatter thresholds against one mill-wide
//! threshold ([`chatter_products`]) and the wear forecast's calibration
//! ([`wear_forecast`]).
//! Their tests (`tests/tests/chatter_eval.rs`, `tests/tests/chatter_loop.rs`,
//! `tests/tests/wear_forecast.rs`) run the quick plans; the docs' tables come from the
//! full ones (`tests/examples/chatter_loop.rs`, `CHATTER_EVAL=full`,
//! `WEAR_FORECAST=full`).

pub mod chatter_eval;
pub mod chatter_loop;
pub mod chatter_products;
pub mod wear_forecast;
