//! The tracker-free fit's chi-square on the start-up's own plan without the wall clock: what a
//! static, correctly modelled start-up gives, and what the simulated cables' stretch adds.
//!
//! `cargo run --release -p taut-tests --example notracker_chi2_null -- CONFIG.toml DWELL_S FIRST_SEED SEEDS`
//!
//! Per seed: the site as `taut start --sim` draws it (`Truth::sample`, 20 cm, 2 m), the dwell
//! plan of CONFIG with `motion.dwell_s = DWELL_S` (the loop's poses and tares, in the nominal
//! frame), the simulator's plant holding each pose (the position cables at the drum lengths that
//! hold it with the planned tensions, the followers in torque mode; a tare: the masked cables at
//! zero tension, a follower outside the mask held at its length) and its static equilibrium,
//! then `DWELL_S` of readings per dwell through the simulator's sensor models (encoders at the
//! loop's 500 Hz rows, 0.05 mm + 10 um quantum; load cells 0.3 N at 128 new readings a second
//! per cable), in the calibrator's data-set format (labelled rows, a tension only when new,
//! separator rows), split into training and held-out dwells as the daemon does, calibrated with
//! `taut_calib::selfcal`. Two variants of the same noise (paired):
//! - `stretch`: the encoders count the drum's unstretched length (the simulator: position-mode
//!   cables stiff, `EA_RIGID`, not rigid), what the start-up records;
//! - `rigid`: the encoders count the geometric length (the static model exactly).
//!
//! Printed per seed: chi2/dof and dof of both, and the mean and the pooled P at the end. No
//! wall clock, no devices, no loop: what is left of an e2e start-up's chi-square excess over
//! these is the devices' and the loop's.

use taut_calib::selfcal::{self, SelfCalOptions};
use taut_config::recording::Recording;
use taut_io::FromRobot;
use taut_rt::motion::{ControllerConfig, MAX_DWELL_POSES};
use taut_sim::sensors::{Encoder, LoadCell};
use taut_sim::{CableCommand, Noise, Physics, Plant, Truth};

/// Loop rows a second (`rt.rate_hz`, calibrator decimation 1).
const ROW_HZ: f64 = 500.0;
/// New tension readings a second per cable (measured on the simulated bus: 125-131).
const TENSION_HZ: f64 = 128.0;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 5 {
        eprintln!("usage: notracker_chi2_null CONFIG.toml DWELL_S FIRST_SEED SEEDS");
        std::process::exit(2);
    }
    let mut cfg = taut_config::RobotConfig::load(&args[1]).unwrap_or_else(|e| panic!("{}: {e}", args[1]));
    cfg.motion.dwell_s = args[2].parse().expect("DWELL_S");
    let first: u64 = args[3].parse().expect("FIRST_SEED");
    let seeds: u64 = args[4].parse().expect("SEEDS");
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let plan = taut_calibrator::notracker::dwell_plan(&cfg, &ccfg).unwrap();
    let nominal = cfg.anchors().unwrap();
    let platform = cfg.platform_points();
    let opts = SelfCalOptions::from_config(&cfg);
    println!(
        "plan: {} poses x {} s, {} tares; {ROW_HZ} rows/s, {TENSION_HZ} tension readings/s per cable",
        plan.poses.len(),
        cfg.motion.dwell_s,
        plan.tare.iter().filter(|&&t| t != 0).count()
    );
    let mut sums = [(0.0, 0usize); 2];
    for seed in first..first + seeds {
        let physics = Physics::default();
        let mut rng = taut_sim::rng(seed, 0);
        let truth = Truth::sample(&cfg, &physics, 0.2, 2.0, &mut rng).unwrap();
        let sets = recordings(&cfg, &ccfg, &plan, &truth, &physics, seed);
        let mut line = format!("seed {seed}:");
        for (v, rec) in sets.iter().enumerate() {
            let (train, _) = taut_calibrator::notracker::split_dwells(rec, cfg.calibration.heldout_fraction);
            match selfcal::calibrate_without_tracker(&train, &platform, Some(&nominal), &opts) {
                Ok(r) => {
                    sums[v].0 += r.chi2;
                    sums[v].1 += r.dof;
                    line += &format!(
                        " {} chi2/dof {:.3} ({} dof, {} dwells, inflation {:.2}/{:.2});",
                        ["stretch", "rigid"][v],
                        r.chi2 / r.dof as f64,
                        r.dof,
                        r.dwells.len(),
                        r.inflation.0,
                        r.inflation.1
                    );
                }
                Err(e) => line += &format!(" {}: {e};", ["stretch", "rigid"][v]),
            }
        }
        println!("{line}");
    }
    for (v, (chi, dof)) in sums.iter().enumerate() {
        println!(
            "{}: pooled chi2/dof {:.3} at {dof} dof, P(chi2 >= that) {:.2e}",
            ["stretch", "rigid"][v],
            chi / *dof as f64,
            taut_tests::honesty::chi2_sf(*chi, *dof)
        );
    }
}

/// The calibrator's data set of one start-up (both variants, the same noise).
fn recordings(
    cfg: &taut_config::RobotConfig,
    ccfg: &ControllerConfig,
    plan: &taut_calib::selfcal::plan::DwellPlan,
    truth: &Truth,
    physics: &Physics,
    seed: u64,
) -> [Recording; 2] {
    let n = truth.n_cables();
    let noise = Noise::default();
    let mut plant = Plant::new(truth, physics, plan.poses[0]);
    // A stream of its own (the site's draws use stream 0).
    let mut rng = taut_sim::rng(seed, 0x5eed);
    let mut enc: Vec<Encoder> = (0..n).map(|j| Encoder::new(truth.scale[j], truth.l0[j], 0.0, &noise)).collect();
    let cells: Vec<LoadCell> = (0..n).map(|j| LoadCell::with_offset(truth.loadcell_offsets[j], &noise)).collect();
    let mut out = [Recording::with_capacity(n, 1 << 16, true, false, true), Recording::with_capacity(n, 1 << 16, true, false, true)];
    let rows = (cfg.motion.dwell_s * ROW_HZ).floor() as usize;
    let mut t = 0.0;
    let nan = vec![f64::NAN; n];
    let mut dwell = |label: i32, cmds: &[CableCommand], plant: &mut Plant, out: &mut [Recording; 2], t: &mut f64| -> Vec<f64> {
        let mut drum = vec![0.0; n];
        let mut ten = vec![0.0; n];
        for _ in 0..50 {
            let o = plant.step(0.002, cmds);
            drum.copy_from_slice(o.drum_m);
            ten.copy_from_slice(o.tension_n);
        }
        let p = plant.position();
        let geo: Vec<f64> = (0..n)
            .map(|j| {
                let b = truth.platform_points[j];
                let a = truth.anchors[j];
                let d = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
            })
            .collect();
        for r in out.iter_mut() {
            if !r.is_empty() {
                r.push(*t, [f64::NAN; 3], None, &nan, Some(&nan), Some(-1));
            }
        }
        let phase: Vec<f64> = (0..n).map(|j| j as f64 / n as f64).collect();
        let per_row = TENSION_HZ / ROW_HZ;
        let (mut l_s, mut l_r, mut f) = (vec![0.0; n], vec![0.0; n], vec![f64::NAN; n]);
        for i in 0..rows {
            for j in 0..n {
                // The same noise for both variants: the stream cloned before the draw.
                let mut same = rng.clone();
                l_s[j] = enc[j].read(drum[j], &mut rng);
                l_r[j] = enc[j].read(geo[j], &mut same);
                let k0 = ((i as f64 + phase[j]) * per_row).floor();
                let k1 = ((i as f64 + 1.0 + phase[j]) * per_row).floor();
                f[j] = if k1 > k0 { (cells[j].read(ten[j], &mut rng) * 1e3).round() / 1e3 } else { f64::NAN };
            }
            out[0].push(*t, [f64::NAN; 3], None, &l_s, Some(&f), Some(label));
            out[1].push(*t, [f64::NAN; 3], None, &l_r, Some(&f), Some(label));
            *t += 1.0 / ROW_HZ;
        }
        drum
    };
    for (k, pose) in plan.poses.iter().enumerate() {
        let tensions = &plan.tensions[k];
        let hold = plant.lengths_holding(*pose, tensions).unwrap();
        let cmds: Vec<CableCommand> =
            (0..n).map(|j| if ccfg.follower[j] { CableCommand::Tension(tensions[j]) } else { CableCommand::Length(hold[j]) }).collect();
        let drum = dwell(k as i32, &cmds, &mut plant, &mut out, &mut t);
        let mask = plan.tare[k];
        if mask != 0 {
            let tare: Vec<CableCommand> =
                (0..n).map(|j| if mask & (1 << j) != 0 { CableCommand::Tension(0.0) } else { CableCommand::Length(drum[j]) }).collect();
            dwell((MAX_DWELL_POSES + k) as i32, &tare, &mut plant, &mut out, &mut t);
        }
    }
    out
}
