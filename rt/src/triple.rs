//! A triple buffer: one writer hands whole values to one reader without locks, without waiting,
//! and without the reader ever allocating or freeing.
//!
//! Three slots: the writer owns one, the reader owns one, and the third ("back") is shared through
//! one atomic byte that holds its index and a "fresh" bit. `write` fills the writer's slot and
//! swaps it with the back slot; `read` swaps the back slot with the reader's one only when it is
//! fresh. A value the reader gives up goes back to the writer, whose next `write` replaces it and
//! drops it there, on the writer's thread. That is why this is used for parameters and not
//! `arc-swap` (whose first `load` on a thread allocates and whose guards may free on the reader).
//! Its atomics and slots switch to `loom`'s under `cfg(loom)`; the model tests are in
//! `loom_tests.rs` (`scripts/loom`).
//!
//! ```
//! let (mut w, mut r) = taut_rt::triple::triple_buffer(0u32);
//! w.write(7);
//! assert_eq!(*r.read(), 7);
//! assert!(!r.update()); // nothing new
//! ```

use crate::sync::{Arc, AtomicU8, Ordering, UnsafeCell};

const INDEX: u8 = 0b011;
const FRESH: u8 = 0b100;

struct Shared<T> {
    slots: [UnsafeCell<T>; 3],
    /// Index of the back slot, plus [`FRESH`] when the writer has put a value there that the
    /// reader has not taken yet.
    back: AtomicU8,
}

// SAFETY: each slot is accessed by at most one side at a time: the writer's and the reader's
// indices and the back index are always a permutation of {0, 1, 2}, and ownership of a slot moves
// only through the atomic swap of `back`.
unsafe impl<T: Send> Sync for Shared<T> {}

/// The writing end.
pub struct Writer<T> {
    shared: Arc<Shared<T>>,
    index: u8,
}

/// The reading end.
pub struct Reader<T> {
    shared: Arc<Shared<T>>,
    index: u8,
}

/// A triple buffer whose three slots start as clones of `init`; the reader sees `init` until the
/// first `write`.
pub fn triple_buffer<T: Clone + Send>(init: T) -> (Writer<T>, Reader<T>) {
    let shared = Arc::new(Shared {
        slots: [UnsafeCell::new(init.clone()), UnsafeCell::new(init.clone()), UnsafeCell::new(init)],
        back: AtomicU8::new(2),
    });
    (Writer { shared: shared.clone(), index: 0 }, Reader { shared, index: 1 })
}

impl<T: Send> Writer<T> {
    /// Publishes `value`. Returns the value it displaced from the writer's slot (an older one the
    /// reader has given up), so that it is dropped here, not on the reader.
    pub fn write(&mut self, value: T) -> T {
        // SAFETY: the slot at `self.index` belongs to the writer until the swap below.
        let old = self.shared.slots[usize::from(self.index)].with_mut(|p| std::mem::replace(unsafe { &mut *p }, value));
        // AcqRel: Release publishes the slot contents written above to the reader's Acquire swap;
        // Acquire makes the reader's last use of the slot we get back happen-before our next write.
        let prev = self.shared.back.swap(self.index | FRESH, Ordering::AcqRel);
        self.index = prev & INDEX;
        old
    }
}

impl<T: Send> Reader<T> {
    /// Takes the newest published value if there is one; true if it was new. Wait-free.
    pub fn update(&mut self) -> bool {
        // Relaxed: only a hint; the swap below carries the ordering.
        if self.shared.back.load(Ordering::Relaxed) & FRESH == 0 {
            return false;
        }
        // AcqRel: Acquire sees the writer's slot contents; Release hands our old slot back to the
        // writer after our last read of it.
        let prev = self.shared.back.swap(self.index, Ordering::AcqRel);
        self.index = prev & INDEX;
        true
    }

    /// The newest value (after taking a fresh one if there is one).
    pub fn read(&mut self) -> &T {
        self.update();
        self.current()
    }

    /// The value taken by the last `update`/`read`, without looking for a newer one.
    pub fn current(&self) -> &T {
        // SAFETY: the slot at `self.index` belongs to the reader until its next swap, which needs
        // `&mut self`.
        self.shared.slots[usize::from(self.index)].with(|p| unsafe { &*p })
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    #[test]
    fn newest_value_wins_and_old_values_return_to_the_writer() {
        let (mut w, mut r) = triple_buffer(vec![0u8]);
        assert_eq!(r.read(), &vec![0]);
        let back = w.write(vec![1]);
        assert_eq!(back, vec![0]); // the writer's own initial slot
        w.write(vec![2]);
        assert_eq!(r.read(), &vec![2]);
        assert!(!r.update());
        // The reader's previous slot ([0]) is the back slot now; the writer gets it on the next
        // write and hands out the one it replaces.
        let displaced = w.write(vec![3]);
        assert_eq!(displaced, vec![1]);
        assert_eq!(r.read(), &vec![3]);
    }

    #[test]
    fn concurrent_reader_sees_monotonic_consistent_values() {
        let (mut w, mut r) = triple_buffer([0u64; 16]);
        let t = std::thread::spawn(move || {
            for i in 1..=200_000u64 {
                w.write([i; 16]);
            }
        });
        let mut last = 0;
        while last < 200_000 {
            let v = *r.read();
            assert!(v.iter().all(|&x| x == v[0]), "torn value {v:?}");
            assert!(v[0] >= last);
            last = v[0];
        }
        t.join().unwrap();
    }
}
