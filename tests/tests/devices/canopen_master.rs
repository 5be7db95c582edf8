//! The CANopen master against virtual CiA 402 drives on the in-process virtual bus, in
//! simulated time: every run sees the same frames in the same order.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use taut_driver::canopen::master::{CommandError, Master, MasterConfig, NodeConfig, NodeEvent, NodeFailure, Phase, Problem};
use taut_driver::transport::candump::{self, Recorder, Replay};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_io::robot_io::Scaling;
use taut_proto::can::{CanTransport, Frame};
use taut_proto::canopen::cia402::{Mode, PowerState};
use taut_proto::canopen::pdo::PdoLayout;
use taut_vdev::{rack_filters, DriveRack};

/// The virtual drives' default drum in cable units (the master deals in counts and ‰; the robot
/// I/O layer converts): 50 mm, 1:1, 2^17 counts per revolution, 1 N·m rated torque.
const DRUM: Scaling = Scaling { drum_radius_m: 0.05, gear_ratio: 1.0, counts_per_rev: 131_072.0, rated_torque_nm: 1.0, sign: 1.0 };

const NODES: [u8; 4] = [1, 2, 3, 4];
const MS: Duration = Duration::from_millis(1);

struct Rig<T: CanTransport> {
    bus: VirtualBus,
    t0: Instant,
    t: Instant,
    master: Master,
    port: T,
    rack: DriveRack<VirtualEndpoint>,
    events: Vec<NodeEvent>,
}

fn config(nodes: &[u8]) -> MasterConfig {
    MasterConfig::new(nodes.iter().enumerate().map(|(i, &n)| NodeConfig::new(n, i)).collect())
}

fn rig(cfg: MasterConfig) -> Rig<VirtualEndpoint> {
    let bus = VirtualBus::new();
    let port = bus.endpoint();
    let nodes: Vec<u8> = cfg.nodes.iter().map(|n| n.node_id).collect();
    let rack = DriveRack::with_nodes(bus.endpoint_with(1024, &rack_filters(&nodes)), &nodes);
    let t0 = Instant::now();
    Rig { bus, t0, t: t0, master: Master::new(cfg), port, rack, events: Vec::new() }
}

impl<T: CanTransport> Rig<T> {
    /// One millisecond: master timers and TX, drives, master RX.
    fn step(&mut self) {
        self.t += MS;
        self.master.poll(self.t);
        while let Some(f) = self.master.poll_tx() {
            self.port.send(&f).unwrap();
        }
        self.rack.step(self.t);
        while let Ok(Some(f)) = self.port.try_recv() {
            self.master.on_frame(&f, self.t);
        }
        while let Some(e) = self.master.poll_event() {
            self.events.push(e);
        }
    }

    fn run(&mut self, d: Duration) {
        let end = self.t + d;
        while self.t < end {
            self.step();
        }
    }

    /// Steps until `cond`, at most `max`; returns the time it took.
    fn until(&mut self, max: Duration, what: &str, mut cond: impl FnMut(&mut Self) -> bool) -> Duration {
        let start = self.t;
        while !cond(self) {
            assert!(self.t - start < max, "{what}: not within {max:?}; events: {:#?}", self.events);
            self.step();
        }
        self.t - start
    }

    fn bring_up(&mut self) {
        self.until(Duration::from_secs(2), "bring-up", |r| r.master.all_operational());
    }

    fn enable_all(&mut self) {
        let n = self.master.len();
        let mut op = self.master.operational().expect("operational");
        for i in 0..n {
            op.enable(i).unwrap();
        }
        self.until(Duration::from_secs(1), "enable", |r| r.master.all_enabled());
    }

    fn count(&self, f: impl Fn(&NodeEvent) -> bool) -> usize {
        self.events.iter().filter(|e| f(e)).count()
    }
}

#[test]
fn bring_up_identifies_configures_and_starts_every_drive() {
    let mut r = rig(config(&NODES));
    let took = r.until(Duration::from_secs(2), "bring-up", |r| r.master.all_operational());
    assert!(took < Duration::from_millis(500), "bring-up took {took:?} of simulated time");
    for (i, s) in r.master.statuses().enumerate() {
        assert_eq!(s.node, NODES[i]);
        assert_eq!(s.phase, Phase::Operational);
        assert_eq!(s.identity.device_type, Some(0x0002_0192));
        assert_eq!(s.identity.vendor, Some(0xACE));
        assert_eq!(s.identity.serial, Some(1000 + u32::from(NODES[i])));
        // 0x1008 is 18 bytes: a segmented upload.
        assert_eq!(s.name(), "taut virtual drive");
        assert_eq!(s.boots, 1);
    }
    for n in NODES {
        for want in [NodeEvent::Booted { node: n }, NodeEvent::Configured { node: n }, NodeEvent::Operational { node: n }] {
            assert_eq!(r.count(|e| *e == want), 1, "{want:?}");
        }
    }
    // The drives run what the master configured: 0x1017, PDO mapping, mode.
    r.run(Duration::from_millis(50));
    for s in r.master.statuses() {
        assert!(s.axis.tpdos > 10, "TPDOs flow every SYNC");
        assert_eq!(s.axis.state, Some(PowerState::ReadyToSwitchOn), "held at ready to switch on until enabled");
    }
    for d in r.rack.drives() {
        assert_eq!(d.target().mode, Mode::CyclicPosition);
        assert!(d.counters().syncs > 10);
    }
    let c = r.master.counters();
    assert_eq!((c.malformed, c.unknown_node, c.sdo_aborts, c.sdo_timeouts), (0, 0, 0, 0), "{c:?}");
}

#[test]
fn csp_motion_moves_the_cable_by_the_commanded_metres() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    // Motion commands need operation enabled: refused before.
    assert_eq!(r.master.operational().unwrap().set_position_counts(0, DRUM.m_to_counts(0.1)), Err(CommandError::NotEnabled { node: 1 }));
    r.enable_all();
    let start: Vec<f64> = r.master.statuses().map(|s| DRUM.counts_to_m(s.axis.position)).collect();
    {
        let mut op = r.master.operational().unwrap();
        op.set_position_counts(0, DRUM.m_to_counts(start[0] + 0.10)).unwrap();
        op.set_position_counts(1, DRUM.m_to_counts(start[1] - 0.05)).unwrap();
        assert_eq!(op.set_torque_permille(2, DRUM.n_to_permille(10.0)), Err(CommandError::WrongMode { node: 3 }));
    }
    r.run(Duration::from_millis(500));
    let s0 = r.master.status(0).unwrap();
    let s1 = r.master.status(1).unwrap();
    let s2 = r.master.status(2).unwrap();
    let count_m = DRUM.metres_per_count();
    assert!(
        (DRUM.counts_to_m(s0.axis.position) - (start[0] + 0.10)).abs() <= 1.5 * count_m,
        "{} vs {}",
        DRUM.counts_to_m(s0.axis.position),
        start[0] + 0.1
    );
    assert!((DRUM.counts_to_m(s1.axis.position) - (start[1] - 0.05)).abs() <= 1.5 * count_m);
    assert!((DRUM.counts_to_m(s2.axis.position) - start[2]).abs() <= 1.5 * count_m, "an enabled drive holds where it stood");
    assert_eq!(s0.axis.state, Some(PowerState::OperationEnabled));
}

#[test]
fn cst_drive_follows_the_commanded_tension() {
    let mut cfg = config(&[5, 6, 7]);
    cfg.nodes[2].mode = Mode::CyclicTorque;
    cfg.nodes[2].pdos = PdoLayout::WithMode.pdos();
    let scaling = DRUM;
    let mut r = rig(cfg);
    r.bring_up();
    r.enable_all();
    r.master.operational().unwrap().set_torque_permille(2, DRUM.n_to_permille(20.0)).unwrap();
    // The maximum tension (500 N) limits the command.
    r.run(Duration::from_millis(20));
    let s = r.master.status(2).unwrap();
    assert_eq!(s.axis.torque, scaling.n_to_permille(20.0));
    assert!((DRUM.permille_to_n(s.axis.torque) - 20.0).abs() < 0.3, "{}", DRUM.permille_to_n(s.axis.torque));
    assert_eq!(s.axis.mode_display, Some(Mode::CyclicTorque), "mode travels in TPDO2 with this layout");
    assert_eq!(r.rack.drive(7).unwrap().target().mode, Mode::CyclicTorque);
}

#[test]
fn emcy_is_decoded_and_a_fault_is_reset_on_request_only() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.enable_all();
    r.rack.drive(2).unwrap().inject_fault(0x2310);
    r.until(Duration::from_millis(100), "fault seen", |r| r.master.status(1).unwrap().axis.state == Some(PowerState::Fault));
    let emcy = r.events.iter().find_map(|e| match e {
        NodeEvent::Emergency { node: 2, emcy } => Some(*emcy),
        _ => None,
    });
    let emcy = emcy.expect("EMCY event");
    assert_eq!(emcy.code, 0x2310);
    assert_eq!(emcy.name(), "continuous over-current (motor side)");
    assert!(format!("{}", NodeEvent::Emergency { node: 2, emcy }).contains("over-current"));
    assert_eq!(r.master.counters().emergencies, 1);
    // No automatic reset, and no motion commands to the faulted drive.
    r.run(Duration::from_millis(100));
    assert_eq!(r.master.status(1).unwrap().axis.state, Some(PowerState::Fault));
    assert_eq!(r.master.operational().unwrap().set_position_counts(1, DRUM.m_to_counts(0.0)), Err(CommandError::NotEnabled { node: 2 }));
    // The other drives stay enabled.
    assert_eq!(r.master.status(0).unwrap().axis.state, Some(PowerState::OperationEnabled));

    r.master.operational().unwrap().fault_reset(1).unwrap();
    r.until(Duration::from_millis(100), "fault reset", |r| r.master.status(1).unwrap().axis.state != Some(PowerState::Fault));
    assert!(r.events.iter().any(|e| matches!(e, NodeEvent::Emergency { node: 2, emcy } if emcy.is_reset())));
    r.enable_all();
}

#[test]
fn heartbeat_loss_is_detected_and_the_node_is_configured_again_when_it_returns() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.rack.drive(3).unwrap().set_heartbeat_off(true);
    let took = r.until(Duration::from_secs(1), "heartbeat lost", |r| r.master.status(2).unwrap().phase == Phase::Lost);
    // 100 ms period, 300 ms timeout.
    assert!(took > Duration::from_millis(250) && took < Duration::from_millis(450), "{took:?}");
    assert!(r.master.operational().is_none(), "no motion interface while a drive is lost");
    assert_eq!(r.count(|e| *e == NodeEvent::HeartbeatLost { node: 3 }), 1);
    assert_eq!(r.master.counters().heartbeat_losses, 1);

    r.rack.drive(3).unwrap().set_heartbeat_off(false);
    r.bring_up();
    assert_eq!(r.count(|e| *e == NodeEvent::HeartbeatRecovered { node: 3 }), 1);
    assert_eq!(r.count(|e| *e == NodeEvent::Configured { node: 3 }), 2, "configured again");
}

#[test]
fn a_silent_node_is_lost_and_comes_back_after_a_power_cycle() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.rack.drive(1).unwrap().set_silent(true);
    r.until(Duration::from_secs(1), "lost", |r| r.master.status(0).unwrap().phase == Phase::Lost);
    let d = r.rack.drive(1).unwrap();
    d.set_silent(false);
    d.power_cycle();
    r.bring_up();
    assert_eq!(r.count(|e| *e == NodeEvent::Rebooted { node: 1 }), 1);
}

#[test]
fn a_node_rebooting_mid_run_is_noticed_and_configured_again() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.enable_all();
    r.master.operational().unwrap().set_position_counts(3, DRUM.m_to_counts(0.02)).unwrap();
    r.run(Duration::from_millis(50));
    r.rack.drive(4).unwrap().power_cycle();
    r.run(Duration::from_millis(5));
    assert_eq!(r.count(|e| *e == NodeEvent::Rebooted { node: 4 }), 1);
    assert!(r.master.operational().is_none(), "the set is not operational while node 4 is reconfigured");
    r.bring_up();
    let s = r.master.status(3).unwrap();
    assert_eq!(s.boots, 2);
    assert_eq!(r.master.counters().reboots, 1);
    r.run(Duration::from_millis(20));
    // Power-on state: disabled; the master does not re-enable by itself.
    assert_eq!(r.master.status(3).unwrap().axis.state, Some(PowerState::ReadyToSwitchOn));
    // The absolute encoder kept its position.
    assert!((DRUM.counts_to_m(r.master.status(3).unwrap().axis.position) - 0.02).abs() < 1e-3);
    r.enable_all();
}

#[test]
fn malformed_frames_and_unknown_nodes_are_counted_and_reported_once() {
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.rack.drive(2).unwrap().queue_malformed();
    let junk = [
        Frame::new(0x77F, &[0x05]),                         // heartbeat of node 127: not configured
        Frame::new(0x1FF, &[0; 8]),                         // TPDO of an unknown node
        Frame::new(0x0FE, &[0; 8]),                         // EMCY of an unknown node
        Frame::new(0x5A0, &[0x60, 0, 0, 0, 0, 0, 0, 0]),    // SDO response of node 0x20
        Frame::new(0x000, &[0x01, 0x00]),                   // NMT from another master
        Frame::new(0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]), // SDO request of another client
        Frame::new(0x7E5, &[0; 8]),                         // LSS
        Frame::try_new(0x1234_5678, true, &[1, 2]).unwrap(),
        Frame::remote(0x181, false, 8).unwrap(),
        Frame::new(0x581, &[0x60, 0, 0, 0, 0, 0, 0, 0]), // SDO response nobody asked for
    ];
    // A third node on the bus sends the junk.
    let mut injector = r.bus.endpoint();
    for f in &junk {
        injector.send(f).unwrap();
    }
    r.run(Duration::from_millis(300));
    assert!(r.master.all_operational(), "bad input does not disturb operation: {:#?}", r.events);
    let c = r.master.counters();
    assert!(c.malformed >= 5, "{c:?}");
    assert_eq!(c.unknown_node, 4, "{c:?}");
    assert_eq!(c.ignored, 5, "{c:?}");
    // One from the junk, one from drive 1 answering the other client's request.
    assert_eq!(c.unexpected_sdo, 2, "{c:?}");
    for kind in [Problem::Malformed, Problem::UnknownNode, Problem::Ignored, Problem::UnexpectedSdo] {
        assert_eq!(r.count(|e| matches!(e, NodeEvent::FirstOfKind { kind: k, .. } if *k == kind)), 1, "{kind:?} once");
    }
    assert!(r.rack.drives().iter().all(|d| d.counters().short_rpdos == 0), "the master never sends short RPDOs");
}

#[test]
fn a_drive_with_the_wrong_identity_is_refused() {
    let mut cfg = config(&[1, 2]);
    cfg.nodes[1].vendor_id = Some(0x1234);
    let mut r = rig(cfg);
    r.run(Duration::from_millis(300));
    let s = r.master.status(1).unwrap();
    assert_eq!(s.phase, Phase::Failed(NodeFailure::WrongDevice { sub: 1, expected: 0x1234, found: 0xACE }));
    assert!(r.master.operational().is_none());
    assert_eq!(r.master.status(0).unwrap().phase, Phase::Operational);
    let msg = r.events.iter().find(|e| matches!(e, NodeEvent::Failed { .. })).unwrap().to_string();
    assert!(msg.contains("0x1018sub1") && msg.contains("wrong drive"), "{msg}");
}

#[test]
fn sdo_timeouts_are_retried_then_the_node_fails() {
    let mut r = rig(config(&[1, 2]));
    // Node 2 boots, then says nothing more.
    r.step();
    r.step();
    r.rack.drive(2).unwrap().set_silent(true);
    r.run(Duration::from_millis(500));
    let s = r.master.status(1).unwrap();
    assert!(matches!(s.phase, Phase::Failed(NodeFailure::Sdo(a)) if !a.by_server), "{:?}", s.phase);
    let c = r.master.counters();
    assert_eq!(c.sdo_timeouts, 3, "first try and two retries: {c:?}");
    assert_eq!(r.count(|e| matches!(e, NodeEvent::FirstOfKind { kind: Problem::SdoTimeout, .. })), 1);
}

#[test]
fn candump_log_of_a_session_replays_to_the_same_state() {
    let bus = VirtualBus::new();
    let sim_us = Arc::new(AtomicU64::new(1_700_000_000_000_000));
    let clock = sim_us.clone();
    let port = Recorder::with_clock(bus.endpoint(), Vec::new(), "vcan0", Box::new(move || clock.load(Ordering::Relaxed)));
    let rack = DriveRack::with_nodes(bus.endpoint_with(1024, &rack_filters(&NODES)), &NODES);
    let t0 = Instant::now();
    let mut r = Rig { bus, t0, t: t0, master: Master::new(config(&NODES)), port, rack, events: vec![] };
    let tick = Cell::new(0u64);
    while r.t - r.t0 < Duration::from_millis(400) {
        tick.set(tick.get() + 1);
        sim_us.store(1_700_000_000_000_000 + tick.get() * 1000, Ordering::Relaxed);
        r.step();
    }
    assert!(r.master.all_operational());
    let live: Vec<_> = r.master.statuses().map(|s| (s.phase, s.identity, s.axis.state, s.axis.position)).collect();
    let (_, log, res) = r.port.finish();
    res.unwrap();
    let text = String::from_utf8(log).unwrap();
    assert!(text.lines().count() > 400, "SYNC, PDOs, SDO, heartbeats: {} lines", text.lines().count());
    for l in text.lines() {
        candump::parse_line(l).unwrap_or_else(|e| panic!("{l}: {e}"));
    }
    assert!(text.contains(" 701#00\n"), "boot-up of node 1 recorded");

    // Replay: a fresh master with the same configuration, fed the logged frames at the logged
    // times, reaches the same state. Its own frames come back too and are ignored.
    let mut m = Master::new(config(&NODES));
    let mut replay = Replay::new(text.as_bytes());
    let base = t0;
    let first = 1_700_000_000_000_000u64;
    while let Ok(Some(f)) = replay.try_recv() {
        let t = base + Duration::from_micros(replay.last_t_us().unwrap() - first);
        m.poll(t);
        while m.poll_tx().is_some() {}
        m.on_frame(&f, t);
    }
    assert_eq!(replay.stats().bad_lines, 0);
    let replayed: Vec<_> = m.statuses().map(|s| (s.phase, s.identity, s.axis.state, s.axis.position)).collect();
    assert_eq!(replayed, live);
    assert!(m.counters().ignored > 0, "the master's own frames are ignored on replay");
}

#[test]
fn master_config_from_a_robot_file() {
    let text = |drives: &str| {
        format!(
            "[robot]\nname = \"t\"\nmass_kg = 1.0\n[can]\ninterface = \"can0\"\ncycle_s = 0.004\n\
             [[cable]]\n[cable.drive]\nnode_id = 3\ndrum_radius_m = 0.04\ngear_ratio = 5.0\ninvert = true\n\
             [[cable]]\n{drives}\n[[cable]]\n[cable.drive]\nnode_id = 9\nmode = \"torque\"\n"
        )
    };
    let cfg = taut_config::RobotConfig::from_toml_str(&text("")).unwrap();
    let m = MasterConfig::from_robot(&cfg).unwrap();
    // The drum units are the robot I/O layer's, from the same table.
    let drum0 = Scaling::from_drive(cfg.cables[0].drive.as_ref().unwrap());
    assert_eq!(m.sync_period, Duration::from_millis(4));
    assert_eq!(m.nodes.len(), 2, "the cable without a drive is skipped");
    assert_eq!((m.nodes[0].node_id, m.nodes[0].cable, drum0.sign), (3, 0, -1.0));
    assert_eq!((m.nodes[1].node_id, m.nodes[1].cable, m.nodes[1].mode), (9, 2, Mode::CyclicTorque));
    assert!((drum0.metres_per_count() - 2.0 * std::f64::consts::PI * 0.04 / (131072.0 * 5.0)).abs() < 1e-15);
    assert!(!m.bus_load().is_high());

    // A duplicate node id is refused when the file is loaded, with its line and key.
    let e = taut_config::RobotConfig::from_toml_str(&text("[cable.drive]\nnode_id = 9")).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("cable[2].drive.node_id"));
    assert!(e.line.is_some() && e.message.contains("cable[1]"), "{e}");

    let mut no_can = cfg.clone();
    no_can.can = None;
    assert_eq!(MasterConfig::from_robot(&no_can).unwrap_err().key, "can");
}

#[test]
fn nmt_reset_node_and_pre_operational_are_followed_by_reconfiguration_and_restart() {
    use taut_proto::canopen::nmt::{NmtCommand, NmtState};
    let mut r = rig(config(&NODES));
    r.bring_up();
    r.master.send_nmt(NmtCommand::ResetNode, 2);
    r.run(Duration::from_millis(5));
    assert_eq!(r.count(|e| *e == NodeEvent::Rebooted { node: 2 }), 1);
    r.bring_up();
    assert_eq!(r.master.status(1).unwrap().boots, 2);

    // Pre-operational: PDOs stop; the next heartbeat says so and the master starts it again.
    r.master.send_nmt(NmtCommand::PreOperational, 3);
    r.run(Duration::from_millis(5));
    assert_eq!(r.rack.drive(3).unwrap().nmt_state(), NmtState::PreOperational);
    r.until(Duration::from_millis(300), "restarted", |r| r.rack.drive(3).unwrap().nmt_state() == NmtState::Operational);
    r.bring_up();
    assert_eq!(r.count(|e| *e == NodeEvent::Operational { node: 3 }), 2);
}

#[test]
fn segmented_sdo_download_and_upload_against_a_virtual_drive() {
    use taut_proto::canopen::sdo::{SdoClient, SdoOutcome};
    let mut r = rig(config(&[8]));
    r.step();
    let mut client = SdoClient::new(8, Duration::from_millis(100));
    let payload: Vec<u8> = (100..125).collect();
    let transfer = |r: &mut Rig<VirtualEndpoint>, c: &mut SdoClient| loop {
        while let Some(f) = c.poll_tx() {
            r.port.send(&f).unwrap();
        }
        r.t += MS;
        r.rack.step(r.t);
        while let Ok(Some(f)) = r.port.try_recv() {
            if f.id == 0x588 {
                if let Ok(Some(o)) = c.on_response(f.data(), r.t) {
                    return o;
                }
            }
        }
        if let Some(o) = c.poll(r.t) {
            return o;
        }
    };
    client.download(0x2000, 0, &payload, false, r.t).unwrap();
    assert_eq!(transfer(&mut r, &mut client), SdoOutcome::Downloaded { index: 0x2000, sub: 0 });
    client.upload(0x2000, 0, r.t).unwrap();
    assert_eq!(transfer(&mut r, &mut client), SdoOutcome::Uploaded { index: 0x2000, sub: 0, len: 25 });
    assert_eq!(client.data(), &payload[..]);
    // A 4-byte value may also go segmented.
    client.download(0x2000, 0, &[1, 2, 3], true, r.t).unwrap();
    assert_eq!(transfer(&mut r, &mut client), SdoOutcome::Downloaded { index: 0x2000, sub: 0 });
    client.upload(0x2000, 0, r.t).unwrap();
    assert_eq!(transfer(&mut r, &mut client), SdoOutcome::Uploaded { index: 0x2000, sub: 0, len: 3 });
    // Too long for the object: the drive aborts, the abort is named.
    client.download(0x2000, 0, &[0; 40], false, r.t).unwrap();
    let SdoOutcome::Aborted(a) = transfer(&mut r, &mut client) else { panic!("expected an abort") };
    assert!(a.by_server && a.to_string().contains("too high"), "{a}");
}

#[test]
fn quick_stop_then_enable_again() {
    let mut r = rig(config(&[1, 2]));
    r.bring_up();
    r.enable_all();
    r.master.operational().unwrap().quick_stop(0).unwrap();
    r.until(Duration::from_millis(50), "quick stop", |r| r.master.status(0).unwrap().axis.state == Some(PowerState::QuickStopActive));
    assert_eq!(r.master.operational().unwrap().set_position_counts(0, DRUM.m_to_counts(0.0)), Err(CommandError::NotEnabled { node: 1 }));
    assert_eq!(r.master.status(1).unwrap().axis.state, Some(PowerState::OperationEnabled), "the other drive is untouched");
    r.enable_all();
    let mut op = r.master.operational().unwrap();
    op.disable(0).unwrap();
    op.disable(1).unwrap();
    r.until(Duration::from_millis(50), "disabled", |r| r.master.statuses().all(|s| s.axis.state == Some(PowerState::ReadyToSwitchOn)));
}

/// The typed drive set, in wall-clock time with the drives on their own thread: a drive that
/// power-cycles while the set is enabled is reported by the next cycle, whether the master is
/// still configuring it again or it already came back operational with its power stage off
/// (here, natively, the drive answers so fast that it usually is back within one cycle: the
/// failure the vcan VM found).
#[test]
fn drive_set_reports_a_drive_that_rebooted_while_enabled() {
    use taut_driver::canopen::drive_set::{DriveSet, DriveSetError};
    use taut_vdev::{spawn_rack, DriveParams, VirtualDrive};
    let bus = VirtualBus::new();
    let nodes = [51u8, 52];
    let mut cfg = config(&nodes);
    cfg.sync_period = Duration::from_millis(2);
    let set = DriveSet::new(bus.endpoint(), cfg);
    let rack =
        spawn_rack(bus.endpoint_with(1024, &rack_filters(&nodes)), nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    let set = set.bring_up().unwrap_or_else(|r| panic!("bring-up: {}", r.error));
    let mut set = set.enable(Duration::from_secs(10)).unwrap_or_else(|r| panic!("enable: {}", r.error));
    set.cycle().unwrap();
    rack.with_drive(51, |d| d.power_cycle()).unwrap();
    let t = Instant::now();
    let err = loop {
        if let Err(e) = set.cycle() {
            break e;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "reboot not reported: {:?}", set.statuses());
    };
    assert!(matches!(err, DriveSetError::NotOperational { node: 51, .. } | DriveSetError::Disabled { node: 51, .. }), "{err}");
    let mut set = set.disable();
    assert_eq!(set.master().counters().reboots, 1);
    // Once it is configured again, the set enables it like at start-up.
    let t = Instant::now();
    while !set.master().all_operational() {
        set.run_for(Duration::from_millis(10)).unwrap();
        assert!(t.elapsed() < Duration::from_secs(10), "node 51 not configured again");
    }
    let mut set = set.enable(Duration::from_secs(10)).unwrap_or_else(|r| panic!("re-enable: {}", r.error));
    set.cycle().unwrap();
    rack.stop();
}
