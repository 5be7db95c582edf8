//! Coverage of the reported EA uncertainty when backlash is present (issue 14): EA 15 kN under
//! 10 mm backlash on the 4-cable robot, many seeds. Prints each cable's EA, its reported sigma
//! and the error in sigmas, then the share of errors within 1, 2 and 3 sigmas (a Gaussian gives
//! 68 / 95 / 99.7 %). `DIAGNOSE_BACKWARD=0` runs the forward-only selection (without the backward step).
//!
//! ```text
//! cargo run --profile test -p taut-tests --example ea_backlash_coverage -- [first seed, default 40] [seeds, default 10] [play mm, default 10] [EA kN, default 15; 0: none] [encoder noise um, default the scenario's]
//! ```

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::{simulate, Physics, Scenario};

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<u64>().expect("a number"));
    let first = args.next().unwrap_or(40);
    let count = args.next().unwrap_or(10);
    let play_m = args.next().unwrap_or(10) as f64 * 1e-3;
    let truth = args.next().unwrap_or(15) as f64 * 1e3;
    let encoder_sigma = args.next().map(|u| u as f64 * 1e-6);
    let mut z = vec![];
    for seed in first..first + count {
        let mut s = Scenario::aras_cam(seed);
        s.physics = Physics { elasticity: (truth > 0.0).then_some(truth), backlash_m: play_m, ..Physics::default() };
        if let Some(e) = encoder_sigma {
            s.noise.encoder_sigma_m = e;
        }
        s.duration_s = 40.0;
        let sim = simulate(&s);
        // DIAGNOSE_BACKWARD=0: the forward-only selection (before the backward step), to compare.
        let opts = DiagnoseOptions {
            backward: std::env::var("DIAGNOSE_BACKWARD").map_or(true, |v| v != "0"),
            ..DiagnoseOptions::from_config(&s.robot.calibration)
        };
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let named: Vec<&str> = d.effects.iter().map(|f| f.effect.name()).collect();
        let Some(f) = d.effects.iter().find(|f| f.effect == Effect::Elasticity) else {
            println!("seed {seed}: elasticity not named ({named:?})");
            continue;
        };
        let line: Vec<String> = f
            .values
            .iter()
            .zip(&f.sigmas)
            .map(|(v, s)| {
                let e = (v - truth) / s;
                z.push(e);
                format!("{v:.0} ± {s:.0} ({e:+.1} σ)")
            })
            .collect();
        let widths = d
            .effects
            .iter()
            .find(|f| f.effect == Effect::Backlash)
            .map(|f| f.values.iter().map(|w| format!("{:.1}", w * 1e3)).collect::<Vec<_>>());
        // The tests that named an effect outside the truth.
        let spur: String = d
            .tests
            .iter()
            .filter(|t| t.decision == taut_calib::diagnose::Decision::Named)
            .filter(|t| ![Effect::Elasticity, Effect::Backlash, Effect::Slack].contains(&t.effect))
            .map(|t| {
                let dropped: String = d
                    .tests
                    .iter()
                    .filter(|q| q.effect == t.effect && q.decision == taut_calib::diagnose::Decision::Dropped)
                    .map(|q| format!("; dropped in round {}: {}", q.round, q.test.map_or("no test".into(), |x| x.to_string())))
                    .collect();
                let v: Vec<String> = t.values.iter().zip(&t.sigmas).map(|(v, s)| format!("{v:.3e} ± {s:.1e}")).collect();
                format!(
                    " [round {} {} ({}): {}{dropped}]",
                    t.round,
                    t.effect.name(),
                    v.join(", "),
                    t.test.map_or("no test".into(), |x| x.to_string())
                )
            })
            .collect();
        println!("seed {seed}: {named:?} EA {} ; play mm {widths:?}{spur}", line.join(", "));
    }
    let share = |k: f64| 100.0 * z.iter().filter(|e| e.abs() <= k).count() as f64 / z.len().max(1) as f64;
    println!("{} cable estimates: within 1 σ {:.0} %, 2 σ {:.0} %, 3 σ {:.0} %", z.len(), share(1.0), share(2.0), share(3.0));
}
