//! Drum build-up concealed in the simulator's recording (its drums' radius shrinks as
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

/// Build-up beside per-cable drum scales (1.003 / 0.998 / 1.002 / 0.999) on the 4-cable robot,
/// seeds 1-4: build-up is named; where the scale is named too both trade off (correlation +1.00,
/// "weakly observable"), where it is not (seed 3) the build-up's evidence says the two trade off
/// and the joint fit with the scale is reported; jointly with the scale every cable's `q` is
/// within 3 sigma of the truth. Prints each seed's values against the truth. Measured: q within
/// 2.2 sigma on seeds 1, 2, 4; on seed 3 the build-up alone is 17-117 sigma off (it carries the
/// scales), jointly with the scale within 1.0 sigma.
/// `cargo test --release -p taut-tests --test offline buildup_beside -- --ignored --nocapture`.
#[test]
#[ignore]
fn drum_buildup_beside_drum_scale_reports_the_trade_off() {
    for seed in 1..=4 {
        let mut s = Scenario::aras_cam(seed);
        s.physics =
            Physics { drum_buildup_m_per_turn: Some(PER_TURN_M), scale: Some(vec![1.003, 0.998, 1.002, 0.999]), ..Physics::default() };
        s.duration_s = 40.0;
        let q = s.physics.drum().expect("build-up on").quadratic_per_m();
        let sim = simulate_next_seed(&mut s);
        let opts = DiagnoseOptions::from_config(&s.robot.calibration);
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let f = d.effects.iter().find(|f| f.effect == Effect::DrumBuildup).unwrap_or_else(|| panic!("seed {seed}: {:?}", d.effects));
        let with_scale = f.joint.iter().find(|j| j.with == Some(Effect::Scale)).expect("fitted jointly with the scale");
        let z: Vec<String> = f.values.iter().zip(&f.sigmas).map(|(v, s)| format!("{:.1}", (v - q) / s)).collect();
        let zj: Vec<String> = with_scale.values.iter().zip(&with_scale.sigmas).map(|(v, s)| format!("{:.1}", (v - q) / s)).collect();
        println!(
            "seed {seed}: scale named {}, correlation {:+.2}, q in sigmas {z:?}, jointly with the scale {zj:?}",
            with_scale.both_named, with_scale.correlation
        );
        assert!(with_scale.correlation.abs() > 0.9, "seed {seed}");
        for (j, (v, sg)) in with_scale.values.iter().zip(&with_scale.sigmas).enumerate() {
            assert!((v - q).abs() <= 3.0 * sg, "seed {seed} cable {j}: jointly with the scale q {v} ± {sg} vs {q}");
        }
        assert!(f.evidence.contains("readings over a wider range of cable lengths separate them"), "seed {seed}: {}", f.evidence);
    }
}
