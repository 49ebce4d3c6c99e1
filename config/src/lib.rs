#![doc = include_str!("../README.md")]

pub mod layout;
pub mod signal;
mod types;

pub use types::*;
