//! The operator's workflow on the simulated robot in simulated time:
//! the control socket's request handling (`ControlLinks`, what the control thread answers) and
//! its periodic work (`ControlLinks::tick`, what the control thread runs every round) driven
//! between the cycles of the whole robot stack in lockstep.
//!
//! status (the human form's key lines; the JSON under 16 KiB after 5 recalibrations),
//! `move` followed to arrival (`MoveWait`, what `taut ctl move --wait` runs), `recalibrate`
//! bringing the platform back, `estop`, `reset`, `stop`, and the event journal that `taut ctl
//! watch` follows, in order.

use serde_json::Value;
use std::sync::{Arc, Mutex};
use taut_calibrator::calib_backend::TautCalib;
use taut_config::RobotConfig;
use taut_io::FromRobot;
use taut_operator::control::{status_text, ControlLinks};
use taut_operator::operator::{GoalEnd, GoalView, MoveWait};
use taut_rt::motion::{ControllerConfig, State};
use taut_simrig::{Lockstep, RunOptions, SimOptions};

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn arr3(v: &Value) -> [f64; 3] {
    let a = v.as_array().unwrap_or_else(|| panic!("not a point: {v}"));
    [a[0].as_f64().unwrap(), a[1].as_f64().unwrap(), a[2].as_f64().unwrap()]
}

/// The robot host and the control socket's side of it.
struct Rig {
    host: Lockstep,
    links: ControlLinks,
    log: Arc<Mutex<Vec<String>>>,
    /// Every journal event read so far, in the order read.
    events: Vec<Value>,
    next: u64,
}

impl Rig {
    fn req(&self, line: &str) -> Value {
        self.links.handle_line(line)
    }

    /// Runs until `done` holds (checked with the control thread's tick every 0.1 s simulated)
    /// or `max_s` pass; reads the journal as `watch` does.
    fn run_until(&mut self, max_s: f64, mut done: impl FnMut(&Value) -> bool) -> bool {
        let links = self.links.clone();
        let mut ok = false;
        let mut got = Vec::new();
        let mut next = self.next;
        self.host.run_until(max_s, |_, _| {
            links.tick();
            let ev = links.handle_line(&format!("events {next}"));
            assert_eq!(ev["lost"], 0, "the journal lost events");
            got.extend(ev["events"].as_array().unwrap().iter().cloned());
            next = ev["next"].as_u64().unwrap();
            ok = done(&links.handle_line("status"));
            ok
        });
        self.events.extend(got);
        self.next = next;
        ok
    }

    /// `move X Y Z --wait`: the reply's goal followed to its end.
    fn move_wait(&mut self, p: [f64; 3], tolerance_m: f64) -> (u64, GoalEnd) {
        let r = self.req(&format!("move {} {} {}", p[0], p[1], p[2]));
        assert_eq!(r["ok"], true, "{r}");
        let id = r["goal"].as_u64().unwrap();
        let mut w = MoveWait::new(id, tolerance_m);
        let mut end = None;
        self.run_until(120.0, |st| {
            end = w.observe(&GoalView::from_status(st));
            end.is_some()
        });
        (id, end.unwrap_or_else(|| panic!("goal #{id} to {p:?}: no end in 120 s")))
    }
}

#[test]
fn the_operator_workflow_on_the_simulated_robot() {
    let wall = std::time::Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = RobotConfig::from_toml_str(include_str!("../../../config/examples/aras-cam-sim.toml")).unwrap();
    cfg.daemon.data_dir = dir.path().join("data").display().to_string();
    // The test start-up's shorter motions (tests/src/startup.rs).
    cfg.motion.excitation_s = taut_tests::startup::EXCITATION_S;
    cfg.motion.init_reel_speed_m_s = taut_tests::startup::INIT_REEL_SPEED_M_S;
    let so = SimOptions { seed: 3, ..Default::default() };
    let p0 = taut_tests::startup::rest_p0(&cfg, &so);
    let host = Lockstep::start(&cfg, p0, &so, RunOptions::default(), Box::new(TautCalib::from_config(&cfg))).unwrap();
    let log = Arc::new(Mutex::new(Vec::<String>::new()));
    let l2 = log.clone();
    host.handle().operator().set_log(Arc::new(move |l: &str| l2.lock().unwrap().push(l.to_string())));
    let links = host.handle().control_links(None);
    let mut rig = Rig { host, links, log, events: Vec::new(), next: 1 };

    // The start-up, as the daemon runs it.
    assert!(rig.run_until(400.0, |st| st["params_version"].as_u64() >= Some(2) && st["swap_active"] == false || !st["fault"].is_null()));
    let st = rig.req("status");
    assert!(st["fault"].is_null(), "{}", st["fault"]);

    // The human form: one line per subject.
    let text = status_text(&st);
    eprintln!("{text}");
    for key in ["state", "fault", "goal", "calibration", "outcomes", "drives", "load cells", "tracker", "loop"] {
        assert!(text.lines().any(|l| l.starts_with(&format!("{key:<12} "))), "no {key:?} line in\n{text}");
    }
    assert!(text.contains("state        operate") && text.contains("parameters v2"), "{text}");
    assert!(text.contains("fault        none"), "{text}");
    assert!(text.contains("worst 1-sigma") && text.contains(" mm ("), "{text}");
    assert!(
        text.contains("cable 1 (node 1): enabled, cable 2 (node 2): enabled, cable 3 (node 3): enabled, cable 4 (node 4): enabled"),
        "{text}"
    );
    assert!(text.contains("tracker      pose ("), "{text}");

    // move --wait: returns on arrival within the tolerance; the platform is there.
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let centre: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
    let half: [f64; 3] = std::array::from_fn(|i| (w[1][i] - w[0][i]) / 2.0);
    let goal: [f64; 3] = std::array::from_fn(|i| centre[i] + [0.4, -0.3, 0.2][i] * half[i]);
    let tol = 5e-3;
    let (id, end) = rig.move_wait(goal, tol);
    assert!(end.arrived(), "goal #{id}: {}", end.describe());
    let err = end.error_m().expect("the tracker measures the error");
    assert!(err <= tol, "arrived {err} m off");
    let there = rig.host.platform().position();
    assert!(dist(&there, &goal) < 2.0 * tol, "the platform is at {there:?}, {:.1} mm from the goal", dist(&there, &goal) * 1e3);
    let st = rig.req("status");
    assert_eq!(arr3(&st["goal"]["target_m"]), goal, "status shows the goal");
    assert_eq!(st["goal"]["ended"]["outcome"], "arrived");

    // A move waited on with a tolerance tighter than the platform can hold ends off target,
    // with its error: `--wait` does not report arrival it cannot see.
    let goal2: [f64; 3] = std::array::from_fn(|i| centre[i] + [0.2, -0.1, 0.2][i] * half[i]);
    let (_, end) = rig.move_wait(goal2, 1e-9);
    assert!(matches!(end, GoalEnd::OffTarget { error_m } if error_m > 1e-9), "{end:?}");

    // recalibrate, five times: says before starting where the platform comes back to, and
    // brings it back there.
    for k in 1..=5 {
        let r = rig.req("recalibrate");
        assert_eq!(r["ok"], true, "recalibration {k}: {r}");
        let back_to = arr3(&r["return_to_m"]);
        assert!(dist(&back_to, &goal2) < 1e-9, "recalibration {k}: returns to {back_to:?}, not to the goal {goal2:?}");
        assert!(r["message"].as_str().unwrap().contains("comes back to"), "{r}");
        let over = rig.run_until(200.0, |st| matches!(st["recalibrate"]["stage"].as_str(), Some("returned" | "stopped")));
        let st = rig.req("status");
        assert!(over, "recalibration {k}: not over: {}", st["recalibrate"]);
        assert_eq!(st["recalibrate"]["stage"], "returned", "recalibration {k}: {}", st["recalibrate"]);
        let there = rig.host.platform().position();
        assert!(
            dist(&there, &back_to) < 2.0 * tol,
            "recalibration {k}: the platform is {:.1} mm from where it was",
            dist(&there, &back_to) * 1e3
        );
    }
    // The outcomes of five recalibrations are in; the calibrator has finished the last one.
    assert!(rig.run_until(60.0, |st| st["calibration"]["outcomes_total"].as_u64() >= Some(7)));
    let st = rig.req("status");
    let json = serde_json::to_string(&st).unwrap();
    eprintln!("status after 5 recalibrations: {} bytes of JSON; human form:\n{}", json.len(), status_text(&st));
    assert!(json.len() < 16 * 1024, "status is {} bytes", json.len());
    assert_eq!(st["calibration"]["outcomes_total"], 7);
    // Each outcome in full behind `outcome N`; a number beyond them is refused with the range.
    let o = rig.req("outcome 3");
    assert_eq!(o["outcome"]["n"], 3, "{o}");
    assert!(o["outcome"]["data_problems"].is_array());
    let bad = rig.req("outcome 99");
    assert!(bad["error"].as_str().unwrap().contains("1 to 7"), "{bad}");

    // A sixth recalibration, stopped by an estop during its excitation: status and log say
    // where the platform stopped instead of claiming it came back. The estop latches, reset
    // brings the robot back holding, stop ends it.
    assert_eq!(rig.req("recalibrate")["ok"], true);
    assert!(rig.run_until(10.0, |st| st["state"] == "excitation"));
    rig.run_until(3.0, |_| false);
    assert_eq!(rig.req("estop")["accepted"], "estop");
    assert!(rig.run_until(2.0, |st| st["state"] == "faulted" && st["recalibrate"]["stage"] == "stopped"));
    let st = rig.req("status");
    let at = arr3(&st["recalibrate"]["at_m"]);
    let there = rig.host.platform().position();
    assert!(dist(&at, &there) < 0.02 && dist(&at, &goal2) > 0.05, "stopped at {at:?}, the platform is at {there:?}");
    assert!(st["recalibrate"]["why"].as_str().unwrap().contains("emergency stop"), "{}", st["recalibrate"]);
    let text = status_text(&st);
    assert!(text.contains("fault        ") && text.contains("taut ctl reset"), "{text}");
    assert!(text.contains("recalibrate  did not return to"), "{text}");
    assert_eq!(rig.req("reset")["accepted"], "reset");
    assert!(rig.run_until(30.0, |st| st["reset"]["last"]["outcome"] == "done"), "{}", rig.req("status")["reset"]);
    assert_eq!(rig.req("stop")["accepted"], "stop");
    assert!(rig.run_until(10.0, |st| st["state"] == "stopped"));
    assert_eq!(rig.host.loop_status().snap.state, State::Stopped);

    // The journal `watch` follows: numbered without gaps, in time order, and the workflow's
    // events in the order they happened.
    for (a, b) in rig.events.iter().zip(rig.events.iter().skip(1)) {
        assert_eq!(b["seq"].as_u64(), a["seq"].as_u64().map(|s| s + 1), "a gap: {a} then {b}");
        assert!(b["t_s"].as_f64() >= a["t_s"].as_f64(), "out of order: {a} then {b}");
    }
    let find = |from: usize, pred: &dyn Fn(&Value) -> bool, what: &str| -> usize {
        from + rig.events[from..].iter().position(pred).unwrap_or_else(|| {
            let tail: Vec<String> = rig.events[from..].iter().map(|e| e["text"].as_str().unwrap().to_string()).collect();
            panic!("no {what} after event {from}: {tail:#?}")
        })
    };
    let is = |kind: &'static str, key: &'static str, val: &'static str| move |e: &Value| e["event"] == kind && e[key] == val;
    let mut i = find(0, &|e| e["event"] == "phase" && e["phase"] == 0, "phase 1 of 3");
    i = find(i, &|e| e["event"] == "outcome" && e["accepted"] == true && e["kind"] == "calibration", "the start-up's calibration");
    i = find(i, &|e| e["event"] == "goal" && e["id"] == id, "the first goal");
    i = find(i, &|e| e["event"] == "goal-end" && e["outcome"] == "arrived", "its arrival");
    // The second goal: the daemon judges arrival with its own 5 mm; the tighter wait above
    // ended off target on its own.
    i = find(i, &|e| e["event"] == "goal" && e["id"] == id + 1, "the second goal");
    i = find(i, &|e| e["event"] == "goal-end" && e["id"] == id + 1, "its end");
    for k in 1..=5 {
        i = find(i, &|e| e["event"] == "recalibrate", &format!("recalibration {k}"));
        i = find(i, &is("state", "to", "excitation"), "the excitation");
        i = find(i, &|e| e["event"] == "goal" && e["origin"] == "recalibrate", "the return goal");
        i = find(i, &is("return", "stage", "returned"), "the return");
    }
    i = find(i, &|e| e["event"] == "recalibrate", "recalibration 6");
    i = find(i, &is("state", "to", "excitation"), "its excitation");
    i = find(i, &|e| e["event"] == "fault" && e["cause"] == "estop", "the estop");
    i = find(i, &is("return", "stage", "stopped"), "the return that did not happen");
    i = find(i, &is("reset", "outcome", "done"), "the reset");
    find(i, &is("state", "to", "stopped"), "the stop");

    // The daemon's log for people: phases with their expected durations, and at each hot-swap
    // the worst 1-sigma, the largest anchor change and the held-out RMS.
    let log = rig.log.lock().unwrap().clone();
    assert!(log.iter().any(|l| l.starts_with("initialisation phase 1 of 3, about ")), "{log:#?}");
    assert!(log.iter().any(|l| l.contains("excitation: about 15 s of motion")), "{log:#?}");
    let swaps: Vec<&String> = log.iter().filter(|l| l.contains("accepted as parameters v")).collect();
    assert!(
        swaps.iter().skip(1).all(|l| l.contains("worst 1-sigma") && l.contains("largest anchor change") && l.contains("held-out RMS")),
        "{swaps:#?}"
    );
    assert!(swaps.len() >= 2, "{log:#?}");
    assert!(log.iter().any(|l| l.starts_with("recalibrate: the platform did not return to ")), "{log:#?}");
    eprintln!(
        "operator workflow: {:.1} s simulated in {:.1} s; {} events; log:\n{}",
        rig.host.sim_s(),
        wall.elapsed().as_secs_f64(),
        rig.events.len(),
        log.join("\n")
    );
    rig.host.finish(true);
}
