//! The start-up flow of `taut start --sim` over real SocketCAN: the CANopen master of the loop
//! and the simulated robot's virtual CiA 402 drives each on their own `vcan0` socket, the load
//! cells on a pseudo-terminal, the tracker on loopback UDP. From cold: bring-up (SDO
//! configuration, NMT start), enable, the three phases, the initial estimate, the excitation,
//! the calibration and its outcome.
//!
//! Runs for real inside the QEMU VM of `tests/vcan/run` (one emulated CPU under TCG, so rates
//! are low, time limits generous, and accuracy is not checked here: `e2e_start` does that on the
//! virtual bus). Elsewhere it skips unless `TAUT_VCAN_REQUIRED=1`.

use std::time::Duration;
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::OutcomeKind;
use taut_io::FromRobot;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use taut_rt::motion::{ControllerConfig, State};
use taut_simrig::{self as simrig, SimOptions};
use taut_tests::vcan;

/// The simulated robot slowed for an emulated CPU (shared with `vcan_plugin_owned`).
pub(crate) fn robot(dir: &std::path::Path) -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    // An emulated CPU: a slow loop, short motions, and patience with every device.
    cfg.rt.rate_hz = 100.0;
    cfg.motion.init_reel_speed_m_s = 0.5;
    cfg.motion.excitation_s = 12.0;
    cfg.motion.enable_timeout_s = 60.0;
    cfg.safety.tension_max_age_s = 3.0;
    cfg.safety.tracker_max_age_s = 3.0;
    for c in &mut cfg.cables {
        let d = c.drive.as_mut().unwrap();
        d.heartbeat_ms = 500;
        d.heartbeat_timeout_ms = Some(10_000);
    }
    let can = cfg.can.as_mut().unwrap();
    can.sdo_timeout_s = 5.0;
    can.bringup_timeout_s = 120.0;
    can.cycle_s = 0.01;
    if let Some(l) = cfg.loadcells.as_mut() {
        l.response_timeout_s = 0.5;
    }
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

#[test]
fn start_up_over_socketcan_runs_every_stage() {
    let Some(iface) = vcan::iface_or_skip("vcan0", "start_up_over_socketcan_runs_every_stage") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let p0 = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0];
    // The load cells on a pseudo-terminal, as the robot opens its serial port (the VM has the
    // machine to itself; the host's start-ups use a socket pair, taut_simrig::LoadCellLine).
    let so = SimOptions {
        seed: 3,
        can: Some(iface.to_string()),
        site_period: Duration::from_millis(5),
        load_cell_line: simrig::LoadCellLine::Pty,
        ..Default::default()
    };
    let p0 = simrig::rest_position(&cfg, &so, p0);
    let sim = simrig::build(&cfg, p0, &so).expect("bring-up over vcan0");
    let site = sim.faults.clone();
    let d =
        Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions { control: false, ..Default::default() })
            .unwrap();
    let finished = d.wait_until(Duration::from_secs(480), |l, c| {
        l.snap.fault.is_some() || c.outcomes.iter().any(|o| o.kind == OutcomeKind::Calibration) || l.snap.state == State::Stopped
    });
    let l = d.loop_status();
    let c = d.calib_status();
    eprintln!(
        "state {:?}, phases {}, stage {}, samples {}, outcomes {:?}",
        l.snap.state,
        l.snap.phases_completed,
        c.stage,
        c.samples_recorded,
        c.outcomes.iter().map(|o| (o.kind, o.accepted, o.reason.clone(), o.data_problems.clone())).collect::<Vec<_>>()
    );
    if !finished || l.snap.fault.is_some() {
        // What the loop saw before it stopped: overruns and the recording's last samples.
        eprintln!(
            "cycles {}, overruns {}, max lateness {:.1} ms, max compute {:.1} ms, plant steps without equilibrium {}",
            l.cycles,
            l.overruns,
            l.max_late_ns as f64 / 1e6,
            l.max_compute_ns as f64 / 1e6,
            site.plant_failed_steps.load(std::sync::atomic::Ordering::Relaxed)
        );
        if let Some(text) = c.recording.as_ref().and_then(|p| std::fs::read_to_string(p).ok()) {
            let lines: Vec<&str> = text.lines().collect();
            let header = lines.iter().take_while(|l| l.starts_with('#')).count();
            eprintln!("{}", lines.get(header).copied().unwrap_or(""));
            // Every 10th sample, then the last 20.
            let tail = lines.len().saturating_sub(20).max(header + 1);
            for (k, line) in lines.iter().enumerate().skip(header + 1) {
                if k >= tail || (k - header) % 10 == 1 {
                    eprintln!("{line}");
                }
            }
        }
    }
    assert!(finished, "the start-up did not reach the calibration in time");
    assert!(l.snap.fault.is_none(), "safety reaction: {:?}", l.snap.fault);
    assert_eq!(l.snap.phases_completed, 3);
    let init = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Initial).expect("an initial estimate");
    assert!(init.accepted, "initial estimate rejected: {}", init.reason);
    assert!(c.outcomes.iter().any(|o| o.kind == OutcomeKind::Calibration), "no calibration outcome");
    assert!(c.samples_recorded > 500, "{} samples", c.samples_recorded);
    assert_eq!(l.dropped, 0);
    d.shutdown();
}
