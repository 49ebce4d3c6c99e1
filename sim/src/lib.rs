#![doc = include_str!("../README.md")]

pub mod can_node;
pub mod chain;
pub mod daq;
pub mod discrepancy;
pub mod modal;
pub mod modbus_bank;
pub mod model;
pub mod plc;
pub mod plot;
pub mod rod;
pub mod schedule;
pub mod stands;
pub mod tree;
pub mod wear_map;
