#![no_std]
#![warn(missing_docs)]
#![doc = include_str!("../README.md")]

pub mod band_gain;
pub mod bite;
pub mod chatter;
pub mod filter;
pub mod fit;
mod linalg;
pub mod mathieu;
pub mod miner;
pub mod mode_damping;
pub mod noise;
pub mod pencil;
pub mod rainflow;
pub mod stiffness;
pub mod testing;
pub mod transient;
pub mod wear_trend;
