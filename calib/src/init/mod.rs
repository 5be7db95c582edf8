//! Initial anchors and offsets with no prior geometry: the paper's three-phase experiment, or
//! algebraic multilateration from any sufficiently excited recording.
//!
//! # Three-phase (paper section III)
//!
//! In each phase two cables are held at fixed length and one is reeled in; the platform (a point
//! mass) then moves on the circle where the spheres around the two held anchors intersect. So:
//!
//! ```text
//! 1. held cables of phase k: the two whose encoder lengths vary least during the phase (robust
//!    5..95% spread); reeled: of the others, the one with the highest median tension (followers
//!    are paid out at low tension), or without tensions the one that varies most; inferred from
//!    the data, never assumed
//! 2. circle fit of the phase's tracker path (plane + Kasa + geometric refinement, [circle])
//! 3. the circle's axis (centre + t normal) passes through both held anchors; an anchor held in
//!    two or more phases is the least-squares point closest to its axes:
//!       (sum_k (I - n_k n_k^T)) A = sum_k (I - n_k n_k^T) c_k
//! 4. sphere refinement: during phase k the held cable h has a constant reading l_hk, so
//!       |X_i - A_h| + L0_h = l_hk   for all samples i of the phases where h is held
//!    a four-parameter fit of exactly the calibration model to the held samples, started at the
//!    line estimate. A short arc fixes its axis direction well but its radius (hence the axis
//!    position) poorly (std(R) = 2 R^2 sigma sqrt(180/m) / L^2 for an arc of chord L); the sphere
//!    fit uses the known constant length across both phases instead of intersecting two
//!    separately fitted lines, which is far better conditioned.
//! 5. final fit: the calibration model on all of the cable's taut readings of the recording
//!    (held, reeled, following), started at the geometric estimate, uniform weights + Huber;
//!    kept if it converges within 1 m of the start
//! 6. L0_j = median_i (l_ij - |X_ij - A_j|) over the cable's taut readings.
//! ```
//!
//! Measured on simulated 1 m arcs with 1.5 mm tracker noise (tests/calibration.rs): line
//! estimates 1-4 cm off, the sphere refinement a little better, the final fit a few mm.
//!
//! Anchors held in fewer than two phases (the fourth cable of a 4-cable robot with three phases)
//! come from multilateration on all of that cable's readings in the recording.
//!
//! # Multilateration
//!
//! Squaring `l - L0 = |X - A|` and centring (`X = Xm + X'`, `A = Xm + A'`, `l = lm + l'`):
//!
//! ```text
//! l^2 - |X'|^2 = -2 X'.A' + 2 l' L0 + c,     c = |A'|^2 - L0^2 + 2 lm L0
//! ```
//!
//! linear in `(A', L0, c)`: one 5x5 least-squares solve. Each row's error is about
//! `2 rho` times the length error, so the rows are then re-weighted by `1 / (2 rho)^2` and by a
//! Huber weight of the length residual (scale: the larger of the noise model and 1.48 MAD), and
//! solved again (a few closed-form rounds). Needs 3D motion: planar data leave `A` along the
//! plane normal confounded with `c` (refused with [`InitError::NotExcited`]), and lengths that
//! never change leave `L0` confounded with `c`.

pub mod circle;

pub use circle::{fit_circle, Circle3};

use crate::noise::{self, CableData, NoiseModel, Weighting};
use crate::{model, solver, CalibOptions, Param, Params, RobustLoss, MIN_READINGS};
use nalgebra::{Matrix3, SMatrix, SVector, SymmetricEigen, Vector3};
use std::fmt;
use taut_config::recording::Recording;

/// Fewer samples than this in a phase is an error.
pub const MIN_PHASE_SAMPLES: usize = 20;

/// How the initial estimate was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The three-phase circle experiment (anchors held in < 2 phases by multilateration).
    ThreePhase,
    /// Algebraic multilateration on the whole recording.
    Multilateration,
    /// The design's anchors (a configuration with tolerances); offsets from the data where the
    /// design gives none ([`from_design`]).
    Design,
}

impl Method {
    /// A stable identifier for JSON output.
    pub fn json_name(self) -> &'static str {
        match self {
            Method::ThreePhase => "three-phase",
            Method::Multilateration => "multilateration",
            Method::Design => "design",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Method::ThreePhase => "three-phase circles (paper section III) with sphere refinement",
            Method::Multilateration => "algebraic multilateration",
            Method::Design => "the design's anchors (priors from the configuration)",
        })
    }
}

/// Where one cable's initial anchor came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnchorSource {
    /// Circle axes of the phases where it was held, refined by the sphere fit.
    HeldPhases,
    /// Multilateration on its readings.
    Multilateration,
    /// The design (configuration).
    Design,
}

/// What the three-phase method found in one phase.
#[derive(Debug, Clone, PartialEq)]
pub struct PhaseDetail {
    /// The phase value in the recording.
    pub phase: i32,
    /// Samples with a position in the phase.
    pub samples: usize,
    /// The two cables inferred as held (least length change).
    pub held: [usize; 2],
    /// The cable inferred as reeled (most length change).
    pub reeled: usize,
    /// 5..95% spread of the held cables' lengths, m.
    pub held_spread_m: [f64; 2],
    /// 5..95% spread of the reeled cable's length, m.
    pub reeled_spread_m: f64,
    /// The fitted circle of the platform path.
    pub circle: Circle3,
    /// RMS distance of the path from the circle, m.
    pub circle_rms_m: f64,
    /// Arc length covered, m (chord between the extreme points).
    pub chord_m: f64,
}

/// What the initialisation did for one cable.
#[derive(Debug, Clone, PartialEq)]
pub struct CableInit {
    /// Where the anchor came from.
    pub source: AnchorSource,
    /// Phases in which the cable was held.
    pub held_in: Vec<i32>,
    /// The line-intersection anchor (three-phase, before the sphere refinement).
    pub line_anchor: Option<[f64; 3]>,
    /// The geometric anchor (three-phase: after the sphere refinement, or the multilateration
    /// result) before the final fit on all of the cable's readings.
    pub geometric_anchor: Option<[f64; 3]>,
    /// RMS length residual of the initial parameters on the cable's taut readings, m.
    pub rms_m: f64,
    /// Readings used.
    pub used: usize,
}

/// The result of an initialisation.
#[derive(Debug, Clone, PartialEq)]
pub struct InitResult {
    /// The initial parameters.
    pub params: Params,
    /// The method used.
    pub method: Method,
    /// Per-phase details (three-phase only).
    pub phases: Vec<PhaseDetail>,
    /// Per-cable details.
    pub cables: Vec<CableInit>,
    /// Things a person should know.
    pub notes: Vec<String>,
}

/// Why an initialisation failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InitError {
    /// Platform points and recording disagree on the number of cables.
    CableCount {
        /// Length columns in the recording.
        recording: usize,
        /// Platform points given.
        platform_points: usize,
    },
    /// No `phase` column, or no phase value >= 0, or fewer than two phases.
    NoPhases {
        /// Phases found.
        found: usize,
    },
    /// A phase has too few samples with a position.
    PhaseTooShort {
        /// Phase value.
        phase: i32,
        /// Samples found.
        samples: usize,
        /// Samples needed.
        needed: usize,
    },
    /// No two cables held still during a phase.
    CannotInferHeld {
        /// Phase value.
        phase: i32,
        /// Spread of the second-stillest cable, m.
        held_spread_m: f64,
        /// Spread of the most-changing cable, m.
        reeled_spread_m: f64,
    },
    /// The phase's path is not a circle arc (too short, or a straight line).
    CircleFit {
        /// Phase value.
        phase: i32,
    },
    /// Too few taut readings for a cable.
    TooFewReadings {
        /// Cable index.
        cable: usize,
        /// Readings usable.
        used: usize,
        /// Readings needed.
        needed: usize,
    },
    /// The motion does not excite a parameter of a cable.
    NotExcited {
        /// Cable index.
        cable: usize,
        /// The unexcited parameter.
        param: Param,
        /// Excitation of the weakest direction relative to the strongest.
        ratio: f64,
    },
}

impl fmt::Display for InitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            InitError::CableCount { recording, platform_points } => write!(
                f,
                "the recording has {recording} cables but {platform_points} platform points were given; use the configuration of the robot that made the recording"
            ),
            InitError::NoPhases { found } => write!(
                f,
                "the three-phase initialisation needs a `phase` column with at least two phases (values >= 0), found {found}; record the three-phase experiment or use multilateration"
            ),
            InitError::PhaseTooShort { phase, samples, needed } => write!(
                f,
                "phase {phase}: only {samples} samples with a tracker position, at least {needed} needed; record the phase longer"
            ),
            InitError::CannotInferHeld { phase, held_spread_m, reeled_spread_m } => write!(
                f,
                "phase {phase}: cannot tell which two cables were held (the second-stillest changed by {:.1} mm, the reeled one by {:.1} mm); hold two cables in position mode and reel only one",
                held_spread_m * 1e3,
                reeled_spread_m * 1e3
            ),
            InitError::CircleFit { phase } => write!(
                f,
                "phase {phase}: the platform path is not a circle arc; reel the cable further (at least 0.5 m of travel)"
            ),
            InitError::TooFewReadings { cable, used, needed } => write!(
                f,
                "cable {}: only {used} taut readings with a tracker position, at least {needed} needed; record with this cable under tension", cable + 1
            ),
            InitError::NotExcited { cable, param, ratio } => write!(
                f,
                "cable {}: {param} is not excited by this recording (weakest direction {ratio:.1e} of the strongest): {}", cable + 1,
                param.advice()
            ),
        }
    }
}

impl std::error::Error for InitError {}

/// Three-phase when the recording has a `phase` column with values >= 0 (falling back to
/// multilateration, with a note, if the phases cannot be used), multilateration otherwise.
pub fn initialise(rec: &Recording, platform_points: &[[f64; 3]], opts: &CalibOptions) -> Result<InitResult, InitError> {
    initialise_with(rec, platform_points, opts, None)
}

/// [`initialise`] with the readings gathered once for the initialisation, the calibration and the
/// Cramér–Rao bound (`noise::gather(rec, platform_points, opts, Weighting::of(rec, opts))`, as
/// [`crate::calibrate_gathered`] takes them).
pub fn initialise_gathered(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    opts: &CalibOptions,
    data: &[CableData],
) -> Result<InitResult, InitError> {
    initialise_with(rec, platform_points, opts, Some(data))
}

fn initialise_with(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    opts: &CalibOptions,
    data: Option<&[CableData]>,
) -> Result<InitResult, InitError> {
    let has_phases = rec.phase.as_ref().is_some_and(|p| p.iter().any(|&v| v >= 0));
    if !has_phases {
        return multilateration_with(rec, platform_points, opts, data);
    }
    match three_phase(rec, platform_points, opts) {
        Ok(r) => Ok(r),
        Err(e) => {
            let mut r = multilateration_with(rec, platform_points, opts, data).map_err(|_| e)?;
            r.notes.insert(0, format!("three-phase initialisation not possible ({e}); used multilateration"));
            Ok(r)
        }
    }
}

/// The start of a calibration with the design's priors: every cable's anchor from `design`
/// (`[A_x, A_y, A_z, L0]` means, `RobotConfig::priors`), its offset from `design` where finite,
/// else the median of `l - |X - A|` over the cable's used readings (`data`, gathered as for
/// [`initialise_gathered`]). For recordings that excite too little for [`initialise`]: a
/// locked winch, a short swing.
pub fn from_design(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    design: &[[f64; 4]],
    data: &[CableData],
) -> Result<InitResult, InitError> {
    check_count(rec, platform_points)?;
    let n = rec.n_cables;
    if design.len() != n || data.len() != n {
        return Err(InitError::CableCount { recording: n, platform_points: design.len().min(data.len()) });
    }
    let mut anchors = Vec::with_capacity(n);
    let mut l0 = Vec::with_capacity(n);
    let mut cables = Vec::with_capacity(n);
    for (j, (m, d)) in design.iter().zip(data).enumerate() {
        let a = [m[0], m[1], m[2]];
        let mut diffs: Vec<f64> = (0..d.len())
            .filter(|&i| d.class[i] == crate::noise::USED)
            .map(|i| d.l[i] - model::norm(model::sub([d.x[i], d.y[i], d.z[i]], a)))
            .collect();
        if diffs.len() < crate::MIN_READINGS {
            return Err(InitError::TooFewReadings { cable: j, used: diffs.len(), needed: crate::MIN_READINGS });
        }
        let offset = if m[3].is_finite() {
            m[3]
        } else {
            diffs.sort_by(f64::total_cmp);
            diffs[diffs.len() / 2]
        };
        let rms = (diffs.iter().map(|e| (e - offset).powi(2)).sum::<f64>() / diffs.len() as f64).sqrt();
        anchors.push(a);
        l0.push(offset);
        cables.push(CableInit {
            source: AnchorSource::Design,
            held_in: Vec::new(),
            line_anchor: None,
            geometric_anchor: Some(a),
            rms_m: rms,
            used: diffs.len(),
        });
    }
    Ok(InitResult {
        params: Params { anchors, l0 },
        method: Method::Design,
        phases: Vec::new(),
        cables,
        notes: vec!["started at the design's anchors (the configuration's tolerances are the calibration's priors)".into()],
    })
}

fn check_count(rec: &Recording, platform_points: &[[f64; 3]]) -> Result<(), InitError> {
    if platform_points.len() != rec.n_cables {
        return Err(InitError::CableCount { recording: rec.n_cables, platform_points: platform_points.len() });
    }
    Ok(())
}

/// Multilateration of every cable on all its taut readings.
pub fn multilateration(rec: &Recording, platform_points: &[[f64; 3]], opts: &CalibOptions) -> Result<InitResult, InitError> {
    multilateration_with(rec, platform_points, opts, None)
}

fn multilateration_with(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    opts: &CalibOptions,
    gathered: Option<&[CableData]>,
) -> Result<InitResult, InitError> {
    check_count(rec, platform_points)?;
    let weighting = Weighting::of(rec, opts);
    let own;
    let data = match gathered {
        Some(d) => d,
        None => {
            own = noise::gather(rec, platform_points, opts, weighting);
            &own[..]
        }
    };
    let sigma = reading_sigma(opts);
    let mut anchors = Vec::new();
    let mut l0 = Vec::new();
    let mut cables = Vec::new();
    // Independent per cable; the first error in cable order is the one reported, as in a loop.
    let solved = crate::par::map(opts.threads, data.len(), |j| multilaterate(&data[j], sigma, j).map(|(a, o)| (a, o, rms(&data[j], a, o))));
    for (d, found) in data.iter().zip(solved) {
        let (a, o, rms_m) = found?;
        anchors.push(a);
        l0.push(o);
        cables.push(CableInit {
            source: AnchorSource::Multilateration,
            held_in: vec![],
            line_anchor: None,
            geometric_anchor: None,
            rms_m,
            used: d.used,
        });
    }
    let mut notes = Vec::new();
    if !weighting.uses_tensions() {
        notes.push("no tensions used: loose readings cannot be excluded from the initialisation".into());
    }
    Ok(InitResult { params: Params { anchors, l0 }, method: Method::Multilateration, phases: vec![], cables, notes })
}

/// One-sigma of a length reading under the noise model, without stretch, m.
fn reading_sigma(opts: &CalibOptions) -> f64 {
    let nm = NoiseModel::new(opts, Weighting::UniformByOption);
    nm.variance([1.0, 0.0, 0.0], 0.0, 0.0).sqrt().max(1e-9)
}

/// Closed-form anchor and offset of one cable from its readings `d` (see the module doc).
pub fn multilaterate(d: &CableData, sigma: f64, cable: usize) -> Result<([f64; 3], f64), InitError> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports the feature `multilaterate_avx2` is compiled for.
            return unsafe { multilaterate_avx2(d, sigma, cable) };
        }
    }
    multilaterate_body(d, sigma, cable)
}

/// [`multilaterate_body`] compiled for AVX2: the same operations in the same order (Rust does
/// not fuse a multiply and an add), on wider registers, so the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn multilaterate_avx2(d: &CableData, sigma: f64, cable: usize) -> Result<([f64; 3], f64), InitError> {
    multilaterate_body(d, sigma, cable)
}

// The normal-equation loops index the 5x5 upper triangle by row and column, as the maths reads.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn multilaterate_body(d: &CableData, sigma: f64, cable: usize) -> Result<([f64; 3], f64), InitError> {
    let slots: Vec<usize> = d.used_slots().collect();
    let m = slots.len();
    if m < MIN_READINGS {
        return Err(InitError::TooFewReadings { cable, used: m, needed: MIN_READINGS });
    }
    let mf = m as f64;
    let mut xm = [0.0; 3];
    let mut lm = 0.0;
    for &k in &slots {
        let p = d.point(k);
        for a in 0..3 {
            xm[a] += p[a] / mf;
        }
        lm += d.l[k] / mf;
    }
    // Excitation: principal spreads of the path, and the spread of the lengths.
    let (cov, lvar) = spreads(d, &slots, xm, lm);
    let eig = SymmetricEigen::new(cov);
    let (imin, imax) = {
        let e = &eig.eigenvalues;
        let mut o = [0usize, 1, 2];
        o.sort_by(|&a, &b| e[a].total_cmp(&e[b]));
        (o[0], o[2])
    };
    let spread_max = eig.eigenvalues[imax].max(0.0).sqrt();
    let spread_min = eig.eigenvalues[imin].max(0.0).sqrt();
    // 2%: a 4 m wide workspace needs 8 cm of motion along every direction.
    const MIN_RATIO: f64 = 0.02;
    if !(spread_min >= MIN_RATIO * spread_max) {
        let v = eig.eigenvectors.column(imin);
        let axis = (0..3).max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs())).unwrap_or(2);
        return Err(InitError::NotExcited { cable, param: Param::from_index(axis), ratio: spread_min / spread_max });
    }
    if !(lvar.sqrt() >= MIN_RATIO * spread_max) {
        return Err(InitError::NotExcited { cable, param: Param::L0, ratio: lvar.sqrt() / spread_max });
    }
    // Rows scaled so the four metre-valued columns are O(1).
    let s = 2.0 * (eig.eigenvalues.iter().map(|v| v.max(0.0)).sum::<f64>()).sqrt();
    let mut w = vec![1.0; m];
    let mut theta = SVector::<f64, 5>::zeros();
    let mut a_est = xm;
    let mut l0_est = 0.0;
    let mut resid = vec![0.0; m];
    // Each reading's row of the linear system and its right-hand side do not change between
    // the rounds (only the weights do): computed once, with the used readings' points and
    // lengths in columns of their own for the re-weighting.
    let two_over_s = 2.0 / s;
    let rows: Vec<([f64; 4], f64)> = slots
        .iter()
        .map(|&k| {
            let x = model::sub(d.point(k), xm);
            let row = [-x[0] * two_over_s, -x[1] * two_over_s, -x[2] * two_over_s, (d.l[k] - lm) * two_over_s];
            (row, d.l[k] * d.l[k] - model::dot(x, x))
        })
        .collect();
    let column = |c: &[f64]| -> Vec<f64> { slots.iter().map(|&k| c[k]).collect() };
    let (px, py, pz, pl) = (column(&d.x), column(&d.y), column(&d.z), column(&d.l));
    for round in 0..4 {
        // The normal equations' upper triangle, accumulated by hand (a 5x5 outer product per
        // reading through nalgebra would be most of the initialisation's time), then mirrored.
        // The row is `[row (4), 1]`: the 4x4 block is accumulated whole (four lanes a row; the
        // entries below the diagonal are dropped), the last column is `row * w` (times 1) and
        // the corner `w`: each kept entry gets the same products in the same order as
        // `upper[a][b] += (row[a] w) row[b]` over the 5x5 upper triangle.
        let NormalSums { block, last, r4, corner, r_last } = normal_sums(&rows, &w);
        let mut upper = [[0.0f64; 5]; 5];
        for a in 0..4 {
            upper[a][..4].copy_from_slice(&block[a]);
            upper[a][4] = last[a];
        }
        upper[4][4] = corner;
        let r = [r4[0], r4[1], r4[2], r4[3], r_last];
        let nmat = SMatrix::<f64, 5, 5>::from_fn(|a, b| if a <= b { upper[a][b] } else { upper[b][a] });
        let rhs = SVector::<f64, 5>::from(r);
        theta = match nmat.cholesky() {
            Some(c) => c.solve(&rhs),
            None => return Err(InitError::NotExcited { cable, param: Param::L0, ratio: 0.0 }),
        };
        a_est = [xm[0] + theta[0] / s, xm[1] + theta[1] / s, xm[2] + theta[2] / s];
        l0_est = theta[3] / s;
        if round == 3 {
            break;
        }
        // Re-weight: rows to length units, Huber on the length residual.
        for i in 0..m {
            let rho = model::norm(model::sub([px[i], py[i], pz[i]], a_est));
            resid[i] = pl[i] - l0_est - rho;
            w[i] = 1.0 / (4.0 * rho * rho).max(1e-6);
        }
        let scale = sigma.max(1.4826 * median_abs(&resid));
        for i in 0..m {
            w[i] *= RobustLoss::Huber { k: 2.0 }.weight_cost((resid[i] / scale).powi(2)).0;
        }
    }
    let _ = theta;
    if !a_est.iter().all(|v| v.is_finite()) {
        return Err(InitError::NotExcited { cable, param: Param::L0, ratio: 0.0 });
    }
    let _ = l0_est;
    Ok((a_est, median_offset(d, a_est)))
}

/// The covariance of the used readings' points about `xm` and the variance of their lengths
/// about `lm`: `sum (v v^T) / m` and `sum (l - lm)^2 / m` in slot order, `v = X - xm`. The
/// matrix is symmetric bit for bit (`v_a v_b = v_b v_a`), so its six distinct entries are summed
/// (with the length's, seven divisions a reading in two vectors instead of ten one by one).
/// Inlined, so that it is compiled with the multilateration's AVX2.
#[inline(always)]
fn spreads(d: &CableData, slots: &[usize], xm: [f64; 3], lm: f64) -> (Matrix3<f64>, f64) {
    let mf = slots.len() as f64;
    // 00 01 02 11 12 22, the length's, and a lane to fill the vector.
    let mut c = [0.0f64; 8];
    for &k in slots {
        let v = model::sub(d.point(k), xm);
        let dl = d.l[k] - lm;
        let prod = [v[0] * v[0], v[0] * v[1], v[0] * v[2], v[1] * v[1], v[1] * v[2], v[2] * v[2], dl * dl, 0.0];
        for (s, p) in c.iter_mut().zip(prod) {
            *s += p / mf;
        }
    }
    let cov = Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]);
    (cov, c[6])
}

/// The sums of one round's normal equations over the rows `(row, y)` weighted by `w`, each in
/// row order: `block[a][b] = sum (row[a] w) row[b]`, `last[a] = sum row[a] w`,
/// `r4[a] = sum (row[a] w) y`, `corner = sum w`, `r_last = sum w y`.
struct NormalSums {
    block: [[f64; 4]; 4],
    last: [f64; 4],
    r4: [f64; 4],
    corner: f64,
    r_last: f64,
}

fn normal_sums(rows: &[([f64; 4], f64)], w: &[f64]) -> NormalSums {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports the feature `normal_sums_avx2` is compiled for.
            return unsafe { normal_sums_avx2(rows, w) };
        }
    }
    normal_sums_scalar(rows, w)
}

/// [`normal_sums`] one row at a time.
#[allow(clippy::needless_range_loop)]
fn normal_sums_scalar(rows: &[([f64; 4], f64)], w: &[f64]) -> NormalSums {
    let (mut block, mut last, mut r4) = ([[0.0f64; 4]; 4], [0.0f64; 4], [0.0f64; 4]);
    let (mut corner, mut r_last) = (0.0f64, 0.0f64);
    for (&(row, y), &wi) in rows.iter().zip(w) {
        let ra = [row[0] * wi, row[1] * wi, row[2] * wi, row[3] * wi];
        for a in 0..4 {
            for b in 0..4 {
                block[a][b] += ra[a] * row[b];
            }
        }
        for a in 0..4 {
            last[a] += ra[a];
            r4[a] += ra[a] * y;
        }
        corner += wi;
        r_last += wi * y;
    }
    NormalSums { block, last, r4, corner, r_last }
}

/// [`normal_sums_scalar`] with the 26 sums held in registers, four lanes a vector: each lane
/// gets the same products (a multiply, then an add: never fused) in the same order, so the same
/// bits. Left to the compiler the loop kept some sums on the stack, a store and a load in every
/// sum's chain.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn normal_sums_avx2(rows: &[([f64; 4], f64)], w: &[f64]) -> NormalSums {
    use std::arch::x86_64::*;
    let z = _mm256_setzero_pd();
    let (mut b0, mut b1, mut b2, mut b3, mut last, mut r4) = (z, z, z, z, z, z);
    let (mut corner, mut r_last) = (0.0f64, 0.0f64);
    for (&(row, y), &wi) in rows.iter().zip(w) {
        // SAFETY: `row` is four f64 (an unaligned load reads exactly those).
        let rv = _mm256_loadu_pd(row.as_ptr());
        let ra = _mm256_mul_pd(rv, _mm256_set1_pd(wi));
        b0 = _mm256_add_pd(b0, _mm256_mul_pd(_mm256_permute4x64_pd::<0x00>(ra), rv));
        b1 = _mm256_add_pd(b1, _mm256_mul_pd(_mm256_permute4x64_pd::<0x55>(ra), rv));
        b2 = _mm256_add_pd(b2, _mm256_mul_pd(_mm256_permute4x64_pd::<0xAA>(ra), rv));
        b3 = _mm256_add_pd(b3, _mm256_mul_pd(_mm256_permute4x64_pd::<0xFF>(ra), rv));
        last = _mm256_add_pd(last, ra);
        r4 = _mm256_add_pd(r4, _mm256_mul_pd(ra, _mm256_set1_pd(y)));
        corner += wi;
        r_last += wi * y;
    }
    let lanes = |v: __m256d| {
        let mut out = [0.0f64; 4];
        // SAFETY: `out` holds four f64.
        _mm256_storeu_pd(out.as_mut_ptr(), v);
        out
    };
    NormalSums { block: [lanes(b0), lanes(b1), lanes(b2), lanes(b3)], last: lanes(last), r4: lanes(r4), corner, r_last }
}

/// `median |v|` (0 for an empty slice).
fn median_abs(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    // Without a sign bit, `total_cmp`'s order of f64 is the order of their bits as integers:
    // the same element is selected, by integer comparisons.
    let mut a: Vec<u64> = v.iter().map(|x| x.abs().to_bits()).collect();
    let mid = a.len() / 2;
    f64::from_bits(*a.select_nth_unstable(mid).1)
}

fn median_in_place(a: &mut [f64]) -> f64 {
    if a.is_empty() {
        return 0.0;
    }
    let mid = a.len() / 2;
    let (_, m, _) = a.select_nth_unstable_by(mid, |x, y| x.total_cmp(y));
    *m
}

/// `L0 = median(l - |X - A|)`: robust to the loose or outlying readings a fit would be pulled by.
fn median_offset(d: &CableData, a: [f64; 3]) -> f64 {
    let mut v: Vec<f64> = d.used_slots().map(|k| d.l[k] - model::norm(model::sub(d.point(k), a))).collect();
    median_in_place(&mut v)
}

fn rms(d: &CableData, a: [f64; 3], l0: f64) -> f64 {
    let s: f64 = d.used_slots().map(|k| (d.l[k] - l0 - model::norm(model::sub(d.point(k), a))).powi(2)).sum();
    (s / d.used.max(1) as f64).sqrt()
}

/// 5..95% spread of the finite values.
fn spread(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.len() < 2 {
        return f64::INFINITY;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
    q(0.95) - q(0.05)
}

/// The paper's three-phase initialisation (see the module doc).
pub fn three_phase(rec: &Recording, platform_points: &[[f64; 3]], opts: &CalibOptions) -> Result<InitResult, InitError> {
    check_count(rec, platform_points)?;
    let n = rec.n_cables;
    let phase = match &rec.phase {
        Some(p) => p,
        None => return Err(InitError::NoPhases { found: 0 }),
    };
    let mut ids: Vec<i32> = phase.iter().copied().filter(|&v| v >= 0).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() < 2 {
        return Err(InitError::NoPhases { found: ids.len() });
    }
    let mut notes = Vec::new();
    if platform_points.iter().any(|b| b.iter().any(|v| *v != 0.0)) {
        notes.push("the circle geometry assumes a point-mass platform; with platform points the line estimate is approximate (the sphere refinement is exact)".into());
    }
    let mut details = Vec::new();
    for &id in &ids {
        let idx: Vec<usize> = (0..rec.len()).filter(|&i| phase[i] == id && rec.p[i].iter().all(|v| v.is_finite())).collect();
        if idx.len() < MIN_PHASE_SAMPLES {
            return Err(InitError::PhaseTooShort { phase: id, samples: idx.len(), needed: MIN_PHASE_SAMPLES });
        }
        let spreads: Vec<f64> = (0..n).map(|j| spread(idx.iter().map(|&i| rec.l[i * n + j]).collect())).collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| spreads[a].total_cmp(&spreads[b]));
        let held = [order[0], order[1]];
        // The reeled cable pulls the platform: with tensions it is the tautest of the others
        // (followers are paid out at low tension and change length too); without, the one
        // whose length changes most.
        let reeled = match &rec.f {
            Some(f) => {
                let med = |j: usize| {
                    let mut v: Vec<f64> = idx.iter().map(|&i| f[i * n + j]).filter(|t| t.is_finite()).collect();
                    if v.is_empty() {
                        f64::NEG_INFINITY
                    } else {
                        median_in_place(&mut v)
                    }
                };
                (0..n).filter(|j| !held.contains(j)).max_by(|&a, &b| med(a).total_cmp(&med(b))).unwrap_or(order[n - 1])
            }
            None => order[n - 1],
        };
        // Held cables move only by encoder noise; 5% of the reeled cable's travel is generous.
        let most = spreads[order[n - 1]];
        if !(spreads[held[1]] < 0.05 * most) {
            return Err(InitError::CannotInferHeld { phase: id, held_spread_m: spreads[held[1]], reeled_spread_m: most });
        }
        let pts: Vec<[f64; 3]> = idx.iter().map(|&i| rec.p[i]).collect();
        let (c, crms) = fit_circle(&pts).ok_or(InitError::CircleFit { phase: id })?;
        let chord = model::norm(model::sub(pts[0], pts[pts.len() - 1]));
        details.push(PhaseDetail {
            phase: id,
            samples: idx.len(),
            held: [held[0].min(held[1]), held[0].max(held[1])],
            reeled,
            held_spread_m: [spreads[held[0].min(held[1])], spreads[held[0].max(held[1])]],
            reeled_spread_m: spreads[reeled],
            circle: c,
            circle_rms_m: crms,
            chord_m: chord,
        });
    }
    let weighting = Weighting::of(rec, opts);
    let data = noise::gather(rec, platform_points, opts, weighting);
    let sigma = reading_sigma(opts);
    // Uniform weights for the sphere fit: the held cables are taut at moderate tension.
    let nm = NoiseModel::new(opts, Weighting::UniformByOption);
    let mut anchors = Vec::with_capacity(n);
    let mut l0 = Vec::with_capacity(n);
    let mut cables = Vec::with_capacity(n);
    for (j, d) in data.iter().enumerate() {
        let held_in: Vec<&PhaseDetail> = details.iter().filter(|p| p.held.contains(&j)).collect();
        let line = if held_in.len() >= 2 { closest_point_to_axes(&held_in) } else { None };
        let (a, source) = match line {
            Some(a_line) => {
                // Sphere refinement on the held samples only.
                let phases_held: Vec<i32> = held_in.iter().map(|p| p.phase).collect();
                let mut hd = d.restricted(|s| phases_held.contains(&phase[s]));
                let a = if hd.used >= MIN_READINGS {
                    let x0 = [a_line[0], a_line[1], a_line[2], median_offset(&hd, a_line)];
                    hd.set_variances(&x0, &nm);
                    let sol = solver::solve(&hd, 0, hd.len(), x0, opts.loss, opts.max_iterations);
                    let moved = model::norm(model::sub([sol.x[0], sol.x[1], sol.x[2]], a_line));
                    // Accept unless it ran away (a degenerate pair of phases): the line estimate
                    // is good to a few cm, so a move of metres is not a refinement.
                    if sol.x.iter().all(|v| v.is_finite()) && moved < 0.5 {
                        [sol.x[0], sol.x[1], sol.x[2]]
                    } else {
                        notes.push(format!(
                            "cable {}: the sphere refinement did not converge near the circle axes; kept the line estimate",
                            j + 1
                        ));
                        a_line
                    }
                } else {
                    a_line
                };
                (a, AnchorSource::HeldPhases)
            }
            None => {
                notes.push(format!(
                    "cable {}: held in {} phase(s); its anchor comes from multilateration on all its readings",
                    j + 1,
                    held_in.len()
                ));
                (multilaterate(d, sigma, j)?.0, AnchorSource::Multilateration)
            }
        };
        if d.used < MIN_READINGS {
            return Err(InitError::TooFewReadings { cable: j, used: d.used, needed: MIN_READINGS });
        }
        // Final fit of the model to all of the cable's taut readings in the recording (held,
        // reeled and following), from the geometric estimate: the geometry supplies a start in
        // the right basin with no prior, the readings then pin the anchor down to what they can
        // tell. Kept only if it converges near the start.
        let geometric = a;
        let mut d = d.clone();
        let x0 = [a[0], a[1], a[2], median_offset(&d, a)];
        d.set_variances(&x0, &nm);
        let sol = solver::solve(&d, 0, d.len(), x0, opts.loss, opts.max_iterations);
        let fitted = [sol.x[0], sol.x[1], sol.x[2]];
        let a = if sol.x.iter().all(|v| v.is_finite()) && sol.termination.was_successful() && model::norm(model::sub(fitted, a)) < 1.0 {
            fitted
        } else {
            notes.push(format!(
                "cable {}: the fit on all readings did not converge near the geometric estimate; kept the geometric estimate",
                j + 1
            ));
            a
        };
        let o = median_offset(&d, a);
        anchors.push(a);
        l0.push(o);
        cables.push(CableInit {
            source,
            held_in: held_in.iter().map(|p| p.phase).collect(),
            line_anchor: line,
            geometric_anchor: Some(geometric),
            rms_m: rms(&d, a, o),
            used: d.used,
        });
    }
    Ok(InitResult { params: Params { anchors, l0 }, method: Method::ThreePhase, phases: details, cables, notes })
}

/// Least-squares point closest to the circle axes of `phases`; `None` when the axes are
/// (nearly) parallel.
fn closest_point_to_axes(phases: &[&PhaseDetail]) -> Option<[f64; 3]> {
    let mut m = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for p in phases {
        let nv = Vector3::from(p.circle.normal);
        let proj = Matrix3::identity() - nv * nv.transpose();
        m += proj;
        b += proj * Vector3::from(p.circle.centre);
    }
    // Two axes at angle theta: smallest eigenvalue 1 - cos(theta); require theta > ~2.5 deg.
    let e = SymmetricEigen::new(m).eigenvalues;
    if !(e.min() > 1e-3) {
        return None;
    }
    let a = m.cholesky()?.solve(&b);
    Some([a[0], a[1], a[2]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_are_the_outer_products_summed() {
        let m = 500;
        let f = |i: usize, s: f64| ((i as f64 * s).sin() * 1.7 + (i as f64 * 0.37 * s).cos()) * (1.0 + s);
        let pts: Vec<[f64; 3]> = (0..m).map(|i| [f(i, 0.11), f(i, 0.23), f(i, 0.05)]).collect();
        let l: Vec<f64> = (0..m).map(|i| 3.0 + f(i, 0.07)).collect();
        let t: Vec<f64> = (0..m).map(|i| i as f64).collect();
        let d = CableData::from_points(&pts, &l, &t);
        let slots: Vec<usize> = d.used_slots().collect();
        let (xm, lm) = ([0.1, -0.2, 0.3], 2.9);
        let mf = slots.len() as f64;
        let (mut cov, mut lvar) = (Matrix3::zeros(), 0.0);
        for &k in &slots {
            let v = Vector3::from(model::sub(d.point(k), xm));
            cov += v * v.transpose() / mf;
            lvar += (d.l[k] - lm).powi(2) / mf;
        }
        let (c, lv) = spreads(&d, &slots, xm, lm);
        assert_eq!(lv.to_bits(), lvar.to_bits());
        for (a, b) in c.iter().zip(cov.iter()) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        assert!(slots.len() == m && c[(0, 1)] != 0.0);
    }

    #[test]
    fn normal_sums_are_the_same_bits_on_every_path() {
        // Values of mixed sign and magnitude, so that a changed order of the adds would show.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let rows: Vec<([f64; 4], f64)> = (0..1001).map(|i| ([next(), next() * 1e3, next() * 1e-3, next()], next() * (i as f64))).collect();
        let w: Vec<f64> = (0..rows.len()).map(|_| next().abs() * 7.0).collect();
        let (a, b) = (normal_sums(&rows, &w), normal_sums_scalar(&rows, &w));
        let bits = |n: &NormalSums| {
            let mut v: Vec<u64> = n.block.iter().flatten().chain(&n.last).chain(&n.r4).map(|x| x.to_bits()).collect();
            v.extend([n.corner.to_bits(), n.r_last.to_bits()]);
            v
        };
        assert_eq!(bits(&a), bits(&b));
        assert!(a.block[1][2] != 0.0 && a.corner > 0.0);
    }
}
