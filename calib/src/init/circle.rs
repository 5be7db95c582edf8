//! Fitting a circle in 3D to noisy points on an arc.
//!
//! ```text
//! 1. plane:     centroid m, normal n = eigenvector of the smallest eigenvalue of the scatter
//! 2. algebraic: in plane coordinates (u, v), minimise sum (u^2 + v^2 + D u + E v + F)^2
//!               (Kasa; linear) -> centre (-D/2, -E/2), radius sqrt(D^2/4 + E^2/4 - F)
//! 3. geometric: minimise sum dist(p_i, circle)^2 over centre c, normal n, radius r, with two
//!               residuals per point whose squares sum to the squared distance:
//!                 a_i = (p_i - c) . n              (out of plane)
//!                 b_i = |q_i| - r,  q_i = (p_i - c) - a_i n   (in plane)
//!               n is updated as normalise(n + alpha e1 + beta e2) (e1, e2 span the plane), so
//!                 da/dc = -n^T        da/dalpha = d.e1     da/dbeta = d.e2
//!                 db/dc = -q^T/|q|    db/dalpha = -a q.e1/|q|   db/dbeta = -a q.e2/|q|   db/dr = -1
//! ```
//!
//! Kasa's fit shrinks the radius of a short noisy arc; the geometric refinement is the
//! maximum-likelihood circle under isotropic noise and removes that bias.

use crate::model::{cross, dot, norm, sub};
use nalgebra::{Matrix3, SMatrix, SVector, SymmetricEigen, Vector3};

/// A circle in 3D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle3 {
    /// Centre, m.
    pub centre: [f64; 3],
    /// Unit normal of its plane (sign arbitrary).
    pub normal: [f64; 3],
    /// Radius, m.
    pub radius: f64,
}

/// Fits a circle to `points`; `None` with fewer than 5 points, points on a line, or no
/// convergence to a finite circle. Returns the circle and the RMS point-to-circle distance.
pub fn fit_circle(points: &[[f64; 3]]) -> Option<(Circle3, f64)> {
    if points.len() < 5 {
        return None;
    }
    let m = points.len() as f64;
    let mut mean = [0.0; 3];
    for p in points {
        for k in 0..3 {
            mean[k] += p[k] / m;
        }
    }
    let mut s = Matrix3::zeros();
    for p in points {
        let d = Vector3::from(sub(*p, mean));
        s += d * d.transpose();
    }
    let eig = SymmetricEigen::new(s);
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    if !(eig.eigenvalues[idx[1]] > 0.0) {
        return None; // collinear points
    }
    let col = |k: usize| -> [f64; 3] {
        let c = eig.eigenvectors.column(k);
        [c[0], c[1], c[2]]
    };
    let e1 = col(idx[0]);
    let n = col(idx[2]);
    let e2 = cross(n, e1);
    // Kasa in plane coordinates.
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for p in points {
        let d = sub(*p, mean);
        let (u, v) = (dot(d, e1), dot(d, e2));
        let row = Vector3::new(u, v, 1.0);
        a += row * row.transpose();
        b -= row * (u * u + v * v);
    }
    let sol = a.cholesky()?.solve(&b);
    let (cu, cv) = (-sol[0] / 2.0, -sol[1] / 2.0);
    let r2 = cu * cu + cv * cv - sol[2];
    if !(r2 > 0.0) {
        return None;
    }
    let centre: [f64; 3] = std::array::from_fn(|k| mean[k] + cu * e1[k] + cv * e2[k]);
    let start = Circle3 { centre, normal: n, radius: r2.sqrt() };
    let c = refine(points, start);
    let rms = (points.iter().map(|p| residuals(*p, &c).iter().map(|r| r * r).sum::<f64>()).sum::<f64>() / m).sqrt();
    (c.radius.is_finite() && c.centre.iter().all(|v| v.is_finite())).then_some((c, rms))
}

/// The two residuals `(a, b)` of point `p` (see the module doc).
pub fn residuals(p: [f64; 3], c: &Circle3) -> [f64; 2] {
    let d = sub(p, c.centre);
    let a = dot(d, c.normal);
    let q = sub(d, c.normal.map(|v| v * a));
    [a, norm(q) - c.radius]
}

/// Jacobian of [`residuals`] w.r.t. `(c_x, c_y, c_z, alpha, beta, r)`, with `e1`, `e2` the plane
/// basis in which `alpha`, `beta` tilt the normal.
pub fn jacobian(p: [f64; 3], c: &Circle3, e1: [f64; 3], e2: [f64; 3]) -> [[f64; 6]; 2] {
    let n = c.normal;
    let d = sub(p, c.centre);
    let a = dot(d, n);
    let q = sub(d, n.map(|v| v * a));
    let qn = norm(q);
    let qh = q.map(|v| v / qn);
    [[-n[0], -n[1], -n[2], dot(d, e1), dot(d, e2), 0.0], [-qh[0], -qh[1], -qh[2], -a * dot(qh, e1), -a * dot(qh, e2), -1.0]]
}

/// A plane basis `(e1, e2)` orthogonal to unit `n`.
pub fn plane_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let t = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let e1 = cross(n, t);
    let l = norm(e1);
    let e1 = e1.map(|v| v / l);
    (e1, cross(n, e1))
}

/// Applies a step `(dc, alpha, beta, dr)` to a circle.
pub fn step(c: &Circle3, dx: &[f64; 6], e1: [f64; 3], e2: [f64; 3]) -> Circle3 {
    let n: [f64; 3] = std::array::from_fn(|k| c.normal[k] + dx[3] * e1[k] + dx[4] * e2[k]);
    let l = norm(n);
    Circle3 { centre: std::array::from_fn(|k| c.centre[k] + dx[k]), normal: n.map(|v| v / l), radius: c.radius + dx[5] }
}

fn cost(points: &[[f64; 3]], c: &Circle3) -> f64 {
    points.iter().map(|p| residuals(*p, c).iter().map(|r| r * r).sum::<f64>()).sum()
}

/// The geometric fit for [`crate::lm`]: the 6x6 normal equations at the current circle, in
/// the plane basis of its normal.
struct Geometric<'a> {
    points: &'a [[f64; 3]],
    /// `(H, -g, e1, e2)` at the current circle (`None`: not built since it changed).
    normal: Option<Normal6>,
}

/// `(H, -g, e1, e2)` of the geometric fit.
type Normal6 = (SMatrix<f64, 6, 6>, SVector<f64, 6>, [f64; 3], [f64; 3]);

impl crate::lm::Problem for Geometric<'_> {
    type X = Circle3;
    /// `(dc, alpha, beta, dr)` and the plane basis `alpha`, `beta` refer to.
    type Step = (SVector<f64, 6>, [f64; 3], [f64; 3]);

    fn cost(&mut self, c: &Circle3) -> f64 {
        cost(self.points, c)
    }

    fn accepted(&mut self) {
        self.normal = None;
    }

    fn step(&mut self, c: &Circle3, lambda: f64) -> Option<Self::Step> {
        let points = self.points;
        let (h, g, e1, e2) = *self.normal.get_or_insert_with(|| {
            let (e1, e2) = plane_basis(c.normal);
            let mut h = SMatrix::<f64, 6, 6>::zeros();
            let mut g = SVector::<f64, 6>::zeros();
            for p in points {
                let r = residuals(*p, c);
                let j = jacobian(*p, c, e1, e2);
                for k in 0..2 {
                    let row = SVector::<f64, 6>::from(j[k]);
                    h += row * row.transpose();
                    g -= row * r[k];
                }
            }
            (h, g, e1, e2)
        });
        let mut a = h;
        for k in 0..6 {
            a[(k, k)] += lambda * h[(k, k)].max(1e-12);
        }
        Some((a.cholesky()?.solve(&g), e1, e2))
    }

    fn apply(&self, c: &Circle3, (dx, e1, e2): &Self::Step) -> Circle3 {
        step(c, &std::array::from_fn(|k| dx[k]), *e1, *e2)
    }

    fn small_step(&self, c: &Circle3, s: &Self::Step) -> bool {
        s.0.norm() < 1e-12 * (1.0 + c.radius)
    }
}

/// Geometric refinement by Levenberg–Marquardt ([`crate::lm`]; 6 parameters, normal equations
/// in one pass; at most 100 accepted steps, each retried until `lambda` reaches 1e12).
fn refine(points: &[[f64; 3]], start: Circle3) -> Circle3 {
    use crate::lm::{CostTest, Count, Damping, Policy};
    let policy = Policy {
        damping: Damping::Factors { down: 10.0, up: 10.0, singular: 10.0 },
        // Stop once lambda >= 1e12.
        max_lambda: f64::from_bits(1e12f64.to_bits() - 1),
        count: Count::Steps { max_tries: usize::MAX },
        cost_test: CostTest::Relative(1e-14),
        ..Policy::factors(1e-3, 10.0, 100)
    };
    crate::lm::minimize(&mut Geometric { points, normal: None }, start, &policy).x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::Rng;

    #[test]
    fn jacobian_matches_finite_differences() {
        let c = Circle3 { centre: [0.1, -0.2, 2.0], normal: [0.0, 0.6, 0.8], radius: 2.5 };
        let (e1, e2) = plane_basis(c.normal);
        for p in [[1.0, 2.0, 3.0], [-2.0, 0.3, 1.1], [0.5, -1.5, 2.9]] {
            let j = jacobian(p, &c, e1, e2);
            for k in 0..6 {
                let h = 1e-6;
                let mut dp = [0.0; 6];
                let mut dm = [0.0; 6];
                dp[k] = h;
                dm[k] = -h;
                let rp = residuals(p, &step(&c, &dp, e1, e2));
                let rm = residuals(p, &step(&c, &dm, e1, e2));
                for r in 0..2 {
                    let fd = (rp[r] - rm[r]) / (2.0 * h);
                    assert!((fd - j[r][k]).abs() < 1e-7, "residual {r} param {k}: {} vs {fd}", j[r][k]);
                }
            }
        }
    }

    #[test]
    fn recovers_a_short_noisy_arc() {
        // 1 m of a 3.6 m radius circle (16 degrees), 1.5 mm noise, 2000 points. Locally the arc
        // is y = x^2 / 2R over a chord L; the quadratic coefficient of m uniform points has
        // std sigma sqrt(180 / m) / L^2, so std(R) = 2 R^2 sigma sqrt(180 / m) / L^2 = 1.2 cm,
        // and the centre moves with the radius.
        let truth = Circle3 { centre: [0.2, -0.1, 3.9], normal: [0.0, 1.0, 0.0], radius: 3.6 };
        let (e1, e2) = ([0.0, 0.0, -1.0], [1.0, 0.0, 0.0]);
        let mut rng = Rng::new(3);
        let m = 2000;
        let pts: Vec<[f64; 3]> = (0..m)
            .map(|i| {
                let phi = 1.0 / 3.6 * (i as f64 / m as f64 - 0.3);
                std::array::from_fn(|k| truth.centre[k] + truth.radius * (phi.cos() * e1[k] + phi.sin() * e2[k]) + 1.5e-3 * rng.normal())
            })
            .collect();
        let (c, rms) = fit_circle(&pts).unwrap();
        // Distance to the circle sees two of the three noise components (not the tangential one).
        assert!((rms - 1.5e-3 * 2f64.sqrt()).abs() < 1e-4, "rms {rms}");
        let sigma_r = 2.0 * 3.6f64.powi(2) * 1.5e-3 * (180.0 / m as f64).sqrt() / 1.0;
        assert!((c.radius - truth.radius).abs() < 4.0 * sigma_r, "radius {} (sigma {sigma_r})", c.radius);
        assert!(norm(sub(c.centre, truth.centre)) < 4.0 * sigma_r, "centre {:?}", c.centre);
        assert!(dot(c.normal, truth.normal).abs() > 1.0 - 1e-6);
    }
}
