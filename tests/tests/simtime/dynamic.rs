//! The start-up with a tracker on the dynamic plant (`taut_sim::Dynamics`): the platform a rigid
//! point mass on elastic, damped 1 MN steel cables, the followers' drums masses moved by their
//! motors, the position drums behind their drives' servos. The platform swings after every reel
//! and during the excitation, and the tensions carry `m a`.
//!
//! Asserted, seeds 1-5 (`TAUT_DYNAMIC_SEEDS`): the three phases complete, the calibration is
//! accepted and hot-swapped, no fault latches, and the worst anchor is within 1 mm of the truth
//! ([`ACCEPTANCE_M`]: the quasi-static plant's accuracy). The anchors' errors, their
//! sigmas and the fitted stiffnesses are printed (`RESULT`).
//!
//! # The stretch, modelled
//!
//! A 1 MN cable of 4-6 m stretches `T L / EA` = 0.04-0.36 mm over the 10-60 N the start-up's
//! cables carry. With the ideal model the anchors absorb the variation of that stretch over the
//! excitation: 2.6-3.0 mm worst anchor on seeds 1-5 (sigmas 0.47-0.55 mm; the quasi-static
//! plant with the same stretch 1.6-1.9 mm). The robot's configuration here says what a
//! datasheet would: the cables' stiffness, 0.9 MN with a 1-sigma of 0.15 MN
//! (`calibration.cable_ea_n`, `cable_ea_sigma_n`; the truth, 1 MN, is 0.7 sigma off). The
//! refinement then models each reading's stretch from its tension, each cable's EA fitted
//! within that prior, and the estimate carries the fitted EA to the loop (docs/effects.md). The
//! calibrator reads a row's tensions at its pose's instant between the load cells' readings
//! around it (a reading is up to a polling round, ~15 ms, old while the swing changes the
//! tension).
//!
//! Measured, worst anchor on seeds 1-5: 0.57 / 0.73 / 0.84 / 0.55 / 0.46 mm,
//! sigmas 0.40-0.45 mm, worst coordinate 2.3-3.2 of its sigmas; fitted EA of cable 0
//! 0.74-0.84 MN, cable 1 0.68-0.83 MN, cable 2 1.04-1.13 MN, cable 3 0.78-0.89 MN. The simulated
//! load cells answer as on the wire: the polling round runs one transaction at a time, each
//! cell answers with the plant's tension at the instant its request reached it (the plant's
//! nearest step), and its reading is stamped when its answer is complete, 1.78 ms later (1 ms
//! latency, 9 characters at 115200 baud). The bound is the acceptance itself, 1 mm.

use taut_simrig::SimOptions;

/// The phases' reel on the dynamic plant, m.
pub const DYNAMIC_REEL_M: f64 = -0.5;

/// The acceptance: the worst anchor within this of the truth, m (issue 27).
const ACCEPTANCE_M: f64 = 1e-3;

/// The cables' stiffness as a datasheet gives it, N: 10 % below the plant's 1 MN.
const DATASHEET_EA_N: f64 = 0.9e6;

/// Its tolerance, 1-sigma, N (17 %).
const DATASHEET_EA_SIGMA_N: f64 = 0.15e6;

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// One start-up on the dynamic plant: the worst anchor error and the calibration's worst anchor
/// sigma, m.
fn startup(seed: u64) -> (f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = taut_tests::startup::example_robot(dir.path());
    // A swinging platform reeled the example's 0.85 m climbs to 3.65 m under 4 m anchors and
    // its held cables go slack: the phases reel 0.5 m (the default of `motion.init_reel_m`).
    cfg.motion.init_reel_m = DYNAMIC_REEL_M;
    // What the robot's configuration knows of its cables (module doc).
    cfg.calibration.cable_ea_n = DATASHEET_EA_N;
    cfg.calibration.cable_ea_sigma_n = DATASHEET_EA_SIGMA_N;
    let mut so = SimOptions { seed, ..Default::default() };
    so.physics.dynamics = Some(taut_sim::Dynamics::default());
    let (run, cal) = taut_tests::startup::accepted_in_sim_time(&cfg, &so, "dynamic");
    let (l, c) = (&run.loop_status, &run.calib_status);
    assert_eq!(l.snap.phases_completed, 3, "seed {seed}");
    assert!(taut_tests::startup::hot_swapped(l, c), "seed {seed}: not hot-swapped");
    let ce = cal.estimate.as_ref().expect("an accepted calibration has an estimate");
    let errs: Vec<f64> = ce.geometry.anchors.iter().zip(&run.truth.anchors).map(|(a, t)| dist(a, t)).collect();
    let worst = errs.iter().cloned().fold(0.0, f64::max);
    let sigma = ce.sigma.anchors.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).fold(0.0, f64::max);
    // The largest coordinate error in its own sigmas (honest sigmas: a few at most).
    let z = ce.geometry.anchors.iter().zip(&run.truth.anchors).zip(&ce.sigma.anchors);
    let z = z.flat_map(|((a, t), s)| (0..3).map(move |x| (a[x] - t[x]).abs() / s[x])).fold(0.0, f64::max);
    eprintln!(
        "RESULT seed {seed} dynamic: worst anchor error {:.3} mm, worst anchor sigma {:.3} mm, worst coordinate {z:.1} sigma, errors {:?} mm; {:.1} s simulated in {:.1} s; note {}",
        worst * 1e3,
        sigma * 1e3,
        errs.iter().map(|e| (e * 1e5).round() / 100.0).collect::<Vec<_>>(),
        run.sim_s,
        run.wall_s,
        ce.note
    );
    (worst, sigma)
}

#[test]
fn tracker_start_up_on_the_dynamic_plant() {
    let seeds: Vec<u64> = std::env::var("TAUT_DYNAMIC_SEEDS")
        .map(|s| s.split(',').map(|x| x.trim().parse().expect("TAUT_DYNAMIC_SEEDS: comma-separated seeds")).collect())
        .unwrap_or_else(|_| (1..=5).collect());
    let mut failures = Vec::new();
    for seed in seeds {
        let (worst, _) = startup(seed);
        if worst > ACCEPTANCE_M {
            failures.push(format!("seed {seed}: worst anchor error {:.2} mm", worst * 1e3));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
