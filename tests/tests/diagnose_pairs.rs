//! Effects under effects (issue 14): concealed pairs and triples on the 3-cable, 4-cable and 20 m
//! outdoor robots, diagnosed from simulated recordings (the simulator's physics is independent of
//! the diagnosis models). Each effect must be named by the held-out test, small effects under
//! large ones included, and where two effects trade off the reported uncertainty must cover the
//! truth.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect, Finding};
use taut_sim::{simulate, Physics, Scenario};

fn run(mut s: Scenario, duration_s: f64) -> Diagnosis {
    s.duration_s = duration_s;
    let sim = simulate(&s);
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

#[test]
fn explore() {
    for (k, (lf, mt, ea)) in [(0.2, 50.0, 5e5), (0.0, 3.0, 5e5), (0.2, 50.0, 1e6)].into_iter().enumerate() {
        let mut s = Scenario::outdoor(23);
        s.physics = Physics { sag: Some(0.33), elasticity: Some(ea), ..Physics::default() };
        s.loose_fraction = lf;
        s.robot.calibration.min_tension_n = mt;
        let t0 = std::time::Instant::now();
        let d = run(s, 60.0);
        eprintln!("case {k} sag+ea {:.1}s {:#?}", t0.elapsed().as_secs_f64(), summary(&d));
    }
}
