//! The robot's real-time side: the periodic control loop, the guided start-up calibration, the
//! lock-free sample pipeline to the calibrator, the parameter hot-swap and the operator control
//! socket.
//!
//! ```text
//!  devices --read--> [loop: motion state machine, safety, IK] --write--> devices
//!                        |  samples (SPSC ring)        ^ parameters (triple buffer)
//!                        v                             |
//!                    [calibrator thread: recorder, calib, validation, params files]
//!  taut ctl --Unix socket--> [control thread] --commands (bounded channel)--> loop
//! ```
//!
//! The loop, the start-up routine and the calibrator are a controller [`plugin`] with the
//! ros2_control lifecycle (configure, activate, update every cycle, deactivate, cleanup) that any
//! host can drive, with its own devices or with taut's; `taut start` ([`daemon`]) is one such
//! host. The plugin's module documentation states what may run in the real-time thread.
//!
//! The loop allocates nothing after start-up: everything it touches is fixed size
//! ([`MAX_CABLES`]), parameters arrive through a [`triple`] buffer that returns old values to
//! the writer, samples leave through a fixed-capacity ring that drops (and counts) when full.
//!
//! ```no_run
//! use taut_rt_core::daemon::{Daemon, DaemonOptions};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! # fn devices() -> Box<dyn taut_rt_core::io::Devices> { unimplemented!() }
//! # fn calibrator() -> Box<dyn taut_rt_core::calibrator::Calibrate> { unimplemented!() }
//! let d = Daemon::start(&cfg, devices(), calibrator(), DaemonOptions::default()).unwrap();
//! d.wait();
//! ```
#![deny(missing_docs)]

pub mod calib_backend;
pub mod calibrator;
pub mod channels;
pub mod control;
pub mod ctl_server;
pub mod daemon;
pub mod excite;
pub mod follower;
pub mod io;
pub mod kin;
#[cfg(all(test, loom))]
mod loom_tests;
pub mod motion;
pub mod notracker;
pub mod plugin;
pub mod ramp;
pub mod robot_io;
pub mod rtsys;
pub mod runner;
pub mod safety;
pub mod sample;
#[cfg(feature = "sim")]
pub mod simrig;
pub mod spsc;
mod sync;
pub mod telemetry;
#[cfg(any(test, feature = "testkit"))]
pub mod testkit;
pub mod triple;
pub mod urgent;

pub use crossbeam_channel;

/// Largest number of cables the loop is built for (fixed-size arrays, no allocation).
pub const MAX_CABLES: usize = 8;
