//! The real-time side of taut: everything the control loop runs every cycle, and nothing else.
//!
//! ```text
//!  Devices::read -> Inputs -> Controller::update (motion state machine, safety, inverse
//!  kinematics, ramps) -> Outputs -> Devices::write -> one Sample into the SPSC ring
//!        ^ commands (CommandSource)   ^ parameters (triple buffer)   ^ estop (Urgent)
//! ```
//!
//! The crate has no threads, no I/O, no locks and no allocation after start-up: everything is
//! fixed size ([`MAX_CABLES`]), parameters arrive through a [`triple`] buffer that returns old
//! values to the writer, samples leave through a fixed-capacity [`spsc`] ring that drops (and
//! counts) when full, commands are taken from a [`CommandSource`] that must not block. Its only
//! dependency is `taut-model` (the cable model formulas, shared with the calibration).
//! `tests/tests/crate_graph.rs` keeps nalgebra, serde, toml, crossbeam, libc and the I/O crates
//! out of its dependency graph; `tests/tests/rt_alloc.rs` counts allocations per cycle; the
//! lock-free hand-overs are model-checked under loom (`scripts/loom`). See
//! `docs/architecture.md`, "The real-time rule".
//!
//! The non-real-time side (`taut-io`: devices and the loop thread; `taut-calibrator`;
//! `taut-operator`: the control socket and telemetry; `taut-plugin`: the lifecycle) fills
//! [`motion::ControllerConfig`] and [`kin::LoopParams`] from the robot's files and imports these
//! modules by this crate's paths (`taut_rt::motion`), so every import shows the real-time side.
#![deny(missing_docs)]

pub mod cycle;
pub mod follower;
pub mod host;
pub mod io;
pub mod kin;
#[cfg(all(test, loom))]
mod loom_tests;
pub mod motion;
pub mod ramp;
pub mod safety;
pub mod sample;
pub mod spsc;
mod sync;
pub mod triple;
pub mod update;
pub mod urgent;
pub mod wiring;

pub use kin::{LoopEffects, LoopParams};
pub use motion::{Command, CommandSource, Controller, ControllerConfig};
pub use taut_model::geometry::{Geometry, GeometryError, Sigmas};

/// Largest number of cables the loop is built for (fixed-size arrays, no allocation).
pub use taut_model::MAX_CABLES;
