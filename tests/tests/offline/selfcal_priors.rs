//! Priors from the design without a tracker: a recording of a few dwell poses (too few for the
//! self-calibration alone, which refuses it) calibrated with the design's anchors and offsets as
//! priors (maximum a posteriori, `taut_calib::selfcal`).
//!
//! The recordings are the simulator's static dwells (`taut_sim::dwell`, ARAS-CAM's frame, 1 s
//! dwells at 100 Hz). The design: every anchor coordinate and every encoder offset off the truth
//! by a draw of 2 cm, `anchor_sigma_m = l0_sigma_m = 0.02` (or the anchors' alone, with load
//! cells); its anchors are also the nominal ones (the start). Asserted over [`SEEDS`] seeds, with load cells and with encoders only:
//! - without the priors the recording is refused (too few dwells) or, with load cells, calibrated
//!   weakly from the dwells cut into moving windows (some anchor sigma above the prior's);
//! - with them it calibrates, in the configuration's frame (the priors fix it), and every
//!   sigma is at most its prior's, with a data share in 0-1 for every parameter;
//! - at least 90 % of the coordinates (12 anchor coordinates and 4 offsets per seed) are within
//!   2 sigma of the truth, compared directly (no alignment: the frame is the design's). A correct
//!   Gaussian posterior puts 95.4 % there; with 20 x 16 coordinates 90 % is 4.7 binomial sigmas
//!   below that.

use taut_calib::selfcal::{self, Frame, SelfCalError, SelfCalOptions, SelfCalReport};
use taut_config::RobotConfig;
use taut_sim::dwell::{self, DwellPlan};
use taut_sim::Scenario;

use crate::gauss;

/// Recordings per case.
const SEEDS: u64 = 20;
/// Dwell poses per recording (the self-calibration alone needs 10 with load cells, 20 without).
const POSES: usize = 5;
/// The design's tolerance, 1-sigma, m.
const PRIOR_SIGMA_M: f64 = 0.02;

/// The scenario's configuration with a design off the truth by `PRIOR_SIGMA_M` per parameter,
/// and its tolerances.
fn design(s: &Scenario, seed: u64, l0: bool) -> RobotConfig {
    use rand::SeedableRng;
    let truth = s.truth().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(500 + seed);
    let mut cfg = s.robot.clone();
    for (j, c) in cfg.cables.iter_mut().enumerate() {
        let a = truth.anchors[j];
        c.anchor = Some(std::array::from_fn(|q| a[q] + PRIOR_SIGMA_M * gauss(&mut rng)));
        c.anchor_sigma_m = Some([PRIOR_SIGMA_M; 3]);
        let l0_m = truth.l0[j] + PRIOR_SIGMA_M * gauss(&mut rng);
        if l0 {
            (c.l0_m, c.l0_sigma_m) = (Some(l0_m), Some(PRIOR_SIGMA_M));
        }
    }
    cfg
}

fn calibrate(
    s: &Scenario,
    cfg: &RobotConfig,
    rec: &taut_config::recording::Recording,
    priors: bool,
) -> Result<SelfCalReport, SelfCalError> {
    let opts = SelfCalOptions { priors: if priors { cfg.priors() } else { None }, ..SelfCalOptions::from_config(cfg) };
    selfcal::calibrate_without_tracker(rec, &s.robot.platform_points(), cfg.anchors().as_deref(), &opts)
}

/// The case over [`SEEDS`]: coordinates within 2 sigma, of how many; the data shares' range.
fn few_poses_calibrate_with_the_designs_priors(tensions: bool, l0: bool) {
    let t0 = std::time::Instant::now();
    let (mut within, mut total) = (0usize, 0usize);
    let (mut share_lo, mut share_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut sig_lo, mut sig_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut refused, mut weak_worst) = (0, Vec::new());
    for seed in 0..SEEDS {
        let s = Scenario { with_tensions: tensions, ..Scenario::aras_cam(seed) };
        let plan = DwellPlan::spread(&s, POSES, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
        let rec = dwell::simulate(&s, &plan).unwrap().recording;
        let cfg = design(&s, seed, l0);
        let truth = s.truth().unwrap();
        match calibrate(&s, &cfg, &rec, false) {
            Err(e) => {
                assert!(matches!(e, SelfCalError::TooFewDwells { found: POSES, .. }), "seed {seed}, without priors: {e}");
                refused += 1;
            }
            Ok(r) => {
                // Calibrated from the dwells cut into moving windows: weak.
                let worst = r.sigma.anchors.iter().flatten().fold(0.0f64, |a, &b| a.max(b));
                assert!(r.moving && worst > PRIOR_SIGMA_M, "seed {seed}, without priors: worst sigma {:.1} mm", worst * 1e3);
                weak_worst.push(worst);
            }
        }
        let r = calibrate(&s, &cfg, &rec, true).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert_eq!(r.frame, Frame::DesignPriors, "seed {seed}");
        assert_eq!(r.used_tensions, tensions, "seed {seed}");
        for j in 0..4 {
            let est = [r.params.anchors[j][0], r.params.anchors[j][1], r.params.anchors[j][2], r.params.l0[j]];
            let sig = [r.sigma.anchors[j][0], r.sigma.anchors[j][1], r.sigma.anchors[j][2], r.sigma.l0[j]];
            let tru = [truth.anchors[j][0], truth.anchors[j][1], truth.anchors[j][2], truth.l0[j]];
            for k in 0..if l0 { 4 } else { 3 } {
                assert!(sig[k] > 0.0 && sig[k] <= PRIOR_SIGMA_M * (1.0 + 1e-6), "seed {seed} cable {j} [{k}]: sigma {}", sig[k]);
                let share = r.data_share[j][k];
                assert!((0.0..=1.0).contains(&share), "seed {seed} cable {j} [{k}]: share {share}");
                share_lo = share_lo.min(share);
                share_hi = share_hi.max(share);
                sig_lo = sig_lo.min(sig[k]);
                sig_hi = sig_hi.max(sig[k]);
                within += usize::from((est[k] - tru[k]).abs() <= 2.0 * sig[k]);
                total += 1;
            }
        }
    }
    let frac = within as f64 / total as f64;
    eprintln!(
        "{}{}, {POSES} dwells, design 2 cm off, {SEEDS} seeds: {within} of {total} coordinates ({:.1} %) within 2 sigma; sigmas {:.1}-{:.1} mm; data shares {:.2}-{:.2}; {:.1} s",
        if tensions { "encoders + load cells" } else { "encoders only" },
        if l0 { "" } else { ", anchor priors only" },
        100.0 * frac,
        sig_lo * 1e3,
        sig_hi * 1e3,
        share_lo,
        share_hi,
        t0.elapsed().as_secs_f64()
    );
    eprint!("  without the priors: {refused} refused, {} weak", weak_worst.len());
    if !weak_worst.is_empty() {
        eprint!(
            " (moving windows; worst anchor sigma {:.0}-{:.0} mm)",
            weak_worst.iter().fold(f64::INFINITY, |a: f64, &b| a.min(b)) * 1e3,
            weak_worst.iter().fold(0.0, |a: f64, &b| a.max(b)) * 1e3
        );
    }
    eprintln!();
    assert!(frac >= 0.9, "{within} of {total} within 2 sigma");
    // The recording informs: some parameter's estimate is mostly from the data.
    assert!(share_hi > 0.5, "largest data share {share_hi:.2}");
}

#[test]
fn few_dwells_with_load_cells_calibrate_with_the_designs_priors() {
    few_poses_calibrate_with_the_designs_priors(true, true);
}

#[test]
fn few_dwells_with_anchor_priors_only() {
    // With load cells the offsets without a prior are the recording's.
    few_poses_calibrate_with_the_designs_priors(true, false);
    // Encoders only, the offsets without a prior can be beyond `max_sigma_m`: refused, naming
    // one (a parameter without a prior keeps today's refusal).
    let s = Scenario { with_tensions: false, ..Scenario::aras_cam(1) };
    let plan = DwellPlan::spread(&s, POSES, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
    let rec = dwell::simulate(&s, &plan).unwrap().recording;
    let e = calibrate(&s, &design(&s, 1, false), &rec, true).unwrap_err();
    assert!(matches!(e, SelfCalError::TooUncertain { quantity: selfcal::Quantity::Offset(_), .. }), "{e}");
}

#[test]
fn few_dwells_encoders_only_calibrate_with_the_designs_priors() {
    few_poses_calibrate_with_the_designs_priors(false, true);
}

#[test]
fn the_tracker_free_start_up_calibrates_with_the_designs_priors() {
    // The daemon's backend with `motion.startup = "dwell"` on the same kind of recording
    // (encoders and load cells, 5 dwells): refused without the tolerances, with them the
    // posterior estimate and sigmas, the note naming the priors.
    use taut_calibrator::calib_backend::TautCalib;
    use taut_calibrator::vocab::{Calibrate, Estimate};
    let s = Scenario::aras_cam(3);
    let plan = DwellPlan::spread(&s, POSES, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
    let rec = dwell::simulate(&s, &plan).unwrap().recording;
    let mut cfg = design(&s, 3, true);
    cfg.motion.startup = Some(taut_config::runtime::Startup::Dwell);
    let truth = s.truth().unwrap();
    let init = |b: &mut TautCalib| -> Estimate { b.initialise(&rec).unwrap() };
    let mut plain = cfg.clone();
    for c in &mut plain.cables {
        (c.anchor_sigma_m, c.l0_sigma_m) = (None, None);
    }
    let mut b = TautCalib::from_config(&plain);
    let i = init(&mut b);
    let e = b.calibrate(&rec, &i).unwrap_err();
    assert!(e.to_string().contains("only 5 dwell poses"), "{e}");
    let mut b = TautCalib::from_config(&cfg);
    let i = init(&mut b);
    let est = b.calibrate(&rec, &i).unwrap();
    assert!(est.note.contains("MAP with the design's priors on 16 parameters"), "{}", est.note);
    let mut within = 0;
    for j in 0..4 {
        for k in 0..3 {
            let sg = est.sigma.anchors[j][k];
            assert!(sg > 0.0 && sg <= PRIOR_SIGMA_M * (1.0 + 1e-6), "cable {j} [{k}]: sigma {sg}");
            within += usize::from((est.geometry.anchors[j][k] - truth.anchors[j][k]).abs() <= 2.0 * sg);
        }
    }
    eprintln!("start-up with priors: {within} of 12 anchor coordinates within 2 sigma; {}", est.note);
    assert!(within >= 10, "{within} of 12 within 2 sigma");
}
