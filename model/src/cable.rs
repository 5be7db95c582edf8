//! The per-cable formulas (see the crate documentation).

use crate::dual::Dual;

/// Straight-line length `|X - A|` from the anchor `anchor` to the platform attachment `x`, m.
#[inline]
pub fn straight_length(x: [f64; 3], anchor: [f64; 3]) -> f64 {
    let d = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// The unstretched length the encoder counts for a cable of geometric length `g` under
/// `tension_n` with compliance `compliance` (`1 / EA`, 1/N): `g / (1 + c T)`.
#[inline]
pub fn unstretched(g: f64, compliance: f64, tension_n: f64) -> f64 {
    g / (1.0 + compliance * tension_n)
}

/// The length the encoder counts when the winch, the frame or the anchor gives way by
/// `compliance t` under the cable's tension `t` (compliance in m/N, independent of the cable's
/// length): the path `u` less that deflection. `u` itself (bit for bit) at compliance 0; a
/// tension that is not finite or not positive deflects nothing (as in [`cable_length`]).
#[inline]
pub fn deflection_counted(u: f64, compliance_m_per_n: f64, tension_n: f64) -> f64 {
    if compliance_m_per_n == 0.0 || !(tension_n.is_finite() && tension_n > 0.0) {
        u
    } else {
        u - compliance_m_per_n * tension_n
    }
}

/// The length a drum with build-up `q` (1/m) counts for a paid-out length `u`: a drum wound in
/// layers pays out `b + q b^2` while its encoder counts `b`, so the count is the root
/// `2 u / (1 + sqrt(1 + 4 q u))`, `u` itself (bit for bit) at `q = 0`. Where `1 + 4 q u` is not
/// positive (the drum's radius would have reached zero: far outside the physical range) the
/// root is taken at the discriminant's floor, 1e-6, so that the value stays finite.
#[inline]
pub fn buildup_counted(u: f64, q: f64) -> f64 {
    2.0 * u / (1.0 + (1.0 + 4.0 * q * u).max(1e-6).sqrt())
}

/// The encoder reading for an unstretched length `u`: `scale u + l0`.
#[inline]
pub fn reading(scale: f64, u: f64, l0: f64) -> f64 {
    scale * u + l0
}

/// The whole model as the loop evaluates it: the encoder reading of a cable from `anchor` to the
/// platform attachment `x`, over a swivel pulley of radius `pulley_r` (0: none; straight below a
/// point on the swivel axis, where the pulley model has no plane), stretched by `tension_n` (not
/// finite or negative: no stretch) with `compliance`, read through a drum of `scale` with offset
/// `l0`. Allocates nothing.
#[inline]
pub fn cable_length(x: [f64; 3], anchor: [f64; 3], pulley_r: f64, compliance: f64, tension_n: f64, scale: f64, l0: f64) -> f64 {
    let straight = straight_length(x, anchor);
    let g = if pulley_r > 0.0 { pulley_length(x, anchor, pulley_r).map_or(straight, |(g, _)| g) } else { straight };
    let t = if tension_n.is_finite() && tension_n > 0.0 { tension_n } else { 0.0 };
    reading(scale, unstretched(g, compliance, t), l0)
}

/// Length over a swivel pulley of radius `r` from the entry point `anchor` to the platform
/// attachment `x`.
///
/// ```text
/// The swivel axis is vertical through the anchor (the cable arrives along it from above); the
/// pulley plane contains the axis and X. In-plane coordinates (rho horizontal towards X, z up),
/// relative to the anchor: pulley centre C = (r, 0), X = (rho, z).
///   d_c  = |X - C|,  psi = atan2(z, rho - r)
///   exit tangent point at angle phi_e = psi - acos(r / d_c)  (mod 2 pi, in [pi, 3 pi))
///   wrap beta = phi_e - pi,   G = r beta + sqrt(d_c^2 - r^2)
/// ```
///
/// Returns `G` and `[dG/dX (3), dG/dr]`; `dG/dA = -dG/dX` (the axis direction is fixed).
pub fn pulley_length(x: [f64; 3], anchor: [f64; 3], r: f64) -> Option<(f64, [f64; 4])> {
    let dx = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
    let rho = (dx[0] * dx[0] + dx[1] * dx[1]).sqrt();
    if rho < 1e-9 {
        return None;
    }
    // Inputs: 0 = rho, 1 = z, 2 = r.
    let rd = Dual::<3>::var(rho, 0);
    let zd = Dual::var(dx[2], 1);
    let radius = Dual::var(r, 2);
    let cx = rd - radius;
    let dc2 = cx * cx + zd * zd;
    if dc2.v <= r * r {
        return None;
    }
    let dc = dc2.sqrt();
    let psi = zd.atan2(cx);
    let phi = psi - (radius / dc).acos();
    // Normalise the value into [pi, 3 pi); the partials do not change.
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut shift = 0.0;
    while phi.v + shift < std::f64::consts::PI {
        shift += two_pi;
    }
    while phi.v + shift >= 3.0 * std::f64::consts::PI {
        shift -= two_pi;
    }
    let beta = phi.offset(shift - std::f64::consts::PI);
    let g = radius * beta + (dc2 - radius * radius).sqrt();
    let (ex, ey) = (dx[0] / rho, dx[1] / rho);
    Some((g.v, [g.d[0] * ex, g.d[0] * ey, g.d[1], g.d[2]]))
}

/// Speed over which the guides' friction turns over with the cable's direction, m/s (see
/// [`cell_tension`]).
pub const FRICTION_V_BAND_M_S: f64 = 0.005;

/// The smooth direction of a cable's motion, `tanh(v / FRICTION_V_BAND_M_S)`: +1 paying out
/// (`v > 0`, the length grows), -1 reeling in, 0 at rest or when the speed is unknown (not
/// finite), where the plain reading is the middle of the static-friction cone.
#[inline]
pub fn friction_direction(v: f64) -> f64 {
    if v.is_finite() {
        (v / FRICTION_V_BAND_M_S).tanh()
    } else {
        0.0
    }
}

/// The cable's tension from its load cell's reading `f` (offset already removed), N: the cell
/// reads `f = gain t exp(-mu_theta s(v))` (capstan friction `mu theta` in the guides between
/// the platform and the cell, `s` = [`friction_direction`] of the length rate `v`, m/s), so
/// `t = f / gain * exp(mu_theta s(v))`. `f` itself (bit for bit) at gain 1 and `mu_theta` 0.
#[inline]
pub fn cell_tension(f: f64, gain: f64, mu_theta: f64, v: f64) -> f64 {
    let t = f / gain;
    if mu_theta == 0.0 {
        t
    } else {
        t * (mu_theta * friction_direction(v)).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ideal_cable_is_the_straight_line_plus_the_offset() {
        assert_eq!(cable_length([0.0, 0.0, 0.0], [3.0, 0.0, 4.0], 0.0, 0.0, 100.0, 1.0, 0.5), 5.5);
    }

    #[test]
    fn stretch_and_scale_compose_as_written() {
        let g = straight_length([0.0; 3], [0.0, 0.0, 4.0]);
        let want = 1.003 * (g / (1.0 + 100.0 / 20_000.0)) + 0.1;
        assert_eq!(cable_length([0.0; 3], [0.0, 0.0, 4.0], 0.0, 1.0 / 20_000.0, 100.0, 1.003, 0.1), want);
        // No usable tension: no stretch.
        for t in [f64::NAN, -5.0, 0.0] {
            assert_eq!(cable_length([0.0; 3], [0.0, 0.0, 4.0], 0.0, 1.0 / 20_000.0, t, 1.0, 0.0), 4.0);
        }
    }

    #[test]
    fn a_pulley_lengthens_the_path_by_less_than_its_radius() {
        let (x, a) = ([1.0, 0.5, 0.0], [0.0, 0.0, 3.0]);
        let extra = cable_length(x, a, 0.05, 0.0, 0.0, 1.0, 0.0) - straight_length(x, a);
        assert!(extra > 0.0 && extra < 0.05, "{extra}");
        // On the swivel axis the pulley has no plane: straight.
        assert_eq!(cable_length([0.0, 0.0, 0.0], a, 0.05, 0.0, 0.0, 1.0, 0.0), 3.0);
    }

    #[test]
    fn cell_tension_undoes_gain_and_friction_and_is_the_reading_when_off() {
        for f in [0.0, 37.25, -1.5, f64::NAN] {
            for v in [0.0, -0.2, 0.3, f64::NAN] {
                assert_eq!(cell_tension(f, 1.0, 0.0, v).to_bits(), f.to_bits());
            }
        }
        let (t, g, c) = (40.0f64, 1.04f64, 0.2f64);
        // Paying out fast the cell reads the platform's tension held back by the guides.
        let paying_out = g * t * (-c).exp();
        assert!((cell_tension(paying_out, g, c, 0.1) - t).abs() < 1e-9);
        let reeling_in = g * t * c.exp();
        assert!((cell_tension(reeling_in, g, c, -0.1) - t).abs() < 1e-9);
        assert!((cell_tension(g * t, g, c, 0.0) - t).abs() < 1e-12);
        assert_eq!(friction_direction(f64::NAN), 0.0);
    }
}
