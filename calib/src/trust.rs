//! Whether a calibrated parameter set may become the robot's parameters: every number finite
//! (a NaN or infinite sigma or RMS says the statistics broke down, whatever the anchors look
//! like), and every anchor inside a plausible envelope. Used by `taut calibrate` before it
//! writes anything and by the daemon's calibration backend before it offers a set.
//!
//! The envelope: an anchor no more than [`crate::screen::ABSURD_M`] (1 km) from the centroid
//! of the tracked positions (the largest cable robot built spans 600 m), and, when the
//! configuration gives nominal anchors, no more than `max_from_nominal_m` from its nominal one.

use crate::{CalibReport, Geometry, Sigmas};
use std::fmt;
use taut_config::recording::Recording;

/// Why a parameter set is refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Untrusted {
    /// A value that must be a finite number is not.
    NonFinite {
        /// Cable, when the value belongs to one.
        cable: Option<usize>,
        /// Which value.
        what: &'static str,
    },
    /// An anchor absurdly far from everything the tracker saw.
    AnchorAbsurd {
        /// Cable.
        cable: usize,
        /// Distance from the centroid of the tracked positions, m.
        distance_m: f64,
        /// The limit, m.
        limit_m: f64,
    },
    /// An anchor far from the configuration's nominal one.
    FarFromNominal {
        /// Cable.
        cable: usize,
        /// Distance from the nominal anchor, m.
        distance_m: f64,
        /// The limit, m.
        limit_m: f64,
    },
    /// No tracked position to judge the anchors against.
    NoPositions,
}

impl fmt::Display for Untrusted {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Untrusted::NonFinite { cable: Some(j), what } => {
                write!(f, "cable {j}: the {what} is not a finite number; the calibration cannot be trusted (look for data problems above, or record again)")
            }
            Untrusted::NonFinite { cable: None, what } => {
                write!(f, "the {what} is not a finite number; the calibration cannot be trusted (look for data problems above, or record again)")
            }
            Untrusted::AnchorAbsurd { cable, distance_m, limit_m } => write!(
                f,
                "cable {cable}: the anchor came out {distance_m:.3e} m from the tracked positions (more than {limit_m:.0} m): not a cable robot; check that the tracker and encoder columns belong together"
            ),
            Untrusted::FarFromNominal { cable, distance_m, limit_m } => write!(
                f,
                "cable {cable}: the anchor came out {distance_m:.3} m from the nominal anchor of the configuration (more than {limit_m:.3} m = 2 x daemon.max_anchor_change_m); check the recording, or correct cable[{cable}].anchor"
            ),
            Untrusted::NoPositions => write!(f, "the recording has no tracked position to judge the anchors against"),
        }
    }
}

impl std::error::Error for Untrusted {}

/// A parameter set with its uncertainty, as [`check`] judges it.
#[derive(Debug, Clone, Copy)]
pub struct Candidate<'a> {
    /// Anchors and encoder offsets, m.
    pub params: &'a Geometry,
    /// 1-sigma of the anchors and offsets, m.
    pub sigma: &'a Sigmas,
    /// Co-registration RMS, m.
    pub rms_m: f64,
}

impl<'a> Candidate<'a> {
    /// The parameters and uncertainty of a calibration report.
    pub fn of(r: &'a CalibReport) -> Self {
        Candidate { params: &r.params, sigma: &r.sigma, rms_m: r.rms_m }
    }
}

/// Checks `c` against the positions of `rec` and, if given, the nominal anchors with the
/// largest plausible distance from them.
pub fn check(c: &Candidate, rec: &Recording, nominal: Option<(&[[f64; 3]], f64)>) -> Result<(), Untrusted> {
    for (j, a) in c.params.anchors.iter().enumerate() {
        if !a.iter().all(|v| v.is_finite()) {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "anchor" });
        }
    }
    for (j, v) in c.params.l0.iter().enumerate() {
        if !v.is_finite() {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "encoder offset" });
        }
    }
    for (j, s) in c.sigma.anchors.iter().enumerate() {
        if !s.iter().all(|v| v.is_finite()) {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "anchor 1-sigma" });
        }
    }
    for (j, v) in c.sigma.l0.iter().enumerate() {
        if !v.is_finite() {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "encoder offset 1-sigma" });
        }
    }
    if !c.rms_m.is_finite() {
        return Err(Untrusted::NonFinite { cable: None, what: "co-registration RMS" });
    }
    let (mut sum, mut cnt) = ([0.0; 3], 0usize);
    for p in &rec.p {
        if p.iter().all(|v| v.is_finite() && v.abs() <= crate::screen::ABSURD_M) {
            for k in 0..3 {
                sum[k] += p[k];
            }
            cnt += 1;
        }
    }
    if cnt == 0 {
        return Err(Untrusted::NoPositions);
    }
    let centroid = sum.map(|s| s / cnt as f64);
    for (j, a) in c.params.anchors.iter().enumerate() {
        let d = crate::model::norm(crate::model::sub(*a, centroid));
        if !(d <= crate::screen::ABSURD_M) {
            return Err(Untrusted::AnchorAbsurd { cable: j, distance_m: d, limit_m: crate::screen::ABSURD_M });
        }
        if let Some((nom, limit)) = nominal {
            if let Some(n) = nom.get(j) {
                let d = crate::model::norm(crate::model::sub(*a, *n));
                if !(d <= limit) {
                    return Err(Untrusted::FarFromNominal { cable: j, distance_m: d, limit_m: limit });
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth;

    #[test]
    fn refuses_non_finite_and_absurd_sets() {
        let truth = synth::aras_cam();
        let rec = synth::box_recording(&synth::Spec::new(truth.clone()), 200, [-1.0; 3], [1.0; 3], 1);
        let sigma = Sigmas::uniform(4, 1e-4);
        let ok = Candidate { params: &truth, sigma: &sigma, rms_m: 1e-3 };
        assert_eq!(check(&ok, &rec, Some((&truth.anchors, 1.0))), Ok(()));
        assert!(matches!(check(&Candidate { rms_m: f64::INFINITY, ..ok }, &rec, None), Err(Untrusted::NonFinite { cable: None, .. })));
        let nan = Sigmas { anchors: vec![[1e-4, f64::NAN, 1e-4]; 4], ..sigma.clone() };
        assert!(matches!(check(&Candidate { sigma: &nan, ..ok }, &rec, None), Err(Untrusted::NonFinite { cable: Some(0), .. })));
        let mut far = truth.clone();
        far.anchors[2] = [1e6, 0.0, 0.0];
        assert!(matches!(check(&Candidate { params: &far, ..ok }, &rec, None), Err(Untrusted::AnchorAbsurd { cable: 2, .. })));
        far.anchors[2] = [-3.0, 1.7, 6.0];
        let e = check(&Candidate { params: &far, ..ok }, &rec, Some((&truth.anchors, 1.0))).unwrap_err();
        assert!(matches!(e, Untrusted::FarFromNominal { cable: 2, .. }), "{e}");
        assert!(e.to_string().contains("cable[2].anchor"));
    }
}
