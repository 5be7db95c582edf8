//! `taut start`: the robot's controller daemon. Brings the devices up, runs the guided three-phase
//! initialisation, the excitation, the calibration and the hot-swap, then keeps operating; `taut
//! ctl` talks to it over the control socket.

use anyhow::{bail, Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Duration;
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::{CalibStatus, OutcomeKind};
use taut_config::RobotConfig;
use taut_driver::tracker::TrackerStatsHandle;
use taut_io::robot_io::{BringUpError, Peripherals, RobotDevices};
use taut_io::runner::LoopStatus;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use taut_plugin::{DeviceMode, DeviceSource};
use taut_rt::io::Devices;
use taut_rt::motion::State;
#[cfg(feature = "sim")]
use taut_simrig::{self as simrig, SimOptions};

/// The simulated site's true anchors and encoder offsets, for the start-up's summary.
type SiteTruth = (Vec<[f64; 3]>, Vec<f64>);

/// Arguments of `taut start`.
#[derive(clap::Args)]
pub struct StartArgs {
    /// Robot configuration (TOML). With --sim, defaults to the ARAS-CAM-like example robot.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Run against the simulated robot instead of hardware.
    #[arg(long)]
    sim: bool,
    /// Exit after the start-up calibration with a summary.
    #[arg(long)]
    once: bool,
    /// Write the summary as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Seed of the simulated site (--sim).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Override `daemon.data_dir` (recordings, parameter history).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Override `daemon.socket`.
    #[arg(long)]
    socket: Option<PathBuf>,
    /// With --sim: put the virtual drives and the CANopen master on this SocketCAN interface
    /// (e.g. `vcan0`) instead of an in-process virtual bus.
    #[arg(long, requires = "sim")]
    can: Option<String>,
    /// A parameter file (taut-params v1 to v5, e.g. from `taut diagnose --out`): the length
    /// effects it carries are modelled and refitted by every calibration, starting from its
    /// values; its load-cell gains and friction correct the loop's tensions, carried unchanged.
    #[arg(long)]
    params: Option<PathBuf>,
    /// With --sim: conceal an effect in the simulated site, NAME=VALUE (as `taut simulate
    /// --effect`: elasticity=20000, scale=1.003, pulley=0.05, sag, time-offset, backlash,
    /// spool-buildup, compliance, loadcell-gain, friction; the last two change the cells' readings
    /// only).
    #[arg(long = "sim-effect", value_name = "NAME=VALUE", requires = "sim")]
    sim_effects: Vec<String>,
    /// With --sim: the simulated robot has no tracker; the start-up runs dwell poses and
    /// calibrates from the encoders and load cells (`motion.startup = "dwell"`).
    #[arg(long = "no-tracker", requires = "sim")]
    no_tracker: bool,
    /// With --sim --once: run the start-up in simulated time, the whole robot stack in lockstep
    /// on one simulated clock, as fast as the CPU allows (the same seed gives the same run, bit
    /// for bit). The JSON gets a `sim_time` object with the speed-up over real time.
    #[arg(long = "sim-time", requires = "sim", requires = "once", conflicts_with = "can")]
    sim_time: bool,
    /// With --sim-time: the simulated plant has dynamics (the platform swings on elastic,
    /// damped 1 MN cables) instead of moving from one static equilibrium to the next; the
    /// initialisation phases reel at most 0.5 m.
    #[arg(long = "dynamic", requires = "sim_time")]
    dynamic: bool,
    /// With --sim-time: faults drawn from the seed (lost and late CAN frames, tracker dropouts,
    /// a pause of the load cells).
    #[arg(long = "sim-faults", requires = "sim_time")]
    sim_faults: bool,
}

/// The simulated robot `taut start --sim` runs without --config (also loaded by the tests).
const DEFAULT_SIM_ROBOT: &str = include_str!("../../config/examples/aras-cam-sim.toml");

/// The longest reel of the initialisation phases on the dynamic plant, m.
const DYNAMIC_REEL_M: f64 = 0.5;

/// Runs `taut start`.
pub fn run(a: &StartArgs, verbosity: i8) -> Result<()> {
    let mut cfg = match &a.config {
        Some(p) => RobotConfig::load(p).map_err(|e| anyhow::anyhow!("{e}"))?,
        None if a.sim => RobotConfig::from_toml_str(DEFAULT_SIM_ROBOT).map_err(|e| anyhow::anyhow!("{e}"))?,
        None => bail!("give the robot configuration: taut start --config robot.toml (or --sim for the simulated robot)"),
    };
    let text = match (&a.config, a.sim) {
        (Some(p), true) => Some(std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?),
        _ => None,
    };
    for note in daemon_paths(&mut cfg, a.sim, text.as_deref(), a.data_dir.as_deref(), a.socket.as_deref()) {
        eprintln!("taut start: {note}");
    }
    if let Some(note) = startup_mode(&mut cfg, a.sim, a.no_tracker) {
        eprintln!("taut start: {note}");
    }
    if a.dynamic && cfg.motion.init_reel_m.abs() > DYNAMIC_REEL_M {
        // A swinging platform reeled 0.85 m (the example's) climbs to 3.65 m under 4 m anchors
        // and its held cables go slack.
        eprintln!(
            "taut start: --dynamic: the phases reel {DYNAMIC_REEL_M} m instead of motion.init_reel_m = {} m (a swinging platform reeled further nears the anchors and slackens the held cables)",
            cfg.motion.init_reel_m
        );
        cfg.motion.init_reel_m = cfg.motion.init_reel_m.signum() * DYNAMIC_REEL_M;
    }
    let (devices, truth, tracker): (DeviceMode, Option<SiteTruth>, _) = if a.sim {
        match simulated_devices(a, &cfg, verbosity)? {
            Some((devices, truth, stats)) => (devices, Some(truth), Some(stats)),
            // --sim-time ran the whole start-up in simulated time.
            None => return Ok(()),
        }
    } else {
        let (d, t) = hardware_devices(&cfg)?;
        (d, None, t)
    };
    let backend = backend(a, &cfg)?;
    // The log for people (states and phases with their expected durations, calibration
    // outcomes, goals, loop health): off with -q.
    let log: taut_plugin::daemon::WarnFn =
        if verbosity < 0 { std::sync::Arc::new(|_: &str| {}) } else { std::sync::Arc::new(|l: &str| eprintln!("taut: {l}")) };
    let daemon = Daemon::start_with(&cfg, devices, Box::new(backend), DaemonOptions { tracker, log, ..DaemonOptions::default() })
        .map_err(|e| anyhow::anyhow!(e))?;
    eprintln!("taut start: control socket {}, recording {}", cfg.daemon.socket, daemon.recording.display());
    if let Some(plan) = &daemon.calib_status().excitation {
        eprintln!("taut start: {}", plan.summary());
    }
    if let Some(m) = daemon.mcap.as_ref().filter(|m| **m != daemon.recording) {
        eprintln!("taut start: MCAP recording {} (open in Foxglove)", m.display());
    }
    if let Some(addr) = daemon.telemetry {
        eprintln!("taut start: telemetry ws://{addr} (Foxglove: Open connection, Foxglove WebSocket)");
    }

    if !a.once {
        taut_io::rtsys::install_stop_signals();
        let mut last = String::new();
        while !daemon.wait_until(Duration::from_millis(500), |l, _| l.snap.state == State::Stopped) {
            if taut_io::rtsys::stop_requested() {
                let _ = daemon.commands.try_send(taut_rt::motion::Command::Stop);
            }
            let l = daemon.loop_status();
            let c = daemon.calib_status();
            let line = progress_line(&l, &c);
            if line != last && verbosity > 0 {
                eprintln!("{line}");
            }
            last = line;
        }
        daemon.wait();
        return Ok(());
    }

    let budget = Duration::from_secs_f64(startup_motion_s(&cfg) + 300.0);
    let mut last = String::new();
    let done = daemon.wait_until(budget, |l, c| {
        let line = progress_line(l, c);
        if line != last && verbosity > 0 {
            eprintln!("{line}");
        }
        last = line;
        taut_operator::control::startup_finished(l, c)
    });
    let l = daemon.loop_status();
    let c = daemon.calib_status();
    let recording = daemon.recording.clone();
    let report = daemon.shutdown();
    let loop_json = json!({
        "rate_hz": cfg.rt.rate_hz,
        "cycles": report.as_ref().map(|r| r.cycles),
        "overruns": report.as_ref().map(|r| r.overruns),
        "max_late_us": report.as_ref().map(|r| r.max_late_ns as f64 * 1e-3),
        "max_compute_us": report.as_ref().map(|r| r.max_compute_ns as f64 * 1e-3),
        "realtime": report.as_ref().map(|r| r.setup.realtime),
    });
    finish(a, &cfg, &l, &c, truth.as_ref(), &recording, done, loop_json, None)
}

/// How long the start-up's motions take, s (three phases, the excitation, the swap ramps), with
/// 30 s for the calibrations: the budget of `--once` is this plus a margin.
fn startup_motion_s(cfg: &RobotConfig) -> f64 {
    let m = &cfg.motion;
    let phase_s = 2.0 * taut_rt::motion::trapezoid_s(m.init_reel_m.abs(), m.init_reel_speed_m_s, m.init_reel_accel_m_s2) + m.init_settle_s;
    3.0 * phase_s + m.excitation_s + 30.0 + 10.0 * m.swap_ramp_s
}

/// The calibration backend of `taut start`: taut-calib from the configuration, with the
/// effects of `--params` if given.
fn backend(a: &StartArgs, cfg: &RobotConfig) -> Result<TautCalib> {
    let mut backend = TautCalib::from_config(cfg);
    if let Some(p) = &a.params {
        let file = taut_config::params::ParamsFile::load(p).map_err(|e| anyhow::anyhow!("{e}"))?;
        anyhow::ensure!(
            file.anchors_m.len() == cfg.cables.len(),
            "{}: {} cables, but the robot configuration has {}; give the parameter file of this robot",
            p.display(),
            file.anchors_m.len(),
            cfg.cables.len()
        );
        backend = backend.with_params(&file);
    }
    if !backend.effects().is_empty() {
        eprintln!("taut start: modelling {}", backend.effects().join(", "));
    }
    Ok(backend)
}

/// `taut start --sim`: the simulated robot's devices and its truth, or `None` when `--sim-time`
/// ran the start-up in simulated time to its summary.
#[cfg(feature = "sim")]
fn simulated_devices(a: &StartArgs, cfg: &RobotConfig, verbosity: i8) -> Result<Option<(DeviceMode, SiteTruth, TrackerStatsHandle)>> {
    use taut_io::FromRobot;
    use taut_rt::motion::ControllerConfig;
    let ccfg = ControllerConfig::from_robot(cfg).map_err(|e| anyhow::anyhow!(e))?;
    let w = ccfg.workspace;
    let p0 = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0];
    let mut so = SimOptions { seed: a.seed, can: a.can.clone(), tracker: !taut_calibrator::notracker::is_dwell(cfg), ..Default::default() };
    crate::simulate::apply_effects(&a.sim_effects, cfg.cables.len(), &mut so.physics, "--sim-effect")?;
    if a.dynamic {
        so.physics.dynamics = Some(taut_sim::Dynamics::default());
    }
    let p0 = simrig::rest_position(cfg, &so, p0);
    if a.sim_time {
        run_sim_time(a, cfg, p0, &so, backend(a, cfg)?, verbosity)?;
        return Ok(None);
    }
    let sim = simrig::build(cfg, p0, &so)?;
    Ok(Some((DeviceMode::ready(sim.devices), (sim.truth.anchors, sim.truth.l0), sim.tracker_stats)))
}

/// A robot's build has no simulated robot.
#[cfg(not(feature = "sim"))]
fn simulated_devices(_: &StartArgs, _: &RobotConfig, _: i8) -> Result<Option<(DeviceMode, SiteTruth, TrackerStatsHandle)>> {
    bail!("--sim: this taut was built without the simulator (taut-cli's `sim` feature, on by default)")
}

/// `taut start --sim --once --sim-time`: the start-up in simulated time.
#[cfg(feature = "sim")]
fn run_sim_time(a: &StartArgs, cfg: &RobotConfig, p0: [f64; 3], so: &SimOptions, backend: TautCalib, verbosity: i8) -> Result<()> {
    let budget_s = startup_motion_s(cfg) + 600.0;
    let faults = if a.sim_faults { simrig::LockstepFaults::drawn(a.seed) } else { simrig::LockstepFaults::default() };
    // A run of its own per seed, with an empty parameter history (the calibrator numbers its
    // parameter sets after the ones on disk): the same seed gives the same summary.
    let dir = std::path::Path::new(&cfg.daemon.data_dir).join("sim-time").join(format!("seed-{}", a.seed));
    match std::fs::remove_dir_all(dir.join("params")) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("clearing the simulated run's parameter history {}", dir.join("params").display()))
        }
        _ => {}
    }
    let mut cfg = cfg.clone();
    cfg.daemon.data_dir = dir.display().to_string();
    let cfg = &cfg;
    let recording = dir.join("recordings").join("start.csv");
    eprintln!("taut start: simulated time (seed {}); recording {}", a.seed, recording.display());
    // `simrig::run_startup`, with the control socket's bookkeeping ticked between cycles as the
    // control thread does: the same log lines for people, in simulated time.
    let opts = simrig::RunOptions { faults: faults.clone(), recording: taut_plugin::RecordingPath::At(recording.clone()), budget_s };
    let mut host = simrig::Lockstep::start(cfg, p0, so, opts, Box::new(backend)).map_err(|e| anyhow::anyhow!("{e}"))?;
    if verbosity >= 0 {
        host.handle().operator().set_log(std::sync::Arc::new(|l: &str| eprintln!("taut: {l}")));
    }
    let links = host.handle().control_links(None);
    let mut over = false;
    host.run_until(budget_s, |l, c| {
        links.tick();
        over = taut_operator::control::startup_finished(l, c);
        over
    });
    links.tick();
    let run = host.finish(over);
    let lc = run.loadcells;
    let loop_json = json!({
        "rate_hz": cfg.rt.rate_hz,
        "cycles": run.cycles,
        "overruns": 0,
        "realtime": false,
    });
    let sim_json = json!({
        "simulated_s": run.sim_s,
        "wall_s": run.wall_s,
        "speedup": run.sim_s / run.wall_s.max(1e-9),
        "seed": a.seed,
        "dynamic_plant": a.dynamic,
        "faults": {
            "frame_loss": faults.frame_loss,
            "frame_late": faults.frame_late,
            "tracker_dropout": faults.tracker_dropout,
            "loadcell_silence_s": faults.loadcell_silence,
        },
        "can": {"frames": run.bus.frames, "lost": run.bus.lost, "late": run.bus.late, "load": run.bus.busy_s / run.sim_s.max(1e-9)},
        "loadcells": {"ok": lc.ok, "timeouts": lc.timeouts, "retries": lc.retries, "failed": lc.failed},
        "plant_failed_steps": run.plant_failed_steps,
        "wall_clock_fields": ["sim_time.wall_s", "sim_time.speedup"],
    });
    eprintln!(
        "taut start: {:.1} s simulated in {:.2} s of wall time ({:.0}x real time)",
        run.sim_s,
        run.wall_s,
        run.sim_s / run.wall_s.max(1e-9)
    );
    let truth = Some((run.truth.anchors.clone(), run.truth.l0.clone()));
    finish(a, cfg, &run.loop_status, &run.calib_status, truth.as_ref(), &recording, run.finished, loop_json, Some(sim_json))
}

/// The summary of a start-up (JSON with --json, and the lines on stdout); fails when the
/// start-up did not end with a hot-swap.
#[allow(clippy::too_many_arguments)]
fn finish(
    a: &StartArgs,
    cfg: &RobotConfig,
    l: &LoopStatus,
    c: &CalibStatus,
    truth: Option<&SiteTruth>,
    recording: &std::path::Path,
    done: bool,
    loop_json: serde_json::Value,
    sim_time: Option<serde_json::Value>,
) -> Result<()> {
    let c_final = c.clone();
    let initial = c_final.outcomes.iter().find(|o| o.kind == OutcomeKind::Initial && o.run == 0);
    let calibrated = c_final.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration && o.run == 0);
    let accepted = calibrated.filter(|o| o.accepted);
    let hot_swapped = accepted.is_some_and(|o| l.snap.params_version == o.version && !l.snap.swap_active);
    let truth_anchors = truth.as_ref().map_or(&[][..], |t| &t.0[..]);
    let err = |a: &[[f64; 3]]| -> f64 {
        a.iter()
            .zip(truth_anchors)
            .map(|(x, t)| ((x[0] - t[0]).powi(2) + (x[1] - t[1]).powi(2) + (x[2] - t[2]).powi(2)).sqrt())
            .fold(0.0, f64::max)
    };
    let init_est = initial.and_then(|o| o.estimate.as_ref());
    let aligned = |a: &[[f64; 3]]| taut_calib::selfcal::align::worst_aligned_error(a, truth_anchors);
    let final_est = accepted.and_then(|o| o.estimate.as_ref());
    let summary = json!({
        "phases_completed": l.snap.phases_completed,
        "initial_anchors_m": init_est.map(|e| e.geometry.anchors.clone()),
        "initial_l0_m": init_est.map(|e| e.geometry.l0.clone()),
        "anchors_m": final_est.map(|e| e.geometry.anchors.clone()),
        "l0_m": final_est.map(|e| e.geometry.l0.clone()),
        "anchor_sigma_m": final_est.map(|e| e.sigma.anchors.clone()),
        "excitation": taut_operator::control::excitation_json(c),
        "truth_anchors_m": truth.as_ref().map(|t| &t.0),
        "truth_l0_m": truth.as_ref().map(|t| &t.1),
        "initial_anchor_error_max_m": init_est.filter(|_| truth.is_some()).map(|e| err(&e.geometry.anchors)),
        "initial_held_anchor_error_max_m": init_est.filter(|_| truth.is_some()).map(|e| err(&e.geometry.anchors[..3.min(e.geometry.anchors.len())])),
        "anchor_error_max_m": final_est.filter(|_| truth.is_some()).map(|e| err(&e.geometry.anchors)),
        "anchor_error_aligned_max_m": final_est.filter(|_| truth.is_some()).map(|e| aligned(&e.geometry.anchors)),
        "without_tracker": taut_calibrator::notracker::is_dwell(cfg),
        "calibration_note": final_est.map(|e| e.note.clone()),
        "model_consistent": final_est.and_then(|e| e.model_consistent),
        "samples_recorded": c.samples_recorded,
        "samples_dropped": l.dropped,
        "hot_swapped": hot_swapped,
        "max_swap_step_m": l.snap.max_swap_step_m,
        "recording": recording.display().to_string(),
        "params_version": l.snap.params_version,
        "heldout_rms_new_m": accepted.map(|o| o.heldout_rms_new_m),
        "heldout_rms_old_m": accepted.map(|o| o.heldout_rms_old_m),
        "rejected": c.outcomes.iter().filter(|o| !o.accepted).map(|o| o.reason.clone()).collect::<Vec<_>>(),
        "fault": l.snap.fault.map(|(cause, r)| json!({"cause": cause.name(), "reaction": r.name(), "message": cause.to_string()})),
        "finished": done,
        "loop": loop_json,
    });
    let mut summary = summary;
    if let Some(st) = sim_time {
        summary["sim_time"] = st;
    }
    if let Some(p) = &a.json {
        taut_config::write_atomic(p, (serde_json::to_string_pretty(&summary)? + "\n").as_bytes())
            .with_context(|| format!("writing {}", p.display()))?;
    }
    println!("phases completed   {}", l.snap.phases_completed);
    if let Some(e) = init_est.filter(|_| truth.is_some()) {
        let held = err(&e.geometry.anchors[..3.min(e.geometry.anchors.len())]);
        println!(
            "initial estimate   max anchor error {:.1} mm on the held cables, {:.1} mm on all ({})",
            held * 1e3,
            err(&e.geometry.anchors) * 1e3,
            e.note
        );
    }
    if let Some(e) = final_est {
        if truth.is_some() {
            println!("calibrated         max anchor error {:.2} mm", err(&e.geometry.anchors) * 1e3);
            if taut_calibrator::notracker::is_dwell(cfg) {
                println!(
                    "                   without a tracker: {:.2} mm after the best translation and rotation about the vertical ({})",
                    aligned(&e.geometry.anchors) * 1e3,
                    e.note
                );
            }
        }
        if let Some(plan) = &c.excitation {
            println!("uncertainty        {}", taut_calibrator::excite::predicted_vs_achieved(plan, &e.sigma.anchors));
        }
        if truth.is_none() {
            for (j, a) in e.geometry.anchors.iter().enumerate() {
                println!("calibrated         anchor {} [{:.4}, {:.4}, {:.4}] m, l0 {:.4} m", j + 1, a[0], a[1], a[2], e.geometry.l0[j]);
            }
        }
    }
    for o in c.outcomes.iter().filter(|o| !o.accepted) {
        println!("rejected           {}", o.reason);
    }
    if let Some((cause, r)) = l.snap.fault {
        println!("safety reaction    {} ({})", r.name(), cause);
    }
    println!("hot-swapped        {hot_swapped} (largest per-cycle step {:.3} mm)", l.snap.max_swap_step_m * 1e3);
    println!("samples            {} recorded, {} dropped -> {}", c.samples_recorded, l.dropped, recording.display());
    if !hot_swapped {
        bail!("the start-up calibration did not finish with a hot-swap (see above)");
    }
    Ok(())
}

/// The start-up routine: `motion.startup` as configured; with `--no-tracker` (simulated robot)
/// or, on hardware, without `[tracker]` and without the key, the dwell start-up. With the
/// dwell start-up the configuration's `[tracker]` is not used. Returns a note saying so.
fn startup_mode(cfg: &mut RobotConfig, sim: bool, no_tracker: bool) -> Option<String> {
    use taut_config::runtime::Startup;
    if no_tracker {
        cfg.motion.startup = Some(Startup::Dwell);
        cfg.tracker = None;
        return Some("no tracker: the start-up runs dwell poses and calibrates from the encoders and load cells".into());
    }
    if !sim && cfg.tracker.is_none() && cfg.motion.startup.is_none() {
        cfg.motion.startup = Some(Startup::Dwell);
        return Some("no [tracker] in the configuration: the start-up runs dwell poses (motion.startup = \"dwell\")".into());
    }
    if cfg.motion.startup == Some(Startup::Dwell) {
        cfg.tracker = None;
        return Some("motion.startup = \"dwell\": the start-up runs dwell poses without the tracker".into());
    }
    None
}

/// Where the daemon's files go. The options win; otherwise the configuration's `[daemon]` keys.
/// With --sim, a key the file does not set (or no file) does not fall back to the hardware
/// defaults `/run/taut` and `/var/lib/taut` (a simulation has no business there, and they need
/// root): the data go to `taut-sim-data` in the current directory and the socket into it.
/// Returns notes saying so.
fn daemon_paths(
    cfg: &mut RobotConfig,
    sim: bool,
    config_text: Option<&str>,
    data_dir: Option<&std::path::Path>,
    socket: Option<&std::path::Path>,
) -> Vec<String> {
    let set_in_file = |key: &str| {
        config_text
            .and_then(|t| t.parse::<toml::Table>().ok())
            .is_some_and(|t| t.get("daemon").and_then(|d| d.as_table()).is_some_and(|d| d.contains_key(key)))
    };
    let mut notes = Vec::new();
    match data_dir {
        Some(d) => cfg.daemon.data_dir = d.display().to_string(),
        None if sim && !set_in_file("data_dir") => {
            cfg.daemon.data_dir = "taut-sim-data".into();
            notes.push(
                "simulated robot: recordings and parameters go to ./taut-sim-data (set daemon.data_dir or give --data-dir for elsewhere)"
                    .into(),
            );
        }
        None => {}
    }
    match socket {
        Some(s) => cfg.daemon.socket = s.display().to_string(),
        None if sim && !set_in_file("socket") => {
            cfg.daemon.socket = PathBuf::from(&cfg.daemon.data_dir).join("taut.sock").display().to_string();
            notes.push(format!("simulated robot: control socket {} (set daemon.socket or give --socket for elsewhere)", cfg.daemon.socket));
        }
        None => {}
    }
    notes
}

/// The robot's own devices: the CiA 402 drives on the `[can]` interface through SocketCAN, the
/// load cells on `[loadcells]`, the tracker on `[tracker]`. The load-cell and tracker ports are
/// opened here (the control socket shows the tracker's counters); the CAN interface is opened
/// and the drives are configured by the plugin's activation ([`Hardware`]), after the control
/// socket is bound and the recording created.
fn hardware_devices(cfg: &RobotConfig) -> Result<(DeviceMode, Option<TrackerStatsHandle>)> {
    let Some(can) = &cfg.can else {
        bail!("the configuration has no [can] table: add one with the drives' interface, e.g. interface = \"can0\"");
    };
    #[cfg(target_os = "linux")]
    {
        let _ = can;
        let peripherals = Peripherals::from_config(cfg).map_err(|e| anyhow::anyhow!("{e}"))?;
        let tracker = peripherals.pose.as_ref().map(|p| p.stats_handle());
        Ok((DeviceMode::Owned(Box::new(Hardware { cfg: cfg.clone(), peripherals: Some(peripherals) })), tracker))
    }
    #[cfg(not(target_os = "linux"))]
    {
        bail!("CAN interface {}: SocketCAN needs Linux", can.interface)
    }
}

/// The drives' bring-up, run by the plugin's `activate`.
#[cfg(target_os = "linux")]
struct Hardware {
    cfg: RobotConfig,
    peripherals: Option<Peripherals>,
}

#[cfg(target_os = "linux")]
impl DeviceSource for Hardware {
    fn bring_up(&mut self) -> std::result::Result<Box<dyn Devices>, BringUpError> {
        use taut_driver::transport::socketcan::SocketCanTransport;
        let can = self.cfg.can.as_ref().ok_or(BringUpError::NoCan)?;
        let bus = SocketCanTransport::open(&can.interface).map_err(|source| BringUpError::CanInterface {
            interface: can.interface.clone(),
            bitrate: can.bitrate,
            source,
        })?;
        let peripherals = self.peripherals.take().ok_or(BringUpError::DevicesTaken)?;
        eprintln!("taut start: bringing up the drives on {}", can.interface);
        Ok(Box::new(RobotDevices::bring_up(&self.cfg, bus, peripherals)?))
    }
}

fn progress_line(l: &LoopStatus, c: &CalibStatus) -> String {
    let phase = if l.snap.phase >= 0 { format!(" {}", l.snap.phase) } else { String::new() };
    let fault = l.snap.fault.map_or(String::new(), |(cause, r)| format!(" [{}: {}]", r.name(), cause));
    // Bus trouble and recoveries are reported as they happen (the reaction is in `fault`).
    let b = &l.snap.inputs.bus;
    let bus = if b.state != taut_rt::io::BusState::Active || b.recoveries > 0 {
        format!("; {} {} ({} recoveries)", b.iface, b.state.name(), b.recoveries)
    } else {
        String::new()
    };
    format!("state {}{phase}; calibrator {}; params v{}{fault}{bus}", l.snap.state.name(), c.stage, l.snap.params_version)
}

#[cfg(test)]
mod daemon_path_tests {
    use super::*;

    fn cfg() -> RobotConfig {
        RobotConfig::from_toml_str(DEFAULT_SIM_ROBOT).unwrap()
    }

    #[test]
    fn sim_without_daemon_keys_stays_out_of_run_and_var_lib() {
        let text = "[robot]\nname = \"x\"\n";
        let mut c = cfg();
        let notes = daemon_paths(&mut c, true, Some(text), None, None);
        assert_eq!((c.daemon.data_dir.as_str(), c.daemon.socket.as_str()), ("taut-sim-data", "taut-sim-data/taut.sock"));
        assert_eq!(notes.len(), 2, "{notes:?}");
        // The file's own keys are kept, and so are the options.
        let mut c = cfg();
        let text = "[daemon]\ndata_dir = \"/srv/sim\"\n";
        c.daemon.data_dir = "/srv/sim".into();
        daemon_paths(&mut c, true, Some(text), None, None);
        assert_eq!((c.daemon.data_dir.as_str(), c.daemon.socket.as_str()), ("/srv/sim", "/srv/sim/taut.sock"));
        let mut c = cfg();
        daemon_paths(&mut c, true, None, Some(std::path::Path::new("d")), Some(std::path::Path::new("s.sock")));
        assert_eq!((c.daemon.data_dir.as_str(), c.daemon.socket.as_str()), ("d", "s.sock"));
        // Hardware: the configuration (or its defaults) as written.
        let mut c = cfg();
        let before = c.daemon.clone();
        assert!(daemon_paths(&mut c, false, None, None, None).is_empty());
        assert_eq!(c.daemon, before);
    }
}
