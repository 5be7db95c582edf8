//! Diagnosis: when the ideal model and a recording disagree, find out why.
//!
//! 1. **Data problems** that are not physics ([`dataq`]): wild values ([`crate::screen`]: encoder
//!    spikes and jumps, impossible tensions, tracker jumps), frozen readings, tracker outliers and
//!    dropouts, clock jumps, dead load cells. Found first, reported with where they are, excluded.
//! 2. **Baseline**: the ideal model `l = |P + R b - A| + L0` fitted on the training blocks (loose
//!    readings excluded: `T < min_tension_n`, or without tensions, readings whose encoder shows
//!    clearly more cable than the straight line).
//! 3. **Locate** the mismatch ([`analysis`]): per cable, per time block, per workspace octant, and
//!    the correlation of the residual with tension, length, T·L, velocity, direction of motion,
//!    elevation, the sag term L^3 cos^2/T^2, 1/T^2 and time.
//! 4. **Name and model** it: forward selection over the effect library ([`effects`]). Each
//!    round, every remaining candidate is fitted jointly with anchors, offsets and the effects
//!    named so far ([`fit`], solved by [`lm`]) on a subsample of the training blocks and tested
//!    on the held-out blocks ([`select`]: the forecast-encompassing test of the nested pair,
//!    with an AR(1)-prewhitened batch-means variance for time-correlated residuals, plus the
//!    current model's own estimation error on the training blocks ([`esterr`]), and a
//!    Student-t reference; time offset and backlash predict held-out samples without their own
//!    readings' noise, so the same test decides all six effects).
//!    Each test runs at `family_alpha / (library x rounds)`, so the probability that a diagnosis
//!    names anything the data do not support is at most `family_alpha` (1e-4 by default). Of the
//!    candidates that pass (and whose parameters are physical: [`Effect::internal_range`] is a
//!    sanity gate, not the decision) the one with the largest held-out gain is named; one that
//!    the named effect adds nothing to at the same level "explains the data equally well", and
//!    the report says which measurement would separate the two. Repeat while effects pass.
//!    Afterwards each named effect's values come from the final joint model, and each is fitted
//!    jointly with the effects it can mimic (time offset / backlash, sag / elasticity, scale /
//!    elasticity, pulley / anchors): the correlation and the joint marginal sigmas are reported.
//! 5. **Show** the fit improve: RMS before and after, in sample and held out.
//!
//! Held-out data are time blocks: the recording is cut into 10 blocks and
//! `round(10 heldout_fraction)` of them, spread over the recording, are held out, so the
//! held-out data cover the workspace rather than only the end of the run.
//!
//! The residuals are weighted uniformly (`sigma^2 = sigma_enc^2 + sigma_tracker^2`): the
//! force-aware variance of [`crate::noise`] grows with T·L, which would down-weight exactly the
//! readings that reveal elasticity. The exception is errors in variables ([`fit::Eiv`]): with
//! [`DiagnoseOptions::loadcell_sigma_n`] a reading whose stretch or sag the tension noise moves
//! counts by its total variance, in the fits and in the held-out tests.
//!
//! ```no_run
//! use taut_calib::diagnose::{diagnose, DiagnoseOptions};
//! use taut_config::{recording::Recording, RobotConfig};
//! let cfg = RobotConfig::load("robot.toml").unwrap();
//! let (rec, _) = Recording::load("rec.csv").unwrap();
//! let d = diagnose(&rec, &cfg.platform_points(), None, &DiagnoseOptions::from_config(&cfg.calibration)).unwrap();
//! for f in &d.effects {
//!     println!("{}: {}", f.effect.name(), f.evidence);
//! }
//! ```

pub mod analysis;
pub mod dataq;
pub mod effects;
pub mod esterr;
pub mod leftover;
/// The joint model the diagnosis fits: [`crate::effects::model`].
pub use crate::effects::model as fit;
/// The dense least-squares problems the diagnosis solves: [`crate::lm::dense`].
pub use crate::lm::dense as lm;
pub mod select;
pub mod tension;

pub use crate::effects::tension::TensionEffect;
use crate::{Geometry, Params, Sigmas};
use analysis::{rms, Mismatch, Regressor};
pub use dataq::{DataProblem, ProblemKind};
pub use effects::{Effect, Sharing, TensionEnd};
use fit::{clear_push_weights, encoder_time_prep, exclude_unseen_pushes, ModelSpec, Prepared};
use nalgebra::{DMatrix, DVector};
pub use select::HeldoutTest;
use std::fmt;
use taut_config::recording::Recording;
use taut_config::CalibrationConfig;

/// Options of [`diagnose`].
#[derive(Debug, Clone, PartialEq)]
pub struct DiagnoseOptions {
    /// Readings with less tension than this are loose, N.
    pub min_tension_n: f64,
    /// Tracker noise, 1-sigma per axis, m.
    pub tracker_sigma_m: f64,
    /// Encoder noise, 1-sigma, m.
    pub encoder_sigma_m: f64,
    /// Load-cell noise, 1-sigma, N: the tension readings' noise enters the predicted length
    /// through `d(stretch + sag)/dT`, and each reading is weighted by its total variance
    /// ([`fit::Eiv`]). 0: the tensions are taken as exact. From `[calibration] loadcell_sigma_n`
    /// (give the load cells' noise to diagnose below the controller's tension floor).
    pub loadcell_sigma_n: f64,
    /// 1-sigma of each load cell's unknown constant offset, N: added to the uncertainty of
    /// stretch and sag (their estimates move with it; see `tension_offset_variance`). 0: the
    /// cells are taken as zeroed exactly. From `[calibration] loadcell_offset_n`.
    pub loadcell_offset_n: f64,
    /// Fraction of the recording held out (in time blocks).
    pub heldout_fraction: f64,
    /// Where the load cells measure tension (sag only).
    pub tension_end: TensionEnd,
    /// At most this many effects are named (slack aside).
    pub max_effects: usize,
    /// Candidate effects are screened on about this many samples.
    pub screen_samples: usize,
    /// The effects to try.
    pub library: Vec<Effect>,
    /// LM iteration limit of a full fit.
    pub max_iterations: usize,
    /// Family-wise false-claim rate of a diagnosis: the probability that any effect is named
    /// that the data do not support is at most this (Bonferroni over the library and the
    /// rounds: each held-out test runs at [`DiagnoseOptions::test_alpha`]).
    pub family_alpha: f64,
    /// Count the current model's estimation error on the training blocks in each held-out
    /// test's variance ([`esterr`]; true). False: the held-out scores' variance only, whose
    /// p-values are too small in the tail; for comparisons only (`tests/examples/null_rate.rs`).
    pub estimation_error: bool,
    /// Backward step (true): after each effect is named, every earlier-named effect is tested
    /// for removal with the same held-out test (the model without it as the current model, it
    /// as the candidate); one the test cannot tell from nothing is dropped and not tried again.
    /// False: forward-only selection (for comparisons only).
    pub backward: bool,
    /// Find stale rows ([`dataq::stale_rows`]: every encoder repeats the previous row while the
    /// platform moves) and leave them out (true). False keeps them, as before (for comparisons
    /// only: `tests/examples/short_recordings.rs`).
    pub stale_rows: bool,
    /// The platform's mass, kg: with it (and tensions in the recording) the tension side runs
    /// ([`tension`]: the load cells against the platform's weight and inertia). `None` (the
    /// default): lengths only.
    pub platform_mass_kg: Option<f64>,
    /// The tension effects to try when the tension side runs.
    pub tension_library: Vec<TensionEffect>,
    /// Unit vector of each cable's swivel-pulley axis, from the anchor towards the winch (the
    /// configuration's `[[cable]] pulley_axis`: `taut_config::RobotConfig::pulley_axes`); empty
    /// (the default): every axis vertical. The pulley effect's path turns about it.
    pub pulley_axis: Vec<[f64; 3]>,
    /// Threads the candidates of a round are fitted on ([`crate::par`]; the diagnosis is the
    /// same whatever the number). 1 by default.
    pub threads: usize,
    /// The design's priors, one per cable: means and 1-sigmas of `[A_x, A_y, A_z, L0]`
    /// (`taut_config::RobotConfig::priors`; a non-finite mean or sigma: none for that
    /// parameter). With them every fit of the diagnosis is maximum a posteriori (each prior one
    /// more row, [`fit::Prepared::priors`]) and the baseline starts from the design, so a
    /// recording that excites little (locked winches) is diagnosed on a geometry the data and
    /// the design agree on. `None` (the default): none.
    pub priors: Option<Vec<([f64; 4], [f64; 4])>>,
}

impl DiagnoseOptions {
    /// Options for the robot `cfg`: its `[calibration]` table ([`DiagnoseOptions::from_config`])
    /// and its cables' swivel-pulley axes.
    pub fn from_robot(cfg: &taut_config::RobotConfig) -> Self {
        DiagnoseOptions { pulley_axis: cfg.pulley_axes(), priors: cfg.priors(), ..Self::from_config(&cfg.calibration) }
    }

    /// Options from the `[calibration]` table (every swivel-pulley axis vertical).
    pub fn from_config(c: &CalibrationConfig) -> Self {
        DiagnoseOptions {
            min_tension_n: c.min_tension_n,
            tracker_sigma_m: c.tracker_sigma_m,
            encoder_sigma_m: c.encoder_sigma_m,
            loadcell_sigma_n: c.loadcell_sigma_n,
            loadcell_offset_n: c.loadcell_offset_n,
            heldout_fraction: if c.heldout_fraction > 0.0 { c.heldout_fraction } else { 0.2 },
            tension_end: TensionEnd::Platform,
            max_effects: 3,
            screen_samples: 3000,
            library: Effect::FITTED.to_vec(),
            max_iterations: 60,
            family_alpha: DEFAULT_FAMILY_ALPHA,
            estimation_error: true,
            backward: true,
            stale_rows: true,
            platform_mass_kg: None,
            tension_library: TensionEffect::ALL.to_vec(),
            pulley_axis: Vec::new(),
            threads: 1,
            priors: None,
        }
    }

    /// The level of each held-out test: `family_alpha / (library size x rounds)`. The library
    /// counts the tension effects when the tension side runs (a platform mass is given): both
    /// sides' tests are one family.
    pub fn test_alpha(&self) -> f64 {
        let fitted = self.library.iter().filter(|e| **e != Effect::Slack).count();
        let tension = if self.platform_mass_kg.is_some() { self.tension_library.len() } else { 0 };
        self.family_alpha / ((fitted + tension).max(1) * self.max_effects.max(1)) as f64
    }
}

/// The default family-wise false-claim rate of a diagnosis (see [`DiagnoseOptions::family_alpha`]).
pub const DEFAULT_FAMILY_ALPHA: f64 = 1e-4;

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self::from_config(&CalibrationConfig::default())
    }
}

/// Why there is no diagnosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DiagnoseError {
    /// Platform points and recording disagree on the number of cables.
    CableCount {
        /// Cables in the recording.
        recording: usize,
        /// Platform points given.
        platform_points: usize,
    },
    /// Too few usable samples after excluding data problems and loose cables.
    TooFewSamples {
        /// Cable with the fewest usable readings.
        cable: usize,
        /// Its usable readings.
        usable: usize,
    },
    /// The ideal-model fit did not produce finite parameters.
    BaselineFailed,
}

impl fmt::Display for DiagnoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DiagnoseError::CableCount { recording, platform_points } => write!(
                f,
                "the recording has {recording} cables but {platform_points} platform points were given; use the configuration of the robot that made the recording"
            ),
            DiagnoseError::TooFewSamples { cable, usable } => write!(
                f,
                "cable {}: only {usable} usable readings after excluding data problems and loose samples; record longer with the cable under tension", cable + 1
            ),
            DiagnoseError::BaselineFailed => {
                write!(f, "the ideal-model fit diverged; check that the tracker and encoder columns belong to the same robot")
            }
        }
    }
}

impl std::error::Error for DiagnoseError {}

/// RMS figures of one model.
#[derive(Debug, Clone, PartialEq)]
pub struct FitSummary {
    /// RMS of the residual on the training readings, m.
    pub rms_m: f64,
    /// RMS on the held-out readings (parameters from the training blocks), m.
    pub heldout_rms_m: f64,
    /// RMS per cable on all usable readings, m.
    pub per_cable_rms_m: Vec<f64>,
    /// Anchors and encoder offsets, m.
    pub params: Geometry,
    /// 1-sigma of the anchors and offsets, m.
    pub sigma: Sigmas,
}

/// One named effect.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// The effect.
    pub effect: Effect,
    /// Cables it shows on.
    pub cables: Vec<usize>,
    /// Parameter value(s) (physical units, see [`Effect::parameter`]): one per cable for a
    /// per-cable effect, one for a shared effect; NaN for a cable without the data to fit it.
    pub values: Vec<f64>,
    /// 1-sigma of each value.
    pub sigmas: Vec<f64>,
    /// Samples (slack only).
    pub samples: Option<usize>,
    /// Training RMS before and after adding the effect, m.
    pub rms_before_m: f64,
    /// Training RMS after, m.
    pub rms_after_m: f64,
    /// Held-out RMS before, m.
    pub heldout_rms_before_m: f64,
    /// Held-out RMS after, m.
    pub heldout_rms_after_m: f64,
    /// The evidence in words.
    pub evidence: String,
    /// Other effects that explain the data equally well on held-out data, with their held-out
    /// RMS, m.
    pub equally_good: Vec<(Effect, f64)>,
    /// Residual before/after against the regressor that revealed it, for figures.
    pub plot: Option<PlotData>,
    /// The held-out test that named it (none for slack).
    pub test: Option<HeldoutTest>,
    /// Joint fits with the effects (or anchors) it can mimic: correlation and the marginal
    /// uncertainty of this effect's parameters when both are fitted together.
    pub joint: Vec<JointFit>,
}

/// This effect fitted together with one it can mimic.
#[derive(Debug, Clone, PartialEq)]
pub struct JointFit {
    /// The other effect; `None`: the anchors (pulley vs shifted anchor).
    pub with: Option<Effect>,
    /// Whether the other effect is named too (then the values are the final model's).
    pub both_named: bool,
    /// Correlation of the two parameter estimates (the largest in magnitude over the cables).
    pub correlation: f64,
    /// This effect's values in the joint fit (physical units).
    pub values: Vec<f64>,
    /// Their marginal 1-sigma from the joint covariance, inflated for correlated residuals.
    pub sigmas: Vec<f64>,
}

/// What the held-out test decided for a candidate effect in one round.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Named: it passed and gained the most this round.
    Named,
    /// Passed, but a paired test says the named one predicts better; tested again next round.
    Outranked,
    /// Passed, and a paired test cannot tell it from the named one.
    Equal,
    /// Passed the test (before the round's comparison).
    Passed,
    /// Does not predict the held-out data better at the test's level.
    NotBetter,
    /// Predicts better, but its parameters are outside the physical range.
    NotPhysical,
    /// Predicts better, but its size is zero within its sigma on every cable (a play of no
    /// width).
    NoSize,
    /// Named earlier; tested for removal once a later effect was named (backward step), and
    /// the model without it predicts the held-out data as well: dropped.
    Dropped,
    /// Named earlier; tested for removal once a later effect was named, and still needed.
    Kept,
    /// Named, then withdrawn: structure that no effect in the library explains remains, and it
    /// is larger than what the named effects explain (the effect was the nearest the library
    /// knows, not the cause).
    Withdrawn,
}

impl Decision {
    /// In words.
    pub fn words(self, alpha: f64) -> String {
        match self {
            Decision::Named => "named".into(),
            Decision::Outranked => "better than the current model, but less so than the named effect (tested again on top of it)".into(),
            Decision::Equal => "explains the held-out data as well as the named effect".into(),
            Decision::Passed => "passed".into(),
            Decision::NotBetter => format!("not better than the current model at alpha {alpha:.1e}"),
            Decision::NotPhysical => "better, but its parameters are not physical".into(),
            Decision::NoSize => "better, but its size is zero within its sigma on every cable".into(),
            Decision::Dropped => format!(
                "named earlier, not needed once a later effect was named (removal test not significant at alpha {alpha:.1e}): dropped"
            ),
            Decision::Kept => "named earlier, still needed once a later effect was named (removal test significant)".into(),
            Decision::Withdrawn => {
                "named, then withdrawn: more structure outside the library remains than the named effects explain".into()
            }
        }
    }
}

/// One candidate's test in one round of the forward selection.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateTest {
    /// Round (1: on top of the ideal model, 2: on top of the first named effect, ...).
    pub round: usize,
    /// The candidate.
    pub effect: Effect,
    /// The held-out test against the current model (`None`: too few held-out samples).
    pub test: Option<HeldoutTest>,
    /// The level it was tested at.
    pub alpha: f64,
    /// What was decided.
    pub decision: Decision,
    /// Its fitted values (screening fit, physical units).
    pub values: Vec<f64>,
    /// Their 1-sigma: inflated for correlated residuals for a candidate that passed (and a
    /// pulley), the plain least-squares sigma otherwise.
    pub sigmas: Vec<f64>,
}

/// Residual against a regressor, before and after, per cable (subsampled).
#[derive(Debug, Clone, PartialEq)]
pub struct PlotData {
    /// The regressor on the x axis.
    pub regressor: Regressor,
    /// Per cable: (x, residual before, residual after), m.
    pub cables: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)>,
}

/// What [`diagnose`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnosis {
    /// Cables.
    pub cables: usize,
    /// Samples in the recording.
    pub samples: usize,
    /// Whether tensions were available (and used).
    pub used_tensions: bool,
    /// The ideal model.
    pub baseline: FitSummary,
    /// Where the baseline mismatch is and what it follows.
    pub mismatch: Mismatch,
    /// Named effects, in the order they were added (slack first when present).
    pub effects: Vec<Finding>,
    /// The final model.
    pub final_fit: FitSummary,
    /// Remaining structure no effect explains, in words.
    pub unexplained: Option<String>,
    /// Data problems (excluded).
    pub data_problems: Vec<DataProblem>,
    /// Candidate effects tried in the last round and why they were not named.
    pub rejected: Vec<String>,
    /// Every candidate's held-out test, round by round.
    pub tests: Vec<CandidateTest>,
    /// The family-wise false-claim rate the tests were run at.
    pub family_alpha: f64,
    /// Things a person should know.
    pub notes: Vec<String>,
    /// Baseline residual against time per cable (subsampled), for figures: (t, r).
    pub baseline_residuals: Vec<(Vec<f64>, Vec<f64>)>,
    /// Final residual against time per cable (subsampled).
    pub final_residuals: Vec<(Vec<f64>, Vec<f64>)>,
    /// The tension side (`None` without tensions or without [`DiagnoseOptions::platform_mass_kg`]).
    pub tension: Option<tension::TensionDiagnosis>,
}

/// The effect models' columns of the rows without data problems ([`fit::prepare`]), with the
/// diagnosis's errors-in-variables weights, velocities, directions and held-out blocks.
fn prepare(rec: &Recording, b: &[[f64; 3]], masks: &dataq::DataMasks, opts: &DiagnoseOptions) -> Prepared {
    let n = rec.n_cables;
    let sel = fit::Selection {
        rows: (0..rec.len()).filter(|&i| masks.row_ok[i]).collect(),
        segment: &masks.segment,
        cable_ok: Some(&masks.cable_ok),
        dead_loadcell: Some(&masks.dead_loadcell),
    };
    let mut prep = fit::prepare(rec, b, &sel, opts.min_tension_n, false, opts.encoder_sigma_m);
    prep.pulley_axis = opts.pulley_axis.clone();
    for (j, p) in opts.priors.iter().flatten().enumerate().take(n) {
        prep.priors.extend(crate::prior_terms(p).map(|(k, mu, sd)| (4 * j + k, mu, sd)));
    }
    let m = prep.t.len();
    // Errors-in-variables weights (time offset: the interpolated pose's noise; stretch and
    // sag: the tension's noise): see `fit::Eiv`.
    prep.eiv = Some(fit::Eiv::new(opts.tracker_sigma_m, opts.encoder_sigma_m, opts.loadcell_sigma_n));
    // Encoder velocity by a central difference over about 40 ms (at least one sample), inside
    // a segment; the direction of motion is held through pauses.
    let k = ((0.02 / masks.dt.max(1e-6)).round() as usize).max(1);
    for j in 0..n {
        let v_noise = opts.encoder_sigma_m * std::f64::consts::SQRT_2 / (2.0 * k as f64 * masks.dt.max(1e-6));
        let thr = (4.0 * v_noise).max(1e-3);
        let mut last = 0.0;
        for i in 0..m {
            let a = i.saturating_sub(k);
            let c = (i + k).min(m - 1);
            let (mut a, mut c) = (a, c);
            while a < i && prep.segment[a] != prep.segment[i] {
                a += 1;
            }
            while c > i && prep.segment[c] != prep.segment[i] {
                c -= 1;
            }
            let v = if c > a && prep.t[c] > prep.t[a] { (prep.l[j][c] - prep.l[j][a]) / (prep.t[c] - prep.t[a]) } else { f64::NAN };
            prep.vel[j][i] = v;
            if v.is_finite() && v.abs() > thr {
                last = v.signum();
            }
            prep.dir[j][i] = last;
        }
    }
    // Held-out time blocks.
    let nb = 10;
    let k_out = ((opts.heldout_fraction * nb as f64).round() as usize).clamp(1, nb - 1);
    let held: Vec<usize> = (0..k_out).map(|q| ((q + 1) * nb) / k_out - 1).collect();
    for i in 0..m {
        let blk = (i * nb / m.max(1)).min(nb - 1);
        prep.heldout[i] = held.contains(&blk);
    }
    prep
}

/// Per-cable algebraic multilateration: `|X|^2 - l^2 = 2 X.A - 2 l L0 + (L0^2 - |A|^2)` is
/// linear in `(A, L0, c)`. Only the fallback when no start is given and the calibration's own
/// initialisation fails.
fn multilaterate(prep: &Prepared, samples: &[usize]) -> Option<Vec<f64>> {
    use nalgebra::{SMatrix, SVector};
    let mut x = vec![];
    for j in 0..prep.n {
        let mut a = SMatrix::<f64, 5, 5>::zeros();
        let mut bv = SVector::<f64, 5>::zeros();
        for &i in samples {
            if !prep.usable[j][i] {
                continue;
            }
            let p = prep.x[j][i];
            let l = prep.l[j][i];
            let row = SVector::<f64, 5>::new(2.0 * p[0], 2.0 * p[1], 2.0 * p[2], -2.0 * l, 1.0);
            let y = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - l * l;
            a += row * row.transpose();
            bv += row * y;
        }
        let s = a.cholesky()?.solve(&bv);
        x.extend_from_slice(&[s[0], s[1], s[2], s[3]]);
    }
    Some(x)
}

#[derive(Clone)]
struct Ctx<'a> {
    prep: &'a Prepared,
    sigma: f64,
    /// 1-sigma of each load cell's unknown constant offset, N (see [`tension_offset_variance`]).
    tension_offset_sigma: f64,
    train: Vec<usize>,
    heldout: Vec<usize>,
    screen_train: Vec<usize>,
    /// Where each held-out time sample's residuals start (see [`Ctx::heldout_residuals`]).
    heldout_rows: Vec<usize>,
    /// Tracker and encoder noise variances, m^2 ([`Ctx::heldout_terms`]).
    tracker_var: f64,
    encoder_var: f64,
}

/// How the held-out test groups the held-out residuals into its score terms (the summands whose
/// time series [`select::long_run_variance`] takes the variance of; [`Ctx::heldout_terms`]):
/// term `t` is the residuals `order[rows[t]..rows[t + 1]]`, the terms in time order.
///
/// The residuals of one term share their tracker noise. Without a play each held-out time
/// sample is a term (its cables share the sample's pose). A play's held reading is predicted from
/// the pose where the play last pushed (its contact), so every reading of a hold (~50 samples of
/// 0.5 s at 100 Hz on the 3-cable robot) carries the same tracker noise: a hold's residuals are
/// one draw (measured on `offset_backlash_coverage`, 30 recordings with a 20 ms offset and a 6
/// mm play: the holds' mean residual 1.3 mm RMS, the readings about it 0.35 mm, the encoder's
/// noise). Counted as ~50 samples the scores' variance would be far too small. So a hold is
/// one term (placed at its contact), and its readings are weighted as the hold's generalised
/// least squares weighs them (`scale`: otherwise the few hold terms carry most of the variance
/// and the test keeps few degrees of freedom). On those recordings 0 of 120 p-values of
/// candidates outside the truth fall below 1e-3 and 1 below 0.01 (BENCHMARKS.md).
#[derive(Debug, Clone)]
struct Terms {
    order: Vec<usize>,
    rows: Vec<usize>,
    /// Per residual (in the residuals' order), the factor both models' residuals are scaled by:
    /// with a play, the square root of the reading's generalised least-squares weight within its
    /// hold of `h` held-out readings, `(s_t^2 + s_e^2) / (h s_t^2 + s_e^2)`; else 1.
    scale: Vec<f64>,
}

fn stride(v: &[usize], target: usize) -> Vec<usize> {
    let s = v.len().div_ceil(target.max(1)).max(1);
    v.iter().step_by(s).copied().collect()
}

fn rms_of(prep: &Prepared, spec: &ModelSpec, samples: &[usize], x: &[f64]) -> f64 {
    let (s, m) = fit::sum_squares(prep, spec, samples, x);
    (s / m.max(1) as f64).sqrt()
}

/// A fitted candidate.
struct Candidate {
    spec: ModelSpec,
    report: lm::LmReport,
    /// Held-out residuals (see [`Ctx::heldout_residuals`]).
    res: Vec<f64>,
    /// Their errors-in-variables factors ([`Ctx::heldout_factors`]).
    res_w: Vec<f64>,
    /// Physical parameter values and sigmas on the screening fit.
    values: Vec<f64>,
    sigmas: Vec<f64>,
    significant: Vec<bool>,
    test: Option<HeldoutTest>,
    decision: Decision,
}

/// An effect's parameters in a fitted model (see [`Ctx::values`]).
struct Values {
    vals: Vec<f64>,
    sigs: Vec<f64>,
    /// Inside the physical range (or not distinguishable from its edge).
    plausible: Vec<bool>,
    /// More than 4 inflated sigmas from the null, and changes the predicted lengths by at
    /// least the measurement noise.
    significant: Vec<bool>,
}

/// LM iterations from each starting weight of the sag candidate before the best goes on.
const SAG_START_ITERATIONS: usize = 6;

impl Ctx<'_> {
    /// The residuals on the held-out samples (time order, usable cables of each sample in
    /// turn: sample `k` is `heldout_rows[k]..heldout_rows[k + 1]`) of `spec` at `x` for the
    /// held-out test against the current model `cur` ([`fit::Joint::heldout_residual`]; the
    /// current model's own are its plain residuals).
    /// `noise_lag`: the tracker noise's correlation length ([`fit::correlation_lag`]).
    fn heldout_residuals(&self, spec: &ModelSpec, x: &[f64], cur: (&ModelSpec, &[f64]), noise_lag: usize) -> Vec<f64> {
        let p = fit::Joint { prep: self.prep, spec, samples: &self.heldout, sigma: 1.0 };
        let c = fit::Joint { prep: self.prep, spec: cur.0, samples: &self.heldout, sigma: 1.0 };
        let mut out = Vec::with_capacity(self.heldout_rows.last().copied().unwrap_or(0));
        for &i in &self.heldout {
            for j in (0..self.prep.n).filter(|&j| self.prep.usable[j][i]) {
                out.push(p.heldout_residual_with(x, &c, cur.1, i, j, noise_lag));
            }
        }
        out
    }

    /// The held-out test's score terms for the current model `spec` at `x` ([`Terms`]): each
    /// held-out residual is placed at the earliest tracker sample its prediction reads
    /// ([`fit::Joint::sources`]), the residuals placed at one sample form one term, and the terms
    /// are in time order. Without a play that is the residual's own sample (the terms are the
    /// held-out time samples); a held reading is placed at its contact, so a hold is one term.
    fn heldout_terms(&self, spec: &ModelSpec, x: &[f64]) -> Terms {
        let n = self.prep.n;
        let rows = self.heldout_rows.last().copied().unwrap_or(0);
        if spec.offset(Effect::Backlash, n).is_none() {
            return Terms { order: (0..rows).collect(), rows: self.heldout_rows.clone(), scale: vec![1.0; rows] };
        }
        let c = fit::Joint { prep: self.prep, spec, samples: &self.heldout, sigma: 1.0 };
        let mut at = Vec::with_capacity(rows);
        let mut hold = Vec::with_capacity(rows);
        for &i in &self.heldout {
            for j in (0..n).filter(|&j| self.prep.usable[j][i]) {
                at.push(c.sources(x, i, j).0.first().map_or(i, |&q| q.min(i)));
                hold.push((j, self.prep.play.contact[j][i]));
            }
        }
        // Each reading weighted as in the generalised least-squares fit of its hold (see
        // `PlayState::hold_weights`), counting the hold's held-out readings.
        let mut count: std::collections::HashMap<(usize, u32), u32> = std::collections::HashMap::new();
        for h in &hold {
            *count.entry(*h).or_default() += 1;
        }
        let (st2, se2) = (self.tracker_var, self.encoder_var.max(1e-18));
        let scale = hold.iter().map(|h| (st2 + se2) / (f64::from(count[h]) * st2 + se2)).map(f64::sqrt).collect();
        let mut order: Vec<usize> = (0..at.len()).collect();
        order.sort_by_key(|&k| (at[k], k));
        let mut rows = vec![0];
        for (q, &k) in order.iter().enumerate() {
            if q > 0 && at[k] != at[order[q - 1]] {
                rows.push(q);
            }
        }
        rows.push(order.len());
        Terms { order, rows, scale }
    }

    /// The errors-in-variables factor `sqrt(sigma^2 / var)` ([`fit::Eiv`]) of each held-out
    /// residual of [`Ctx::heldout_residuals`] (same order): the held-out test compares two models
    /// on residuals scaled by the smaller factor of the two (the larger noise variance), so a
    /// reading whose prediction the tension noise moves by centimetres counts as little in the
    /// test as in the fits. 1 everywhere without tension effects or load-cell noise.
    fn heldout_factors(&self, spec: &ModelSpec, x: &[f64]) -> Vec<f64> {
        let rows = self.heldout_rows.last().copied().unwrap_or(0);
        // Without tension noise only a time offset changes the factor, by the same amount at
        // every sample (its interpolation fraction): no pass needed, the test is scale-free.
        if self.prep.eiv.is_none_or(|e| e.tension_var == 0.0) || !spec.effects.iter().any(|e| e.needs_tension()) {
            return vec![1.0; rows];
        }
        let p = fit::Joint { prep: self.prep, spec, samples: &self.heldout, sigma: 1.0 };
        let mut out = Vec::with_capacity(rows);
        for &i in &self.heldout {
            for j in (0..self.prep.n).filter(|&j| self.prep.usable[j][i]) {
                let pr = p.predict(x, i, j);
                out.push(p.weight_of(&pr, i, j));
            }
        }
        out
    }

    /// Fits candidate spec `s2` (with effect `e` just added) on the screening samples.
    fn fit_candidate(&self, e: Effect, s2: &ModelSpec, x0: &[f64], iters: usize) -> lm::LmReport {
        if e != Effect::Sag {
            return self.fit(s2, &self.screen_train, x0, iters);
        }
        // The sag excess grows as w^2: near a small start the gradient in w all but vanishes
        // and the fit stays there. Try heavier cables too: a few iterations from each start,
        // then the best one fitted to the end (each catenary is a Newton solve: four full fits
        // were most of a diagnosis's time).
        let o = s2.offset(e, self.prep.n).expect("active");
        let mut best = self.fit(s2, &self.screen_train, x0, SAG_START_ITERATIONS);
        for w in [0.5, 2.0, 8.0] {
            let mut xs = x0.to_vec();
            xs[o] = w;
            let rs = self.fit(s2, &self.screen_train, &xs, SAG_START_ITERATIONS);
            if rs.x.iter().all(|v| v.is_finite()) && (rs.cost < best.cost || !best.cost.is_finite()) {
                best = rs;
            }
        }
        if best.x.iter().all(|v| v.is_finite()) {
            self.fit(s2, &self.screen_train, &best.x, iters)
        } else {
            best
        }
    }

    /// The backward step's test of a named effect `e` in the current model `spec` (fitted on the
    /// training blocks: `cur`): the model without `e` becomes the current model of a forward
    /// round (fitted on the training blocks from `cur`'s values) and `e` its candidate (fitted on
    /// the screening samples), and the same held-out test decides, with the same residual span,
    /// estimation error and clear-push rows as the forward round would use. Returns the reduced
    /// model, its fit and the test (`None`: too few held-out samples); `None` when a fit diverged
    /// (the effect then stays).
    fn removal_test(
        &self,
        e: Effect,
        spec: &ModelSpec,
        cur: &lm::LmReport,
        opts: &DiagnoseOptions,
    ) -> Option<(ModelSpec, lm::LmReport, Option<HeldoutTest>)> {
        let n = self.prep.n;
        let mut red = spec.clone();
        red.effects.retain(|&q| q != e);
        let x0 = red.extend(n, spec, &cur.x);
        let pp = play_prep(self.prep, &red, &x0, opts.encoder_sigma_m);
        let red_fit = Ctx { prep: pp.as_ref().unwrap_or(self.prep), ..self.clone() }.fit(&red, &self.train, &x0, opts.max_iterations);
        if !red_fit.x.iter().all(|v| v.is_finite()) {
            return None;
        }
        // As at the start of a forward round with `red` as the current model.
        let phi = fit::noise_phi(self.prep, &red, &self.train, &red_fit.x);
        let noise_lag = fit::correlation_lag(phi, fit::MAX_NOISE_LAG);
        let cur_res = self.heldout_residuals(&red, &red_fit.x, (&red, &red_fit.x), noise_lag);
        let cur_w = self.heldout_factors(&red, &red_fit.x);
        let terms = self.heldout_terms(&red, &red_fit.x);
        let red_pp = play_prep(self.prep, &red, &red_fit.x, opts.encoder_sigma_m);
        let err = opts
            .estimation_error
            .then(|| {
                esterr::EstimationError::new(
                    red_pp.as_ref().unwrap_or(self.prep),
                    &red,
                    &self.train,
                    &self.heldout,
                    &red_fit,
                    self.sigma,
                    phi,
                )
            })
            .flatten();
        // The candidate, from the values it has in the current model.
        let mut s2 = red.clone();
        s2.effects.push(e);
        let xc = s2.extend(n, spec, &cur.x);
        let cpp = red_pp.as_ref().and_then(|_| play_prep(self.prep, &s2, &xc, opts.encoder_sigma_m));
        let r = Ctx { prep: cpp.as_ref().unwrap_or(self.prep), ..self.clone() }.fit_candidate(e, &s2, &xc, 30);
        if !r.x.iter().all(|v| v.is_finite()) {
            return None;
        }
        let cand_phi = fit::noise_phi(self.prep, &s2, &self.train, &r.x);
        let lag = if noise_lag > 1 { fit::correlation_lag(phi.min(cand_phi), fit::MAX_NOISE_LAG) } else { noise_lag };
        let res = self.heldout_residuals(&s2, &r.x, (&red, &red_fit.x), lag);
        let res_w = self.heldout_factors(&s2, &r.x);
        let test = weighted_test(&cur_res, &cur_w, &res, &res_w, &terms, err.as_ref(), Some(cand_phi));
        Some((red, red_fit, test))
    }

    /// The named effects' values and sigmas from the final model `fin` (fitted on the training
    /// blocks), and each named effect fitted jointly with the effects it can mimic.
    fn joint_fits(
        &self,
        effects: &mut [Finding],
        spec: &ModelSpec,
        fin: &lm::LmReport,
        has_t: &[bool],
        opts: &DiagnoseOptions,
        last_round: &[(Effect, Candidate)],
    ) {
        let n = self.prep.n;
        for f in effects.iter_mut().filter(|f| f.effect != Effect::Slack) {
            let e = f.effect;
            // The last named effect's values were computed from this very fit.
            let v = if spec.effects.last() == Some(&e) {
                Values { vals: f.values.clone(), sigs: f.sigmas.clone(), plausible: vec![], significant: vec![] }
            } else {
                self.values(e, spec, fin, has_t, &self.train)
            };
            f.values = v.vals.clone();
            f.sigmas = v.sigs.clone();
            for &p in e.mimics() {
                let Some(p) = p else {
                    // The anchors: always in the model.
                    if let Some(c) = correlation(fin, spec, e, None, n) {
                        f.joint.push(JointFit {
                            with: None,
                            both_named: true,
                            correlation: c,
                            values: v.vals.clone(),
                            sigmas: v.sigs.clone(),
                        });
                    }
                    continue;
                };
                if !opts.library.contains(&p) || (p.needs_tension() && !has_t.iter().any(|h| *h)) {
                    continue;
                }
                if spec.effects.contains(&p) {
                    if let Some(c) = correlation(fin, spec, e, Some(p), n) {
                        f.joint.push(JointFit {
                            with: Some(p),
                            both_named: true,
                            correlation: c,
                            values: v.vals.clone(),
                            sigmas: v.sigs.clone(),
                        });
                    }
                } else if spec.effects.len() < 4 {
                    let mut s2 = spec.clone();
                    s2.effects.push(p);
                    // Fitted already when the last round tested it on top of the final model.
                    let r = match last_round.iter().find(|(q, c)| *q == p && c.spec == s2) {
                        Some((_, c)) => c.report.clone(),
                        None => self.fit_candidate(p, &s2, &s2.extend(n, spec, &fin.x), 30),
                    };
                    if !r.x.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    let vj = self.values(e, &s2, &r, has_t, &self.screen_train);
                    if let Some(c) = correlation(&r, &s2, e, Some(p), n) {
                        f.joint.push(JointFit { with: Some(p), both_named: false, correlation: c, values: vj.vals, sigmas: vj.sigs });
                    }
                }
            }
            let param_text = match e.sharing() {
                Sharing::Shared => format!("{} = {}", e.parameter(), taut_config::numfmt::plus_minus(f.values[0], f.sigmas[0])),
                Sharing::PerCable => format!(
                    "{} = {}",
                    e.parameter(),
                    f.values
                        .iter()
                        .zip(&f.sigmas)
                        .enumerate()
                        .map(|(j, (v, s))| format!("{} ({})", taut_config::numfmt::plus_minus(*v, *s), taut_config::cable_name(j)))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            };
            f.evidence.push_str(&format!("; {param_text}"));
            for j in &f.joint {
                let with = j.with.map_or("the anchors", |w| w.name());
                if j.both_named {
                    f.evidence.push_str(&format!("; correlation with {with} {:+.2}", j.correlation));
                    // Named, but nearly the same model as the other: say how weakly this
                    // recording fixes the split and what would fix it (a pulley against the
                    // anchors is the usual case: r 78 mm against 50 mm true was seen online).
                    if j.correlation.abs() > 0.9 {
                        f.evidence.push_str(&format!(
                            " (weakly observable: the two trade off in this recording; {})",
                            e.separating_measurement(j.with)
                        ));
                    }
                } else if j.correlation.abs() > 0.9 {
                    f.evidence.push_str(&format!(
                        "; fitted together with {with} (not named) the estimates correlate {:+.2}: {}",
                        j.correlation,
                        e.separating_measurement(j.with)
                    ));
                }
            }
        }
    }

    fn fit(&self, spec: &ModelSpec, samples: &[usize], x0: &[f64], iters: usize) -> lm::LmReport {
        fit::fit(self.prep, spec, samples, x0, self.sigma, iters)
    }

    fn summary(&self, spec: &ModelSpec, train_fit: &lm::LmReport, all_fit: &lm::LmReport) -> FitSummary {
        let n = self.prep.n;
        let all: Vec<usize> = (0..self.prep.t.len()).collect();
        let res = fit::residuals(self.prep, spec, &all, &all_fit.x);
        let sig = all_fit.sigmas();
        FitSummary {
            rms_m: rms_of(self.prep, spec, &self.train, &train_fit.x),
            heldout_rms_m: rms_of(self.prep, spec, &self.heldout, &train_fit.x),
            per_cable_rms_m: res.iter().map(|r| rms(r)).collect(),
            params: Geometry::from_packed(&all_fit.x, n),
            sigma: Sigmas::from_packed(&sig, n),
        }
    }

    /// Physical values and least-squares sigmas (not inflated) of effect `e` in a fitted spec,
    /// for a candidate that did not pass its test (no gate is evaluated).
    fn raw_values(&self, e: Effect, spec: &ModelSpec, r: &lm::LmReport, has_t: &[bool]) -> Values {
        let n = self.prep.n;
        let o = spec.offset(e, n).expect("active");
        let sig = r.sigmas();
        let (mut vals, mut sigs) = (vec![], vec![]);
        for k in 0..fit::width(e, n) {
            let has = e.sharing() == Sharing::Shared || !e.needs_tension() || has_t[k];
            let (v, s) = if has { e.to_physical(r.x[o + k], sig[o + k]) } else { (f64::NAN, f64::NAN) };
            vals.push(v);
            sigs.push(s);
        }
        let w = vals.len();
        Values { vals, sigs, plausible: vec![true; w], significant: vec![false; w] }
    }

    /// Physical values, sigmas and whether each is plausible / significant, for effect `e` in
    /// a fitted spec. Cables without the data for the effect get NaN.
    ///
    /// The least-squares sigmas assume independent residuals; the residuals of a recording are
    /// correlated in time (the platform moves smoothly, unmodelled physics leaves slow
    /// structure), so each effect parameter's sigma is widened by the batch-means sandwich of
    /// [`sandwich_inflation`] (the spread over contiguous time blocks of `samples` of each
    /// block's influence on the estimate; never narrowed). A parameter is
    /// significant only if it is more than 4 inflated sigmas from its null value *and* its
    /// predicted length change (RMS over `samples`, the fitted model with and without the
    /// parameter) is at least `NEGLIGIBLE` of the measurement noise: a parameter that moves
    /// the predicted lengths by far less than the noise names no physics.
    fn values(&self, e: Effect, spec: &ModelSpec, r: &lm::LmReport, has_t: &[bool], samples: &[usize]) -> Values {
        let n = self.prep.n;
        let o = spec.offset(e, n).expect("active");
        let mut sig = r.sigmas();
        let base_res = fit::residuals(self.prep, spec, samples, &r.x);
        let infl = sandwich_inflation(self.prep, spec, samples, r, self.sigma, o..o + fit::width(e, n));
        let sys = tension_offset_variance(self.prep, spec, samples, r, self.sigma, self.tension_offset_sigma, o..o + fit::width(e, n));
        let mut change = vec![0.0; fit::width(e, n)];
        for k in 0..fit::width(e, n) {
            if sig[o + k].is_finite() {
                sig[o + k] = ((sig[o + k] * infl[k]).powi(2) + sys[k]).sqrt();
            }
            change[k] = length_change(self.prep, spec, samples, &r.x, &base_res, o + k);
        }
        let w = fit::width(e, n);
        let (lo, hi) = e.internal_range();
        let (mut vals, mut sigs, mut plausible, mut significant) = (vec![], vec![], vec![], vec![]);
        for k in 0..w {
            let has = e.sharing() == Sharing::Shared || !e.needs_tension() || has_t[k];
            let (x, s) = (r.x[o + k], sig[o + k]);
            let (v, vs) = e.to_physical(x, s);
            if !has {
                vals.push(f64::NAN);
                sigs.push(f64::NAN);
                plausible.push(true);
                significant.push(false);
                continue;
            }
            vals.push(v);
            sigs.push(vs);
            // Plausible: inside the range, or not distinguishable from its edge.
            let inside = x >= lo - 3.0 * s && x <= hi + 3.0 * s && x.abs() < 0.999 * (hi - lo).abs().max(hi.abs());
            plausible.push(inside && x >= lo - 3.0 * s);
            // Every effect's internal parameter is 0 at its null (scale is stored as scale - 1).
            significant.push(x.abs() > 4.0 * s && x >= lo && x <= hi && change[k] >= NEGLIGIBLE * self.sigma);
        }
        Values { vals, sigs, plausible, significant }
    }
}

/// A parameter whose predicted length change (RMS, the other parameters held) is below this
/// fraction of the measurement noise is physically negligible. On noise-only recordings a
/// time offset of about a millisecond "explains" 10% of the held-out sum of squares (the
/// interpolated tracker pose is less noisy than a sample) while changing the lengths by only
/// 0.4-0.6 mm against 1.5 mm noise; real effects change them by several mm.
const NEGLIGIBLE: f64 = 1.0;

/// Number of contiguous time blocks for the batch-means sigma inflation.
const BLOCKS: usize = 20;

/// For the parameters `params` of the fit `r` on `samples`: the factor (>= 1) by which the
/// residuals' correlation in time widens each one's least-squares sigma, from a batch-means
/// (block sandwich) covariance of the estimate.
///
/// The estimate moves, to first order, by `H^-1 g` with `H = J^T J` and `g = J^T r` the score;
/// cut `samples` into [`BLOCKS`] contiguous time blocks, each block's score `g_b` and the
/// parameter's influence `z_b = (H^-1 g_b)_k`. Their spread `B/(B-1) sum (z_b - mean z)^2`
/// estimates `var(x_k)` whatever the correlation inside a block, against `s^2 (H^-1)_kk` that
/// assumes independent residuals. The influence, not the parameter's own score, is batched:
/// a parameter that correlates strongly with others (elasticity with the offsets, the play and
/// the anchors) is estimated from what is left after them, and residual structure the others
/// absorb must not count (nor may structure the others leave in the profiled direction be
/// missed: the raw score's blocks under-covered EA under backlash, 52 / 75 / 85 % within 1 / 2 /
/// 3 sigma over 48 estimates).
pub(crate) fn sandwich_inflation(
    prep: &Prepared,
    spec: &ModelSpec,
    samples: &[usize],
    r: &lm::LmReport,
    sigma: f64,
    params: std::ops::Range<usize>,
) -> Vec<f64> {
    let ones = vec![1.0; params.len()];
    let Some(hinv) = r.inv_normal.as_ref() else {
        return ones;
    };
    let np = r.x.len();
    let m = samples.len();
    if m < BLOCKS || r.m <= np {
        return ones;
    }
    let joint = fit::Joint { prep, spec, samples, sigma };
    let inv = 1.0 / sigma;
    // Block scores, in the scaled units of `H` (residuals and rows divided by sigma).
    let mut g = vec![vec![0.0; np]; BLOCKS];
    for (idx, &i) in samples.iter().enumerate() {
        let b = idx * BLOCKS / m;
        for j in 0..prep.n {
            if !prep.usable[j][i] {
                continue;
            }
            let p = joint.predict(&r.x, i, j);
            let w = inv * joint.weight_of(&p, i, j);
            let mut dlog = [(0usize, 0.0f64); 8];
            let dl = joint.weight_dlog(&p, &mut dlog);
            let res = (p.value - prep.l[j][i]) * w;
            if !res.is_finite() {
                continue;
            }
            for &(a, v) in &p.row[..p.len] {
                g[b][a] += v * w * res;
            }
            // The errors-in-variables weight's own term of the score (see `fit::Eiv`).
            for &(a, v) in &dlog[..dl] {
                g[b][a] += res * res * v;
            }
        }
    }
    let s2 = r.cost / (r.m - np) as f64;
    let bf = BLOCKS as f64;
    params
        .map(|k| {
            let z: Vec<f64> = g.iter().map(|gb| (0..np).map(|a| hinv[(k, a)] * gb[a]).sum::<f64>()).collect();
            let mean = z.iter().sum::<f64>() / bf;
            let var = bf / (bf - 1.0) * z.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>();
            let naive = hinv[(k, k)] * s2;
            if naive > 0.0 && var.is_finite() {
                (var / naive).sqrt().max(1.0)
            } else {
                1.0
            }
        })
        .collect()
}

/// The held-out test of `r1` against `r0` ([`select::encompassing_test_with`]) on residuals
/// scaled by the smaller of their errors-in-variables factors `w0`, `w1`
/// ([`Ctx::heldout_factors`]), with the variance the current model's estimation error adds
/// (`err`, see [`esterr`]).
fn weighted_test(
    r0: &[f64],
    w0: &[f64],
    r1: &[f64],
    w1: &[f64],
    terms: &Terms,
    err: Option<&esterr::EstimationError>,
    cand_phi: Option<f64>,
) -> Option<HeldoutTest> {
    if r0.len() != terms.order.len() || r1.len() != terms.order.len() {
        return None;
    }
    let plain = w0.iter().chain(w1).chain(&terms.scale).all(|w| *w == 1.0);
    let w: Vec<f64> =
        if plain { vec![1.0; r0.len()] } else { w0.iter().zip(w1).zip(&terms.scale).map(|((a, b), s)| a.min(*b) * s).collect() };
    let a: Vec<f64> = r0.iter().zip(&w).map(|(r, w)| r * w).collect();
    let b: Vec<f64> = r1.iter().zip(&w).map(|(r, w)| r * w).collect();
    let delta: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    let est = err.and_then(|e| e.variance_with(&delta, (!plain).then_some(&w[..]), cand_phi));
    let a: Vec<f64> = terms.order.iter().map(|&k| a[k]).collect();
    let b: Vec<f64> = terms.order.iter().map(|&k| b[k]).collect();
    select::encompassing_test_with(&a, &b, &terms.rows, select::BATCHES, est)
}

/// For the parameters `params` of the fit `r` on `samples`: the variance each one gets from the
/// load cells' unknown constant offsets (1-sigma `offset_sigma_n` per cell, independent), to
/// add to the statistical variance.
///
/// Stretch and sag are read off the tensions: a cell reading `delta` N high moves every
/// prediction of its cable by `g_T delta` (`g_T = d reading / dT`, [`fit::Prediction::g_t`]) and
/// the estimate by `z_j delta`, `z_j = H^-1 sum_i J_i^T w_i g_T,i` to first order (the
/// least-squares response to a change of the data). The sag's excess falls as `1/T^2`, so an
/// offset of 0.5 N at tens of newtons moves the sag weight by about a percent, far more than
/// its statistical sigma on a minute's recording; no fit of this data can tell it from the
/// weight (both change the sag along the same curve), so it is reported as an uncertainty:
/// `var_k = offset_sigma^2 sum_j z_jk^2`. 0 without tension effects or without offsets.
fn tension_offset_variance(
    prep: &Prepared,
    spec: &ModelSpec,
    samples: &[usize],
    r: &lm::LmReport,
    sigma: f64,
    offset_sigma_n: f64,
    params: std::ops::Range<usize>,
) -> Vec<f64> {
    let zeros = vec![0.0; params.len()];
    let Some(hinv) = r.inv_normal.as_ref() else {
        return zeros;
    };
    if !(offset_sigma_n > 0.0) || !spec.effects.iter().any(|e| e.needs_tension()) {
        return zeros;
    }
    let np = r.x.len();
    let joint = fit::Joint { prep, spec, samples, sigma };
    let inv = 1.0 / sigma;
    // Per cable: J^T (d weighted residual / d offset), in the scaled units of `H`.
    let mut g = vec![vec![0.0; np]; prep.n];
    for &i in samples {
        for j in 0..prep.n {
            if !prep.usable[j][i] {
                continue;
            }
            let p = joint.predict(&r.x, i, j);
            let w = inv * joint.weight_of(&p, i, j);
            let d = w * p.g_t;
            if !d.is_finite() || d == 0.0 {
                continue;
            }
            for &(a, v) in &p.row[..p.len] {
                g[j][a] += v * w * d;
            }
        }
    }
    params
        .map(|k| {
            let v: f64 = g.iter().map(|gj| (0..np).map(|a| hinv[(k, a)] * gj[a]).sum::<f64>().powi(2)).sum();
            if v.is_finite() {
                v * offset_sigma_n * offset_sigma_n
            } else {
                0.0
            }
        })
        .collect()
}

/// For parameter `k` of the fitted `x`: the RMS predicted length change the parameter makes
/// (against its null value 0) over `samples`. `res` are the residuals at `x` on `samples`.
fn length_change(prep: &Prepared, spec: &ModelSpec, samples: &[usize], x: &[f64], res: &[Vec<f64>], k: usize) -> f64 {
    let mut x0 = x.to_vec();
    x0[k] = 0.0;
    let r0 = fit::residuals(prep, spec, samples, &x0);
    let (mut ch, mut chn) = (0.0, 0usize);
    // Over the readings the parameter moves (its cable; a reading without the data for it, e.g.
    // no tension, is not moved).
    for j in 0..res.len() {
        for i in 0..samples.len() {
            let (r, z) = (res[j][i], r0[j][i]);
            if r.is_finite() && z.is_finite() && z != r {
                ch += (z - r) * (z - r);
                chn += 1;
            }
        }
    }
    (ch / chn.max(1) as f64).sqrt()
}

/// The correlation of effect `e`'s parameter estimates with `other`'s (`None`: the anchors) in
/// the fitted `r`: the largest in magnitude (same cable when both are per cable), signed.
fn correlation(r: &lm::LmReport, spec: &ModelSpec, e: Effect, other: Option<Effect>, n: usize) -> Option<f64> {
    let c = r.inv_normal.as_ref()?;
    let oe = spec.offset(e, n)?;
    let we = fit::width(e, n);
    let (oo, wo) = match other {
        Some(o) => (spec.offset(o, n)?, fit::width(o, n)),
        None => (0, 4 * n),
    };
    let mut best: Option<f64> = None;
    for k in 0..we {
        for l in 0..wo {
            let same_cable = match other {
                Some(o) => e.sharing() == Sharing::Shared || o.sharing() == Sharing::Shared || k == l,
                // Anchor coordinates (not L0) of the same cable, or of any cable for a shared effect.
                None => l % 4 != 3 && (e.sharing() == Sharing::Shared || l / 4 == k),
            };
            if !same_cable {
                continue;
            }
            let (a, b) = (oe + k, oo + l);
            let d = (c[(a, a)] * c[(b, b)]).sqrt();
            if d > 0.0 && d.is_finite() {
                let rho = c[(a, b)] / d;
                if best.is_none_or(|x| rho.abs() > x.abs()) {
                    best = Some(rho);
                }
            }
        }
    }
    best
}

fn subsample_series(prep: &Prepared, samples: &[usize], res: &[Vec<f64>], max: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
    let s = samples.len().div_ceil(max.max(1)).max(1);
    res.iter()
        .map(|r| {
            let mut t = vec![];
            let mut v = vec![];
            for k in (0..samples.len()).step_by(s) {
                if r[k].is_finite() {
                    t.push(prep.t[samples[k]]);
                    v.push(r[k]);
                }
            }
            (t, v)
        })
        .collect()
}

/// `prep` with the weights of a selection fit of `spec` at `x` when it has a play: 1 on the rows
/// that read clear pushes only, 0 elsewhere ([`fit::clear_push_rows`], at `x`'s time offset if
/// it has one); `None` without a play. Every selection fit of such a model uses them (the current
/// model, the candidates on top of it, the backward step's reduced models), and with a time
/// offset the final estimates too; the held-out tests still compare the models on every held-out
/// reading. A hold's level is the input's extreme over the push that left it, and the play
/// pattern read off noisy readings misplaces some push ends (at sharp reversals a rise of noise
/// is taken as the push's slow end, a reading then predicted millimetres off): fitted on those
/// rows, unweighted, a long hold pins the play to one tracker error and the misread ends leave a
/// misfit that a third candidate takes up: a play alone then has a spurious pulley, scale, sag or
/// time offset named beside it (BENCHMARKS.md). The final estimates of a play without a time
/// offset keep the hold-weighted holds (`PlayState::hold_weights`): they pin its width at the
/// push's start, where only the offset trades off with it.
fn play_prep(prep: &Prepared, spec: &ModelSpec, x: &[f64], encoder_sigma_m: f64) -> Option<Prepared> {
    let n = prep.n;
    spec.offset(Effect::Backlash, n)?;
    let delta = spec.offset(Effect::TimeOffset, n).map(|o| x[o]);
    let mut p = prep.clone();
    p.hold_weight = clear_push_weights(prep, &prep.usable, delta, encoder_sigma_m);
    Some(p)
}

/// Diagnoses `rec`: see the module documentation. `start` (e.g. from the calibration) is used
/// as the starting point of the baseline fit; without it the calibration's initialisation runs.
pub fn diagnose(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    start: Option<&Params>,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis, DiagnoseError> {
    let n = rec.n_cables;
    if platform_points.len() != n {
        return Err(DiagnoseError::CableCount { recording: n, platform_points: platform_points.len() });
    }
    let mut notes = vec![];
    let screened = find_data_problems(rec, opts);
    let rec = screened.recording(rec);
    let mut prep = prepare(rec, platform_points, &screened.masks, opts);
    let base = fit_baseline(rec, platform_points, start, &mut prep, opts, &mut notes)?;
    let prep = prep; // frozen from here on
    let ctx = Ctx::new(&prep, &base, opts);
    let located = locate(&ctx, &base, opts);
    let mut effects: Vec<Finding> = loose_cables(&ctx, &base, &located.baseline, opts).into_iter().collect();
    let mut named = name_effects(&ctx, &base, opts, &mut effects, &mut notes);
    let (final_train, final_all) = final_estimates(&ctx, &base, &named, opts, &mut effects);
    let mut final_fit = ctx.summary(&named.spec, &final_train, &final_all);
    let (mut final_res, unexplained, structure) = leftover_structure(&ctx, &base, &named.spec, &final_train, &final_fit, &located.an_sub);
    let named_any = effects.iter().any(|f| f.effect != Effect::Slack);
    // A play named alone whose final width is zero within its sigma on every cable is no play
    // (the candidate's widths, from the screening fit, need not have been zero yet; see
    // `Decision::NoSize`).
    let only_play = effects.iter().filter(|f| f.effect != Effect::Slack).map(|f| f.effect).eq([Effect::Backlash]);
    let no_play = only_play
        && effects.iter().filter(|f| f.effect == Effect::Backlash).all(|f| f.values.iter().zip(&f.sigmas).all(|(w, s)| w.abs() <= *s));
    let withdraw = if no_play {
        Some("but its final width is zero within its sigma on every cable: no play".to_string())
    } else {
        structure.as_ref().filter(|_| named_any).and_then(|st| {
            if st.outweighs(&located.baseline, &final_fit) {
                return Some(format!("but more structure outside the library remains ({})", st.test));
            }
            match beyond_structure(&ctx, &base, st, &named.spec, &final_train) {
                Some(t) if t.gain > 0.0 && t.p_value < opts.test_alpha() => {
                    notes.push(format!(
                        "the named effects explain held-out data beside the structure outside the library: with it fitted \
                     beside them as well as alone, {t}"
                    ));
                    None
                }
                t => Some(format!(
                    "but structure outside the library remains ({}), and with it fitted beside them the effects no longer \
                 explain held-out data it does not ({}; needed p < {:.1e})",
                    st.test,
                    t.map_or("no test".into(), |t| t.to_string()),
                    opts.test_alpha()
                )),
            }
        })
    };
    if let Some(why) = withdraw {
        for f in effects.iter().filter(|f| f.effect != Effect::Slack) {
            named.rejected.push(format!(
                "{} fitted part of the mismatch (held-out RMS {:.2} -> {:.2} mm), {why}: withdrawn, not named",
                f.effect.name(),
                located.baseline.heldout_rms_m * 1e3,
                final_fit.heldout_rms_m * 1e3,
            ));
            for t in named.tests.iter_mut().filter(|t| t.effect == f.effect && t.decision == Decision::Named) {
                t.decision = Decision::Withdrawn;
            }
        }
        effects.retain(|f| f.effect == Effect::Slack);
        final_fit = located.baseline.clone();
        final_res = located.base_res.clone();
    }
    if effects.iter().all(|f| f.effect == Effect::Slack) && unexplained.is_none() {
        notes.push("no effect beyond loose cables was found: the residual is noise".into());
    }
    let tension = tension_side(rec, platform_points, &screened.masks, &final_fit.params, opts, &mut notes);
    let all_rows: Vec<usize> = (0..prep.t.len()).collect();
    Ok(Diagnosis {
        cables: n,
        samples: rec.len(),
        used_tensions: base.used_tensions,
        baseline: located.baseline,
        mismatch: located.mismatch,
        effects,
        final_fit,
        unexplained,
        data_problems: screened.problems,
        rejected: named.rejected,
        tests: named.tests,
        family_alpha: opts.family_alpha,
        notes,
        baseline_residuals: subsample_series(&prep, &all_rows, &located.base_res, 2000),
        final_residuals: subsample_series(&prep, &all_rows, &final_res, 2000),
        tension,
    })
}

/// Step 8, **the tension side** ([`tension`]): the load cells against the platform's weight and
/// inertia along the final geometry, and the tension effects named with the same test.
fn tension_side(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    masks: &dataq::DataMasks,
    geometry: &Geometry,
    opts: &DiagnoseOptions,
    notes: &mut Vec<String>,
) -> Option<tension::TensionDiagnosis> {
    tension::diagnose_tensions(rec, masks, geometry, platform_points, opts, notes)
}

/// The recording after step 1, its data problems and the masks of what is left.
struct Screened {
    /// The recording with the stale rows' lengths removed, if there were any.
    unstale: Option<Recording>,
    /// The screen of wild values.
    screen: crate::screen::Screen,
    /// Every data problem found, the screen's first.
    problems: Vec<DataProblem>,
    /// What is left usable.
    masks: dataq::DataMasks,
}

impl Screened {
    /// The recording the diagnosis works on: stale lengths removed, wild values screened.
    fn recording<'a>(&'a self, rec: &'a Recording) -> &'a Recording {
        self.screen.recording(self.unstale.as_ref().unwrap_or(rec))
    }
}

/// Step 1, **data problems** ([`dataq`], [`crate::screen`]): stale rows, wild values, frozen
/// readings, tracker outliers and dropouts, clock jumps and dead load cells, found, reported
/// and masked out before any fit.
fn find_data_problems(rec: &Recording, opts: &DiagnoseOptions) -> Screened {
    // Wild values first: a single 1e308 must neither move the fit nor pass for physics.
    // Stale rows before the screen: their repeated lengths, centimetres off on a moving
    // platform, would otherwise pass for wild readings of some cables and stay on others.
    let stale = if opts.stale_rows { dataq::stale_rows(rec, opts.tracker_sigma_m, opts.encoder_sigma_m) } else { vec![] };
    let unstale = dataq::without_lengths(rec, &stale);
    let screen = crate::screen::screen(unstale.as_ref().unwrap_or(rec), &crate::screen::ScreenOptions::new(opts.min_tension_n));
    let rec = screen.recording(unstale.as_ref().unwrap_or(rec));
    let (mut problems, masks) = dataq::detect_screened(
        rec,
        opts.tracker_sigma_m,
        opts.encoder_sigma_m,
        &screen.removed_rows,
        opts.stale_rows.then_some(&stale[..]),
    );
    problems.splice(0..0, dataq::from_screen(&screen));
    Screened { unstale, screen, problems, masks }
}

/// The ideal model fitted after step 2, and what the later steps need of it.
struct Baseline {
    /// The ideal model (no effect).
    ideal: ModelSpec,
    /// Its fit on the training blocks.
    fit: lm::LmReport,
    /// Noise sigma of a reading, m.
    sigma: f64,
    /// Per cable: the recording has tensions.
    has_t: Vec<bool>,
    /// Some cable has tensions.
    used_tensions: bool,
    /// Readings found loose by their tension, and (cables without tensions) by their residual.
    loose_by_tension: usize,
    loose_by_residual: usize,
    /// Training and held-out samples.
    train: Vec<usize>,
    heldout: Vec<usize>,
    /// The usable mask before the readings held since a push while loose were left out
    /// ([`exclude_unseen_pushes`]).
    usable_before_play: Vec<Vec<bool>>,
}

/// Step 2, **baseline**: the ideal model `l = |P + R b - A| + L0` fitted on the training blocks
/// from `start` (or the calibration's start), loose readings excluded (`T < min_tension_n`, or
/// without tensions, readings whose encoder shows clearly more cable than the straight line),
/// and the readings held since a push while loose left out of the fits.
fn fit_baseline(
    rec: &Recording,
    platform_points: &[[f64; 3]],
    start: Option<&Params>,
    prep: &mut Prepared,
    opts: &DiagnoseOptions,
    notes: &mut Vec<String>,
) -> Result<Baseline, DiagnoseError> {
    let n = rec.n_cables;
    let has_t: Vec<bool> = (0..n).map(|j| prep.f[j].iter().any(|v| v.is_finite())).collect();
    let used_tensions = has_t.iter().any(|x| *x);
    if !used_tensions {
        notes.push(
            "the recording has no tensions: elasticity and sag cannot be claimed; loose cables are found from the residual alone".into(),
        );
    }
    let sigma = (opts.tracker_sigma_m.powi(2) + opts.encoder_sigma_m.powi(2)).sqrt().max(1e-6);
    let m = prep.t.len();
    for j in 0..n {
        let u = prep.usable[j].iter().filter(|x| **x).count();
        if u < 20 {
            return Err(DiagnoseError::TooFewSamples { cable: j, usable: u });
        }
    }
    let loose_by_tension: usize =
        (0..n).map(|j| (0..m).filter(|&i| prep.f[j][i].is_finite() && prep.f[j][i] < opts.min_tension_n).count()).sum();

    // Start: given, or the calibration's initialisation + force-aware calibration; with the
    // design's priors, the design and the calibration with them (maximum a posteriori).
    let all_rows: Vec<usize> = (0..m).collect();
    let mut x0: Option<Vec<f64>> = start.map(|p| (0..n).flat_map(|j| p.cable(j)).collect());
    let copts = crate::CalibOptions {
        min_tension_n: opts.min_tension_n,
        tracker_sigma_m: opts.tracker_sigma_m,
        encoder_sigma_m: opts.encoder_sigma_m,
        // Only a start for the diagnosis's own fits.
        model_check: false,
        priors: opts.priors.clone().filter(|p| p.len() == n),
        ..crate::CalibOptions::default()
    };
    if let (None, Some(priors)) = (&x0, &copts.priors) {
        let means: Vec<[f64; 4]> = priors.iter().map(|(mu, _)| *mu).collect();
        if means.iter().all(|m| m[..3].iter().all(|v| v.is_finite())) {
            let mut data = crate::noise::gather(rec, platform_points, &copts, crate::Weighting::of(rec, &copts));
            if let Ok(init) = crate::init::from_design(rec, platform_points, &means, &data) {
                let p = crate::calibrate_gathered(rec, platform_points, &init.params, &copts, &mut data)
                    .map(|r| r.params)
                    .unwrap_or(init.params);
                x0 = Some((0..n).flat_map(|j| p.cable(j)).collect());
                notes.push("started from the design's anchors, calibrated with its priors".into());
            }
        }
    }
    if x0.is_none() {
        if let Ok(init) = crate::init::initialise(rec, platform_points, &copts) {
            let p = crate::calibrate(rec, platform_points, &init.params, &copts).map(|r| r.params).unwrap_or(init.params);
            x0 = Some((0..n).flat_map(|j| p.cable(j)).collect());
        }
    }
    let x0 = match x0 {
        Some(x) if x.iter().all(|v| v.is_finite()) => x,
        _ => {
            notes.push("the calibration's initialisation failed; started from algebraic multilateration".into());
            multilaterate(prep, &stride(&all_rows, 4000)).ok_or(DiagnoseError::BaselineFailed)?
        }
    };

    let ideal = ModelSpec { effects: vec![], tension_end: opts.tension_end };
    let train: Vec<usize> = (0..m).filter(|&i| !prep.heldout[i]).collect();
    let heldout: Vec<usize> = (0..m).filter(|&i| prep.heldout[i]).collect();
    let mut base = fit::fit(prep, &ideal, &train, &x0, sigma, opts.max_iterations);
    if !base.x.iter().all(|v| v.is_finite()) {
        return Err(DiagnoseError::BaselineFailed);
    }

    // Loose cables without tensions: the encoder shows clearly more cable than the straight
    // line (one-sided), found iteratively from the residual.
    let mut loose_by_residual = 0;
    if has_t.iter().any(|h| !h) {
        for _ in 0..3 {
            let res = fit::residuals(prep, &ideal, &all_rows, &base.x);
            let mut flagged = 0;
            for j in (0..n).filter(|&j| !has_t[j]) {
                let mut a: Vec<f64> = res[j].iter().copied().filter(|v| v.is_finite()).collect();
                let med = {
                    let k = a.len() / 2;
                    a.select_nth_unstable_by(k, |x, y| x.total_cmp(y));
                    a[k]
                };
                let mut dev: Vec<f64> = a.iter().map(|v| (v - med).abs()).collect();
                let k = dev.len() / 2;
                dev.select_nth_unstable_by(k, |x, y| x.total_cmp(y));
                let s = 1.4826 * dev[k];
                let thr = med + (6.0 * s).max(6.0 * sigma);
                for i in 0..m {
                    if prep.usable[j][i] && res[j][i] > thr {
                        prep.usable[j][i] = false;
                        prep.loose[j][i] = true;
                        flagged += 1;
                    }
                }
            }
            loose_by_residual += flagged;
            if flagged == 0 {
                break;
            }
            base = fit::fit(prep, &ideal, &train, &base.x, sigma, opts.max_iterations);
        }
    }
    // Readings held since a push while the cable was loose: the play's level is unknown there.
    // (With a time offset the final refit redoes this in encoder time from the mask before it:
    // `fit::encoder_time_play`.)
    // Readings held since a push while the cable was loose: the play's level is unknown there.
    // (With a time offset the final refit redoes this in encoder time from the mask before it:
    // `fit::encoder_time_play`.)
    let usable_before_play = exclude_unseen_pushes(prep);
    Ok(Baseline { ideal, fit: base, sigma, has_t, used_tensions, loose_by_tension, loose_by_residual, train, heldout, usable_before_play })
}

impl<'a> Ctx<'a> {
    /// The fitting context on `prep` after the baseline: its training, held-out and screening
    /// samples and the noise.
    fn new(prep: &'a Prepared, b: &Baseline, opts: &DiagnoseOptions) -> Ctx<'a> {
        let (n, m) = (prep.n, prep.t.len());
        let (train, heldout) = (b.train.clone(), b.heldout.clone());
        let sigma = b.sigma;
        let mut heldout_rows = vec![0];
        for &i in &heldout {
            heldout_rows.push(heldout_rows.last().copied().unwrap_or(0) + (0..n).filter(|&j| prep.usable[j][i]).count());
        }
        let mut ctx = Ctx {
            prep,
            sigma,
            tension_offset_sigma: opts.loadcell_offset_n,
            train,
            heldout,
            screen_train: vec![],
            heldout_rows,
            tracker_var: opts.tracker_sigma_m.powi(2),
            encoder_var: opts.encoder_sigma_m.powi(2),
        };
        let frac = opts.screen_samples as f64 / m.max(1) as f64;
        ctx.screen_train = stride(&ctx.train, (frac * ctx.train.len() as f64).ceil() as usize);
        ctx
    }
}

/// What step 3 found: the baseline's summary and residuals and where they mismatch.
struct Located {
    /// The baseline's fit summary.
    baseline: FitSummary,
    /// Its residuals on every sample, per cable.
    base_res: Vec<Vec<f64>>,
    /// Where the mismatch is.
    mismatch: Mismatch,
    /// The samples the analysis uses.
    an_sub: Vec<usize>,
}

/// Step 3, **locate** the mismatch ([`analysis`]): the baseline's residual per cable, time
/// block and workspace octant, and its correlation with the effects' signature regressors.
fn locate(ctx: &Ctx<'_>, b: &Baseline, opts: &DiagnoseOptions) -> Located {
    let prep = ctx.prep;
    let m = prep.t.len();
    let all_rows: Vec<usize> = (0..m).collect();
    let (ideal, base, has_t) = (&b.ideal, &b.fit, &b.has_t);
    let base_all = ctx.fit(ideal, &all_rows, &base.x, opts.max_iterations);
    let baseline = ctx.summary(ideal, base, &base_all);
    let base_res = fit::residuals(prep, ideal, &all_rows, &base.x);
    let anchors0: Vec<[f64; 3]> = baseline.params.anchors.clone();
    let an_sub = stride(&all_rows, 6000);
    let sub_res: Vec<Vec<f64>> = base_res.iter().map(|r| an_sub.iter().map(|&i| r[i]).collect()).collect();
    let mismatch = analysis::analyse(prep, &an_sub, &sub_res, &anchors0, has_t);

    Located { baseline, base_res, mismatch, an_sub }
}

/// The `slack` finding of step 2's loose readings: the baseline's RMS on every present reading
/// (loose ones included) against without them.
fn loose_cables(ctx: &Ctx<'_>, b: &Baseline, baseline: &FitSummary, opts: &DiagnoseOptions) -> Option<Finding> {
    let prep = ctx.prep;
    let (n, m) = (prep.n, prep.t.len());
    let (ideal, base, loose_by_tension, loose_by_residual) = (&b.ideal, &b.fit, b.loose_by_tension, b.loose_by_residual);
    if loose_by_tension + loose_by_residual > 0 {
        // Before: the baseline on every present reading, loose ones included.
        let mut ss = 0.0;
        let mut cnt = 0usize;
        let mut ss_ho = 0.0;
        let mut cnt_ho = 0usize;
        let probe =
            Prepared { usable: (0..n).map(|j| (0..m).map(|i| prep.usable[j][i] || prep.loose[j][i]).collect()).collect(), ..prep.clone() };
        for i in 0..m {
            for j in 0..n {
                if probe.usable[j][i] {
                    let r = fit::Joint { prep: &probe, spec: ideal, samples: &[], sigma: 1.0 }.residual(&base.x, i, j);
                    if prep.heldout[i] {
                        ss_ho += r * r;
                        cnt_ho += 1;
                    } else {
                        ss += r * r;
                        cnt += 1;
                    }
                }
            }
        }
        let cables: Vec<usize> = (0..n).filter(|&j| (0..m).any(|i| probe.usable[j][i] && !prep.usable[j][i])).collect();
        let samples = loose_by_tension + loose_by_residual;
        return Some(Finding {
            effect: Effect::Slack,
            cables,
            values: vec![if loose_by_tension > 0 { opts.min_tension_n } else { f64::NAN }],
            sigmas: vec![f64::NAN],
            samples: Some(samples),
            rms_before_m: (ss / cnt.max(1) as f64).sqrt(),
            rms_after_m: baseline.rms_m,
            heldout_rms_before_m: (ss_ho / cnt_ho.max(1) as f64).sqrt(),
            heldout_rms_after_m: baseline.heldout_rms_m,
            evidence: if loose_by_tension > 0 {
                format!("{loose_by_tension} readings with tension below {} N (loose cable); excluded", opts.min_tension_n)
            } else {
                format!("{loose_by_residual} readings where the encoder shows clearly more cable than the straight line (loose cable, found without tensions); excluded")
            },
            equally_good: vec![],
            plot: None,
            test: None,
            joint: vec![],
        });
    }

    None
}

/// The model step 4 arrived at, and the record of its tests.
struct Named {
    /// The final model.
    spec: ModelSpec,
    /// Its fit on the training blocks.
    cur_train: lm::LmReport,
    /// Candidates of the last round that were not named, and why.
    rejected: Vec<String>,
    /// Every candidate test of every round.
    tests: Vec<CandidateTest>,
    /// The last round's candidates when it named nothing (reused by the joint fits).
    last_round: Vec<(Effect, Candidate)>,
}

/// Step 4, **name and model**: forward selection over the effect library ([`select`]), each
/// round's candidates fitted jointly with the effects named so far and tested on the held-out
/// blocks; the best that passes is named (with the candidates that explain the data equally
/// well), then a backward step drops an earlier effect the new one made redundant.
fn name_effects(ctx: &Ctx<'_>, b: &Baseline, opts: &DiagnoseOptions, effects: &mut Vec<Finding>, notes: &mut Vec<String>) -> Named {
    let prep = ctx.prep;
    let n = prep.n;
    let all_rows: Vec<usize> = (0..prep.t.len()).collect();
    let (ideal, base, has_t, sigma) = (&b.ideal, &b.fit, &b.has_t, b.sigma);
    // Forward selection: every round refits each remaining candidate on top of the effects named
    // so far and tests it on the held-out blocks (see [`select`]); the best that passes is named.
    let alpha = opts.test_alpha();
    let mut spec = ideal.clone();
    let mut cur_train = base.clone();
    let mut rejected = vec![];
    let mut tests: Vec<CandidateTest> = vec![];
    let plot_samples = stride(&all_rows, 1500);
    let mut round = 0;
    // The last round's candidates when it named nothing: each is the current model plus one
    // effect, fitted jointly, which the joint fits below reuse.
    let mut last_round: Vec<(Effect, Candidate)> = vec![];
    // Effects dropped by the backward step: not tried again (no cycling).
    let mut dropped: Vec<Effect> = vec![];
    // At most `max_effects` rounds (the Bonferroni count of `test_alpha`), drops or not.
    while spec.effects.len() < opts.max_effects && round < opts.max_effects {
        round += 1;
        let (mut cands, cur_pp) = round_candidates(ctx, b, opts, &spec, &cur_train, &dropped, alpha, &mut rejected);
        let gain = |c: &Candidate| c.test.map_or(f64::NEG_INFINITY, |t| t.gain);
        // A pulley whose radius is clearly not zero but which does not predict held-out data
        // better: the ideal model's anchors, shifted, absorb it (on many geometries the two are
        // nearly the same model). Say so rather than stay silent.
        let absorbed_pulley = cands
            .iter()
            .find(|(e, c)| *e == Effect::Pulley && c.decision == Decision::NotBetter && c.significant.iter().any(|s| *s))
            .map(|(_, c)| {
                format!(
                    "a swivel pulley of radius {:.3} ± {:.3} m and the ideal model with shifted anchors fit equally well ({}; not better at alpha {alpha:.1e}): this recording cannot tell them apart; {}",
                    c.values[0],
                    c.sigmas[0],
                    c.test.map_or("no test".into(), |t| t.to_string()),
                    Effect::Pulley.separating_measurement(None),
                )
            });
        let best = cands
            .iter()
            .enumerate()
            .filter(|(_, c)| c.1.decision == Decision::Passed)
            .max_by(|a, b| gain(&a.1 .1).total_cmp(&gain(&b.1 .1)))
            .map(|(i, _)| i);
        let Some(bi) = best else {
            notes.extend(absorbed_pulley);
            for (e, c) in &cands {
                rejected.push(format!(
                    "{}: {}; {}",
                    e.name(),
                    c.test.map_or("too few held-out samples to test".into(), |t| t.to_string()),
                    c.decision.words(alpha)
                ));
                tests.push(CandidateTest {
                    round,
                    effect: *e,
                    test: c.test,
                    alpha,
                    decision: c.decision,
                    values: c.values.clone(),
                    sigmas: c.sigmas.clone(),
                });
            }
            last_round = cands;
            break;
        };
        let best = cands[bi].0;
        // Candidates that also passed: does the named one add anything beyond them?
        let mut equally_good: Vec<(Effect, f64)> = vec![];
        let mut separate = vec![];
        for (k, (e, c)) in cands.iter().enumerate() {
            let mut decision = c.decision;
            if k != bi && c.decision == Decision::Passed {
                // B as the current model: its estimation error is that of its screening fit.
                let err = opts
                    .estimation_error
                    .then(|| {
                        let pp = cur_pp.as_ref().and_then(|_| play_prep(prep, &c.spec, &c.report.x, opts.encoder_sigma_m));
                        let pp = pp.as_ref().unwrap_or(prep);
                        let phi = fit::noise_phi(pp, &c.spec, &ctx.screen_train, &c.report.x);
                        esterr::EstimationError::new(pp, &c.spec, &ctx.screen_train, &ctx.heldout, &c.report, sigma, phi)
                    })
                    .flatten();
                let pair = weighted_test(
                    &c.res,
                    &c.res_w,
                    &cands[bi].1.res,
                    &cands[bi].1.res_w,
                    &ctx.heldout_terms(&c.spec, &c.report.x),
                    err.as_ref(),
                    None,
                );
                if pair.is_none_or(|t| t.p_value >= alpha) {
                    let ho = (c.res.iter().map(|r| r * r).sum::<f64>() / c.res.len().max(1) as f64).sqrt();
                    equally_good.push((*e, ho));
                    separate.push(best.separating_measurement(Some(*e)));
                    decision = Decision::Equal;
                } else {
                    decision = Decision::Outranked;
                }
            }
            if k == bi {
                decision = Decision::Named;
            }
            tests.push(CandidateTest {
                round,
                effect: *e,
                test: c.test,
                alpha,
                decision,
                values: c.values.clone(),
                sigmas: c.sigmas.clone(),
            });
        }
        let cand = cands.swap_remove(bi).1;
        let new_spec = cand.spec.clone();
        let pp = play_prep(prep, &new_spec, &cand.report.x, opts.encoder_sigma_m);
        let fctx = Ctx { prep: pp.as_ref().unwrap_or(prep), ..ctx.clone() };
        let full = fctx.fit(&new_spec, &ctx.train, &cand.report.x, opts.max_iterations);
        let v = fctx.values(best, &new_spec, &full, has_t, &ctx.train);
        let cables: Vec<usize> = match best.sharing() {
            Sharing::PerCable => (0..n).filter(|&j| v.significant[j]).collect(),
            Sharing::Shared => (0..n).filter(|&j| !best.needs_tension() || has_t[j]).collect(),
        };
        // Evidence: the residual before against the effect's signature regressor.
        let reg = best.model().regressor();
        let before_res = fit::residuals(prep, &spec, &plot_samples, &cur_train.x);
        let after_res = fit::residuals(prep, &new_spec, &plot_samples, &full.x);
        let mut rs = vec![];
        let mut pcables = vec![];
        for j in 0..n {
            let an = [cur_train.x[4 * j], cur_train.x[4 * j + 1], cur_train.x[4 * j + 2]];
            let xs: Vec<f64> = plot_samples.iter().map(|&i| reg.value(prep, an, i, j)).collect();
            let sign = best.model().signature_sign();
            rs.push(sign * analysis::correlation(&xs, &before_res[j]));
            pcables.push((xs, before_res[j].clone(), after_res[j].clone()));
        }
        let fin: Vec<f64> = rs.iter().copied().filter(|r| r.is_finite()).collect();
        let strong: Vec<usize> = (0..n).filter(|&j| rs[j].is_finite() && rs[j].abs() >= 0.3).collect();
        let follows = if fin.is_empty() {
            String::new()
        } else {
            let lo = fin.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = fin.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let which = if strong.len() == n {
                "every cable".to_string()
            } else if strong.is_empty() {
                "no cable clearly".to_string()
            } else {
                taut_config::cable_list(&strong)
            };
            format!("residual follows {} on {which} (r = {lo:.2} .. {hi:.2}); ", best.signature(),)
        };
        let rms_before = rms_of(prep, &spec, &ctx.train, &cur_train.x);
        let rms_after = rms_of(prep, &new_spec, &ctx.train, &full.x);
        let ho_before = rms_of(prep, &spec, &ctx.heldout, &cur_train.x);
        let ho_after = rms_of(prep, &new_spec, &ctx.heldout, &full.x);
        let mut evidence = format!(
            "{follows}held-out RMS {:.2} -> {:.2} mm; {}",
            ho_before * 1e3,
            ho_after * 1e3,
            cand.test.map_or(String::new(), |t| format!("{t} < alpha {alpha:.1e}"))
        );
        if !equally_good.is_empty() {
            evidence.push_str(&format!(
                "; explains the held-out data as well as {} (a paired held-out test cannot separate them): {}",
                equally_good.iter().map(|(e, _)| e.name()).collect::<Vec<_>>().join(", "),
                separate.join("; ")
            ));
        }
        effects.push(Finding {
            effect: best,
            cables,
            values: v.vals,
            sigmas: v.sigs,
            samples: None,
            rms_before_m: rms_before,
            rms_after_m: rms_after,
            heldout_rms_before_m: ho_before,
            heldout_rms_after_m: ho_after,
            evidence,
            equally_good,
            plot: Some(PlotData { regressor: reg, cables: pcables }),
            test: cand.test,
            joint: vec![],
        });
        spec = new_spec;
        cur_train = full;
        backward_step(ctx, b, opts, round, alpha, &mut spec, &mut cur_train, effects, &mut tests, notes, &mut dropped);
    }
    Named { spec, cur_train, rejected, tests, last_round }
}
/// One round of step 4: every effect of the library not in `spec` (nor dropped) fitted
/// jointly with the current model on the screening samples and tested against it on the
/// held-out blocks ([`weighted_test`]), with its values and the decision. Returns the
/// candidates and the current model's clear-push data (`None`: it has not both a play and a
/// time offset); the effects not tried go to `rejected` with the reason.
#[allow(clippy::too_many_arguments)]
fn round_candidates(
    ctx: &Ctx<'_>,
    b: &Baseline,
    opts: &DiagnoseOptions,
    spec: &ModelSpec,
    cur_train: &lm::LmReport,
    dropped: &[Effect],
    alpha: f64,
    rejected: &mut Vec<String>,
) -> (Vec<(Effect, Candidate)>, Option<Prepared>) {
    let prep = ctx.prep;
    let n = prep.n;
    let (has_t, used_tensions, sigma) = (&b.has_t, b.used_tensions, b.sigma);
    // How far apart the current model's residuals stay correlated (the tracker noise's
    // correlation length, 1 when white): the held-out replacement's span.
    // `noise_phi` once per round: the same residuals give the estimation error's long-run
    // factor below (the clear-push weights of `cur_pp` do not enter the residuals).
    let cur_phi = fit::noise_phi(prep, spec, &ctx.train, &cur_train.x);
    let noise_lag = fit::correlation_lag(cur_phi, fit::MAX_NOISE_LAG);
    let cur_res = ctx.heldout_residuals(spec, &cur_train.x, (spec, &cur_train.x), noise_lag);
    let cur_w = ctx.heldout_factors(spec, &cur_train.x);
    let cur_terms = ctx.heldout_terms(spec, &cur_train.x);
    // The current model's own estimation error on the training blocks: part of every
    // held-out test's variance (see [`esterr`]).
    let cur_pp = play_prep(prep, spec, &cur_train.x, opts.encoder_sigma_m);
    let cur_err = opts
        .estimation_error
        .then(|| esterr::EstimationError::new(cur_pp.as_ref().unwrap_or(prep), spec, &ctx.train, &ctx.heldout, cur_train, sigma, cur_phi))
        .flatten();
    // Each candidate is its own fit and test (on `opts.threads` threads); the results are
    // taken in the library's order, so the output does not depend on the threads.
    let todo: Vec<Effect> = opts.library.iter().copied().filter(|e| !spec.effects.contains(e) && *e != Effect::Slack).collect();
    let tried = crate::par::map(opts.threads, todo.len(), |k| -> Result<(Effect, Candidate), String> {
        let e = todo[k];
        if dropped.contains(&e) {
            return Err(format!("{}: dropped by the backward step (see the tests), not tried again", e.name()));
        }
        if e.needs_tension() && !used_tensions {
            return Err(format!("{}: needs tensions, the recording has none", e.name()));
        }
        let mut s2 = spec.clone();
        s2.effects.push(e);
        let x0 = s2.extend(n, spec, &cur_train.x);
        // On the clear-push rows only once the current model has both a play and a time
        // offset: a candidate that adds the second of them, fitted on other rows than the
        // current model, predicted the holds differently and "won" the held-out test
        // (a spurious time offset under EA and a play on 3 of 50 recordings).
        let pp = cur_pp.as_ref().and_then(|_| play_prep(prep, &s2, &x0, opts.encoder_sigma_m));
        let cctx = Ctx { prep: pp.as_ref().unwrap_or(prep), ..ctx.clone() };
        let r = cctx.fit_candidate(e, &s2, &x0, 30);
        if !r.x.iter().all(|v| v.is_finite()) {
            return Err(format!("{}: the fit diverged", e.name()));
        }
        // The replacement's span from the smaller of the two models' noise correlation: a
        // model that leaves out a slow effect reads it as correlated noise (the holds of a
        // play ramp the ideal model's residuals: `phi` 0.995 and a span of 100 samples under
        // AR(1) 0.9, where a pose interpolated over 2 s predicts nothing and a real 6 mm play
        // is seldom named), the candidate that has the effect does not; under
        // the null both carry the same noise. Only where the span is more than one sample.
        let cand_phi = fit::noise_phi(prep, &s2, &ctx.train, &r.x);
        let lag = if noise_lag > 1 { fit::correlation_lag(cur_phi.min(cand_phi), fit::MAX_NOISE_LAG) } else { noise_lag };
        let res = ctx.heldout_residuals(&s2, &r.x, (spec, &cur_train.x), lag);
        let res_w = ctx.heldout_factors(&s2, &r.x);
        let test = weighted_test(&cur_res, &cur_w, &res, &res_w, &cur_terms, cur_err.as_ref(), Some(cand_phi));
        // The inflated sigmas and the gates (several residual passes per parameter) only
        // where they can matter: a candidate that passed, or a pulley (the absorbed note).
        let v = if test.is_some_and(|t| t.p_value < alpha) || e == Effect::Pulley {
            cctx.values(e, &s2, &r, has_t, &ctx.screen_train)
        } else {
            cctx.raw_values(e, &s2, &r, has_t)
        };
        let physical = v.plausible.iter().all(|p| *p);
        let better = test.is_some_and(|t| t.p_value < alpha);
        // A play of zero width on every cable (each within one sigma of zero) is no play: the
        // play model's holds weigh the held-out readings otherwise than the current model, and
        // that alone can pass the test (an eccentric drum on the outdoor robot: widths 0-0.06
        // mm, held-out sum of squares 22 % worse, p 1.7e-8).
        let no_size = e == Effect::Backlash && v.vals.iter().zip(&v.sigs).all(|(w, s)| w.abs() <= *s);
        let decision = if !better {
            Decision::NotBetter
        } else if !physical {
            Decision::NotPhysical
        } else if no_size {
            Decision::NoSize
        } else {
            Decision::Passed
        };
        Ok((e, Candidate { spec: s2, report: r, res, res_w, values: v.vals, sigmas: v.sigs, significant: v.significant, test, decision }))
    });
    let mut cands: Vec<(Effect, Candidate)> = vec![];
    rejected.clear();
    for t in tried {
        match t {
            Ok(c) => cands.push(c),
            Err(why) => rejected.push(why),
        }
    }
    (cands, cur_pp)
}

/// The backward step of step 4, after `spec`'s last effect was named: each earlier-named
/// effect is tested for removal ([`Ctx::removal_test`]); of those the test cannot keep at
/// `alpha`, the one with the largest p-value is dropped (its finding removed, the last one's
/// values refitted without it), and the rest are tested again on the smaller model.
#[allow(clippy::too_many_arguments)]
fn backward_step(
    ctx: &Ctx<'_>,
    b: &Baseline,
    opts: &DiagnoseOptions,
    round: usize,
    alpha: f64,
    spec: &mut ModelSpec,
    cur_train: &mut lm::LmReport,
    effects: &mut Vec<Finding>,
    tests: &mut Vec<CandidateTest>,
    notes: &mut Vec<String>,
    dropped: &mut Vec<Effect>,
) {
    let prep = ctx.prep;
    let has_t = &b.has_t;
    // Backward step: each earlier-named effect is tested for removal (see
    // [`Ctx::removal_test`]); of those the test cannot keep at `alpha`, the one with the
    // largest p-value is dropped, and the rest are tested again on the smaller model.
    while opts.backward && spec.effects.len() >= 2 {
        let last = *spec.effects.last().expect("named");
        let mut results = vec![];
        for e in spec.effects.clone().into_iter().filter(|&e| e != last) {
            if let Some((red, red_fit, test)) = ctx.removal_test(e, spec, cur_train, opts) {
                results.push((e, red, red_fit, test));
            }
        }
        let p = |t: &Option<HeldoutTest>| t.map_or(0.0, |t| t.p_value);
        let worst =
            results.iter().enumerate().filter(|(_, r)| p(&r.3) >= alpha).max_by(|a, b| p(&a.1 .3).total_cmp(&p(&b.1 .3))).map(|(i, _)| i);
        let record = |e: Effect, test: Option<HeldoutTest>, decision: Decision, effects: &[Finding]| {
            let f = effects.iter().find(|f| f.effect == e).expect("named");
            CandidateTest { round, effect: e, test, alpha, decision, values: f.values.clone(), sigmas: f.sigmas.clone() }
        };
        let Some(wi) = worst else {
            // Every earlier effect is still needed.
            for (e, _, _, test) in &results {
                tests.push(record(*e, *test, Decision::Kept, effects));
            }
            break;
        };
        let (e, red, red_fit, test) = results.swap_remove(wi);
        tests.push(record(e, test, Decision::Dropped, effects));
        let named_in = tests.iter().find(|t| t.effect == e && t.decision == Decision::Named).map_or(0, |t| t.round);
        let words = format!(
            "{} (named in round {named_in}) was dropped in round {round} once {} was named: the model without it predicts the held-out data as well ({}; not significant at alpha {alpha:.1e})",
            e.name(),
            last.name(),
            test.map_or("no test".into(), |t| t.to_string())
        );
        effects.retain(|f| f.effect != e);
        let pp = play_prep(prep, &red, &red_fit.x, opts.encoder_sigma_m);
        let rctx = Ctx { prep: pp.as_ref().unwrap_or(prep), ..ctx.clone() };
        if let Some(f) = effects.iter_mut().find(|f| f.effect == last) {
            let v = rctx.values(last, &red, &red_fit, has_t, &ctx.train);
            (f.values, f.sigmas) = (v.vals, v.sigs);
            f.rms_after_m = rms_of(prep, &red, &ctx.train, &red_fit.x);
            f.heldout_rms_after_m = rms_of(prep, &red, &ctx.heldout, &red_fit.x);
            f.evidence.push_str(&format!("; {words}"));
        }
        notes.push(words);
        dropped.push(e);
        *spec = red;
        *cur_train = red_fit;
    }
}

/// The named effects' final values (end of step 4): the training fit the figures come from and
/// the fit on every sample.
fn final_estimates(
    ctx: &Ctx<'_>,
    b: &Baseline,
    named: &Named,
    opts: &DiagnoseOptions,
    effects: &mut [Finding],
) -> (lm::LmReport, lm::LmReport) {
    let prep = ctx.prep;
    let n = prep.n;
    let all_rows: Vec<usize> = (0..prep.t.len()).collect();
    let (has_t, usable_before_play) = (&b.has_t, &b.usable_before_play);
    let (spec, cur_train, last_round) = (&named.spec, &named.cur_train, &named.last_round);
    // The named effects' values from the final model (each one fitted jointly with every other
    // named effect), and the mimicking pairs fitted jointly.
    //
    // With backlash the estimates come from a refit with the hold weights
    // (`PlayState::hold_weights`: the readings held since one push share its tracker error and
    // count as one observation), the generalised least-squares fit of the play model; unweighted,
    // a long hold pinned the play width and through it the compliance, 4-8 sigma off on some
    // recordings. Selection (the held-out tests) stays on the selection's fit (`play_prep`: the
    // clear-push rows).
    //
    // The final model's RMS figures (RMS, held-out RMS, the structure left) say how close the
    // model comes to the noise on every reading, so they come from the fit that minimises the
    // sum of squares over every training reading: for a play without a time offset an
    // unweighted refit (the clear-push fit leaves out the holds and the push ends the play
    // pattern misreads, and the GLS weights give a hold the weight of one reading: on EA 20 kN
    // under 8 mm play either gave 1.72 mm held out over every reading, against a 1.50 mm noise
    // floor, `diagnose_concealed`); with a time offset as well the selection's clear-push fit.
    let refit = (spec.effects.contains(&Effect::Backlash) && spec.offset(Effect::TimeOffset, n).is_none())
        .then(|| ctx.fit(spec, &ctx.train, &cur_train.x, opts.max_iterations))
        .filter(|r| r.x.iter().all(|v| v.is_finite()));
    let final_train = refit.unwrap_or_else(|| cur_train.clone());
    let final_all = if spec.effects.contains(&Effect::Backlash) {
        // The rows that keep a weight: not held since a push while loose (in encoder time with
        // a time offset, whose excluded rows stay readings for the encoder's interpolation:
        // `fit::encoder_time_exclusion`), and with a time offset reading clear pushes only
        // (`fit::clear_push_rows`: a hold's level is the input's extreme, which a mistaken push
        // end misses on one side).
        let prep_w = match spec.offset(Effect::TimeOffset, n).map(|o| cur_train.x[o]) {
            Some(d) => encoder_time_prep(prep, usable_before_play, d, opts.encoder_sigma_m),
            // Without a time offset the holds stay, weighted (see `play_prep`).
            None => {
                Prepared { hold_weight: prep.play.hold_weights(&prep.usable, opts.tracker_sigma_m, opts.encoder_sigma_m), ..prep.clone() }
            }
        };
        let wctx = Ctx { prep: &prep_w, ..ctx.clone() };
        let cur_w = wctx.fit(spec, &wctx.train, &cur_train.x, opts.max_iterations);
        // Every named effect's values from the weighted fit (none reused from the unweighted one).
        let keep: Vec<(Vec<f64>, Vec<f64>)> = effects.iter().map(|f| (f.values.clone(), f.sigmas.clone())).collect();
        if let Some(f) = effects.iter_mut().find(|f| spec.effects.last() == Some(&f.effect)) {
            let v = wctx.values(f.effect, spec, &cur_w, has_t, &wctx.train);
            (f.values, f.sigmas) = (v.vals, v.sigs);
        }
        if cur_w.x.iter().all(|v| v.is_finite()) {
            wctx.joint_fits(effects, spec, &cur_w, has_t, opts, &[]);
            wctx.fit(spec, &all_rows, &cur_w.x, opts.max_iterations)
        } else {
            for (f, (v, s)) in effects.iter_mut().zip(keep) {
                (f.values, f.sigmas) = (v, s);
            }
            ctx.joint_fits(effects, spec, cur_train, has_t, opts, last_round);
            ctx.fit(spec, &all_rows, &cur_train.x, opts.max_iterations)
        }
    } else {
        ctx.joint_fits(effects, spec, cur_train, has_t, opts, last_round);
        ctx.fit(spec, &all_rows, &cur_train.x, opts.max_iterations)
    };
    (final_train, final_all)
}

/// False-alarm rate of "structure remains" on a recording the final model explains (the
/// families of [`leftover`] together, Bonferroni).
pub const LEFTOVER_ALPHA: f64 = 1e-3;

/// Structure the final model leaves that a family of [`leftover`] predicts on the held-out
/// blocks.
struct Structure {
    follows: leftover::Follows,
    test: HeldoutTest,
    nuisance: leftover::Nuisance,
}

impl Structure {
    /// The held-out sum of squares this structure holds is larger than what the named effects
    /// removed from the baseline's: they fitted the nearest thing the library knows.
    fn outweighs(&self, baseline: &FitSummary, final_fit: &FitSummary) -> bool {
        let (sb, sf) = (baseline.heldout_rms_m.powi(2), final_fit.heldout_rms_m.powi(2));
        self.test.gain * sf > sb - sf
    }

    /// Words for people: what it follows, where, and the test.
    fn words(&self, n: usize) -> String {
        let cables: Vec<usize> = (0..n).filter(|&j| self.nuisance.removed_m[j].is_finite()).collect();
        let mut s = format!("it {}", self.follows.words());
        if self.follows == leftover::Follows::PeriodicInLength {
            let wavelengths = self.nuisance.wavelengths_m();
            let w: Vec<String> = cables.iter().map(|&j| format!("{:.0}", wavelengths[j] * 1e3)).collect();
            s.push_str(&format!(
                " (wavelength {} mm on {}; a drum's circumference or a guide's pitch repeats like this)",
                w.join(", "),
                taut_config::cable_list(&cables)
            ));
        }
        let r: Vec<String> = cables.iter().map(|&j| format!("{:.2}", self.nuisance.removed_m[j] * 1e3)).collect();
        s.push_str(&format!("; {} mm RMS of it on {}; {}", r.join(", "), taut_config::cable_list(&cables), self.test));
        s
    }
}

/// The most significant family of [`leftover`] on the final model's held-out residuals, if any
/// passes at [`LEFTOVER_ALPHA`]. The height family is reported instead of the position family,
/// when it carries at least 70 % of the position family's gain, and the periodic one instead of
/// the length family at 90 % and with one wavelength (within 10 %) on every cable.
fn leftover_test(ctx: &Ctx<'_>, spec: &ModelSpec, x: &[f64], res: &[Vec<f64>]) -> Option<Structure> {
    let prep = ctx.prep;
    let mut r0 = Vec::with_capacity(ctx.heldout_rows.last().copied().unwrap_or(0));
    for &i in &ctx.heldout {
        for j in (0..prep.n).filter(|&j| prep.usable[j][i]) {
            r0.push(res[j][i]);
        }
    }
    let terms = ctx.heldout_terms(spec, x);
    let w = ctx.heldout_factors(spec, x);
    let families = leftover::Follows::ALL.len() as f64;
    let passed: Vec<Structure> = leftover::Follows::ALL
        .iter()
        .filter_map(|&follows| {
            let nuisance = leftover::fit(prep, res, &ctx.train, &ctx.heldout, follows);
            let test = weighted_test(&r0, &w, &nuisance.heldout, &w, &terms, None, None)?;
            (test.p_value * families < LEFTOVER_ALPHA && test.gain > 0.0).then_some(Structure { follows, test, nuisance })
        })
        .collect();
    // A nested or narrower family is reported when it carries most of the wider one's gain.
    let gain_of = |f| passed.iter().find(|s| s.follows == f).map(|s| s.test.gain);
    let height = gain_of(leftover::Follows::Height);
    // A periodic cause (a drum's circumference) repeats at one wavelength on every cable.
    let periodic = passed
        .iter()
        .find(|s| s.follows == leftover::Follows::PeriodicInLength)
        .filter(|s| {
            let w: Vec<f64> = s.nuisance.wavelengths_m().into_iter().filter(|w| w.is_finite()).collect();
            let (lo, hi) = w.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
            hi <= 1.1 * lo
        })
        .map(|s| s.test.gain);
    let has_length = passed.iter().any(|s| s.follows == leftover::Follows::Length);
    passed
        .into_iter()
        .filter(|s| match s.follows {
            leftover::Follows::Position => !height.is_some_and(|g| g >= 0.7 * s.test.gain),
            // A sinusoid has 3 parameters against the length family's dozens: it must carry
            // nearly all of that family's gain to be the better description.
            leftover::Follows::Length => !periodic.is_some_and(|g| g >= 0.9 * s.test.gain),
            leftover::Follows::PeriodicInLength => periodic.is_some() || !has_length,
            _ => true,
        })
        .max_by(|a, b| a.test.gain.total_cmp(&b.test.gain))
}

/// The named effects tested again with the leftover `st`'s family fitted beside them: the
/// baseline with the family against the final model with the family, each fitted jointly on the
/// training blocks ([`with_family`]), on the held-out blocks. Effects that fitted part of a
/// mismatch outside the library (a height error taken up by drum scales and build-up) explain
/// nothing the family does not; effects that are there beside it (a stretch beside an eccentric
/// drum) still do. The test leaves out the variance the estimation error of the family's many
/// coefficients adds ([`esterr`] covers the library's models only), so it leans towards keeping
/// the effects.
fn beyond_structure(ctx: &Ctx<'_>, b: &Baseline, st: &Structure, spec: &ModelSpec, final_train: &lm::LmReport) -> Option<HeldoutTest> {
    let base = with_family(ctx, &b.ideal, &b.fit.x, &st.nuisance);
    let full = with_family(ctx, spec, &final_train.x, &st.nuisance);
    let terms = ctx.heldout_terms(&b.ideal, &base.1);
    let w0 = ctx.heldout_factors(&b.ideal, &base.1);
    let w1 = ctx.heldout_factors(spec, &full.1);
    weighted_test(&base.0, &w0, &full.0, &w1, &terms, None, None)
}

/// A cable's regressor matrix, decomposed.
type Svd = nalgebra::SVD<f64, nalgebra::Dyn, nalgebra::Dyn>;

/// Most Levenberg–Marquardt iterations of [`with_family`], and the relative fall of its cost
/// below which it has converged.
const WITH_FAMILY: (usize, f64) = (40, 1e-10);

/// `spec` and the family `nu` (its basis per cable as fitted on the training blocks; a periodic
/// family keeps its wavelengths) fitted together on the training blocks, from `x0`: the held-out
/// residuals (the layout of [`leftover::Nuisance::heldout`]) and the model's parameters.
///
/// Variable projection: the family is linear, so for given parameters its coefficients are each
/// cable's least squares, and the model's parameters minimise what the family's span leaves of
/// the residuals (Levenberg–Marquardt on the projected residuals, finite-difference Jacobian).
/// Alternating the two fits instead converges slowly: the family's constant and slopes share
/// directions with the offsets and anchors (a height error took 300 rounds to split).
fn with_family(ctx: &Ctx<'_>, spec: &ModelSpec, x0: &[f64], nu: &leftover::Nuisance) -> (Vec<f64>, Vec<f64>) {
    let prep = ctx.prep;
    let n = prep.n;
    let train = &ctx.train;
    let r0 = fit::residuals(prep, spec, train, x0);
    // Per cable: the training positions it is fitted on, and its basis's SVD there.
    let cables: Vec<(Vec<usize>, Option<Svd>)> = (0..n)
        .map(|j| {
            let rows: Vec<usize> = (0..train.len()).filter(|&k| r0[j][k].is_finite()).collect();
            let b: Vec<Vec<f64>> = rows.iter().filter_map(|&k| nu.regressors(prep, train[k], j)).collect();
            if b.len() != rows.len() || b.is_empty() {
                return (rows, None);
            }
            let q = b[0].len();
            let m = DMatrix::from_fn(rows.len(), q, |r, c| b[r][c]);
            (rows, Some(m.svd(true, true)))
        })
        .collect();
    // What the family's span leaves of cable `j`'s training residuals `r` (on its rows).
    let tol = |svd: &Svd| svd.singular_values.max() * 1e-10;
    let project = |j: usize, r: &DVector<f64>| -> DVector<f64> {
        match &cables[j].1 {
            Some(svd) => {
                let u = svd.u.as_ref().expect("u");
                let keep: Vec<usize> = (0..svd.singular_values.len()).filter(|&c| svd.singular_values[c] > tol(svd)).collect();
                let mut out = r.clone();
                for c in keep {
                    let col = u.column(c);
                    out -= col * col.dot(r);
                }
                out
            }
            None => r.clone(),
        }
    };
    let stacked = |x: &[f64]| -> Option<DVector<f64>> {
        let res = fit::residuals(prep, spec, train, x);
        let mut out = Vec::new();
        for (j, (rows, _)) in cables.iter().enumerate() {
            let r = DVector::from_iterator(rows.len(), rows.iter().map(|&k| res[j][k]));
            if !r.iter().all(|v| v.is_finite()) {
                return None;
            }
            out.extend(project(j, &r).iter().copied());
        }
        Some(DVector::from_vec(out))
    };
    let p = x0.len();
    let mut x = x0.to_vec();
    let (iters, rel) = WITH_FAMILY;
    if let Some(mut r) = stacked(&x) {
        let mut cost = r.norm_squared();
        let mut lambda = 1e-3;
        for _ in 0..iters {
            let mut jac = DMatrix::zeros(r.len(), p);
            for k in 0..p {
                let h = 1e-7 * (1.0 + x[k].abs());
                let mut xh = x.clone();
                xh[k] += h;
                let Some(rh) = stacked(&xh) else { continue };
                jac.set_column(k, &((rh - &r) / h));
            }
            let jtj = jac.transpose() * &jac;
            let g = jac.transpose() * &r;
            let mut improved = false;
            for _ in 0..10 {
                let mut a = jtj.clone();
                for k in 0..p {
                    a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
                }
                let Some(step) = a.cholesky().map(|c| c.solve(&(-&g))) else {
                    lambda *= 10.0;
                    continue;
                };
                let xt: Vec<f64> = x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
                match stacked(&xt) {
                    Some(rt) if rt.norm_squared() < cost => {
                        let fell = (cost - rt.norm_squared()) / cost.max(f64::MIN_POSITIVE);
                        (x, r, cost) = (xt, rt.clone(), rt.norm_squared());
                        lambda = (lambda / 10.0).max(1e-12);
                        improved = fell > rel;
                        break;
                    }
                    _ => lambda *= 10.0,
                }
            }
            if !improved {
                break;
            }
        }
    }
    // The family's coefficients at `x`, per cable, and the held-out residuals without it.
    let res = fit::residuals(prep, spec, train, &x);
    let coef: Vec<Option<DVector<f64>>> = cables
        .iter()
        .enumerate()
        .map(|(j, (rows, svd))| {
            let svd = svd.as_ref()?;
            let r = DVector::from_iterator(rows.len(), rows.iter().map(|&k| res[j][k]));
            svd.solve(&r, tol(svd)).ok()
        })
        .collect();
    let held = fit::residuals(prep, spec, &ctx.heldout, &x);
    let mut out = Vec::new();
    for (k, &i) in ctx.heldout.iter().enumerate() {
        for j in (0..n).filter(|&j| prep.usable[j][i]) {
            let f = match (&coef[j], nu.regressors(prep, i, j)) {
                (Some(c), Some(b)) => b.iter().zip(c.iter()).map(|(a, b)| a * b).sum(),
                _ => 0.0,
            };
            out.push(held[j][k] - f);
        }
    }
    (out, x)
}

/// Step 5, **show** the fit improve: the final model's residuals on every sample, and the
/// structure no effect in the library explains: what a family of [`leftover`] predicts on the
/// held-out blocks ([`leftover_test`]).
fn leftover_structure(
    ctx: &Ctx<'_>,
    b: &Baseline,
    spec: &ModelSpec,
    final_train: &lm::LmReport,
    final_fit: &FitSummary,
    an_sub: &[usize],
) -> (Vec<Vec<f64>>, Option<String>, Option<Structure>) {
    let prep = ctx.prep;
    let n = prep.n;
    let all_rows: Vec<usize> = (0..prep.t.len()).collect();
    let final_res = fit::residuals(prep, spec, &all_rows, &final_train.x);
    let structure = leftover_test(ctx, spec, &final_train.x, &final_res);

    // Only the held-out test speaks of structure: an amplitude rule (RMS against twice the
    // sample-to-sample noise) took correlated tracker noise for it (AR(1) 0.9: 42 of 50
    // effect-free recordings).
    let unexplained = structure.as_ref().map(|st| {
        let fsub: Vec<Vec<f64>> = final_res.iter().map(|r| an_sub.iter().map(|&i| r[i]).collect()).collect();
        let after = analysis::analyse(prep, an_sub, &fsub, &final_fit.params.anchors, &b.has_t);
        let mut s = format!("structure remains that no effect in the library explains: {}", st.words(n));
        let also: Vec<&str> =
            after.words.iter().filter(|w| w.starts_with("follows") || w.starts_with("largest")).map(|w| w.as_str()).collect();
        if !also.is_empty() {
            s.push_str(&format!("; the residual {}", also.join("; ")));
        }
        s
    });
    (final_res, unexplained, structure)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{self, Spec, Stretch};

    fn box_rec(stretch: Stretch, ea: f64, tensions: bool, seed: u64) -> (Recording, Spec) {
        let mut spec = Spec::new(synth::aras_cam());
        spec.stretch = stretch;
        spec.cable_ea_n = ea;
        spec.loose_fraction = 0.03;
        spec.tensions = tensions;
        let rec = synth::box_recording(&spec, 3000, [-2.5, -1.2, 0.5], [2.5, 1.2, 2.8], seed);
        (rec, spec)
    }

    #[test]
    fn the_load_cell_noise_comes_from_the_calibration_table() {
        let c = CalibrationConfig { loadcell_sigma_n: 0.3, loadcell_offset_n: 0.5, ..CalibrationConfig::default() };
        let o = DiagnoseOptions::from_config(&c);
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.3, 0.5));
        // Without the keys the tensions are exact, as before the keys existed.
        let o = DiagnoseOptions::default();
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.0, 0.0));
    }

    #[test]
    fn noise_only_names_nothing_but_slack() {
        let (rec, spec) = box_rec(Stretch::None, 2e5, true, 3);
        let d = diagnose(&rec, &spec.platform_points, None, &DiagnoseOptions::default()).unwrap();
        let named: Vec<_> = d.effects.iter().filter(|f| f.effect != Effect::Slack).map(|f| (f.effect, f.evidence.clone())).collect();
        assert!(named.is_empty(), "{named:#?}\n{:#?}", d.rejected);
        assert!(d.effects.iter().any(|f| f.effect == Effect::Slack));
    }

    #[test]
    fn elasticity_is_named_with_ea_and_heldout_falls() {
        let (rec, spec) = box_rec(Stretch::Physical, 20_000.0, true, 4);
        let d = diagnose(&rec, &spec.platform_points, None, &DiagnoseOptions::default()).unwrap();
        let f = d.effects.iter().find(|f| f.effect == Effect::Elasticity).unwrap_or_else(|| panic!("{:#?}", d.rejected));
        for (v, s) in f.values.iter().zip(&f.sigmas) {
            assert!((v - 20_000.0).abs() < 6.0 * s, "EA {v} ± {s}");
        }
        // The issue's rule: the held-out RMS falls 3x where the effect leaves more than 3x the
        // noise; otherwise it falls to the noise.
        let noise = (spec.tracker_sigma_m.powi(2) + spec.encoder_sigma_m.powi(2)).sqrt();
        let (b, a) = (d.baseline.heldout_rms_m, d.final_fit.heldout_rms_m);
        if b > 3.0 * noise {
            assert!(3.0 * a <= b, "{b} -> {a}");
        } else {
            assert!(a < 1.1 * noise, "{b} -> {a}, noise {noise}");
        }
        assert!(f.evidence.contains("T*L"), "{}", f.evidence);
    }

    #[test]
    fn without_tensions_elasticity_is_not_claimed() {
        let (rec, spec) = box_rec(Stretch::Physical, 20_000.0, false, 5);
        let d = diagnose(&rec, &spec.platform_points, None, &DiagnoseOptions::default()).unwrap();
        assert!(!d.used_tensions);
        assert!(d.effects.iter().all(|f| !f.effect.needs_tension()));
    }
}
