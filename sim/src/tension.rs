//! The tension distribution a controller would choose for a point-mass platform.
//!
//! Given unit cable directions `u_j` (from the platform towards the anchors) and the force the
//! cables must provide, `f = m (a - g)`:
//!
//! 1. minimum norm `|T|^2` subject to `sum T_j u_j = f`, `T_j >= t_min` (for three cables: the
//!    unique solution, if it respects the floor);
//! 2. where that is infeasible, the same with the floor at zero: a cable held at zero is one the
//!    trajectory would need to push, it is **loose**;
//! 3. where even that is infeasible (the force is outside the cone of the cables), the
//!    non-negative least-squares tensions; cables at zero are loose and a force residual remains.
//!
//! Steps 1 and 2 enumerate the active sets (cables held at the floor) and keep the feasible
//! candidate of least norm: the QP is convex, so its optimum is one of these candidates. Step 3
//! enumerates the supports of at most three cables. Exact and simple for the few cables of a
//! suspended robot (at most [`MAX_SIM_CABLES`]).

use nalgebra::{Matrix3, Vector3};

/// Most cables the simulator's tension enumeration handles (2^n candidates). More than the
/// robot's [`taut_config::geometry::MAX_CABLES`] on purpose: the simulator also models robots
/// taut does not drive, for the offline tools.
pub const MAX_SIM_CABLES: usize = 12;
const _: () = assert!(MAX_SIM_CABLES >= taut_config::geometry::MAX_CABLES);

/// The outcome of [`distribute`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distribution {
    /// Bit `j` set: cable `j` is loose (zero tension, the trajectory would need it to push).
    pub loose: u32,
    /// Whether every cable respects the floor `t_min`.
    pub feasible: bool,
    /// Force the cables cannot provide, `f - sum T_j u_j`, N (zero unless outside the cone).
    pub residual: [f64; 3],
}

/// Minimum-norm tensions with `T_j >= floor`; `None` if infeasible.
fn min_norm_with_floor(u: &[[f64; 3]], f: [f64; 3], floor: f64, out: &mut [f64]) -> Option<u32> {
    let n = u.len();
    let mut best: Option<(f64, u32)> = None;
    let mut cand = [0.0; MAX_SIM_CABLES];
    for fixed in 0u32..(1 << n) {
        if n - (fixed.count_ones() as usize) < 3 {
            continue;
        }
        let mut r = Vector3::from(f);
        let mut m = Matrix3::zeros();
        for (j, uj) in u.iter().enumerate() {
            let v = Vector3::from(*uj);
            if fixed >> j & 1 == 1 {
                r -= floor * v;
            } else {
                m += v * v.transpose();
            }
        }
        // Free tensions T_F = U_F^T lambda with U_F U_F^T lambda = r.
        let Some(lambda) = m.cholesky().map(|c| c.solve(&r)) else { continue };
        let mut ok = true;
        let mut norm2 = 0.0;
        for (j, uj) in u.iter().enumerate() {
            let t = if fixed >> j & 1 == 1 { floor } else { Vector3::from(*uj).dot(&lambda) };
            if t < floor - 1e-9 * (1.0 + f[2].abs()) {
                ok = false;
                break;
            }
            cand[j] = t;
            norm2 += t * t;
        }
        if ok && best.is_none_or(|(b, _)| norm2 < b) {
            best = Some((norm2, fixed));
            out[..n].copy_from_slice(&cand[..n]);
        }
    }
    best.map(|(_, fixed)| fixed)
}

/// Non-negative least squares over supports of at most three cables.
fn nnls(u: &[[f64; 3]], f: [f64; 3], out: &mut [f64]) -> [f64; 3] {
    let n = u.len();
    let fv = Vector3::from(f);
    let mut best: Option<(f64, u32)> = None;
    let mut cand = [0.0; MAX_SIM_CABLES];
    for support in 1u32..(1 << n) {
        let k = support.count_ones() as usize;
        if k > 3 {
            continue;
        }
        let idx: Vec<usize> = (0..n).filter(|j| support >> j & 1 == 1).collect();
        // Normal equations of the k-column least squares.
        let mut a = nalgebra::DMatrix::<f64>::zeros(k, k);
        let mut b = nalgebra::DVector::<f64>::zeros(k);
        for (r, &i) in idx.iter().enumerate() {
            let ui = Vector3::from(u[i]);
            b[r] = ui.dot(&fv);
            for (c, &j) in idx.iter().enumerate() {
                a[(r, c)] = ui.dot(&Vector3::from(u[j]));
            }
        }
        let Some(x) = a.cholesky().map(|c| c.solve(&b)) else { continue };
        if x.iter().any(|&t| t < 0.0) {
            continue;
        }
        cand[..n].fill(0.0);
        let mut res = fv;
        for (r, &i) in idx.iter().enumerate() {
            cand[i] = x[r];
            res -= x[r] * Vector3::from(u[i]);
        }
        let norm2: f64 = x.iter().map(|t| t * t).sum();
        // Least residual; among (near-)exact fits the least norm.
        let score = res.norm_squared() + 1e-12 * norm2;
        if best.is_none_or(|(s, _)| score < s) {
            best = Some((score, support));
            out[..n].copy_from_slice(&cand[..n]);
        }
    }
    if best.is_none() {
        out[..n].fill(0.0);
    }
    let mut res = fv;
    for (j, uj) in u.iter().enumerate() {
        res -= out[j] * Vector3::from(*uj);
    }
    res.into()
}

/// The controller's tension distribution: see the module doc. `u` are unit directions from the
/// platform towards the anchors, `f` the force the cables must provide (N), `t_min` the floor
/// (N). Writes one tension per cable into `out`.
///
/// # Panics
/// With more than [`MAX_SIM_CABLES`] cables.
pub fn distribute(u: &[[f64; 3]], f: [f64; 3], t_min: f64, out: &mut [f64]) -> Distribution {
    let n = u.len();
    assert!((3..=MAX_SIM_CABLES).contains(&n), "tension distribution: 3..={MAX_SIM_CABLES} cables, got {n}");
    if min_norm_with_floor(u, f, t_min, out).is_some() {
        return Distribution { loose: 0, feasible: true, residual: [0.0; 3] };
    }
    if t_min > 0.0 {
        if let Some(fixed) = min_norm_with_floor(u, f, 0.0, out) {
            return Distribution { loose: fixed, feasible: false, residual: [0.0; 3] };
        }
    }
    let residual = nnls(u, f, out);
    let loose = (0..n).filter(|&j| out[j] <= 0.0).fold(0u32, |m, j| m | 1 << j);
    Distribution { loose, feasible: false, residual }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(a: [f64; 3], p: [f64; 3]) -> [f64; 3] {
        let d = [a[0] - p[0], a[1] - p[1], a[2] - p[2]];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / l, d[1] / l, d[2] / l]
    }

    const ANCHORS: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

    fn balance(u: &[[f64; 3]], t: &[f64], f: [f64; 3]) -> f64 {
        let mut r = f;
        for (uj, tj) in u.iter().zip(t) {
            for k in 0..3 {
                r[k] -= tj * uj[k];
            }
        }
        (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
    }

    #[test]
    fn interior_point_balances_with_the_floor_and_minimum_norm() {
        let p = [0.7, -0.3, 1.8];
        let u: Vec<_> = ANCHORS.iter().map(|a| unit(*a, p)).collect();
        let f = [0.2, -0.1, 3.0 * 9.81];
        let mut t = [0.0; 4];
        let d = distribute(&u, f, 5.0, &mut t);
        assert!(d.feasible && d.loose == 0);
        assert!(balance(&u, &t, f) < 1e-9);
        assert!(t.iter().all(|&x| x >= 5.0 - 1e-9), "{t:?}");
        // Minimum norm along the one-dimensional null space: moving along it increases the norm
        // or leaves the feasible set.
        // Null vector of the 3x4 matrix [u_0 .. u_3]: signed 3x3 minors.
        let null: Vec<f64> = (0..4)
            .map(|j| {
                let cols: Vec<usize> = (0..4).filter(|&c| c != j).collect();
                let m = Matrix3::from_fn(|r, c| u[cols[c]][r]);
                if j % 2 == 0 {
                    m.determinant()
                } else {
                    -m.determinant()
                }
            })
            .collect();
        assert!(balance(&u, &null, [0.0; 3]) < 1e-12);
        for s in [-1e-3, 1e-3] {
            let tt: Vec<f64> = (0..4).map(|j| t[j] + s * null[j]).collect();
            let feasible = tt.iter().all(|&x| x >= 5.0 - 1e-12);
            let n0: f64 = t.iter().map(|x| x * x).sum();
            let n1: f64 = tt.iter().map(|x| x * x).sum();
            assert!(!feasible || n1 >= n0 - 1e-9);
        }
    }

    #[test]
    fn three_cables_are_unique() {
        let a = [[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]];
        let p = [0.1, 0.2, 1.0];
        let u: Vec<_> = a.iter().map(|x| unit(*x, p)).collect();
        let f = [0.0, 0.0, 2.0 * 9.81];
        let mut t = [0.0; 3];
        let d = distribute(&u, f, 1.0, &mut t);
        assert!(d.feasible);
        let m = Matrix3::from_fn(|r, c| u[c][r]);
        let exact = m.lu().solve(&Vector3::from(f)).unwrap();
        for j in 0..3 {
            assert!((t[j] - exact[j]).abs() < 1e-9);
        }
    }

    #[test]
    fn outward_acceleration_at_the_edge_loosens_the_far_cables() {
        let p = [0.0, 1.5, 1.0];
        let u: Vec<_> = ANCHORS.iter().map(|a| unit(*a, p)).collect();
        let m = 3.0;
        let f = [0.0, m * 3.0, m * 9.81];
        let mut t = [0.0; 4];
        let d = distribute(&u, f, 5.0, &mut t);
        assert!(!d.feasible);
        assert_eq!(d.loose, 0b1001, "cables 0 and 3 (y = -1.75) go loose: {t:?} {d:?}");
        assert_eq!((t[0], t[3]), (0.0, 0.0));
        assert!(t[1] > 0.0 && t[2] > 0.0);
    }
}
