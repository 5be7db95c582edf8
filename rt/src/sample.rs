//! The samples the loop hands to the calibrator, and the lock-free ring that carries them.
//!
//! The ring is taut's own fixed-capacity single-producer single-consumer ring ([`crate::spsc`]),
//! allocated once at start-up and checked under `loom` (`scripts/loom`). A full ring never blocks
//! the loop: the sample is dropped and counted.

use crate::io::{CableCommand, DriveStatus};
use crate::safety::{Cause, Reaction};
use crate::spsc::{self, Consumer, Producer};
use crate::MAX_CABLES;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// One tension-tagged sample per loop cycle. `Copy`, fixed size.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// Loop time, s.
    pub t: f64,
    /// Number of cables.
    pub n: u8,
    /// Motion state ([`crate::motion::State`] as `u8`).
    pub state: u8,
    /// Initialisation phase, -1 outside.
    pub phase: i8,
    /// Calibration run: 0 for the start-up, +1 for every recalibration.
    pub run: u16,
    /// Encoder lengths, m.
    pub length_m: [f64; MAX_CABLES],
    /// Their ages, s.
    pub length_age_s: [f64; MAX_CABLES],
    /// Tensions, N.
    pub tension_n: [f64; MAX_CABLES],
    /// Their ages, s.
    pub tension_age_s: [f64; MAX_CABLES],
    /// Drive states.
    pub drive: [DriveStatus; MAX_CABLES],
    /// Tracker position, m.
    pub pose_m: [f64; 3],
    /// Its age, s.
    pub pose_age_s: f64,
    /// What the loop commanded each cable this cycle (length or tension).
    pub cmd: [CableCommand; MAX_CABLES],
    /// The latched safety cause and reaction, if any.
    pub fault: Option<(Cause, Reaction)>,
    /// Version of the parameters the loop runs on.
    pub params_version: u64,
}

impl Sample {
    /// An empty sample of `n` cables.
    pub fn empty(n: usize) -> Sample {
        Sample {
            t: 0.0,
            n: n as u8,
            state: 0,
            phase: -1,
            run: 0,
            length_m: [f64::NAN; MAX_CABLES],
            length_age_s: [f64::INFINITY; MAX_CABLES],
            tension_n: [f64::NAN; MAX_CABLES],
            tension_age_s: [f64::INFINITY; MAX_CABLES],
            drive: [DriveStatus::Unknown; MAX_CABLES],
            pose_m: [f64::NAN; 3],
            pose_age_s: f64::INFINITY,
            cmd: [CableCommand::Idle; MAX_CABLES],
            fault: None,
            params_version: 0,
        }
    }
}

/// The loop's end of the ring.
pub struct SampleTx {
    prod: Producer<Sample>,
    dropped: Arc<AtomicU64>,
    pushed: Arc<AtomicU64>,
}

/// The calibrator's end of the ring.
pub struct SampleRx {
    cons: Consumer<Sample>,
    dropped: Arc<AtomicU64>,
    pushed: Arc<AtomicU64>,
}

/// A ring of `capacity` samples (allocated here, once).
///
/// # Panics
/// If `capacity` is 0 (the runtime configuration refuses fewer than 16).
pub fn sample_ring(capacity: usize) -> (SampleTx, SampleRx) {
    let (prod, cons) = spsc::ring::<Sample>(capacity);
    let dropped = Arc::new(AtomicU64::new(0));
    let pushed = Arc::new(AtomicU64::new(0));
    (SampleTx { prod, dropped: dropped.clone(), pushed: pushed.clone() }, SampleRx { cons, dropped, pushed })
}

impl SampleTx {
    /// Pushes a sample; a full ring drops it and counts it. Never blocks, never allocates.
    #[inline]
    pub fn push(&mut self, s: &Sample) -> bool {
        match self.prod.push(*s) {
            Ok(()) => {
                // Relaxed: a statistic; the sample itself is published by the ring's Release store.
                self.pushed.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(_) => {
                // Relaxed: a statistic read for status output only.
                self.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Samples dropped because the ring was full.
    pub fn dropped(&self) -> u64 {
        // Relaxed: a statistic.
        self.dropped.load(Ordering::Relaxed)
    }
}

impl SampleRx {
    /// Takes the oldest sample, if any.
    #[inline]
    pub fn pop(&mut self) -> Option<Sample> {
        self.cons.pop()
    }

    /// Samples dropped so far because the ring was full.
    pub fn dropped(&self) -> u64 {
        // Relaxed: a statistic.
        self.dropped.load(Ordering::Relaxed)
    }

    /// Samples pushed so far.
    pub fn pushed(&self) -> u64 {
        // Relaxed: a statistic.
        self.pushed.load(Ordering::Relaxed)
    }

    /// A handle on the dropped counter, for status output from another thread.
    pub fn dropped_counter(&self) -> Arc<AtomicU64> {
        self.dropped.clone()
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    #[test]
    fn full_ring_counts_drops_and_keeps_order() {
        let (mut tx, mut rx) = sample_ring(4);
        for i in 0..6 {
            let mut s = Sample::empty(3);
            s.t = i as f64;
            tx.push(&s);
        }
        assert_eq!(tx.dropped(), 2);
        let got: Vec<f64> = std::iter::from_fn(|| rx.pop()).map(|s| s.t).collect();
        assert_eq!(got, vec![0.0, 1.0, 2.0, 3.0]);
        assert_eq!(rx.pushed(), 4);
    }
}
