//! The counting global allocator of the `memory` test binary (a global allocator is one per
//! binary): it counts the allocations (and reallocations) and the frees of a thread while that
//! thread's `WATCHING` is set, in that thread's `ALLOCS` and `FREES`. Thread-local, so the tests
//! of this binary that run beside each other (libtest runs each test on a thread of its own) do
//! not disturb each other's counts: each counts only what its own measuring thread does.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::thread::LocalKey;

thread_local! {
    // const-initialised thread locals need no allocation on first use.
    pub static WATCHING: Cell<bool> = const { Cell::new(false) };
    pub static ALLOCS: Cell<u64> = const { Cell::new(0) };
    pub static FREES: Cell<u64> = const { Cell::new(0) };
}

fn count(c: &'static LocalKey<Cell<u64>>) {
    // try_with: the allocator also runs while a thread's locals are torn down.
    let _ = WATCHING.try_with(|w| {
        if w.get() {
            c.with(|a| a.set(a.get() + 1));
        }
    });
}

struct Counting;

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count(&ALLOCS);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        count(&FREES);
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count(&ALLOCS);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;
