//! The start-up with a fault injected at each stage (load cell silent, drive EMCY, heartbeat
//! lost, tracker gone): each ends in its defined safety reaction, with the cause in the status,
//! and the parameters in force are not changed by it. In simulated time (the robot stack in
//! lockstep): the fault lands at a defined cycle, whatever the machine is doing.

use std::sync::atomic::Ordering;
use taut_calibrator::calib_backend::TautCalib;
use taut_rt::motion::State;
use taut_rt::safety::{Cause, Reaction};
use taut_simrig::{Lockstep, RunOptions, SimFaults, SimOptions};
use taut_tests::startup::rest_p0;

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

/// Runs the start-up in simulated time until `when` holds, injects the fault, and returns the
/// latched cause and reaction, the parameter version before the fault and after.
fn inject(when: fn(State, i8) -> bool, fault: fn(&SimFaults)) -> (Cause, Reaction, u64, u64, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let so = SimOptions { seed: 5, ..Default::default() };
    let mut host = Lockstep::start(&cfg, rest_p0(&cfg, &so), &so, RunOptions::default(), Box::new(TautCalib::from_config(&cfg))).unwrap();
    assert!(host.run_until(120.0, |l, _| when(l.snap.state, l.snap.phase) || l.snap.fault.is_some()), "stage not reached");
    assert!(host.loop_status().snap.fault.is_none(), "fault before injection: {:?}", host.loop_status().snap.fault);
    let before = host.loop_status().snap.params_version;
    fault(host.faults());
    assert!(host.run_until(10.0, |l, _| l.snap.fault.is_some()), "no reaction");
    // Let the calibrator see the interruption, then check nothing new was published.
    host.run_for(0.5);
    let l = host.loop_status();
    let c = host.calib_status();
    let (cause, reaction) = l.snap.fault.unwrap();
    assert_eq!(l.snap.state, State::Faulted);
    let reasons = c.outcomes.iter().filter(|o| !o.accepted).map(|o| o.reason.clone()).collect();
    let after = l.snap.params_version;
    let files = std::fs::read_dir(dir.path().join("data/params"))
        .map_or(0, |r| r.filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("params-v")).count());
    assert_eq!(files as u64, after, "parameter files written after the fault");
    host.finish(false);
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
