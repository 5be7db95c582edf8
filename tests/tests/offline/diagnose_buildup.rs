//! Issue 26: drum build-up concealed in the simulator's recording (its drums' radius shrinks as
//! they pay out; the simulator's physics is its own, `taut_sim::sensors::Drum`) is named as drum
//! build-up, not as the sag or the drum scale it can resemble, with each cable's coefficient
//! within three of its reported sigmas of the truth.
//!
//! Measured (release, `concealed_probe aras 1 4 buildup=-5e-6`): named alone on seeds 1-4, held
//! out 3.2-5.9 -> 1.50-1.54 mm, every cable's `q` within 1.4 sigma of the truth -6.37e-4 /m.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

/// A 25 mm drum losing 5 um of radius each turn paid out: `q = -6.37e-4` /m, 3-6 mm held out.
const PER_TURN_M: f64 = -5e-6;

fn run(seed: u64) -> (Diagnosis, f64) {
    let mut s = Scenario::aras_cam(seed);
    s.physics = Physics { drum_buildup_m_per_turn: Some(PER_TURN_M), ..Physics::default() };
    s.duration_s = 40.0;
    let q = s.physics.drum().expect("build-up on").quadratic_per_m();
    let sim = simulate_next_seed(&mut s);
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    (diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis"), q)
}

fn check(seed: u64) {
    let (d, q) = run(seed);
    let named: Vec<Effect> = d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect();
    let tests: Vec<String> = d.tests.iter().map(|t| format!("round {} {}: {:?}", t.round, t.effect.name(), t.decision)).collect();
    assert_eq!(named, vec![Effect::DrumBuildup], "seed {seed}: {tests:#?}");
    let f = d.effects.iter().find(|f| f.effect == Effect::DrumBuildup).expect("named");
    for (j, (v, s)) in f.values.iter().zip(&f.sigmas).enumerate() {
        assert!((v - q).abs() <= 3.0 * s, "seed {seed} cable {j}: q {v} ± {s} vs truth {q} ({:.1} sigma)", (v - q).abs() / s);
    }
    assert!(d.final_fit.heldout_rms_m < 0.6 * d.baseline.heldout_rms_m, "seed {seed}: {:?} -> {:?}", d.baseline, d.final_fit);
}

#[test]
fn drum_buildup_is_named_not_sag_or_scale() {
    for seed in [1, 2] {
        check(seed);
    }
}

/// More seeds (about 1 s each in release):
/// `cargo test --release -p taut-tests --test offline diagnose_buildup -- --ignored`.
#[test]
#[ignore]
fn drum_buildup_is_named_on_ten_seeds() {
    for seed in 3..=12 {
        check(seed);
    }
}
