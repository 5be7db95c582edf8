//! Effect-free simulated recordings for the false-claim rate of `taut diagnose`: 3-, 4- and
//! 8-cable robots and the 20 m outdoor robot, at three noise levels, each with its own seed.
//! Shared by `tests/diagnose_null.rs` (a subset, in CI) and `examples/null_rate.rs` (the sweep).

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect};
use taut_sim::{try_simulate, Physics, Scenario};

/// Geometries of the sweep.
pub const GEOMETRIES: [&str; 4] = ["three-cable", "aras-cam", "octagon-8", "outdoor-20m"];

/// Noise levels (multiples of the default tracker and encoder noise).
pub const NOISE_LEVELS: [f64; 3] = [0.5, 1.0, 2.0];

/// An 8-cable robot: anchors on a regular octagon of radius 4 m, 4 m up, 5 kg platform.
fn octagon(seed: u64) -> Scenario {
    let mut s = Scenario::aras_cam(seed);
    let mut cfg = taut_config::RobotConfig::point_mass(8);
    cfg.robot.name = "octagon-8".into();
    cfg.robot.mass_kg = 5.0;
    for (k, c) in cfg.cables.iter_mut().enumerate() {
        let a = (k as f64 + 0.5) * std::f64::consts::TAU / 8.0;
        c.anchor = Some([4.0 * a.cos(), 4.0 * a.sin(), 4.0]);
    }
    s.robot = cfg;
    // The three-phase plan pairs cables for 3 or 4 anchors; the 8-cable robot records the
    // excitation only (the diagnosis then starts from the calibration's initialisation).
    s.three_phase = None;
    s
}

/// Effect-free case `k`: geometry `k % 4`, noise level `(k / 4) % 3`, seed `1000 + k`; loose
/// cables are on (they are found and excluded, never an effect). Returns the scenario and the
/// recording's duration, s.
pub fn case(k: usize) -> (Scenario, f64) {
    let seed = 1000 + k as u64;
    let geometry = GEOMETRIES[k % GEOMETRIES.len()];
    let mut s = match geometry {
        "three-cable" => Scenario::three_cable(seed),
        "aras-cam" => Scenario::aras_cam(seed),
        "octagon-8" => octagon(seed),
        _ => Scenario::outdoor(seed),
    };
    s.physics = Physics::default();
    let f = NOISE_LEVELS[(k / GEOMETRIES.len()) % NOISE_LEVELS.len()];
    s.noise.tracker_sigma_m *= f;
    s.noise.encoder_sigma_m *= f;
    // The diagnosis is told the noise the sensors have (as a configuration states it).
    s.robot.calibration.tracker_sigma_m = s.noise.tracker_sigma_m;
    s.robot.calibration.encoder_sigma_m = s.noise.encoder_sigma_m;
    let duration = if geometry == "outdoor-20m" { 60.0 } else { 40.0 };
    (s, duration)
}

/// A one-line description of case `k`.
pub fn describe(k: usize) -> String {
    format!("{} noise x{} seed {}", GEOMETRIES[k % GEOMETRIES.len()], NOISE_LEVELS[(k / GEOMETRIES.len()) % NOISE_LEVELS.len()], 1000 + k)
}

/// Simulates and diagnoses case `k`. A seed whose motion the simulator cannot hold in static
/// equilibrium (a rare planned pose at the workspace edge) is replaced by the seed 10,000 higher.
pub fn diagnose_case(k: usize) -> Diagnosis {
    let (mut s, duration) = case(k);
    s.duration_s = duration;
    let sim = loop {
        match try_simulate(&s) {
            Ok(sim) => break sim,
            Err(e) if s.seed < 100_000 => {
                eprintln!("{}: seed {} not simulated ({e}); next seed", describe(k), s.seed);
                s.seed += 10_000;
            }
            Err(e) => panic!("{}: {e}", describe(k)),
        }
    };
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis")
}

/// The effects named (slack aside).
pub fn claims(d: &Diagnosis) -> Vec<Effect> {
    d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect()
}
