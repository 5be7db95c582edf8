//! Compliance independent of length concealed in the simulator, alone or beside elasticity, on
//! the 3-cable, 4-cable and outdoor robots: how often it is named, what else is named, and the
//! 1/2/3-sigma coverage of every cable's compliance (and of EA in the pair).
//!
//! ```text
//! cargo run --profile test -p taut-tests --example compliance_coverage -- ROBOT CASE FIRST_SEED COUNT [K_M_PER_N] [KEY=VALUE ..] [-v]
//! ROBOT: three | aras | outdoor
//! CASE: alone | ea | alone-pretension | ea-pretension | ea-only-pretension | none-pretension
//! KEY: duration=S (default 40, outdoor 60), loose=FRACTION (default: the robot's),
//!      levels=N,N,.. (default 50,-50), hold=S (default 2), ramp=S (default 0.5)
//! ```
//!
//! The `-pretension` cases have the controller of a redundant robot (4 cables) move its internal
//! force along the excitation (`taut_sim::Scenario::pretension`): the levels in turn, each held
//! `hold` s and reached by a `ramp` s ramp, clamped where a cable would reach the floor (the
//! default, +-50 N, alternates between the two ends of what the floor allows). The same poses at
//! different tensions: the deflection `k T` changes with the tension alone, the stretch
//! `T L / EA` with the tension times the length. The example also prints how far the internal
//! force moved the tensions (against the same seed without it). `ea-only-pretension` conceals
//! elasticity alone (compliance named there is a false claim), `none-pretension` nothing (any
//! effect named is). The 3-cable robot has no internal force, its tensions being fixed by the
//! pose, and is refused.
//!
//! Magnitudes: about 1 mm of deflection at each robot's working tensions (the light robots'
//! cables carry 5-30 N, the outdoor robot's 100-300 N): 5e-5 m/N on the light robots, 5e-6 m/N
//! outdoors; EA 20 kN (light) and 500 kN (outdoor) in the pair. 100 Hz, the outdoor robot with
//! the controller's 50 N floor.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::{Physics, Pretension};
use taut_tests::sim::{scenario_named, simulate_next_seed};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let robot = args.first().map(String::as_str).unwrap_or("aras").to_string();
    let case = args.get(1).map(String::as_str).unwrap_or("alone").to_string();
    let first: u64 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(1);
    let count: u64 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(10);
    let verbose = args.iter().any(|a| a == "-v");
    let (k, ea) = if robot == "outdoor" { (5e-6, 5e5) } else { (5e-5, 2e4) };
    let k: f64 = args.get(4).filter(|a| *a != "-v" && !a.contains('=')).map_or(k, |a| a.parse().expect("K_M_PER_N"));
    let (with_k, with_ea, pretension) = match case.as_str() {
        "alone" => (true, false, false),
        "ea" => (true, true, false),
        "alone-pretension" => (true, false, true),
        "ea-pretension" => (true, true, true),
        "ea-only-pretension" => (false, true, true),
        "none-pretension" => (false, false, true),
        other => panic!("unknown case {other}: alone | ea | alone-pretension | ea-pretension | ea-only-pretension | none-pretension"),
    };
    let knob = |key: &str, default: f64| -> f64 {
        args.iter().find_map(|a| a.strip_prefix(key)).map_or(default, |v| v.parse().unwrap_or_else(|_| panic!("{key}N")))
    };
    let hold = knob("hold=", 2.0);
    let loose = knob("loose=", -1.0);
    let duration = knob("duration=", if robot == "outdoor" { 60.0 } else { 40.0 });
    let ramp = knob("ramp=", 0.5);
    let levels: Vec<f64> = args
        .iter()
        .find_map(|a| a.strip_prefix("levels="))
        .map_or(vec![50.0, -50.0], |v| v.split(',').map(|x| x.parse().expect("levels=N,N,..")).collect());
    assert!(!(pretension && robot == "three"), "the 3-cable robot has no internal force to vary: its tensions are fixed by the pose");
    let (mut named, mut ea_named, mut wrong, mut total) = (0, 0, 0, 0);
    let (mut kz, mut eaz): (Vec<f64>, Vec<f64>) = (vec![], vec![]);
    // Recordings whose report says compliance and elasticity trade off (in either finding).
    let mut weak = 0;
    // The taut readings' tensions, for the deflection `k T` they make.
    let mut tensions: Vec<f64> = vec![];
    // Each taut sample's largest change of a cable's tension from the run without the internal
    // force (the same poses), N.
    let mut swings: Vec<f64> = vec![];
    for seed in first..first + count {
        let mut s = scenario_named(&robot, seed);
        s.physics = Physics { compliance_m_per_n: with_k.then_some(k), elasticity: with_ea.then_some(ea), ..Physics::default() };
        s.duration_s = duration;
        if loose >= 0.0 {
            s.loose_fraction = loose;
        }
        if robot == "outdoor" {
            s.robot.calibration.min_tension_n = 50.0;
        }
        let plain = pretension.then(|| simulate_next_seed(&mut s.clone()));
        if pretension {
            s.pretension = Some(Pretension { levels_n: levels.clone(), hold_s: hold, ramp_s: ramp });
        }
        let sim = simulate_next_seed(&mut s);
        if let Some(plain) = &plain {
            let n = sim.recording.n_cables;
            for i in sim.excitation_start..sim.positions.len() {
                if plain.positions[i] == sim.positions[i] && !sim.loose[i * n..(i + 1) * n].iter().any(|&x| x) {
                    let d = (0..n).map(|j| (sim.tensions[i * n + j] - plain.tensions[i * n + j]).abs());
                    swings.push(d.fold(0.0, f64::max));
                }
            }
        }
        if let Some(f) = &sim.recording.f {
            tensions.extend(f.iter().filter(|t| **t >= s.robot.calibration.min_tension_n));
        }
        let opts = DiagnoseOptions::from_config(&s.robot.calibration);
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        total += 1;
        let names: Vec<Effect> = d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect();
        let others: Vec<&str> = names
            .iter()
            .filter(|e| !(with_k && **e == Effect::Compliance || with_ea && **e == Effect::Elasticity))
            .map(|e| e.name())
            .collect();
        wrong += usize::from(!others.is_empty());
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Compliance) {
            named += 1;
            if with_k {
                kz.extend(f.values.iter().zip(&f.sigmas).filter(|(v, _)| v.is_finite()).map(|(v, s)| (v - k) / s));
            }
        }
        weak += usize::from(d.effects.iter().any(|f| {
            let other = if f.effect == Effect::Compliance { "elasticity" } else { "compliance" };
            matches!(f.effect, Effect::Compliance | Effect::Elasticity)
                && f.evidence
                    .split(';')
                    .any(|part| part.contains(other) && (part.contains("trade off") || part.contains("estimates correlate")))
        }));
        if let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Elasticity) {
            ea_named += 1;
            if with_ea {
                eaz.extend(f.values.iter().zip(&f.sigmas).filter(|(v, _)| v.is_finite()).map(|(v, s)| (v - ea) / s));
            }
        }
        if verbose {
            let line: Vec<String> = d
                .effects
                .iter()
                .filter(|f| f.effect != Effect::Slack)
                .map(|f| {
                    let v: Vec<String> = f.values.iter().zip(&f.sigmas).map(|(v, s)| format!("{v:.3e}±{s:.1e}")).collect();
                    format!("{} [{}]", f.effect.name(), v.join(", "))
                })
                .collect();
            println!(
                "seed {seed}: {} | held-out {:.3} -> {:.3} mm",
                line.join("; "),
                d.baseline.heldout_rms_m * 1e3,
                d.final_fit.heldout_rms_m * 1e3
            );
        }
    }
    let cover = |z: &[f64]| -> String {
        if z.is_empty() {
            return "-".into();
        }
        let pct = |m: f64| 100.0 * z.iter().filter(|v| v.abs() <= m).count() as f64 / z.len() as f64;
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        format!("{:.0} / {:.0} / {:.0} % (n {}, mean z {:+.2})", pct(1.0), pct(2.0), pct(3.0), z.len(), mean)
    };
    tensions.sort_by(f64::total_cmp);
    let q = |p: f64| tensions.get((p * (tensions.len().max(1) - 1) as f64) as usize).copied().unwrap_or(f64::NAN);
    println!(
        "{robot}: taut tensions {:.0} / {:.0} / {:.0} N (10 / 50 / 90 %), k T {:.2} / {:.2} / {:.2} mm",
        q(0.1),
        q(0.5),
        q(0.9),
        k * q(0.1) * 1e3,
        k * q(0.5) * 1e3,
        k * q(0.9) * 1e3
    );
    if !swings.is_empty() {
        swings.sort_by(f64::total_cmp);
        let q = |p: f64| swings[(p * (swings.len() - 1) as f64) as usize];
        println!(
            "{robot}: internal force (levels {levels:?} N, {hold} s each, {ramp} s ramps): the most-changed cable's tension moved {:.1} / {:.1} / {:.1} N (10 / 50 / 90 % of the excitation's taut samples)",
            q(0.1),
            q(0.5),
            q(0.9)
        );
    }
    println!(
        "{robot} {case} ({}{}), seeds {first}-{}: compliance named {named}/{total}, elasticity named {ea_named}/{total}, the two reported to trade off on {weak}, other effects named on {wrong}; k within 1/2/3 sigma {}; EA {}",
        if with_k { format!("k {k:e} m/N") } else { "no compliance".into() },
        if with_ea { format!(", EA {ea:e} N") } else { String::new() },
        first + count - 1,
        cover(&kz),
        cover(&eaz)
    );
}
