//! Drives as they are in the field, over real SocketCAN (`vcan0`): drives heartbeating before
//! taut starts, left enabled or in fault by a previous run, slow and duplicated SDO answers,
//! a lost boot-up, and taut killed (SIGKILL) mid-run.
//!
//! Runs for real inside the QEMU VM of `tests/vcan/run`; elsewhere the tests skip unless
//! `TAUT_VCAN_REQUIRED=1`. Timing under TCG emulation means nothing: timeouts are generous and
//! the tests check what happens, not how fast. The tests share one bus, so they run one at a
//! time (a lock), each with its own node ids. These tests send NMT reset communication to all
//! nodes, as taut does at start: only this file's drives are on the bus while they run.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::thread;
use std::time::{Duration, Instant};

use taut_driver::canopen::drive_set::{Configuring, DriveSet, DriveSetError, Operational};
use taut_driver::canopen::master::{MasterConfig, NodeEvent};
use taut_driver::transport::socketcan::SocketCanTransport;
use taut_proto::can::CanTransport;
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::nmt::NmtState;
use taut_tests::vcan;
use taut_vdev::{spawn_rack, DriveParams, RackHandle, VirtualDrive};

const IFACE: &str = "vcan0";
/// Set in the child process that plays taut in [`drives_stop_when_taut_is_killed_over_vcan`].
const CHILD_ENV: &str = "TAUT_FIELD_MASTER_NODES";
static BUS: Mutex<()> = Mutex::new(());
/// What the child prints once the drives are enabled.
const ENABLED: &str = "TAUT-FIELD-MASTER-ENABLED";

fn lock() -> MutexGuard<'static, ()> {
    BUS.lock().unwrap_or_else(|e| e.into_inner())
}

fn config(nodes: &[u8]) -> MasterConfig {
    let mut cfg = vcan::master_config(nodes);
    cfg.boot_wait = Duration::from_secs(2);
    // Consumer time 3 s: a TCG stall of the test thread must not look like a dead master.
    cfg.supervision.heartbeat = Duration::from_secs(1);
    cfg.reset_on_start = true;
    cfg
}

/// Drives heartbeating at 100 ms from power-on, each with `f` applied to its parameters.
fn drives(nodes: &[u8], f: impl Fn(&mut DriveParams)) -> Vec<VirtualDrive> {
    nodes
        .iter()
        .map(|&n| {
            let mut p = DriveParams::new(n);
            p.stored_heartbeat_ms = 100;
            f(&mut p);
            VirtualDrive::new(p)
        })
        .collect()
}

/// The drives are powered first and heartbeat on the bus; taut's socket opens later and taut
/// starts 150 ms after that (frames queue in its socket meanwhile).
fn field(
    nodes: &[u8],
    drives: Vec<VirtualDrive>,
    prepare: impl FnOnce(&RackHandle),
) -> (DriveSet<SocketCanTransport, Configuring>, RackHandle) {
    let rack = spawn_rack(SocketCanTransport::open(IFACE).expect("open vcan0 for the drives"), drives);
    thread::sleep(Duration::from_millis(500));
    prepare(&rack);
    let port = SocketCanTransport::open(IFACE).expect("open vcan0 for taut");
    thread::sleep(Duration::from_millis(150));
    (DriveSet::new(port, config(nodes)), rack)
}

fn up(set: DriveSet<SocketCanTransport, Configuring>) -> DriveSet<SocketCanTransport, Operational> {
    set.bring_up().unwrap_or_else(|r| panic!("bring-up over vcan0: {}; {:?}; {:#?}", r.error, r.set.master().counters(), r.set.statuses()))
}

fn events<T: CanTransport, S>(set: &mut DriveSet<T, S>) -> Vec<NodeEvent> {
    std::iter::from_fn(|| set.poll_event()).collect()
}

#[test]
fn eight_heartbeating_drives_come_up_without_sdo_aborts_or_retries_over_vcan() {
    const TEST: &str = "eight_heartbeating_drives_come_up_without_sdo_aborts_or_retries_over_vcan";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let _g = lock();
    let nodes = [71, 72, 73, 74, 75, 76, 77, 78];
    // NMT resets take effect 20 ms late and SDO answers leave 5 ms late, as in slow firmware.
    let slow = |p: &mut DriveParams| {
        p.reset_latency = Duration::from_millis(20);
        p.sdo_delay = Duration::from_millis(5);
    };
    let (set, rack) = field(&nodes, drives(&nodes, slow), |_| {});
    let mut set = up(set);
    set.run_for(Duration::from_millis(500)).unwrap();
    let c = set.master().counters();
    println!("{TEST}: {c:?}");
    assert_eq!((c.sdo_aborts, c.sdo_timeouts, c.sdo_retries, c.boot_ups_missing), (0, 0, 0, 0), "{c:?}");
    let ev = events(&mut set);
    for n in nodes {
        assert_eq!(ev.iter().filter(|e| **e == NodeEvent::Configured { node: n }).count(), 1, "node {n}: {ev:#?}");
    }
    rack.with(|ds| ds.iter().for_each(|d| assert_eq!(d.counters().sdo_aborts, 0, "node {}", d.node_id())));
    rack.stop();
}

#[test]
fn a_drive_left_enabled_is_switched_off_and_a_fault_waits_for_the_operator_over_vcan() {
    const TEST: &str = "a_drive_left_enabled_is_switched_off_and_a_fault_waits_for_the_operator_over_vcan";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let _g = lock();
    let nodes = [81, 82, 83];
    let (set, rack) = field(&nodes, drives(&nodes, |_| {}), |rack| {
        rack.with_drive(82, |d| {
            d.set_actual(50_000, 0);
            d.left_by_previous_run(PowerState::OperationEnabled, 0);
        });
        rack.with_drive(83, |d| d.left_by_previous_run(PowerState::Fault, 0x2310));
    });
    let mut set = up(set);
    set.run_for(Duration::from_millis(500)).unwrap();
    let ev = events(&mut set);
    assert!(ev.contains(&NodeEvent::FoundPowered { node: 82, state: PowerState::OperationEnabled }), "{ev:#?}");
    assert_eq!(rack.with_drive(82, |d| (d.state(), d.position())), Some((PowerState::ReadyToSwitchOn, 50_000)));
    assert_eq!(rack.with_drive(83, |d| d.state()), Some(PowerState::Fault));
    // Enabling is refused while a drive is in fault: nothing resets it but the operator.
    let refused = set.enable(Duration::from_secs(20)).err().expect("enable refused with a drive in fault");
    assert!(matches!(refused.error, DriveSetError::Fault { node: 83, .. } | DriveSetError::Timeout { node: 83, .. }), "{}", refused.error);
    let mut set = refused.set;
    assert_eq!(rack.with_drive(83, |d| d.state()), Some(PowerState::Fault));
    set.fault_reset(Duration::from_secs(30)).unwrap();
    let set = set.enable(Duration::from_secs(30)).unwrap_or_else(|r| panic!("enable: {}", r.error));
    assert_eq!(rack.with_drive(82, |d| (d.state(), d.position())), Some((PowerState::OperationEnabled, 50_000)), "enabled where it stood");
    let _ = set.disable();
    rack.stop();
}

#[test]
fn slow_and_duplicated_sdo_answers_over_vcan() {
    const TEST: &str = "slow_and_duplicated_sdo_answers_over_vcan";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let _g = lock();
    let nodes = [91, 92, 93];
    let (set, rack) = field(
        &nodes,
        drives(&nodes, |p| {
            p.sdo_delay = Duration::from_millis(30);
            p.sdo_duplicate_every = 1;
        }),
        |_| {},
    );
    let mut set = up(set);
    set.run_for(Duration::from_millis(500)).unwrap();
    let c = set.master().counters();
    let dups: u64 = rack.with(|ds| ds.iter().map(|d| d.counters().sdo_duplicates).sum());
    println!("{TEST}: {dups} duplicates; {c:?}");
    assert!(dups > 20);
    assert_eq!((c.sdo_aborts, c.sdo_retries), (0, 0), "{c:?}");
    assert_eq!(c.sdo_discarded + c.unexpected_sdo, dups, "every duplicate dropped and counted: {c:?}");
    assert!(set.statuses().iter().all(|s| s.name() == "taut virtual drive"));
    rack.stop();
}

#[test]
fn a_lost_boot_up_over_vcan() {
    const TEST: &str = "a_lost_boot_up_over_vcan";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    let _g = lock();
    let nodes = [101, 102];
    let (set, rack) = field(&nodes, drives(&nodes, |_| {}), |rack| {
        rack.with_drive(102, |d| d.lose_boot_ups(1));
    });
    let mut set = up(set);
    let c = set.master().counters();
    assert_eq!(c.boot_ups_missing, 1, "{c:?}");
    assert_eq!((c.sdo_aborts, c.sdo_retries), (0, 0), "{c:?}");
    assert_eq!(rack.with_drive(102, |d| d.counters().boots_lost), Some(1));
    let ev = events(&mut set);
    assert_eq!(ev.iter().filter(|e| **e == NodeEvent::Configured { node: 102 }).count(), 1, "{ev:#?}");
    rack.stop();
}

/// The taut side of [`drives_stop_when_taut_is_killed_over_vcan`], run in a child process (this
/// test binary again, with [`CHILD_ENV`] set): bring the drives up, enable them, say so, and
/// cycle until killed. Without the variable it does nothing.
#[test]
fn field_master_child() {
    let Ok(nodes) = std::env::var(CHILD_ENV) else { return };
    let nodes: Vec<u8> = nodes.split(',').map(|n| n.parse().expect("node id")).collect();
    let port = SocketCanTransport::open(IFACE).expect("child: open vcan0");
    let mut cfg = config(&nodes);
    // The child is killed while it runs: a short consumer time, so the parent waits little.
    cfg.supervision.heartbeat = Duration::from_millis(500);
    let set = up(DriveSet::new(port, cfg));
    let mut set = set.enable(Duration::from_secs(60)).unwrap_or_else(|r| panic!("child: enable: {}", r.error));
    // On its own line: the harness has already printed "test field_master_child ... ".
    println!("\n{ENABLED}");
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(300) {
        set.cycle().expect("child: cycle");
    }
    panic!("child: not killed within 300 s");
}

#[test]
fn drives_stop_when_taut_is_killed_over_vcan() {
    const TEST: &str = "drives_stop_when_taut_is_killed_over_vcan";
    let Some(_) = vcan::iface_or_skip(IFACE, TEST) else { return };
    if std::env::var(CHILD_ENV).is_ok() {
        return;
    }
    let _g = lock();
    let nodes = [111u8, 112, 113];
    let rack = spawn_rack(SocketCanTransport::open(IFACE).expect("open vcan0 for the drives"), drives(&nodes, |_| {}));
    thread::sleep(Duration::from_millis(300));
    let list = nodes.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(",");
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["vcan_field::field_master_child", "--exact", "--nocapture", "--test-threads=1"])
        .env(CHILD_ENV, &list)
        .stdout(Stdio::piped())
        .stdin(Stdio::null())
        .spawn()
        .expect("spawn the taut child");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    loop {
        line.clear();
        let n = out.read_line(&mut line).unwrap();
        assert!(n > 0, "the taut child exited before enabling the drives: {:?}", child.wait());
        if line.trim() == ENABLED {
            break;
        }
    }
    // Running: the drives hear taut and stay enabled.
    thread::sleep(Duration::from_secs(2));
    rack.with(|ds| {
        for d in ds.iter() {
            assert_eq!(d.state(), PowerState::OperationEnabled, "node {} while taut runs", d.node_id());
            assert_eq!(d.heartbeat_consumer() & 0xFFFF, 1500, "0x1016: 3 x 500 ms");
            assert_eq!(d.abort_connection_option(), 3);
        }
    });
    let held: Vec<i32> = rack.with(|ds| ds.iter().map(|d| d.position()).collect());
    child.kill().expect("SIGKILL the taut child");
    let killed = Instant::now();
    let _ = child.wait();
    while rack.with(|ds| ds.iter().any(|d| d.state() == PowerState::OperationEnabled)) {
        assert!(killed.elapsed() < Duration::from_secs(60), "drives still enabled 60 s after taut was killed");
        thread::sleep(Duration::from_millis(10));
    }
    println!("{TEST}: drives left operation enabled {:?} after SIGKILL (consumer time 1.5 s; TCG timing)", killed.elapsed());
    rack.with(|ds| {
        for (d, p) in ds.iter().zip(&held) {
            assert_eq!(d.state(), PowerState::QuickStopActive, "node {}", d.node_id());
            assert_eq!(d.counters().consumer_timeouts, 1, "node {}", d.node_id());
            assert_eq!(d.nmt_state(), NmtState::PreOperational);
            assert_eq!(d.position(), *p, "node {} held where it stood", d.node_id());
        }
    });
    rack.stop();
}
