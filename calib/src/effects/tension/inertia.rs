//! The platform's inertia: during fast moves the tensions balance `m (a - g)`, not `-m g`. A
//! statics-only balance leaves `m a` in its residual, which follows the tracker's acceleration
//! and is the same force whichever cables carry it. The parameter is the inertial mass `m_i`,
//! kg (internal and reported): named, it should come out as the platform's mass (a point-mass
//! platform; a platform's rotational inertia is not modelled).
//!
//! A length effect cannot take it up: the balance contains no length, and the length residuals
//! contain no platform acceleration (the cables' stretch and sag follow the measured tensions,
//! which carry the inertia whatever the model of the balance).

use super::{BalanceRow, TensionEffect, TensionEffectModel, Term};
use crate::effects::Sharing;

/// The inertia effect (`inertia` in the reports).
pub struct Inertia;

impl TensionEffectModel for Inertia {
    fn id(&self) -> TensionEffect {
        TensionEffect::Inertia
    }
    fn name(&self) -> &'static str {
        "inertia"
    }
    fn parameter(&self) -> &'static str {
        "inertial_mass_kg"
    }
    fn sharing(&self) -> Sharing {
        Sharing::Shared
    }
    /// Any positive mass up to 10 t: the inertial mass is compared with the known one in the
    /// report, not gated.
    fn internal_range(&self) -> (f64, f64) {
        (0.0, 1e4)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 1e5)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn term(&self, x: f64, row: &BalanceRow, _j: usize) -> Term {
        Term::PlatformForce { value: row.a.map(|a| x * a), d: row.a }
    }
    fn mimics(&self) -> &'static [(&'static str, &'static str)] {
        &[(
            "friction",
            "both change at reversals; inertia follows the platform's acceleration whichever way the cables move, friction the cables' direction of motion at any acceleration",
        )]
    }
    fn signature(&self) -> &'static str {
        "the platform's acceleration"
    }
}
