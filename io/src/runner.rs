//! The periodic loop thread: real-time set-up of the calling thread, then one
//! [`LoopCore::cycle`] per period. The cycle and its types are `taut_rt::cycle`'s, re-exported
//! for [`run_loop`] and [`run_periodic`]; the clock, the thread and the stop flag are this side's.

pub use taut_rt::cycle::{LoopCore, LoopStatus, LoopTiming};

use crate::rtsys::{monotonic_ns, setup_current_thread, Periodic, RtSetupReport};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use taut_config::runtime::RtConfig;
use taut_rt::io::Devices;
use taut_rt::triple::Writer;

/// How the loop ended.
#[derive(Debug, Clone)]
pub struct LoopReport {
    /// What the real-time set-up achieved.
    pub setup: RtSetupReport,
    /// Cycles run.
    pub cycles: u64,
    /// Periods missed.
    pub overruns: u64,
    /// Largest wake-up lateness, ns.
    pub max_late_ns: i64,
    /// Largest compute time of one cycle, ns.
    pub max_compute_ns: i64,
}

/// Runs the loop on the calling thread until the controller has stopped or `quit` is set.
/// Real-time set-up happens here, first; warnings go to `warn` once.
pub fn run_loop<D: Devices>(
    rt: &RtConfig,
    mut core: LoopCore<D>,
    mut status: Writer<LoopStatus>,
    quit: Arc<AtomicBool>,
    warn: &dyn Fn(&str),
) -> LoopReport {
    let mut st = LoopStatus::initial(core.controller.snapshot(0.0, &core.inputs));
    run_periodic(rt, quit, warn, |now, dt, timing| {
        core.cycle(now, dt);
        st = LoopStatus { snap: core.controller.snapshot(now, &core.inputs), dropped: core.dropped(), ..timing.apply(st) };
        // The displaced value is a Copy struct: nothing is freed here.
        status.write(st);
        core.controller.finished()
    })
}

/// The periodic loop every host of the controller shares: real-time set-up of the calling
/// thread, then `cycle(now_s, period_s, timing)` once per period until it returns true
/// (finished) or `quit` is set. `now_s` counts from the first wake-up's period start.
pub fn run_periodic(
    rt: &RtConfig,
    quit: Arc<AtomicBool>,
    warn: &dyn Fn(&str),
    mut cycle: impl FnMut(f64, f64, &LoopTiming) -> bool,
) -> LoopReport {
    let setup = setup_current_thread(rt);
    for w in &setup.warnings {
        warn(w);
    }
    let period_ns = (1e9 / rt.rate_hz).round() as i64;
    let mut timer = Periodic::new(period_ns);
    let t0 = monotonic_ns();
    let mut last = 0.0;
    let mut tm = LoopTiming { realtime: setup.realtime, ..LoopTiming::default() };
    loop {
        let late = timer.wait();
        let c0 = monotonic_ns();
        let now = (c0 - t0) as f64 * 1e-9;
        let dt = if tm.cycles == 0 { period_ns as f64 * 1e-9 } else { now - last };
        last = now;
        tm.late_ns = late;
        tm.max_late_ns = tm.max_late_ns.max(late);
        tm.overruns = timer.overruns;
        let finished = cycle(now, dt, &tm);
        tm.cycles += 1;
        let compute = monotonic_ns() - c0;
        tm.max_compute_ns = tm.max_compute_ns.max(compute);
        // Relaxed: a stop request needs no ordering with other data; a cycle's delay is fine.
        if finished || quit.load(Ordering::Relaxed) {
            break;
        }
    }
    LoopReport { setup, cycles: tm.cycles, overruns: tm.overruns, max_late_ns: tm.max_late_ns, max_compute_ns: tm.max_compute_ns }
}
