//! The per-cable model of a cable robot, in one place for every crate that evaluates it: the
//! calibration and diagnosis (`taut-calib`, with partial derivatives) and the real-time loop's
//! inverse kinematics (`taut-rt`). No dependencies, no I/O; the formulas allocate nothing.
//!
//! The encoder reading of cable `j` for the platform attachment point `X` (in the world frame),
//! the anchor `A`, tension `T`:
//!
//! ```text
//! G = |X - A|                                   ideal straight cable         straight_length
//!   = r beta + sqrt(|X - C|^2 - r^2)            over a swivel pulley, radius r,  pulley_length
//!                                               swivel axis per cable (default vertical)
//! U = G / (1 + c T),   c = 1 / EA               the encoder counts unstretched cable   unstretched
//! U -= k T                                      winch, frame or anchor deflection k, m/N   deflection_counted
//! B + q B^2 = U                                 drum build-up q: the drum counts B     buildup_counted
//! l = s B + L0                                  drum scale s, encoder offset L0   reading
//! ```
//!
//! [`cable_length`] chains them the way the loop does. On the tension side, [`cell_tension`]
//! is the cable's tension from its load cell's reading through the cell's gain and the guides'
//! capstan friction (the loop corrects its measured tensions with it). Sag and backlash are calibration-only
//! effects and stay in `taut-calib`; the derivatives they need are carried by [`dual::Dual`].
//!
//! Beside the formulas, the crate holds the little vocabulary the layers share without
//! depending on each other: the CAN bus status types ([`bus`]: decoded by `taut-driver`, carried
//! in `taut-rt`'s safety causes), and the one home of the robot's geometry and its
//! uncertainties ([`geometry`]: anchors, encoder offsets, their 1-sigma; owned `Vec`s built off
//! the loop, converted at the edges to the loop's fixed-size form and to the parameter file).

#![deny(missing_docs)]

/// Most cables taut drives: the size of the real-time loop's fixed per-cable arrays, of the C
/// ABI's and the bound a configuration is checked against (`taut_rt::MAX_CABLES`,
/// `taut_config::geometry::MAX_CABLES` and the C header's `TAUT_MAX_CABLES` are this one).
pub const MAX_CABLES: usize = 8;

pub mod bus;
mod cable;
pub mod dual;
pub mod geometry;
pub mod tour;

pub use cable::{
    buildup_counted, cable_length, cell_tension, deflection_counted, friction_direction, pulley_length, reading, straight_length,
    unstretched, SwivelPulley, FRICTION_V_BAND_M_S, VERTICAL_AXIS,
};
pub use geometry::{Geometry, GeometryError, Sigmas};
