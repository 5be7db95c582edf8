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
//!
//! On a robot with four or more cables a controller may add an internal force, tensions that
//! cancel at the platform ([`Pretension`], [`shift_internal`]); on a suspended robot it trades
//! tension between cables (all anchors above: no internal force raises every cable), and where
//! the distribution already holds cables at the floor it can move only one way, or not at all.

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

/// An internal force a redundant robot's controller varies along the excitation: on top of the
/// distribution of [`distribute`], the tensions move by `lambda d`, where `d` is the alternating
/// pattern `(+1, -1, +1, ...)` projected onto the null space of the cables' directions (forces
/// that cancel at the platform), scaled so its largest entry is 1. On anchors ordered around
/// the frame, the diagonal pairs trade tension; the pose, and the force on the platform, stay
/// as planned. `lambda` follows the levels in turn, each held `hold_s` and reached by a
/// raised-cosine ramp of `ramp_s` from the one before, and is clamped where a cable would leave
/// `[t_min, t_max]`. A statically determinate robot (three cables) has no such force.
#[derive(Debug, Clone, PartialEq)]
pub struct Pretension {
    /// The internal-force levels, N (the change of the most-changed cable), in turn.
    pub levels_n: Vec<f64>,
    /// How long each level is held, s (the ramp included).
    pub hold_s: f64,
    /// The ramp from one level to the next, s (at most `hold_s`).
    pub ramp_s: f64,
}

impl Pretension {
    /// The target level at excitation time `t`, N (the levels repeat; before 0 they run
    /// backwards from the last); 0 for a schedule that is not [`Pretension::is_valid`].
    pub fn level_at(&self, t: f64) -> f64 {
        let n = self.levels_n.len();
        if n == 0 || !self.is_valid() {
            return 0.0;
        }
        let k = (t / self.hold_s).floor();
        let idx = (k as i64).rem_euclid(n as i64) as usize;
        let (prev, cur) = (self.levels_n[(idx + n - 1) % n], self.levels_n[idx]);
        let into = t - k * self.hold_s;
        if self.ramp_s > 0.0 && into < self.ramp_s {
            let w = 0.5 - 0.5 * (std::f64::consts::PI * into / self.ramp_s).cos();
            prev + w * (cur - prev)
        } else {
            cur
        }
    }

    /// Whether the levels and times are usable: finite levels, `0 <= ramp_s <= hold_s`,
    /// `hold_s > 0`.
    pub fn is_valid(&self) -> bool {
        self.levels_n.iter().all(|l| l.is_finite())
            && self.hold_s > 0.0
            && self.hold_s.is_finite()
            && self.ramp_s >= 0.0
            && self.ramp_s <= self.hold_s
    }
}

/// The internal-force direction of [`Pretension`] for unit directions `u`: the alternating
/// pattern minus its part the cables' force balance sees, scaled to a largest entry of 1.
/// `None` for three cables or where the pattern has no part in the null space.
pub fn internal_direction(u: &[[f64; 3]]) -> Option<[f64; MAX_SIM_CABLES]> {
    let n = u.len();
    if !(4..=MAX_SIM_CABLES).contains(&n) {
        return None;
    }
    let sign = |j: usize| if j.is_multiple_of(2) { 1.0 } else { -1.0 };
    // d = s - A^T (A A^T)^-1 A s, A = [u_0 .. u_n-1] (3 x n).
    let mut aat = Matrix3::zeros();
    let mut a_s = Vector3::zeros();
    for (j, uj) in u.iter().enumerate() {
        let v = Vector3::from(*uj);
        aat += v * v.transpose();
        a_s += sign(j) * v;
    }
    let y = aat.cholesky()?.solve(&a_s);
    let mut d = [0.0; MAX_SIM_CABLES];
    for (j, uj) in u.iter().enumerate() {
        d[j] = sign(j) - Vector3::from(*uj).dot(&y);
    }
    let big = d[..n].iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    if big.is_nan() || big <= 1e-6 {
        return None;
    }
    for x in &mut d[..n] {
        *x /= big;
    }
    Some(d)
}

/// Moves the tensions `t` (balanced, each within `[t_min, t_max]`) by `lambda d` along the
/// internal-force direction of `u` ([`internal_direction`]), `lambda` the `target` clamped to
/// keep every cable within `[t_min, t_max]`. Returns the `lambda` applied, N (0 without a
/// direction or where `t` is already outside the limits).
pub fn shift_internal(u: &[[f64; 3]], t_min: f64, t_max: f64, target: f64, t: &mut [f64]) -> f64 {
    let n = u.len();
    let Some(d) = internal_direction(u) else { return 0.0 };
    if t[..n].iter().any(|&x| x < t_min - 1e-9 || x > t_max + 1e-9) {
        return 0.0;
    }
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for j in 0..n {
        if d[j] > 0.0 {
            lo = lo.max((t_min - t[j]) / d[j]);
            hi = hi.min((t_max - t[j]) / d[j]);
        } else if d[j] < 0.0 {
            lo = lo.max((t_max - t[j]) / d[j]);
            hi = hi.min((t_min - t[j]) / d[j]);
        }
    }
    let lambda = target.clamp(lo.min(0.0), hi.max(0.0));
    for j in 0..n {
        t[j] += lambda * d[j];
    }
    lambda
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
    fn internal_force_keeps_the_balance_and_the_limits() {
        let p = [0.7, -0.3, 1.8];
        let u: Vec<_> = ANCHORS.iter().map(|a| unit(*a, p)).collect();
        let f = [0.2, -0.1, 3.0 * 9.81];
        let mut t0 = [0.0; 4];
        assert!(distribute(&u, f, 5.0, &mut t0).feasible);
        let d = internal_direction(&u).expect("four cables have an internal force");
        assert!(balance(&u, &d[..4], [0.0; 3]) < 1e-12, "{d:?}");
        assert!((d[..4].iter().fold(0.0_f64, |m, x| m.max(x.abs())) - 1.0).abs() < 1e-12);
        // The diagonal pairs trade tension.
        assert!(d[0] > 0.0 && d[2] > 0.0 && d[1] < 0.0 && d[3] < 0.0, "{d:?}");
        // A small level is applied in full; the most-changed cable moves by it.
        let mut t = t0;
        let lambda = shift_internal(&u, 5.0, 500.0, 2.0, &mut t);
        assert_eq!(lambda, 2.0);
        assert!(balance(&u, &t, f) < 1e-9);
        let moved = (0..4).map(|j| (t[j] - t0[j]).abs()).fold(0.0, f64::max);
        assert!((moved - 2.0).abs() < 1e-12, "{t:?} vs {t0:?}");
        // Large levels either way stop where a cable reaches the floor or the ceiling.
        let near = t0.iter().fold(0.0_f64, |m, &x| m.max(x)) + 3.0;
        for (target, ceiling) in [(1e3, 500.0), (-1e3, 500.0), (1e3, near), (-1e3, near)] {
            let mut t = t0;
            let lambda = shift_internal(&u, 5.0, ceiling, target, &mut t);
            assert!(lambda != 0.0 && lambda.abs() < 1e3, "{lambda}");
            assert!(balance(&u, &t, f) < 1e-9, "{t:?}");
            assert!(t.iter().all(|&x| (5.0 - 1e-9..=ceiling + 1e-9).contains(&x)), "{t:?}");
            assert!(t.iter().any(|&x| (x - 5.0).abs() < 1e-9 || (x - ceiling).abs() < 1e-9), "{t:?}");
        }
        // Three cables: nothing to vary.
        let a3 = [[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]];
        let u3: Vec<_> = a3.iter().map(|x| unit(*x, [0.1, 0.2, 1.0])).collect();
        let mut t3 = [10.0; 3];
        assert!(internal_direction(&u3).is_none());
        assert_eq!(shift_internal(&u3, 1.0, 500.0, 5.0, &mut t3), 0.0);
        assert_eq!(t3, [10.0; 3]);
    }

    #[test]
    fn pretension_levels_are_held_and_ramped() {
        let p = Pretension { levels_n: vec![0.0, 10.0, -10.0], hold_s: 4.0, ramp_s: 1.0 };
        assert!(p.is_valid());
        assert_eq!(p.level_at(2.0), 0.0);
        assert_eq!(p.level_at(4.0), 0.0);
        assert!((p.level_at(4.5) - 5.0).abs() < 1e-12);
        assert_eq!(p.level_at(6.0), 10.0);
        assert!((p.level_at(8.5) - 0.0).abs() < 1e-12);
        assert_eq!(p.level_at(10.0), -10.0);
        assert!((p.level_at(12.5) + 5.0).abs() < 1e-12, "at 12 s the cycle restarts from -10 towards 0");
        assert_eq!(p.level_at(14.0), 0.0);
        assert_eq!(p.level_at(-2.0), -10.0);
        assert!(!Pretension { ramp_s: 5.0, ..p.clone() }.is_valid());
        assert!(!Pretension { hold_s: 0.0, ramp_s: 0.0, ..p }.is_valid());
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
