//! The loop's tension side: every load cell's reading becomes its cable's tension (gain and
//! friction from the parameters) before the statics, the stretch and the safety limits read it.

use crate::runner::LoopCore;
use crate::testkit::{quick_config, truth_params, KinematicRobot};
use crate::FromRobot;
use taut_rt::io::{CableCommand, DriveStatus, Inputs, Outputs};
use taut_rt::kin::{LoopEffects, LoopParams};
use taut_rt::motion::*;
use taut_rt::safety::Cause;
use taut_rt::sample::sample_ring;
use taut_rt::triple::triple_buffer;

/// Runs a controller with `effects` on hand-made inputs: every cable's length changes at `v`
/// m/s, cable 0's cell reads 30 N for 0.2 s (the speed estimate settles), then `reading`.
/// Returns the first latched cause and cable 0's estimated speed.
fn judge(effects: LoopEffects, v: f64, reading: f64) -> (Option<Cause>, f64) {
    let ccfg = ControllerConfig::from_robot(&quick_config(4, &std::env::temp_dir())).unwrap();
    let mut p = truth_params(4, 0.1).with_effects(effects);
    p.version = 1;
    let (_tx, rx) = triple_buffer(p);
    let mut c = Controller::new(ccfg, || None::<Command>, rx);
    let (mut inp, mut out) = (Inputs::new(4), Outputs::new(4));
    let dt = 0.002;
    for k in 0..150 {
        let t = k as f64 * dt;
        for j in 0..4 {
            inp.length_m[j] = 5.0 + v * t;
            inp.length_age_s[j] = 0.0;
            inp.tension_n[j] = if j == 0 && k >= 100 { reading } else { 30.0 };
            inp.tension_age_s[j] = 0.0;
            inp.drive[j] = DriveStatus::Disabled;
        }
        c.update(t, dt, &inp, &mut out);
        if let Some((cause, _)) = c.fault() {
            return (Some(cause), c.cable_speed(0));
        }
    }
    (None, c.cable_speed(0))
}

/// With a known gain and friction the safety limit judges the cable's true tension: a cable
/// paying out over its limit whose cell reads under it (the guides hold back) latches with the
/// true tension; one reeling in under its limit whose cell reads over it does not.
#[test]
fn safety_judges_the_cable_tension_through_gain_and_friction() {
    let max = ControllerConfig::from_robot(&quick_config(4, &std::env::temp_dir())).unwrap().max_tension_n;
    let (gain, mu_theta, v) = (1.1, 0.2f64, 0.05);
    let effects = LoopEffects::NONE.with_tension_side(Some(&[gain, 1.0, 1.0, 1.0]), Some(&[mu_theta; 4]));
    // Paying out at 10x the friction band: the cell reads gain t exp(-mu theta).
    let truth = 1.05 * max;
    let reading = gain * truth * (-mu_theta).exp();
    assert!(reading < max, "the raw reading is under the limit");
    let (cause, speed) = judge(effects, v, reading);
    assert!((speed - v).abs() < 1e-9, "the encoders' length rate: {speed}");
    match cause {
        Some(Cause::TensionHigh { cable: 0, tension_n }) => {
            assert!((f64::from(tension_n) - truth).abs() < 1e-5 * truth, "judged {tension_n} N, true {truth} N")
        }
        other => panic!("the true tension is over the limit: {other:?}"),
    }
    assert_eq!(judge(LoopEffects::NONE, v, reading).0, None, "without the effects the reading is under the limit");
    // Reeling in: the cell reads gain t exp(mu theta), over the limit for a cable under it.
    let truth = 0.9 * max;
    let reading = gain * truth * mu_theta.exp();
    assert!(reading > max);
    assert_eq!(judge(effects, -v, reading).0, None, "the true tension is under the limit");
    assert!(matches!(judge(LoopEffects::NONE, -v, reading).0, Some(Cause::TensionHigh { cable: 0, .. })));
}

/// Every cycle's drive commands of the 4-cable kinematic robot from start-up through the
/// phases, the calibrated parameters, a move and a hold, with `effects` in the parameters from
/// the start and every cell reading `reading_n`.
fn commands(effects: LoopEffects, reading_n: f64) -> Vec<(DriveStatus, [CableCommand; 4])> {
    let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(4);
    let ccfg = ControllerConfig::from_robot(&quick_config(4, &std::env::temp_dir())).unwrap();
    let truth = truth_params(4, 0.1);
    let (mut params_tx, params_rx) = triple_buffer(LoopParams::invalid(4).with_effects(effects));
    let (sample_tx, _sample_rx) = sample_ring(64);
    let mut robot = KinematicRobot::new(truth, [0.2, 0.1, 2.0]);
    robot.tension_n = reading_n;
    let mut c = LoopCore::new(4, robot, Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx), sample_tx);
    let mut log = vec![];
    let mut t = 0.0;
    let mut step = |c: &mut LoopCore<KinematicRobot>, log: &mut Vec<_>| {
        t += 0.002;
        c.cycle(t, 0.002);
        let mut cmd = [CableCommand::Idle; 4];
        cmd.copy_from_slice(&c.outputs.cable[..4]);
        log.push((c.inputs.drive[0], cmd));
    };
    while c.controller.state() != State::AwaitInitial && log.len() < 20_000 {
        step(&mut c, &mut log);
    }
    let mut p = truth.with_effects(effects);
    p.version = 1;
    params_tx.write(p);
    while c.controller.state() != State::Operate && log.len() < 40_000 {
        step(&mut c, &mut log);
    }
    assert_eq!(c.controller.state(), State::Operate, "{:?}", c.controller.fault());
    cmd_tx.send(Command::MoveTo([0.5, 0.2, 2.0])).unwrap();
    for _ in 0..2000 {
        step(&mut c, &mut log);
    }
    log
}

/// Without a tension side the loop is what it was, bit for bit: gain 1 and no friction give
/// the commands of the model without them, and so do cells that read exactly twice the tension
/// with a gain of 2 (the correction runs and divides exactly). The cables are elastic, so the
/// tension reaches the commanded lengths.
#[test]
fn without_a_tension_side_the_loop_commands_bit_for_bit_the_same() {
    let elastic = LoopEffects::from_values(Some(&[20_000.0; 4]), None, None, None, None, None);
    let base = commands(elastic, 30.0);
    let bits = |log: &[(DriveStatus, [CableCommand; 4])]| -> Vec<u64> {
        log.iter()
            .flat_map(|(_, c)| {
                c.iter().map(|m| match m {
                    CableCommand::Position(x) => x.to_bits(),
                    CableCommand::Tension(x) => x.to_bits() ^ 1 << 63,
                    CableCommand::Idle => 0,
                })
            })
            .collect()
    };
    let first_difference =
        |a: &[u64], b: &[u64]| a.iter().zip(b).position(|(x, y)| x != y).or((a.len() != b.len()).then_some(a.len().min(b.len())));
    let base = bits(&base);
    let off = elastic.with_tension_side(Some(&[1.0; 4]), Some(&[0.0; 4]));
    assert!(!off.corrects_tensions());
    assert_eq!(first_difference(&bits(&commands(off, 30.0)), &base), None, "gain 1, no friction");
    let doubled = elastic.with_tension_side(Some(&[2.0; 4]), Some(&[0.0; 4]));
    assert!(doubled.corrects_tensions());
    assert_eq!(first_difference(&bits(&commands(doubled, 60.0)), &base), None, "cells reading double with gain 2");
    // (and the reading matters: the same cells read as they are give other commands)
    assert!(first_difference(&bits(&commands(elastic, 60.0)), &base).is_some());
}
