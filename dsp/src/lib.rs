#![no_std]
#![doc = include_str!("../README.md")]

pub mod bite;
pub mod chatter;
pub mod fit;
pub mod mathieu;
pub mod pencil;
pub mod stiffness;
pub mod transient;
