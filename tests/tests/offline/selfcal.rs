//! Self-calibration without a tracker on recordings of the simulator's own
//! physics (`taut_sim::dwell`: static equilibria with the controller's tension distribution,
//! encoders, load cells with offsets; no tracker columns).
//!
//! The accuracy criterion is statistical. The anchor error after the best alignment (translation
//! and rotation about the vertical; any rotation without load cells) is compared with the
//! Cramér–Rao bound the calibration reports for the same recording, pooled over seeds:
//! `sum_seeds |err|^2 <= 1.5^2 sum_seeds CRB_rms^2 n`. With a correct, efficient estimator the
//! left side is a sum of about 8 chi-square degrees of freedom per seed (12 anchor coordinates
//! minus the 4 of the frame) scaled by the bound; over 5 seeds (~40 dof) exceeding 2.25x its
//! mean has probability ~1e-5 (1e-3 even if unequal eigenvalues halve the effective dof). The
//! same for the encoder offsets (4 dof per seed, 20 pooled: ~1e-3).

use taut_calib::selfcal::{self, Frame, SelfCalError, SelfCalOptions, SelfCalReport};
use taut_sim::dwell::{self, DwellPlan};
use taut_sim::{Scenario, SimRun};

/// 1 s dwells at 100 Hz, 0.5 s moves.
fn run(s: &Scenario, poses: usize) -> SimRun {
    let plan = DwellPlan::spread(s, poses, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
    dwell::simulate(s, &plan).unwrap()
}

fn opts(s: &Scenario) -> SelfCalOptions {
    SelfCalOptions::from_config(&s.robot)
}

fn calibrate(s: &Scenario, sim: &SimRun) -> Result<SelfCalReport, SelfCalError> {
    let nominal = s.robot.anchors().unwrap();
    selfcal::calibrate_without_tracker(&sim.recording, &s.robot.platform_points(), Some(&nominal), &opts(s))
}

/// Squared anchor error after the best alignment of `est` onto `truth`: translation plus yaw
/// (`yaw_only`) or plus any rotation.
fn aligned_sq_error(est: &[[f64; 3]], truth: &[[f64; 3]], yaw_only: bool) -> f64 {
    let n = est.len() as f64;
    let ce: [f64; 3] = std::array::from_fn(|a| est.iter().map(|p| p[a]).sum::<f64>() / n);
    let ct: [f64; 3] = std::array::from_fn(|a| truth.iter().map(|p| p[a]).sum::<f64>() / n);
    let e: Vec<nalgebra::Vector3<f64>> = est.iter().map(|p| nalgebra::Vector3::new(p[0] - ce[0], p[1] - ce[1], p[2] - ce[2])).collect();
    let t: Vec<nalgebra::Vector3<f64>> = truth.iter().map(|p| nalgebra::Vector3::new(p[0] - ct[0], p[1] - ct[1], p[2] - ct[2])).collect();
    let r = if yaw_only {
        let (mut sc, mut cc) = (0.0, 0.0);
        for (a, b) in e.iter().zip(&t) {
            cc += a.x * b.x + a.y * b.y;
            sc += a.x * b.y - a.y * b.x;
        }
        let th = sc.atan2(cc);
        nalgebra::Matrix3::new(th.cos(), -th.sin(), 0.0, th.sin(), th.cos(), 0.0, 0.0, 0.0, 1.0)
    } else {
        // Kabsch.
        let h: nalgebra::Matrix3<f64> = e.iter().zip(&t).map(|(a, b)| b * a.transpose()).sum();
        let svd = h.svd(true, true);
        let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
        let mut d = nalgebra::Matrix3::identity();
        d[(2, 2)] = (u * vt).determinant().signum();
        u * d * vt
    };
    e.iter().zip(&t).map(|(a, b)| (r * a - b).norm_squared()).sum()
}

struct Pooled {
    err_sq: f64,
    crb_sq: f64,
    shape_sq: f64,
    shape_crb_sq: f64,
    l0_err_sq: f64,
    l0_crb_sq: f64,
}

impl Pooled {
    fn new() -> Self {
        Pooled { err_sq: 0.0, crb_sq: 0.0, shape_sq: 0.0, shape_crb_sq: 0.0, l0_err_sq: 0.0, l0_crb_sq: 0.0 }
    }

    fn add(&mut self, r: &SelfCalReport, sim: &SimRun) {
        let n = r.params.anchors.len();
        let e = aligned_sq_error(&r.params.anchors, &sim.truth.anchors, r.frame == Frame::NominalTranslationYaw);
        let crb_sq = r.anchor_rms_crb_m.powi(2) * n as f64;
        let le: f64 = r.params.l0.iter().zip(&sim.truth.l0).map(|(a, b)| (a - b).powi(2)).sum();
        let lc: f64 = (0..n).map(|j| r.covariance[(3 * n + j, 3 * n + j)]).sum();
        eprintln!(
            "  anchors: RMS error {:.3} mm vs CRB {:.3} mm; offsets RMS error {:.3} mm vs CRB {:.3} mm; chi2/dof {:.2}; {} dwells",
            (e / n as f64).sqrt() * 1e3,
            r.anchor_rms_crb_m * 1e3,
            (le / n as f64).sqrt() * 1e3,
            (lc / n as f64).sqrt() * 1e3,
            r.chi2 / r.dof as f64,
            r.dwells.len()
        );
        let shape = aligned_sq_error(&r.params.anchors, &sim.truth.anchors, false);
        eprintln!("  shape (any rotation): RMS error {:.3} mm vs CRB {:.3} mm", (shape / n as f64).sqrt() * 1e3, r.shape_rms_crb_m * 1e3);
        self.shape_sq += shape;
        self.shape_crb_sq += r.shape_rms_crb_m.powi(2) * n as f64;
        self.err_sq += e;
        self.crb_sq += crb_sq;
        self.l0_err_sq += le;
        self.l0_crb_sq += lc;
    }

    fn check(&self, what: &str) {
        let ra = (self.err_sq / self.crb_sq).sqrt();
        let rl = (self.l0_err_sq / self.l0_crb_sq).sqrt();
        let rs = (self.shape_sq / self.shape_crb_sq).sqrt();
        eprintln!("{what}: pooled anchor error / CRB = {ra:.2}, shape {rs:.2}, offsets {rl:.2}");
        assert!(ra <= 1.5, "{what}: anchors {ra:.2} x the Cramér–Rao bound");
        assert!(rs <= 1.5, "{what}: anchor shape {rs:.2} x the Cramér–Rao bound");
        assert!(rl <= 1.5, "{what}: offsets {rl:.2} x the Cramér–Rao bound");
    }
}

#[test]
fn four_cables_with_load_cells_reach_the_cramer_rao_bound_from_anchors_20_cm_off() {
    let mut pooled = Pooled::new();
    for seed in 1..=5 {
        let s = Scenario::aras_cam(seed);
        let sim = run(&s, 60);
        // The true anchors are up to site_error_m = 20 cm from the nominal ones the solver starts at.
        let off = sim
            .truth
            .anchors
            .iter()
            .zip(s.robot.anchors().unwrap())
            .map(|(t, n)| ((t[0] - n[0]).powi(2) + (t[1] - n[1]).powi(2) + (t[2] - n[2]).powi(2)).sqrt());
        eprintln!("seed {seed}: start {:.0} mm off at most", off.fold(0.0, f64::max) * 1e3);
        let r = calibrate(&s, &sim).unwrap();
        assert!(r.used_tensions && r.frame == Frame::NominalTranslationYaw);
        assert!(r.chi2_ok, "chi2/dof {:.2}: {:?}", r.chi2 / r.dof as f64, r.notes);
        // Load-cell offsets recovered within 4 sigma (0.5 N drawn).
        for (j, (c, t)) in r.loadcell_offsets.as_ref().unwrap().iter().zip(&sim.truth.loadcell_offsets).enumerate() {
            assert!((c.value - t).abs() <= 4.0 * c.crb, "seed {seed} cell {j}: {:.3} N vs {t:.3} N (sigma {:.3})", c.value, c.crb);
        }
        pooled.add(&r, &sim);
    }
    pooled.check("4 cables, encoders + load cells");
}

#[test]
fn eight_cables_and_four_cables_without_load_cells() {
    let mut eight = Pooled::new();
    for seed in 11..=15 {
        let mut s = Scenario::aras_cam(seed);
        let mut cfg = taut_config::RobotConfig::point_mass(8);
        cfg.robot.name = "box-8".into();
        cfg.robot.mass_kg = 3.0;
        let a = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        for (j, c) in cfg.cables.iter_mut().enumerate() {
            let b = a[j % 4];
            c.anchor = Some(if j < 4 { b } else { [0.8 * b[0], 0.8 * b[1], 3.4] });
        }
        s.robot = cfg;
        let sim = run(&s, 40);
        let r = calibrate(&s, &sim).unwrap();
        eight.add(&r, &sim);
    }
    eight.check("8 cables, encoders + load cells");

    // Encoders alone need anchors out of one plane (with coplanar anchors a horizontal stretch of
    // the frame is lost): two anchors 0.7 m lower.
    let mut enc = Pooled::new();
    for seed in 21..=25 {
        let s = Scenario { with_tensions: false, robot: staggered(), ..Scenario::aras_cam(seed) };
        let sim = run(&s, 120);
        assert!(sim.recording.f.is_none());
        let r = calibrate(&s, &sim).unwrap();
        assert!(!r.used_tensions && r.frame == Frame::NominalRigid && r.heights.is_none());
        enc.add(&r, &sim);
    }
    enc.check("4 cables, encoders only");
}

/// ARAS-CAM with anchors 1 and 3 0.7 m lower.
fn staggered() -> taut_config::RobotConfig {
    let mut cfg = taut_config::RobotConfig::point_mass(4);
    cfg.robot.name = "staggered-4".into();
    cfg.robot.mass_kg = 3.0;
    for (c, a) in cfg.cables.iter_mut().zip([[3.5, -1.75, 4.0], [3.5, 1.75, 3.3], [-3.5, 1.75, 4.0], [-3.5, -1.75, 3.3]]) {
        c.anchor = Some(a);
    }
    cfg
}

#[test]
fn three_cables_are_refused_with_the_reason() {
    let s = Scenario::three_cable(3);
    let sim = run(&s, 40);
    let e = calibrate(&s, &sim).unwrap_err();
    eprintln!("{e}");
    assert!(matches!(e, SelfCalError::TooFewCables { n: 3 }), "{e}");
    assert!(e.to_string().contains("no information") && e.to_string().contains("tracker"), "{e}");
}

#[test]
fn poses_in_one_plane_are_refused_with_the_reason() {
    // Every pose at half the anchors' height (to 1e-9 of it). Encoders only: refused, naming the
    // plane. With load cells gravity still fixes the heights, to a few mm here (60 dwells of 1 s):
    // the estimate comes back with the weak anchor heights named and the same advice.
    let s = Scenario { with_tensions: false, ..Scenario::aras_cam(4) };
    let plan = DwellPlan::spread(&s, 60, 0.8, 0.5, 0.5 + 1e-9, 1.0, 0.5).unwrap();
    let e = calibrate(&s, &dwell::simulate(&s, &plan).unwrap()).unwrap_err();
    eprintln!("{e}");
    assert!(matches!(e, SelfCalError::TooUncertain { .. } | SelfCalError::Singular { .. }), "{e}");
    assert!(e.to_string().contains("one horizontal plane"), "{e}");
    let s = Scenario::aras_cam(4);
    let r = calibrate(&s, &dwell::simulate(&s, &plan).unwrap()).unwrap();
    assert!(!r.weak.is_empty());
    assert!(r.notes.iter().any(|n| n.contains("one horizontal plane")), "{:?}", r.notes);
}

#[test]
fn too_few_dwells_are_refused() {
    let s = Scenario::aras_cam(5);
    let sim = run(&s, 5);
    let e = calibrate(&s, &sim).unwrap_err();
    assert!(matches!(e, SelfCalError::TooFewDwells { found: 5, .. }), "{e}");
}

#[test]
fn cramer_rao_bound_against_the_issue_table() {
    // Issue 11: 4 cables ~6.5 x 3.2 x 3 m, 2.9 kg, encoders 0.05 mm, load cells 0.3 N, static
    // poses: 50 -> 2.4 mm, 200 -> 0.94 mm with load cells, 200 -> 1.4 mm encoders only (one
    // reading per pose). Here each pose is a dwell of ~21 readings: the bound per single reading
    // is sqrt(readings) times the reported one. The issue's pose set and tension distribution are
    // not given, so its absolute values are not a test; what it implies is: how the bound falls
    // with the poses, and that the load cells add shape information. Measured values are printed
    // (BENCHMARKS.md).
    let mut s = Scenario::aras_cam(7);
    let mut cfg = taut_config::RobotConfig::point_mass(4);
    cfg.robot.mass_kg = 2.9;
    for (c, a) in cfg.cables.iter_mut().zip([[3.25, -1.6, 3.0], [3.25, 1.6, 3.0], [-3.25, 1.6, 3.0], [-3.25, -1.6, 3.0]]) {
        c.anchor = Some(a);
    }
    s.robot = cfg;
    let per_reading = |r: &SelfCalReport, v: f64| v * (r.samples_used as f64 / r.dwells.len() as f64).sqrt();
    let plan = DwellPlan::spread(&s, 200, 0.9, 0.1, 0.9, 0.25, 0.2).unwrap();
    let with = calibrate(&s, &dwell::simulate(&s, &plan).unwrap()).unwrap();
    let few = DwellPlan { poses: plan.poses[..50].to_vec(), ..plan.clone() };
    let with50 = calibrate(&s, &dwell::simulate(&s, &few).unwrap()).unwrap();
    let s2 = Scenario { with_tensions: false, ..s.clone() };
    let without = calibrate(&s2, &dwell::simulate(&s2, &plan).unwrap()).unwrap();
    let (a, a50, b) = (
        per_reading(&with, with.shape_rms_crb_m),
        per_reading(&with50, with50.shape_rms_crb_m),
        per_reading(&without, without.shape_rms_crb_m),
    );
    eprintln!(
        "CRB per single reading (shape, any rotation aligned): load cells 50 poses {:.2} mm (issue 2.4), 200 poses {:.2} mm (issue 0.94); encoders only 200 poses {:.2} mm (issue 1.4); load cells, gravity frame (yaw aligned) 200 poses {:.2} mm",
        a50 * 1e3,
        a * 1e3,
        b * 1e3,
        per_reading(&with, with.anchor_rms_crb_m) * 1e3
    );
    // The issue's own 50 -> 200 ratio is 2.4 / 0.94 = 2.55 (more than the asymptotic 2: the
    // nuisance offsets cost relatively more with few poses); within 25 % of it.
    assert!((0.75 * 2.55..=1.25 * 2.55).contains(&(a50 / a)), "50 -> 200 poses: x{:.2}", a50 / a);
    assert!(a < b, "load cells must add information");
}

#[test]
fn three_phase_recording_of_a_four_cable_robot_gives_an_estimate() {
    // Issue 11 item 5: the three-phase motion alone (the fourth cable only follows) was refused
    // ("cable 3: A_x is not observable (singular value 7.0e1 vs 9.0e4, 1-sigma 8.6e-3 m)"). A
    // parameter known to millimetres is weakly determined, not unobservable: the estimate comes
    // back, every sigma below the refusal tolerance, the weak ones named.
    use taut_calib::{calibrate, init, CalibOptions};
    let s = Scenario { duration_s: 0.0, ..Scenario::aras_cam(2) };
    let sim = taut_sim::simulate(&s);
    let b = s.robot.platform_points();
    let opts = CalibOptions::from_config(&s.robot.calibration);
    let start = init::initialise(&sim.recording, &b, &opts).unwrap();
    let r = calibrate(&sim.recording, &b, &start.params, &opts).unwrap();
    for w in &r.weak {
        eprintln!("{w}");
    }
    for (j, sg) in r.sigma.anchors.iter().enumerate() {
        eprintln!("cable {j}: anchor 1-sigma {:.2} {:.2} {:.2} mm", sg[0] * 1e3, sg[1] * 1e3, sg[2] * 1e3);
        assert!(sg.iter().all(|v| *v <= opts.max_sigma_m));
    }
    assert_eq!(r.weak.is_empty(), !r.notes.iter().any(|n| n.contains("weakly determined")));
}
