//! Requests that must reach the loop whatever else is going on: emergency stop and stop.
//!
//! The control server sets a flag; the loop tests it at the start of every cycle and again
//! before each queued command, so neither a full command queue nor a slow client can hold an
//! estop back, and setting the flag never waits (one atomic store). The loop clears the flag
//! when it acts on it.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The urgent flags shared by the control server (writer) and the loop (reader).
#[derive(Debug, Default)]
pub struct Urgent {
    estop: AtomicBool,
    stop: AtomicBool,
    estops: AtomicU64,
}

// Every access is Relaxed: a flag is the whole message, no other memory is published with it.
// A command sent through the channel after the flag was set happens-after the store (the
// channel synchronises sender and receiver), so the loop's test after receiving that command
// sees the flag (write-read coherence) and the estop is never overtaken by a later command.
impl Urgent {
    /// Requests an emergency stop (quick stop, latched) at the loop's next cycle.
    pub fn estop(&self) {
        self.estop.store(true, Ordering::Relaxed);
        self.estops.fetch_add(1, Ordering::Relaxed);
    }

    /// Requests a controlled stop at the loop's next cycle.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Loop side: true once per requested estop (clears the flag). No allocation, no wait.
    #[inline]
    pub fn take_estop(&self) -> bool {
        // Cheap load first: the swap (a locked read-modify-write) only when set.
        self.estop.load(Ordering::Relaxed) && self.estop.swap(false, Ordering::Relaxed)
    }

    /// Loop side: true once per requested stop (clears the flag).
    #[inline]
    pub fn take_stop(&self) -> bool {
        self.stop.load(Ordering::Relaxed) && self.stop.swap(false, Ordering::Relaxed)
    }

    /// True while an estop is requested and not yet taken by the loop.
    pub fn estop_pending(&self) -> bool {
        self.estop.load(Ordering::Relaxed)
    }

    /// Estops requested so far.
    pub fn estops_requested(&self) -> u64 {
        self.estops.load(Ordering::Relaxed)
    }
}
