//! The CANopen master against virtual drives that behave like drives in the field, on the
//! in-process virtual bus in simulated time: drives that have been heartbeating long before
//! taut starts, drives left enabled or in fault by a previous run, slow and duplicated SDO
//! answers, a boot-up lost on the bus, and a master that disappears mid-run.

use std::time::{Duration, Instant};

use taut_driver::canopen::master::{Counters, Master, MasterConfig, NodeConfig, NodeEvent, Phase};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_proto::can::CanTransport;
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::nmt::NmtState;
use taut_vdev::{rack_filters, DriveParams, DriveRack, VirtualDrive};

const MS: Duration = Duration::from_millis(1);

/// A bus with a rack of drives that is powered (and stepped) before the master exists.
struct Field {
    bus: VirtualBus,
    t: Instant,
    rack: DriveRack<VirtualEndpoint>,
    master: Option<(Master, VirtualEndpoint)>,
    events: Vec<NodeEvent>,
}

impl Field {
    fn new(drives: Vec<VirtualDrive>) -> Field {
        let bus = VirtualBus::new();
        let nodes: Vec<u8> = drives.iter().map(|d| d.node_id()).collect();
        let rack = DriveRack::new(bus.endpoint_with(4096, &rack_filters(&nodes)), drives);
        Field { bus, t: Instant::now(), rack, master: None, events: Vec::new() }
    }

    /// Opens the master's socket now; the master itself runs from the next [`step`].
    fn connect(&mut self, cfg: MasterConfig) {
        self.master = Some((Master::new(cfg), self.bus.endpoint_with(4096, &[])));
    }

    /// Opens the master's socket, lets `startup` pass (taut reading its configuration while
    /// frames queue in the socket), then runs the master from then on.
    fn start_master_after(&mut self, cfg: MasterConfig, startup: Duration) {
        self.connect(cfg);
        let m = self.master.take();
        self.run(startup);
        self.master = m;
    }

    /// One millisecond: master timers and TX, drives, master RX.
    fn step(&mut self) {
        self.t += MS;
        if let Some((m, port)) = &mut self.master {
            m.poll(self.t);
            while let Some(f) = m.poll_tx() {
                port.send(&f).unwrap();
            }
        }
        self.rack.step(self.t);
        if let Some((m, port)) = &mut self.master {
            while let Ok(Some(f)) = port.try_recv() {
                m.on_frame(&f, self.t);
            }
            while let Some(e) = m.poll_event() {
                self.events.push(e);
            }
        }
    }

    fn run(&mut self, d: Duration) {
        let end = self.t + d;
        while self.t < end {
            self.step();
        }
    }

    fn master(&mut self) -> &mut Master {
        &mut self.master.as_mut().expect("master connected").0
    }

    fn counters(&mut self) -> Counters {
        self.master().counters()
    }

    /// Steps until `cond`, at most `max`; returns the time it took.
    fn until(&mut self, max: Duration, what: &str, mut cond: impl FnMut(&mut Self) -> bool) -> Duration {
        let start = self.t;
        while !cond(self) {
            if self.t - start >= max {
                let c = self.counters();
                let st: Vec<_> = self.master().statuses().map(|s| (s.node, s.phase)).collect();
                panic!("{what}: not within {max:?}; counters {c:?}; phases {st:?}; events: {:#?}", self.events);
            }
            self.step();
        }
        self.t - start
    }

    fn count(&self, f: impl Fn(&NodeEvent) -> bool) -> usize {
        self.events.iter().filter(|e| f(e)).count()
    }
}

fn config(nodes: &[u8]) -> MasterConfig {
    MasterConfig::new(nodes.iter().enumerate().map(|(i, &n)| NodeConfig::new(n, i)).collect())
}

/// Drives that come out of power-on (and every reset communication) heartbeating every
/// `hb_ms`, as drives with a stored 0x1017 do.
fn heartbeating(nodes: &[u8], hb_ms: u16) -> Vec<VirtualDrive> {
    nodes
        .iter()
        .map(|&n| {
            let mut p = DriveParams::new(n);
            p.stored_heartbeat_ms = hb_ms;
            VirtualDrive::new(p)
        })
        .collect()
}

/// Regression (issue 9): drives already heartbeating at 100 ms when taut starts. taut sends
/// NMT reset communication; a heartbeat that reached taut's socket before the reset took effect
/// started configuration (upload 0x1000), the boot-up that followed started it again, the drive
/// answered both, and the SDO client stayed one reply behind for the whole bring-up: abort
/// 0x05040001 and a retry at every step, sometimes a FAILED node.
#[test]
fn heartbeating_drives_are_brought_up_without_sdo_aborts_or_retries() {
    const NODES: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
    // The master's first poll at several phases of the drives' 100 ms heartbeat.
    for startup_ms in [0u64, 13, 37, 50, 99, 150, 260] {
        let mut f = Field::new(heartbeating(&NODES, 100));
        f.run(Duration::from_secs(2)); // powered long before taut starts
        f.start_master_after(config(&NODES), Duration::from_millis(startup_ms));
        f.until(Duration::from_secs(3), "bring-up", |f| f.master().all_operational());
        f.run(Duration::from_millis(300));
        let c = f.counters();
        assert_eq!(
            (c.sdo_aborts, c.sdo_timeouts, c.sdo_retries, c.sdo_discarded, c.boot_ups_missing),
            (0, 0, 0, 0, 0),
            "startup {startup_ms} ms: {c:?}; events {:#?}",
            f.events
        );
        for n in NODES {
            assert_eq!(f.count(|e| *e == NodeEvent::Configured { node: n }), 1, "startup {startup_ms} ms: node {n} configured once");
        }
        for d in f.rack.drives() {
            assert_eq!(d.counters().sdo_aborts, 0, "startup {startup_ms} ms: node {} answered a request with an abort", d.node_id());
        }
        assert!(f.master().statuses().all(|s| s.phase == Phase::Operational));
    }
}

/// The same race without any queueing in taut's socket: the drives take 20 ms to act on the
/// NMT reset and answer SDO 5 ms late, so a heartbeat sent in that window reaches taut after its
/// reset, and answers to requests made before the reset arrive after the boot-up.
#[test]
fn heartbeats_sent_while_the_reset_takes_effect_do_not_start_configuration() {
    const NODES: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
    for offset_ms in [0u64, 3, 7, 11, 17, 45, 81, 95] {
        let drives = NODES
            .iter()
            .map(|&n| {
                VirtualDrive::new(params(n, |p| {
                    p.reset_latency = Duration::from_millis(20);
                    p.sdo_delay = Duration::from_millis(5);
                }))
            })
            .collect();
        let mut f = Field::new(drives);
        f.run(Duration::from_millis(1000 + offset_ms));
        f.start_master_after(config(&NODES), Duration::ZERO);
        f.until(Duration::from_secs(3), "bring-up", |f| f.master().all_operational());
        f.run(Duration::from_millis(200));
        let c = f.counters();
        assert_eq!(
            (c.sdo_aborts, c.sdo_timeouts, c.sdo_retries, c.sdo_discarded, c.boot_ups_missing, c.reboots),
            (0, 0, 0, 0, 0, 0),
            "offset {offset_ms} ms: {c:?}"
        );
        for n in NODES {
            assert_eq!(f.count(|e| *e == NodeEvent::Configured { node: n }), 1, "offset {offset_ms} ms: node {n}");
        }
    }
}

fn params(n: u8, f: impl Fn(&mut DriveParams)) -> DriveParams {
    let mut p = DriveParams::new(n);
    p.stored_heartbeat_ms = 100;
    f(&mut p);
    p
}

/// A restarted taut finds drive 2 still in operation enabled (the previous run's drives had
/// 0x6007 = 0: nothing noticed it go) and drive 3 in fault. Drive 2 is switched off by SDO
/// before anything else is written and never moves; drive 3 stays in fault: only the operator
/// resets a fault.
#[test]
fn a_drive_left_enabled_is_switched_off_without_moving_and_a_faulted_one_stays_in_fault() {
    const NODES: [u8; 4] = [1, 2, 3, 4];
    let mut f = Field::new(heartbeating(&NODES, 100));
    f.run(Duration::from_millis(500));
    {
        let d2 = f.rack.drive(2).unwrap();
        d2.set_actual(50_000, 0);
        d2.left_by_previous_run(PowerState::OperationEnabled, 0);
        f.rack.drive(3).unwrap().left_by_previous_run(PowerState::Fault, 0x2310);
    }
    f.run(Duration::from_millis(300));
    f.start_master_after(config(&NODES), Duration::from_millis(40));
    let mut moved = 0i32;
    f.until(Duration::from_secs(3), "bring-up", |f| {
        moved = moved.max((f.rack.drive(2).unwrap().position() - 50_000).abs());
        assert_eq!(f.rack.drive(3).unwrap().state(), PowerState::Fault, "fault left alone");
        f.master().all_operational()
    });
    f.run(Duration::from_millis(300));
    assert_eq!(f.count(|e| *e == NodeEvent::FoundPowered { node: 2, state: PowerState::OperationEnabled }), 1, "{:#?}", f.events);
    assert_eq!(f.count(|e| matches!(e, NodeEvent::FoundPowered { .. })), 1);
    assert_eq!(f.rack.drive(2).unwrap().state(), PowerState::ReadyToSwitchOn);
    assert_eq!(f.rack.drive(3).unwrap().state(), PowerState::Fault);
    assert_eq!(f.master().status(2).unwrap().axis.state, Some(PowerState::Fault));
    assert_eq!(f.master().status(1).unwrap().axis.position, 50_000);
    // Enabled again on request, drive 2 holds where it stood; drive 3 needs a fault reset.
    {
        let mut op = f.master().operational().unwrap();
        for i in 0..4 {
            op.enable(i).unwrap();
        }
    }
    f.until(Duration::from_secs(1), "enable", |f| {
        moved = moved.max((f.rack.drive(2).unwrap().position() - 50_000).abs());
        f.rack.drive(2).unwrap().state() == PowerState::OperationEnabled
    });
    f.run(Duration::from_millis(300));
    moved = moved.max((f.rack.drive(2).unwrap().position() - 50_000).abs());
    assert_eq!(moved, 0, "drive 2 moved by {moved} counts");
    assert_eq!(f.rack.drive(3).unwrap().state(), PowerState::Fault, "no automatic fault reset");
    f.master().operational().unwrap().fault_reset(2).unwrap();
    f.until(Duration::from_secs(1), "fault reset on request", |f| f.rack.drive(3).unwrap().state() != PowerState::Fault);
    let c = f.counters();
    assert_eq!((c.sdo_aborts, c.sdo_retries), (0, 0), "{c:?}");
}

/// Drives that answer SDO requests 30 ms late, and send answers twice: every answer, or every
/// third. The duplicates are dropped and counted; nothing is aborted or retried.
#[test]
fn slow_and_duplicated_sdo_answers_do_not_desynchronise_bring_up() {
    const NODES: [u8; 4] = [1, 2, 3, 4];
    for every in [1u32, 3] {
        let drives = NODES
            .iter()
            .map(|&n| {
                VirtualDrive::new(params(n, |p| {
                    p.sdo_delay = Duration::from_millis(30);
                    p.sdo_duplicate_every = every;
                }))
            })
            .collect();
        let mut f = Field::new(drives);
        f.run(Duration::from_secs(1));
        f.start_master_after(config(&NODES), Duration::from_millis(20));
        f.until(Duration::from_secs(10), "bring-up", |f| f.master().all_operational());
        f.run(Duration::from_millis(200));
        let c = f.counters();
        let dups: u64 = f.rack.drives().iter().map(|d| d.counters().sdo_duplicates).sum();
        assert!(dups > 20, "every {every}: {dups} duplicates sent");
        assert_eq!((c.sdo_aborts, c.sdo_timeouts, c.sdo_retries), (0, 0, 0), "every {every}: {c:?}");
        // A duplicate arrives while the next request is in flight (dropped as stale) or after
        // the last one (no transfer: unexpected).
        assert_eq!(c.sdo_discarded + c.unexpected_sdo, dups, "every {every}: {c:?}");
        for n in NODES {
            assert_eq!(f.count(|e| *e == NodeEvent::Configured { node: n }), 1, "every {every}: node {n}");
        }
        for d in f.rack.drives() {
            assert_eq!(d.counters().sdo_aborts, 0, "every {every}: node {} got a request it refused", d.node_id());
        }
        assert!(f.master().statuses().all(|s| s.name() == "taut virtual drive"), "segmented upload through duplicates");
    }
}

/// Drive 3's boot-up after taut's reset communication is lost on the bus. It heartbeats, so
/// taut configures it once, `boot_wait` after its first heartbeat, and counts the missing
/// boot-up; the others are configured at their boot-up.
#[test]
fn a_lost_boot_up_is_configured_once_after_the_boot_wait() {
    const NODES: [u8; 4] = [1, 2, 3, 4];
    let mut f = Field::new(heartbeating(&NODES, 100));
    f.run(Duration::from_millis(500));
    f.rack.drive(3).unwrap().lose_boot_ups(1);
    let cfg = config(&NODES);
    let wait = cfg.boot_wait;
    f.start_master_after(cfg, Duration::from_millis(10));
    let took = f.until(Duration::from_secs(5), "bring-up", |f| f.master().all_operational());
    assert!(took >= wait, "node 3 configured after the boot wait, not before: {took:?}");
    assert!(took < wait + Duration::from_millis(500), "{took:?}");
    let c = f.counters();
    assert_eq!(c.boot_ups_missing, 1, "{c:?}");
    assert_eq!(f.rack.drive(3).unwrap().counters().boots_lost, 1);
    assert_eq!((c.sdo_aborts, c.sdo_retries, c.sdo_discarded), (0, 0, 0), "{c:?}");
    for n in NODES {
        assert_eq!(f.count(|e| *e == NodeEvent::Configured { node: n }), 1, "node {n}");
    }
    assert_eq!(f.count(|e| *e == NodeEvent::Booted { node: 3 }), 0);
}

/// taut configures each drive's heartbeat consumer for its own heartbeat and the abort
/// connection option; when taut stops (here: the master is no longer called), every drive
/// leaves operation enabled within the consumer time, by the configured reaction.
#[test]
fn drives_leave_operation_enabled_when_the_master_stops() {
    const NODES: [u8; 4] = [1, 2, 3, 4];
    for (code, want) in [(3i16, PowerState::QuickStopActive), (1, PowerState::Fault), (2, PowerState::SwitchOnDisabled)] {
        let mut f = Field::new(heartbeating(&NODES, 100));
        f.run(Duration::from_millis(300));
        let mut cfg = config(&NODES);
        cfg.supervision.abort_connection = code;
        let consumer = Duration::from_millis(u64::from(cfg.supervision.consumer_time_ms()));
        let period = cfg.supervision.heartbeat;
        f.start_master_after(cfg, Duration::from_millis(5));
        f.until(Duration::from_secs(3), "bring-up", |f| f.master().all_operational());
        {
            let mut op = f.master().operational().unwrap();
            for i in 0..NODES.len() {
                op.enable(i).unwrap();
            }
        }
        f.until(Duration::from_secs(1), "enable", |f| f.master().all_enabled());
        f.run(Duration::from_millis(500));
        for d in f.rack.drives() {
            assert_eq!(d.heartbeat_consumer(), 127 << 16 | 300, "0x1016 sub 1");
            assert_eq!(d.abort_connection_option(), code);
            assert_eq!(d.counters().consumer_timeouts, 0, "no timeout while taut runs");
        }
        let held: Vec<i32> = f.rack.drives().iter().map(|d| d.position()).collect();
        // taut stops: killed between two cycles.
        let gone = f.master.take();
        let stopped = f.t;
        let took = f.until(consumer + period, "drives leave operation enabled", |f| {
            f.rack.drives().iter().all(|d| d.state() != PowerState::OperationEnabled)
        });
        assert!(took + period > consumer, "code {code}: not before the consumer time: {took:?}");
        for (d, p) in f.rack.drives().iter().zip(&held) {
            assert_eq!(d.state(), want, "code {code}");
            assert_eq!(d.counters().consumer_timeouts, 1);
            assert_eq!(d.counters().abort_connection_actions, 1);
            assert_eq!(d.nmt_state(), NmtState::PreOperational, "CiA 301 error behaviour 0x1029 = 0");
            assert_eq!(d.position(), *p, "code {code}: node {} held", d.node_id());
        }
        // The drives' EMCY 0x8130 (heartbeat error) is waiting in taut's socket.
        let (m, mut port) = gone.unwrap();
        let mut emcy = 0;
        while let Ok(Some(fr)) = port.try_recv() {
            if fr.id & !0x7F == 0x080 && fr.data()[..2] == [0x30, 0x81] {
                emcy += 1;
            }
        }
        assert_eq!(emcy, NODES.len(), "code {code}");
        let _ = stopped;
        // taut comes back (a stalled process resumes): it starts the drives again, but does
        // not enable them by itself.
        f.master = Some((m, port));
        f.until(Duration::from_secs(2), "operational again", |f| f.rack.drives().iter().all(|d| d.nmt_state() == NmtState::Operational));
        f.run(Duration::from_millis(500));
        for (d, p) in f.rack.drives().iter().zip(&held) {
            assert_ne!(d.state(), PowerState::OperationEnabled, "code {code}: node {} enabled again without a request", d.node_id());
            assert_eq!(d.position(), *p);
        }
        assert!(f.master().all_operational() && !f.master().all_enabled());
    }
}

/// A drive slower than the SDO timeout: every transfer times out once. Each abort taut decides
/// to send is on the bus (before the retry that follows it), and the late answers are dropped
/// or, when they answer the same request again, taken: bring-up still succeeds.
#[test]
fn every_client_abort_reaches_the_bus() {
    use taut_proto::can::Filter;
    let mut f = Field::new(vec![VirtualDrive::new(params(1, |p| p.sdo_delay = Duration::from_millis(150)))]);
    let mut monitor = f.bus.endpoint_with(65_536, &[Filter { id: 0x600, mask: 0x780, extended: false }]);
    f.run(Duration::from_millis(300));
    f.start_master_after(config(&[1]), Duration::from_millis(5));
    f.until(Duration::from_secs(20), "bring-up", |f| f.master().all_operational());
    let c = f.counters();
    let mut aborts = 0;
    while let Ok(Some(fr)) = monitor.try_recv() {
        if fr.data()[0] == 0x80 {
            aborts += 1;
            assert_eq!(fr.data()[4..8], 0x0504_0000u32.to_le_bytes(), "SDO protocol timed out");
        }
    }
    assert!(c.sdo_timeouts > 10, "{c:?}");
    assert_eq!(aborts, c.sdo_timeouts, "{c:?}");
    // A timeout is retried unless its tries are used up (the optional device name, whose
    // segments are all late, is given up after 2 retries).
    assert!(c.sdo_retries > 10 && c.sdo_retries <= c.sdo_timeouts, "{c:?}");
    assert_eq!(f.count(|e| *e == NodeEvent::Configured { node: 1 }), 1);
}
