//! CAN transports: the only code in the driver that opens sockets.
//!
//! The protocol code only sees [`Frame`]s; a [`CanTransport`] (both from `taut_proto::can`) moves
//! them. Three implementations prove the seam: [`socketcan::SocketCanTransport`] (real hardware
//! and vcan), [`virtual_bus::VirtualBus`] (in-process, deterministic, for the simulator, tests
//! and benchmarks) and [`candump`] (record a session to a `candump -l` log, replay a log).

pub mod candump;
pub mod kernel;
pub mod socketcan;
pub mod virtual_bus;

pub use taut_model::bus::{BusEvent, IfName};

use taut_proto::can::{CanTransport, Filter, Frame, TransportError, MAX_EXT_ID, MAX_STD_ID};
