//! Tests that measure this process's memory: allocation counts with a counting global allocator
//! (`counting`: one per binary, so these tests share it) and the resident size (`hostile_ctl`).
//!
//! The counts are per thread, so these tests run beside each other like any others. The resident
//! size is the process's: the test that reads it and the tests that allocate much (a daemon with
//! its calibrator, a simulated robot's start-up) hold [`MEMORY`], one at a time.

use std::sync::Mutex;

mod counting;

/// Held by `hostile_ctl`'s memory test (it reads the process's resident size) and by the tests of
/// this binary that allocate much.
static MEMORY: Mutex<()> = Mutex::new(());

mod canopen_fuzz;
mod hostile_ctl;
mod modbus_loop_alloc;
mod plugin_alloc;
mod rt_alloc;
