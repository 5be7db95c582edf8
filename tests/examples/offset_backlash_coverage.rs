//! Coverage of the reported play-width (and time-offset) uncertainty when a time offset and
//! backlash are present together (issue 14): a 20 ms offset and a 6 mm play on the 3-cable robot
//! (optionally with EA 20 kN), many seeds. Prints each cable's play width, its reported sigma and
//! the error in sigmas, then per effect in the truth the recordings that name it, the estimates'
//! bias and spread against the reported sigmas, and the share within 1, 2 and 3 sigmas (a
//! Gaussian gives 68 / 95 / 99.7 %). A play or offset of 0 (or EA 0) leaves that effect out.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example offset_backlash_coverage -- [first seed, default 100] [seeds, default 10] [EA kN, default 0: none] [robot: 3 or 4 cables, default 3] [play mm, default 6] [offset ms, default 20]
//! ```
//!
//! Variants for finding a bias's cause (environment): `COVERAGE_TRACKER_MM=0.1` sets the
//! simulated tracker noise and the diagnosis's noise model to 0.1 mm; `COVERAGE_CLEAN=1` turns off
//! tracker outliers and dropouts; `COVERAGE_LOOSE=0` sets the loose-cable fraction; `COVERAGE_LIBRARY=time-offset,backlash` limits the candidates;
//! `COVERAGE_TESTS=1` prints every candidate test; `COVERAGE_AR_PHI=0.9` makes the simulated tracker noise AR(1) with that lag-1 correlation per
//! sample and the same marginal sigma (`taut_sim::Noise::tracker_phi`; the diagnosis is not told);
//! `DIAGNOSE_BACKWARD=0` runs the forward-only selection (without the backward step).

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_tests::sim::{offset_backlash_scenario, simulate_next_seed};

/// A backward step's removal test (not a candidate's forward test).
fn removal(t: &taut_calib::diagnose::CandidateTest) -> bool {
    matches!(t.decision, taut_calib::diagnose::Decision::Dropped | taut_calib::diagnose::Decision::Kept)
}

/// "; dropped in round r (test)" when the backward step dropped `e`.
fn dropped_words(d: &taut_calib::diagnose::Diagnosis, e: Effect) -> String {
    d.tests
        .iter()
        .filter(|t| t.effect == e && t.decision == taut_calib::diagnose::Decision::Dropped)
        .map(|t| format!("; dropped in round {}: {}", t.round, t.test.map_or("no test".into(), |x| x.to_string())))
        .collect()
}

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<u64>().expect("a number"));
    let first = args.next().unwrap_or(100);
    let count = args.next().unwrap_or(10);
    let ea_kn = args.next().unwrap_or(0);
    let cables = args.next().unwrap_or(3);
    let play = args.next().unwrap_or(6) as f64 * 1e-3;
    let offset = args.next().unwrap_or(20) as f64 * 1e-3;
    // Per effect (play, offset, EA): (error, reported sigma) of every estimate, and the recordings
    // that name it.
    let (mut zw, mut zo, mut ze) = (vec![], vec![], vec![]);
    let mut named_count = [0usize; 3];
    let mut spurious = 0;
    let (mut after_truth, mut alpha) = (vec![], f64::NAN);
    for seed in first..first + count {
        let clean = std::env::var("COVERAGE_CLEAN").is_ok_and(|v| v == "1");
        let mut s = offset_backlash_scenario(seed, cables, ea_kn, play, offset, clean);
        if let Ok(v) = std::env::var("COVERAGE_TRACKER_MM") {
            let sigma = v.parse::<f64>().expect("COVERAGE_TRACKER_MM: a number") * 1e-3;
            s.noise.tracker_sigma_m = sigma;
            s.robot.calibration.tracker_sigma_m = sigma;
        }
        if let Ok(v) = std::env::var("COVERAGE_LOOSE") {
            s.loose_fraction = v.parse::<f64>().expect("COVERAGE_LOOSE: a fraction");
        }
        if let Ok(v) = std::env::var("COVERAGE_AR_PHI") {
            s.noise.tracker_phi = v.parse::<f64>().expect("COVERAGE_AR_PHI: a number in [0, 1)");
        }
        let sim = simulate_next_seed(&mut s);
        let mut opts = DiagnoseOptions::from_config(&s.robot.calibration);
        // DIAGNOSE_BACKWARD=0: the forward-only selection (before the backward step), to compare.
        opts.backward = std::env::var("DIAGNOSE_BACKWARD").map_or(true, |v| v != "0");
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
        for (q, e) in [Effect::Backlash, Effect::TimeOffset, Effect::Elasticity].into_iter().enumerate() {
            named_count[q] += usize::from(d.effects.iter().any(|f| f.effect == e));
        }
        if d.effects.iter().any(|f| f.effect != Effect::Slack && !truth_has(f.effect)) {
            spurious += 1;
        }
        // The tests of candidates outside the truth once every effect of the truth is in the
        // current model (rounds after the truth's count): their p-values should be uniform.
        let in_truth = [Effect::TimeOffset, Effect::Backlash, Effect::Elasticity].into_iter().filter(|e| truth_has(*e)).count();
        let truth_named = d.effects.iter().filter(|f| f.effect != Effect::Slack && truth_has(f.effect)).count() == in_truth;
        if truth_named {
            alpha = d.tests.first().map_or(alpha, |t| t.alpha);
            after_truth.extend(
                d.tests
                    .iter()
                    .filter(|t| t.round > in_truth && !truth_has(t.effect))
                    .filter(|t| !removal(t))
                    .filter_map(|t| t.test.map(|x| x.p_value)),
            );
        }
        // The test that named an effect outside the truth, and its values.
        let spur: Vec<String> = d
            .tests
            .iter()
            .filter(|t| t.decision == taut_calib::diagnose::Decision::Named && !truth_has(t.effect))
            .map(|t| {
                let vals: Vec<String> = t.values.iter().zip(&t.sigmas).map(|(v, s)| format!("{v:.3e} ± {s:.1e}")).collect();
                format!(
                    " [round {} {}: {}; {}{}]",
                    t.round,
                    t.effect.name(),
                    t.test.map_or("no test".into(), |x| x.to_string()),
                    vals.join(", "),
                    dropped_words(&d, t.effect)
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
                    zw.push((v - play, *sg));
                    format!("{:.2} ± {:.2} ({e:+.1} σ)", v * 1e3, sg * 1e3)
                })
                .collect();
            line.push_str(&format!(" play mm {}", w.join(", ")));
        }
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::TimeOffset) {
            let e = (f.values[0] - offset) / f.sigmas[0];
            zo.push((f.values[0] - offset, f.sigmas[0]));
            line.push_str(&format!("; offset {:.2} ± {:.2} ms ({e:+.1} σ)", f.values[0] * 1e3, f.sigmas[0] * 1e3));
        }
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Elasticity) {
            let v: Vec<String> = f
                .values
                .iter()
                .zip(&f.sigmas)
                .map(|(v, sg)| {
                    let e = (v - ea_kn as f64 * 1e3) / sg;
                    ze.push((v - ea_kn as f64 * 1e3, *sg));
                    format!("{v:.0} ± {sg:.0} ({e:+.1} σ)")
                })
                .collect();
            line.push_str(&format!("; EA {}", v.join(", ")));
        }
        line.push_str(&spur.concat());
        println!("{line}");
        if std::env::var("COVERAGE_TESTS").is_ok_and(|v| v == "1") {
            for t in &d.tests {
                println!(
                    "    round {} {}: {:?}, {}",
                    t.round,
                    t.effect.name(),
                    t.decision,
                    t.test.map_or("no test".into(), |x| x.to_string())
                );
            }
        }
    }
    let phi = std::env::var("COVERAGE_AR_PHI").unwrap_or_else(|_| "0 (white)".into());
    println!("tracker noise lag-1 correlation {phi}; {count} recordings");
    let share = |z: &[(f64, f64)], k: f64| 100.0 * z.iter().filter(|(e, s)| e.abs() <= k * s).count() as f64 / z.len().max(1) as f64;
    let mean = |x: &mut dyn Iterator<Item = f64>| {
        let v: Vec<f64> = x.collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let truth = [(play > 0.0, play * 1e3), (offset > 0.0, offset * 1e3), (ea_kn > 0, ea_kn as f64)];
    for (q, (name, unit, scale, z)) in
        [("play", "mm", 1e3, &zw), ("offset", "ms", 1e3, &zo), ("EA", "kN", 1e-3, &ze)].into_iter().enumerate()
    {
        if !truth[q].0 && z.is_empty() {
            continue;
        }
        let bias = mean(&mut z.iter().map(|x| x.0 * scale));
        let sd = mean(&mut z.iter().map(|x| (x.0 * scale - bias).powi(2))).sqrt();
        let sigma_rms = mean(&mut z.iter().map(|x| (x.1 * scale).powi(2))).sqrt();
        println!(
            "{name} (truth {} {unit}): named in {} of {count}; {} estimates, error mean {bias:+.4} {unit} ({:+.2} σ), SD {sd:.4} / RMS σ {sigma_rms:.4} {unit}; within 1 σ {:.0} %, 2 σ {:.0} %, 3 σ {:.0} %",
            truth[q].1,
            named_count[q],
            z.len(),
            mean(&mut z.iter().map(|x| x.0 / x.1)),
            share(z, 1.0),
            share(z, 2.0),
            share(z, 3.0),
        );
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
