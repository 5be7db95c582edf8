//! One wild value in a clean recording: an encoder reading of
//! 1e308, 1e160, -1e308, inf, a 5 cm spike, a 2 cm jump; an impossible tension; a wild tracker
//! position. Each goes through `taut calibrate --out --json`, `taut diagnose --json` (the
//! binary) and the daemon's calibration path (`calibrator::evaluate`: the same screening,
//! backend and acceptance rules as `taut start`). Each must be reported as a data problem at
//! its row, and the result must stay within a few sigma of the clean recording's, with no
//! non-finite number in any file; or the run must fail cleanly with the reason.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::calibrator::evaluate;
use taut_calibrator::vocab::{CalibratorConfig, Estimate, HeldoutBlocks};
use taut_config::params::ParamsFile;
use taut_config::recording::Recording;
use taut_rt::kin::LoopParams;
use taut_sim::{simulate, Scenario};

#[derive(Debug, Clone, Copy)]
enum Target {
    Encoder(usize),
    Tension(usize),
    Tracker(usize),
}

#[derive(Debug, Clone, Copy)]
enum Change {
    Set(f64),
    Add(f64),
    /// Every reading from the row on moves by this much (lost counts).
    StepFrom(f64),
}

struct Case {
    name: &'static str,
    target: Target,
    /// Where, as a fraction of the recording; `1.0` is the last row.
    at: f64,
    change: Change,
}

fn cases() -> Vec<Case> {
    use Change::*;
    use Target::*;
    let c = |name, target, at, change| Case { name, target, at, change };
    vec![
        c("encoder 1e308", Encoder(0), 0.37, Set(1e308)),
        c("encoder 1e160", Encoder(1), 0.52, Set(1e160)),
        c("encoder 1e200", Encoder(2), 0.61, Set(1e200)),
        c("encoder -1e308", Encoder(3), 0.44, Set(-1e308)),
        c("encoder inf", Encoder(0), 0.29, Set(f64::INFINITY)),
        c("encoder -inf", Encoder(1), 0.71, Set(f64::NEG_INFINITY)),
        c("encoder 5 cm spike", Encoder(2), 0.33, Add(0.05)),
        c("encoder -5 cm spike", Encoder(3), 0.55, Add(-0.05)),
        c("encoder 1 cm spike", Encoder(1), 0.48, Add(0.01)),
        c("encoder 2 mm spike", Encoder(3), 0.27, Add(0.002)),
        c("encoder reads 0", Encoder(0), 0.66, Set(0.0)),
        c("encoder 1e6 m", Encoder(2), 0.58, Set(1e6)),
        c("encoder 2 cm jump", Encoder(0), 0.5, StepFrom(0.02)),
        c("encoder -2 cm jump", Encoder(1), 0.35, StepFrom(-0.02)),
        c("encoder 5 mm jump", Encoder(2), 0.75, StepFrom(0.005)),
        c("encoder 1e308 in the first row", Encoder(3), 0.0, Set(1e308)),
        c("encoder 5 cm spike in the last row", Encoder(1), 1.0, Add(0.05)),
        c("tension inf", Tension(0), 0.4, Set(f64::INFINITY)),
        c("tension 1e308", Tension(1), 0.45, Set(1e308)),
        c("tension -50 N", Tension(2), 0.5, Set(-50.0)),
        c("tension -1e308", Tension(3), 0.62, Set(-1e308)),
        c("tension 1e200", Tension(0), 0.3, Set(1e200)),
        c("tension 1e160", Tension(1), 0.7, Set(1e160)),
        c("tracker x 1e308", Tracker(0), 0.42, Set(1e308)),
        c("tracker y 1e160", Tracker(1), 0.53, Set(1e160)),
        c("tracker z -1e308", Tracker(2), 0.47, Set(-1e308)),
        c("tracker x +30 cm", Tracker(0), 0.38, Add(0.3)),
        c("tracker z -5 cm", Tracker(2), 0.64, Add(-0.05)),
        c("tracker y inf", Tracker(1), 0.31, Set(f64::INFINITY)),
        c("tracker x 1e200", Tracker(0), 0.57, Set(1e200)),
        c("tracker y +2 cm", Tracker(1), 0.68, Add(0.02)),
        c("tracker z reads 0", Tracker(2), 0.49, Set(0.0)),
    ]
}

/// The row a case hits: the first at or after `at` (in the excitation; `1.0` is the last row)
/// whose values are all present and, for an encoder, where its cable is taut (over 10 N at the
/// row, over 8 N three rows either side; slack is below 2 x 3 N). A slack cable's encoder follows its winch, not the
/// geometry: the screen does not test it locally (see `taut_calib::screen`).
fn row_of(rec: &Recording, first_exc: usize, at: f64, target: Target) -> usize {
    let m = rec.len();
    if at >= 1.0 {
        return m - 1;
    }
    let n = rec.n_cables;
    let present = |i: usize| {
        rec.p[i].iter().all(|v| v.is_finite())
            && rec.lengths(i).iter().all(|v| v.is_finite())
            && rec.f.as_ref().is_none_or(|f| f[i * n..(i + 1) * n].iter().all(|v| v.is_finite()))
    };
    let taut = |i: usize| match target {
        Target::Encoder(j) => {
            let f = rec.f.as_ref().unwrap();
            f[i * n + j] > 10.0 && (i.saturating_sub(3)..(i + 4).min(m)).all(|k| f[k * n + j] > 8.0)
        }
        _ => true,
    };
    let start = if at == 0.0 { 0 } else { first_exc.max((at * m as f64) as usize) };
    let ok = |i: &usize| present(*i) && (at == 0.0 || taut(*i));
    (start..m).find(ok).or_else(|| (first_exc..start).rev().find(ok)).expect("a complete row")
}

fn apply(rec: &mut Recording, case: &Case, row: usize) {
    let n = rec.n_cables;
    let set = |x: &mut f64, c: Change| match c {
        Change::Set(v) => *x = v,
        Change::Add(v) | Change::StepFrom(v) => *x += v,
    };
    let rows = match case.change {
        Change::StepFrom(_) => row..rec.len(),
        _ => row..row + 1,
    };
    for i in rows {
        match case.target {
            Target::Encoder(j) => set(&mut rec.l[i * n + j], case.change),
            Target::Tension(j) => set(&mut rec.f.as_mut().unwrap()[i * n + j], case.change),
            Target::Tracker(a) => set(&mut rec.p[i][a], case.change),
        }
    }
}

fn expected_problem(t: Target, change: Change) -> (&'static str, &'static str, Option<usize>) {
    match (t, change) {
        (Target::Encoder(j), Change::StepFrom(_)) => ("encoder-jump", "encoder-jump", Some(j)),
        (Target::Encoder(j), _) => ("encoder-spike", "encoder-spike", Some(j)),
        (Target::Tension(j), _) => ("impossible-tension", "impossible-tension", Some(j)),
        (Target::Tracker(_), _) => ("tracker-jump", "tracker-outlier", None),
    }
}

/// The `taut` binary, built with the profile of this test (the library crates optimised).
fn taut_bin() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf();
    let st = Command::new(env!("CARGO"))
        .args(["build", "--quiet", "--profile", "test", "-p", "taut-cli", "--bin", "taut"])
        .current_dir(&root)
        .status()
        .expect("run cargo build");
    assert!(st.success(), "building taut failed");
    let exe = std::env::current_exe().unwrap();
    exe.parent().unwrap().parent().unwrap().join("taut")
}

struct Run {
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

/// Runs `taut` with a deadline (a hang is a failure, not a stuck test).
fn run(bin: &Path, args: &[&str]) -> Run {
    let mut child = Command::new(bin).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn taut");
    let out_pipe = child.stdout.take().unwrap();
    let err_pipe = child.stderr.take().unwrap();
    let read = |mut p: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = p.read_to_string(&mut s);
            s
        })
    };
    let (to, te) = (read(Box::new(out_pipe)), read(Box::new(err_pipe)));
    let deadline = Instant::now() + Duration::from_secs(600);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stdout = to.join().unwrap();
    let stderr = te.join().unwrap();
    assert!(status.is_some(), "taut {args:?} hung for 600 s");
    Run { code: status.unwrap().code(), stdout, stderr }
}

/// The 1-based line of data row `row` in a CSV file (after the comments and the header).
fn line_of_row(csv: &str, row: usize) -> usize {
    let text = std::fs::read_to_string(csv).unwrap();
    let header = text.lines().position(|l| !l.starts_with('#') && !l.trim().is_empty()).unwrap();
    header + 2 + row
}

/// True when a panic shows in the output (exit code 101 or the panic message).
fn panicked(r: &Run) -> bool {
    r.code == Some(101) || r.stderr.contains("panicked at")
}

fn anchors_of(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|a| {
            let a = a.as_array().unwrap();
            [0, 1, 2].map(|k| a[k].as_f64().unwrap_or(f64::NAN))
        })
        .collect()
}

/// Largest |a - b| over sigma, per coordinate.
fn worst_sigmas(a: &[[f64; 3]], b: &[[f64; 3]], s: &[[f64; 3]]) -> f64 {
    let mut w = 0.0f64;
    for j in 0..a.len() {
        for k in 0..3 {
            let z = (a[j][k] - b[j][k]).abs() / s[j][k];
            w = if z.is_nan() { f64::INFINITY } else { w.max(z) };
        }
    }
    w
}

/// Every number in a TOML or JSON text is finite: no `nan`, `inf` (TOML), and no `null` where a
/// number should be (JSON writes non-finite as null) in the parameters.
fn no_non_finite_token(text: &str) -> bool {
    !text
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .any(|w| matches!(w.to_ascii_lowercase().as_str(), "nan" | "inf" | "infinity"))
}

#[derive(Default)]
struct Tally {
    cases: usize,
    clean_errors: usize,
    panics: usize,
    wrong_successes: usize,
    failures: Vec<String>,
}

/// Tolerance on the anchors, in the clean run's one-sigma: one excluded reading (or a
/// re-referenced jump, sigma about half the encoder noise) moves them by a small fraction of
/// a sigma; 3 sigma leaves no room for a result dragged by a wild value (the 26 mm
/// against 0.3 mm).
const SIGMAS: f64 = 3.0;

#[test]
// `!(w <= SIGMAS)` fails a NaN distance too, which `w > SIGMAS` would let through.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn one_wild_value_is_a_data_problem_in_calibrate_diagnose_and_the_daemon() {
    let mut s = Scenario::aras_cam(31);
    // No gross tracker outliers in the clean recording: the only wild value is the injected one
    // (the screen finds the simulator's own outliers too; they would only crowd the report).
    s.noise.tracker_outlier_prob = 0.0;
    let sim = simulate(&s);
    let clean = sim.recording;
    let m = clean.len();
    let first_exc = clean.phase.as_ref().and_then(|p| p.iter().rposition(|&k| k >= 0)).map_or(0, |i| i + 1);
    eprintln!("clean recording: {m} rows x {} cables, excitation from row {first_exc}", clean.n_cables);
    let dir = tempfile::tempdir().unwrap();
    let bin = taut_bin();
    let path = |name: &str| dir.path().join(name).display().to_string();

    // The clean recording: no data problem at all, and the reference results.
    clean.save_atomic(path("clean.csv")).unwrap();
    let r = run(&bin, &["calibrate", &path("clean.csv"), "--out", &path("clean.toml"), "--json", &path("clean.json")]);
    assert_eq!(r.code, Some(0), "clean calibrate: {}\n{}", r.stdout, r.stderr);
    assert!(!r.stdout.contains("data problem"), "a clean simulator recording has no wild value: {}", r.stdout);
    let clean_p = ParamsFile::load(path("clean.toml")).unwrap();
    let r = run(&bin, &["diagnose", &path("clean.csv"), "--json", &path("clean-d.json")]);
    assert_eq!(r.code, Some(0), "clean diagnose: {}\n{}", r.stdout, r.stderr);
    let clean_d: Value = serde_json::from_str(&std::fs::read_to_string(path("clean-d.json")).unwrap()).unwrap();
    let clean_effects: Vec<String> =
        clean_d["effects"].as_array().unwrap().iter().map(|e| e["effect"].as_str().unwrap().to_string()).collect();
    let clean_d_anchors = anchors_of(&clean_d["final"]["anchors_m"]);
    let clean_d_sigma = anchors_of(&clean_d["final"]["anchor_sigma_m"]);
    assert!(
        !clean_d["data_problems"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| matches!(p["problem"].as_str(), Some("encoder-spike" | "encoder-jump" | "impossible-tension" | "tracker-outlier"))),
        "{}",
        clean_d["data_problems"]
    );

    // The daemon's path: the excitation rows, from running parameters 5 mm off the clean result.
    let robot = &s.robot;
    let ccfg = CalibratorConfig::from_robot(robot);
    let exc = clean.slice(first_exc..m);
    let mut init = Estimate {
        model_consistent: None,
        geometry: clean_p.geometry(),
        sigma: clean_p.sigmas(),
        rms_m: clean_p.rms_m,
        observable: true,
        note: "test".into(),
        effects: Default::default(),
    };
    for a in init.geometry.anchors.iter_mut() {
        a[0] += 0.005;
        a[2] -= 0.005;
    }
    let current = LoopParams::from_geometry(1, &init.geometry, &ccfg.platform).unwrap();
    let mut backend = TautCalib::from_config(robot);
    let base = evaluate(&ccfg, &mut backend, &exc, &init, current);
    assert!(base.accepted, "clean excitation refused: {}", base.reason);
    assert!(base.data_problems.is_empty(), "{:#?}", base.data_problems);
    let base_est = base.estimate.clone().unwrap();
    let split = HeldoutBlocks::new(exc.len(), ccfg.heldout_fraction);

    let mut t = Tally::default();
    for case in cases() {
        let row = row_of(&clean, first_exc, case.at, case.target);
        let mut rec = clean.clone();
        apply(&mut rec, &case, row);
        let (kind_cal, kind_diag, cable) = expected_problem(case.target, case.change);
        let tag = case.name.replace(' ', "_");
        let csv = path(&format!("{tag}.csv"));
        rec.save_atomic(&csv).unwrap();
        let out = path(&format!("{tag}.toml"));
        let js = path(&format!("{tag}.json"));
        let djs = path(&format!("{tag}-d.json"));
        let finite_value = match case.change {
            Change::Set(v) | Change::Add(v) | Change::StepFrom(v) => v.is_finite(),
        };
        let fail = |t: &mut Tally, wrong: bool, what: String| {
            if wrong {
                t.wrong_successes += 1;
            }
            t.failures.push(format!("{} (row {row}): {what}", case.name));
        };

        // 1. taut calibrate --out --json.
        t.cases += 1;
        let r = run(&bin, &["calibrate", &csv, "--out", &out, "--json", &js]);
        if panicked(&r) {
            t.panics += 1;
            fail(&mut t, false, format!("calibrate panicked: {}", r.stderr));
        } else if !finite_value {
            // The recording format has no infinite values: the reader refuses the file, naming the
            // line (comment lines + header + row) and the column, and nothing is written.
            let line = line_of_row(&csv, row);
            let line_ok = r.stderr.contains(&format!("line {line}")) || r.stderr.contains(&format!(":{line}"));
            if r.code != Some(0) && line_ok && !Path::new(&out).exists() {
                t.clean_errors += 1;
            } else {
                fail(&mut t, r.code == Some(0), format!("calibrate on a file with inf: exit {:?}, {}", r.code, r.stderr));
            }
        } else if r.code != Some(0) {
            let refused = r.stderr.contains("refused") || r.stderr.contains("failed");
            if refused && !Path::new(&out).exists() {
                t.clean_errors += 1;
            } else {
                fail(&mut t, false, format!("calibrate failed unclearly: {}", r.stderr));
            }
        } else {
            let text = std::fs::read_to_string(&out).unwrap_or_default();
            let v: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap_or_default()).unwrap_or(Value::Null);
            let reported = v["data_problems"].as_array().is_some_and(|a| {
                a.iter().any(|p| p["problem"] == kind_cal && p["row"] == row && p["cable"].as_u64().map(|c| c as usize) == cable)
            });
            let p = ParamsFile::load(&out);
            match p {
                Err(e) => fail(&mut t, true, format!("calibrate wrote an unreadable file: {e}")),
                Ok(p) => {
                    let w = worst_sigmas(&p.anchors_m, &clean_p.anchors_m, &clean_p.anchor_sigma_m);
                    if !no_non_finite_token(&text) {
                        fail(&mut t, true, format!("non-finite number in the parameters: {text}"));
                    } else if !(w <= SIGMAS) {
                        fail(&mut t, true, format!("anchors {w:.1} sigma from the clean calibration"));
                    } else if !reported {
                        fail(&mut t, true, format!("{kind_cal} at row {row} not reported: {}", v["data_problems"]));
                    }
                }
            }
        }

        // 2. taut diagnose --json.
        t.cases += 1;
        let r = run(&bin, &["diagnose", &csv, "--json", &djs]);
        if panicked(&r) {
            t.panics += 1;
            fail(&mut t, false, format!("diagnose panicked: {}", r.stderr));
        } else if !finite_value {
            let line = line_of_row(&csv, row);
            let line_ok = r.stderr.contains(&format!("line {line}")) || r.stderr.contains(&format!(":{line}"));
            if r.code != Some(0) && line_ok {
                t.clean_errors += 1;
            } else {
                fail(&mut t, r.code == Some(0), format!("diagnose on a file with inf: exit {:?}, {}", r.code, r.stderr));
            }
        } else if r.code != Some(0) {
            if r.stderr.contains("refused") {
                t.clean_errors += 1;
            } else {
                fail(&mut t, false, format!("diagnose failed: {}", r.stderr));
            }
        } else {
            let text = std::fs::read_to_string(&djs).unwrap_or_default();
            let d: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
            let reported = d["data_problems"].as_array().is_some_and(|a| {
                a.iter().any(|p| {
                    p["problem"] == kind_diag
                        && p["cable"].as_u64().map(|c| c as usize) == cable
                        && p["description"].as_str().is_some_and(|s| s.contains(&format!("row {row} ")))
                })
            });
            let effects: Vec<String> = d["effects"]
                .as_array()
                .map(|a| a.iter().map(|e| e["effect"].as_str().unwrap_or("").to_string()).collect())
                .unwrap_or_default();
            let anchors = anchors_of(&d["final"]["anchors_m"]);
            let sig = anchors_of(&d["final"]["anchor_sigma_m"]);
            let w = worst_sigmas(&anchors, &clean_d_anchors, &clean_d_sigma);
            if !reported {
                fail(&mut t, true, format!("diagnose did not report {kind_diag} at row {row}: {}", d["data_problems"]));
            } else if effects != clean_effects {
                fail(&mut t, true, format!("diagnose named {effects:?}, the clean recording {clean_effects:?}"));
            } else if !(w <= SIGMAS) || sig.iter().flatten().any(|v| !v.is_finite()) {
                fail(&mut t, true, format!("diagnose anchors {w:.1} sigma from the clean ones, sigmas {sig:?}"));
            }
        }

        // 3. The daemon's calibration of the excitation with the same wild value.
        t.cases += 1;
        // Known gap: the daemon does not handle encoder jumps (`ScreenOptions::jumps` is off
        // there: its data sets show mm steps that are no lost counts), so a real lost-count jump
        // in a recalibration's data goes through. Not claimed, not counted.
        if matches!(case.change, Change::StepFrom(_)) {
            t.cases -= 1;
            continue;
        }
        if row < first_exc {
            // The first-row case is in the three phases, not in the excitation data set.
            t.cases -= 1;
            continue;
        }
        let mut erec = exc.clone();
        apply(&mut erec, &Case { at: 0.0, ..case }, row - first_exc);
        let o = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| evaluate(&ccfg, &mut backend, &erec, &init, current)));
        let Ok(o) = o else {
            t.panics += 1;
            fail(&mut t, false, "the daemon's calibration panicked".into());
            continue;
        };
        let (part, r) = match split.part_of(row - first_exc) {
            (false, k) => ("training", k),
            (true, k) => ("held-out", k),
        };
        // The daemon does not re-reference jumps (`ScreenOptions::jumps`): a jump shows there as
        // the readings it excluded, or the result is refused.
        let kind_daemon = if kind_cal == "encoder-jump" { "encoder-" } else { kind_cal };
        let reported = o
            .data_problems
            .iter()
            .any(|p| p.contains(part) && p.contains(kind_daemon) && (kind_cal == "encoder-jump" || p.contains(&format!("row {r} "))));
        if !o.accepted {
            if o.reason.is_empty() {
                fail(&mut t, false, "refused without a reason".into());
            } else {
                t.clean_errors += 1;
                eprintln!("{}: the daemon refuses: {}", case.name, o.reason);
            }
        } else {
            let e = o.estimate.as_ref().unwrap();
            let w = worst_sigmas(&e.geometry.anchors, &base_est.geometry.anchors, &base_est.sigma.anchors);
            let finite = e
                .geometry
                .anchors
                .iter()
                .flatten()
                .chain(&e.geometry.l0)
                .chain(e.sigma.anchors.iter().flatten())
                .chain(&e.sigma.l0)
                .all(|v| v.is_finite())
                && e.rms_m.is_finite();
            if !finite {
                fail(&mut t, true, "the daemon accepted non-finite numbers".into());
            } else if !(w <= SIGMAS) {
                fail(&mut t, true, format!("the daemon's anchors {w:.1} sigma from the clean excitation's"));
            } else if !reported {
                fail(&mut t, true, format!("the daemon did not report {kind_cal} at {part} row {r}: {:#?}", o.data_problems));
            }
        }
    }
    eprintln!(
        "hostile wild values: {} cases, {} clean errors, {} panics, {} wrong successes, {} other failures",
        t.cases,
        t.clean_errors,
        t.panics,
        t.wrong_successes,
        t.failures.len() - t.wrong_successes.min(t.failures.len())
    );
    assert!(t.cases >= 85, "{} cases", t.cases);
    assert!(t.failures.is_empty() && t.panics == 0, "{:#?}", t.failures);
}

/// The screen's false-alarm rate on the simulator (independent of the synthetic generator of the
/// unit tests): up to 18 clean recordings of ARAS-CAM and the three-cable robot (a scenario the
/// simulator cannot run is skipped: 17 today), three-phase motion,
/// slack excursions, dropouts and load-cell offsets included, gross tracker outliers off. At the
/// stated 1e-3 per recording, a flag in any of them would be a 1.8% event. Not the 20 m outdoor
/// robot: its heavy cables' sag follows the tension faster than the encoder noise allows, and
/// the screen takes a few of those readings per recording for spikes (known limitation).
#[test]
fn clean_simulator_recordings_have_no_wild_value() {
    use taut_calib::screen::{screen, ScreenOptions};
    let mut flagged = vec![];
    let mut count = 0;
    for seed in 0..9u64 {
        for mut s in [Scenario::aras_cam(100 + seed), Scenario::three_cable(200 + seed)] {
            s.noise.tracker_outlier_prob = 0.0;
            s.duration_s = 40.0;
            // A scenario the simulator cannot run (no static equilibrium) is skipped.
            let Ok(run) = taut_sim::try_simulate(&s) else {
                continue;
            };
            let rec = run.recording;
            let sc = screen(&rec, &ScreenOptions::new(s.robot.calibration.min_tension_n));
            count += 1;
            for w in &sc.findings {
                flagged.push(format!("{} seed {}: {w}", s.robot.robot.name, s.seed));
            }
        }
    }
    eprintln!("screen on clean simulator recordings: {count} recordings, {} flags", flagged.len());
    assert!(count >= 15, "only {count} recordings simulated");
    assert!(flagged.is_empty(), "{flagged:#?}");
}
