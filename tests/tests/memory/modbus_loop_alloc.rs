//! The real-time loop's side of the load cells and the tracker allocates nothing: a counting
//! global allocator checks `TensionReader::update/tension` and `PoseReader::latest` while the
//! I/O threads run.

use std::time::{Duration, Instant};
use taut_driver::{loadcell, tracker};
use taut_proto::devices::{LoadCellBusConfig, LoadCellConfig, TrackerConfig};
use taut_vdev::{TensionHandle, TrackerStream, VirtualLoadCells};

// The counting global allocator of this test binary (one per binary): `crate::counting`.
use crate::counting::{ALLOCS, FREES, WATCHING};

/// Runs `f`, counting this thread's allocations and frees.
fn counted<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCS.with(|a| a.get()) + FREES.with(|a| a.get());
    WATCHING.with(|w| w.set(true));
    let r = f();
    WATCHING.with(|w| w.set(false));
    let n = ALLOCS.with(|a| a.get()) + FREES.with(|a| a.get()) - before;
    (r, n)
}

#[test]
fn loop_side_does_not_allocate() {
    let t = TensionHandle::new(2);
    t.set_all(&[10.0, 20.0]);
    let server = VirtualLoadCells::spawn(vec![LoadCellConfig::new(1), LoadCellConfig::new(2)], t).unwrap();
    let mut bus = LoadCellBusConfig::new(server.path().to_str().unwrap());
    // This checks allocations, not timing: allowances for a loaded machine, whose
    // pseudo-terminal passes answers on hundreds of ms late (tests/src/startup.rs).
    bus.response_timeout_s = taut_tests::startup::LOADCELL_RESPONSE_TIMEOUT_S;
    bus.max_age_s = 2.0;
    let (_io, mut tensions) = loadcell::spawn(&bus, &[(0, LoadCellConfig::new(1)), (1, LoadCellConfig::new(2))], 2).unwrap();
    let (rx, mut poses) = tracker::spawn(&TrackerConfig::new("127.0.0.1:0")).unwrap();
    let _stream = TrackerStream::spawn(rx.local_addr(), Duration::from_millis(2), 0.0, |t| ([t, 0.0, 1.0], None)).unwrap();

    let t0 = Instant::now();
    let (mut got_t, mut got_p, mut allocs) = (0, 0, 0);
    // At least 500 ms of cycles, and on until data has come through (a loaded machine).
    while t0.elapsed() < Duration::from_millis(500) || (t0.elapsed() < Duration::from_secs(30) && (got_t <= 10 || got_p <= 10)) {
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
