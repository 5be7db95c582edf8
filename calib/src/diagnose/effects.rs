//! The library of physical effects the ideal model `l = |X - A| + L0` leaves out.
//!
//! Each effect is a model with physically meaningful parameters and a plausible range; a fit that
//! lands outside the range is not physics and the effect is not claimed. The modelled encoder
//! reading of cable `j` at sample `i` is built up in this order:
//!
//! ```text
//! X      = P(t_i - delta) + R b_j                      time-offset: delta > 0, encoder lags tracker
//! G      = |X - A|          or  r*beta + sqrt(|X - C|^2 - r^2)      pulley (swivel, radius r)
//! G     += s(a, h, w, T) - sqrt(a^2 + h^2)             sag: catenary arc minus chord
//! U      = G / (1 + T c),   c = 1/EA                   elasticity: encoder sees unstretched length
//! v      = (1 + k) U + L0                              scale k = scale - 1
//! l_hat  = play(v; w_b)                                backlash: play operator of width w_b
//! ```
//!
//! The play runs over the samples in time order (see [`super::fit::PlayState`]): the reading
//! stays put while `v` moves inside `[l_hat - w_b/2, l_hat + w_b/2]` and is pushed along once `v`
//! leaves it, so `l_hat_i = v_c - sigma w_b / 2` with `c` the last sample that pushed and
//! `sigma = +1` paying out, `-1` reeling in.
//!
//! Loose cables (`slack`) are not modelled: their samples are found and excluded.

use taut_model::dual::Dual;

/// One effect of the library. Names are the `taut-diagnosis v1` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// Cable stretch `T L / EA` that the encoder does not see.
    Elasticity,
    /// Catenary of a cable with weight per length `w`.
    Sag,
    /// Swivel pulley of radius `r`: wrap and moving exit point.
    Pulley,
    /// Drum radius or encoder scale error per cable.
    Scale,
    /// Encoders and tracker sampled with a delay between them.
    TimeOffset,
    /// Play in the drive train: the reading depends on the direction of motion.
    Backlash,
    /// Loose-cable samples (found and excluded, not modelled).
    Slack,
}

/// Whether an effect has one parameter per cable or one for the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sharing {
    /// One value per cable.
    PerCable,
    /// One value shared by all cables.
    Shared,
}

impl Effect {
    /// The effects that are fitted (everything but `slack`), in a fixed order.
    pub const FITTED: [Effect; 6] = [Effect::Elasticity, Effect::Sag, Effect::Pulley, Effect::Scale, Effect::TimeOffset, Effect::Backlash];

    /// The name in the `taut-diagnosis v1` output.
    pub fn name(self) -> &'static str {
        match self {
            Effect::Elasticity => "elasticity",
            Effect::Sag => "sag",
            Effect::Pulley => "pulley",
            Effect::Scale => "scale",
            Effect::TimeOffset => "time-offset",
            Effect::Backlash => "backlash",
            Effect::Slack => "slack",
        }
    }

    /// The parameter name in the output.
    pub fn parameter(self) -> &'static str {
        match self {
            Effect::Elasticity => "EA_N",
            Effect::Sag => "weight_per_length_N_per_m",
            Effect::Pulley => "radius_m",
            Effect::Scale => "scale",
            Effect::TimeOffset => "offset_s",
            Effect::Backlash => "width_m",
            Effect::Slack => "threshold_N",
        }
    }

    /// Needs measured tensions.
    pub fn needs_tension(self) -> bool {
        matches!(self, Effect::Elasticity | Effect::Sag)
    }

    /// One parameter per cable, or one shared.
    pub fn sharing(self) -> Sharing {
        match self {
            Effect::Elasticity | Effect::Scale | Effect::Backlash => Sharing::PerCable,
            _ => Sharing::Shared,
        }
    }

    /// Plausible range of the *internal* parameter (see [`Effect::to_physical`]): compliance
    /// 1/EA for elasticity (EA from 1 kN to 1 GN), w in N/m, r in m, scale - 1, delay in s,
    /// width in m.
    pub fn internal_range(self) -> (f64, f64) {
        match self {
            Effect::Elasticity => (1e-9, 1e-3),
            Effect::Sag => (1e-3, 60.0),
            Effect::Pulley => (2e-3, 0.5),
            Effect::Scale => (-0.05, 0.05),
            Effect::TimeOffset => (-0.5, 0.5),
            Effect::Backlash => (1e-5, 0.05),
            Effect::Slack => (0.0, f64::INFINITY),
        }
    }

    /// The effects (`None`: the anchors) whose fitted form can stand in for this one on some
    /// recordings, and which are therefore also fitted jointly with it.
    pub fn mimics(self) -> &'static [Option<Effect>] {
        match self {
            Effect::Elasticity => &[Some(Effect::Sag), Some(Effect::Scale)],
            Effect::Sag => &[Some(Effect::Elasticity)],
            Effect::Scale => &[Some(Effect::Elasticity)],
            Effect::Pulley => &[None],
            Effect::TimeOffset => &[Some(Effect::Backlash)],
            Effect::Backlash => &[Some(Effect::TimeOffset)],
            Effect::Slack => &[],
        }
    }

    /// The measurement that would separate this effect from `other` (`None`: a shifted anchor)
    /// when a recording cannot.
    pub fn separating_measurement(self, other: Option<Effect>) -> &'static str {
        use Effect::*;
        match (self, other) {
            (TimeOffset, Some(Backlash)) | (Backlash, Some(TimeOffset)) => {
                "reversals at different speeds separate them (a time offset's error grows with speed, backlash's does not)"
            }
            (Sag, Some(Elasticity)) | (Elasticity, Some(Sag)) => {
                "the same cable length held at different tensions separates them (stretch grows as T, the sag excess falls as 1/T^2)"
            }
            (Scale, Some(Elasticity)) | (Elasticity, Some(Scale)) => {
                "the same cable length held at different tensions separates them (stretch changes with tension, a scale error does not)"
            }
            (Pulley, _) | (_, Some(Pulley)) | (_, None) => {
                "poses at large wrap angles (the platform far out, cables near horizontal) separate a swivel pulley from a shifted anchor; or measure the pulley radius or the anchor positions"
            }
            _ => "a recording over more of the workspace, at several speeds and tensions, would separate them",
        }
    }

    /// Internal parameter -> reported value and its 1-sigma.
    pub fn to_physical(self, x: f64, sigma: f64) -> (f64, f64) {
        match self {
            // EA = 1/c, sigma_EA = sigma_c / c^2 (first order).
            Effect::Elasticity => (1.0 / x, sigma / (x * x)),
            Effect::Scale => (1.0 + x, sigma),
            _ => (x, sigma),
        }
    }

    /// A starting value of the internal parameter for the fit.
    pub fn start(self) -> f64 {
        match self {
            Effect::Elasticity => 1e-6,
            Effect::Sag => 0.05,
            Effect::Pulley => 0.02,
            // Not 0: with no play every sample pushes, and the side follows the tracker noise.
            Effect::Backlash => 1e-3,
            _ => 0.0,
        }
    }

    /// What the residual follows when this effect is left out, in words.
    pub fn signature(self) -> &'static str {
        match self {
            Effect::Elasticity => "-T*L",
            Effect::Sag => "L^3 cos^2(elev)/T^2",
            Effect::Pulley => "cable elevation angle",
            Effect::Scale => "L",
            Effect::TimeOffset => "-cable velocity",
            Effect::Backlash => "direction of motion",
            Effect::Slack => "low tension",
        }
    }

    /// Parses a `taut-diagnosis v1` name.
    pub fn from_name(s: &str) -> Option<Effect> {
        Effect::FITTED.into_iter().chain([Effect::Slack]).find(|e| e.name() == s)
    }
}

/// Which end of the cable the load cell measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TensionEnd {
    /// At the anchor / winch (a load cell on the frame).
    Anchor,
    /// At the platform attachment.
    Platform,
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

pub use taut_model::pulley_length;

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn pulley_reduces_to_straight_cable_for_small_radius_and_jacobian_is_right() {
        let x = [1.5, 0.7, -3.0];
        let an = [0.0, 0.0, 0.0];
        let (g, _) = pulley_length(x, an, 1e-9).unwrap();
        let straight = (1.5f64 * 1.5 + 0.49 + 9.0).sqrt();
        assert!((g - straight).abs() < 1e-8);
        let r = 0.06;
        let (_, d) = pulley_length(x, an, r).unwrap();
        for k in 0..3 {
            let num = fd(
                |v| {
                    let mut xx = x;
                    xx[k] = v;
                    pulley_length(xx, an, r).unwrap().0
                },
                x[k],
                1e-6,
            );
            assert!((d[k] - num).abs() < 1e-7, "dX{k}: {} vs {num}", d[k]);
        }
        let num = fd(|v| pulley_length(x, an, v).unwrap().0, r, 1e-7);
        assert!((d[3] - num).abs() < 1e-6, "dr: {} vs {num}", d[3]);
        // The gradient wrt X is the unit direction of the free segment.
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((n - 1.0).abs() < 1e-9);
    }

    #[test]
    fn pulley_wrap_geometry_by_hand() {
        // Platform straight below the pulley centre, far away: wrap 90 degrees... no: the cable
        // leaves the leftmost point going down only when X is below the anchor. X level with the
        // centre and to the right: wrap is half a turn minus nothing -> beta = pi/2 below? Check a
        // case computed by hand: X = (r + 1, -1) relative to the anchor, r = 1:
        // C = (1, 0), d_c = sqrt(2), psi = -45 deg, acos(1/sqrt 2) = 45 deg -> phi_e = -90 deg = 270 deg,
        // beta = 90 deg, free segment = 1, G = pi/2 + 1.
        let (g, _) = pulley_length([2.0, 0.0, -1.0], [0.0; 3], 1.0).unwrap();
        assert!((g - (std::f64::consts::FRAC_PI_2 + 1.0)).abs() < 1e-12, "{g}");
    }

    #[test]
    fn names_round_trip() {
        for e in Effect::FITTED {
            assert_eq!(Effect::from_name(e.name()), Some(e));
        }
        assert_eq!(Effect::TimeOffset.name(), "time-offset");
    }
}
