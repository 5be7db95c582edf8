//! Real-time priority for the device I/O threads.
//!
//! A device thread that feeds the loop's safety checks (the load cells: a tension older than
//! `safety.tension_max_age_s` latches a hold) has a deadline too. Under the normal scheduler a
//! loaded machine stretches its transactions until healthy readings go stale; `SCHED_FIFO` just
//! below the loop keeps them fresh (`cargo run -p taut-simrig --example loadcell_ages`).

use std::os::unix::thread::JoinHandleExt;
use std::thread::JoinHandle;

/// Puts a running thread under `SCHED_FIFO` at `priority` (1..=99). Fails without
/// `CAP_SYS_NICE` or an `RLIMIT_RTPRIO` that allows it (the caller says what to do).
pub fn set_fifo<T>(thread: &JoinHandle<T>, priority: i32) -> std::io::Result<()> {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: the pthread_t belongs to a thread that has not been joined (we hold its handle);
    // `param` outlives the call.
    let rc = unsafe { libc::pthread_setschedparam(thread.as_pthread_t(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::from_raw_os_error(rc))
    }
}
