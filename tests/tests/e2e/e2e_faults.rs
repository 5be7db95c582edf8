//! The start-up with a fault injected at each stage (load cell silent, drive EMCY, heartbeat
//! lost, tracker gone): each ends in its defined safety reaction, with the cause in the status,
//! and the parameters in force are not changed by it.

use std::sync::atomic::Ordering;
use std::time::Duration;
use taut_rt_core::calib_backend::TautCalib;
use taut_rt_core::daemon::{Daemon, DaemonOptions};
use taut_rt_core::motion::{ControllerConfig, State};
use taut_rt_core::safety::{Cause, Reaction};
use taut_rt_core::FromRobot;
use taut_simrig::{self as simrig, SimFaults, SimOptions};

fn robot(dir: &std::path::Path) -> taut_config::RobotConfig {
    // The simulated robot of `taut start --sim`, with faster phases and a shorter excitation.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    cfg.motion.init_reel_speed_m_s = 0.5;
    cfg.motion.excitation_s = 20.0;
    cfg.daemon.socket = dir.join("s.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

/// Runs the start-up until `when` holds, injects the fault, and returns the latched cause and
/// reaction, the parameter version before the fault and after.
fn inject(when: fn(State, i8) -> bool, fault: fn(&SimFaults)) -> (Cause, Reaction, u64, u64, Vec<String>) {
    // One simulated robot at a time: four at once starve each other's I/O threads on two cores.
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let so = SimOptions { seed: 5, ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0]);
    let sim = simrig::build(&cfg, p0, &so).unwrap();
    let faults = sim.faults.clone();
    let d =
        Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions { control: false, ..Default::default() })
            .unwrap();
    assert!(d.wait_until(Duration::from_secs(120), |l, _| when(l.snap.state, l.snap.phase) || l.snap.fault.is_some()), "stage not reached");
    assert!(d.loop_status().snap.fault.is_none(), "fault before injection: {:?}", d.loop_status().snap.fault);
    let before = d.loop_status().snap.params_version;
    fault(&faults);
    assert!(d.wait_until(Duration::from_secs(10), |l, _| l.snap.fault.is_some()), "no reaction");
    // Let the calibrator see the interruption, then check nothing new was published.
    std::thread::sleep(Duration::from_millis(500));
    let l = d.loop_status();
    let c = d.calib_status();
    let (cause, reaction) = l.snap.fault.unwrap();
    assert_eq!(l.snap.state, State::Faulted);
    let reasons = c.outcomes.iter().filter(|o| !o.accepted).map(|o| o.reason.clone()).collect();
    let after = l.snap.params_version;
    let files = std::fs::read_dir(dir.path().join("data/params"))
        .map_or(0, |r| r.filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("params-v")).count());
    assert_eq!(files as u64, after, "parameter files written after the fault");
    d.shutdown();
    (cause, reaction, before, after, reasons)
}

#[test]
fn load_cell_silent_during_the_phases_holds() {
    let (cause, reaction, before, after, reasons) =
        inject(|s, p| s == State::InitPhase && p == 1, |f| f.loadcell_silent.store(true, Ordering::Relaxed));
    assert!(matches!(cause, Cause::TensionStale { .. }), "{cause:?}");
    assert_eq!(reaction, Reaction::Hold);
    assert_eq!((before, after), (0, 0));
    assert!(reasons.iter().any(|r| r.contains("initialisation interrupted")), "{reasons:?}");
}

#[test]
fn heartbeat_lost_during_the_phases_quick_stops() {
    let (cause, reaction, before, after, _) =
        inject(|s, p| s == State::InitPhase && p == 2, |f| f.heartbeat_lost.store(true, Ordering::Relaxed));
    assert_eq!(cause, Cause::HeartbeatLost { node: 2 });
    assert_eq!(reaction, Reaction::QuickStop);
    assert_eq!((before, after), (0, 0));
}

#[test]
fn drive_emcy_during_the_excitation_quick_stops() {
    let (cause, reaction, before, after, reasons) = inject(|s, _| s == State::Excitation, |f| f.drive_emcy.store(true, Ordering::Relaxed));
    assert_eq!(cause, Cause::DriveFault { node: 2, code: 0x2310 });
    assert_eq!(reaction, Reaction::QuickStop);
    assert_eq!(before, 1, "the initial estimate was running");
    assert_eq!(after, before, "no parameters changed");
    assert!(reasons.iter().any(|r| r.contains("excitation interrupted")), "{reasons:?}");
}

#[test]
fn tracker_gone_during_the_excitation_holds() {
    let (cause, reaction, before, after, reasons) =
        inject(|s, _| s == State::Excitation, |f| f.tracker_gone.store(true, Ordering::Relaxed));
    assert_eq!(cause, Cause::TrackerStale);
    assert_eq!(reaction, Reaction::Hold);
    assert_eq!(after, before);
    assert!(reasons.iter().any(|r| r.contains("excitation interrupted")), "{reasons:?}");
}
