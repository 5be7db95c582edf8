//! Drum build-up: the cable winds on its drum in layers, so the drum's effective radius changes
//! with the cable on it and the length paid out per encoder count is not constant. The length is
//! then quadratic in the drum's angle; a linear drum scale ([`super::drum_scale`]) does not absorb
//! it.
//!
//! Physics. A drum of effective radius `r(phi) = r_n + b phi` at the angle `phi` paid out from
//! the reference (`b = dr/dphi`; for a multi-layer winding of a cable of diameter `d` at pitch
//! `p` on a drum `W` wide, `|b| = d p / (2 pi W)`: one layer `d` per `W / p` turns; a single-layer
//! helix has `b = 0`; paying out of a full drum `b < 0`) pays out
//!
//! ```text
//! l_true = integral r dphi = r_n phi + b phi^2 / 2 = u + q u^2,   u = r_n phi = l_enc - L0,
//! q = b / (2 r_n^2)                                   per cable; internal parameter q, 1/m
//! ```
//!
//! `u` is the length the encoder derives with the nominal radius `r_n` (the reading less its
//! offset: the reference is the cable length zero the offsets refer to). The prediction inverts
//! it: the encoder sees `B = 2 U / (1 + sqrt(1 + 4 q U))` of the unstretched length `U`, then
//! the scale and the offset act on `B`. Example: a 1 mm cable, five turns a layer on a 25 mm
//! drum: `b = -3.2e-5` m/rad, `q = -0.025` /m, 22 mm over a 1.5 m stroke's curvature.
//!
//! Over a workspace's range of lengths `q u^2` is a straight line (a scale and an offset) plus
//! the curvature `q (u - u_mid)^2`: with a scale in the model only the curvature identifies `q`.

use super::{Effect, EffectModel, Sharing};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The drum build-up effect (`spool-buildup` in the reports; `drum-buildup` is still read, see
/// [`super::Effect::from_name`]).
pub struct DrumBuildup;

/// The encoder-derived length `B` whose true paid-out length `B + q B^2` is `u` (the root that
/// is `u` at `q = 0`), with `dB/du` and `dB/dq`.
///
/// The value is the loop's (`taut_model::buildup_counted`, with its floor where `1 + 4 q u` is not
/// positive).
pub fn encoder_length(u: f64, q: f64) -> (f64, f64, f64) {
    let b = taut_model::buildup_counted(u, q);
    // B + q B^2 = u: (1 + 2 q B) dB = du - B^2 dq.
    let den = 1.0 + 2.0 * q * b;
    (b, 1.0 / den, -b * b / den)
}

impl EffectModel for DrumBuildup {
    fn id(&self) -> Effect {
        Effect::DrumBuildup
    }
    fn name(&self) -> &'static str {
        "spool-buildup"
    }
    fn parameter(&self) -> &'static str {
        "buildup_per_m"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("drum build-up q", "1/m", 1.0)
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    /// `|q| <= 0.05` /m: a 2 mm cable, five turns a layer on a 25 mm drum.
    fn internal_range(&self) -> (f64, f64) {
        (-0.05, 0.05)
    }
    fn bounds(&self) -> (f64, f64) {
        (-0.1, 0.1)
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Scale), Some(Effect::Sag)]
    }
    fn separation(&self, other: Option<Effect>) -> Option<&'static str> {
        match other {
            Some(Effect::Scale) => Some(
                "readings over a wider range of cable lengths separate them (build-up is quadratic in the paid-out length, a scale error linear); or count the drum's turns per layer",
            ),
            Some(Effect::Sag) => Some(
                "the same cable length held at different tensions or cable angles separates them (sag changes with both, build-up depends on the length alone)",
            ),
            _ => None,
        }
    }
    fn signature(&self) -> &'static str {
        "L^2"
    }
    fn regressor(&self) -> Regressor {
        Regressor::Length
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("drum_buildup_per_m")
    }
    /// The file's `drum_buildup_per_m` (`taut-params v3`); the loop's kinematics count each
    /// cable's length on its drum with it (`taut_model::buildup_counted`).
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.drum_buildup_per_m.as_ref().and_then(|v| v.get(j).copied())
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.drum_buildup_per_m, out.drum_buildup_sigma_per_m) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `B + q B^2 = u`, and `dB/du`, `dB/dq` match central differences.
    #[test]
    fn encoder_length_inverts_the_quadratic_and_its_derivatives_match_finite_differences() {
        for (u, q) in [(2.5, -0.03), (4.0, 0.02), (1.0, 0.0), (0.3, 0.08)] {
            let (b, du, dq) = encoder_length(u, q);
            assert!((b + q * b * b - u).abs() < 1e-12, "{u} {q}");
            let fd_u = (encoder_length(u + 1e-6, q).0 - encoder_length(u - 1e-6, q).0) / 2e-6;
            let fd_q = (encoder_length(u, q + 1e-7).0 - encoder_length(u, q - 1e-7).0) / 2e-7;
            assert!((du - fd_u).abs() < 1e-7, "{du} {fd_u}");
            assert!((dq - fd_q).abs() < 1e-6 * dq.abs().max(1.0), "{dq} {fd_q}");
        }
        assert_eq!(encoder_length(3.0, 0.0), (3.0, 1.0, -9.0));
    }
}
