//! Modbus RTU master for the RS-485 load cells.
//!
//! - [`crc`] and [`rtu`]: the sans-IO frame codec (CRC-16, request/response/exception frames,
//!   frame lengths, inter-frame timing).
//! - [`value`]: two registers to a tension in newtons (int32 / float32, word order, scale,
//!   offset).
//! - [`link`]: the byte link trait and its `serialport` implementation.
//! - [`master`]: one transaction with timeout and retries, counters, reconnect back-off.
//!
//! The I/O thread that polls every cell and feeds the real-time loop is [`crate::loadcell`].
//!
//! ```
//! use taut_driver::modbus::rtu::{self, Function, Request};
//! let mut buf = [0u8; rtu::MAX_FRAME];
//! let n = rtu::encode(&Request { unit: 1, function: Function::ReadHoldingRegisters, address: 0, quantity: 10 }, &mut buf);
//! assert_eq!(&buf[..n], &[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD]);
//! ```

pub mod crc;
pub mod link;
pub mod master;
pub mod rtu;
pub mod value;
