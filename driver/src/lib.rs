//! placeholder
pub mod loadcell;
pub mod modbus;
pub mod tracker;
