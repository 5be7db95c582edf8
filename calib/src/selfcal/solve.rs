//! The sparse least-squares problem of self-calibration and its Levenberg–Marquardt solver.
//!
//! ```text
//! globals  g = (A_0 .. A_(n-1), L0_0 .. L0_(n-1), c_0 .. c_(n-1) [tensions], m [if estimated])
//! per dwell k: P_k (3)
//!
//! length   r_kj = l_kj - (|P_k + b_j - A_j| (1 - s_j T_kj / EA) + L0_j)   var sigma_enc^2 / N_kj
//! force    r_k  = -(sum_j (f_kj - c_j) v_kj + m g_vec)         cov sum_j sigma_f^2 / N_kj v_kj v_kj^T
//!          v_kj = (A_j - X_kj) / |A_j - X_kj|,  g_vec = (0, 0, -9.81)
//! tare     r_kj = f_kj - c_j                                   var sigma_f^2 / N_kj
//! prior    r_j  = 1 - s_j                                       var (sigma_EA / EA)^2
//! design   r_i  = mu_i - g_i                                    var sigma_i^2
//! ```
//!
//! With a known stiffness ([`Problem::stretch`], the datasheet `EA`) a length reading is the
//! distance less the cable's stretch under its tension `T_kj = f_kj - c_j` (as
//! [`crate::bundle::Stretch`]: the drum pays out the unstretched length, the encoder reads
//! `d / (1 + T / EA_true)`, to first order the model). With a tolerance above 0 each cable's
//! factor `s_j = EA / EA_j` is a global (after the mass) tied to 1 by its prior row; with 0 it
//! is held at 1; without a stretch (or without tensions) the ideal model `s_j T = 0`.
//!
//! The design's priors ([`Problem::design`]: an anchor coordinate or an offset `L0` known to a
//! tolerance) are pseudo-readings of their globals, one row each: the solution is then the
//! maximum a posteriori estimate, and [`posterior`] its covariance.
//!
//! In a tare dwell ([`Dwell::tared`]) the tared cables carry no tension: each gives the tare
//! row (its reading is its load cell's offset) instead of a term of the force balance, and no
//! length (a slack cable's length says nothing about the geometry).
//!
//! The force rows are whitened by the Cholesky factor of their 3x3 covariance (held fixed during a
//! solve, updated between solves), so every row has unit weight. The normal matrix is block-arrow
//! shaped: each dwell couples its own 3x3 block `H_pp,k` to the globals only. One LM step
//! eliminates the poses (Schur complement)
//!
//! ```text
//! S = H_gg - sum_k H_pg,k^T H_pp,k^-1 H_pg,k,   s = b_g - sum_k H_pg,k^T H_pp,k^-1 b_p,k
//! [S  C^T] [dg]   [s        ]
//! [C   0 ] [mu] = [d - C g  ]        gauge: C g = d (see `super::gauge`)
//! dP_k = H_pp,k^-1 (b_p,k - H_pg,k dg)
//! ```
//!
//! so a step costs `O(K ng^2)` for `K` dwells and `ng` globals (at most 41): linear in the poses.
//! The covariance of the globals in the gauge `C` is the top-left block of the inverse of the
//! bordered matrix at the solution: the Cramér–Rao bound of the recording when the noise model
//! holds.

use super::dwell::Dwell;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// Standard gravity, m/s^2.
pub const G: f64 = 9.81;

/// Index layout of the global parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// Cables.
    pub n: usize,
    /// Load-cell offsets are unknowns (tensions used).
    pub offsets: bool,
    /// The mass is an unknown.
    pub mass: bool,
    /// The cables' stretch factors `s_j` are unknowns (a stiffness with a tolerance).
    pub ea: bool,
}

impl Layout {
    /// Number of globals.
    pub fn count(&self) -> usize {
        4 * self.n + if self.offsets { self.n } else { 0 } + usize::from(self.mass) + if self.ea { self.n } else { 0 }
    }
    /// First index of anchor `j`.
    pub fn a(&self, j: usize) -> usize {
        3 * j
    }
    /// Index of `L0_j`.
    pub fn l0(&self, j: usize) -> usize {
        3 * self.n + j
    }
    /// Index of load-cell offset `c_j`.
    pub fn c(&self, j: usize) -> usize {
        4 * self.n + j
    }
    /// Index of the mass.
    pub fn m(&self) -> usize {
        4 * self.n + if self.offsets { self.n } else { 0 }
    }
    /// Index of the stretch factor `s_j` (with [`Layout::ea`]).
    pub fn s(&self, j: usize) -> usize {
        self.m() + usize::from(self.mass) + j
    }
}

/// The data and noise model.
pub struct Problem<'a> {
    /// Layout of the globals.
    pub lay: Layout,
    /// Platform points.
    pub b: &'a [[f64; 3]],
    /// The dwells.
    pub dwells: &'a [Dwell],
    /// Variance of one encoder reading, m^2.
    pub var_l: f64,
    /// Variance of one tension reading, N^2.
    pub var_f: f64,
    /// Known mass, kg (start value when estimated).
    pub mass: f64,
    /// Readings below this tension are loose: their lengths are not used.
    pub min_tension_n: f64,
    /// The cables' stretch (used with tensions): `None`, the ideal model. Its `rel_sigma`
    /// above 0 needs [`Layout::ea`] (the factors fitted), 0 holds the stiffness.
    pub stretch: Option<crate::bundle::Stretch>,
    /// The design's priors: `(global index, mean, 1-sigma)`, one pseudo-reading each.
    pub design: &'a [(usize, f64, f64)],
    /// Gauge constraints `C g = d`.
    pub c: DMatrix<f64>,
    /// Right-hand side of the gauge constraints.
    pub d: DVector<f64>,
}

/// Current estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    /// Globals.
    pub g: DVector<f64>,
    /// One position per dwell.
    pub p: Vec<[f64; 3]>,
}

impl State {
    /// Anchor `j`.
    pub fn anchor(&self, j: usize) -> [f64; 3] {
        [self.g[3 * j], self.g[3 * j + 1], self.g[3 * j + 2]]
    }
}

/// Whitening of the force rows of each dwell (`None`: no force rows).
pub type Whitening = Vec<Option<Matrix3<f64>>>;

/// Rows of one dwell: whitened residuals and Jacobians (pose part, global part).
struct Rows {
    r: Vec<f64>,
    jp: Vec<[f64; 3]>,
    jg: Vec<Vec<(usize, f64)>>,
}

impl Problem<'_> {
    fn length_used(&self, d: &Dwell, j: usize) -> bool {
        d.nl[j] > 0 && d.l[j].is_finite() && !(d.f[j] < self.min_tension_n)
    }

    /// Cables of dwell `d` known to carry no tension (a tare, with load cells only).
    fn tared(&self, d: &Dwell) -> Vec<bool> {
        if self.lay.offsets {
            d.tared(self.min_tension_n)
        } else {
            vec![false; self.lay.n]
        }
    }

    fn force_used(&self, d: &Dwell) -> bool {
        self.lay.offsets && d.nf.iter().all(|&c| c > 0) && d.f.iter().all(|v| v.is_finite())
    }

    /// `T / EA` of cable `j` in dwell `d` at `s` and the stretch factor (`(0, 1)`: none).
    fn stretch_of(&self, s: &State, d: &Dwell, j: usize) -> (f64, f64) {
        match self.stretch {
            Some(st) if self.lay.offsets && st.ea_n > 0.0 && st.ea_n.is_finite() && d.f[j].is_finite() => {
                let sf = if self.lay.ea { s.g[self.lay.s(j)] } else { 1.0 };
                ((d.f[j] - s.g[self.lay.c(j)]) / st.ea_n, sf)
            }
            _ => (0.0, 1.0),
        }
    }

    /// The prior rows of the stretch factors and of the design: `(index, whitened residual,
    /// weight)`.
    fn prior_rows(&self, s: &State) -> Vec<(usize, f64, f64)> {
        let mut rows = match self.stretch {
            Some(st) if self.lay.ea && st.rel_sigma > 0.0 => {
                (0..self.lay.n).map(|j| (self.lay.s(j), (1.0 - s.g[self.lay.s(j)]) / st.rel_sigma, 1.0 / st.rel_sigma)).collect()
            }
            _ => Vec::new(),
        };
        rows.extend(self.design.iter().map(|&(i, mu, sd)| (i, (mu - s.g[i]) / sd, 1.0 / sd)));
        rows
    }

    fn mass_of(&self, s: &State) -> f64 {
        if self.lay.mass {
            s.g[self.lay.m()]
        } else {
            self.mass
        }
    }

    /// Whitening matrices `L^-1` (`Sigma_F = L L^T`) at the state `s`.
    pub fn whitening(&self, s: &State) -> Whitening {
        self.dwells
            .iter()
            .zip(&s.p)
            .map(|(d, p)| {
                if !self.force_used(d) {
                    return None;
                }
                let mut cov = Matrix3::zeros();
                let tared = self.tared(d);
                for j in (0..self.lay.n).filter(|&j| !tared[j]) {
                    let v = self.dir(s, p, j).1;
                    cov += v * v.transpose() * (self.var_f / d.nf[j] as f64);
                }
                cov.cholesky().and_then(|c| c.l().try_inverse())
            })
            .collect()
    }

    /// `(rho, v)`: distance and unit vector from the platform point of cable `j` to its anchor.
    fn dir(&self, s: &State, p: &[f64; 3], j: usize) -> (f64, Vector3<f64>) {
        let a = s.anchor(j);
        let b = self.b[j];
        let d = Vector3::new(a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]);
        let rho = d.norm();
        (rho, d / rho)
    }

    fn rows(&self, s: &State, k: usize, p: &[f64; 3], w: &Option<Matrix3<f64>>) -> Rows {
        let d = &self.dwells[k];
        let lay = self.lay;
        let mut rows = Rows { r: Vec::with_capacity(lay.n + 3), jp: Vec::with_capacity(lay.n + 3), jg: Vec::with_capacity(lay.n + 3) };
        for j in 0..lay.n {
            if !self.length_used(d, j) {
                continue;
            }
            let (rho, v) = self.dir(s, p, j);
            let sw = (d.nl[j] as f64 / self.var_l).sqrt();
            // model = rho (1 - s_j T / EA) + L0; d rho / dP = -v, d rho / dA = v,
            // d model / d s_j = -rho T / EA, d model / d c_j = rho s_j / EA.
            let (te, sf) = self.stretch_of(s, d, j);
            let k = 1.0 - sf * te;
            rows.r.push(sw * (d.l[j] - rho * k - s.g[lay.l0(j)]));
            rows.jp.push([-sw * k * v[0], -sw * k * v[1], -sw * k * v[2]]);
            let a = lay.a(j);
            let mut jg = vec![(a, sw * k * v[0]), (a + 1, sw * k * v[1]), (a + 2, sw * k * v[2]), (lay.l0(j), sw)];
            if te != 0.0 {
                let ea = self.stretch.map_or(f64::INFINITY, |st| st.ea_n);
                jg.push((lay.c(j), sw * rho * sf / ea));
                if lay.ea {
                    jg.push((lay.s(j), -sw * rho * te));
                }
            }
            rows.jg.push(jg);
        }
        if let Some(wm) = w {
            let m = self.mass_of(s);
            // m (g - a): gravity, less the force that accelerates the platform (zero at a rest).
            let ga = Vector3::new(-d.accel[0], -d.accel[1], -G - d.accel[2]);
            let mut f = m * ga;
            let mut dfdp = Matrix3::zeros();
            // Columns of dF/dg, sparse: (index, 3-vector).
            let mut cols: Vec<(usize, Vector3<f64>)> = Vec::with_capacity(4 * lay.n + 1);
            let tared = self.tared(d);
            for j in (0..lay.n).filter(|&j| tared[j]) {
                // model c_j, reading f_kj.
                let sw = (d.nf[j] as f64 / self.var_f).sqrt();
                rows.r.push(sw * (d.f[j] - s.g[lay.c(j)]));
                rows.jp.push([0.0; 3]);
                rows.jg.push(vec![(lay.c(j), sw)]);
            }
            for j in (0..lay.n).filter(|&j| !tared[j]) {
                let (rho, v) = self.dir(s, p, j);
                let t = d.f[j] - s.g[lay.c(j)];
                f += v * t;
                let proj = (Matrix3::identity() - v * v.transpose()) * (t / rho);
                dfdp -= proj;
                let a = lay.a(j);
                for q in 0..3 {
                    cols.push((a + q, proj.column(q).into_owned()));
                }
                cols.push((lay.c(j), -v));
            }
            if lay.mass {
                cols.push((lay.m(), ga));
            }
            // Residual -F (the measured force balance is zero), whitened.
            let r = wm * (-f);
            let jp = wm * dfdp;
            for q in 0..3 {
                rows.r.push(r[q]);
                rows.jp.push([jp[(q, 0)], jp[(q, 1)], jp[(q, 2)]]);
                rows.jg.push(cols.iter().map(|(i, c)| (*i, (wm.row(q) * c)[0])).collect());
            }
        }
        rows
    }

    /// Whitened chi-square at `s`, and the number of rows.
    pub fn cost(&self, s: &State, w: &Whitening) -> (f64, usize) {
        let (mut c, mut m) = (0.0, 0usize);
        for k in 0..self.dwells.len() {
            let rows = self.rows(s, k, &s.p[k], &w[k]);
            c += rows.r.iter().map(|r| r * r).sum::<f64>();
            m += rows.r.len();
        }
        let prior = self.prior_rows(s);
        c += prior.iter().map(|(_, r, _)| r * r).sum::<f64>();
        (c, m + prior.len())
    }
}

/// Normal equations in block-arrow form.
struct Normal {
    hpp: Vec<Matrix3<f64>>,
    hpg: Vec<DMatrix<f64>>,
    bp: Vec<Vector3<f64>>,
    hgg: DMatrix<f64>,
    bg: DVector<f64>,
}

fn normal(pr: &Problem<'_>, s: &State, w: &Whitening) -> Normal {
    let mut nm = normal_data(pr, s, w);
    for (i, r, jw) in pr.prior_rows(s) {
        nm.hgg[(i, i)] += jw * jw;
        nm.bg[i] += jw * r;
    }
    nm
}

/// The normal equations of the readings alone (no prior rows).
fn normal_data(pr: &Problem<'_>, s: &State, w: &Whitening) -> Normal {
    let ng = pr.lay.count();
    let kd = pr.dwells.len();
    let mut nm = Normal {
        hpp: Vec::with_capacity(kd),
        hpg: Vec::with_capacity(kd),
        bp: Vec::with_capacity(kd),
        hgg: DMatrix::zeros(ng, ng),
        bg: DVector::zeros(ng),
    };
    for k in 0..kd {
        let rows = pr.rows(s, k, &s.p[k], &w[k]);
        let mut hpp = Matrix3::zeros();
        let mut hpg = DMatrix::zeros(3, ng);
        let mut bp = Vector3::zeros();
        for i in 0..rows.r.len() {
            let (r, jp, jg) = (rows.r[i], rows.jp[i], &rows.jg[i]);
            for a in 0..3 {
                bp[a] += jp[a] * r;
                for b in 0..3 {
                    hpp[(a, b)] += jp[a] * jp[b];
                }
                for &(gi, gv) in jg {
                    hpg[(a, gi)] += jp[a] * gv;
                }
            }
            for &(gi, gv) in jg {
                nm.bg[gi] += gv * r;
                for &(gk, gw) in jg {
                    nm.hgg[(gi, gk)] += gv * gw;
                }
            }
        }
        nm.hpp.push(hpp);
        nm.hpg.push(hpg);
        nm.bp.push(bp);
    }
    nm
}

/// The Schur-reduced matrix and right-hand side, and the damped inverse pose blocks.
type Reduced = (DMatrix<f64>, DVector<f64>, Vec<Matrix3<f64>>);

/// The Schur-reduced system with damping `lambda` (Marquardt's diagonal scaling).
fn reduce(nm: &Normal, lambda: f64) -> Option<Reduced> {
    let mut s = nm.hgg.clone();
    for i in 0..s.nrows() {
        s[(i, i)] += lambda * nm.hgg[(i, i)];
    }
    let mut rhs = nm.bg.clone();
    let mut invs = Vec::with_capacity(nm.hpp.len());
    for k in 0..nm.hpp.len() {
        let mut h = nm.hpp[k];
        for a in 0..3 {
            h[(a, a)] *= 1.0 + lambda;
        }
        let inv = h.try_inverse()?;
        let ihg = inv * &nm.hpg[k]; // 3 x ng
        s -= nm.hpg[k].transpose() * &ihg;
        rhs -= ihg.transpose() * nm.bp[k];
        invs.push(inv);
    }
    Some((s, rhs, invs))
}

/// Solves the bordered (gauge-constrained) system `[S C^T; C 0] [x; mu] = [r; e]`.
fn bordered(s: &DMatrix<f64>, c: &DMatrix<f64>, r: &DVector<f64>, e: &DVector<f64>) -> Option<DVector<f64>> {
    let (ng, nc) = (s.nrows(), c.nrows());
    let mut k = DMatrix::zeros(ng + nc, ng + nc);
    k.view_mut((0, 0), (ng, ng)).copy_from(s);
    k.view_mut((ng, 0), (nc, ng)).copy_from(c);
    k.view_mut((0, ng), (ng, nc)).copy_from(&c.transpose());
    let mut rhs = DVector::zeros(ng + nc);
    rhs.rows_mut(0, ng).copy_from(r);
    rhs.rows_mut(ng, nc).copy_from(e);
    let x = k.lu().solve(&rhs)?;
    x.iter().all(|v| v.is_finite()).then(|| x.rows(0, ng).into_owned())
}

/// How the solve ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveReport {
    /// LM iterations.
    pub iterations: usize,
    /// Final whitened chi-square.
    pub chi2: f64,
    /// Rows (scalar measurements).
    pub rows: usize,
    /// True when the cost change fell below the tolerance.
    pub converged: bool,
}

/// The self-calibration for [`crate::lm`]: the cost alone at a trial point, the block-arrow
/// normal equations at the current point when a step needs them.
struct Selfcal<'p, 'a> {
    pr: &'p Problem<'a>,
    w: &'p Whitening,
    /// The normal equations at the current point (`None`: not built since it changed).
    nm: Option<Normal>,
    /// Rows of the problem (the same at every point).
    rows: usize,
}

impl crate::lm::Problem for Selfcal<'_, '_> {
    type X = State;
    /// The trial state (the pose updates need the eliminated blocks, so the step builds it).
    type Step = State;

    fn cost(&mut self, s: &State) -> f64 {
        let (c, rows) = self.pr.cost(s, self.w);
        self.rows = rows;
        c
    }

    fn accepted(&mut self) {
        self.nm = None;
    }

    fn step(&mut self, s: &State, lambda: f64) -> Option<State> {
        let nm = self.nm.get_or_insert_with(|| normal(self.pr, s, self.w));
        let (sm, rhs, invs) = reduce(nm, lambda)?;
        let e = &self.pr.d - &self.pr.c * &s.g;
        let dg = bordered(&sm, &self.pr.c, &rhs, &e)?;
        let mut trial = State { g: &s.g + &dg, p: s.p.clone() };
        for k in 0..trial.p.len() {
            let dp = invs[k] * (nm.bp[k] - &nm.hpg[k] * &dg);
            for a in 0..3 {
                trial.p[k][a] += dp[a];
            }
        }
        Some(trial)
    }

    fn apply(&self, _s: &State, trial: &State) -> State {
        trial.clone()
    }
}

/// Levenberg–Marquardt ([`crate::lm`]) on the whole problem from `s` (whitening fixed). A
/// chi-square change of 1e-4 moves the parameters by ~1e-2 sigma: converged; so is a point
/// where no damping finds a lower cost (the minimum to round-off).
pub fn lm(pr: &Problem<'_>, s: &mut State, w: &Whitening, max_iter: usize) -> SolveReport {
    use crate::lm::{CostTest, Policy, Stop};
    let policy =
        Policy { max_lambda: 1e12, accept_ties: true, cost_test: CostTest::Absolute(1e-4), ..Policy::factors(1e-4, 4.0, max_iter) };
    let mut p = Selfcal { pr, w, nm: None, rows: 0 };
    let r = crate::lm::minimize(&mut p, s.clone(), &policy);
    *s = r.x;
    SolveReport {
        iterations: r.iterations,
        chi2: r.cost,
        rows: p.rows,
        converged: matches!(r.stop, Stop::SmallCostChange | Stop::NoDecrease),
    }
}

/// The Fisher information on the globals with the poses eliminated (the Schur complement
/// `H_gg - sum_k H_pg,k^T H_pp,k^-1 H_pg,k` at `s`, no gauge): it adds over dwells, which the
/// dwell planner ([`super::plan`]) uses to predict the bound of a set of poses. `None` when a
/// pose block is singular.
pub fn information(pr: &Problem<'_>, s: &State, w: &Whitening) -> Option<DMatrix<f64>> {
    let nm = normal(pr, s, w);
    reduce(&nm, 0.0).map(|r| r.0)
}

/// Covariance of the globals in the gauge `C g = d` at `s` (inverse Fisher information,
/// gauge-projected). `None` when the information is singular beyond the gauge.
pub fn covariance(pr: &Problem<'_>, s: &State, w: &Whitening) -> Option<DMatrix<f64>> {
    let nm = normal(pr, s, w);
    let (sm, _, _) = reduce(&nm, 0.0)?;
    bordered_inverse(&sm, &pr.c)
}

/// The posterior covariance of the globals in the gauge `C g = d` at `s`, the readings'
/// information divided by `data_scale` (the a-posteriori variance factor, when above 1) and
/// the priors' taken as given: `(S_data / data_scale + H_prior)^-1`, gauge-projected. Every
/// parameter with a prior has a posterior variance at most its prior's. `None` as
/// [`covariance`].
pub fn posterior(pr: &Problem<'_>, s: &State, w: &Whitening, data_scale: f64) -> Option<DMatrix<f64>> {
    let nm = normal_data(pr, s, w);
    let (mut sm, _, _) = reduce(&nm, 0.0)?;
    sm /= data_scale;
    for (i, _, jw) in pr.prior_rows(s) {
        sm[(i, i)] += jw * jw;
    }
    bordered_inverse(&sm, &pr.c)
}

/// The top-left block of `[S C^T; C 0]^-1`; without constraints `S^-1`, by Cholesky (the
/// readings' information can exceed a prior's by 1e5 and more: an LU inverse loses the prior's
/// small eigenvalues to round-off).
fn bordered_inverse(sm: &DMatrix<f64>, c: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let (ng, nc) = (sm.nrows(), c.nrows());
    if nc == 0 {
        let cov = sm.clone().cholesky()?.inverse();
        return cov.iter().all(|v| v.is_finite()).then_some(cov);
    }
    let mut k = DMatrix::zeros(ng + nc, ng + nc);
    k.view_mut((0, 0), (ng, ng)).copy_from(sm);
    k.view_mut((ng, 0), (nc, ng)).copy_from(c);
    k.view_mut((0, ng), (ng, nc)).copy_from(&c.transpose());
    let inv = k.try_inverse()?;
    let cov = inv.view((0, 0), (ng, ng)).into_owned();
    cov.iter().all(|v| v.is_finite()).then_some(cov)
}
