//! The lockstep simulation itself: a seed reproduces a start-up bit for bit, the same start-up
//! rides through the faults its seed draws, and the simulated devices keep the protocols'
//! timing (the bus load the SYNC cycle implies, the load cells' polling rate).

use taut_calibrator::vocab::OutcomeKind;
use taut_config::RobotConfig;
use taut_simrig::{LockstepFaults, RunOptions, SimOptions, StartupRun};

fn robot(dir: &std::path::Path) -> RobotConfig {
    let mut cfg = RobotConfig::from_toml_str(include_str!("../../../config/examples/aras-cam-sim.toml")).unwrap();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

fn startup(seed: u64, faults: LockstepFaults) -> StartupRun {
    let dir = tempfile::tempdir().unwrap();
    let cfg = robot(dir.path());
    let so = SimOptions { seed, ..Default::default() };
    let run = taut_tests::startup::in_sim_time(&cfg, &so, RunOptions { faults, ..Default::default() }, |_, _| false);
    eprintln!(
        "seed {seed}: {:.1} s simulated in {:.2} s ({:.0}x), {} cycles; CAN {} frames ({} lost, {} late), load {:.2}; load cells {:?}",
        run.sim_s,
        run.wall_s,
        run.sim_s / run.wall_s,
        run.cycles,
        run.bus.frames,
        run.bus.lost,
        run.bus.late,
        run.bus.busy_s / run.sim_s,
        run.loadcells
    );
    run
}

/// Every number of a start-up's outcome that a run could change: estimates, sigmas, held-out
/// figures, sample counts, the loop's counters.
fn fingerprint(r: &StartupRun) -> Vec<u64> {
    let mut v = vec![r.cycles, r.bus.frames, r.bus.lost, r.loadcells.ok, r.loadcells.timeouts, r.calib_status.samples_recorded];
    for o in &r.calib_status.outcomes {
        v.push(o.version);
        v.push(o.heldout_rms_new_m.to_bits());
        if let Some(e) = &o.estimate {
            v.extend(e.geometry.anchors.iter().flatten().map(|x| x.to_bits()));
            v.extend(e.geometry.l0.iter().map(|x| x.to_bits()));
            v.extend(e.sigma.anchors.iter().flatten().map(|x| x.to_bits()));
        }
    }
    v.push(r.loop_status.snap.params_version);
    v.push(r.loop_status.snap.max_swap_step_m.to_bits());
    v
}

fn accepted_worst_anchor_m(r: &StartupRun, seed: u64) -> f64 {
    let cal = r.calib_status.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration && o.run == 0);
    let cal = cal.unwrap_or_else(|| panic!("seed {seed}: no calibration; fault {:?}", r.loop_status.snap.fault));
    assert!(cal.accepted, "seed {seed}: {}", cal.reason);
    let e = cal.estimate.as_ref().unwrap();
    e.geometry
        .anchors
        .iter()
        .zip(&r.truth.anchors)
        .map(|(a, t)| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

#[test]
fn a_seed_reproduces_the_start_up_bit_for_bit() {
    let faults = LockstepFaults::drawn(7);
    let a = startup(7, faults.clone());
    let b = startup(7, faults);
    assert!(a.finished && b.finished);
    assert_eq!(fingerprint(&a), fingerprint(&b), "seed 7: two runs differ");
    // A different seed is a different site: the check above can see a difference.
    let c = startup(8, LockstepFaults::default());
    assert_ne!(fingerprint(&a), fingerprint(&c));
}

#[test]
fn the_start_up_rides_through_the_faults_its_seed_draws() {
    for seed in [3u64, 4] {
        let faults = LockstepFaults::drawn(seed);
        let r = startup(seed, faults.clone());
        assert!(r.finished, "seed {seed}: did not finish");
        assert!(r.loop_status.snap.fault.is_none(), "seed {seed} with {faults:?}: {:?}", r.loop_status.snap.fault);
        assert!(r.bus.lost > 0 || faults.frame_loss * r.bus.frames as f64 <= 3.0, "seed {seed}: no frame was lost");
        assert!(r.loadcells.timeouts > 0, "seed {seed}: the load cells' pause caused no timeout");
        let worst = accepted_worst_anchor_m(&r, seed);
        // Lost SYNCs and TPDOs cost accuracy (measured 0.84-1.45 mm on seeds 4-6, against
        // 0.3-0.5 mm without faults): asserted loosely here, the 1 mm is the fault-free
        // acceptance's (`excitation`).
        assert!(worst < 3e-3, "seed {seed}: worst anchor {:.2} mm with faults", worst * 1e3);
    }
}

#[test]
fn the_simulated_bus_and_line_keep_their_timing() {
    let r = startup(1, LockstepFaults::default());
    // Every cycle: 4 drives x (RPDO1 + RPDO2) + SYNC from the master, 4 x (TPDO1 + TPDO2) back,
    // at 500 Hz; the bus cannot carry more than its bitrate.
    let load = r.bus.busy_s / r.sim_s;
    assert!(load > 0.3 && load < 1.0, "CAN load {load}");
    // Four cells polled back to back at 115200 baud: each transaction is 8 + 9 characters of
    // 10 bits (1.48 ms), 1 ms of answer latency and t3.5 (0.30 ms) apart: ~2.8 ms, so ~89
    // readings per second per cell.
    let per_cell_per_s = r.loadcells.ok as f64 / 4.0 / r.sim_s;
    assert!((60.0..120.0).contains(&per_cell_per_s), "{per_cell_per_s} readings/s per cell");
    assert_eq!(r.loadcells.timeouts, 0);
    assert!(accepted_worst_anchor_m(&r, 1) < 1e-3);
}
