//! The start-up's designed excitation on the simulated robot (config/examples/aras-cam-sim.toml,
//! 30 s, tracker at 100 Hz with 1.5 mm noise): worst anchor error against the simulator's truth,
//! the calibration's own sigmas and the design's prediction. Asserted: the calibration is
//! accepted, its note states the predicted and the achieved uncertainty, the achieved worst-anchor
//! sigma is within a bound of the predicted one derived from the time-block sandwich's scatter
//! (1e-5 per run), every anchor coordinate is within 4.53-4.86 of its sigmas (7e-5 per run), and
//! **the worst anchor error is at most 1 mm**.
//!
//! # The 1 mm: failure probability per seed for correct code, computed
//!
//! A correct calibration's anchor errors are Gaussian with the covariance the design predicts
//! times the honesty `c`, the achieved / predicted worst-anchor sigma (at the length noise the
//! calibration measures: 0.050 mm, the configured encoder noise, in every run so far). The
//! measured `c` ([`RATIOS`]) give the predictive distribution of the next one (Student's t).
//! 1. The design (deterministic, `the_design_meets_the_budget`): P(worst > 1 mm) integrated over
//!    that distribution, at each `c` the union over the anchors of P(|e_j| > 1 mm) computed by
//!    quadrature (`taut_calib::design::Prediction::worst_exceeds_bound`), below [`PLAN_P_MAX`].
//! 2. The recording's own P(worst > 1 mm), from the prediction at the measured length noise
//!    scaled up by the achieved / predicted ratio where above 1, must be below
//!    [`RECORDING_P_MAX`] before the 1 mm is asserted. The design keeps that P below it up to
//!    [`SCALE_CHECKED`] x its sigma (checked first), so a correct run fails this check only when
//!    its ratio exceeds that: below [`RECORDING_CHANCE_MAX`] by the same prediction (or when the
//!    length noise rises, e.g. on a starved machine: what the check is for).
//!
//! Sum for the 1 mm: [`PLAN_P_MAX`] + [`RECORDING_CHANCE_MAX`] per seed ([`BUDGET_1MM`],
//! docs/test-robustness.md).

use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;
use taut_simrig::SimOptions;

/// The loop's Lissajous point `t` s after the approach (as `taut_calibrator::excite` predicts it).
fn ccfg_lissajous(ccfg: &ControllerConfig, t: f64) -> [f64; 3] {
    let w = ccfg.workspace;
    let v = ccfg.excitation_speed_m_s;
    std::array::from_fn(|i| {
        let c = (w[0][i] + w[1][i]) / 2.0;
        let amp = 0.8 * (w[1][i] - w[0][i]) / 2.0;
        let omega = taut_rt::motion::LISSAJOUS_RATIO[i] * v / (3f64.sqrt() * amp.max(1e-3));
        c + amp * (omega * t + taut_rt::motion::LISSAJOUS_PHASE[i]).sin()
    })
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Blocks of the refinement's time-block sandwich (`taut_calib::bundle`'s `SANDWICH_BLOCKS`).
const SANDWICH_BLOCKS: usize = 32;

/// The effective degrees of freedom of the time-block sandwich variance of each anchor
/// coordinate along `path` (the training rows the calibration fits, cut into
/// [`SANDWICH_BLOCKS`] consecutive blocks). Under the model a block's gradient has covariance
/// `I_b` (its information), so the sandwich variance of coordinate `k` is
/// `sum_b lambda_b chi2_1` with `lambda_b = (C I_b C)_kk`, `C` the inverse of the total: by
/// Satterthwaite a `(sum lambda) chi2_nu / nu` with `nu = (sum lambda)^2 / sum lambda^2` (31 for
/// equal blocks; less where a coordinate is seen in few blocks).
fn sandwich_dof(inp: &taut_calib::design::DesignInput, path: impl Fn(f64) -> [f64; 3]) -> Vec<[f64; 3]> {
    let rows = (inp.duration_s * inp.sample_hz).floor() as usize;
    let pts: Vec<[f64; 3]> =
        taut_calib::design::training_rows(rows, inp.used_fraction, inp.heldout_blocks).map(|k| path(k as f64 / inp.sample_hz)).collect();
    let blocks: Vec<_> = (0..SANDWICH_BLOCKS)
        .map(|b| {
            let r = b * pts.len() / SANDWICH_BLOCKS..(b + 1) * pts.len() / SANDWICH_BLOCKS;
            taut_calib::design::information(inp, pts[r].iter())
        })
        .collect();
    let total = blocks.iter().fold(nalgebra::DMatrix::<f64>::zeros(blocks[0].nrows(), blocks[0].ncols()), |a, b| a + b);
    let Some(c) = total.try_inverse() else { return vec![[1.0; 3]; inp.anchors.len()] };
    let per_block: Vec<_> = blocks.iter().map(|ib| &c * ib * &c).collect();
    (0..inp.anchors.len())
        .map(|j| {
            std::array::from_fn(|i| {
                let k = 4 * j + i;
                let s: f64 = per_block.iter().map(|m| m[(k, k)]).sum();
                s * s / per_block.iter().map(|m| m[(k, k)].powi(2)).sum::<f64>()
            })
        })
        .collect()
}

/// Achieved / predicted (at the measured length noise) worst-anchor sigma of every start-up on
/// the local-search tour (seeds 1-5 three times; the first five printed to three decimals).
const RATIOS: [f64; 15] =
    [1.008, 1.019, 1.071, 0.981, 0.994, 1.0077, 1.0212, 1.0207, 0.9847, 0.9931, 1.0072, 1.0587, 1.0260, 0.9802, 0.9920];

/// The design's P(worst anchor error > 1 mm), integrated over the honesty's prediction.
const PLAN_P_MAX: f64 = 5e-6;

/// The recording's own P(worst > 1 mm) from its achieved sigma.
const RECORDING_P_MAX: f64 = 1e-3;

/// The design keeps P(worst > 1 mm) below [`RECORDING_P_MAX`] up to this many times its
/// predicted sigma.
const SCALE_CHECKED: f64 = 1.4;

/// The largest chance a correct run's ratio exceeds [`SCALE_CHECKED`] (the prediction over [`RATIOS`]).
const RECORDING_CHANCE_MAX: f64 = 5e-6;

/// The 1 mm assertion's failure probability per seed with the asserted bounds.
const BUDGET_1MM: f64 = PLAN_P_MAX + RECORDING_CHANCE_MAX;
const _: () = assert!(BUDGET_1MM < 1e-4);

/// Family error rate of the per-coordinate k-sigma check (Bonferroni over the 12 coordinates of
/// each seed run).
const KSIGMA_FAMILY: f64 = 7e-5;

/// Family error rate of the achieved / predicted sigma-ratio bound.
const RATIO_FAMILY: f64 = 1e-5;

/// The whole test's failure probability per CI run for correct code: the k-sigma check, the
/// sigma-ratio bound and the 1 mm (the design's and the recording's parts).
const _: () = assert!(KSIGMA_FAMILY + RATIO_FAMILY + BUDGET_1MM < 1e-4);

/// The simulated robot's configuration as written.
fn robot(dir: &std::path::Path) -> taut_config::RobotConfig {
    taut_tests::startup::example_robot(dir)
}

/// The recording check's chance failure from the measured ratios.
#[test]
fn the_measured_ratios_give_the_budget() {
    let (mean, sd, up) = taut_tests::honesty::upper_prediction_bound(&RATIOS, 1e-5);
    let chance = taut_tests::honesty::exceeds_chance(&RATIOS, SCALE_CHECKED);
    eprintln!(
        "{} ratios: mean {mean:.3}, sd {sd:.4}; upper prediction bound at 1e-5 {up:.3}; P(ratio > {SCALE_CHECKED}) = {chance:.1e}; 1 mm budget {BUDGET_1MM:.1e} per seed",
        RATIOS.len()
    );
    assert!(chance < RECORDING_CHANCE_MAX, "P(ratio > {SCALE_CHECKED}) = {chance:.1e}");
}

/// The design of the simulated robot (deterministic) keeps P(worst > 1 mm) within the budget.
#[test]
fn the_design_meets_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let mut ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let plan = taut_calibrator::excite::plan(&cfg, &mut ccfg);
    assert!(ccfg.tour.is_some(), "{}", plan.summary());
    let pred = plan.predicted.as_ref().expect("a prediction");
    let p_plan = taut_tests::honesty::integrated_failure(&RATIOS, |c| pred.worst_exceeds_bound(1e-3, c));
    let p_checked = pred.worst_exceeds_bound(1e-3, SCALE_CHECKED);
    eprintln!(
        "{}; P(worst > 1 mm) = {p_plan:.1e} over the honesty's prediction, {:.1e} at 1 x, {p_checked:.1e} at {SCALE_CHECKED} x its sigma",
        plan.summary(),
        pred.worst_exceeds_bound(1e-3, 1.0)
    );
    assert!(p_plan < PLAN_P_MAX, "P(worst > 1 mm) = {p_plan:.1e}");
    assert!(p_checked < RECORDING_P_MAX, "P(worst > 1 mm) = {p_checked:.1e} at {SCALE_CHECKED} x");
}

/// P(worst > 1 mm) of the design at each scale (`TAUT_SCALES=1.0,1.2`) and the largest scale
/// with P below [`RECORDING_P_MAX`]:
/// `cargo test -p taut-tests --test e2e e2e_excitation::design_scales -- --ignored --nocapture`.
#[test]
#[ignore]
fn design_scales() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let mut ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let plan = taut_calibrator::excite::plan(&cfg, &mut ccfg);
    let pred = plan.predicted.as_ref().expect("a prediction");
    let scales: Vec<f64> = std::env::var("TAUT_SCALES")
        .unwrap_or_else(|_| "1.0,1.1,1.2,1.3,1.4".into())
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    for s in scales {
        eprintln!("{}: scale {s}: P(worst > 1 mm) <= {:.2e}", plan.summary(), pred.worst_exceeds_bound(1e-3, s));
    }
    let (mut lo, mut hi) = (1.0, 3.0);
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if pred.worst_exceeds_bound(1e-3, mid) < RECORDING_P_MAX {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    eprintln!("P < {RECORDING_P_MAX:.0e} up to scale {lo:.3}");
}

/// One start-up against the truth, m.
struct Run {
    worst_err_m: f64,
    worst_sigma_m: f64,
    predicted_m: f64,
    /// The prediction at the length noise the calibration measured, m.
    at_noise_m: f64,
    /// Predicted 1-sigma of each anchor (root of its three variances) at the measured length
    /// noise, m.
    predicted_anchor_m: Vec<f64>,
    /// Effective degrees of freedom of the refinement's time-block sandwich per anchor
    /// coordinate (at the nominal geometry; the smallest over the tour's joins).
    sandwich_dof: Vec<[f64; 3]>,
    noise_m: f64,
    errs_m: Vec<f64>,
    axis_errs_m: Vec<[f64; 3]>,
    sigmas_m: Vec<[f64; 3]>,
    samples: usize,
    /// This recording's P(worst > 1 mm): the prediction at the measured length noise, scaled up
    /// by the achieved / predicted worst-anchor sigma where above 1.
    p1: f64,
    /// The scale used for it.
    p1_scale: f64,
}

fn startup(seed: u64, designed: bool) -> Run {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = robot(dir.path());
    cfg.motion.design_excitation = designed;
    // `TAUT_EXCITE_S=25`: the test start-ups' excitation (tests/src/startup.rs EXCITATION_S).
    if let Ok(s) = std::env::var("TAUT_EXCITE_S") {
        cfg.motion.excitation_s = s.parse().expect("TAUT_EXCITE_S: the excitation's duration, s");
    }
    let so = SimOptions { seed, ..Default::default() };
    // In simulated time (the robot stack in lockstep): no machine load can starve it.
    let (run, cal) = taut_tests::startup::accepted_in_sim_time(&cfg, &so, "excite");
    let (truth, c) = (run.truth.clone(), &run.calib_status);
    let ce = cal.estimate.as_ref().unwrap_or_else(|| panic!("seed {seed}: {}", cal.reason));
    assert!(ce.note.contains("predicted worst anchor 1-sigma"), "seed {seed}: the note lacks the prediction: {}", ce.note);
    let predicted_m = c.excitation.as_ref().map_or(f64::NAN, |p| p.predicted_worst_m());
    // The design predicts at the configured encoder noise; the calibration weighs the lengths
    // with the noise it measures in its residuals (`length noise X mm` in the note). The same
    // prediction at that noise checks the information model apart from the noise level.
    let noise_m = ce
        .note
        .split("length noise ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|x| x.parse::<f64>().ok())
        .map(|mm| mm * 1e-3)
        .unwrap_or_else(|| panic!("seed {seed}: the note lacks the measured length noise: {}", ce.note));
    let mut ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let _ = taut_calibrator::excite::plan(&cfg, &mut ccfg);
    let mut inp = taut_calibrator::excite::design_input(&cfg, &ccfg).unwrap();
    inp.length_sigma_m = noise_m;
    let pred = match ccfg.tour {
        Some(tour) => taut_calib::design::predict_tour(&inp, &tour),
        None => taut_calib::design::predict(&inp, |t| ccfg_lissajous(&ccfg, t)),
    };
    let at_noise_m = pred.as_ref().map_or(f64::NAN, |p| p.worst_anchor_sigma_m());
    let predicted_anchor_m: Vec<f64> = pred.as_ref().map_or(vec![f64::NAN; truth.anchors.len()], |p| {
        p.anchor_sigma.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).collect()
    });
    let sandwich_dof = match ccfg.tour {
        Some(tour) => (0..tour.n.max(1))
            .map(|k| {
                let (_, t0) = tour.nearest_waypoint(&tour.waypoints[k]);
                sandwich_dof(&inp, |t| tour.point(t + t0))
            })
            .reduce(|a, b| a.iter().zip(&b).map(|(x, y)| std::array::from_fn(|i| x[i].min(y[i]))).collect())
            .unwrap_or_default(),
        None => sandwich_dof(&inp, |t| ccfg_lissajous(&ccfg, t)),
    };
    let errs_m: Vec<f64> = ce.geometry.anchors.iter().zip(&truth.anchors).map(|(a, t)| dist(a, t)).collect();
    let sig: Vec<f64> = ce.sigma.anchors.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).collect();
    let p1_scale = (sig.iter().cloned().fold(0.0, f64::max) / at_noise_m).max(1.0);
    let p1 = pred.as_ref().map_or(1.0, |p| p.worst_exceeds_bound(1e-3, p1_scale));
    eprintln!("seed {seed}: note {}", ce.note);
    eprintln!(
        "seed {seed}: {:.1} s simulated in {:.1} s; CAN {} frames, load {:.2}",
        run.sim_s,
        run.wall_s,
        run.bus.frames,
        run.bus.busy_s / run.sim_s
    );
    Run {
        worst_err_m: errs_m.iter().cloned().fold(0.0, f64::max),
        worst_sigma_m: sig.iter().cloned().fold(0.0, f64::max),
        predicted_m,
        at_noise_m,
        predicted_anchor_m,
        sandwich_dof,
        noise_m,
        errs_m,
        axis_errs_m: ce.geometry.anchors.iter().zip(&truth.anchors).map(|(a, t)| std::array::from_fn(|i| a[i] - t[i])).collect(),
        sigmas_m: ce.sigma.anchors.clone(),
        samples: cal.samples,
        p1,
        p1_scale,
    }
}

#[test]
fn designed_excitation_reaches_its_predicted_uncertainty() {
    let seeds: Vec<u64> = std::env::var("TAUT_EXCITE_SEEDS")
        .map(|s| s.split(',').map(|x| x.trim().parse().expect("TAUT_EXCITE_SEEDS: comma-separated seeds")).collect())
        .unwrap_or_else(|_| vec![1, 2, 3, 4, 5]);
    let designed = std::env::var("TAUT_EXCITE_PATH").map_or(true, |p| p != "lissajous");
    let mut failures = vec![];
    let comparisons = 12 * seeds.len();
    for seed in seeds {
        let r = startup(seed, designed);
        eprintln!(
            "RESULT seed {seed} designed {designed}: worst anchor error {:.3} mm, worst anchor sigma {:.3} mm (predicted {:.3} mm; {:.3} mm at the measured length noise {:.4} mm), samples {}, errors {:?} mm, sigmas {:?} mm",
            r.worst_err_m * 1e3,
            r.worst_sigma_m * 1e3,
            r.predicted_m * 1e3,
            r.at_noise_m * 1e3,
            r.noise_m * 1e3,
            r.samples,
            r.errs_m.iter().map(|e| (e * 1e5).round() / 100.0).collect::<Vec<_>>(),
            r.sigmas_m.iter().map(|s| s.map(|x| (x * 1e5).round() / 100.0)).collect::<Vec<_>>()
        );
        if !designed {
            continue;
        }
        // The 1 mm (see the module documentation for its failure rate): first whether
        // this recording shows it at the stated rate, then the error itself.
        eprintln!(
            "seed {seed}: achieved / predicted worst-anchor sigma {:.4} (at the measured noise; {:.4} at the configured); this recording's P(worst > 1 mm) <= {:.1e} (predicted covariance at the measured noise x {:.3}^2)",
            r.worst_sigma_m / r.at_noise_m,
            r.worst_sigma_m / r.predicted_m,
            r.p1,
            r.p1_scale
        );
        if r.p1 >= RECORDING_P_MAX {
            failures.push(format!(
                "seed {seed}: this recording's P(worst > 1 mm) is up to {:.1e}: it does not show the 1 mm at the stated error rate",
                r.p1
            ));
        } else if r.worst_err_m > 1e-3 {
            failures.push(format!("seed {seed}: worst anchor error {:.2} mm > 1 mm", r.worst_err_m * 1e3));
        }
        //
        // The achieved worst-anchor sigma against the prediction at the length noise the
        // calibration measured (the design's own prediction at the configured encoder noise is
        // printed beside it). The refinement reports per coordinate the larger of its model
        // variance m_ji and the time-block sandwich s_ji, so with sigma_j = sqrt(sum_i m_ji):
        //   R = max_j sqrt(sum_i max(m_ji, s_ji)) / pred_w
        //     <= c * max_j rho_j * max(1, max_i sqrt(W_ji)),
        // c = the model's sigmas over the prediction's: deterministic given the path (the
        // approach's extra rows, true vs nominal anchors, the actual join; 0.90-1.00 measured),
        // allowed up to C_MAX; rho_j = pred_j / pred_w; under the model
        // s_ji = m_ji W_ji with W_ji ~ chi2_nu / nu (Satterthwaite, `sandwich_dof`: 13-31 here,
        // lowest where a coordinate is seen in few of the 32 blocks). So R exceeds
        //   r_max = C_MAX * max(1, max_j rho_j sqrt(q_ji))
        // with probability at most sum_ji P(W_ji > q_ji), each q_ji at 1e-5 / (12 x seeds)
        // (Wilson-Hilferty at floor(nu), which errs high: 71.2 vs 70.2 at nu = 20, z = 5.1).
        // The old fixed 1.5 failed by chance with ~1e-3 per seed even at nu = 31, c = 1 (seen
        // once: seed 4, 1.52). The lower side, R >= c > 1/1.5, is not random (the reported
        // sigma is at least the model's): only a wrong information model fails it.
        const C_MAX: f64 = 1.1;
        let z = taut_calib::screen::normal_upper_quantile(RATIO_FAMILY / comparisons as f64);
        let mut r_max: f64 = 1.0;
        for (nu, pj) in r.sandwich_dof.iter().zip(&r.predicted_anchor_m) {
            for v in nu {
                let v = v.floor().max(1.0);
                r_max = r_max.max(pj / r.at_noise_m * (taut_calib::selfcal::chi2_quantile(v as usize, z) / v).sqrt());
            }
        }
        let r_max = C_MAX * r_max;
        let ratio = r.worst_sigma_m / r.at_noise_m;
        eprintln!(
            "seed {seed}: achieved / predicted worst-anchor sigma {ratio:.3}, allowed 0.667-{r_max:.3} (sandwich dof per anchor {:?}, predicted sigmas {:?} mm)",
            r.sandwich_dof.iter().map(|a| a.map(|x| (x * 10.0).round() / 10.0)).collect::<Vec<_>>(),
            r.predicted_anchor_m.iter().map(|x| (x * 1e4).round() / 10.0).collect::<Vec<_>>()
        );
        if !(ratio > 1.0 / 1.5 && ratio < r_max) {
            failures.push(format!(
                "seed {seed}: achieved worst anchor sigma {:.2} mm vs predicted {:.2} mm at the measured length noise {:.3} mm (ratio {ratio:.2}, allowed 0.667-{r_max:.3})",
                r.worst_sigma_m * 1e3,
                r.at_noise_m * 1e3,
                r.noise_m * 1e3
            ));
        }
        // Every coordinate within k of its own sigmas, k by Bonferroni over the 12 coordinates of
        // each seed for a family error rate of KSIGMA_FAMILY with a right covariance (k = 4.53
        // for the one default seed, 4.86 for five; a flat 4 fails 7.6e-4 of runs by chance per
        // seed).
        let k = taut_calib::screen::normal_upper_quantile(KSIGMA_FAMILY / (2.0 * comparisons as f64));
        for (j, (e, s)) in r.axis_errs_m.iter().zip(&r.sigmas_m).enumerate() {
            for i in 0..3 {
                if e[i].abs() > k * s[i] {
                    failures.push(format!("seed {seed}: anchor {j}[{i}] off by {:.2} mm, sigma {:.2} mm", e[i] * 1e3, s[i] * 1e3));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
