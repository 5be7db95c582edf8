//! The tension side of the diagnosis on the simulated 4-cable robot over many seeds: how often
//! each concealed tension effect (load-cell gains, guide friction, inertia on fast recordings,
//! friction beside a time offset) is named, what else is named, and the 1/2/3-sigma coverage of
//! the parameters.
//!
//! `cargo run --release -p taut-tests --example tension_coverage -- CASE FIRST_SEED COUNT`
//! (CASE: free, gain, friction, friction-offset, fast; `-v` after them prints every recording;
//! `TENSION_ROBOT=three-cable` or `outdoor` for those robots instead of the 4-cable one).

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect, TensionEffect};
use taut_sim::Scenario;
use taut_tests::sim::{simulate_next_seed, tension_scenario_for, TensionCase, TENSION_FRICTION, TENSION_GAINS};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let case = match args.first().map(String::as_str).unwrap_or("gain") {
        "free" => TensionCase::Free,
        "gain" => TensionCase::Gain,
        "friction" => TensionCase::Friction,
        "friction-offset" => TensionCase::FrictionOffset,
        "fast" => TensionCase::Fast,
        other => panic!("unknown case {other}: free, gain, friction, friction-offset, fast"),
    };
    let first: u64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let count: u64 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let verbose = args.iter().any(|a| a == "-v");
    let robot = std::env::var("TENSION_ROBOT").unwrap_or_else(|_| "aras-cam".into());
    let base = |seed: u64| match robot.as_str() {
        "three-cable" => Scenario::three_cable(seed),
        "outdoor" => Scenario::outdoor(seed),
        _ => Scenario::aras_cam(seed),
    };
    let truth_of = |e: TensionEffect, mass: f64, n: usize| -> Vec<f64> {
        match e {
            TensionEffect::LoadcellGain => (0..n).map(|j| TENSION_GAINS[j % 4]).collect(),
            TensionEffect::Friction => vec![TENSION_FRICTION; n],
            TensionEffect::Inertia => vec![mass],
        }
    };
    let expected: &[TensionEffect] = match case {
        TensionCase::Free => &[],
        TensionCase::Gain => &[TensionEffect::LoadcellGain],
        TensionCase::Friction | TensionCase::FrictionOffset => &[TensionEffect::Friction],
        TensionCase::Fast => &[TensionEffect::Inertia],
    };
    let (mut exact, mut extra_t, mut missing, mut length_claims) = (0, 0, 0, 0);
    let mut within = [0usize; 3];
    let mut values = 0usize;
    let mut min_p_free: Vec<f64> = vec![];
    let mut level = f64::NAN;
    for seed in first..first + count {
        let mut s = tension_scenario_for(base(seed), case);
        if let Ok(v) = std::env::var("TENSION_LOADCELL_SIGMA") {
            s.noise.loadcell_sigma_n = v.parse().expect("TENSION_LOADCELL_SIGMA: a number");
        }
        let sim = simulate_next_seed(&mut s);
        let mass = s.robot.robot.mass_kg;
        let opts = DiagnoseOptions {
            platform_mass_kg: Some(mass),
            loadcell_sigma_n: s.noise.loadcell_sigma_n,
            ..DiagnoseOptions::from_config(&s.robot.calibration)
        };
        let t0 = std::time::Instant::now();
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let secs = t0.elapsed().as_secs_f64();
        level = opts.test_alpha();
        let Some(td) = &d.tension else {
            println!("seed {seed}: no tension side ({:?})", d.notes);
            continue;
        };
        let named: Vec<TensionEffect> = td.effects.iter().map(|f| f.effect).collect();
        let lengths: Vec<&str> = d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).map(|e| e.name()).collect();
        let length_ok = match case {
            TensionCase::FrictionOffset => lengths == ["time-offset"],
            _ => lengths.is_empty(),
        };
        if !length_ok {
            length_claims += 1;
        }
        let has_all = expected.iter().all(|e| named.contains(e));
        // Inertia is in every simulated recording (the simulator's tensions balance m (a - g)),
        // so naming it on slow recordings is true, not a false claim.
        let extra: Vec<TensionEffect> = named.iter().copied().filter(|e| !expected.contains(e) && *e != TensionEffect::Inertia).collect();
        if !has_all {
            missing += 1;
        }
        if !extra.is_empty() {
            extra_t += 1;
        }
        if has_all && extra.is_empty() {
            exact += 1;
        }
        let mut line = vec![];
        for f in &td.effects {
            let truth = truth_of(f.effect, mass, s.robot.cables.len());
            let z: Vec<f64> = f.values.iter().zip(&f.sigmas).zip(&truth).map(|((v, s), t)| (v - t) / s).collect();
            if expected.contains(&f.effect) || f.effect == TensionEffect::Inertia {
                for zz in &z {
                    values += 1;
                    for (k, w) in within.iter_mut().enumerate() {
                        if zz.abs() <= (k + 1) as f64 {
                            *w += 1;
                        }
                    }
                }
            }
            line.push(format!(
                "{} {:?} (z {:?}, p {:.1e})",
                f.effect.name(),
                f.values.iter().map(|v| format!("{v:.4}")).collect::<Vec<_>>(),
                z.iter().map(|v| format!("{v:.1}")).collect::<Vec<_>>(),
                f.test.p_value
            ));
        }
        if std::env::var("TENSION_TESTS").is_ok() {
            for t in &td.tests {
                println!(
                    "  round {} {}: {:?} {:?} {}",
                    t.round,
                    t.effect.name(),
                    t.decision,
                    t.values,
                    t.test.map_or("-".into(), |x| x.to_string())
                );
            }
        }
        let round1: Vec<String> = td
            .tests
            .iter()
            .filter(|t| t.round == 1)
            .map(|t| format!("{} p {:.1e}", t.effect.name(), t.test.map_or(f64::NAN, |x| x.p_value)))
            .collect();
        // A gain or friction the recording does not conceal: its smallest removal-test p (a
        // claim needs it below the level in the last round).
        min_p_free.push(
            td.tests
                .iter()
                .filter(|t| !expected.contains(&t.effect) && t.effect != TensionEffect::Inertia)
                .filter_map(|t| t.test)
                .map(|t| t.p_value)
                .fold(1.0, f64::min),
        );
        if verbose {
            println!(
                "  offsets {:?} ± {:?} (truth {:?}); final anchors {:?} (truth {:?})",
                td.offsets_n.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>(),
                td.offset_sigmas_n.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>(),
                sim.truth.loadcell_offsets.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>(),
                d.final_fit.params.anchors.iter().map(|a| format!("{:.4},{:.4},{:.4}", a[0], a[1], a[2])).collect::<Vec<_>>(),
                sim.truth.anchors.iter().map(|a| format!("{:.4},{:.4},{:.4}", a[0], a[1], a[2])).collect::<Vec<_>>()
            );
            println!(
                "seed {seed} ({secs:.1} s, {} rows, held-out RMS {:.3} -> {:.3} N): tension {line:?}; length {lengths:?}; round 1 {round1:?}; leads {:?}",
                td.rows,
                td.heldout_rms_before_n,
                td.heldout_rms_after_n,
                td.leads.iter().take(3).map(|l| format!("{:?} {:?} t {:.1}", l.cable, l.follows, l.t)).collect::<Vec<_>>()
            );
        }
    }
    let pct = |k: usize| 100.0 * k as f64 / values.max(1) as f64;
    println!(
        "{case:?}, seeds {first}..{}: expected named exactly {exact} / {count}, missing {missing}, other tension effects {extra_t}, length claims off the truth {length_claims}; \
         values within 1/2/3 sigma {:.0} / {:.0} / {:.0} % of {values}; smallest removal-test p of a gain or friction not concealed {:.1e} (level {:.1e})",
        first + count - 1,
        pct(within[0]),
        pct(within[1]),
        pct(within[2]),
        min_p_free.iter().copied().fold(1.0, f64::min),
        level
    );
}
