//! Device drivers of the robot, the master side of each bus: the CAN transports, the CANopen
//! master for CiA 402 drives, the Modbus RTU load-cell master and the tracker input.
//!
//! The codecs and the device configuration are `taut-proto`'s, shared with the device side
//! (`taut-vdev`). The master is sans-IO; only `transport`, the load-cell I/O thread and the
//! tracker receiver open sockets, ttys and threads. The driver deals in drive units (encoder
//! counts, ‰ of rated torque): metres and newtons belong to `taut_io::robot_io`.
//!
//! # Public surface
//!
//! What an application uses is re-exported here; the modules stay public for the tests and the
//! fuzz targets.
//!
//! | re-export                                                               | from                    |
//! |-------------------------------------------------------------------------|-------------------------|
//! | [`Master`], [`MasterConfig`], [`NodeConfig`], [`NodeStatus`], [`NodeEvent`], [`Phase`], [`CommandError`], [`ConfigProblem`] | [`canopen::master`] (sans-IO master) |
//! | [`DriveSet`], [`DriveSetError`]                                         | [`canopen::drive_set`] (master + transport, lifecycle in types) |
//! | [`BusEvent`]                                                            | [`transport`]           |
//! | [`SocketCanTransport`], [`VirtualBus`], [`VirtualEndpoint`]             | [`transport::socketcan`], [`transport::virtual_bus`] |
//! | [`LoadCellIo`], [`TensionReader`]                                       | [`loadcell`] (Modbus RTU I/O thread) |
//! | [`TrackerThread`], [`PoseReader`]                                       | [`tracker`] (UDP receiver thread) |
//! | [`Clock`], [`WallClock`], [`SimClock`], [`SharedClock`]                  | [`clock`] (wall or simulated time) |
//!
//! Frames, the transport trait, node ids and the CiA 402 states are `taut_proto::can` and
//! `taut_proto::canopen`. By path here: [`transport::candump`] and [`transport::kernel`] (log
//! and kernel frame formats, which only the transports use).
//!
//! ```no_run
//! use taut_driver::{Master, MasterConfig, SocketCanTransport};
//! use taut_proto::can::CanTransport;
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

pub use canopen::drive_set::{DriveSet, DriveSetError};
pub use canopen::master::{CommandError, ConfigProblem, Master, MasterConfig, NodeConfig, NodeEvent, NodeStatus, Phase};
pub use clock::{Clock, SharedClock, SimClock, WallClock};
pub use loadcell::{LoadCellIo, TensionReader};
pub use tracker::{PoseReader, TrackerThread};
pub use transport::socketcan::SocketCanTransport;
pub use transport::virtual_bus::{VirtualBus, VirtualEndpoint};
pub use transport::BusEvent;
