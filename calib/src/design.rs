//! The start-up excitation designed from the nominal geometry for what the calibration must
//! observe: a tour of the workspace box's corners, chosen to minimise the predicted anchor
//! uncertainty under the speed, acceleration, tension and workspace limits.
//!
//! # Prediction (the calibration's Fisher information at the nominal geometry)
//!
//! The start-up calibration refines all cables at once with the platform positions as unknowns
//! ([`crate::bundle`]): per tracker sample `i`, the lengths `l_ij = |p_i + b_j - A_j| + L0_j + e`
//! (`e ~ N(0, s_l^2)`) and the tracker reading `P_i = p_i + t` (`t ~ N(0, s_t^2 I)`). With
//! `J_x` (n x 4n: `-e_ij` for `A_j`, 1 for `L0_j`) and `J_p` (n x 3: the unit vectors `e_ij`
//! from the anchors to the platform), eliminating `p_i` (Schur complement) gives each sample's
//! information on the parameters `x = (A_j, L0_j)_j`:
//!
//! ```text
//! I_i = J_x^T W_i J_x,   W_i = R^-1 - R^-1 J_p (J_p^T R^-1 J_p + I / s_t^2)^-1 J_p^T R^-1,   R = s_l^2 I
//! Cov(x) >= (sum_i I_i)^-1                                  (Cramer-Rao)
//! ```
//!
//! summed over the samples the calibration will use (tracker rate x duration x training
//! fraction). The criterion is the worst anchor's 1-sigma (the root of the trace of its 3x3
//! block): the acceptance is a worst-anchor error.
//!
//! # Why the box's extremes, and why a tour
//!
//! An anchor is seen along the directions `e_ij`; its component along the mean direction (traded
//! against `L0_j`) is determined only by the *second-order* spread of those directions, which is
//! largest at the box's extremes. Time spent near the corners buys the most information; the
//! speed limit decides how many fit. Measured on the ARAS-CAM-like robot (30 s, 0.4 m/s):
//! today's Lissajous (80 % amplitudes, incommensurate frequencies, under one period in 30 s)
//! predicts a 2.7 mm worst-anchor sigma, the best commensurate Lissajous 2.2 mm, a corner tour
//! 1.2 mm.
//!
//! # Search
//!
//! Candidate waypoints are the points of a 4 x 4 x 4 grid over the box shrunk by a margin where
//! the platform can rest with every position-controlled cable within `[min, max]` tension (the
//! followers at their torque tension). Each straight move is driven with a trapezoidal speed
//! profile (speed `v`, acceleration `a`, rest at each waypoint); a move along which a cable
//! would leave its limits (statics plus the profile's +-a along the move) is not used. The
//! information of every move is computed once. The search is a steepest descent over closed
//! tours (moves: insert a waypoint, replace one, remove one, reverse a stretch), scored by the
//! worst-anchor sigma of the loop's information times the loops that fit in the excitation,
//! started from the 12 best two-waypoint loops; the local optima are ranked by the exact
//! prediction at their worst join ([`predict_tour`]).
//!
//! The tour is *closed within the excitation*: its loop (the return to the first waypoint
//! included, which must be feasible too) fits in `duration_s`, so wherever the loop joins it
//! (at the waypoint nearest the platform) every move is driven. The calibration holds out the
//! ends of [`DesignInput::heldout_blocks`] time blocks, so training and held-out rows both lie
//! along the whole path, and the prediction counts exactly the training rows
//! ([`training_rows`]).
//!
//! # What decides the result
//!
//! ARAS-CAM-like robot (config/examples/aras-cam-sim.toml: 30 s, 80 % for training, tracker
//! 1.5 mm at 100 Hz, encoders 0.05 mm, follower at 10 N, 3 N least tension, 0.8 m/s, 1 m/s^2;
//! `cargo run --release -p taut-calib --example design_study [knobs|tensions|paths]`):
//! - The waypoints. A beam search over the 8 corners finds 0.44 mm: with
//!   cable 3 following at 10 N, three of the corners (the two on cable 3's side, and the low one
//!   beside it at 2.1 N) cannot be rested at, and the long moves between the remaining ones
//!   left 7 corner visits in 30 s. The grid's waypoints near the infeasible corners and inside
//!   the faces give 0.275 mm (3 x 3 x 3 grid: 0.325 mm; 6 x 6 x 6: 0.268 mm).
//! - The tension limits: without them 0.207 mm (the best spread of 2,400 samples over the
//!   feasible 9 x 9 x 9 grid points, travel ignored: 0.221 mm; over all of them 0.176 mm). A
//!   larger acceleration makes more moves infeasible (2 m/s^2: 0.35 mm), a follower at 20 N or
//!   5 N moves the feasible region (0.31, 0.30 mm).
//! - The samples: 60 s 0.198 mm, the tracker at 200 Hz 0.203 mm, all rows for training (no
//!   held-out rows) 0.242 mm. The speed no longer (1 m/s: 0.271 mm; 0.6 m/s 0.363 mm).
//!
//! The result is a [`Tour`]: fixed-size, `Copy`, evaluated by [`Tour::point`] without
//! allocation, so the real-time loop can run it.

use nalgebra::{DMatrix, Matrix3, Vector3};
use std::fmt;

pub use taut_model::tour::{segment_distance, segment_time, Tour, MAX_WAYPOINTS};

/// What the design needs to know.
#[derive(Debug, Clone)]
pub struct DesignInput {
    /// Nominal anchors, m.
    pub anchors: Vec<[f64; 3]>,
    /// Platform attachment points, m (platform frame, no rotation).
    pub platform: Vec<[f64; 3]>,
    /// Workspace box `[min, max]`, m.
    pub workspace: [[f64; 3]; 2],
    /// Distance the waypoints keep from the box's faces, m.
    pub margin_m: f64,
    /// Largest platform speed, m/s.
    pub speed_m_s: f64,
    /// Acceleration of the speed profile, m/s^2.
    pub accel_m_s2: f64,
    /// Duration of the excitation, s.
    pub duration_s: f64,
    /// Tracker samples per second the calibration receives.
    pub sample_hz: f64,
    /// Fraction of the samples the calibration fits (the rest is held out).
    pub used_fraction: f64,
    /// The held-out rows are the last `1 - used_fraction` of each of this many consecutive time
    /// blocks of the excitation (the daemon's `calibrator::HeldoutBlocks`); 1: its last part.
    pub heldout_blocks: usize,
    /// Tracker noise, 1-sigma per axis, m.
    pub tracker_sigma_m: f64,
    /// Length noise of the calibration's model (encoder plus model error), 1-sigma, m.
    pub length_sigma_m: f64,
    /// Platform mass, kg (0: no tension check).
    pub mass_kg: f64,
    /// Cables in torque mode (their tension is `follower_tension_n`).
    pub follower: Vec<bool>,
    /// Torque-mode tension of the followers, N.
    pub follower_tension_n: f64,
    /// Least tension of a position-controlled cable, N.
    pub min_tension_n: f64,
    /// Largest tension, N.
    pub max_tension_n: f64,
}

/// Predicted uncertainty of the calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// Per cable, the anchor's 1-sigma per axis, m.
    pub anchor_sigma: Vec<[f64; 3]>,
    /// Per cable, the offset's 1-sigma, m.
    pub l0_sigma: Vec<f64>,
    /// Samples the prediction counts.
    pub samples: usize,
    /// Covariance of the anchors' coordinates (`3n x 3n`, anchor `j`'s x, y, z at `3j..3j + 3`,
    /// row-major), m^2.
    pub anchor_cov_m2: Vec<f64>,
}

impl Prediction {
    /// The worst anchor's 1-sigma (root of the sum of its three variances), m.
    pub fn worst_anchor_sigma_m(&self) -> f64 {
        self.anchor_sigma.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).fold(0.0, f64::max)
    }

    /// Upper bound on P(the largest anchor error exceeds `limit_m`) for anchor errors Gaussian
    /// with this covariance times `scale^2`: the sum over anchors of P(|e_j| > limit) (union
    /// bound; the anchors' errors are nearly independent, so it is close), each computed by
    /// quadrature ([`norm_exceeds`]). Deterministic; 1 when there is no covariance.
    pub fn worst_exceeds_bound(&self, limit_m: f64, scale: f64) -> f64 {
        let k = self.anchor_sigma.len() * 3;
        if self.anchor_cov_m2.len() != k * k {
            return 1.0;
        }
        let p: f64 = (0..k / 3)
            .map(|j| {
                let block = Matrix3::from_fn(|r, c| self.anchor_cov_m2[(3 * j + r) * k + 3 * j + c] * scale * scale);
                let lam = block.symmetric_eigenvalues();
                norm_exceeds([lam[0], lam[1], lam[2]], limit_m)
            })
            .sum();
        p.min(1.0)
    }

    /// P(the largest anchor error exceeds `limit_m`) for anchor errors Gaussian with this
    /// covariance times `scale^2`: Monte Carlo over `draws` draws of a fixed generator (the same
    /// numbers on every call). Returns the estimate and its 99.9 % upper bound (normal
    /// approximation plus `10 / draws` for the rare-event end).
    pub fn worst_exceeds_probability(&self, limit_m: f64, scale: f64, draws: usize) -> (f64, f64) {
        let k = self.anchor_sigma.len() * 3;
        let limit2 = limit_m * limit_m;
        crate::mc::gaussian_exceeds(&self.anchor_cov_m2, k, scale, draws, 0x5eed_de51, |e| {
            (0..k / 3).any(|j| e[3 * j] * e[3 * j] + e[3 * j + 1] * e[3 * j + 1] + e[3 * j + 2] * e[3 * j + 2] > limit2)
        })
    }
}

/// P(|e| > `r`) for a 3-D Gaussian `e` with covariance eigenvalues `lam` (m^2), by quadrature:
/// with `e = (sqrt(l1) z1, sqrt(l2) z2, sqrt(l3) z3)`, conditioned on `z3` the other two give
/// `P(l1 z1^2 + l2 z2^2 > s) = (2 / pi) int_0^{pi/2} exp(-s / (2 q(t))) dt`,
/// `q(t) = l1 cos^2 t + l2 sin^2 t` (polar coordinates: `rho^2 / 2` is exponential), integrated
/// over `z3`'s density (Simpson's rule inside `|z3| < r / sqrt(l3)`, at most 9; beyond, the
/// third axis alone exceeds `r`).
pub fn norm_exceeds(lam: [f64; 3], r: f64) -> f64 {
    let mut l = lam.map(|x| x.max(0.0));
    l.sort_by(f64::total_cmp);
    // Condition on the smallest: the largest stay in the closed form.
    let (l3, l1, l2) = (l[0], l[1], l[2]);
    if l1 + l2 <= 0.0 {
        return if l3 * 81.0 > r * r { 1.0 } else { 0.0 };
    }
    let inner = |s: f64| -> f64 {
        if s <= 0.0 {
            return 1.0;
        }
        let m = 200;
        let h = std::f64::consts::FRAC_PI_2 / m as f64;
        let f = |t: f64| {
            let q = l1 * t.cos().powi(2) + l2 * t.sin().powi(2);
            if q > 0.0 {
                (-s / (2.0 * q)).exp()
            } else {
                0.0
            }
        };
        let mut acc = f(0.0) + f(std::f64::consts::FRAC_PI_2);
        for i in 1..m {
            acc += if i % 2 == 1 { 4.0 } else { 2.0 } * f(i as f64 * h);
        }
        acc * h / 3.0 / std::f64::consts::FRAC_PI_2
    };
    // Beyond |z3| = r / sqrt(l3) the third axis alone exceeds r: there the integrand is the
    // density (exactly 2 P(Z > zk)); inside, it is smooth.
    let zk = if l3 > 0.0 { (r / l3.sqrt()).min(9.0) } else { 9.0 };
    let tail = if l3 > 0.0 && r / l3.sqrt() < 9.0 { 2.0 * crate::screen::normal_sf(zk) } else { 0.0 };
    let m = 400;
    let h = 2.0 * zk / m as f64;
    let g = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt() * inner(r * r - l3 * z * z);
    let mut acc = g(-zk) + g(zk);
    for i in 1..m {
        acc += if i % 2 == 1 { 4.0 } else { 2.0 } * g(-zk + i as f64 * h);
    }
    (acc * h / 3.0 + tail).clamp(0.0, 1.0)
}

/// A designed excitation with its predicted uncertainty.
#[derive(Debug, Clone)]
pub struct Design {
    /// The path.
    pub tour: Tour,
    /// Its predicted uncertainty.
    pub predicted: Prediction,
}

/// Why no excitation could be designed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DesignError {
    /// Fewer than 3 or more than 8 cables, or anchors and platform points of different counts.
    Cables {
        /// Anchors given.
        n: usize,
    },
    /// A limit is not a positive finite number (or the box is empty after the margin).
    Limits,
    /// No pair of the box's grid points can be joined with every position-controlled cable within its tension limits.
    NoFeasibleSegment,
    /// The information matrix is singular along every candidate (the geometry cannot be observed).
    Unobservable,
}

impl fmt::Display for DesignError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DesignError::Cables { n } => write!(f, "the excitation design needs 3 to 8 cables with one platform point each, got {n}"),
            DesignError::Limits => write!(
                f,
                "the excitation design needs a non-empty workspace box (after the margin), a positive speed, \
                 acceleration, duration, tracker rate and noise"
            ),
            DesignError::NoFeasibleSegment => write!(
                f,
                "no straight move between rest points of the workspace box keeps every position-controlled cable \
                 within its tension limits: enlarge [safety] max_tension_n or move the box below the anchors"
            ),
            DesignError::Unobservable => write!(f, "the anchors are not observable along any path in the workspace box"),
        }
    }
}

impl std::error::Error for DesignError {}

/// Information of the samples taken along `points` (see the module documentation), `4n x 4n`:
/// parameters anchor `j` (x, y, z) then its offset at `4j..4j + 4`. Public for tests that need
/// how the information is spread over the path (e.g. the degrees of freedom of a time-block
/// sandwich).
pub fn information<'a>(inp: &DesignInput, points: impl Iterator<Item = &'a [f64; 3]>) -> DMatrix<f64> {
    let n = inp.anchors.len();
    let mut info = DMatrix::<f64>::zeros(4 * n, 4 * n);
    let rl = 1.0 / (inp.length_sigma_m * inp.length_sigma_m);
    let rt = 1.0 / (inp.tracker_sigma_m * inp.tracker_sigma_m);
    let mut e = vec![Vector3::zeros(); n];
    for p in points {
        let mut m = Matrix3::identity() * rt;
        for j in 0..n {
            let a = inp.anchors[j];
            let b = inp.platform[j];
            let d = Vector3::new(p[0] + b[0] - a[0], p[1] + b[1] - a[1], p[2] + b[2] - a[2]);
            e[j] = d / d.norm();
            m += e[j] * e[j].transpose() * rl;
        }
        let Some(mi) = m.try_inverse() else { continue };
        // W = rl I - rl^2 E M^-1 E^T with E the n x 3 stack of e_j^T.
        for j in 0..n {
            for k in 0..n {
                let w = if j == k { rl } else { 0.0 } - rl * rl * (e[j].transpose() * mi * e[k])[0];
                // Rows of J_x: cable j has (-e_j, 1) in its four columns.
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
    info
}

fn prediction(info: &DMatrix<f64>, n: usize, samples: usize) -> Option<Prediction> {
    let cov = info.clone().cholesky()?.inverse();
    let anchor_sigma = (0..n).map(|j| std::array::from_fn(|i| cov[(4 * j + i, 4 * j + i)].max(0.0).sqrt())).collect();
    let l0_sigma = (0..n).map(|j| cov[(4 * j + 3, 4 * j + 3)].max(0.0).sqrt()).collect();
    let anchor_cov_m2 =
        (0..3 * n).flat_map(|r| (0..3 * n).map(move |c| (r, c))).map(|(r, c)| cov[(r / 3 * 4 + r % 3, c / 3 * 4 + c % 3)]).collect();
    Some(Prediction { anchor_sigma, l0_sigma, samples, anchor_cov_m2 })
}

fn worst(info: &DMatrix<f64>, n: usize) -> f64 {
    prediction(info, n, 0).map_or(f64::INFINITY, |p| p.worst_anchor_sigma_m())
}

/// The rows the calibration fits out of `rows` consecutive excitation rows: the last
/// `1 - used_fraction` of each of `blocks` consecutive blocks is held out (the daemon's
/// `taut_calibrator::vocab::HeldoutBlocks`, kept equal to this by a test in taut-calibrator).
pub fn training_rows(rows: usize, used_fraction: f64, blocks: usize) -> impl Iterator<Item = usize> {
    let held = 1.0 - used_fraction;
    (0..blocks.max(1)).flat_map(move |b| heldout_block(rows, held, blocks, b).0)
}

/// Block `b` of `blocks` consecutive blocks over `rows` rows, the last `held_fraction` of it
/// held out: its training rows, then its held-out rows. The daemon's split
/// (`taut_calibrator::vocab::HeldoutBlocks`) and [`training_rows`] are both this.
pub fn heldout_block(rows: usize, held_fraction: f64, blocks: usize, b: usize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
    let blocks = blocks.max(1);
    let (start, end) = (b * rows / blocks, (b + 1) * rows / blocks);
    let held_start = end - (((end - start) as f64) * held_fraction.clamp(0.0, 1.0)).round() as usize;
    (start..held_start, held_start..end)
}

/// Predicted uncertainty of the calibration from an excitation `path(t)`, `t` in `[0, duration_s)`:
/// the samples at the tracker rate that the calibration fits ([`training_rows`]).
pub fn predict(inp: &DesignInput, path: impl Fn(f64) -> [f64; 3]) -> Option<Prediction> {
    let rows = (inp.duration_s * inp.sample_hz).floor().max(0.0) as usize;
    let pts: Vec<[f64; 3]> = training_rows(rows, inp.used_fraction, inp.heldout_blocks).map(|k| path(k as f64 / inp.sample_hz)).collect();
    prediction(&information(inp, pts.iter()), inp.anchors.len(), pts.len())
}

/// Tensions of the position-controlled cables at `p` with acceleration `acc` (followers at their
/// torque tension): within the limits? `None` when it cannot be decided (not exactly three
/// position-controlled cables, or a singular configuration).
fn tensions_ok(inp: &DesignInput, p: &[f64; 3], acc: &[f64; 3]) -> Option<bool> {
    let n = inp.anchors.len();
    let held: Vec<usize> = (0..n).filter(|j| !inp.follower.get(*j).copied().unwrap_or(false)).collect();
    if held.len() != 3 || inp.mass_kg <= 0.0 {
        return None;
    }
    let unit = |j: usize| {
        let a = inp.anchors[j];
        let b = inp.platform[j];
        let d = Vector3::new(a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]);
        d / d.norm()
    };
    // sum_j T_j u_j = m (acc + g e_z), u_j towards the anchor.
    let mut rhs = Vector3::new(acc[0], acc[1], acc[2] + 9.81) * inp.mass_kg;
    for j in 0..n {
        if !held.contains(&j) {
            rhs -= unit(j) * inp.follower_tension_n;
        }
    }
    let a = Matrix3::from_columns(&[unit(held[0]), unit(held[1]), unit(held[2])]);
    let t = a.try_inverse()? * rhs;
    Some(t.iter().all(|t| *t >= inp.min_tension_n && *t <= inp.max_tension_n))
}

/// Grid points per axis of the candidate waypoints: corners, edge midpoints, face centres and
/// the centre of the box (a 3 x 3 x 3 grid).
const GRID: usize = 4;

/// Start tours of the local search (the best two-waypoint loops).
const STARTS: usize = 12;

/// A segment's duration, s, and the information of its samples.
type SegmentInfo = (f64, DMatrix<f64>);

/// Designs the excitation (see the module documentation).
pub fn design(inp: &DesignInput) -> Result<Design, DesignError> {
    let n = inp.anchors.len();
    if !(3..=8).contains(&n) || inp.platform.len() != n {
        return Err(DesignError::Cables { n });
    }
    let lo: [f64; 3] = std::array::from_fn(|i| inp.workspace[0][i] + inp.margin_m);
    let hi: [f64; 3] = std::array::from_fn(|i| inp.workspace[1][i] - inp.margin_m);
    let positive = |x: f64| x.is_finite() && x > 0.0;
    let limits = [inp.speed_m_s, inp.accel_m_s2, inp.duration_s, inp.sample_hz, inp.tracker_sigma_m, inp.length_sigma_m];
    let ok = (0..3).all(|i| hi[i] > lo[i]) && limits.into_iter().all(positive) && inp.used_fraction > 0.0 && inp.used_fraction <= 1.0;
    if !ok {
        return Err(DesignError::Limits);
    }
    let (v, a) = (inp.speed_m_s, inp.accel_m_s2);
    // Candidate waypoints: the grid points where the platform can rest.
    let at = |k: usize, i: usize| lo[i] + (hi[i] - lo[i]) * k as f64 / (GRID - 1) as f64;
    let cands: Vec<[f64; 3]> = (0..GRID * GRID * GRID)
        .map(|c| [at(c / (GRID * GRID), 0), at(c / GRID % GRID, 1), at(c % GRID, 2)])
        .filter(|p| tensions_ok(inp, p, &[0.0; 3]).unwrap_or(true))
        .collect();
    let k = cands.len();
    let dt = 1.0 / inp.sample_hz;
    // Samples along a segment from `p0` to `p1` (from its start, for `t_max` s at most).
    let seg_points = |p0: &[f64; 3], p1: &[f64; 3], t_max: f64| -> Vec<[f64; 3]> {
        let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
        let dur = segment_time(len, v, a);
        let m = (dur.min(t_max) / dt).floor() as usize;
        (0..m)
            .map(|k| {
                let s = segment_distance(k as f64 * dt, len, dur, v, a) / len;
                std::array::from_fn(|i| p0[i] + s * (p1[i] - p0[i]))
            })
            .collect()
    };
    // Per ordered pair: duration and information, when every position-controlled cable stays
    // within its tension limits along it (statics plus the profile's +-a).
    let mut seg: Vec<Option<SegmentInfo>> = vec![None; k * k];
    for c0 in 0..k {
        for c1 in 0..k {
            if c0 == c1 {
                continue;
            }
            let (p0, p1) = (&cands[c0], &cands[c1]);
            let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
            let pts = seg_points(p0, p1, f64::INFINITY);
            let dir: [f64; 3] = std::array::from_fn(|i| (p1[i] - p0[i]) / len);
            let feasible = pts
                .iter()
                .step_by(10)
                .chain(std::iter::once(p1))
                .all(|p| [1.0, -1.0, 0.0].iter().all(|s| tensions_ok(inp, p, &dir.map(|d| d * a * s)).unwrap_or(true)));
            if feasible {
                seg[c0 * k + c1] = Some((segment_time(len, v, a), information(inp, pts.iter())));
            }
        }
    }
    if seg.iter().all(Option::is_none) {
        return Err(DesignError::NoFeasibleSegment);
    }
    let total = inp.duration_s;
    // The search's score of a closed tour: the worst-anchor sigma of its loop's information
    // times the loops that fit in the excitation (which waypoint the loop joins at moves the
    // cut end; the final choice is ranked by the exact prediction at the worst join). Infinite
    // when a move is infeasible or the loop does not fit in the excitation.
    let score = |seq: &[usize]| -> f64 {
        if seq.len() < 2 || seq.len() > MAX_WAYPOINTS {
            return f64::INFINITY;
        }
        let mut info = DMatrix::<f64>::zeros(4 * n, 4 * n);
        let mut period = 0.0;
        for (i, c0) in seq.iter().enumerate() {
            let c1 = seq[(i + 1) % seq.len()];
            let Some((dur, si)) = &seg[c0 * k + c1] else { return f64::INFINITY };
            period += dur;
            info += si;
        }
        if period > total {
            return f64::INFINITY;
        }
        worst(&(info * (total / period)), n)
    };
    // Starts: the best two-waypoint loops (back and forth).
    let mut pairs: Vec<(f64, Vec<usize>)> =
        (0..k).flat_map(|c0| (c0 + 1..k).map(move |c1| vec![c0, c1])).map(|s| (score(&s), s)).filter(|(w, _)| w.is_finite()).collect();
    // A pair alone rarely observes every anchor (infinite sigma): order those by their
    // information's trace, the rest by their sigma.
    let trace = |s: &[usize]| -> f64 {
        seg[s[0] * k + s[1]].as_ref().map_or(0.0, |x| x.1.trace()) + seg[s[1] * k + s[0]].as_ref().map_or(0.0, |x| x.1.trace())
    };
    if pairs.is_empty() {
        pairs = (0..k)
            .flat_map(|c0| (c0 + 1..k).map(move |c1| vec![c0, c1]))
            .filter(|s| seg[s[0] * k + s[1]].is_some() && seg[s[1] * k + s[0]].is_some())
            .map(|s| (-trace(&s), s))
            .collect();
    }
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    // Steepest descent from each start over the moves: insert a waypoint, replace one, remove
    // one, reverse a stretch (2-opt).
    let descend = |mut cur: Vec<usize>| -> (f64, Vec<usize>) {
        let mut best = score(&cur);
        loop {
            let mut next: Option<(f64, Vec<usize>)> = None;
            let mut consider = |s: Vec<usize>| {
                let w = score(&s);
                if w < next.as_ref().map_or(best * (1.0 - 1e-9), |x| x.0) {
                    next = Some((w, s));
                }
            };
            let m = cur.len();
            for pos in 0..=m {
                for c in 0..k {
                    let mut s = cur.clone();
                    s.insert(pos, c);
                    consider(s);
                }
            }
            for pos in 0..m {
                for c in 0..k {
                    if c != cur[pos] {
                        let mut s = cur.clone();
                        s[pos] = c;
                        consider(s);
                    }
                }
                if m > 2 {
                    let mut s = cur.clone();
                    s.remove(pos);
                    consider(s);
                }
                for end in pos + 2..=m {
                    let mut s = cur.clone();
                    s[pos..end].reverse();
                    consider(s);
                }
            }
            match next {
                Some((w, s)) => (best, cur) = (w, s),
                None => return (best, cur),
            }
        }
    };
    let tour_of = |seq: &[usize]| {
        let mut tour = Tour { waypoints: [[0.0; 3]; MAX_WAYPOINTS], n: seq.len(), speed_m_s: v, accel_m_s2: a };
        for (i, c) in seq.iter().enumerate() {
            tour.waypoints[i] = cands[*c];
        }
        tour
    };
    // The local optima, ranked by the exact prediction at their worst join.
    let mut found: Vec<Vec<usize>> = vec![];
    for (_, s) in pairs.into_iter().take(STARTS) {
        let (_, s) = descend(s);
        if !found.contains(&s) {
            found.push(s);
        }
    }
    let (predicted, tour) = found
        .iter()
        .filter_map(|s| {
            let t = tour_of(s);
            predict_tour(inp, &t).map(|p| (p, t))
        })
        .min_by(|x, y| x.0.worst_anchor_sigma_m().total_cmp(&y.0.worst_anchor_sigma_m()))
        .ok_or(DesignError::Unobservable)?;
    if !predicted.worst_anchor_sigma_m().is_finite() {
        return Err(DesignError::Unobservable);
    }
    Ok(Design { tour, predicted })
}

/// Predicted uncertainty of the calibration from the excitation `tour`, joined at whichever
/// waypoint gives the largest worst-anchor sigma: the loop joins the tour at the waypoint
/// nearest the platform ([`Tour::nearest_waypoint`]), which is not known before the start-up
/// (a 30 s tour of the simulated robot: 0.40-0.46 mm by waypoint). `None` if singular.
pub fn predict_tour(inp: &DesignInput, tour: &Tour) -> Option<Prediction> {
    let mut out: Option<Prediction> = None;
    for k in 0..tour.n.max(1) {
        let (_, t0) = tour.nearest_waypoint(&tour.waypoints[k]);
        let p = predict(inp, |t| tour.point(t + t0))?;
        if out.as_ref().is_none_or(|o| p.worst_anchor_sigma_m() > o.worst_anchor_sigma_m()) {
            out = Some(p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input() -> DesignInput {
        DesignInput {
            anchors: vec![[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]],
            platform: vec![[0.0; 3]; 4],
            workspace: [[-1.75, -0.875, 1.0], [1.75, 0.875, 3.0]],
            margin_m: 0.05,
            speed_m_s: 0.8,
            accel_m_s2: 1.0,
            duration_s: 30.0,
            sample_hz: 100.0,
            used_fraction: 0.8,
            heldout_blocks: 8,
            tracker_sigma_m: 1.5e-3,
            length_sigma_m: 5e-5,
            mass_kg: 3.0,
            follower: vec![false, false, false, true],
            follower_tension_n: 10.0,
            min_tension_n: 3.0,
            max_tension_n: 500.0,
        }
    }

    #[test]
    fn tour_respects_speed_box_and_is_continuous() {
        let inp = input();
        let d = design(&inp).unwrap();
        let dt = 0.002;
        let mut prev = d.tour.point(0.0);
        let mut vmax: f64 = 0.0;
        for k in 1..(40.0 / dt) as usize {
            let p = d.tour.point(k as f64 * dt);
            let v = ((p[0] - prev[0]).powi(2) + (p[1] - prev[1]).powi(2) + (p[2] - prev[2]).powi(2)).sqrt() / dt;
            vmax = vmax.max(v);
            for i in 0..3 {
                assert!(p[i] >= inp.workspace[0][i] + inp.margin_m - 1e-9 && p[i] <= inp.workspace[1][i] - inp.margin_m + 1e-9);
            }
            prev = p;
        }
        assert!(vmax <= 0.8 + 1e-6 && vmax > 0.7, "largest speed {vmax}");
    }

    #[test]
    fn the_tour_closes_within_the_excitation_so_any_joining_waypoint_drives_it_all() {
        for duration_s in [25.0, 30.0] {
            let inp = DesignInput { duration_s, ..input() };
            let d = design(&inp).unwrap();
            let t = &d.tour;
            assert!(t.n >= 4, "{duration_s} s: {} waypoints", t.n);
            assert!(t.period_s() <= duration_s + 1e-9, "{duration_s} s: period {} s", t.period_s());
            // Joined at any waypoint (the loop takes the nearest), the prediction barely moves;
            // the design's is the worst of them.
            let w = d.predicted.worst_anchor_sigma_m();
            for k in 0..t.n {
                let (_, t0) = t.nearest_waypoint(&t.waypoints[k]);
                let wk = predict(&inp, |x| t.point(x + t0)).unwrap().worst_anchor_sigma_m();
                eprintln!("{duration_s} s, joined at waypoint {k}: {:.3} mm (from the first: {:.3} mm)", wk * 1e3, w * 1e3);
                assert!(wk <= w * (1.0 + 1e-12) && wk > 0.75 * w, "{duration_s} s, joined at waypoint {k}: {wk} vs {w}");
            }
        }
        let inp = input();
        let t = design(&inp).unwrap().tour;
        // Every move, the return to the first waypoint included, keeps the tensions in bounds.
        for k in 0..t.n {
            let (p0, p1) = (t.waypoints[k], t.waypoints[(k + 1) % t.n]);
            for s in 0..=20 {
                let f = s as f64 / 20.0;
                let p: [f64; 3] = std::array::from_fn(|i| p0[i] + f * (p1[i] - p0[i]));
                assert_eq!(tensions_ok(&inp, &p, &[0.0; 3]), Some(true), "move {k} at {f}");
            }
        }
    }

    /// Today's Lissajous of the loop (80 % amplitudes, frequency ratios 1 : 0.77 : 0.59,
    /// `|a_i w_i| <= v / sqrt 3`).
    fn lissajous(inp: &DesignInput) -> impl Fn(f64) -> [f64; 3] {
        let w = inp.workspace;
        let c: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
        let amp: [f64; 3] = std::array::from_fn(|i| 0.8 * (w[1][i] - w[0][i]) / 2.0);
        let ratio = [1.0, 0.77, 0.59];
        let phase = [0.0, std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_4];
        let v = inp.speed_m_s;
        move |t| std::array::from_fn(|i| c[i] + amp[i] * (ratio[i] * v / (3f64.sqrt() * amp[i]) * t + phase[i]).sin())
    }

    #[test]
    fn designed_tour_predicts_less_than_half_the_lissajous_sigma() {
        let inp = input();
        let d = design(&inp).unwrap();
        // The Lissajous curve runs at the loop's excitation speed (0.4 m/s on the simulated robot).
        let today = predict(&inp, lissajous(&DesignInput { speed_m_s: 0.4, ..input() })).unwrap();
        let (wd, wt) = (d.predicted.worst_anchor_sigma_m(), today.worst_anchor_sigma_m());
        eprintln!("worst anchor 1-sigma: designed {:.2} mm ({} waypoints), Lissajous {:.2} mm", wd * 1e3, d.tour.n, wt * 1e3);
        assert!(wd < 0.5 * wt, "designed {wd} vs Lissajous {wt}");
        // What more time or speed would buy (BENCHMARKS.md).
        for (dur, v) in [(30.0, 0.4), (60.0, 0.4), (30.0, 0.6), (30.0, 1.0), (60.0, 0.8)] {
            let p = design(&DesignInput { duration_s: dur, speed_m_s: v, ..input() }).unwrap().predicted.worst_anchor_sigma_m();
            eprintln!("designed, {dur} s at {v} m/s: worst anchor 1-sigma {:.2} mm", p * 1e3);
        }
        // At the length noise the simulated robot's calibration measures (BENCHMARKS.md).
        for dur in [30.0, 60.0] {
            let p = design(&DesignInput { duration_s: dur, length_sigma_m: 1.13e-4, ..input() }).unwrap().predicted.worst_anchor_sigma_m();
            eprintln!("designed, {dur} s at 0.8 m/s, length noise 0.113 mm: worst anchor 1-sigma {:.2} mm", p * 1e3);
        }
    }

    #[test]
    fn information_is_the_length_covariance_with_tracker_noise_carried_through() {
        // One sample, two parameters perturbed: the Schur-complement information equals
        // J^T (R + J_p S_t J_p^T)^-1 J, the information of the lengths with the tracker noise
        // carried through them (Woodbury).
        let inp = input();
        let p = [0.3, -0.2, 2.1];
        let info = information(&inp, std::iter::once(&p));
        let n = 4;
        let e: Vec<Vector3<f64>> =
            inp.anchors.iter().map(|a| (Vector3::new(p[0], p[1], p[2]) - Vector3::new(a[0], a[1], a[2])).normalize()).collect();
        let jp = DMatrix::from_fn(n, 3, |j, i| e[j][i]);
        let cov = DMatrix::identity(n, n) * inp.length_sigma_m.powi(2) + &jp * jp.transpose() * inp.tracker_sigma_m.powi(2);
        let jx = DMatrix::from_fn(n, 4 * n, |j, c| {
            if c / 4 != j {
                0.0
            } else if c % 4 == 3 {
                1.0
            } else {
                -e[j][c % 4]
            }
        });
        let want = jx.transpose() * cov.try_inverse().unwrap() * &jx;
        assert!((&info - &want).abs().max() < 1e-6 * want.abs().max(), "{}", (&info - &want).abs().max());
    }

    #[test]
    fn the_norm_tail_matches_closed_forms_and_the_monte_carlo() {
        // Isotropic: |e|^2 / s^2 is chi-square with 3 dof; P(chi2_3 > x) =
        // 2 P(Z > sqrt(x)) + sqrt(2 x / pi) exp(-x / 2).
        let chi3 = |x: f64| 2.0 * crate::screen::normal_sf(x.sqrt()) + (2.0 * x / std::f64::consts::PI).sqrt() * (-x / 2.0).exp();
        for x in [1.0f64, 9.0, 25.0, 36.0] {
            let p = norm_exceeds([1.0, 1.0, 1.0], x.sqrt());
            assert!((p / chi3(x) - 1.0).abs() < 1e-6, "x {x}: {p} vs {}", chi3(x));
        }
        // One axis only: 2 Phi(-r / s).
        let p = norm_exceeds([0.0, 0.0, 4.0], 5.0);
        assert!((p / (2.0 * crate::screen::normal_sf(2.5)) - 1.0).abs() < 1e-6, "{p}");
        // A design's prediction, where P is large enough to measure: each anchor's quadrature
        // against a Monte Carlo of its 3 x 3 block (the sum of the two), and the union over
        // the anchors above the joint Monte Carlo (an upper bound: the anchors' errors are
        // positively correlated, 4.6e-2 vs 4.0e-2 at 0.5 mm).
        let d = design(&input()).unwrap();
        let p = &d.predicted;
        let k = 3 * p.anchor_sigma.len();
        for limit in [0.5e-3, 0.6e-3] {
            let bound = p.worst_exceeds_bound(limit, 1.0);
            let mut rng = crate::mc::SplitMix(7);
            let draws = 200_000;
            let mut sum_mc = 0.0;
            for j in 0..k / 3 {
                let block = Matrix3::from_fn(|r, c| p.anchor_cov_m2[(3 * j + r) * k + 3 * j + c]);
                let l = block.cholesky().unwrap().l();
                let over = (0..draws)
                    .filter(|_| {
                        let z = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                        (l * z).norm() > limit
                    })
                    .count();
                sum_mc += over as f64 / draws as f64;
            }
            // The sum of four binomial estimates: its sd is below sqrt(bound / draws).
            let sd = (bound / draws as f64).sqrt();
            let (joint, _) = p.worst_exceeds_probability(limit, 1.0, draws);
            eprintln!("limit {limit}: union bound {bound:.4e}, per-anchor Monte Carlo sum {sum_mc:.4e} (sd {sd:.1e}), joint {joint:.4e}");
            assert!((bound - sum_mc).abs() < 5.0 * sd, "limit {limit}: quadrature {bound} vs Monte Carlo {sum_mc}");
            assert!(bound > joint, "limit {limit}: union {bound} below the joint {joint}");
        }
    }

    #[test]
    fn training_rows_are_the_ends_of_each_block_held_out() {
        let rows: Vec<usize> = training_rows(100, 0.8, 8).collect();
        // Blocks of 12 or 13 rows, 2 or 3 held out at each block's end.
        assert_eq!(rows.len(), 80);
        assert_eq!(&rows[..10], &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9]);
        assert!(!rows.contains(&10) && !rows.contains(&11) && rows.contains(&12) && !rows.contains(&99));
        assert_eq!(training_rows(100, 0.8, 1).collect::<Vec<_>>(), (0..80).collect::<Vec<_>>());
        assert_eq!(training_rows(7, 1.0, 8).count(), 7);
    }

    #[test]
    fn no_feasible_segment_is_an_error() {
        let mut inp = input();
        inp.max_tension_n = 5.0;
        assert_eq!(design(&inp).unwrap_err(), DesignError::NoFeasibleSegment);
        let mut inp = input();
        inp.workspace = [[0.0; 3], [0.05, 1.0, 1.0]];
        assert_eq!(design(&inp).unwrap_err(), DesignError::Limits);
    }
}
