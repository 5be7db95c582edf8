//! SYNC producer (CiA 301 7.2.5): an empty frame on COB-ID 0x080 every cycle. Synchronous PDOs
//! are sampled (TPDO) and applied (RPDO) at each SYNC.

use crate::can::Frame;
use std::time::{Duration, Instant};

/// COB-ID of SYNC.
pub const SYNC_COB_ID: u16 = 0x080;

/// The SYNC frame (no counter: 0 data bytes).
pub fn frame() -> Frame {
    Frame::new(SYNC_COB_ID, &[])
}

/// True if `f` is a SYNC frame (with or without the 1-byte counter).
pub fn is_sync(f: &Frame) -> bool {
    f.std_id() == Some(SYNC_COB_ID) && f.dlc <= 1
}

/// Produces SYNC at a fixed period. The schedule advances by whole periods, so a late poll
/// does not shift the phase; cycles missed entirely are skipped and counted.
#[derive(Debug, Clone, Copy)]
pub struct SyncProducer {
    period: Duration,
    next: Option<Instant>,
    missed: u64,
}

impl SyncProducer {
    /// A producer with the given period; the first SYNC goes out at the first poll.
    pub fn new(period: Duration) -> Self {
        SyncProducer { period, next: None, missed: 0 }
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Returns true when a SYNC is due at `now` (and schedules the next one).
    pub fn poll(&mut self, now: Instant) -> bool {
        match self.next {
            None => {
                self.next = Some(now + self.period);
                true
            }
            Some(t) if now >= t => {
                let mut next = t + self.period;
                while next <= now {
                    next += self.period;
                    self.missed += 1;
                }
                self.next = Some(next);
                true
            }
            Some(_) => false,
        }
    }

    /// When the next SYNC is due.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.next
    }

    /// Cycles skipped because the caller polled more than a period late.
    pub fn missed(&self) -> u64 {
        self.missed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_phase_and_counts_missed_cycles() {
        let t0 = Instant::now();
        let p = Duration::from_millis(2);
        let mut s = SyncProducer::new(p);
        assert!(s.poll(t0));
        assert!(!s.poll(t0 + Duration::from_millis(1)));
        assert!(s.poll(t0 + Duration::from_micros(2100)));
        assert_eq!(s.next_deadline(), Some(t0 + 2 * p));
        assert!(s.poll(t0 + Duration::from_micros(9000)));
        assert_eq!(s.missed(), 2);
        assert_eq!(s.next_deadline(), Some(t0 + 5 * p));
        assert!(is_sync(&frame()));
    }
}
