//! The acceptance for the start-up without a tracker (issue 11 item 3): `taut start
//! --sim` without a tracker, worst anchor error after the alignment (translation + rotation
//! about the vertical) at most 3 mm, hot-swapped, with the example's plan
//! (config/examples/aras-cam-sim-notracker.toml).
//!
//! About 13 minutes of real time: NOT part of `cargo test --workspace` (`test = false` in
//! tests/Cargo.toml) but its own serial step of `scripts/test`, after the workspace tests, on an
//! otherwise idle machine: `cargo test -p taut-tests --test e2e_notracker_3mm -- --nocapture`
//! (`TAUT_E2E_SEEDS=1,2,4` for other sites, one after the other).
//!
//! # Failure probability per run (one start-up, correct code): below 1e-4, computed
//!
//! The information is the load cells' (0.3 N per reading at the ~128 readings a second per cable
//! that four Modbus cells polled back to back at 115200 baud give, against a 29 N weight: the
//! anchor heights carry the frame's tilt, which only gravity fixes); it grows with the dwell
//! time and nothing else the plan can choose (BENCHMARKS.md, "Start-up without a tracker").
//!
//! 1. The 3 mm: a correct calibration's anchor errors are Gaussian with the covariance the
//!    planner predicts, times the model's honesty c = achieved / predicted worst-anchor sigma.
//!    Measured c over eight start-ups (six of session 13, seeds 1 and 2 of this plan): 0.84-0.95
//!    (mean 0.914, sd 0.035); its 99.9 % upper prediction bound (Student's t, 7 dof) is
//!    [`HONESTY_UP`] = 1.10. The plan is checked first (deterministic): P(worst > 3 mm) at 1.10 x
//!    the predicted covariance is below [`PLAN_P_MAX`] = 6e-5 (Monte Carlo, 99.9 % upper bound).
//! 2. The recording's own P(worst > 3 mm), from its achieved sigma (the planner's covariance at
//!    the reading rate measured in the recording, scaled up to the achieved sigma where larger)
//!    must be below [`RECORDING_P_MAX`] = 1e-3 before the 3 mm is asserted. The plan has that P
//!    below 1e-3 up to [`SCALE_CHECKED`] = 1.32 x its sigma (checked first); the achieved sigma
//!    is the CRB at the fit (c <= 0.94 x predicted in every run) times sqrt(chi2/dof) when above
//!    1, so a correct run fails this check only when chi2/dof exceeds (1.32 / 0.94)^2 = 1.97:
//!    P = 3.1e-6 at the 68 degrees of freedom of the plan's fit, 1.1e-5 even at 60 (computed and
//!    printed by the test from the fit's own dof), or when the simulated bus delivers fewer
//!    readings (a starved machine: what this check is for).
//! 3. The checks every start-up makes (`notracker::start`): 12 anchor coordinates within 4.89
//!    sigma (1.2e-5), chi2 below its 1e-5 quantile (1e-5).
//!
//! Sum: 6e-5 + 1.1e-5 + 1.2e-5 + 1e-5 = 9.3e-5 per run (the asserted bounds, 60 dof; the plan's
//! own numbers are printed by `the_example_plan_meets_the_budget`).
//! OPEN: run 4 (seed 4) had a CRB ratio of 0.988 > the 0.94 assumed in 2.; with it and the honesty
//! bound over nine ratios the sum is roughly 1.4e-4 per run, not 9.3e-5 (BENCHMARKS.md, Session
//! 14 `ntci`). A longer plan (16 x 32 s: 0.641 mm) or a larger checked scale would restore it.
//!
//! The test raises `safety.tension_max_age_s` (see `notracker::robot`): a test-machine
//! allowance, not the robot's.

mod notracker;

use notracker::{report, robot, start, Plan};
use taut_rt_core::motion::ControllerConfig;
use taut_rt_core::FromRobot;

/// 99.9 % upper prediction bound of achieved / predicted worst-anchor sigma (at the measured
/// reading rate): six start-ups of session 13 (0.884, 0.942 with the 6-tare long plan; 0.904,
/// 0.922, 0.930, 0.938 with the short one) and seeds 1, 2 of this plan (0.843, 0.946): mean
/// 0.914 + t(0.999, 7) 4.785 x sd 0.0353 x sqrt(1 + 1/8) = 1.093.
const HONESTY_UP: f64 = 1.10;

/// The plan's P(worst aligned anchor > 3 mm) at [`HONESTY_UP`] x its predicted covariance.
const PLAN_P_MAX: f64 = 6e-5;

/// The recording's own P(worst aligned anchor > 3 mm) from its achieved sigmas.
const RECORDING_P_MAX: f64 = 1e-3;

/// The plan keeps P(worst > 3 mm) below [`RECORDING_P_MAX`] up to this many times its predicted
/// sigma: the recording's check passes unless the achieved sigma is that much larger.
const SCALE_CHECKED: f64 = 1.32;

/// The largest achieved / predicted worst-anchor CRB (sigma without the variance factor) seen:
/// 0.84-0.94 over eight start-ups.
const CRB_RATIO_MAX: f64 = 0.94;

/// Tension readings a second per cable on the simulated bus (measured 128-131 in every run):
/// what the plan is judged at; the recording's check uses the rate measured in it.
const RATE_HZ: f64 = 128.0;

/// The plan first (deterministic: the example's configuration and the planner), at the rate the
/// simulated bus delivers; the loop runs the plan computed at the configured rate (polled back
/// to back: the planner assumes 50/s), which must be the same poses and tares.
#[test]
fn the_example_plan_meets_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path(), Plan::Example);
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let run = taut_rt_core::notracker::dwell_plan(&cfg, &ccfg).unwrap();
    let mut at_rate = cfg.clone();
    at_rate.loadcells.as_mut().unwrap().poll_period_s = 1.0 / RATE_HZ;
    let plan = taut_rt_core::notracker::dwell_plan(&at_rate, &ccfg).unwrap();
    assert_eq!(plan.tare, run.tare);
    for (a, b) in plan.poses.iter().zip(&run.poses) {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-9), "the plan at {RATE_HZ}/s differs from the one the loop runs: {a:?} vs {b:?}");
    }
    let nominal = cfg.anchors().unwrap();
    let (_, p_honest) = plan.worst_exceeds_probability(&nominal, 3e-3, HONESTY_UP, 4_000_000);
    let (_, p_checked) = plan.worst_exceeds_probability(&nominal, 3e-3, SCALE_CHECKED, 4_000_000);
    eprintln!(
        "plan: {} poses x {} s, {} tares; worst-anchor sigma {:.3} mm at {RATE_HZ}/s; P(worst > 3 mm) <= {p_honest:.1e} at {HONESTY_UP} sigma, <= {p_checked:.1e} at {SCALE_CHECKED} sigma",
        cfg.motion.dwell_poses,
        cfg.motion.dwell_s,
        plan.tare.iter().filter(|&&t| t != 0).count(),
        plan.worst_anchor_sigma_m * 1e3
    );
    assert!(p_honest < PLAN_P_MAX, "the example's plan: P(worst > 3 mm) up to {p_honest:.1e} at {HONESTY_UP} sigma");
    assert!(p_checked < RECORDING_P_MAX, "the example's plan: P(worst > 3 mm) up to {p_checked:.1e} at {SCALE_CHECKED} sigma");
}

/// The start-up, one per seed (default seed 1; `TAUT_E2E_SEEDS=1,2,4`).
#[test]
fn worst_anchor_within_3_mm() {
    // One start-up per seed, one after the other: two simulated robots in parallel on a
    // two-core machine starve each other's device threads (stale load cells, missed heartbeats).
    let seeds: Vec<u64> = std::env::var("TAUT_E2E_SEEDS").map_or(vec![1], |v| v.split(',').map(|x| x.trim().parse().unwrap()).collect());
    let vf_fail = (SCALE_CHECKED / CRB_RATIO_MAX).powi(2);
    for seed in seeds {
        let r = start(seed, Plan::Example, false);
        report(seed, &r);
        eprintln!(
            "seed {seed}: achieved / predicted (at the measured rate) worst-anchor sigma {:.3}; chi2/dof {:.2} at {} dof: P(chi2/dof >= {vf_fail:.2}) = {:.1e} (the recording check's chance failure)",
            r.achieved_worst_sigma_m / r.repredicted_worst_sigma_m,
            r.chi2_dof,
            r.dof,
            chi2_tail(r.dof, vf_fail)
        );
        assert!(
            r.p3_upper < RECORDING_P_MAX,
            "seed {seed}: this recording's P(worst > 3 mm) is up to {:.1e}: it does not show the 3 mm at the stated error rate",
            r.p3_upper
        );
        assert!(r.worst_aligned_m <= 3e-3, "seed {seed}: worst anchor {:.2} mm after alignment", r.worst_aligned_m * 1e3);
    }
}

/// P(chi2 / dof >= v) for a chi-square with `dof` degrees of freedom (Wilson–Hilferty, the
/// inverse of `taut_calib::selfcal::chi2_quantile`).
fn chi2_tail(dof: usize, v: f64) -> f64 {
    let h = 2.0 / (9.0 * dof.max(1) as f64);
    let z = (v.cbrt() - (1.0 - h)) / h.sqrt();
    0.5 * erfc(z / std::f64::consts::SQRT_2)
}

/// Complementary error function (Numerical Recipes' erfcc, relative error < 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07 + t * (-1.135_203_98 + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[test]
fn chi2_tail_matches_tables() {
    // scipy.stats.chi2: isf(1e-3, 100) = 149.45, isf(1e-5, 80) = 145.76, sf(1.77 x 79, 79) = 2.97e-5.
    assert!((chi2_tail(100, 1.4945) / 1e-3 - 1.0).abs() < 0.05, "{}", chi2_tail(100, 1.4945));
    assert!((chi2_tail(80, 145.76 / 80.0) / 1e-5 - 1.0).abs() < 0.2, "{}", chi2_tail(80, 145.76 / 80.0));
    assert!((chi2_tail(79, 1.77) / 2.97e-5 - 1.0).abs() < 0.2, "{}", chi2_tail(79, 1.77));
    // The recording check's chance failure (1.32 / 0.94)^2 = 1.972: sf at 68 dof 3.14e-6, at 60 1.07e-5.
    assert!((chi2_tail(68, 1.972) / 3.14e-6 - 1.0).abs() < 0.25, "{}", chi2_tail(68, 1.972));
    assert!((chi2_tail(60, 1.972) / 1.07e-5 - 1.0).abs() < 0.2, "{}", chi2_tail(60, 1.972));
}
