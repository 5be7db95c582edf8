//! Device drivers of the robot: the CAN transports, the CANopen master and CiA 402 drive
//! profile, the Modbus RTU load cells and the tracker input.
//!
//! Protocol code is sans-IO (frames and time in, frames and events out); only `transport`, the
//! load-cell I/O thread and the tracker receiver open sockets, ttys and threads. The driver deals
//! in drive units (encoder counts, torque in ‰ of rated torque): metres and newtons belong to the
//! robot I/O layer (`taut_rt_core::robot_io`).
//!
//! # Public surface
//!
//! What an application uses is re-exported here; the modules stay public for the codecs that the
//! device side (`taut-vdev`), the fuzz targets and the tests need by path.
//!
//! | re-export                                                               | from                    |
//! |-------------------------------------------------------------------------|-------------------------|
//! | [`Master`], [`MasterConfig`], [`NodeConfig`], [`NodeStatus`], [`Event`], [`Phase`], [`CommandError`], [`ConfigProblem`] | [`canopen::master`] (sans-IO master) |
//! | [`DriveSet`], [`DriveSetError`]                                         | [`canopen::drive_set`] (master + transport, lifecycle in types) |
//! | [`Mode`], [`State`], [`NodeId`]                                         | [`canopen::cia402`], [`canopen`] |
//! | [`CanTransport`], [`Frame`], [`BusEvent`], [`TransportError`]           | [`transport`]           |
//! | [`SocketCanTransport`], [`VirtualBus`], [`VirtualEndpoint`]             | [`transport::socketcan`], [`transport::virtual_bus`] |
//! | [`LoadCellIo`], [`TensionReader`]                                       | [`loadcell`] (Modbus RTU I/O thread) |
//! | [`TrackerThread`], [`PoseReader`]                                       | [`tracker`] (UDP receiver thread) |
//! | [`Clock`], [`WallClock`], [`SimClock`], [`SharedClock`]                  | [`clock`] (wall or simulated time) |
//!
//! Codecs by path: [`canopen`]'s `nmt`, `sync`, `heartbeat`, `emcy`, `sdo`, `pdo`, `od`,
//! `cia402`; [`modbus::rtu`], [`modbus::value`]; [`tracker::parse_line`]/[`tracker::format_line`];
//! [`transport::candump`] and [`transport::kernel`].
//!
//! ```no_run
//! use taut_driver::{CanTransport, Master, MasterConfig, SocketCanTransport};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! let mut bus = SocketCanTransport::open("can0").unwrap();
//! let mut master = Master::new(MasterConfig::from_robot(&cfg).unwrap());
//! let now = std::time::Instant::now();
//! master.poll(now);
//! while let Some(f) = master.poll_tx() { bus.send(&f).unwrap(); }
//! ```
#![deny(missing_docs)]

pub mod canopen;
pub mod clock;
pub mod loadcell;
pub mod modbus;
pub mod sched;
pub mod tracker;
pub mod transport;

pub use canopen::cia402::{Mode, State};
pub use canopen::drive_set::{DriveSet, DriveSetError};
pub use canopen::master::{CommandError, ConfigProblem, Event, Master, MasterConfig, NodeConfig, NodeStatus, Phase};
pub use canopen::NodeId;
pub use clock::{Clock, SharedClock, SimClock, WallClock};
pub use loadcell::{LoadCellIo, TensionReader};
pub use tracker::{PoseReader, TrackerThread};
pub use transport::socketcan::SocketCanTransport;
pub use transport::virtual_bus::{VirtualBus, VirtualEndpoint};
pub use transport::{BusEvent, CanTransport, Frame, TransportError};
