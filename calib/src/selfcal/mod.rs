//! Self-calibration without a tracker: anchors, encoder offsets, load-cell offsets (and
//! optionally the platform mass) from the encoders and the load cells alone, on a recording of
//! static dwell poses.
//!
//! # Model
//!
//! The platform positions are unknowns beside the robot's parameters, one per dwell (a stretch
//! where every encoder is still, [`dwell`]). Each dwell contributes the averaged encoder lengths
//! and, with load cells, the static equilibrium of the averaged tensions:
//!
//! ```text
//! l_kj = |P_k + b_j - A_j| + L0_j                                  (n equations, sigma_enc^2 / N)
//! sum_j (f_kj - c_j) v_kj + m (0, 0, -g) = 0                       (3 equations, sigma_f^2 / N)
//! ```
//!
//! `c_j`: the load cell's offset (unknown: 0.5 N unmodelled shifts inter-anchor distances by
//! 5-11 mm), `v_kj`: unit vector from the platform point to the anchor. A redundant robot (more
//! cables than the three position unknowns) over-determines each pose; a 3-cable robot does not,
//! and is refused ([`SelfCalError::TooFewCables`]). The problem and its solver (Schur complement
//! on the 3x3 pose blocks, time linear in the dwells) are in [`solve`].
//!
//! # Frame (gauge)
//!
//! Lengths and forces do not see where the robot stands: translating the whole robot, or turning
//! it about the vertical, changes no measurement (without load cells gravity is unknown too and
//! any rotation is free). The frame is fixed by the nominal anchors of the configuration: the
//! estimate is the one whose anchors are best aligned with the nominal ones by a translation and
//! a rotation about the vertical (any rotation without tensions). These are linear constraints
//! on the anchors, exact for the least-squares alignment:
//!
//! ```text
//! sum_j (A_j - N_j) = 0,     sum_j (N_j - N_mean) x A_j = 0   (z component; all three without tensions)
//! ```
//!
//! Quantities that do not depend on the frame are reported with their uncertainties: the
//! inter-anchor distances, the offsets `L0`, the load-cell offsets, and (with tensions, which
//! fix the vertical) the anchor heights relative to anchor 0.
//!
//! # Uncertainty, refusal
//!
//! The covariance is the inverse Fisher information at the solution in that frame (the
//! Cramér–Rao bound of the recording), scaled up by the a-posteriori variance factor
//! `chi2 / dof` when above 1. A parameter whose sigma exceeds `weak_sigma_m` is returned with a
//! warning; beyond `max_sigma_m`, or when the information is singular beyond the frame, the
//! calibration is refused, naming the quantity and what to record instead (poses spanning the
//! height and the width of the workspace, the load cells).
//!
//! # Priors from the design
//!
//! With [`SelfCalOptions::priors`] (a configuration's `anchor_sigma_m` and `l0_sigma_m`) each
//! anchor coordinate and offset with a tolerance is a pseudo-reading of its design value, one
//! row of the least squares ([`solve::Problem::design`]), counted in the degrees of freedom: the
//! estimate is maximum a posteriori. Anchor priors are in the configuration's frame, so they fix
//! the frame themselves: the directions of the frame (translations, the rotation(s) above) they
//! fix are released from the nominal alignment ([`Frame::DesignPriors`] when they fix all);
//! without them the convention above stays. The reported sigmas are the posterior's, the
//! readings' information scaled down by the variance factor (when above 1) and the priors'
//! taken as given, so each is at most its prior's; [`SelfCalReport::data_share`] says, per
//! parameter, how much came from the recording (`1 - sigma_post^2 / sigma_prior^2`). A
//! parameter with a prior is never refused as too uncertain, and a recording of a few poses
//! (at least three, the priors counted among the readings) is calibrated instead of refused.
//!
//! # Start and the mirror solution
//!
//! The start is the nominal anchors. Positions come from the force balance at each dwell
//! (tensions) or from the workspace centre below the anchors (encoders only), then the
//! offsets and positions are alternated (median offset, Gauss–Newton per pose) with the anchors
//! held, before the joint solve. The mirror image of the poses above the anchor plane fits the
//! lengths but not gravity: a solution with the poses above the anchors, or whose
//! `chi2 / dof` fails the chi-square test at a 1e-3 false-alarm rate, is retried from the
//! mirrored poses and the better fit kept; a fit that still fails is reported (note), not hidden.

pub mod align;
pub mod dwell;
pub mod plan;
pub mod rest;
pub mod solve;

use crate::{Params, Sigmas};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use std::fmt;
use taut_config::recording::Recording;
use taut_config::RobotConfig;

use solve::{Layout, Problem, State, G};

/// Options of [`calibrate_without_tracker`].
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCalOptions {
    /// Encoder noise of one reading, 1-sigma, m.
    pub encoder_sigma_m: f64,
    /// Load-cell noise of one reading, 1-sigma, N; `None`: the pooled scatter within the dwells.
    pub loadcell_sigma_n: Option<f64>,
    /// Tensions below this are loose: the cable's length is not used at that dwell, N.
    pub min_tension_n: f64,
    /// Platform mass, kg (known, or the start when estimated).
    pub mass_kg: f64,
    /// Estimate the mass too.
    pub estimate_mass: bool,
    /// Use the load cells (when the recording has tensions).
    pub use_tensions: bool,
    /// Warn when a parameter's 1-sigma exceeds this, m.
    pub weak_sigma_m: f64,
    /// Refuse when a parameter's 1-sigma exceeds this, m.
    pub max_sigma_m: f64,
    /// Shortest dwell, samples.
    pub min_dwell_samples: usize,
    /// A recording with too few rests is cut into moving windows of this length, s (0: never;
    /// [`dwell::windows`]).
    pub window_s: f64,
    /// LM iteration limit per solve.
    pub max_iterations: usize,
    /// The cables' stretch under tension (with the load cells): `None`, the ideal model; a
    /// datasheet stiffness with its tolerance (`rel_sigma` above 0: each cable's EA fitted within
    /// it; 0: held), as the tracker's refinement ([`crate::bundle::Stretch`]).
    pub stretch: Option<crate::bundle::Stretch>,
    /// The design's priors, one per cable: means and 1-sigmas of `[A_x, A_y, A_z, L0]`
    /// (`RobotConfig::priors`; a non-finite mean or sigma: none for that parameter). With them
    /// the estimate is maximum a posteriori (see "Priors from the design" above).
    pub priors: Option<Vec<([f64; 4], [f64; 4])>>,
}

/// The moving windows' length, s: long enough for a dozen tension readings at 62 per second
/// and 40 encoder rows at 200 Hz (the batch-means inflation), short enough that the platform's
/// path is straight over it and its acceleration is resolved by the windows' poses.
pub const WINDOW_S: f64 = 0.2;

/// Fewest rows in a moving window.
const MIN_WINDOW_ROWS: usize = 4;

/// Most travel of any cable within a moving window, m: the window's path is then straight
/// enough that the curvature correction of its mean lengths (`curvature`) holds to a
/// fraction of a micrometre.
pub const MAX_WINDOW_TRAVEL_M: f64 = 0.05;

impl SelfCalOptions {
    /// From a robot configuration (`[calibration]` and the platform mass).
    pub fn from_config(cfg: &RobotConfig) -> Self {
        let c = &cfg.calibration;
        SelfCalOptions {
            encoder_sigma_m: c.encoder_sigma_m,
            loadcell_sigma_n: None,
            min_tension_n: c.min_tension_n,
            mass_kg: cfg.robot.mass_kg,
            estimate_mass: false,
            use_tensions: true,
            weak_sigma_m: c.weak_sigma_m,
            max_sigma_m: c.max_sigma_m,
            min_dwell_samples: 20,
            window_s: WINDOW_S,
            max_iterations: 200,
            // `[calibration] cable_ea_sigma_n` above 0: `cable_ea_n` is a datasheet value.
            stretch: (c.cable_ea_sigma_n > 0.0 && c.cable_ea_n > 0.0 && c.cable_ea_n.is_finite())
                .then(|| crate::bundle::Stretch { ea_n: c.cable_ea_n, rel_sigma: c.cable_ea_sigma_n / c.cable_ea_n }),
            priors: cfg.priors(),
        }
    }
}

/// How the frame of the result is fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame {
    /// Best translation and rotation about the vertical onto the nominal anchors (gravity fixes
    /// the vertical).
    NominalTranslationYaw,
    /// Best translation and rotation onto the nominal anchors (no tensions: the vertical is not
    /// observed either).
    NominalRigid,
    /// The configuration's own frame, fixed by the design's priors on the anchors (they fix
    /// every direction the readings leave free).
    DesignPriors,
}

/// A frame-free quantity and its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Value (m, N or kg).
    pub value: f64,
    /// 1-sigma, scaled by the variance factor when above 1.
    pub sigma: f64,
    /// Cramér–Rao bound (the unscaled 1-sigma).
    pub crb: f64,
}

/// Which quantity a refusal or warning is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Anchor `j`, coordinate `axis` (0 x, 1 y, 2 z) in the aligned frame.
    Anchor(usize, usize),
    /// Encoder offset of cable `j`.
    Offset(usize),
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Quantity::Anchor(j, a) => write!(f, "anchor of cable {} {}", j + 1, ["x", "y", "z"][a.min(2)]),
            Quantity::Offset(j) => write!(f, "offset L0 of cable {}", j + 1),
        }
    }
}

/// What the recording lacks, for the advice in a refusal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    /// Standard deviation of the dwell heights, m.
    pub height_m: f64,
    /// Standard deviation of the dwell positions horizontally (the smaller axis), m.
    pub width_m: f64,
    /// Tensions were used.
    pub tensions: bool,
}

impl Spread {
    fn advice(&self) -> String {
        let mut a = Vec::new();
        if self.height_m < 0.2 * self.width_m {
            a.push(format!(
                "the poses lie nearly in one horizontal plane (heights spread {:.0} mm): add poses spanning the height of the workspace",
                self.height_m * 1e3
            ));
        }
        if self.width_m < 0.2 * self.height_m.max(0.25) {
            a.push(format!("the poses span little width ({:.0} mm): add poses across the workspace", self.width_m * 1e3));
        }
        if !self.tensions {
            a.push("record the load cells too (gravity then fixes the vertical and the shape)".into());
        }
        if a.is_empty() {
            a.push("record more dwell poses spread through the height and the width of the workspace".into());
        }
        a.join("; ")
    }
}

/// Why [`calibrate_without_tracker`] gave no result.
#[derive(Debug, Clone, PartialEq)]
pub enum SelfCalError {
    /// Fewer than four cables: the lengths carry no information beyond the pose.
    TooFewCables {
        /// Cables.
        n: usize,
    },
    /// No nominal anchors: no start and no frame.
    NoNominalAnchors,
    /// The priors do not match the recording's cables.
    PriorCount {
        /// Length columns in the recording.
        recording: usize,
        /// Cables with priors.
        priors: usize,
    },
    /// Platform points or nominal anchors do not match the recording's cables.
    CableCount {
        /// Length columns in the recording.
        recording: usize,
        /// Platform points.
        platform_points: usize,
        /// Nominal anchors.
        nominal: usize,
    },
    /// Too few dwells for the unknowns.
    TooFewDwells {
        /// Dwells found.
        found: usize,
        /// Dwells needed.
        needed: usize,
        /// Runs dropped because the encoders crept.
        drifting: usize,
        /// Why the recording's motion, cut into moving windows, did not calibrate either
        /// (`None`: not tried).
        moving: Option<String>,
    },
    /// The information is singular beyond the frame.
    Singular {
        /// What to record instead.
        advice: String,
    },
    /// A parameter's predicted uncertainty is beyond the tolerance.
    TooUncertain {
        /// The worst quantity.
        quantity: Quantity,
        /// Its 1-sigma, m.
        sigma_m: f64,
        /// The tolerance, m.
        max_sigma_m: f64,
        /// What to record instead.
        advice: String,
    },
    /// The iteration produced non-finite numbers.
    Diverged,
}

impl fmt::Display for SelfCalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SelfCalError::TooFewCables { n } => write!(
                f,
                "a {n}-cable robot cannot calibrate itself without a tracker: its {n} lengths only fix the platform's position, they carry no information on the anchors, and the load cells alone give cm-level anchors that follow every load-cell offset; record with a tracker (e.g. the three-phase start-up with `[tracker]`)"
            ),
            SelfCalError::NoNominalAnchors => write!(
                f,
                "calibration without a tracker needs the nominal anchors (`anchor = [x, y, z]` in every [[cable]], a tape measure to ~20 cm is enough): they are the start and define the frame"
            ),
            SelfCalError::CableCount { recording, platform_points, nominal } => write!(
                f,
                "the recording has {recording} cables, the configuration {platform_points} platform points and {nominal} nominal anchors; use the configuration of the robot that made the recording"
            ),
            SelfCalError::PriorCount { recording, priors } => {
                write!(f, "the recording has {recording} cables, the priors {priors}; use the configuration of the robot that made the recording")
            }
            SelfCalError::TooFewDwells { found, needed, drifting, moving } => {
                write!(
                    f,
                    "only {found} dwell poses found (stretches where every encoder is still), at least {needed} needed ({drifting} stretches dropped because the encoders crept); hold the platform still at each pose for a second or more, at poses spread through the height and the width of the workspace"
                )?;
                match moving {
                    Some(why) => write!(f, " (the motion between them, as a slow continuous motion, did not calibrate either: {why})"),
                    None => Ok(()),
                }
            }
            SelfCalError::Singular { advice } => {
                write!(f, "the recording does not determine the robot's geometry (the information is singular beyond the frame): {advice}")
            }
            SelfCalError::TooUncertain { quantity, sigma_m, max_sigma_m, advice } => write!(
                f,
                "{quantity} is too weakly determined by this recording (1-sigma {:.1} mm, above calibration.max_sigma_m = {:.1} mm): {advice}",
                sigma_m * 1e3,
                max_sigma_m * 1e3
            ),
            SelfCalError::Diverged => {
                write!(f, "the calibration diverged (non-finite numbers); check that the nominal anchors and the platform mass are right")
            }
        }
    }
}

impl std::error::Error for SelfCalError {}

/// What [`calibrate_without_tracker`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCalReport {
    /// Anchors (in the frame of [`SelfCalReport::frame`]) and encoder offsets.
    pub params: Params,
    /// 1-sigma of each anchor coordinate in that frame and of each offset, m (the readings'
    /// information scaled down by the variance factor when above 1; with priors, the posterior).
    pub sigma: Sigmas,
    /// Per cable, `[A_x, A_y, A_z, L0]`: the share of the estimate from the recording,
    /// `1 - sigma_posterior^2 / sigma_prior^2` (0: the design's prior alone, 1: the readings
    /// alone); NaN where the parameter has no prior ([`SelfCalOptions::priors`]).
    pub data_share: Vec<[f64; 4]>,
    /// Cramér–Rao bound on the anchors: `sqrt(trace(Cov_A) / n)`, the expected RMS error over
    /// anchors after the frame alignment, m.
    pub anchor_rms_crb_m: f64,
    /// Cramér–Rao bound on the anchors' shape: the expected RMS error over anchors after the best
    /// alignment by any translation and rotation (the tilt, which only gravity fixes, removed), m.
    /// Equal to `anchor_rms_crb_m` without tensions.
    pub shape_rms_crb_m: f64,
    /// Inter-anchor distances `(i, j, distance)`, i < j.
    pub distances: Vec<(usize, usize, Estimate)>,
    /// Heights relative to anchor 0 (with tensions only).
    pub heights: Option<Vec<Estimate>>,
    /// Load-cell offsets, N (with tensions).
    pub loadcell_offsets: Option<Vec<Estimate>>,
    /// The mass, kg, when estimated.
    pub mass: Option<Estimate>,
    /// With [`SelfCalOptions::stretch`] and tensions: each cable's stiffness EA, N (fitted
    /// within the tolerance, or the datasheet value held).
    pub cable_ea_n: Option<Vec<Estimate>>,
    /// The dwell positions, m, in the frame.
    pub poses: Vec<[f64; 3]>,
    /// The dwells used (moving windows when [`SelfCalReport::moving`]).
    pub dwells: Vec<dwell::Dwell>,
    /// The poses are moving windows of a recording without enough rests ([`dwell::windows`]).
    pub moving: bool,
    /// Samples inside the dwells.
    pub samples_used: usize,
    /// How the frame is fixed.
    pub frame: Frame,
    /// True when the load cells entered.
    pub used_tensions: bool,
    /// Load-cell noise used, N (one reading).
    pub loadcell_sigma_n: f64,
    /// Encoder noise used, m (one reading: the configured one or the measured scatter within
    /// the dwells, the larger).
    pub encoder_sigma_m: f64,
    /// Variance inflation of a dwell's mean encoder reading and mean tension over independent
    /// readings (repeated or correlated readings, [`dwell`]).
    pub inflation: (f64, f64),
    /// Whitened chi-square and its degrees of freedom.
    pub chi2: f64,
    /// Degrees of freedom.
    pub dof: usize,
    /// True when `chi2` passes the chi-square test at a 1e-3 false-alarm rate.
    pub chi2_ok: bool,
    /// LM iterations, all solves.
    pub iterations: usize,
    /// Full covariance of the globals (anchors, offsets, load-cell offsets, mass) in the frame,
    /// unscaled (the Cramér–Rao bound).
    pub covariance: DMatrix<f64>,
    /// Weakly determined parameters (1-sigma above `weak_sigma_m`), m.
    pub weak: Vec<(Quantity, f64)>,
    /// Things a person should know.
    pub notes: Vec<String>,
}

/// Calibrates anchors and offsets from the dwells of `rec` without using its tracker columns.
pub fn calibrate_without_tracker(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    nominal: Option<&[[f64; 3]]>,
    opts: &SelfCalOptions,
) -> Result<SelfCalReport, SelfCalError> {
    let n = rec.n_cables;
    let nominal = nominal.ok_or(SelfCalError::NoNominalAnchors)?;
    if platform_points.len() != n || nominal.len() != n {
        return Err(SelfCalError::CableCount { recording: n, platform_points: platform_points.len(), nominal: nominal.len() });
    }
    if n < 4 {
        return Err(SelfCalError::TooFewCables { n });
    }
    if let Some(p) = opts.priors.as_ref().filter(|p| p.len() != n) {
        return Err(SelfCalError::PriorCount { recording: n, priors: p.len() });
    }
    let rests = dwell::find(rec, opts.encoder_sigma_m.max(1e-7), opts.min_dwell_samples);
    let needed = PoseSetup::of(rec, &rests, opts).needed;
    if rests.dwells.len() >= needed {
        return solve_poses(rec, platform_points, nominal, opts, rests, false);
    }
    let too_few =
        |moving: Option<String>| SelfCalError::TooFewDwells { found: rests.dwells.len(), needed, drifting: rests.drifting, moving };
    if opts.window_s <= 0.0 {
        return Err(too_few(None));
    }
    // Too few rests: a slow continuous motion, each window a pose with its inertia. When that
    // fails too, the refusal is the rests' (what to record), with the windows' reason beside it.
    let w = dwell::windows(rec, opts.encoder_sigma_m.max(1e-7), opts.window_s, MAX_WINDOW_TRAVEL_M, MIN_WINDOW_ROWS);
    let needed_w = PoseSetup::of(rec, &w, opts).needed;
    if w.dwells.len() < needed_w {
        return Err(too_few(Some(format!("{} moving windows, {needed_w} needed", w.dwells.len()))));
    }
    solve_poses(rec, platform_points, nominal, opts, w, true).map_err(|e| too_few(Some(e.to_string())))
}

/// What the poses can determine: with every tension at some pose, the load-cell offsets (and
/// the mass, the stiffness) beside the anchors and offsets, in the frame that gravity fixes.
struct PoseSetup {
    tensions: bool,
    stretch: Option<crate::bundle::Stretch>,
    lay: Layout,
    frame: Frame,
    /// Poses needed: enough that the globals are over-determined twice (each adds rows - 3);
    /// the priors' pseudo-readings count towards it.
    needed: usize,
}

/// Fewest poses with the design's priors: with them a recording that excites little gives an
/// estimate (the prior where the poses say nothing), and three poses still leave the
/// chi-square test some degrees of freedom.
const MIN_POSES_WITH_PRIORS: usize = 3;

/// The design's prior rows of `priors` in the layout `lay`: `(global index, mean, 1-sigma)`
/// for each parameter with a finite mean and a finite positive sigma.
fn design_rows(priors: Option<&[([f64; 4], [f64; 4])]>, lay: Layout) -> Vec<(usize, f64, f64)> {
    let cables = priors.unwrap_or_default().iter().enumerate().take(lay.n);
    cables.flat_map(|(j, p)| crate::prior_terms(p).map(move |(k, mu, sd)| (if k < 3 { lay.a(j) + k } else { lay.l0(j) }, mu, sd))).collect()
}

impl PoseSetup {
    fn of(rec: &Recording, found: &dwell::Dwells, opts: &SelfCalOptions) -> PoseSetup {
        let n = rec.n_cables;
        let tensions = opts.use_tensions && rec.f.is_some() && found.dwells.iter().any(|d| d.nf.iter().all(|&c| c > 0));
        let stretch = opts.stretch.filter(|st| tensions && st.ea_n > 0.0 && st.ea_n.is_finite());
        let lay = Layout { n, offsets: tensions, mass: tensions && opts.estimate_mass, ea: stretch.is_some_and(|st| st.rel_sigma > 0.0) };
        let frame = if tensions { Frame::NominalTranslationYaw } else { Frame::NominalRigid };
        let per_dwell = n + if tensions { 3 } else { 0 } - 3;
        let free = lay.count() - if tensions { 4 } else { 6 };
        let priors = design_rows(opts.priors.as_deref(), lay).len();
        let needed = if priors == 0 {
            (2 * free).div_ceil(per_dwell).max(10)
        } else {
            (2 * free.saturating_sub(priors)).div_ceil(per_dwell).max(MIN_POSES_WITH_PRIORS)
        };
        PoseSetup { tensions, stretch, lay, frame, needed }
    }
}

/// The calibration on the poses `found`: rests, or the windows of a moving recording
/// (`moving`).
fn solve_poses(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    nominal: &[[f64; 3]],
    opts: &SelfCalOptions,
    found: dwell::Dwells,
    moving: bool,
) -> Result<SelfCalReport, SelfCalError> {
    let n = rec.n_cables;
    let PoseSetup { tensions, stretch, lay, frame, .. } = PoseSetup::of(rec, &found, opts);
    let design = design_rows(opts.priors.as_deref(), lay);
    let (c, d) = gauge(nominal, lay, frame);
    let (c, d, fixed) = prior_gauge(c, d, nominal, lay, &design);
    let frame = if fixed.is_some_and(|(f, k)| f == k) { Frame::DesignPriors } else { frame };
    let free = lay.count() - c.nrows();
    let sigma_f = opts.loadcell_sigma_n.or_else(|| found.loadcell_sigma()).unwrap_or(0.3).max(1e-3);
    // The variance of a dwell mean: one reading's variance (the encoders' at least the
    // configured one) times the long-run inflation of correlated or repeated readings
    // ([`dwell`]); the fit divides by the rows averaged.
    let sigma_l = opts.encoder_sigma_m.max(found.length_row_sigma.unwrap_or(0.0)).max(1e-7);
    let pr = Problem {
        lay,
        b: platform_points,
        dwells: &found.dwells,
        var_l: sigma_l * sigma_l * found.length_inflation,
        var_f: sigma_f * sigma_f * found.tension_inflation,
        mass: opts.mass_kg,
        min_tension_n: opts.min_tension_n,
        stretch,
        design: &design,
        c,
        d,
    };
    let mut notes = Vec::new();
    let z_plane = nominal.iter().map(|a| a[2]).fold(f64::INFINITY, f64::min);
    let start = start(&pr, nominal);
    let (mut s, mut iters, mut rep) = solve_from(&pr, start, opts.max_iterations);
    let dof = rep.rows.saturating_sub(3 * found.dwells.len() + free).max(1);
    let mean_z = |s: &State| s.p.iter().map(|p| p[2]).sum::<f64>() / s.p.len() as f64;
    let ok = |chi2: f64| chi2 <= chi2_quantile(dof, 3.09);
    if !ok(rep.chi2) || mean_z(&s) > z_plane {
        // Retry from the mirror image of the poses in the anchor plane; keep the better fit.
        let mut m = s.clone();
        for p in &mut m.p {
            p[2] = 2.0 * z_plane - p[2];
        }
        let (s2, it2, rep2) = solve_from(&pr, m, opts.max_iterations);
        iters += it2;
        if rep2.chi2 < rep.chi2 && mean_z(&s2) <= z_plane {
            notes.push(format!(
                "restarted from the mirrored poses: chi2/dof {:.1} -> {:.2}",
                rep.chi2 / dof as f64,
                rep2.chi2 / dof as f64
            ));
            (s, rep) = (s2, rep2);
        }
    }
    // Moving windows: the platform's velocity and acceleration from the solved path; the mean
    // lengths corrected for the curvature of |P - A| along it, the equilibrium balancing
    // `m (a - g)`; solved again, twice (the second path from the first correction).
    let mut dwells = found.dwells.clone();
    if moving {
        let (t_mid, t_var): (Vec<f64>, Vec<f64>) = dwells
            .iter()
            .map(|w| {
                let t = &rec.t[w.start..w.end];
                let m = t.iter().sum::<f64>() / t.len() as f64;
                (m, t.iter().map(|x| (x - m).powi(2)).sum::<f64>() / t.len() as f64)
            })
            .unzip();
        for _ in 0..2 {
            let anchors: Vec<[f64; 3]> = (0..n).map(|j| s.anchor(j)).collect();
            let between = path_between(&found.dwells, &t_mid, &s.p);
            for (k, w) in dwells.iter_mut().enumerate() {
                let (vel, accel) = between[k].unwrap_or_else(|| path_within(w, &anchors, platform_points, s.p[k]));
                if tensions {
                    w.accel = accel;
                }
                for j in 0..n {
                    w.l[j] = found.dwells[k].l[j] - curvature(anchors[j], platform_points[j], s.p[k], vel, t_var[k]);
                }
            }
            let (s2, it2, rep2) = solve_from(&with_dwells(&pr, &dwells), s.clone(), opts.max_iterations);
            iters += it2;
            (s, rep) = (s2, rep2);
        }
        let peak = dwells.iter().map(|w| Vector3::from(w.accel).norm()).fold(0.0, f64::max);
        let inertia =
            if tensions { format!(", with its acceleration from the estimated path (largest {peak:.2} m/s²)") } else { String::new() };
        notes.push(format!(
            "no rests: {} windows of {:.2} s of the moving platform{inertia}; {} windows holding a jerk left out",
            dwells.len(),
            opts.window_s,
            found.drifting
        ));
    }
    let pr = with_dwells(&pr, &dwells);
    if !s.g.iter().all(|v| v.is_finite()) || !s.p.iter().flatten().all(|v| v.is_finite()) {
        return Err(SelfCalError::Diverged);
    }
    let spread = spread(&s.p, tensions);
    let w = pr.whitening(&s);
    let cov = solve::covariance(&pr, &s, &w).ok_or_else(|| SelfCalError::Singular { advice: spread.advice() })?;
    let vf = rep.chi2 / dof as f64;
    // With priors the variance factor scales the readings' information, not the priors' (whose
    // variances are given).
    let post = match design.is_empty() {
        true => None,
        false => Some(solve::posterior(&pr, &s, &w, vf.max(1.0)).ok_or_else(|| SelfCalError::Singular { advice: spread.advice() })?),
    };
    let chi2_ok = ok(rep.chi2);
    if !chi2_ok {
        notes.push(format!(
            "chi2/dof = {vf:.2} fails the chi-square test (1e-3 false-alarm rate): the readings disagree with the static model more than their noise (motion in the dwells, stretch, sag, a wrong mass or encoder sigma); sigmas scaled up by sqrt({vf:.2})"
        ));
    }
    if !rep.converged {
        notes.push(format!("the solver stopped at its iteration limit ({} iterations)", opts.max_iterations));
    }
    let scale = vf.max(1.0).sqrt();
    let sd = |i: usize| cov[(i, i)].max(0.0).sqrt();
    // The 1-sigma of `grad . g`: the posterior's with priors, else the bound scaled.
    let sigma_of = |grad: &DVector<f64>| match &post {
        Some(p) => (grad.transpose() * p * grad)[0].max(0.0).sqrt(),
        None => (grad.transpose() * &cov * grad)[0].max(0.0).sqrt() * scale,
    };
    let est = |value: f64, grad: &DVector<f64>| Estimate {
        value,
        sigma: sigma_of(grad),
        crb: (grad.transpose() * &cov * grad)[0].max(0.0).sqrt(),
    };
    let unit = |i: usize| DVector::from_fn(lay.count(), |k, _| if k == i { 1.0 } else { 0.0 });
    let sdp = |i: usize| match &post {
        Some(p) => p[(i, i)].max(0.0).sqrt(),
        None => sd(i) * scale,
    };
    let anchors: Vec<[f64; 3]> = (0..n).map(|j| s.anchor(j)).collect();
    let l0: Vec<f64> = (0..n).map(|j| s.g[lay.l0(j)]).collect();
    let anchor_sigma: Vec<[f64; 3]> = (0..n).map(|j| [0, 1, 2].map(|a| sdp(lay.a(j) + a))).collect();
    let l0_sigma: Vec<f64> = (0..n).map(|j| sdp(lay.l0(j))).collect();
    // Each parameter's prior 1-sigma (infinite: none) and the share of the data.
    let mut prior_sd = vec![[f64::INFINITY; 4]; n];
    for &(i, _, sg) in &design {
        let (j, k) = if i < 3 * n { (i / 3, i % 3) } else { (i - lay.l0(0), 3) };
        prior_sd[j][k] = sg;
    }
    let data_share: Vec<[f64; 4]> = (0..n)
        .map(|j| {
            let post_sd = [anchor_sigma[j][0], anchor_sigma[j][1], anchor_sigma[j][2], l0_sigma[j]];
            std::array::from_fn(|k| match prior_sd[j][k].is_finite() {
                true => (1.0 - (post_sd[k] / prior_sd[j][k]).powi(2)).clamp(0.0, 1.0),
                false => f64::NAN,
            })
        })
        .collect();
    // Refusal and warnings by the predicted uncertainty. With a prior a parameter's sigma is at
    // most the prior's: the refusal applies to the parameters the recording alone must
    // determine, and a weak one with a prior is named by its share of the data.
    let mut worst: Option<(Quantity, f64)> = None;
    let mut weak = Vec::new();
    for j in 0..n {
        let qs = (0..3).map(|a| (Quantity::Anchor(j, a), anchor_sigma[j][a], a)).chain([(Quantity::Offset(j), l0_sigma[j], 3)]);
        for (q, sg, k) in qs {
            let has_prior = prior_sd[j][k].is_finite();
            if !has_prior && worst.is_none_or(|(_, w)| sg > w) {
                worst = Some((q, sg));
            }
            if sg > opts.weak_sigma_m {
                weak.push((q, sg));
                if !has_prior {
                    notes.push(format!(
                        "{q} is weakly determined (1-sigma {:.1} mm, above calibration.weak_sigma_m): {}",
                        sg * 1e3,
                        spread.advice()
                    ));
                }
            }
            if has_prior && data_share[j][k] < 0.5 {
                notes.push(format!(
                    "{q} is mostly the design's prior ({:.0} % from the data; 1-sigma {:.1} mm of the prior's {:.1} mm)",
                    100.0 * data_share[j][k],
                    sg * 1e3,
                    prior_sd[j][k] * 1e3
                ));
            }
        }
    }
    if let Some((quantity, sigma_m)) = worst.filter(|(_, s)| !(*s <= opts.max_sigma_m)) {
        return Err(SelfCalError::TooUncertain { quantity, sigma_m, max_sigma_m: opts.max_sigma_m, advice: spread.advice() });
    }
    match fixed {
        Some((f, k)) if f == k => {
            notes.push("frame: the configuration's own, fixed by the design's priors on the anchors".to_string())
        }
        Some((f, k)) => notes.push(format!(
            "frame: the design's priors on the anchors fix {f} of its {k} free directions, the alignment with the nominal anchors the others"
        )),
        None => {}
    }
    let mut distances = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let (ai, aj) = (Vector3::from(anchors[i]), Vector3::from(anchors[j]));
            let dv = ai - aj;
            let dist = dv.norm();
            let u = dv / dist;
            let mut grad = DVector::zeros(lay.count());
            for a in 0..3 {
                grad[lay.a(i) + a] = u[a];
                grad[lay.a(j) + a] = -u[a];
            }
            distances.push((i, j, est(dist, &grad)));
        }
    }
    let heights = tensions.then(|| {
        (0..n)
            .map(|j| {
                let (zi, z0) = (lay.a(j) + 2, lay.a(0) + 2);
                est(anchors[j][2] - anchors[0][2], &(unit(zi) - unit(z0)))
            })
            .collect()
    });
    let loadcell_offsets = tensions.then(|| (0..n).map(|j| est(s.g[lay.c(j)], &unit(lay.c(j)))).collect());
    let mass = lay.mass.then(|| est(s.g[lay.m()], &unit(lay.m())));
    // EA_j = EA / s_j, its sigma to first order.
    let cable_ea_n = stretch.map(|st| {
        (0..n)
            .map(|j| match lay.ea {
                true => {
                    let (sf, var) = (s.g[lay.s(j)], cov[(lay.s(j), lay.s(j))]);
                    Estimate {
                        value: st.ea_n / sf,
                        sigma: st.ea_n * sdp(lay.s(j)) / (sf * sf),
                        crb: st.ea_n * var.max(0.0).sqrt() / (sf * sf),
                    }
                }
                false => Estimate { value: st.ea_n, sigma: 0.0, crb: 0.0 },
            })
            .collect()
    });
    let anchor_rms_crb_m = ((0..3 * n).map(|i| cov[(i, i)]).sum::<f64>() / n as f64).sqrt();
    let shape_rms_crb_m = shape_rms(&anchors, &cov);
    if !tensions {
        let vertical = if frame == Frame::DesignPriors { "the design's priors" } else { "the nominal anchors" };
        notes.insert(
            0,
            if rec.f.is_some() && opts.use_tensions {
                format!("no dwell has every tension: encoders only, the frame's vertical is taken from {vertical}")
            } else {
                format!("no tensions: encoders only, the frame's vertical is taken from {vertical}")
            },
        );
    }
    Ok(SelfCalReport {
        params: Params { anchors, l0 },
        sigma: Sigmas { anchors: anchor_sigma, l0: l0_sigma },
        data_share,
        anchor_rms_crb_m,
        shape_rms_crb_m,
        distances,
        heights,
        loadcell_offsets,
        mass,
        cable_ea_n,
        poses: s.p.clone(),
        samples_used: found.samples,
        dwells,
        moving,
        frame,
        used_tensions: tensions,
        loadcell_sigma_n: sigma_f,
        encoder_sigma_m: sigma_l,
        inflation: (found.length_inflation, found.tension_inflation),
        chi2: rep.chi2,
        dof,
        chi2_ok,
        iterations: iters,
        covariance: cov,
        weak,
        notes,
    })
}

/// `pr` on other dwells (the same poses, their accelerations changed).
fn with_dwells<'a>(pr: &Problem<'a>, dwells: &'a [dwell::Dwell]) -> Problem<'a> {
    Problem { dwells, c: pr.c.clone(), d: pr.d.clone(), ..*pr }
}

/// The platform's velocity and mean acceleration over each window of a moving recording whose
/// neighbours on both sides join it: the first and second differences of the solved poses `p`
/// at the windows' mean times `t` (the quadratic through the three). Precise (the poses'
/// noise over the windows' spacing) where the path is smooth across them; `None` for the
/// others (the ends, and next to a gap or a window left out for a jerk: a difference across
/// the jerk would smear it), which [`path_within`] estimates.
fn path_between(windows: &[dwell::Dwell], t: &[f64], p: &[[f64; 3]]) -> Vec<Option<([f64; 3], [f64; 3])>> {
    let k = windows.len();
    let joined = |a: usize| windows[a].end == windows[a + 1].start;
    let mut d = vec![None; k];
    for i in 1..k.saturating_sub(1) {
        if joined(i - 1) && joined(i) {
            let (h0, h1) = (t[i] - t[i - 1], t[i + 1] - t[i]);
            let (s0, s1): ([f64; 3], [f64; 3]) =
                (std::array::from_fn(|q| (p[i][q] - p[i - 1][q]) / h0), std::array::from_fn(|q| (p[i + 1][q] - p[i][q]) / h1));
            // The quadratic's slope at t_i weighs each side's by the other's length.
            let v = std::array::from_fn(|q| (s0[q] * h1 + s1[q] * h0) / (h0 + h1));
            let a = std::array::from_fn(|q| 2.0 * (s1[q] - s0[q]) / (h0 + h1));
            d[i] = Some((v, a));
        }
    }
    d
}

/// The platform's velocity and acceleration at a moving window's mean time, from its cables'
/// rates and second derivatives ([`dwell::Dwell::l_rate`]) at the pose `p` of the geometry
/// `anchors`, `b`: with `u_j` the unit vector from the anchor to the platform point and `rho_j`
/// the length,
///
/// ```text
/// l'_j  = u_j . V                                  -> V, least squares over the cables
/// l''_j = u_j . a + (|V|^2 - (u_j . V)^2) / rho_j  -> a
/// ```
///
/// Taken within the window, they need no neighbour, at the price of the noise of a curvature
/// fitted over one window (3.4e-3 m/s² for 100 readings of 50 µm over 0.2 s). Cables without a
/// rate (a rest) give zeros.
fn path_within(w: &dwell::Dwell, anchors: &[[f64; 3]], b: &[[f64; 3]], p: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let n = w.l_rate.len().min(anchors.len());
    if n < 3 {
        return ([0.0; 3], [0.0; 3]);
    }
    let mut ut = nalgebra::DMatrix::<f64>::zeros(n, 3);
    let mut rho = vec![0.0; n];
    for j in 0..n {
        let d = Vector3::new(p[0] + b[j][0] - anchors[j][0], p[1] + b[j][1] - anchors[j][1], p[2] + b[j][2] - anchors[j][2]);
        rho[j] = d.norm();
        let u = d / rho[j];
        for q in 0..3 {
            ut[(j, q)] = u[q];
        }
    }
    let Some(ch) = (ut.transpose() * &ut).cholesky() else { return ([0.0; 3], [0.0; 3]) };
    let solve = |y: DVector<f64>| -> [f64; 3] {
        let x = ch.solve(&(ut.transpose() * y));
        [x[0], x[1], x[2]]
    };
    let v = solve(DVector::from_iterator(n, w.l_rate.iter().copied()));
    let vv = Vector3::from(v);
    let a = solve(DVector::from_fn(n, |j, _| {
        let along = vv.dot(&Vector3::new(ut[(j, 0)], ut[(j, 1)], ut[(j, 2)]));
        w.l_curve[j] - (vv.norm_squared() - along * along) / rho[j]
    }));
    (v, a)
}

/// How much a window's mean length exceeds the length at its mean pose, m: along a path
/// `P(t) = P + V (t - t_mean) + ...`, `|P(t) + b - A|` curves by `|V x u|^2 / rho` (`u` the
/// cable's unit vector, `rho` its length), so its mean over the window's times (variance
/// `t_var`) is `rho + |V x u|^2 t_var / (2 rho)`. The acceleration's share moves the mean pose
/// itself and is in the pose.
fn curvature(anchor: [f64; 3], b: [f64; 3], p: [f64; 3], v: [f64; 3], t_var: f64) -> f64 {
    let d = Vector3::new(anchor[0] - p[0] - b[0], anchor[1] - p[1] - b[1], anchor[2] - p[2] - b[2]);
    let rho = d.norm();
    let vv = Vector3::from(v);
    let perp2 = (vv.norm_squared() - (vv.dot(&d) / rho).powi(2)).max(0.0);
    perp2 * t_var / (2.0 * rho)
}

/// Two LM solves, the force whitening re-evaluated at the first one's solution.
fn solve_from(pr: &Problem<'_>, mut s: State, max_iter: usize) -> (State, usize, solve::SolveReport) {
    let mut iters = 0;
    let mut rep = None;
    for _ in 0..2 {
        let w = pr.whitening(&s);
        let r = solve::lm(pr, &mut s, &w, max_iter);
        iters += r.iterations;
        rep = Some(r);
    }
    let w = pr.whitening(&s);
    let (chi2, rows) = pr.cost(&s, &w);
    let r =
        rep.map(|r| solve::SolveReport { chi2, rows, ..r }).unwrap_or(solve::SolveReport { iterations: 0, chi2, rows, converged: false });
    (s, iters, r)
}

/// Gauge constraints `C g = d` on the anchors: centroid and rotation(s) matched to `nominal`.
fn gauge(nominal: &[[f64; 3]], lay: Layout, frame: Frame) -> (DMatrix<f64>, DVector<f64>) {
    let n = nominal.len();
    let cn: [f64; 3] = std::array::from_fn(|a| nominal.iter().map(|p| p[a]).sum::<f64>() / n as f64);
    let rows = if frame == Frame::NominalTranslationYaw { 4 } else { 6 };
    let mut c = DMatrix::zeros(rows, lay.count());
    let mut d = DVector::zeros(rows);
    for a in 0..3 {
        for j in 0..n {
            c[(a, lay.a(j) + a)] = 1.0;
            d[a] += nominal[j][a];
        }
    }
    // sum_j (N_j - N_mean) x A_j = 0: row 3 the z component, rows 4-5 x and y.
    for j in 0..n {
        let r = [nominal[j][0] - cn[0], nominal[j][1] - cn[1], nominal[j][2] - cn[2]];
        let a = lay.a(j);
        c[(3, a)] = -r[1];
        c[(3, a + 1)] = r[0];
        if rows == 6 {
            c[(4, a + 1)] = -r[2];
            c[(4, a + 2)] = r[1];
            c[(5, a)] = r[2];
            c[(5, a + 2)] = -r[0];
        }
    }
    (c, d)
}

/// The gauge constraints `C g = d` ([`gauge`]) with the design's priors `design` on the
/// anchors: the frame's free directions (the rigid motions of the anchors `C` constrains) that
/// the priors fix are released, the others keep the nominal alignment. `(C, d)` unchanged and
/// `None` without anchor priors; else `Some((fixed, free))`, the directions the priors fix of the
/// frame's free ones.
fn prior_gauge(
    c: DMatrix<f64>,
    d: DVector<f64>,
    nominal: &[[f64; 3]],
    lay: Layout,
    design: &[(usize, f64, f64)],
) -> (DMatrix<f64>, DVector<f64>, Option<(usize, usize)>) {
    let anchors = 3 * lay.n;
    let w: Vec<(usize, f64)> = design.iter().filter(|r| r.0 < anchors).map(|&(i, _, sg)| (i, 1.0 / (sg * sg))).collect();
    if w.is_empty() {
        return (c, d, None);
    }
    let k = c.nrows();
    // An orthonormal basis of the frame's motions, and the priors' information along them.
    let q = c.transpose().qr().q();
    let mut m = DMatrix::zeros(k, k);
    for &(i, wi) in &w {
        let row = q.row(i);
        m += row.transpose() * row * wi;
    }
    let max_w = w.iter().map(|r| r.1).fold(0.0, f64::max);
    let eig = nalgebra::SymmetricEigen::new(m);
    let free: Vec<usize> = (0..k).filter(|&e| eig.eigenvalues[e] <= 1e-6 * max_w).collect();
    let mut g_nom = DVector::zeros(lay.count());
    for (j, a) in nominal.iter().enumerate() {
        for ax in 0..3 {
            g_nom[lay.a(j) + ax] = a[ax];
        }
    }
    let mut c2 = DMatrix::zeros(free.len(), lay.count());
    for (r, &e) in free.iter().enumerate() {
        c2.row_mut(r).copy_from(&(q.clone() * eig.eigenvectors.column(e)).transpose());
    }
    let d2 = &c2 * g_nom;
    (c2, d2, Some((k - free.len(), k)))
}

/// Start: nominal anchors, zero load-cell offsets, the known mass, the design's values where it
/// has priors; poses from the force balance (tensions) or the workspace centre, then offsets and
/// poses alternated with the anchors held.
fn start(pr: &Problem<'_>, nominal: &[[f64; 3]]) -> State {
    let lay = pr.lay;
    let n = lay.n;
    let mut g = DVector::zeros(lay.count());
    for j in 0..n {
        for a in 0..3 {
            g[lay.a(j) + a] = nominal[j][a];
        }
    }
    if lay.mass {
        g[lay.m()] = pr.mass;
    }
    if lay.ea {
        for j in 0..n {
            g[lay.s(j)] = 1.0;
        }
    }
    let z_top = nominal.iter().map(|a| a[2]).fold(f64::INFINITY, f64::min);
    let span = nominal.iter().map(|a| a[0]).fold(f64::NEG_INFINITY, f64::max) - nominal.iter().map(|a| a[0]).fold(f64::INFINITY, f64::min);
    let centre = [
        nominal.iter().map(|a| a[0]).sum::<f64>() / n as f64,
        nominal.iter().map(|a| a[1]).sum::<f64>() / n as f64,
        z_top - 0.3 * span.max(0.5),
    ];
    let mut s = State { g, p: vec![centre; pr.dwells.len()] };
    if lay.offsets {
        for k in 0..pr.dwells.len() {
            if let Some(p) = force_position(pr, &s, k, centre, z_top) {
                s.p[k] = p;
            }
        }
    }
    // The design's offsets, where it gives them, are the start and held through the
    // alternation; the others are the median of (reading - distance) over the dwells.
    let designed: Vec<bool> = (0..n).map(|j| pr.design.iter().any(|r| r.0 == lay.l0(j))).collect();
    for &(i, mu, _) in pr.design {
        s.g[i] = mu;
    }
    for round in 0..8 {
        for j in (0..n).filter(|&j| !designed[j]) {
            let mut v: Vec<f64> = pr
                .dwells
                .iter()
                .zip(&s.p)
                .filter(|(d, _)| d.l[j].is_finite())
                .map(|(d, p)| {
                    let a = s.anchor(j);
                    let b = pr.b[j];
                    d.l[j] - ((p[0] + b[0] - a[0]).powi(2) + (p[1] + b[1] - a[1]).powi(2) + (p[2] + b[2] - a[2]).powi(2)).sqrt()
                })
                .collect();
            if !v.is_empty() {
                v.sort_by(|x, y| x.total_cmp(y));
                s.g[lay.l0(j)] = v[v.len() / 2];
            }
        }
        if round == 7 {
            break;
        }
        for k in 0..pr.dwells.len() {
            s.p[k] = length_position(pr, &s, k, s.p[k], z_top);
        }
    }
    s
}

/// Position where the measured tensions balance the weight (anchors and mass of `s`).
fn force_position(pr: &Problem<'_>, s: &State, k: usize, from: [f64; 3], z_top: f64) -> Option<[f64; 3]> {
    let d = &pr.dwells[k];
    if !d.f.iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut p = Vector3::from(from);
    for _ in 0..30 {
        let mut f = Vector3::new(0.0, 0.0, -pr.mass * G);
        let mut jac = Matrix3::zeros();
        for j in 0..pr.lay.n {
            let a = Vector3::from(s.anchor(j)) - Vector3::from(pr.b[j]);
            let dv = a - p;
            let rho = dv.norm();
            let v = dv / rho;
            f += v * d.f[j];
            jac -= (Matrix3::identity() - v * v.transpose()) * (d.f[j] / rho);
        }
        let step = jac.lu().solve(&(-f))?;
        let len = step.norm();
        p += if len > 0.3 { step * (0.3 / len) } else { step };
        p[2] = p[2].min(z_top - 0.05);
        if len < 1e-7 {
            break;
        }
    }
    p.iter().all(|v| v.is_finite()).then(|| [p[0], p[1], p[2]])
}

/// Gauss–Newton on dwell `k`'s lengths alone (anchors and offsets of `s`).
fn length_position(pr: &Problem<'_>, s: &State, k: usize, from: [f64; 3], z_top: f64) -> [f64; 3] {
    let d = &pr.dwells[k];
    let mut p = Vector3::from(from);
    for _ in 0..10 {
        let (mut h, mut r) = (Matrix3::zeros(), Vector3::zeros());
        for j in 0..pr.lay.n {
            if !d.l[j].is_finite() {
                continue;
            }
            let x = p + Vector3::from(pr.b[j]);
            let dv = x - Vector3::from(s.anchor(j));
            let rho = dv.norm();
            let u = dv / rho;
            let e = d.l[j] - rho - s.g[pr.lay.l0(j)];
            h += u * u.transpose();
            r += u * e;
        }
        for a in 0..3 {
            h[(a, a)] *= 1.0 + 1e-6;
        }
        let Some(step) = h.lu().solve(&r) else { break };
        let len = step.norm();
        p += if len > 0.3 { step * (0.3 / len) } else { step };
        p[2] = p[2].min(z_top - 0.05);
        if len < 1e-8 {
            break;
        }
    }
    if p.iter().all(|v| v.is_finite()) {
        [p[0], p[1], p[2]]
    } else {
        from
    }
}

/// `sqrt(trace(Pi Cov_A Pi) / n)` with `Pi` the projector that removes the infinitesimal rigid
/// motions (translation, rotation about the anchors' centroid) from the anchor errors: the
/// linearised error after the best least-squares alignment by any translation and rotation.
fn shape_rms(anchors: &[[f64; 3]], cov: &DMatrix<f64>) -> f64 {
    let n = anchors.len();
    let c: [f64; 3] = std::array::from_fn(|a| anchors.iter().map(|p| p[a]).sum::<f64>() / n as f64);
    let mut g = DMatrix::zeros(3 * n, 6);
    for (j, p) in anchors.iter().enumerate() {
        let r = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        for a in 0..3 {
            g[(3 * j + a, a)] = 1.0;
        }
        // omega x r for omega = e_x, e_y, e_z.
        g[(3 * j + 1, 3)] = -r[2];
        g[(3 * j + 2, 3)] = r[1];
        g[(3 * j, 4)] = r[2];
        g[(3 * j + 2, 4)] = -r[0];
        g[(3 * j, 5)] = -r[1];
        g[(3 * j + 1, 5)] = r[0];
    }
    let Some(gtg_inv) = (g.transpose() * &g).try_inverse() else { return f64::NAN };
    let pi = DMatrix::<f64>::identity(3 * n, 3 * n) - &g * gtg_inv * g.transpose();
    let ca = cov.view((0, 0), (3 * n, 3 * n)).into_owned();
    ((&pi * ca * &pi).trace().max(0.0) / n as f64).sqrt()
}

fn spread(p: &[[f64; 3]], tensions: bool) -> Spread {
    let k = p.len().max(1) as f64;
    let mean: [f64; 3] = std::array::from_fn(|a| p.iter().map(|q| q[a]).sum::<f64>() / k);
    let sd = |a: usize| (p.iter().map(|q| (q[a] - mean[a]).powi(2)).sum::<f64>() / k).sqrt();
    Spread { height_m: sd(2), width_m: sd(0).min(sd(1)), tensions }
}

/// Upper quantile of the chi-square distribution with `dof` degrees of freedom at the standard
/// normal quantile `z` (Wilson–Hilferty; 3.09 gives the 1e-3 false-alarm level).
pub fn chi2_quantile(dof: usize, z: f64) -> f64 {
    let k = dof.max(1) as f64;
    let h = 2.0 / (9.0 * k);
    k * (1.0 - h + z * h.sqrt()).powi(3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauge_rows_vanish_on_rigid_motions_of_the_nominal_anchors() {
        // C g = d holds for the nominal anchors, and the rotation rows are the derivative of the
        // Procrustes cross term: a small yaw of the nominal changes row 3 by yaw * sum |r_xy|^2.
        let nom = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.1], [-3.5, 1.75, 3.9], [-3.5, -1.75, 4.0]];
        let lay = Layout { n: 4, offsets: true, mass: false, ea: false };
        let (c, d) = gauge(&nom, lay, Frame::NominalRigid);
        let mut g = DVector::zeros(lay.count());
        for j in 0..4 {
            for a in 0..3 {
                g[3 * j + a] = nom[j][a];
            }
        }
        let r = &c * &g - &d;
        assert!(r.norm() < 1e-12, "{r}");
        // Translate: rows 0-2 change by 4 x the shift, the rotation rows not at all.
        let mut t = g.clone();
        for j in 0..4 {
            t[3 * j] += 0.1;
        }
        let r = &c * &t - &d;
        assert!((r[0] - 0.4).abs() < 1e-12 && r[3].abs() < 1e-12 && r[4].abs() < 1e-12 && r[5].abs() < 1e-12, "{r}");
    }

    #[test]
    fn anchor_priors_release_the_frame_directions_they_fix() {
        let nom = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.1], [-3.5, 1.75, 3.9], [-3.5, -1.75, 4.0]];
        let lay = Layout { n: 4, offsets: true, mass: false, ea: false };
        let fixed = |rows: Vec<(usize, f64, f64)>| {
            let (c, d) = gauge(&nom, lay, Frame::NominalTranslationYaw);
            let (c2, d2, f) = prior_gauge(c, d, &nom, lay, &rows);
            // The constraints left still hold for the nominal anchors.
            let mut g = DVector::zeros(lay.count());
            for j in 0..4 {
                for a in 0..3 {
                    g[3 * j + a] = nom[j][a];
                }
            }
            assert!((&c2 * &g - &d2).norm() < 1e-9);
            (c2.nrows(), f)
        };
        // Offsets only: the convention unchanged.
        assert_eq!(fixed(vec![(lay.l0(0), 1.0, 0.02)]), (4, None));
        // Every coordinate: the priors fix the whole frame.
        let all: Vec<_> = (0..12).map(|i| (i, 0.0, 0.02)).collect();
        assert_eq!(fixed(all), (0, Some((4, 4))));
        // One anchor: the translations, not the yaw about it.
        assert_eq!(fixed((0..3).map(|i| (i, 0.0, 0.02)).collect()), (1, Some((3, 4))));
        // The heights only: the vertical translation.
        assert_eq!(fixed((0..4).map(|j| (3 * j + 2, 0.0, 0.02)).collect()), (3, Some((1, 4))));
    }

    #[test]
    fn chi2_quantile_matches_tables() {
        // chi2 0.999 quantiles: dof 10 -> 29.59, dof 100 -> 149.4, dof 1000 -> 1143.9.
        assert!((chi2_quantile(10, 3.09) - 29.59).abs() < 0.5);
        assert!((chi2_quantile(100, 3.09) - 149.4).abs() < 1.0);
        assert!((chi2_quantile(1000, 3.09) - 1143.9).abs() < 2.0);
    }
}

#[cfg(test)]
mod stretch_tests {
    // Index loops over parallel per-cable arrays, as in the library.
    #![allow(clippy::needless_range_loop)]
    use super::*;
    use crate::bundle::Stretch;
    use crate::synth::Rng;
    use nalgebra::{Matrix3x4, Vector4};

    const NOMINAL: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

    /// The minimum-norm static tensions of a 3 kg point mass moved along the null direction to
    /// keep every one at `t_min` or above (as the selfcal bench); `None` where none does.
    fn tensions(anchors: &[[f64; 3]], p: [f64; 3], t_min: f64) -> Option<[f64; 4]> {
        balancing(anchors, p, Vector3::new(0.0, 0.0, 3.0 * G), t_min)
    }

    /// Minimum-norm tensions whose pull on the platform at `p` is `need`, N (`m (a + g)` up),
    /// as [`tensions`].
    fn balancing(anchors: &[[f64; 3]], p: [f64; 3], need: Vector3<f64>, t_min: f64) -> Option<[f64; 4]> {
        let mut u = Matrix3x4::zeros();
        for j in 0..4 {
            let d = Vector3::new(anchors[j][0] - p[0], anchors[j][1] - p[1], anchors[j][2] - p[2]);
            u.set_column(j, &(d / d.norm()));
        }
        let pinv = u.transpose() * (u * u.transpose()).try_inverse()?;
        let t0: Vector4<f64> = pinv * need;
        let e = Vector4::new(1.0, -1.0, 1.0, -1.0);
        let null = e - pinv * (u * e);
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for j in 0..4 {
            let b = (t_min - t0[j]) / null[j];
            if null[j] > 1e-9 {
                lo = lo.max(b);
            } else if null[j] < -1e-9 {
                hi = hi.min(b);
            } else if t0[j] < t_min {
                return None;
            }
        }
        (lo <= hi).then(|| {
            let t = t0 + null * 0.0f64.clamp(lo, hi);
            [t[0], t[1], t[2], t[3]]
        })
    }

    /// 60 dwells of 100 readings on cables of stiffness `ea` (N): the drum pays out the
    /// unstretched length, the encoder reads `d / (1 + T / EA)`.
    fn stretched(seed: u64, ea: f64) -> (Recording, Vec<[f64; 3]>) {
        let mut rng = Rng::new(seed);
        let truth: Vec<[f64; 3]> = NOMINAL
            .iter()
            .map(|a| {
                let v = rng.unit_vector();
                let m = rng.range(0.05, 0.2);
                [a[0] + m * v[0], a[1] + m * v[1], a[2] + m * v[2]]
            })
            .collect();
        let l0: Vec<f64> = (0..4).map(|_| rng.range(-2.0, 2.0)).collect();
        let cell: Vec<f64> = (0..4).map(|_| 0.5 * rng.normal()).collect();
        let mut rec = Recording::with_capacity(4, 6000, true, false, false);
        let (mut k, mut t) = (0, 0.0);
        while k < 60 {
            let p = [rng.range(-2.5, 2.5), rng.range(-1.2, 1.2), rng.range(0.6, 3.4)];
            let Some(tt) = tensions(&truth, p, 5.0) else { continue };
            k += 1;
            for _ in 0..100 {
                let (mut l, mut f) = ([0.0; 4], [0.0; 4]);
                for j in 0..4 {
                    let d = ((p[0] - truth[j][0]).powi(2) + (p[1] - truth[j][1]).powi(2) + (p[2] - truth[j][2]).powi(2)).sqrt();
                    l[j] = d / (1.0 + tt[j] / ea) + l0[j] + 5e-5 * rng.normal();
                    f[j] = tt[j] + cell[j] + 0.3 * rng.normal();
                }
                rec.push(t, [f64::NAN; 3], None, &l, Some(&f), None);
                t += 0.01;
            }
        }
        (rec, truth)
    }

    fn opts(stretch: Option<Stretch>) -> SelfCalOptions {
        SelfCalOptions {
            encoder_sigma_m: 5e-5,
            loadcell_sigma_n: None,
            min_tension_n: 3.0,
            mass_kg: 3.0,
            estimate_mass: false,
            use_tensions: true,
            weak_sigma_m: 2e-3,
            max_sigma_m: 0.1,
            min_dwell_samples: 20,
            window_s: WINDOW_S,
            max_iterations: 200,
            stretch,
            priors: None,
        }
    }

    #[test]
    fn a_continuous_motion_calibrates_from_windows_with_the_platform_inertia() {
        // 3 kg swept through the workspace for 120 s at 200 Hz, never at rest: x, y, z on
        // incommensurate sines (periods 34, 22 and 14 s; up to 0.37 m/s, and 0.07-0.16 m/s²:
        // up to 0.5 N of inertia against the 0.07 N noise of a window's mean tension).
        let mut rng = Rng::new(11);
        let truth: Vec<[f64; 3]> =
            NOMINAL.iter().map(|a| [a[0] + rng.range(-0.1, 0.1), a[1] + rng.range(-0.1, 0.1), a[2] + rng.range(-0.1, 0.1)]).collect();
        let l0: Vec<f64> = (0..4).map(|_| rng.range(-2.0, 2.0)).collect();
        let cell: Vec<f64> = (0..4).map(|_| 0.5 * rng.normal()).collect();
        let (amp, w) = ([2.0, 1.0, 0.8], [std::f64::consts::TAU / 34.0, std::f64::consts::TAU / 22.0, std::f64::consts::TAU / 14.0]);
        let path = |t: f64| -> ([f64; 3], [f64; 3]) {
            let c = [0.0, 0.0, 2.0];
            (std::array::from_fn(|q| c[q] + amp[q] * (w[q] * t).sin()), std::array::from_fn(|q| -amp[q] * w[q] * w[q] * (w[q] * t).sin()))
        };
        let mut rec = Recording::with_capacity(4, 24_000, true, false, false);
        for i in 0..24_000 {
            let t = i as f64 * 0.005;
            let (p, a) = path(t);
            let tt = balancing(&truth, p, Vector3::new(3.0 * a[0], 3.0 * a[1], 3.0 * (a[2] + G)), 5.0).expect("taut along the path");
            let (mut l, mut f) = ([0.0; 4], [0.0; 4]);
            for j in 0..4 {
                let d = ((p[0] - truth[j][0]).powi(2) + (p[1] - truth[j][1]).powi(2) + (p[2] - truth[j][2]).powi(2)).sqrt();
                l[j] = d + l0[j] + 5e-5 * rng.normal();
                f[j] = tt[j] + cell[j] + 0.3 * rng.normal();
            }
            rec.push(t, [f64::NAN; 3], None, &l, Some(&f), None);
        }
        let b = [[0.0; 3]; 4];
        let r = calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts(None)).unwrap();
        let vf = r.chi2 / r.dof as f64;
        assert!(r.notes[0].starts_with("no rests"), "{:?}", r.notes);
        assert!(r.chi2_ok, "chi2/dof {vf:.2}: {:?}", r.notes);
        // Each window's acceleration from the solved path against the truth's mean over it.
        // Between windows (both neighbours joined): the second difference of poses ~30 µm apart
        // in noise over 0.135 s, ~4e-3 m/s² (its bias 2e-4 at the 14 s period); measured worst
        // of ~870: 0.012. Within a window (next to one left out, or at an end): a curvature
        // fitted over the window's 4-27 readings, 0.014 m/s² at 27 and more at fewer; measured
        // worst: 0.088. The bounds are ~1.7x the measured worst.
        let (mut between, mut within) = (0.0f64, 0.0f64);
        for (k, d) in r.dwells.iter().enumerate() {
            let mean: [f64; 3] =
                std::array::from_fn(|q| (d.start..d.end).map(|i| path(rec.t[i]).1[q]).sum::<f64>() / (d.end - d.start) as f64);
            let err = (0..3).map(|q| (d.accel[q] - mean[q]).abs()).fold(0.0, f64::max);
            let joined = k > 0 && k + 1 < r.dwells.len() && r.dwells[k - 1].end == d.start && d.end == r.dwells[k + 1].start;
            if joined {
                between = between.max(err);
            } else {
                within = within.max(err);
            }
        }
        assert!(between < 0.02 && within < 0.15, "acceleration off by {between:.3} / {within:.3} m/s² in some window");
        let al = align::align_translation_yaw(&r.params.anchors, &truth);
        for j in 0..4 {
            for a in 0..3 {
                let (e, s) = ((al[j][a] - truth[j][a]).abs(), r.sigma.anchors[j][a]);
                assert!(e < 4.9 * s, "anchor {j}[{a}] off by {:.3} mm, sigma {:.3} mm", e * 1e3, s * 1e3);
            }
        }
        // Without the inertia the same windows do not fit: the accelerations held at zero.
        let mut still = r.dwells.clone();
        for d in &mut still {
            d.accel = [0.0; 3];
        }
        let lay = Layout { n: 4, offsets: true, mass: false, ea: false };
        let (c, dd) = gauge(&NOMINAL, lay, Frame::NominalTranslationYaw);
        let sigma_f = r.loadcell_sigma_n;
        let pr = Problem {
            lay,
            b: &b,
            dwells: &still,
            var_l: r.encoder_sigma_m.powi(2) * r.inflation.0,
            var_f: sigma_f * sigma_f * r.inflation.1,
            mass: 3.0,
            min_tension_n: 3.0,
            stretch: None,
            design: &[],
            c,
            d: dd,
        };
        let s0 = State {
            g: DVector::from_iterator(
                lay.count(),
                r.params
                    .anchors
                    .iter()
                    .flatten()
                    .copied()
                    .chain(r.params.l0.iter().copied())
                    .chain(r.loadcell_offsets.as_ref().unwrap().iter().map(|e| e.value)),
            ),
            p: r.poses.clone(),
        };
        let (_, _, rep) = solve_from(&pr, s0, 200);
        eprintln!("with the inertia: chi2/dof {vf:.2}; without: {:.2}", rep.chi2 / r.dof as f64);
        assert!(rep.chi2 > chi2_quantile(r.dof, 3.09), "the inertia is not needed here: chi2/dof {:.2}", rep.chi2 / r.dof as f64);
    }

    #[test]
    fn a_known_stiffness_takes_the_stretch_from_the_dwells() {
        // EA 1e5 N under 5-30 N over 2-6 m: 0.1-1.8 mm of stretch, many sigmas of a dwell mean.
        let (rec, truth) = stretched(7, 1e5);
        let b = [[0.0; 3]; 4];
        let worst = |r: &SelfCalReport| {
            let al = align::align_translation_yaw(&r.params.anchors, &truth);
            al.iter()
                .zip(&truth)
                .map(|(a, t)| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt())
                .fold(0.0, f64::max)
        };
        let ideal = calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts(None)).unwrap();
        assert!(!ideal.chi2_ok && ideal.cable_ea_n.is_none(), "ideal model: chi2/dof {:.2}", ideal.chi2 / ideal.dof as f64);
        // The datasheet 10 % soft, its tolerance 15 %.
        let st = Stretch { ea_n: 0.9e5, rel_sigma: 0.15 / 0.9 };
        let fitted = calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts(Some(st))).unwrap();
        let vf = fitted.chi2 / fitted.dof as f64;
        eprintln!(
            "ideal: worst {:.3} mm, chi2/dof {:.2}; stretch modelled: worst {:.3} mm, chi2/dof {vf:.2}",
            worst(&ideal) * 1e3,
            ideal.chi2 / ideal.dof as f64,
            worst(&fitted) * 1e3
        );
        eprintln!(
            "stretch modelled: largest anchor coordinate sigma {:.3} mm",
            fitted.sigma.anchors.iter().flatten().fold(0.0f64, |m, &v| m.max(v)) * 1e3
        );
        assert!(fitted.chi2_ok, "chi2/dof {vf:.2}: {:?}", fitted.notes);
        // Worst anchor 2.95 mm (the largest coordinate sigma 3.4 mm here), the ideal model's 5.25 mm.
        assert!(worst(&fitted) < worst(&ideal));
        let al = align::align_translation_yaw(&fitted.params.anchors, &truth);
        for j in 0..4 {
            for a in 0..3 {
                let (e, s) = ((al[j][a] - truth[j][a]).abs(), fitted.sigma.anchors[j][a]);
                assert!(e < 4.9 * s, "anchor {j}[{a}] off by {:.3} mm, sigma {:.3} mm", e * 1e3, s * 1e3);
            }
        }
        for (j, e) in fitted.cable_ea_n.as_ref().unwrap().iter().enumerate() {
            assert!(e.sigma > 0.0 && e.sigma < 0.15e5, "cable {j}: EA sigma {}", e.sigma);
            assert!((e.value - 1e5).abs() < 4.0 * e.sigma, "cable {j}: EA {:.0} +- {:.0} N, truth 100000", e.value, e.sigma);
        }
        // Held at the datasheet value (tolerance 0): reported as it is.
        let held = calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts(Some(Stretch { ea_n: 1e5, rel_sigma: 0.0 }))).unwrap();
        assert!(held.chi2_ok && held.cable_ea_n.as_ref().unwrap().iter().all(|e| e.value == 1e5 && e.sigma == 0.0));
    }
}
