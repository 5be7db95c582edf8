//! One home for the robot's geometry and its uncertainties.
//!
//! [`Geometry`] is what a calibration estimates and what the loop's kinematics use: per cable
//! `j`, the anchor `A_j` (where the cable leaves the frame, tracker frame, m) and the encoder
//! offset `L0_j` (m), so that `l_j = |P + R b_j - A_j| + L0_j`. [`Sigmas`] holds their 1-sigma
//! uncertainties in the same shape (NaN: unknown). Every other form of these numbers is a
//! conversion at an edge, one named function per pair of types:
//!
//! ```text
//! taut_config::params::ParamsFile  <->  Geometry + Sigmas    ParamsFile::from_geometry / geometry / sigmas
//! taut_rt::kin::LoopParams         <->  Geometry + platform  LoopParams::from_geometry / geometry
//! solver vectors [A_x A_y A_z L0]*n ->  Geometry, Sigmas     Geometry::from_packed / Sigmas::from_packed
//! ```
//!
//! The platform attachment points `b_j` are not part of [`Geometry`]: they come from the robot
//! configuration, are never estimated, and only the loop's fixed-size form carries them beside
//! the estimate. These types own `Vec`s: they are built and converted on the calibrator thread
//! or at start-up, never in the real-time loop (which holds the `Copy` form, `LoopParams`).

use std::fmt;

/// Which per-cable quantity an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Field {
    /// The anchor `A_j`.
    Anchor,
    /// The encoder offset `L0_j`.
    Offset,
    /// The 1-sigma of the anchor.
    AnchorSigma,
    /// The 1-sigma of the encoder offset.
    OffsetSigma,
    /// The platform attachment point `b_j`.
    Platform,
}

impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Field::Anchor => "anchor",
            Field::Offset => "encoder offset L0",
            Field::AnchorSigma => "anchor 1-sigma",
            Field::OffsetSigma => "encoder offset 1-sigma",
            Field::Platform => "platform point",
        })
    }
}

/// Why a geometry (or its sigmas) was refused. `Copy`, so that callers on any path can keep it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GeometryError {
    /// No cable at all.
    NoCables,
    /// `field` has `len` entries for `n` cables.
    Length {
        /// The quantity with the wrong count.
        field: Field,
        /// Its number of entries.
        len: usize,
        /// The number of cables (the number of anchors).
        n: usize,
    },
    /// Cable `cable`'s `field` is NaN or infinite (a sigma: infinite, or NaN beside known ones).
    NotFinite {
        /// Cable index, 0-based.
        cable: usize,
        /// The quantity.
        field: Field,
    },
    /// Cable `cable`'s 1-sigma of `field` is negative.
    NegativeSigma {
        /// Cable index, 0-based.
        cable: usize,
        /// The quantity.
        field: Field,
    },
    /// More cables than the fixed-size form holds.
    TooManyCables {
        /// The number of cables given.
        n: usize,
        /// The most the form holds.
        max: usize,
    },
}

impl fmt::Display for GeometryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            GeometryError::NoCables => write!(f, "no cables: give at least one anchor and encoder offset"),
            GeometryError::Length { field, len, n } => write!(f, "{len} values of the {field} for {n} cables: give one per cable"),
            GeometryError::NotFinite { cable, field } => write!(f, "the {field} of cable {cable} is not finite"),
            GeometryError::NegativeSigma { cable, field } => write!(f, "the {field} of cable {cable} is negative"),
            GeometryError::TooManyCables { n, max } => write!(f, "{n} cables, at most {max} are supported"),
        }
    }
}

impl std::error::Error for GeometryError {}

/// The robot's estimated geometry: one anchor and one encoder offset per cable.
///
/// Fields are public so that the numerical code reads `p.anchors[j]`; [`Geometry::new`] and
/// [`Geometry::check`] are the validation every input from outside goes through.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Geometry {
    /// Anchor (cable exit point) of each cable in the tracker frame, m.
    pub anchors: Vec<[f64; 3]>,
    /// Encoder offset of each cable, m: `l = |P + R b - A| + L0`.
    pub l0: Vec<f64>,
}

impl Geometry {
    /// A checked geometry: at least one cable, one offset per anchor, every number finite.
    pub fn new(anchors: Vec<[f64; 3]>, l0: Vec<f64>) -> Result<Geometry, GeometryError> {
        let g = Geometry { anchors, l0 };
        g.check()?;
        Ok(g)
    }

    /// At least one cable, one offset per anchor, every number finite.
    pub fn check(&self) -> Result<(), GeometryError> {
        let n = self.anchors.len();
        if n == 0 {
            return Err(GeometryError::NoCables);
        }
        if self.l0.len() != n {
            return Err(GeometryError::Length { field: Field::Offset, len: self.l0.len(), n });
        }
        if let Some(cable) = self.anchors.iter().position(|a| !a.iter().all(|v| v.is_finite())) {
            return Err(GeometryError::NotFinite { cable, field: Field::Anchor });
        }
        if let Some(cable) = self.l0.iter().position(|v| !v.is_finite()) {
            return Err(GeometryError::NotFinite { cable, field: Field::Offset });
        }
        Ok(())
    }

    /// Number of cables.
    pub fn n_cables(&self) -> usize {
        self.anchors.len()
    }

    /// Cable `j`'s parameters as `(A_x, A_y, A_z, L0)`.
    pub fn cable(&self, j: usize) -> [f64; 4] {
        let a = self.anchors[j];
        [a[0], a[1], a[2], self.l0[j]]
    }

    /// From per-cable rows `(A_x, A_y, A_z, L0)`.
    pub fn from_cables(x: &[[f64; 4]]) -> Geometry {
        Geometry { anchors: x.iter().map(|v| [v[0], v[1], v[2]]).collect(), l0: x.iter().map(|v| v[3]).collect() }
    }

    /// The first `4 n` values of a solver's parameter vector, packed per cable as
    /// `[A_x, A_y, A_z, L0]` (the layout of the bundle, effect and diagnosis fits).
    pub fn from_packed(x: &[f64], n: usize) -> Geometry {
        Geometry { anchors: (0..n).map(|j| [x[4 * j], x[4 * j + 1], x[4 * j + 2]]).collect(), l0: (0..n).map(|j| x[4 * j + 3]).collect() }
    }
}

/// 1-sigma uncertainties of a [`Geometry`], same shape. NaN: unknown (all of a field at once);
/// infinite: unbounded (a refused or unobservable estimate).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sigmas {
    /// 1-sigma of each anchor coordinate, m.
    pub anchors: Vec<[f64; 3]>,
    /// 1-sigma of each encoder offset, m.
    pub l0: Vec<f64>,
}

impl Sigmas {
    /// Unknown (NaN) sigmas of `n` cables.
    pub fn unknown(n: usize) -> Sigmas {
        Sigmas::uniform(n, f64::NAN)
    }

    /// The same 1-sigma `s` for every coordinate and offset of `n` cables.
    pub fn uniform(n: usize, s: f64) -> Sigmas {
        Sigmas { anchors: vec![[s; 3]; n], l0: vec![s; n] }
    }

    /// The square roots of the first `4 n` diagonal entries of a covariance, given as its
    /// diagonal `var`, packed as in [`Geometry::from_packed`]; a negative variance (numerical
    /// round-off of a singular matrix) counts as 0.
    pub fn from_variances(var: &[f64], n: usize) -> Sigmas {
        let s = |i: usize| var[i].max(0.0).sqrt();
        Sigmas { anchors: (0..n).map(|j| [s(4 * j), s(4 * j + 1), s(4 * j + 2)]).collect(), l0: (0..n).map(|j| s(4 * j + 3)).collect() }
    }

    /// Sigmas already packed per cable as `[A_x, A_y, A_z, L0]`.
    pub fn from_packed(sig: &[f64], n: usize) -> Sigmas {
        let g = Geometry::from_packed(sig, n);
        Sigmas { anchors: g.anchors, l0: g.l0 }
    }

    /// Number of cables.
    pub fn n_cables(&self) -> usize {
        self.anchors.len()
    }

    /// True when every value is NaN (nothing known).
    pub fn is_unknown(&self) -> bool {
        self.anchors.iter().flatten().chain(&self.l0).all(|v| v.is_nan())
    }

    /// Sigmas of `n` cables that a file may hold: each field finite and non-negative, or all
    /// NaN (unknown).
    pub fn check(&self, n: usize) -> Result<(), GeometryError> {
        if self.anchors.len() != n {
            return Err(GeometryError::Length { field: Field::AnchorSigma, len: self.anchors.len(), n });
        }
        if self.l0.len() != n {
            return Err(GeometryError::Length { field: Field::OffsetSigma, len: self.l0.len(), n });
        }
        let field = |field: Field, v: &mut dyn Iterator<Item = (usize, f64)>| -> Result<(), GeometryError> {
            let v: Vec<(usize, f64)> = v.collect();
            if v.iter().all(|(_, x)| x.is_nan()) {
                return Ok(());
            }
            if let Some(&(cable, _)) = v.iter().find(|(_, x)| !x.is_finite()) {
                return Err(GeometryError::NotFinite { cable, field });
            }
            if let Some(&(cable, _)) = v.iter().find(|(_, x)| *x < 0.0) {
                return Err(GeometryError::NegativeSigma { cable, field });
            }
            Ok(())
        };
        field(Field::AnchorSigma, &mut self.anchors.iter().enumerate().flat_map(|(j, a)| a.iter().map(move |&x| (j, x))))?;
        field(Field::OffsetSigma, &mut self.l0.iter().copied().enumerate())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_names_the_cable_and_field() {
        assert!(Geometry::new(vec![[1.0, 2.0, 3.0]; 2], vec![0.1, 0.2]).is_ok());
        assert_eq!(Geometry::new(vec![], vec![]), Err(GeometryError::NoCables));
        assert_eq!(Geometry::new(vec![[1.0; 3]; 3], vec![0.1; 2]), Err(GeometryError::Length { field: Field::Offset, len: 2, n: 3 }));
        assert_eq!(
            Geometry::new(vec![[1.0; 3], [1.0, f64::NAN, 1.0]], vec![0.1; 2]),
            Err(GeometryError::NotFinite { cable: 1, field: Field::Anchor })
        );
        assert_eq!(
            Geometry::new(vec![[1.0; 3]; 2], vec![0.1, f64::INFINITY]),
            Err(GeometryError::NotFinite { cable: 1, field: Field::Offset })
        );
        let e = GeometryError::NotFinite { cable: 1, field: Field::Offset }.to_string();
        assert!(e.contains("cable 1") && e.contains("offset"), "{e}");
    }

    #[test]
    fn packed_and_cable_rows_round_trip() {
        let x = [1.0, 2.0, 3.0, 0.1, 4.0, 5.0, 6.0, 0.2, 99.0];
        let g = Geometry::from_packed(&x, 2);
        assert_eq!(g, Geometry { anchors: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], l0: vec![0.1, 0.2] });
        assert_eq!(g.n_cables(), 2);
        assert_eq!(g.cable(1), [4.0, 5.0, 6.0, 0.2]);
        assert_eq!(Geometry::from_cables(&[g.cable(0), g.cable(1)]), g);
        let s = Sigmas::from_packed(&x, 2);
        assert_eq!((s.anchors, s.l0), (g.anchors, g.l0));
        let v = Sigmas::from_variances(&[4.0, 9.0, -1e-18, 16.0], 1);
        assert_eq!(v, Sigmas { anchors: vec![[2.0, 3.0, 0.0]], l0: vec![4.0] });
    }

    #[test]
    fn sigmas_are_known_or_all_unknown() {
        assert!(Sigmas::unknown(3).is_unknown());
        assert!(Sigmas::unknown(3).check(3).is_ok());
        assert!(Sigmas::uniform(3, 1e-4).check(3).is_ok());
        assert!(!Sigmas::uniform(3, 1e-4).is_unknown());
        assert_eq!(Sigmas::unknown(2).check(3), Err(GeometryError::Length { field: Field::AnchorSigma, len: 2, n: 3 }));
        let mut s = Sigmas::uniform(3, 1e-4);
        s.l0[2] = f64::NAN;
        assert_eq!(s.check(3), Err(GeometryError::NotFinite { cable: 2, field: Field::OffsetSigma }));
        let mut s = Sigmas::uniform(3, 1e-4);
        s.anchors[1][2] = -1.0;
        assert_eq!(s.check(3), Err(GeometryError::NegativeSigma { cable: 1, field: Field::AnchorSigma }));
        let mut s = Sigmas::uniform(3, 1e-4);
        s.anchors[0][0] = f64::INFINITY;
        assert_eq!(s.check(3), Err(GeometryError::NotFinite { cable: 0, field: Field::AnchorSigma }));
    }
}
