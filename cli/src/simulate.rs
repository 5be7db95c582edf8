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
    /// Output recording (cdpr-recording v1 CSV); by default recording.csv in the current
    /// directory.
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
    /// `backlash=0.002` (m), `spool-buildup=-5e-6` (m per turn; `drum-buildup` too),
    /// `loadcell-gain=1.03` (`load-cell-gain` too), `friction=0.2` (mu theta), `compliance=1.5e-6`
    /// (m/N). Repeatable.
    #[arg(long = "effect", value_name = "NAME=VALUE")]
    pub effects: Vec<String>,
}

/// Sample rates the simulator accepts, Hz: the loop's own range (`[rt] rate_hz`).
pub const RATE_HZ: (f64, f64) = (1.0, 10_000.0);

/// Longest excitation, s (a day).
pub const MAX_DURATION_S: f64 = 86_400.0;

/// Most excitation samples (`duration x rate`), checked before anything is allocated: 2 million
/// samples is 5.5 h at 100 Hz, a few hundred MB in memory.
pub const MAX_SAMPLES: f64 = 2.0e6;

/// The simulated effects, their unit and the physical range of their value.
pub const EFFECTS: [(&str, &str, f64, f64, &str); 10] = [
    // EA of a real cable: 1 kN (an elastic cord) to 100 MN (a 35 mm steel rope); stiffer cables
    // are rigid for the plant's equilibrium search.
    ("elasticity", "N", 1e3, 1e8, "axial stiffness EA"),
    // Weight per length: 0 to 20 N/m (a 20 mm steel rope). Heavy cables on a light platform can
    // still have no catenary solution: the simulator then says so.
    ("sag", "N/m", 0.0, 20.0, "cable weight per length"),
    ("pulley", "m", 0.0, 0.5, "pulley radius"),
    // A drum radius error of +-10 %.
    ("scale", "", 0.9, 1.1, "encoder scale"),
    ("time-offset", "s", -1.0, 1.0, "encoder lag behind the tracker"),
    ("backlash", "m", 0.0, 0.05, "play in the drive train"),
    // Radius change per turn paid out on the simulator's 25 mm drums: -0.2 mm (a 1 mm cable,
    // five turns a layer, paid out of a full drum) keeps a radius at 10 m paid out.
    ("spool-buildup", "m", -2e-4, 2e-4, "drum radius change per turn paid out"),
    // A cell 20 % off is a wiring or scaling fault, not a gain error.
    ("loadcell-gain", "", 0.8, 1.25, "load-cell gain"),
    // mu theta: a coefficient of 0.3 over a wrap of 190 degrees is about 1.
    ("friction", "", 0.0, 1.0, "guide friction mu*theta"),
    // A winch, frame or anchor that gives 1 mm per newton is a spring, not a frame.
    ("compliance", "m/N", 0.0, 1e-3, "winch/frame/anchor compliance"),
];

/// A number for a message: plain when of an everyday size, else in e-notation (1e300 is not
/// three hundred digits).
fn human(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-3..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Builds the scenario the arguments describe.
pub fn scenario(a: &SimulateArgs) -> Result<Scenario> {
    let mut s = Scenario::aras_cam(a.seed);
    if let Some(p) = &a.config {
        s.robot = RobotConfig::load(p)?;
        anyhow::ensure!(s.robot.anchors().is_some(), "{}: every [[cable]] needs a nominal `anchor` to simulate the robot", p.display());
    }
    anyhow::ensure!(
        a.rate.is_finite() && (RATE_HZ.0..=RATE_HZ.1).contains(&a.rate),
        "--rate {}: the sample rate must be {} to {} Hz",
        human(a.rate),
        RATE_HZ.0,
        RATE_HZ.1
    );
    anyhow::ensure!(
        a.duration.is_finite() && a.duration > 0.0 && a.duration <= MAX_DURATION_S,
        "--duration {}: the excitation must last more than 0 and at most {MAX_DURATION_S} s",
        human(a.duration)
    );
    anyhow::ensure!(
        a.duration * a.rate <= MAX_SAMPLES,
        "--duration {} s at --rate {} Hz is {:.3e} samples, more than the {MAX_SAMPLES:.0e} a simulated recording may have; \
         shorten it or lower the rate",
        a.duration,
        a.rate,
        a.duration * a.rate
    );
    anyhow::ensure!((0.0..0.9).contains(&a.loose_fraction), "--loose-fraction {}: must be in [0, 0.9)", a.loose_fraction);
    s.duration_s = a.duration;
    s.rate_hz = a.rate;
    s.loose_fraction = a.loose_fraction;
    s.with_tensions = !a.no_tensions;
    if a.no_three_phase {
        s.three_phase = None;
    }
    let n = s.robot.cables.len();
    apply_effects(&a.effects, n, &mut s.physics, "--effect")?;
    Ok(s)
}

/// Sets the effects given as `NAME=VALUE` (`flag` names the option in messages) on `physics`
/// for `n` cables: each a simulated effect, a number in its physical range, given once.
pub fn apply_effects(effects: &[String], n: usize, physics: &mut taut_sim::Physics, flag: &str) -> Result<()> {
    let mut seen = Vec::new();
    for e in effects {
        let shown = taut_config::recording::excerpt(e);
        let (name, value) = e.split_once('=').with_context(|| format!("{flag} `{shown}`: expected NAME=VALUE, e.g. elasticity=20000"))?;
        let name = taut_config::canonical_effect_name(name.trim());
        let Some(&(_, unit, lo, hi, what)) = EFFECTS.iter().find(|x| x.0 == name) else {
            bail!(
                "{flag} `{}` is not a simulated effect; use one of {}",
                taut_config::recording::excerpt(name),
                EFFECTS.map(|x| x.0).join(", ")
            )
        };
        let v: f64 = value
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("{flag} `{shown}`: `{}` is not a number", taut_config::recording::excerpt(value)))?;
        anyhow::ensure!(
            v.is_finite() && v >= lo && v <= hi,
            "{flag} {name}={}: the {what} must be {} to {}{}{unit}",
            human(v),
            human(lo),
            human(hi),
            if unit.is_empty() { "" } else { " " }
        );
        anyhow::ensure!(!seen.contains(&name), "{flag} {name} is given twice; give each effect once");
        seen.push(name);
        match name {
            "elasticity" => physics.elasticity = Some(v),
            "sag" => physics.sag = Some(v),
            "pulley" => physics.pulley = Some(v),
            "scale" => physics.scale = Some(vec![v; n]),
            "time-offset" => physics.time_offset_s = v,
            "backlash" => physics.backlash_m = v,
            "spool-buildup" => physics.drum_buildup_m_per_turn = Some(v),
            "loadcell-gain" => physics.loadcell_gain = Some(vec![v; n]),
            "friction" => physics.friction_mu_theta = Some(v),
            "compliance" => physics.compliance_m_per_n = Some(v),
            _ => unreachable!("every name in EFFECTS is matched"),
        }
    }
    Ok(())
}

pub fn run(a: &SimulateArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = a.config.iter().map(|p| p.as_path()).collect();
    let files: Vec<crate::outputs::Output> = [("--output", Some(&a.output)), ("--truth", a.truth.as_ref())]
        .into_iter()
        .filter_map(|(f, p)| p.map(|p| (f, p.as_path())))
        .collect();
    crate::outputs::check(&files, &[], &inputs)?;
    let s = scenario(a)?;
    let run = taut_sim::try_simulate(&s).map_err(|e| anyhow::anyhow!("cannot simulate this robot: {e}"))?;
    run.recording.save_atomic(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    eprintln!(
        "wrote {}: {} samples, {} cables, {} samples with a loose cable",
        a.output.display(),
        run.recording.len(),
        run.recording.n_cables,
        run.loose_samples
    );
    if let Some(t) = &a.truth {
        write_truth(t, &s, a.seed, &run)?;
    }
    Ok(())
}

/// Writes the simulation truth (anchors, offsets) as a taut-params file.
pub fn write_truth(t: &std::path::Path, s: &Scenario, seed: u64, run: &taut_sim::SimRun) -> Result<()> {
    let n = run.truth.anchors.len();
    let p = taut_config::params::ParamsFile {
        robot: s.robot.robot.name.clone(),
        source: format!("simulation truth, seed {seed}"),
        rms_m: 0.0,
        heldout_rms_m: f64::NAN,
        // The concealed effects, as the robot's model would hold them.
        effects: taut_config::params::Effects {
            ea_n: s.physics.elasticity.map(|ea| vec![ea; n]),
            drum_scale: s.physics.scale.clone(),
            pulley_radius_m: s.physics.pulley.map(|r| vec![r; n]),
            backlash_m: (s.physics.backlash_m > 0.0).then(|| vec![s.physics.backlash_m; n]),
            time_offset_s: (s.physics.time_offset_s != 0.0).then_some(s.physics.time_offset_s),
            drum_buildup_per_m: s.physics.drum().map(|d| vec![d.quadratic_per_m(); n]),
            loadcell_gain: s.physics.loadcell_gain.clone(),
            friction_mu_theta: s.physics.friction_mu_theta.filter(|c| *c != 0.0).map(|c| vec![c; n]),
            compliance_m_per_n: s.physics.compliance_m_per_n.filter(|c| *c != 0.0).map(|c| vec![c; n]),
            ..Default::default()
        },
        ..taut_config::params::ParamsFile::from_geometry(&run.truth.geometry(), &taut_config::params::Sigmas::uniform(n, 0.0))
    };
    p.save_atomic(t).with_context(|| format!("writing {}", t.display()))
}
