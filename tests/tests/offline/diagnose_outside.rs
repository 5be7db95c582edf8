//! Effects the library does not have are not forced onto the nearest one it knows: an eccentric
//! drum (the simulator's `drum_eccentricity_m`, periodic in the paid-out length) is named as
//! structure outside the library that is periodic in the cable's length at the drum's
//! circumference, and no library effect is named for it, not even the build-up that removes a
//! few per cent of it (withdrawn). A length error that follows the platform's height is
//! reported as structure that follows the platform's position, and the drum scales that took up
//! most of it are withdrawn once the structure is fitted beside them; a stretch beside an
//! eccentric drum is still named.
//!
//! Sweeps: `cargo run --release -p taut-tests --example outside_library -- aras 1 50 ecc=0.001`
//! (figures in BENCHMARKS.md, "Effects outside the library").

use taut_calib::diagnose::{diagnose, Decision, DiagnoseOptions, Diagnosis, Effect};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

fn run(seed: u64, physics: Physics) -> Diagnosis {
    let mut s = Scenario::aras_cam(seed);
    s.physics = physics;
    s.duration_s = 40.0;
    let sim = simulate_next_seed(&mut s);
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis")
}

fn named(d: &Diagnosis) -> Vec<Effect> {
    d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect()
}

#[test]
fn an_eccentric_drum_is_reported_as_periodic_structure_not_as_a_library_effect() {
    let circumference_mm = std::f64::consts::TAU * taut_sim::physics::DRUM_RADIUS_M * 1e3;
    let d = run(1, Physics { drum_eccentricity_m: Some(1e-3), ..Physics::default() });
    assert!(named(&d).is_empty(), "named {:?}; rejected {:#?}", named(&d), d.rejected);
    let u = d.unexplained.as_deref().expect("structure reported");
    assert!(u.contains("periodic in the cable's length"), "{u}");
    let at = u.find("wavelength ").expect("wavelengths") + "wavelength ".len();
    let list = &u[at..u[at..].find(" mm").expect("unit") + at];
    for w in list.split(", ") {
        let w: f64 = w.parse().expect("a wavelength");
        assert!((w - circumference_mm).abs() < 0.05 * circumference_mm, "wavelength {w} mm in {u}");
    }
    // The build-up removes a few per cent of the held-out sum of squares: withdrawn.
    assert!(
        d.tests.iter().any(|t| t.decision == Decision::Withdrawn),
        "{:#?}",
        d.tests.iter().map(|t| format!("{} {:?}", t.effect.name(), t.decision)).collect::<Vec<_>>()
    );
}

#[test]
fn a_length_error_that_follows_the_height_is_reported_with_what_it_follows() {
    let d = run(3, Physics { height_error_per_m: Some(3e-3), ..Physics::default() });
    let u = d.unexplained.as_deref().unwrap_or_else(|| panic!("no structure reported; named {:?}", named(&d)));
    assert!(u.contains("follows the platform's height") || u.contains("follows the platform's position"), "{u}");
    // Drum scales take up most of it; with the structure fitted beside them they explain
    // nothing it does not: withdrawn.
    assert!(named(&d).is_empty(), "named {:?}", named(&d));
    assert!(d.rejected.iter().any(|r| r.contains("no longer explain")), "{:#?}", d.rejected);
}

/// A library effect beside one outside the library is still named: with the periodic structure
/// fitted beside it, a stretch explains held-out data the structure does not.
#[test]
fn a_stretch_beside_an_eccentric_drum_is_still_named() {
    let d = run(2, Physics { drum_eccentricity_m: Some(1e-3), elasticity: Some(20_000.0), ..Physics::default() });
    assert!(named(&d).contains(&Effect::Elasticity), "named {:?}; rejected {:#?}", named(&d), d.rejected);
    let u = d.unexplained.as_deref().expect("structure reported");
    assert!(u.contains("periodic in the cable's length"), "{u}");
    assert!(d.notes.iter().any(|n| n.contains("beside the structure outside the library")), "{:#?}", d.notes);
}

#[test]
fn an_effect_free_recording_reports_no_structure() {
    let d = run(1, Physics::default());
    assert!(named(&d).is_empty() && d.unexplained.is_none(), "{:?} {:?}", named(&d), d.unexplained);
}
