//! Swivel pulley: the cable leaves the frame over a pulley of radius `r` that turns about an
//! axis through the anchor, so the exit point moves and the cable wraps. The axis is the
//! robot's, per cable (`[[cable]] pulley_axis` of the configuration, [`Prepared::pulley_axis`];
//! vertical where none is given), not a fitted parameter.
//!
//! ```text
//! G = r beta + sqrt(|X - C|^2 - r^2)       wrap angle beta, pulley centre C (taut_model::pulley_length)
//! ```
//!
//! One radius for the robot. A shifted anchor mimics it over a small workspace.

use super::{Effect, EffectModel, Path, Sharing, ANCHOR_SEPARATION};
use crate::diagnose::analysis::Regressor;
#[cfg(doc)]
use crate::effects::model::Prepared;
use taut_config::params::Effects;
use taut_model::pulley_length;

/// The pulley effect.
pub struct Pulley;

/// The path from the anchor over a swivel pulley of radius `r` about the unit vector `axis` to
/// `x`, and `dG/dr`; `None` where the pulley has no path there (the prediction then takes the
/// straight cable).
pub fn path(x: [f64; 3], anchor: [f64; 3], axis: [f64; 3], r: f64) -> Option<(Path, f64)> {
    pulley_length(x, anchor, axis, r).map(|(len, d)| (Path { g: len, gx: [d[0], d[1], d[2]], g_t: 0.0, g_tw: 0.0 }, d[3]))
}

impl EffectModel for Pulley {
    fn id(&self) -> Effect {
        Effect::Pulley
    }
    fn name(&self) -> &'static str {
        "pulley"
    }
    fn parameter(&self) -> &'static str {
        "radius_m"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("pulley radius", "mm", 1e3)
    }
    fn sharing(&self) -> Sharing {
        Sharing::Shared
    }
    fn internal_range(&self) -> (f64, f64) {
        (2e-3, 0.5)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 1.0)
    }
    fn start(&self) -> f64 {
        0.02
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[None]
    }
    fn separation(&self, _other: Option<Effect>) -> Option<&'static str> {
        Some(ANCHOR_SEPARATION)
    }
    fn signature(&self) -> &'static str {
        "cable elevation angle"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Elevation
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("pulley_radius_m")
    }
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.pulley_radius_m.as_ref().and_then(|v| v.get(j).copied())
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.pulley_radius_m, out.pulley_radius_sigma_m) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use taut_model::VERTICAL_AXIS;

    fn fd(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    #[test]
    fn pulley_reduces_to_straight_cable_for_small_radius_and_jacobian_is_right() {
        let x = [1.5, 0.7, -3.0];
        let an = [0.0, 0.0, 0.0];
        let (g, _) = pulley_length(x, an, VERTICAL_AXIS, 1e-9).unwrap();
        let straight = (1.5f64 * 1.5 + 0.49 + 9.0).sqrt();
        assert!((g - straight).abs() < 1e-8);
        let r = 0.06;
        let (_, d) = pulley_length(x, an, VERTICAL_AXIS, r).unwrap();
        for k in 0..3 {
            let num = fd(
                |v| {
                    let mut xx = x;
                    xx[k] = v;
                    pulley_length(xx, an, VERTICAL_AXIS, r).unwrap().0
                },
                x[k],
                1e-6,
            );
            assert!((d[k] - num).abs() < 1e-7, "dX{k}: {} vs {num}", d[k]);
        }
        let num = fd(|v| pulley_length(x, an, VERTICAL_AXIS, v).unwrap().0, r, 1e-7);
        assert!((d[3] - num).abs() < 1e-6, "dr: {} vs {num}", d[3]);
        // The gradient wrt X is the unit direction of the free segment.
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((n - 1.0).abs() < 1e-9);
    }

    #[test]
    fn pulley_wrap_geometry_by_hand() {
        // Platform straight below the pulley centre, far away: wrap 90 degrees... no: the cable
        // leaves the leftmost point going down only when X is below the anchor. X level with the
        // centre and to the right: wrap is half a turn minus nothing -> beta = pi/2 below? Check a
        // case computed by hand: X = (r + 1, -1) relative to the anchor, r = 1:
        // C = (1, 0), d_c = sqrt(2), psi = -45 deg, acos(1/sqrt 2) = 45 deg -> phi_e = -90 deg = 270 deg,
        // beta = 90 deg, free segment = 1, G = pi/2 + 1.
        let (g, _) = pulley_length([2.0, 0.0, -1.0], [0.0; 3], VERTICAL_AXIS, 1.0).unwrap();
        assert!((g - (std::f64::consts::FRAC_PI_2 + 1.0)).abs() < 1e-12, "{g}");
    }

    /// A pulley of radius 0 is the straight cable.
    #[test]
    fn a_vanishing_pulley_is_the_straight_path() {
        let (x, a) = ([1.5, 0.7, -3.0], [0.2, -0.1, 0.3]);
        let (p, _) = path(x, a, VERTICAL_AXIS, 1e-12).unwrap();
        let s = Path::straight(x, a);
        assert!((p.g - s.g).abs() < 1e-9 && (0..3).all(|k| (p.gx[k] - s.gx[k]).abs() < 1e-9), "{p:?} {s:?}");
    }

    /// The pulley is separated from everything by the same measurement (large wrap angles).
    #[test]
    fn the_pulley_separation_is_the_anchor_one() {
        for e in Effect::FITTED {
            assert_eq!(e.separating_measurement(Some(Effect::Pulley)), ANCHOR_SEPARATION);
        }
        assert_eq!(Effect::Pulley.separating_measurement(None), ANCHOR_SEPARATION);
    }
}
