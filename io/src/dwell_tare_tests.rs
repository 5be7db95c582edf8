//! The tare of the tracker-free start-up in the loop: after the dwells with a tare mask, the
//! platform stays at the pose, the mask's cables are ramped to zero tension (the others hold it
//! in position mode) and the tare is recorded with the label `MAX_DWELL_POSES + index`; then
//! the slack cables are ramped back.

use crate::testkit::quick_config;
use crate::FromRobot;
use taut_rt::io::CableCommand;
use taut_rt::motion::*;

#[test]
fn tares_follow_their_dwells_with_the_masked_cables_at_zero_tension() {
    let (_cmd_tx, cmd_rx) = crossbeam_channel::bounded::<Command>(4);
    let mut cfg = quick_config(4, &std::env::temp_dir());
    cfg.safety.tension_max_age_s = 5.0;
    let poses = [[1.0, 0.5, 2.5], [-1.0, -0.5, 1.5], [0.5, -0.5, 2.0]];
    let probe = ControllerConfig::from_robot(&cfg).unwrap();
    let followers: Vec<usize> = (0..4).filter(|&j| probe.follower[j]).collect();
    assert_eq!(followers.len(), 1);
    let fmask = 1u8 << followers[0];
    // Pose 1: the follower's tare; pose 2: a position cable's (cable p).
    let p = (0..4).find(|&j| !probe.follower[j]).unwrap();
    let pmask = 1u8 << p;
    let ccfg = probe.with_dwell_plan(&poses, 1.0, 0.2, 0.5).with_dwell_tares(&[0, fmask, pmask]);
    let (mut c, mut params_tx, truth) = crate::motion_tests::dwell_rig(ccfg, cmd_rx);
    let dt = 0.002;
    let mut t = 0.0;
    let mut labels: Vec<i8> = Vec::new();
    let mut tare_cycles = [0usize; 3];
    let mut given = false;
    // The slack cables' tension command: never a step (ramped over half the settle time).
    let mut last_tension: [Option<f64>; 4] = [None; 4];
    let mut largest_step: f64 = 0.0;
    for _ in 0..200_000 {
        t += dt;
        c.cycle(t, dt);
        assert_eq!(c.controller.fault(), None, "{labels:?}");
        if c.controller.state() == State::AwaitInitial && !given {
            let mut p1 = truth;
            p1.version = 1;
            p1.valid = true;
            params_tx.write(p1);
            given = true;
        }
        if c.controller.state() != State::Excitation {
            if c.controller.state() == State::Operate {
                break;
            }
            continue;
        }
        for (last, out) in last_tension.iter_mut().zip(&c.outputs.cable) {
            if let CableCommand::Tension(f) = *out {
                if let Some(prev) = *last {
                    largest_step = largest_step.max((f - prev).abs());
                }
                *last = Some(f);
            } else {
                *last = None;
            }
        }
        let l = c.controller.phase_label();
        if labels.last() != Some(&l) {
            labels.push(l);
        }
        let tare = (l as i32 - MAX_DWELL_POSES as i32).clamp(-1, 2);
        if tare >= 1 {
            tare_cycles[tare as usize] += 1;
            let slack = if tare == 1 { fmask } else { pmask };
            // The mask's cables slack, the others in position mode at the pose.
            for j in 0..4 {
                match c.outputs.cable[j] {
                    CableCommand::Tension(f) => assert!(slack & (1 << j) != 0 && f == 0.0, "tare {tare}: cable {j}: {f} N"),
                    CableCommand::Position(_) => assert!(slack & (1 << j) == 0, "tare {tare}: cable {j} in position mode"),
                    CableCommand::Idle => panic!("cable {j} idle in the tare"),
                }
            }
            let q = c.devices.p;
            assert!((0..3).all(|i| (q[i] - poses[tare as usize][i]).abs() < 1e-6), "tare {tare}: held at {q:?}");
        } else if l >= 0 {
            for &j in &followers {
                assert!(
                    matches!(c.outputs.cable[j], CableCommand::Tension(f) if f > 0.0),
                    "follower {j} in a dwell: {:?}",
                    c.outputs.cable[j]
                );
            }
            for j in (0..4).filter(|&j| !probe.follower[j]) {
                assert!(matches!(c.outputs.cable[j], CableCommand::Position(_)), "cable {j} in a dwell: {:?}", c.outputs.cable[j]);
            }
        }
    }
    assert_eq!(c.controller.state(), State::Operate, "{labels:?}");
    let rec: Vec<i8> = labels.iter().copied().filter(|&l| l >= 0).collect();
    assert_eq!(rec, vec![0, 1, MAX_DWELL_POSES as i8 + 1, 2, MAX_DWELL_POSES as i8 + 2], "{labels:?}");
    // Recorded for dwell_s at 500 Hz (one cycle either way).
    for (k, cycles) in tare_cycles.iter().enumerate().skip(1) {
        assert!((499..=501).contains(cycles), "{cycles} cycles in tare {k}");
    }
    // 30 N (the stand-in's tension) down over 0.1 s (50 cycles) and back over 0.2 s: a
    // smoothstep's steepest step is 1.5 x the mean one, 0.9 N per cycle; a step would be 30 N.
    assert!(largest_step > 0.1 && largest_step < 1.0, "largest tension step {largest_step} N per cycle");
}
