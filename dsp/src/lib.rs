#![no_std]
#![doc = include_str!("../README.md")]

pub mod band_gain;
pub mod bite;
pub mod chatter;
pub mod filter;
pub mod fit;
pub mod mode_damping;
pub mod pencil;
pub mod stiffness;
pub mod transient;
