//! The tension of the cables that follow in torque mode (the redundant cables of a point-mass
//! platform), chosen every cycle from the statics at the commanded pose.
//!
//! Three position-mode cables fix a point mass; every other cable ("follower") pulls with a
//! tension the drive holds. With the followers at one common tension `t_f` the position cables
//! carry what the force balance leaves (platform at rest, weight `m g`, unit vectors `u_j` from
//! the attachment point towards the anchor):
//!
//! ```text
//! sum_{j in P} t_j u_j = m g e_z - t_f sum_{f in F} u_f
//! t_P(t_f) = M^-1 (m g e_z) - t_f M^-1 (sum_f u_f) = a + k t_f      M = [u_P] (3 x 3)
//! ```
//!
//! A fixed follower tension lets a position cable go slack where the follower's pull turns
//! against it (near the follower's own anchor the opposite cable needs more follower tension,
//! not less): the platform then leaves the commanded pose by centimetres, whatever the
//! parameters. [`distribute`] returns the interval of `t_f` that keeps every cable between
//! `min_n` and `max_n`; the loop commands the lowest tension in it that is at least the
//! configured follower tension. The statics use the loop's own parameters (anchors and
//! attachment points; a swivel pulley moves the exit point by its radius, which turns the
//! directions by under a degree).

use crate::kin::LoopParams;
use crate::MAX_CABLES;

/// Standard gravity, m/s^2.
const G: f64 = 9.81;

/// The follower tensions the statics allow at one pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowerRange {
    /// Lowest follower tension that keeps every position cable at `min_n` or more, N.
    pub lo_n: f64,
    /// Highest follower tension that keeps every position cable at `max_n` or less, N.
    pub hi_n: f64,
}

impl FollowerRange {
    /// True when some follower tension keeps every cable in its range.
    pub fn feasible(&self) -> bool {
        self.lo_n <= self.hi_n
    }

    /// The tension to command when `want_n` is asked for: `want_n` moved into the range (the
    /// lower end if the range is empty: a taut position cable matters more than the upper
    /// margin, which the safety check still enforces).
    pub fn clamp(&self, want_n: f64) -> f64 {
        if !self.feasible() {
            return self.lo_n;
        }
        want_n.max(self.lo_n).min(self.hi_n)
    }
}

/// The follower-tension range at platform position `p` for a platform of `mass_kg`, with the
/// cables of `follower` in torque mode at one common tension and every cable held within
/// `[min_n, max_n]`. `None` when the statics do not apply: not exactly three position cables,
/// no follower, parameters not valid, or the position cables' directions (nearly) coplanar.
/// Allocates nothing.
pub fn distribute(
    params: &LoopParams,
    follower: &[bool; MAX_CABLES],
    p: &[f64; 3],
    mass_kg: f64,
    min_n: f64,
    max_n: f64,
) -> Option<FollowerRange> {
    let n = params.n;
    if !params.valid || n > MAX_CABLES {
        return None;
    }
    let mut pos = [0usize; 3];
    let mut np = 0;
    let mut s = [0.0; 3];
    let mut nf = 0;
    for (j, &follows) in follower.iter().enumerate().take(n) {
        let a = params.anchors[j];
        let b = params.platform[j];
        let d = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if r.is_nan() || r <= 1e-9 {
            return None;
        }
        if follows {
            nf += 1;
            for i in 0..3 {
                s[i] += d[i] / r;
            }
        } else {
            if np == 3 {
                return None;
            }
            pos[np] = j;
            np += 1;
        }
    }
    if np != 3 || nf == 0 {
        return None;
    }
    let u = |j: usize| {
        let a = params.anchors[j];
        let b = params.platform[j];
        let d = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / r, d[1] / r, d[2] / r]
    };
    let (c0, c1, c2) = (u(pos[0]), u(pos[1]), u(pos[2]));
    let d = det(c0, c1, c2);
    // Unit columns: |det| is the volume they span; below 1e-6 the tensions are meaningless.
    if d.is_nan() || d.abs() <= 1e-6 {
        return None;
    }
    let w = [0.0, 0.0, mass_kg * G];
    // Cramer's rule for a = M^-1 w and c = M^-1 s; k = -c.
    let a = [det(w, c1, c2) / d, det(c0, w, c2) / d, det(c0, c1, w) / d];
    let c = [det(s, c1, c2) / d, det(c0, s, c2) / d, det(c0, c1, s) / d];
    let (mut lo, mut hi) = (min_n, max_n);
    for i in 0..3 {
        let k = -c[i];
        // t_i = a_i + k t_f within [min_n, max_n].
        if k > 1e-12 {
            lo = lo.max((min_n - a[i]) / k);
            hi = hi.min((max_n - a[i]) / k);
        } else if k < -1e-12 {
            hi = hi.min((min_n - a[i]) / k);
            lo = lo.max((max_n - a[i]) / k);
        } else if a[i] < min_n || a[i] > max_n {
            // The follower cannot change this cable's tension and it is out of range.
            lo = f64::INFINITY;
        }
    }
    Some(FollowerRange { lo_n: lo, hi_n: hi })
}

/// Every cable's tension at platform position `p` by the statics of a platform of `mass_kg` at
/// rest, with the cables of `follower` in torque mode at `follower_n` and the three others
/// solving the force balance (`t_P = a + k t_f`, see the module documentation); `None` where
/// [`distribute`] has no statics. Allocates nothing.
pub fn statics(
    params: &LoopParams,
    follower: &[bool; MAX_CABLES],
    p: &[f64; 3],
    mass_kg: f64,
    follower_n: f64,
) -> Option<[f64; MAX_CABLES]> {
    let n = params.n;
    if !params.valid || n > MAX_CABLES {
        return None;
    }
    let u = |j: usize| {
        let (a, b) = (params.anchors[j], params.platform[j]);
        let d = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / r, d[1] / r, d[2] / r]
    };
    let mut pos = [0usize; 3];
    let mut np = 0;
    let mut rhs = [0.0, 0.0, mass_kg * G];
    let mut out = [0.0; MAX_CABLES];
    for (j, &follows) in follower.iter().enumerate().take(n) {
        let uj = u(j);
        if !uj.iter().all(|x| x.is_finite()) {
            return None;
        }
        if follows {
            out[j] = follower_n;
            for i in 0..3 {
                rhs[i] -= follower_n * uj[i];
            }
        } else {
            if np == 3 {
                return None;
            }
            pos[np] = j;
            np += 1;
        }
    }
    if np != 3 {
        return None;
    }
    let (c0, c1, c2) = (u(pos[0]), u(pos[1]), u(pos[2]));
    let d = det(c0, c1, c2);
    if d.is_nan() || d.abs() <= 1e-6 {
        return None;
    }
    out[pos[0]] = det(rhs, c1, c2) / d;
    out[pos[1]] = det(c0, rhs, c2) / d;
    out[pos[2]] = det(c0, c1, rhs) / d;
    Some(out)
}

/// Determinant of the 3x3 matrix with columns `c0`, `c1`, `c2` (Cramer's rule above).
fn det(c0: [f64; 3], c1: [f64; 3], c2: [f64; 3]) -> f64 {
    c0[0] * (c1[1] * c2[2] - c1[2] * c2[1]) - c1[0] * (c0[1] * c2[2] - c0[2] * c2[1]) + c2[0] * (c0[1] * c1[2] - c0[2] * c1[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulated ARAS-CAM-like robot: four anchors at 4 m, a 3 kg point mass, cable 3 the
    /// follower.
    fn robot() -> LoopParams {
        let a = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        LoopParams::new(1, &a, &[0.0; 4], &[[0.0; 3]; 4])
    }

    fn follower() -> [bool; MAX_CABLES] {
        std::array::from_fn(|j| j == 3)
    }

    /// The tensions of the three position cables for a follower tension, by the force balance
    /// solved independently (Gauss elimination on the 3 x 3 system).
    fn position_tensions(p: [f64; 3], tf: f64) -> [f64; 3] {
        let prm = robot();
        let u = |j: usize| {
            let d: [f64; 3] = std::array::from_fn(|i| prm.anchors[j][i] - p[i]);
            let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            [d[0] / r, d[1] / r, d[2] / r]
        };
        let uf = u(3);
        let mut m = [[0.0; 4]; 3];
        for i in 0..3 {
            for (k, j) in [0, 1, 2].into_iter().enumerate() {
                m[i][k] = u(j)[i];
            }
            m[i][3] = [0.0, 0.0, 3.0 * 9.81][i] - tf * uf[i];
        }
        for c in 0..3 {
            let piv = (c..3).max_by(|&x, &y| m[x][c].abs().total_cmp(&m[y][c].abs())).unwrap();
            m.swap(c, piv);
            for r in 0..3 {
                if r != c {
                    let f = m[r][c] / m[c][c];
                    let pivot = m[c];
                    for (x, y) in m[r][c..].iter_mut().zip(&pivot[c..]) {
                        *x -= f * y;
                    }
                }
            }
        }
        std::array::from_fn(|i| m[i][3] / m[i][i])
    }

    /// At a pose near the follower's anchor a fixed 10 N follower lets the opposite position
    /// cable go slack (the platform then misses the pose by centimetres, whatever the
    /// parameters). The range's lower end keeps it taut.
    #[test]
    fn near_the_followers_anchor_the_follower_must_pull_harder() {
        let p = [-0.875, -0.4375, 1.5];
        let t10 = position_tensions(p, 10.0);
        assert!(t10[1] < 0.0, "the fixed 10 N follower slackens cable 1 there: {t10:?}");
        let r = distribute(&robot(), &follower(), &p, 3.0, 5.0, 250.0).unwrap();
        assert!(r.feasible(), "{r:?}");
        let t = r.clamp(10.0);
        assert!(t > 10.0);
        let tp = position_tensions(p, t);
        // The lowest follower tension that keeps them taut puts one cable at the minimum.
        assert!(tp.iter().all(|&x| x >= 5.0 - 1e-9), "{tp:?}");
        assert!(tp.iter().any(|&x| (x - 5.0).abs() < 1e-9), "{tp:?}");
        // In the middle 10 N is enough and is kept.
        let r = distribute(&robot(), &follower(), &[0.0, 0.0, 2.0], 3.0, 5.0, 250.0).unwrap();
        assert_eq!(r.clamp(10.0), 10.0);
        assert!(position_tensions([0.0, 0.0, 2.0], 10.0).iter().all(|&x| x >= 5.0));
    }

    /// The range's ends are where a position cable reaches a limit, over poses of the
    /// workspace (against the independent solve).
    #[test]
    fn the_range_ends_are_where_a_cable_reaches_its_limit() {
        for p in [[0.5, 0.3, 1.2], [-1.0, 0.6, 2.5], [1.2, -0.7, 1.8], [0.0, 0.0, 3.0]] {
            let r = distribute(&robot(), &follower(), &p, 3.0, 5.0, 100.0).unwrap();
            assert!(r.feasible(), "{p:?}: {r:?}");
            let at = |t: f64| position_tensions(p, t);
            let inside = |t: f64| at(t).iter().all(|&x| (5.0 - 1e-6..=100.0 + 1e-6).contains(&x));
            assert!(inside(r.lo_n) && inside(r.hi_n) && inside(0.5 * (r.lo_n + r.hi_n)), "{p:?}: {r:?}");
            if r.lo_n > 5.0 {
                assert!(!inside(r.lo_n - 1e-3), "{p:?}: lower end not tight");
            }
            if r.hi_n < 100.0 {
                assert!(!inside(r.hi_n + 1e-3), "{p:?}: upper end not tight");
            }
        }
        // `statics` at the range's lower end puts the position cables where the independent
        // solve does.
        let p = [0.5, 0.3, 1.2];
        let r = distribute(&robot(), &follower(), &p, 3.0, 5.0, 100.0).unwrap();
        let t = statics(&robot(), &follower(), &p, 3.0, r.lo_n).unwrap();
        let want = position_tensions(p, r.lo_n);
        for k in 0..3 {
            assert!((t[k] - want[k]).abs() < 1e-9, "{t:?} vs {want:?}");
        }
        assert_eq!(t[3], r.lo_n);
        // Not three position cables, or invalid parameters: no statics.
        assert!(distribute(&robot(), &[false; MAX_CABLES], &[0.0, 0.0, 2.0], 3.0, 5.0, 100.0).is_none());
        assert!(distribute(&LoopParams::invalid(4), &follower(), &[0.0, 0.0, 2.0], 3.0, 5.0, 100.0).is_none());
    }
}
