//! The start-up with a tracker on the dynamic plant (`taut_sim::Dynamics`): the platform a rigid
//! point mass on elastic, damped 1 MN steel cables, the followers' drums masses moved by their
//! motors, the position drums behind their drives' servos. The platform swings after every reel
//! and during the excitation, and the tensions carry `m a`.
//!
//! Asserted, seeds 1-5 (`TAUT_DYNAMIC_SEEDS`): the three phases complete, the calibration is
//! accepted and hot-swapped, no fault latches. The anchors' error against the truth is printed
//! (`RESULT`) and bounded by the stretch the ideal model leaves out (below): it is not the 1 mm
//! of the quasi-static plant's cables, which do not stretch.
//!
//! # Why the bound is what it is
//!
//! The robot calibrates with the ideal model (no `elasticity` effect). A 1 MN cable of 4-6 m
//! stretches `T L / EA` = 0.04-0.36 mm over the 10-60 N the start-up's cables carry, and the
//! anchors absorb the variation of that stretch over the excitation. Measured (2026-11-28): the
//! quasi-static plant with the same 1 MN stretch gives 1.9 and 1.6 mm (seeds 1, 2; honest sigmas
//! of 0.29-0.33 mm), with 300 kN 6.2 mm (seed 1). The dynamic plant gives 2.6-3.0 mm on seeds 1-5
//! with sigmas of 0.47-0.55 mm: about 1 mm more, from the swing (a load cell's reading is up to
//! a polling round old while the swing changes the stretch). [`STRETCH_BOUND_M`] is 5 mm, under
//! twice the largest measured; 1 mm on this plant needs the stretch modelled (open, docs/testing.md).

use taut_simrig::SimOptions;

/// The phases' reel on the dynamic plant, m.
pub const DYNAMIC_REEL_M: f64 = -0.5;

/// The bound on the worst anchor error the unmodelled stretch allows (module doc), m.
const STRETCH_BOUND_M: f64 = 5e-3;

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
    eprintln!(
        "RESULT seed {seed} dynamic: worst anchor error {:.3} mm, worst anchor sigma {:.3} mm, errors {:?} mm; {:.1} s simulated in {:.1} s; note {}",
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
        if worst > STRETCH_BOUND_M {
            failures.push(format!("seed {seed}: worst anchor error {:.2} mm", worst * 1e3));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
