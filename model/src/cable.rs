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

/// The swivel axis of a pulley that does not say otherwise: vertical, the cable arriving along
/// it from above.
pub const VERTICAL_AXIS: [f64; 3] = [0.0, 0.0, 1.0];

/// A swivel pulley at a cable's anchor: its radius and the unit vector of its swivel axis,
/// pointing from the anchor towards where the cable comes from (the winch).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwivelPulley {
    /// Radius, m (0: no pulley, the cable leaves from the anchor point).
    pub r: f64,
    /// Unit vector of the swivel axis ([`VERTICAL_AXIS`]: the cable comes down from above).
    pub axis: [f64; 3],
}

impl SwivelPulley {
    /// No pulley: the straight cable from the anchor.
    pub const NONE: SwivelPulley = SwivelPulley { r: 0.0, axis: VERTICAL_AXIS };
}

/// The whole model as the loop evaluates it: the encoder reading of a cable from `anchor` to the
/// platform attachment `x`, over `pulley` (radius 0: none; straight on the swivel axis, where
/// the pulley model has no plane), stretched by `tension_n` (not finite or negative: no
/// stretch) with `compliance`, read through a drum of `scale` with offset `l0`. Allocates
/// nothing.
#[inline]
pub fn cable_length(x: [f64; 3], anchor: [f64; 3], pulley: SwivelPulley, compliance: f64, tension_n: f64, scale: f64, l0: f64) -> f64 {
    let straight = straight_length(x, anchor);
    let g = if pulley.r > 0.0 { pulley_length(x, anchor, pulley.axis, pulley.r).map_or(straight, |(g, _)| g) } else { straight };
    let t = if tension_n.is_finite() && tension_n > 0.0 { tension_n } else { 0.0 };
    reading(scale, unstretched(g, compliance, t), l0)
}

/// Length over a swivel pulley of radius `r` from the entry point `anchor` to the platform
/// attachment `x`; the pulley swivels about the unit vector `axis` through the anchor.
///
/// ```text
/// The cable arrives along the swivel axis from the side `axis` points to (VERTICAL_AXIS: from
/// above) and touches the pulley at the anchor; the pulley plane contains the axis and X.
/// In-plane coordinates relative to the anchor: z = (X - A).axis along the axis, rho the
/// distance of X from it, e = the unit vector from the axis towards X. Pulley centre C = A + r e,
/// in the plane C = (r, 0), X = (rho, z).
///   d_c  = |X - C|,  psi = atan2(z, rho - r)
///   exit tangent point at angle phi_e = psi - acos(r / d_c)  (mod 2 pi, in [pi, 3 pi))
///   wrap beta = phi_e - pi,   G = r beta + sqrt(d_c^2 - r^2)
///   dG/dX = dG/drho e + dG/dz axis
/// ```
///
/// `axis` must be a unit vector (the configuration normalises it). With [`VERTICAL_AXIS`] the
/// in-plane coordinates are taken directly as `rho = |(X - A)_xy|`, `z = (X - A)_z`: the
/// projection onto `[0, 0, 1]` gives the same numbers up to signed zeros and rounding order, and
/// the direct form keeps the vertical case exact to the bit, which the loop's commands rely on.
///
/// Returns `G` and `[dG/dX (3), dG/dr]`; `dG/dA = -dG/dX` (the axis direction is fixed);
/// `None` on the axis (no plane) or inside the pulley.
pub fn pulley_length(x: [f64; 3], anchor: [f64; 3], axis: [f64; 3], r: f64) -> Option<(f64, [f64; 4])> {
    let dx = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
    let vertical = axis == VERTICAL_AXIS;
    // The distance from the axis, the coordinate along it, and the part of X - A across it.
    let (rho, z, across) = if vertical {
        ((dx[0] * dx[0] + dx[1] * dx[1]).sqrt(), dx[2], [dx[0], dx[1], 0.0])
    } else {
        let z = dx[0] * axis[0] + dx[1] * axis[1] + dx[2] * axis[2];
        let p = [dx[0] - z * axis[0], dx[1] - z * axis[1], dx[2] - z * axis[2]];
        ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt(), z, p)
    };
    if rho < 1e-9 {
        return None;
    }
    // Inputs: 0 = rho, 1 = z, 2 = r.
    let rd = Dual::<3>::var(rho, 0);
    let zd = Dual::var(z, 1);
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
    let e = [across[0] / rho, across[1] / rho, across[2] / rho];
    let dx_of = if vertical {
        [g.d[0] * e[0], g.d[0] * e[1], g.d[1]]
    } else {
        [g.d[0] * e[0] + g.d[1] * axis[0], g.d[0] * e[1] + g.d[1] * axis[1], g.d[0] * e[2] + g.d[1] * axis[2]]
    };
    Some((g.v, [dx_of[0], dx_of[1], dx_of[2], g.d[2]]))
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
        assert_eq!(cable_length([0.0, 0.0, 0.0], [3.0, 0.0, 4.0], SwivelPulley::NONE, 0.0, 100.0, 1.0, 0.5), 5.5);
    }

    #[test]
    fn stretch_and_scale_compose_as_written() {
        let g = straight_length([0.0; 3], [0.0, 0.0, 4.0]);
        let want = 1.003 * (g / (1.0 + 100.0 / 20_000.0)) + 0.1;
        assert_eq!(cable_length([0.0; 3], [0.0, 0.0, 4.0], SwivelPulley::NONE, 1.0 / 20_000.0, 100.0, 1.003, 0.1), want);
        // No usable tension: no stretch.
        for t in [f64::NAN, -5.0, 0.0] {
            assert_eq!(cable_length([0.0; 3], [0.0, 0.0, 4.0], SwivelPulley::NONE, 1.0 / 20_000.0, t, 1.0, 0.0), 4.0);
        }
    }

    #[test]
    fn a_pulley_lengthens_the_path_by_less_than_its_radius() {
        let (x, a) = ([1.0, 0.5, 0.0], [0.0, 0.0, 3.0]);
        let pulley = SwivelPulley { r: 0.05, axis: VERTICAL_AXIS };
        let extra = cable_length(x, a, pulley, 0.0, 0.0, 1.0, 0.0) - straight_length(x, a);
        assert!(extra > 0.0 && extra < 0.05, "{extra}");
        // On the swivel axis the pulley has no plane: straight.
        assert_eq!(cable_length([0.0, 0.0, 0.0], a, pulley, 0.0, 0.0, 1.0, 0.0), 3.0);
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

    /// The vertical-axis formula as it was before the axis became a parameter, kept as the
    /// reference the vertical case must reproduce bit for bit.
    fn vertical_reference(x: [f64; 3], anchor: [f64; 3], r: f64) -> Option<(f64, [f64; 4])> {
        let dx = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
        let rho = (dx[0] * dx[0] + dx[1] * dx[1]).sqrt();
        if rho < 1e-9 {
            return None;
        }
        let rd = Dual::<3>::var(rho, 0);
        let zd = Dual::var(dx[2], 1);
        let radius = Dual::var(r, 2);
        let cx = rd - radius;
        let dc2 = cx * cx + zd * zd;
        if dc2.v <= r * r {
            return None;
        }
        let dc = dc2.sqrt();
        let phi = zd.atan2(cx) - (radius / dc).acos();
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

    /// A small deterministic generator for the sweeps below.
    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn unit(v: [f64; 3]) -> [f64; 3] {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    }

    #[test]
    fn the_vertical_axis_gives_the_old_formula_bit_for_bit() {
        let mut s = 7u64;
        let mut compared = 0;
        for _ in 0..5000 {
            let x = [4.0 * lcg(&mut s), 4.0 * lcg(&mut s), 3.0 * lcg(&mut s)];
            let a = [4.0 * lcg(&mut s), 4.0 * lcg(&mut s), 4.0 + lcg(&mut s)];
            let r = 0.1 * (lcg(&mut s) + 1.0);
            let (new, old) = (pulley_length(x, a, VERTICAL_AXIS, r), vertical_reference(x, a, r));
            assert_eq!(new.is_some(), old.is_some());
            if let (Some((g, d)), Some((g0, d0))) = (new, old) {
                assert_eq!(g.to_bits(), g0.to_bits());
                assert!(d.iter().zip(&d0).all(|(a, b)| a.to_bits() == b.to_bits()), "{d:?} {d0:?}");
                compared += 1;
            }
        }
        assert!(compared > 4900, "{compared}");
    }

    /// Rotating the whole scene (platform point, anchor and axis) leaves the length and turns its
    /// gradient with it: the general arithmetic agrees with the vertical one for every axis.
    #[test]
    fn any_axis_is_the_vertical_one_rotated() {
        let mut s = 11u64;
        for _ in 0..500 {
            let axis = unit([lcg(&mut s), lcg(&mut s), lcg(&mut s)]);
            // A rotation taking the vertical to `axis` (Rodrigues about z x axis).
            let k = [-axis[1], axis[0], 0.0];
            let (sn, c) = ((k[0] * k[0] + k[1] * k[1]).sqrt(), axis[2]);
            let rot = |v: [f64; 3]| -> [f64; 3] {
                if sn < 1e-12 {
                    return if c > 0.0 { v } else { [v[0], -v[1], -v[2]] };
                }
                let k = [k[0] / sn, k[1] / sn, 0.0];
                let kv = k[0] * v[0] + k[1] * v[1];
                let cr = [k[1] * v[2], -k[0] * v[2], k[0] * v[1] - k[1] * v[0]];
                std::array::from_fn(|i| v[i] * c + cr[i] * sn + k[i] * kv * (1.0 - c))
            };
            let x = [3.0 * lcg(&mut s), 3.0 * lcg(&mut s), 2.0 * lcg(&mut s) - 2.5];
            let a = [lcg(&mut s), lcg(&mut s), 0.5 * lcg(&mut s)];
            let r = 0.02 + 0.05 * (lcg(&mut s) + 1.0);
            let Some((g, d)) = pulley_length(x, a, VERTICAL_AXIS, r) else { continue };
            let (g1, d1) = pulley_length(rot(x), rot(a), rot(VERTICAL_AXIS), r).unwrap();
            assert!((g - g1).abs() < 1e-12 * g.max(1.0), "{g} {g1} axis {axis:?}");
            let want = rot([d[0], d[1], d[2]]);
            assert!((0..3).all(|i| (want[i] - d1[i]).abs() < 1e-9) && (d[3] - d1[3]).abs() < 1e-9, "{want:?} {d1:?}");
        }
    }

    fn fd(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    /// dG/dX and dG/dr against central differences at horizontal and inclined axes, with the
    /// platform on either side of the pulley plane's normal and at small and large wrap angles.
    #[test]
    fn derivatives_at_horizontal_and_inclined_axes_match_finite_differences() {
        let axes = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], unit([1.0, 1.0, 0.0]), unit([1.0, 0.0, 1.0]), unit([-0.3, 0.5, 0.8])];
        let points = [[-2.0, 0.3, -3.0], [-0.5, 1.5, -0.2], [1.0, -2.0, -1.0], [-3.0, -0.1, 0.4]];
        let a = [0.3, -0.2, 0.1];
        let mut checked = 0;
        for axis in axes {
            for x in points {
                for r in [0.025, 0.04, 0.3] {
                    let Some((g, d)) = pulley_length(x, a, axis, r) else { continue };
                    assert!(g >= straight_length(x, a) - 1e-12, "the path over the pulley is never shorter");
                    for k in 0..3 {
                        let num = fd(
                            |v| {
                                let mut xx = x;
                                xx[k] = v;
                                pulley_length(xx, a, axis, r).unwrap().0
                            },
                            x[k],
                            1e-6,
                        );
                        assert!((d[k] - num).abs() < 1e-7, "axis {axis:?} x {x:?} r {r}: dX{k} {} vs {num}", d[k]);
                        // dG/dA = -dG/dX.
                        let num_a = fd(
                            |v| {
                                let mut aa = a;
                                aa[k] = v;
                                pulley_length(x, aa, axis, r).unwrap().0
                            },
                            a[k],
                            1e-6,
                        );
                        assert!((d[k] + num_a).abs() < 1e-7, "dA{k} {} vs {num_a}", -d[k]);
                    }
                    let num = fd(|v| pulley_length(x, a, axis, v).unwrap().0, r, 1e-7);
                    assert!((d[3] - num).abs() < 1e-6, "axis {axis:?} x {x:?}: dr {} vs {num}", d[3]);
                    // The gradient wrt X is the unit direction of the free segment.
                    assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-9);
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, axes.len() * points.len() * 3);
    }

    /// A horizontal axis by hand: the cable comes in along +x towards the anchor at the origin
    /// (axis [1, 0, 0]: from the winch on the +x side), the platform is 1 m beyond the pulley
    /// (-x) and 1 m below its plane's entry level: in the plane (axis coordinate z = -1, rho = 2
    /// with r = 1 measured straight down), C = (1, 0), X = (2, -1): a quarter turn and 1 m free.
    #[test]
    fn a_horizontal_axis_by_hand() {
        let (g, _) = pulley_length([-1.0, 0.0, -2.0], [0.0; 3], [1.0, 0.0, 0.0], 1.0).unwrap();
        assert!((g - (std::f64::consts::FRAC_PI_2 + 1.0)).abs() < 1e-12, "{g}");
        // On the axis there is no pulley plane.
        assert!(pulley_length([-2.0, 0.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0], 0.05).is_none());
        // A pulley through which the cable runs on straight, along its axis, wraps nothing.
        let (g, _) = pulley_length([-3.0, 1e-3, 0.0], [0.0; 3], [1.0, 0.0, 0.0], 1e-9).unwrap();
        assert!((g - straight_length([-3.0, 1e-3, 0.0], [0.0; 3])).abs() < 1e-8);
    }
}
