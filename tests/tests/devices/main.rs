//! The device layer against simulated devices, without a whole robot: the CANopen master and
//! virtual CiA 402 drives on the in-process bus in simulated time, Modbus RTU load cells on
//! pseudo-terminals (and against implementations we did not write), the tracker receiver on
//! loopback UDP. One test binary, a module per subject.

/// The bus-fault scenario, shared with `vcan_busfault` (the `vcan` binary).
#[path = "../busfault/mod.rs"]
mod busfault;

mod canopen_busfault;
mod canopen_field;
mod canopen_master;
mod canopen_pdo_eds;
mod modbus_external;
mod modbus_pty;
mod pose_age_clock;
mod tracker_sources;
mod tracker_udp;
