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

/// The `[loadcells]` table: the RS-485 bus of the load cells (Modbus RTU master side).
///
/// Every field but `port` has a default, so the smallest table is `port = "/dev/taut-loadcells"`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCellBusConfig {
    /// Serial device, e.g. `/dev/taut-loadcells` (the udev rule in `udev/` makes that name).
    pub port: String,
    /// Baud rate, bit/s.
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Data bits per character. Modbus RTU needs 8; other values are refused.
    #[serde(default = "default_data_bits")]
    pub data_bits: u8,
    /// Parity: `"none"`, `"even"` or `"odd"`. The Modbus spec's default is even; most load-cell
    /// amplifiers ship with none (8N1).
    #[serde(default)]
    pub parity: Parity,
    /// Stop bits, 1 or 2.
    #[serde(default = "default_stop_bits")]
    pub stop_bits: u8,
    /// How long to wait for a response before the try counts as a timeout, s.
    #[serde(default = "default_response_timeout")]
    pub response_timeout_s: f64,
    /// Further tries after a timeout, a CRC error or garbage, before the reading of this cycle
    /// counts as missing.
    #[serde(default = "default_retries")]
    pub retries: u8,
    /// Period at which all cells are polled, s; 0 polls back to back as fast as the bus allows.
    #[serde(default)]
    pub poll_period_s: f64,
    /// A tension sample older than this counts as missing in the real-time loop, s.
    #[serde(default = "default_max_age")]
    pub max_age_s: f64,
    /// First wait before reopening a port that failed or vanished (USB unplug), s. Doubles on
    /// every failed reopen up to `reconnect_max_s`.
    #[serde(default = "default_reconnect_min")]
    pub reconnect_min_s: f64,
    /// Longest wait between reopen attempts, s.
    #[serde(default = "default_reconnect_max")]
    pub reconnect_max_s: f64,
}

/// Serial parity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Parity {
    /// No parity bit.
    #[default]
    None,
    /// Even parity.
    Even,
    /// Odd parity.
    Odd,
}

fn default_baud() -> u32 {
    115_200
}
fn default_data_bits() -> u8 {
    8
}
fn default_stop_bits() -> u8 {
    1
}
fn default_response_timeout() -> f64 {
    0.05
}
fn default_retries() -> u8 {
    2
}
fn default_max_age() -> f64 {
    0.05
}
fn default_reconnect_min() -> f64 {
    0.1
}
fn default_reconnect_max() -> f64 {
    5.0
}

impl LoadCellBusConfig {
    /// A bus on `port` with every other field at its default.
    pub fn new(port: impl Into<String>) -> Self {
        LoadCellBusConfig {
            port: port.into(),
            baud: default_baud(),
            data_bits: default_data_bits(),
            parity: Parity::None,
            stop_bits: default_stop_bits(),
            response_timeout_s: default_response_timeout(),
            retries: default_retries(),
            poll_period_s: 0.0,
            max_age_s: default_max_age(),
            reconnect_min_s: default_reconnect_min(),
            reconnect_max_s: default_reconnect_max(),
        }
    }

    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, m: String| Err((k.to_string(), m));
        if self.port.trim().is_empty() {
            return bad("port", "must name the serial device, e.g. \"/dev/taut-loadcells\"".into());
        }
        if !(300..=4_000_000).contains(&self.baud) {
            return bad("baud", format!("must be a baud rate in 300..=4000000, got {}", self.baud));
        }
        if self.data_bits != 8 {
            return bad("data_bits", format!("Modbus RTU uses 8 data bits, got {}", self.data_bits));
        }
        if !(1..=2).contains(&self.stop_bits) {
            return bad("stop_bits", format!("must be 1 or 2, got {}", self.stop_bits));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        for (k, v) in [
            ("response_timeout_s", self.response_timeout_s),
            ("max_age_s", self.max_age_s),
            ("reconnect_min_s", self.reconnect_min_s),
            ("reconnect_max_s", self.reconnect_max_s),
        ] {
            if !positive(v) {
                return bad(k, format!("must be a positive time in seconds, got {v}"));
            }
        }
        if !(self.poll_period_s.is_finite() && self.poll_period_s >= 0.0) {
            return bad("poll_period_s", format!("must be 0 (back to back) or a positive time in seconds, got {}", self.poll_period_s));
        }
        if self.reconnect_max_s < self.reconnect_min_s {
            return bad(
                "reconnect_max_s",
                format!("must be at least reconnect_min_s ({} s), got {} s", self.reconnect_min_s, self.reconnect_max_s),
            );
        }
        Ok(())
    }
}

/// Which Modbus register table holds a load cell's reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RegisterKind {
    /// Input registers, read with function 0x04.
    #[default]
    Input,
    /// Holding registers, read with function 0x03.
    Holding,
}

/// How the two 16-bit registers of a reading encode the value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ValueFormat {
    /// Two's-complement signed 32-bit integer.
    #[default]
    Int32,
    /// IEEE 754 single precision.
    Float32,
}

/// Order of the two 16-bit words of a 32-bit value (bytes inside a word are always big-endian,
/// as Modbus sends them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WordOrder {
    /// High word at the lower register address (`ABCD`), the common default.
    #[default]
    Big,
    /// Low word at the lower register address (`CDAB`, "word swapped").
    Little,
}

/// The `[cable.loadcell]` sub-table: the load cell of one cable.
///
/// Tension in newtons = `raw * scale + offset`, where `raw` is the 32-bit value at `register`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCellConfig {
    /// Modbus unit id, 1..=247.
    pub unit_id: u8,
    /// Address of the first of the two registers of the reading (0-based, as on the wire).
    #[serde(default)]
    pub register: u16,
    /// `"input"` (function 0x04) or `"holding"` (function 0x03).
    #[serde(default)]
    pub registers: RegisterKind,
    /// `"int32"` or `"float32"`.
    #[serde(default)]
    pub format: ValueFormat,
    /// `"big"` (high word first) or `"little"` (low word first).
    #[serde(default)]
    pub word_order: WordOrder,
    /// Newtons per raw unit.
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Newtons added after scaling.
    #[serde(default)]
    pub offset: f64,
}

fn default_scale() -> f64 {
    1.0
}

impl LoadCellConfig {
    /// A cell at `unit_id` with every other field at its default (input registers at 0, int32,
    /// big word order, raw value in newtons).
    pub fn new(unit_id: u8) -> Self {
        LoadCellConfig {
            unit_id,
            register: 0,
            registers: RegisterKind::Input,
            format: ValueFormat::Int32,
            word_order: WordOrder::Big,
            scale: 1.0,
            offset: 0.0,
        }
    }

    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(1..=247).contains(&self.unit_id) {
            return Err(("unit_id".into(), format!("must be a Modbus unit id in 1..=247, got {}", self.unit_id)));
        }
        if self.register == u16::MAX {
            return Err(("register".into(), "a 32-bit reading needs two registers; 65535 is the last address".into()));
        }
        if !(self.scale.is_finite() && self.scale != 0.0) {
            return Err(("scale".into(), format!("must be a finite non-zero number of newtons per raw unit, got {}", self.scale)));
        }
        if !self.offset.is_finite() {
            return Err(("offset".into(), format!("must be a finite number of newtons, got {}", self.offset)));
        }
        Ok(())
    }
}

/// Checks what no single `[cable.loadcell]` table can: two cables sharing one unit id.
/// Takes the cells in cable order (`None` for a cable without a load cell) and returns the index
/// of the second cable using an id, with the message.
pub fn validate_unit_ids<'a>(cells: impl IntoIterator<Item = Option<&'a LoadCellConfig>>) -> Result<(), (usize, String)> {
    let mut seen = [usize::MAX; 256];
    for (i, c) in cells.into_iter().enumerate() {
        if let Some(c) = c {
            let first = &mut seen[c.unit_id as usize];
            if *first != usize::MAX {
                return Err((i, format!("unit_id {} is already used by cable[{}]: every load cell needs its own id", c.unit_id, *first)));
            }
            *first = i;
        }
    }
    Ok(())
}

/// The `[tracker]` table: where the external position tracker's UDP pose datagrams arrive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// UDP address to listen on for pose datagrams, e.g. `0.0.0.0:5005`.
    pub listen: String,
    /// A pose older than this is late: dropped on arrival if it spent longer than this in
    /// transit, and missing in the loop once it is this old, s.
    #[serde(default = "default_tracker_max_age")]
    pub max_age_s: f64,
}

fn default_tracker_max_age() -> f64 {
    0.05
}

impl TrackerConfig {
    /// Listening on `listen` with the default age limit.
    pub fn new(listen: impl Into<String>) -> Self {
        TrackerConfig { listen: listen.into(), max_age_s: default_tracker_max_age() }
    }

    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err((
                "listen".into(),
                format!("must be an IP address and UDP port such as \"0.0.0.0:5005\", got {:?}", self.listen),
            ));
        }
        if !(self.max_age_s.is_finite() && self.max_age_s > 0.0) {
            return Err(("max_age_s".into(), format!("must be a positive time in seconds, got {}", self.max_age_s)));
        }
        Ok(())
    }
}

#[cfg(test)]
mod loadcell_tracker_tests {
    use super::*;

    #[test]
    fn loadcell_defaults_and_enums_parse() {
        let c: LoadCellConfig = toml::from_str("unit_id = 3\nformat = \"float32\"\nword_order = \"little\"\nregisters = \"holding\"").unwrap();
        assert_eq!(c.format, ValueFormat::Float32);
        assert_eq!(c.word_order, WordOrder::Little);
        assert_eq!(c.registers, RegisterKind::Holding);
        assert_eq!(c.scale, 1.0);
        c.validate().unwrap();
        let b: LoadCellBusConfig = toml::from_str("port = \"/dev/x\"\nparity = \"even\"").unwrap();
        assert_eq!(b, LoadCellBusConfig { parity: Parity::Even, ..LoadCellBusConfig::new("/dev/x") });
        b.validate().unwrap();
    }

    #[test]
    fn bad_values_name_the_key() {
        let mut b = LoadCellBusConfig::new("/dev/x");
        b.reconnect_max_s = 0.01;
        assert_eq!(b.validate().unwrap_err().0, "reconnect_max_s");
        let mut c = LoadCellConfig::new(1);
        c.scale = 0.0;
        assert_eq!(c.validate().unwrap_err().0, "scale");
        assert_eq!(TrackerConfig::new("nowhere").validate().unwrap_err().0, "listen");
        let a = LoadCellConfig::new(5);
        let e = validate_unit_ids([Some(&a), None, Some(&a)]).unwrap_err();
        assert_eq!(e.0, 2);
        assert!(e.1.contains("cable[0]"), "{}", e.1);
    }
}
