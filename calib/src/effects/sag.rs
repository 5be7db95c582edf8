//! Sag: a cable of weight `w` per metre hangs in a catenary, longer than the chord by an
//! excess that grows as `w^2 L^3 cos^2(elevation) / T^2`.
//!
//! ```text
//! G += s(a, h, w, T) - sqrt(a^2 + h^2)       catenary arc minus chord (horizontal a, height h)
//! ```
//!
//! One weight per length for the robot. Needs the measured tension (at the end the load cell
//! sits, [`TensionEnd`]); elasticity mimics it over a narrow range of tensions. The running
//! robot does not model it.

use super::{Effect, EffectModel, Needs, Path, Sharing, TensionEnd};
use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;
use taut_model::dual::Dual;

/// The sag effect.
pub struct Sag;

/// Adds the catenary's excess of a cable of weight `w` per metre at the measured tension `t`
/// (at `end`) to `path` (length, `dG/dX`, `dG/dT`, `d^2 G / dT dw`), and returns `dG/dw`.
/// Without a tension, or where no taut catenary carries it, the path is left straight
/// (`dG/dw = 0`).
pub fn add_excess(path: &mut Path, x: [f64; 3], anchor: [f64; 3], w: f64, t: f64, end: TensionEnd) -> f64 {
    if !(t.is_finite() && w > 0.0) {
        return 0.0;
    }
    let Some((e, d)) = sag_excess(x, anchor, w, t, end) else { return 0.0 };
    path.g += e;
    path.gx = [path.gx[0] + d[0], path.gx[1] + d[1], path.gx[2] + d[2]];
    path.g_t = d[4];
    // The excess grows about as w^2 (a function of w / T): d(dG/dT)/dw = 2 g_t / w.
    path.g_tw = 2.0 * d[4] / w;
    d[3]
}

impl EffectModel for Sag {
    fn id(&self) -> Effect {
        Effect::Sag
    }
    fn name(&self) -> &'static str {
        "sag"
    }
    fn parameter(&self) -> &'static str {
        "weight_per_length_N_per_m"
    }
    fn parameter_words(&self) -> (&'static str, &'static str, f64) {
        ("weight per length", "N/m", 1.0)
    }
    fn sharing(&self) -> Sharing {
        Sharing::Shared
    }
    fn needs(&self) -> Needs {
        Needs { tensions: true, time_series: false }
    }
    fn internal_range(&self) -> (f64, f64) {
        (1e-3, 60.0)
    }
    fn bounds(&self) -> (f64, f64) {
        (0.0, 100.0)
    }
    fn start(&self) -> f64 {
        0.05
    }
    fn mimics(&self) -> &'static [Option<Effect>] {
        &[Some(Effect::Elasticity), Some(Effect::DrumBuildup)]
    }
    fn separation(&self, other: Option<Effect>) -> Option<&'static str> {
        (other == Some(Effect::Elasticity)).then_some(
            "the same cable length held at different tensions separates them (stretch grows as T, the sag excess falls as 1/T^2)",
        )
    }
    fn signature(&self) -> &'static str {
        "L^3 cos^2(elev)/T^2"
    }
    fn regressor(&self) -> Regressor {
        Regressor::SagTerm
    }
    fn store(&self, _out: &mut Effects, _values: Vec<f64>, _sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        Err("sag not written: the running robot does not model it")
    }
}

/// A catenary through the platform end (origin) and the anchor end at horizontal distance `a`
/// and height `h` above it, for weight per length `w` and the tension `t` at one end.
///
/// ```text
/// D = w a / H,  E = w h / H,  m = asinh(E / (2 sinh(D/2)))
/// u_anchor = m + D/2,  u_platform = m - D/2       (u = w (x - x0) / H)
/// s = sqrt(h^2 + (2H/w sinh(D/2))^2)               arc length
/// T_anchor = H cosh(u_anchor),  T_platform = H cosh(u_platform)
/// ```
///
/// `H` (horizontal tension) is found by Newton from the measured end tension, starting from the
/// straight cable `H = t a / chord`, which picks the taut branch. Returns the arc length and its
/// partials `[ds/da, ds/dh, ds/dw, ds/dt]`, or `None` when no taut catenary carries `t`.
pub fn catenary(a: f64, h: f64, w: f64, t: f64, end: TensionEnd) -> Option<(f64, [f64; 4])> {
    let chord = (a * a + h * h).sqrt();
    if !(a > 1e-9 && w > 0.0 && t > 0.0 && chord > 0.0) {
        return None;
    }
    // Inputs of the dual numbers: 0 = H, 1 = a, 2 = h, 3 = w. The Newton steps need d/dH only:
    // they run with one derivative (`N = 1`, inputs 1-3 constants), whose value and d/dH are
    // the same operations on the same numbers as the first slot of `N = 4` (every dual
    // operation treats its slots alike), so the iterates are the same bits at a quarter of the
    // derivative work (this solve is most of a diagnosis's time).
    fn eval<const N: usize>(hh: f64, a: f64, h: f64, w: f64, end: TensionEnd) -> (Dual<N>, Dual<N>) {
        let var = |v: f64, k: usize| if k < N { Dual::<N>::var(v, k) } else { Dual::<N> { v, d: [0.0; N] } };
        let hd = var(hh, 0);
        let ad = var(a, 1);
        let vd = var(h, 2);
        let wd = var(w, 3);
        let dd = wd * ad / hd;
        let ee = wd * vd / hd;
        let half = (dd * 0.5).sinh();
        let m = (ee / (half * 2.0)).asinh();
        let u = match end {
            TensionEnd::Anchor => m + dd * 0.5,
            TensionEnd::Platform => m - dd * 0.5,
        };
        let tension = hd * u.cosh();
        let span = hd / wd * half * 2.0;
        let s = (vd * vd + span * span).sqrt();
        (tension, s)
    }
    let mut hh = t * a / chord;
    let mut converged = false;
    for _ in 0..60 {
        let (tn, _) = eval::<1>(hh, a, h, w, end);
        let g = tn.v - t;
        let dg = tn.d[0];
        if !(dg.is_finite() && dg > 0.0) {
            return None;
        }
        let mut step = g / dg;
        // Keep H positive: at most halve it per step.
        if step > 0.5 * hh {
            step = 0.5 * hh;
        }
        hh -= step;
        if step.abs() <= 1e-13 * hh.max(1e-9) {
            converged = true;
            break;
        }
    }
    if !converged || !(hh > 0.0) {
        return None;
    }
    let (tn, s) = eval::<4>(hh, a, h, w, end);
    if !s.v.is_finite() {
        return None;
    }
    // Implicit function: T(H, a, h, w) = t  =>  dH/dq = -dT/dq / dT/dH,  dH/dt = 1 / dT/dH.
    let dt_dh = tn.d[0];
    let ds = |k: usize| s.d[k] - s.d[0] * tn.d[k] / dt_dh;
    Some((s.v, [ds(1), ds(2), ds(3), s.d[0] / dt_dh]))
}

/// Sag excess of a cable: catenary arc length minus chord, for platform attachment `x` and anchor
/// `a` (z up). Returns the excess and its partials `[d/dX (3), d/dw, d/dT]`; `d/dA = -d/dX`.
/// `None` when the catenary has no taut solution for this tension.
pub fn sag_excess(x: [f64; 3], anchor: [f64; 3], w: f64, t: f64, end: TensionEnd) -> Option<(f64, [f64; 5])> {
    let dx = [anchor[0] - x[0], anchor[1] - x[1]];
    let a = (dx[0] * dx[0] + dx[1] * dx[1]).sqrt();
    let h = anchor[2] - x[2];
    let chord = (a * a + h * h).sqrt();
    let (s, [ds_da, ds_dh, ds_dw, ds_dt]) = catenary(a, h, w, t, end)?;
    let e_da = ds_da - a / chord;
    let e_dh = ds_dh - h / chord;
    // a grows as X moves away from A horizontally; h shrinks as X rises.
    let (ex, ey) = if a > 0.0 { (-dx[0] / a, -dx[1] / a) } else { (0.0, 0.0) };
    Some((s - chord, [e_da * ex, e_da * ey, -e_dh, ds_dw, ds_dt]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::TensionEnd;

    fn fd(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    /// Integrates the cable curve from the platform end: the horizontal force H is constant and
    /// the vertical force grows by w per metre of cable (RK4 in arc length). Returns (a, h).
    fn integrate_cable(hf: f64, v0: f64, w: f64, length: f64) -> (f64, f64) {
        let n = 20_000;
        let ds = length / n as f64;
        let f = |s: f64| {
            let v = v0 + w * s;
            let t = (hf * hf + v * v).sqrt();
            (hf / t, v / t)
        };
        let (mut x, mut z) = (0.0, 0.0);
        for k in 0..n {
            let s = k as f64 * ds;
            let k1 = f(s);
            let k2 = f(s + 0.5 * ds);
            let k4 = f(s + ds);
            x += ds / 6.0 * (k1.0 + 4.0 * k2.0 + k4.0);
            z += ds / 6.0 * (k1.1 + 4.0 * k2.1 + k4.1);
        }
        (x, z)
    }

    #[test]
    fn catenary_matches_numerical_integration_of_the_cable_curve() {
        for &(hf, v0, w, len) in &[(200.0, 150.0, 0.5, 20.0), (30.0, 40.0, 2.0, 8.0), (500.0, -20.0, 5.0, 25.0), (80.0, 10.0, 1.0, 3.0)] {
            let (a, h) = integrate_cable(hf, v0, w, len);
            let t_plat = (hf * hf + v0 * v0).sqrt();
            let v1 = v0 + w * len;
            let t_anchor = (hf * hf + v1 * v1).sqrt();
            let (s, _) = catenary(a, h, w, t_plat, TensionEnd::Platform).unwrap();
            assert!((s - len).abs() < 1e-7 * len, "platform end: s = {s}, integrated {len}");
            let (s, _) = catenary(a, h, w, t_anchor, TensionEnd::Anchor).unwrap();
            assert!((s - len).abs() < 1e-7 * len, "anchor end: s = {s}, integrated {len}");
            // Tension difference between the ends is w h (a property of every catenary).
            assert!((t_anchor - t_plat - w * h).abs() < 1e-6 * t_anchor);
        }
    }

    #[test]
    fn catenary_jacobian_matches_finite_differences() {
        let (a, h, w, t) = (12.0, 9.0, 1.5, 120.0);
        for end in [TensionEnd::Anchor, TensionEnd::Platform] {
            let (_, d) = catenary(a, h, w, t, end).unwrap();
            let s = |a: f64, h: f64, w: f64, t: f64| catenary(a, h, w, t, end).unwrap().0;
            let num = [
                fd(|x| s(x, h, w, t), a, 1e-5),
                fd(|x| s(a, x, w, t), h, 1e-5),
                fd(|x| s(a, h, x, t), w, 1e-6),
                fd(|x| s(a, h, w, x), t, 1e-4),
            ];
            for k in 0..4 {
                assert!((d[k] - num[k]).abs() < 1e-6 * (1.0 + num[k].abs()), "k={k}: {} vs {}", d[k], num[k]);
            }
        }
    }

    #[test]
    fn sag_excess_jacobian_matches_finite_differences() {
        let x = [1.0, -2.0, 0.5];
        let an = [8.0, 6.0, 12.0];
        let (w, t) = (0.8, 90.0);
        let (_, d) = sag_excess(x, an, w, t, TensionEnd::Platform).unwrap();
        for k in 0..3 {
            let num = fd(
                |v| {
                    let mut xx = x;
                    xx[k] = v;
                    sag_excess(xx, an, w, t, TensionEnd::Platform).unwrap().0
                },
                x[k],
                1e-5,
            );
            assert!((d[k] - num).abs() < 1e-7, "dX{k}: {} vs {num}", d[k]);
        }
        let num = fd(|v| sag_excess(x, an, v, t, TensionEnd::Platform).unwrap().0, w, 1e-6);
        assert!((d[3] - num).abs() < 1e-7);
        let num = fd(|v| sag_excess(x, an, w, v, TensionEnd::Platform).unwrap().0, t, 1e-4);
        assert!((d[4] - num).abs() < 1e-8);
    }

    #[test]
    fn sag_excess_matches_small_sag_approximation() {
        // Small sag: s - chord ~ w^2 a^2 chord / (24 H^2) for a horizontal-ish chord.
        let (w, t) = (0.2, 500.0);
        let (e, _) = sag_excess([0.0; 3], [10.0, 0.0, 0.0], w, t, TensionEnd::Platform).unwrap();
        let approx = w * w * 1000.0 / (24.0 * t * t);
        assert!((e - approx).abs() < 0.01 * approx, "{e} vs {approx}");
    }
}
