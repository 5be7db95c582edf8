//! The 3 mm without a tracker on the dynamic plant, with rests that begin while the platform
//! still swings: the platform swings on its 1 MN cables after every move, and every rest begins
//! while it swings.
//! The configuration gives the cables' datasheet stiffness (0.9 +- 0.15 MN, truth 1 MN): the
//! calibration fits each cable's stretch within it, and the planner counts those unknowns.
//!
//! `cargo test -p taut-tests --test simtime notracker_3mm_dynamic -- --nocapture` (seed 1);
//! `TAUT_E2E_SEEDS=1,2,4` for other sites; the ignored `seeds` runs 1-5.
//!
//! # The plan: the example's poses and tares, dwells of 130 s
//!
//! The simulated-time bus delivers 62 tension readings a second per cable ([`SIM_RATE_HZ`]): the
//! Modbus master's own timing on a 115200 baud line (character times, t3.5, the cell's 1 ms
//! answer latency). The example's 16 x 34 s was chosen at the 128 a second of cells on a
//! pseudo-terminal (no character times); at 62 a second its worst-anchor sigma is 0.89 mm, and
//! its P(worst > 3 mm) reaches the recording check's 1e-3 at 1.01 x that sigma, so any run
//! with an achieved / predicted ratio above 1.01 fails that check (seeds 4 and 5 did, at 1.12
//! and 1.19). The stiffness unknowns in the planner change its sigma by 0.3 % only. With dwells
//! of [`crate::notracker::BUS_DWELL_S`] = 130 s (about 55 minutes of the robot's time, ~25 s of
//! wall time) the planner predicts 0.457 mm at 62 a second.
//!
//! # Failure probability per run (one start-up, correct code): below 1e-4, computed
//!
//! As the quasi-static acceptance (`notracker_3mm`), with the dynamic plant's own ratios:
//!
//! 1. The honesty c = achieved / predicted worst-anchor sigma on the dynamic plant ([`RATIOS`],
//!    36 runs: mean 1.040, sd 0.145) has a 99.9 % upper prediction bound of 1.530
//!    ([`HONESTY_UP`] = 1.54), above the quasi-static 1.181, which the dynamic plant exceeds
//!    (seed 4: 1.24-1.34). The spread is mostly the sites' (the CRB part 0.79-1.18), then the
//!    chi-square. The plan has P(worst > 3 mm) <= 2.9e-5 at [`HONESTY_UP`] x its covariance,
//!    asserted below [`super::notracker_3mm::PLAN_P_MAX`].
//! 2. The recording's own P(worst > 3 mm) from its achieved sigma below [`RECORDING_P_MAX`]:
//!    the plan keeps it there up to [`SCALE_CHECKED`] x its sigma (4.2e-4 there, checked), which
//!    a correct run's ratio exceeds with a chance of 1.7e-6 (below [`RECORDING_CHANCE_MAX`]).
//! 3. The checks every start-up makes: 12 anchor coordinates within 4.89 sigma (1.2e-5), chi2
//!    below its 1e-5 quantile (1e-5). (`start_on_plant`'s 0.8-1.5 range of the ratio is not
//!    applied to this plan: it would fail 6 % of correct runs here.)
//!
//! Sum: 6e-5 + 5e-6 + 1.2e-5 + 1e-5 = 8.7e-5 per run.

use super::notracker_3mm::{check_plan, chi2_tail, RECORDING_CHANCE_MAX, RECORDING_P_MAX, SIM_RATE_HZ};
use crate::notracker::{report, robot, start_on_plant, Plan, Run};

/// Achieved / predicted (at the measured rate) worst-anchor sigma of tracker-free start-ups on
/// the dynamic plant with the stiffness modelled, every run measured: 16 poses with 8 tares,
/// dwells of 70 s (seeds 1-20), 110 s (seeds 1-5, 20), 115 s (seeds 1-5) and 130 s (this plan,
/// seeds 1-5). The CRB part (the fit's CRB at the site's geometry against the prediction at
/// the nominal one) is the site's (seed 4: 1.13-1.18 at every length, seed 20: 0.79-0.80); the
/// rest is the chi-square (chi2/dof 0.61-1.45, no trend with the dwell).
const RATIOS: [f64; 36] = [
    0.858, 1.039, 1.025, 1.236, 1.170, 0.953, 0.834, 1.034, 0.961, 0.952, 1.117, 1.050, 1.071, 0.824, 0.840, 1.079, 1.058, 0.936, 1.018,
    0.789, // 110 s
    0.967, 1.137, 1.043, 1.277, 1.198, 0.796, // 115 s
    0.889, 1.051, 1.100, 1.340, 1.288, // 130 s
    0.884, 1.122, 1.141, 1.171, 1.180,
];

/// At least the 99.9 % upper prediction bound of the next ratio on the dynamic plant
/// ([`RATIOS`]: 1.530 over all 36; 1.537 over the first 31, when this plan was chosen).
pub(crate) const HONESTY_UP: f64 = 1.54;

/// The plan keeps P(worst > 3 mm) below [`RECORDING_P_MAX`] up to this many times its sigma
/// (checked); a correct run's ratio exceeds it with a chance of 1.7e-6 over [`RATIOS`].
const SCALE_CHECKED: f64 = 1.85;

/// The dynamic plant's configuration: the example robot running [`Plan::Bus`] with the cables'
/// datasheet stiffness (as `start_on_plant`).
fn config(dir: &std::path::Path) -> taut_config::RobotConfig {
    let mut cfg = robot(dir, Plan::Bus);
    cfg.calibration.cable_ea_n = 0.9e6;
    cfg.calibration.cable_ea_sigma_n = 0.15e6;
    cfg
}

#[test]
fn the_measured_dynamic_ratios_give_the_budget() {
    let (mean, sd, up) = taut_tests::honesty::upper_prediction_bound(&RATIOS, 1e-3);
    let chance = taut_tests::honesty::exceeds_chance(&RATIOS, SCALE_CHECKED);
    eprintln!(
        "{} dynamic-plant ratios: mean {mean:.3}, sd {sd:.4}; 99.9 % upper prediction bound {up:.3} (quasi-static {}); P(ratio > {SCALE_CHECKED}) = {chance:.1e}",
        RATIOS.len(),
        super::notracker_3mm::HONESTY_UP
    );
    assert!(up <= HONESTY_UP, "the honesty bound over the dynamic plant's ratios is {up:.3} > {HONESTY_UP}");
    assert!(chance < RECORDING_CHANCE_MAX, "P(ratio > {SCALE_CHECKED}) = {chance:.1e}");
}

/// The plan at the simulated bus's rate, with the stiffness unknowns; the loop runs the plan
/// computed at the configured rate, which must be the same poses and tares.
#[test]
fn the_plan_meets_the_budget_on_the_dynamic_plant() {
    let dir = tempfile::tempdir().unwrap();
    check_plan(&config(dir.path()), SIM_RATE_HZ, HONESTY_UP, SCALE_CHECKED);
}

/// One start-up on the dynamic plant (the checks of `start_on_plant`: k-sigma, chi-square,
/// tares, hot-swap) and its figures.
fn run(seed: u64) -> Run {
    let r = start_on_plant(seed, Plan::Bus, false, true, true);
    report(seed, &r);
    let ratio = r.achieved_worst_sigma_m / r.repredicted_worst_sigma_m;
    eprintln!(
        "dynamic seed {seed}: worst {:.2} mm; achieved / predicted sigma {ratio:.3} (CRB part {:.3}; the recording check fails above {SCALE_CHECKED}); chi2/dof {:.2} at {} dof (P >= {:.1e}); P(worst > 3 mm) <= {:.1e}; predicted {:.3} mm at the measured rate; {:.1} s wall",
        r.worst_aligned_m * 1e3,
        ratio / r.chi2_dof.max(1.0).sqrt(),
        r.chi2_dof,
        r.dof,
        chi2_tail(r.dof, r.chi2_dof),
        r.p3_upper,
        r.repredicted_worst_sigma_m * 1e3,
        r.seconds
    );
    r
}

/// The recording's check, then the 3 mm.
fn accept(seed: u64, r: &Run) {
    assert!(
        r.p3_upper < RECORDING_P_MAX,
        "seed {seed}: this recording's P(worst > 3 mm) is up to {:.1e}: it does not show the 3 mm at the stated error rate",
        r.p3_upper
    );
    assert!(r.worst_aligned_m <= 3e-3, "seed {seed}: worst anchor {:.2} mm after alignment", r.worst_aligned_m * 1e3);
}

/// The start-up, one per seed (default seed 1; `TAUT_E2E_SEEDS=1,2,4`).
#[test]
fn worst_anchor_within_3_mm_on_the_dynamic_plant() {
    let seeds: Vec<u64> = std::env::var("TAUT_E2E_SEEDS").map_or(vec![1], |v| v.split(',').map(|x| x.trim().parse().unwrap()).collect());
    for seed in seeds {
        accept(seed, &run(seed));
    }
}

/// Seeds 1-5, each seed's failure reported and the loop going on:
/// `cargo test -p taut-tests --test simtime notracker_3mm_dynamic::seeds -- --ignored --nocapture`.
#[test]
#[ignore]
fn seeds() {
    let failed: Vec<u64> = (1..=5).filter(|&seed| std::panic::catch_unwind(|| accept(seed, &run(seed))).is_err()).collect();
    assert!(failed.is_empty(), "seeds {failed:?} failed");
}
