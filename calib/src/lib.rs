//! Kinematic calibration of suspended cable-driven parallel robots from a tracker, the cable
//! encoders and (optionally) the load cells: force-aware Levenberg–Marquardt, prior-free
//! initialisation (three-phase circles or algebraic multilateration), and the metrics to judge the
//! result (co-registration, held-out error, Cramér–Rao bound).
//!
//! Pure: no I/O. No threads unless the caller asks for them (`CalibOptions::threads`, [`par`]):
//! then scoped workers take whole cables or channels, with the same results bit for bit.
//! The input is a [`Recording`] (crate `taut-config`).
//!
//! ```no_run
//! use taut_calib::{calibrate, init, CalibOptions};
//! use taut_config::{recording::Recording, RobotConfig};
//!
//! let cfg = RobotConfig::load("config/examples/aras-cam.toml").unwrap();
//! let (rec, _) = Recording::load("excitation.csv").unwrap();
//! let opts = CalibOptions::from_config(&cfg.calibration);
//! let b = cfg.platform_points();
//! let start = init::initialise(&rec, &b, &opts).unwrap();
//! let report = calibrate(&rec, &b, &start.params, &opts).unwrap();
//! for (j, (a, s)) in report.params.anchors.iter().zip(&report.sigma.anchors).enumerate() {
//!     println!("cable {j}: anchor {a:?} m, 1-sigma {s:?} m");
//! }
//! println!("co-registration RMS {:.2} mm, held out {:.2} mm", report.rms_m * 1e3, report.heldout_rms_m * 1e3);
//! ```
//!
//! # Model
//!
//! ```text
//! l_ij = | P_i + R_i b_j - A_j | + L0_j          (paper eq. 2 and 7, with a platform point b_j)
//! ```
//!
//! `P_i`, `R_i`: tracker position and orientation of sample `i` (`R_i = I` when the recording has
//! no orientation); `b_j`: attachment point of cable `j` on the platform; `A_j`: anchor (cable
//! exit point) in the tracker frame; `L0_j`: the unknown offset of the incremental encoder.
//! Parameters per cable: `x_j = (A_j, L0_j)`, four numbers. Jacobians: [`model`].
//!
//! # Noise model (force-aware weighting)
//!
//! Each reading gets a variance, not an ad-hoc weight ([`noise`]):
//!
//! ```text
//! sigma_ij^2 = sigma_enc^2 + u_ij^T Sigma_P u_ij + (T_ij rho_ij / EA)^2
//! ```
//!
//! encoder noise, tracker noise projected on the cable direction `u`, and the unobserved elastic
//! stretch `T L / EA` (paper eq. 10) as a one-sigma error. Readings of a loose cable
//! (`T < min_tension_n`) are excluded: the encoder then counts slack, not geometry. Missing values
//! (NaN) are skipped. Tracker outliers (a few cm, rare) are handled by a robust loss (Huber by
//! default) applied to `e_ij = r_ij / sigma_ij` by iteratively re-weighted least squares inside
//! LM. Without tensions, or with `force_aware: false`, the variance is uniform and no reading is
//! excluded; the report says which ([`Weighting`]).
//!
//! # Solver
//!
//! ```text
//! minimise_x  sum_i rho( (l_ij - f_ij(x)) / sigma_ij )     separately for each cable j
//! ```
//!
//! Cable `j`'s residuals depend only on `x_j`, so the problem is `n` independent four-parameter
//! problems. Each LM iteration is one pass over the cable's readings that accumulates the 4x4
//! `J^T W J` and `J^T W r` without ever storing the `m x 4` Jacobian; see [`solver`] for the
//! iteration and why it is fast.
//!
//! # Uncertainty and observability
//!
//! ```text
//! Cov(x_j) = s_j^2 (J^T W J)^-1,   s_j^2 = max(1, chi2_j / (m_j - 4))
//! ```
//!
//! `(J^T W J)^-1` is the covariance if the noise model is right. The a-posteriori variance factor
//! `chi2 / (m - 4)` tests that: near 1 the model holds and the formal covariance is kept; above 1
//! the residuals are larger than modelled (unmodelled slack, sag, a wrong `tracker_sigma_m`) and
//! the covariance is scaled up by it. It is never scaled *down*: with a correct model the factor
//! fluctuates around 1 by `sqrt(2/m)`, and shrinking the sigmas on a lucky recording would claim
//! more than the sensors can give. The factor is reported per cable.
//!
//! Observability is decided by what it costs the user: the predicted one-sigma of each parameter.
//! A parameter known to 9 mm is weakly determined, not unobservable. Above `weak_sigma_m`
//! (`[calibration] weak_sigma_m`, default 2 mm) the estimate is returned with a warning in the
//! notes and in [`CalibReport::weak`]; only above `max_sigma_m` (`[calibration] max_sigma_m`,
//! default 10 cm), or when `J^T W J` cannot be inverted at all, does [`calibrate`] refuse with
//! [`CalibError::NotObservable`], naming the cable and the parameter and saying how to move the
//! robot. The singular values of the weighted Jacobian `W^(1/2) J` are still reported (they say
//! which direction is weakest), but a ratio of them decides nothing: its scale depends on the
//! units and the number of readings, the sigma does not.
//!
//! # What it achieves (measured, see `tests/calibration.rs` and `benches/calibrate.rs`)
//!
//! - Simulated ARAS-CAM-like robot, 1.5 mm tracker noise, 4000 samples, 5% loose readings,
//!   0.2% tracker outliers of 5 cm: every anchor coordinate and offset within 1.1 Cramér–Rao
//!   sigmas of the truth (sigmas 0.4-0.6 mm), reported sigmas within 15% of the bound. The paper
//!   reports ~1 cm co-registration after calibration; here the co-registration RMS is the
//!   sensor noise (~1.7 mm incl. tracker noise) and the anchors are sub-millimetre.
//! - 20% loose readings: force weighting 6.6x closer to the truth than unweighted least squares
//!   (the paper's comparison); 1.7x with the Huber loss on both (which already rejects slack of
//!   several cm as outliers).
//! - Three-phase initialisation on 1 m arcs, no prior geometry: anchors within 4-6 mm (the
//!   paper: ~50 cm); the circle-axis estimates alone are 1-4 cm off.
//! - 100 000 samples x 4 cables from a start 5-10 cm off: 40-60 ms wall for the whole
//!   [`calibrate`] (gather, least-squares and Huber stages, covariance, statistics, held-out
//!   estimate), 35-45 ms without the held-out estimate, on one core of a 2-vCPU Xeon VM shared
//!   with other builds (run under SCHED_FIFO; the spread is the neighbours' memory traffic).
//!   `scipy.optimize.least_squares` (trf, Huber, analytic Jacobian, per cable) takes 11-15 s on
//!   the same data: 150-200x slower, same parameters to about 1 µm (`bench/run-calib-bench`).
//!
//! # Modules
//!
//! - [`model`]: geometry and Jacobians. [`noise`]: which readings are used, their variance.
//! - [`solver`]: per-cable LM. [`init`]: three-phase and multilateration initialisation.
//! - [`metrics`]: co-registration, held-out split, Cramér–Rao bound.
//! - [`screen`]: wild values (encoder spikes and jumps, impossible tensions, tracker jumps), found and excluded before any fit.
//! - [`synth`]: deterministic synthetic recordings for tests, benchmarks and examples.
//! - [`selfcal`]: calibration without a tracker, from dwell poses, the encoders and the load cells.
//! - [`effect_fit`]: anchors, offsets and a fixed set of effects fitted together (the running robot's refit).
//! - [`design`]: the start-up excitation designed from the nominal geometry, with its predicted uncertainty.
//! - [`par`]: independent cables or channels on several cores, results in index order.
//! - [`trust`]: whether a calibrated set may become the robot's parameters (finite, plausible anchors).
#![deny(missing_docs)]
// `!(a > b)` is deliberate throughout: a NaN must fail a check, not pass it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Index loops over parallel column arrays (x, y, z, l, ...) read clearer than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod bundle;
pub mod consistency;
pub mod design;
pub mod diagnose;
pub mod effect_fit;
pub mod effects;
pub mod init;
pub mod lm;
mod mc;
pub mod metrics;
pub mod model;
pub mod noise;
pub mod par;
pub mod screen;
pub mod selfcal;
pub mod solver;
pub mod synth;
pub mod trust;

use std::fmt;
use taut_config::recording::Recording;
use taut_config::CalibrationConfig;

pub use noise::Weighting;
pub use solver::Termination;

/// Fewer used readings than this for a cable is an error (four parameters, and a margin to see
/// the residuals).
pub const MIN_READINGS: usize = 10;

/// Kinematic parameters of the robot: the shared [`Geometry`] (anchors and encoder offsets), under
/// the name the calibration code has always used.
pub type Params = Geometry;
pub use taut_model::geometry::{Geometry, GeometryError, Sigmas};

/// A robust loss on the normalised residual `e = r / sigma`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RobustLoss {
    /// Plain least squares, `rho = e^2 / 2`.
    None,
    /// Huber: quadratic up to `|e| = k`, linear beyond. Convex, so it cannot create local minima.
    Huber {
        /// Threshold in sigmas.
        k: f64,
    },
    /// Cauchy: `rho = c^2/2 ln(1 + e^2/c^2)`; a gross outlier's weight goes to zero. Not convex:
    /// use it from a good start.
    Cauchy {
        /// Scale in sigmas.
        c: f64,
    },
}

/// Options of [`calibrate`] and of the initialisation.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibOptions {
    /// Use tensions: exclude loose readings and add the stretch variance. `false` gives the
    /// paper's unweighted baseline (uniform variance, nothing excluded).
    pub force_aware: bool,
    /// Readings with less tension than this are loose and excluded, N.
    pub min_tension_n: f64,
    /// Tracker position noise, 1-sigma per axis, m (isotropic).
    pub tracker_sigma_m: f64,
    /// Full tracker position covariance, m^2, row-major; overrides `tracker_sigma_m` (e.g. a
    /// stereo tracker that is worse in depth).
    pub tracker_cov_m2: Option<[[f64; 3]; 3]>,
    /// Encoder length noise, 1-sigma, m.
    pub encoder_sigma_m: f64,
    /// Axial stiffness EA of the cables, N (0 or infinite: no stretch term).
    pub cable_ea_n: f64,
    /// Fraction of the recording (its last block in time) held out for validation; 0 disables.
    pub heldout_fraction: f64,
    /// LM iteration limit per cable (one pass over the data each).
    pub max_iterations: usize,
    /// Robust loss against tracker outliers.
    pub loss: RobustLoss,
    /// Warn (and list in [`CalibReport::weak`]) when a parameter's one-sigma exceeds this, m.
    pub weak_sigma_m: f64,
    /// Refuse when a parameter's one-sigma exceeds this, m.
    pub max_sigma_m: f64,
    /// A reading whose normalised residual exceeds this many sigmas is counted as an outlier in
    /// the report.
    pub outlier_sigma: f64,
    /// Threads the per-cable work may use ([`par`]): 1 (the default) keeps it on the caller's
    /// thread; more gives the same results sooner on a machine with free cores.
    pub threads: usize,
    /// The design's priors, one per cable: means and 1-sigmas of `[A_x, A_y, A_z, L0]`
    /// (`RobotConfig::priors`; infinite sigma: none for that parameter). With them the
    /// calibration is maximum a posteriori: a parameter the recording does not excite keeps
    /// its prior's uncertainty instead of being refused ([`CableReport::data_share`]).
    pub priors: Option<Vec<([f64; 4], [f64; 4])>>,
    /// Test the held-out residual against the noise model ([`consistency`], a 5-block cross-fit
    /// independent of `heldout_fraction`; true). The daemon's backend, which holds nothing out
    /// itself, keeps it.
    pub model_check: bool,
}

impl Default for CalibOptions {
    fn default() -> Self {
        Self::from_config(&CalibrationConfig::default())
    }
}

impl CalibOptions {
    /// Options from the `[calibration]` table of a robot configuration, with the solver defaults.
    pub fn from_config(c: &CalibrationConfig) -> Self {
        CalibOptions {
            force_aware: true,
            min_tension_n: c.min_tension_n,
            tracker_sigma_m: c.tracker_sigma_m,
            tracker_cov_m2: None,
            encoder_sigma_m: c.encoder_sigma_m,
            cable_ea_n: c.cable_ea_n,
            heldout_fraction: c.heldout_fraction,
            max_iterations: 100,
            // k = 2: 98% efficient on Gaussian noise; a 5 cm tracker outlier (30 sigma) pulls
            // like a 2-sigma reading instead of a 30-sigma one.
            loss: RobustLoss::Huber { k: 2.0 },
            weak_sigma_m: c.weak_sigma_m,
            max_sigma_m: c.max_sigma_m,
            outlier_sigma: 6.0,
            threads: 1,
            priors: None,
            model_check: true,
        }
    }
}

/// One of a cable's four parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    /// Anchor x.
    Ax,
    /// Anchor y.
    Ay,
    /// Anchor z.
    Az,
    /// Encoder offset.
    L0,
}

impl Param {
    /// Parameter by index in `(A_x, A_y, A_z, L0)`.
    pub fn from_index(k: usize) -> Self {
        [Param::Ax, Param::Ay, Param::Az, Param::L0][k]
    }

    /// What motion excites this parameter.
    pub fn advice(self) -> &'static str {
        match self {
            Param::Ax => "move the platform along x, towards and away from the anchor",
            Param::Ay => "move the platform along y, towards and away from the anchor",
            Param::Az => "move the platform vertically",
            Param::L0 => "move the platform over a wider range of distances from the anchor",
        }
    }
}

impl fmt::Display for Param {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Param::Ax => "A_x",
            Param::Ay => "A_y",
            Param::Az => "A_z",
            Param::L0 => "L0",
        })
    }
}

/// Why [`calibrate`] gave no result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CalibError {
    /// Counts of cables disagree between recording, platform points and initial parameters.
    CableCount {
        /// Length columns in the recording.
        recording: usize,
        /// Platform points given.
        platform_points: usize,
        /// Cables in the initial parameters.
        init: usize,
    },
    /// An initial parameter is NaN or infinite.
    BadInit {
        /// Cable index.
        cable: usize,
    },
    /// Too few usable readings for a cable.
    TooFewReadings {
        /// Cable index.
        cable: usize,
        /// Readings usable.
        used: usize,
        /// Readings excluded as loose.
        loose: usize,
        /// Readings missing.
        missing: usize,
        /// Readings needed.
        needed: usize,
    },
    /// The recording does not excite a parameter.
    NotObservable {
        /// Cable index.
        cable: usize,
        /// The parameter that dominates the weakest direction.
        param: Param,
        /// Smallest singular value of the weighted Jacobian.
        singular_value: f64,
        /// Largest singular value.
        largest: f64,
        /// One-sigma of `param`, m (possibly infinite).
        sigma_m: f64,
        /// The refusal tolerance `max_sigma_m`, m.
        max_sigma_m: f64,
        /// True when `J^T W J` cannot be inverted (no information at all in some direction);
        /// false when the direction is excited but too weakly for `max_sigma_m`.
        singular: bool,
    },
    /// The iteration produced non-finite parameters.
    Diverged {
        /// Cable index.
        cable: usize,
    },
}

impl fmt::Display for CalibError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            CalibError::CableCount { recording, platform_points, init } => write!(
                f,
                "the recording has {recording} cables, the configuration {platform_points} platform points and the initial estimate {init} cables; use the configuration of the robot that made the recording"
            ),
            CalibError::BadInit { cable } => {
                write!(f, "cable {}: the initial anchor or offset is not a finite number; run the initialisation first", cable + 1)
            }
            CalibError::TooFewReadings { cable, used, loose, missing, needed } => write!(
                f,
                "cable {}: only {used} usable readings ({loose} loose, {missing} missing), at least {needed} needed; record with this cable under tension (>= min_tension_n) while the tracker sees the platform", cable + 1
            ),
            CalibError::NotObservable { cable, param, singular: true, .. } => write!(
                f,
                "cable {}: {param} is not observable from this recording (no information in its direction): {}", cable + 1,
                param.advice()
            ),
            CalibError::NotObservable { cable, param, sigma_m, max_sigma_m, singular: false, .. } => write!(
                f,
                "cable {}: {param} is too weakly determined by this recording (1-sigma {:.1} mm, above calibration.max_sigma_m = {:.1} mm): {}; or move the platform over a larger part of the workspace, in all three directions, or record longer (or raise calibration.max_sigma_m to accept it)", cable + 1,
                sigma_m * 1e3,
                max_sigma_m * 1e3,
                param.advice()
            ),
            CalibError::Diverged { cable } => write!(
                f,
                "cable {}: the calibration diverged (non-finite parameters); check the initial estimate and that the tracker and encoder columns belong together", cable + 1
            ),
        }
    }
}

impl std::error::Error for CalibError {}

/// Readings not used by the calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Excluded {
    /// Loose: tension below `min_tension_n`.
    pub loose: usize,
    /// Missing position, orientation, length or tension.
    pub missing: usize,
}

/// The result for one cable.
#[derive(Debug, Clone, PartialEq)]
pub struct CableReport {
    /// Why its LM stopped.
    pub termination: Termination,
    /// LM iterations (passes over its readings).
    pub iterations: usize,
    /// Final robust cost.
    pub cost: f64,
    /// Readings used.
    pub used: usize,
    /// Readings excluded.
    pub excluded: Excluded,
    /// Used readings the robust loss down-weighted (`|e| > k`).
    pub downweighted: usize,
    /// Used readings beyond `outlier_sigma` sigmas.
    pub outliers: usize,
    /// A-posteriori variance factor `chi2 / (m - 4)`.
    pub variance_factor: f64,
    /// Co-registration RMS and peak on the used readings, m.
    pub rms_m: f64,
    /// Peak |residual| on the used readings, m.
    pub peak_m: f64,
    /// RMS on the held-out block with parameters from the training block, m (NaN if none).
    pub heldout_rms_m: f64,
    /// Per parameter `[A_x, A_y, A_z, L0]`, how much of the estimate came from the data:
    /// `1 - sigma_posterior^2 / sigma_prior^2` (0: the prior alone, 1: the data alone); NaN
    /// where the parameter has no prior ([`CalibOptions::priors`]).
    pub data_share: [f64; 4],
}

/// What [`calibrate`] found, and how sure it is.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibReport {
    /// Calibrated parameters (all taut readings).
    pub params: Params,
    /// One-sigma of each anchor coordinate and offset, m (scaled by the variance factor when
    /// above 1).
    pub sigma: Sigmas,
    /// Covariance of `(A_x, A_y, A_z, L0)` per cable, m^2.
    pub covariance: Vec<[[f64; 4]; 4]>,
    /// The worst termination over cables.
    pub termination: Termination,
    /// The largest iteration count over cables.
    pub iterations: usize,
    /// Total robust cost.
    pub cost: f64,
    /// Singular values of each cable's weighted Jacobian, largest first.
    pub singular_values: Vec<[f64; 4]>,
    /// Readings used (sample x cable).
    pub samples_used: usize,
    /// Readings not used: loose + missing.
    pub samples_excluded: usize,
    /// The excluded readings by reason.
    pub excluded: Excluded,
    /// Used readings the robust loss down-weighted.
    pub downweighted: usize,
    /// Used readings beyond `outlier_sigma` sigmas.
    pub outliers: usize,
    /// True when tensions entered the weights.
    pub used_tensions: bool,
    /// How readings were weighted.
    pub weighting: Weighting,
    /// Co-registration RMS on the used readings, m.
    pub rms_m: f64,
    /// Peak |co-registration error| on the used readings, m.
    pub peak_m: f64,
    /// Co-registration RMS on the used and the loose readings (everything but missing values), m.
    pub rms_all_m: f64,
    /// Peak on the used and the loose readings, m.
    pub peak_all_m: f64,
    /// RMS on the used readings of the held-out block (the last `heldout_fraction` of the
    /// recording in time), with parameters calibrated on the training block only, m. `None` when
    /// disabled (`heldout_fraction` 0) or too short: NaN.
    pub heldout_rms_m: f64,
    /// Peak on the held-out block, m (NaN when there is none).
    pub heldout_peak_m: f64,
    /// Per-cable details.
    pub per_cable: Vec<CableReport>,
    /// Parameters returned although their one-sigma exceeds `weak_sigma_m`.
    pub weak: Vec<WeakParam>,
    /// Things a person should know (fallbacks, scaled sigmas, exclusions, weak parameters);
    /// first, when the model is inconsistent, the consistency test's words.
    pub notes: Vec<String>,
    /// The held-out residual against the noise model ([`consistency`], every reading held out
    /// once in a 5-block cross-fit); `None` when switched off ([`CalibOptions::model_check`]) or
    /// when a cable's cross-fit is singular.
    pub consistency: Option<consistency::ModelConsistency>,
}

impl CalibReport {
    /// False when the held-out test says the model does not explain the data
    /// ([`consistency::ModelConsistency`]); true when it does or the test was not made.
    pub fn model_consistent(&self) -> bool {
        self.consistency.is_none_or(|c| c.consistent)
    }
}

/// A parameter the recording determines only weakly (one-sigma above `weak_sigma_m`, below the
/// refusal tolerance `max_sigma_m`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeakParam {
    /// Cable index.
    pub cable: usize,
    /// Which parameter.
    pub param: Param,
    /// Its one-sigma, m.
    pub sigma_m: f64,
}

impl WeakParam {
    /// The parameters of cable `cable` whose one-sigma (`sig`: A_x, A_y, A_z, L0, m) exceeds
    /// `weak_sigma_m`, in that order.
    pub fn of_cable(cable: usize, sig: [f64; 4], weak_sigma_m: f64) -> impl Iterator<Item = WeakParam> {
        (0..4).filter(move |&k| sig[k] > weak_sigma_m).map(move |k| WeakParam { cable, param: Param::from_index(k), sigma_m: sig[k] })
    }

    /// The parameters of `sigma` above `weak_sigma_m`, in the order cable, A_x, A_y, A_z, L0
    /// (for a set whose uncertainty comes from elsewhere than [`calibrate`]'s per-cable solve,
    /// e.g. the bundle refinement).
    pub fn of_sigmas(sigma: &Sigmas, weak_sigma_m: f64) -> Vec<WeakParam> {
        let cables = sigma.anchors.iter().zip(&sigma.l0).enumerate();
        cables.flat_map(|(j, (a, &l0))| Self::of_cable(j, [a[0], a[1], a[2], l0], weak_sigma_m)).collect()
    }
}

impl fmt::Display for WeakParam {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "cable {}: {} is weakly determined (1-sigma {:.1} mm, above calibration.weak_sigma_m): estimate kept; to improve it, {}",
            self.cable + 1,
            self.param,
            self.sigma_m * 1e3,
            self.param.advice()
        )
    }
}

impl CalibReport {
    /// True when every cable converged.
    pub fn was_successful(&self) -> bool {
        self.termination.was_successful()
    }
}

/// The parameters one cable's design prior (means and 1-sigmas of `[A_x, A_y, A_z, L0]`,
/// [`CalibOptions::priors`]) constrains: `(k, mean, 1-sigma)` for each with a finite mean and a
/// finite positive sigma; any other has no prior. Every fit with priors reads them through this.
pub(crate) fn prior_terms((mu, sd): &([f64; 4], [f64; 4])) -> impl Iterator<Item = (usize, f64, f64)> + '_ {
    (0..4).filter(|&k| mu[k].is_finite() && sd[k].is_finite() && sd[k] > 0.0).map(|k| (k, mu[k], sd[k]))
}

/// Calibrates anchors and encoder offsets from `rec`, starting at `init`.
///
/// `platform_points[j]` is `b_j`, the attachment point of cable `j` on the platform (zero for a
/// point mass). The parameters come from all used readings; the held-out figures from a second
/// solve on the training block only.
pub fn calibrate(rec: &Recording, platform_points: &[[f64; 3]], init: &Params, opts: &CalibOptions) -> Result<CalibReport, CalibError> {
    calibrate_readings(rec, platform_points, init, opts, None)
}

/// [`calibrate`] on readings gathered once for the initialisation, the calibration and the
/// Cramér–Rao bound: `data` must be `noise::gather(rec, platform_points, opts, Weighting::of(rec,
/// opts))` (checked for its shape); the calibration sets their variances.
pub fn calibrate_gathered(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    init: &Params,
    opts: &CalibOptions,
    data: &mut [noise::CableData],
) -> Result<CalibReport, CalibError> {
    assert!(data.len() == rec.n_cables && data.iter().all(|d| d.len() == rec.len()), "readings gathered from this recording");
    calibrate_readings(rec, platform_points, init, opts, Some(data))
}

fn calibrate_readings(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    init: &Params,
    opts: &CalibOptions,
    gathered: Option<&mut [noise::CableData]>,
) -> Result<CalibReport, CalibError> {
    let n = rec.n_cables;
    if platform_points.len() != n || init.anchors.len() != n || init.l0.len() != n {
        return Err(CalibError::CableCount { recording: n, platform_points: platform_points.len(), init: init.anchors.len() });
    }
    for j in 0..n {
        if !init.cable(j).iter().all(|v| v.is_finite()) {
            return Err(CalibError::BadInit { cable: j });
        }
    }
    let weighting = Weighting::of(rec, opts);
    let nm = noise::NoiseModel::new(opts, weighting);
    let mut own: Vec<noise::CableData>;
    let data = match gathered {
        Some(d) => d,
        None => {
            own = noise::gather(rec, platform_points, opts, weighting);
            &mut own[..]
        }
    };
    let split = metrics::heldout_start(rec, opts.heldout_fraction);
    if let Some(p) = &opts.priors {
        if p.len() != n {
            return Err(CalibError::CableCount { recording: n, platform_points: platform_points.len(), init: p.len() });
        }
        for (d, p) in data.iter_mut().zip(p) {
            d.prior = Some(*p);
        }
    }
    // The cables are independent problems (on `opts.threads` threads); everything summed or
    // listed over them is summed and listed in cable order below, as one thread would.
    let cables = par::map_mut(opts.threads, data, |j, d| calibrate_cable(j, d, init, &nm, opts, split, rec.len()));

    let mut xs = Vec::with_capacity(n);
    let mut per_cable = Vec::with_capacity(n);
    let mut covariance = Vec::with_capacity(n);
    let mut singular_values = Vec::with_capacity(n);
    let mut notes = Vec::new();
    let mut weak = Vec::new();
    let mut terms = consistency::HeldoutTerms::with_rows(rec.len());
    let mut cables_crossfit = 0;
    let (mut ho_sum, mut ho_n, mut ho_peak) = (0.0, 0usize, 0.0f64);
    let (mut all_sum, mut all_n, mut all_peak) = (0.0, 0usize, 0.0f64);
    for c in cables {
        let c = c?;
        notes.extend(c.weak.iter().map(|w| w.to_string()));
        weak.extend(c.weak);
        if let Some(t) = &c.heldout_terms {
            cables_crossfit += usize::from(t.score.len() == terms.score.len());
            terms.merge(t);
        }
        if let Some((sum, count, peak)) = c.heldout {
            ho_sum += sum;
            ho_n += count;
            ho_peak = ho_peak.max(peak);
        }
        notes.extend(c.notes);
        all_sum += c.all.0;
        all_n += c.all.1;
        all_peak = all_peak.max(c.all.2);
        covariance.push(c.covariance);
        singular_values.push(c.singular_values);
        per_cable.push(c.report);
        xs.push(c.x);
    }
    let params = Params::from_cables(&xs);
    match weighting {
        Weighting::UniformNoTensions => {
            notes.insert(0, "the recording has no tensions: uniform weights, loose cables cannot be detected and are not excluded".into())
        }
        Weighting::UniformByOption => notes.insert(0, "force weighting switched off: uniform weights, loose readings not excluded".into()),
        Weighting::ForceAware => {}
    }
    // Every cable's cross-fit must be there for the test to be of the model.
    let consistency = if cables_crossfit == n { consistency::ModelConsistency::test(&terms, consistency::CONSISTENCY_ALPHA) } else { None };
    if let Some(c) = consistency.filter(|c| !c.consistent) {
        notes.insert(0, c.to_string());
    }
    let used: usize = per_cable.iter().map(|c| c.used).sum();
    let sum_sq: f64 = per_cable.iter().map(|c| c.rms_m * c.rms_m * c.used as f64).sum();
    let worst = per_cable.iter().map(|c| c.termination).max_by_key(|t| t.severity()).unwrap_or(Termination::SmallStep);
    Ok(CalibReport {
        sigma: Sigmas::from_variances(
            &covariance.iter().flat_map(|c| [c[0][0], c[1][1], c[2][2], c[3][3]]).collect::<Vec<_>>(),
            covariance.len(),
        ),
        covariance,
        termination: worst,
        iterations: per_cable.iter().map(|c| c.iterations).max().unwrap_or(0),
        cost: per_cable.iter().map(|c| c.cost).sum(),
        singular_values,
        samples_used: used,
        samples_excluded: per_cable.iter().map(|c| c.excluded.loose + c.excluded.missing).sum(),
        excluded: Excluded {
            loose: per_cable.iter().map(|c| c.excluded.loose).sum(),
            missing: per_cable.iter().map(|c| c.excluded.missing).sum(),
        },
        downweighted: per_cable.iter().map(|c| c.downweighted).sum(),
        outliers: per_cable.iter().map(|c| c.outliers).sum(),
        used_tensions: weighting.uses_tensions(),
        weighting,
        rms_m: (sum_sq / used.max(1) as f64).sqrt(),
        peak_m: per_cable.iter().map(|c| c.peak_m).fold(0.0, f64::max),
        rms_all_m: (all_sum / all_n.max(1) as f64).sqrt(),
        peak_all_m: all_peak,
        heldout_rms_m: if ho_n > 0 { (ho_sum / ho_n as f64).sqrt() } else { f64::NAN },
        heldout_peak_m: if ho_n > 0 { ho_peak } else { f64::NAN },
        per_cable,
        params,
        weak,
        notes,
        consistency,
    })
}

/// What [`calibrate`] found for one cable, summed over the cables in cable order.
struct CableOutcome {
    x: [f64; 4],
    report: CableReport,
    covariance: [[f64; 4]; 4],
    singular_values: [f64; 4],
    /// Weak parameters (each also a note, listed before `notes`).
    weak: Vec<WeakParam>,
    notes: Vec<String>,
    /// Held-out sum of squares, readings and peak, when there is a held-out block.
    heldout: Option<(f64, usize, f64)>,
    /// The consistency test's cross-fitted terms, one per row ([`crossfit_terms`]; `None` when
    /// switched off or singular).
    heldout_terms: Option<consistency::HeldoutTerms>,
    /// Sum of squares, readings and peak over the used and the loose readings.
    all: (f64, usize, f64),
}

/// Adds to `out` the consistency test's terms of cable data `d` on slots `lo..hi` at the
/// training parameters `x` with the training block's inverse normal matrix `h_inv` (the
/// parameters' covariance under the noise model).
fn consistency_terms(
    d: &noise::CableData,
    lo: usize,
    hi: usize,
    x: &[f64; 4],
    h_inv: &nalgebra::Matrix4<f64>,
    outlier_sigma: f64,
    out: &mut consistency::HeldoutTerms,
) {
    let c = h_inv;
    for k in lo..hi {
        if d.class[k] != noise::USED || !(d.iv[k] > 0.0) {
            continue;
        }
        let (dx, dy, dz) = (d.x[k] - x[0], d.y[k] - x[1], d.z[k] - x[2]);
        let rho = (dx * dx + dy * dy + dz * dz).sqrt();
        let r = d.l[k] - (rho + x[3]);
        let j = [-dx / rho, -dy / rho, -dz / rho, 1.0];
        let mut q = 0.0;
        for a in 0..4 {
            q += j[a] * (c[(a, 0)] * j[0] + c[(a, 1)] * j[1] + c[(a, 2)] * j[2] + c[(a, 3)] * j[3]);
        }
        out.add(k, r, d.iv[k], q, outlier_sigma);
    }
}

/// Time blocks of the consistency test's cross-fit ([`crossfit_terms`]).
const CROSSFIT_BLOCKS: usize = 5;

/// The consistency test's terms of every slot `0..slots` of cable data `d`, each predicted by
/// parameters fitted without its time block: the slots are cut into [`CROSSFIT_BLOCKS`]
/// contiguous blocks, and each block is predicted from one Gauss-Newton step from the full
/// solution `x` on the other blocks (as the held-out figures are: the step lands on the
/// training optimum to a small fraction of a sigma); the other blocks' normal equations are the
/// whole recording's less the block's. Every reading is then held out once, five times the
/// readings of the last-block split, for two passes over the data. `None` when a block's
/// training normal matrix is singular. `all` is `solver::pass(d, 0, slots, x, opts.loss)` when
/// the caller has it already.
fn crossfit_terms(
    d: &noise::CableData,
    slots: usize,
    x: &[f64; 4],
    opts: &CalibOptions,
    all: Option<solver::Pass>,
) -> Option<consistency::HeldoutTerms> {
    let mut out = consistency::HeldoutTerms::with_rows(slots);
    let all = all.unwrap_or_else(|| solver::pass(d, 0, slots, x, opts.loss));
    for b in 0..CROSSFIT_BLOCKS {
        let (lo, hi) = (b * slots / CROSSFIT_BLOCKS, (b + 1) * slots / CROSSFIT_BLOCKS);
        let blk = solver::pass(d, lo, hi, x, opts.loss);
        let mut tp = all;
        tp.h.iter_mut().zip(&blk.h).for_each(|(a, b)| *a -= b);
        tp.g.iter_mut().zip(&blk.g).for_each(|(a, b)| *a -= b);
        let h = tp.h_matrix();
        let step = h.cholesky().map(|c| c.solve(&nalgebra::Vector4::from(tp.g)))?;
        let h_inv = h.try_inverse()?;
        let xt = [x[0] + step[0], x[1] + step[1], x[2] + step[2], x[3] + step[3]];
        if !xt.iter().all(|v| v.is_finite()) {
            return None;
        }
        consistency_terms(d, lo, hi, &xt, &h_inv, opts.outlier_sigma, &mut out);
    }
    Some(out)
}

/// [`calibrate`] for cable `j` on its readings `d`; `split` is the first held-out slot, `rows`
/// the recording's length.
fn calibrate_cable(
    j: usize,
    d: &mut noise::CableData,
    init: &Params,
    nm: &noise::NoiseModel,
    opts: &CalibOptions,
    split: usize,
    rows: usize,
) -> Result<CableOutcome, CalibError> {
    // `m` readings used; the solver runs over all `slots` (unused ones weigh zero).
    let (m, slots) = (d.used, d.len());
    if m < MIN_READINGS {
        return Err(CalibError::TooFewReadings { cable: j, used: m, loose: d.loose, missing: d.missing, needed: MIN_READINGS });
    }
    // The variances depend (weakly) on the geometry (stretch ~ rho, tracker projection ~ u).
    // They are held fixed during a solve, so that LM's accept/reject test compares values of
    // one cost function: a least-squares stage with the uniform variance brings the start
    // near the optimum, the variances are then set at that point (a few sigma from the final
    // one) for the final solve, and re-checked once more if that solve moved the anchor by
    // more than 0.5% of the shortest cable (an isotropic tracker's variances then change by
    // under 1%; with an anisotropic one they are always re-checked).
    let x0 = init.cable(j);
    d.set_uniform_variance(nm.uniform_variance());
    let s1 = solver::lm(d, 0, slots, x0, RobustLoss::None, opts.max_iterations, solver::Tolerances::COARSE);
    let mut iterations = s1.iterations;
    if !s1.x.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Diverged { cable: j });
    }
    let x = s1.x;
    d.set_variances(&x, nm);
    let mut x_var = x;
    let mut sol = solver::lm(d, 0, slots, x, opts.loss, opts.max_iterations, solver::Tolerances::FINAL);
    iterations += sol.iterations;
    for _ in 0..3 {
        if !sol.x.iter().all(|v| v.is_finite()) {
            return Err(CalibError::Diverged { cable: j });
        }
        let moved = model::norm(model::sub([sol.x[0], sol.x[1], sol.x[2]], [x_var[0], x_var[1], x_var[2]]));
        if nm.iso.is_some() && moved <= 0.005 * d.rho_min {
            break;
        }
        x_var = sol.x;
        if d.set_variances(&sol.x, nm) <= 0.01 {
            break;
        }
        sol = solver::lm(d, 0, slots, sol.x, opts.loss, opts.max_iterations, solver::Tolerances::FINAL);
        iterations += sol.iterations;
    }
    if !sol.x.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Diverged { cable: j });
    }
    sol.iterations = iterations;
    let fin = solver::final_pass(d, 0, slots, &sol.x, opts.loss, opts.outlier_sigma);
    sol.at_x = fin.pass;
    let h = sol.at_x.h_matrix();
    let eig = nalgebra::SymmetricEigen::new(h);
    let mut order: [usize; 4] = [0, 1, 2, 3];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let sv = order.map(|k| eig.eigenvalues[k].max(0.0).sqrt());
    // A prior's parameters are pseudo-readings: they count in the degrees of freedom.
    let mut prior_sigma = [f64::INFINITY; 4];
    for (k, _, s) in d.prior.iter().flat_map(prior_terms) {
        prior_sigma[k] = s;
    }
    let n_prior = prior_sigma.iter().filter(|s| s.is_finite() && **s > 0.0).count();
    let vf = sol.at_x.chi2 / ((m + n_prior) as f64 - 4.0);
    let scale = vf.max(1.0);
    // The variance factor scales the data's information, not the prior's (whose variance is
    // given): H = H_data / scale + H_prior.
    let mut hs = h;
    for k in 0..4 {
        if prior_sigma[k].is_finite() && prior_sigma[k] > 0.0 {
            let w = 1.0 / (prior_sigma[k] * prior_sigma[k]);
            hs[(k, k)] -= w;
        }
    }
    hs /= scale;
    for k in 0..4 {
        if prior_sigma[k].is_finite() && prior_sigma[k] > 0.0 {
            hs[(k, k)] += 1.0 / (prior_sigma[k] * prior_sigma[k]);
        }
    }
    // By Cholesky: nalgebra's 4x4 `try_inverse` is the adjugate formula, which loses the small
    // eigenvalues of this matrix (1e9 along the cable against 1e3 across a short swing) to
    // cancellation.
    let cov = hs.cholesky().map(|c| c.inverse());
    let sig: [f64; 4] = match &cov {
        Some(c) => [0, 1, 2, 3].map(|k| c[(k, k)].max(0.0).sqrt()),
        None => [f64::INFINITY; 4],
    };
    // Observability by the predicted uncertainty: refuse beyond the user's tolerance (or
    // without any information in some direction), warn beyond the weak level.
    let singular = cov.is_none() || sig.iter().any(|s| !s.is_finite());
    // With a prior a parameter's sigma is at most the prior's: the refusal applies to the
    // parameters the recording alone must determine.
    let too_wide = |k: usize| !(sig[k] <= opts.max_sigma_m) && !prior_sigma[k].is_finite();
    if singular || (0..4).any(too_wide) {
        let param = if singular {
            let weakest = eig.eigenvectors.column(order[3]).into_owned();
            dominant(&[weakest[0], weakest[1], weakest[2], weakest[3]])
        } else {
            Param::from_index((0..4).filter(|&k| too_wide(k)).max_by(|&a, &b| sig[a].total_cmp(&sig[b])).unwrap_or(0))
        };
        let k = param as usize;
        return Err(CalibError::NotObservable {
            cable: j,
            param,
            singular_value: sv[3],
            largest: sv[0],
            sigma_m: sig[k],
            max_sigma_m: opts.max_sigma_m,
            singular,
        });
    }
    let weak: Vec<WeakParam> = WeakParam::of_cable(j, sig, opts.weak_sigma_m).collect();
    let mut notes = Vec::new();
    let data_share: [f64; 4] =
        std::array::from_fn(
            |k| if prior_sigma[k].is_finite() { (1.0 - (sig[k] / prior_sigma[k]).powi(2)).clamp(0.0, 1.0) } else { f64::NAN },
        );
    for (k, &share) in data_share.iter().enumerate() {
        if share.is_finite() && share < 0.5 {
            notes.push(format!(
                "cable {}: {} is mostly the design's prior ({:.0} % from the data; 1-sigma {:.1} mm of the prior's {:.1} mm)",
                j + 1,
                Param::from_index(k),
                100.0 * share,
                sig[k] * 1e3,
                prior_sigma[k] * 1e3
            ));
        }
    }
    // Held-out: the parameters of the training block alone, evaluated on the rest. The
    // training optimum is within about a standard deviation of the full-data one, where the
    // cost is quadratic: one Gauss-Newton step from the full solution on the training block
    // lands on it to a small fraction of a sigma (checked against a full solve in the
    // tests), for one pass instead of a whole solve.
    let ntrain = d.used_in(0..split);
    let (mut heldout, mut heldout_sums) = (f64::NAN, None);
    let mut heldout_terms = None;
    if split < rows && ntrain >= MIN_READINGS && ntrain < m {
        let tp = solver::pass(d, 0, split, &sol.x, opts.loss);
        if let Some(step) = tp.h_matrix().cholesky().map(|c| c.solve(&nalgebra::Vector4::from(tp.g))) {
            let xt = [sol.x[0] + step[0], sol.x[1] + step[1], sol.x[2] + step[2], sol.x[3] + step[3]];
            if xt.iter().all(|v| v.is_finite()) {
                let hs = solver::final_pass(d, split, slots, &xt, opts.loss, opts.outlier_sigma);
                heldout_sums = Some((hs.sum_sq, m - ntrain, hs.peak));
                heldout = (hs.sum_sq / (m - ntrain) as f64).sqrt();
            }
        }
    }
    if opts.model_check {
        // The final pass's sums are the full pass's at `sol.x` (the same loop, with statistics).
        let all = (slots <= rows).then_some(fin.pass);
        heldout_terms = crossfit_terms(d, slots.min(rows), &sol.x, opts, all);
    }
    if d.loose > 0 {
        notes.push(format!("cable {}: {} loose readings excluded (tension < {} N)", j + 1, d.loose, opts.min_tension_n));
    }
    if vf > 1.5 {
        notes.push(format!(
            "cable {}: residuals are {:.1}x larger than the noise model predicts (variance factor {vf:.2}); its sigmas are scaled up accordingly", j + 1,
            vf.sqrt()
        ));
    }
    if !sol.termination.was_successful() {
        notes.push(format!("cable {}: {} after {} iterations", j + 1, sol.termination, sol.iterations));
    }
    let mut c4 = [[0.0; 4]; 4];
    if let Some(c) = &cov {
        for a in 0..4 {
            for b in 0..4 {
                c4[a][b] = c[(a, b)];
            }
        }
    } else {
        c4 = [[f64::INFINITY; 4]; 4];
    }
    let report = CableReport {
        termination: sol.termination,
        iterations: sol.iterations,
        cost: sol.at_x.cost,
        used: m,
        excluded: Excluded { loose: d.loose, missing: d.missing },
        downweighted: fin.downweighted,
        outliers: fin.outliers,
        variance_factor: vf,
        rms_m: (fin.sum_sq / m as f64).sqrt(),
        peak_m: fin.peak,
        heldout_rms_m: heldout,
        data_share,
    };
    Ok(CableOutcome {
        x: sol.x,
        report,
        covariance: c4,
        singular_values: sv,
        weak,
        notes,
        heldout: heldout_sums,
        heldout_terms,
        // All readings, loose ones included.
        all: (fin.sum_sq_all, m + d.loose, fin.peak_all),
    })
}

/// The parameter with the largest component in `v`, preferring an anchor coordinate over `L0`
/// when they are comparable: an anchor coordinate is what motion can fix.
fn dominant(v: &[f64; 4]) -> Param {
    let a = (0..3).max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs())).unwrap_or(2);
    if v[a].abs() >= 0.5 * v[3].abs() {
        Param::from_index(a)
    } else {
        Param::L0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weak_parameters_are_named_by_their_uncertainty() {
        let mut s = Sigmas::uniform(4, 0.5e-3);
        s.anchors[2][0] = 6.6e-3;
        s.l0[3] = 2.5e-3;
        let w = WeakParam::of_sigmas(&s, 2e-3);
        assert_eq!(w.len(), 2);
        assert_eq!((w[0].cable, w[0].param, w[0].sigma_m), (2, Param::Ax, 6.6e-3));
        assert_eq!((w[1].cable, w[1].param), (3, Param::L0));
        assert!(WeakParam::of_sigmas(&Sigmas::uniform(4, 1e-3), 2e-3).is_empty());
        // At the level exactly: not weak.
        let w: Vec<_> = WeakParam::of_cable(1, [2e-3, 3e-3, 1e-3, 4e-3], 2e-3).map(|w| w.param).collect();
        assert_eq!(w, [Param::Ay, Param::L0]);
    }
}
