//! Modbus RTU master for the RS-485 load cells.
//!
//! - [`link`]: the byte link on a real serial port ([`link::SerialPortLink`]).
//! - [`master`]: one transaction with timeout and retries, counters, reconnect back-off.
//!
//! The frame codec, the register values and the link trait are `taut_proto::modbus`. The I/O
//! thread that polls every cell and feeds the real-time loop is [`crate::loadcell`].

pub mod link;
pub mod master;
