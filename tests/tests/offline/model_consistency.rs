//! A wrong model is never silent: `taut_calib::calibrate` compares the held-out
//! residual with the noise model ([`taut_calib::consistency`], false-alarm rate 1e-3).
//!
//! Acceptance: of 50 simulated recordings each with a concealed cable stretch, drum scale or time
//! offset that biases some anchor beyond 3 of its stated sigmas, at least 95 % are called
//! inconsistent; of 100 effect-free recordings at most 1 %. Recordings: the ARAS-CAM-like robot
//! without the three-phase motion, 90 s at 20 Hz with 20 % loose samples (the simulator's physics,
//! written independently of the calibration's model).

use taut_calib::{calibrate, init, CalibOptions, CalibReport};
use taut_sim::{simulate, Physics, Scenario};

/// The calibration of one recording and its worst anchor error in stated sigmas.
fn calibrated(seed: u64, physics: Physics) -> (CalibReport, f64) {
    let mut s = Scenario::aras_cam(seed);
    s.three_phase = None;
    s.duration_s = 90.0;
    s.rate_hz = 20.0;
    s.physics = physics;
    let run = simulate(&s);
    let opts = CalibOptions::from_config(&s.robot.calibration);
    let b = s.robot.platform_points();
    let init = init::initialise(&run.recording, &b, &opts).expect("initialisation");
    let rep = calibrate(&run.recording, &b, &init.params, &opts).expect("calibration");
    let worst = rep
        .params
        .anchors
        .iter()
        .zip(&rep.sigma.anchors)
        .zip(&run.truth.anchors)
        .flat_map(|((a, sg), t)| (0..3).map(move |k| (a[k] - t[k]).abs() / sg[k]))
        .fold(0.0, f64::max);
    (rep, worst)
}

fn line(seed: u64, what: &str, rep: &CalibReport, worst: f64) -> String {
    format!("seed {seed} {what}: worst anchor {worst:.1} sigma; {}", rep.consistency.map_or("no held-out test".into(), |c| c.numbers()))
}

/// The effect of seed `k`: stretch, drum scale or time offset in turn, sized so that it biases
/// the anchors by several sigmas.
fn effect(k: u64) -> (String, Physics) {
    match k % 3 {
        0 => ("EA 20 kN".into(), Physics { elasticity: Some(20_000.0), ..Physics::default() }),
        1 => ("drum scale 1.003".into(), Physics { scale: Some(vec![1.003, 0.998, 1.0, 1.002]), ..Physics::default() }),
        _ => ("time offset 20 ms".into(), Physics { time_offset_s: 0.02, ..Physics::default() }),
    }
}

#[test]
fn a_concealed_effect_that_biases_an_anchor_is_flagged() {
    let t0 = std::time::Instant::now();
    let (mut biased, mut flagged, mut lines, mut largest_p) = (0, 0, vec![], 0.0f64);
    let mut seed = 1;
    while biased < 50 {
        assert!(seed <= 80, "only {biased} of {} recordings biased beyond 3 sigma: {lines:#?}", seed - 1);
        let (what, physics) = effect(seed);
        let (rep, worst) = calibrated(seed, physics);
        let l = line(seed, &what, &rep, worst);
        if worst > 3.0 {
            biased += 1;
            largest_p = largest_p.max(rep.consistency.map_or(1.0, |c| c.p_value));
            if !rep.model_consistent() {
                flagged += 1;
                assert!(rep.notes[0].contains("taut diagnose"), "{:?}", rep.notes);
            } else {
                lines.push(l);
            }
        }
        seed += 1;
    }
    eprintln!(
        "{flagged} of {biased} biased recordings flagged (seeds 1-{}; largest p {largest_p:.1e}) ({:.1} s)",
        seed - 1,
        t0.elapsed().as_secs_f64()
    );
    assert!(flagged * 100 >= 95 * biased, "{flagged} of {biased} flagged; not flagged: {lines:#?}");
}

#[test]
fn effect_free_recordings_are_consistent() {
    let t0 = std::time::Instant::now();
    let (mut flagged, mut p) = (vec![], vec![]);
    for seed in 1001..=1100 {
        let (rep, worst) = calibrated(seed, Physics::default());
        let c = rep.consistency.unwrap_or_else(|| panic!("seed {seed}: no held-out test"));
        p.push(c.p_value);
        if !rep.model_consistent() {
            flagged.push(line(seed, "effect-free", &rep, worst));
        }
    }
    let below = |a: f64| p.iter().filter(|&&v| v < a).count();
    eprintln!(
        "{} of 100 effect-free recordings flagged; p below 0.05 / 0.01: {} / {}, smallest {:.1e} ({:.1} s)",
        flagged.len(),
        below(0.05),
        below(0.01),
        p.iter().copied().fold(1.0, f64::min),
        t0.elapsed().as_secs_f64()
    );
    assert!(flagged.len() <= 1, "{flagged:#?}");
}

/// `taut calibrate` on a recording with a concealed stretch: the text says the model does not
/// explain the data with the numbers and names `taut diagnose`, the JSON carries
/// `"model_consistent": false`, the report's verdict changes, and the exit code stays 0. On an
/// effect-free recording: `true`, and the report says the check passed.
#[test]
fn taut_calibrate_says_so_in_text_json_and_report() {
    use crate::hostile::{run_with_deadline, taut_bin};
    let dir = tempfile::tempdir().unwrap();
    for (name, physics, consistent) in
        [("stretch", Physics { elasticity: Some(20_000.0), ..Physics::default() }, false), ("ideal", Physics::default(), true)]
    {
        let mut s = Scenario::aras_cam(3);
        s.three_phase = None;
        s.duration_s = 90.0;
        s.rate_hz = 20.0;
        s.physics = physics;
        let rec = dir.path().join(format!("{name}.csv"));
        simulate(&s).recording.save_atomic(&rec).unwrap();
        let (json, html) = (dir.path().join(format!("{name}.json")), dir.path().join(format!("{name}.html")));
        let mut cmd = std::process::Command::new(taut_bin());
        cmd.arg("calibrate").arg(&rec).arg("--json").arg(&json).arg("--report").arg(&html);
        let run = run_with_deadline(cmd, std::time::Duration::from_secs(120));
        assert_eq!(run.code, Some(0), "{name}: {}", run.stderr);
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(v["model_consistent"], serde_json::json!(consistent), "{name}: {}", v["model_check"]);
        let page = std::fs::read_to_string(&html).unwrap();
        if consistent {
            assert!(run.stdout.contains("model check: consistent with the noise model"), "{}", run.stdout);
            assert!(page.contains("Model check: consistent") && !page.contains("does not explain"), "{name}: verdict");
        } else {
            let line = run.stdout.lines().find(|l| l.starts_with("model check:")).unwrap_or_default();
            assert!(line.contains("INCONSISTENT") && line.contains("taut diagnose") && line.contains("mm against"), "{}", run.stdout);
            assert!(v["model_check"]["p_value"].as_f64().unwrap() < 1e-3, "{}", v["model_check"]);
            assert!(page.contains("Calibrated, but the model does not explain the data."), "{name}: verdict");
        }
    }
}

/// The daemon's calibrations go through the same `taut_calib::calibrate`: its backend's estimate
/// carries `model_consistent` and, when false, a note that says so and names `taut diagnose`
/// (the set is not refused for it).
#[test]
fn the_daemons_estimate_says_so_too() {
    use taut_calibrator::calib_backend::TautCalib;
    use taut_calibrator::vocab::{Calibrate, Estimate};
    for (physics, consistent) in [(Physics { elasticity: Some(20_000.0), ..Physics::default() }, false), (Physics::default(), true)] {
        let mut s = Scenario::aras_cam(4);
        s.three_phase = None;
        s.duration_s = 90.0;
        s.rate_hz = 20.0;
        s.physics = physics;
        let run = simulate(&s);
        let b = s.robot.platform_points();
        let opts = CalibOptions::from_config(&s.robot.calibration);
        let init = init::initialise(&run.recording, &b, &opts).expect("initialisation");
        let start = Estimate {
            model_consistent: None,
            sigma: taut_calib::Sigmas::unknown(4),
            geometry: init.params,
            rms_m: f64::NAN,
            observable: true,
            note: "test".into(),
            effects: Default::default(),
        };
        let mut cfg = s.robot.clone();
        // The test's recording has its own site error: no nominal-anchor bounds.
        cfg.cables.iter_mut().for_each(|c| c.anchor = None);
        let est = TautCalib::from_config(&cfg).calibrate(&run.recording, &start).expect("calibration");
        assert_eq!(est.model_consistent, Some(consistent), "{}", est.note);
        assert_eq!(
            est.note.contains("the model does not explain the data") && est.note.contains("taut diagnose"),
            !consistent,
            "{}",
            est.note
        );
    }
}
