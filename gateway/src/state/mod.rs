//! The shared vocabulary between the field and the stages that produce and consume
//! results: the results types and the [`catalogue`] that names every published figure
//! once, the live results [`board`], the history's events and its sending side, the
//! gap-map data, the commands the analysis takes and the [`latency`] histograms. `analysis` writes here, `outputs`
//! read here; neither imports the other.

pub mod board;
pub mod captures;
pub mod catalogue;
pub(crate) mod changes;
pub mod commands;
pub mod context;
pub mod events;
pub mod gap_maps;
pub mod history;
pub mod latency;
pub mod results;
pub mod time;
