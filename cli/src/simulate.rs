//! `taut simulate`: write a recording of a simulated robot.

use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use taut_config::RobotConfig;
use taut_sim::Scenario;

/// Arguments of `taut simulate` (shared with `taut demo`).
#[derive(clap::Args, Clone)]
pub struct SimulateArgs {
    /// Robot configuration whose nominal anchors the simulated site deviates from.
    /// Default: the built-in ARAS-CAM-like robot.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output recording (cdpr-recording v1 CSV).
    #[arg(short, long, default_value = "recording.csv")]
    pub output: PathBuf,
    /// Write the simulation truth (anchors, offsets) as taut-params TOML here.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Random seed; the same seed gives the same recording.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Duration of the excitation run, s.
    #[arg(long, default_value_t = 90.0)]
    pub duration: f64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    pub rate: f64,
    /// Fraction of samples that should have a loose cable (excursions to the workspace edge).
    #[arg(long, default_value_t = 0.2)]
    pub loose_fraction: f64,
    /// Leave out the guided three-phase initialisation motion.
    #[arg(long)]
    pub no_three_phase: bool,
    /// Leave out the tensions (a robot without load cells).
    #[arg(long)]
    pub no_tensions: bool,
    /// Switch on cable physics that the ideal model leaves out, e.g. `elasticity=20000`
    /// (EA, N), `sag=0.5` (N/m), `pulley=0.05` (m), `scale=1.002`, `time-offset=0.02` (s),
    /// `backlash=0.002` (m). Repeatable.
    #[arg(long = "effect", value_name = "NAME=VALUE")]
    pub effects: Vec<String>,
}

/// Builds the scenario the arguments describe.
pub fn scenario(a: &SimulateArgs) -> Result<Scenario> {
    let mut s = Scenario::aras_cam(a.seed);
    if let Some(p) = &a.config {
        s.robot = RobotConfig::load(p)?;
        anyhow::ensure!(
            s.robot.anchors().is_some(),
            "{}: every [[cable]] needs a nominal `anchor` to simulate the robot",
            p.display()
        );
    }
    anyhow::ensure!(a.duration > 0.0 && a.rate > 0.0, "--duration and --rate must be positive");
    anyhow::ensure!((0.0..0.9).contains(&a.loose_fraction), "--loose-fraction must be in [0, 0.9)");
    s.duration_s = a.duration;
    s.rate_hz = a.rate;
    s.loose_fraction = a.loose_fraction;
    s.with_tensions = !a.no_tensions;
    if a.no_three_phase {
        s.three_phase = None;
    }
    for e in &a.effects {
        let (name, value) = e
            .split_once('=')
            .with_context(|| format!("--effect `{e}`: expected NAME=VALUE, e.g. elasticity=20000"))?;
        let v: f64 = value.trim().parse().with_context(|| format!("--effect `{e}`: `{value}` is not a number"))?;
        let n = s.robot.cables.len();
        match name.trim() {
            "elasticity" => s.physics.elasticity = Some(v),
            "sag" => s.physics.sag = Some(v),
            "pulley" => s.physics.pulley = Some(v),
            "scale" => s.physics.scale = Some(vec![v; n]),
            "time-offset" => s.physics.time_offset_s = v,
            "backlash" => s.physics.backlash_m = v,
            other => bail!(
                "--effect `{other}` is not a simulated effect; use one of elasticity, sag, pulley, scale, time-offset, backlash"
            ),
        }
    }
    Ok(s)
}

pub fn run(a: &SimulateArgs) -> Result<()> {
    let s = scenario(a)?;
    let run = taut_sim::simulate(&s);
    run.recording.save_atomic(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    eprintln!(
        "wrote {}: {} samples, {} cables, {} samples with a loose cable",
        a.output.display(),
        run.recording.len(),
        run.recording.n_cables,
        run.loose_samples
    );
    if let Some(t) = &a.truth {
        let n = run.truth.anchors.len();
        let p = taut_config::params::ParamsFile {
            format: taut_config::params::FORMAT.into(),
            version: 0,
            created_unix_s: 0.0,
            robot: s.robot.robot.name.clone(),
            source: format!("simulation truth, seed {}", a.seed),
            anchors_m: run.truth.anchors.clone(),
            l0_m: run.truth.l0.clone(),
            anchor_sigma_m: vec![[0.0; 3]; n],
            l0_sigma_m: vec![0.0; n],
            rms_m: 0.0,
            heldout_rms_m: f64::NAN,
        };
        p.save_atomic(t).with_context(|| format!("writing {}", t.display()))?;
    }
    Ok(())
}
