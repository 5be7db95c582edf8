//! Compliance independent of the cable's length: the winch, its frame or the anchor gives way
//! under the cable's tension, so the encoder counts `k T` less than the cable's path while an
//! elastic cable ([`super::stretch`]) would count `G c T`, in proportion to its length.
//!
//! ```text
//! U' = U - k T                                     per cable; internal parameter k, m/N
//! ```
//!
//! Applied to the unstretched length `U`, before the drum build-up and the scale: the deflection
//! is paid out (or taken up) at the drum like any length. The sign is the physics of every
//! source named above: a winch pulled towards the platform, a bent frame or a twisted drive
//! train between the encoder and the drum all let the platform sit farther from the drum than
//! the count says. `k < 0` is not physics, so the fit's bound is 0.
//!
//! What it mimics and what separates them:
//! - **Elasticity**: both shorten the reading by something proportional to the tension; the
//!   stretch by `G T / EA`. On a recording whose cables keep nearly one length, `G` is a
//!   constant and the two are one regressor; only tensions varying at different lengths of the
//!   same cable separate them. A redundant robot's controller can change the tensions at the
//!   same poses by moving its internal force (measured: docs/diagnosis.md).
//! - **Drum scale** (not fitted jointly: it mimics only through the tension's dependence on the
//!   pose): a tension that rises with the cable's length makes `k T` nearly linear in the
//!   length; tensions changed independently of the length (a follower's swing) separate them.
//!
//! A time offset is not among them: it follows the cable's velocity along the path, which the
//! tension does not (the quasi-static tension is a function of the pose, not of its rate).
//!
//! The value is the loop's (`taut_model::deflection_counted`).

use super::{Effect, EffectModel, Needs, Sharing, Unstretched};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

/// The compliance effect (`compliance` in the reports).
pub struct Compliance;

/// The length the encoder counts, `U - k T`, of the unstretched `un` at compliance `k` (m/N) and
/// tension `t`, with `dU'/dk = -T`; `U'`'s tension derivative `U_T - k` (its derivative by `k`
/// is -1).
pub fn deflect(un: Unstretched, k: f64, t: f64) -> (Unstretched, f64) {
    let u = taut_model::deflection_counted(un.u, k, t);
    let t_eff = if t.is_finite() && t > 0.0 { t } else { 0.0 };
    (Unstretched { u, u_t: un.u_t - k, ..un }, -t_eff)
}

impl EffectModel for Compliance {
    fn id(&self) -> Effect {
        Effect::Compliance
    }
    fn name(&self) -> &'static str {
        "compliance"
    }
    fn parameter(&self) -> &'static str {
        "compliance_m_per_N"
    }
    /// Shown in mm/kN: a frame's deflection of 0.45 mm at 300 N is 1.5 mm/kN.
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("compliance k", "mm/kN", 1e6)
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    fn needs(&self) -> Needs {
        Needs { tensions: true, time_series: false }
    }
    /// 1 um/kN (a steel frame's give, far below a reading's noise) to 1 mm/N (a light robot's
    /// sprung or plastic mount: a few millimetres at its 5-30 N).
    fn internal_range(&self) -> (f64, f64) {
        (1e-9, 1e-3)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 1e-2)
    }
    /// 1 mm/kN.
    fn start(&self) -> f64 {
        1e-6
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Elasticity)]
    }
    fn separation(&self, other: Option<Effect>) -> Option<&'static str> {
        match other {
            Some(Effect::Elasticity) => Some(
                "the same cable tensioned differently at short and long lengths separates them (the stretch grows with the length, the frame's deflection does not): on a robot with four or more cables, record a long taut excitation while the controller moves its internal force (the cables trading tension at the same poses); or load the winch at a fixed length and measure its give",
            ),
            _ => None,
        }
    }
    fn signature(&self) -> &'static str {
        "-T"
    }
    fn signature_sign(&self) -> f64 {
        -1.0
    }
    fn regressor(&self) -> Regressor {
        Regressor::Tension
    }
    fn parameter_key(&self) -> Option<&'static str> {
        Some("compliance_m_per_n")
    }
    /// The file's `compliance_m_per_n` (`taut-params v5`); the loop's kinematics count each
    /// cable's length less it (`taut_model::deflection_counted`).
    fn start_from(&self, running: &Effects, j: usize) -> Option<f64> {
        running.compliance_m_per_n.as_ref().and_then(|v| v.get(j).copied())
    }
    fn store(&self, out: &mut Effects, values: Vec<f64>, sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        (out.compliance_m_per_n, out.compliance_sigma_m_per_n) = (Some(values), sigmas);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `U' = U - k T`, and its derivatives by `k`, `T` and `U` match central differences; no
    /// tension deflects nothing.
    #[test]
    fn deflect_derivatives_match_finite_differences() {
        let path = super::super::Path { g: 6.0, gx: [1.0, 0.0, 0.0], g_t: 0.0, g_tw: 0.0 };
        let at = |k: f64, t: f64| {
            let un = super::super::stretch::unstretch(&path, [0.0; 3], 2e-5, t);
            deflect(un, k, t)
        };
        let fd = |f: &dyn Fn(f64) -> f64, x: f64, h: f64| (f(x + h) - f(x - h)) / (2.0 * h);
        for (k, t) in [(1.5e-6, 300.0), (4e-6, 40.0), (0.0, 120.0)] {
            let (u, du_dk) = at(k, t);
            // U' is linear in k: a step of 1e-4 m/N has no truncation error and little rounding.
            assert!((du_dk - fd(&|v| at(v, t).0.u, k, 1e-4)).abs() < 1e-8 * t, "dU/dk {du_dk}");
            assert!((u.u_t - fd(&|v| at(k, v).0.u, t, 1e-2)).abs() < 1e-9, "dU/dT {}", u.u_t);
            assert!((fd(&|v| at(v, t).0.u_t, k, 1e-4) + 1.0).abs() < 1e-9, "d(dU/dT)/dk");
            let by_g = |g: f64| deflect(super::super::stretch::unstretch(&super::super::Path { g, ..path }, [0.0; 3], 2e-5, t), k, t).0.u;
            assert!((u.du_dg - fd(&by_g, 6.0, 1e-4)).abs() < 1e-9);
        }
        let rigid = Unstretched::rigid(&path, [0.0; 3]);
        let (none, d) = deflect(rigid, 2e-6, f64::NAN);
        assert_eq!((none.u, d), (6.0, 0.0));
        assert_eq!(deflect(rigid, 0.0, 250.0).0.u, 6.0);
    }

    #[test]
    fn stores_in_the_parameter_file_and_starts_from_it() {
        let mut e = Effects::default();
        Compliance.store(&mut e, vec![1.5e-6, 3e-7], Some(vec![1e-7; 2])).unwrap();
        assert_eq!(Compliance.start_from(&e, 1), Some(3e-7));
        assert_eq!(Compliance.start_from(&e, 2), None);
        assert_eq!(e.names(), vec!["compliance"]);
    }
}
