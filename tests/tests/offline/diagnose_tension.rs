//! The tension side of the diagnosis (issue 26, item 2) on the simulated 4-cable robot, 60 s at
//! 100 Hz: the load cells against the platform's weight and inertia along the fitted geometry.
//! The simulator's tensions balance `m (a - g)` on every recording (its physics, written apart
//! from calib), so inertia is a true effect everywhere: it is named once the accelerations
//! carry it (slow motion too: `m a` of 0.15 N against 0.3 N cells over a minute), and never
//! counts as a false claim; a gain or a friction the recording does not have does.
//!
//! Measured over many seeds (`tension_coverage`, BENCHMARKS.md "Diagnosis: the tension side").

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect, TensionEffect};
use taut_tests::sim::{simulate_next_seed, tension_scenario, TensionCase, TENSION_FRICTION, TENSION_GAINS};

fn run(seed: u64, case: TensionCase) -> (Diagnosis, f64) {
    let mut s = tension_scenario(seed, case);
    let sim = simulate_next_seed(&mut s);
    let mass = s.robot.robot.mass_kg;
    let opts = DiagnoseOptions {
        platform_mass_kg: Some(mass),
        loadcell_sigma_n: s.noise.loadcell_sigma_n,
        ..DiagnoseOptions::from_config(&s.robot.calibration)
    };
    (diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis"), mass)
}

/// The tension effects named, and the length effects (slack aside).
fn named(d: &Diagnosis) -> (Vec<TensionEffect>, Vec<Effect>) {
    let t = d.tension.as_ref().expect("the tension side ran");
    (t.effects.iter().map(|f| f.effect).collect(), d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect())
}

/// Every value of `e` within 3 of its sigmas of `truth`.
fn within_3_sigma(d: &Diagnosis, e: TensionEffect, truth: &[f64], seed: u64) {
    let f = d.tension.as_ref().unwrap().effects.iter().find(|f| f.effect == e).unwrap_or_else(|| panic!("seed {seed}: {e:?} not named"));
    for (j, ((v, s), t)) in f.values.iter().zip(&f.sigmas).zip(truth).enumerate() {
        assert!((v - t).abs() <= 3.0 * s, "seed {seed} {e:?} [{j}]: {v} ± {s} vs truth {t} ({:.1} sigma)", (v - t).abs() / s);
    }
}

fn tests_of(d: &Diagnosis) -> Vec<String> {
    d.tension.as_ref().map_or(vec![], |t| {
        t.tests.iter().map(|x| format!("round {} {}: {:?} {:?}", x.round, x.effect.name(), x.decision, x.test.map(|t| t.p_value))).collect()
    })
}

#[test]
fn loadcell_gains_are_named_with_each_gain_within_three_sigma() {
    for seed in [1, 2] {
        let (d, mass) = run(seed, TensionCase::Gain);
        let (t, l) = named(&d);
        assert!(t.contains(&TensionEffect::LoadcellGain) && !t.contains(&TensionEffect::Friction), "seed {seed}: {:#?}", tests_of(&d));
        assert!(l.is_empty(), "seed {seed}: length effects {l:?}");
        within_3_sigma(&d, TensionEffect::LoadcellGain, &TENSION_GAINS, seed);
        if t.contains(&TensionEffect::Inertia) {
            within_3_sigma(&d, TensionEffect::Inertia, &[mass], seed);
        }
    }
}

#[test]
fn friction_is_named_with_each_coefficient_within_three_sigma() {
    for seed in [2, 3] {
        let (d, _) = run(seed, TensionCase::Friction);
        let (t, l) = named(&d);
        assert!(t.contains(&TensionEffect::Friction) && !t.contains(&TensionEffect::LoadcellGain), "seed {seed}: {:#?}", tests_of(&d));
        assert!(l.is_empty(), "seed {seed}: length effects {l:?}");
        within_3_sigma(&d, TensionEffect::Friction, &[TENSION_FRICTION; 4], seed);
        // The leads point at the direction of motion.
        let lead = &d.tension.as_ref().unwrap().leads[0];
        assert_eq!(lead.follows, taut_calib::diagnose::tension::LeadKind::Direction, "seed {seed}: {lead:?}");
    }
}

/// Fast excursions (2.5-4.5 m/s^2) with no effect but the platform's inertia: the tension side
/// names inertia with the platform's mass, and the length side names nothing.
#[test]
fn inertia_alone_is_named_inertia_and_not_a_length_effect() {
    for seed in [1, 2] {
        let (d, mass) = run(seed, TensionCase::Fast);
        let (t, l) = named(&d);
        assert_eq!(t, vec![TensionEffect::Inertia], "seed {seed}: {:#?}", tests_of(&d));
        assert!(l.is_empty(), "seed {seed}: length effects {l:?}");
        within_3_sigma(&d, TensionEffect::Inertia, &[mass], seed);
    }
}

/// Cells with their offsets only: no gain, no friction, no length effect.
#[test]
fn effect_free_cells_name_no_gain_and_no_friction() {
    for seed in [3, 4] {
        let (d, mass) = run(seed, TensionCase::Free);
        let (t, l) = named(&d);
        assert!(t.iter().all(|e| *e == TensionEffect::Inertia), "seed {seed}: {:#?}", tests_of(&d));
        assert!(l.is_empty(), "seed {seed}: length effects {l:?}");
        if !t.is_empty() {
            within_3_sigma(&d, TensionEffect::Inertia, &[mass], seed);
        }
    }
}

/// Friction with a 20 ms encoder time offset: the length side names the offset, the tension
/// side the friction (the tensions are on the tracker's clock; a lag of the cells would be a
/// third thing, see docs/diagnosis.md).
#[test]
fn friction_beside_a_time_offset_names_both_on_their_sides() {
    let seed = 2;
    let (d, _) = run(seed, TensionCase::FrictionOffset);
    let (t, l) = named(&d);
    assert_eq!(
        l,
        vec![Effect::TimeOffset],
        "seed {seed}: {:?}",
        d.tests.iter().map(|x| (x.round, x.effect, x.decision)).collect::<Vec<_>>()
    );
    assert!(t.contains(&TensionEffect::Friction) && !t.contains(&TensionEffect::LoadcellGain), "seed {seed}: {:#?}", tests_of(&d));
    within_3_sigma(&d, TensionEffect::Friction, &[TENSION_FRICTION; 4], seed);
}

/// Without a platform mass the tension side does not run and the tests' level is the length
/// library's alone (the length side's outputs are those of before).
#[test]
fn without_a_mass_the_tension_side_does_not_run() {
    let mut s = tension_scenario(5, TensionCase::Gain);
    s.duration_s = 20.0;
    let sim = simulate_next_seed(&mut s);
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
    assert!(d.tension.is_none());
    assert_eq!(opts.test_alpha(), opts.family_alpha / (Effect::FITTED.len() * opts.max_effects) as f64);
    let with = DiagnoseOptions { platform_mass_kg: Some(3.0), ..opts.clone() };
    assert_eq!(with.test_alpha(), opts.family_alpha / ((Effect::FITTED.len() + TensionEffect::ALL.len()) * opts.max_effects) as f64);
}

/// `taut diagnose --out`: the named gains and friction go into the parameter file as
/// `loadcell_gain` and `friction_mu_theta` with their sigmas (inertia stays out, with a
/// note), read back and into the loop's tension correction.
#[test]
fn named_gains_and_friction_travel_in_the_parameter_file_to_the_loop() {
    use taut_config::params::ParamsFile;
    use taut_io::EffectsFromFile;
    use taut_rt::kin::LoopEffects;
    for (case, e) in [(TensionCase::Gain, TensionEffect::LoadcellGain), (TensionCase::Friction, TensionEffect::Friction)] {
        let (d, _) = run(1, case);
        let f = d.tension.as_ref().unwrap().effects.iter().find(|f| f.effect == e).expect("named").clone();
        let (effects, notes) = taut_calib::effect_fit::effects_of(&d);
        let (values, sigmas) = match e {
            TensionEffect::LoadcellGain => (&effects.loadcell_gain, &effects.loadcell_gain_sigma),
            _ => (&effects.friction_mu_theta, &effects.friction_mu_theta_sigma),
        };
        assert_eq!((values.as_ref(), sigmas.as_ref()), (Some(&f.values), Some(&f.sigmas)), "{e:?}");
        let named_inertia = d.tension.as_ref().unwrap().effects.iter().any(|f| f.effect == TensionEffect::Inertia);
        assert_eq!(notes.iter().any(|n| n.starts_with("inertia not written")), named_inertia, "{notes:?}");
        let fin = &d.final_fit;
        let file = ParamsFile { version: 1, effects, ..ParamsFile::from_geometry(&fin.params, &fin.sigma) };
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.toml");
        file.save_atomic(&p).unwrap();
        let back = ParamsFile::load(&p).unwrap();
        assert_eq!(back.effects, file.effects);
        let l = LoopEffects::from_file(&back.effects);
        for (j, v) in f.values.iter().enumerate() {
            let got = if e == TensionEffect::LoadcellGain { l.cell_gain[j] } else { l.friction_mu_theta[j] };
            assert_eq!(got, *v, "{e:?} cable {j}");
        }
        assert!(l.corrects_tensions());
    }
}
