//! Slack: a loose cable's encoder counts slack, not geometry. Not modelled: its readings are
//! found (tension below a threshold) and left out of every fit.

use super::{Effect, EffectModel, Needs, Sharing};
use crate::diagnose::analysis::Regressor;

/// The slack effect.
pub struct Slack;

impl EffectModel for Slack {
    fn id(&self) -> Effect {
        Effect::Slack
    }
    fn name(&self) -> &'static str {
        "slack"
    }
    fn parameter(&self) -> &'static str {
        "threshold_N"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("loose below", "N", 1.0)
    }
    fn sharing(&self) -> Sharing {
        Sharing::Shared
    }
    fn needs(&self) -> Needs {
        Needs { tensions: false, time_series: false }
    }
    fn internal_range(&self) -> (f64, f64) {
        (0.0, f64::INFINITY)
    }
    fn bounds(&self) -> (f64, f64) {
        (f64::NEG_INFINITY, f64::INFINITY)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[]
    }
    fn signature(&self) -> &'static str {
        "low tension"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Tension
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slack_is_not_fitted() {
        assert!(!Effect::FITTED.contains(&Effect::Slack));
        assert_eq!(Effect::from_name("slack"), Some(Effect::Slack));
    }
}
