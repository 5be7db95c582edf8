//! Diagnoses simulated recordings with a chosen set of concealed effects on a chosen robot and
//! prints what is named, with values, and (PROBE_TESTS=1) every candidate test. For exploring
//! pairs and triples (issue 14).
//!
//! ```text
//! cargo run --release -p taut-tests --example concealed_probe -- ROBOT FIRST_SEED COUNT [key=value ...]
//! ROBOT: three | aras | outdoor; keys: ea (N), sag (N/m), pulley (m), scale (comma list),
//! offset (s), play (m), buildup (drum radius change per turn paid out, m), compliance (winch,
//! frame and anchor, m/N), dur (s), floor (N)
//! ```

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::Physics;
use taut_tests::sim::{scenario_named, simulate_next_seed};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let robot = args.first().expect("robot").clone();
    let first: u64 = args.get(1).expect("first seed").parse().expect("seed");
    let count: u64 = args.get(2).expect("count").parse().expect("count");
    let mut physics = Physics::default();
    let (mut dur, mut floor) = (40.0, None);
    for kv in &args[3..] {
        let (k, v) = kv.split_once('=').expect("key=value");
        match k {
            "ea" => physics.elasticity = Some(v.parse().expect("ea")),
            "sag" => physics.sag = Some(v.parse().expect("sag")),
            "pulley" => physics.pulley = Some(v.parse().expect("pulley")),
            "scale" => physics.scale = Some(v.split(',').map(|x| x.parse().expect("scale")).collect()),
            "offset" => physics.time_offset_s = v.parse().expect("offset"),
            "play" => physics.backlash_m = v.parse().expect("play"),
            "buildup" => physics.drum_buildup_m_per_turn = Some(v.parse().expect("buildup")),
            "compliance" => physics.compliance_m_per_n = Some(v.parse().expect("compliance")),
            "dur" => dur = v.parse().expect("dur"),
            "floor" => floor = Some(v.parse::<f64>().expect("floor")),
            _ => panic!("unknown key {k}"),
        }
    }
    let show_tests = std::env::var("PROBE_TESTS").is_ok_and(|v| v == "1");
    for seed in first..first + count {
        let mut s = scenario_named(&robot, seed);
        s.physics = physics.clone();
        s.duration_s = dur;
        if let Some(f) = floor {
            s.robot.calibration.min_tension_n = f;
        }
        let sim = simulate_next_seed(&mut s);
        let opts = DiagnoseOptions::from_config(&s.robot.calibration);
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let named: Vec<String> = d
            .effects
            .iter()
            .filter(|f| f.effect != Effect::Slack)
            .map(|f| {
                let v: Vec<String> = f.values.iter().zip(&f.sigmas).map(|(v, s)| format!("{v:.4e}±{s:.1e}")).collect();
                format!("{} [{}]", f.effect.name(), v.join(", "))
            })
            .collect();
        println!(
            "seed {seed}: {} | held-out {:.3} -> {:.3} mm",
            named.join("; "),
            d.baseline.heldout_rms_m * 1e3,
            d.final_fit.heldout_rms_m * 1e3
        );
        if show_tests {
            for f in &d.effects {
                println!("    {}: {}", f.effect.name(), f.evidence);
            }
            for t in &d.tests {
                println!("    round {} {}: {:?} {}", t.round, t.effect.name(), t.decision, t.test.map_or("-".into(), |x| x.to_string()));
            }
            for r in d.rejected.iter().chain(&d.notes) {
                println!("    - {r}");
            }
        }
    }
}
