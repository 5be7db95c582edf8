//! Sag and elasticity on the 20 m outdoor robot below the controller's tension floor (issue 14):
//! sag 0.33 N/m and EA 500 kN, the diagnosis told a floor of `floor` N and the load cells' noise
//! (0: tensions taken as exact). Prints per seed what is named, the sag weight and EA with their
//! sigmas and errors in sigmas, the sag/EA correlation, and the coverage over the seeds.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example outdoor_sag_ea -- [first seed, default 23] [seeds, default 10] [floor N, default 15] [load-cell sigma mN, default 300]
//! ```

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<u64>().expect("a number"));
    let first = args.next().unwrap_or(23);
    let count = args.next().unwrap_or(10);
    let floor = args.next().unwrap_or(15) as f64;
    let cell_sigma = args.next().unwrap_or(300) as f64 * 1e-3;
    let (sag, ea) = (0.33, 5e5);
    let (mut zs, mut ze) = (vec![], vec![]);
    let (mut both, mut spurious) = (0, 0);
    for seed in first..first + count {
        let mut s = Scenario::outdoor(seed);
        s.physics = Physics { sag: Some(sag), elasticity: Some(ea), ..Physics::default() };
        s.robot.calibration.min_tension_n = floor;
        s.duration_s = 60.0;
        let sim = simulate_next_seed(&mut s);
        let mut o = DiagnoseOptions::from_config(&s.robot.calibration);
        o.loadcell_sigma_n = cell_sigma;
        // The simulated cells' constant offsets (1-sigma), as a data sheet or a tare states it.
        o.loadcell_offset_n = if cell_sigma > 0.0 { s.noise.loadcell_offset_n } else { 0.0 };
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &o).expect("diagnosis");
        let named: Vec<&str> = d.effects.iter().filter(|f| f.effect != Effect::Slack).map(|f| f.effect.name()).collect();
        if d.effects.iter().any(|f| !matches!(f.effect, Effect::Slack | Effect::Sag | Effect::Elasticity)) {
            spurious += 1;
        }
        let mut line = format!("seed {:6}: {named:?}", s.seed);
        let fs = d.effects.iter().find(|f| f.effect == Effect::Sag);
        let fe = d.effects.iter().find(|f| f.effect == Effect::Elasticity);
        if fs.is_some() && fe.is_some() {
            both += 1;
        }
        if let Some(f) = fs {
            let z = (f.values[0] - sag) / f.sigmas[0];
            zs.push(z);
            let rho = f.joint.iter().find(|j| j.with == Some(Effect::Elasticity)).map_or(f64::NAN, |j| j.correlation);
            line.push_str(&format!(" sag {:.4} ± {:.4} N/m ({z:+.1} σ, corr with EA {rho:+.2})", f.values[0], f.sigmas[0]));
        }
        if let Some(f) = fe {
            let v: Vec<String> = f
                .values
                .iter()
                .zip(&f.sigmas)
                .map(|(v, sg)| {
                    let z = (v - ea) / sg;
                    ze.push(z);
                    format!("{:.0} ± {:.0} ({z:+.1} σ)", v / 1e3, sg / 1e3)
                })
                .collect();
            line.push_str(&format!("; EA kN {}", v.join(", ")));
        }
        line.push_str(&format!("; held-out {:.2} -> {:.2} mm", d.baseline.heldout_rms_m * 1e3, d.final_fit.heldout_rms_m * 1e3));
        println!("{line}");
    }
    let share = |z: &[f64], k: f64| 100.0 * z.iter().filter(|e| e.abs() <= k).count() as f64 / z.len().max(1) as f64;
    let mean = |z: &[f64]| z.iter().sum::<f64>() / z.len().max(1) as f64;
    for (name, z) in [("sag", &zs), ("EA", &ze)] {
        println!(
            "{name}: {} estimates, within 1 σ {:.0} %, 2 σ {:.0} %, 3 σ {:.0} %; mean error {:+.2} σ",
            z.len(),
            share(z, 1.0),
            share(z, 2.0),
            share(z, 3.0),
            mean(z)
        );
    }
    println!("both named on {both} of {count}; an effect not in the truth on {spurious}; floor {floor} N, load-cell sigma {cell_sigma} N");
}
