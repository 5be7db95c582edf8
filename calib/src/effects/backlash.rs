//! Backlash: play of width `w_b` in the drive train, so the reading depends on the direction
//! of motion.
//!
//! ```text
//! l_hat = play(v; w_b)       l_hat_i = v_c - sigma w_b / 2, c the last sample that pushed
//! ```
//!
//! Per cable. Needs the readings in time order (the play's history,
//! [`super::model::PlayState`]); a time offset mimics it at reversals.

use super::{Effect, EffectModel, Needs, Sharing};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The backlash effect.
pub struct Backlash;

impl EffectModel for Backlash {
    fn id(&self) -> Effect {
        Effect::Backlash
    }
    fn name(&self) -> &'static str {
        "backlash"
    }
    fn parameter(&self) -> &'static str {
        "width_m"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("play", "mm", 1e3)
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    fn needs(&self) -> Needs {
        Needs { tensions: false, time_series: true }
    }
    fn internal_range(&self) -> (f64, f64) {
        (1e-5, 0.05)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 0.1)
    }
    /// Not 0: with no play every sample pushes, and the side follows the tracker noise.
    fn start(&self) -> f64 {
        1e-3
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::TimeOffset)]
    }
    fn separation(&self, other: Option<Effect>) -> Option<&'static str> {
        (other == Some(Effect::TimeOffset))
            .then_some("reversals at different speeds separate them (a time offset's error grows with speed, backlash's does not)")
    }
    fn signature(&self) -> &'static str {
        "direction of motion"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Direction
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("backlash_m")
    }
    /// A running width of zero is no play: the fit starts at [`EffectModel::start`].
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.backlash_m.as_ref().and_then(|v| v.get(j).copied()).filter(|w| *w > 0.0)
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.backlash_m, out.backlash_sigma_m) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_zero_running_play_starts_at_the_default() {
        let mut e = Effects::default();
        Backlash.store(&mut e, vec![0.0, 2e-3], None).unwrap();
        assert_eq!(Backlash.start_from(&e, 0), None);
        assert_eq!(Backlash.start_from(&e, 1), Some(2e-3));
        assert!(Effect::Backlash.separating_measurement(Some(Effect::TimeOffset)).contains("speeds"));
    }
}
