//! `taut_update` allocates nothing: a counting global allocator counts the allocations made on
//! the calling thread while it is inside `taut_update`, over the simulated robot's enabling and
//! three initialisation phases (the calibrator thread allocates as it likes: it is not counted).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use taut::sim::*;
use taut::*;

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);
thread_local! {
    // const-initialised, no destructor: reading it never allocates.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            // Relaxed: a counter read after the measured calls on the same thread.
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn taut_update_allocates_nothing_through_the_start_up_phases() {
    let dir = tempfile::tempdir().unwrap();
    let config = std::ffi::CString::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml")).unwrap();
    let data = std::ffi::CString::new(dir.path().to_str().unwrap()).unwrap();
    let mut sim: *mut TautSim = std::ptr::null_mut();
    let mut h: *mut TautPlugin = std::ptr::null_mut();
    let mut opts = unsafe { std::mem::zeroed::<TautOptions>() };
    unsafe {
        assert_eq!(taut_sim_new(config.as_ptr(), 5, &mut sim), TautError::Ok);
        assert_eq!(taut_options_init(&mut opts), TautError::Ok);
        opts.data_dir = data.as_ptr();
        assert_eq!(taut_configure(config.as_ptr(), TAUT_CONFIG_PATH, &opts, &mut h), TautError::Ok);
        assert_eq!(taut_activate(h), TautError::Ok);
    }
    let (mut inp, mut cmd) = (TautInputs::default(), TautCommands::default());
    let period = 0.002;
    let mut phases = 0u8;
    let mut cycles = 0u64;
    for k in 0..40_000u64 {
        let now = k as f64 * period;
        unsafe { assert_eq!(taut_sim_read(sim, now, &mut inp), TautError::Ok) };
        COUNTING.with(|c| c.set(true));
        let r = unsafe { taut_update(h, now, period, &inp, &mut cmd) };
        COUNTING.with(|c| c.set(false));
        assert_eq!(r, TautError::Ok);
        assert_eq!(cmd.faulted, 0, "a safety reaction at t = {now:.3} s");
        unsafe { assert_eq!(taut_sim_write(sim, now, period, &cmd), TautError::Ok) };
        cycles += 1;
        let mut st = TautStatus::default();
        if k % 100 == 0 {
            unsafe { assert_eq!(taut_status(h, &mut st), TautError::Ok) };
            phases = st.phases_completed;
            if phases == 3 {
                break;
            }
        }
    }
    assert_eq!(phases, 3, "the three initialisation phases did not end in {cycles} cycles");
    assert_eq!(ALLOCS.load(Ordering::Relaxed), 0, "allocations inside taut_update over {cycles} cycles");
    unsafe {
        assert_eq!(taut_cleanup(h), TautError::Ok);
        taut_sim_free(sim);
    }
}
