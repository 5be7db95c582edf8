//! A fixed-capacity single-producer single-consumer ring of `Copy` values, in the manner of
//! `rtrb`: the buffer is allocated once, in [`ring`]; after that pushing and popping never
//! allocate, never block and never wait. A full ring hands the value back to the producer.
//!
//! Head (next slot to read) and tail (next slot to write) are positions in `0..2 * capacity`, so
//! that a full ring (`tail - head == capacity`) and an empty one (`tail == head`) differ without
//! a spare slot. Each side keeps a cached copy of the other side's index and reads the shared one
//! only when the cache says full (producer) or empty (consumer). The indices sit on separate cache
//! lines so that the two threads do not share a line they both write.
//!
//! ```
//! let (mut tx, mut rx) = taut_rt::spsc::ring::<u32>(2);
//! assert_eq!(tx.push(1), Ok(()));
//! assert_eq!(tx.push(2), Ok(()));
//! assert_eq!(tx.push(3), Err(3)); // full: the value comes back
//! assert_eq!(rx.pop(), Some(1));
//! assert_eq!(rx.pop(), Some(2));
//! assert_eq!(rx.pop(), None);
//! ```

use crate::sync::{Arc, AtomicUsize, Ordering, UnsafeCell};
use std::mem::MaybeUninit;

/// Keeps its contents on a cache line of their own (128 bytes covers the adjacent-line
/// prefetcher of x86 and the 128-byte lines of some ARM cores).
#[repr(align(128))]
struct Padded<T>(T);

struct Ring<T> {
    /// Position of the next value to pop; written only by the consumer.
    head: Padded<AtomicUsize>,
    /// Position of the next slot to fill; written only by the producer.
    tail: Padded<AtomicUsize>,
    slots: Box<[UnsafeCell<MaybeUninit<T>>]>,
}

// SAFETY: a slot between head and tail belongs to the consumer, any other slot to the producer;
// a slot changes hands only through a Release store of `tail` (producer to consumer) or `head`
// (consumer to producer) that the other side reads with Acquire before touching it.
unsafe impl<T: Send> Sync for Ring<T> {}

impl<T> Ring<T> {
    #[inline]
    fn capacity(&self) -> usize {
        self.slots.len()
    }

    /// Positions between `head` and `tail` (both in `0..2 * capacity`).
    #[inline]
    fn distance(&self, head: usize, tail: usize) -> usize {
        if tail >= head {
            tail - head
        } else {
            tail + 2 * self.capacity() - head
        }
    }

    /// The position after `pos`.
    #[inline]
    fn next(&self, pos: usize) -> usize {
        if pos + 1 < 2 * self.capacity() {
            pos + 1
        } else {
            0
        }
    }

    /// The slot of position `pos`.
    #[inline]
    fn slot(&self, pos: usize) -> &UnsafeCell<MaybeUninit<T>> {
        let cap = self.capacity();
        &self.slots[if pos < cap { pos } else { pos - cap }]
    }
}

/// The pushing end.
pub struct Producer<T> {
    ring: Arc<Ring<T>>,
    /// Our own tail (only we write it).
    tail: usize,
    /// The consumer's head as last read.
    head: usize,
}

/// The popping end.
pub struct Consumer<T> {
    ring: Arc<Ring<T>>,
    /// Our own head (only we write it).
    head: usize,
    /// The producer's tail as last read.
    tail: usize,
}

/// A ring of `capacity` values, allocated here, once.
///
/// # Panics
/// If `capacity` is 0 or `2 * capacity` overflows `usize`.
pub fn ring<T: Copy + Send>(capacity: usize) -> (Producer<T>, Consumer<T>) {
    assert!(capacity > 0 && capacity <= usize::MAX / 2, "ring capacity must be in 1..=usize::MAX/2, got {capacity}");
    let slots = (0..capacity).map(|_| UnsafeCell::new(MaybeUninit::uninit())).collect();
    let ring = Arc::new(Ring { head: Padded(AtomicUsize::new(0)), tail: Padded(AtomicUsize::new(0)), slots });
    (Producer { ring: ring.clone(), tail: 0, head: 0 }, Consumer { ring, head: 0, tail: 0 })
}

impl<T: Copy + Send> Producer<T> {
    /// Appends `value`, or hands it back if the ring is full. Wait-free.
    #[inline]
    pub fn push(&mut self, value: T) -> Result<(), T> {
        let ring = &*self.ring;
        if ring.distance(self.head, self.tail) == ring.capacity() {
            // Acquire: the consumer's reads of the slots it has freed happen-before we overwrite them.
            self.head = ring.head.0.load(Ordering::Acquire);
            if ring.distance(self.head, self.tail) == ring.capacity() {
                return Err(value);
            }
        }
        // SAFETY: the slot at `tail` is outside head..tail, so it is ours until the store below.
        ring.slot(self.tail).with_mut(|p| unsafe { (*p).write(value) });
        self.tail = ring.next(self.tail);
        // Release: publishes the slot contents written above to the consumer's Acquire load.
        ring.tail.0.store(self.tail, Ordering::Release);
        Ok(())
    }

    /// The number of values the ring holds when full.
    pub fn capacity(&self) -> usize {
        self.ring.capacity()
    }
}

impl<T: Copy + Send> Consumer<T> {
    /// Takes the oldest value, if any. Wait-free.
    #[inline]
    pub fn pop(&mut self) -> Option<T> {
        let ring = &*self.ring;
        if self.head == self.tail {
            // Acquire: the producer's writes of the slots it has published happen-before our reads.
            self.tail = ring.tail.0.load(Ordering::Acquire);
            if self.head == self.tail {
                return None;
            }
        }
        // SAFETY: the slot at `head` is inside head..tail: the producer has initialised it and will
        // not touch it until the store below gives it back.
        let value = ring.slot(self.head).with(|p| unsafe { (*p).assume_init_read() });
        self.head = ring.next(self.head);
        // Release: our read of the slot above happens-before the producer's Acquire load and reuse.
        ring.head.0.store(self.head, Ordering::Release);
        Some(value)
    }

    /// The number of values the ring holds when full.
    pub fn capacity(&self) -> usize {
        self.ring.capacity()
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    #[test]
    fn fifo_full_and_wrap_around_many_times() {
        for cap in [1usize, 2, 3, 5, 16] {
            let (mut tx, mut rx) = ring::<u64>(cap);
            let mut next_in = 0u64;
            let mut next_out = 0u64;
            // Fill to full, drain partly, over many laps of both position ranges.
            for round in 0..(10 * cap as u64 + 7) {
                while tx.push(next_in).is_ok() {
                    next_in += 1;
                }
                assert_eq!(next_in - next_out, cap as u64, "cap {cap}: full at exactly capacity");
                assert_eq!(tx.push(u64::MAX), Err(u64::MAX));
                for _ in 0..=(round as usize % cap) {
                    assert_eq!(rx.pop(), Some(next_out));
                    next_out += 1;
                }
            }
            while let Some(v) = rx.pop() {
                assert_eq!(v, next_out);
                next_out += 1;
            }
            assert_eq!(next_out, next_in);
            assert_eq!(rx.pop(), None);
        }
    }

    #[test]
    #[should_panic(expected = "ring capacity")]
    fn zero_capacity_is_refused() {
        let _ = ring::<u8>(0);
    }

    #[test]
    fn threads_see_every_value_once_in_order_and_untorn() {
        let (mut tx, mut rx) = ring::<[u64; 8]>(7);
        const N: u64 = 200_000;
        let t = std::thread::spawn(move || {
            let mut i = 0;
            while i < N {
                if tx.push([i; 8]).is_ok() {
                    i += 1;
                } else {
                    std::hint::spin_loop();
                }
            }
        });
        let mut expect = 0;
        while expect < N {
            if let Some(v) = rx.pop() {
                assert!(v.iter().all(|&x| x == expect), "expected {expect}, got {v:?}");
                expect += 1;
            } else {
                std::hint::spin_loop();
            }
        }
        t.join().unwrap();
        assert_eq!(rx.pop(), None);
    }
}
