//! The tension side of the diagnosis: do the load cells balance the platform's weight and
//! inertia along the fitted geometry, and if not, which tension effect explains why?
//!
//! With a tracker, the fitted anchors and the platform's known mass, each row where every cable
//! is taut gives the balance residual of [`crate::effects::tension`] (three numbers, N). The
//! baseline is statics with a constant offset per cell (fitted, like the encoders' `L0`):
//!
//! ```text
//! r_i = sum_j (f_ij - o_j) exp(-lambda_ij) u_ij  -  m g_up  -  F_i         (lambda = 0, F = 0 in the baseline)
//! ```
//!
//! **The path's derivatives, and the balance filtered to match.** Velocities and
//! accelerations come from a local quadratic fitted to the tracker's positions over `t_i +- h`
//! ([`ACCEL_HALF_WINDOW_S`], at least 3.5 samples) inside one segment (a dropout or a clock jump
//! ends it), on the rows' own (irregular) times. Its acceleration is a weighted sum
//! `a_i = sum_k w_ik p_k` of positions, which for a smooth path equals `integral K_i(s) p''(s) ds`
//! with the Peano kernel `K_i(s) = sum_k w_ik (t_k - s)_+` (a bump of unit area over the window).
//! So the balance is tested on the tensions filtered by the same kernel,
//! `sum_k kappa_ik r_k = m a_i` (`kappa` the kernel's trapezoid weights on the rows' times): the
//! estimator's smoothing is on both sides, its bias cancels, and the window can be long enough
//! to make the acceleration's noise small (0.02-0.03 m/s^2 at 100 Hz, 1.5 mm) without blurring
//! fast moves out of the test. A quadratic over a short window, unfiltered, has a bias of
//! `(omega h)^2 / 14` at angular frequency `omega`, and a window short enough for a 1 Hz
//! excursion leaves the acceleration so noisy (0.2-0.6 m/s^2) that slow recordings' inertia goes
//! unseen and is absorbed by load-cell gains (slow harmonic motion's `m a = -m omega^2 x` is a
//! force that follows the position, as gains' tension pattern does). The filtered rows are taken
//! every half window (they overlap by half; the test's batch means take the correlation).
//!
//! **Weights.** Each row's residual is whitened by its covariance
//! `s_T^2 sum_k kappa_k^2 sum_j u_j u_j^T + m_i^2 var_a I` (the load cells' noise `s_T` through
//! the filter, and the acceleration's noise through an inertia term). The inertia's mass multiplies a noisy
//! regressor, so the cost with that covariance is minimised as a whole (Deming's errors-in-
//! variables estimator; least squares with fixed weights would shrink `m_i` by the share of the
//! acceleration's variance that is noise, ~30 % on a recording that is fast only in its
//! excursions). `s_T` is [`super::DiagnoseOptions::loadcell_sigma_n`], or estimated from the
//! residuals when that is 0.
//!
//! **Locating.** On the baseline, each cable's whitened residual is regressed on its cell's
//! tension level, the level times the direction of motion and times the speed, and the
//! platform's residual on its acceleration; each lead's t statistic (AR(1)-prewhitened batch
//! means, [`super::select::long_run_variance`]) says where the balance departs.
//!
//! **Naming.** The same held-out test as the length side
//! ([`super::select::encompassing_test_with`], with the current model's estimation error by a
//! sandwich over contiguous clusters of training windows), at the same per-test level (the
//! family counts the tension effects: [`super::DiagnoseOptions::test_alpha`]), cross-fitted: each
//! fold of the length side's time blocks is held out once and the folds' held-out residuals are
//! tested together (one split held out too few filtered rows). The selection is backward
//! elimination from the whole tension library: every effect's removal test (the model without
//! it as the current model, it as the candidate); the least significant effect that fails its
//! test is dropped and the rest tested again. Forward selection stalled where two true effects
//! each hid the other (friction under the inertia every moving platform has: 12 of 20 named),
//! as a test on a model missing a true effect sees its structure as correlated noise.
//! A gain's or friction's held-out change is proportional to the readings, which carry the same
//! cell noise as the current model's residual; through the filter that shared part is
//! `sum kappa^2 s_T^2` per row against a tension level of tens of newtons, a bias of the
//! statistic of about `s_f sqrt(n_eff) / t` (0.04 of its sd at 0.1 N filtered noise, 15 N), so
//! the readings are used as they are.

use super::select::{self, HeldoutTest};
use super::{dataq::DataMasks, lm, Decision, DiagnoseOptions};
use crate::effects::tension::{friction, BalanceRow, TensionEffect, Term};
use crate::effects::Sharing;
use crate::model::{mat_vec, rotation};
use nalgebra::{DMatrix, DVector};
use taut_config::recording::Recording;
use taut_model::Geometry;

/// Half-width of the local polynomial that gives the path's velocity and acceleration, s.
pub const ACCEL_HALF_WINDOW_S: f64 = 0.25;

/// Standard gravity, m/s^2.
const G: f64 = 9.81;

/// Contiguous clusters of training rows for the estimation-error sandwich and the parameters'
/// batch-means sigmas.
const CLUSTERS: usize = 40;

/// Fewest filtered balance rows (windows) the tension side works with.
const MIN_ROWS: usize = 100;

/// What the tension side found.
#[derive(Debug, Clone, PartialEq)]
pub struct TensionDiagnosis {
    /// Filtered balance rows (windows where every cable was taut and the path's derivatives
    /// were known; taken every half window).
    pub rows: usize,
    /// The platform's mass the balance used, kg.
    pub mass_kg: f64,
    /// The load cells' noise used in the weights, N (1-sigma).
    pub loadcell_sigma_n: f64,
    /// Whether that noise was estimated from the residuals (none was given).
    pub sigma_estimated: bool,
    /// Half-width of the local polynomial for velocity and acceleration, s.
    pub accel_window_s: f64,
    /// Each cell's offset (final model), N, and its 1-sigma.
    pub offsets_n: Vec<f64>,
    /// 1-sigma of the offsets, N.
    pub offset_sigmas_n: Vec<f64>,
    /// RMS of the filtered balance residual per axis, baseline fitted and taken on the training
    /// rows of the split that holds out the last fold (the length side's split at 20 %), N.
    pub rms_before_n: f64,
    /// Baseline, held out, N.
    pub heldout_rms_before_n: f64,
    /// Final model fitted on the training rows of the same split, there, N.
    pub rms_after_n: f64,
    /// Final model fitted on the training rows, on the held-out ones, N.
    pub heldout_rms_after_n: f64,
    /// Where the baseline balance departs, strongest first.
    pub leads: Vec<TensionLead>,
    /// Named tension effects, in the order they were named.
    pub effects: Vec<TensionFinding>,
    /// Every candidate's held-out test, round by round.
    pub tests: Vec<TensionTest>,
    /// Things a person should know.
    pub notes: Vec<String>,
}

/// One place the baseline balance departs: a cable (or the platform) and what it follows.
#[derive(Debug, Clone, PartialEq)]
pub struct TensionLead {
    /// The cable (`None`: the platform).
    pub cable: Option<usize>,
    /// What the residual follows.
    pub follows: LeadKind,
    /// The regression coefficient (per cable: the share of the tension level, or per m/s of
    /// speed; the platform: kg).
    pub coefficient: f64,
    /// Its t statistic (time-correlated residuals accounted for).
    pub t: f64,
}

/// What a lead's residual follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LeadKind {
    /// The cell's tension level (gain).
    Level,
    /// The level times the cable's direction of motion (+ paying out).
    Direction,
    /// The level times the cable's speed, per m/s.
    Speed,
    /// The platform's acceleration.
    Acceleration,
}

impl LeadKind {
    /// In words.
    pub fn words(self) -> &'static str {
        match self {
            LeadKind::Level => "its tension level",
            LeadKind::Direction => "its tension times the direction of motion (reads more reeling in than paying out when negative)",
            LeadKind::Speed => "its tension times its speed",
            LeadKind::Acceleration => "the platform's acceleration",
        }
    }
}

/// One named tension effect.
#[derive(Debug, Clone, PartialEq)]
pub struct TensionFinding {
    /// The effect.
    pub effect: TensionEffect,
    /// Its values (physical: gain, `mu theta`, kg), one per cable or one for the platform.
    pub values: Vec<f64>,
    /// Their 1-sigma (batch-means sandwich, never narrower than least squares).
    pub sigmas: Vec<f64>,
    /// The held-out test that named it.
    pub test: HeldoutTest,
    /// The evidence in words.
    pub evidence: String,
}

/// One candidate's test in one round.
#[derive(Debug, Clone, PartialEq)]
pub struct TensionTest {
    /// Round (1: on top of the baseline).
    pub round: usize,
    /// The candidate.
    pub effect: TensionEffect,
    /// The held-out test (`None`: too few held-out rows).
    pub test: Option<HeldoutTest>,
    /// The level it was tested at.
    pub alpha: f64,
    /// What was decided.
    pub decision: Decision,
    /// Its fitted values (physical).
    pub values: Vec<f64>,
}

/// One filtered row of the balance: the rows of the window with their kernel weights.
struct Window {
    /// The row whose acceleration the window's kernel matches.
    center: usize,
    /// `(row, kappa)`.
    w: Vec<(usize, f64)>,
    /// `sum kappa^2`.
    s2: f64,
}

/// The balance rows of a recording and the filtered rows over them.
struct Data {
    raw: Vec<BalanceRow>,
    win: Vec<Window>,
    /// Per window: its fold (time blocks; see [`Data::folds`]).
    fold: Vec<usize>,
    /// Folds: fold `k` holds the time blocks `b` with `b % folds == k`.
    folds: usize,
}

/// The local quadratic's position, velocity and acceleration, and the acceleration's weights
/// `w_k` per position.
struct LocalPath {
    p: [f64; 3],
    v: [f64; 3],
    a: [f64; 3],
    w: Vec<f64>,
}

/// Local quadratic at row `i` over the rows `ks` (same segment, pose present).
fn local_path(rec: &Recording, i: usize, ks: &[usize], h: f64) -> Option<LocalPath> {
    const D: usize = 3;
    let basis = |k: usize| {
        let tau = (rec.t[k] - rec.t[i]) / h;
        [1.0, tau, tau * tau]
    };
    let mut xtx = DMatrix::<f64>::zeros(D, D);
    for &k in ks {
        let b = basis(k);
        for r in 0..D {
            for c in 0..D {
                xtx[(r, c)] += b[r] * b[c];
            }
        }
    }
    let g = xtx.try_inverse()?;
    let (mut p, mut v, mut a, mut wa) = ([0.0; 3], [0.0; 3], [0.0; 3], Vec::with_capacity(ks.len()));
    for &k in ks {
        let b = basis(k);
        let w: [f64; 3] = std::array::from_fn(|d| (0..D).map(|c| g[(d, c)] * b[c]).sum::<f64>());
        let wk = 2.0 * w[2] / (h * h);
        for ax in 0..3 {
            p[ax] += w[0] * rec.p[k][ax];
            v[ax] += w[1] * rec.p[k][ax] / h;
            a[ax] += wk * rec.p[k][ax];
        }
        wa.push(wk);
    }
    Some(LocalPath { p, v, a, w: wa })
}

/// The kernel weights `kappa_k` (trapezoid on the rows' times) of the Peano kernel
/// `K(s) = sum_k w_k (t_k - s)_+` of acceleration weights `w` over the times `t` (increasing).
fn kernel_weights(t: &[f64], w: &[f64]) -> Vec<f64> {
    let k_at = |s: f64| t.iter().zip(w).map(|(tk, wk)| wk * (tk - s).max(0.0)).sum::<f64>();
    let m = t.len();
    (0..m)
        .map(|q| {
            let left = if q > 0 { t[q] - t[q - 1] } else { 0.0 };
            let right = if q + 1 < m { t[q + 1] - t[q] } else { 0.0 };
            k_at(t[q]) * 0.5 * (left + right)
        })
        .collect()
}

/// The balance rows (every cable taut and its cell alive, the pose present) and the windows
/// whose every row is one.
fn balance_data(
    rec: &Recording,
    masks: &DataMasks,
    geometry: &Geometry,
    platform_points: &[[f64; 3]],
    opts: &DiagnoseOptions,
) -> Option<Data> {
    let n = rec.n_cables;
    let f = rec.f.as_ref()?;
    let h = ACCEL_HALF_WINDOW_S.max(3.5 * masks.dt);
    let m = rec.len();
    let pose_ok = |k: usize| masks.row_ok[k] && rec.p[k].iter().all(|v| v.is_finite());
    let taut = |k: usize| pose_ok(k) && f[k * n..(k + 1) * n].iter().all(|v| v.is_finite() && *v >= opts.min_tension_n);
    let mut raw = vec![];
    let mut raw_of = vec![usize::MAX; m];
    let mut windows: Vec<(usize, Vec<usize>, Vec<f64>)> = vec![];
    let stride = ((h / masks.dt.max(1e-6)).round() as usize).max(1);
    for i in 0..m {
        if !taut(i) {
            continue;
        }
        let mut ks = vec![];
        let mut k = i;
        while k > 0 && rec.t[i] - rec.t[k - 1] <= h && masks.segment[k - 1] == masks.segment[i] {
            k -= 1;
        }
        while k < m && rec.t[k] - rec.t[i] <= h && masks.segment[k] == masks.segment[i] {
            if pose_ok(k) {
                ks.push(k);
            }
            k += 1;
        }
        let (before, after) = (ks.iter().filter(|&&k| k < i).count(), ks.iter().filter(|&&k| k > i).count());
        if ks.len() < 5 || before < 2 || after < 2 {
            continue;
        }
        let Some(LocalPath { p, v: vel, a, w: wa }) = local_path(rec, i, &ks, h) else { continue };
        let r = rec.q.as_ref().and_then(|q| rotation(q[i]));
        let mut u = Vec::with_capacity(n);
        let mut v = Vec::with_capacity(n);
        for (j, b) in platform_points.iter().enumerate() {
            let o = r.map(|r| mat_vec(&r, *b)).unwrap_or(*b);
            let x = [p[0] + o[0], p[1] + o[1], p[2] + o[2]];
            let d = [geometry.anchors[j][0] - x[0], geometry.anchors[j][1] - x[1], geometry.anchors[j][2] - x[2]];
            let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let uj = [d[0] / rho, d[1] / rho, d[2] / rho];
            u.push(uj);
            v.push(-(uj[0] * vel[0] + uj[1] * vel[1] + uj[2] * vel[2]));
        }
        let var_a = wa.iter().map(|w| w * w).sum::<f64>() * opts.tracker_sigma_m.powi(2);
        raw_of[i] = raw.len();
        raw.push(BalanceRow { t: rec.t[i], a, var_a, u, f: f[i * n..(i + 1) * n].to_vec(), v });
        if i % stride == 0 && ks.iter().all(|&k| taut(k)) {
            windows.push((i, ks, wa));
        }
    }
    let mut win = vec![];
    let mut centers = vec![];
    for (i, ks, wa) in windows {
        // Every row of the window must have its own derivatives (its own window inside the
        // segment) to be a balance row.
        if ks.iter().any(|&k| raw_of[k] == usize::MAX) {
            continue;
        }
        let t: Vec<f64> = ks.iter().map(|&k| rec.t[k]).collect();
        let kappa = kernel_weights(&t, &wa);
        let s2 = kappa.iter().map(|k| k * k).sum();
        win.push(Window { center: raw_of[i], w: ks.iter().zip(kappa).map(|(&k, c)| (raw_of[k], c)).collect(), s2 });
        centers.push(i);
    }
    if win.len() < MIN_ROWS {
        return None;
    }
    // The length side's time blocks (10 over the recording's rows), `round(10 heldout_fraction)`
    // held out at a time, spread over the recording; every fold is held out once.
    let nb = 10;
    let k_out = ((opts.heldout_fraction * nb as f64).round() as usize).clamp(1, nb - 1);
    let folds = (nb / k_out).max(2);
    let fold = centers.iter().map(|&i| (i * nb / m.max(1)).min(nb - 1) % folds).collect();
    Some(Data { raw, win, fold, folds })
}

/// The balance model: offsets and the named tension effects, in that parameter order.
#[derive(Debug, Clone)]
struct Spec {
    n: usize,
    mass: f64,
    effects: Vec<TensionEffect>,
}

impl Spec {
    fn width(&self) -> usize {
        self.n + self.effects.iter().map(|e| e.width(self.n)).sum::<usize>()
    }

    /// Offset of effect `k`'s parameters.
    fn offset(&self, k: usize) -> usize {
        self.n + self.effects[..k].iter().map(|e| e.width(self.n)).sum::<usize>()
    }

    fn start(&self, prev: Option<(&Spec, &[f64])>) -> Vec<f64> {
        let mut x = vec![0.0; self.width()];
        for (k, e) in self.effects.iter().enumerate() {
            let o = self.offset(k);
            x[o..o + e.width(self.n)].fill(e.model().start());
        }
        if let Some((ps, px)) = prev {
            x[..self.n].copy_from_slice(&px[..self.n]);
            for (k, e) in ps.effects.iter().enumerate() {
                if let Some(k2) = self.effects.iter().position(|x| x == e) {
                    let w = e.width(self.n);
                    let (o1, o2) = (ps.offset(k), self.offset(k2));
                    x[o2..o2 + w].copy_from_slice(&px[o1..o1 + w]);
                }
            }
        }
        x
    }

    /// The filtered balance residual of window `wi`, N, its derivatives by every parameter (into
    /// `jac`), and the inertial mass in the model (0 without inertia; it enters the weights).
    fn residual_jac(&self, x: &[f64], data: &Data, wi: usize, mut jac: Option<&mut Vec<[f64; 3]>>) -> ([f64; 3], f64) {
        let n = self.n;
        let win = &data.win[wi];
        if let Some(jac) = jac.as_deref_mut() {
            jac.clear();
            jac.resize(self.width(), [0.0; 3]);
        }
        let mut r = [0.0; 3];
        let mut ksum = 0.0;
        let mut lambda = vec![0.0; n];
        let mut parts: Vec<(usize, usize, f64)> = vec![];
        for &(k, c) in &win.w {
            let row = &data.raw[k];
            ksum += c;
            lambda.fill(0.0);
            parts.clear();
            for (q, e) in self.effects.iter().enumerate() {
                let m = e.model();
                if m.sharing() == Sharing::Shared {
                    continue;
                }
                let o = self.offset(q);
                for (j, l) in lambda.iter_mut().enumerate() {
                    if let Term::CellLogFactor { value, d } = m.term(x[o + j], row, j) {
                        *l += value;
                        parts.push((o + j, j, d));
                    }
                }
            }
            for j in 0..n {
                let g = (-lambda[j]).exp();
                let t = (row.f[j] - x[j]) * g;
                for ax in 0..3 {
                    r[ax] += c * t * row.u[j][ax];
                }
                if let Some(jac) = jac.as_deref_mut() {
                    for ax in 0..3 {
                        jac[j][ax] -= c * g * row.u[j][ax];
                    }
                }
                lambda[j] = t;
            }
            if let Some(jac) = jac.as_deref_mut() {
                for &(q, j, d) in &parts {
                    for ax in 0..3 {
                        jac[q][ax] -= c * lambda[j] * d * row.u[j][ax];
                    }
                }
            }
        }
        r[2] -= ksum * self.mass * G;
        let center = &data.raw[win.center];
        let mut mi = 0.0;
        for (q, e) in self.effects.iter().enumerate() {
            let m = e.model();
            if m.sharing() != Sharing::Shared {
                continue;
            }
            let o = self.offset(q);
            if let Term::PlatformForce { value, d } = m.term(x[o], center, 0) {
                for ax in 0..3 {
                    r[ax] -= value[ax];
                }
                if let Some(jac) = jac.as_deref_mut() {
                    for ax in 0..3 {
                        jac[o][ax] -= d[ax];
                    }
                }
                if *e == TensionEffect::Inertia {
                    mi = x[o];
                }
            }
        }
        (r, mi)
    }

    /// The filtered balance residual of window `wi`, N.
    fn residual(&self, x: &[f64], data: &Data, wi: usize) -> [f64; 3] {
        self.residual_jac(x, data, wi, None).0
    }

    /// Lower Cholesky factor of window `wi`'s residual covariance with inertial mass `mi`: the
    /// cells' noise along the cables through the filter (the centre's directions; the readings'
    /// scale, a gain of a few percent changes the weights by as much) and the acceleration's
    /// noise times `mi`.
    fn chol(&self, mi: f64, data: &Data, wi: usize, sigma_t: f64) -> [[f64; 3]; 3] {
        let win = &data.win[wi];
        let row = &data.raw[win.center];
        let mut c = [[0.0; 3]; 3];
        let s2 = sigma_t * sigma_t * win.s2;
        for j in 0..self.n {
            for a in 0..3 {
                for b in 0..3 {
                    c[a][b] += s2 * row.u[j][a] * row.u[j][b];
                }
            }
        }
        let extra = mi * mi * row.var_a + 1e-9 * s2;
        for (a, ca) in c.iter_mut().enumerate() {
            ca[a] += extra;
        }
        chol3(&c)
    }

    /// Index of the inertial mass among the parameters.
    fn inertia_index(&self) -> Option<usize> {
        self.effects.iter().position(|e| *e == TensionEffect::Inertia).map(|k| self.offset(k))
    }

    /// The whitened residual (`L^-1 r`, the whitening at the parameters' own inertial mass).
    fn whitened(&self, x: &[f64], data: &Data, wi: usize, sigma_t: f64) -> [f64; 3] {
        let (r, mi) = self.residual_jac(x, data, wi, None);
        solve_lower(&self.chol(mi, data, wi, sigma_t), r)
    }
}

fn chol3(c: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let s = c[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            l[i][j] = if i == j { s.max(1e-300).sqrt() } else { s / l[j][j] };
        }
    }
    l
}

fn solve_lower(l: &[[f64; 3]; 3], r: [f64; 3]) -> [f64; 3] {
    let y0 = r[0] / l[0][0];
    let y1 = (r[1] - l[1][0] * y0) / l[1][1];
    let y2 = (r[2] - l[2][0] * y0 - l[2][1] * y1) / l[2][2];
    [y0, y1, y2]
}

/// The least-squares problem of a [`Spec`] on some rows: whitened residuals, the whitening
/// evaluated at the parameters themselves (the errors-in-variables cost), derivatives by
/// central differences.
struct Balance<'a> {
    spec: &'a Spec,
    data: &'a Data,
    sel: &'a [usize],
    sigma_t: f64,
}

impl Balance<'_> {
    /// Whitened residual and its Jacobian rows (3 x p) at row `i`: analytic through the
    /// residual, plus the whitening's own derivative by the inertial mass (central difference).
    fn row_jacobian(&self, x: &[f64], i: usize) -> ([f64; 3], Vec<[f64; 3]>) {
        let mut jac = Vec::with_capacity(x.len());
        let (r, mi) = self.spec.residual_jac(x, self.data, i, Some(&mut jac));
        let l = self.spec.chol(mi, self.data, i, self.sigma_t);
        let e = solve_lower(&l, r);
        for d in jac.iter_mut() {
            *d = solve_lower(&l, *d);
        }
        if let Some(q) = self.spec.inertia_index() {
            let h = 1e-6 * mi.abs().max(1.0);
            let (lp, lm) =
                (self.spec.chol(mi + h, self.data, i, self.sigma_t), self.spec.chol((mi - h).max(0.0), self.data, i, self.sigma_t));
            let (ep, em) = (solve_lower(&lp, r), solve_lower(&lm, r));
            let span = mi + h - (mi - h).max(0.0);
            for a in 0..3 {
                jac[q][a] += (ep[a] - em[a]) / span;
            }
        }
        (e, jac)
    }
}

impl lm::LeastSquares for Balance<'_> {
    fn n_params(&self) -> usize {
        self.spec.width()
    }
    fn rows(&self, x: &[f64], jacobian: bool, visit: &mut lm::RowVisitor<'_>) {
        let mut buf: Vec<(usize, f64)> = Vec::with_capacity(x.len());
        for &i in self.sel {
            if jacobian {
                let (e, jac) = self.row_jacobian(x, i);
                for a in 0..3 {
                    buf.clear();
                    buf.extend(jac.iter().enumerate().map(|(k, d)| (k, d[a])));
                    visit(e[a], &buf);
                }
            } else {
                for v in self.spec.whitened(x, self.data, i, self.sigma_t) {
                    visit(v, &[]);
                }
            }
        }
    }
    fn project(&self, x: &mut [f64]) {
        for (k, e) in self.spec.effects.iter().enumerate() {
            let (lo, hi) = e.model().bounds();
            let o = self.spec.offset(k);
            for v in &mut x[o..o + e.width(self.spec.n)] {
                *v = v.clamp(lo, hi);
            }
        }
    }
}

fn fit(spec: &Spec, data: &Data, sel: &[usize], sigma_t: f64, x0: &[f64]) -> lm::LmReport {
    let p = Balance { spec, data, sel, sigma_t };
    lm::minimize(&p, x0, lm::LmOptions { max_iterations: 40, cost_tolerance: 1e-10 })
}

/// RMS per axis of the balance residual, N.
fn rms_n(spec: &Spec, x: &[f64], data: &Data, sel: &[usize]) -> f64 {
    let ss: f64 = sel.iter().map(|&i| spec.residual(x, data, i).iter().map(|v| v * v).sum::<f64>()).sum();
    (ss / (3 * sel.len()).max(1) as f64).sqrt()
}

/// Per-parameter sigmas: the least-squares sigma (reduced chi-square) widened by the batch
/// means of the parameters' influence over contiguous clusters of `sel` (never narrower).
fn sigmas(spec: &Spec, data: &Data, sel: &[usize], sigma_t: f64, r: &lm::LmReport) -> Vec<f64> {
    let np = r.x.len();
    let naive = r.sigmas();
    let Some(hinv) = r.inv_normal.as_ref() else { return naive };
    let p = Balance { spec, data, sel, sigma_t };
    let m = sel.len();
    let mut g = vec![vec![0.0; np]; CLUSTERS];
    for (idx, &i) in sel.iter().enumerate() {
        let (e, jac) = p.row_jacobian(&r.x, i);
        let b = idx * CLUSTERS / m.max(1);
        for (k, d) in jac.iter().enumerate() {
            g[b][k] += (0..3).map(|a| d[a] * e[a]).sum::<f64>();
        }
    }
    let bf = CLUSTERS as f64;
    (0..np)
        .map(|k| {
            let z: Vec<f64> = g.iter().map(|gb| (0..np).map(|a| hinv[(k, a)] * gb[a]).sum::<f64>()).collect();
            let mean = z.iter().sum::<f64>() / bf;
            let var = bf / (bf - 1.0) * z.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>();
            if var.is_finite() {
                naive[k].max(var.sqrt())
            } else {
                naive[k]
            }
        })
        .collect()
}

/// One fold's share of the held-out test: the current model's whitened held-out residuals
/// `r0`, the candidate's `r1` (per window, three each), and the standard deviation of
/// `sum r0 delta` that the current model's estimation error on the fold's training windows adds
/// (sandwich over clusters of them), with its degrees of freedom.
struct FoldPiece {
    held: Vec<usize>,
    r0: Vec<f64>,
    r1: Vec<f64>,
    est: Option<(f64, f64)>,
}

#[allow(clippy::too_many_arguments)]
fn fold_piece(
    cur: &Spec,
    x0: &lm::LmReport,
    cand: &Spec,
    x1: &[f64],
    data: &Data,
    train: &[usize],
    held: &[usize],
    sigma_t: f64,
) -> FoldPiece {
    let (mut r0, mut r1) = (Vec::with_capacity(3 * held.len()), Vec::with_capacity(3 * held.len()));
    let x0v = &x0.x;
    for &i in held {
        let (r, mi) = cur.residual_jac(x0v, data, i, None);
        let l = cur.chol(mi, data, i, sigma_t);
        let e0 = solve_lower(&l, r);
        let c1 = cand.residual(x1, data, i);
        let d = solve_lower(&l, [r[0] - c1[0], r[1] - c1[1], r[2] - c1[2]]);
        for a in 0..3 {
            r0.push(e0[a]);
            r1.push(e0[a] - d[a]);
        }
    }
    // c = J_h^T delta over the held-out windows, cov(x0) = H^-1 (sum_b s_b s_b^T) H^-1.
    let est = x0.inv_normal.as_ref().and_then(|hinv| {
        let np = x0v.len();
        let p0 = Balance { spec: cur, data, sel: held, sigma_t };
        let mut c = DVector::<f64>::zeros(np);
        for (q, &i) in held.iter().enumerate() {
            let (_, jac) = p0.row_jacobian(x0v, i);
            for (k, dk) in jac.iter().enumerate() {
                for a in 0..3 {
                    c[k] += dk[a] * (r0[3 * q + a] - r1[3 * q + a]);
                }
            }
        }
        let pt = Balance { spec: cur, data, sel: train, sigma_t };
        let mut s = vec![DVector::<f64>::zeros(np); CLUSTERS];
        for (idx, &i) in train.iter().enumerate() {
            let (e, jac) = pt.row_jacobian(x0v, i);
            let b = idx * CLUSTERS / train.len().max(1);
            for (k, dk) in jac.iter().enumerate() {
                s[b][k] += (0..3).map(|a| dk[a] * e[a]).sum::<f64>();
            }
        }
        let hc = hinv * &c;
        let var: f64 = s.iter().map(|sb| hc.dot(sb).powi(2)).sum();
        let dof = (CLUSTERS as f64 - np as f64).max(1.0);
        (var.is_finite() && var > 0.0).then_some((var.sqrt(), dof))
    });
    FoldPiece { held: held.to_vec(), r0, r1, est }
}

/// The held-out test over every fold: the folds' held-out residuals in time order, one score
/// term per window. The folds' estimation errors come from overlapping training sets, so their
/// standard deviations are added as if perfectly correlated (an upper bound of the variance of
/// their sum), with the smallest of their degrees of freedom.
fn crossfit_test(pieces: &[FoldPiece]) -> Option<HeldoutTest> {
    let mut order: Vec<(usize, usize, usize)> = vec![];
    for (f, p) in pieces.iter().enumerate() {
        for (q, &i) in p.held.iter().enumerate() {
            order.push((i, f, q));
        }
    }
    order.sort_unstable();
    let (mut r0, mut r1, mut starts) = (vec![], vec![], vec![0]);
    for (_, f, q) in order {
        r0.extend_from_slice(&pieces[f].r0[3 * q..3 * q + 3]);
        r1.extend_from_slice(&pieces[f].r1[3 * q..3 * q + 3]);
        starts.push(r0.len());
    }
    let sd: f64 = pieces.iter().filter_map(|p| p.est.map(|e| e.0)).sum();
    let dof = pieces.iter().filter_map(|p| p.est.map(|e| e.1)).fold(f64::INFINITY, f64::min);
    let est = (sd > 0.0 && dof.is_finite()).then_some((sd * sd, dof));
    select::encompassing_test_with(&r0, &r1, &starts, select::BATCHES, est)
}

/// The load cells' noise from the baseline's residuals: `s_T^2 = chi^2 / dof` with unit cell
/// noise.
fn estimate_sigma(spec: &Spec, data: &Data, sel: &[usize], x: &[f64]) -> f64 {
    let ss: f64 = sel.iter().map(|&i| spec.whitened(x, data, i, 1.0).iter().map(|v| v * v).sum::<f64>()).sum();
    (ss / (3 * sel.len()).saturating_sub(x.len()).max(1) as f64).sqrt()
}

/// The leads of the baseline: each cable's residual against its level, direction and speed, and
/// the platform's against its acceleration; strongest first.
fn locate(spec: &Spec, x: &[f64], data: &Data, sel: &[usize], sigma_t: f64) -> Vec<TensionLead> {
    let n = spec.n;
    let mut leads = vec![];
    let e: Vec<[f64; 3]> = sel.iter().map(|&i| spec.whitened(x, data, i, sigma_t)).collect();
    let ls: Vec<[[f64; 3]; 3]> = sel.iter().map(|&i| spec.chol(0.0, data, i, sigma_t)).collect();
    // A per-row regressor filtered as the balance is (`platform`: the centre's value alone).
    let filtered = |i: usize, reg: &dyn Fn(&BalanceRow) -> [f64; 3], platform: bool| -> [f64; 3] {
        let w = &data.win[i];
        if platform {
            return reg(&data.raw[w.center]);
        }
        let mut out = [0.0; 3];
        for &(k, c) in &w.w {
            let v = reg(&data.raw[k]);
            for a in 0..3 {
                out[a] += c * v[a];
            }
        }
        out
    };
    let mut one = |cable: Option<usize>, follows: LeadKind, reg: &dyn Fn(&BalanceRow) -> [f64; 3]| {
        let d: Vec<[f64; 3]> = sel.iter().zip(&ls).map(|(&i, l)| solve_lower(l, filtered(i, reg, cable.is_none()))).collect();
        let dd: f64 = d.iter().map(|v| v.iter().map(|a| a * a).sum::<f64>()).sum();
        if dd <= 0.0 {
            return;
        }
        let ed: f64 = e.iter().zip(&d).map(|(a, b)| (0..3).map(|k| a[k] * b[k]).sum::<f64>()).sum();
        let c = ed / dd;
        let u: Vec<f64> = e.iter().zip(&d).map(|(a, b)| (0..3).map(|k| (a[k] - c * b[k]) * b[k]).sum::<f64>()).collect();
        let w: Vec<f64> = d.iter().map(|v| v.iter().map(|a| a * a).sum::<f64>()).collect();
        let (var, _) = select::long_run_variance(&u, &w, select::BATCHES.min(u.len() / 4).max(3));
        if var > 0.0 {
            leads.push(TensionLead { cable, follows, coefficient: c, t: c * dd / var.sqrt() });
        }
    };
    for j in 0..n {
        let t = |r: &BalanceRow| r.f[j] - x[j];
        one(Some(j), LeadKind::Level, &|r| r.u[j].map(|v| t(r) * v));
        one(Some(j), LeadKind::Direction, &|r| r.u[j].map(|v| t(r) * friction::direction(r.v[j]) * v));
        one(Some(j), LeadKind::Speed, &|r| r.u[j].map(|v| t(r) * r.v[j].abs() * v));
    }
    one(None, LeadKind::Acceleration, &|r| r.a);
    leads.sort_by(|a, b| b.t.abs().total_cmp(&a.t.abs()));
    leads
}

/// Physical values of effect `k` of `spec` in `x` with their sigmas.
fn physical(spec: &Spec, k: usize, x: &[f64], s: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let e = spec.effects[k];
    let o = spec.offset(k);
    (o..o + e.width(spec.n)).map(|q| e.model().to_physical(x[q], s.get(q).copied().unwrap_or(f64::NAN))).unzip()
}

/// The tension-side step of the diagnosis: `None` without tensions, a mass, a dead cell, or
/// enough taut rows (a note says which).
pub(crate) fn diagnose_tensions(
    rec: &Recording,
    masks: &DataMasks,
    geometry: &Geometry,
    platform_points: &[[f64; 3]],
    opts: &DiagnoseOptions,
    notes: &mut Vec<String>,
) -> Option<TensionDiagnosis> {
    let mass = opts.platform_mass_kg?;
    rec.f.as_ref()?;
    if masks.dead_loadcell.iter().any(|d| *d) {
        notes.push("tension side not run: a load cell is dead, so the platform's balance cannot be formed".into());
        return None;
    }
    let Some(data) = balance_data(rec, masks, geometry, platform_points, opts) else {
        notes.push(format!(
            "tension side not run: fewer than {MIN_ROWS} windows of {:.2} s with every cable taut and the path's derivatives known",
            2.0 * ACCEL_HALF_WINDOW_S
        ));
        return None;
    };
    let n = rec.n_cables;
    let all: Vec<usize> = (0..data.win.len()).collect();
    let train_of = |f: usize| -> Vec<usize> { all.iter().copied().filter(|&i| data.fold[i] != f).collect() };
    let held_of = |f: usize| -> Vec<usize> { all.iter().copied().filter(|&i| data.fold[i] == f).collect() };
    let folds: Vec<(Vec<usize>, Vec<usize>)> = (0..data.folds).map(|f| (train_of(f), held_of(f))).collect();
    let base = Spec { n, mass, effects: vec![] };
    let x_start = vec![0.0; n];
    let mut own_notes = vec![];
    let (sigma_t, sigma_estimated) = if opts.loadcell_sigma_n > 0.0 {
        (opts.loadcell_sigma_n, false)
    } else {
        let r = fit(&base, &data, &all, 1.0, &x_start);
        let s = estimate_sigma(&base, &data, &all, &r.x);
        own_notes.push(format!(
            "no load-cell noise was given (`[calibration] loadcell_sigma_n`): {s:.3} N per reading was estimated from the statics residual, so any departure counts as noise in the weights"
        ));
        (s, true)
    };
    let alpha = opts.test_alpha();
    let base_all = fit(&base, &data, &all, sigma_t, &x_start);
    let leads = locate(&base, &base_all.x, &data, &all, sigma_t);
    let cur: Vec<lm::LmReport> = folds.iter().map(|(tr, _)| fit(&base, &data, tr, sigma_t, &base_all.x)).collect();
    // RMS on the training windows of the first fold's split and on its held-out ones (the
    // length side's split when 20 % are held out).
    let (train0, held0) = (&folds[folds.len() - 1].0, &folds[folds.len() - 1].1);
    let (rms_before, held_before) =
        (rms_n(&base, &cur[folds.len() - 1].x, &data, train0), rms_n(&base, &cur[folds.len() - 1].x, &data, held0));

    // Backward elimination from the whole library: each effect's removal test (the model
    // without it as the current model, it as the candidate); the least needed effect whose test
    // is not significant at `alpha` (or whose value is not physical) is dropped, and the rest
    // are tested again.
    let library: Vec<TensionEffect> = opts.tension_library.clone();
    let mut spec = Spec { n, mass, effects: library.clone() };
    let mut full: Vec<lm::LmReport> =
        folds.iter().zip(&cur).map(|((tr, _), c)| fit(&spec, &data, tr, sigma_t, &spec.start(Some((&base, &c.x))))).collect();
    let mut tests = vec![];
    let mut last: Vec<(TensionEffect, Option<HeldoutTest>)> = vec![];
    for round in 1..=library.len() {
        let mut results = vec![];
        for (k, &e) in spec.effects.iter().enumerate() {
            let reduced = Spec { n, mass, effects: spec.effects.iter().copied().filter(|x| *x != e).collect() };
            let fits: Vec<lm::LmReport> = folds
                .iter()
                .zip(&full)
                .map(|((tr, _), c)| fit(&reduced, &data, tr, sigma_t, &reduced.start(Some((&spec, &c.x)))))
                .collect();
            let pieces: Vec<FoldPiece> = folds
                .iter()
                .zip(fits.iter().zip(&full))
                .map(|((tr, he), (c, r1))| fold_piece(&reduced, c, &spec, &r1.x, &data, tr, he, sigma_t))
                .collect();
            let test = crossfit_test(&pieces);
            let o = spec.offset(k);
            let (plo, phi) = e.model().internal_range();
            let physical_ok = full.iter().all(|r1| r1.x[o..o + e.width(n)].iter().all(|v| (plo..=phi).contains(v)));
            let passed = test.is_some_and(|t| t.p_value < alpha);
            let values = physical(&spec, k, &full[full.len() - 1].x, &[]).0;
            results.push((e, reduced, fits, test, passed && physical_ok, values));
        }
        // The effect to drop: the least significant of those not kept.
        let drop = results
            .iter()
            .enumerate()
            .filter(|(_, r)| !r.4)
            .max_by(|a, b| a.1 .3.map_or(1.0, |t| t.p_value).total_cmp(&b.1 .3.map_or(1.0, |t| t.p_value)))
            .map(|(q, _)| q);
        for (q, r) in results.iter().enumerate() {
            let decision = if Some(q) == drop {
                Decision::Dropped
            } else if r.4 {
                Decision::Kept
            } else {
                Decision::NotBetter
            };
            tests.push(TensionTest { round, effect: r.0, test: r.3, alpha, decision, values: r.5.clone() });
        }
        last = results.iter().map(|r| (r.0, r.3)).collect();
        let Some(q) = drop else { break };
        let (_, reduced, fits, _, _, _) = results.swap_remove(q);
        last.remove(q);
        spec = reduced;
        full = fits;
        if spec.effects.is_empty() {
            break;
        }
    }
    let named: Vec<(TensionEffect, HeldoutTest)> =
        spec.effects.iter().map(|e| (*e, last.iter().find(|x| x.0 == *e).and_then(|x| x.1).expect("a kept effect was tested"))).collect();
    let cur = full;
    let (train, held) = (train0.clone(), held0.clone());

    // Final estimates on every row, the noise re-estimated when none was given.
    let mut x = spec.start(Some((&spec, &cur[cur.len() - 1].x)));
    let mut final_fit = fit(&spec, &data, &all, sigma_t, &x);
    let sigma_t = if sigma_estimated && !spec.effects.is_empty() {
        let s = refit_sigma(&spec, &data, &all, &final_fit.x, sigma_t);
        x.clone_from(&final_fit.x);
        final_fit = fit(&spec, &data, &all, s, &x);
        s
    } else {
        sigma_t
    };
    let s = sigmas(&spec, &data, &all, sigma_t, &final_fit);
    let mut effects = vec![];
    for (k, (e, test)) in named.into_iter().enumerate() {
        let (values, sig) = physical(&spec, k, &final_fit.x, &s);
        let mut evidence = format!(
            "the balance residual follows {}; held-out test {test}; {} = {}",
            e.model().signature(),
            e.model().parameter(),
            values.iter().zip(&sig).map(|(v, s)| format!("{v:.4} ± {s:.4}")).collect::<Vec<_>>().join(", ")
        );
        if e == TensionEffect::Inertia {
            evidence.push_str(&format!(" (the platform's mass is {mass} kg)"));
        }
        let mimics: Vec<String> = e.model().mimics().iter().map(|(w, how)| format!("{w}: {how}")).collect();
        evidence.push_str(&format!("; can be mimicked by {}", mimics.join("; ")));
        effects.push(TensionFinding { effect: e, values, sigmas: sig, test, evidence });
    }
    if effects.is_empty() {
        own_notes.push("tension side: the load cells balance the platform's weight within their noise (offsets only)".into());
    }
    notes.extend(own_notes.iter().cloned());
    let xr = &final_fit.x;
    Some(TensionDiagnosis {
        rows: data.win.len(),
        mass_kg: mass,
        loadcell_sigma_n: sigma_t,
        sigma_estimated,
        accel_window_s: ACCEL_HALF_WINDOW_S.max(3.5 * masks.dt),
        offsets_n: xr[..n].to_vec(),
        offset_sigmas_n: s[..n].to_vec(),
        rms_before_n: rms_before,
        heldout_rms_before_n: held_before,
        rms_after_n: rms_n(&spec, &cur[cur.len() - 1].x, &data, &train),
        heldout_rms_after_n: rms_n(&spec, &cur[cur.len() - 1].x, &data, &held),
        leads,
        effects,
        tests,
        notes: own_notes,
    })
}

/// The cells' noise `s` that makes the final model's chi-square per degree of freedom 1 (the
/// acceleration's noise in the weights is known from the tracker's; only `s` is solved for).
fn refit_sigma(spec: &Spec, data: &Data, sel: &[usize], x: &[f64], start: f64) -> f64 {
    let dof = (3 * sel.len()).saturating_sub(x.len()).max(1) as f64;
    let chi = |s: f64| sel.iter().map(|&i| spec.whitened(x, data, i, s).iter().map(|v| v * v).sum::<f64>()).sum::<f64>() / dof;
    let (mut lo, mut hi) = (start * 1e-3, start * 10.0);
    for _ in 0..60 {
        let mid = (lo * hi).sqrt();
        if chi(mid) > 1.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo * hi).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Peano kernel of the local quadratic's acceleration, applied to the true acceleration
    /// on irregular sample times, gives the estimator's acceleration (its smoothing bias is on
    /// both sides), while the estimate itself is biased against the true value at the centre.
    #[test]
    fn kernel_filters_the_acceleration_as_the_estimator_smooths_it() {
        let mut rec = Recording::with_capacity(1, 200, false, false, false);
        let pos = |t: f64| [(6.0 * t).sin(), (2.0 * t).cos(), t * t * t];
        let acc = |t: f64| [-36.0 * (6.0 * t).sin(), -4.0 * (2.0 * t).cos(), 6.0 * t];
        for k in 0..200 {
            let t = k as f64 * 0.01 + 0.003 * ((k * 7919) % 13) as f64 / 13.0;
            rec.push(t, pos(t), None, &[1.0], None, None);
        }
        let i = 100;
        let h = 0.25;
        let ks: Vec<usize> = (0..200).filter(|&k| (rec.t[k] - rec.t[i]).abs() <= h).collect();
        let lp = local_path(&rec, i, &ks, h).expect("fit");
        let t: Vec<f64> = ks.iter().map(|&k| rec.t[k]).collect();
        let kappa = kernel_weights(&t, &lp.w);
        assert!((kappa.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        for ax in 0..3 {
            let filtered: f64 = ks.iter().zip(&kappa).map(|(&k, c)| c * acc(rec.t[k])[ax]).sum();
            let scale = acc(rec.t[i])[ax].abs().max(1.0);
            assert!((filtered - lp.a[ax]).abs() < 2e-3 * scale, "axis {ax}: filtered {filtered} vs estimate {}", lp.a[ax]);
        }
        // The estimate alone is ~16 % low on the 1 Hz axis ((omega h)^2 / 14).
        assert!((lp.a[0] - acc(rec.t[i])[0]).abs() > 0.05 * acc(rec.t[i])[0].abs());
    }
}
