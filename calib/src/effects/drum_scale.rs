//! Drum scale: the drum radius or the encoder's counts per metre differ from the nominal, so
//! each cable's reading is off by a factor.
//!
//! ```text
//! v = (1 + k) U + L0,   k = scale - 1      per cable; internal parameter k
//! ```

use super::{Effect, EffectModel, Sharing};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The drum-scale effect (`scale` in the reports).
pub struct DrumScale;

/// The reading's factor `1 + k` for the internal parameter `k` (`dv/dk = U`).
pub fn factor(k: f64) -> f64 {
    1.0 + k
}

impl EffectModel for DrumScale {
    fn id(&self) -> Effect {
        Effect::Scale
    }
    fn name(&self) -> &'static str {
        "scale"
    }
    fn parameter(&self) -> &'static str {
        "scale"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("length scale", "", 1.0)
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    fn internal_range(&self) -> (f64, f64) {
        (-0.05, 0.05)
    }
    fn bounds(&self) -> (f64, f64) {
        (-0.2, 0.2)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Elasticity), Some(Effect::DrumBuildup)]
    }
    fn separation(&self, other: Option<Effect>) -> Option<&'static str> {
        (other == Some(Effect::Elasticity)).then_some(
            "the same cable length held at different tensions separates them (stretch changes with tension, a scale error does not)",
        )
    }
    fn to_physical(&self, x: f64, sigma: f64) -> (f64, f64) {
        (1.0 + x, sigma)
    }
    fn signature(&self) -> &'static str {
        "L"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Length
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("drum_scale")
    }
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.drum_scale.as_ref().and_then(|v| v.get(j).copied()).map(|s| s - 1.0)
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.drum_scale, out.drum_scale_sigma) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_is_reported_as_the_factor() {
        assert_eq!(DrumScale.to_physical(0.01, 1e-4), (1.01, 1e-4));
        let mut e = Effects::default();
        DrumScale.store(&mut e, vec![1.01], Some(vec![1e-4])).unwrap();
        assert!((DrumScale.start_from(&e, 0).unwrap() - 0.01).abs() < 1e-15);
    }
}
