//! Device sections of the robot configuration: the CANopen bus and drives, the Modbus RTU load
//! cells, and the tracker input.
//!
//! Each `validate` returns `(key, message)` for the first bad field; the caller adds the file, line
//! and the path of the enclosing table.

use serde::{Deserialize, Serialize};

/// The `[can]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// SocketCAN interface name, e.g. `can0`.
    pub interface: String,
    /// Bus bitrate, bit/s.
    #[serde(default = "default_bitrate")]
    pub bitrate: u32,
    /// SYNC / PDO cycle period, s.
    #[serde(default = "default_cycle")]
    pub cycle_s: f64,
}

fn default_bitrate() -> u32 {
    1_000_000
}
fn default_cycle() -> f64 {
    0.002
}

/// The `[cable.drive]` sub-table: the CiA 402 servo drive of one cable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveConfig {
    /// CANopen node id, 1..=127.
    pub node_id: u8,
}

impl DriveConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(1..=127).contains(&self.node_id) {
            return Err(("node_id".into(), format!("must be a CANopen node id in 1..=127, got {}", self.node_id)));
        }
        Ok(())
    }
}

/// The `[loadcells]` table: the RS-485 bus of the load cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCellBusConfig {
    /// Serial device, e.g. `/dev/taut-loadcells`.
    pub port: String,
    /// Baud rate.
    #[serde(default = "default_baud")]
    pub baud: u32,
}

fn default_baud() -> u32 {
    115_200
}

/// The `[cable.loadcell]` sub-table: the load cell of one cable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCellConfig {
    /// Modbus unit id, 1..=247.
    pub unit_id: u8,
}

impl LoadCellConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(1..=247).contains(&self.unit_id) {
            return Err(("unit_id".into(), format!("must be a Modbus unit id in 1..=247, got {}", self.unit_id)));
        }
        Ok(())
    }
}

/// The `[tracker]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// UDP address to listen on for pose datagrams, e.g. `0.0.0.0:5005`.
    pub listen: String,
}
