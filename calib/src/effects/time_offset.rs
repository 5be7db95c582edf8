//! Time offset: the encoders and the tracker are sampled with a delay `delta` between them
//! (`delta > 0`: the encoders lag), so a moving cable's reading belongs to another pose.
//!
//! ```text
//! residual_i = l(t_i + delta) - model(pose_i, T_i)     encoder series interpolated in time
//! ```
//!
//! One offset for the robot. Needs the readings in time order; backlash mimics it at
//! reversals.

use super::{Effect, EffectModel, Needs, Sharing};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The time-offset effect.
pub struct TimeOffset;

impl EffectModel for TimeOffset {
    fn id(&self) -> Effect {
        Effect::TimeOffset
    }
    fn name(&self) -> &'static str {
        "time-offset"
    }
    fn parameter(&self) -> &'static str {
        "offset_s"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("time offset", "ms", 1e3)
    }
    fn sharing(&self) -> Sharing {
        Sharing::Shared
    }
    fn needs(&self) -> Needs {
        Needs { tensions: false, time_series: true }
    }
    fn internal_range(&self) -> (f64, f64) {
        (-0.5, 0.5)
    }
    fn bounds(&self) -> (f64, f64) {
        (-1.0, 1.0)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Backlash)]
    }
    fn signature(&self) -> &'static str {
        "-cable velocity"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Velocity
    }
    fn signature_sign(&self) -> f64 {
        -1.0
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("time_offset_s")
    }
    /// The data were aligned by the running offset: what is left starts at zero.
    fn start_from(&self, _running: &Effects, _j: usize) -> Option<f64> {
        Some(0.0)
    }
    /// One value for the robot (the first).
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.time_offset_s, out.time_offset_sigma_s) = (Some(values[0]), sigmas.map(|s| s[0]));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_offset_for_the_robot() {
        let mut e = Effects::default();
        TimeOffset.store(&mut e, vec![0.02], Some(vec![1e-3])).unwrap();
        assert_eq!((e.time_offset_s, e.time_offset_sigma_s), (Some(0.02), Some(1e-3)));
        assert_eq!(TimeOffset.start_from(&e, 3), Some(0.0));
    }
}
