//! The CANopen master and virtual CiA 402 drives over real SocketCAN (`vcan0`), each on its own
//! socket: the drives on a thread, the master on the test thread.
//!
//! Runs for real inside the QEMU VM of `tests/vcan/run`; elsewhere the tests skip unless
//! `TAUT_VCAN_REQUIRED=1`. Timing under TCG emulation means nothing, so periods and timeouts
//! are generous and only behaviour is checked. The tests share one bus, so they run one at a
//! time (a lock), and each uses its own node ids.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::thread;
use std::time::{Duration, Instant};

use taut_driver::canopen::drive_set::{DriveSet, DriveSetError, Enabled, Operational};
use taut_driver::canopen::master::{Master, MasterConfig, NodeEvent, Phase};
use taut_driver::transport::candump::Replay;
use taut_driver::transport::socketcan::SocketCanTransport;
use taut_io::robot_io::Scaling;
use taut_proto::can::CanTransport;
use taut_proto::canopen::cia402::PowerState;
use taut_tests::vcan;
use taut_vdev::{spawn_rack, DriveParams, RackHandle, VirtualDrive};

/// The virtual drives' default drum in cable units: the drive set deals in counts, the robot I/O
/// layer converts (50 mm, 1:1, 2^17 counts per revolution).
const DRUM: Scaling = Scaling { drum_radius_m: 0.05, gear_ratio: 1.0, counts_per_rev: 131_072.0, rated_torque_nm: 1.0, sign: 1.0 };

fn positions_m<T: CanTransport>(set: &DriveSet<T, Enabled>) -> Vec<f64> {
    set.positions_counts().into_iter().map(|c| DRUM.counts_to_m(c)).collect()
}

fn counts(m: &[f64]) -> Vec<i32> {
    m.iter().map(|&x| DRUM.m_to_counts(x)).collect()
}

const IFACE: &str = "vcan0";
static BUS: Mutex<()> = Mutex::new(());

fn lock() -> MutexGuard<'static, ()> {
    BUS.lock().unwrap_or_else(|e| e.into_inner())
}

fn config(nodes: &[u8]) -> MasterConfig {
    let mut cfg = vcan::master_config(nodes);
    // The drives below start after the master's socket is open, so their boot-up is seen;
    // a broadcast reset would also reset drives of other processes on the bus.
    cfg.reset_on_start = false;
    // Consumer time 6 s in the drives: a TCG stall of the test thread (spawning cangen or
    // candump) must not look like a dead master.
    cfg.supervision.heartbeat = Duration::from_secs(2);
    cfg
}

/// Master socket first (so it sees the boot-ups), then the drives on their own socket.
fn setup(nodes: &[u8]) -> (DriveSet<SocketCanTransport, taut_driver::canopen::drive_set::Configuring>, RackHandle) {
    let master_port = SocketCanTransport::open(IFACE).expect("open vcan0 for the master");
    let drive_port = SocketCanTransport::open(IFACE).expect("open vcan0 for the drives");
    let set = DriveSet::new(master_port, config(nodes));
    let rack = spawn_rack(drive_port, nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    (set, rack)
}

fn up(set: DriveSet<SocketCanTransport, taut_driver::canopen::drive_set::Configuring>) -> DriveSet<SocketCanTransport, Operational> {
    set.bring_up().unwrap_or_else(|r| panic!("bring-up over vcan0: {}; {:#?}", r.error, r.set.statuses()))
}

fn enable(set: DriveSet<SocketCanTransport, Operational>) -> DriveSet<SocketCanTransport, Enabled> {
    set.enable(Duration::from_secs(30)).unwrap_or_else(|r| panic!("enable: {}; {:#?}", r.error, r.set.statuses()))
}

fn events<T: CanTransport, S>(set: &mut DriveSet<T, S>) -> Vec<NodeEvent> {
    std::iter::from_fn(|| set.poll_event()).collect()
}

#[test]
fn bring_up_configure_enable_and_move_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "bring_up_configure_enable_and_move_over_vcan") else { return };
    let _g = lock();
    let (set, rack) = setup(&[11, 12, 13]);
    let mut set = up(set);
    for s in set.statuses() {
        assert_eq!(s.identity.vendor, Some(0xACE));
        assert_eq!(s.name(), "taut virtual drive", "segmented SDO upload over SocketCAN");
    }
    set.run_for(Duration::from_millis(300)).unwrap();
    assert!(set.statuses().iter().all(|s| s.axis.tpdos > 0), "PDO cycle running");
    let mut set = enable(set);
    let start = positions_m(&set);
    let goal: Vec<f64> = start.iter().enumerate().map(|(i, p)| p + 0.01 * (i as f64 + 1.0)).collect();
    set.set_positions_counts(&counts(&goal)).unwrap();
    let t = Instant::now();
    loop {
        set.cycle().unwrap();
        let pos = positions_m(&set);
        if pos.iter().zip(&goal).all(|(p, g)| (p - g).abs() < 1e-4) {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "motion did not reach {goal:?}: at {pos:?}");
    }
    let set = set.disable();
    assert_eq!(set.master().counters().malformed, 0);
    rack.stop();
}

#[test]
fn emcy_and_fault_reset_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "emcy_and_fault_reset_over_vcan") else { return };
    let _g = lock();
    let (set, rack) = setup(&[21, 22]);
    let mut set = enable(up(set));
    rack.with_drive(22, |d| d.inject_fault(0x4310)).unwrap();
    let t = Instant::now();
    let err = loop {
        if let Err(e) = set.cycle() {
            break e;
        }
        assert!(t.elapsed() < Duration::from_secs(30), "fault not reported");
    };
    assert_eq!(err, DriveSetError::Fault { node: 22, code: 0x4310 });
    assert!(err.to_string().contains("excess temperature, drive"), "{err}");
    let ev = events(&mut set);
    assert!(ev.iter().any(|e| matches!(e, NodeEvent::Emergency { node: 22, emcy } if emcy.code == 0x4310)), "{ev:#?}");
    let mut set = set.disable();
    set.fault_reset(Duration::from_secs(30)).unwrap();
    let set = enable(set);
    assert!(set.statuses().iter().all(|s| s.axis.state == Some(PowerState::OperationEnabled)));
    rack.stop();
}

#[test]
fn heartbeat_loss_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "heartbeat_loss_over_vcan") else { return };
    let _g = lock();
    let (set, rack) = setup(&[31, 32]);
    let mut set = up(set);
    rack.with_drive(32, |d| d.set_heartbeat_off(true)).unwrap();
    let t = Instant::now();
    while set.statuses()[1].phase != Phase::Lost {
        set.run_for(Duration::from_millis(100)).unwrap();
        assert!(t.elapsed() < Duration::from_secs(60), "heartbeat loss not detected");
    }
    assert!(events(&mut set).contains(&NodeEvent::HeartbeatLost { node: 32 }));
    assert!(set.cycle().is_err(), "an operational set with a lost drive reports it");
    rack.with_drive(32, |d| d.set_heartbeat_off(false)).unwrap();
    let t = Instant::now();
    while set.statuses()[1].phase != Phase::Operational {
        set.run_for(Duration::from_millis(100)).unwrap();
        assert!(t.elapsed() < Duration::from_secs(60), "node 32 not back: {:?}", set.statuses()[1].phase);
    }
    assert!(events(&mut set).contains(&NodeEvent::HeartbeatRecovered { node: 32 }));
    rack.stop();
}

#[test]
fn node_rebooting_mid_run_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "node_rebooting_mid_run_over_vcan") else { return };
    let _g = lock();
    let (set, rack) = setup(&[41, 42]);
    let mut set = enable(up(set));
    set.cycle().unwrap();
    rack.with_drive(41, |d| d.power_cycle()).unwrap();
    let t = Instant::now();
    let err = loop {
        if let Err(e) = set.cycle() {
            break e;
        }
        if t.elapsed() > Duration::from_secs(30) {
            let ev = events(&mut set);
            let drive = rack.with_drive(41, |d| format!("nmt {:?}, state {:?}, {:?}", d.nmt_state(), d.state(), d.counters()));
            panic!(
                "reboot not noticed; counters {:?}; events {ev:#?}; statuses {:#?}; drive {drive:?}",
                set.master().counters(),
                set.statuses()
            );
        }
    };
    // Still being configured again (NotOperational), or already back but disabled (Disabled):
    // which one depends on how fast the drive answers its SDOs.
    assert!(matches!(err, DriveSetError::NotOperational { node: 41, .. } | DriveSetError::Disabled { node: 41, .. }), "{err}");
    let mut set = set.disable();
    let t = Instant::now();
    while !set.master().all_operational() {
        set.run_for(Duration::from_millis(100)).unwrap();
        assert!(t.elapsed() < Duration::from_secs(60), "node 41 not configured again");
    }
    assert_eq!(set.master().counters().reboots, 1);
    assert!(events(&mut set).contains(&NodeEvent::Rebooted { node: 41 }));
    let _set = enable(set);
    rack.stop();
}

/// Number of CAN receivers registered on `iface` (from /proc/net/can), to know when a spawned
/// candump has bound its socket.
fn can_receivers(iface: &str) -> Option<usize> {
    let mut n = 0;
    for entry in fs::read_dir("/proc/net/can").ok()? {
        let path = entry.ok()?.path();
        if !path.file_name()?.to_str()?.starts_with("rcvlist_") {
            continue;
        }
        let text = fs::read_to_string(&path).ok()?;
        n += text.lines().filter(|l| l.split_whitespace().next() == Some(iface) && !l.contains("no entry")).count();
    }
    Some(n)
}

fn wait_bound(iface: &str, before: Option<usize>, child: &mut Child) {
    let Some(before) = before else {
        thread::sleep(Duration::from_secs(3));
        return;
    };
    let t = Instant::now();
    while can_receivers(iface).unwrap_or(0) <= before {
        assert!(child.try_wait().unwrap().is_none(), "candump exited early");
        assert!(t.elapsed() < Duration::from_secs(30), "candump never bound to {iface}");
        thread::sleep(Duration::from_millis(20));
    }
}

fn wait_exit(child: &mut Child, timeout: Duration, what: &str) {
    let t = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            assert!(st.success(), "{what}: {st}");
            return;
        }
        if t.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} did not finish within {timeout:?}");
        }
        thread::sleep(Duration::from_millis(20));
    }
}

fn only_log(dir: &Path) -> PathBuf {
    let logs: Vec<PathBuf> =
        fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "log")).collect();
    assert_eq!(logs.len(), 1, "{logs:?}");
    logs.into_iter().next().unwrap()
}

#[test]
fn candump_log_of_a_session_parses_and_replays() {
    const TEST: &str = "candump_log_of_a_session_parses_and_replays";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let Some(candump) = vcan::tool_or_skip("candump", TEST) else { return };
    let _g = lock();
    let dir = tempfile::tempdir().unwrap();
    let before = can_receivers(IFACE);
    // -n: exit after that many frames, so the log is complete when candump exits.
    const FRAMES: usize = 300;
    let mut dump = Command::new(candump)
        .args(["-l", "-n", &FRAMES.to_string(), IFACE])
        .current_dir(dir.path())
        .stdin(Stdio::null())
        .spawn()
        .expect("spawn candump");
    wait_bound(IFACE, before, &mut dump);

    let (set, rack) = setup(&[51, 52]);
    let mut set = up(set);
    let live: Vec<_> = set.statuses().iter().map(|s| (s.node, s.identity)).collect();
    let t = Instant::now();
    while dump.try_wait().unwrap().is_none() {
        set.run_for(Duration::from_millis(50)).unwrap();
        assert!(t.elapsed() < Duration::from_secs(120), "candump did not see {FRAMES} frames");
    }
    wait_exit(&mut dump, Duration::from_secs(30), "candump");
    rack.stop();

    let log = only_log(dir.path());
    let text = fs::read_to_string(&log).unwrap();
    let mut replay = Replay::new(text.as_bytes()).only_interface(IFACE);
    let mut m = Master::new(config(&[51, 52]));
    let t0 = Instant::now();
    let mut first = None;
    let mut n = 0;
    while let Ok(Some(f)) = replay.try_recv() {
        let us = replay.last_t_us().unwrap();
        let t = t0 + Duration::from_micros(us - *first.get_or_insert(us));
        m.poll(t);
        while m.poll_tx().is_some() {}
        m.on_frame(&f, t);
        n += 1;
    }
    let s = replay.stats();
    assert_eq!(s.bad_lines, 0, "{:?}", s.first_bad);
    assert_eq!(n, FRAMES, "every logged frame parsed");
    assert!(text.contains(" 733#00") || text.contains(" 734#00"), "boot-up messages logged:\n{text}");
    // Fed the recorded traffic, a fresh master learns the same identities.
    let replayed: Vec<_> = m.statuses().map(|s| (s.node, s.identity)).collect();
    assert_eq!(replayed, live);
}

#[test]
fn cangen_flood_is_counted_while_the_master_keeps_working() {
    const TEST: &str = "cangen_flood_is_counted_while_the_master_keeps_working";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let Some(cangen) = vcan::tool_or_skip("cangen", TEST) else { return };
    let _g = lock();
    let (set, rack) = setup(&[61, 62]);
    let mut set = enable(up(set));
    let base = set.master().counters();
    // Random extended-id frames (no CANopen node may use them), and EMCY-id frames of node 127,
    // which is not configured. Random 11-bit ids would hit the configured nodes' ids now and
    // then, which no master can tell from the real thing.
    let mut floods = vec![
        Command::new(&cangen).args([IFACE, "-e", "-g", "1", "-n", "1000"]).spawn().expect("cangen"),
        Command::new(&cangen).args([IFACE, "-I", "0FF", "-L", "8", "-g", "2", "-n", "300"]).spawn().expect("cangen"),
    ];
    let mut goal = positions_m(&set);
    let t = Instant::now();
    while floods.iter_mut().any(|c| c.try_wait().unwrap().is_none()) {
        goal[0] += 1e-4;
        set.set_positions_counts(&counts(&goal)).expect("commands go on during the flood");
        set.cycle().expect("the drives stay enabled during the flood");
        assert!(t.elapsed() < Duration::from_secs(300), "cangen did not finish");
    }
    for mut c in floods {
        wait_exit(&mut c, Duration::from_secs(30), "cangen");
    }
    for _ in 0..20 {
        set.cycle().unwrap();
    }
    let c = set.master().counters();
    assert_eq!(c.ignored - base.ignored, 1000, "every extended frame ignored: {c:?}");
    assert_eq!(c.unknown_node - base.unknown_node, 300, "every frame of node 127 counted: {c:?}");
    assert_eq!(c.malformed, 0);
    assert!(set.master().all_enabled());
    assert!((positions_m(&set)[0] - goal[0]).abs() < 1e-3);
    rack.stop();
}
