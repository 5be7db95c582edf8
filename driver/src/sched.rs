//! Real-time priority for the device I/O threads.
//!
//! A device thread that feeds the real-time loop's safety checks (the load cells: a tension older
//! than `safety.tension_max_age_s` latches a hold) has a deadline too. With the normal scheduler
//! it competes with everything else on the machine: on a loaded two-core machine a Modbus
//! transaction (three wake-ups: the t3.5 pause, the device, the answer) then took ~16 ms instead
//! of ~2 ms, and readings went 100-300 ms stale with every device healthy. Under `SCHED_FIFO`
//! just below the loop the same thread kept every reading under 100 ms (measured with
//! `cargo run -p taut-simrig --example loadcell_ages` under load 10-12).

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
