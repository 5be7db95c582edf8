//! A generic dense Levenberg–Marquardt solver for the joint fit (anchors, offsets and effect
//! parameters together).
//!
//! ```text
//! minimise  F(x) = sum_i r_i(x)^2           r_i already divided by the noise sigma
//! step      (J^T J + lambda diag(J^T J)) dx = -J^T r          (paper eq. 5)
//! accept    when F(x + dx) < F(x): lambda /= 3, else lambda *= 4 and retry   (crate::lm)
//! covariance  Cov = s^2 (J^T J)^-1,  s^2 = F / (m - p)        (reduced chi-square)
//! ```
//!
//! The problem hands each residual row to the solver with its sparse Jacobian row; the solver
//! accumulates the dense normal equations, so memory does not grow with the number of samples.

use nalgebra::{DMatrix, DVector};

/// Receives one residual and its sparse Jacobian row `(parameter, dr/dx_k)`.
pub type RowVisitor<'a> = dyn FnMut(f64, &[(usize, f64)]) + 'a;

/// A least-squares problem.
pub trait LeastSquares {
    /// Number of parameters.
    fn n_params(&self) -> usize;
    /// Calls `visit(r_i, row_i)` for every residual, `row_i` listing `(parameter, dr_i/dx_k)`.
    /// With `jacobian == false` the rows may be empty (only the cost is needed).
    fn rows(&self, x: &[f64], jacobian: bool, visit: &mut RowVisitor<'_>);
    /// Projects `x` onto the feasible set (bounds); the default does nothing.
    fn project(&self, _x: &mut [f64]) {}
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The relative decrease of the cost fell below the tolerance.
    Converged,
    /// The step became negligible.
    SmallStep,
    /// The iteration limit was reached.
    MaxIterations,
    /// No step decreased the cost even with strong damping.
    Stalled,
    /// The cost is not finite at the start.
    NotFinite,
}

/// The result of a fit.
#[derive(Debug, Clone)]
pub struct LmReport {
    /// The parameters.
    pub x: Vec<f64>,
    /// Sum of squared residuals at `x`.
    pub cost: f64,
    /// Number of residuals.
    pub m: usize,
    /// Iterations done.
    pub iterations: usize,
    /// Why it stopped.
    pub termination: Termination,
    /// `(J^T J)^-1` at `x` (not yet scaled by the reduced chi-square), if invertible.
    pub inv_normal: Option<DMatrix<f64>>,
}

impl LmReport {
    /// True unless the start was not finite or the fit stalled before its first step.
    pub fn was_successful(&self) -> bool {
        !matches!(self.termination, Termination::NotFinite) && self.cost.is_finite()
    }

    /// 1-sigma of each parameter from the covariance scaled by the reduced chi-square.
    pub fn sigmas(&self) -> Vec<f64> {
        let p = self.x.len();
        let dof = (self.m as f64 - p as f64).max(1.0);
        let s2 = self.cost / dof;
        match &self.inv_normal {
            Some(c) => (0..p).map(|k| (c[(k, k)].max(0.0) * s2).sqrt()).collect(),
            None => vec![f64::NAN; p],
        }
    }
}

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when the relative cost decrease of an accepted step is below this.
    pub cost_tolerance: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions { max_iterations: 50, cost_tolerance: 1e-9 }
    }
}

fn normal_equations(p: &dyn LeastSquares, x: &[f64]) -> (DMatrix<f64>, DVector<f64>, f64, usize) {
    let n = p.n_params();
    let mut jtj = DMatrix::<f64>::zeros(n, n);
    let mut jtr = DVector::<f64>::zeros(n);
    let mut cost = 0.0;
    let mut m = 0;
    p.rows(x, true, &mut |r, row| {
        cost += r * r;
        m += 1;
        for &(a, va) in row {
            jtr[a] += va * r;
            for &(b, vb) in row {
                if b >= a {
                    jtj[(a, b)] += va * vb;
                }
            }
        }
    });
    for a in 0..n {
        for b in 0..a {
            jtj[(a, b)] = jtj[(b, a)];
        }
    }
    (jtj, jtr, cost, m)
}

/// A [`LeastSquares`] problem for [`crate::lm`]: the trial point's normal equations are built
/// with its cost (an accepted step, most are, needs them next, so the model is evaluated once
/// per accepted step instead of twice).
struct Dense<'a> {
    p: &'a dyn LeastSquares,
    /// `(J^T J, J^T r, cost, m)` at the current point.
    cur: (DMatrix<f64>, DVector<f64>, f64, usize),
    /// The same at the last point evaluated.
    trial: Option<(DMatrix<f64>, DVector<f64>, f64, usize)>,
}

impl crate::lm::Problem for Dense<'_> {
    type X = Vec<f64>;
    /// The step and its relative length `sqrt(sum (dx_k / (|x_k| + 1e-6))^2)`.
    type Step = (DVector<f64>, f64);

    fn cost(&mut self, x: &Vec<f64>) -> f64 {
        let t = normal_equations(self.p, x);
        let c = t.2;
        self.trial = Some(t);
        c
    }

    fn accepted(&mut self) {
        if let Some(t) = self.trial.take() {
            self.cur = t;
        }
    }

    fn step(&mut self, x: &Vec<f64>, lambda: f64) -> Option<(DVector<f64>, f64)> {
        let jtj = &self.cur.0;
        let mut a = jtj.clone();
        for k in 0..a.nrows() {
            // A floor on the diagonal keeps parameters that nothing constrains (a dead load
            // cell's elasticity) from making the system singular.
            let dk = jtj[(k, k)].max(1e-12);
            a[(k, k)] += lambda * dk;
            if jtj[(k, k)] == 0.0 {
                a[(k, k)] = 1.0;
            }
        }
        let dx = a.cholesky()?.solve(&(-&self.cur.1));
        let step: f64 = dx.iter().zip(x).map(|(d, v)| (d / (v.abs() + 1e-6)).powi(2)).sum::<f64>().sqrt();
        Some((dx, step))
    }

    fn apply(&self, x: &Vec<f64>, s: &(DVector<f64>, f64)) -> Vec<f64> {
        let mut xn: Vec<f64> = x.iter().zip(s.0.iter()).map(|(a, b)| a + b).collect();
        self.p.project(&mut xn);
        xn
    }

    fn small_step(&self, _x: &Vec<f64>, s: &(DVector<f64>, f64)) -> bool {
        s.1 < 1e-12
    }
}

/// Minimises the problem from `x0` ([`crate::lm::minimize`]: damping `lambda` / 3 on success,
/// `* 4` on failure, 25 retries per step).
pub fn minimize(p: &dyn LeastSquares, x0: &[f64], opts: LmOptions) -> LmReport {
    use crate::lm::{CostTest, Count, Policy, Stop};
    let n = p.n_params();
    let mut x = x0.to_vec();
    p.project(&mut x);
    let policy = Policy {
        count: Count::Steps { max_tries: 25 },
        cost_test: CostTest::Relative(opts.cost_tolerance),
        ..Policy::factors(1e-3, 4.0, opts.max_iterations)
    };
    let mut dense = Dense { p, cur: (DMatrix::zeros(n, n), DVector::zeros(n), 0.0, 0), trial: None };
    let r = crate::lm::minimize(&mut dense, x, &policy);
    let termination = match r.stop {
        Stop::NotFinite => Termination::NotFinite,
        Stop::SmallCostChange | Stop::SmallGradient => Termination::Converged,
        Stop::SmallStep => Termination::SmallStep,
        Stop::MaxIterations => Termination::MaxIterations,
        Stop::NoDecrease if r.iterations > 1 => Termination::Converged,
        Stop::NoDecrease | Stop::Singular => Termination::Stalled,
    };
    let (jtj, _, cost, m) = dense.cur;
    if termination == Termination::NotFinite {
        return LmReport { x: r.x, cost, m, iterations: 0, termination, inv_normal: None };
    }
    let mut a = jtj;
    for k in 0..n {
        if a[(k, k)] == 0.0 {
            a[(k, k)] = 1.0;
        }
    }
    let inv_normal = a.try_inverse();
    LmReport { x: r.x, cost, m, iterations: r.iterations, termination, inv_normal }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fit y = a exp(b t) + c to exact data: the solver must find the truth.
    struct Exp {
        t: Vec<f64>,
        y: Vec<f64>,
    }
    impl LeastSquares for Exp {
        fn n_params(&self) -> usize {
            3
        }
        fn rows(&self, x: &[f64], _jac: bool, visit: &mut RowVisitor<'_>) {
            for (t, y) in self.t.iter().zip(&self.y) {
                let e = (x[1] * t).exp();
                visit(x[0] * e + x[2] - y, &[(0, e), (1, x[0] * t * e), (2, 1.0)]);
            }
        }
    }

    #[test]
    fn fits_an_exponential() {
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.1).collect();
        let y = t.iter().map(|t| 2.0 * (-0.7 * t).exp() + 0.3).collect();
        let p = Exp { t, y };
        let r = minimize(&p, &[1.0, -0.1, 0.0], LmOptions::default());
        assert!(r.was_successful());
        assert!((r.x[0] - 2.0).abs() < 1e-6 && (r.x[1] + 0.7).abs() < 1e-6 && (r.x[2] - 0.3).abs() < 1e-6, "{:?}", r.x);
    }

    #[test]
    fn sigma_of_a_mean_is_sigma_over_sqrt_n() {
        struct Mean(Vec<f64>);
        impl LeastSquares for Mean {
            fn n_params(&self) -> usize {
                1
            }
            fn rows(&self, x: &[f64], _j: bool, visit: &mut RowVisitor<'_>) {
                for y in &self.0 {
                    visit(x[0] - y, &[(0, 1.0)]);
                }
            }
        }
        let ys: Vec<f64> = (0..1000).map(|k| if k % 2 == 0 { 1.0 } else { -1.0 }).collect();
        let r = minimize(&Mean(ys), &[0.5], LmOptions::default());
        let s = r.sigmas()[0];
        assert!((s - 1.0 / (999f64).sqrt()).abs() < 1e-3, "{s}");
    }
}
