//! Simulated cable robot: physics, sensors and the guided motions.
//!
//! Physics only: the virtual devices (CiA 402 drives, Modbus load cells, tracker sender) are in
//! `taut-vdev`, and this crate depends on no device or driver crate. `taut-simrig`, the simulated
//! rig, couples the [`Plant`] to the virtual devices.
//!
//! The simulator is the tests' ground truth. Its physics is written independently of
//! `taut-calib`'s models on purpose: a wrong model must not hide behind a simulator that makes the
//! same mistake.
//!
//! | module            | what                                                                  |
//! |-------------------|-----------------------------------------------------------------------|
//! | [`truth`]         | true anchors (site error), encoder offsets                            |
//! | [`physics`]       | one cable: elasticity, sag, swivel pulley, drum commands              |
//! | [`catenary`]      | the exact elastic catenary                                            |
//! | [`tension`]       | the controller's tension distribution, loose cables, internal force   |
//! | [`equilibrium`]   | static equilibrium by energy minimisation                             |
//! | [`trajectory`]    | excitation trajectories with excursions                               |
//! | [`three_phase`]   | the guided three-phase initialisation motion                          |
//! | [`dwell`]         | dwell-pose recordings without a tracker (self-calibration)            |
//! | [`sensors`]       | tracker, encoders (backlash, quantisation), load cells                |
//! | [`scenario`]      | scenarios -> `cdpr-recording v1` + truth                              |
//! | [`field`]         | recordings sampled as a real logger: slow, irregular, stale rows      |
//! | [`plant`]         | the stepping plant for the real-time loop and the virtual drives      |
//! | [`dynamics`]      | the plant's dynamic mode: mass on elastic, damped cables; its modes   |
//!
//! ```no_run
//! let mut s = taut_sim::Scenario::aras_cam(42);
//! s.loose_fraction = 0.2;
//! let run = taut_sim::simulate(&s);
//! run.recording.save_atomic("aras-cam-42.csv").unwrap();
//! println!("anchors {:?}, {} loose samples", run.truth.anchors, run.loose_samples);
//! ```
#![deny(missing_docs)]
// Numerical code indexes several per-cable arrays in step; iterators would hide that.
#![allow(clippy::needless_range_loop)]

pub mod catenary;
pub mod dwell;
pub mod dynamics;
pub mod equilibrium;
pub mod field;
pub mod physics;
pub mod plant;
pub mod scenario;
pub mod sensors;
pub mod tension;
pub mod three_phase;
pub mod trajectory;
pub mod truth;

#[cfg(test)]
mod tests;

pub use dynamics::{Dynamics, Mode, RigidBody};
pub use physics::{CableCommand, Physics};
pub use plant::Plant;
pub use scenario::{simulate, try_simulate, Scenario, SimRun};
pub use sensors::Noise;
pub use tension::Pretension;
pub use three_phase::ThreePhasePlan;
pub use truth::Truth;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub(crate) const STREAM_TRUTH: u64 = 0;
pub(crate) const STREAM_TRAJECTORY: u64 = 1;
pub(crate) const STREAM_SLACK: u64 = 2;
pub(crate) const STREAM_TRACKER: u64 = 3;
pub(crate) const STREAM_ENCODER: u64 = 4;
pub(crate) const STREAM_LOADCELL: u64 = 5;
pub(crate) const STREAM_PLANT: u64 = 6;
// 7: the logger's sampling (`field`).

/// The generator of one concern (`stream`) of a seeded simulation: ChaCha8, so the same seed
/// gives the same numbers on every platform and version of this crate.
pub fn rng(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(stream);
    r
}

/// Why a scenario or a motion cannot be simulated.
#[derive(Debug, Clone, PartialEq)]
pub enum SimError {
    /// The robot configuration lacks nominal anchors.
    MissingAnchors,
    /// A scenario parameter is out of range.
    BadScenario(&'static str),
    /// The three-phase plan cannot start.
    ThreePhaseInfeasible {
        /// What is wrong and what to do.
        reason: &'static str,
    },
    /// A position-mode cable lost its tension during the three-phase motion.
    ThreePhaseSlack {
        /// Phase (-1: returning to the centre).
        phase: i32,
        /// Cable index.
        cable: usize,
        /// Time from the motion's start, s.
        t: f64,
        /// Its tension, N.
        tension_n: f64,
    },
    /// The equilibrium search failed.
    Equilibrium {
        /// Time, s.
        t: f64,
        /// Force residual left, N.
        residual_n: f64,
    },
    /// A catenary could not be solved.
    Catenary(String),
}

impl std::fmt::Display for SimError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SimError::MissingAnchors => write!(f, "every [[cable]] needs a nominal `anchor` to simulate the robot"),
            SimError::BadScenario(m) => write!(f, "bad scenario: {m}"),
            SimError::ThreePhaseInfeasible { reason } => write!(f, "three-phase plan: {reason}"),
            SimError::ThreePhaseSlack { phase, cable, t, tension_n } => write!(
                f,
                "three-phase motion: cable {cable} went slack ({tension_n:.2} N) at t = {t:.2} s in phase {phase}; \
                 reel less, change the follower tension or set another start"
            ),
            SimError::Equilibrium { t, residual_n } => {
                write!(f, "no static equilibrium found at t = {t:.3} s (residual {residual_n:.3e} N)")
            }
            SimError::Catenary(m) => write!(f, "{m}"),
        }
    }
}

impl std::error::Error for SimError {}
