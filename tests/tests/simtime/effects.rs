//! End to end: `taut start --sim` on a site that conceals elasticity (EA 20 kN), drum-scale
//! errors (up to 0.3 %) and 5 cm swivel pulleys, once with the ideal model and once with
//! `[calibration] effects = ["elasticity", "scale", "pulley"]`. The start-up calibration with
//! the effect model reaches the noise floor of the held-out co-registration where the ideal
//! model leaves millimetres, and the platform, commanded to poses across the workspace, ends up
//! nearer them (the simulator's plant knows where it really is). In simulated time (the robot
//! stack in lockstep, `taut_simrig::Lockstep`).
//!
//! `TAUT_E2E_EFFECTS_SEEDS=3,4,5` runs more sites (for BENCHMARKS.md); the default is one.
//! `TAUT_E2E_EFFECTS_MODEL=elasticity,scale` changes the modelled effects,
//! `TAUT_E2E_EFFECTS_CONCEAL=elasticity,scale` the concealed ones.

use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::{Calibrate, Estimate, HeldoutBlocks, OutcomeKind};
use taut_io::EffectsFromFile;
use taut_io::FromRobot;
use taut_plugin::RecordingPath;
use taut_rt::kin::{LoopEffects, LoopParams};
use taut_rt::motion::ControllerConfig;
use taut_sim::Physics;
use taut_simrig::{self as simrig, Lockstep, RunOptions, SimOptions};

/// The simulated robot `taut start --sim` runs, with its files in `dir` and a test-length
/// excitation.
fn robot(dir: &std::path::Path, effects: &[&str]) -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    cfg.motion.excitation_s = 25.0;
    // The Lissajous excitation this acceptance was measured on. The designed tour
    // (`[motion] design_excitation = true`) optimises the anchors only: on seed 3 it
    // left the effect model at 1.84 mm held out (limit 1.73 mm) and the ideal model at 2.96 mm,
    // while the reached RMS fell to 0.69 mm. Designing for the effect parameters too is open.
    cfg.motion.design_excitation = false;
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg.calibration.effects = effects.iter().map(|s| s.to_string()).collect();
    if effects.is_empty() {
        // The ideal model on a site with concealed stretch, scale and pulleys: its residuals
        // are systematic along the path, and the refinement's time-block sandwich sigma says
        // so (~30 mm, the anchors are ~0.1 m off), which the daemon refuses at its default
        // `daemon.max_sigma_m` of 30 mm. This run is the comparison (what the ideal model
        // does in the loop): publish it anyway.
        cfg.daemon.max_sigma_m = 0.2;
        // For the same reason its anchors and offsets may move far from the initial estimate
        // along the scale/offset/anchor trade-off of coplanar anchors: on seed 4 anchor 3 moved
        // 0.543 m and its offset 0.545 m, beyond `daemon.max_anchor_change_m` and
        // `max_l0_change_m` (0.5 m each), and the comparison run was refused.
        cfg.daemon.max_anchor_change_m = 1.0;
        cfg.daemon.max_l0_change_m = 1.0;
    }
    cfg
}

/// The concealed physics: what `taut start --sim --sim-effect elasticity=20000 --sim-effect
/// pulley=0.05` sets, with a drum-scale error that differs per cable.
fn concealed(n: usize) -> Physics {
    let scale = [1.003, 0.998, 1.002, 0.9985];
    let list = std::env::var("TAUT_E2E_EFFECTS_CONCEAL").unwrap_or_else(|_| "elasticity,scale,pulley".into());
    let on = |e: &str| list.split(',').any(|x| taut_config::canonical_effect_name(x.trim()) == e);
    Physics {
        elasticity: on("elasticity").then_some(20_000.0),
        pulley: on("pulley").then_some(0.05),
        scale: on("scale").then(|| (0..n).map(|j| scale[j % 4]).collect()),
        // Drums whose radius shrinks 5 µm per turn paid out (q ~ -6.4e-4 /m).
        drum_buildup_m_per_turn: on("spool-buildup").then_some(-5e-6),
        // Winches, frame and anchors giving 20 mm/kN: about 1 mm at the start-up's tensions.
        compliance_m_per_n: on("compliance").then_some(2e-5),
        ..Physics::default()
    }
}

#[derive(Debug)]
struct Run {
    heldout_rms_m: f64,
    /// Held-out RMS of the initial estimate on the same rows.
    heldout_initial_m: f64,
    /// Held-out rows left out as tracker outliers, of `heldout_rows`.
    heldout_outliers: usize,
    /// Held-out rows with a pose and a taut cable.
    heldout_rows: usize,
    /// Rows the calibration was fitted to (the data set less the held-out rows).
    training_rows: usize,
    /// Held-out RMS of the published set and the initial estimate with the outliers kept.
    heldout_with_outliers_m: [f64; 2],
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

/// A calibration backend that knows the site: it returns the truth (anchors, offsets and the
/// concealed effects) for both the initial estimate and the calibration. With it the loop runs
/// on perfect parameters, which shows the floor the loop itself reaches.
struct TruthCalib(Estimate);

impl TruthCalib {
    fn new(truth: &taut_sim::Truth, physics: &Physics) -> TruthCalib {
        let n = truth.anchors.len();
        let effects = taut_config::params::Effects {
            ea_n: physics.elasticity.map(|ea| vec![ea; n]),
            drum_scale: physics.scale.as_ref().map(|_| truth.scale.clone()),
            pulley_radius_m: physics.pulley.map(|r| vec![r; n]),
            ..Default::default()
        };
        TruthCalib(Estimate {
            model_consistent: None,
            geometry: truth.geometry(),
            sigma: taut_calib::Sigmas::uniform(n, 1e-4),
            rms_m: 0.0,
            observable: true,
            note: "the site's truth".into(),
            effects,
        })
    }
}

impl Calibrate for TruthCalib {
    fn initialise(&mut self, _: &taut_config::recording::Recording) -> Result<Estimate, taut_calibrator::vocab::BackendError> {
        Ok(self.0.clone())
    }
    fn calibrate(&mut self, _: &taut_config::recording::Recording, _: &Estimate) -> Result<Estimate, taut_calibrator::vocab::BackendError> {
        Ok(self.0.clone())
    }
}

/// Which parameters the loop runs on.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Backend {
    /// The daemon's own calibration (`taut-calib`).
    Taut,
    /// The site's truth ([`TruthCalib`]).
    Truth,
}

fn run(seed: u64, effects: &[&str]) -> Run {
    run_with(seed, effects, Backend::Taut)
}

fn run_with(seed: u64, effects: &[&str], backend: Backend) -> Run {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path(), effects);
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let centre: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
    let half: [f64; 3] = std::array::from_fn(|i| (w[1][i] - w[0][i]) / 2.0);
    let so = SimOptions { seed, physics: concealed(cfg.cables.len()), ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, centre);
    let truth = simrig::site_truth(&cfg, &so).unwrap();
    let calib: Box<dyn Calibrate> = match backend {
        Backend::Taut => Box::new(TautCalib::from_config(&cfg)),
        Backend::Truth => Box::new(TruthCalib::new(&truth, &so.physics)),
    };
    // In simulated time: the robot stack in lockstep, the moves below commanded between cycles.
    let mut host = Lockstep::start(&cfg, p0, &so, RunOptions { recording: RecordingPath::Default, ..Default::default() }, calib).unwrap();
    let ok = host.run_until(400.0, taut_tests::startup::start_up_over);
    let l = host.loop_status();
    let c = host.calib_status();
    let reasons: Vec<&str> = c.outcomes.iter().map(|o| o.reason.as_str()).collect();
    assert!(ok && l.snap.fault.is_none(), "seed {seed} {effects:?}: start-up did not finish: {:?} {reasons:?}", l.snap.fault);
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).unwrap();
    assert!(cal.accepted, "seed {seed} {effects:?}: {}", cal.reason);
    let est = cal.estimate.clone().unwrap();
    let anchor_err_max_m = est.geometry.anchors.iter().zip(&truth.anchors).map(|(a, t)| dist(a, t)).fold(0.0, f64::max);

    // Poses across the workspace, each reached at the move speed, then held for 2 s.
    let frac =
        [[0.0, 0.0, 0.0], [0.5, 0.5, -0.5], [-0.5, 0.5, 0.5], [-0.5, -0.5, -0.5], [0.5, -0.5, 0.5], [0.6, 0.0, 0.0], [0.0, -0.6, -0.3]];
    let mut errs = vec![];
    for f in frac {
        let goal: [f64; 3] = std::array::from_fn(|i| centre[i] + f[i] * half[i]);
        host.handle().move_to(goal).unwrap_or_else(|r| panic!("seed {seed}: move to {goal:?} refused: {r}"));
        let arrived = host.run_until(60.0, |l, _| l.snap.fault.is_some() || dist(&l.snap.target_m, &goal) < 1e-9);
        let fault = host.loop_status().snap.fault;
        assert!(arrived && fault.is_none(), "seed {seed}: move to {goal:?} failed: {fault:?}");
        host.run_for(2.0);
        let reached = host.platform().position();
        errs.push(dist(&reached, &goal));
        if std::env::var_os("TAUT_E2E_EFFECTS_DECOMPOSE").is_some() {
            decompose(&host.loop_status().snap, &est, &truth, &so.physics, goal, reached);
        }
    }
    host.handle().stop();
    let recording = host.recording().map(|p| p.to_path_buf());
    host.finish(true);
    if let (Some(rec), true) = (recording, std::env::var_os("TAUT_E2E_KEEP").is_some()) {
        // Keep the recording for a look after a failure.
        let name = format!("taut-e2e-effects-{seed}-{}.csv", if effects.is_empty() { "ideal" } else { "model" });
        let _ = std::fs::copy(rec, std::env::temp_dir().join(name));
    }
    let current = taut_config::params::ParamsFile::load(dir.path().join("data/params/current.toml")).unwrap();
    assert_eq!(current.format, taut_config::params::FORMAT);
    let reached_rms_m = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
    let r = Run {
        heldout_rms_m: cal.heldout_rms_new_m,
        heldout_initial_m: cal.heldout_rms_old_m,
        heldout_outliers: cal.heldout_outliers,
        heldout_rows: cal.heldout_rows,
        training_rows: cal.samples - cal.heldout_rows,
        heldout_with_outliers_m: cal.heldout_rms_with_outliers_m,
        anchor_err_max_m,
        reached_rms_m,
        reached_max_m: errs.iter().copied().fold(0.0, f64::max),
        note: est.note.clone(),
        effects: est.effects.clone(),
        file_effects: current.effects.names(),
    };
    eprintln!(
        "E2E-EFFECTS seed {seed} model {:<26} held-out RMS {:.2} mm (initial estimate {:.2} mm; {} of {} rows left out as \
         tracker outliers, with them {:.2} / {:.2} mm), max anchor error {:.1} mm, reached RMS {:.2} mm max {:.2} mm; {}; {:?}",
        if effects.is_empty() { "ideal".to_string() } else { effects.join("+") },
        r.heldout_rms_m * 1e3,
        r.heldout_initial_m * 1e3,
        r.heldout_outliers,
        r.heldout_rows,
        r.heldout_with_outliers_m[0] * 1e3,
        r.heldout_with_outliers_m[1] * 1e3,
        r.anchor_err_max_m * 1e3,
        r.reached_rms_m * 1e3,
        r.reached_max_m * 1e3,
        r.note,
        r.effects
    );
    r
}

/// Where a reached-pose error comes from, per cable, at rest at a commanded pose: the
/// commanded encoder length (the estimate's inverse kinematics at the goal under the measured
/// tension), the measured one (the drive's following), and the truth's model at the goal and at
/// the reached position under the same tension (parameter error; the model against the plant).
fn decompose(
    snap: &taut_rt::motion::Snapshot,
    est: &Estimate,
    truth: &taut_sim::Truth,
    physics: &Physics,
    goal: [f64; 3],
    reached: [f64; 3],
) {
    let n = truth.anchors.len();
    let platform = &truth.platform_points;
    let e = LoopParams::from_geometry(1, &est.geometry, platform).unwrap().with_effects(LoopEffects::from_file(&est.effects));
    let t = TruthCalib::new(truth, physics).0;
    let tp = LoopParams::from_geometry(1, &t.geometry, platform).unwrap().with_effects(LoopEffects::from_file(&t.effects));
    let inp = &snap.inputs;
    let pose = inp.pose_m;
    eprintln!(
        "DECOMPOSE goal {goal:.3?} reached {reached:.4?} error {:.1} mm, tracker {pose:.4?} ({:.1} mm from the plant)",
        dist(&reached, &goal) * 1e3,
        dist(&pose, &reached) * 1e3
    );
    for j in 0..n {
        let f = inp.tension_n[j];
        eprintln!(
            "  cable {j}: T {f:6.1} N cmd-meas {:+7.2} mm, est(goal)-truth(goal) {:+7.2} mm, meas-truth(reached) {:+7.2} mm, est(goal)-cmd {:+7.2} mm",
            (snap.cmd_m[j] - inp.length_m[j]) * 1e3,
            (e.length_at(j, &goal, f) - tp.length_at(j, &goal, f)) * 1e3,
            (inp.length_m[j] - tp.length_at(j, &reached, f)) * 1e3,
            (e.length_at(j, &goal, f) - snap.cmd_m[j]) * 1e3,
        );
    }
}

fn seeds() -> Vec<u64> {
    std::env::var("TAUT_E2E_EFFECTS_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![3])
}

/// The floor of the loop itself: the same start-up and moves with the site's true parameters
/// published (a test-only backend). Run with `--ignored --nocapture` for the numbers.
#[test]
#[ignore = "diagnostic: prints the reached-pose error with the truth in the loop"]
fn reached_pose_error_with_the_truth_in_the_loop() {
    let m = modelled();
    let m: Vec<&str> = m.iter().map(String::as_str).collect();
    for seed in seeds() {
        run_with(seed, &m, Backend::Truth);
    }
}

fn modelled() -> Vec<String> {
    let list = std::env::var("TAUT_E2E_EFFECTS_MODEL").unwrap_or_else(|_| "elasticity,scale,pulley".into());
    list.split(',').map(|s| taut_config::canonical_effect_name(s.trim()).to_string()).collect()
}

/// Upper bound of the held-out RMS of a model at the noise floor, m, and the floor itself.
///
/// At the floor a held-out residual is the tracker's noise along the cable plus the encoder's:
/// `sigma_f^2 = sigma_t^2 + sigma_e^2` (1.5008 mm; the drum scale and stretch change the
/// gradient's length by < 0.3 %). Per row the squared residuals sum to `delta^T G^T G delta`
/// (one 3-D tracker error seen by `k` cables): a weighted sum of chi-square(1) with weights
/// summing to `k sigma_f^2`, which has at least one degree of freedom (all cables parallel is
/// the worst case). So over `N` held-out rows the mean square is at most as spread as
/// `sigma_f^2 chi^2(N) / N`; its upper quantile at `z` (Wilson-Hilferty) bounds it with
/// probability `1 - Phi(z)` for a model at the floor. Fitting `p` parameters to `n` training
/// rows (3 tracker degrees of freedom each) raises the expected held-out mean square by
/// `p / 3n` (~0.4 % here), added.
fn floor_bound(heldout_rows: usize, training_rows: usize, parameters: usize, z: f64) -> (f64, f64) {
    let noise = taut_sim::Noise::default();
    let floor = (noise.tracker_sigma_m.powi(2) + noise.encoder_sigma_m.powi(2)).sqrt();
    let n = heldout_rows.max(1);
    let ms = taut_calib::selfcal::chi2_quantile(n, z) / n as f64 + parameters as f64 / (3.0 * training_rows.max(1) as f64);
    (floor * ms.sqrt(), floor)
}

/// The acceptance of issue 14 item 3: the effect model is fitted at start-up, published as a
/// v2 file with the effects and runs in the loop; its held-out RMS reaches the noise floor, the
/// ideal model's does not, and the platform reaches the commanded poses at least twice as well
/// as with the ideal model (see BENCHMARKS.md). It needs the followers' tension from the statics
/// (a slack cable put one pose 35 mm off with any parameters), the excitation's tension swing
/// (stretch told from scale) and a held-out check robust to tracker outliers (the simulator's
/// 0.2 % of ~5 cm: two in seed 3's held-out rows took the model from 1.55 to 2.06 mm; the
/// daemon now leaves them out, `taut_calibrator::heldout`).
///
/// The floor bound (`floor_bound`) at z = 3.72: a model truly at the floor fails it with
/// probability 1e-4 per seed (the run's one random assertion that is near its bound; the
/// others have margins of 2-20x, docs/test-robustness.md). The ideal model must be above the
/// same bound: not at the floor, by a statistical test at the same level.
#[test]
fn start_up_with_the_effect_model_reaches_the_noise_floor_and_the_commanded_poses() {
    let m = modelled();
    let m: Vec<&str> = m.iter().map(String::as_str).collect();
    // Anchors and offsets (16), EA and drum scale per cable, one pulley radius.
    let count = |e: &[&str]| {
        16 + 4 * e.iter().filter(|x| **x == "elasticity" || **x == "scale" || **x == "spool-buildup" || **x == "compliance").count()
            + usize::from(e.contains(&"pulley"))
    };
    const Z: f64 = 3.72;
    for seed in seeds() {
        let model = run(seed, &m);
        let ideal = run(seed, &[]);
        assert_eq!(
            model.file_effects,
            ["elasticity", "scale", "pulley", "spool-buildup", "compliance"].iter().filter(|e| m.contains(e)).copied().collect::<Vec<_>>()
        );
        assert!(ideal.file_effects.is_empty());
        let (bound, floor) = floor_bound(model.heldout_rows, model.training_rows, count(&m), Z);
        let (ideal_bound, _) = floor_bound(ideal.heldout_rows, ideal.training_rows, count(&[]), Z);
        eprintln!(
            "E2E-EFFECTS seed {seed}: floor {:.3} mm; effect model {:.3} mm against its bound {:.3} mm ({} held-out rows, {} outliers); \
             ideal {:.3} mm against {:.3} mm ({} rows, {} outliers)",
            floor * 1e3,
            model.heldout_rms_m * 1e3,
            bound * 1e3,
            model.heldout_rows,
            model.heldout_outliers,
            ideal.heldout_rms_m * 1e3,
            ideal_bound * 1e3,
            ideal.heldout_rows,
            ideal.heldout_outliers
        );
        assert!(
            model.heldout_rms_m < bound,
            "seed {seed}: effect model held out {:.2} mm, above the floor's bound {:.2} mm (floor {:.2} mm)",
            model.heldout_rms_m * 1e3,
            bound * 1e3,
            floor * 1e3
        );
        assert!(
            ideal.heldout_rms_m > ideal_bound,
            "seed {seed}: ideal model held out {:.2} mm, within the floor's bound {:.2} mm",
            ideal.heldout_rms_m * 1e3,
            ideal_bound * 1e3
        );
        assert!(
            model.heldout_rms_m < ideal.heldout_rms_m,
            "seed {seed}: held out {:.2} mm with the model, {:.2} mm without",
            model.heldout_rms_m * 1e3,
            ideal.heldout_rms_m * 1e3
        );
        assert!(
            model.reached_rms_m < 0.5 * ideal.reached_rms_m,
            "seed {seed}: reached RMS {:.2} mm with the model, {:.2} mm without",
            model.reached_rms_m * 1e3,
            ideal.reached_rms_m * 1e3
        );
    }
}

/// Offline look at a kept start-up recording (`TAUT_E2E_KEEP=1`): the daemon's backend on its
/// excitation, and the fit with effects from the site's truth, with the held-out RMS of each.
/// `TAUT_E2E_EFFECTS_CSV=/tmp/taut-e2e-effects-3-model.csv` (seed from `TAUT_E2E_EFFECTS_SEEDS`).
#[test]
#[ignore = "diagnostic on a kept recording"]
fn offline_fit_of_a_kept_start_up_recording() {
    use taut_calib::effect_fit::{fit_effects, EffectFitOptions};
    let Some(path) = std::env::var_os("TAUT_E2E_EFFECTS_CSV") else { return };
    let text = std::fs::read_to_string(&path).unwrap();
    let states: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).skip(1).map(|l| l.rsplit(',').next().unwrap_or("")).collect();
    let e0 = states.iter().position(|s| *s == "excitation").unwrap();
    let e1 = e0 + states[e0..].iter().take_while(|s| **s == "excitation").count();
    let (rec, _) = taut_config::recording::Recording::load(&path).unwrap();
    let seed = seeds()[0];
    let m = modelled();
    let m: Vec<&str> = m.iter().map(String::as_str).collect();
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path(), &m);
    let so = SimOptions { seed, physics: concealed(cfg.cables.len()), ..Default::default() };
    let truth = taut_sim::Truth::sample(&cfg, &so.physics, so.site_error_m, so.l0_range_m, &mut taut_sim::rng(seed, 0)).unwrap();
    // The daemon's rows: one per fresh tracker pose (the CSV repeats a pose until the next one
    // arrives), every `calib_decimation`-th; the lengths are the loop's at that sample, not
    // interpolated at the pose's instant as the daemon does (a few tenths of a mm at speed).
    let fresh: Vec<std::ops::Range<usize>> = (e0..e1)
        .filter(|&i| i == 0 || rec.p[i] != rec.p[i - 1])
        .filter(|&i| rec.p[i].iter().all(|x| x.is_finite()))
        .step_by(cfg.daemon.calib_decimation.max(1))
        .map(|i| i..i + 1)
        .collect();
    let exc = rec.gather(&fresh);
    let (train, held) = HeldoutBlocks::new(exc.len(), cfg.calibration.heldout_fraction).split(&exc);
    let platform = cfg.platform_points();
    let heldout = |g: &taut_calib::Geometry, e: &taut_config::params::Effects| {
        let p = LoopParams::from_geometry(1, g, &platform).unwrap().with_effects(LoopEffects::from_file(e));
        p.coregistration_rms((0..held.len()).map(|i| (&held.p[i], held.lengths(i), held.tensions(i))), cfg.calibration.min_tension_n)
            .unwrap()
    };
    let aerr = |anchors: &[[f64; 3]]| anchors.iter().zip(&truth.anchors).map(|(a, t)| dist(a, t)).fold(0.0, f64::max);
    let mut backend = TautCalib::from_config(&cfg);
    let init = backend.initialise(&rec.slice(0..e0)).unwrap();
    let t0 = std::time::Instant::now();
    let est = backend.calibrate(&train, &init).unwrap();
    eprintln!(
        "OFFLINE backend: held out {:.2} mm, anchors {:.1} mm, {:.1} s; {:?}; {}",
        heldout(&est.geometry, &est.effects) * 1e3,
        aerr(&est.geometry.anchors) * 1e3,
        t0.elapsed().as_secs_f64(),
        est.effects,
        est.note
    );
    let t = TruthCalib::new(&truth, &so.physics).0;
    eprintln!("OFFLINE truth: held out {:.2} mm", heldout(&t.geometry, &t.effects) * 1e3);
    // The held-out rows' tracker outliers (the daemon's rule), the fitted set against the truth.
    let lp = |g: &taut_calib::Geometry, e: &taut_config::params::Effects| {
        LoopParams::from_geometry(1, g, &platform).unwrap().with_effects(LoopEffects::from_file(e))
    };
    let cmp = taut_calibrator::heldout::HeldoutComparison::new(
        &lp(&est.geometry, &est.effects),
        &lp(&t.geometry, &t.effects),
        &held,
        cfg.calibration.min_tension_n,
    );
    eprintln!("OFFLINE held-out outliers (fitted vs truth, threshold {:.1} sigma): {:?}", cmp.threshold_sigma, cmp.rms());
    // After the daemon's wild-value screen (which runs on the held-out rows first).
    let sc = taut_calib::screen::screen(
        &held,
        &taut_calib::screen::ScreenOptions { jumps: false, ..taut_calib::screen::ScreenOptions::new(cfg.calibration.min_tension_n) },
    );
    let screened = sc.cleaned.unwrap_or(held.clone());
    let cmp = taut_calibrator::heldout::HeldoutComparison::new(
        &lp(&est.geometry, &est.effects),
        &lp(&t.geometry, &t.effects),
        &screened,
        cfg.calibration.min_tension_n,
    );
    eprintln!(
        "OFFLINE screen: {} findings {:?}; then {:?}",
        sc.findings.len(),
        sc.findings.iter().map(|w| w.to_string()).collect::<Vec<_>>(),
        cmp.rms()
    );
    let c = &cfg.calibration;
    for iters in [80, 400] {
        let o =
            EffectFitOptions { max_iterations: iters, ..EffectFitOptions::new(&m, c.min_tension_n, c.tracker_sigma_m, c.encoder_sigma_m) };
        for (name, a, l0) in [("truth", &truth.anchors, &truth.l0), ("init", &init.geometry.anchors, &init.geometry.l0)] {
            match fit_effects(&train, &platform, a, l0, &Default::default(), &o) {
                Ok(f) => eprintln!(
                    "OFFLINE fit from {name}, {iters} iterations: held out {:.2} mm, train {:.2} mm, anchors {:.1} mm, {} iterations; EA {:?} scale {:?} pulley {:?}",
                    heldout(&f.params, &f.effects) * 1e3,
                    f.rms_m * 1e3,
                    aerr(&f.params.anchors) * 1e3,
                    f.iterations,
                    f.effects.ea_n,
                    f.effects.drum_scale,
                    f.effects.pulley_radius_m
                ),
                Err(e) => eprintln!("OFFLINE fit from {name}: {e}"),
            }
        }
    }
}
