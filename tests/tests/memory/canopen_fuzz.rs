//! Arbitrary frames into an operational master (property test, the stable-toolchain stand-in for
//! `fuzz/`): it never panics, counts every frame, and the drives stay operational when the noise
//! cannot be told from nothing (ids of nodes it does not have, extended ids).
//!
//! Also: the steady-state SYNC cycle allocates nothing (a counting global allocator).

use proptest::prelude::*;
use std::time::{Duration, Instant};

use taut_driver::canopen::master::{Master, MasterConfig, NodeConfig};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_proto::can::{CanTransport, Frame};
use taut_vdev::{rack_filters, DriveRack};

// The counting global allocator of this test binary (one per binary): `crate::counting`. Only
// the measuring thread counts: the property tests (and the other tests of this binary) run on
// other test threads at the same time and allocate freely.
use crate::counting::{ALLOCS, WATCHING};

struct Rig {
    bus: VirtualBus,
    t: Instant,
    master: Master,
    port: VirtualEndpoint,
    rack: DriveRack<VirtualEndpoint>,
}

impl Rig {
    fn new(nodes: &[u8]) -> Rig {
        let bus = VirtualBus::new();
        let port = bus.endpoint();
        let rack = DriveRack::with_nodes(bus.endpoint_with(4096, &rack_filters(nodes)), nodes);
        let cfg = MasterConfig::new(nodes.iter().enumerate().map(|(i, &n)| NodeConfig::new(n, i)).collect());
        let mut r = Rig { bus, t: Instant::now(), master: Master::new(cfg), port, rack };
        for _ in 0..2000 {
            if r.master.all_operational() {
                break;
            }
            r.step();
        }
        assert!(r.master.all_operational());
        r
    }

    fn step(&mut self) {
        self.t += Duration::from_millis(1);
        self.master.poll(self.t);
        while let Some(f) = self.master.poll_tx() {
            self.port.send(&f).unwrap();
        }
        self.rack.step(self.t);
        while let Ok(Some(f)) = self.port.try_recv() {
            self.master.on_frame(&f, self.t);
        }
        while self.master.poll_event().is_some() {}
    }
}

fn arb_frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        (0u16..0x800, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::new(id, &d)),
        (0u32..=0x1FFF_FFFF, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::try_new(id, true, &d).unwrap()),
        (0u32..0x800, 0u8..=8).prop_map(|(id, n)| Frame::remote(id, false, n).unwrap()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn arbitrary_frames_never_panic_the_master(frames in proptest::collection::vec(arb_frame(), 1..200)) {
        let mut r = Rig::new(&[1, 2]);
        let before = r.master.counters().rx_frames;
        let mut noise = r.bus.endpoint();
        for f in &frames {
            noise.send(f).unwrap();
            r.step();
        }
        // Every injected frame was seen by the master, besides the drives' own traffic.
        prop_assert!(r.master.counters().rx_frames - before >= frames.len() as u64);
        for _ in 0..2000 {
            if r.master.all_operational() { break; }
            r.step();
        }
    }

    #[test]
    fn noise_from_elsewhere_does_not_disturb_operation(
        frames in proptest::collection::vec(prop_oneof![
            (0x7Fu16..0x80, proptest::collection::vec(any::<u8>(), 0..=8), prop_oneof![Just(0x080u16), Just(0x180), Just(0x280), Just(0x580), Just(0x700)])
                .prop_map(|(node, d, base)| Frame::new(base + node, &d)),
            (0u32..=0x1FFF_FFFF, proptest::collection::vec(any::<u8>(), 0..=8))
                .prop_map(|(id, d)| Frame::try_new(id, true, &d).unwrap()),
        ], 1..100)
    ) {
        let mut r = Rig::new(&[1, 2]);
        let mut noise = r.bus.endpoint();
        let c0 = r.master.counters();
        for f in &frames {
            noise.send(f).unwrap();
            r.step();
        }
        prop_assert!(r.master.all_operational());
        let c = r.master.counters();
        prop_assert_eq!((c.unknown_node - c0.unknown_node) + (c.ignored - c0.ignored), frames.len() as u64);
        prop_assert_eq!(c.malformed, 0);
    }
}

#[test]
fn the_sync_cycle_allocates_nothing() {
    let mut r = Rig::new(&[1, 2, 3, 4, 5, 6, 7, 8]);
    let n = r.master.len();
    let mut op = r.master.operational().unwrap();
    for i in 0..n {
        op.enable(i).unwrap();
    }
    for _ in 0..100 {
        r.step();
    }
    assert!(r.master.all_enabled());
    let before = ALLOCS.with(|a| a.get());
    WATCHING.with(|w| w.set(true));
    for k in 0..1000 {
        if k % 10 == 0 {
            let mut op = r.master.operational().unwrap();
            op.set_position_counts(k % n, k as i32).unwrap();
        }
        r.step();
    }
    WATCHING.with(|w| w.set(false));
    let after = ALLOCS.with(|a| a.get());
    assert_eq!(after - before, 0, "allocations in 1000 SYNC cycles of master + 8 virtual drives + bus");
}
