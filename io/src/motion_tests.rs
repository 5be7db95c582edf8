//! Tests of the motion state machine run in the loop core against the kinematic test robot
//! (`runner`, `testkit`), both of this crate.

use crate::runner::LoopCore;
use crate::testkit::{quick_config, truth_params, KinematicRobot};
use crate::FromRobot;
use taut_rt::motion::*;
use taut_rt::safety::*;
use taut_rt::sample::sample_ring;
use taut_rt::triple::triple_buffer;

/// The 4-cable kinematic robot without a tracker in the loop core, running `ccfg`, with no
/// parameters yet: the core, the writer of the loop's parameters and the robot's truth.
pub(crate) fn dwell_rig(
    ccfg: ControllerConfig,
    cmd_rx: crossbeam_channel::Receiver<Command>,
) -> (LoopCore<KinematicRobot>, taut_rt::triple::Writer<taut_rt::kin::LoopParams>, taut_rt::kin::LoopParams) {
    let truth = truth_params(4, 0.1);
    let (params_tx, params_rx) = triple_buffer(taut_rt::kin::LoopParams::invalid(4));
    let (sample_tx, _sample_rx) = sample_ring(64);
    let mut robot = KinematicRobot::new(truth, [0.2, 0.1, 2.0]);
    robot.inject.tracker_gone = true;
    (LoopCore::new(4, robot, Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx), sample_tx), params_tx, truth)
}

fn core(dir: &std::path::Path) -> LoopCore<KinematicRobot> {
    let mut cfg = quick_config(4, dir);
    cfg.safety.tension_max_age_s = 5.0;
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let truth = truth_params(4, 0.1);
    let (_params_tx, params_rx) = triple_buffer(taut_rt::kin::LoopParams::invalid(4));
    let (_cmd_tx, cmd_rx) = crossbeam_channel::bounded(4);
    let (sample_tx, _sample_rx) = sample_ring(64);
    LoopCore::new(
        4,
        KinematicRobot::new(truth, [0.2, 0.1, 2.0]),
        Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx),
        sample_tx,
    )
}

/// A loose reading taken before the reel began (the newest one after a stall of the
/// load-cell thread, still within the tension age limit) does not stop the phase as a loose
/// reeled cable; a loose reading taken during the reel does.
#[test]
fn a_reeled_cable_is_judged_loose_only_on_readings_taken_during_the_reel() {
    // Nothing is written: the directory only names the socket and data paths.
    let mut c = core(&std::env::temp_dir());
    let dt = 0.002;
    let mut t = 0.0;
    let mut step = |c: &mut LoopCore<KinematicRobot>, k: usize| {
        for _ in 0..k {
            t += dt;
            c.cycle(t, dt);
        }
    };
    for _ in 0..5000 {
        step(&mut c, 1);
        if c.controller.state() == State::InitPhase {
            break;
        }
    }
    assert_eq!(c.controller.state(), State::InitPhase, "{:?}", c.controller.fault());
    assert_eq!(c.controller.phase_label(), -1, "settling before the reel");
    // Loose at rest, then the load cells go quiet: the reel starts on that old reading.
    c.devices.tension_n = 0.3;
    step(&mut c, 1);
    c.devices.inject.loadcells_silent = true;
    step(&mut c, 100);
    assert_eq!(c.controller.phase_label(), 0, "reeling");
    step(&mut c, 100);
    assert_eq!(c.controller.fault(), None, "judged on a reading from before the reel");
    // A reading taken during the reel says loose: the phase stops.
    c.devices.inject.loadcells_silent = false;
    step(&mut c, 1);
    let (cause, _) = c.controller.fault().expect("a loose reeled cable latches");
    assert!(matches!(cause, Cause::CableLoose { tension_n, .. } if tension_n < 1.0), "{cause:?}");
}

/// A drum that turned while the drives were stopped (a quick stop's ramp, a brake that
/// slipped): after the reset the cable is held where it now stands, not where it was when
/// the reaction latched.
#[test]
fn a_reset_holds_where_the_drives_stand_now() {
    let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(4);
    let mut cfg = quick_config(4, &std::env::temp_dir());
    cfg.safety.tension_max_age_s = 5.0;
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let (_params_tx, params_rx) = triple_buffer(taut_rt::kin::LoopParams::invalid(4));
    let (sample_tx, _sample_rx) = sample_ring(64);
    let robot = KinematicRobot::new(truth_params(4, 0.1), [0.2, 0.1, 2.0]);
    let mut c = LoopCore::new(4, robot, Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx), sample_tx);
    let mut t = 0.0;
    let mut step = |c: &mut LoopCore<KinematicRobot>, k: usize| {
        for _ in 0..k {
            t += 0.002;
            c.cycle(t, 0.002);
        }
    };
    step(&mut c, 300);
    assert_eq!(c.controller.state(), State::InitPhase, "{:?}", c.controller.fault());
    cmd_tx.send(Command::Estop).unwrap();
    step(&mut c, 10);
    assert_eq!(c.controller.fault().map(|f| f.1), Some(Reaction::QuickStop));
    // The drum of cable 0 turns by 5 mm while the drives are stopped.
    c.devices.len[0] += 0.005;
    let moved = c.devices.len[0];
    step(&mut c, 10);
    // A reset that is not asked for does not happen.
    assert_eq!(c.controller.state(), State::Faulted);
    cmd_tx.send(Command::Reset).unwrap();
    step(&mut c, 20);
    assert_eq!(c.controller.state(), State::Holding, "{:?}", c.controller.snapshot(0.0, &c.inputs).last_reset);
    let s = c.controller.snapshot(0.0, &c.inputs);
    assert_eq!(s.last_reset, Some(ResetOutcome::Done));
    assert_eq!(s.resets, 1);
    // (The stand-in robot re-levels the platform over the four cables when they are
    // enabled, so cable 0 ends a little short of `moved`; what matters is that it is not
    // pulled back the 5 mm to where it was when the reaction latched.)
    let latched = moved - 0.005;
    assert!((s.cmd_m[0] - latched).abs() > 0.003, "held at {} m, the stale {latched} m, the drum at {moved} m", s.cmd_m[0]);
    assert!((s.cmd_m[0] - s.inputs.length_m[0]).abs() < 1e-9, "holds where it stands");
    assert!(s.reenable_step_m < 1e-6, "step {} m", s.reenable_step_m);
    // A second reset with nothing latched is refused with the reason.
    cmd_tx.send(Command::Reset).unwrap();
    step(&mut c, 2);
    let s = c.controller.snapshot(0.0, &c.inputs);
    assert_eq!(s.last_reset, Some(ResetOutcome::Refused(ResetRefusal::NothingToReset)));
    assert_eq!(s.state, State::Holding);
}

/// Without a tracker: the rest dwell (phase 0), the wait for the rest estimate, the dwell
/// plan's poses in order (each labelled with its index while recorded, the platform at the
/// pose), operate; `Recalibrate` visits the poses again. No tracker pose is ever read.
#[test]
fn dwell_startup_runs_the_plan_and_recalibrates() {
    let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(4);
    let mut cfg = quick_config(4, &std::env::temp_dir());
    cfg.safety.tension_max_age_s = 5.0;
    let poses = [[1.0, 0.5, 2.5], [-1.0, -0.5, 1.5], [0.5, -0.5, 2.0]];
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap().with_dwell_plan(&poses, 1.0, 0.2, 0.5);
    let (mut c, mut params_tx, truth) = dwell_rig(ccfg, cmd_rx);
    let dt = 0.002;
    let mut t = 0.0;
    let mut labels: Vec<(State, i8)> = Vec::new();
    let mut at_pose: Vec<[f64; 3]> = Vec::new();
    let mut run = |c: &mut LoopCore<KinematicRobot>,
                   until: &dyn Fn(&LoopCore<KinematicRobot>) -> bool,
                   labels: &mut Vec<(State, i8)>,
                   at_pose: &mut Vec<[f64; 3]>| {
        for _ in 0..200_000 {
            t += dt;
            c.cycle(t, dt);
            let l = (c.controller.state(), c.controller.phase_label());
            if labels.last() != Some(&l) {
                if labels.last().is_some_and(|p| p.0 == State::Excitation && p.1 >= 0) {
                    at_pose.push(c.devices.p);
                }
                labels.push(l);
            }
            assert_eq!(c.controller.fault(), None, "{labels:?}");
            if until(c) {
                return;
            }
        }
        panic!("not reached: {labels:?}");
    };
    run(&mut c, &|c| c.controller.state() == State::AwaitInitial, &mut labels, &mut at_pose);
    assert!(labels.contains(&(State::InitPhase, 0)), "the rest dwell is recorded: {labels:?}");
    assert_eq!(c.controller.snapshot(0.0, &c.inputs).phases_completed, 1);
    // The rest estimate arrives: the robot's own parameters, version 1.
    let mut p1 = truth;
    p1.version = 1;
    p1.valid = true;
    params_tx.write(p1);
    run(&mut c, &|c| c.controller.state() == State::Operate, &mut labels, &mut at_pose);
    let rec: Vec<i8> = labels.iter().filter(|l| l.0 == State::Excitation && l.1 >= 0).map(|l| l.1).collect();
    assert_eq!(rec, vec![0, 1, 2], "{labels:?}");
    for (p, q) in at_pose.iter().zip(&poses) {
        assert!((0..3).all(|i| (p[i] - q[i]).abs() < 1e-6), "held at {p:?}, planned {q:?}");
    }
    // Recalibration visits the poses again.
    labels.clear();
    at_pose.clear();
    cmd_tx.send(Command::Recalibrate).unwrap();
    run(&mut c, &|c| c.controller.state() == State::Excitation, &mut labels, &mut at_pose);
    assert_eq!(c.controller.run(), 1);
    run(&mut c, &|c| c.controller.state() == State::Operate, &mut labels, &mut at_pose);
    let rec: Vec<i8> = labels.iter().filter(|l| l.0 == State::Excitation && l.1 >= 0).map(|l| l.1).collect();
    assert_eq!(rec, vec![0, 1, 2], "{labels:?}");
}
