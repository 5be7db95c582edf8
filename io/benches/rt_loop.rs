//! Loop benchmarks (figures for BENCHMARKS.md; not timed tests):
//!
//! 1. compute time of one cycle (read -> update -> write -> sample push -> status copy) for 4 and
//!    8 cables, operating with a parameter swap every 500 cycles: p50 / p99 / max;
//! 2. the longest cycle while a swap is faded in;
//! 3. wake-up lateness of the periodic clock at 1 kHz, normal scheduler and SCHED_FIFO;
//! 4. (`RT_SOAK_S=600`) a soak at 1 kHz with a consumer thread draining the ring and a busy
//!    thread competing for the CPUs: samples dropped.
//!
//! `RT_TENSION_SIDE=1`: the parameters carry load-cell gains and friction (every cell reading
//! corrected each cycle) in the compute benchmarks.
//!
//! `cargo bench -p taut-io --bench rt_loop`

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;
use taut_config::runtime::RtConfig;
use taut_io::rtsys::{monotonic_ns, setup_current_thread, Periodic};
use taut_io::runner::LoopCore;
use taut_io::testkit::{quick_config, truth_params, KinematicRobot};
use taut_io::FromRobot;
use taut_rt::io::{CableCommand, Devices, DriveRequest, DriveStatus, Inputs, Outputs};
use taut_rt::kin::{LoopEffects, LoopParams};
use taut_rt::motion::{Command, Controller, ControllerConfig, State};
use taut_rt::sample::sample_ring;
use taut_rt::triple::triple_buffer;

/// Devices that echo the commands back (no physics): the loop's own cost only.
struct Echo {
    n: usize,
    len: [f64; 8],
    enabled: bool,
    pose: [f64; 3],
}

impl Devices for Echo {
    fn read(&mut self, _now: f64, inp: &mut Inputs) {
        for j in 0..self.n {
            inp.length_m[j] = self.len[j];
            inp.length_age_s[j] = 0.0;
            inp.tension_n[j] = 30.0;
            inp.tension_age_s[j] = 0.0;
            inp.drive[j] = if self.enabled { DriveStatus::Enabled } else { DriveStatus::Disabled };
        }
        inp.pose_m = self.pose;
        inp.pose_age_s = 0.0;
    }
    fn write(&mut self, _now: f64, out: &Outputs) {
        self.enabled = out.request == DriveRequest::Enable;
        for j in 0..self.n {
            if let CableCommand::Position(l) = out.cable[j] {
                self.len[j] = l;
            }
        }
    }
}

fn pct(v: &mut [i64], p: f64) -> f64 {
    v.sort_unstable();
    v[((v.len() as f64 - 1.0) * p).round() as usize] as f64 * 1e-3
}

fn compute_bench(n: usize, kinematic: bool) {
    let dir = std::env::temp_dir().join(format!("taut-bench-{}", std::process::id()));
    let cfg = quick_config(n, &dir);
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let mut truth = truth_params(n, 0.1);
    let tension_side = std::env::var_os("RT_TENSION_SIDE").is_some();
    if tension_side {
        truth = truth.with_effects(LoopEffects::NONE.with_tension_side(Some(&[1.02; 8]), Some(&[0.1; 8])));
    }
    let (mut ptx, prx) = triple_buffer(LoopParams::invalid(n));
    let (ctx, crx) = crossbeam_channel::bounded(16);
    let (stx, mut srx) = sample_ring(1 << 14);
    let (mut status_tx, _status_rx) = triple_buffer(0u64);
    let p0 = [0.2, 0.1, 2.0];
    let dev: Box<dyn Devices> = if kinematic {
        Box::new(KinematicRobot::new(truth, p0))
    } else {
        let mut len = [0.0; 8];
        let mut l = [0.0; 8];
        truth.lengths(&p0, &mut l);
        len[..n].copy_from_slice(&l[..n]);
        Box::new(Echo { n, len, enabled: false, pose: p0 })
    };
    let mut core = LoopCore::new(n, dev, Controller::new(ccfg, move || crx.try_recv().ok(), prx), stx);
    let dt = 0.001;
    let mut t = 0.0;
    // Bring it to operate: phases, initial estimate, excitation.
    let mut v = 1;
    for _ in 0..200_000 {
        t += dt;
        core.cycle(t, dt);
        while srx.pop().is_some() {}
        match core.controller.state() {
            State::AwaitInitial => {
                let mut p = truth;
                p.version = v;
                v += 1;
                ptx.write(p);
            }
            State::Operate => break,
            _ => {}
        }
    }
    assert_eq!(core.controller.state(), State::Operate, "{:?}", core.controller.fault());
    ctx.send(Command::MoveTo([0.3, 0.2, 2.1])).unwrap();
    let cycles = 200_000;
    let mut all = Vec::with_capacity(cycles);
    let mut swap = Vec::with_capacity(cycles);
    for i in 0..cycles {
        if i % 500 == 0 {
            let mut p = truth;
            p.version = v;
            p.anchors[0][0] += if v % 2 == 0 { 0.003 } else { -0.003 };
            v += 1;
            ptx.write(p);
        }
        t += dt;
        let c0 = monotonic_ns();
        core.cycle(t, dt);
        status_tx.write(i as u64);
        let c = monotonic_ns() - c0;
        all.push(c);
        if i % 500 < 2 {
            swap.push(c);
        }
        while srx.pop().is_some() {}
    }
    let name = match (kinematic, tension_side) {
        (true, false) => "with kinematic stand-in robot",
        (false, false) => "loop only (echo devices)",
        (true, true) => "with kinematic stand-in robot, tension side on",
        (false, true) => "loop only (echo devices), tension side on",
    };
    let max_swap = *swap.iter().max().unwrap() as f64 * 1e-3;
    println!(
        "cycle compute, {n} cables, {name}: p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us, max {:.1} us; longest swap-start cycle {:.1} us; max swap step {:.4} mm",
        pct(&mut all.clone(), 0.5),
        pct(&mut all.clone(), 0.99),
        pct(&mut all.clone(), 0.999),
        pct(&mut all, 1.0),
        max_swap,
        core.controller.max_swap_step_m() * 1e3
    );
}

fn lateness_bench(fifo: bool, seconds: f64) {
    let rt = RtConfig { priority: if fifo { 80 } else { 0 }, lock_memory: fifo, ..Default::default() };
    let h = std::thread::spawn(move || {
        let setup = setup_current_thread(&rt);
        let mut p = Periodic::new(1_000_000);
        let n = (seconds * 1000.0) as usize;
        let mut late = Vec::with_capacity(n);
        for _ in 0..n {
            late.push(p.wait());
        }
        (setup, late, p.overruns)
    });
    let (setup, mut late, overruns) = h.join().unwrap();
    let label = if fifo {
        if setup.realtime {
            "SCHED_FIFO 80"
        } else {
            "SCHED_FIFO refused -> normal"
        }
    } else {
        "normal scheduler"
    };
    println!(
        "wake-up lateness at 1 kHz, {label}: p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us, overruns {overruns} in {} cycles",
        pct(&mut late.clone(), 0.5),
        pct(&mut late.clone(), 0.99),
        pct(&mut late.clone(), 0.999),
        pct(&mut late, 1.0),
        (seconds * 1000.0) as usize
    );
}

fn soak(seconds: f64) {
    let n = 4;
    let dir = std::env::temp_dir().join(format!("taut-soak-{}", std::process::id()));
    let mut cfg = quick_config(n, &dir);
    cfg.rt.rate_hz = 1000.0;
    cfg.rt.priority = 80;
    cfg.motion.excitation_s = seconds;
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let truth = truth_params(n, 0.1);
    let (mut ptx, prx) = triple_buffer(LoopParams::invalid(n));
    let (_ctx, crx) = crossbeam_channel::bounded(16);
    let (stx, mut srx) = sample_ring(cfg.rt.ring_capacity);
    let (status_tx, _status_rx) = triple_buffer(taut_io::runner::LoopStatus::initial(
        Controller::new(ccfg, || None, triple_buffer(LoopParams::invalid(n)).1).snapshot(0.0, &Inputs::new(n)),
    ));
    let core = LoopCore::new(n, KinematicRobot::new(truth, [0.2, 0.1, 2.0]), Controller::new(ccfg, move || crx.try_recv().ok(), prx), stx);
    let quit = Arc::new(AtomicBool::new(false));
    let q2 = quit.clone();
    let busy = std::thread::spawn(move || {
        // A calibrator-like CPU hog: dense arithmetic on a growing data set.
        let mut v: Vec<f64> = Vec::new();
        let mut acc = 0.0;
        while !q2.load(Ordering::Relaxed) {
            v.push(acc);
            if v.len() > 1 << 20 {
                v.clear();
            }
            for x in v.iter().rev().take(10_000) {
                acc = (acc + x.sin()).fract();
            }
        }
        acc
    });
    let q3 = quit.clone();
    let drained = std::thread::spawn(move || {
        let mut k = 0u64;
        let mut published = false;
        while !q3.load(Ordering::Relaxed) {
            while let Some(s) = srx.pop() {
                k += 1;
                if !published && State::from_u8(s.state) == State::AwaitInitial {
                    let mut p = truth;
                    p.version = 1;
                    ptx.write(p);
                    published = true;
                }
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        (k, srx.dropped())
    });
    let t0 = Instant::now();
    let q4 = quit.clone();
    let stopper = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_secs_f64(seconds + 20.0));
        q4.store(true, Ordering::Relaxed);
    });
    let rep = taut_io::runner::run_loop(&cfg.rt, core, status_tx, quit.clone(), &|w| eprintln!("warning: {w}"));
    quit.store(true, Ordering::Relaxed);
    let (k, dropped) = drained.join().unwrap();
    let _ = busy.join();
    let _ = stopper.join();
    println!(
        "soak {:.0} s at 1 kHz with a busy thread: {} cycles, {} samples drained, {} dropped, overruns {}, max lateness {:.1} us, max compute {:.1} us, realtime {}",
        t0.elapsed().as_secs_f64(),
        rep.cycles,
        k,
        dropped,
        rep.overruns,
        rep.max_late_ns as f64 * 1e-3,
        rep.max_compute_ns as f64 * 1e-3,
        rep.setup.realtime
    );
}

/// The device side of a cycle on the hardware code path: `RobotDevices::read` + `write` (drain
/// the TPDOs, master events and state, mode and targets, RPDOs + SYNC out) with `n` virtual CiA
/// 402 drives answering on their own thread over the in-process virtual bus, drives enabled and
/// following position targets, at 1 kHz.
fn canopen_io_bench(n: usize, cycles: usize) {
    use taut_driver::transport::virtual_bus::VirtualBus;
    use taut_io::robot_io::{Peripherals, RobotDevices};
    use taut_vdev::{rack_filters, spawn_rack, DriveParams, VirtualDrive};

    let mut t = String::from("[robot]\nname = \"bench\"\nmass_kg = 3.0\n[can]\ninterface = \"vcan0\"\ncycle_s = 0.001\n");
    for j in 0..n {
        let a = std::f64::consts::TAU * j as f64 / n as f64;
        t += &format!(
            "[[cable]]\nanchor = [{}, {}, 4.0]\n[cable.drive]\nnode_id = {}\npdo = \"with_mode\"\n",
            3.0 * a.cos(),
            3.0 * a.sin(),
            j + 1
        );
    }
    let cfg = taut_config::RobotConfig::from_toml_str(&t).unwrap();
    let bus = VirtualBus::new();
    let nodes: Vec<u8> = (1..=n as u8).collect();
    let master_end = bus.endpoint_with(1024, &[]);
    let rack = spawn_rack(
        bus.endpoint_with(1024, &rack_filters(&nodes)),
        nodes.iter().map(|&id| VirtualDrive::new(DriveParams::new(id))).collect(),
    );
    let mut dev = RobotDevices::bring_up(&cfg, master_end, Peripherals { loadcells: None, tracker: None, pose: None }).unwrap();
    let mut inp = Inputs::new(n);
    let mut out = Outputs::new(n);
    out.request = DriveRequest::Enable;
    let t0 = std::time::Instant::now();
    let mut all = Vec::with_capacity(cycles);
    let mut enabled = 0usize;
    for k in 0..cycles {
        let deadline = t0 + std::time::Duration::from_micros(1000 * (k as u64 + 1));
        for j in 0..n {
            out.cable[j] = CableCommand::Position(1.0 + 1e-5 * k as f64);
        }
        let now = t0.elapsed().as_secs_f64();
        let c0 = monotonic_ns();
        dev.read(now, &mut inp);
        dev.write(now, &out);
        all.push(monotonic_ns() - c0);
        enabled += usize::from(inp.drive[..n].iter().all(|d| *d == DriveStatus::Enabled));
        if let Some(d) = deadline.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(d);
        }
    }
    rack.stop();
    println!(
        "device I/O per cycle, {n} CiA 402 drives over the virtual bus (RobotDevices read + write): p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us, max {:.1} us; enabled in {enabled} of {cycles} cycles",
        pct(&mut all.clone(), 0.5),
        pct(&mut all.clone(), 0.99),
        pct(&mut all.clone(), 0.999),
        pct(&mut all, 1.0),
    );
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    for n in [4, 8] {
        compute_bench(n, false);
        compute_bench(n, true);
    }
    for n in [4, 8] {
        canopen_io_bench(n, 20_000);
    }
    let secs = std::env::var("RT_LATENCY_S").ok().and_then(|s| s.parse().ok()).unwrap_or(10.0);
    lateness_bench(false, secs);
    lateness_bench(true, secs);
    if let Some(s) = std::env::var("RT_SOAK_S").ok().and_then(|s| s.parse::<f64>().ok()) {
        soak(s);
    }
}
