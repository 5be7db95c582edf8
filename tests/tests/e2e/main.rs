//! End to end on the simulated robot in real time: `taut start --sim` (start-up, excitation,
//! calibration, hot-swap, faults and recovery, MCAP recording, live telemetry) and the plugin's
//! lifecycle as a host sees it. One test binary, a module per subject. (The tracker-free 3 mm
//! acceptance, `e2e_notracker_3mm`, is a target of its own, run alone by scripts/test.)
//!
//! libtest runs as many tests at once as the machine has cores, as it did inside each of the
//! former per-file binaries.

/// The hostile-input suite's runner (here for `taut_bin`).
#[path = "../../src/hostile.rs"]
mod hostile;
/// The tracker-free start-up, shared with `e2e_notracker_3mm`.
#[path = "../notracker/mod.rs"]
mod notracker;

mod e2e_effects;
mod e2e_excitation;
mod e2e_faults;
mod e2e_notracker;
mod e2e_reset;
mod e2e_start;
mod mcap_kill;
mod mcap_start;
mod plugin_lifecycle;
mod telemetry_ws;
