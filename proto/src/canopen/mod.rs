//! CANopen (CiA 301) services and the CiA 402 drive profile as codecs, for both ends of the bus.
//!
//! Files are named after the services of CiA 301 (`nmt`, `sync`, `heartbeat`, `emcy`, `sdo`,
//! `pdo`), the object dictionary entries taut uses (`od`) and the profile (`cia402`). Time is
//! passed in where a service has timers. The master that combines them is
//! `taut_driver::canopen::master`; the device side is `taut-vdev`'s virtual drive.
//!
//! Predefined connection set (CiA 301 7.3.5), 11-bit ids, `n` = node id 1..=127:
//!
//! ```text
//! 0x000      NMT command (master -> all)     0x180+n  TPDO1   0x200+n  RPDO1
//! 0x080      SYNC                            0x280+n  TPDO2   0x300+n  RPDO2
//! 0x080+n    EMCY                            0x380+n  TPDO3   0x400+n  RPDO3
//! 0x580+n    SDO server -> client            0x480+n  TPDO4   0x500+n  RPDO4
//! 0x600+n    SDO client -> server            0x700+n  heartbeat / boot-up (NMT error control)
//! ```

pub mod cia402;
pub mod emcy;
pub mod heartbeat;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;
pub mod sync;

/// A CANopen node id, 1..=127.
pub type NodeId = u8;

/// Function code of an 11-bit CANopen COB-ID (its upper 4 bits, CiA 301 7.3.5).
pub fn function_code(cob_id: u16) -> u16 {
    cob_id & 0x780
}

/// Node id part of an 11-bit CANopen COB-ID (its lower 7 bits).
pub fn node_of(cob_id: u16) -> u8 {
    (cob_id & 0x7F) as u8
}
