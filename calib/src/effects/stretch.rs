//! Elasticity: the cable stretches `T L / EA` under tension and the encoder, which counts the
//! unstretched length paid out, does not see it.
//!
//! ```text
//! U = G / (1 + c T),   c = 1/EA            per cable; internal parameter the compliance c
//! ```
//!
//! Fitted in the compliance: the model is linear in it and `c = 0` (a rigid cable) is inside
//! the bounds, where `EA` would be infinite.

use super::{Effect, EffectModel, Needs, Sharing};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The elasticity effect.
pub struct Stretch;

impl EffectModel for Stretch {
    fn id(&self) -> Effect {
        Effect::Elasticity
    }
    fn name(&self) -> &'static str {
        "elasticity"
    }
    fn parameter(&self) -> &'static str {
        "EA_N"
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    fn needs(&self) -> Needs {
        Needs { tensions: true, time_series: false }
    }
    /// EA from 1 kN to 1 GN.
    fn internal_range(&self) -> (f64, f64) {
        (1e-9, 1e-3)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 1e-2)
    }
    fn start(&self) -> f64 {
        1e-6
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Sag), Some(Effect::Scale)]
    }
    /// EA = 1/c, sigma_EA = sigma_c / c^2 (first order).
    fn to_physical(&self, x: f64, sigma: f64) -> (f64, f64) {
        (1.0 / x, sigma / (x * x))
    }
    fn signature(&self) -> &'static str {
        "-T*L"
    }
    fn regressor(&self) -> Regressor {
        Regressor::TensionLength
    }
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.ea_n.as_ref().and_then(|v| v.get(j).copied()).map(|ea| 1.0 / ea)
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.ea_n, out.ea_sigma_n) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compliance_converts_to_stiffness_and_back_from_the_running_model() {
        let (ea, s) = Stretch.to_physical(5e-6, 1e-7);
        assert!((ea - 2e5).abs() < 1e-6 && (s - 4e3).abs() < 1e-6, "{ea} {s}");
        let mut e = Effects::default();
        Stretch.store(&mut e, vec![2e5, 4e5], None).unwrap();
        assert_eq!(Stretch.start_from(&e, 1), Some(1.0 / 4e5));
        assert_eq!(Stretch.start_from(&e, 2), None);
    }
}
