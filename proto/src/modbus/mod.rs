//! Modbus RTU for the RS-485 load cells, sans-IO, for the master and the device side alike.
//!
//! - [`crc`] and [`rtu`]: the frame codec (CRC-16, request/response/exception frames, frame
//!   lengths, inter-frame timing).
//! - [`value`]: two registers to a tension in newtons (int32 / float32, word order, scale,
//!   offset).
//! - [`link`]: the byte link trait both ends talk through, and its error.
//!
//! The master (transactions, retries, the serial port, the I/O thread) is
//! `taut_driver::modbus`; the virtual load cells are `taut-vdev`'s.
//!
//! ```
//! use taut_proto::modbus::rtu::{self, Function, Request};
//! let mut buf = [0u8; rtu::MAX_FRAME];
//! let n = rtu::encode(&Request { unit: 1, function: Function::ReadHoldingRegisters, address: 0, quantity: 10 }, &mut buf);
//! assert_eq!(&buf[..n], &[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD]);
//! ```

pub mod crc;
pub mod link;
pub mod rtu;
pub mod value;
