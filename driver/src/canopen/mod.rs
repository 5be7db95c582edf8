//! The CANopen (CiA 301) master for CiA 402 drives, sans-IO.
//!
//! [`master`] combines the services of `taut_proto::canopen` (NMT, SYNC, heartbeat, EMCY, SDO,
//! PDO, the CiA 402 state machine) into one state machine that takes frames and time in and hands
//! frames and [`master::NodeEvent`]s out; [`drive_set`] puts a transport under it with the lifecycle
//! in types. [`busload`] estimates the bus load of a configuration and [`eds_check`] checks a
//! configuration against the drives' electronic data sheets.

pub mod busload;
pub mod drive_set;
pub mod eds_check;
pub mod master;
