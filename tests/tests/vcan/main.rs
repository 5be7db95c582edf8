//! Real SocketCAN (`vcan0`, `vcan1`): run for real inside the QEMU VM of `tests/vcan/run` (one
//! test module at a time, `--test-threads=1`); on a host without the interfaces every test skips
//! (see `taut_tests::vcan`). One test binary, a module per subject.

/// The bus-fault scenario, shared with `canopen_busfault` (the `devices` binary).
#[path = "../busfault/mod.rs"]
mod busfault;

mod vcan_busfault;
mod vcan_canopen;
mod vcan_field;
mod vcan_pdo_map;
mod vcan_plugin_owned;
mod vcan_socketcan;
mod vcan_start;
