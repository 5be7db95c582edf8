//! The dwell-pose plan of a start-up without a tracker: where the platform stops, chosen from the
//! nominal geometry for what the self-calibration must observe.
//!
//! ```text
//! candidates  grid of nx x ny x nz points inside the workspace box (below the anchor plane)
//! feasible    the tensions that hold the platform there (followers at their torque-mode tension,
//!             the three position-controlled cables from the static balance) are all
//!             >= tension_margin x min_tension and <= max_tension / tension_margin
//! information I_k = Schur complement of candidate k's pose block (lengths and force balance,
//!             each averaged over a dwell), at the nominal anchors          (`solve::information`)
//! selection   greedy A-optimal: add the candidate that most lowers trace(Cov_A) of
//!             [sum I_k + prior, C^T; C, 0]^-1 (C: the frame of `super::gauge`); the weak prior
//!             (1 m on every global) only makes the first picks well-posed
//! order       nearest neighbour from the start, then 2-opt: a short path
//! prediction  the Cramér–Rao bound of the chosen set without the prior: per-anchor 1-sigma
//! ```
//!
//! With a datasheet stiffness ([`PlanInput::stretch`], `[calibration] cable_ea_n` with its
//! sigma) the calibration fits each cable's stretch factor within its tolerance
//! ([`super::solve`]); the planner's information then carries those factors too, with their
//! prior added once to the sum (not per candidate), so the predicted anchor covariance
//! includes what the unknown stiffness costs. Without it the layout and the bound are the
//! ideal model's.
//!
//! The information of a set of dwells is the sum of theirs (each dwell's pose is its own
//! unknown), so the greedy choice is cheap; greedy selection of a trace criterion is not
//! guaranteed optimal, but every step is the best single addition and the bound it reports is
//! the exact bound of the chosen set at the nominal geometry. Everything is deterministic given
//! the inputs (no random draws).

use super::dwell::Dwell;
use super::solve::{self, Layout, Problem, State};
use super::{gauge, Frame};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use std::fmt;

/// What the planner needs: the nominal robot, its limits and its sensors.
#[derive(Debug, Clone)]
pub struct PlanInput<'a> {
    /// Nominal anchors, m.
    pub nominal: &'a [[f64; 3]],
    /// Platform points, m.
    pub platform: &'a [[f64; 3]],
    /// Platform mass, kg.
    pub mass_kg: f64,
    /// Workspace box `[min, max]`, m.
    pub workspace: [[f64; 3]; 2],
    /// Cables that follow in torque mode (the others are position controlled; exactly three
    /// must be).
    pub follower: &'a [bool],
    /// The followers' tension, N.
    pub follower_tension_n: f64,
    /// Tensions below this are loose (`calibration.min_tension_n`), N.
    pub min_tension_n: f64,
    /// The tension limit (`safety.max_tension_n`), N.
    pub max_tension_n: f64,
    /// Every planned tension is at least `tension_margin x min_tension_n` and at most
    /// `max_tension_n / tension_margin`: the robot moves with the nominal anchors, a few cm off.
    pub tension_margin: f64,
    /// Encoder noise of one reading, m.
    pub encoder_sigma_m: f64,
    /// Load-cell noise of one reading, N; `None`: no load cells (encoders only).
    pub loadcell_sigma_n: Option<f64>,
    /// Encoder readings averaged per dwell.
    pub length_samples: usize,
    /// Tension readings averaged per dwell (distinct readings: a reading held over several
    /// loop cycles counts once).
    pub tension_samples: usize,
    /// Tare dwells wanted: after its dwell, the platform stays at the pose with the followers
    /// commanded to zero tension (the three position-controlled cables hold it), and their load
    /// cells read their offsets (`tare_samples` readings each). Only poses where the three
    /// hold the platform within the tension bounds alone qualify.
    pub tares: usize,
    /// Tension readings of each slack cable's offset per tare (the loop records a tare as long
    /// as a dwell: `tension_samples`).
    pub tare_samples: usize,
    /// The tares rotate through every cable (4-cable robots): a position-controlled cable's
    /// tare slackens it while the three others (the follower now in position mode) hold the
    /// platform, so every load cell reads its offset; only poses where those three hold it
    /// within the tension bounds qualify. `false`: the followers only.
    pub tare_each_cable: bool,
    /// Dwell poses wanted.
    pub poses: usize,
    /// Where the path starts (the platform's rest position, if known), m.
    pub start: Option<[f64; 3]>,
    /// The cables' stretch as the calibration models it ([`super::SelfCalOptions::stretch`]):
    /// `None`, the ideal model; with `rel_sigma` above 0 the stretch factors are unknowns
    /// with their prior. Used with load cells only (as the calibration).
    pub stretch: Option<crate::bundle::Stretch>,
    /// Candidate grid points per axis `[x, y, z]`.
    pub grid: [usize; 3],
}

/// The plan: poses in the order visited, with the predicted uncertainty.
#[derive(Debug, Clone, PartialEq)]
pub struct DwellPlan {
    /// Dwell positions in the order visited, m (nominal frame).
    pub poses: Vec<[f64; 3]>,
    /// Planned tensions at each pose, N.
    pub tensions: Vec<Vec<f64>>,
    /// Cables slackened in the tare dwell after each pose, as a bit mask (bit `j`: cable `j`;
    /// 0: no tare).
    pub tare: Vec<u8>,
    /// Predicted 1-sigma of each anchor coordinate (Cramér–Rao bound at the nominal geometry), m.
    pub anchor_sigma_m: Vec<[f64; 3]>,
    /// Predicted worst anchor: `max_j sqrt(sx^2 + sy^2 + sz^2)`, m.
    pub worst_anchor_sigma_m: f64,
    /// Predicted RMS anchor error after the frame alignment: `sqrt(trace(Cov_A) / n)`, m.
    pub anchor_rms_m: f64,
    /// The predicted covariance of the anchor coordinates (`3n x 3n`, row-major, anchor `j`'s
    /// coordinate `a` at `3j + a`) in the nominal frame, m^2.
    pub anchor_cov_m2: Vec<f64>,
    /// Predicted 1-sigma of each encoder offset, m.
    pub l0_sigma_m: Vec<f64>,
    /// Path length through the poses (from the start, if given), m.
    pub path_m: f64,
    /// Feasible candidates the poses were chosen from.
    pub candidates: usize,
}

/// Why no plan could be made.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanError {
    /// Fewer than four cables: tracker-free calibration is not possible (see
    /// [`super::SelfCalError::TooFewCables`]).
    TooFewCables {
        /// Cables.
        n: usize,
    },
    /// The followers leave other than three position-controlled cables.
    PositionCables {
        /// Position-controlled cables.
        count: usize,
    },
    /// Inputs of different lengths or non-finite values.
    BadInput(&'static str),
    /// Too few feasible candidates in the workspace.
    TooFewFeasible {
        /// Feasible candidates.
        feasible: usize,
        /// Poses wanted.
        wanted: usize,
    },
    /// The chosen set does not determine the geometry (singular information).
    Singular,
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlanError::TooFewCables { n } => {
                write!(f, "a {n}-cable robot cannot calibrate itself without a tracker; configure `[tracker]`")
            }
            PlanError::PositionCables { count } => {
                write!(f, "{count} position-controlled cables: the dwell plan holds the platform with exactly three")
            }
            PlanError::BadInput(what) => write!(f, "dwell plan: {what}"),
            PlanError::TooFewFeasible { feasible, wanted } => write!(
                f,
                "only {feasible} poses in the workspace box hold every cable between the tension bounds, {wanted} wanted: \
                 widen motion.workspace_min_m/max_m, lower motion.dwell_poses or calibration.min_tension_n, or raise the followers' tension"
            ),
            PlanError::Singular => {
                f.write_str("the feasible poses do not determine the geometry (singular information): widen the workspace box")
            }
        }
    }
}

impl std::error::Error for PlanError {}

/// Tensions holding a point mass at `p` (platform points `b`) with the followers at `follower_n`
/// and the three position-controlled cables from the static balance. `None` if degenerate.
pub fn static_tensions(
    anchors: &[[f64; 3]],
    b: &[[f64; 3]],
    follower: &[bool],
    follower_n: f64,
    mass_kg: f64,
    p: [f64; 3],
) -> Option<Vec<f64>> {
    let n = anchors.len();
    let unit = |j: usize| {
        let d = Vector3::from(anchors[j]) - Vector3::from(p) - Vector3::from(b[j]);
        d / d.norm()
    };
    let mut rhs = Vector3::new(0.0, 0.0, mass_kg * solve::G);
    let mut cols = Vec::with_capacity(3);
    for j in 0..n {
        if follower[j] {
            rhs -= unit(j) * follower_n;
        } else {
            cols.push(j);
        }
    }
    if cols.len() != 3 {
        return None;
    }
    let m = Matrix3::from_columns(&[unit(cols[0]), unit(cols[1]), unit(cols[2])]);
    let t = m.lu().solve(&rhs)?;
    let mut out = vec![follower_n; n];
    for (k, &j) in cols.iter().enumerate() {
        out[j] = t[k];
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// Chooses the dwell poses (module documentation).
pub fn plan(inp: &PlanInput<'_>) -> Result<DwellPlan, PlanError> {
    let n = inp.nominal.len();
    if n < 4 {
        return Err(PlanError::TooFewCables { n });
    }
    if n > 8 {
        return Err(PlanError::BadInput("more than 8 cables (the tare masks are 8 bits, the loop's limit)"));
    }
    if inp.platform.len() != n || inp.follower.len() != n {
        return Err(PlanError::BadInput("platform points, followers and anchors differ in number"));
    }
    let count = inp.follower.iter().filter(|f| !**f).count();
    if count != 3 {
        return Err(PlanError::PositionCables { count });
    }
    let finite = inp.nominal.iter().chain(inp.platform).flatten().chain(inp.workspace.iter().flatten()).all(|v| v.is_finite())
        && inp.mass_kg.is_finite()
        && inp.mass_kg > 0.0;
    if !finite || inp.poses == 0 || inp.grid.iter().any(|&g| g < 2) {
        return Err(PlanError::BadInput("non-finite geometry, no mass, no poses or a grid under 2 points per axis"));
    }
    let z_plane = inp.nominal.iter().map(|a| a[2]).fold(f64::INFINITY, f64::min);
    let lo_t = inp.tension_margin * inp.min_tension_n;
    let hi_t = inp.max_tension_n / inp.tension_margin.max(1.0);
    // The tare groups: the followers together, and with `tare_each_cable` (4 cables) each
    // position-controlled cable alone (the three others hold the platform).
    let fmask: u8 = (0..n).filter(|&j| inp.follower[j]).fold(0, |m, j| m | (1 << j));
    let mut groups: Vec<u8> = vec![fmask];
    if inp.tare_each_cable && n == 4 {
        groups.extend((0..n).filter(|&j| !inp.follower[j]).map(|j| 1u8 << j));
    }
    // Candidates: the grid, each feasible one with its tensions.
    // (position, tensions, per tare group: the lowest holding tension with the group at zero).
    let mut cand: Vec<([f64; 3], Vec<f64>, Vec<f64>)> = Vec::new();
    let w = inp.workspace;
    for iz in 0..inp.grid[2] {
        for iy in 0..inp.grid[1] {
            for ix in 0..inp.grid[0] {
                let at = |i: usize, k: usize, a: usize| w[0][a] + (w[1][a] - w[0][a]) * i as f64 / (k - 1) as f64;
                let p = [at(ix, inp.grid[0], 0), at(iy, inp.grid[1], 1), at(iz, inp.grid[2], 2)];
                if p[2] >= z_plane - 0.05 {
                    continue;
                }
                if let Some(t) = static_tensions(inp.nominal, inp.platform, inp.follower, inp.follower_tension_n, inp.mass_kg, p) {
                    if t.iter().all(|&x| x >= lo_t && x <= hi_t) {
                        let margins = groups
                            .iter()
                            .map(|&g| {
                                let slack: Vec<bool> = (0..n).map(|j| g & (1 << j) != 0).collect();
                                let zero = static_tensions(inp.nominal, inp.platform, &slack, 0.0, inp.mass_kg, p);
                                zero.filter(|z| z.iter().zip(&slack).all(|(&x, &s)| s || x <= hi_t)).map_or(f64::NEG_INFINITY, |z| {
                                    z.iter().zip(&slack).filter(|(_, &s)| !s).map(|(&x, _)| x).fold(f64::INFINITY, f64::min)
                                })
                            })
                            .collect();
                        cand.push((p, t, margins));
                    }
                }
            }
        }
    }
    if cand.len() < inp.poses {
        return Err(PlanError::TooFewFeasible { feasible: cand.len(), wanted: inp.poses });
    }
    let tensions = inp.loadcell_sigma_n.is_some();
    let stretch = inp.stretch.filter(|st| tensions && st.ea_n > 0.0 && st.ea_n.is_finite());
    let fitted = stretch.filter(|st| st.rel_sigma > 0.0);
    let lay = Layout { n, offsets: tensions, mass: false, ea: fitted.is_some() };
    let frame = if tensions { Frame::NominalTranslationYaw } else { Frame::NominalRigid };
    let (c, d) = gauge(inp.nominal, lay, frame);
    let ng = lay.count();
    let mut g = DVector::zeros(ng);
    for j in 0..n {
        for a in 0..3 {
            g[lay.a(j) + a] = inp.nominal[j][a];
        }
        if lay.ea {
            g[lay.s(j)] = 1.0;
        }
    }
    let var_f = inp.loadcell_sigma_n.unwrap_or(1.0).max(1e-6).powi(2);
    // Each candidate's information on the globals, its pose eliminated.
    let mut info = Vec::with_capacity(cand.len());
    for (p, t, _) in &cand {
        let l: Vec<f64> =
            (0..n).map(|j| (Vector3::from(*p) + Vector3::from(inp.platform[j]) - Vector3::from(inp.nominal[j])).norm()).collect();
        let dw = Dwell {
            start: 0,
            end: 1,
            l,
            nl: vec![inp.length_samples.max(1); n],
            f: if tensions { t.clone() } else { vec![f64::NAN; n] },
            nf: vec![if tensions { inp.tension_samples.max(1) } else { 0 }; n],
            f_ss: vec![0.0; n],
            label: -1,
            accel: [0.0; 3],
            l_rate: Vec::new(),
            l_curve: Vec::new(),
        };
        let dws = [dw];
        let pr = Problem {
            lay,
            b: inp.platform,
            dwells: &dws,
            var_l: inp.encoder_sigma_m.max(1e-9).powi(2),
            var_f,
            mass: inp.mass_kg,
            min_tension_n: inp.min_tension_n,
            // The factors' prior is added once to the sum below: none per candidate.
            stretch: stretch.map(|st| crate::bundle::Stretch { rel_sigma: 0.0, ..st }),
            design: &[],
            c: c.clone(),
            d: d.clone(),
        };
        let s = State { g: g.clone(), p: vec![*p] };
        let wh = pr.whitening(&s);
        info.push(solve::information(&pr, &s, &wh).ok_or(PlanError::Singular)?);
    }
    // The tares: the groups in turn, each at the feasible candidate with the largest margin (the
    // lowest holding tension with the group at zero) not tared yet, `tare_samples` readings
    // of each slack cable's offset each; their information on the offsets is part of the sum
    // from the start.
    let mut tare_at: Vec<(usize, u8)> = Vec::new();
    // Groups no candidate can tare (the others cannot hold the platform alone anywhere in the
    // box) are left out of the rotation.
    let tareable: Vec<usize> = (0..groups.len()).filter(|&gi| cand.iter().any(|c| c.2[gi] >= lo_t)).collect();
    if tensions && !tareable.is_empty() {
        for s in 0..inp.tares.min(inp.poses) {
            let gi = tareable[s % tareable.len()];
            let best = (0..cand.len())
                .filter(|&k| cand[k].2[gi] >= lo_t && !tare_at.iter().any(|&(q, _)| q == k))
                .max_by(|&a, &b| cand[a].2[gi].total_cmp(&cand[b].2[gi]).then(b.cmp(&a)));
            if let Some(k) = best {
                tare_at.push((k, groups[gi]));
            }
        }
    }
    // Greedy A-optimal selection with a weak prior.
    let prior = DMatrix::<f64>::identity(ng, ng);
    let mut sum = DMatrix::<f64>::zeros(ng, ng);
    if let Some(st) = fitted {
        for j in 0..n {
            sum[(lay.s(j), lay.s(j))] += 1.0 / (st.rel_sigma * st.rel_sigma);
        }
    }
    for &(_, g) in &tare_at {
        for j in (0..n).filter(|&j| g & (1 << j) != 0) {
            sum[(lay.c(j), lay.c(j))] += inp.tare_samples.max(1) as f64 / var_f;
        }
    }
    let mut chosen: Vec<usize> = Vec::with_capacity(inp.poses);
    let mut used = vec![false; cand.len()];
    // The tare poses are dwell poses too.
    for &(k, _) in &tare_at {
        used[k] = true;
        sum += &info[k];
        chosen.push(k);
    }
    while chosen.len() < inp.poses {
        let mut best: Option<(usize, f64)> = None;
        for k in 0..cand.len() {
            if used[k] {
                continue;
            }
            let trial = &sum + &info[k] + &prior;
            let Some(cov) = bordered_cov(&trial, &c) else { continue };
            let crit = (0..3 * n).map(|i| cov[(i, i)]).sum::<f64>();
            if best.is_none_or(|(_, b)| crit < b) {
                best = Some((k, crit));
            }
        }
        let (k, _) = best.ok_or(PlanError::Singular)?;
        used[k] = true;
        sum += &info[k];
        chosen.push(k);
    }
    let cov = bordered_cov(&sum, &c).ok_or(PlanError::Singular)?;
    let anchor_sigma_m: Vec<[f64; 3]> = (0..n).map(|j| [0, 1, 2].map(|a| cov[(lay.a(j) + a, lay.a(j) + a)].max(0.0).sqrt())).collect();
    let worst_anchor_sigma_m = anchor_sigma_m.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).fold(0.0, f64::max);
    let anchor_rms_m = ((0..3 * n).map(|i| cov[(i, i)]).sum::<f64>() / n as f64).sqrt();
    let anchor_cov_m2 =
        (0..3 * n).flat_map(|r| (0..3 * n).map(move |q| (r, q))).map(|(r, q)| cov[(lay.a(r / 3) + r % 3, lay.a(q / 3) + q % 3)]).collect();
    let l0_sigma_m = (0..n).map(|j| cov[(lay.l0(j), lay.l0(j))].max(0.0).sqrt()).collect();
    if !worst_anchor_sigma_m.is_finite() {
        return Err(PlanError::Singular);
    }
    let pts: Vec<[f64; 3]> = chosen.iter().map(|&k| cand[k].0).collect();
    let order = short_path(&pts, inp.start);
    let poses: Vec<[f64; 3]> = order.iter().map(|&i| pts[i]).collect();
    let path_m = path_length(&poses, inp.start);
    Ok(DwellPlan {
        tensions: order.iter().map(|&i| cand[chosen[i]].1.clone()).collect(),
        tare: order.iter().map(|&i| tare_at.iter().find(|&&(k, _)| k == chosen[i]).map_or(0, |&(_, g)| g)).collect(),
        poses,
        anchor_sigma_m,
        worst_anchor_sigma_m,
        anchor_rms_m,
        anchor_cov_m2,
        l0_sigma_m,
        path_m,
        candidates: cand.len(),
    })
}

impl DwellPlan {
    /// The probability that the worst anchor error after the best translation and rotation
    /// about the vertical ([`super::align::worst_aligned_error`]) exceeds `limit_m`, for a
    /// calibration whose anchor errors are Gaussian with the predicted covariance
    /// ([`DwellPlan::anchor_cov_m2`], scaled by `scale^2`: e.g. the square root of the ratio of
    /// the assumed to the achieved tension readings), at the nominal anchors `nominal`.
    ///
    /// Monte Carlo with `draws` draws from a fixed generator (deterministic): returns the
    /// fraction exceeding and its one-sided 99.9 % upper confidence bound
    /// (`p + 3.1 sqrt(p (1 - p) / draws) + 10 / draws`, conservative where few exceed).
    pub fn worst_exceeds_probability(&self, nominal: &[[f64; 3]], limit_m: f64, scale: f64, draws: usize) -> (f64, f64) {
        let n = nominal.len();
        let mut moved = vec![[0.0; 3]; n];
        crate::mc::gaussian_exceeds(&self.anchor_cov_m2, 3 * n, scale, draws, 0x5eed_7a07, |e| {
            for j in 0..n {
                moved[j] = std::array::from_fn(|a| nominal[j][a] + e[3 * j + a]);
            }
            super::align::worst_aligned_error(&moved, nominal) > limit_m
        })
    }
}

/// Top-left block of `[S C^T; C 0]^-1`: the covariance in the frame `C`.
fn bordered_cov(s: &DMatrix<f64>, c: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let (ng, nc) = (s.nrows(), c.nrows());
    let mut k = DMatrix::zeros(ng + nc, ng + nc);
    k.view_mut((0, 0), (ng, ng)).copy_from(s);
    k.view_mut((ng, 0), (nc, ng)).copy_from(c);
    k.view_mut((0, ng), (ng, nc)).copy_from(&c.transpose());
    let inv = k.try_inverse()?;
    let cov = inv.view((0, 0), (ng, ng)).into_owned();
    ((0..ng).all(|i| cov[(i, i)].is_finite() && cov[(i, i)] >= -1e-18)).then_some(cov)
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn path_length(p: &[[f64; 3]], start: Option<[f64; 3]>) -> f64 {
    let first = match (start, p.first()) {
        (Some(s), Some(f)) => dist(&s, f),
        _ => 0.0,
    };
    first + p.windows(2).map(|w| dist(&w[0], &w[1])).sum::<f64>()
}

/// A short visiting order: nearest neighbour from `start` (or the first point), improved by
/// 2-opt (segment reversals) until no reversal shortens the open path.
fn short_path(p: &[[f64; 3]], start: Option<[f64; 3]>) -> Vec<usize> {
    let k = p.len();
    if k == 0 {
        return vec![];
    }
    let mut order = Vec::with_capacity(k);
    let mut left: Vec<usize> = (0..k).collect();
    let mut at = start.unwrap_or(p[0]);
    while !left.is_empty() {
        let (i, _) =
            left.iter().enumerate().map(|(i, &q)| (i, dist(&at, &p[q]))).fold((0, f64::INFINITY), |b, x| if x.1 < b.1 { x } else { b });
        let q = left.remove(i);
        at = p[q];
        order.push(q);
    }
    let len = |o: &[usize]| path_length(&o.iter().map(|&i| p[i]).collect::<Vec<_>>(), start);
    let mut best = len(&order);
    let mut improved = true;
    let mut rounds = 0;
    while improved && rounds < 100 {
        improved = false;
        rounds += 1;
        for i in 0..k {
            for j in i + 1..k {
                order[i..=j].reverse();
                let l = len(&order);
                if l < best - 1e-12 {
                    best = l;
                    improved = true;
                } else {
                    order[i..=j].reverse();
                }
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input<'a>(nominal: &'a [[f64; 3]], b: &'a [[f64; 3]], follower: &'a [bool], poses: usize) -> PlanInput<'a> {
        PlanInput {
            nominal,
            platform: b,
            mass_kg: 3.0,
            workspace: [[-1.75, -0.875, 1.0], [1.75, 0.875, 3.0]],
            follower,
            follower_tension_n: 10.0,
            min_tension_n: 1.0,
            max_tension_n: 500.0,
            tension_margin: 2.0,
            encoder_sigma_m: 5e-5,
            loadcell_sigma_n: Some(0.3),
            length_samples: 300,
            tension_samples: 100,
            tares: 0,
            tare_samples: 100,
            tare_each_cable: false,
            poses,
            start: Some([0.0, 0.0, 2.0]),
            grid: [5, 5, 4],
            stretch: None,
        }
    }

    const NOM: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

    #[test]
    fn plan_spans_height_and_width_keeps_tensions_and_is_deterministic() {
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let inp = input(&NOM, &b, &fol, 20);
        let p = plan(&inp).unwrap();
        assert_eq!(p.poses.len(), 20);
        assert_eq!(p, plan(&inp).unwrap(), "deterministic");
        let (zs, xs): (Vec<f64>, Vec<f64>) = p.poses.iter().map(|q| (q[2], q[0])).unzip();
        let span = |v: &[f64]| v.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - v.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(span(&zs) > 1.5 && span(&xs) > 2.5, "height {} width {}", span(&zs), span(&xs));
        for (q, t) in p.poses.iter().zip(&p.tensions) {
            assert!(t.iter().all(|&x| (2.0..=250.0).contains(&x)), "{q:?}: {t:?}");
            // The tensions balance the weight at the pose.
            let mut f = Vector3::new(0.0, 0.0, -3.0 * solve::G);
            for j in 0..4 {
                let u = Vector3::from(NOM[j]) - Vector3::from(*q);
                f += u / u.norm() * t[j];
            }
            assert!(f.norm() < 1e-9, "{f}");
        }
        // The designed set predicts a smaller bound than the same number of poses on one
        // horizontal plane (the poorly conditioned case).
        let flat = PlanInput { workspace: [[-1.75, -0.875, 2.0], [1.75, 0.875, 2.0001]], grid: [6, 5, 2], ..inp.clone() };
        let pf = plan(&flat).unwrap();
        assert!(p.worst_anchor_sigma_m < 0.5 * pf.worst_anchor_sigma_m, "{} vs flat {}", p.worst_anchor_sigma_m, pf.worst_anchor_sigma_m);
        // More poses, smaller bound.
        let p40 = plan(&input(&NOM, &b, &fol, 40)).unwrap();
        assert!(p40.anchor_rms_m < p.anchor_rms_m);
        // The path is no longer than the visiting order of the selection.
        assert!(p.path_m < 40.0, "{}", p.path_m);
    }

    #[test]
    fn tares_are_planned_where_three_cables_hold_the_platform_and_lower_the_bound() {
        // The planner's own numbers (16 poses, 2.5 s at 500 Hz, 290 tension readings per dwell,
        // derived box): worst-anchor 1-sigma 4.05 mm without a tare, 3.23 mm with four tares of
        // the follower; the heights (the frame's tilt) dominate either way. With every load
        // cell's offset known as well it would be 1.72 mm: the tilt is limited by the load
        // cells' noise against the weight, not by the offsets alone.
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let inp = PlanInput {
            length_samples: 1250,
            tension_samples: 290,
            tare_samples: 290,
            min_tension_n: 5.0,
            grid: [9, 7, 6],
            ..input(&NOM, &b, &fol, 16)
        };
        let none = plan(&inp).unwrap();
        assert!(none.tare.iter().all(|&t| t == 0));
        let tared = plan(&PlanInput { tares: 4, ..inp.clone() }).unwrap();
        assert_eq!(tared.tare.iter().filter(|&&t| t == 0b1000).count(), 4);
        assert!(
            tared.worst_anchor_sigma_m < 0.85 * none.worst_anchor_sigma_m,
            "{} vs {}",
            tared.worst_anchor_sigma_m,
            none.worst_anchor_sigma_m
        );
        for (q, _) in tared.poses.iter().zip(&tared.tare).filter(|x| *x.1 != 0) {
            // The three position cables hold the platform alone, within the tension bounds.
            let t = static_tensions(&NOM, &b, &fol, 0.0, 3.0, *q).unwrap();
            assert!(t[..3].iter().all(|&x| (10.0..=250.0).contains(&x)), "{q:?}: {t:?}");
            assert_eq!(t[3], 0.0);
        }
    }

    #[test]
    fn longer_tares_lower_the_bound_and_without_tares_their_length_is_moot() {
        // A tare reads the slack cable's offset, which leaks into the frame's tilt through the
        // cable's horizontal direction: four times the tare readings, a smaller bound.
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let inp = PlanInput {
            length_samples: 1250,
            tension_samples: 320,
            tare_samples: 320,
            min_tension_n: 5.0,
            grid: [9, 7, 6],
            tares: 4,
            tare_each_cable: true,
            ..input(&NOM, &b, &fol, 16)
        };
        let short = plan(&inp).unwrap();
        let long = plan(&PlanInput { tare_samples: 1280, ..inp.clone() }).unwrap();
        assert!(
            long.worst_anchor_sigma_m < 0.95 * short.worst_anchor_sigma_m,
            "{} vs {}",
            long.worst_anchor_sigma_m,
            short.worst_anchor_sigma_m
        );
        let none = PlanInput { tares: 0, ..inp.clone() };
        assert_eq!(plan(&none).unwrap(), plan(&PlanInput { tare_samples: 1280, ..none.clone() }).unwrap());
    }

    #[test]
    fn tares_through_every_cable_hold_the_platform_with_three_others_and_lower_the_bound() {
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let inp = PlanInput {
            length_samples: 1250,
            tension_samples: 320,
            tare_samples: 320,
            min_tension_n: 5.0,
            grid: [9, 7, 6],
            tares: 6,
            ..input(&NOM, &b, &fol, 16)
        };
        let followers_only = plan(&inp).unwrap();
        let each = plan(&PlanInput { tare_each_cable: true, ..inp.clone() }).unwrap();
        assert!(
            each.worst_anchor_sigma_m < 0.95 * followers_only.worst_anchor_sigma_m,
            "{} vs {}",
            each.worst_anchor_sigma_m,
            followers_only.worst_anchor_sigma_m
        );
        let masks: Vec<u8> = each.tare.iter().copied().filter(|&m| m != 0).collect();
        assert!(masks.len() >= 4, "{masks:?}");
        assert!(masks.iter().any(|&m| m != 0b1000), "a position cable is tared: {masks:?}");
        for (q, &m) in each.poses.iter().zip(&each.tare).filter(|x| *x.1 != 0) {
            // One cable slack, the three others hold the platform within the tension bounds.
            assert_eq!(m.count_ones(), 1, "{m:#b}");
            let slack: Vec<bool> = (0..4).map(|j| m & (1 << j) != 0).collect();
            let t = static_tensions(&NOM, &b, &slack, 0.0, 3.0, *q).unwrap();
            for j in 0..4 {
                if slack[j] {
                    assert_eq!(t[j], 0.0);
                } else {
                    assert!((10.0..=250.0).contains(&t[j]), "{q:?} with {m:#b} slack: {t:?}");
                }
            }
        }
    }

    #[test]
    fn fitted_stiffness_widens_the_bound_and_a_tight_prior_gives_the_held_one() {
        // EA 1e5 N (a soft cable: up to ~2 mm of stretch at these tensions), 16 poses with
        // tares. Fitting each cable's stiffness within +-15 % costs anchor precision; a prior
        // of +-1e-6 is the stiffness held, which the ideal model's bound equals to the stretch's
        // small change of the Jacobian.
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let base = PlanInput {
            length_samples: 1250,
            tension_samples: 320,
            tare_samples: 320,
            min_tension_n: 5.0,
            tares: 6,
            ..input(&NOM, &b, &fol, 16)
        };
        let ideal = plan(&base).unwrap();
        let st = |rel_sigma| Some(crate::bundle::Stretch { ea_n: 1e5, rel_sigma });
        let fitted = plan(&PlanInput { stretch: st(0.15), ..base.clone() }).unwrap();
        let held = plan(&PlanInput { stretch: st(0.0), ..base.clone() }).unwrap();
        let tight = plan(&PlanInput { stretch: st(1e-6), ..base.clone() }).unwrap();
        eprintln!(
            "worst-anchor sigma: ideal {:.3} mm, stiffness held {:.3} mm, fitted +-15 % {:.3} mm, +-1e-6 {:.3} mm",
            ideal.worst_anchor_sigma_m * 1e3,
            held.worst_anchor_sigma_m * 1e3,
            fitted.worst_anchor_sigma_m * 1e3,
            tight.worst_anchor_sigma_m * 1e3
        );
        assert!(fitted.worst_anchor_sigma_m > 1.01 * held.worst_anchor_sigma_m);
        assert!((tight.worst_anchor_sigma_m / held.worst_anchor_sigma_m - 1.0).abs() < 1e-3);
        assert!((held.worst_anchor_sigma_m / ideal.worst_anchor_sigma_m - 1.0).abs() < 0.05);
        // No load cells: the stretch is not modelled (as the calibration), the bound unchanged.
        let enc = PlanInput { loadcell_sigma_n: None, ..base.clone() };
        assert_eq!(plan(&PlanInput { stretch: st(0.15), ..enc.clone() }).unwrap(), plan(&enc).unwrap());
    }

    #[test]
    fn the_probability_of_exceeding_matches_a_case_worked_by_hand() {
        // Only anchor 0's height uncertain (sigma 1 mm): the alignment's vertical translation
        // takes a quarter of its error off it (and puts a quarter on each other anchor), so the
        // worst aligned error is 0.75 |e|: P(worst > 0.75 x 2.5 mm) = 2 Phi(-2.5) = 0.012419.
        let mut p = plan(&input(&NOM, &[[0.0; 3]; 4], &[false, false, false, true], 10)).unwrap();
        p.anchor_cov_m2 = vec![0.0; 144];
        p.anchor_cov_m2[2 * 12 + 2] = 1e-6;
        let (pr, up) = p.worst_exceeds_probability(&NOM, 0.75 * 2.5e-3, 1.0, 1_000_000);
        // Deterministic draws; 5 standard errors of the estimate.
        assert!((pr - 0.012419).abs() < 5.0 * (0.012419f64 * 0.987581 / 1e6).sqrt(), "{pr}");
        assert!(up > pr && up < pr + 1e-3);
        // Twice the sigma: far more often.
        let (p2, _) = p.worst_exceeds_probability(&NOM, 0.75 * 2.5e-3, 2.0, 100_000);
        assert!(p2 > 0.2, "{p2}");
    }

    #[test]
    fn impossible_plans_are_refused_with_the_reason() {
        let b = [[0.0; 3]; 4];
        let fol = [false, false, false, true];
        let three = &NOM[..3];
        assert!(matches!(plan(&input(three, &b[..3], &fol[..3], 10)), Err(PlanError::TooFewCables { n: 3 })));
        let all = [false; 4];
        assert!(matches!(plan(&input(&NOM, &b, &all, 10)), Err(PlanError::PositionCables { count: 4 })));
        let tight = PlanInput { min_tension_n: 40.0, ..input(&NOM, &b, &fol, 10) };
        let e = plan(&tight).unwrap_err();
        assert!(matches!(e, PlanError::TooFewFeasible { .. }), "{e}");
        assert!(e.to_string().contains("motion.dwell_poses"), "{e}");
    }
}
