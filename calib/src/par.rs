//! Independent pieces of work (one cable, one screened channel) on more than one core, with the
//! results in the order a single thread would give them.
//!
//! The calibration separates per cable and the wild-value screen per channel, so each piece
//! runs the same code on the same inputs whichever thread takes it: the results are bit for bit
//! those of the sequential loop, and every sum or note over the pieces is still made in index
//! order by the caller. The caller decides how many threads (`CalibOptions::threads`,
//! `ScreenOptions::threads`): one by default, so the robot's calibrator thread stays one thread;
//! the one-shot commands (`taut calibrate`) use the machine's cores. The workers are scoped
//! (`std::thread::scope`): none outlives the call, and a panic in one is raised in the caller.

use std::sync::Mutex;

/// The number of threads a one-shot command may use: the cores the OS gives this process (1 if
/// it cannot say), at most `cap`.
pub fn available(cap: usize) -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, cap.max(1))
}

/// `[f(0), f(1), ..., f(n - 1)]`, computed on up to `threads` threads (the calling thread is one
/// of them). Each index is taken by exactly one thread, the next free one, so pieces of unequal
/// cost still share the cores. With `threads <= 1` or `n <= 1` it is the plain loop.
pub fn map<R: Send>(threads: usize, n: usize, f: impl Fn(usize) -> R + Sync) -> Vec<R> {
    let mut idx: Vec<usize> = (0..n).collect();
    map_mut(threads, &mut idx, |k, _| f(k))
}

/// `[f(0, &mut items[0]), f(1, &mut items[1]), ...]` as [`map`] computes it: each item is
/// handed to exactly one thread.
pub fn map_mut<T: Send, R: Send>(threads: usize, items: &mut [T], f: impl Fn(usize, &mut T) -> R + Sync) -> Vec<R> {
    let n = items.len();
    let workers = threads.min(n);
    if workers <= 1 {
        return items.iter_mut().enumerate().map(|(k, it)| f(k, it)).collect();
    }
    // The next free item. The lock is held only to take one (never while `f` runs, so a panic
    // in `f` cannot poison it).
    let queue = Mutex::new(items.iter_mut().enumerate());
    let work = || {
        let mut done = Vec::new();
        loop {
            let next = queue.lock().unwrap_or_else(|e| e.into_inner()).next();
            match next {
                Some((k, it)) => done.push((k, f(k, it))),
                None => return done,
            }
        }
    };
    let mut slots: Vec<Option<R>> = (0..n).map(|_| None).collect();
    std::thread::scope(|s| {
        let helpers: Vec<_> = (1..workers).map(|_| s.spawn(work)).collect();
        let mut place = |done: Vec<(usize, R)>| {
            for (k, r) in done {
                slots[k] = Some(r);
            }
        };
        place(work());
        for h in helpers {
            place(h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)));
        }
    });
    slots.into_iter().map(|r| r.expect("every item is taken by one thread")).collect()
}

/// `(a(), b())`, the second on another thread when `threads > 1`.
pub fn join<A: Send, B: Send>(threads: usize, a: impl FnOnce() -> A + Send, b: impl FnOnce() -> B + Send) -> (A, B) {
    if threads <= 1 {
        let ra = a();
        return (ra, b());
    }
    std::thread::scope(|s| {
        let hb = s.spawn(b);
        let ra = a();
        (ra, hb.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_are_in_index_order_whatever_the_threads() {
        // Unequal pieces, so the threads finish them out of order.
        let f = |k: usize| (0..(k % 7) * 20_000).fold(k as u64, |a, b| a.wrapping_mul(31).wrapping_add(b as u64));
        let one = map(1, 50, f);
        for threads in [2, 3, 8, 100] {
            assert_eq!(map(threads, 50, f), one, "{threads} threads");
        }
        assert!(map(4, 0, f).is_empty());
        let mut v: Vec<u64> = (0..20).collect();
        let doubled = map_mut(2, &mut v, |k, x| {
            *x *= 2;
            k
        });
        assert_eq!(doubled, (0..20).collect::<Vec<_>>());
        assert_eq!(v, (0..20).map(|x| 2 * x).collect::<Vec<u64>>());
        assert_eq!(join(2, || 1, || 2), (1, 2));
        assert_eq!(join(1, || "a", || "b"), ("a", "b"));
    }

    #[test]
    fn a_panic_in_a_worker_reaches_the_caller() {
        let r = std::panic::catch_unwind(|| map(2, 8, |k| if k == 5 { panic!("piece 5") } else { k }));
        assert!(r.is_err());
    }
}
