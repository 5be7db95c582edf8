//! End to end: `taut start --sim --once` from cold to calibrated, then `taut ctl recalibrate`
//! against the running daemon, over its Unix socket.

use std::time::Duration;
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::OutcomeKind;
use taut_operator::control;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use taut_tests::startup;

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn start_sim_once_calibrates_and_hot_swaps_then_ctl_recalibrates() {
    let dir = tempfile::tempdir().unwrap();
    eprintln!("e2e files in {}", dir.path().display());
    let cfg = startup::sim_robot(dir.path());
    let sim = startup::build_at_rest(&cfg, 3);
    let truth = sim.truth.clone();
    let d = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default()).unwrap();
    let sock = dir.path().join("taut.sock");
    let meta = std::fs::metadata(&sock).unwrap();
    use std::os::unix::fs::PermissionsExt;
    assert_eq!(meta.permissions().mode() & 0o777, 0o660);

    let ok = d.wait_until(Duration::from_secs(240), startup::start_up_over);
    let l = d.loop_status();
    let c = d.calib_status();
    if std::env::var_os("TAUT_E2E_KEEP").is_some() {
        // Keep the recording for a look after a failure.
        let _ = std::fs::copy(&d.recording, std::env::temp_dir().join("taut-e2e-recording.csv"));
    }
    assert!(ok, "start-up did not finish: state {:?}, stage {}", l.snap.state, c.stage);
    assert!(l.snap.fault.is_none(), "fault {:?}", l.snap.fault);
    assert_eq!(l.snap.phases_completed, 3);
    let init = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Initial).unwrap();
    assert!(init.accepted, "{}", init.reason);
    let ie = init.estimate.as_ref().unwrap();
    // The three cables held in the phases are found by the three-phase method; the follower
    // (cable 3, torque mode) starts at its nominal anchor and is refined with the others.
    // Goal: 2 cm. Over runs of this start-up the held cables' initial anchors come within 5-13 mm
    // (three-phase geometry, then all cables' lengths with the positions as unknowns).
    for (j, (a, t)) in ie.geometry.anchors.iter().zip(&truth.anchors).enumerate().take(3) {
        assert!(dist(a, t) < 0.02, "initial anchor {j} off by {:.1} mm", dist(a, t) * 1e3);
    }
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).unwrap();
    assert!(cal.accepted, "{} ({:?})", cal.reason, cal.estimate.as_ref().map(|e| (&e.sigma.anchors, &e.sigma.l0)));
    let ce = cal.estimate.as_ref().unwrap();
    // Every anchor coordinate within k of the calibrator's own sigmas (plus encoder
    // quantisation), k by Bonferroni over the 12 coordinates for a family error rate of 1e-4
    // with a right covariance (k = 4.46; a flat 4 sigma failed 7.6e-4 of runs by chance).
    let k = taut_calib::screen::normal_upper_quantile(1e-4 / (2.0 * 12.0));
    let mut z_max = 0.0f64;
    for (j, ((a, t), s)) in ce.geometry.anchors.iter().zip(&truth.anchors).zip(&ce.sigma.anchors).enumerate() {
        for i in 0..3 {
            z_max = z_max.max((a[i] - t[i]).abs() / s[i]);
            assert!(
                (a[i] - t[i]).abs() < k * s[i] + 2e-4,
                "anchor {j}[{i}] off by {:.2} mm, sigma {:.2} mm",
                (a[i] - t[i]).abs() * 1e3,
                s[i] * 1e3
            );
        }
    }
    eprintln!(
        "ROBUST e2e_start: largest anchor error {z_max:.2} sigma; held-out RMS {:.3} mm (initial estimate {:.3} mm)",
        cal.heldout_rms_new_m * 1e3,
        cal.heldout_rms_old_m * 1e3
    );
    // Accepted by the daemon's held-out rule (not clearly worse than the running set by more than
    // daemon.heldout_tolerance_m: unit-tested with its error rates in taut-calibrator). Its
    // RMS values are reported; comparing them again here (it was: new < 1.05 old) asserted on
    // held-out noise, a few hundredths of a mm either way when the initial estimate is good.
    assert!(cal.heldout_rms_new_m > 0.0 && cal.heldout_rms_old_m > 0.0, "{} vs {}", cal.heldout_rms_new_m, cal.heldout_rms_old_m);
    // Bumpless: the ramp's largest per-cycle step is 1.5 |delta| dt / T; the change the new
    // parameters cause is a few mm, so well under a tenth of a millimetre per cycle.
    assert!(l.snap.max_swap_step_m > 0.0 && l.snap.max_swap_step_m < 1e-4, "max swap step {} m", l.snap.max_swap_step_m);
    assert_eq!(l.dropped, 0);
    assert!(c.samples_recorded > 1000);
    let params_dir = dir.path().join("data/params");
    assert!(params_dir.join("params-v0001.toml").exists() && params_dir.join("params-v0002.toml").exists());
    let current = taut_config::params::ParamsFile::load(params_dir.join("current.toml")).unwrap();
    assert_eq!(current.version, 2);
    // The recording is a valid cdpr-recording v1 file.
    let (rec, _) = taut_config::recording::Recording::load(&d.recording).unwrap();
    assert!(rec.len() > 1000 && rec.phase.is_some() && rec.f.is_some());

    // The operator's side: status, params, recalibrate, progress in status, stop.
    let st = control::request(&sock, "status", Duration::from_secs(5)).unwrap();
    assert_eq!(st["state"], "operate");
    let p = control::request(&sock, "params", Duration::from_secs(5)).unwrap();
    assert_eq!(p["params"]["version"], 2);
    // The `taut` binary over the real socket: the human status, a watcher following the events,
    // a move waited on to arrival.
    let taut = |args: &[&str]| {
        let o = std::process::Command::new(crate::hostile::taut_bin()).arg("ctl").arg("--socket").arg(&sock).args(args).output().unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (ok, out, err) = taut(&["status"]);
    assert!(ok, "{err}");
    for key in [
        "state        operate",
        "fault        none",
        "calibration  v2",
        "drives       cable 1 (node 1): enabled",
        "tracker      pose (",
        "loop         ",
    ] {
        assert!(out.contains(key), "no {key:?} in\n{out}");
    }
    let watch = std::process::Command::new(crate::hostile::taut_bin())
        .args(["ctl", "--socket"])
        .arg(&sock)
        .args(["watch", "--from", "1"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let goal = {
        use taut_io::FromRobot;
        let w = taut_rt::motion::ControllerConfig::from_robot(&cfg).unwrap().workspace;
        let t = st["target_m"].as_array().unwrap();
        // 0.15 m from where the start-up left the platform, towards the middle: a short move.
        let here: [f64; 3] = std::array::from_fn(|i| t[i].as_f64().unwrap());
        let mid: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
        let d = dist(&here, &mid);
        std::array::from_fn::<f64, 3, _>(|i| here[i] + 0.15 * (mid[i] - here[i]) / d)
    };
    let (xs, ys, zs) = (goal[0].to_string(), goal[1].to_string(), goal[2].to_string());
    let (ok, out, err) = taut(&["move", &xs, &ys, &zs, "--wait", "--tolerance", "10"]);
    assert!(ok, "move --wait: {out}{err}");
    assert!(out.contains("arrived") && out.contains("mm from the goal"), "{out}");

    // `taut ctl recalibrate --wait`: says before starting where the platform comes back to, and
    // returns when the outcome is in and the platform is back.
    let (ok, out, err) = taut(&["recalibrate", "--wait"]);
    assert!(ok, "recalibrate --wait: {out}{err}");
    assert!(out.contains("comes back to") && out.contains("outcome #3: ") && out.contains("back at"), "{out}");
    let st = control::request(&sock, "status", Duration::from_secs(5)).unwrap();
    let back_to = st["recalibrate"]["return_to_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>();
    assert!(dist(&[back_to[0], back_to[1], back_to[2]], &goal) < 1e-9, "returns to {back_to:?}, not to {goal:?}");
    assert_eq!(st["recalibrate"]["stage"], "returned", "{}", st["recalibrate"]);
    let outcomes = st["calibration"]["outcomes"].as_array().unwrap();
    let last = outcomes.last().unwrap();
    assert_eq!(last["run"], 1);
    // Accepted (a better fit) or rejected with a reason; rejected leaves version 2 running.
    if last["accepted"] == true {
        assert!(d.wait_until(Duration::from_secs(10), |l, _| l.snap.params_version == 3 && !l.snap.swap_active));
    } else {
        assert!(!last["reason"].as_str().unwrap().is_empty());
        assert_eq!(d.loop_status().snap.params_version, 2);
    }
    let json = serde_json::to_string(&st).unwrap();
    eprintln!("e2e_start: status after a recalibration: {} bytes of JSON", json.len());
    assert!(json.len() < 16 * 1024, "status is {} bytes", json.len());
    let r = control::request(&sock, "stop", Duration::from_secs(5)).unwrap();
    assert_eq!(r["ok"], true);
    let rep = d.wait().unwrap();
    assert!(rep.cycles > 10_000);
    assert!(!sock.exists(), "the socket is removed on exit");
    // The watcher saw the events in order and ended with the daemon.
    let out = watch.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let mut at = 0;
    for want in [
        "initialisation phase 1 of 3",
        "accepted as parameters v2",
        "goal #1",
        "arrived",
        "recalibrate: the excitation",
        "-> excitation",
        "recalibrate: back at",
        "-> stopped",
        "-- the daemon has stopped",
    ] {
        let k = text[at..].find(want).unwrap_or_else(|| {
            panic!("watch: no {want:?} after byte {at} in\n{text}\nits stderr:\n{}", String::from_utf8_lossy(&out.stderr))
        });
        at += k + want.len();
    }
}
