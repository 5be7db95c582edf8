//! Master processing per SYNC cycle: a full in-memory TX -> RX round trip with virtual drives
//! answering (SYNC + RPDOs out, drives step, TPDOs back into the master), for 4 and 8 drives;
//! and the master alone on pre-made TPDOs. Goal: < 5 µs per cycle for 8 drives.

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use std::time::{Duration, Instant};
use taut_driver::canopen::master::{Master, MasterConfig, NodeConfig};
use taut_driver::transport::virtual_bus::{VirtualBus, VirtualEndpoint};
use taut_proto::can::{CanTransport, Frame};
use taut_vdev::{rack_filters, DriveRack};

struct Rig {
    t: Instant,
    master: Master,
    port: VirtualEndpoint,
    rack: DriveRack<VirtualEndpoint>,
}

impl Rig {
    fn new(n: u8, hb_timeout: Duration) -> Rig {
        let nodes: Vec<u8> = (1..=n).collect();
        let mut cfg = MasterConfig::new(nodes.iter().enumerate().map(|(i, &id)| NodeConfig::new(id, i)).collect());
        cfg.sync_period = Duration::from_millis(1);
        for node in &mut cfg.nodes {
            node.heartbeat_timeout = hb_timeout;
        }
        let bus = VirtualBus::new();
        let port = bus.endpoint();
        let rack = DriveRack::with_nodes(bus.endpoint_with(1024, &rack_filters(&nodes)), &nodes);
        let mut r = Rig { t: Instant::now(), master: Master::new(cfg), port, rack };
        while !r.master.all_operational() {
            r.cycle();
        }
        let mut op = r.master.operational().unwrap();
        for i in 0..usize::from(n) {
            op.enable(i).unwrap();
        }
        while !r.master.all_enabled() {
            r.cycle();
        }
        r
    }

    fn cycle(&mut self) {
        self.t += Duration::from_millis(1);
        self.master.poll(self.t);
        while let Some(f) = self.master.poll_tx() {
            let _ = self.port.send(&f);
        }
        self.rack.step(self.t);
        while let Ok(Some(f)) = self.port.try_recv() {
            self.master.on_frame(&f, self.t);
        }
        while self.master.poll_event().is_some() {}
    }
}

fn round_trip(c: &mut Criterion) {
    let mut g = c.benchmark_group("sync_cycle_round_trip");
    for n in [4u8, 8] {
        let mut rig = Rig::new(n, Duration::from_millis(300));
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| b.iter(|| rig.cycle()));
    }
    g.finish();
}

fn master_only(c: &mut Criterion) {
    let mut g = c.benchmark_group("sync_cycle_master_only");
    for n in [4u8, 8] {
        // No heartbeats are fed below: a timeout longer than any run keeps the drives in.
        let mut rig = Rig::new(n, Duration::from_secs(1_000_000));
        // Record one cycle of TPDOs, then feed the same frames to the master alone.
        rig.master.poll(rig.t + Duration::from_millis(1));
        while let Some(f) = rig.master.poll_tx() {
            let _ = rig.port.send(&f);
        }
        rig.t += Duration::from_millis(1);
        rig.rack.step(rig.t);
        let mut tpdos: Vec<Frame> = Vec::new();
        while let Ok(Some(f)) = rig.port.try_recv() {
            tpdos.push(f);
        }
        let mut m = rig.master;
        let mut t = rig.t;
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                t += Duration::from_millis(1);
                m.poll(t);
                while let Some(f) = m.poll_tx() {
                    black_box(f);
                }
                for f in &tpdos {
                    m.on_frame(f, t);
                }
            })
        });
    }
    g.finish();
}

criterion_group!(benches, round_trip, master_only);
criterion_main!(benches);
