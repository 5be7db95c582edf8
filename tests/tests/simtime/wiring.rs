//! The start-up's wiring check (`taut_rt::wiring`): a simulated robot whose
//! drives or load cells are wired to other cables than the configuration says, or whose encoder
//! counts the other way (`taut_simrig::Wiring`: the plant's physics with the miswiring, not a
//! flag the check reads), stops in the first initialisation phase with the cause named; the
//! same robots wired as configured run the three phases without a stop.
//!
//! `TAUT_WIRING_SEEDS=1-40` runs the correct-wiring sweep over more seeds (the false-alarm
//! rate in docs/testing.md); `wiring_detection_rates` (ignored) sweeps the miswirings.

use taut_config::RobotConfig;
use taut_io::runner::LoopStatus;
use taut_rt::motion::State;
use taut_rt::safety::{Cause, Miswiring, Reaction};
use taut_simrig::{RunOptions, SimOptions, Wiring};
use taut_tests::startup::{example_robot, in_sim_time};

/// The simulated robot of `taut start --sim` with the phases at 0.5 m/s.
fn four(dir: &std::path::Path) -> RobotConfig {
    let mut cfg = example_robot(dir);
    cfg.motion.init_reel_speed_m_s = 0.5;
    cfg
}

/// The 8-cable robot of `taut_sim::Scenario::octagon` (anchors on an octagon of radius 4 m,
/// 4 m up, 5 kg; in another order) with the example's drives and load cells, one per cable.
fn eight(dir: &std::path::Path) -> RobotConfig {
    let mut cfg = four(dir);
    let sc = taut_sim::Scenario::octagon(1);
    let anchors = sc.robot.anchors().expect("the octagon has nominal anchors");
    let proto = cfg.cables[0].clone();
    // The three cables that hold the platform (the phases' and operation's 0, 1, 2) spread
    // round the octagon, so that they can hold it above the middle: anchors 0, 3 and 5 first.
    cfg.cables = [0, 3, 5, 1, 2, 4, 6, 7]
        .iter()
        .enumerate()
        .map(|(j, &k)| {
            let mut c = proto.clone();
            c.anchor = Some(anchors[k]);
            c.drive.as_mut().expect("the example has drives").node_id = j as u8 + 1;
            c.loadcell.as_mut().expect("the example has load cells").unit_id = j as u8 + 1;
            c
        })
        .collect();
    cfg.robot.mass_kg = sc.robot.robot.mass_kg;
    // Eight drives' PDOs and SYNC take 2 ms of a 1 Mbit/s bus: a 500 Hz loop would find the
    // readings a cycle or more late (measured: encoder changes at a quarter of the motion's).
    cfg.rt.rate_hz = 250.0;
    cfg
}

/// Runs the start-up until the three phases are over or a fault latches; the loop's status then.
fn phases(cfg: &RobotConfig, so: &SimOptions) -> LoopStatus {
    let over = |s: State| matches!(s, State::AwaitInitial | State::Excitation | State::Operate | State::Faulted);
    let run = in_sim_time(cfg, so, RunOptions { budget_s: 120.0, ..Default::default() }, |l, _| over(l.snap.state));
    let l = run.loop_status;
    assert!(over(l.snap.state), "seed {}: the phases did not end: {:?}", so.seed, l.snap.state);
    l
}

/// The latched cause of a start-up with `wiring`, which must stop in the first phase.
fn stops_in_phase_1(cfg: &RobotConfig, seed: u64, wiring: Wiring, dynamic: bool) -> (Cause, LoopStatus) {
    let mut so = SimOptions { seed, wiring, ..Default::default() };
    if dynamic {
        so.physics.dynamics = Some(taut_sim::Dynamics::default());
    }
    let l = phases(cfg, &so);
    let (cause, reaction) = l.snap.fault.unwrap_or_else(|| panic!("seed {seed}: {:?} did not stop the start-up", so.wiring));
    eprintln!("seed {seed} {:?}: {cause}", so.wiring);
    assert_eq!(l.snap.phases_completed, 0, "seed {seed}: stopped after phase 1: {cause}");
    assert_eq!(reaction, Reaction::Hold);
    (cause, l)
}

fn miswired(c: Cause) -> (Miswiring, u8, u8, f32) {
    match c {
        Cause::Miswired { fault, cable, other, angle_deg, .. } => (fault, cable, other, angle_deg),
        other => panic!("not a wiring cause: {other:?} ({other})"),
    }
}

#[test]
fn swapped_drives_stop_the_first_phase_4_cables() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = four(dir.path());
    // Phase 1 holds 0 and 1 and reels 2; 3 follows. A held cable's drive on the follower, a
    // held cable's on the reeled one.
    for (i, k) in [(0, 3), (1, 2)] {
        let (cause, _) = stops_in_phase_1(&cfg, 3, Wiring::swapped_drives(4, i, k), false);
        let (fault, cable, other, _) = miswired(cause);
        assert_eq!((fault, cable, other), (Miswiring::DrivesSwapped, i as u8, k as u8), "{cause}");
        let text = cause.to_string();
        assert!(text.starts_with(&format!("drives of cables {i} and {k} look swapped")), "{text}");
    }
    // The reeled cable's drive on the follower: cables 2 and 3 are mirror images about the
    // plane the platform moves in (anchors at y = +-1.75 m), so their encoders change alike and
    // only the tensions show the swap, which two swapped load cells would show as well.
    let (cause, _) = stops_in_phase_1(&cfg, 3, Wiring::swapped_drives(4, 2, 3), false);
    let (fault, cable, other, _) = miswired(cause);
    assert_eq!((fault, cable, other), (Miswiring::DrivesOrLoadCellsSwapped, 2, 3), "{cause}");
    assert!(cause.to_string().starts_with("drives or load cells of cables 2 and 3 look swapped"), "{cause}");
}

#[test]
fn swapped_drives_stop_the_first_phase_8_cables() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = eight(dir.path());
    let (cause, _) = stops_in_phase_1(&cfg, 2, Wiring::swapped_drives(8, 2, 5), false);
    let (fault, cable, other, _) = miswired(cause);
    assert_eq!((fault, cable, other), (Miswiring::DrivesSwapped, 2, 5), "{cause}");
    assert!(cause.to_string().starts_with("drives of cables 2 and 5 look swapped"), "{cause}");
}

#[test]
fn an_inverted_encoder_stops_the_first_phase() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = four(dir.path());
    // The reeled cable's: its drive turns the drum the other way, the platform moves away from
    // the predicted direction.
    let (cause, _) = stops_in_phase_1(&cfg, 4, Wiring::inverted_encoder(4, 2), false);
    let (fault, cable, _, angle) = miswired(cause);
    assert_eq!((fault, cable), (Miswiring::EncoderInverted, 2), "{cause}");
    assert!(angle > 150.0, "{cause}");
    let text = cause.to_string();
    assert!(text.starts_with("reeling cable 2 moved the platform") && text.contains("its encoder sign looks inverted"), "{text}");
    // A follower's: it pays out what the motion asks, its encoder says the opposite.
    let (cause, _) = stops_in_phase_1(&cfg, 4, Wiring::inverted_encoder(4, 3), false);
    assert_eq!(miswired(cause).0, Miswiring::EncoderInverted, "{cause}");
    assert_eq!(miswired(cause).1, 3, "{cause}");
    assert!(cause.to_string().contains("cable 3's encoder changed"), "{cause}");
}

#[test]
fn a_load_cell_on_the_wrong_cable_stops_the_first_phase() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = four(dir.path());
    // Each held cable's and the follower's. (Two position cables' cells, e.g. 0 and 2, differ
    // by less than the statics with anchors 0.2 m off can tell in phase 1 on this seed; the
    // third phase names them: `wiring_detection_rates`.)
    for (i, k) in [(1, 3), (0, 3)] {
        let (cause, _) = stops_in_phase_1(&cfg, 5, Wiring::swapped_load_cells(4, i, k), false);
        let (fault, cable, other, _) = miswired(cause);
        assert_eq!((fault, cable, other), (Miswiring::LoadCellsSwapped, i as u8, k as u8), "{cause}");
        assert!(cause.to_string().starts_with(&format!("load cell of cable {i} reads cable {k}'s tension")), "{cause}");
    }
}

/// Seeds of the correct-wiring sweep: `TAUT_WIRING_SEEDS` (`1-40` or `1,2,5`), default 1-3.
fn seeds() -> Vec<u64> {
    match std::env::var("TAUT_WIRING_SEEDS") {
        Ok(s) if s.contains('-') => {
            let (a, b) = s.split_once('-').unwrap();
            (a.trim().parse().unwrap()..=b.trim().parse().unwrap()).collect()
        }
        Ok(s) => s.split(',').map(|x| x.trim().parse().expect("TAUT_WIRING_SEEDS")).collect(),
        Err(_) => (1..=3).collect(),
    }
}

/// The robots wired as configured are never stopped by the wiring check: 4 cables
/// quasi-static, 4 cables on the dynamic plant (reel 0.5 m), 8 cables; the simulated sites'
/// anchors up to 0.2 m from the nominal ones (`SimOptions::site_error_m`, the default). Prints
/// the largest normalised residual of each (1: the tolerance), and the start-ups another cause
/// stopped (some sites drawn by some seeds take a held cable past its limit in a phase: a
/// limit of the phases' motion, not of the wiring check; none of seeds 1-3).
#[test]
fn correct_wiring_never_stops() {
    let dir = tempfile::tempdir().unwrap();
    let mut dynamic = four(dir.path());
    dynamic.motion.init_reel_m = super::dynamic::DYNAMIC_REEL_M;
    let robots = [("4 cables", four(dir.path()), false), ("4 cables dynamic", dynamic, true), ("8 cables", eight(dir.path()), false)];
    let mut stops = Vec::new();
    for (name, cfg, dyn_plant) in &robots {
        let mut worst = [0.0f64; 2];
        let mut others = 0;
        let seeds = seeds();
        for &seed in &seeds {
            let mut so = SimOptions { seed, ..Default::default() };
            if *dyn_plant {
                so.physics.dynamics = Some(taut_sim::Dynamics::default());
            }
            let l = phases(cfg, &so);
            let w = l.snap.wiring_worst;
            worst = [worst[0].max(w[0]), worst[1].max(w[1])];
            match l.snap.fault {
                Some((c @ Cause::Miswired { .. }, _)) => stops.push(format!("{name} seed {seed}: {c}")),
                Some((c, _)) => {
                    others += 1;
                    eprintln!("OTHER {name} seed {seed}: phase {}: {c}", l.snap.phases_completed + 1);
                    if seed <= 3 {
                        stops.push(format!("{name} seed {seed}: {c}"));
                    }
                }
                None => assert_eq!(l.snap.phases_completed, 3, "{name} seed {seed}"),
            }
            eprintln!("WIRING {name} seed {seed}: worst residual encoders {:.2}, load cells {:.2} of the tolerance", w[0], w[1]);
        }
        eprintln!(
            "RESULT wiring {name}: {} seeds, worst residual encoders {:.2}, load cells {:.2}; stopped by another cause {others}",
            seeds.len(),
            worst[0],
            worst[1]
        );
    }
    assert!(stops.is_empty(), "stops: {stops:#?}");
}

/// The detection rates of docs/testing.md: each miswiring on seeds `TAUT_WIRING_SEEDS`
/// (default 1-3), counted as named in phase 1 (the right cause and cables), named later (before
/// the excitation), stopped with another cause, or not stopped. A measurement: it asserts only
/// that every case ran.
#[test]
#[ignore = "measurement: TAUT_WIRING_SEEDS=1-20 cargo test -p taut-tests --test simtime wiring_detection_rates -- --ignored --nocapture"]
fn wiring_detection_rates() {
    let dir = tempfile::tempdir().unwrap();
    let mut dynamic = four(dir.path());
    dynamic.motion.init_reel_m = super::dynamic::DYNAMIC_REEL_M;
    let (c4, c8) = (four(dir.path()), eight(dir.path()));
    type Case<'a> = (&'a str, &'a RobotConfig, bool, Wiring, &'a [Miswiring], (u8, u8));
    let drives: &[Miswiring] = &[Miswiring::DrivesSwapped];
    let either: &[Miswiring] = &[Miswiring::DrivesSwapped, Miswiring::DrivesOrLoadCellsSwapped];
    let cells: &[Miswiring] = &[Miswiring::LoadCellsSwapped];
    let cells_either: &[Miswiring] = &[Miswiring::LoadCellsSwapped, Miswiring::DrivesOrLoadCellsSwapped];
    let inverted: &[Miswiring] = &[Miswiring::EncoderInverted];
    let cases: Vec<Case> = vec![
        ("4 drives 0-3 (held, follower)", &c4, false, Wiring::swapped_drives(4, 0, 3), drives, (0, 3)),
        ("4 drives 1-2 (held, reeled)", &c4, false, Wiring::swapped_drives(4, 1, 2), drives, (1, 2)),
        ("4 drives 2-3 (reeled, follower)", &c4, false, Wiring::swapped_drives(4, 2, 3), either, (2, 3)),
        ("4 drives 0-1 (both held)", &c4, false, Wiring::swapped_drives(4, 0, 1), drives, (0, 1)),
        ("4 encoder 2 inverted (reeled)", &c4, false, Wiring::inverted_encoder(4, 2), inverted, (2, 2)),
        ("4 encoder 3 inverted (follower)", &c4, false, Wiring::inverted_encoder(4, 3), inverted, (3, 3)),
        ("4 encoder 0 inverted (held)", &c4, false, Wiring::inverted_encoder(4, 0), inverted, (0, 0)),
        ("4 cells 1-3 (held, follower)", &c4, false, Wiring::swapped_load_cells(4, 1, 3), cells, (1, 3)),
        ("4 cells 0-3 (held, follower)", &c4, false, Wiring::swapped_load_cells(4, 0, 3), cells, (0, 3)),
        ("4 cells 0-2 (held, reeled)", &c4, false, Wiring::swapped_load_cells(4, 0, 2), cells, (0, 2)),
        ("4 cells 2-3 (reeled, follower)", &c4, false, Wiring::swapped_load_cells(4, 2, 3), cells_either, (2, 3)),
        ("4 cells 0-1 (both held)", &c4, false, Wiring::swapped_load_cells(4, 0, 1), cells, (0, 1)),
        ("4 dynamic drives 0-3", &dynamic, true, Wiring::swapped_drives(4, 0, 3), drives, (0, 3)),
        ("4 dynamic encoder 2 inverted", &dynamic, true, Wiring::inverted_encoder(4, 2), inverted, (2, 2)),
        ("4 dynamic encoder 3 inverted", &dynamic, true, Wiring::inverted_encoder(4, 3), inverted, (3, 3)),
        ("4 dynamic cells 1-3", &dynamic, true, Wiring::swapped_load_cells(4, 1, 3), cells, (1, 3)),
        ("8 drives 2-5 (reeled, follower)", &c8, false, Wiring::swapped_drives(8, 2, 5), either, (2, 5)),
        ("8 drives 0-6 (held, follower)", &c8, false, Wiring::swapped_drives(8, 0, 6), either, (0, 6)),
        ("8 drives 4-7 (two followers)", &c8, false, Wiring::swapped_drives(8, 4, 7), drives, (4, 7)),
        ("8 encoder 5 inverted (follower)", &c8, false, Wiring::inverted_encoder(8, 5), inverted, (5, 5)),
        ("8 cells 1-6 (held, follower)", &c8, false, Wiring::swapped_load_cells(8, 1, 6), cells_either, (1, 6)),
    ];
    for (name, cfg, dyn_plant, wiring, faults, pair) in cases {
        let (mut first, mut later, mut other, mut none) = (0, 0, Vec::new(), 0);
        let seeds = seeds();
        for &seed in &seeds {
            let mut so = SimOptions { seed, wiring: wiring.clone(), ..Default::default() };
            if dyn_plant {
                so.physics.dynamics = Some(taut_sim::Dynamics::default());
            }
            let l = phases(cfg, &so);
            match l.snap.fault {
                Some((c @ Cause::Miswired { fault, cable, other: o, .. }, _)) if faults.contains(&fault) && (cable, o) == pair => {
                    if l.snap.phases_completed == 0 {
                        first += 1;
                    } else {
                        later += 1;
                    }
                    let _ = c;
                }
                Some((c, _)) => other.push(format!("seed {seed} phase {}: {c}", l.snap.phases_completed + 1)),
                None => none += 1,
            }
        }
        eprintln!(
            "RESULT wiring detection {name}: {} seeds: named in phase 1 {first}, named later {later}, other cause {}, not stopped {none}",
            seeds.len(),
            other.len()
        );
        for o in &other {
            eprintln!("    {o}");
        }
    }
}
