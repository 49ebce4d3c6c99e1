#![no_std]
#![warn(missing_docs)]
#![doc = include_str!("../README.md")]

pub mod bite;
pub mod chatter;
pub mod fit;
mod linalg;
pub mod mathieu;
pub mod pencil;
pub mod stiffness;
pub mod testing;
pub mod transient;
