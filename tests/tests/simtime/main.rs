//! The accuracy and acceptance start-ups in simulated time: the whole robot stack (the plugin in
//! plugin-owned mode, the CANopen master against the virtual drives, the Modbus RTU master against
//! the virtual load cells, the tracker receiver, the calibrator) in lockstep on one simulated
//! clock (`taut_simrig::run_startup`). Nothing here depends on the scheduler, so a loaded machine
//! cannot fail these tests; a seed reproduces a run bit for bit.
//!
//! Which test covers which path (docs/testing.md has the whole table): the accuracy of the
//! start-up with a tracker (`excitation`: the designed excitation's 1 mm on seeds 1-5), without a
//! tracker (`notracker_3mm`), determinism and faults drawn from the seed (`lockstep`), reset after
//! each cause (`reset`: estop, drive fault, power cycle, bus-off, heartbeat loss). The
//! wall-clock path (threads, ptys, UDP, SocketCAN, the control socket, telemetry) keeps its smoke
//! tests in the `e2e` and `vcan` targets.

/// The tracker-free start-up (shared with `e2e`).
#[path = "../notracker/mod.rs"]
mod notracker;

mod dynamic;
mod effects;
mod excitation;
mod faults;
mod lockstep;
mod notracker_2mm;
mod notracker_3mm;
mod notracker_3mm_dynamic;
mod notracker_continuous;
mod notracker_short;
mod notracker_short_rests;
mod operator;
mod reset;
mod tension_side;
mod wiring;
