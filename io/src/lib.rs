//! The robot's devices behind the real-time loop and the thread that runs it.
//!
//! - [`robot_io`]: the robot's devices as the loop's [`taut_rt::io::Devices`]: the CANopen drive
//!   set, the load cells and the tracker, brought up from the configuration, with the drum and
//!   load-cell unit conversions ([`robot_io::Scaling`]).
//! - [`runner`]: the periodic loop thread ([`runner::run_periodic`]) around `taut_rt`'s
//!   per-cycle core.
//! - [`rtsys`]: the operating system's side of a real-time thread: `SCHED_FIFO`, CPU affinity,
//!   locked memory, the absolute-time periodic sleep, the stop signals.
//! - [`FromRobot`] and [`EffectsFromFile`]: the loop's plain configuration filled from the
//!   robot's files.
//!
//! The real-time thread calls into this crate every cycle (the `read`/`write` of [`robot_io`],
//! the cycle of [`runner`]), which allocate nothing and never block. So it links no calibration
//! (`taut-calib`, nalgebra), JSON, MCAP or WebSocket (`tests/tests/offline/crate_graph.rs`
//! checks it); the calibrator, the operator's services and the plugin are crates above it.
#![deny(missing_docs)]

#[cfg(test)]
mod dwell_tare_tests;
#[cfg(test)]
mod motion_tests;
pub mod robot_io;
mod rt_config;
pub mod rtsys;
pub mod runner;
#[cfg(test)]
mod tension_tests;
#[cfg(any(test, feature = "testkit"))]
pub mod testkit;

pub use rt_config::{EffectsFromFile, FromRobot};
