//! Levenberg–Marquardt for one cable: four parameters `x = (A_x, A_y, A_z, L0)`.
//!
//! # Why per cable, and why it is fast
//!
//! The residual of reading `(i, j)` depends only on cable `j`'s anchor and offset, so the
//! identification Jacobian of all `4n` parameters is block diagonal and the problem is `n`
//! independent 4-parameter problems. For each, one pass over the cable's readings accumulates the
//! 4x4 normal matrix `H = J^T W J` (10 distinct numbers), the gradient `g = J^T W r` (4) and the
//! cost, directly from each reading's residual and Jacobian row: the `m x 4` Jacobian is never
//! stored, memory traffic is five `f64` per reading (`x, y, z, l, 1/sigma^2`, column-wise, the
//! points shared by all cables of a point-mass platform), and a step is a 4x4 Cholesky solve. A
//! dense solver on the joint problem (e.g. MINPACK through `scipy.optimize.least_squares`) forms
//! an `n m x 4n` Jacobian and factorises it every iteration.
//!
//! The pass itself is written for SIMD (see [`pass`]): element-wise block loops, independent
//! partial sums, the robust weight computed only for the few readings beyond the quadratic part
//! of the loss, and an AVX2+FMA build chosen at run time. About 0.5 ms per 100 000 readings; a
//! calibration needs 8-10 passes per cable.
//!
//! # The iteration
//!
//! ```text
//! r_i   = l_i - (|X_i - A| + L0)                residual, m
//! J_i   = [-u_i^T, 1]                           d model / d x
//! e_i   = r_i / sigma_i,  sigma_i^2 = var_i(x)  normalised residual (noise model, crate::noise)
//! cost  = sum_i rho(e_i)                         rho = e^2/2 (least squares) or Huber / Cauchy
//! w_i   = rho'(e_i) / e_i / sigma_i^2           IRLS weight (1/sigma^2 for least squares)
//! H     = sum w_i J_i^T J_i,   g = sum w_i J_i r_i
//! (H + lambda diag(H)) dx = g                   Marquardt's scaled damping (paper eq. 5)
//! ```
//!
//! A trial point is evaluated in one pass that also accumulates its `H` and `g`; if the robust
//! cost decreased the step is accepted and those are reused, so every iteration costs exactly
//! one pass. `lambda` starts near Gauss–Newton (1e-9) and follows Nielsen's rule on the gain ratio
//! (actual / predicted decrease).
//! The robust weights are re-evaluated at every point and held fixed for the derivative (IRLS).
//! The variances are held fixed for a whole solve (set by the caller, see [`crate::calibrate`]),
//! so accept/reject compares values of one cost function; the fixed point is the weighted
//! least-squares solution under the noise model, not a maximum of a likelihood that would also
//! trade `log sigma(x)` against the fit.
//!
//! Convergence is judged statistically: stop when the proposed step is below 1e-3 standard
//! deviations (`dx^T H dx <= 1e-6`), without spending a pass on evaluating it.
//!
//! With a robust loss the calibration runs in two stages: plain least squares first (quadratic
//! convergence from a poor start where all residuals would otherwise be "outliers", stopped once
//! the next step is below 10 sigma), then the robust loss from there.

use crate::noise::CableData;
use crate::RobustLoss;
use nalgebra::{Matrix4, Vector4};

/// Why the iteration stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The step became smaller than the parameter tolerance.
    SmallStep,
    /// The actual and predicted cost decrease became smaller than the cost tolerance.
    SmallCostChange,
    /// The gradient vanished (e.g. a noise-free fit).
    SmallGradient,
    /// The iteration limit was reached before convergence.
    MaxIterations,
    /// No step decreases the cost any more although the tolerances are not met (round-off, or a
    /// degenerate problem).
    Stalled,
}

impl Termination {
    /// True for the reasons that mean "converged".
    pub fn was_successful(self) -> bool {
        matches!(self, Termination::SmallStep | Termination::SmallCostChange | Termination::SmallGradient)
    }

    /// Orders reasons from good to bad, to report the worst over cables.
    pub(crate) fn severity(self) -> u8 {
        match self {
            Termination::SmallStep | Termination::SmallCostChange | Termination::SmallGradient => 0,
            Termination::Stalled => 1,
            Termination::MaxIterations => 2,
        }
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Termination::SmallStep => "converged (step below tolerance)",
            Termination::SmallCostChange => "converged (cost change below tolerance)",
            Termination::SmallGradient => "converged (gradient vanished)",
            Termination::MaxIterations => "stopped at the iteration limit",
            Termination::Stalled => "stalled (no step decreases the cost)",
        })
    }
}

/// Cost, normal equations and statistics of one pass.
#[derive(Debug, Clone, Copy, Default)]
pub struct Pass {
    /// Robust cost `sum rho(e_i)`.
    pub cost: f64,
    /// Upper triangle of `H`, row-major: 00 01 02 03 11 12 13 22 23 33.
    pub h: [f64; 10],
    /// `g = J^T W r`.
    pub g: [f64; 4],
    /// `sum w_i^robust e_i^2`: the weighted chi-square for the a-posteriori variance factor.
    pub chi2: f64,
}

impl Pass {
    /// `H` as a matrix.
    pub fn h_matrix(&self) -> Matrix4<f64> {
        let h = &self.h;
        Matrix4::new(
            h[0], h[1], h[2], h[3], //
            h[1], h[4], h[5], h[6], //
            h[2], h[5], h[7], h[8], //
            h[3], h[6], h[8], h[9],
        )
    }
}

/// [`Pass`] plus residual statistics ([`final_pass`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct FinalPass {
    /// The pass.
    pub pass: Pass,
    /// `sum r_i^2` over the used readings, m^2.
    pub sum_sq: f64,
    /// `max |r_i|` over the used readings, m.
    pub peak: f64,
    /// `sum r_i^2` over the used and the loose readings, m^2.
    pub sum_sq_all: f64,
    /// `max |r_i|` over the used and the loose readings, m.
    pub peak_all: f64,
    /// Readings the robust loss down-weighted.
    pub downweighted: usize,
    /// Readings with `|e_i| > outlier_sigma`.
    pub outliers: usize,
}

/// A pass that also gathers the residual statistics of the report, in the same sweep.
pub fn final_pass(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss, outlier_sigma: f64) -> FinalPass {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports the features `final_pass_avx2` is compiled for.
            return unsafe { final_pass_avx2(d, lo, hi, x, loss, outlier_sigma) };
        }
    }
    final_pass_dispatch(d, lo, hi, x, loss, outlier_sigma)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn final_pass_avx2(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss, outlier_sigma: f64) -> FinalPass {
    final_pass_dispatch(d, lo, hi, x, loss, outlier_sigma)
}

#[inline(always)]
fn final_pass_dispatch(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss, outlier_sigma: f64) -> FinalPass {
    let o2 = outlier_sigma * outlier_sigma;
    match loss {
        RobustLoss::None => pass_with::<_, true>(d, lo, hi, x, Squares, o2),
        RobustLoss::Huber { k } => pass_with::<_, true>(d, lo, hi, x, Huber(k), o2),
        RobustLoss::Cauchy { c } => pass_with::<_, true>(d, lo, hi, x, Cauchy(c), o2),
    }
}

/// A loss function `rho(e)` of the normalised residual, monomorphised into the pass.
trait Loss: Copy {
    /// `(w, rho)` for `e^2`: the IRLS weight `rho'(e)/e` and the loss.
    fn weight_cost(self, e2: f64) -> (f64, f64);
    /// Below this `e^2` the loss is `e^2 / 2` (weight 1): the pass computes those readings in
    /// its SIMD loop and fixes up only the others.
    fn quadratic_below(self) -> f64;
}

#[derive(Clone, Copy)]
struct Squares;
impl Loss for Squares {
    #[inline(always)]
    fn weight_cost(self, e2: f64) -> (f64, f64) {
        (1.0, 0.5 * e2)
    }
    #[inline(always)]
    fn quadratic_below(self) -> f64 {
        f64::INFINITY
    }
}

#[derive(Clone, Copy)]
struct Huber(f64);
impl Loss for Huber {
    #[inline(always)]
    fn weight_cost(self, e2: f64) -> (f64, f64) {
        let k = self.0;
        if e2 <= k * k {
            (1.0, 0.5 * e2)
        } else {
            let e = e2.sqrt();
            (k / e, k * e - 0.5 * k * k)
        }
    }
    #[inline(always)]
    fn quadratic_below(self) -> f64 {
        self.0 * self.0
    }
}

#[derive(Clone, Copy)]
struct Cauchy(f64);
impl Loss for Cauchy {
    #[inline(always)]
    fn weight_cost(self, e2: f64) -> (f64, f64) {
        let c2 = self.0 * self.0;
        let s = 1.0 + e2 / c2;
        (1.0 / s, 0.5 * c2 * s.ln())
    }
    #[inline(always)]
    fn quadratic_below(self) -> f64 {
        -1.0
    }
}

impl RobustLoss {
    /// `(w, rho)` for a normalised residual squared (outside the hot loop).
    pub(crate) fn weight_cost(self, e2: f64) -> (f64, f64) {
        match self {
            RobustLoss::None => Squares.weight_cost(e2),
            RobustLoss::Huber { k } => Huber(k).weight_cost(e2),
            RobustLoss::Cauchy { c } => Cauchy(c).weight_cost(e2),
        }
    }
}

/// One pass over readings `lo..hi` of a cable at parameters `x`, with the inverse variances
/// stored in the data ([`CableData::set_variances`]).
///
/// The readings are processed in blocks: first an element-wise loop computes each reading's
/// Jacobian row, residual and weight into small stack buffers (no loop-carried dependence, so it
/// compiles to SIMD square roots and divisions), then the sixteen sums are taken over the block
/// with several independent partial sums each (SIMD again, without reassociating a
/// floating-point sum the compiler would have to keep in order). On x86-64 CPUs with AVX2 and
/// FMA the same code is compiled a second time for those features and chosen at run time.
pub fn pass(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss) -> Pass {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports the features `pass_avx2` is compiled for (checked above).
            return unsafe { pass_avx2(d, lo, hi, x, loss) };
        }
    }
    pass_dispatch(d, lo, hi, x, loss)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn pass_avx2(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss) -> Pass {
    pass_dispatch(d, lo, hi, x, loss)
}

#[inline(always)]
fn pass_dispatch(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: RobustLoss) -> Pass {
    match loss {
        RobustLoss::None => pass_with::<_, false>(d, lo, hi, x, Squares, 0.0).pass,
        RobustLoss::Huber { k } => pass_with::<_, false>(d, lo, hi, x, Huber(k), 0.0).pass,
        RobustLoss::Cauchy { c } => pass_with::<_, false>(d, lo, hi, x, Cauchy(c), 0.0).pass,
    }
}

/// Readings per block: the per-reading buffers (about ten of this many `f64`) stay in L1.
const BLOCK: usize = 256;

/// `sum_k a_k b_k` with eight independent partial sums.
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (ac, bc) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    let mut s = acc.iter().sum::<f64>();
    for (x, y) in ar.iter().zip(br) {
        s += x * y;
    }
    s
}

/// `max_k |a_k|` with eight independent running maxima (a select per element, which
/// vectorises; `f64::max` with its NaN rules does not).
#[inline(always)]
fn max_abs(a: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let ac = a.chunks_exact(8);
    let ar = ac.remainder();
    for x in ac {
        for i in 0..8 {
            let v = x[i].abs();
            acc[i] = if v > acc[i] { v } else { acc[i] };
        }
    }
    let mut m = acc.iter().fold(0.0f64, |m, &v| if v > m { v } else { m });
    for v in ar {
        let v = v.abs();
        m = if v > m { v } else { m };
    }
    m
}

/// `sum_k a_k` with eight independent partial sums.
#[inline(always)]
fn total(a: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let ac = a.chunks_exact(8);
    let ar = ac.remainder();
    for x in ac {
        for i in 0..8 {
            acc[i] += x[i];
        }
    }
    acc.iter().sum::<f64>() + ar.iter().sum::<f64>()
}

/// The pass; with `STATS` also the residual statistics of [`FinalPass`] (`o2`: outlier
/// threshold on `e^2`).
#[inline(always)]
fn pass_with<L: Loss, const STATS: bool>(d: &CableData, lo: usize, hi: usize, x: &[f64; 4], loss: L, o2: f64) -> FinalPass {
    let mut out = FinalPass::default();
    let mut rv = [0.0f64; BLOCK];
    let mut ev = [0.0f64; BLOCK];
    let mut flags = [[0.0f64; BLOCK]; 2];
    // Residuals of the used readings (0 elsewhere) and of used + loose ones (statistics only).
    let mut ru = [0.0f64; BLOCK];
    let mut ra = [0.0f64; BLOCK];
    let mut h = [0.0f64; 10];
    let mut g = [0.0f64; 4];
    let (mut cost, mut chi2) = (0.0, 0.0);
    // Per-reading buffers: J = [-u, 1] as (jx, jy, jz), weight w, w r, loss, robust weight e^2.
    let mut jx = [0.0f64; BLOCK];
    let mut jy = [0.0f64; BLOCK];
    let mut jz = [0.0f64; BLOCK];
    let mut wv = [0.0f64; BLOCK];
    let mut wr = [0.0f64; BLOCK];
    let mut cv = [0.0f64; BLOCK];
    let mut ch = [0.0f64; BLOCK];
    let mut start = lo;
    while start < hi {
        let end = (start + BLOCK).min(hi);
        let n = end - start;
        let (xs, ys, zs, ls, ivs) = (&d.x[start..end], &d.y[start..end], &d.z[start..end], &d.l[start..end], &d.iv[start..end]);
        let cs = &d.class[start..end];
        for k in 0..n {
            let dx = xs[k] - x[0];
            let dy = ys[k] - x[1];
            let dz = zs[k] - x[2];
            let rho = (dx * dx + dy * dy + dz * dz).sqrt();
            let inv = 1.0 / rho;
            jx[k] = -dx * inv;
            jy[k] = -dy * inv;
            jz[k] = -dz * inv;
            let r = ls[k] - (rho + x[3]);
            let e2 = r * r * ivs[k];
            // The quadratic part of the loss for every reading; the few beyond it are fixed up
            // below (no square root or division per reading for the robust weight here).
            let w = ivs[k];
            rv[k] = r;
            ev[k] = e2;
            wv[k] = w;
            wr[k] = w * r;
            cv[k] = 0.5 * e2;
            ch[k] = e2;
            if STATS {
                flags[0][k] = 0.0;
                flags[1][k] = if e2 > o2 { 1.0 } else { 0.0 };
                ru[k] = if ivs[k] > 0.0 { r } else { 0.0 };
                ra[k] = if cs[k] != crate::noise::MISSING { r } else { 0.0 };
            }
        }
        let bound = loss.quadratic_below();
        for k in 0..n {
            if ev[k] > bound {
                let (rw, c) = loss.weight_cost(ev[k]);
                let w = rw * ivs[k];
                wv[k] = w;
                wr[k] = w * rv[k];
                cv[k] = c;
                ch[k] = rw * ev[k];
                if STATS && rw < 1.0 {
                    flags[0][k] = 1.0;
                }
            }
        }
        if STATS {
            let (u, a) = (&ru[..n], &ra[..n]);
            out.sum_sq += dot(u, u);
            out.peak = out.peak.max(max_abs(u));
            out.sum_sq_all += dot(a, a);
            out.peak_all = out.peak_all.max(max_abs(a));
            out.downweighted += total(&flags[0][..n]) as usize;
            out.outliers += total(&flags[1][..n]) as usize;
        }
        let (jx, jy, jz, wv, wr) = (&jx[..n], &jy[..n], &jz[..n], &wv[..n], &wr[..n]);
        // w j_a j_b = (w j_a) j_b: form w j once per column.
        let mut wj = [[0.0f64; BLOCK]; 3];
        for k in 0..n {
            wj[0][k] = wv[k] * jx[k];
            wj[1][k] = wv[k] * jy[k];
            wj[2][k] = wv[k] * jz[k];
        }
        let (w0, w1, w2) = (&wj[0][..n], &wj[1][..n], &wj[2][..n]);
        h[0] += dot(w0, jx);
        h[1] += dot(w0, jy);
        h[2] += dot(w0, jz);
        h[3] += total(w0);
        h[4] += dot(w1, jy);
        h[5] += dot(w1, jz);
        h[6] += total(w1);
        h[7] += dot(w2, jz);
        h[8] += total(w2);
        h[9] += total(wv);
        g[0] += dot(wr, jx);
        g[1] += dot(wr, jy);
        g[2] += dot(wr, jz);
        g[3] += total(wr);
        cost += total(&cv[..n]);
        chi2 += total(&ch[..n]);
        start = end;
    }
    // The design's prior: a pseudo-reading `mu_k` of parameter `k` with variance `sigma_k^2`
    // (Jacobian the unit vector, residual `mu_k - x_k`), once per pass whatever its range.
    for (k, mu, sigma) in d.prior.iter().flat_map(crate::prior_terms) {
        let w = 1.0 / (sigma * sigma);
        let r = mu - x[k];
        h[DIAG[k]] += w;
        g[k] += w * r;
        cost += 0.5 * w * r * r;
        chi2 += w * r * r;
    }
    out.pass = Pass { cost, h, g, chi2 };
    out
}

/// Tolerances of one solve.
#[derive(Debug, Clone, Copy)]
pub struct Tolerances {
    /// Relative step tolerance: stop when `|dx| <= xtol (|x| + xtol)`.
    pub xtol: f64,
    /// Relative cost tolerance on both actual and predicted decrease.
    pub ftol: f64,
    /// Gradient tolerance: stop when `max_k |g_k| / sqrt(H_kk cost) <= gtol` (the cosine of the
    /// angle between the residual and the Jacobian's columns, as in MINPACK).
    pub gtol: f64,
    /// Statistical step tolerance: stop when `dx^T H dx <= step_sigma2`, i.e. when the step is
    /// below `sqrt(step_sigma2)` standard deviations of the estimate. Scale-free, and the reason
    /// the solve stops after a handful of passes instead of chasing nanometres.
    pub step_sigma2: f64,
}

impl Tolerances {
    /// Tolerances for the final solve: a step of 1e-3 standard deviations is converged.
    pub const FINAL: Tolerances = Tolerances { xtol: 1e-12, ftol: 1e-14, gtol: 1e-10, step_sigma2: 1e-6 };
    /// Loose tolerances for the least-squares stage before a robust one: stop once the next
    /// step would be below 100 sigma. The least-squares stage only has to bring the start into
    /// the region where most residuals are inliers (100 sigma of an estimate from m readings
    /// moves a single residual by about 100 / sqrt(m) reading sigmas: 0.3 for m = 1e5); the
    /// robust stage then converges in a few Gauss–Newton steps.
    pub const COARSE: Tolerances = Tolerances { xtol: 1e-9, ftol: 1e-10, gtol: 1e-8, step_sigma2: 1e2 };
}

/// The result of one solve.
#[derive(Debug, Clone, Copy)]
pub struct Solution {
    /// `(A_x, A_y, A_z, L0)`.
    pub x: [f64; 4],
    /// Why it stopped.
    pub termination: Termination,
    /// LM iterations (accepted and rejected steps; each is one pass).
    pub iterations: usize,
    /// The last pass at `x`.
    pub at_x: Pass,
}

/// Solves one cable on readings `lo..hi` from `x0`, with a least-squares stage first when `loss`
/// is robust (use [`lm`] with the robust loss directly to refine from a point already close).
pub fn solve(d: &CableData, lo: usize, hi: usize, x0: [f64; 4], loss: RobustLoss, max_iterations: usize) -> Solution {
    if loss == RobustLoss::None {
        return lm(d, lo, hi, x0, loss, max_iterations, Tolerances::FINAL);
    }
    let first = lm(d, lo, hi, x0, RobustLoss::None, max_iterations, Tolerances::COARSE);
    let rest = max_iterations.saturating_sub(first.iterations).max(1);
    let mut second = lm(d, lo, hi, first.x, loss, rest, Tolerances::FINAL);
    second.iterations += first.iterations;
    second
}

/// One cable's problem for [`crate::lm`]: the pass gives the cost and the normal equations at
/// once, so a trial point's pass is kept as the current one when the step is accepted.
struct Cable<'a> {
    d: &'a CableData,
    lo: usize,
    hi: usize,
    loss: RobustLoss,
    tol: Tolerances,
    /// The pass at the current point.
    cur: Pass,
    /// The pass at the last point evaluated.
    trial: Pass,
}

/// A step of [`Cable`] with what the stopping tests need.
struct CableStep {
    dx: Vector4<f64>,
    /// `dx^T H dx`: the step's length in standard deviations, squared.
    mstep: f64,
    /// Predicted decrease `g.dx - dx^T H dx / 2`.
    pred: f64,
    /// `|dx|`.
    norm: f64,
}

impl Cable<'_> {
    /// The step-length test: `|dx| <= xtol (|x| + xtol)`.
    fn tiny(&self, x: &[f64; 4], s: &CableStep) -> bool {
        let xn_norm = (x.iter().map(|v| v * v).sum::<f64>()).sqrt();
        s.norm <= self.tol.xtol * (xn_norm + self.tol.xtol)
    }
}

impl crate::lm::Problem for Cable<'_> {
    type X = [f64; 4];
    type Step = CableStep;

    fn cost(&mut self, x: &[f64; 4]) -> f64 {
        self.trial = pass(self.d, self.lo, self.hi, x, self.loss);
        self.trial.cost
    }

    fn accepted(&mut self) {
        self.cur = self.trial;
    }

    fn step(&mut self, _x: &[f64; 4], lambda: f64) -> Option<CableStep> {
        let h = self.cur.h_matrix();
        let dmax = (0..4).map(|k| h[(k, k)]).fold(0.0, f64::max);
        let mut a = h;
        for k in 0..4 {
            // Floor the scaling so an unexcited direction still gets damped.
            a[(k, k)] += lambda * h[(k, k)].max(1e-12 * dmax).max(f64::MIN_POSITIVE);
        }
        let g = Vector4::from(self.cur.g);
        let dx = a.cholesky()?.solve(&g);
        let mstep = dx.dot(&(h * dx));
        Some(CableStep { dx, mstep, pred: dx.dot(&g) - 0.5 * mstep, norm: dx.norm() })
    }

    fn apply(&self, x: &[f64; 4], s: &CableStep) -> [f64; 4] {
        [x[0] + s.dx[0], x[1] + s.dx[1], x[2] + s.dx[2], x[3] + s.dx[3]]
    }

    /// Gradient test (MINPACK's gtol): the residual is orthogonal to every column of J.
    fn converged(&self, _x: &[f64; 4], _cost: f64) -> bool {
        let cur = &self.cur;
        let gmax = (0..4)
            .map(|k| cur.g[k].abs() / (cur.h[DIAG[k]] * 2.0 * cur.cost.max(f64::MIN_POSITIVE)).sqrt().max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max);
        gmax <= self.tol.gtol || cur.cost == 0.0
    }

    /// The proposed step is already below the statistical tolerance: x is converged, and
    /// evaluating x + dx would cost a pass to learn nothing (x is returned, with its pass).
    fn negligible(&self, s: &CableStep) -> bool {
        s.mstep <= self.tol.step_sigma2
    }

    fn small_step(&self, x: &[f64; 4], s: &CableStep) -> bool {
        s.mstep <= self.tol.step_sigma2 || self.tiny(x, s)
    }

    /// A step that cannot even change x (or whose predicted gain is at round-off) means we are
    /// at the minimum to machine precision.
    fn at_minimum(&self, x: &[f64; 4], s: &CableStep, cost: f64) -> bool {
        self.tiny(x, s) || s.pred.abs() <= 1e-15 * cost
    }

    fn predicted_decrease(&self, s: &CableStep) -> f64 {
        s.pred
    }
}

/// Damped Gauss–Newton (Levenberg–Marquardt, [`crate::lm`]) with Nielsen's damping update.
#[allow(clippy::too_many_arguments)]
pub fn lm(d: &CableData, lo: usize, hi: usize, x0: [f64; 4], loss: RobustLoss, max_iterations: usize, tol: Tolerances) -> Solution {
    use crate::lm::{minimize, CostTest, Count, Damping, Policy, Stop};
    // Start almost at Gauss–Newton: J^T W J is ill-conditioned along (A along the mean cable
    // direction, L0) (eigenvalue ratios 1e4..1e5), and a Marquardt damping of 1e-3 diag(H) would
    // shrink the step along exactly that direction tenfold, turning quadratic convergence into
    // a crawl. The gain ratio raises lambda when a step fails.
    let policy = Policy {
        lambda0: 1e-9,
        damping: Damping::Nielsen { min_factor: 0.1 },
        min_lambda: 1e-12,
        max_lambda: 1e20,
        max_iterations,
        count: Count::Attempts,
        accept_ties: false,
        singular_stops: false,
        cost_test: CostTest::WithPredicted(tol.ftol),
    };
    let mut p = Cable { d, lo, hi, loss, tol, cur: Pass::default(), trial: Pass::default() };
    let r = minimize(&mut p, x0, &policy);
    let termination = match r.stop {
        Stop::SmallGradient => Termination::SmallGradient,
        Stop::SmallStep => Termination::SmallStep,
        Stop::SmallCostChange => Termination::SmallCostChange,
        Stop::MaxIterations => Termination::MaxIterations,
        Stop::NoDecrease | Stop::Singular | Stop::NotFinite => Termination::Stalled,
    };
    Solution { x: r.x, termination, iterations: r.iterations, at_x: p.cur }
}

/// Index of `H_kk` in [`Pass::h`].
const DIAG: [usize; 4] = [0, 4, 7, 9];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::{NoiseModel, Weighting};
    use crate::CalibOptions;

    /// The normal equations accumulated in one pass equal J^T W J and J^T W r built from a
    /// finite-difference Jacobian.
    #[test]
    fn pass_matches_finite_difference_normal_equations() {
        let pts = [[0.1, 0.2, 1.0], [1.0, -0.5, 2.0], [-1.2, 0.7, 0.5], [0.4, 1.1, 1.7], [-0.3, -0.9, 2.4]];
        let a_true = [3.0, -1.5, 4.0];
        let l: Vec<f64> =
            pts.iter().enumerate().map(|(k, p)| crate::model::cable_length(*p, a_true, 0.5) + 1e-3 * (k as f64 - 2.0)).collect();
        let t: Vec<f64> = (0..pts.len()).map(|k| 10.0 * k as f64).collect();
        let mut d = CableData::from_points(&pts, &l, &t);
        let opts = CalibOptions::default();
        let nm = NoiseModel::new(&opts, Weighting::ForceAware);
        let x = [2.9, -1.4, 4.1, 0.45];
        d.set_variances(&x, &nm);
        let p = pass(&d, 0, d.len(), &x, RobustLoss::None);
        let hh = 1e-7;
        let model = |x: &[f64; 4], k: usize| crate::model::cable_length(d.point(k), [x[0], x[1], x[2]], x[3]);
        let mut h = [[0.0; 4]; 4];
        let mut g = [0.0; 4];
        for k in 0..d.len() {
            let (rho, u) = crate::model::direction(d.point(k), [x[0], x[1], x[2]]);
            let w = 1.0 / nm.variance(u, rho, d.t[k]);
            let r = d.l[k] - model(&x, k);
            let mut j = [0.0; 4];
            for a in 0..4 {
                let mut xp = x;
                let mut xm = x;
                xp[a] += hh;
                xm[a] -= hh;
                j[a] = (model(&xp, k) - model(&xm, k)) / (2.0 * hh);
            }
            for a in 0..4 {
                g[a] += w * j[a] * r;
                for b in 0..4 {
                    h[a][b] += w * j[a] * j[b];
                }
            }
        }
        let hm = p.h_matrix();
        for a in 0..4 {
            assert!((p.g[a] - g[a]).abs() <= 1e-6 * g[a].abs().max(1.0), "g[{a}] {} vs {}", p.g[a], g[a]);
            for b in 0..4 {
                assert!((hm[(a, b)] - h[a][b]).abs() <= 1e-6 * h[a][b].abs().max(1.0), "H[{a}][{b}]");
            }
        }
    }

    #[test]
    fn huber_and_cauchy_weights_are_derivative_over_residual() {
        for loss in [RobustLoss::Huber { k: 1.5 }, RobustLoss::Cauchy { c: 2.0 }] {
            for e in [0.3, 1.2, 1.6, 4.0, 30.0] {
                let h = 1e-6;
                let drho = (loss.weight_cost((e + h) * (e + h)).1 - loss.weight_cost((e - h) * (e - h)).1) / (2.0 * h);
                let w = loss.weight_cost(e * e).0;
                assert!((w * e - drho).abs() < 1e-6 * (1.0 + drho.abs()), "{loss:?} e={e}: {} vs {drho}", w * e);
            }
        }
    }
}
