//! The tare of the tracker-free start-up in the loop: after the dwells marked for a tare, the
//! platform stays at the pose, the followers are commanded to zero tension (the position cables
//! keep holding it) and the tare is recorded with the label `MAX_DWELL_POSES + index`.

use crate::motion::*;
use crate::testkit::quick_config;
use crate::FromRobot;
use taut_rt::io::CableCommand;

#[test]
fn tares_follow_their_dwells_with_the_followers_at_zero_tension() {
    let (_cmd_tx, cmd_rx) = crate::crossbeam_channel::bounded::<Command>(4);
    let mut cfg = quick_config(4, &std::env::temp_dir());
    cfg.safety.tension_max_age_s = 5.0;
    let poses = [[1.0, 0.5, 2.5], [-1.0, -0.5, 1.5], [0.5, -0.5, 2.0]];
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap().with_dwell_plan(&poses, 1.0, 0.2, 0.5).with_dwell_tares(&[false, true, false]);
    let followers: Vec<usize> = (0..4).filter(|&j| ccfg.follower[j]).collect();
    assert!(!followers.is_empty());
    let (mut c, mut params_tx, truth) = crate::motion_tests::dwell_rig(ccfg, cmd_rx);
    let dt = 0.002;
    let mut t = 0.0;
    let mut labels: Vec<i8> = Vec::new();
    let mut tare_cycles = 0;
    let mut given = false;
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
        let l = c.controller.phase_label();
        if labels.last() != Some(&l) {
            labels.push(l);
        }
        if l == MAX_DWELL_POSES as i8 + 1 {
            tare_cycles += 1;
            // The followers slack, the others in position mode at the pose.
            for j in 0..4 {
                match c.outputs.cable[j] {
                    CableCommand::Tension(f) => assert!(followers.contains(&j) && f == 0.0, "cable {j}: {f} N"),
                    CableCommand::Position(_) => assert!(!followers.contains(&j), "cable {j} in position mode"),
                    CableCommand::Idle => panic!("cable {j} idle in the tare"),
                }
            }
            let p = c.devices.p;
            assert!((0..3).all(|i| (p[i] - poses[1][i]).abs() < 1e-6), "held at {p:?}");
        } else if l >= 0 {
            for &j in &followers {
                assert!(
                    matches!(c.outputs.cable[j], CableCommand::Tension(f) if f > 0.0),
                    "follower {j} in a dwell: {:?}",
                    c.outputs.cable[j]
                );
            }
        }
    }
    assert_eq!(c.controller.state(), State::Operate, "{labels:?}");
    let rec: Vec<i8> = labels.iter().copied().filter(|&l| l >= 0).collect();
    assert_eq!(rec, vec![0, 1, MAX_DWELL_POSES as i8 + 1, 2], "{labels:?}");
    // Recorded for dwell_s at 500 Hz (one cycle either way).
    assert!((499..=501).contains(&tare_cycles), "{tare_cycles} tare cycles");
}
