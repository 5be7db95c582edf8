//! End to end on the simulated robot in real time: `taut start --sim` (start-up, excitation,
//! calibration, hot-swap, faults and recovery, MCAP recording, live telemetry) and the plugin's
//! lifecycle as a host sees it. One test binary, a module per subject. (The accuracy acceptances run
//! in simulated time: the `simtime` target.)
//!
//! libtest runs as many tests at once as the machine has cores, as it did inside each of the
//! former per-file binaries.

/// The hostile-input suite's runner (here for `taut_bin`).
#[path = "../../src/hostile.rs"]
mod hostile;
/// The tracker-free start-up, shared with `simtime`'s 3 mm acceptance.
#[path = "../notracker/mod.rs"]
mod notracker;

mod e2e_effects;
mod e2e_notracker;
mod e2e_reset;
mod e2e_start;
mod mcap_kill;
mod mcap_start;
mod plugin_lifecycle;
mod telemetry_ws;
