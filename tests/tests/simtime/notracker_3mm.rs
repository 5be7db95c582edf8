//! The start-up without a tracker reaches 3 mm: `taut start --sim` without a tracker, worst
//! anchor error after the alignment (translation + rotation about the vertical) at most 3 mm,
//! hot-swapped, with the example's poses and tares (config/examples/aras-cam-sim-notracker.toml),
//! on the quasi-static plant.
//!
//! # The rate the budget is judged at
//!
//! The example's 16 x 34 s was chosen at the ~128 tension readings a second per cable of load
//! cells on a pseudo-terminal, which has no character times. The simulated-time bus models the
//! line (115200 baud, t3.5, the cell's 1 ms answer latency) and delivers 62 a second
//! ([`SIM_RATE_HZ`]), as a real line would at best. At 62 a second the example's plan has a
//! worst-anchor sigma of 0.89 mm and its P(worst > 3 mm) reaches the recording check's 1e-3 at
//! 1.01 x that sigma: the budget below would not hold. So the start-up here runs the example's
//! poses and tares with dwells of 130 s ([`Plan::Bus`], the dynamic plant's acceptance's plan,
//! `notracker_3mm_dynamic`), and its plan is checked at 62 a second
//! ([`the_suite_plan_meets_the_budget_at_the_bus_rate`]). The example's own plan is checked at
//! the 128 a second it was chosen for ([`the_example_plan_meets_the_budget`]).
//!
//! About 15 minutes of the robot's time, run in simulated time (the robot stack in lockstep,
//! `taut_simrig::run_startup`): `cargo test -p taut-tests --test simtime notracker_3mm --
//! --nocapture` (`TAUT_E2E_SEEDS=1,2,4` for other sites, one after the other).
//!
//! # Failure probability per run (one start-up, correct code): below 1e-4, computed
//!
//! The information is the load cells' (0.3 N per reading at the ~128 readings a second per cable
//! that four Modbus cells polled back to back at 115200 baud give, against a 29 N weight: the
//! anchor heights carry the frame's tilt, which only gravity fixes); it grows with the tension
//! readings recorded at rest, in the dwells (the tilt) and in the tares (each cable's offset,
//! which leaks into the tilt), and with little else the plan can choose: many poses with short
//! rests do worse, not better (`notracker_2mm`; BENCHMARKS.md, "Start-up without a tracker").
//!
//! 1. The 3 mm: a correct calibration's anchor errors are Gaussian with the covariance the
//!    planner predicts, times the model's honesty c = achieved / predicted worst-anchor sigma
//!    (achieved: the CRB at the fit times sqrt(chi2/dof) when above 1). Every c measured
//!    ([`RATIOS`]: fifteen start-ups, 0.843-1.051) gives a 99.9 % upper prediction bound
//!    (Student's t) of 1.165 ([`honesty_bound`], asserted <= [`HONESTY_UP`] = 1.181). The plan is checked first (deterministic): P(worst > 3 mm) at
//!    [`HONESTY_UP`] x the predicted covariance below [`PLAN_P_MAX`] = 6e-5 (Monte Carlo, 99.9 %
//!    upper bound; 16 poses x 34 s with 8 tares: 5.5e-5).
//! 2. The recording's own P(worst > 3 mm), from its achieved sigma (the planner's covariance at
//!    the reading rate measured in the recording, scaled up to the achieved sigma where larger)
//!    must be below [`RECORDING_P_MAX`] = 1e-3 before the 3 mm is asserted. The plan has that P
//!    below 1e-3 up to [`SCALE_CHECKED`] = 1.45 x its sigma (checked first), so a correct run
//!    fails this check only when its c exceeds 1.45: 4.2e-6 by the same prediction over ten
//!    ratios, 3.9e-7 over fifteen (Student's t over [`RATIOS`], computed by the test), or when the simulated bus delivers fewer readings
//!    (a starved machine: what this check is for).
//! 3. The checks every start-up makes (`notracker::start`): 12 anchor coordinates within 4.89
//!    sigma (1.2e-5), chi2 below its 1e-5 quantile (1e-5).
//!
//! Sum: 6e-5 + 5e-6 + 1.2e-5 + 1e-5 = 8.7e-5 per run (the asserted bounds, [`BUDGET`]; 8.1e-5
//! with the plan's own 5.5e-5 and the computed 4.2e-6). 16 x 30 s dwells (0.662 mm) would put
//! the plan at ~1.4e-4 per run at that honesty bound; the 34 s dwells cost ~1.6 minutes (~14.8
//! minutes in all). The k-sigma and chi2 terms assume the static model, and the chi2 term's 1e-5
//! stands on its measured null distribution: the fit on this plan's static dwells without the
//! wall clock (800 sites, `tests/examples/notracker_chi2_null.rs`) gives chi2/dof 0.983 with sd
//! 0.165 (chi2 at 67 dof: 1, 0.173), and the site's truth stands still through every recorded
//! dwell from its first row (BENCHMARKS.md, "Start-up without a tracker").
//!
//! The test raises `safety.tension_max_age_s` (see `notracker::robot`): a test-machine
//! allowance, not the robot's.

use crate::notracker::{report, robot, start_on, Plan};
use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;

/// Achieved / predicted (at the measured reading rate) worst-anchor sigma of every tracker-free
/// start-up on the quasi-static plant measured: the 6-tare long plan (seeds 3, 5: 0.884,
/// 0.942), the short plan (seeds 3, 5 twice: 0.904, 0.922, 0.930, 0.938), 16 x 30 s (seeds 1, 2,
/// 4: 0.843, 0.946, 0.988; seed 1 again: 1.043) and 16 x 34 s (seed 1: 0.912, 0.910, 0.876; seed
/// 2: 0.858; seed 4: 1.051, whose site is the farthest from the nominal one).
const RATIOS: [f64; 15] = [0.884, 0.942, 0.904, 0.922, 0.930, 0.938, 0.843, 0.946, 0.988, 1.043, 0.912, 0.910, 0.876, 0.858, 1.051];

/// At least the 99.9 % upper prediction bound of the next ratio ([`honesty_bound`]: 1.180 over
/// the first ten, when the plan was chosen; 1.141 over twelve, 1.165 over all fifteen).
pub(crate) const HONESTY_UP: f64 = 1.181;

/// The plan's P(worst aligned anchor > 3 mm) at [`HONESTY_UP`] x its predicted covariance.
pub(crate) const PLAN_P_MAX: f64 = 6e-5;

/// The recording's own P(worst aligned anchor > 3 mm) from its achieved sigmas.
pub(crate) const RECORDING_P_MAX: f64 = 1e-3;

/// The plan keeps P(worst > 3 mm) below [`RECORDING_P_MAX`] up to this many times its predicted
/// sigma: the recording's check passes unless the achieved sigma is that much larger.
pub(crate) const SCALE_CHECKED: f64 = 1.45;

/// The largest chance a correct run's ratio exceeds [`SCALE_CHECKED`] (the prediction over
/// [`RATIOS`]: 4.2e-6 over the first ten, 3.9e-7 over twelve and over all fifteen).
pub(crate) const RECORDING_CHANCE_MAX: f64 = 5e-6;

/// The failure probability per run with the asserted bounds: the plan, the recording check, the
/// k-sigma check (12 coordinates at 4.89 sigma) and the chi-square check (its 1e-5 quantile).
const BUDGET: f64 = PLAN_P_MAX + RECORDING_CHANCE_MAX + 1.2e-5 + 1e-5;
const _: () = assert!(BUDGET < 1e-4);

/// Tension readings a second per cable of load cells on a pseudo-terminal (measured 128-131 in
/// every real-time run): what the example's plan was chosen at.
const RATE_HZ: f64 = 128.0;

/// Tension readings a second per cable on the simulated-time bus (62 in every run measured):
/// what the suite's plan is judged at; the recording's check uses the rate measured in it.
pub const SIM_RATE_HZ: f64 = 62.0;

/// Mean, standard deviation and the 99.9 % upper prediction bound of the next value of `x`
/// (Student's t with n - 1 dof: mean + t sd sqrt(1 + 1/n)).
fn honesty_bound(x: &[f64]) -> (f64, f64, f64) {
    taut_tests::honesty::upper_prediction_bound(x, 1e-3)
}

/// The honesty bound and the recording check's chance failure from the measured ratios.
#[test]
fn the_measured_ratios_give_the_budget() {
    let (mean, sd, up) = honesty_bound(&RATIOS);
    let chance = taut_tests::honesty::exceeds_chance(&RATIOS, SCALE_CHECKED);
    eprintln!(
        "{} ratios: mean {mean:.3}, sd {sd:.4}; 99.9 % upper prediction bound {up:.3}; P(ratio > {SCALE_CHECKED}) = {chance:.1e}; budget {BUDGET:.1e} per run",
        RATIOS.len()
    );
    assert!(up <= HONESTY_UP, "the honesty bound over the measured ratios is {up:.3} > {HONESTY_UP}");
    assert!(chance < RECORDING_CHANCE_MAX, "P(ratio > {SCALE_CHECKED}) = {chance:.1e}");
}

/// The example's plan (deterministic: the example's configuration and the planner), at the rate
/// it was chosen for; the loop runs the plan computed at the configured rate (polled back to
/// back: the planner assumes 50/s), which must be the same poses and tares.
#[test]
fn the_example_plan_meets_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    check_plan(&robot(dir.path(), Plan::Example), RATE_HZ, HONESTY_UP, SCALE_CHECKED);
}

/// The plan the start-up below runs, at the rate the simulated-time bus delivers.
#[test]
fn the_suite_plan_meets_the_budget_at_the_bus_rate() {
    let dir = tempfile::tempdir().unwrap();
    check_plan(&robot(dir.path(), Plan::Bus), SIM_RATE_HZ, HONESTY_UP, SCALE_CHECKED);
}

/// `cfg`'s plan at `rate` tension readings a second per cable: the same poses and tares as the
/// loop's, P(worst > 3 mm) below [`PLAN_P_MAX`] at `honesty_up` x its covariance and below
/// [`RECORDING_P_MAX`] at `scale_checked` x.
pub fn check_plan(cfg: &taut_config::RobotConfig, rate: f64, honesty_up: f64, scale_checked: f64) {
    let ccfg = ControllerConfig::from_robot(cfg).unwrap();
    let run = taut_calibrator::notracker::dwell_plan(cfg, &ccfg).unwrap();
    let mut at_rate = cfg.clone();
    at_rate.loadcells.as_mut().unwrap().poll_period_s = 1.0 / rate;
    let plan = taut_calibrator::notracker::dwell_plan(&at_rate, &ccfg).unwrap();
    assert_eq!(plan.tare, run.tare);
    for (a, b) in plan.poses.iter().zip(&run.poses) {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-9), "the plan at {rate}/s differs from the one the loop runs: {a:?} vs {b:?}");
    }
    let nominal = cfg.anchors().unwrap();
    let (_, p_honest) = plan.worst_exceeds_probability(&nominal, 3e-3, honesty_up, 4_000_000);
    let (_, p_checked) = plan.worst_exceeds_probability(&nominal, 3e-3, scale_checked, 4_000_000);
    eprintln!(
        "plan: {} poses x {} s, {} tares; worst-anchor sigma {:.3} mm at {rate}/s; P(worst > 3 mm) <= {p_honest:.1e} at {honesty_up} sigma, <= {p_checked:.1e} at {scale_checked} sigma",
        cfg.motion.dwell_poses,
        cfg.motion.dwell_s,
        plan.tare.iter().filter(|&&t| t != 0).count(),
        plan.worst_anchor_sigma_m * 1e3
    );
    assert!(p_honest < PLAN_P_MAX, "the plan at {rate}/s: P(worst > 3 mm) up to {p_honest:.1e} at {honesty_up} sigma");
    assert!(p_checked < RECORDING_P_MAX, "the plan at {rate}/s: P(worst > 3 mm) up to {p_checked:.1e} at {scale_checked} sigma");
}

/// The start-up on the quasi-static plant, one per seed (default seed 1; `TAUT_E2E_SEEDS=1,2,4`):
/// `cargo test -p taut-tests --test simtime notracker_3mm -- --ignored --nocapture`. The suite
/// runs the same plan on the dynamic plant (`notracker_3mm_dynamic`), where the platform swings
/// into every rest; this one (about 30 s of wall time) is for comparing the two plants.
#[test]
#[ignore]
fn worst_anchor_within_3_mm() {
    // One start-up per seed, one after the other: two simulated robots in parallel on a
    // two-core machine starve each other's device threads (stale load cells, missed heartbeats).
    let seeds: Vec<u64> = std::env::var("TAUT_E2E_SEEDS").map_or(vec![1], |v| v.split(',').map(|x| x.trim().parse().unwrap()).collect());
    for seed in seeds {
        let r = start_on(seed, Plan::Bus, false, true);
        report(seed, &r);
        // The ratio is the honesty of one more start-up (RATIOS); its CRB part (without the
        // variance factor) and the chi-square's tail say whether a larger one is the model's
        // (chi2/dof above its noise) or the geometry's.
        let ratio = r.achieved_worst_sigma_m / r.repredicted_worst_sigma_m;
        eprintln!(
            "seed {seed}: achieved / predicted (at the measured rate) worst-anchor sigma {ratio:.3} (CRB part {:.3}; the recording check fails above {SCALE_CHECKED}); chi2/dof {:.2} at {} dof: P(chi2/dof >= that) = {:.1e}",
            ratio / r.chi2_dof.max(1.0).sqrt(),
            r.chi2_dof,
            r.dof,
            chi2_tail(r.dof, r.chi2_dof)
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
pub(crate) fn chi2_tail(dof: usize, v: f64) -> f64 {
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
    // sf(1.972 x 68, 68) = 3.14e-6, sf(1.972 x 60, 60) = 1.07e-5.
    assert!((chi2_tail(68, 1.972) / 3.14e-6 - 1.0).abs() < 0.25, "{}", chi2_tail(68, 1.972));
    assert!((chi2_tail(60, 1.972) / 1.07e-5 - 1.0).abs() < 0.2, "{}", chi2_tail(60, 1.972));
}

/// Candidate plans for the budget: per plan the predicted worst-anchor sigma, the robot's time
/// through it (`taut_calibrator::notracker::plan_robot_time_s`: the first rest, the moves at
/// the start-up's acceleration, settling, dwells and tares), P(worst > the limit) at the scales
/// given and the largest scale at which P stays below [`RECORDING_P_MAX`]:
/// `TAUT_PLANS="16x30x8,16x36x8" TAUT_SCALES="1.0,1.2" cargo test -p taut-tests --test simtime plan_candidates -- --ignored --nocapture`.
///
/// A plan is `POSESxDWELLxTARES` or `POSESxDWELLxTARESxTARE_S` (a tare's own recorded time, s;
/// the loop records a tare as long as a dwell). `TAUT_RATE`: tension readings a second per
/// cable (default [`RATE_HZ`]); `TAUT_EA=1`: the dynamic plant's datasheet stiffness (the
/// planner with its unknowns); `TAUT_SETTLE` (s), `TAUT_SPEED` (m/s), `TAUT_ACCEL` (m/s^2):
/// `motion.dwell_settle_s`, `dwell_speed_m_s`, `init_reel_accel_m_s2`; `TAUT_GRID="9x7x6"`:
/// the candidate grid (more poses than the loop's 64 need more candidates); `TAUT_LIMIT_MM`:
/// the worst-anchor limit (default 3); `TAUT_ENCODERS_ONLY=1`: no load cells; `TAUT_MASS`: the
/// platform's mass, kg.
#[test]
#[ignore]
fn plan_candidates() {
    use taut_calibrator::notracker::{dwell_plan_with, plan_robot_time_s, PlanKnobs};
    let dir = tempfile::tempdir().unwrap();
    let base = robot(dir.path(), Plan::Example);
    let list = |key: &str, default: &str| std::env::var(key).unwrap_or_else(|_| default.to_string());
    let scales: Vec<f64> = list("TAUT_SCALES", "1.0,1.1,1.2").split(',').map(|s| s.trim().parse().unwrap()).collect();
    let nominal = base.anchors().unwrap();
    let rate: f64 = list("TAUT_RATE", &RATE_HZ.to_string()).parse().unwrap();
    let ea = std::env::var_os("TAUT_EA").is_some();
    let limit = list("TAUT_LIMIT_MM", "3").parse::<f64>().unwrap() * 1e-3;
    let grid: Vec<usize> = list("TAUT_GRID", "7x5x4").split('x').map(|s| s.trim().parse().unwrap()).collect();
    // TAUT_ENCODERS_ONLY=1: without load cells (the anchors then in the frame of the nominal
    // anchors' best rigid motion: what the encoders alone leave of the shape).
    let encoders_only = std::env::var_os("TAUT_ENCODERS_ONLY").is_some();
    let knob = |key: &str| std::env::var(key).ok().map(|v| v.parse::<f64>().unwrap());
    for spec in list("TAUT_PLANS", "16x30x8,16x32x8,16x34x8,16x36x8").split(',') {
        let v: Vec<f64> = spec.trim().split('x').map(|s| s.parse().unwrap()).collect();
        let mut cfg = base.clone();
        cfg.motion.dwell_poses = v[0] as usize;
        cfg.motion.dwell_s = v[1];
        cfg.motion.dwell_tares = v[2] as usize;
        cfg.motion.dwell_settle_s = knob("TAUT_SETTLE").unwrap_or(cfg.motion.dwell_settle_s);
        cfg.motion.dwell_speed_m_s = knob("TAUT_SPEED").unwrap_or(cfg.motion.dwell_speed_m_s);
        cfg.motion.init_reel_accel_m_s2 = knob("TAUT_ACCEL").unwrap_or(cfg.motion.init_reel_accel_m_s2);
        cfg.robot.mass_kg = knob("TAUT_MASS").unwrap_or(cfg.robot.mass_kg);
        cfg.loadcells.as_mut().unwrap().poll_period_s = 1.0 / rate;
        if ea {
            cfg.calibration.cable_ea_n = 0.9e6;
            cfg.calibration.cable_ea_sigma_n = 0.15e6;
        }
        if encoders_only {
            cfg.loadcells = None;
            cfg.cables.iter_mut().for_each(|c| c.loadcell = None);
        }
        let knobs = PlanKnobs { max_poses: usize::MAX, grid: [grid[0], grid[1], grid[2]], tare_s: v.get(3).copied() };
        let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
        let p = match dwell_plan_with(&cfg, &ccfg, &knobs) {
            Ok(p) => p,
            Err(e) => {
                eprintln!("{spec}: no plan: {e}");
                continue;
            }
        };
        let tares = p.tare.iter().filter(|&&t| t != 0).count();
        let robot_s = plan_robot_time_s(&p, &cfg, &ccfg, knobs.tare_s);
        let ps: Vec<String> =
            scales.iter().map(|&s| format!("{s}: {:.1e}", p.worst_exceeds_probability(&nominal, limit, s, 4_000_000).1)).collect();
        // The largest scale with P <= RECORDING_P_MAX (bisection, 1e6 draws, 99.9 % bound).
        let (mut lo, mut hi) = (0.0, 2.0);
        for _ in 0..12 {
            let mid = 0.5 * (lo + hi);
            if p.worst_exceeds_probability(&nominal, limit, mid, 1_000_000).1 < RECORDING_P_MAX {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let per: Vec<String> =
            p.anchor_sigma_m.iter().map(|s| format!("[{:.2} {:.2} {:.2}]", s[0] * 1e3, s[1] * 1e3, s[2] * 1e3)).collect();
        eprintln!(
            "{spec}: sigma {:.3} mm (x y z per anchor {}), {tares} tares, robot time {robot_s:.0} s (path {:.1} m); P(worst > {} mm) upper at scale {}; P < {RECORDING_P_MAX:.0e} up to scale {lo:.3}",
            p.worst_anchor_sigma_m * 1e3,
            per.join(" "),
            p.path_m,
            limit * 1e3,
            ps.join(", ")
        );
    }
}
