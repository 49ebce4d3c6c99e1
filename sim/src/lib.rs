#![doc = include_str!("../README.md")]

pub mod can_node;
pub mod chain;
pub mod modal;
pub mod model;
pub mod plot;
pub mod wear_map;
