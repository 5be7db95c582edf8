//! `taut start`: the robot's controller daemon. Brings the devices up, runs the guided three-phase
//! initialisation, the excitation, the calibration and the hot-swap, then keeps operating; `taut
//! ctl` talks to it over the control socket.

use anyhow::{bail, Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Duration;
use taut_config::RobotConfig;
use taut_rt_core::calib_backend::TautCalib;
use taut_rt_core::calibrator::{CalibStatus, OutcomeKind};
use taut_rt_core::daemon::{Daemon, DaemonOptions};
use taut_rt_core::motion::{ControllerConfig, State};
use taut_rt_core::runner::LoopStatus;
use taut_rt_core::simrig::{self, SimOptions};

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
}

const DEFAULT_SIM_ROBOT: &str = r#"
[robot]
name = "aras-cam-sim"
mass_kg = 3.0
[[cable]]
anchor = [3.5, -1.75, 4.0]
[cable.loadcell]
unit_id = 1
scale = 0.001
[[cable]]
anchor = [3.5, 1.75, 4.0]
[cable.loadcell]
unit_id = 2
scale = 0.001
[[cable]]
anchor = [-3.5, 1.75, 4.0]
[cable.loadcell]
unit_id = 3
scale = 0.001
[[cable]]
anchor = [-3.5, -1.75, 4.0]
[cable.loadcell]
unit_id = 4
scale = 0.001
[loadcells]
port = "/dev/taut-loadcells"
[rt]
# The simulated plant is stepped inside the loop's device calls: no real-time priority for it.
priority = 0
lock_memory = false
[motion]
init_reel_m = -0.7
init_reel_speed_m_s = 0.25
init_settle_s = 0.3
excitation_s = 30.0
excitation_speed_m_s = 0.4
swap_ramp_s = 1.0
[safety]
# The simulator shares two cores with everything else: allow its I/O threads some lateness.
tension_max_age_s = 0.5
tracker_max_age_s = 0.5
[daemon]
max_sigma_m = 0.03
"#;

/// Runs `taut start`.
pub fn run(a: &StartArgs) -> Result<()> {
    let mut cfg = match &a.config {
        Some(p) => RobotConfig::load(p).map_err(|e| anyhow::anyhow!("{e}"))?,
        None if a.sim => RobotConfig::from_toml_str(DEFAULT_SIM_ROBOT).map_err(|e| anyhow::anyhow!("{e}"))?,
        None => bail!("give the robot configuration: taut start --config robot.toml (or --sim for the simulated robot)"),
    };
    if a.sim && a.config.is_none() && a.data_dir.is_none() {
        cfg.daemon.data_dir = "taut-sim-data".into();
    }
    if let Some(d) = &a.data_dir {
        cfg.daemon.data_dir = d.display().to_string();
    }
    if let Some(s) = &a.socket {
        cfg.daemon.socket = s.display().to_string();
    } else if a.sim && a.config.is_none() {
        cfg.daemon.socket = PathBuf::from(&cfg.daemon.data_dir).join("taut.sock").display().to_string();
    }
    if !a.sim {
        bail!(
            "hardware start-up needs the CANopen drive set, which is not wired into the daemon yet; \
             run `taut start --sim` for the simulated robot"
        );
    }
    let ccfg = ControllerConfig::from_robot(&cfg).map_err(|e| anyhow::anyhow!(e))?;
    let w = ccfg.workspace;
    let p0 = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0];
    let so = SimOptions { seed: a.seed, ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, p0);
    let sim = simrig::build(&cfg, p0, &so).map_err(|e| anyhow::anyhow!(e))?;
    let truth = sim.truth.clone();
    let daemon = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default())
        .map_err(|e| anyhow::anyhow!(e))?;
    eprintln!("taut start: control socket {}, recording {}", cfg.daemon.socket, daemon.recording.display());

    if !a.once {
        taut_rt_core::rtsys::install_stop_signals();
        let mut last = String::new();
        while !daemon.wait_until(Duration::from_millis(500), |l, _| l.snap.state == State::Stopped) {
            if taut_rt_core::rtsys::stop_requested() {
                let _ = daemon.commands.try_send(taut_rt_core::motion::Command::Stop);
            }
            let l = daemon.loop_status();
            let c = daemon.calib_status();
            let line = progress_line(&l, &c);
            if line != last {
                eprintln!("{line}");
                last = line;
            }
        }
        daemon.wait();
        return Ok(());
    }

    let m = &cfg.motion;
    let phase_s = 2.0 * m.init_reel_m.abs() / m.init_reel_speed_m_s + m.init_settle_s;
    let budget = Duration::from_secs_f64(3.0 * phase_s + m.excitation_s + 30.0 + 10.0 * m.swap_ramp_s + 300.0);
    let mut last = String::new();
    let done = daemon.wait_until(budget, |l, c| {
        let line = progress_line(l, c);
        if line != last {
            eprintln!("{line}");
            last = line;
        }
        startup_finished(l, c)
    });
    let l = daemon.loop_status();
    let c = daemon.calib_status();
    let recording = daemon.recording.clone();
    let report = daemon.shutdown();
    let c_final = c.clone();
    let initial = c_final.outcomes.iter().find(|o| o.kind == OutcomeKind::Initial && o.run == 0);
    let calibrated = c_final.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration && o.run == 0);
    let accepted = calibrated.filter(|o| o.accepted);
    let hot_swapped = accepted.is_some_and(|o| l.snap.params_version == o.version && !l.snap.swap_active);
    let err = |a: &[[f64; 3]]| -> f64 {
        a.iter()
            .zip(&truth.anchors)
            .map(|(x, t)| ((x[0] - t[0]).powi(2) + (x[1] - t[1]).powi(2) + (x[2] - t[2]).powi(2)).sqrt())
            .fold(0.0, f64::max)
    };
    let init_est = initial.and_then(|o| o.estimate.as_ref());
    let final_est = accepted.and_then(|o| o.estimate.as_ref());
    let summary = json!({
        "phases_completed": l.snap.phases_completed,
        "initial_anchors_m": init_est.map(|e| e.anchors.clone()),
        "initial_l0_m": init_est.map(|e| e.l0.clone()),
        "anchors_m": final_est.map(|e| e.anchors.clone()),
        "l0_m": final_est.map(|e| e.l0.clone()),
        "anchor_sigma_m": final_est.map(|e| e.anchor_sigma.clone()),
        "truth_anchors_m": truth.anchors,
        "truth_l0_m": truth.l0,
        "initial_anchor_error_max_m": init_est.map(|e| err(&e.anchors)),
        "initial_held_anchor_error_max_m": init_est.map(|e| err(&e.anchors[..3.min(e.anchors.len())])),
        "anchor_error_max_m": final_est.map(|e| err(&e.anchors)),
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
        "loop": {
            "rate_hz": cfg.rt.rate_hz,
            "cycles": report.as_ref().map(|r| r.cycles),
            "overruns": report.as_ref().map(|r| r.overruns),
            "max_late_us": report.as_ref().map(|r| r.max_late_ns as f64 * 1e-3),
            "max_compute_us": report.as_ref().map(|r| r.max_compute_ns as f64 * 1e-3),
            "realtime": report.as_ref().map(|r| r.setup.realtime),
        },
    });
    if let Some(p) = &a.json {
        std::fs::write(p, serde_json::to_string_pretty(&summary)? + "\n").with_context(|| format!("writing {}", p.display()))?;
    }
    println!("phases completed   {}", l.snap.phases_completed);
    if let Some(e) = init_est {
        let held = err(&e.anchors[..3.min(e.anchors.len())]);
        println!("initial estimate   max anchor error {:.1} mm on the held cables, {:.1} mm on all ({})", held * 1e3, err(&e.anchors) * 1e3, e.note);
    }
    if let Some(e) = final_est {
        println!("calibrated         max anchor error {:.2} mm", err(&e.anchors) * 1e3);
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

/// True when the start-up is over, well or badly.
fn startup_finished(l: &LoopStatus, c: &CalibStatus) -> bool {
    if l.snap.fault.is_some() || l.snap.state == State::Stopped {
        return true;
    }
    if c.outcomes.iter().any(|o| o.run == 0 && !o.accepted) {
        return true;
    }
    match c.outcomes.iter().find(|o| o.run == 0 && o.kind == OutcomeKind::Calibration && o.accepted) {
        Some(o) => l.snap.params_version == o.version && !l.snap.swap_active,
        None => false,
    }
}

fn progress_line(l: &LoopStatus, c: &CalibStatus) -> String {
    let phase = if l.snap.phase >= 0 { format!(" {}", l.snap.phase) } else { String::new() };
    let fault = l.snap.fault.map_or(String::new(), |(cause, r)| format!(" [{}: {}]", r.name(), cause));
    format!("state {}{phase}; calibrator {}; params v{}{fault}", l.snap.state.name(), c.stage, l.snap.params_version)
}
