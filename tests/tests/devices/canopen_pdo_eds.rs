//! PDO maps from the configuration, the strict CiA 301 mapping rules of the virtual drives, and
//! the EDS (CiA 306) check: on the in-process virtual bus, in simulated time.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use taut_config::RobotConfig;
use taut_driver::canopen::master::{Master, MasterConfig, NodeEvent, NodeFailure, Phase};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_io::robot_io::{Peripherals, RobotDevices};
use taut_proto::can::{CanTransport, Frame};
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::sdo::{AbortCode, Initiate, SdoRequest, SdoResponse};
use taut_proto::eds::Eds;
use taut_vdev::{rack_filters, DriveParams, DriveRack, VirtualDrive};

const MS: Duration = Duration::from_millis(1);

fn eds_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/eds")
}

/// Three drives; cable 0 has a map of its own with the velocity actual value in TPDO2.
fn robot_text(drive0_extra: &str) -> String {
    format!(
        "[robot]\nname = \"t\"\nmass_kg = 1.0\n[can]\ninterface = \"can0\"\n\
         [[cable]]\n[cable.drive]\nnode_id = 5\n{drive0_extra}\n\
         [[cable.drive.rpdo]]\nmap = [\"0x6040:0/16\", \"0x607A:0/32\"]\n\
         [[cable.drive.tpdo]]\nmap = [\"0x6041\", \"0x6064:0/32\"]\n\
         [[cable.drive.tpdo]]\nmap = [\"0x606C:0/32\", \"0x60F4:0/32\"]\n\
         [[cable]]\n[cable.drive]\nnode_id = 6\n\
         [[cable]]\n[cable.drive]\nnode_id = 7\npdo = \"with_mode\"\n"
    )
}

/// Changes a frame on its way from the drives to the master.
type Tamper = Box<dyn FnMut(&mut Frame)>;

struct Rig {
    t: Instant,
    master: Master,
    port: VirtualEndpoint,
    monitor: VirtualEndpoint,
    rack: DriveRack<VirtualEndpoint>,
    events: Vec<NodeEvent>,
    /// Frames the drives sent, by id.
    seen: Vec<Frame>,
    /// Changes SDO answers on their way to the master (fault injection).
    tamper: Option<Tamper>,
}

fn rig(cfg: MasterConfig) -> Rig {
    let bus = VirtualBus::new();
    let nodes: Vec<u8> = cfg.nodes.iter().map(|n| n.node_id).collect();
    let rack = DriveRack::with_nodes(bus.endpoint_with(1024, &rack_filters(&nodes)), &nodes);
    let port = bus.endpoint();
    let monitor = bus.endpoint_with(1 << 16, &[]);
    Rig { t: Instant::now(), master: Master::new(cfg), port, monitor, rack, events: vec![], seen: vec![], tamper: None }
}

impl Rig {
    fn step(&mut self) {
        self.t += MS;
        self.master.poll(self.t);
        while let Some(f) = self.master.poll_tx() {
            self.port.send(&f).unwrap();
        }
        self.rack.step(self.t);
        while let Ok(Some(mut f)) = self.port.try_recv() {
            if let Some(t) = &mut self.tamper {
                t(&mut f);
            }
            self.seen.push(f);
            self.master.on_frame(&f, self.t);
        }
        while let Some(e) = self.master.poll_event() {
            self.events.push(e);
        }
    }

    fn until(&mut self, max: Duration, what: &str, mut cond: impl FnMut(&mut Self) -> bool) {
        let start = self.t;
        while !cond(self) {
            assert!(self.t - start < max, "{what}: not within {max:?}; events: {:#?}", self.events);
            self.step();
        }
    }
}

#[test]
fn a_custom_map_with_velocity_is_written_read_back_and_runs_cycles() {
    let cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    let mcfg = MasterConfig::from_robot(&cfg).unwrap();
    assert_eq!(mcfg.nodes[0].pdos.len(), 3);
    let mut r = rig(mcfg);
    r.until(Duration::from_secs(3), "bring-up", |r| r.master.all_operational());
    let c = r.master.counters();
    // Unused PDOs 3 and 4 exist on the virtual drive: switching them off is answered, not aborted.
    assert_eq!((c.sdo_aborts, c.sdo_timeouts), (0, 0), "{c:?}");
    let mut op = r.master.operational().unwrap();
    for i in 0..3 {
        op.enable(i).unwrap();
    }
    r.until(Duration::from_secs(1), "enable", |r| r.master.all_enabled());
    let start = r.master.status(0).unwrap().axis.position;
    r.master.operational().unwrap().set_position_counts(0, start + 200_000).unwrap();
    let mut max_v = 0;
    for _ in 0..800 {
        r.step();
        max_v = max_v.max(r.master.status(0).unwrap().axis.velocity);
    }
    let s = r.master.status(0).unwrap();
    assert!((s.axis.position - (start + 200_000)).abs() < 10, "position {} after the move", s.axis.position);
    // The drive's speed limit is 400 000 counts/s: the velocity in TPDO2 reaches it mid-move.
    assert!((300_000..=400_000).contains(&max_v), "largest velocity actual {max_v} counts/s");
    assert_eq!(s.axis.state, Some(PowerState::OperationEnabled));
    // The frames on the bus follow the maps: node 5 sends TPDO1 of 6 bytes and TPDO2 of 8; the
    // compact drive 6 nothing on 0x286 (its factory TPDO2 was switched off); node 7 TPDO2 3 bytes.
    let dlc = |id: u16| r.seen.iter().filter(|f| f.id == u32::from(id)).map(|f| f.dlc).collect::<std::collections::BTreeSet<_>>();
    assert_eq!(dlc(0x185), [6].into());
    assert_eq!(dlc(0x285), [8].into());
    assert_eq!(dlc(0x186), [8].into());
    assert!(dlc(0x286).is_empty(), "factory TPDO2 of a compact drive still sending");
    assert_eq!(dlc(0x287), [3].into());
    // And the master sends node 5 an RPDO of 6 bytes (controlword, target position).
    let mut rpdo = vec![];
    while let Ok(Some(f)) = r.monitor.try_recv() {
        if f.id == 0x205 {
            rpdo.push(f.dlc);
        }
    }
    assert!(rpdo.len() > 100 && rpdo.iter().all(|&d| d == 6), "{} RPDOs to node 5", rpdo.len());
}

#[test]
fn a_drive_that_does_not_hold_the_mapping_fails_naming_the_object() {
    let cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    let mut r = rig(MasterConfig::from_robot(&cfg).unwrap());
    // The read-back of TPDO2's second entry on node 5 answers another object.
    r.tamper = Some(Box::new(|f: &mut Frame| {
        let d = f.data();
        if f.id == 0x585 && d.len() == 8 && d[0] == 0x43 && d[1..4] == [0x01, 0x1A, 0x02] {
            let mut b = [0u8; 8];
            b.copy_from_slice(d);
            b[4..8].copy_from_slice(&0x6077_0010u32.to_le_bytes());
            *f = Frame::new(0x585, &b);
        }
    }));
    r.until(Duration::from_secs(3), "failure", |r| matches!(r.master.status(0).unwrap().phase, Phase::Failed(_)));
    let want = NodeFailure::Readback { index: 0x1A01, sub: 2, expected: 0x60F4_0020, found: 0x6077_0010 };
    assert_eq!(r.master.status(0).unwrap().phase, Phase::Failed(want));
    assert!(want.to_string().contains("0x1A01sub2"), "{want}");
    assert!(r.seen.iter().all(|f| f.id != 0x185), "a node that failed is never started");
}

#[test]
fn a_tpdo_cob_id_read_back_with_bit_30_is_the_same_cob_id() {
    // CiA 301: bit 30 of a TPDO COB-ID says "no RTR"; drives that implement it report it set.
    let cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    let mut r = rig(MasterConfig::from_robot(&cfg).unwrap());
    r.tamper = Some(Box::new(|f: &mut Frame| {
        let d = f.data();
        if (0x585..=0x587).contains(&f.id) && d.len() == 8 && d[0] == 0x43 && d[2] == 0x18 && d[3] == 1 {
            let mut b = [0u8; 8];
            b.copy_from_slice(d);
            b[7] |= 0x40;
            *f = Frame::new(f.id as u16, &b);
        }
    }));
    r.until(Duration::from_secs(3), "bring-up", |r| r.master.all_operational());
}

fn sdo(d: &mut VirtualDrive, t: Instant, index: u16, sub: u8, v: u32, len: u8) -> SdoResponse {
    let req = SdoRequest::InitiateDownload { index, sub, kind: Initiate::Expedited { data: v.to_le_bytes(), len } };
    d.on_frame(&req.encode(d.node_id()), t);
    let mut last = None;
    while let Some(f) = d.poll_tx() {
        last = Some(f);
    }
    SdoResponse::decode(last.expect("an answer").data()).unwrap()
}

#[test]
fn the_virtual_drive_keeps_the_cia301_mapping_rules() {
    let t = Instant::now();
    let mut d = VirtualDrive::new(DriveParams::new(3));
    d.poll(t);
    let abort = |r: SdoResponse| match r {
        SdoResponse::Abort { code, .. } => Some(code.0),
        _ => None,
    };
    let ok = |r: SdoResponse| matches!(r, SdoResponse::DownloadInitiated { .. });
    // TPDO2 is valid from the factory: its COB-ID may not change, its mapping may not be written.
    assert_eq!(abort(sdo(&mut d, t, 0x1801, 1, 0x0000_0390, 4)), Some(0x0609_0030));
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 0, 0, 1)), Some(0x0601_0000));
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x6041_0010, 4)), Some(0x0601_0000));
    // Invalid first; an extended (bit 29) id is refused too.
    assert_eq!(abort(sdo(&mut d, t, 0x1801, 1, 0xA000_0283, 4)), Some(0x0609_0030));
    assert!(ok(sdo(&mut d, t, 0x1801, 1, 0x8000_0283, 4)));
    // Entries only with sub 0 = 0.
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x6041_0010, 4)), Some(0x0601_0000));
    assert!(ok(sdo(&mut d, t, 0x1A01, 0, 0, 1)));
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x5555_0010, 4)), Some(0x0602_0000), "no such object");
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x6041_0510, 4)), Some(0x0609_0011), "no such sub-index");
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x6040_0010, 4)), Some(0x0604_0041), "controlword is not a TPDO object");
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x6064_0010, 4)), Some(0x0604_0041), "wrong length");
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 1, 0x1017_0010, 4)), Some(0x0604_0041), "heartbeat time is not mappable");
    for (s, e) in [(1, 0x6064_0020u32), (2, 0x606C_0020), (3, 0x6041_0010)] {
        assert!(ok(sdo(&mut d, t, 0x1A01, s, e, 4)));
    }
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 0, 3, 1)), Some(0x0604_0042), "80 bits");
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 0, 9, 1)), Some(0x0604_0042), "9 entries");
    assert!(ok(sdo(&mut d, t, 0x1A01, 0, 2, 1)));
    // Count back to 0, entry 2 cleared: a count of 2 now names an empty entry.
    assert!(ok(sdo(&mut d, t, 0x1A01, 0, 0, 1)));
    assert!(ok(sdo(&mut d, t, 0x1A01, 2, 0, 4)));
    assert_eq!(abort(sdo(&mut d, t, 0x1A01, 0, 2, 1)), Some(0x0604_0043));
    assert!(ok(sdo(&mut d, t, 0x1A01, 0, 1, 1)));
    assert_eq!(abort(sdo(&mut d, t, 0x1801, 2, 245, 1)), Some(0x0609_0030), "reserved transmission type");
    assert!(ok(sdo(&mut d, t, 0x1801, 1, 0x0000_0283, 4)));
    // TPDO4 has no mapping: it may not be made valid.
    assert_eq!(abort(sdo(&mut d, t, 0x1803, 1, 0x0000_0483, 4)), Some(0x0609_0030));
    assert_eq!(AbortCode::UNSUPPORTED_ACCESS.0, 0x0601_0000);
}

#[test]
fn the_virtual_drive_packs_what_it_was_given() {
    // Through the master: TPDO2 of node 5 carries velocity and following error, and they decode
    // to what the drive holds.
    let cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    let mut r = rig(MasterConfig::from_robot(&cfg).unwrap());
    r.until(Duration::from_secs(3), "bring-up", |r| r.master.all_operational());
    r.until(Duration::from_millis(100), "a TPDO2", |r| r.seen.iter().any(|f| f.id == 0x285));
    let f = r.seen.iter().rev().find(|f| f.id == 0x285).unwrap();
    assert_eq!(f.dlc, 8);
    let sw = r.seen.iter().rev().find(|f| f.id == 0x185).unwrap();
    let pos = i32::from_le_bytes(sw.data()[2..6].try_into().unwrap());
    assert_eq!(pos, r.rack.drive(5).unwrap().position());
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_bad_pdo_table_names_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, &str, &str, &str); 6] = [
        ("[\"0x6040:0/16\", \"0x607A:0/32\"]", "[\"0x6041\", \"0x6064\", \"0x6077\", \"0x606C\"]", "tpdo[0].map", "96 bits"),
        ("[\"0x6040:0/16\", \"0x607A:0/32\"]", "[\"0x6041\", \"0x6041\", \"0x6064\"]", "tpdo[0].map[1]", "already mapped"),
        ("[\"0x6040:0/16\", \"0x607A:0/16\"]", "[\"0x6041\", \"0x6064\"]", "rpdo[0].map[1]", "32 bits long"),
        ("[\"0x6040:0/16\", \"0x607A:0/32\"]", "[\"0x6041\", \"0x2100\"]", "tpdo[0].map[1]", "length"),
        ("[\"0x6040:0/16\", \"0x607A:0/32\"]", "[\"0x6041\", \"0x6077\"]", "tpdo", "0x6064"),
        ("[\"0x6040:0/16\", \"0x6064:0/32\"]", "[\"0x6041\", \"0x6064\"]", "rpdo[0].map[1]", "map it in a tpdo"),
    ];
    for (rx, tx, key, what) in cases {
        let text = format!(
            "[robot]\nname = \"t\"\nmass_kg = 1.0\n[can]\ninterface = \"can0\"\n[[cable]]\n[cable.drive]\nnode_id = 1\n\
             [[cable.drive.rpdo]]\nmap = {rx}\n[[cable.drive.tpdo]]\nmap = {tx}\n[[cable]]\n[[cable]]\n"
        );
        let p = write(dir.path(), "robot.toml", &text);
        let e = RobotConfig::load(&p).unwrap_err();
        assert_eq!(e.file.as_deref(), Some(p.as_path()));
        assert_eq!(e.key.as_deref(), Some(format!("cable[0].drive.{key}").as_str()), "{e}");
        let want_line = if key.starts_with("rpdo") { 10 } else { 12 };
        assert_eq!(e.line, Some(want_line), "{e}");
        assert!(e.message.contains(what), "{e}");
        let shown = e.to_string();
        assert!(shown.starts_with(&format!("{}:{want_line}: key `cable[0].drive.{key}`", p.display())), "{shown}");
    }
    // A preset and tables together.
    let e = RobotConfig::from_toml_str(&robot_text("pdo = \"compact\"")).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("cable[0].drive.pdo"), "{e}");

    // A configuration built in code skips the file check: bring-up refuses it all the same,
    // naming the key, before a frame is sent.
    let mut cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    cfg.cables[0].drive.as_mut().unwrap().tpdo[1] = taut_proto::devices::PdoTable::new(["0x606C:0/32", "0x606C:0/32"]);
    let bus = VirtualBus::new();
    let e = RobotDevices::bring_up(&cfg, bus.endpoint(), Peripherals { loadcells: None, tracker: None, pose: None }).err().unwrap();
    assert_eq!(e.key(), "cable[0].drive.tpdo[1].map[1]", "{e}");
    assert_eq!(bus.frames_sent(), 0);
}

/// The robot with an `eds` for cable 0, written beside the configuration; bring-up on a virtual
/// bus; returns the error and the number of frames that reached the bus.
fn bring_up_with_eds(eds: &str) -> (Result<(), String>, usize) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(eds_dir().join(eds), dir.path().join("drive.eds")).unwrap();
    let mut text = robot_text("eds = \"drive.eds\"");
    text = text.replace("[can]\ninterface = \"can0\"\n", "[can]\ninterface = \"can0\"\nbringup_timeout_s = 3.0\n");
    let p = write(dir.path(), "robot.toml", &text);
    let cfg = RobotConfig::load(&p).unwrap();
    let bus = VirtualBus::new();
    let r = RobotDevices::bring_up(&cfg, bus.endpoint(), Peripherals { loadcells: None, tracker: None, pose: None });
    let frames = bus.frames_sent() as usize;
    (r.map(|_| ()).map_err(|e| e.to_string()), frames)
}

#[test]
fn a_bad_eds_names_object_file_and_line_and_nothing_reaches_the_bus() {
    for (file, line, words) in [
        ("velocity_not_mappable.eds", Some(982), "0x606Csub0: PDOMapping=0"),
        ("heartbeat_read_only.eds", Some(43), "0x1017sub0: AccessType=ro, but taut writes it"),
        ("no_position_actual.eds", None, "0x6064sub0: not in the EDS"),
        ("target_position_16bit.eds", Some(1003), "0x607Asub0: DataType=0x0003 is 16 bits"),
        ("malformed_section.eds", Some(996), "malformed section header"),
    ] {
        let (r, frames) = bring_up_with_eds(file);
        let e = r.unwrap_err();
        assert!(e.contains("cable[0].drive.eds"), "{file}: {e}");
        assert!(e.contains("drive.eds"), "{file}: {e}");
        if let Some(l) = line {
            assert!(e.contains(&format!("drive.eds:{l}")), "{file}: {e}");
        }
        assert!(e.contains(words), "{file}: {e}");
        assert_eq!(frames, 0, "{file}: frames reached the bus before the EDS check");
    }
}

#[test]
fn a_matching_eds_passes_and_bring_up_goes_on() {
    let eds = Eds::load(eds_dir().join("virtual_drive.eds")).unwrap();
    let cfg = RobotConfig::from_toml_str(&robot_text("")).unwrap();
    let m = MasterConfig::from_robot(&cfg).unwrap();
    for n in &m.nodes {
        let uses = taut_driver::canopen::eds_check::check(n, &eds).unwrap();
        assert!(uses.iter().any(|u| u.u.index == 0x1017), "the heartbeat write is checked");
    }
    let summary = taut_driver::canopen::eds_check::summary(
        5,
        "virtual_drive.eds",
        &taut_driver::canopen::eds_check::check(&m.nodes[0], &eds).unwrap(),
    );
    assert!(
        summary.contains("0x606Csub0") && summary.contains("Velocity actual value") && summary.contains("maps it into a TPDO"),
        "{summary}"
    );
    // With the EDS in the configuration, the bring-up runs to the end: no drive answers here,
    // so it fails on the bus, not on the EDS.
    let (r, frames) = bring_up_with_eds("virtual_drive.eds");
    let e = r.unwrap_err();
    assert!(!e.contains("drive.eds"), "{e}");
    assert!(frames > 0);
}

fn mutate(base: &[u8], edits: &[(usize, u8)]) -> Vec<u8> {
    let mut v = base.to_vec();
    for &(i, b) in edits {
        if !v.is_empty() {
            let k = i % v.len();
            v[k] = b;
        }
    }
    v
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Byte fuzz of the EDS parser (the nightly fuzz target `eds_parse` does the same for
    /// longer): any bytes give a parse or an error with a line inside the text, never a panic.
    #[test]
    fn eds_parser_takes_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        check_parse(&bytes);
    }

    #[test]
    fn eds_parser_takes_mutated_files(edits in proptest::collection::vec((any::<usize>(), prop_oneof![Just(b'['), Just(b']'), Just(b'='), Just(b'\n'), Just(b';'), any::<u8>()]), 1..16)) {
        let base = std::fs::read(eds_dir().join("virtual_drive.eds")).unwrap();
        check_parse(&mutate(&base, &edits));
    }
}

fn check_parse(bytes: &[u8]) {
    let lines = bytes.iter().filter(|&&b| b == b'\n').count() + 1;
    if let Err(e) = Eds::parse(bytes) {
        assert!(e.line.is_none_or(|l| (1..=lines).contains(&l)), "{e} of {lines} lines");
        assert!(!e.message.is_empty());
    }
}
