#![doc = include_str!("../README.md")]

pub mod chain;
pub mod modal;
pub mod model;
