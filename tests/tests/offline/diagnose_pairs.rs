//! Effects under effects: concealed pairs and triples on the 3-cable, 4-cable and 20 m
//! outdoor robots, diagnosed from simulated recordings (the simulator's physics is independent of
//! the diagnosis models). Each effect must be named by the held-out test, small effects under
//! large ones included, and where two effects trade off the reported uncertainty must cover the
//! truth.

use taut_calib::diagnose::{diagnose, Decision, DiagnoseOptions, Diagnosis, Effect, Finding};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

/// Simulates (the next seed where one cannot be: [`simulate_next_seed`]) and diagnoses `s`.
fn run(mut s: Scenario, duration_s: f64) -> Diagnosis {
    s.duration_s = duration_s;
    let sim = simulate_next_seed(&mut s);
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis")
}

fn named(d: &Diagnosis) -> Vec<Effect> {
    d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect()
}

fn summary(d: &Diagnosis) -> Vec<String> {
    let mut v: Vec<String> = d.effects.iter().map(|f| format!("{}: {}", f.effect.name(), f.evidence)).collect();
    v.extend(d.tests.iter().map(|t| {
        format!(
            "round {} {}: {} -> {:?} {:?}",
            t.round,
            t.effect.name(),
            t.test.map_or("-".into(), |x| x.to_string()),
            t.decision,
            t.values
        )
    }));
    v.extend(d.notes.iter().cloned());
    v.push(format!("baseline {:.3} mm held out {:.3} mm", d.baseline.rms_m * 1e3, d.baseline.heldout_rms_m * 1e3));
    v.push(format!("final {:.3} mm held out {:.3} mm", d.final_fit.rms_m * 1e3, d.final_fit.heldout_rms_m * 1e3));
    v
}

fn finding(d: &Diagnosis, e: Effect) -> &Finding {
    d.effects.iter().find(|f| f.effect == e).unwrap_or_else(|| panic!("{} not named: {:#?}", e.name(), summary(d)))
}

/// |estimate - truth| within `k` reported sigmas, or within `rel` of the truth (the simulator's
/// physics is independent of the diagnosis models, so a small model difference remains).
fn assert_recovered(name: &str, est: f64, sigma: f64, truth: f64, k: f64, rel: f64) {
    let err = (est - truth).abs();
    assert!(
        err <= k * sigma || err <= rel * truth.abs(),
        "{name}: estimate {est} ± {sigma} vs truth {truth} (error {err}, {:.1} sigma)",
        err / sigma
    );
}

/// Issue 14: a 5.3 cm swivel pulley on the 4-cable robot. The ideal model with shifted anchors
/// absorbs most of it (its held-out RMS is within a few percent of the noise), but the held-out
/// test still separates them: the pulley is named, not reported as "fits equally well".
#[test]
fn swivel_pulley_of_5_3_cm_is_named() {
    for seed in [21, 31] {
        let mut s = Scenario::aras_cam(seed);
        s.physics = Physics { pulley: Some(0.053), ..Physics::default() };
        let d = run(s, 40.0);
        assert_eq!(named(&d).first(), Some(&Effect::Pulley), "seed {seed}: {:#?}", summary(&d));
        let f = finding(&d, Effect::Pulley);
        assert_recovered("radius_m", f.values[0], f.sigmas[0], 0.053, 4.0, 0.15);
        assert!(f.test.is_some_and(|t| t.p_value < d.tests[0].alpha), "{:?}", f.test);
        assert!(!d.notes.iter().any(|n| n.contains("equally well")), "seed {seed}: {:#?}", d.notes);
        // The pulley mimics a shifted anchor: the correlation is reported.
        assert!(f.joint.iter().any(|j| j.with.is_none() && j.correlation.abs() > 0.5), "{:#?}", f.joint);
        // Above 0.9 the radius is weakly observable: the evidence says so and names the
        // measurement that would fix it (and says nothing of the kind below).
        let weak = f.joint.iter().any(|j| j.with.is_none() && j.correlation.abs() > 0.9);
        assert_eq!(f.evidence.contains("weakly observable") && f.evidence.contains("wrap angles"), weak, "seed {seed}: {}", f.evidence);
        println!("seed {seed}: {}", f.evidence);
    }
}

/// Issue 14: elasticity (EA 19,000 N) under a 30 ms time offset on the 4-cable robot: the
/// large effect is named first, the small one on top of it.
#[test]
fn elasticity_under_a_time_offset_both_named() {
    for seed in [22, 32] {
        let mut s = Scenario::aras_cam(seed);
        s.physics = Physics { elasticity: Some(19_000.0), time_offset_s: 0.03, ..Physics::default() };
        let dt = 1.0 / s.rate_hz;
        let d = run(s, 40.0);
        let n = named(&d);
        assert!(n.contains(&Effect::TimeOffset) && n.contains(&Effect::Elasticity), "seed {seed}: {:#?}", summary(&d));
        let f = finding(&d, Effect::Elasticity);
        for (v, sg) in f.values.iter().zip(&f.sigmas) {
            assert_recovered("EA", *v, *sg, 19_000.0, 4.0, 0.1);
        }
        // The interpolated noisy tracker pulls the offset toward a half sample (see
        // diagnose_concealed.rs): within half a sample interval.
        let f = finding(&d, Effect::TimeOffset);
        assert_recovered("offset_s", f.values[0], f.sigmas[0], 0.03, 4.0, 0.5 * dt / 0.03);
    }
}

/// Issue 14: sag (0.33 N/m) and elasticity (EA 500 kN) on the 20 m outdoor robot, with the
/// diagnosis told the controller's 50 N floor. Both named; the sag weight, fitted jointly with
/// EA, lies within 3 of its reported (joint, correlation-inflated) sigmas of the truth.
#[test]
fn sag_and_elasticity_on_the_outdoor_robot() {
    for seed in [23, 33] {
        let mut s = Scenario::outdoor(seed);
        s.physics = Physics { sag: Some(0.33), elasticity: Some(5e5), ..Physics::default() };
        s.robot.calibration.min_tension_n = 50.0;
        let d = run(s, 60.0);
        let n = named(&d);
        assert!(n.contains(&Effect::Sag) && n.contains(&Effect::Elasticity), "seed {seed}: {:#?}", summary(&d));
        let f = finding(&d, Effect::Sag);
        assert_recovered("weight_per_length", f.values[0], f.sigmas[0], 0.33, 3.0, 0.0);
        assert!(f.joint.iter().any(|j| j.with == Some(Effect::Elasticity) && j.both_named), "{:#?}", f.joint);
        let f = finding(&d, Effect::Elasticity);
        for (v, sg) in f.values.iter().zip(&f.sigmas) {
            assert_recovered("EA", *v, *sg, 5e5, 4.0, 0.05);
        }
    }
}

/// A triple on the 3-cable robot: a 20 ms time offset, 6 mm backlash and EA 20,000 N.
#[test]
fn time_offset_backlash_and_elasticity_on_three_cables() {
    let mut s = Scenario::three_cable(42);
    s.physics = Physics { elasticity: Some(20_000.0), backlash_m: 0.006, time_offset_s: 0.02, ..Physics::default() };
    let d = run(s, 40.0);
    let mut n = named(&d);
    n.sort();
    assert_eq!(n, vec![Effect::Elasticity, Effect::TimeOffset, Effect::Backlash], "{:#?}", summary(&d));
    let f = finding(&d, Effect::Backlash);
    for (v, sg) in f.values.iter().zip(&f.sigmas) {
        assert_recovered("width_m", *v, *sg, 0.006, 4.0, 0.15);
    }
}

/// Small EA (15,000 N) under large backlash (10 mm) on the 4-cable robot: both named, and every
/// cable's EA within 4 sigma or 10 % on both seeds. (Seed 46 once gave 8,983 ± 885 N, 6.8 sigma
/// low, on one cable: a hold of seconds counted as hundreds of readings with one tracker error;
/// the estimates now come from the hold-weighted fit, `PlayState::hold_weights`: -1.1 .. +1.2
/// sigma. The seeds are fixed, so the outcome is deterministic.)
#[test]
fn small_elasticity_under_large_backlash() {
    for seed in [45, 46] {
        let mut s = Scenario::aras_cam(seed);
        s.physics = Physics { elasticity: Some(15_000.0), backlash_m: 0.01, ..Physics::default() };
        let d = run(s, 40.0);
        let n = named(&d);
        assert!(n.contains(&Effect::Backlash) && n.contains(&Effect::Elasticity), "seed {seed}: {:#?}", summary(&d));
        let f = finding(&d, Effect::Elasticity);
        for (v, sg) in f.values.iter().zip(&f.sigmas) {
            assert_recovered("EA", *v, *sg, 15_000.0, 4.0, 0.1);
        }
    }
}

/// A triple on the outdoor robot: sag, elasticity and a drum scale error.
#[test]
fn sag_elasticity_and_scale_on_the_outdoor_robot() {
    let mut s = Scenario::outdoor(47);
    s.physics = Physics { sag: Some(0.33), elasticity: Some(5e5), scale: Some(vec![1.003, 0.997, 1.002, 0.998]), ..Physics::default() };
    s.robot.calibration.min_tension_n = 50.0;
    let d = run(s, 60.0);
    let mut n = named(&d);
    n.sort();
    assert_eq!(n, vec![Effect::Elasticity, Effect::Sag, Effect::Scale], "{:#?}", summary(&d));
}

/// Issue 14: a time offset that only stood in for a play is dropped once the play is named (the
/// backward step). A 3 mm play alone on the 3-cable robot (seed 102, simulated as 10102): round 1
/// names a time offset (4.7 ms: it absorbs part of the play), round 2 names the play, and the
/// removal test of the offset on top of the play is far from significant (p = 0.77 measured), so
/// it is dropped, the report says so, and the play alone remains. Forward-only selection (before
/// the backward step) kept the offset (`offset_backlash_coverage -- 100 24 0 3 3 0`: 7 of 24).
/// The seed is fixed, so the outcome is deterministic.
///
/// With drum build-up in the library (issue 26) round 2 names a build-up (p = 3.4e-6 at the level
/// 4.8e-6, `q` 1e-5 .. 1e-4 /m: it too takes up part of the play's misfit) and round 3 the play,
/// which drops both the offset (p = 0.94) and the build-up (p = 0.94): the play alone remains.
/// With compliance in the library too each test runs at 4.2e-6: the offset's round-1 p (4.5e-6)
/// no longer passes, the build-up is named in round 1, the offset in round 2 (p = 2.4e-6) and the
/// play in round 3, which drops both (p = 0.94 each): the play alone remains.
#[test]
fn a_time_offset_standing_in_for_a_play_is_dropped() {
    let s = taut_tests::sim::offset_backlash_scenario(102, 3, 0, 0.003, 0.0, false);
    let d = run(s, 40.0);
    let offset = d
        .tests
        .iter()
        .find(|t| t.effect == Effect::TimeOffset && t.decision == Decision::Named)
        .unwrap_or_else(|| panic!("time offset not named: {:#?}", summary(&d)));
    let play = d
        .tests
        .iter()
        .find(|t| t.effect == Effect::Backlash && t.decision == Decision::Named)
        .unwrap_or_else(|| panic!("play not named: {:#?}", summary(&d)));
    let drop = d
        .tests
        .iter()
        .find(|t| t.effect == Effect::TimeOffset && t.decision == Decision::Dropped)
        .unwrap_or_else(|| panic!("time offset not dropped: {:#?}", summary(&d)));
    assert!(offset.round < play.round, "the offset is named before the play: {:#?}", summary(&d));
    assert_eq!(drop.round, play.round, "dropped once the play is named: {:#?}", summary(&d));
    assert!(drop.test.is_some_and(|t| t.p_value >= drop.alpha), "{:#?}", summary(&d));
    assert_eq!(named(&d), vec![Effect::Backlash], "{:#?}", summary(&d));
    let note = format!("time-offset (named in round {}) was dropped in round {}", offset.round, play.round);
    assert!(d.notes.iter().any(|n| n.starts_with(&note)), "{:#?}", d.notes);
    assert!(finding(&d, Effect::Backlash).evidence.contains("dropped"), "{:#?}", summary(&d));
}

/// Issue 14: a play alone is named alone. Its selection fits use the rows that read clear pushes
/// (`play_prep`); fitted on every row, holds included, the misread push ends and the holds pinned
/// to one tracker error left a misfit another candidate took up: on these recordings a drum
/// scale at its null value, named in round 2 (3-cable robot, 6 mm play, seed 106: p = 4.6e-11;
/// 4-cable robot, seed 113: p = 1.0e-6), and on 6 of 24 / 4 of 24 / 11 of 50 recordings of the
/// coverage sets (BENCHMARKS.md, "playclear"). The seeds are fixed, so the outcome is
/// deterministic; for a correct diagnosis the chance of failing here is about 2e-4 (the family
/// rate of a claim, 1e-4 per recording nominal, and seven play widths each within 4.5 sigma,
/// 6.8e-6 each).
#[test]
fn a_play_alone_names_nothing_else() {
    for (seed, cables) in [(106, 3), (113, 4)] {
        let s = taut_tests::sim::offset_backlash_scenario(seed, cables, 0, 0.006, 0.0, false);
        let d = run(s, 40.0);
        assert_eq!(named(&d), vec![Effect::Backlash], "seed {seed}, {cables} cables: {:#?}", summary(&d));
        for (v, sg) in finding(&d, Effect::Backlash).values.iter().zip(&finding(&d, Effect::Backlash).sigmas) {
            assert_recovered("play", *v, *sg, 0.006, 4.5, 0.0);
        }
    }
}

/// Issue 14: a triple on the 4-cable robot: EA 25 kN under drum scale errors and a 40 ms time
/// offset. On seed 1 cable 0's encoder readings are data problems from 30 ms after a usable
/// held-out row on, so a time offset of ~40 ms read no encoder sample for that row: its
/// prediction was NaN, the time offset's held-out test was left out ("too few held-out samples
/// to test") and nothing was named, at 16 mm held out. Now such a row reads the segment's
/// nearest reading (`Joint::nearest_reading`) and all three are named, down to the noise. The
/// seed is fixed, so the outcome is deterministic.
#[test]
fn elasticity_scale_and_a_time_offset_next_to_encoder_data_problems() {
    let mut s = Scenario::aras_cam(1);
    s.physics =
        Physics { elasticity: Some(25_000.0), scale: Some(vec![1.003, 0.997, 1.002, 0.998]), time_offset_s: 0.04, ..Physics::default() };
    let dt = 1.0 / s.rate_hz;
    let noise = (s.robot.calibration.tracker_sigma_m.powi(2) + s.robot.calibration.encoder_sigma_m.powi(2)).sqrt();
    let d = run(s, 40.0);
    let mut n = named(&d);
    n.sort();
    assert_eq!(n, vec![Effect::Elasticity, Effect::Scale, Effect::TimeOffset], "{:#?}", summary(&d));
    for (v, sg) in finding(&d, Effect::Elasticity).values.iter().zip(&finding(&d, Effect::Elasticity).sigmas) {
        assert_recovered("EA", *v, *sg, 25_000.0, 4.0, 0.1);
    }
    for ((v, sg), truth) in
        finding(&d, Effect::Scale).values.iter().zip(&finding(&d, Effect::Scale).sigmas).zip([1.003, 0.997, 1.002, 0.998])
    {
        assert_recovered("scale", *v, *sg, truth, 4.0, 0.0);
    }
    let f = finding(&d, Effect::TimeOffset);
    assert_recovered("offset_s", f.values[0], f.sigmas[0], 0.04, 4.0, 0.5 * dt / 0.04);
    assert!(d.final_fit.heldout_rms_m < 1.1 * noise, "{:#?}", summary(&d));
}
