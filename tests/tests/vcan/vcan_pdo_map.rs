//! PDO maps from the configuration over real SocketCAN (`vcan0`), and the virtual drive's CiA 301
//! mapping rules answered over the bus. The map test: a drive with a map of its own
//! (velocity actual value 0x606C in TPDO2), checked against the virtual drive's EDS, and a
//! compact drive, brought up by the master on one socket against virtual drives on another,
//! with a third socket watching what crosses the bus.
//!
//! Runs inside the QEMU VM of `tests/vcan/run` (`TAUT_VCAN_TESTS=vcan_pdo_map`); elsewhere it
//! skips unless `TAUT_VCAN_REQUIRED=1`. Timing under TCG means nothing: generous timeouts, only
//! behaviour is checked.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use taut_config::RobotConfig;
use taut_driver::canopen::drive_set::{DriveSet, Enabled};
use taut_driver::canopen::master::MasterConfig;
use taut_driver::transport::socketcan::SocketCanTransport;
use taut_io::robot_io::Scaling;
use taut_proto::can::CanTransport;
use taut_proto::canopen::sdo::{Initiate, SdoRequest, SdoResponse};
use taut_tests::vcan;
use taut_vdev::{spawn_rack, DriveParams, VirtualDrive};

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
/// The virtual drive's EDS, carried in the binary: the VM has no source tree.
const EDS: &[u8] = include_bytes!("../../data/eds/virtual_drive.eds");

#[test]
fn custom_pdo_map_brings_up_and_runs_cycles_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "custom_pdo_map_brings_up_and_runs_cycles_over_vcan") else { return };
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("drive.eds"), EDS).unwrap();
    let text = "[robot]\nname = \"t\"\nmass_kg = 1.0\n\
        [can]\ninterface = \"vcan0\"\ncycle_s = 0.01\nsdo_timeout_s = 2.0\nbringup_timeout_s = 60.0\nreset_on_start = false\n\
        [[cable]]\n[cable.drive]\nnode_id = 41\neds = \"drive.eds\"\nheartbeat_ms = 250\nheartbeat_timeout_ms = 3000\n\
        [[cable.drive.rpdo]]\nmap = [\"0x6040:0/16\", \"0x607A:0/32\"]\n\
        [[cable.drive.tpdo]]\nmap = [\"0x6041:0/16\", \"0x6064:0/32\"]\n\
        [[cable.drive.tpdo]]\nmap = [\"0x606C:0/32\"]\n\
        [[cable]]\n[cable.drive]\nnode_id = 42\neds = \"drive.eds\"\nheartbeat_ms = 250\nheartbeat_timeout_ms = 3000\n\
        [[cable]]\n";
    let path = dir.path().join("robot.toml");
    std::fs::write(&path, text).unwrap();
    let cfg = RobotConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let mcfg = MasterConfig::from_robot(&cfg).unwrap_or_else(|e| panic!("{e}"));

    // Master socket and watcher first (they see the boot-ups), then the drives.
    let master_port = SocketCanTransport::open(IFACE).expect("open vcan0 for the master");
    let mut watch = SocketCanTransport::open(IFACE).expect("open vcan0 to watch");
    // The watcher drains its socket all along (a socket's receive buffer holds a few hundred
    // frames; bring-up alone is about that many).
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let watcher = std::thread::spawn(move || {
        let mut dlcs: BTreeMap<u32, BTreeSet<u8>> = BTreeMap::new();
        // Relaxed: the flag carries no data; join() synchronises.
        while !stop2.load(Ordering::Relaxed) {
            if let Ok(Some(f)) = watch.recv_deadline(Instant::now() + Duration::from_millis(50)) {
                dlcs.entry(f.id).or_default().insert(f.dlc);
            }
        }
        while let Ok(Some(f)) = watch.try_recv() {
            dlcs.entry(f.id).or_default().insert(f.dlc);
        }
        dlcs
    });
    let drive_port = SocketCanTransport::open(IFACE).expect("open vcan0 for the drives");
    let set = DriveSet::new(master_port, mcfg);
    let rack = spawn_rack(drive_port, [41, 42].iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    let set = set.bring_up().unwrap_or_else(|r| panic!("bring-up over vcan0: {}; {:#?}", r.error, r.set.statuses()));
    let mut set = set.enable(Duration::from_secs(30)).unwrap_or_else(|r| panic!("enable: {}; {:#?}", r.error, r.set.statuses()));
    let start = positions_m(&set);
    let goal = vec![start[0] + 0.02, start[1]];
    set.set_positions_counts(&counts(&goal)).unwrap();
    let t = Instant::now();
    let mut max_v = 0;
    loop {
        set.cycle().unwrap();
        max_v = max_v.max(set.master().status(0).unwrap().axis.velocity.abs());
        if (positions_m(&set)[0] - goal[0]).abs() < 1e-4 {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "motion did not reach {goal:?}: at {:?}", positions_m(&set));
    }
    assert!(max_v > 0, "velocity actual value never arrived in TPDO2 of node 41");
    let c = set.master().counters();
    assert_eq!((c.malformed, c.pdo_length, c.sdo_aborts), (0, 0, 0), "{c:?}");
    let _set = set.disable();
    rack.stop();

    // What crossed the bus: node 41 TPDO1 6 bytes, TPDO2 4 bytes, RPDO1 6 bytes; node 42 the
    // compact preset (8-byte PDO1s) and nothing on its factory TPDO2 0x2AA once configured.
    stop.store(true, Ordering::Relaxed);
    let dlcs = watcher.join().unwrap();
    let get = |id: u32| dlcs.get(&id).cloned().unwrap_or_default();
    assert_eq!(get(0x1A9), [6].into());
    assert_eq!(get(0x2A9), [4].into());
    assert_eq!(get(0x229), [6].into());
    assert_eq!(get(0x1AA), [8].into());
    assert_eq!(get(0x22A), [8].into());
    assert!(get(0x2AA).is_empty(), "node 42's factory TPDO2 still sending");
}

/// One expedited SDO download over the socket; the drive's answer.
fn sdo_write(port: &mut SocketCanTransport, node: u8, index: u16, sub: u8, v: u32, len: u8) -> SdoResponse {
    let req = SdoRequest::InitiateDownload { index, sub, kind: Initiate::Expedited { data: v.to_le_bytes(), len } };
    port.send(&req.encode(node)).unwrap();
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        match port.recv_deadline(end) {
            Ok(Some(f)) if f.id == 0x580 + u32::from(node) => return SdoResponse::decode(f.data()).unwrap(),
            Ok(Some(_)) => {}
            other => panic!("no SDO answer from node {node} for 0x{index:04X}sub{sub}: {other:?}"),
        }
    }
}

#[test]
fn virtual_drive_mapping_rules_over_vcan() {
    let Some(_) = vcan::iface_or_skip(IFACE, "virtual_drive_mapping_rules_over_vcan") else { return };
    let mut port = SocketCanTransport::open(IFACE).expect("open vcan0 for the SDO client");
    let drive_port = SocketCanTransport::open(IFACE).expect("open vcan0 for the drive");
    let rack = spawn_rack(drive_port, vec![VirtualDrive::new(DriveParams::new(45))]);
    let abort = |r: SdoResponse| match r {
        SdoResponse::Abort { code, .. } => Some(code.0),
        _ => None,
    };
    let n = 45;
    // Factory TPDO2 is valid: no new COB-ID, no mapping change.
    assert_eq!(abort(sdo_write(&mut port, n, 0x1801, 1, 0x0000_03AD, 4)), Some(0x0609_0030));
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 0, 0, 1)), Some(0x0601_0000));
    assert_eq!(abort(sdo_write(&mut port, n, 0x1801, 1, 0x8000_02AD, 4)), None);
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 1, 0x606C_0020, 4)), Some(0x0601_0000), "entry while sub 0 != 0");
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 0, 0, 1)), None);
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 1, 0x4321_0020, 4)), Some(0x0602_0000));
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 1, 0x6040_0010, 4)), Some(0x0604_0041));
    for (s, e) in [(1, 0x6064_0020u32), (2, 0x606C_0020), (3, 0x6041_0010)] {
        assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, s, e, 4)), None);
    }
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 0, 3, 1)), Some(0x0604_0042));
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 0, 5, 1)), Some(0x0604_0043), "entries 4 and 5 are empty");
    assert_eq!(abort(sdo_write(&mut port, n, 0x1A01, 0, 2, 1)), None);
    assert_eq!(abort(sdo_write(&mut port, n, 0x1801, 1, 0x0000_02AD, 4)), None);
    rack.stop();
}
