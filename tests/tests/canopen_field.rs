//! The CANopen master against virtual drives that behave like drives in the field, on the
//! in-process virtual bus in simulated time: drives that have been heartbeating long before
//! taut starts, drives left enabled or in fault by a previous run, slow and duplicated SDO
//! answers, a boot-up lost on the bus, and a master that disappears mid-run.

use std::time::{Duration, Instant};

use taut_driver::canopen::master::{Counters, Event, Master, MasterConfig, NodeConfig, Phase};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_driver::transport::CanTransport;
use taut_sim::devices::drive::{rack_filters, DriveParams, DriveRack, VirtualDrive};

const MS: Duration = Duration::from_millis(1);

/// A bus with a rack of drives that is powered (and stepped) before the master exists.
struct Field {
    bus: VirtualBus,
    t: Instant,
    rack: DriveRack<VirtualEndpoint>,
    master: Option<(Master, VirtualEndpoint)>,
    events: Vec<Event>,
}

impl Field {
    fn new(drives: Vec<VirtualDrive>) -> Field {
        let bus = VirtualBus::new();
        let nodes: Vec<u8> = drives.iter().map(|d| d.node_id()).collect();
        let rack = DriveRack::new(bus.endpoint_with(4096, &rack_filters(&nodes)), drives);
        Field {
            bus,
            t: Instant::now(),
            rack,
            master: None,
            events: Vec::new(),
        }
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
    fn until(
        &mut self,
        max: Duration,
        what: &str,
        mut cond: impl FnMut(&mut Self) -> bool,
    ) -> Duration {
        let start = self.t;
        while !cond(self) {
            if self.t - start >= max {
                let c = self.counters();
                let st: Vec<_> = self
                    .master()
                    .statuses()
                    .map(|s| (s.node, s.phase))
                    .collect();
                panic!(
                    "{what}: not within {max:?}; counters {c:?}; phases {st:?}; events: {:#?}",
                    self.events
                );
            }
            self.step();
        }
        self.t - start
    }

    fn count(&self, f: impl Fn(&Event) -> bool) -> usize {
        self.events.iter().filter(|e| f(e)).count()
    }
}

fn config(nodes: &[u8]) -> MasterConfig {
    MasterConfig::new(
        nodes
            .iter()
            .enumerate()
            .map(|(i, &n)| NodeConfig::new(n, i))
            .collect(),
    )
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
        f.until(Duration::from_secs(3), "bring-up", |f| {
            f.master().all_operational()
        });
        f.run(Duration::from_millis(300));
        let c = f.counters();
        assert_eq!(
            (c.sdo_aborts, c.sdo_timeouts, c.sdo_retries, c.sdo_discarded, c.boot_ups_missing),
            (0, 0, 0, 0, 0),
            "startup {startup_ms} ms: {c:?}; events {:#?}",
            f.events
        );
        for n in NODES {
            assert_eq!(
                f.count(|e| *e == Event::Configured { node: n }),
                1,
                "startup {startup_ms} ms: node {n} configured once"
            );
        }
        for d in f.rack.drives() {
            assert_eq!(
                d.counters().sdo_aborts,
                0,
                "startup {startup_ms} ms: node {} answered a request with an abort",
                d.node_id()
            );
        }
        assert!(f.master().statuses().all(|s| s.phase == Phase::Operational));
    }
}
