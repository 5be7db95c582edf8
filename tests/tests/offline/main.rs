//! Tests that need no devices, no device threads and no motion in real time: the calibrator,
//! the diagnosis and self-calibration on simulated recordings, the `taut` binary's offline
//! commands (`calibrate`, `diagnose`, `export`, reports) under hostile input, parameter files,
//! the workspace's dependency rules and the udev files. One test binary, a module per subject.

/// The hostile-input suite's runner (the `taut` binary in a fresh directory with a deadline).
#[path = "../../src/hostile.rs"]
mod hostile;
/// The effect-free recordings of the null-rate sweep.
#[path = "../support/null_cases.rs"]
mod null_cases;

/// `taut diagnose rec.csv --config <cfg> --json <out>` in `dir`, its JSON.
fn taut_diagnose(dir: &std::path::Path, cfg: &taut_config::RobotConfig, name: &str) -> serde_json::Value {
    let toml = dir.join(format!("{name}.toml"));
    cfg.save_atomic(&toml).unwrap();
    let json = dir.join(format!("{name}.json"));
    let out = std::process::Command::new(hostile::taut_bin())
        .current_dir(dir)
        .args(["diagnose", "rec.csv", "--config"])
        .arg(&toml)
        .arg("--json")
        .arg(&json)
        .output()
        .expect("running taut diagnose");
    assert!(out.status.success(), "{name}: {}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap()
}

/// A standard normal draw from `rng` (Box-Muller).
fn gauss(rng: &mut rand_chacha::ChaCha8Rng) -> f64 {
    use rand::Rng;
    let (u1, u2): (f64, f64) = (rng.gen::<f64>().max(1e-300), rng.gen());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

mod accuracy_sim;
mod calibrate_notracker;
mod crate_graph;
mod diagnose_buildup;
mod diagnose_compliance;
mod diagnose_concealed;
mod diagnose_data_problems;
mod diagnose_eiv;
mod diagnose_loadcell_key;
mod diagnose_null;
mod diagnose_outside;
mod diagnose_pairs;
mod diagnose_ptail;
mod diagnose_pulley_axis;
mod diagnose_short;
mod diagnose_tension;
mod hostile_args;
mod hostile_config;
mod hostile_outputs;
mod hostile_recordings;
mod hostile_wild_values;
mod mcap_export;
mod model_consistency;
mod params_v2;
mod priors;
mod report_html;
mod selfcal;
mod selfcal_priors;
mod swapped_cables;
mod udev_rules;
