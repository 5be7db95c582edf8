//! Where the device code reads the time: the wall clock on the robot, or a simulated clock that
//! a lockstep simulation advances (`taut start --sim --sim-time`).
//!
//! Protocol timers take `now: Instant` (sans-IO); the few places that read the time themselves
//! (the drive set's bring-up, the Modbus master's silence and timeout, the reading ages) ask a
//! [`Clock`], so that one code path runs on both clocks.
//!
//! A [`SimClock`] is an `Instant` fixed at its creation plus a count of simulated nanoseconds:
//! `Instant` arithmetic, deadlines and ages then work unchanged, and two runs that advance the
//! clock by the same steps see the same durations, bit for bit.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A source of time.
pub trait Clock: Send + Sync {
    /// The current instant.
    fn now(&self) -> Instant;
    /// Lets `d` pass: the wall clock sleeps, a simulated clock advances.
    fn sleep(&self, d: Duration);
}

/// The operating system's monotonic clock.
#[derive(Debug, Clone, Copy, Default)]
pub struct WallClock;

impl Clock for WallClock {
    fn now(&self) -> Instant {
        Instant::now()
    }
    fn sleep(&self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// A simulated clock: its creation instant plus the simulated time advanced since, ns. Clones
/// share the count.
#[derive(Debug, Clone)]
pub struct SimClock {
    base: Instant,
    ns: Arc<AtomicU64>,
}

impl Default for SimClock {
    fn default() -> Self {
        SimClock::new()
    }
}

impl SimClock {
    /// A clock at simulated time zero.
    pub fn new() -> SimClock {
        SimClock { base: Instant::now(), ns: Arc::new(AtomicU64::new(0)) }
    }

    /// Simulated time since the clock's creation.
    pub fn elapsed(&self) -> Duration {
        // Relaxed: one thread advances and reads the clock in a lockstep run; other threads
        // (status readers) only need some recent value.
        Duration::from_nanos(self.ns.load(Ordering::Relaxed))
    }

    /// Simulated time of an instant of this clock (zero for instants before its start).
    pub fn since_start(&self, t: Instant) -> Duration {
        t.saturating_duration_since(self.base)
    }

    /// A clock of its own that starts at this clock's now, on the same time axis, and then
    /// advances independently (one transaction on a simulated line, run ahead of the rest).
    pub fn fork(&self) -> SimClock {
        SimClock { base: self.base, ns: Arc::new(AtomicU64::new(self.ns.load(Ordering::Relaxed))) }
    }

    /// Advances by `d`.
    pub fn advance(&self, d: Duration) {
        let ns = u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        self.ns.fetch_add(ns, Ordering::Relaxed);
    }

    /// Moves to `t` if that is later (a clock never goes back).
    pub fn advance_to(&self, t: Instant) {
        let ns = u64::try_from(self.since_start(t).as_nanos()).unwrap_or(u64::MAX);
        self.ns.fetch_max(ns, Ordering::Relaxed);
    }
}

impl Clock for SimClock {
    fn now(&self) -> Instant {
        self.base + self.elapsed()
    }
    fn sleep(&self, d: Duration) {
        self.advance(d);
    }
}

/// A shared clock, as the device layers hold it.
pub type SharedClock = Arc<dyn Clock>;

/// The wall clock as a [`SharedClock`].
pub fn wall() -> SharedClock {
    Arc::new(WallClock)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_simulated_clock_moves_only_when_advanced_and_never_back() {
        let c = SimClock::new();
        let t0 = c.now();
        std::thread::sleep(Duration::from_millis(2));
        assert_eq!(c.now(), t0, "wall time must not leak into a simulated clock");
        c.sleep(Duration::from_millis(5));
        assert_eq!(c.now() - t0, Duration::from_millis(5));
        c.advance_to(t0 + Duration::from_millis(1));
        assert_eq!(c.elapsed(), Duration::from_millis(5), "advance_to to an earlier instant is ignored");
        let shared = c.clone();
        shared.advance(Duration::from_micros(250));
        assert_eq!(c.elapsed(), Duration::from_micros(5250), "clones share the time");
    }
}
