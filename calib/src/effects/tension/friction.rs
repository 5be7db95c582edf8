//! Friction in the pulleys and guides between the platform and the load cell at the winch. A
//! cable wrapped by `theta` over guides with friction coefficient `mu` (capstan equation) needs
//! `t exp(mu theta)` at the winch to reel in against the platform's `t`, and holds with
//! `t exp(-mu theta)` while it pays out:
//!
//! ```text
//! f = t exp(-c s(v)) + o,    c = mu theta per cable (internal, >= 0),   s(v) = tanh(v / V_BAND)
//! ```
//!
//! with `v` the cable's length rate (> 0 paying out). Near zero speed static friction holds any
//! force inside the cone `[t e^-c, t e^c]`; which one depends on the history, so the smooth sign
//! `s` over [`V_BAND`] takes the middle (the plain reading) at rest and the full factor once the
//! cable moves faster than a few times the band.

use super::{BalanceRow, TensionEffect, TensionEffectModel, Term};
use crate::effects::Sharing;

/// Speed over which the friction's sign turns over, m/s: at `V_BAND` the factor is 76 % of its
/// sliding value, at 3x 99.5 %. The tracker's smoothed speed is good to about 1 mm/s. The
/// running loop's correction uses the same band (`taut_model::cell_tension`).
pub const V_BAND: f64 = taut_model::FRICTION_V_BAND_M_S;

/// The friction effect (`friction` in the reports).
pub struct Friction;

/// The smooth direction of motion `s(v)` (+1 paying out, -1 reeling in).
pub fn direction(v: f64) -> f64 {
    taut_model::friction_direction(v)
}

impl TensionEffectModel for Friction {
    fn id(&self) -> TensionEffect {
        TensionEffect::Friction
    }
    fn name(&self) -> &'static str {
        "friction"
    }
    fn parameter(&self) -> &'static str {
        "mu_theta"
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    /// `mu theta` up to 1: a coefficient of 0.3 over a wrap of 190 degrees.
    fn internal_range(&self) -> (f64, f64) {
        (0.0, 1.0)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 2.0)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn term(&self, x: f64, row: &BalanceRow, j: usize) -> Term {
        let s = direction(row.v[j]);
        Term::CellLogFactor { value: -x * s, d: -s }
    }
    fn mimics(&self) -> &'static [(&'static str, &'static str)] {
        &[
            (
                "loadcell time offset",
                "a cell that lags reads t - delta dt/dt, which changes sign with the tension's rate, not with the cable's direction; moves at constant speed (no tension change) separate them",
            ),
            (
                "inertia",
                "both change at reversals; friction is a step proportional to the tension at a reversal and stays while the cable moves, inertia follows the acceleration and is zero at constant speed",
            ),
        ]
    }
    fn signature(&self) -> &'static str {
        "the cell's tension times the cable's direction of motion (reel in / pay out)"
    }
}

#[cfg(test)]
mod tests {
    use super::super::loadcell_gain::LoadcellGain;
    use super::*;

    /// The balance's corrected tension `f exp(-lambda)` with the gain's and the friction's log
    /// factors is the loop's `taut_model::cell_tension`: one formula on both sides.
    #[test]
    fn the_balance_corrects_a_reading_as_the_loop_does() {
        let (gain, mu_theta, f) = (1.07f64, 0.3, 52.0);
        for v in [-0.05, -0.004, 0.0, 0.002, 0.05] {
            let row = BalanceRow { t: 0.0, a: [0.0; 3], var_a: 0.0, u: vec![[0.0, 0.0, 1.0]], f: vec![f], v: vec![v] };
            let lambda: f64 = [LoadcellGain.term(gain.ln(), &row, 0), Friction.term(mu_theta, &row, 0)]
                .iter()
                .map(|t| match t {
                    Term::CellLogFactor { value, .. } => *value,
                    Term::PlatformForce { .. } => panic!("a cell effect"),
                })
                .sum();
            let loop_t = taut_model::cell_tension(f, gain, mu_theta, v);
            assert!((f * (-lambda).exp() - loop_t).abs() < 1e-9 * f, "v {v}");
        }
    }
}
