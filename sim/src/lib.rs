#![doc = include_str!("../README.md")]

pub mod chain;
#[cfg(feature = "devices")]
pub mod devices;
pub mod discrepancy;
pub mod modal;
pub mod model;
#[cfg(feature = "plot")]
pub mod plot;
pub mod schedule;
pub mod stands;
pub mod wear_map;
