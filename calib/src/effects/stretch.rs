//! Elasticity: the cable stretches `T L / EA` under tension and the encoder, which counts the
//! unstretched length paid out, does not see it.
//!
//! ```text
//! U = G / (1 + c T),   c = 1/EA            per cable; internal parameter the compliance c
//! ```
//!
//! Fitted in the compliance: the model is linear in it and `c = 0` (a rigid cable) is inside
//! the bounds, where `EA` would be infinite.

use super::{Effect, EffectModel, Needs, Path, Sharing, Unstretched};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The elasticity effect.
pub struct Stretch;

/// The unstretched length `U = G / (1 + c T)` of `path` at compliance `c` and tension `t`, and
/// its derivatives; `g_tx` the path's `d (dG/dT) / dX`.
pub fn unstretch(path: &Path, g_tx: [f64; 3], c: f64, t: f64) -> Unstretched {
    let (g, g_t, g_tw) = (path.g, path.g_t, path.g_tw);
    let q = 1.0 + c * t;
    Unstretched {
        u: taut_model::unstretched(g, c, t),
        du_dg: 1.0 / q,
        du_dc: -g * t / (q * q),
        // u = G / (1 + c T): du/dT = G_T / q - G c / q^2.
        u_t: g_t / q - g * c / (q * q),
        u_tc: -g_t * t / (q * q) - g / (q * q) + 2.0 * g * c * t / (q * q * q),
        u_tw: g_tw / q,
        u_tg: -c / (q * q),
        u_tx: g_tx.map(|v| v / q),
    }
}

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
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("EA", "N", 1.0)
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
        &[Some(Effect::Sag), Some(Effect::Scale), Some(Effect::Compliance)]
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
    fn signature_sign(&self) -> f64 {
        -1.0
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("ea_n")
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

    /// The derivatives of `U` by `G`, `c` and `T` match finite differences.
    #[test]
    fn unstretch_derivatives_match_finite_differences() {
        let (g, c, t) = (7.5, 5e-6, 300.0);
        let at = |g: f64, c: f64, t: f64| unstretch(&Path { g, gx: [1.0, 0.0, 0.0], g_t: 0.0, g_tw: 0.0 }, [0.0; 3], c, t);
        let u = at(g, c, t);
        let fd = |f: &dyn Fn(f64) -> f64, x: f64, h: f64| (f(x + h) - f(x - h)) / (2.0 * h);
        assert!((u.du_dg - fd(&|v| at(v, c, t).u, g, 1e-4)).abs() < 1e-9);
        assert!((u.du_dc - fd(&|v| at(g, v, t).u, c, 1e-9)).abs() < 1e-6 * u.du_dc.abs());
        assert!((u.u_t - fd(&|v| at(g, c, v).u, t, 1e-2)).abs() < 1e-9);
        assert!((u.u_tc - fd(&|v| at(g, v, t).u_t, c, 1e-9)).abs() < 1e-6 * u.u_tc.abs());
    }

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
