//! The robot's protocols and device formats, without I/O: what the master (`taut-driver`) and
//! the device side (`taut-vdev`) must agree on, in one crate that both use and that opens no
//! socket, tty or thread.
//!
//! | module        | what                                                                      |
//! |---------------|---------------------------------------------------------------------------|
//! | [`can`]       | classic CAN [`can::Frame`]s, the [`can::CanTransport`] trait, acceptance filters |
//! | [`canopen`]   | CiA 301 services (NMT, SYNC, heartbeat, EMCY, SDO, PDO), the object dictionary entries taut uses, the CiA 402 profile |
//! | [`modbus`]    | Modbus RTU frames with CRC-16, register values, the byte-link trait       |
//! | [`tracker`]   | the tracker's pose line: parse and write                                  |
//! | [`devices`]   | the device tables of the robot configuration: CAN bus and drives, load cells, tracker |
//! | [`pdo_map`]   | PDO maps as the configuration gives them, and their rules                 |
//! | [`eds`]       | electronic data sheets (CiA 306)                                          |
//!
//! Everything here is sans-IO: frames, bytes and time in, frames, bytes and events out
//! ([`eds::Eds::load`] reads a file, nothing else touches the system). Codecs that run in the
//! real-time thread allocate nothing.
//!
//! ```
//! use taut_proto::canopen::nmt::{self, NmtCommand};
//! use taut_proto::modbus::rtu::{self, Function, Request};
//! let f = nmt::encode(NmtCommand::Start, 0);
//! assert_eq!(nmt::decode(&f), Some((NmtCommand::Start, 0)));
//! let mut buf = [0u8; rtu::MAX_FRAME];
//! let n = rtu::encode(&Request { unit: 1, function: Function::ReadHoldingRegisters, address: 0, quantity: 2 }, &mut buf);
//! assert_eq!(n, 8);
//! ```
#![deny(missing_docs)]

pub mod can;
pub mod canopen;
pub mod devices;
pub mod eds;
pub mod modbus;
pub mod pdo_map;
pub mod tracker;
