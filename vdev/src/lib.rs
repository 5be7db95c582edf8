//! Virtual devices for the simulated robot and the tests: the device side of the protocols the
//! master in `taut-driver` speaks, on the same transports as the real devices.
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
//! The crate graph: `taut-vdev` depends on `taut-driver` (frames, codecs, transports) and
//! `taut-config`, never on `taut-sim`. The physics stays in `taut-sim`; `taut-rt-core`'s simulated
//! rig couples the two (the plant reads [`VirtualDrive::target`] and writes
//! [`VirtualDrive::set_actual`], and sets the load cells' [`TensionHandle`]). `taut-driver`
//! depends on neither, not even for its benches: the master's round-trip bench is `benches/master.rs` here.
//!
//! ```no_run
//! use taut_driver::VirtualBus;
//! use taut_vdev::{rack_filters, DriveRack};
//! let bus = VirtualBus::new();
//! let master_port = bus.endpoint();
//! let mut rack = DriveRack::with_nodes(bus.endpoint_with(256, &rack_filters(&[1, 2])), &[1, 2]);
//! rack.step(std::time::Instant::now());
//! # drop(master_port);
//! ```
#![deny(missing_docs)]

mod drive;
mod loadcell;
mod tracker;

pub use drive::{rack_filters, spawn_rack, DriveCounters, DriveParams, DriveRack, RackHandle, Target, VirtualDrive};
pub use loadcell::{LoadCellFault, LoadCellResponder, ServerStats, SocketLink, SocketPort, TensionHandle, VirtualLoadCells};
pub use tracker::{TrackerSender, TrackerStream};
