//! The real-time loop's side of the load cells and the tracker allocates nothing: a counting
//! global allocator checks `TensionReader::update/tension` and `PoseReader::latest` while the
//! I/O threads run.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::{Duration, Instant};
use taut_config::devices::{LoadCellBusConfig, LoadCellConfig, TrackerConfig};
use taut_driver::{loadcell, tracker};
use taut_vdev::{TensionHandle, TrackerStream, VirtualLoadCells};

thread_local! {
    /// Allocations made by this thread while counting is on.
    static COUNT: Cell<Option<u64>> = const { Cell::new(None) };
}

struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = COUNT.try_with(|c| c.set(c.get().map(|n| n + 1)));
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        let _ = COUNT.try_with(|c| c.set(c.get().map(|n| n + 1)));
        System.dealloc(p, l)
    }
}

#[global_allocator]
static A: Counting = Counting;

fn counted<R>(f: impl FnOnce() -> R) -> (R, u64) {
    COUNT.with(|c| c.set(Some(0)));
    let r = f();
    let n = COUNT.with(|c| c.replace(None)).unwrap_or(0);
    (r, n)
}

#[test]
fn loop_side_does_not_allocate() {
    let t = TensionHandle::new(2);
    t.set_all(&[10.0, 20.0]);
    let server = VirtualLoadCells::spawn(vec![LoadCellConfig::new(1), LoadCellConfig::new(2)], t).unwrap();
    let bus = LoadCellBusConfig::new(server.path().to_str().unwrap());
    let (_io, mut tensions) = loadcell::spawn(&bus, &[(0, LoadCellConfig::new(1)), (1, LoadCellConfig::new(2))], 2).unwrap();
    let (rx, mut poses) = tracker::spawn(&TrackerConfig::new("127.0.0.1:0")).unwrap();
    let _stream = TrackerStream::spawn(rx.local_addr(), Duration::from_millis(2), 0.0, |t| ([t, 0.0, 1.0], None)).unwrap();

    let t0 = Instant::now();
    let (mut got_t, mut got_p, mut allocs) = (0, 0, 0);
    while t0.elapsed() < Duration::from_millis(500) {
        let ((nt, np), n) = counted(|| {
            tensions.update();
            let now = Instant::now();
            let a = tensions.tension(0, now).is_some() as u32 + tensions.tension(1, now).is_some() as u32;
            (a, poses.latest(now).is_some() as u32)
        });
        got_t += nt;
        got_p += np;
        allocs += n;
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(got_t > 10 && got_p > 10, "the loop saw data ({got_t} tensions, {got_p} poses)");
    assert_eq!(allocs, 0, "the loop side allocated");
}
