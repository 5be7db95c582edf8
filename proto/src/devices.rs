//! Device sections of the robot configuration: the CANopen bus and drives, the Modbus RTU load
//! cells, and the tracker input.
//!
//! Each `validate` returns `(key, message)` for the first bad field; the caller adds the file, line
//! and the path of the enclosing table.

use crate::pdo_map::{Dir, PdoMaps, PdoObject};
use serde::{Deserialize, Serialize};
use toml::Spanned;

/// The `[can]` table: the CANopen bus of the servo drives.
///
/// Only `interface` is required:
///
/// ```toml
/// [can]
/// interface = "can0"
/// bitrate = 1000000     # bit/s; the adapter must be brought up at the same rate
/// cycle_s = 0.002       # SYNC / PDO cycle
/// ```
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
    /// Time to wait for one SDO response before the try counts as timed out, s.
    #[serde(default = "default_sdo_timeout")]
    pub sdo_timeout_s: f64,
    /// Further tries of an SDO transfer after a timeout.
    #[serde(default = "default_sdo_retries")]
    pub sdo_retries: u8,
    /// How long start-up waits for every drive to boot, be configured and become operational, s.
    #[serde(default = "default_bringup_timeout")]
    pub bringup_timeout_s: f64,
    /// Send NMT "reset communication" to all nodes at start-up, so that every drive announces
    /// itself with a boot-up message. Turn off only if another master shares the bus.
    #[serde(default = "default_true")]
    pub reset_on_start: bool,
    /// taut's own node id on the bus: its heartbeat is 0x700 + this id. Must differ from every
    /// drive's node id.
    #[serde(default = "default_master_node_id")]
    pub master_node_id: u8,
    /// Period of taut's heartbeat, ms. Each drive's heartbeat consumer (0x1016) is set to 3
    /// periods: a drive that hears nothing from taut for that long applies `abort_connection`.
    #[serde(default = "default_master_heartbeat_ms")]
    pub master_heartbeat_ms: u16,
    /// What a drive does when taut is gone (0x6007, CiA 402): see [`AbortConnection`].
    #[serde(default)]
    pub abort_connection: AbortConnection,
}

/// The abort connection option code (0x6007) taut writes into every drive: the drive's own
/// reaction when taut's heartbeat stops (taut killed, crashed, cable cut) or taut stops or
/// resets it. CiA 402 applies it from "operation enabled". See docs/canopen.md for the choice.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AbortConnection {
    /// 3: quick stop: the drive stops on its quick-stop ramp under position control, so the
    /// hanging platform is never left unsupported; what follows (hold, or brake and disable)
    /// is the drive's quick stop option code 0x605A.
    #[default]
    QuickStop,
    /// 1: fault: the drive's fault reaction (0x605E), then FAULT until the operator resets it.
    Fault,
    /// 2: disable voltage: power stage off at once; the load is held only if the motor brake
    /// engages in time. Not for suspended loads without a fast brake.
    DisableVoltage,
}

impl AbortConnection {
    /// The 0x6007 value.
    pub fn code(&self) -> i16 {
        match self {
            AbortConnection::Fault => 1,
            AbortConnection::DisableVoltage => 2,
            AbortConnection::QuickStop => 3,
        }
    }
}

fn default_bitrate() -> u32 {
    1_000_000
}
fn default_cycle() -> f64 {
    0.002
}
fn default_sdo_timeout() -> f64 {
    0.1
}
fn default_sdo_retries() -> u8 {
    2
}
fn default_bringup_timeout() -> f64 {
    5.0
}
fn default_true() -> bool {
    true
}
fn default_master_node_id() -> u8 {
    127
}
fn default_master_heartbeat_ms() -> u16 {
    100
}

/// CAN bitrates that CiA 301 / CiA 102 define.
pub const CAN_BITRATES: [u32; 9] = [10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000, 100_000];

impl CanConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.interface.is_empty() || self.interface.len() > 15 || self.interface.contains(['/', ' ']) {
            return Err((
                "interface".into(),
                format!("must be a network interface name such as `can0` (1..15 characters), got {:?}", self.interface),
            ));
        }
        if !CAN_BITRATES.contains(&self.bitrate) {
            return Err(("bitrate".into(), format!("must be one of the CiA bitrates {CAN_BITRATES:?} bit/s, got {}", self.bitrate)));
        }
        if !(self.cycle_s.is_finite() && self.cycle_s >= 0.0005 && self.cycle_s <= 1.0) {
            return Err(("cycle_s".into(), format!("must be a cycle period in [0.0005, 1] s, got {}", self.cycle_s)));
        }
        if !(self.sdo_timeout_s.is_finite() && self.sdo_timeout_s > 0.0 && self.sdo_timeout_s <= 10.0) {
            return Err(("sdo_timeout_s".into(), format!("must be in (0, 10] s, got {}", self.sdo_timeout_s)));
        }
        if !(self.bringup_timeout_s.is_finite() && self.bringup_timeout_s > 0.0) {
            return Err(("bringup_timeout_s".into(), format!("must be a positive time in s, got {}", self.bringup_timeout_s)));
        }
        if !(1..=127).contains(&self.master_node_id) {
            return Err(("master_node_id".into(), format!("must be a CANopen node id 1..=127, got {}", self.master_node_id)));
        }
        if !(10..=5000).contains(&self.master_heartbeat_ms) {
            return Err((
                "master_heartbeat_ms".into(),
                format!("must be in 10..=5000 ms (drives stop 3 periods after taut's last heartbeat), got {}", self.master_heartbeat_ms),
            ));
        }
        Ok(())
    }
}

/// Which objects the drive's PDOs carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PdoMapping {
    /// RPDO1: controlword, target position, target torque; TPDO1: statusword, position actual,
    /// torque actual. One 8-byte frame each way per drive and cycle; the mode is set by SDO.
    #[default]
    Compact,
    /// Compact plus RPDO2: mode of operation, TPDO2: mode display and error code.
    WithMode,
}

/// One `[[cable.drive.rpdo]]` / `[[cable.drive.tpdo]]` table: the objects of one PDO, in order
/// (see [`crate::pdo_map`] for the syntax and the rules).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PdoTable {
    /// Objects, e.g. `["0x6040:0/16", "0x607A:0/32"]`.
    pub map: Spanned<Vec<Spanned<String>>>,
}

impl PdoTable {
    /// A table of these objects (no file position).
    pub fn new<S: Into<String>>(objects: impl IntoIterator<Item = S>) -> Self {
        PdoTable { map: Spanned::new(0..0, objects.into_iter().map(|s| Spanned::new(0..0, s.into())).collect()) }
    }
}

/// The CiA 402 mode a drive runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriveMode {
    /// Cyclic synchronous position (8): holding and reeling a cable.
    #[default]
    Position,
    /// Cyclic synchronous torque (10): a follower cable held at low tension.
    Torque,
}

/// The `[cable.drive]` sub-table: the CiA 402 servo drive of one cable.
///
/// ```toml
/// [cable.drive]
/// node_id = 1
/// drum_radius_m = 0.05      # to the cable's centre line
/// gear_ratio = 10.0         # motor turns per drum turn
/// counts_per_rev = 131072   # encoder counts per motor turn
/// rated_torque_nm = 1.27    # the 1000 per mille of 0x6071 / 0x6077
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveConfig {
    /// CANopen node id, 1..=127.
    pub node_id: u8,
    /// Drum radius to the cable's centre line, m.
    #[serde(default = "default_drum_radius")]
    pub drum_radius_m: f64,
    /// Motor revolutions per drum revolution.
    #[serde(default = "default_gear_ratio")]
    pub gear_ratio: f64,
    /// Encoder counts per motor revolution.
    #[serde(default = "default_counts_per_rev")]
    pub counts_per_rev: u32,
    /// Rated motor torque, N·m: the 1000 ‰ of the drive's torque objects.
    #[serde(default = "default_rated_torque")]
    pub rated_torque_nm: f64,
    /// True when positive counts reel the cable in (shorten it).
    #[serde(default)]
    pub invert: bool,
    /// Cyclic synchronous position or torque.
    #[serde(default)]
    pub mode: DriveMode,
    /// PDO preset (`compact` when neither this nor `rpdo`/`tpdo` tables are given).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pdo: Option<PdoMapping>,
    /// `[[cable.drive.rpdo]]` tables: the objects of RPDO1.. (instead of a preset).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rpdo: Vec<PdoTable>,
    /// `[[cable.drive.tpdo]]` tables: the objects of TPDO1.. (instead of a preset).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tpdo: Vec<PdoTable>,
    /// The drive's EDS file (CiA 306), relative to the configuration file: every object taut
    /// reads, writes or maps is checked against it before the bus is touched.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eds: Option<String>,
    /// Heartbeat period the drive is configured to produce (0x1017), ms.
    #[serde(default = "default_heartbeat_ms")]
    pub heartbeat_ms: u16,
    /// Missing heartbeats for this long mean the drive is lost, ms. Default: 3 periods.
    #[serde(default)]
    pub heartbeat_timeout_ms: Option<u32>,
    /// Largest tension the drive may be commanded to, N.
    #[serde(default = "default_max_tension")]
    pub max_tension_n: f64,
    /// Expected vendor id (0x1018 sub 1); start-up refuses a different drive. Optional.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vendor_id: Option<u32>,
    /// Expected product code (0x1018 sub 2). Optional.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub product_code: Option<u32>,
}

fn default_drum_radius() -> f64 {
    0.05
}
fn default_gear_ratio() -> f64 {
    1.0
}
fn default_counts_per_rev() -> u32 {
    131_072
}
fn default_rated_torque() -> f64 {
    1.0
}
fn default_heartbeat_ms() -> u16 {
    100
}
fn default_max_tension() -> f64 {
    500.0
}

impl DriveConfig {
    /// A drive with every default and node id `node_id`.
    pub fn with_node_id(node_id: u8) -> Self {
        DriveConfig {
            node_id,
            drum_radius_m: default_drum_radius(),
            gear_ratio: default_gear_ratio(),
            counts_per_rev: default_counts_per_rev(),
            rated_torque_nm: default_rated_torque(),
            invert: false,
            mode: DriveMode::default(),
            pdo: None,
            rpdo: Vec::new(),
            tpdo: Vec::new(),
            eds: None,
            heartbeat_ms: default_heartbeat_ms(),
            heartbeat_timeout_ms: None,
            max_tension_n: default_max_tension(),
            vendor_id: None,
            product_code: None,
        }
    }

    /// The PDO maps: the `rpdo`/`tpdo` tables, or the preset. Checked against the rules of
    /// [`crate::pdo_map`]; an error carries the span of the bad text where the tables came from a file.
    pub fn pdo_maps(&self) -> Result<PdoMaps, (String, Option<std::ops::Range<usize>>, String)> {
        if self.rpdo.is_empty() && self.tpdo.is_empty() {
            let m = PdoMaps::preset(self.pdo.unwrap_or_default());
            m.check(self.mode).map_err(|p| ("pdo".to_string(), None, format!("preset: {}", p.message)))?;
            return Ok(m);
        }
        if self.pdo.is_some() {
            return Err((
                "pdo".into(),
                None,
                "give either a preset (pdo = \"compact\" / \"with_mode\") or [[cable.drive.rpdo]] / [[cable.drive.tpdo]] tables, not both"
                    .into(),
            ));
        }
        let mut maps = PdoMaps::default();
        for (dir, tables) in [(Dir::Rx, &self.rpdo), (Dir::Tx, &self.tpdo)] {
            let out = if dir == Dir::Rx { &mut maps.rx } else { &mut maps.tx };
            for (p, t) in tables.iter().enumerate() {
                let mut objs = Vec::with_capacity(t.map.get_ref().len());
                for (e, s) in t.map.get_ref().iter().enumerate() {
                    let o = PdoObject::parse(s.get_ref()).map_err(|m| (format!("{}[{p}].map[{e}]", dir.key()), Some(s.span()), m))?;
                    objs.push(o);
                }
                out.push(objs);
            }
        }
        maps.check(self.mode).map_err(|p| {
            let span = match (p.pdo, p.entry) {
                (Some(k), Some(e)) => self.tables(p.dir).get(k).and_then(|t| t.map.get_ref().get(e)).map(|s| s.span()),
                (Some(k), None) => self.tables(p.dir).get(k).map(|t| t.map.span()),
                _ => self.tables(p.dir).first().or(self.rpdo.first()).map(|t| t.map.span()),
            };
            (p.key(), span, p.message)
        })?;
        Ok(maps)
    }

    fn tables(&self, d: Dir) -> &[PdoTable] {
        match d {
            Dir::Rx => &self.rpdo,
            Dir::Tx => &self.tpdo,
        }
    }

    /// The heartbeat timeout, ms: as configured, or three heartbeat periods.
    pub fn heartbeat_timeout(&self) -> u32 {
        self.heartbeat_timeout_ms.unwrap_or(3 * u32::from(self.heartbeat_ms))
    }

    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(1..=127).contains(&self.node_id) {
            return Err(("node_id".into(), format!("must be a CANopen node id in 1..=127, got {}", self.node_id)));
        }
        let positive = |k: &str, v: f64, unit: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err((k.to_string(), format!("must be a positive number ({unit}), got {v}")))
            }
        };
        positive("drum_radius_m", self.drum_radius_m, "m")?;
        positive("gear_ratio", self.gear_ratio, "motor turns per drum turn")?;
        positive("rated_torque_nm", self.rated_torque_nm, "N·m")?;
        positive("max_tension_n", self.max_tension_n, "N")?;
        if self.counts_per_rev == 0 {
            return Err(("counts_per_rev".into(), "must be the encoder's counts per motor turn, > 0".into()));
        }
        if self.heartbeat_ms == 0 {
            return Err(("heartbeat_ms".into(), "must be > 0: the master detects lost drives by their heartbeat".into()));
        }
        if self.heartbeat_timeout() <= u32::from(self.heartbeat_ms) {
            return Err((
                "heartbeat_timeout_ms".into(),
                format!("must be longer than heartbeat_ms ({}), got {}", self.heartbeat_ms, self.heartbeat_timeout()),
            ));
        }
        if let Some(e) = &self.eds {
            if e.trim().is_empty() {
                return Err(("eds".into(), "must name the drive's EDS file, e.g. \"drive.eds\" beside the configuration".into()));
            }
        }
        self.pdo_maps().map_err(|(k, _, m)| (k, m))?;
        Ok(())
    }
}

#[cfg(test)]
mod can_drive_tests {
    use super::*;

    #[test]
    fn can_and_drive_defaults_and_enums_parse() {
        let c: CanConfig = toml::from_str("interface = \"can0\"").unwrap();
        assert_eq!((c.bitrate, c.cycle_s, c.sdo_retries, c.reset_on_start), (1_000_000, 0.002, 2, true));
        assert_eq!((c.master_node_id, c.master_heartbeat_ms, c.abort_connection), (127, 100, AbortConnection::QuickStop));
        c.validate().unwrap();
        let d: DriveConfig = toml::from_str("node_id = 4\nmode = \"torque\"\npdo = \"with_mode\"\ninvert = true").unwrap();
        assert_eq!(
            d,
            DriveConfig { mode: DriveMode::Torque, pdo: Some(PdoMapping::WithMode), invert: true, ..DriveConfig::with_node_id(4) }
        );
        assert_eq!(d.heartbeat_timeout(), 300);
        d.validate().unwrap();
        assert!(toml::from_str::<DriveConfig>("node_id = 4\nmode = \"velocity\"").is_err());
        assert!(toml::from_str::<DriveConfig>("node_id = 4\nradius = 1.0").is_err(), "unknown keys are refused");
    }

    #[test]
    fn pdo_tables_parse_and_survive_a_save() {
        let text = "node_id = 2\n[[rpdo]]\nmap = [\"0x6040:0/16\", \"0x607A\"]\n[[tpdo]]\nmap = [\"0x6041\", \"0x6064:0/32\"]\n";
        let d: DriveConfig = toml::from_str(text).unwrap();
        let m = d.pdo_maps().unwrap();
        assert_eq!((m.rx[0].len(), m.tx[0][1]), (2, PdoObject::new(0x6064, 0, 32)));
        assert_eq!(&text[d.rpdo[0].map.get_ref()[1].span()], "\"0x607A\"");
        let back: DriveConfig = toml::from_str(&toml::to_string(&d).unwrap()).unwrap();
        assert_eq!(back, d);
        let t = DriveConfig { rpdo: vec![PdoTable::new(["0x6040"])], ..d };
        assert_eq!(t.validate().unwrap_err().0, "rpdo", "target position missing in position mode");
    }

    #[test]
    fn bad_can_and_drive_values_name_the_key() {
        let can = |s: &str| toml::from_str::<CanConfig>(&format!("interface = \"can0\"\n{s}")).unwrap().validate();
        assert_eq!(can("bitrate = 123456").unwrap_err().0, "bitrate");
        assert_eq!(can("cycle_s = 0.0").unwrap_err().0, "cycle_s");
        assert_eq!(can("sdo_timeout_s = -1.0").unwrap_err().0, "sdo_timeout_s");
        assert_eq!(can("master_node_id = 0").unwrap_err().0, "master_node_id");
        assert_eq!(can("master_node_id = 128").unwrap_err().0, "master_node_id");
        assert_eq!(can("master_heartbeat_ms = 5").unwrap_err().0, "master_heartbeat_ms");
        assert!(toml::from_str::<CanConfig>("interface = \"can0\"\nabort_connection = \"none\"").is_err(), "no 'no action' on master loss");
        let c: CanConfig = toml::from_str("interface = \"can0\"\nabort_connection = \"fault\"").unwrap();
        assert_eq!(c.abort_connection.code(), 1);
        assert_eq!(toml::from_str::<CanConfig>("interface = \"\"").unwrap().validate().unwrap_err().0, "interface");
        let drive = |s: &str| toml::from_str::<DriveConfig>(&format!("node_id = 1\n{s}")).unwrap().validate();
        assert_eq!(drive("drum_radius_m = 0.0").unwrap_err().0, "drum_radius_m");
        assert_eq!(drive("gear_ratio = nan").unwrap_err().0, "gear_ratio");
        assert_eq!(drive("counts_per_rev = 0").unwrap_err().0, "counts_per_rev");
        assert_eq!(drive("heartbeat_ms = 0").unwrap_err().0, "heartbeat_ms");
        assert_eq!(drive("heartbeat_ms = 100\nheartbeat_timeout_ms = 50").unwrap_err().0, "heartbeat_timeout_ms");
        assert_eq!(DriveConfig::with_node_id(0).validate().unwrap_err().0, "node_id");
        assert_eq!(DriveConfig::with_node_id(128).validate().unwrap_err().0, "node_id");
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
    // At 115200 baud a request and its answer take 1.5 ms on the wire and the FTDI latency
    // timer is 1 ms (udev/99-taut-loadcells.rules): 20 ms leaves a load cell ~17 ms to answer,
    // and three tries (67 ms) stay inside the default safety.tension_max_age_s (loadcell_timing).
    0.02
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

/// One entry of `[tracker] sources`: an IP address (any port) or an address and port.
pub fn parse_tracker_source(s: &str) -> Option<std::net::SocketAddr> {
    match s.trim().parse::<std::net::SocketAddr>() {
        Ok(a) => Some(a),
        // Port 0 stands for "any port": no sender can send from port 0.
        Err(_) => s.trim().parse::<std::net::IpAddr>().ok().map(|ip| std::net::SocketAddr::new(ip, 0)),
    }
}

/// The `[tracker]` table: where the external position tracker's UDP pose datagrams arrive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// UDP address to listen on for pose datagrams: the controller's address on the tracker's
    /// network, e.g. `192.168.10.1:5005`.
    pub listen: String,
    /// A pose older than this is late: dropped on arrival if it spent longer than this in
    /// transit, and missing in the loop once it is this old, s.
    #[serde(default = "default_tracker_max_age")]
    pub max_age_s: f64,
    /// Senders whose datagrams are taken: IP addresses (any port) or `address:port`. Datagrams
    /// from anyone else are dropped and counted. Empty: any sender, which is refused when
    /// `listen` is on every interface (`0.0.0.0`, `::`) unless `allow_any_source = true`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sources: Vec<String>,
    /// Take poses from any sender although `listen` is on every interface (a forged pose
    /// stream goes into the calibration that moves the robot: say so only on a closed network).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub allow_any_source: bool,
}

fn default_tracker_max_age() -> f64 {
    0.05
}

impl TrackerConfig {
    /// Listening on `listen` with the default age limit.
    pub fn new(listen: impl Into<String>) -> Self {
        TrackerConfig { listen: listen.into(), max_age_s: default_tracker_max_age(), sources: Vec::new(), allow_any_source: false }
    }

    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err((
                "listen".into(),
                format!("must be an IP address and UDP port such as \"192.168.10.1:5005\", got {:?}", self.listen),
            ));
        }
        if !(self.max_age_s.is_finite() && self.max_age_s > 0.0) {
            return Err(("max_age_s".into(), format!("must be a positive time in seconds, got {}", self.max_age_s)));
        }
        for (i, src) in self.sources.iter().enumerate() {
            if parse_tracker_source(src).is_none() {
                return Err((
                    format!("sources[{i}]"),
                    format!(
                        "must be the tracker's IP address (\"192.168.10.20\") or address and port (\"192.168.10.20:5005\"), got {src:?}"
                    ),
                ));
            }
        }
        let everywhere = self.listen.parse::<std::net::SocketAddr>().is_ok_and(|a| a.ip().is_unspecified());
        if everywhere && self.sources.is_empty() && !self.allow_any_source {
            return Err((
                "sources".into(),
                format!(
                    "listen = {:?} takes datagrams on every interface and no sources are listed, so anyone who can reach \
                     the controller could send poses: list the tracker's address (sources = [\"192.168.10.20\"]), \
                     listen on the tracker network's address only, or set allow_any_source = true",
                    self.listen
                ),
            ));
        }
        if self.allow_any_source && !self.sources.is_empty() {
            return Err(("allow_any_source".into(), "is true but sources are listed: remove one of the two".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod loadcell_tracker_tests {
    use super::*;

    #[test]
    fn loadcell_defaults_and_enums_parse() {
        let c: LoadCellConfig =
            toml::from_str("unit_id = 3\nformat = \"float32\"\nword_order = \"little\"\nregisters = \"holding\"").unwrap();
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
