//! The running robot's refit with a fixed set of effects (`taut_calib::effect_fit::fit_effects`,
//! as `taut start` and `ctl recalibrate` run it) on the recordings of `offset_backlash_coverage`:
//! a concealed time offset and play on the 3-cable robot (optionally with EA), many seeds. The
//! fit starts from the ideal calibration's result (from the nominal anchors), as the robot's does.
//! Prints each estimate with its reported sigma and error in sigmas, then per parameter the mean
//! error, the share within 1, 2 and 3 reported sigmas (a Gaussian: 68 / 95 / 99.7 %), how many
//! time-offset estimates sit on a whole encoder sample (within 1 ns of a multiple of the median
//! sample interval), and a checksum of every fitted number (anchors, offsets, effects, sigmas:
//! bit-identical runs print the same checksum).
//!
//! `EFFECT_FIT_CLEAN=1` turns off the simulated tracker outliers and dropouts (as
//! `offset_backlash_coverage`'s `COVERAGE_CLEAN=1`). The effect fit leaves out rows without a pose
//! and tracker outliers by the diagnosis's rules (`dataq::pose_missing`, `dataq::tracker_outliers`);
//! each line says how many outliers were left out.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example effect_fit_coverage -- [first seed, default 100] [seeds, default 10] [effects, default time-offset,backlash] [EA kN, default 0: none] [play mm, default 6] [offset ms, default 20]
//! ```

use taut_calib::effect_fit::{fit_effects, EffectFitOptions};
use taut_calib::{calibrate, CalibOptions, Geometry};
use taut_tests::sim::{offset_backlash_scenario, simulate_next_seed};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |k: usize, d: u64| args.get(k).map_or(d, |a| a.parse::<u64>().expect("a number"));
    let (first, count) = (num(0, 100), num(1, 10));
    let effects: Vec<&str> = args.get(2).map_or("time-offset,backlash", |s| s.as_str()).split(',').collect();
    let ea_kn = num(3, 0);
    let play = num(4, 6) as f64 * 1e-3;
    let offset = num(5, 20) as f64 * 1e-3;
    let (mut zw, mut ew, mut zo, mut eo, mut ze) = (vec![], vec![], vec![], vec![], vec![]);
    let mut whole = 0;
    let mut outliers = 0;
    let mut failed = 0;
    // FNV-1a over the bits of every fitted number.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut mix = |v: f64| {
        for b in v.to_bits().to_le_bytes() {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for seed in first..first + count {
        let clean = std::env::var("EFFECT_FIT_CLEAN").is_ok_and(|v| v == "1");
        let mut s = offset_backlash_scenario(seed, 3, ea_kn, play, offset, clean);
        let sim = simulate_next_seed(&mut s);
        let rec = &sim.recording;
        let platform = &sim.truth.platform_points;
        let c = &s.robot.calibration;
        // The ideal calibration first, from the nominal anchors (the robot's start-up order).
        let nominal = Geometry { anchors: s.robot.anchors().expect("anchors"), l0: sim.truth.l0.clone() };
        let ideal = calibrate(rec, platform, &nominal, &CalibOptions::from_config(c)).expect("ideal calibration");
        let o = EffectFitOptions::new(&effects, c.min_tension_n, c.tracker_sigma_m, c.encoder_sigma_m);
        let f = match fit_effects(rec, platform, &ideal.params.anchors, &ideal.params.l0, &Default::default(), &o) {
            Ok(f) => f,
            Err(e) => {
                println!("seed {:6}: {e}", s.seed);
                failed += 1;
                continue;
            }
        };
        for (a, l) in f.params.anchors.iter().zip(&f.params.l0) {
            a.iter().for_each(|v| mix(*v));
            mix(*l);
        }
        f.sigma.anchors.iter().flatten().for_each(|v| mix(*v));
        f.sigma.l0.iter().for_each(|v| mix(*v));
        let e = &f.effects;
        for v in [&e.ea_n, &e.ea_sigma_n, &e.drum_scale, &e.drum_scale_sigma, &e.backlash_m, &e.backlash_sigma_m].into_iter().flatten() {
            v.iter().for_each(|x| mix(*x));
        }
        e.time_offset_s.into_iter().chain(e.time_offset_sigma_s).for_each(&mut mix);
        mix(f.rms_m);
        outliers += f.tracker_outliers;
        let mut line = format!(
            "seed {:6}: rms {:.3} mm, {} readings, {} iterations, {} tracker outliers left out",
            s.seed,
            f.rms_m * 1e3,
            f.readings,
            f.iterations,
            f.tracker_outliers
        );
        if let (Some(v), Some(sg)) = (&e.backlash_m, &e.backlash_sigma_m) {
            let w: Vec<String> = v
                .iter()
                .zip(sg)
                .map(|(v, sg)| {
                    let z = (v - play) / sg;
                    zw.push(z);
                    ew.push(v - play);
                    format!("{:.3} ± {:.3} ({z:+.1} σ)", v * 1e3, sg * 1e3)
                })
                .collect();
            line.push_str(&format!("; play mm {}", w.join(", ")));
        }
        if let (Some(v), Some(sg)) = (e.time_offset_s, e.time_offset_sigma_s) {
            let z = (v - offset) / sg;
            zo.push(z);
            eo.push(v - offset);
            let dt = {
                let mut d: Vec<f64> = rec.t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
                d.sort_by(|a, b| a.total_cmp(b));
                d[d.len() / 2]
            };
            let on_grid = (v / dt - (v / dt).round()).abs() * dt < 1e-9;
            whole += usize::from(on_grid);
            line.push_str(&format!(
                "; offset {:.4} ± {:.3} ms ({z:+.1} σ){}",
                v * 1e3,
                sg * 1e3,
                if on_grid { " ON A WHOLE SAMPLE" } else { "" }
            ));
        }
        if let Some(v) = &e.ea_n {
            let sg = e.ea_sigma_n.clone().unwrap_or_else(|| vec![f64::NAN; v.len()]);
            let w: Vec<String> = v
                .iter()
                .zip(&sg)
                .map(|(v, sg)| {
                    if ea_kn > 0 {
                        ze.push((v - ea_kn as f64 * 1e3) / sg);
                    }
                    format!("{v:.0} ± {sg:.0}")
                })
                .collect();
            line.push_str(&format!("; EA {}", w.join(", ")));
        }
        if let Some(v) = &e.drum_scale {
            line.push_str(&format!("; scale {}", v.iter().map(|v| format!("{v:.6}")).collect::<Vec<_>>().join(", ")));
        }
        println!("{line}");
    }
    let share = |z: &[f64], k: f64| 100.0 * z.iter().filter(|e| e.abs() <= k).count() as f64 / z.len().max(1) as f64;
    let mean = |z: &[f64]| z.iter().sum::<f64>() / z.len().max(1) as f64;
    let sd = |z: &[f64]| {
        let m = mean(z);
        (z.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (z.len().max(2) - 1) as f64).sqrt()
    };
    for (name, z, err, unit, scale) in [("play", &zw, &ew, "mm", 1e3), ("offset", &zo, &eo, "ms", 1e3), ("EA", &ze, &vec![], "", 1.0)] {
        if !z.is_empty() {
            let e = if err.is_empty() {
                String::new()
            } else {
                format!("; error mean {:+.4} {unit}, SD {:.4} {unit}", mean(err) * scale, sd(err) * scale)
            };
            println!(
                "{name}: {} estimates, within 1 σ {:.0} %, 2 σ {:.0} %, 3 σ {:.0} %; mean error {:+.2} σ{e}",
                z.len(),
                share(z, 1.0),
                share(z, 2.0),
                share(z, 3.0),
                mean(z)
            );
        }
    }
    if !zo.is_empty() {
        println!("offset estimates on a whole encoder sample: {whole} of {}", zo.len());
    }
    println!("tracker outliers left out: {outliers}");
    println!("fits refused: {failed} of {count}");
    println!("checksum {hash:016x}");
}
