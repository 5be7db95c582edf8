//! Cable geometry: attachment points, modelled encoder lengths and their analytic Jacobians.
//!
//! ```text
//! X_j = P + R b_j                 attachment point of cable j in the tracker frame
//! d   = X_j - A_j,  rho = |d|,  u = d / rho     (unit vector anchor -> platform)
//! l_j = rho + L0_j                modelled encoder reading
//!
//! dl/dA_j  = -u^T      dl/dL0_j = 1
//! dl/dP    =  u^T      dl/dtheta = ((R b_j) x u)^T   (small rotation R <- exp([theta]x) R)
//! ```
//!
//! Every Jacobian here is checked against central finite differences in the tests below.

/// A 3x3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// Rotation matrix of a quaternion `(w, x, y, z)`; the quaternion is normalised first, so a
/// slightly denormalised tracker output still gives a rotation. `None` for a zero or non-finite
/// quaternion (a tracker dropout).
pub fn rotation(q: [f64; 4]) -> Option<Mat3> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n.is_finite() && n > 1e-9) {
        return None;
    }
    let [w, x, y, z] = q.map(|v| v / n);
    Some([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ])
}

/// `R v`.
pub fn mat_vec(r: &Mat3, v: [f64; 3]) -> [f64; 3] {
    [
        r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
        r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
        r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
    ]
}

/// Attachment point `X = P + R b` of a cable in the tracker frame; `R` is the identity when the
/// recording has no orientation.
pub fn attachment(p: [f64; 3], r: Option<&Mat3>, b: [f64; 3]) -> [f64; 3] {
    let rb = match r {
        Some(r) => mat_vec(r, b),
        None => b,
    };
    [p[0] + rb[0], p[1] + rb[1], p[2] + rb[2]]
}

/// Geometric cable length `rho = |X - A|` and unit direction `u = (X - A) / rho`.
pub fn direction(x: [f64; 3], a: [f64; 3]) -> (f64, [f64; 3]) {
    let d = [x[0] - a[0], x[1] - a[1], x[2] - a[2]];
    let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    (rho, [d[0] / rho, d[1] / rho, d[2] / rho])
}

/// Modelled encoder reading `|X - A| + L0`.
pub fn cable_length(x: [f64; 3], a: [f64; 3], l0: f64) -> f64 {
    direction(x, a).0 + l0
}

/// `dl / d(A_x, A_y, A_z, L0)` at attachment point `x`.
pub fn jacobian_params(x: [f64; 3], a: [f64; 3]) -> [f64; 4] {
    let (_, u) = direction(x, a);
    [-u[0], -u[1], -u[2], 1.0]
}

/// `dl / dP`: how a tracker position error moves the modelled length (used to project the
/// tracker covariance on the cable direction).
pub fn jacobian_position(x: [f64; 3], a: [f64; 3]) -> [f64; 3] {
    direction(x, a).1
}

/// `dl / dtheta` for a small rotation `R <- exp([theta]x) R` of the platform: `(R b) x u`.
pub fn jacobian_orientation(x: [f64; 3], a: [f64; 3], rb: [f64; 3]) -> [f64; 3] {
    let (_, u) = direction(x, a);
    cross(rb, u)
}

/// `a x b`.
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `a . b`.
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a - b`.
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `|a|`.
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: f64 = 1e-6;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
    }

    fn cases() -> Vec<([f64; 3], [f64; 3], f64)> {
        vec![
            ([0.3, -0.2, 1.5], [3.5, -1.75, 4.0], 0.7),
            ([-1.0, 0.8, 0.4], [-3.5, 1.75, 4.0], -2.0),
            ([0.01, 0.02, 2.9], [0.0, 0.0, 3.0], 0.0),
        ]
    }

    #[test]
    fn parameter_jacobian_matches_finite_differences() {
        for (x, a, l0) in cases() {
            let j = jacobian_params(x, a);
            for k in 0..4 {
                let mut ap = a;
                let mut am = a;
                let (mut lp, mut lm) = (l0, l0);
                if k < 3 {
                    ap[k] += H;
                    am[k] -= H;
                } else {
                    lp += H;
                    lm -= H;
                }
                let fd = (cable_length(x, ap, lp) - cable_length(x, am, lm)) / (2.0 * H);
                assert!(close(j[k], fd, 1e-8), "param {k}: analytic {} vs fd {fd}", j[k]);
            }
        }
    }

    #[test]
    fn position_jacobian_matches_finite_differences() {
        for (x, a, l0) in cases() {
            let j = jacobian_position(x, a);
            for k in 0..3 {
                let mut xp = x;
                let mut xm = x;
                xp[k] += H;
                xm[k] -= H;
                let fd = (cable_length(xp, a, l0) - cable_length(xm, a, l0)) / (2.0 * H);
                assert!(close(j[k], fd, 1e-8), "axis {k}: analytic {} vs fd {fd}", j[k]);
            }
        }
    }

    fn small_rotation(theta: [f64; 3]) -> Mat3 {
        // exp([theta]x) via the quaternion of the rotation vector.
        let angle = norm(theta);
        if angle == 0.0 {
            return rotation([1.0, 0.0, 0.0, 0.0]).unwrap();
        }
        let s = (angle / 2.0).sin() / angle;
        rotation([(angle / 2.0).cos(), theta[0] * s, theta[1] * s, theta[2] * s]).unwrap()
    }

    fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
        let mut c = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
            }
        }
        c
    }

    #[test]
    fn orientation_jacobian_matches_finite_differences() {
        let r0 = rotation([0.9, 0.1, -0.3, 0.2]).unwrap();
        let b = [0.12, -0.05, 0.08];
        for (p, a, l0) in cases() {
            let rb = mat_vec(&r0, b);
            let x = attachment(p, Some(&r0), b);
            let j = jacobian_orientation(x, a, rb);
            for k in 0..3 {
                let mut tp = [0.0; 3];
                let mut tm = [0.0; 3];
                tp[k] = H;
                tm[k] = -H;
                let rp = mat_mul(&small_rotation(tp), &r0);
                let rm = mat_mul(&small_rotation(tm), &r0);
                let fd = (cable_length(attachment(p, Some(&rp), b), a, l0) - cable_length(attachment(p, Some(&rm), b), a, l0)) / (2.0 * H);
                assert!(close(j[k], fd, 1e-7), "rot axis {k}: analytic {} vs fd {fd}", j[k]);
            }
        }
    }

    proptest::proptest! {
        /// The parameter and position Jacobians match central differences for any geometry with
        /// the cable at least 10 cm long.
        #[test]
        fn jacobians_match_finite_differences_anywhere(
            x in proptest::array::uniform3(-3.0f64..3.0),
            a in proptest::array::uniform3(-5.0f64..5.0),
            l0 in -2.0f64..2.0,
        ) {
            proptest::prop_assume!(norm(sub(x, a)) > 0.1);
            let jp = jacobian_params(x, a);
            let jx = jacobian_position(x, a);
            for k in 0..3 {
                let (mut ap, mut am, mut xp, mut xm) = (a, a, x, x);
                ap[k] += H;
                am[k] -= H;
                xp[k] += H;
                xm[k] -= H;
                let fa = (cable_length(x, ap, l0) - cable_length(x, am, l0)) / (2.0 * H);
                let fx = (cable_length(xp, a, l0) - cable_length(xm, a, l0)) / (2.0 * H);
                proptest::prop_assert!(close(jp[k], fa, 1e-6), "dA_{k}: {} vs {fa}", jp[k]);
                proptest::prop_assert!(close(jx[k], fx, 1e-6), "dP_{k}: {} vs {fx}", jx[k]);
            }
        }
    }

    #[test]
    fn quaternion_gives_a_rotation() {
        let r = rotation([2.0, 0.4, -0.2, 1.0]).unwrap(); // not normalised on purpose
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(rotation([f64::NAN, 0.0, 0.0, 0.0]).is_none());
        assert!(rotation([0.0; 4]).is_none());
        // 90 degrees about z maps x to y.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let r = rotation([s, 0.0, 0.0, s]).unwrap();
        let v = mat_vec(&r, [1.0, 0.0, 0.0]);
        assert!((v[0]).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12);
    }
}
