//! The plugin's `update` allocates and frees nothing: a counting global allocator watches every
//! `update` / `update_with` call of the simulated robot's whole start-up (enable, three phases,
//! initial estimate, excitation, calibration, hot-swap), an operator's recalibration, estop and
//! reset from another thread, and the stop, in host-owned mode (the test is the host: it reads
//! the simulated devices and passes the readings in) and in plugin-owned mode (the plugin reads
//! and writes the simulated CANopen drives, load cells and tracker itself). The event queue is
//! kept tiny and never polled during the run, so its drop path is exercised too.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use taut_rt_core::calibrator::OutcomeKind;
use taut_rt_core::io::{Devices, Inputs};
use taut_rt_core::motion::{ControllerConfig, State};
use taut_rt_core::plugin::{DeviceMode, HostInputs, HostOutputs, Plugin, PluginHandle, PluginOptions, RecordingPath, Tick};
use taut_rt_core::rtsys::{monotonic_ns, Periodic};
use taut_rt_core::FromRobot;
use taut_simrig::{self as simrig, SimOptions};

struct Counting;

thread_local! {
    // const-initialised thread locals need no allocation on first use.
    static WATCHING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
    static FREES: Cell<u64> = const { Cell::new(0) };
}

fn count(c: &'static std::thread::LocalKey<Cell<u64>>) {
    let _ = WATCHING.try_with(|w| {
        if w.get() {
            c.with(|a| a.set(a.get() + 1));
        }
    });
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count(&ALLOCS);
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        count(&FREES);
        System.dealloc(p, l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count(&ALLOCS);
        System.realloc(p, l, n)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// One simulated robot at a time: two at once on a loaded machine make the start-up's timing
/// (and so the test) depend on the other.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn watched<T>(f: impl FnOnce() -> T) -> T {
    WATCHING.with(|w| w.set(true));
    let r = f();
    WATCHING.with(|w| w.set(false));
    r
}

fn sim_robot(dir: &std::path::Path) -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    cfg.motion.excitation_s = 25.0;
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

fn hot_swapped(h: &PluginHandle) -> bool {
    let (l, c) = (h.loop_status(), h.calib_status());
    c.outcomes.iter().any(|o| o.kind == OutcomeKind::Calibration && o.accepted && l.snap.params_version == o.version && !l.snap.swap_active)
}

/// Runs the whole script, calling `cycle` once per period (it does the watched update); returns
/// the states seen.
fn script(p: &mut Plugin, rate_hz: f64, mut cycle: impl FnMut(&mut Plugin, f64, f64) -> Tick) -> Vec<State> {
    let h = p.handle().clone();
    let mut timer = Periodic::new((1e9 / rate_hz) as i64);
    let t0 = monotonic_ns();
    let mut last = 0.0;
    let mut seen = Vec::new();
    let mut run_until = |p: &mut Plugin, timeout: Duration, pred: &mut dyn FnMut() -> bool| {
        let t = Instant::now();
        while t.elapsed() < timeout {
            timer.wait();
            let now = (monotonic_ns() - t0) as f64 * 1e-9;
            let dt = if last == 0.0 { 1.0 / rate_hz } else { now - last };
            last = now;
            let tick = cycle(p, now, dt);
            if seen.last() != Some(&tick.state) {
                seen.push(tick.state);
            }
            if pred() {
                return true;
            }
        }
        false
    };
    let ok = run_until(p, Duration::from_secs(300), &mut || {
        let l = h.loop_status();
        l.snap.fault.is_some() || h.calib_status().outcomes.iter().any(|o| !o.accepted) || hot_swapped(&h)
    });
    let l = h.loop_status();
    assert!(
        ok && hot_swapped(&h),
        "start-up did not end in a hot-swap: state {:?}, fault {:?}, stage {}, outcomes {:?}",
        l.snap.state,
        l.snap.fault,
        h.calib_status().stage,
        h.calib_status().outcomes.iter().map(|o| (o.kind, o.accepted, o.reason.clone())).collect::<Vec<_>>()
    );

    // The operator, from another thread, while the loop is watched.
    let stage = Arc::new(AtomicU8::new(0));
    let op = {
        let h = h.clone();
        let stage = stage.clone();
        std::thread::spawn(move || {
            let wait = |pred: &dyn Fn() -> bool| {
                let t = Instant::now();
                while !pred() && t.elapsed() < Duration::from_secs(60) {
                    std::thread::sleep(Duration::from_millis(10));
                }
            };
            h.request_recalibration().unwrap();
            wait(&|| h.status().state == State::Excitation);
            h.estop();
            wait(&|| h.status().fault.is_some());
            h.reset().unwrap();
            wait(&|| h.status().state == State::Holding);
            stage.store(1, Ordering::SeqCst);
        })
    };
    assert!(run_until(p, Duration::from_secs(90), &mut || stage.load(Ordering::SeqCst) == 1));
    op.join().unwrap();
    h.stop();
    assert!(run_until(p, Duration::from_secs(5), &mut || h.loop_status().snap.state == State::Stopped && h.loop_status().cycles > 0));
    // The stop's remaining cycles until the loop is finished.
    for _ in 0..20 {
        let now = (monotonic_ns() - t0) as f64 * 1e-9;
        cycle(p, now, 1.0 / rate_hz);
    }
    assert!(p.finished());
    seen
}

fn check(seen: &[State], h: &PluginHandle, what: &str) {
    // Plugin-owned, the drives are enabled by `activate` (not a real-time call): its first
    // `update` starts the first phase.
    let enabling: &[State] = if what == "host-owned" { &[State::Enabling] } else { &[] };
    let rest = [
        State::InitPhase,
        State::AwaitInitial,
        State::Excitation,
        State::Operate,
        State::Faulted,
        State::Resetting,
        State::Holding,
        State::Stopped,
    ];
    for s in enabling.iter().chain(&rest) {
        assert!(seen.contains(s), "{what}: state {s:?} not visited ({seen:?})");
    }
    assert!(h.events_dropped() > 0, "{what}: the event queue never filled");
    let (allocs, frees) = (ALLOCS.with(|a| a.get()), FREES.with(|a| a.get()));
    let cycles = h.loop_status().cycles;
    assert!(cycles > 10_000, "{what}: {cycles} cycles");
    assert_eq!((allocs, frees), (0, 0), "{what}: update allocated {allocs} times and freed {frees} times in {cycles} cycles");
}

#[test]
fn host_owned_update_allocates_nothing_through_a_whole_start_up() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_robot(dir.path());
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let so = SimOptions { seed: 7, ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0]);
    let mut sim = simrig::build(&cfg, p0, &so).unwrap();
    let n = cfg.cables.len();
    let opts = PluginOptions { recording: RecordingPath::At(dir.path().join("rec.csv")), event_capacity: 4, ..Default::default() };
    let mut p = Plugin::configure(&cfg, DeviceMode::Host, opts).unwrap();
    p.activate().unwrap();
    let h = p.handle().clone();
    let mut inputs = Inputs::new(n);
    let mut hin = HostInputs::default();
    let mut hout = HostOutputs::default();
    let seen = script(&mut p, cfg.rt.rate_hz, |p, now, dt| {
        // The host's device layer is the host's business: only the plugin's call is watched.
        inputs.fault = None;
        sim.devices.read(now, &mut inputs);
        hin = HostInputs::from_inputs(&inputs);
        let tick = watched(|| p.update_with(now, dt, &hin, &mut hout)).unwrap();
        sim.devices.write(now, &hout.to_outputs());
        tick
    });
    check(&seen, &h, "host-owned");
    p.deactivate().unwrap();
    p.cleanup().unwrap();
    drop(sim);
}

#[test]
fn plugin_owned_update_allocates_nothing_through_a_whole_start_up() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_robot(dir.path());
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let so = SimOptions { seed: 8, ..Default::default() };
    let p0 = simrig::rest_position(&cfg, &so, [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0]);
    let sim = simrig::build(&cfg, p0, &so).unwrap();
    let opts = PluginOptions { recording: RecordingPath::At(dir.path().join("rec.csv")), event_capacity: 4, ..Default::default() };
    let mut p = Plugin::configure(&cfg, DeviceMode::ready(sim.devices), opts).unwrap();
    p.activate().unwrap();
    let h = p.handle().clone();
    // The plugin's CANopen master, load-cell reader and tracker reader are inside the watch.
    let seen = script(&mut p, cfg.rt.rate_hz, |p, now, dt| watched(|| p.update(now, dt)).unwrap());
    check(&seen, &h, "plugin-owned");
    p.deactivate().unwrap();
    p.cleanup().unwrap();
}

#[test]
fn the_counter_sees_allocations() {
    let v = watched(|| std::hint::black_box(vec![1u8; 10]));
    watched(|| drop(v));
    assert!(ALLOCS.with(|a| a.get()) >= 1 && FREES.with(|a| a.get()) >= 1);
}
