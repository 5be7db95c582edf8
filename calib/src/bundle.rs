//! Errors-in-variables refinement ("bundle adjustment") of anchors and encoder offsets.
//!
//! The force-aware calibration treats the tracker's platform position as exact and the cable
//! lengths as noisy, one cable at a time. On a robot with more than three taut cables the
//! opposite is closer to the truth: the encoders resolve micrometres, the tracker millimetres,
//! and every sample has one or more redundant cables. Here the platform position of every
//! sample is an unknown too, tied to the tracker reading by its noise and to every taut cable
//! by its length:
//!
//! ```text
//! minimise  sum_i [ sum_j rho( (|p_i + b_j - A_j| + L0_j - l_ij) / s_l )  +  |p_i - P_i|^2 / s_t^2 ]
//!   over    A_j, L0_j (all cables)  and  p_i (every sample)
//! ```
//!
//! with `s_l` the length noise (encoder plus model error), `s_t` the tracker noise, `rho` a
//! Huber loss (slack and outliers). The tracker readings fix the frame (no gauge freedom); the
//! redundant lengths pin each `p_i` far better than the tracker, and through them the anchors.
//! The normal equations are block-arrowhead (3x3 per sample, `4n` global): each LM step
//! eliminates the samples' blocks (Schur complement) and solves a small dense system, so a
//! step costs O(samples x n^2).
//!
//! Point-mass platforms or platforms without orientation data (`platform_points` as fixed
//! offsets). A sample is used when at least four cables are taut and its pose is known.

use crate::model;
use crate::{Geometry, Sigmas};
use taut_config::recording::Recording;

/// Settings of the refinement.
#[derive(Debug, Clone, Copy)]
pub struct BundleOptions {
    /// Length noise (encoder and unmodelled effects), m.
    pub length_sigma_m: f64,
    /// Tracker noise per axis, m.
    pub tracker_sigma_m: f64,
    /// Cables below this tension are not used, N.
    pub min_tension_n: f64,
    /// Huber threshold, in sigmas.
    pub huber_k: f64,
    /// Iterations at most.
    pub max_iterations: usize,
    /// Re-estimate the length noise from the residuals (variance components, see [`refine`]),
    /// never below this, m; 0: keep `length_sigma_m`.
    pub length_sigma_floor_m: f64,
    /// The cables' stretch, modelled: `None`, the ideal model (a length reading is the
    /// distance plus the offset). See [`Stretch`].
    pub stretch: Option<Stretch>,
}

/// A known axial stiffness: the length reading of a cable under tension `T` is the distance
/// less the stretch, `l = d (1 - s T / EA) + L0`, with `EA` the datasheet stiffness and `s` a
/// per-cable factor (1 when the datasheet is right) fitted with the prior `1 +- rel_sigma`.
/// The drum pays out the unstretched length, so the encoder reads `d / (1 + T / EA_true)`;
/// to first order in `T / EA` (1e-4 at most on a steel rope) that is the model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stretch {
    /// The cables' axial stiffness EA, N (datasheet value).
    pub ea_n: f64,
    /// Its relative 1-sigma (0.15: +-15 %); 0: taken as exact (not fitted).
    pub rel_sigma: f64,
}

impl Default for BundleOptions {
    fn default() -> Self {
        BundleOptions {
            length_sigma_m: 2e-4,
            tracker_sigma_m: 1.5e-3,
            min_tension_n: 2.0,
            huber_k: 3.0,
            max_iterations: 30,
            length_sigma_floor_m: 0.0,
            stretch: None,
        }
    }
}

/// What the refinement found.
#[derive(Debug, Clone)]
pub struct BundleResult {
    /// Anchors and encoder offsets, m.
    pub params: Geometry,
    /// 1-sigma of each anchor coordinate and offset (from the reduced normal matrix), m.
    pub sigma: Sigmas,
    /// Samples used.
    pub samples: usize,
    /// RMS of the length residuals at the solution, m.
    pub length_rms_m: f64,
    /// RMS of the tracker residuals (tracker minus refined position) at the solution, m.
    pub tracker_rms_m: f64,
    /// Iterations run.
    pub iterations: usize,
    /// The length noise of the final fit (the weights and the sigmas are computed with it), m:
    /// `length_sigma_m`, or the re-estimated one (see [`refine`]).
    pub length_sigma_m: f64,
    /// With [`BundleOptions::stretch`]: each cable's fitted stiffness EA and its 1-sigma, N
    /// (the datasheet's when it is taken as exact: sigma 0).
    pub ea: Option<Vec<(f64, f64)>>,
}

struct Row {
    /// Tracker position.
    pos: [f64; 3],
    /// Lengths (NaN: not used).
    l: Vec<f64>,
    /// Tensions divided by the datasheet EA (0: no stretch modelled or no tension reading).
    te: Vec<f64>,
}

fn rows(rec: &Recording, opts: &BundleOptions) -> Vec<Row> {
    let n = rec.n_cables;
    (0..rec.len())
        .filter_map(|i| {
            let pos = rec.p[i];
            if !pos.iter().all(|v| v.is_finite()) {
                return None;
            }
            let f = rec.tensions(i);
            let l: Vec<f64> = (0..n)
                .map(|j| {
                    let x = rec.lengths(i)[j];
                    let taut = f.is_none_or(|f| f[j] >= opts.min_tension_n);
                    if taut && x.is_finite() {
                        x
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let te: Vec<f64> = (0..n)
                .map(|j| match (opts.stretch, f) {
                    (Some(st), Some(f)) if f[j].is_finite() && st.ea_n > 0.0 && st.ea_n.is_finite() => f[j] / st.ea_n,
                    _ => 0.0,
                })
                .collect();
            (l.iter().filter(|x| x.is_finite()).count() >= 4).then_some(Row { pos, l, te })
        })
        .collect()
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn huber_w(r: f64, k: f64) -> f64 {
    if r.abs() <= k {
        1.0
    } else {
        k / r.abs()
    }
}

fn huber_cost(r: f64, k: f64) -> f64 {
    if r.abs() <= k {
        0.5 * r * r
    } else {
        k * (r.abs() - 0.5 * k)
    }
}

/// Solves the symmetric positive definite `a x = b` (dense, row-major `m x m`) by Cholesky.
fn cholesky_solve(a: &[f64], b: &[f64], m: usize) -> Option<(Vec<f64>, Vec<f64>)> {
    let mut l = vec![0.0; m * m];
    for i in 0..m {
        for j in 0..=i {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= l[i * m + k] * l[j * m + k];
            }
            if i == j {
                if !(s > 0.0) {
                    return None;
                }
                l[i * m + i] = s.sqrt();
            } else {
                l[i * m + j] = s / l[j * m + j];
            }
        }
    }
    let solve = |b: &[f64]| {
        let mut y = vec![0.0; m];
        for i in 0..m {
            let mut s = b[i];
            for k in 0..i {
                s -= l[i * m + k] * y[k];
            }
            y[i] = s / l[i * m + i];
        }
        for i in (0..m).rev() {
            let mut s = y[i];
            for k in i + 1..m {
                s -= l[k * m + i] * y[k];
            }
            y[i] = s / l[i * m + i];
        }
        y
    };
    let x = solve(b);
    // Diagonal of the inverse, for the sigmas.
    let mut diag = vec![0.0; m];
    for (c, d) in diag.iter_mut().enumerate() {
        let mut e = vec![0.0; m];
        e[c] = 1.0;
        *d = solve(&e)[c];
    }
    Some((x, diag))
}

fn inv3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if !(det.abs() > 1e-300) {
        return None;
    }
    let c = |r0: usize, c0: usize, r1: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    Some([
        [c(1, 1, 2, 2) / det, -c(0, 1, 2, 2) / det, c(0, 1, 1, 2) / det],
        [-c(1, 0, 2, 2) / det, c(0, 0, 2, 2) / det, -c(0, 0, 1, 2) / det],
        [c(1, 0, 2, 1) / det, -c(0, 0, 2, 1) / det, c(0, 0, 1, 1) / det],
    ])
}

/// Refines `anchors` and `l0` (a start within a few centimetres) on the recording. `None` if
/// fewer than 20 samples have four taut cables, or the platform has orientation data.
///
/// With `length_sigma_floor_m > 0` the length noise is a variance component estimated from the
/// data: after the fit with `length_sigma_m` (a conservative start, for the convergence from
/// centimetres off), `s_l^2 = sum r^2 / (n_l - sum_i tr(H_pp,i^-1 L_i) - 4n)` over the length
/// residuals `r` (those within 4 s_l: Huber-down-weighted slack and outliers are not noise),
/// with `L_i` the length part of sample `i`'s 3x3 position information (its lengths take that
/// much of its position's degrees of freedom), and the fit is repeated with it (at least the
/// floor, at most the start) until it changes by less than 5 %. The encoders resolve far
/// better than a fixed conservative length sigma says, and the weight of the redundant cables
/// against the tracker is what pins the anchors. Where the model misses something (stretch,
/// sag: residuals above the start) the start's weighting is kept.
pub fn refine(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    anchors: &[[f64; 3]],
    l0: &[f64],
    opts: &BundleOptions,
) -> Option<BundleResult> {
    let n = rec.n_cables;
    if rec.q.is_some() || anchors.len() != n || l0.len() != n || n < 4 {
        return None;
    }
    let data = rows(rec, opts);
    if data.len() < 20 {
        return None;
    }
    let mut r = solve(&data, platform_points, anchors, l0, opts.length_sigma_m, opts)?;
    if opts.length_sigma_floor_m > 0.0 {
        for _ in 0..4 {
            let Some(est) = r.length_sigma_estimate else { break };
            // Lowered only: where the model misses something (residuals above the start) the
            // start's weighting stays (a misfit in mm let e2e_effects' ideal model drift).
            let next = est.clamp(opts.length_sigma_floor_m, opts.length_sigma_m);
            if (next / r.result.length_sigma_m - 1.0).abs() < 0.05 {
                break;
            }
            let (a, l): (Vec<[f64; 3]>, Vec<f64>) = (r.result.params.anchors.clone(), r.result.params.l0.clone());
            r = solve(&data, platform_points, &a, &l, next, opts)?;
        }
    }
    Some(r.result)
}

/// Consecutive time blocks of the samples for the sandwich covariance (at least twice the
/// 4n <= 32 parameters would be better; 32 keeps each block ~1 s of a 30 s excitation, longer
/// than the tour's segments, so a misfit that follows the path stays within a block).
const SANDWICH_BLOCKS: usize = 32;

/// Variances of the time-block sandwich `S^-1 (B/(B-1) sum_b g_b g_b^T) S^-1` (`S` the reduced
/// normal matrix, `g_b` block `b`'s share of the reduced gradient at the solution). With the
/// model right its expectation is the model covariance `S^-1`; a misfit correlated along the
/// path (a time offset between tracker and encoders, unmodelled effects) raises it where the
/// model covariance would not. The refinement reports the larger of the two per parameter:
/// under the model the sandwich's own scatter (32 blocks: ~25 % in a variance) makes that a
/// few percent conservative.
fn sandwich(s: &[f64], block_grad: &[Vec<f64>], m: usize) -> Option<Vec<f64>> {
    let b = block_grad.len();
    if b < 2 {
        return None;
    }
    let si = nalgebra::DMatrix::from_row_slice(m, m, s).try_inverse()?;
    let mut meat = nalgebra::DMatrix::<f64>::zeros(m, m);
    for g in block_grad {
        let g = nalgebra::DVector::from_column_slice(g);
        meat += &g * g.transpose();
    }
    meat *= b as f64 / (b - 1) as f64;
    let cov = &si * meat * &si;
    Some((0..m).map(|k| cov[(k, k)].max(0.0)).collect())
}

/// One pass of [`solve`]'s fit.
enum Pass {
    /// A damped step: the trial globals and poses, and `max |dg|`.
    Step(Vec<f64>, Vec<[f64; 3]>, f64),
    /// The undamped pass at the solution: the diagonal of the inverse reduced normal matrix and
    /// the sandwich variances.
    Final(Vec<f64>, Option<Vec<f64>>),
}

/// [`solve`]'s fit for [`crate::lm`]: globals and poses, the cost and one pass per step
/// (the damping enters the elimination of the poses, so each step is a pass over the samples).
struct Fit<C, P> {
    cost: C,
    pass: P,
}

/// Globals and poses.
type Poses = (Vec<f64>, Vec<[f64; 3]>);

impl<C, P> crate::lm::Problem for Fit<C, P>
where
    C: Fn(&[f64], &[[f64; 3]]) -> f64,
    P: Fn(&[f64], &[[f64; 3]], f64, bool) -> Option<Pass>,
{
    type X = Poses;
    /// The trial point and `max |dg|`.
    type Step = (Vec<f64>, Vec<[f64; 3]>, f64);

    fn cost(&mut self, x: &Poses) -> f64 {
        (self.cost)(&x.0, &x.1)
    }

    fn step(&mut self, x: &Poses, lambda: f64) -> Option<Self::Step> {
        match (self.pass)(&x.0, &x.1, lambda, false)? {
            Pass::Step(g, p, step) => Some((g, p, step)),
            Pass::Final(..) => None,
        }
    }

    fn apply(&self, _x: &Poses, s: &Self::Step) -> Poses {
        (s.0.clone(), s.1.clone())
    }

    fn small_step(&self, _x: &Poses, s: &Self::Step) -> bool {
        s.2 < 1e-7
    }
}

/// A fit at one length noise, with the variance-component estimate of the length noise.
struct Solved {
    result: BundleResult,
    length_sigma_estimate: Option<f64>,
}

fn solve(data: &[Row], platform_points: &[[f64; 3]], anchors: &[[f64; 3]], l0: &[f64], sl: f64, opts: &BundleOptions) -> Option<Solved> {
    let n = anchors.len();
    let b = |j: usize| platform_points.get(j).copied().unwrap_or([0.0; 3]);
    // Per cable A_x, A_y, A_z, L0 and, when the stiffness is fitted, its factor `s`.
    let fit_ea = opts.stretch.filter(|s| s.rel_sigma > 0.0);
    let np = if fit_ea.is_some() { 5 } else { 4 };
    let m = np * n;
    let (st, k) = (opts.tracker_sigma_m, opts.huber_k);
    let g: Vec<f64> = (0..n).flat_map(|j| [anchors[j][0], anchors[j][1], anchors[j][2], l0[j], 1.0].into_iter().take(np)).collect();
    // The stretch factor of cable j (1 when not fitted).
    let factor = |g: &[f64], j: usize| if np == 5 { g[np * j + 4] } else { 1.0 };
    // The prior's cost on the stretch factors.
    let prior = |g: &[f64]| fit_ea.map_or(0.0, |f| (0..n).map(|j| 0.5 * ((g[np * j + 4] - 1.0) / f.rel_sigma).powi(2)).sum());
    let p: Vec<[f64; 3]> = data.iter().map(|r| r.pos).collect();
    let cost = |g: &[f64], p: &[[f64; 3]]| -> f64 {
        let mut c = prior(g);
        for (r, pi) in data.iter().zip(p) {
            for j in 0..n {
                if r.l[j].is_finite() {
                    let a = [g[np * j], g[np * j + 1], g[np * j + 2]];
                    let d = model::norm(model::sub(add(*pi, b(j)), a));
                    c += huber_cost((d * (1.0 - factor(g, j) * r.te[j]) + g[np * j + 3] - r.l[j]) / sl, k);
                }
            }
            let e = model::sub(*pi, r.pos);
            c += 0.5 * (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) / (st * st);
        }
        c
    };
    // One pass at `(g, p)`: the normal equations with the samples eliminated on the fly, damped
    // by `lambda`. A step gives its trial point `(g + dg, p + dp)` and `max |dg|`; the finishing
    // pass (undamped) the diagonal of the inverse and the sandwich variances.
    let pass = |g: &[f64], p: &[[f64; 3]], lambda: f64, finishing: bool| -> Option<Pass> {
        // Normal equations, samples eliminated on the fly.
        let mut s = vec![0.0; m * m];
        let mut rhs = vec![0.0; m];
        // Per sample: Hpp (3x3), Hpg (3 x m, sparse: 4 columns per used cable), bp.
        struct Blk {
            hpp_inv: [[f64; 3]; 3],
            bp: [f64; 3],
            cols: Vec<(usize, [f64; 3])>, // (global column, Hpg column)
        }
        let mut blocks = Vec::with_capacity(data.len());
        // In the final pass: each time block's share of the reduced gradient (the sandwich).
        let mut block_grad = vec![vec![0.0; m]; if finishing { SANDWICH_BLOCKS } else { 0 }];
        for (i, (r, pi)) in data.iter().zip(p).enumerate() {
            let before = if finishing { rhs.clone() } else { vec![] };
            let mut hpp = [[0.0; 3]; 3];
            let mut bp = [0.0; 3];
            let mut cols: Vec<(usize, [f64; 3])> = Vec::with_capacity(np * n);
            let e = model::sub(*pi, r.pos);
            // Quadratic: the tracker is what fixes the frame (a robust loss let a wrong model
            // drift it, e2e_effects' ideal-model run).
            let wt = 1.0 / (st * st);
            for a in 0..3 {
                hpp[a][a] += wt;
                bp[a] -= e[a] * wt;
            }
            for j in 0..n {
                if !r.l[j].is_finite() {
                    continue;
                }
                let a = [g[np * j], g[np * j + 1], g[np * j + 2]];
                let v = model::sub(add(*pi, b(j)), a);
                let d = model::norm(v);
                // The distance's share of the reading (1 less the stretch per metre).
                let q = 1.0 - factor(g, j) * r.te[j];
                let u = [q * v[0] / d, q * v[1] / d, q * v[2] / d];
                let res = (d * q + g[np * j + 3] - r.l[j]) / sl;
                let w = huber_w(res, k) / (sl * sl);
                let rr = res * sl;
                // d res / d p = u, d res / d A = -u, d res / d L0 = 1, d res / d s = -d T / EA
                // (times 1/sl, folded in w).
                let jg = [-u[0], -u[1], -u[2], 1.0, -d * r.te[j]];
                let jg = &jg[..np];
                for x in 0..3 {
                    for y in 0..3 {
                        hpp[x][y] += w * u[x] * u[y];
                    }
                    bp[x] -= w * u[x] * rr;
                }
                for (c, &jc) in jg.iter().enumerate() {
                    let col = np * j + c;
                    for (c2, &jc2) in jg.iter().enumerate() {
                        s[col * m + np * j + c2] += w * jc * jc2;
                    }
                    rhs[col] -= w * jc * rr;
                    cols.push((col, [w * u[0] * jc, w * u[1] * jc, w * u[2] * jc]));
                }
            }
            for (x, row) in hpp.iter_mut().enumerate() {
                row[x] *= 1.0 + lambda;
            }
            let hpp_inv = inv3(&hpp)?;
            // Schur: S -= Hgp Hpp^-1 Hpg; rhs -= Hgp Hpp^-1 bp.
            let t: Vec<[f64; 3]> = cols
                .iter()
                .map(|(_, h)| {
                    [
                        hpp_inv[0][0] * h[0] + hpp_inv[0][1] * h[1] + hpp_inv[0][2] * h[2],
                        hpp_inv[1][0] * h[0] + hpp_inv[1][1] * h[1] + hpp_inv[1][2] * h[2],
                        hpp_inv[2][0] * h[0] + hpp_inv[2][1] * h[1] + hpp_inv[2][2] * h[2],
                    ]
                })
                .collect();
            for (a, (ca, _)) in cols.iter().enumerate() {
                let ta = t[a];
                rhs[*ca] -= ta[0] * bp[0] + ta[1] * bp[1] + ta[2] * bp[2];
                for (cb, hb) in &cols {
                    s[ca * m + cb] -= ta[0] * hb[0] + ta[1] * hb[1] + ta[2] * hb[2];
                }
            }
            blocks.push(Blk { hpp_inv, bp, cols });
            if finishing {
                let g = &mut block_grad[i * SANDWICH_BLOCKS / data.len()];
                for ((gx, after), b) in g.iter_mut().zip(&rhs).zip(&before) {
                    *gx += after - b;
                }
            }
        }
        // The stiffness prior (not in the time blocks' gradients: it is no data).
        if let Some(f) = fit_ea {
            for j in 0..n {
                let x = np * j + 4;
                s[x * m + x] += 1.0 / (f.rel_sigma * f.rel_sigma);
                rhs[x] -= (g[x] - 1.0) / (f.rel_sigma * f.rel_sigma);
            }
        }
        for x in 0..m {
            s[x * m + x] *= 1.0 + lambda;
            s[x * m + x] += 1e-12;
        }
        let (dg, dinv) = cholesky_solve(&s, &rhs, m)?;
        if finishing {
            return Some(Pass::Final(dinv, sandwich(&s, &block_grad, m)));
        }
        let mut g2 = g.to_vec();
        for (x, d) in g2.iter_mut().zip(&dg) {
            *x += d;
        }
        let p2: Vec<[f64; 3]> = blocks
            .iter()
            .zip(p)
            .map(|(bk, pi)| {
                // dp = Hpp^-1 (bp - Hpg dg)
                let mut r = bk.bp;
                for (col, h) in &bk.cols {
                    for x in 0..3 {
                        r[x] -= h[x] * dg[*col];
                    }
                }
                let h = &bk.hpp_inv;
                [
                    pi[0] + h[0][0] * r[0] + h[0][1] * r[1] + h[0][2] * r[2],
                    pi[1] + h[1][0] * r[0] + h[1][1] * r[1] + h[1][2] * r[2],
                    pi[2] + h[2][0] * r[0] + h[2][1] * r[1] + h[2][2] * r[2],
                ]
            })
            .collect();
        let step = dg.iter().fold(0.0f64, |a, d| a.max(d.abs()));
        Some(Pass::Step(g2, p2, step))
    };
    let policy = crate::lm::Policy {
        min_lambda: 1e-9,
        max_lambda: 1e8,
        accept_ties: true,
        singular_stops: true,
        cost_test: crate::lm::CostTest::Relative(1e-10),
        ..crate::lm::Policy::factors(1e-3, 10.0, opts.max_iterations)
    };
    let r = crate::lm::minimize(&mut Fit { cost, pass: &pass }, (g, p), &policy);
    if r.stop == crate::lm::Stop::Singular {
        return None;
    }
    let ((g, p), iterations) = (r.x, r.iterations);
    // After the last step one more pass, undamped, for the sigmas at the solution: the last
    // step's matrix carries the damping, and when the steps stalled (lambda grown towards 1e8 by
    // rejected steps at the optimum) its inverse is ~0 (a start-up calibration reported a
    // worst-anchor sigma of 0.00 mm).
    let Some(Pass::Final(diag_inv, sandwich_var)) = pass(&g, &p, 0.0, true) else {
        return None;
    };
    // Residual statistics at the solution, and the variance component of the lengths: the
    // residuals within 4 s_l over their redundancy (see `refine`).
    let (mut sl2, mut nl, mut st2) = (0.0, 0usize, 0.0);
    let (mut in2, mut n_in, mut hat) = (0.0, 0usize, 0.0);
    for (r, pi) in data.iter().zip(&p) {
        let mut lpart = [[0.0; 3]; 3];
        let e = model::sub(*pi, r.pos);
        let wt = 1.0 / (st * st);
        let mut hpp = [[0.0; 3]; 3];
        for (a, row) in hpp.iter_mut().enumerate() {
            row[a] = wt;
        }
        for j in 0..n {
            if r.l[j].is_finite() {
                let a = [g[np * j], g[np * j + 1], g[np * j + 2]];
                let v = model::sub(add(*pi, b(j)), a);
                let d = model::norm(v);
                let q = 1.0 - factor(&g, j) * r.te[j];
                let res = d * q + g[np * j + 3] - r.l[j];
                sl2 += res * res;
                nl += 1;
                if res.abs() <= 4.0 * sl {
                    in2 += res * res;
                    n_in += 1;
                    let u = [q * v[0] / d, q * v[1] / d, q * v[2] / d];
                    for x in 0..3 {
                        for y in 0..3 {
                            lpart[x][y] += u[x] * u[y] / (sl * sl);
                            hpp[x][y] += u[x] * u[y] / (sl * sl);
                        }
                    }
                }
            }
        }
        if let Some(hi) = inv3(&hpp) {
            hat += (0..3).map(|x| (0..3).map(|y| hi[x][y] * lpart[y][x]).sum::<f64>()).sum::<f64>();
        }
        st2 += e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
    }
    let redundancy = n_in as f64 - hat - m as f64;
    let length_sigma_estimate = (redundancy > 0.1 * n_in as f64).then(|| (in2 / redundancy).sqrt());
    let var: Vec<f64> = match &sandwich_var {
        Some(sw) => diag_inv.iter().zip(sw).map(|(a, b)| a.max(*b)).collect(),
        None => diag_inv.clone(),
    };
    // Anchors and offsets packed four per cable, as `Geometry` and `Sigmas` take them.
    let four = |x: &[f64]| -> Vec<f64> { (0..n).flat_map(|j| x[np * j..np * j + 4].to_vec()).collect() };
    let ea = opts.stretch.map(|st| {
        (0..n)
            .map(|j| match fit_ea {
                // EA = EA_0 / s, its sigma to first order.
                Some(_) => (st.ea_n / g[np * j + 4], st.ea_n * var[np * j + 4].max(0.0).sqrt() / (g[np * j + 4] * g[np * j + 4])),
                None => (st.ea_n, 0.0),
            })
            .collect()
    });
    let result = BundleResult {
        params: Geometry::from_packed(&four(&g), n),
        sigma: Sigmas::from_variances(&four(&var), n),
        samples: data.len(),
        length_rms_m: (sl2 / nl.max(1) as f64).sqrt(),
        tracker_rms_m: (st2 / (3 * data.len()) as f64).sqrt(),
        iterations,
        length_sigma_m: sl,
        ea,
    };
    Some(Solved { result, length_sigma_estimate })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::Rng;

    /// Every anchor coordinate of `r` within `k` of its own sigma of `truth`.
    pub(super) fn assert_within_sigmas(r: &BundleResult, truth: &[[f64; 3]], k: f64) {
        for (j, (a, t)) in r.params.anchors.iter().zip(truth).enumerate() {
            for x in 0..3 {
                let e = (a[x] - t[x]).abs();
                assert!(
                    e < k * r.sigma.anchors[j][x],
                    "anchor {j}[{x}] off {:.3} mm, sigma {:.3} mm",
                    e * 1e3,
                    r.sigma.anchors[j][x] * 1e3
                );
            }
        }
    }
    #[test]
    fn redundant_cables_refine_the_anchors_beyond_the_calibration() {
        let truth = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let l0 = [1.0, -0.5, 0.25, 2.0];
        let mut rng = Rng::new(5);
        let mut rec = Recording::with_capacity(4, 2000, true, false, false);
        for i in 0..2000 {
            let p = [rng.range(-1.0, 1.0), rng.range(-0.6, 0.6), rng.range(1.5, 2.5)];
            let l: Vec<f64> = (0..4).map(|j| model::norm(model::sub(p, truth[j])) + l0[j] + 5e-5 * rng.normal()).collect();
            let m = [p[0] + 1.5e-3 * rng.normal(), p[1] + 1.5e-3 * rng.normal(), p[2] + 1.5e-3 * rng.normal()];
            rec.push(i as f64 * 0.01, m, None, &l, Some(&[20.0; 4]), None);
        }
        // Start 2 cm off.
        let start: Vec<[f64; 3]> = truth.iter().map(|a| [a[0] + 0.02, a[1] - 0.015, a[2] + 0.01]).collect();
        let r = refine(&rec, &[[0.0; 3]; 4], &start, &[1.02, -0.48, 0.23, 2.01], &BundleOptions::default()).unwrap();
        // The force-aware calibration on the same data, for comparison.
        let o = crate::CalibOptions { heldout_fraction: 0.0, ..Default::default() };
        let c = crate::calibrate(&rec, &[[0.0; 3]; 4], &crate::Params { anchors: start.clone(), l0: vec![1.02, -0.48, 0.23, 2.01] }, &o)
            .unwrap();
        let worst = |a: &[[f64; 3]]| a.iter().zip(&truth).map(|(a, t)| model::norm(model::sub(*a, *t))).fold(0.0, f64::max);
        let (eb, ec) = (worst(&r.params.anchors), worst(&c.params.anchors));
        assert!(eb < 0.5 * ec, "bundle {:.2} mm, calibration {:.2} mm", eb * 1e3, ec * 1e3);
        assert!(eb < 2.5e-3, "bundle worst anchor {:.2} mm", eb * 1e3);
        for (j, (a, t)) in r.params.anchors.iter().zip(&truth).enumerate() {
            for x in 0..3 {
                assert!((a[x] - t[x]).abs() < 5.0 * r.sigma.anchors[j][x] + 1e-5, "anchor {j}[{x}] beyond 5 sigma");
            }
        }
        assert!(r.length_rms_m < 1e-4, "length rms {}", r.length_rms_m);
        assert!(r.tracker_rms_m > 1.0e-3 && r.tracker_rms_m < 2.0e-3, "tracker rms {}", r.tracker_rms_m);
    }

    /// Synthetic excitation: 2,000 samples in the box, length noise `s_l` plus a model error of
    /// amplitude `miss` (a wave along x no geometry explains), tracker 1.5 mm with 0.5 %
    /// outliers of 5 cm.
    pub(super) fn synthetic(seed: u64, s_l: f64, miss: f64) -> (Recording, [[f64; 3]; 4], [f64; 4]) {
        let truth = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let l0 = [1.0, -0.5, 0.25, 2.0];
        let mut rng = Rng::new(seed);
        let mut rec = Recording::with_capacity(4, 2000, true, false, false);
        for i in 0..2000 {
            let p = [rng.range(-1.5, 1.5), rng.range(-0.8, 0.8), rng.range(1.2, 2.8)];
            let l: Vec<f64> = (0..4)
                .map(|j| {
                    let d = model::norm(model::sub(p, truth[j]));
                    d + miss * (5.0 * p[0] + j as f64).sin() + l0[j] + s_l * rng.normal()
                })
                .collect();
            let mut m = [p[0] + 1.5e-3 * rng.normal(), p[1] + 1.5e-3 * rng.normal(), p[2] + 1.5e-3 * rng.normal()];
            if rng.range(0.0, 1.0) < 0.005 {
                m[0] += 0.05;
            }
            rec.push(i as f64 * 0.01, m, None, &l, Some(&[20.0; 4]), None);
        }
        (rec, truth, l0)
    }

    #[test]
    fn the_length_noise_is_estimated_from_the_residuals_and_the_anchors_follow() {
        let (rec, truth, l0) = synthetic(7, 5e-5, 0.0);
        let start: Vec<[f64; 3]> = truth.iter().map(|a| [a[0] + 0.02, a[1] - 0.015, a[2] + 0.01]).collect();
        let l0s: Vec<f64> = l0.iter().map(|x| x + 0.01).collect();
        let fixed = refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &BundleOptions::default()).unwrap();
        let o = BundleOptions { length_sigma_floor_m: 1e-5, ..Default::default() };
        let est = refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &o).unwrap();
        // 2,000 redundant lengths: the estimate's relative standard error is 1/sqrt(4000) = 1.6 %.
        assert!((est.length_sigma_m / 5e-5 - 1.0).abs() < 0.1, "estimated length sigma {:.4} mm", est.length_sigma_m * 1e3);
        assert_eq!(fixed.length_sigma_m, 2e-4);
        let worst_sigma = |r: &BundleResult| r.sigma.anchors.iter().flatten().fold(0.0f64, |a, s| a.max(*s));
        assert!(worst_sigma(&est) < 0.7 * worst_sigma(&fixed), "{} vs {}", worst_sigma(&est), worst_sigma(&fixed));
        // The sigmas are honest: every coordinate within 4.5 of its sigmas (12 comparisons).
        assert_within_sigmas(&est, &truth, 4.5);
        // The floor holds.
        let floor =
            refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &BundleOptions { length_sigma_floor_m: 1e-4, ..Default::default() }).unwrap();
        assert_eq!(floor.length_sigma_m, 1e-4);
    }

    #[test]
    fn an_unmodelled_effect_raises_the_estimated_length_noise() {
        // 0.3 mm of length error the model lacks.
        let (rec, truth, l0) = synthetic(8, 5e-5, 3e-4);
        let o = BundleOptions { length_sigma_floor_m: 1e-5, ..Default::default() };
        let est = refine(&rec, &[[0.0; 3]; 4], &truth, &l0, &o).unwrap();
        assert!(est.length_sigma_m > 2.0 * 5e-5, "estimated length sigma {:.4} mm", est.length_sigma_m * 1e3);
        assert!(est.length_sigma_m <= o.length_sigma_m, "never above the start");
    }
}

#[cfg(test)]
mod stretch_tests {
    use super::tests::assert_within_sigmas;
    use super::*;
    use crate::synth::Rng;

    /// 2,000 samples in the box on cables of stiffness `ea` (N) under 10-60 N that vary with
    /// the pose (as a platform's weight shares do), lengths as a drum pays them out:
    /// `d / (1 + T / EA)`.
    fn stretched(seed: u64, ea: f64) -> (Recording, [[f64; 3]; 4], [f64; 4]) {
        let truth = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let l0 = [1.0, -0.5, 0.25, 2.0];
        let mut rng = Rng::new(seed);
        let mut rec = Recording::with_capacity(4, 2000, true, false, false);
        for i in 0..2000 {
            let p = [rng.range(-1.5, 1.5), rng.range(-0.8, 0.8), rng.range(1.2, 2.8)];
            let (mut l, mut f) = ([0.0; 4], [0.0; 4]);
            for j in 0..4 {
                let d = model::norm(model::sub(p, truth[j]));
                f[j] = 35.0 + 25.0 * ((p[0] * truth[j][0] + p[1] * truth[j][1]) / 6.0 + 0.3 * rng.normal()).tanh();
                l[j] = d / (1.0 + f[j] / ea) + l0[j] + 5e-5 * rng.normal();
            }
            let m = [p[0] + 1.5e-3 * rng.normal(), p[1] + 1.5e-3 * rng.normal(), p[2] + 1.5e-3 * rng.normal()];
            rec.push(i as f64 * 0.01, m, None, &l, Some(&f), None);
        }
        (rec, truth, l0)
    }

    #[test]
    fn a_known_stiffness_takes_the_stretch_from_the_anchors() {
        let (rec, truth, l0) = stretched(3, 2e5);
        let start: Vec<[f64; 3]> = truth.iter().map(|a| [a[0] + 0.02, a[1] - 0.015, a[2] + 0.01]).collect();
        let l0s: Vec<f64> = l0.iter().map(|x| x + 0.01).collect();
        let worst =
            |r: &BundleResult| r.params.anchors.iter().zip(&truth).map(|(a, t)| model::norm(model::sub(*a, *t))).fold(0.0, f64::max);
        let base = BundleOptions { length_sigma_floor_m: 1e-5, ..Default::default() };
        let ideal = refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &base).unwrap();
        assert!(ideal.ea.is_none());
        // The datasheet 15 % soft, fitted within +-20 %; and taken as exact.
        let fitted =
            refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &BundleOptions { stretch: Some(Stretch { ea_n: 1.7e5, rel_sigma: 0.2 }), ..base })
                .unwrap();
        let exact =
            refine(&rec, &[[0.0; 3]; 4], &start, &l0s, &BundleOptions { stretch: Some(Stretch { ea_n: 2e5, rel_sigma: 0.0 }), ..base })
                .unwrap();
        assert!(worst(&exact) < 0.2 * worst(&ideal), "exact EA {:.3} mm, ideal {:.3} mm", worst(&exact) * 1e3, worst(&ideal) * 1e3);
        assert!(worst(&fitted) < 0.3 * worst(&ideal), "fitted EA {:.3} mm, ideal {:.3} mm", worst(&fitted) * 1e3, worst(&ideal) * 1e3);
        assert_eq!(exact.ea.as_ref().unwrap(), &vec![(2e5, 0.0); 4]);
        for (j, &(ea, sd)) in fitted.ea.as_ref().unwrap().iter().enumerate() {
            assert!(sd > 0.0 && sd < 0.2 * 1.7e5, "cable {j}: EA sigma {sd}");
            assert!((ea - 2e5).abs() < 4.0 * sd, "cable {j}: EA {ea:.0} ± {sd:.0} N, truth 200000");
        }
        // Honest sigmas with the stiffness fitted: every coordinate within 4.5 of its sigmas.
        assert_within_sigmas(&fitted, &truth, 4.5);
    }
}

#[cfg(test)]
mod sigma_tests {
    use super::*;
    use nalgebra::{DMatrix, Matrix3, Vector3};

    /// The Cramer-Rao covariance of anchors and offsets with the positions eliminated (the
    /// module's model, written out independently: per sample `J_x^T W J_x`, `W` the lengths'
    /// weight with the tracker noise carried through).
    fn crb(rec: &Recording, g: &Geometry, sl: f64, st: f64) -> DMatrix<f64> {
        let n = rec.n_cables;
        let mut info = DMatrix::<f64>::zeros(4 * n, 4 * n);
        for i in 0..rec.len() {
            let p = rec.p[i];
            let e: Vec<Vector3<f64>> = g.anchors.iter().map(|a| Vector3::new(p[0] - a[0], p[1] - a[1], p[2] - a[2]).normalize()).collect();
            let mut m = Matrix3::identity() / (st * st);
            for ej in &e {
                m += ej * ej.transpose() / (sl * sl);
            }
            let mi = m.try_inverse().unwrap();
            for j in 0..n {
                for k in 0..n {
                    let w = if j == k { 1.0 / (sl * sl) } else { 0.0 } - (e[j].transpose() * mi * e[k])[0] / sl.powi(4);
                    let gj = [-e[j][0], -e[j][1], -e[j][2], 1.0];
                    let gk = [-e[k][0], -e[k][1], -e[k][2], 1.0];
                    for u in 0..4 {
                        for v in 0..4 {
                            info[(4 * j + u, 4 * k + v)] += w * gj[u] * gk[v];
                        }
                    }
                }
            }
        }
        info.try_inverse().unwrap()
    }

    /// Regression: the sigmas came from the last LM step's damped matrix; when the steps stalled
    /// at the optimum (lambda grown by rejected steps) a start-up calibration reported 0.00 mm.
    /// They are the undamped covariance at the solution, wherever the iterations stopped (or
    /// the time-block sandwich where larger: with the model right, within its scatter).
    #[test]
    fn sigmas_are_the_undamped_covariance_wherever_the_iterations_stop() {
        // The model exactly (no tracker outliers: the sandwich rightly grows with them).
        let truth = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let l0 = [1.0, -0.5, 0.25, 2.0];
        let mut rng = crate::synth::Rng::new(11);
        let mut rec = Recording::with_capacity(4, 2000, true, false, false);
        for i in 0..2000 {
            let p = [rng.range(-1.5, 1.5), rng.range(-0.8, 0.8), rng.range(1.2, 2.8)];
            let l: Vec<f64> = (0..4).map(|j| model::norm(model::sub(p, truth[j])) + l0[j] + 5e-5 * rng.normal()).collect();
            let m = [p[0] + 1.5e-3 * rng.normal(), p[1] + 1.5e-3 * rng.normal(), p[2] + 1.5e-3 * rng.normal()];
            rec.push(i as f64 * 0.01, m, None, &l, Some(&[20.0; 4]), None);
        }
        let o = BundleOptions { length_sigma_m: 5e-5, ..Default::default() };
        let start: Vec<[f64; 3]> = truth.iter().map(|a| [a[0] + 0.02, a[1] - 0.015, a[2] + 0.01]).collect();
        let first = refine(&rec, &[[0.0; 3]; 4], &start, &[1.02, -0.48, 0.23, 2.01], &o).unwrap();
        // Restarted at its own solution: steps of rounding size, rejected or accepted.
        let again = refine(&rec, &[[0.0; 3]; 4], &first.params.anchors, &first.params.l0, &o).unwrap();
        let cov = crb(&rec, &Geometry { anchors: truth.to_vec(), l0: l0.to_vec() }, 5e-5, 1.5e-3);
        for r in [&first, &again] {
            for j in 0..4 {
                for i in 0..3 {
                    let want = cov[(4 * j + i, 4 * j + i)].sqrt();
                    let got = r.sigma.anchors[j][i];
                    // Huber down-weights the few residuals beyond 3 sigma (0.3 %): a percent;
                    // the sandwich (32 blocks) scatters ~12 % in a sigma, 3 of that above.
                    assert!(got / want > 0.95 && got / want < 1.4, "anchor {j}[{i}]: {got:e} vs {want:e} ({} iterations)", r.iterations);
                }
            }
        }
    }
}
