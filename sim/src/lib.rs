#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod chain;
#[cfg(feature = "devices")]
pub mod devices;
pub mod discrepancy;
pub mod modal;
pub mod model;
#[cfg(feature = "plot")]
pub mod plot;
pub mod rod;
pub mod schedule;
pub mod tandem;
pub(crate) mod tree;
pub mod wear_growth;
pub mod wear_map;
