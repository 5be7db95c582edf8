//! Effect-free simulated recordings for the false-claim rate of `taut diagnose`: 3-, 4- and
//! 8-cable robots and the 20 m outdoor robot, at three noise levels, each with its own seed.
//! Shared by `tests/diagnose_null.rs` (a subset, in CI) and `examples/null_rate.rs` (the sweep).

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect};
use taut_sim::{try_simulate, Physics, Scenario};

/// Geometries of the sweep.
pub const GEOMETRIES: [&str; 4] = ["three-cable", "aras-cam", "octagon-8", "outdoor-20m"];

/// Noise levels (multiples of the default tracker and encoder noise).
pub const NOISE_LEVELS: [f64; 3] = [0.5, 1.0, 2.0];

/// Effect-free case `k`: geometry `k % 4`, noise level `(k / 4) % 3`, seed `1000 + k`; loose
/// cables are on (they are found and excluded, never an effect). Returns the scenario and the
/// recording's duration, s.
pub fn case(k: usize) -> (Scenario, f64) {
    let seed = 1000 + k as u64;
    let geometry = GEOMETRIES[k % GEOMETRIES.len()];
    let mut s = match geometry {
        "three-cable" => Scenario::three_cable(seed),
        "aras-cam" => Scenario::aras_cam(seed),
        "octagon-8" => Scenario {
            // The three-phase plan pairs cables for 3 or 4 anchors; the 8-cable robot records the
            // excitation only (the diagnosis then starts from the calibration's initialisation).
            three_phase: None,
            ..Scenario::octagon(seed)
        },
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
#[allow(dead_code)]
pub fn diagnose_case(k: usize) -> Diagnosis {
    diagnose_with(k, Variant::Sim, true)
}

/// What an effect-free recording is made of, to split the causes of the p-values' tail
/// (`examples/null_rate.rs`, `NULL_VARIANT`): the simulator as it is, the simulator without one
/// kind of structure, or the ideal model itself along the simulator's path.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(dead_code)]
pub enum Variant {
    /// The simulator as it is (what `diagnose_null` runs).
    Sim,
    /// No tracker outliers.
    NoOutliers,
    /// No loose-cable excursions.
    NoLoose,
    /// Neither outliers nor loose cables nor dropouts, encoders not quantised.
    Clean,
    /// The ideal model along the simulated path: readings `|P + b - A| + L0` of the true
    /// positions plus white Gaussian encoder and tracker noise (the recording's sigmas); true
    /// tensions.
    Ideal,
    /// As [`Variant::Ideal`] with AR(1) tracker noise, lag-1 coefficient 0.9 per sample
    /// (`NULL_AR_PHI` sets another).
    IdealAr1,
    /// The simulator as it is with its AR(1) tracker noise (`Noise::tracker_phi`, the same
    /// marginal sigma), lag-1 coefficient 0.9 per sample (`NULL_AR_PHI` sets another).
    SimAr1,
}

#[allow(dead_code)]
impl Variant {
    /// From a name (`sim`, `no-outliers`, `no-loose`, `clean`, `ideal`, `ideal-ar1`, `sim-ar1`).
    pub fn parse(s: &str) -> Option<Variant> {
        Some(match s {
            "sim" => Variant::Sim,
            "no-outliers" => Variant::NoOutliers,
            "no-loose" => Variant::NoLoose,
            "clean" => Variant::Clean,
            "ideal" => Variant::Ideal,
            "ideal-ar1" => Variant::IdealAr1,
            "sim-ar1" => Variant::SimAr1,
            _ => return None,
        })
    }
}

/// The lag-1 coefficient of [`Variant::IdealAr1`]'s and [`Variant::SimAr1`]'s tracker noise: `NULL_AR_PHI`, default 0.9.
pub fn ar1_phi() -> f64 {
    std::env::var("NULL_AR_PHI").ok().and_then(|v| v.parse().ok()).filter(|p: &f64| (0.0..1.0).contains(p)).unwrap_or(0.9)
}

/// The ideal model's readings along a simulated path (see [`Variant::Ideal`]).
fn ideal_recording(sim: &taut_sim::SimRun, s: &Scenario, phi: f64) -> taut_config::recording::Recording {
    use taut_calib::synth::Rng;
    let rec = &sim.recording;
    let n = rec.n_cables;
    let tr = &sim.truth;
    let mut out = taut_config::recording::Recording::with_capacity(n, rec.len(), rec.f.is_some(), false, rec.phase.is_some());
    let mut rng = Rng::new(s.seed ^ 0x1dea1);
    let innov = (1.0 - phi * phi).sqrt();
    let mut e: [f64; 3] = std::array::from_fn(|_| rng.normal());
    let mut l = vec![0.0; n];
    for i in 0..rec.len() {
        let p = sim.positions[i];
        for (j, lj) in l.iter_mut().enumerate() {
            let b = tr.platform_points[j];
            let a = tr.anchors[j];
            let d = [p[0] + b[0] - a[0], p[1] + b[1] - a[1], p[2] + b[2] - a[2]];
            *lj = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() + tr.l0[j] + s.noise.encoder_sigma_m * rng.normal();
        }
        let pm: [f64; 3] = std::array::from_fn(|k| p[k] + s.noise.tracker_sigma_m * e[k]);
        for v in e.iter_mut() {
            *v = phi * *v + innov * rng.normal();
        }
        let f = rec.f.as_ref().map(|_| &sim.tensions[i * n..(i + 1) * n]);
        out.push(rec.t[i], pm, None, &l, f, rec.phase.as_ref().map(|ph| ph[i]));
    }
    out
}

/// Simulates and diagnoses case `k` as `variant` makes it (see [`diagnose_case`]), with the
/// held-out tests' estimation-error term on or off ([`DiagnoseOptions::estimation_error`]).
pub fn diagnose_with(k: usize, variant: Variant, estimation_error: bool) -> Diagnosis {
    let (mut s, duration) = case(k);
    s.duration_s = duration;
    match variant {
        Variant::NoOutliers => s.noise.tracker_outlier_prob = 0.0,
        Variant::NoLoose => s.loose_fraction = 0.0,
        Variant::Clean => {
            s.noise.tracker_outlier_prob = 0.0;
            s.noise.tracker_dropout_prob = 0.0;
            s.noise.encoder_quantum_m = 0.0;
            s.loose_fraction = 0.0;
        }
        Variant::SimAr1 => s.noise.tracker_phi = ar1_phi(),
        _ => {}
    }
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
    let mut opts = DiagnoseOptions { estimation_error, ..DiagnoseOptions::from_config(&s.robot.calibration) };
    // `NULL_TENSION=1`: the tension side too (the platform's mass and the cells' noise given).
    if std::env::var("NULL_TENSION").is_ok_and(|v| v == "1") {
        opts.platform_mass_kg = Some(s.robot.robot.mass_kg);
        opts.loadcell_sigma_n = s.noise.loadcell_sigma_n;
    }
    let rec = match variant {
        Variant::Ideal => ideal_recording(&sim, &s, 0.0),
        Variant::IdealAr1 => ideal_recording(&sim, &s, ar1_phi()),
        _ => sim.recording.clone(),
    };
    diagnose(&rec, &sim.truth.platform_points, None, &opts).expect("diagnosis")
}

/// The effects named (slack aside).
pub fn claims(d: &Diagnosis) -> Vec<Effect> {
    d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect()
}
