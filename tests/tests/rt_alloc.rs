//! The loop thread allocates and frees nothing after start-up: a counting global allocator
//! watches 100,000+ cycles through every state, parameter swaps, safety reactions and a full
//! sample ring.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use taut_rt_core::io::DeviceFault;
use taut_rt_core::kin::LoopParams;
use taut_rt_core::motion::{Command, Controller, ControllerConfig, State};
use taut_rt_core::runner::LoopCore;
use taut_rt_core::sample::sample_ring;
use taut_rt_core::testkit::{quick_config, truth_params, KinematicRobot};
use taut_rt_core::triple::triple_buffer;

struct Counting;

thread_local! {
    // const-initialised thread locals need no allocation on first use.
    static WATCHING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
    static FREES: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = WATCHING.try_with(|w| {
            if w.get() {
                ALLOCS.with(|a| a.set(a.get() + 1));
            }
        });
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        let _ = WATCHING.try_with(|w| {
            if w.get() {
                FREES.with(|a| a.set(a.get() + 1));
            }
        });
        System.dealloc(p, l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        let _ = WATCHING.try_with(|w| {
            if w.get() {
                ALLOCS.with(|a| a.set(a.get() + 1));
            }
        });
        System.realloc(p, l, n)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn loop_allocates_nothing_in_any_state() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = quick_config(4, dir.path());
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let truth = truth_params(4, 0.1);
    let (mut params_tx, params_rx) = triple_buffer(LoopParams::invalid(4));
    let (cmd_tx, cmd_rx) = taut_rt_core::crossbeam_channel::bounded(16);
    // A small ring nobody drains: it is full for most of the run, so drops are exercised too.
    let (sample_tx, _sample_rx) = sample_ring(1024);
    let robot = KinematicRobot::new(truth, [0.2, 0.1, 2.0]);
    let mut core = LoopCore::new(4, robot, Controller::new(ccfg, cmd_rx, params_rx), sample_tx);

    let dt = 0.002;
    let mut t = 0.0;
    let mut seen = std::collections::BTreeSet::new();
    let cycles = Cell::new(0u64);
    let mut run = |core: &mut LoopCore<KinematicRobot>, k: usize, seen: &mut std::collections::BTreeSet<u8>| {
        for _ in 0..k {
            t += dt;
            WATCHING.with(|w| w.set(true));
            core.cycle(t, dt);
            WATCHING.with(|w| w.set(false));
            seen.insert(core.controller.state() as u8);
            cycles.set(cycles.get() + 1);
        }
    };
    let initial = |v: u64, off: f64| {
        let mut p = truth;
        p.version = v;
        for a in p.anchors.iter_mut().take(4) {
            a[0] += off;
        }
        p
    };

    // Enable and the three phases.
    run(&mut core, 1, &mut seen);
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::AwaitInitial {
            break;
        }
    }
    assert_eq!(core.controller.state(), State::AwaitInitial, "{:?}", core.controller.fault());
    run(&mut core, 50, &mut seen);
    // Initial estimate -> excitation -> operate.
    params_tx.write(initial(1, 0.01));
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::Operate {
            break;
        }
    }
    assert_eq!(core.controller.state(), State::Operate, "{:?}", core.controller.fault());
    // Calibrated parameters: a swap while operating, and a move.
    params_tx.write(initial(2, 0.0));
    run(&mut core, 1000, &mut seen);
    cmd_tx.send(Command::MoveTo([0.5, 0.2, 2.0])).unwrap();
    run(&mut core, 3000, &mut seen);
    // Recalibration run with another swap during its excitation.
    cmd_tx.send(Command::Recalibrate).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Excitation);
    params_tx.write(initial(3, 0.002));
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::Operate {
            break;
        }
    }
    // Safety reactions of each kind, each followed by a reset.
    cmd_tx.send(Command::Estop).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Faulted);
    cmd_tx.send(Command::Reset).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Holding);
    core.devices.inject.tension_bias_n = 1000.0;
    run(&mut core, 200, &mut seen);
    core.devices.inject.tension_bias_n = 0.0;
    cmd_tx.send(Command::Reset).unwrap();
    core.devices.inject.fault = Some(DeviceFault::Emcy { node: 2, code: 0x2310 });
    run(&mut core, 200, &mut seen);
    core.devices.inject.fault = Some(DeviceFault::BusOff);
    run(&mut core, 200, &mut seen);
    core.devices.inject.fault = None;
    cmd_tx.send(Command::Reset).unwrap();
    core.devices.inject.loadcells_silent = true;
    run(&mut core, 200, &mut seen);
    core.devices.inject.loadcells_silent = false;
    cmd_tx.send(Command::Reset).unwrap();
    run(&mut core, 10, &mut seen);
    // Long holding/operating stretch with swaps every few hundred cycles.
    let mut v = 4;
    cmd_tx.send(Command::MoveTo([0.0, 0.0, 2.2])).unwrap();
    while cycles.get() < 110_000 {
        params_tx.write(initial(v, if v % 2 == 0 { 0.001 } else { 0.0 }));
        v += 1;
        run(&mut core, 400, &mut seen);
    }
    cmd_tx.send(Command::Stop).unwrap();
    run(&mut core, 20, &mut seen);
    assert!(core.controller.finished());

    let allocs = ALLOCS.with(|a| a.get());
    let frees = FREES.with(|a| a.get());
    let cycles = cycles.get();
    assert!(cycles >= 100_000);
    for s in [State::Enabling, State::InitPhase, State::AwaitInitial, State::Excitation, State::Operate, State::Holding, State::Faulted, State::Stopped] {
        assert!(seen.contains(&(s as u8)), "state {s:?} not visited");
    }
    assert!(core.dropped() > 0, "the ring never filled");
    assert_eq!((allocs, frees), (0, 0), "the loop allocated {allocs} times and freed {frees} times in {cycles} cycles");
}

#[test]
fn the_counter_sees_allocations() {
    WATCHING.with(|w| w.set(true));
    let v = std::hint::black_box(vec![1u8; 10]);
    drop(v);
    WATCHING.with(|w| w.set(false));
    assert!(ALLOCS.with(|a| a.get()) >= 1 && FREES.with(|a| a.get()) >= 1);
}
