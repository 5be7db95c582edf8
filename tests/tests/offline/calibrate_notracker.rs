//! `taut calibrate REC.csv` on recordings without a tracker, run as the real
//! binary: empty tracker columns in every row -> tracker-free calibration, said in the output and
//! in the parameters file; no tensions; missing lengths; tracker in some rows only (calibrated
//! with the tracker on those rows, said in a note); 3 cables and no nominal anchors refused; a few
//! dwells calibrated with the design's priors (the data shares reported).

use crate::hostile;

use std::path::Path;
use std::process::Command;
use taut_sim::dwell::{self, DwellPlan};
use taut_sim::Scenario;

fn config_toml(s: &Scenario) -> String {
    let mut t = format!("[robot]\nname = \"{}\"\nmass_kg = {}\n", s.robot.robot.name, s.robot.robot.mass_kg);
    for a in s.robot.anchors().unwrap() {
        t += &format!("\n[[cable]]\nanchor = [{}, {}, {}]\n", a[0], a[1], a[2]);
    }
    t
}

fn write(dir: &Path, s: &Scenario, poses: usize, edit: impl FnOnce(&mut taut_config::recording::Recording)) {
    let plan = DwellPlan::spread(s, poses, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
    let mut sim = dwell::simulate(s, &plan).unwrap();
    edit(&mut sim.recording);
    sim.recording.save_atomic(dir.join("rec.csv")).unwrap();
    std::fs::write(dir.join("robot.toml"), config_toml(s)).unwrap();
}

fn taut(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let mut cmd = Command::new(hostile::taut_bin());
    cmd.current_dir(dir).args(args);
    let r = hostile::run_with_deadline(cmd, hostile::DEADLINE);
    eprintln!("--- taut {}\n{}{}", args.join(" "), r.stdout, r.stderr);
    (r.code == Some(0), r.stdout, r.stderr)
}

const ARGS: [&str; 8] = ["calibrate", "rec.csv", "--config", "robot.toml", "--out", "params.toml", "--json", "out.json"];

#[test]
fn empty_tracker_columns_calibrate_without_a_tracker_and_say_so() {
    let d = tempfile::tempdir().unwrap();
    let s = Scenario::aras_cam(31);
    write(d.path(), &s, 40, |_| {});
    let (ok, out, err) = taut(d.path(), &ARGS);
    assert!(ok, "{err}");
    assert!(out.contains("calibrated WITHOUT a tracker") && out.contains("encoders + load cells"), "{out}");
    assert!(out.contains("distance anchor 1 - anchor 2") && out.contains("load-cell offset of cable 4"), "{out}");
    let params = std::fs::read_to_string(d.path().join("params.toml")).unwrap();
    assert!(params.contains("without tracker"), "{params}");
    let p = taut_config::params::ParamsFile::load(d.path().join("params.toml")).unwrap();
    let truth = taut_sim::Scenario::aras_cam(31).truth().unwrap();
    // Frame-free check: the inter-anchor distances within 5 mm of the truth.
    for i in 0..4 {
        for j in i + 1..4 {
            let dist = |a: &[[f64; 3]]| ((a[i][0] - a[j][0]).powi(2) + (a[i][1] - a[j][1]).powi(2) + (a[i][2] - a[j][2]).powi(2)).sqrt();
            let e = dist(&p.anchors_m) - dist(&truth.anchors);
            assert!(e.abs() < 5e-3, "distance {i}-{j} off by {:.2} mm", e * 1e3);
        }
    }
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.path().join("out.json")).unwrap()).unwrap();
    assert_eq!(json["tracker"], serde_json::json!(false));
    assert_eq!(json["method"], serde_json::json!("selfcal"));
}

#[test]
fn no_tensions_and_missing_lengths() {
    let d = tempfile::tempdir().unwrap();
    let s = Scenario { with_tensions: false, ..Scenario::aras_cam(32) };
    // Every 97th reading of cable 1 missing (NaN): the dwells around it are split, not poisoned.
    write(d.path(), &s, 80, |r| {
        for i in (50..r.len()).step_by(97) {
            r.l[i * r.n_cables + 1] = f64::NAN;
        }
    });
    let (ok, out, err) = taut(d.path(), &ARGS);
    assert!(ok, "{err}");
    assert!(out.contains("calibrated WITHOUT a tracker") && out.contains("encoders only"), "{out}");
    assert!(out.contains("no tensions"), "{out}");
}

#[test]
fn tracker_in_some_rows_only_uses_the_tracker_and_says_so() {
    let d = tempfile::tempdir().unwrap();
    let s = Scenario::aras_cam(33);
    let plan = DwellPlan::spread(&s, 40, 0.8, 0.15, 0.85, 1.0, 0.5).unwrap();
    let sim = dwell::simulate(&s, &plan).unwrap();
    let mut rec = sim.recording.clone();
    // The true positions in the first half of the rows, nothing in the rest.
    for i in 0..rec.len() / 2 {
        rec.p[i] = sim.positions[i];
    }
    rec.save_atomic(d.path().join("rec.csv")).unwrap();
    std::fs::write(d.path().join("robot.toml"), config_toml(&s)).unwrap();
    let (_, out, err) = taut(d.path(), &ARGS);
    assert!(err.contains("rows have no tracker position: calibrating with the tracker"), "{err}");
    assert!(!out.contains("WITHOUT a tracker"), "{out}");
}

#[test]
fn three_cables_and_missing_nominal_anchors_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let s = Scenario::three_cable(34);
    write(d.path(), &s, 30, |_| {});
    let (ok, _, err) = taut(d.path(), &ARGS);
    assert!(!ok);
    assert!(err.contains("cannot calibrate itself without a tracker") && err.contains("no information"), "{err}");
    assert!(!d.path().join("params.toml").exists());

    let d = tempfile::tempdir().unwrap();
    write(d.path(), &Scenario::aras_cam(35), 30, |_| {});
    let (ok, _, err) = taut(d.path(), &["calibrate", "rec.csv", "--out", "params.toml"]);
    assert!(!ok);
    assert!(err.contains("needs the nominal anchors"), "{err}");
    assert!(!d.path().join("params.toml").exists());
}

#[test]
fn few_dwells_calibrate_with_the_designs_priors_and_report_the_data_share() {
    // Encoders only, 5 dwells: refused without priors (20 needed). With the design's anchors
    // (here the true ones) known to 2 cm per axis: calibrated in the configuration's frame, each
    // coordinate's share from the data in the text and the JSON.
    let d = tempfile::tempdir().unwrap();
    let s = Scenario { with_tensions: false, ..Scenario::aras_cam(36) };
    write(d.path(), &s, 5, |_| {});
    let (ok, _, err) = taut(d.path(), &ARGS);
    assert!(!ok && err.contains("only 5 dwell poses found"), "{err}");
    let truth = s.truth().unwrap();
    let mut t = format!("[robot]\nname = \"{}\"\nmass_kg = {}\n", s.robot.robot.name, s.robot.robot.mass_kg);
    for a in &truth.anchors {
        t += &format!("\n[[cable]]\nanchor = [{}, {}, {}]\nanchor_sigma_m = 0.02\n", a[0], a[1], a[2]);
    }
    std::fs::write(d.path().join("robot.toml"), t).unwrap();
    let (ok, out, err) = taut(d.path(), &ARGS);
    assert!(ok, "{err}");
    assert!(out.contains("design priors") && out.contains("share from the data"), "{out}");
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.path().join("out.json")).unwrap()).unwrap();
    let shares = json["data_share"].as_array().unwrap();
    assert_eq!(shares.len(), 4);
    for (j, c) in shares.iter().enumerate() {
        let c = c.as_array().unwrap();
        // Anchor coordinates: a share in 0-1; L0 has no prior here: null.
        for k in 0..3 {
            let v = c[k].as_f64().unwrap_or_else(|| panic!("cable {j} [{k}]: {c:?}"));
            assert!((0.0..=1.0).contains(&v), "cable {j} [{k}]: {v}");
        }
        assert!(c[3].is_null(), "cable {j}: {c:?}");
    }
    for (j, s) in json["anchor_sigma_m"].as_array().unwrap().iter().enumerate() {
        for v in s.as_array().unwrap() {
            // At most the prior's, to round-off: where the readings say nothing (the y
            // coordinates here) their Schur complement is a difference of terms ~1e9 larger than
            // the prior's 2500 m^-2, and cancels to ~1e-8 of the prior's variance (measured
            // 7.5e-9 above it).
            assert!(v.as_f64().unwrap() <= 0.02 * (1.0 + 1e-6), "cable {j}: sigma {v}");
        }
    }
    let params = std::fs::read_to_string(d.path().join("params.toml")).unwrap();
    assert!(params.contains("design priors"), "{params}");
}
