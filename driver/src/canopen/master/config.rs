//! The master's settings: per drive ([`NodeConfig`]), for the bus ([`MasterConfig`]), taut's own
//! supervision, and which objects bring-up touches (for the EDS check).

use super::node::Node;
use super::script::Step;
use super::DEFAULT_BOOT_WAIT;
use std::fmt;
use std::time::Duration;
use taut_proto::canopen::cia402::Mode;
use taut_proto::canopen::pdo::{self, PdoLayout, PdoSet};
use taut_proto::canopen::{od, NodeId};

/// Settings of one drive, in driver units.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeConfig {
    /// Node id.
    pub node_id: NodeId,
    /// Index of the cable this drive winds.
    pub cable: usize,
    /// The PDOs and their maps (a preset or the configuration's tables).
    pub pdos: PdoSet,
    /// Mode of operation.
    pub mode: Mode,
    /// Heartbeat period configured into 0x1017, ms.
    pub heartbeat_ms: u16,
    /// Heartbeat timeout.
    pub heartbeat_timeout: Duration,
    /// Expected vendor id.
    pub vendor_id: Option<u32>,
    /// Expected product code.
    pub product_code: Option<u32>,
}

impl NodeConfig {
    /// A drive with test-friendly defaults (compact PDOs, CSP, 100 ms heartbeat).
    pub fn new(node_id: NodeId, cable: usize) -> Self {
        NodeConfig {
            node_id,
            cable,
            pdos: PdoLayout::Compact.pdos(),
            mode: Mode::CyclicPosition,
            heartbeat_ms: 100,
            heartbeat_timeout: Duration::from_millis(300),
            vendor_id: None,
            product_code: None,
        }
    }
}

/// How the master uses an object (see [`NodeConfig::object_uses`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Use {
    /// Read by SDO.
    Read,
    /// Written by SDO, `bytes` long.
    Write {
        /// Bytes written.
        bytes: u8,
    },
    /// Written every cycle in an RPDO.
    Rpdo {
        /// Mapped length.
        bits: u8,
    },
    /// Received every cycle in a TPDO.
    Tpdo {
        /// Mapped length.
        bits: u8,
    },
}

impl Use {
    /// "reads it", "writes it", "maps it into an RPDO", "maps it into a TPDO".
    pub fn verb(&self) -> &'static str {
        match self {
            Use::Read => "reads it",
            Use::Write { .. } => "writes it",
            Use::Rpdo { .. } => "maps it into an RPDO",
            Use::Tpdo { .. } => "maps it into a TPDO",
        }
    }
}

/// One object the master uses on a drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObjectUse {
    /// Index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// How.
    pub kind: Use,
    /// True if bring-up goes on when the drive does not have it.
    pub optional: bool,
}

impl NodeConfig {
    /// Every object bring-up reads or writes (from the same steps the master runs) and every
    /// mapped object, in order, each once per use.
    pub fn object_uses(&self) -> Vec<ObjectUse> {
        let mut out: Vec<ObjectUse> = Vec::new();
        let mut add = |u: ObjectUse| {
            if !out.contains(&u) {
                out.push(u);
            }
        };
        for s in Node::new(self.clone(), Duration::ZERO, Supervision::default()).steps {
            match s {
                Step::Upload { index, sub, required, .. } => add(ObjectUse { index, sub, kind: Use::Read, optional: !required }),
                Step::Verify(w) => add(ObjectUse { index: w.index, sub: w.sub, kind: Use::Read, optional: false }),
                Step::Download(w) => add(ObjectUse { index: w.index, sub: w.sub, kind: Use::Write { bytes: w.len }, optional: false }),
                Step::Optional(w) => add(ObjectUse { index: w.index, sub: w.sub, kind: Use::Write { bytes: w.len }, optional: true }),
                // Written only to a drive found powered, but then it must be writable.
                Step::PowerOff => add(ObjectUse { index: od::CONTROLWORD, sub: 0, kind: Use::Write { bytes: 2 }, optional: false }),
            }
        }
        for p in self.pdos.iter() {
            for e in p.entries() {
                let kind = if p.dir == pdo::Direction::Rx { Use::Rpdo { bits: e.bits } } else { Use::Tpdo { bits: e.bits } };
                add(ObjectUse { index: e.index, sub: e.sub, kind, optional: false });
            }
        }
        out
    }
}

/// Settings of the master.
#[derive(Debug, Clone, PartialEq)]
pub struct MasterConfig {
    /// The drives, in cable order.
    pub nodes: Vec<NodeConfig>,
    /// SYNC period.
    pub sync_period: Duration,
    /// Per-message SDO timeout.
    pub sdo_timeout: Duration,
    /// Further tries after an SDO timeout.
    pub sdo_retries: u8,
    /// Broadcast NMT reset communication at start-up.
    pub reset_on_start: bool,
    /// Bus bitrate, bit/s (for the bus load).
    pub bitrate: u32,
    /// How long bring-up may take.
    pub bringup_timeout: Duration,
    /// After taut's reset communication, how long a node that heartbeats may take to send its
    /// boot-up before it is configured without one (its boot-up was lost, or it ignores the
    /// reset). Heartbeats alone never start configuration before that: the boot-up does.
    pub boot_wait: Duration,
    /// taut's own heartbeat and what the drives do when it stops.
    pub supervision: Supervision,
}

/// Master supervision the CiA 301 way: taut produces a heartbeat, and every drive's heartbeat
/// consumer (0x1016) watches it; when it stops for `consumer_time` the drive raises EMCY 0x8130
/// and applies the abort connection option (0x6007, CiA 402), so a drive never holds "operation
/// enabled" for a master that is gone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Supervision {
    /// taut's node id (heartbeat COB-ID 0x700 + id).
    pub node_id: NodeId,
    /// Heartbeat period.
    pub heartbeat: Duration,
    /// 0x6007: 1 fault, 2 disable voltage, 3 quick stop.
    pub abort_connection: i16,
}

impl Supervision {
    /// The consumer time written to the drives: 3 heartbeat periods, so one lost or late
    /// heartbeat (a bus-off recovery, a stalled scheduler) does not stop the robot, and two do.
    pub fn consumer_time_ms(&self) -> u16 {
        u16::try_from(self.heartbeat.as_millis().saturating_mul(3)).unwrap_or(u16::MAX)
    }
}

impl Default for Supervision {
    /// Node 127, 100 ms, quick stop.
    fn default() -> Self {
        Supervision { node_id: 127, heartbeat: Duration::from_millis(100), abort_connection: 3 }
    }
}

/// A configuration that cannot drive a bus: the key and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigProblem {
    /// Key path, e.g. `cable[2].drive.node_id`.
    pub key: String,
    /// What is wrong and what to do.
    pub message: String,
}

impl fmt::Display for ConfigProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "key `{}`: {}", self.key, self.message)
    }
}

impl std::error::Error for ConfigProblem {}

impl MasterConfig {
    /// A configuration for `nodes` with test-friendly defaults (2 ms cycle, 1 Mbit/s).
    pub fn new(nodes: Vec<NodeConfig>) -> Self {
        MasterConfig {
            nodes,
            sync_period: Duration::from_millis(2),
            sdo_timeout: Duration::from_millis(100),
            sdo_retries: 2,
            reset_on_start: true,
            bitrate: 1_000_000,
            bringup_timeout: Duration::from_secs(5),
            boot_wait: DEFAULT_BOOT_WAIT,
            supervision: Supervision::default(),
        }
    }

    /// Builds the master's configuration from the robot description: the `[can]` table and
    /// every `[cable.drive]`.
    pub fn from_robot(cfg: &taut_config::RobotConfig) -> Result<Self, ConfigProblem> {
        use taut_proto::devices::DriveMode;
        let problem = |key: String, message: String| ConfigProblem { key, message };
        let can = cfg
            .can
            .as_ref()
            .ok_or_else(|| problem("can".into(), "the configuration has no [can] table; add one with `interface = \"can0\"`".into()))?;
        can.validate().map_err(|(k, m)| problem(format!("can.{k}"), m))?;
        let mut nodes = Vec::new();
        for (i, c) in cfg.cables.iter().enumerate() {
            let Some(d) = &c.drive else { continue };
            d.validate().map_err(|(k, m)| problem(format!("cable[{i}].drive.{k}"), m))?;
            if let Some(other) = nodes.iter().find(|n: &&NodeConfig| n.node_id == d.node_id) {
                return Err(problem(
                    format!("cable[{i}].drive.node_id"),
                    format!("node id {} is also used by cable[{}]; every drive needs its own", d.node_id, other.cable),
                ));
            }
            let node = NodeConfig {
                node_id: d.node_id,
                cable: i,
                pdos: PdoSet::from_maps(&d.pdo_maps().map_err(|(k, _, m)| problem(format!("cable[{i}].drive.{k}"), m))?),
                mode: match d.mode {
                    DriveMode::Position => Mode::CyclicPosition,
                    DriveMode::Torque => Mode::CyclicTorque,
                },
                heartbeat_ms: d.heartbeat_ms,
                heartbeat_timeout: Duration::from_millis(u64::from(d.heartbeat_timeout())),
                vendor_id: d.vendor_id,
                product_code: d.product_code,
            };
            if let Some(path) = &d.eds {
                // CiA 306: every object bring-up touches must be in the drive's EDS, checked
                // before a frame is sent.
                let key = format!("cable[{i}].drive.eds");
                let eds = taut_proto::eds::Eds::load(path).map_err(|e| problem(key.clone(), e.to_string()))?;
                crate::canopen::eds_check::check(&node, &eds).map_err(|p| {
                    let at = p.line.map_or(String::new(), |l| format!(":{l}"));
                    problem(key.clone(), format!("{path}{at}: {p}"))
                })?;
            }
            nodes.push(node);
        }
        if nodes.is_empty() {
            return Err(problem("cable.drive".into(), "no [cable.drive] table: give each driven cable a drive with a node_id".into()));
        }
        if let Some(n) = nodes.iter().find(|n| n.node_id == can.master_node_id) {
            return Err(problem(
                "can.master_node_id".into(),
                format!("node id {} is taut's own (its heartbeat) and also cable[{}]'s drive; give taut a free id", n.node_id, n.cable),
            ));
        }
        Ok(MasterConfig {
            nodes,
            sync_period: Duration::from_secs_f64(can.cycle_s),
            sdo_timeout: Duration::from_secs_f64(can.sdo_timeout_s),
            sdo_retries: can.sdo_retries,
            reset_on_start: can.reset_on_start,
            bitrate: can.bitrate,
            bringup_timeout: Duration::from_secs_f64(can.bringup_timeout_s),
            boot_wait: DEFAULT_BOOT_WAIT,
            supervision: Supervision {
                node_id: can.master_node_id,
                heartbeat: Duration::from_millis(u64::from(can.master_heartbeat_ms)),
                abort_connection: can.abort_connection.code(),
            },
        })
    }

    /// Worst-case bus load of the cyclic traffic of this configuration.
    pub fn bus_load(&self) -> crate::canopen::busload::BusLoad {
        // Layouts may differ per node: sum them node by node.
        let cycle = self.sync_period.as_secs_f64();
        let mut load = crate::canopen::busload::BusLoad::compute(0, &[], cycle, self.bitrate, 0);
        for n in &self.nodes {
            let one = crate::canopen::busload::BusLoad::compute(1, &n.pdos, cycle, self.bitrate, n.heartbeat_ms);
            let sync_bits = crate::canopen::busload::frame_bits(0, false);
            load.frames_per_cycle += one.frames_per_cycle - 1;
            load.bits_per_cycle += one.bits_per_cycle - sync_bits;
            load.heartbeat_bits_per_s += one.heartbeat_bits_per_s;
        }
        load.load = (f64::from(load.bits_per_cycle) / cycle + load.heartbeat_bits_per_s) / f64::from(self.bitrate);
        load
    }
}
