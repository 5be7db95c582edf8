//! The calibrator: the thread that takes the loop's samples, records them, runs the calibration
//! on them and publishes the parameters it accepts to the loop.
//!
//! - [`vocab`]: the types the calibrator shares with the operator's services and the plugin
//!   (configuration, estimate, outcome, status, errors, the held-out split, the outputs trait).
//!   It imports nothing from the rest of the crate.
//! - [`calibrator`]: the calibrator thread's state machine, its worker thread and the versioned
//!   parameter files.
//! - [`recorder`]: the recording file and the data sets' rows (lengths and tensions
//!   interpolated to the pose's time).
//! - [`acceptance`]: whether a new set may replace the running one (bounds and the held-out
//!   test).
//! - [`calib_backend`]: the calibration backend on `taut-calib` ([`calib_backend::TautCalib`]).
//! - [`heldout`]: the held-out comparison and its tracker-outlier rule.
//! - [`excite`]: the start-up excitation's design and predicted uncertainty.
//! - [`notracker`]: the start-up without a tracker (dwells, their plan and held-out check).
//!
//! Nothing here runs in the real-time thread: the loop pushes `Copy` samples into a ring and
//! reads parameters from a triple buffer; this crate is on the other end of both.
#![deny(missing_docs)]

pub mod acceptance;
pub mod calib_backend;
pub mod calibrator;
pub mod excite;
pub mod heldout;
pub mod notracker;
pub mod recorder;
pub mod vocab;
