//! The robot's side around the real-time loop: the periodic loop thread, the guided start-up
//! calibration, the lock-free sample pipeline to the calibrator, the parameter hot-swap and the
//! operator control socket.
//!
//! What runs every cycle (motion state machine, safety, inverse kinematics, ramps, the
//! lock-free hand-overs) lives in the `taut-rt` crate, which has no threads, no I/O and no
//! dependency but the cable model. Code here names those modules by their crate
//! ([`taut_rt::motion`], [`taut_rt::kin`], [`taut_rt::io`], [`taut_rt::safety`], ...), so every
//! import shows which side of the real-time boundary it reaches; nothing is re-exported. This
//! crate fills its plain configuration from the robot's files ([`FromRobot`],
//! [`EffectsFromFile`]) and owns the threads, the channels and the files.
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
//! ([`taut_rt::MAX_CABLES`]), parameters arrive through a [`taut_rt::triple`] buffer that returns old values to
//! the writer, samples leave through a fixed-capacity ring that drops (and counts) when full.
//!
//! ```no_run
//! use taut_rt_core::daemon::{Daemon, DaemonOptions};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! # fn devices() -> Box<dyn taut_rt::io::Devices> { unimplemented!() }
//! # fn calibrator() -> Box<dyn taut_rt_core::calibrator::Calibrate> { unimplemented!() }
//! let d = Daemon::start(&cfg, devices(), calibrator(), DaemonOptions::default()).unwrap();
//! d.wait();
//! ```
#![deny(missing_docs)]

pub mod calib_backend;
mod calib_error;
pub mod calibrator;
pub mod channels;
pub mod control;
pub mod ctl_server;
pub mod daemon;
#[cfg(test)]
mod dwell_tare_tests;
pub mod excite;
pub mod heldout;
pub mod localtime;
#[cfg(test)]
mod motion_tests;
pub mod notracker;
pub mod operator;
pub mod plugin;
pub mod robot_io;
mod rt_config;
pub mod rtsys;
pub mod runner;
pub mod telemetry;
#[cfg(any(test, feature = "testkit"))]
pub mod testkit;

pub use rt_config::{EffectsFromFile, FromRobot};
