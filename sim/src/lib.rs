//! Simulated cable robot: physics, sensors, the guided motions, and (in [`devices`]) virtual CiA 402
//! drives and Modbus RTU load cells.
//!
//! The simulator is the tests' ground truth. Its physics is written independently of
//! `taut-calib`'s models on purpose: a wrong model must not hide behind a simulator that makes the
//! same mistake.
#![deny(missing_docs)]

pub mod catenary;
pub mod devices;
