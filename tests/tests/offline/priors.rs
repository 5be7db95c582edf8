//! Priors from the design: a robot recorded with its winches locked while the
//! platform swings freely (pushed every 4 s), calibrated with the design's anchors as priors.
//!
//! The recordings come from the simulator's dynamic plant (`taut_sim::Dynamics`, independent of
//! the calibration's model): the four drums held at lengths 1-3 cm longer than the platform's
//! rest needs, so that it hangs on two or three cables and swings after a push, its cables going
//! slack and taut again; tracker at 100 Hz (1.5 mm), encoders and load cells with the default
//! noise. The encoders read constant lengths: the offsets are not excited and the anchors only
//! along the swing, which the initialisation refuses ("not excited"). The design: every anchor
//! off the truth by a draw of 2 cm per axis, `anchor_sigma_m = 0.02`. Two robots:
//! - `locked_winches_calibrate_with_the_designs_priors`: ARAS-CAM's frame, a point-mass
//!   platform (orientation fixed, platform points at the reference point);
//! - `locked_winches_6dof_calibrate_with_the_designs_priors`: a 2 m frame and a 13 kg rigid
//!   platform (`taut_sim::RigidBody`) with its cables at the corners of a 0.3 m x 0.2 m
//!   rectangle; each push also twists it, so it swings and rotates (up to 13-50 degrees per
//!   recording); the tracker also reports the orientation (0.1 degree per axis) and the
//!   calibration uses it with the platform points.
//!
//! Asserted over [`SEEDS`] seeds, for each robot:
//! - the calibration runs (no refusal) and every anchor coordinate's sigma is at most its
//!   prior's, smaller where the data inform: the cables the swing keeps taut (a data share of
//!   0.1 or more on some coordinate in at least 15 of the 20 recordings; point mass: 18
//!   measured, shares up to 0.6, the cables that stay slack keep their prior; 6-DoF: 20
//!   measured, shares up to 0.8);
//! - at least 90 % of the anchor coordinates are within 2 sigma of the truth (a correct
//!   Gaussian posterior puts 95.4 % there; with 20 x 12 coordinates, 90 % is 4.5 binomial sigmas
//!   below that; measured 94.6 % for the point mass, 96.7 % for the 6-DoF platform, which falls
//!   to 2 % when its recording's orientation is replaced by the identity);
//! - without the priors the same recordings are refused.
//!
//! `locked_winches_are_diagnosed_with_the_designs_priors`: the diagnosis (`taut diagnose`) of
//! the point-mass recordings. Without priors its baseline starts from algebraic multilateration
//! and lands metres off; with them it starts from the design and every fit is maximum a
//! posteriori: at least 90 % of the anchor coordinates of its baseline and final fits within 2
//! sigma of the truth over [`DIAGNOSE_SEEDS`] seeds (measured 95.0 %).

use crate::gauss;
use taut_calib::{init, noise, CalibOptions};
use taut_config::recording::Recording;
use taut_sim::{CableCommand, Dynamics, Noise, Physics, RigidBody, Scenario};

/// Recordings in the test.
const SEEDS: u64 = 20;
/// How much longer than the rest needs each drum is locked: `a + b U(0, 1)`, m.
const LOCK_SLACK_M: (f64, f64) = (0.01, 0.03);
/// 1-sigma of the push's horizontal speed, m/s.
const PUSH_M_S: f64 = 0.8;
/// Recordings diagnosed (a diagnosis takes ~0.5 s).
const DIAGNOSE_SEEDS: u64 = 10;
/// The design's tolerance, 1-sigma per axis, m.
const PRIOR_SIGMA_M: f64 = 0.02;

/// `s`'s dynamic plant with its drums locked a little long (`LOCK_SLACK_M`, drawn from `rng`),
/// so that the platform sags onto two or three cables and can swing, after 2 s of settling: the
/// plant, the rest lengths and the locked commands.
fn locked(s: &Scenario, rng: &mut rand_chacha::ChaCha8Rng) -> (taut_sim::Plant, Vec<f64>, Vec<CableCommand>) {
    let (mut plant, hold) = s.plant().unwrap();
    let cmds: Vec<CableCommand> =
        hold.iter().map(|&l| CableCommand::Length(l + LOCK_SLACK_M.0 + LOCK_SLACK_M.1 * rand::Rng::gen::<f64>(rng))).collect();
    for _ in 0..2000 {
        plant.step(1e-3, &cmds);
    }
    (plant, hold, cmds)
}

/// A locked-winch swing of 20 s: the recording and the true anchors.
fn locked_swing(seed: u64) -> (Recording, Vec<[f64; 3]>) {
    use rand::SeedableRng;
    let mut s = Scenario::aras_cam(seed);
    s.physics = Physics { dynamics: Some(Dynamics::default()), ..Physics::ideal() };
    s.noise = Noise::default();
    let truth = s.truth().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 + seed);
    let (mut plant, hold, cmds) = locked(&s, &mut rng);
    let mut tracker = taut_sim::sensors::Tracker::new(&s.noise);
    let mut trng = rand_chacha::ChaCha8Rng::seed_from_u64(2000 + seed);
    let n = hold.len();
    let mut rec = Recording::with_capacity(n, 2000, true, false, false);
    for k in 0..20_000 {
        // A push every 4 s, each its own way: the platform swings onto other cables.
        if k % 4000 == 0 {
            let push = [PUSH_M_S * gauss(&mut rng), PUSH_M_S * gauss(&mut rng), 0.3 * PUSH_M_S * gauss(&mut rng)];
            plant.nudge([0.0; 3], push);
        }
        let out = plant.step(1e-3, &cmds);
        if k % 10 == 0 {
            let (l, f) = (out.encoder_m.to_vec(), out.tension_n.to_vec());
            let p = tracker.measure(out.position, &mut trng);
            rec.push(k as f64 * 1e-3, p, None, &l, Some(&f), None);
        }
    }
    if std::env::var_os("TAUT_PRIORS_DEBUG").is_some() {
        let taut: Vec<usize> = (0..n).map(|j| (0..rec.len()).filter(|&i| rec.tensions(i).is_some_and(|t| t[j] > 5.0)).count()).collect();
        let span: Vec<f64> = (0..3)
            .map(|a| {
                rec.p.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max) - rec.p.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min)
            })
            .collect();
        eprintln!("seed {seed}: taut rows per cable {taut:?} of {}, swing span {span:?} m", rec.len());
    }
    (rec, truth.anchors.clone())
}

/// Options as `taut calibrate` sets them from a configuration with the design's priors.
fn options(design: &[[f64; 3]], with_priors: bool) -> CalibOptions {
    let priors = with_priors.then(|| {
        design.iter().map(|a| ([a[0], a[1], a[2], f64::NAN], [PRIOR_SIGMA_M, PRIOR_SIGMA_M, PRIOR_SIGMA_M, f64::INFINITY])).collect()
    });
    CalibOptions { priors, ..CalibOptions::default() }
}

/// The tally over the seeds of one robot.
#[derive(Default)]
struct Tally {
    /// Anchor coordinates within 2 sigma of the truth, and all of them.
    within: usize,
    total: usize,
    /// Recordings refused without the priors.
    refused_without: usize,
    /// Recordings with some anchor coordinate's data share at 0.1 or more.
    informed_seeds: usize,
}

/// Calibrates one seed's recording `rec` (platform points `b`, true anchors `truth`) without
/// priors (the initialisation or the calibration should refuse) and with the design's priors
/// (the design drawn for `seed`; maximum a posteriori from the design), asserts every anchor
/// sigma within its prior, and adds the seed to `t`.
fn calibrate_seed(label: &str, seed: u64, rec: &Recording, b: &[[f64; 3]], truth: &[[f64; 3]], t: &mut Tally) {
    use rand::SeedableRng;
    let n = rec.n_cables;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3000 + seed);
    let design: Vec<[f64; 3]> = truth.iter().map(|a| std::array::from_fn(|i| a[i] + PRIOR_SIGMA_M * gauss(&mut rng))).collect();
    let plain = options(&design, false);
    let refused = match init::initialise(rec, b, &plain) {
        Err(_) => true,
        Ok(i) => taut_calib::calibrate(rec, b, &i.params, &plain).is_err(),
    };
    t.refused_without += usize::from(refused);
    let opts = options(&design, true);
    let means: Vec<[f64; 4]> = opts.priors.as_ref().unwrap().iter().map(|(m, _)| *m).collect();
    let mut data = noise::gather(rec, b, &opts, taut_calib::Weighting::of(rec, &opts));
    let start = init::from_design(rec, b, &means, &data).unwrap_or_else(|e| panic!("{label} seed {seed}: {e}"));
    let r = taut_calib::calibrate_gathered(rec, b, &start.params, &opts, &mut data).unwrap_or_else(|e| panic!("{label} seed {seed}: {e}"));
    if std::env::var_os("TAUT_PRIORS_DEBUG").is_some() {
        for j in 0..n {
            eprintln!(
                "cable {j}: cov diag {:?} vf {} share {:?} sigma {:?}",
                (0..4).map(|k| r.covariance[j][k][k].sqrt()).collect::<Vec<_>>(),
                r.per_cable[j].variance_factor,
                r.per_cable[j].data_share,
                r.sigma.anchors[j]
            );
        }
    }
    let mut informed = 0;
    for (j, tr) in truth.iter().enumerate() {
        for (i, &ti) in tr.iter().enumerate() {
            let (e, s) = (r.params.anchors[j][i] - ti, r.sigma.anchors[j][i]);
            assert!(s <= PRIOR_SIGMA_M * (1.0 + 1e-9), "{label} seed {seed}: anchor {j}[{i}] sigma {s} above its prior");
            t.total += 1;
            t.within += usize::from(e.abs() <= 2.0 * s);
            informed += usize::from(r.per_cable[j].data_share[i] >= 0.1);
        }
    }
    eprintln!(
        "RESULT {label} seed {seed}: worst anchor error {:.1} mm (design {:.1} mm), sigmas {:?} mm, data shares {:?}, variance factors {:?}, refused without priors: {refused}",
        (0..n).map(|j| taut_calib::model::norm(taut_calib::model::sub(r.params.anchors[j], truth[j]))).fold(0.0, f64::max) * 1e3,
        (0..n).map(|j| taut_calib::model::norm(taut_calib::model::sub(design[j], truth[j]))).fold(0.0, f64::max) * 1e3,
        r.sigma.anchors.iter().map(|s| s.map(|v| (v * 1e4).round() / 10.0)).collect::<Vec<_>>(),
        r.per_cable.iter().map(|c| c.data_share.map(|v| (v * 100.0).round() / 100.0)).collect::<Vec<_>>(),
        r.per_cable.iter().map(|c| (c.variance_factor * 100.0).round() / 100.0).collect::<Vec<_>>(),
    );
    t.informed_seeds += usize::from(informed > 0);
}

/// The assertions over all seeds: 90 % of the coordinates within 2 sigma, every recording
/// refused without priors, at least 15 recordings informing some coordinate.
fn finish(label: &str, t: &Tally) {
    let frac = t.within as f64 / t.total as f64;
    eprintln!(
        "{label}: {} of {} anchor coordinates within 2 sigma ({:.1} %); {} of {SEEDS} refused without priors; {} recordings inform some coordinate (data share >= 0.1)",
        t.within,
        t.total,
        100.0 * frac,
        t.refused_without,
        t.informed_seeds
    );
    assert!(frac >= 0.90, "{label}: {} of {} anchor coordinates within 2 sigma", t.within, t.total);
    assert_eq!(t.refused_without, SEEDS as usize, "{label}: without priors these recordings should be refused");
    assert!(t.informed_seeds >= 15, "{label}: only {} of {SEEDS} recordings inform any anchor coordinate", t.informed_seeds);
}

#[test]
fn locked_winches_calibrate_with_the_designs_priors() {
    // The swing informs the cables it keeps taut (18 of 20 recordings when measured).
    let mut t = Tally::default();
    for seed in 1..=SEEDS {
        let (rec, truth) = locked_swing(seed);
        calibrate_seed("point mass", seed, &rec, &vec![[0.0; 3]; rec.n_cables], &truth, &mut t);
    }
    finish("point mass", &t);
}

/// The 6-DoF robot: 2 m frame (anchors on the corners of its 2 m x 2 m top, 2 m up), a 13 kg
/// platform with its cables at the corners of a 0.3 m x 0.2 m rectangle 5 cm above the reference
/// point.
const FRAME_ANCHORS: [[f64; 3]; 4] = [[1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0], [-1.0, -1.0, 2.0]];
const PLATFORM_POINTS: [[f64; 3]; 4] = [[0.15, -0.1, 0.05], [0.15, 0.1, 0.05], [-0.15, 0.1, 0.05], [-0.15, -0.1, 0.05]];
const PLATFORM_KG: f64 = 13.0;
/// 1-sigma of the 6-DoF push's horizontal speed, m/s, and of its angular speed per axis, rad/s.
const PUSH_6DOF: (f64, f64) = (0.4, 1.0);
/// The tracker's orientation noise, 1-sigma per axis, rad (0.1 deg).
const TRACKER_ORIENTATION_RAD: f64 = 0.1 * std::f64::consts::PI / 180.0;

/// `q` turned by a rotation vector of `sigma` per axis (a tracker's orientation error).
fn noisy_orientation(q: [f64; 4], sigma: f64, rng: &mut rand_chacha::ChaCha8Rng) -> [f64; 4] {
    let d: [f64; 3] = std::array::from_fn(|_| sigma * gauss(rng));
    let a = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let s = if a > 0.0 { (0.5 * a).sin() / a } else { 0.5 };
    let e = [(0.5 * a).cos(), s * d[0], s * d[1], s * d[2]];
    // e q
    [
        e[0] * q[0] - e[1] * q[1] - e[2] * q[2] - e[3] * q[3],
        e[0] * q[1] + e[1] * q[0] + e[2] * q[3] - e[3] * q[2],
        e[0] * q[2] - e[1] * q[3] + e[2] * q[0] + e[3] * q[1],
        e[0] * q[3] + e[1] * q[2] - e[2] * q[1] + e[3] * q[0],
    ]
}

/// A locked-winch swing of 20 s of the 6-DoF robot, its platform a rigid body (a uniform
/// 0.4 m x 0.3 m x 0.2 m box with its centre of mass 5 cm below the reference point), pushed
/// and twisted every 4 s: the recording (tracker position and orientation) and the true anchors.
fn locked_swing_6dof(seed: u64) -> (Recording, Vec<[f64; 3]>) {
    use rand::SeedableRng;
    let mut s = Scenario::aras_cam(seed);
    s.robot.robot.mass_kg = PLATFORM_KG;
    for ((c, a), b) in s.robot.cables.iter_mut().zip(FRAME_ANCHORS).zip(PLATFORM_POINTS) {
        c.anchor = Some(a);
        c.platform_point = b;
    }
    let body = RigidBody::uniform_box(PLATFORM_KG, [0.4, 0.3, 0.2], [0.0, 0.0, -0.05]);
    s.physics = Physics { dynamics: Some(Dynamics { rigid_body: Some(body), ..Dynamics::default() }), ..Physics::ideal() };
    s.noise = Noise::default();
    let truth = s.truth().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 + seed);
    let (mut plant, hold, cmds) = locked(&s, &mut rng);
    let mut tracker = taut_sim::sensors::Tracker::new(&s.noise);
    let mut trng = rand_chacha::ChaCha8Rng::seed_from_u64(2000 + seed);
    let mut qrng = rand_chacha::ChaCha8Rng::seed_from_u64(4000 + seed);
    let n = hold.len();
    let mut rec = Recording::with_capacity(n, 2000, true, true, false);
    let mut tilt_max = 0.0f64;
    for k in 0..20_000 {
        if k % 4000 == 0 {
            let (v, w) = PUSH_6DOF;
            plant.nudge([0.0; 3], [v * gauss(&mut rng), v * gauss(&mut rng), 0.3 * v * gauss(&mut rng)]);
            plant.nudge_rotation([w * gauss(&mut rng), w * gauss(&mut rng), w * gauss(&mut rng)]);
        }
        let out = plant.step(1e-3, &cmds);
        if k % 10 == 0 {
            let (l, f, p) = (out.encoder_m.to_vec(), out.tension_n.to_vec(), out.position);
            let q = plant.orientation();
            tilt_max = tilt_max.max(2.0 * q[0].abs().min(1.0).acos());
            let pm = tracker.measure(p, &mut trng);
            let qm = noisy_orientation(q, TRACKER_ORIENTATION_RAD, &mut qrng);
            rec.push(k as f64 * 1e-3, pm, Some(qm), &l, Some(&f), None);
        }
    }
    assert_eq!(plant.failed_steps(), 0, "seed {seed}: the plant failed steps");
    if std::env::var_os("TAUT_PRIORS_DEBUG").is_some() {
        let taut: Vec<usize> = (0..n).map(|j| (0..rec.len()).filter(|&i| rec.tensions(i).is_some_and(|t| t[j] > 5.0)).count()).collect();
        let span: Vec<f64> = (0..3)
            .map(|a| {
                rec.p.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max) - rec.p.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min)
            })
            .collect();
        eprintln!(
            "seed {seed}: taut rows per cable {taut:?} of {}, swing span {span:?} m, largest rotation {:.1} deg",
            rec.len(),
            tilt_max.to_degrees()
        );
    }
    (rec, truth.anchors.clone())
}

/// Acceptance (issue 28, "Priors from the design"): locked-winch swinging recordings of a
/// 6-DoF platform (a rigid body that swings and rotates; tracker position and orientation),
/// design anchors off the truth by a 2 cm draw per axis with `anchor_sigma_m = 0.02`.
#[test]
fn locked_winches_6dof_calibrate_with_the_designs_priors() {
    let mut t = Tally::default();
    for seed in 1..=SEEDS {
        let (rec, truth) = locked_swing_6dof(seed);
        calibrate_seed("6-DoF", seed, &rec, &PLATFORM_POINTS, &truth, &mut t);
    }
    finish("6-DoF", &t);
}

#[test]
fn locked_winches_are_diagnosed_with_the_designs_priors() {
    // `taut diagnose` on the point-mass recordings. Without priors the diagnosis's baseline
    // starts from algebraic multilateration (the initialisation refuses) and its anchors land
    // metres off; with them it starts from the design and every fit is maximum a posteriori.
    use taut_calib::diagnose::{diagnose, DiagnoseOptions};
    let (mut within, mut total, mut worst_plain) = (0usize, 0usize, f64::INFINITY);
    let mut sig_hi = 0.0f64;
    for seed in 1..=DIAGNOSE_SEEDS {
        let (rec, truth) = locked_swing(seed);
        let b = vec![[0.0; 3]; rec.n_cables];
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3000 + seed);
        let design: Vec<[f64; 3]> = truth.iter().map(|a| std::array::from_fn(|i| a[i] + PRIOR_SIGMA_M * gauss(&mut rng))).collect();
        let err = |a: &[[f64; 3]]| {
            a.iter()
                .zip(&truth)
                .map(|(a, t)| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt())
                .fold(0.0, f64::max)
        };
        let plain = (seed <= 3).then(|| diagnose(&rec, &b, None, &DiagnoseOptions::default()).unwrap());
        if let Some(p) = &plain {
            worst_plain = worst_plain.min(err(&p.baseline.params.anchors));
        }
        let priors = options(&design, true).priors;
        let d = diagnose(&rec, &b, None, &DiagnoseOptions { priors, ..DiagnoseOptions::default() })
            .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert!(d.notes.iter().any(|n| n.contains("with its priors")), "seed {seed}: {:?}", d.notes);
        for fit in [&d.baseline, &d.final_fit] {
            for ((a, sg), t) in fit.params.anchors.iter().zip(&fit.sigma.anchors).zip(&truth) {
                for k in 0..3 {
                    sig_hi = sig_hi.max(sg[k]);
                    within += usize::from((a[k] - t[k]).abs() <= 2.0 * sg[k]);
                    total += 1;
                }
            }
        }
        eprintln!(
            "seed {seed}: effects {:?}, baseline worst anchor {:.1} mm (without priors {:.0} mm)",
            d.effects.iter().map(|e| e.effect.name()).collect::<Vec<_>>(),
            err(&d.baseline.params.anchors) * 1e3,
            plain.map_or(f64::NAN, |p| err(&p.baseline.params.anchors) * 1e3)
        );
    }
    let frac = within as f64 / total as f64;
    eprintln!("diagnosis with priors, {DIAGNOSE_SEEDS} seeds: {within} of {total} anchor coordinates (baseline and final fits) within 2 sigma ({:.1} %), largest sigma {:.1} mm; without priors (seeds 1-3) the worst anchor of every baseline at least {:.2} m off", 100.0 * frac, sig_hi * 1e3, worst_plain);
    assert!(frac >= 0.9, "{within} of {total}");
    assert!(worst_plain > 1.0, "without priors the baseline is within {worst_plain:.2} m");
}

#[test]
fn taut_diagnose_uses_the_configurations_priors() {
    // `taut diagnose rec.csv --config` on one locked-winch recording: the configuration's
    // `anchor_sigma_m` reach the diagnosis (its baseline starts from the design), and its
    // baseline anchors are within 4 sigma of the prior of the truth (8 cm).
    let (rec, truth) = locked_swing(4);
    let dir = tempfile::tempdir().unwrap();
    rec.save_atomic(dir.path().join("rec.csv")).unwrap();
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3004);
    let mut cfg = Scenario::aras_cam(4).robot;
    for (c, t) in cfg.cables.iter_mut().zip(&truth) {
        c.anchor = Some(std::array::from_fn(|i| t[i] + PRIOR_SIGMA_M * gauss(&mut rng)));
        c.anchor_sigma_m = Some([PRIOR_SIGMA_M; 3]);
        c.platform_point = [0.0; 3];
    }
    let json = crate::taut_diagnose(dir.path(), &cfg, "priors");
    let notes = json["notes"].as_array().unwrap();
    assert!(notes.iter().any(|n| n.as_str().unwrap().contains("with its priors")), "{notes:?}");
    let anchors: Vec<[f64; 3]> = serde_json::from_value(json["baseline"]["anchors_m"].clone()).unwrap();
    for (a, t) in anchors.iter().zip(&truth) {
        for k in 0..3 {
            assert!((a[k] - t[k]).abs() < 4.0 * PRIOR_SIGMA_M, "{a:?} against {t:?}");
        }
    }
}
