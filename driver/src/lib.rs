//! Device drivers of the robot: the CAN transport ([`transport`]), the CANopen master and CiA 402
//! drive profile ([`canopen`]).
//!
//! Protocol code is sans-IO (frames and time in, frames and events out); only [`transport`]
//! opens sockets.
//!
//! ```no_run
//! use taut_driver::canopen::master::{Master, MasterConfig};
//! use taut_driver::transport::{socketcan::SocketCanTransport, CanTransport};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! let mut bus = SocketCanTransport::open("can0").unwrap();
//! let mut master = Master::new(MasterConfig::from_robot(&cfg).unwrap());
//! let now = std::time::Instant::now();
//! master.poll(now);
//! while let Some(f) = master.poll_tx() { bus.send(&f).unwrap(); }
//! ```
#![deny(missing_docs)]

pub mod canopen;
pub mod loadcell;
pub mod modbus;
pub mod tracker;
pub mod transport;
