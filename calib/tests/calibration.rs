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
            let r = rep.anchor_sigma[j][k] / crb.anchor_sigma[j][k];
            assert!((0.85..1.15).contains(&r), "cable {j} axis {k}: reported/CRB sigma {r:.3}");
        }
    }
    // 5% of the readings are loose and were excluded.
    let expect = 0.05 * 4000.0 * 4.0;
    let loose = rep.excluded.loose as f64;
    assert!((loose - expect).abs() < 4.0 * expect.sqrt(), "loose {loose} vs {expect}");
    // Co-registration of used readings: the noise level sqrt(enc^2 + tracker^2 + stretch^2) ~
    // 1.6 mm (outliers add a little).
    assert!(rep.rms_m > 1.4e-3 && rep.rms_m < 2.2e-3, "rms {}", rep.rms_m);
    let ho = rep.heldout_rms_m;
    assert!(ho > 1.4e-3 && ho < 2.2e-3, "held-out rms {ho}");
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
