//! Virtual devices for the simulated robot and the tests: the device side of the protocols the
//! master in `taut-driver` speaks, on any transport the master can use.
//!
//! | item                                   | what                                                        |
//! |----------------------------------------|-------------------------------------------------------------|
//! | [`VirtualDrive`], [`DriveParams`]      | one CiA 402 servo drive: object dictionary, SDO server, PDO engine, NMT, heartbeat, EMCY |
//! | [`DriveRack`], [`rack_filters`]        | several drives on one CAN transport endpoint, sans-IO       |
//! | [`spawn_rack`], [`RackHandle`]         | a rack on its own thread, for wall-clock use (probe, vcan)  |
//! | [`Target`], [`DriveCounters`]          | what a drive is asked to do (for coupling a plant), its counters |
//! | [`VirtualLoadCells`], [`TensionHandle`]| Modbus RTU load cells behind a pseudo-terminal, with [`LoadCellFault`]s to inject |
//! | [`TrackerSender`], [`TrackerStream`]   | pose datagrams in the tracker line format over UDP          |
//!
//! `taut-vdev` depends on `taut-proto`, never on the master (`taut-driver`) nor on the physics
//! (`taut-sim`). `taut-simrig` couples them: the plant reads [`VirtualDrive::target`], writes
//! [`VirtualDrive::set_actual`] and sets the load cells' [`TensionHandle`].
//!
//! ```no_run
//! use taut_proto::can::CanTransport;
//! use taut_vdev::{rack_filters, DriveRack};
//! // Any transport: `taut_driver`'s in-process bus endpoint, filtered with `rack_filters(&[1, 2])`,
//! // or a SocketCAN socket.
//! fn run(port: impl CanTransport) {
//!     let mut rack = DriveRack::with_nodes(port, &[1, 2]);
//!     rack.step(std::time::Instant::now());
//! }
//! # let _ = rack_filters(&[1, 2]);
//! ```
#![deny(missing_docs)]

mod drive;
mod loadcell;
mod tracker;

pub use drive::{rack_filters, spawn_rack, DriveCounters, DriveParams, DriveRack, RackHandle, Target, VirtualDrive};
pub use loadcell::{LoadCellFault, LoadCellResponder, ServerStats, SocketLink, SocketPort, TensionHandle, VirtualLoadCells};
pub use tracker::{TrackerSender, TrackerStream};
