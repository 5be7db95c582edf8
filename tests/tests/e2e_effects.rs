//! End to end: `taut start --sim` on a site that conceals elasticity (EA 20 kN), drum-scale
//! errors (up to 0.3 %) and 5 cm swivel pulleys, once with the ideal model and once with
//! `[calibration] effects = ["elasticity", "scale", "pulley"]`. The start-up calibration with
//! the effect model reaches the noise floor of the held-out co-registration where the ideal
//! model leaves millimetres, and the platform, commanded to poses across the workspace, ends up
//! nearer them (the simulator's plant knows where it really is).
//!
//! `TAUT_E2E_EFFECTS_SEEDS=3,4,5` runs more sites (for BENCHMARKS.md); the default is one.
//! `TAUT_E2E_EFFECTS_MODEL=elasticity,scale` changes the modelled effects,
//! `TAUT_E2E_EFFECTS_CONCEAL=elasticity,scale` the concealed ones.

use std::time::Duration;
use taut_rt_core::calib_backend::TautCalib;
use taut_rt_core::calibrator::OutcomeKind;
use taut_rt_core::daemon::{Daemon, DaemonOptions};
use taut_rt_core::motion::{Command, ControllerConfig};
use taut_rt_core::FromRobot;
use taut_sim::Physics;
use taut_simrig::{self as simrig, SimOptions};

/// The simulated robot `taut start --sim` runs, with its files in `dir` and a test-length
/// excitation.
fn robot(dir: &std::path::Path, effects: &[&str]) -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    cfg.motion.excitation_s = 25.0;
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg.calibration.effects = effects.iter().map(|s| s.to_string()).collect();
    cfg
}

/// The concealed physics: what `taut start --sim --sim-effect elasticity=20000 --sim-effect
/// pulley=0.05` sets, with a drum-scale error that differs per cable.
fn concealed(n: usize) -> Physics {
    let scale = [1.003, 0.998, 1.002, 0.9985];
    let list = std::env::var("TAUT_E2E_EFFECTS_CONCEAL").unwrap_or_else(|_| "elasticity,scale,pulley".into());
    let on = |e: &str| list.split(',').any(|x| x.trim() == e);
    Physics {
        elasticity: on("elasticity").then_some(20_000.0),
        pulley: on("pulley").then_some(0.05),
        scale: on("scale").then(|| (0..n).map(|j| scale[j % 4]).collect()),
        ..Physics::default()
    }
}

#[derive(Debug)]
struct Run {
    heldout_rms_m: f64,
    /// Held-out RMS of the initial estimate on the same rows.
    heldout_initial_m: f64,
    anchor_err_max_m: f64,
    reached_rms_m: f64,
    reached_max_m: f64,
    note: String,
    effects: taut_config::params::Effects,
    /// The effects in the published `params/current.toml`.
    file_effects: Vec<&'static str>,
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn run(seed: u64, effects: &[&str]) -> Run {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path(), effects);
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let centre: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
    let half: [f64; 3] = std::array::from_fn(|i| (w[1][i] - w[0][i]) / 2.0);
    let so = SimOptions { seed, physics: concealed(cfg.cables.len()), ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, centre);
    let sim = simrig::build(&cfg, p0, &so).unwrap();
    let truth = sim.truth.clone();
    let platform = sim.platform.clone();
    let d = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default()).unwrap();
    let ok = d.wait_until(Duration::from_secs(400), |l, c| {
        l.snap.fault.is_some()
            || c.outcomes.iter().any(|o| !o.accepted)
            || c.outcomes
                .iter()
                .any(|o| o.kind == OutcomeKind::Calibration && o.accepted && l.snap.params_version == o.version && !l.snap.swap_active)
    });
    let l = d.loop_status();
    let c = d.calib_status();
    if std::env::var_os("TAUT_E2E_KEEP").is_some() {
        // Keep the recording for a look after a failure.
        let name = format!("taut-e2e-effects-{seed}-{}.csv", if effects.is_empty() { "ideal" } else { "model" });
        let _ = std::fs::copy(&d.recording, std::env::temp_dir().join(name));
    }
    let reasons: Vec<&str> = c.outcomes.iter().map(|o| o.reason.as_str()).collect();
    assert!(ok && l.snap.fault.is_none(), "seed {seed} {effects:?}: start-up did not finish: {:?} {reasons:?}", l.snap.fault);
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).unwrap();
    assert!(cal.accepted, "seed {seed} {effects:?}: {}", cal.reason);
    let est = cal.estimate.clone().unwrap();
    let anchor_err_max_m = est.anchors.iter().zip(&truth.anchors).map(|(a, t)| dist(a, t)).fold(0.0, f64::max);

    // Poses across the workspace, each reached at the move speed, then held for 2 s.
    let frac =
        [[0.0, 0.0, 0.0], [0.5, 0.5, -0.5], [-0.5, 0.5, 0.5], [-0.5, -0.5, -0.5], [0.5, -0.5, 0.5], [0.6, 0.0, 0.0], [0.0, -0.6, -0.3]];
    let mut errs = vec![];
    for f in frac {
        let goal: [f64; 3] = std::array::from_fn(|i| centre[i] + f[i] * half[i]);
        d.commands.send(Command::MoveTo(goal)).unwrap();
        let arrived = d.wait_until(Duration::from_secs(60), |l, _| l.snap.fault.is_some() || dist(&l.snap.target_m, &goal) < 1e-9);
        assert!(arrived && d.loop_status().snap.fault.is_none(), "seed {seed}: move to {goal:?} failed: {:?}", d.loop_status().snap.fault);
        std::thread::sleep(Duration::from_secs(2));
        errs.push(dist(&platform.position(), &goal));
    }
    d.commands.send(Command::Stop).unwrap();
    d.wait();
    let current = taut_config::params::ParamsFile::load(dir.path().join("data/params/current.toml")).unwrap();
    assert_eq!(current.format, taut_config::params::FORMAT);
    let reached_rms_m = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
    let r = Run {
        heldout_rms_m: cal.heldout_rms_new_m,
        heldout_initial_m: cal.heldout_rms_old_m,
        anchor_err_max_m,
        reached_rms_m,
        reached_max_m: errs.iter().copied().fold(0.0, f64::max),
        note: est.note.clone(),
        effects: est.effects.clone(),
        file_effects: current.effects.names(),
    };
    eprintln!(
        "E2E-EFFECTS seed {seed} model {:<26} held-out RMS {:.2} mm (initial estimate {:.2} mm), max anchor error {:.1} mm, \
         reached RMS {:.2} mm max {:.2} mm; {}; {:?}",
        if effects.is_empty() { "ideal".to_string() } else { effects.join("+") },
        r.heldout_rms_m * 1e3,
        r.heldout_initial_m * 1e3,
        r.anchor_err_max_m * 1e3,
        r.reached_rms_m * 1e3,
        r.reached_max_m * 1e3,
        r.note,
        r.effects
    );
    r
}

fn seeds() -> Vec<u64> {
    std::env::var("TAUT_E2E_EFFECTS_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![3])
}

fn modelled() -> Vec<String> {
    let list = std::env::var("TAUT_E2E_EFFECTS_MODEL").unwrap_or_else(|_| "elasticity,scale,pulley".into());
    list.split(',').map(|s| s.trim().to_string()).collect()
}

/// What works today: the effect model is fitted at start-up, published as a v2 file with the
/// effects, runs in the loop, and fits the held-out rows better than the ideal model.
#[test]
fn start_up_fits_and_publishes_the_effect_model_and_beats_the_ideal_model_held_out() {
    let m = modelled();
    let m: Vec<&str> = m.iter().map(String::as_str).collect();
    for seed in seeds() {
        let model = run(seed, &m);
        let ideal = run(seed, &[]);
        assert_eq!(model.file_effects, ["elasticity", "scale", "pulley"].iter().filter(|e| m.contains(e)).copied().collect::<Vec<_>>());
        assert!(ideal.file_effects.is_empty());
        assert!(
            model.heldout_rms_m < ideal.heldout_rms_m,
            "seed {seed}: held out {:.2} mm with the model, {:.2} mm without",
            model.heldout_rms_m * 1e3,
            ideal.heldout_rms_m * 1e3
        );
    }
}

/// The acceptance of issue 14 item 3, not met yet (measured on seed 3: held-out 2.95 mm
/// against a 1.5 mm floor, reached RMS 13.2 mm against 14.5 mm ideal; see BENCHMARKS.md):
/// with the model the held-out RMS reaches the noise floor and the platform reaches the
/// commanded poses at least twice as well. Run with `--ignored`.
#[test]
#[ignore = "acceptance not met yet: the start-up's 25 s excitation at 5-35 N does not separate stretch from drum scale on every cable"]
fn start_up_with_the_effect_model_reaches_the_noise_floor_and_the_commanded_poses() {
    let m = modelled();
    let m: Vec<&str> = m.iter().map(String::as_str).collect();
    let noise = taut_sim::Noise::default();
    // The floor of the co-registration RMS: tracker noise along the cable and encoder noise.
    let floor = (noise.tracker_sigma_m.powi(2) + noise.encoder_sigma_m.powi(2)).sqrt();
    for seed in seeds() {
        let model = run(seed, &m);
        let ideal = run(seed, &[]);
        assert!(ideal.heldout_rms_m > 2.0 * floor, "seed {seed}: ideal model held out {:.2} mm", ideal.heldout_rms_m * 1e3);
        // Thousands of held-out readings put the RMS's own sampling error at 1-2 %; the 15 %
        // allows for the tracker's outliers, which the held-out RMS keeps.
        assert!(
            model.heldout_rms_m < 1.15 * floor,
            "seed {seed}: effect model held out {:.2} mm, floor {:.2} mm",
            model.heldout_rms_m * 1e3,
            floor * 1e3
        );
        assert!(
            model.reached_rms_m < 0.5 * ideal.reached_rms_m,
            "seed {seed}: reached RMS {:.2} mm with the model, {:.2} mm without",
            model.reached_rms_m * 1e3,
            ideal.reached_rms_m * 1e3
        );
    }
}
