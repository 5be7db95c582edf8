//! Swapped length columns: with the configuration's nominal anchors,
//! a calibration whose anchors land at other cables' nominal anchors is called out by name
//! ("cables 1 and 2 look swapped") and `taut calibrate` exits non-zero unless `--allow-swapped`;
//! the same recording unswapped calibrates without a word about it. 4 and 8 cables.
//!
//! Without a configuration the lengths alone cannot tell: the platform is then a point mass, and
//! a file whose columns `l0` and `l1` are exchanged is exactly the recording of a robot whose
//! cables are numbered the other way round. With tensions recorded, length columns exchanged
//! without their tension columns are named (the platform's force balance at the calibrated
//! anchors holds only with the tensions exchanged too); both exchanged is again a renumbered
//! robot and calibrates without a word (docs/diagnosis.md, "Swapped cables").

use crate::hostile::{run_with_deadline, taut_bin};
use taut_config::recording::Recording;
use taut_sim::{simulate, Scenario};

/// `s` with a 90 s excitation at 20 Hz and no three-phase motion, and its recording.
fn recorded(mut s: Scenario) -> (Scenario, Recording) {
    s.three_phase = None;
    s.duration_s = 90.0;
    s.rate_hz = 20.0;
    let rec = simulate(&s).recording;
    (s, rec)
}

/// Runs `taut calibrate` on the recording `rec` of `s` with columns `swap` exchanged (none: as
/// recorded), with the robot's configuration; returns the exit code, stdout and stderr.
fn calibrate(
    dir: &std::path::Path,
    s: &(Scenario, Recording),
    swap: Option<(usize, usize)>,
    extra: &[&str],
) -> (Option<i32>, String, String) {
    calibrate_with(dir, s, swap, false, true, extra)
}

/// [`calibrate`], also exchanging the tension columns (`tensions_too`), with or without the
/// configuration.
fn calibrate_with(
    dir: &std::path::Path,
    (s, rec): &(Scenario, Recording),
    swap: Option<(usize, usize)>,
    tensions_too: bool,
    config: bool,
    extra: &[&str],
) -> (Option<i32>, String, String) {
    let mut rec = rec.clone();
    let n = rec.n_cables;
    if let Some((a, b)) = swap {
        for i in 0..rec.len() {
            rec.l.swap(i * n + a, i * n + b);
            if tensions_too {
                rec.f.as_mut().expect("tensions").swap(i * n + a, i * n + b);
            }
        }
    }
    let tag = format!("{}-{swap:?}-{tensions_too}-{config}-{}", s.robot.robot.name, extra.join("")).replace([' ', '(', ')', ','], "");
    let (path, cfg) = (dir.join(format!("{tag}.csv")), dir.join(format!("{tag}.toml")));
    rec.save_atomic(&path).unwrap();
    s.robot.save_atomic(&cfg).unwrap();
    let mut cmd = std::process::Command::new(taut_bin());
    cmd.arg("calibrate").arg(&path).args(extra);
    if config {
        cmd.arg("--config").arg(&cfg);
    }
    let run = run_with_deadline(cmd, std::time::Duration::from_secs(120));
    (run.code, run.stdout, run.stderr)
}

fn check(s: &(Scenario, Recording), swap: (usize, usize)) {
    let dir = tempfile::tempdir().unwrap();
    let (code, out, err) = calibrate(dir.path(), s, None, &[]);
    assert_eq!(code, Some(0), "as recorded: {err}");
    assert!(!out.contains("swapped") && !err.contains("swapped"), "{out}\n{err}");
    let (code, out, err) = calibrate(dir.path(), s, Some(swap), &[]);
    let named = format!("cables {} and {} look swapped", swap.0 + 1, swap.1 + 1);
    assert_ne!(code, Some(0), "swapped: {out}");
    assert!(err.contains(&named) && err.contains("--allow-swapped"), "{err}");
    let (code, out, err) = calibrate(dir.path(), s, Some(swap), &["--allow-swapped"]);
    assert_eq!(code, Some(0), "--allow-swapped: {err}");
    assert!(out.contains(&format!("swapped (--allow-swapped, calibrated as recorded): {named}")), "{out}");
}

/// Without a configuration: as recorded and with both column pairs exchanged nothing is said;
/// lengths exchanged without their tensions are named, refused, and allowed by `--allow-swapped`.
fn check_without_config(s: &(Scenario, Recording), swap: (usize, usize)) {
    let dir = tempfile::tempdir().unwrap();
    for (sw, both) in [(None, false), (Some(swap), true)] {
        let (code, out, err) = calibrate_with(dir.path(), s, sw, both, false, &[]);
        assert_eq!(code, Some(0), "{sw:?} {both}: {err}");
        assert!(!out.contains("swapped") && !err.contains("swapped"), "{out}\n{err}");
    }
    let named = format!("cables {} and {} look swapped: their length columns disagree with their tension columns", swap.0 + 1, swap.1 + 1);
    let (code, out, err) = calibrate_with(dir.path(), s, Some(swap), false, false, &[]);
    assert_ne!(code, Some(0), "lengths swapped: {out}");
    assert!(err.contains(&named) && err.contains("--allow-swapped"), "{err}");
    eprintln!("{}", err.lines().last().unwrap_or_default());
    let (code, out, err) = calibrate_with(dir.path(), s, Some(swap), false, false, &["--allow-swapped"]);
    assert_eq!(code, Some(0), "--allow-swapped: {err}");
    assert!(out.contains(&format!("swapped (--allow-swapped, calibrated as recorded): {named}")), "{out}");
}

#[test]
fn swapped_columns_of_4_cables_are_named() {
    let s = recorded(Scenario::aras_cam(5));
    check(&s, (0, 1));
    check_without_config(&s, (0, 1));
}

#[test]
fn swapped_columns_of_8_cables_are_named() {
    let s = recorded(Scenario::octagon(6));
    check(&s, (2, 5));
    check_without_config(&s, (2, 5));
}
