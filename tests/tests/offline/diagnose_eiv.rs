//! Errors-in-variables in the diagnosis: stretch and sag predicted from noisy
//! tensions, near slack. The seeds are fixed, so each outcome is deterministic (the coverage
//! over many seeds is in BENCHMARKS.md: `examples/outdoor_sag_ea.rs`).

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect, Finding};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

fn run(mut s: Scenario, duration_s: f64, opts: impl Fn(&Scenario) -> DiagnoseOptions) -> Diagnosis {
    s.duration_s = duration_s;
    let sim = simulate_next_seed(&mut s);
    diagnose(&sim.recording, &sim.truth.platform_points, None, &opts(&s)).expect("diagnosis")
}

fn finding(d: &Diagnosis, e: Effect) -> &Finding {
    d.effects.iter().find(|f| f.effect == e).unwrap_or_else(|| {
        panic!("{} not named: {:#?}", e.name(), d.effects.iter().map(|f| (f.effect.name(), &f.evidence)).collect::<Vec<_>>())
    })
}

fn within(name: &str, est: f64, sigma: f64, truth: f64, k: f64) {
    assert!((est - truth).abs() <= k * sigma, "{name}: {est} ± {sigma} vs truth {truth} ({:+.1} sigma)", (est - truth) / sigma);
}

/// Sag 0.33 N/m and EA 500 kN on the 20 m outdoor robot with the diagnosis told a 10 N floor
/// (the controller's is 50 N) and the load cells' noise (0.3 N) and offsets (0.5 N): both named,
/// the sag weight within 3 and each EA within 4 of their sigmas, which include the load-cell
/// offsets (the sag weight moves about 1 % per 0.5 N: its statistical sigma alone is ~0.15 %).
#[test]
fn sag_and_elasticity_below_the_tension_floor_with_errors_in_variables() {
    for seed in [23, 33] {
        let mut s = Scenario::outdoor(seed);
        s.physics = Physics { sag: Some(0.33), elasticity: Some(5e5), ..Physics::default() };
        s.robot.calibration.min_tension_n = 10.0;
        let d = run(s, 60.0, |s| {
            let mut o = DiagnoseOptions::from_config(&s.robot.calibration);
            o.loadcell_sigma_n = s.noise.loadcell_sigma_n;
            o.loadcell_offset_n = s.noise.loadcell_offset_n;
            o
        });
        let f = finding(&d, Effect::Sag);
        within("weight_per_length", f.values[0], f.sigmas[0], 0.33, 3.0);
        // The offsets dominate the sag's uncertainty: it says so by its size.
        assert!(f.sigmas[0] > 0.002, "seed {seed}: sag sigma {}", f.sigmas[0]);
        let f = finding(&d, Effect::Elasticity);
        for (v, sg) in f.values.iter().zip(&f.sigmas) {
            within("EA", *v, *sg, 5e5, 4.0);
        }
        let extra: Vec<_> =
            d.effects.iter().filter(|f| !matches!(f.effect, Effect::Slack | Effect::Sag | Effect::Elasticity)).map(|f| f.effect).collect();
        assert!(extra.is_empty(), "seed {seed}: {extra:?}");
    }
}
