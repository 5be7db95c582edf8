//! End-to-end tests of calibration, initialisation and metrics on synthetic recordings with a
//! known truth. Every tolerance is derived from the noise (the Cramér–Rao bound or a stated
//! geometric argument), never tuned to pass.

use taut_calib::metrics::{self, anchor_error};
use taut_calib::synth::{self, PhaseSpec, Spec, Stretch};
use taut_calib::{calibrate, init, CalibError, CalibOptions, Param, Params, RobustLoss, Weighting};

/// ARAS-CAM-like workspace: 5 m x 2.5 m x 2 m under the anchors.
const LO: [f64; 3] = [-2.5, -1.25, 0.5];
const HI: [f64; 3] = [2.5, 1.25, 2.5];

fn perturbed(p: &Params, by: f64) -> Params {
    // A deterministic perturbation of about `by` per coordinate, different per cable.
    let mut q = p.clone();
    for (j, a) in q.anchors.iter_mut().enumerate() {
        let s = [1.0, -0.7, 0.5].map(|v| v * by * if j % 2 == 0 { 1.0 } else { -1.0 });
        for k in 0..3 {
            a[k] += s[k];
        }
        q.l0[j] += 0.5 * by;
    }
    q
}

fn opts_for(spec: &Spec) -> CalibOptions {
    CalibOptions {
        tracker_sigma_m: spec.tracker_sigma_m,
        encoder_sigma_m: spec.encoder_sigma_m,
        cable_ea_n: spec.cable_ea_n,
        ..CalibOptions::default()
    }
}

/// Per-coordinate error over CRB sigma, worst over anchors and offsets.
fn worst_z(rep: &Params, truth: &Params, crb: &metrics::CrbReport) -> f64 {
    let mut z = 0.0f64;
    for j in 0..truth.n_cables() {
        for k in 0..3 {
            z = z.max((rep.anchors[j][k] - truth.anchors[j][k]).abs() / crb.anchor_sigma[j][k]);
        }
        z = z.max((rep.l0[j] - truth.l0[j]).abs() / crb.l0_sigma[j]);
    }
    z
}

#[test]
fn recovers_truth_within_cramer_rao_bound() {
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.05;
    spec.outlier_prob = 0.002;
    let rec = synth::box_recording(&spec, 4000, LO, HI, 11);
    let opts = opts_for(&spec);
    let b = spec.platform_points.clone();
    let rep = calibrate(&rec, &b, &perturbed(&truth, 0.3), &opts).unwrap();
    let crb = metrics::cramer_rao(&rec, &b, &truth, &opts);
    assert!(rep.was_successful(), "{:?}", rep.termination);
    assert!(rep.used_tensions && rep.weighting == Weighting::ForceAware);
    // An efficient estimator is within 4 sigma per coordinate (16 numbers: a 4-sigma excursion
    // has probability 1e-3), and its Mahalanobis distance (chi, 4 dof) below 4.7 (99.9%).
    let z = worst_z(&rep.params, &truth, &crb);
    assert!(z < 4.0, "worst error {z:.2} CRB sigmas");
    for j in 0..4 {
        let d = crb.normalised_error(j, rep.params.cable(j), truth.cable(j));
        assert!(d < 4.7, "cable {j}: Mahalanobis {d:.2}");
        // The reported sigmas are the CRB at the estimate, up to the variance factor (~1 here)
        // and the Huber weights: within 15%.
        for k in 0..3 {
            let r = rep.sigma.anchors[j][k] / crb.anchor_sigma[j][k];
            assert!((0.85..1.15).contains(&r), "cable {j} axis {k}: reported/CRB sigma {r:.3}");
        }
    }
    // 5% of the readings are loose and were excluded.
    let expect = 0.05 * 4000.0 * 4.0;
    let loose = rep.excluded.loose as f64;
    assert!((loose - expect).abs() < 4.0 * expect.sqrt(), "loose {loose} vs {expect}");
    // Co-registration of the used readings is the noise: enc^2 + tracker^2 + stretch^2, where
    // the stretch (T rho / EA, T uniform in 5..60 N) is computed from the truth, plus the
    // outliers: 0.2% of the samples with 5 cm in a random direction, (5 cm)^2 / 3 projected on
    // a cable. About 8 outlier samples: their share is Poisson, so allow from none to three
    // times the expected share, and 5% for the rest.
    let mut st = 0.0;
    for i in 0..rec.len() {
        for j in 0..4 {
            let rho = anchor_error(rec.p[i], truth.anchors[j]);
            st += (rec.tensions(i).unwrap()[j] * rho / spec.cable_ea_n).powi(2);
        }
    }
    let base = spec.encoder_sigma_m.powi(2) + spec.tracker_sigma_m.powi(2) + st / (4.0 * rec.len() as f64);
    let out = spec.outlier_prob * spec.outlier_m.powi(2) / 3.0;
    let (lo, hi) = (0.95 * base.sqrt(), 1.05 * (base + 3.0 * out).sqrt());
    assert!(rep.rms_m > lo && rep.rms_m < hi, "rms {} not in {lo}..{hi}", rep.rms_m);
    let ho = rep.heldout_rms_m;
    assert!(ho > lo && ho < hi, "held-out rms {ho} not in {lo}..{hi}");
    eprintln!("iterations per cable {:?}", rep.per_cable.iter().map(|c| c.iterations).collect::<Vec<_>>());
    eprintln!(
        "crb test: worst z {z:.2}, rms {:.3} mm, heldout {:.3} mm, iterations {}, crb anchor sigma {:?}",
        rep.rms_m * 1e3,
        ho * 1e3,
        rep.iterations,
        crb.anchor_sigma
    );
}

#[test]
fn multilateration_is_exact_on_noise_free_data() {
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.tracker_sigma_m = 0.0;
    spec.encoder_sigma_m = 0.0;
    spec.stretch = Stretch::None;
    let rec = synth::box_recording(&spec, 500, LO, HI, 5);
    let r = init::multilateration(&rec, &spec.platform_points, &CalibOptions::default()).unwrap();
    assert_eq!(r.method, init::Method::Multilateration);
    for j in 0..4 {
        assert!(anchor_error(r.params.anchors[j], truth.anchors[j]) < 1e-9, "cable {j}: {:?}", r.params.anchors[j]);
        assert!((r.params.l0[j] - truth.l0[j]).abs() < 1e-9);
    }
}

#[test]
fn force_aware_beats_unweighted_with_loose_cables() {
    // 20% of the readings loose, reading 2-8 cm long: the situation of the paper's Fig. 8.
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.2;
    let rec = synth::box_recording(&spec, 4000, LO, HI, 21);
    let b = spec.platform_points.clone();
    let start = perturbed(&truth, 0.2);
    let err = |p: &Params| (0..4).map(|j| anchor_error(p.anchors[j], truth.anchors[j])).fold(0.0, f64::max);
    for loss in [RobustLoss::None, RobustLoss::Huber { k: 2.0 }] {
        let fa = CalibOptions { loss, ..opts_for(&spec) };
        let plain = CalibOptions { force_aware: false, ..fa.clone() };
        let rf = calibrate(&rec, &b, &start, &fa).unwrap();
        let rp = calibrate(&rec, &b, &start, &plain).unwrap();
        assert_eq!(rp.weighting, Weighting::UniformByOption);
        assert!(rp.notes.iter().any(|n| n.contains("switched off")));
        let (ef, ep) = (err(&rf.params), err(&rp.params));
        eprintln!(
            "loss {loss:?}: force-aware worst anchor error {:.2} mm, unweighted {:.2} mm, ratio {:.1}; rms {:.2} vs {:.2} mm",
            ef * 1e3,
            ep * 1e3,
            ep / ef,
            rf.rms_m * 1e3,
            rp.rms_m * 1e3
        );
        if loss == RobustLoss::None {
            // The paper's comparison (least squares with and without force weighting).
            assert!(ep >= 3.0 * ef, "{loss:?}: unweighted {ep} vs force-aware {ef}");
        } else {
            // A robust loss already rejects slack of several cm as outliers, so the unweighted
            // solve is much closer here; force weighting still wins.
            assert!(ep > ef, "{loss:?}: unweighted {ep} vs force-aware {ef}");
        }
        // Force-aware stays efficient: within 4 CRB sigmas of the truth.
        let crb = metrics::cramer_rao(&rec, &b, &truth, &fa);
        let z = worst_z(&rf.params, &truth, &crb);
        assert!(z < 4.0, "{loss:?}: {z:.2} sigma");
    }
}

#[test]
fn without_tensions_falls_back_to_uniform_and_says_so() {
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.tensions = false;
    spec.stretch = Stretch::None;
    let rec = synth::box_recording(&spec, 2000, LO, HI, 8);
    assert!(rec.f.is_none());
    let rep = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.1), &opts_for(&spec)).unwrap();
    assert!(!rep.used_tensions);
    assert_eq!(rep.weighting, Weighting::UniformNoTensions);
    assert!(rep.notes.iter().any(|n| n.contains("no tensions")), "{:?}", rep.notes);
    assert_eq!(rep.excluded.loose, 0);
    // Data without loose readings: uniform weights are the right ones, still efficient.
    let crb = metrics::cramer_rao(&rec, &spec.platform_points, &truth, &opts_for(&spec));
    let z = worst_z(&rep.params, &truth, &crb);
    assert!(z < 4.0, "{z:.2} sigma");
}

#[test]
fn refuses_when_the_platform_only_moves_along_a_line() {
    // Distances from points on a line do not change when the anchor turns about the line: the
    // anchor's angle about it is not observable at all (singular value at the noise level).
    let truth = synth::aras_cam();
    let spec = Spec::new(truth.clone());
    let rec = synth::box_recording(&spec, 2000, [-2.5, 0.0, 1.5], [2.5, 0.0, 1.5], 4);
    // At a 5 cm tolerance (the tracker noise leaves the direction known to ~9 cm, not exactly
    // singular; the default 10 cm would return it with a warning).
    let opts = CalibOptions { max_sigma_m: 0.05, ..opts_for(&spec) };
    let e = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.05), &opts).unwrap_err();
    eprintln!("{e}");
    // Refused by the predicted uncertainty (the tracker noise keeps it from exactly singular).
    match e {
        CalibError::NotObservable { param, sigma_m, max_sigma_m, singular, .. } => {
            assert!(singular || sigma_m > max_sigma_m, "{e}");
            assert!(matches!(param, Param::Ay | Param::Az), "{e}");
        }
        other => panic!("expected NotObservable, got {other}"),
    }
}

#[test]
fn planar_motion_observability() {
    // z never varies. The linear multilateration is then exactly singular (A_z is confounded with
    // the constant term) and refuses, naming A_z. The nonlinear model still sees A_z through the
    // curvature of |P - A| when the anchors are well outside the plane and the plane is wide: the
    // calibration from a given start is then as good as its Cramér-Rao bound says.
    let truth = synth::aras_cam();
    let spec = Spec::new(truth.clone());
    let opts = opts_for(&spec);
    let wide = synth::box_recording(&spec, 2000, [-2.5, -1.25, 1.5], [2.5, 1.25, 1.5], 4);
    let ie = init::multilateration(&wide, &spec.platform_points, &opts).unwrap_err();
    assert!(matches!(ie, init::InitError::NotExcited { param: Param::Az, .. }), "{ie}");
    assert!(ie.to_string().contains("vertically"), "{ie}");
    let rep = calibrate(&wide, &spec.platform_points, &perturbed(&truth, 0.05), &opts).unwrap();
    let crb = metrics::cramer_rao(&wide, &spec.platform_points, &truth, &opts);
    assert!(worst_z(&rep.params, &truth, &crb) < 4.0);
    eprintln!("wide plane: A_z sigma {:?} mm", rep.sigma.anchors.iter().map(|s| s[2] * 1e3).collect::<Vec<_>>());
    // A small patch of a plane: the curvature is too weak, the calibration refuses.
    let patch = synth::box_recording(&spec, 2000, [-0.3, -0.3, 1.5], [0.3, 0.3, 1.5], 4);
    let opts = CalibOptions { max_sigma_m: 0.05, ..opts };
    let e = calibrate(&patch, &spec.platform_points, &perturbed(&truth, 0.05), &opts).unwrap_err();
    eprintln!("{e}");
    assert!(matches!(e, CalibError::NotObservable { .. }), "{e}");
}

#[test]
fn refuses_when_a_sigma_exceeds_the_limit() {
    // Well-excited data, but a one-sigma limit tighter than the data can give (0.1 mm).
    let truth = synth::aras_cam();
    let spec = Spec::new(truth.clone());
    let rec = synth::box_recording(&spec, 1000, LO, HI, 9);
    let opts = CalibOptions { max_sigma_m: 1e-4, ..opts_for(&spec) };
    let e = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.05), &opts).unwrap_err();
    assert!(matches!(e, CalibError::NotObservable { singular: false, .. }), "{e}");
    assert!(e.to_string().contains("larger part of the workspace"), "{e}");
}

#[test]
fn weakly_determined_parameters_are_returned_with_a_warning() {
    // The same well-excited data: a warning level below what the data give (0.1 mm) keeps the
    // estimate and names every parameter above it; the refusal tolerance is untouched.
    let truth = synth::aras_cam();
    let spec = Spec::new(truth.clone());
    let rec = synth::box_recording(&spec, 1000, LO, HI, 9);
    let opts = CalibOptions { weak_sigma_m: 1e-4, ..opts_for(&spec) };
    let r = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.05), &opts).unwrap();
    assert!(!r.weak.is_empty());
    for w in &r.weak {
        assert!(w.sigma_m > 1e-4 && w.sigma_m <= opts.max_sigma_m, "{w}");
    }
    assert!(r.notes.iter().any(|n| n.contains("weakly determined")), "{:?}", r.notes);
    // At the default level (2 mm) nothing is weak on these data.
    let r = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.05), &opts_for(&spec)).unwrap();
    assert!(r.weak.is_empty(), "{:?}", r.weak);
}

fn three_phase_case(truth: &Params, phases: &[PhaseSpec], n_per_phase: usize, seed: u64) -> (init::InitResult, f64, f64) {
    let spec = Spec::new(truth.clone());
    let rec = synth::three_phase_recording(&spec, phases, n_per_phase, seed);
    let r = init::initialise(&rec, &spec.platform_points, &opts_for(&spec)).unwrap();
    assert_eq!(r.method, init::Method::ThreePhase, "{:?}", r.notes);
    for (k, (d, p)) in r.phases.iter().zip(phases).enumerate() {
        let mut held = p.held;
        held.sort();
        assert_eq!(d.held, held, "phase {k}: held cables inferred wrongly");
        assert_eq!(d.reeled, p.reeled, "phase {k}: reeled cable inferred wrongly");
    }
    let worst = (0..truth.n_cables()).map(|j| anchor_error(r.params.anchors[j], truth.anchors[j])).fold(0.0, f64::max);
    let worst_line =
        r.cables.iter().enumerate().filter_map(|(j, c)| c.line_anchor.map(|a| anchor_error(a, truth.anchors[j]))).fold(0.0, f64::max);
    let worst_geo =
        r.cables.iter().enumerate().filter_map(|(j, c)| c.geometric_anchor.map(|a| anchor_error(a, truth.anchors[j]))).fold(0.0, f64::max);
    eprintln!(
        "three-phase: worst anchor error {:.2} mm (line estimates {:.2} mm, geometric {:.2} mm), l0 errors {:?} mm, sources {:?}",
        worst * 1e3,
        worst_line * 1e3,
        worst_geo * 1e3,
        (0..truth.n_cables()).map(|j| ((r.params.l0[j] - truth.l0[j]) * 1e3 * 100.0).round() / 100.0).collect::<Vec<_>>(),
        r.cables.iter().map(|c| c.source).collect::<Vec<_>>()
    );
    (r, worst, worst_line)
}

#[test]
fn three_phase_initialisation_on_a_three_cable_robot() {
    let truth = synth::tri3();
    let home = [0.1, -0.1, 1.0];
    let phases = [
        PhaseSpec { held: [0, 1], reeled: 2, start: home, arc_m: 1.0 },
        PhaseSpec { held: [1, 2], reeled: 0, start: home, arc_m: 1.0 },
        PhaseSpec { held: [2, 0], reeled: 1, start: home, arc_m: 1.0 },
    ];
    let (r, worst, _) = three_phase_case(&truth, &phases, 1500, 31);
    assert!(r.cables.iter().all(|c| c.source == init::AnchorSource::HeldPhases));
    // Goal: within 2 cm of the truth with 1.5 mm tracker noise (the paper: ~50 cm).
    assert!(worst < 0.02, "worst anchor error {worst}");
}

#[test]
fn three_phase_initialisation_on_a_four_cable_robot() {
    // Three phases on four cables: cable 3 is never held and comes from multilateration on the
    // whole recording.
    let truth = synth::aras_cam();
    let home = [0.2, 0.1, 1.2];
    let phases = [
        PhaseSpec { held: [0, 1], reeled: 2, start: home, arc_m: 1.0 },
        PhaseSpec { held: [1, 2], reeled: 3, start: home, arc_m: 1.0 },
        PhaseSpec { held: [2, 0], reeled: 1, start: home, arc_m: 1.0 },
    ];
    let (r, worst, _) = three_phase_case(&truth, &phases, 1500, 32);
    assert_eq!(r.cables[3].source, init::AnchorSource::Multilateration);
    assert!(worst < 0.02, "worst anchor error {worst}");
}

#[test]
fn three_phase_is_exact_on_noise_free_circles() {
    let truth = synth::tri3();
    let mut spec = Spec::new(truth.clone());
    spec.tracker_sigma_m = 0.0;
    spec.encoder_sigma_m = 0.0;
    spec.stretch = Stretch::None;
    let home = [0.1, -0.1, 1.0];
    let phases = [
        PhaseSpec { held: [0, 1], reeled: 2, start: home, arc_m: 0.8 },
        PhaseSpec { held: [1, 2], reeled: 0, start: home, arc_m: 0.8 },
        PhaseSpec { held: [2, 0], reeled: 1, start: home, arc_m: 0.8 },
    ];
    let rec = synth::three_phase_recording(&spec, &phases, 300, 1);
    let r = init::three_phase(&rec, &spec.platform_points, &CalibOptions::default()).unwrap();
    for j in 0..3 {
        assert!(anchor_error(r.cables[j].line_anchor.unwrap(), truth.anchors[j]) < 1e-6, "line estimate {j}");
        assert!(anchor_error(r.params.anchors[j], truth.anchors[j]) < 1e-6, "anchor {j}");
        assert!((r.params.l0[j] - truth.l0[j]).abs() < 1e-6);
    }
}

#[test]
fn heldout_rms_matches_a_full_solve_on_the_training_block() {
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.05;
    spec.outlier_prob = 0.002;
    let rec = synth::box_recording(&spec, 3000, LO, HI, 41);
    let opts = opts_for(&spec);
    let b = spec.platform_points.clone();
    let rep = calibrate(&rec, &b, &perturbed(&truth, 0.1), &opts).unwrap();
    let split = metrics::heldout_start(&rec, opts.heldout_fraction);
    assert_eq!(split, 2400, "the last 20% in time");
    let train =
        calibrate(&rec.slice(0..split), &b, &perturbed(&truth, 0.1), &CalibOptions { heldout_fraction: 0.0, ..opts.clone() }).unwrap();
    let res = metrics::co_registration(&rec, &b, &train.params);
    let mask = metrics::taut_mask(&rec, &opts).within(split..rec.len());
    let full = metrics::rms_peak(&res, &mask);
    // The held-out RMS (m ~ 2400 readings of ~1.6 mm) has a sampling error of ~1.4%; the
    // one-step training estimate must agree with the full solve far below that.
    let rel = (rep.heldout_rms_m - full.rms).abs() / full.rms;
    assert!(rel < 1e-3, "one-step {} vs full solve {} (rel {rel:.2e})", rep.heldout_rms_m, full.rms);
    assert_eq!(full.n, rep.per_cable.iter().map(|c| c.used).sum::<usize>() - train.samples_used);
}

#[test]
fn missing_values_are_skipped_and_counted() {
    let truth = synth::aras_cam();
    let spec = Spec::new(truth.clone());
    let mut rec = synth::box_recording(&spec, 3000, LO, HI, 51);
    // Tracker dropouts (all four readings of the sample), lost encoder and load-cell readings.
    let n = rec.n_cables;
    let (mut dropouts, mut lengths, mut tensions) = (0, 0, 0);
    for i in (0..rec.len()).step_by(37) {
        rec.p[i][1] = f64::NAN;
        dropouts += 1;
    }
    for i in (5..rec.len()).step_by(53) {
        if !rec.p[i][1].is_nan() {
            rec.l[i * n + 2] = f64::NAN;
            lengths += 1;
        }
    }
    for i in (7..rec.len()).step_by(41) {
        if !rec.p[i][1].is_nan() && !rec.l[i * n].is_nan() {
            rec.f.as_mut().unwrap()[i * n] = f64::NAN;
            tensions += 1;
        }
    }
    let opts = opts_for(&spec);
    let rep = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.1), &opts).unwrap();
    assert_eq!(rep.excluded.missing, dropouts * n + lengths + tensions);
    assert_eq!(rep.samples_used, rec.len() * n - rep.excluded.missing);
    assert_eq!(rep.per_cable[2].excluded.missing, dropouts + lengths);
    let crb = metrics::cramer_rao(&rec, &spec.platform_points, &truth, &opts);
    assert!(worst_z(&rep.params, &truth, &crb) < 4.0);
    // The residuals are NaN exactly where a position or a length is missing.
    let res = metrics::co_registration(&rec, &spec.platform_points, &rep.params);
    let nan = res.values.iter().filter(|v| v.is_nan()).count();
    assert_eq!(nan, dropouts * n + lengths);
}

#[test]
fn huber_loss_rejects_tracker_outliers() {
    // 1% of the samples carry a 5 cm tracker outlier (five times the rate the project expects,
    // so that the effect is measurable on a small recording).
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.outlier_prob = 0.01;
    let rec = synth::box_recording(&spec, 4000, LO, HI, 61);
    let b = spec.platform_points.clone();
    let huber = opts_for(&spec);
    let ls = CalibOptions { loss: RobustLoss::None, ..huber.clone() };
    let rh = calibrate(&rec, &b, &perturbed(&truth, 0.1), &huber).unwrap();
    let rl = calibrate(&rec, &b, &perturbed(&truth, 0.1), &ls).unwrap();
    let crb = metrics::cramer_rao(&rec, &b, &truth, &huber);
    // Sum over cables of the squared Mahalanobis errors: chi-square with 16 dof (mean 16) for
    // an efficient estimator. Outliers of 5 cm projected on a cable add about
    // 0.01 * 0.05^2 / 3 = 8e-6 m^2 to a reading variance of 2.3e-6 m^2: least squares should be
    // about 4.5 times worse; Huber caps their influence at 2 sigma.
    let chi2 = |p: &Params| (0..4).map(|j| crb.normalised_error(j, p.cable(j), truth.cable(j)).powi(2)).sum::<f64>();
    let (ch, cl) = (chi2(&rh.params), chi2(&rl.params));
    eprintln!("outliers: chi2 huber {ch:.1}, least squares {cl:.1}; flagged {} readings", rh.outliers);
    assert!(ch < 39.3, "huber chi2 {ch} (99.9% of chi2(16) is below 39.3)");
    assert!(cl > ch, "least squares {cl} vs huber {ch}");
    // Cauchy (redescending) from the Huber solution: also efficient.
    let cauchy = CalibOptions { loss: RobustLoss::Cauchy { c: 2.5 }, ..huber.clone() };
    let rc = calibrate(&rec, &b, &rh.params, &cauchy).unwrap();
    let cc = chi2(&rc.params);
    eprintln!("outliers: chi2 cauchy {cc:.1}");
    assert!(cc < 39.3, "cauchy chi2 {cc}");
    // ~40 outlier samples x 4 cables; a 5 cm error projected on a cable exceeds 6 sigma
    // (1 cm) unless it is nearly perpendicular to it.
    let expect = 0.01 * 4000.0 * 4.0;
    assert!((rh.outliers as f64) > 0.6 * expect && (rh.outliers as f64) < 1.2 * expect, "{} outliers", rh.outliers);
}

#[test]
fn platform_points_and_orientation() {
    // A 40 cm x 30 cm platform tilting up to 10 degrees: the anchors are those of the cable exit
    // points, the model uses P + R b_j.
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.platform_points = vec![[0.2, -0.15, 0.05], [0.2, 0.15, 0.05], [-0.2, 0.15, 0.05], [-0.2, -0.15, 0.05]];
    spec.tilt_deg = 10.0;
    let rec = synth::box_recording(&spec, 3000, LO, HI, 71);
    assert!(rec.q.is_some());
    let opts = opts_for(&spec);
    let start = init::initialise(&rec, &spec.platform_points, &opts).unwrap();
    let rep = calibrate(&rec, &spec.platform_points, &start.params, &opts).unwrap();
    let crb = metrics::cramer_rao(&rec, &spec.platform_points, &truth, &opts);
    let z = worst_z(&rep.params, &truth, &crb);
    assert!(z < 4.0, "{z:.2} sigma");
    // Ignoring the platform geometry instead leaves residuals well above the noise (the anchors
    // and offsets absorb part of it).
    let wrong = calibrate(&rec, &[[0.0; 3]; 4], &start.params, &opts);
    if let Ok(w) = wrong {
        assert!(w.rms_m > 3.0 * rep.rms_m, "{} vs {}", w.rms_m, rep.rms_m);
    }
}

#[test]
fn converges_from_half_a_metre_off() {
    // The paper's initialisation was ~50 cm off; the calibration must still find the optimum.
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.05;
    spec.outlier_prob = 0.002;
    let rec = synth::box_recording(&spec, 3000, LO, HI, 81);
    let opts = opts_for(&spec);
    let near = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.01), &opts).unwrap();
    let far = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.5), &opts).unwrap();
    assert!(far.was_successful(), "{:?}", far.termination);
    // The same optimum. The variances (hence weights) are evaluated at points that differ by a
    // few sigma between the two runs, i.e. by well under 1% (relative change 2 drho / rho), and
    // a weight change of 1% moves a weighted mean by at most ~1% of a sigma: within 0.02 sigma.
    for j in 0..4 {
        for k in 0..3 {
            let d = (far.params.anchors[j][k] - near.params.anchors[j][k]).abs();
            assert!(d < 2e-2 * near.sigma.anchors[j][k], "cable {j} axis {k}: {d}");
        }
    }
}

#[test]
fn anisotropic_tracker_noise_is_weighted_by_its_projection() {
    // A tracker three times worse in z: vertical-ish cables see the depth noise. With the full
    // covariance the estimate is as good as the bound under that covariance.
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.tracker_axis_scale = [1.0, 1.0, 3.0];
    let rec = synth::box_recording(&spec, 3000, LO, HI, 91);
    let s2 = spec.tracker_sigma_m.powi(2);
    let opts = CalibOptions { tracker_cov_m2: Some([[s2, 0.0, 0.0], [0.0, s2, 0.0], [0.0, 0.0, 9.0 * s2]]), ..opts_for(&spec) };
    let rep = calibrate(&rec, &spec.platform_points, &perturbed(&truth, 0.1), &opts).unwrap();
    let crb = metrics::cramer_rao(&rec, &spec.platform_points, &truth, &opts);
    let z = worst_z(&rep.params, &truth, &crb);
    assert!(z < 4.0, "{z:.2} sigma");
    // The residuals are as large as the model says: variance factor near 1 (m = 3000:
    // its sampling sd is sqrt(2/m) = 0.026).
    for c in &rep.per_cable {
        assert!((c.variance_factor - 1.0).abs() < 0.1, "variance factor {}", c.variance_factor);
    }
}
