//! Operating-system set-up of the loop thread and its periodic clock: `mlockall`, `SCHED_FIFO`,
//! CPU affinity, and absolute-time wake-ups with `clock_nanosleep(TIMER_ABSTIME)`.
//!
//! Set-up runs once, before the loop. A missing permission (no `CAP_SYS_NICE`, `LimitRTPRIO` or
//! `LimitMEMLOCK`) is a warning and the loop runs unprivileged, with more jitter.

use taut_config::runtime::RtConfig;

/// What the set-up achieved; `warnings` says what did not work and what to do.
#[derive(Debug, Clone, Default)]
pub struct RtSetupReport {
    /// Memory locked.
    pub memory_locked: bool,
    /// `SCHED_FIFO` at the configured priority.
    pub realtime: bool,
    /// Pinned to the configured CPU.
    pub pinned: bool,
    /// One line per thing that did not work.
    pub warnings: Vec<String>,
}

/// Applies the configuration to the calling thread (and `mlockall` to the process).
pub fn setup_current_thread(cfg: &RtConfig) -> RtSetupReport {
    let mut r = RtSetupReport::default();
    if cfg.lock_memory {
        // SAFETY: plain system call without pointers.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
            r.memory_locked = true;
        } else {
            r.warnings.push(format!(
                "mlockall failed ({}): memory may be paged out; raise LimitMEMLOCK (see deploy/taut.service) or run with CAP_IPC_LOCK",
                std::io::Error::last_os_error()
            ));
        }
    }
    prefault_stack();
    if cfg.priority > 0 {
        let param = libc::sched_param { sched_priority: cfg.priority };
        // SAFETY: `param` outlives the call; pthread_self is the calling thread.
        let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
        if rc == 0 {
            r.realtime = true;
        } else {
            r.warnings.push(format!(
                "SCHED_FIFO priority {} refused ({}): the loop runs with the normal scheduler; set LimitRTPRIO=99 (deploy/taut.service) or grant CAP_SYS_NICE",
                cfg.priority,
                std::io::Error::from_raw_os_error(rc)
            ));
        }
    }
    if let Some(cpu) = cfg.cpu {
        // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET bounds-checks nothing, so the
        // index is checked first.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            if cpu < libc::CPU_SETSIZE as usize {
                libc::CPU_SET(cpu, &mut set);
                if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
                    r.pinned = true;
                }
            }
        }
        if !r.pinned {
            r.warnings
                .push(format!("cannot pin the loop to CPU {cpu} ({}): rt.cpu must name an online CPU", std::io::Error::last_os_error()));
        }
    }
    r
}

/// Touches 256 KiB of stack so that the loop never page-faults on it.
fn prefault_stack() {
    let mut buf = [0u8; 256 * 1024];
    // Volatile writes so the buffer is not optimised away.
    for i in (0..buf.len()).step_by(4096) {
        // SAFETY: in bounds.
        unsafe { std::ptr::write_volatile(buf.as_mut_ptr().add(i), 1) };
    }
    std::hint::black_box(&buf);
}

/// Monotonic time, ns.
#[inline]
pub fn monotonic_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// A periodic wake-up on absolute times: the period does not drift with the loop's own work.
pub struct Periodic {
    next_ns: i64,
    period_ns: i64,
    /// Periods missed entirely (the loop woke up more than one period late).
    pub overruns: u64,
}

impl Periodic {
    /// First wake-up one period from now.
    pub fn new(period_ns: i64) -> Periodic {
        Periodic { next_ns: monotonic_ns() + period_ns, period_ns, overruns: 0 }
    }

    /// Sleeps until the next period starts; returns how late the wake-up was, ns.
    pub fn wait(&mut self) -> i64 {
        let ts = libc::timespec { tv_sec: self.next_ns / 1_000_000_000, tv_nsec: self.next_ns % 1_000_000_000 };
        loop {
            // SAFETY: `ts` is valid; the remainder pointer may be null with TIMER_ABSTIME.
            let rc = unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
            if rc != libc::EINTR {
                break;
            }
        }
        let now = monotonic_ns();
        let late = now - self.next_ns;
        self.next_ns += self.period_ns;
        if now >= self.next_ns {
            // Overrun: skip the periods already gone rather than running them back to back.
            let missed = (now - self.next_ns) / self.period_ns + 1;
            self.overruns += missed as u64;
            self.next_ns += missed * self.period_ns;
        }
        late
    }
}

static STOP_SIGNAL: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_stop_signal(_: libc::c_int) {
    // Relaxed: async-signal-safe store; the poller only needs to see it eventually.
    STOP_SIGNAL.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Makes SIGINT and SIGTERM set a flag instead of killing the process, so the daemon can hold and
/// disable the drives before it exits. Poll with [`stop_requested`].
pub fn install_stop_signals() {
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, on_stop_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_stop_signal as *const () as libc::sighandler_t);
    }
}

/// True once SIGINT or SIGTERM arrived (after [`install_stop_signals`]).
pub fn stop_requested() -> bool {
    // Relaxed: see on_stop_signal.
    STOP_SIGNAL.load(std::sync::atomic::Ordering::Relaxed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn periodic_wakes_on_schedule() {
        let mut p = Periodic::new(1_000_000);
        let t0 = monotonic_ns();
        for _ in 0..20 {
            let late = p.wait();
            assert!(late >= 0);
        }
        let el = monotonic_ns() - t0;
        assert!(el >= 19_000_000, "{el}");
    }

    #[test]
    fn unprivileged_setup_warns_instead_of_failing() {
        let r = setup_current_thread(&RtConfig { lock_memory: false, priority: 0, ..Default::default() });
        assert!(r.warnings.is_empty());
        assert!(!r.realtime);
    }
}
