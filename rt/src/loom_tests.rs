//! `loom` model tests of the lock-free hand-overs: the triple buffer ([`crate::triple`]) and the
//! sample ring ([`crate::spsc`], [`crate::sample`]). Loom runs each closure under every
//! interleaving of the threads (up to a preemption bound) and every outcome the C++11 memory
//! model allows the chosen orderings, and fails if two accesses to the same slot are not ordered
//! by a happens-before edge. Built and run only with `RUSTFLAGS="--cfg loom"`: `scripts/loom`.

use crate::sample::{sample_ring, Sample};
use crate::spsc;
use crate::sync::{Arc, AtomicUsize, Ordering};
use crate::triple::triple_buffer;
use crate::MAX_CABLES;
use loom::thread;

/// Every test's model: exhaustive over all interleavings (no preemption bound; the whole suite
/// explores in a few seconds). `LOOM_MAX_PREEMPTIONS=N scripts/loom` bounds it, as loom's
/// `Builder::new` reads that and the other `LOOM_*` settings from the environment.
fn model(f: impl Fn() + Sync + Send + 'static) {
    loom::model::Builder::new().check(f);
}

/// A value whose halves must agree: a torn read (half old, half new) shows as a mismatch.
type Pair = [u64; 2];

#[test]
fn loom_triple_reader_sees_whole_fresh_monotonic_written_values() {
    model(|| {
        let (mut w, mut r) = triple_buffer::<Pair>([0, 0]);
        // The newest version whose `write` has returned; the writer stores it after each write.
        let done = Arc::new(AtomicUsize::new(0));
        let done_w = done.clone();
        let writer = thread::spawn(move || {
            for v in 1..=3u64 {
                let displaced = w.write([v, v]);
                // What comes back is an older value the reader has given up, never the new one.
                assert_eq!(displaced[0], displaced[1], "torn value returned to the writer");
                assert!(displaced[0] < v, "write {v} displaced {displaced:?}");
                // Release: orders the write above before a reader's Acquire load of `done`.
                done_w.store(v as usize, Ordering::Release);
            }
        });
        let mut last = 0;
        for _ in 0..3 {
            // Acquire: a `write` that has returned happens-before what we read next.
            let seen = done.load(Ordering::Acquire) as u64;
            let v = *r.read();
            assert_eq!(v[0], v[1], "torn read {v:?}");
            assert!(v[0] <= 3, "read {v:?}, which was never written");
            assert!(v[0] >= seen, "stale read {v:?} after write {seen} returned");
            assert!(v[0] >= last, "went back from {last} to {v:?}");
            last = v[0];
        }
        writer.join().unwrap();
        assert_eq!(*r.read(), [3, 3], "the last value is not lost");
        assert!(!r.update(), "nothing newer after the last value was taken");
    });
}

#[test]
fn loom_triple_update_then_current_holds_the_taken_value() {
    model(|| {
        let (mut w, mut r) = triple_buffer::<Pair>([0, 0]);
        let writer = thread::spawn(move || {
            w.write([1, 1]);
            w.write([2, 2]);
        });
        let mut last = 0;
        for _ in 0..2 {
            let fresh = r.update();
            let a = *r.current();
            // The writer keeps writing; `current` must still be the value `update` took.
            let b = *r.current();
            assert_eq!(a, b, "current changed without update");
            assert_eq!(a[0], a[1], "torn read {a:?}");
            assert!(a[0] >= last && (fresh || a[0] == last), "update said {fresh}, value {a:?}, before {last}");
            last = a[0];
        }
        writer.join().unwrap();
        r.update();
        assert_eq!(*r.current(), [2, 2]);
    });
}

/// Producer pushes `0..n` into a ring of `cap`; the consumer pops `tries` times meanwhile and
/// drains after the join. Checks FIFO order, no duplicate, no loss except refused pushes (which
/// hand the same value back), no torn value.
fn spsc_case(cap: usize, n: u64, tries: usize) {
    model(move || {
        let (mut tx, mut rx) = spsc::ring::<[u64; 4]>(cap);
        let producer = thread::spawn(move || {
            let mut accepted = Vec::new();
            for i in 0..n {
                match tx.push([i; 4]) {
                    Ok(()) => accepted.push(i),
                    Err(back) => {
                        assert_eq!(back, [i; 4], "a refused push hands back its own value")
                    }
                }
            }
            accepted
        });
        let mut got = Vec::new();
        for _ in 0..tries {
            if let Some(v) = rx.pop() {
                got.push(v);
            }
        }
        let accepted = producer.join().unwrap();
        while let Some(v) = rx.pop() {
            got.push(v);
        }
        for v in &got {
            assert!(v.iter().all(|&x| x == v[0]), "torn value {v:?}");
        }
        let got: Vec<u64> = got.iter().map(|v| v[0]).collect();
        assert_eq!(got, accepted, "cap {cap}: popped values differ from accepted pushes");
        // The first `cap` pushes always fit.
        assert!(accepted.len() >= cap.min(n as usize), "cap {cap}: only {accepted:?} accepted");
    });
}

#[test]
fn loom_spsc_capacity_1_wraps_the_position_range() {
    spsc_case(1, 3, 2);
}

#[test]
fn loom_spsc_capacity_2() {
    spsc_case(2, 4, 3);
}

#[test]
fn loom_spsc_capacity_3() {
    spsc_case(3, 4, 2);
}

#[test]
fn loom_sample_ring_counts_drops_and_keeps_order() {
    model(|| {
        let (mut tx, mut rx) = sample_ring(2);
        let producer = thread::spawn(move || {
            let mut accepted = Vec::new();
            for i in 0..3u8 {
                let mut s = Sample::empty(MAX_CABLES);
                s.t = f64::from(i);
                s.length_m = [f64::from(i); MAX_CABLES];
                s.tension_n = [f64::from(i); MAX_CABLES];
                if tx.push(&s) {
                    accepted.push(f64::from(i));
                }
            }
            (accepted, tx.dropped())
        });
        let mut got = Vec::new();
        for _ in 0..2 {
            got.extend(rx.pop());
        }
        let (accepted, dropped_tx) = producer.join().unwrap();
        got.extend(std::iter::from_fn(|| rx.pop()));
        for s in &got {
            assert!(s.length_m.iter().chain(&s.tension_n).all(|&x| x == s.t), "torn sample at t={}", s.t);
        }
        let got: Vec<f64> = got.iter().map(|s| s.t).collect();
        assert_eq!(got, accepted);
        assert_eq!(rx.pushed(), accepted.len() as u64);
        assert_eq!(rx.dropped(), dropped_tx);
        assert_eq!(rx.pushed() + rx.dropped(), 3, "every push is either carried or counted as dropped");
    });
}
