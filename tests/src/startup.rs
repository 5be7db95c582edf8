//! The simulated robot's start-up as the end-to-end tests run it: the robot `taut start --sim`
//! runs (config/examples/aras-cam-sim.toml) with a test-length start-up (faster initialisation
//! phases, a shorter designed excitation), built at rest in the middle of its workspace, and the
//! conditions that end a start-up.

use std::path::Path;
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::{CalibStatus, OutcomeKind};
use taut_config::RobotConfig;
use taut_io::runner::LoopStatus;
use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;
use taut_simrig::{self as simrig, RunOptions, SimOptions, SimRobot, StartupRun};

/// Excitation of the test start-ups, s (the example's is 30 s). The real-time tests check flow
/// (the accuracy acceptances run in simulated time, `--test simtime`): 15 s of designed tour
/// calibrate seeds 3, 5, 7 and 8 to 0.64-1.36 mm (`taut start --sim --once --sim-time` with this
/// excitation and [`INIT_REEL_SPEED_M_S`]); 10 s do not (the sigma gates refuse them).
pub const EXCITATION_S: f64 = 15.0;

/// `loadcells.response_timeout_s` of the wall-clock tests whose load cells answer over a
/// pseudo-terminal, s (the example's is 0.05 s). The terminal's bytes are passed on by kernel
/// work at the normal scheduler's priority: under two busy loops beside builds and other tests
/// (load 10-13) answers came 225-425 ms late, every try of whole polling rounds timed out at
/// 50 ms and the late answers were thrown away as garbage, until a cable's reading was 2 s old
/// (TensionStale in both `plugin_alloc` start-ups; with 0.3 s, 2 of 2 passed). The simulated
/// robot's start-ups use a socket pair instead (`taut_simrig::LoadCellLine`).
pub const LOADCELL_RESPONSE_TIMEOUT_S: f64 = 0.3;

/// `rt.priority` of the test start-ups: the deployed robot's (config's default).
pub const REALTIME_PRIORITY: i32 = 80;

/// Reel speed of the test start-ups' initialisation phases, m/s (the example's is 0.25).
pub const INIT_REEL_SPEED_M_S: f64 = 0.5;

/// The simulated robot of `taut start --sim` (`config/examples/aras-cam-sim.toml`) as written,
/// with its socket and data directory in `dir`.
pub fn example_robot(dir: &Path) -> RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = RobotConfig::load(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

/// The simulated robot of `taut start --sim` with its socket and data directory in `dir` and an
/// excitation of [`EXCITATION_S`].
pub fn sim_robot(dir: &Path) -> RobotConfig {
    let mut cfg = example_robot(dir);
    cfg.motion.excitation_s = EXCITATION_S;
    cfg.motion.init_reel_speed_m_s = INIT_REEL_SPEED_M_S;
    // As on a robot (deploy/taut.service): the loop under SCHED_FIFO, its device threads just
    // below, so that other work on the machine cannot starve them (as root; otherwise each
    // refusal is a warning and the normal scheduler runs them).
    cfg.rt.priority = REALTIME_PRIORITY;
    cfg
}

/// The simulated robot for `cfg` with seed `seed`, the platform at rest below the middle of the
/// workspace.
pub fn build_at_rest(cfg: &RobotConfig, seed: u64) -> SimRobot {
    let so = SimOptions { seed, ..Default::default() };
    simrig::build(cfg, rest_p0(cfg, &so), &so).unwrap_or_else(|e| panic!("building the simulated robot: {e}"))
}

/// Where the simulated platform of `cfg` rests before the start-up: the simulator's rest position
/// below the middle of the workspace.
pub fn rest_p0(cfg: &RobotConfig, so: &SimOptions) -> [f64; 3] {
    let w = ControllerConfig::from_robot(cfg).expect("the configuration is valid").workspace;
    let centre = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0];
    simrig::rest_position(cfg, so, centre)
}

/// The start-up of `cfg` on the simulated robot of `so` in simulated time (the robot stack in
/// lockstep, `taut_simrig::run_startup`), from [`rest_p0`], calibrating with taut-calib.
pub fn in_sim_time(
    cfg: &RobotConfig,
    so: &SimOptions,
    run: RunOptions,
    on_check: impl FnMut(&LoopStatus, &CalibStatus) -> bool,
) -> StartupRun {
    simrig::run_startup(cfg, rest_p0(cfg, so), so, run, Box::new(TautCalib::from_config(cfg)), on_check)
        .unwrap_or_else(|e| panic!("seed {}: {e}", so.seed))
}

/// A start-up of `cfg` in simulated time ([`in_sim_time`]) that must end with its calibration
/// accepted and no fault latched; the run and the calibration's outcome. With `TAUT_E2E_KEEP`
/// its recording is kept as `taut-{tag}-{seed}.csv` in the temporary directory.
pub fn accepted_in_sim_time(cfg: &RobotConfig, so: &SimOptions, tag: &str) -> (StartupRun, taut_calibrator::vocab::CalibrationOutcome) {
    let seed = so.seed;
    let run = in_sim_time(cfg, so, RunOptions { recording: taut_plugin::RecordingPath::Default, ..Default::default() }, |_, _| false);
    let (l, c) = (&run.loop_status, &run.calib_status);
    if std::env::var_os("TAUT_E2E_KEEP").is_some() {
        if let Some(r) = &run.recording {
            let _ = std::fs::copy(r, std::env::temp_dir().join(format!("taut-{tag}-{seed}.csv")));
        }
    }
    assert!(run.finished, "seed {seed}: start-up did not finish: state {:?}, stage {}", l.snap.state, c.stage);
    assert!(l.snap.fault.is_none(), "seed {seed}: fault {:?}", l.snap.fault);
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).cloned().unwrap_or_else(|| {
        panic!("seed {seed}: no calibration outcome: state {:?}, stage {}, outcomes {:?}", l.snap.state, c.stage, c.outcomes)
    });
    assert!(cal.accepted, "seed {seed}: calibration rejected: {}", cal.reason);
    (run, cal)
}

/// The start-up has hot-swapped to accepted calibrated parameters and the swap's ramp is over.
pub fn hot_swapped(l: &LoopStatus, c: &CalibStatus) -> bool {
    c.outcomes.iter().any(|o| o.kind == OutcomeKind::Calibration && o.accepted && l.snap.params_version == o.version && !l.snap.swap_active)
}

/// The start-up is over, one way or another: hot-swapped, a fault latched, or a calibration
/// rejected. Wait for this, then assert which.
pub fn start_up_over(l: &LoopStatus, c: &CalibStatus) -> bool {
    l.snap.fault.is_some() || c.outcomes.iter().any(|o| !o.accepted) || hot_swapped(l, c)
}
