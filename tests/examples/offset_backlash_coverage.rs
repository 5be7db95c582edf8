//! Coverage of the reported play-width (and time-offset) uncertainty when a time offset and
//! backlash are present together (issue 14): a 20 ms offset and a 6 mm play on the 3-cable robot
//! (optionally with EA 20 kN), many seeds. Prints each cable's play width, its reported sigma and
//! the error in sigmas, then the share within 1, 2 and 3 sigmas (a Gaussian gives 68 / 95 / 99.7 %).
//!
//! ```text
//! cargo run --profile test -p taut-tests --example offset_backlash_coverage -- [first seed, default 100] [seeds, default 10] [EA kN, default 0: none] [robot: 3 or 4 cables, default 3] [play mm, default 6] [offset ms, default 20]
//! ```
//!
//! Variants for finding a bias's cause (environment): `COVERAGE_TRACKER_MM=0.1` sets the
//! simulated tracker noise and the diagnosis's noise model to 0.1 mm; `COVERAGE_CLEAN=1` turns off
//! tracker outliers and dropouts; `COVERAGE_LOOSE=0` sets the loose-cable fraction; `COVERAGE_LIBRARY=time-offset,backlash` limits the candidates.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<u64>().expect("a number"));
    let first = args.next().unwrap_or(100);
    let count = args.next().unwrap_or(10);
    let ea_kn = args.next().unwrap_or(0);
    let cables = args.next().unwrap_or(3);
    let play = args.next().unwrap_or(6) as f64 * 1e-3;
    let offset = args.next().unwrap_or(20) as f64 * 1e-3;
    let (mut zw, mut zo, mut ze) = (vec![], vec![], vec![]);
    let mut spurious = 0;
    let (mut after_truth, mut alpha) = (vec![], f64::NAN);
    for seed in first..first + count {
        let mut s = if cables == 4 { Scenario::aras_cam(seed) } else { Scenario::three_cable(seed) };
        s.physics = Physics {
            elasticity: (ea_kn > 0).then_some(ea_kn as f64 * 1e3),
            backlash_m: play,
            time_offset_s: offset,
            ..Physics::default()
        };
        s.duration_s = 40.0;
        if let Ok(v) = std::env::var("COVERAGE_TRACKER_MM") {
            let sigma = v.parse::<f64>().expect("COVERAGE_TRACKER_MM: a number") * 1e-3;
            s.noise.tracker_sigma_m = sigma;
            s.robot.calibration.tracker_sigma_m = sigma;
        }
        if let Ok(v) = std::env::var("COVERAGE_LOOSE") {
            s.loose_fraction = v.parse::<f64>().expect("COVERAGE_LOOSE: a fraction");
        }
        if std::env::var("COVERAGE_CLEAN").is_ok_and(|v| v == "1") {
            s.noise.tracker_outlier_prob = 0.0;
            s.noise.tracker_dropout_prob = 0.0;
        }
        let sim = simulate_next_seed(&mut s);
        let mut opts = DiagnoseOptions::from_config(&s.robot.calibration);
        if let Ok(v) = std::env::var("COVERAGE_LIBRARY") {
            opts.library = v.split(',').map(|e| Effect::from_name(e).expect("COVERAGE_LIBRARY: effect names")).collect();
        }
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let named: Vec<&str> = d.effects.iter().filter(|f| f.effect != Effect::Slack).map(|f| f.effect.name()).collect();
        let truth_has = |e: Effect| match e {
            Effect::TimeOffset => offset > 0.0,
            Effect::Backlash => play > 0.0,
            Effect::Elasticity => ea_kn > 0,
            _ => false,
        };
        if d.effects.iter().any(|f| f.effect != Effect::Slack && !truth_has(f.effect)) {
            spurious += 1;
        }
        // The tests of candidates outside the truth once every effect of the truth is in the
        // current model (rounds after the truth's count): their p-values should be uniform.
        let in_truth = [Effect::TimeOffset, Effect::Backlash, Effect::Elasticity].into_iter().filter(|e| truth_has(*e)).count();
        let truth_named = d.effects.iter().filter(|f| f.effect != Effect::Slack && truth_has(f.effect)).count() == in_truth;
        if truth_named {
            alpha = d.tests.first().map_or(alpha, |t| t.alpha);
            after_truth
                .extend(d.tests.iter().filter(|t| t.round > in_truth && !truth_has(t.effect)).filter_map(|t| t.test.map(|x| x.p_value)));
        }
        // The test that named an effect outside the truth, and its values.
        let spur: Vec<String> = d
            .tests
            .iter()
            .filter(|t| t.decision == taut_calib::diagnose::Decision::Named && !truth_has(t.effect))
            .map(|t| {
                let vals: Vec<String> = t.values.iter().zip(&t.sigmas).map(|(v, s)| format!("{v:.3e} ± {s:.1e}")).collect();
                format!(
                    " [round {} {}: {}; {}]",
                    t.round,
                    t.effect.name(),
                    t.test.map_or("no test".into(), |x| x.to_string()),
                    vals.join(", ")
                )
            })
            .collect();
        let mut line = format!("seed {:6}: {named:?}", s.seed);
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Backlash) {
            let w: Vec<String> = f
                .values
                .iter()
                .zip(&f.sigmas)
                .map(|(v, sg)| {
                    let e = (v - play) / sg;
                    zw.push(e);
                    format!("{:.2} ± {:.2} ({e:+.1} σ)", v * 1e3, sg * 1e3)
                })
                .collect();
            line.push_str(&format!(" play mm {}", w.join(", ")));
        }
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::TimeOffset) {
            let e = (f.values[0] - offset) / f.sigmas[0];
            zo.push(e);
            line.push_str(&format!("; offset {:.2} ± {:.2} ms ({e:+.1} σ)", f.values[0] * 1e3, f.sigmas[0] * 1e3));
        }
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Elasticity) {
            let v: Vec<String> = f
                .values
                .iter()
                .zip(&f.sigmas)
                .map(|(v, sg)| {
                    let e = (v - ea_kn as f64 * 1e3) / sg;
                    ze.push(e);
                    format!("{v:.0} ± {sg:.0} ({e:+.1} σ)")
                })
                .collect();
            line.push_str(&format!("; EA {}", v.join(", ")));
        }
        line.push_str(&spur.concat());
        println!("{line}");
    }
    let share = |z: &[f64], k: f64| 100.0 * z.iter().filter(|e| e.abs() <= k).count() as f64 / z.len().max(1) as f64;
    let mean = |z: &[f64]| z.iter().sum::<f64>() / z.len().max(1) as f64;
    for (name, z) in [("play", &zw), ("offset", &zo), ("EA", &ze)] {
        if !z.is_empty() {
            println!(
                "{name}: {} estimates, within 1 σ {:.0} %, 2 σ {:.0} %, 3 σ {:.0} %; mean error {:+.2} σ",
                z.len(),
                share(z, 1.0),
                share(z, 2.0),
                share(z, 3.0),
                mean(z)
            );
        }
    }
    println!("recordings naming an effect not in the truth: {spurious} of {count}");
    let below = |a: f64| after_truth.iter().filter(|p| **p < a).count();
    println!(
        "tests of candidates outside the truth after it was named: {}; p below 0.05: {}, 0.01: {}, 1e-3: {}, 1e-4: {}, alpha {alpha:.1e}: {} (a uniform p: {:.1}, {:.1}, {:.2}, {:.3}, {:.1e})",
        after_truth.len(),
        below(0.05),
        below(0.01),
        below(1e-3),
        below(1e-4),
        below(alpha),
        0.05 * after_truth.len() as f64,
        0.01 * after_truth.len() as f64,
        1e-3 * after_truth.len() as f64,
        1e-4 * after_truth.len() as f64,
        alpha * after_truth.len() as f64
    );
}
