//! End to end on the simulated robot in real time: `taut start --sim` (start-up, calibration,
//! hot-swap, `ctl recalibrate`), reset after faults, MCAP recording, live telemetry, and the
//! plugin's lifecycle as a host sees it: the threads, ptys, sockets and files. One test binary, a
//! module per subject. (Accuracy, fault injection and the tracker-free start-ups run in
//! simulated time: the `simtime` target.)
//!
//! libtest runs as many tests at once as the machine has cores, as it did inside each of the
//! former per-file binaries.

/// The hostile-input suite's runner (here for `taut_bin`).
#[path = "../../src/hostile.rs"]
mod hostile;

mod e2e_reset;
mod e2e_start;
mod mcap_kill;
mod mcap_start;
mod plugin_lifecycle;
mod telemetry_ws;
