//! The plugin's `update` allocates and frees nothing: a counting global allocator watches every
//! `update` / `update_with` call of the simulated robot's whole start-up (enable, three phases,
//! initial estimate, excitation, calibration, hot-swap), an operator's recalibration, estop and
//! reset from another thread, and the stop, in host-owned mode (the test is the host: it reads
//! the simulated devices and passes the readings in) and in plugin-owned mode (the plugin reads
//! and writes the simulated CANopen drives, load cells and tracker itself). The event queue is
//! kept tiny and never polled during the run, so its drop path is exercised too.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use taut_io::rtsys::{monotonic_ns, Periodic};
use taut_plugin::{DeviceMode, HostInputs, HostOutputs, Plugin, PluginHandle, PluginOptions, RecordingPath, Tick};
use taut_rt::io::{Devices, Inputs};
use taut_rt::motion::State;
use taut_tests::startup;

// The counting global allocator of this test binary (one per binary): `crate::counting`.
use crate::counting::{ALLOCS, FREES, WATCHING};

/// One simulated robot at a time: two at once on a loaded machine make the start-up's timing
/// (and so the test) depend on the other. The lock is this binary's `MEMORY`: a robot's start-up
/// allocates much, and `hostile_ctl`'s memory test reads the process's resident size.
use crate::MEMORY as ONE_AT_A_TIME;

fn watched<T>(f: impl FnOnce() -> T) -> T {
    WATCHING.with(|w| w.set(true));
    let r = f();
    WATCHING.with(|w| w.set(false));
    r
}

fn hot_swapped(h: &PluginHandle) -> bool {
    startup::hot_swapped(&h.loop_status(), &h.calib_status())
}

/// Runs the whole script, calling `cycle` once per period (it does the watched update); returns
/// the states seen.
fn script(p: &mut Plugin, rate_hz: f64, mut cycle: impl FnMut(&mut Plugin, f64, f64) -> Tick) -> Vec<State> {
    // This thread is the host's real-time loop: under SCHED_FIFO as a controller runs it (as
    // root; otherwise a warning and the normal scheduler), so that other work on the machine does
    // not starve the cycles the start-up is timed by.
    let rt = taut_config::runtime::RtConfig { priority: startup::REALTIME_PRIORITY, lock_memory: false, ..Default::default() };
    for w in taut_io::rtsys::setup_current_thread(&rt).warnings {
        eprintln!("plugin_alloc: {w}");
    }
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
    let ok = run_until(p, Duration::from_secs(300), &mut || startup::start_up_over(&h.loop_status(), &h.calib_status()));
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
    let cfg = startup::sim_robot(dir.path());
    let mut sim = startup::build_at_rest(&cfg, 7);
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
    let cfg = startup::sim_robot(dir.path());
    let sim = startup::build_at_rest(&cfg, 8);
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
