//! The CANopen master: one sans-IO state machine for all drives of the robot.
//!
//! ```text
//!            boot-up / heartbeat           all SDO steps done          heartbeat "operational"
//! Waiting ──────────────────────> Configuring ──────────> Starting ──────────────────> Operational
//!    ^                              │  identity 0x1000, 0x1018, 0x1008 (uploads)          │
//!    │   boot-up again (reboot) ────┤  0x1017 heartbeat, PDO mapping, 0x6060 (downloads)  │
//!    │                              v                                                     v
//!    └──────────────────────── Failed (abort/mismatch)        Lost (heartbeat timeout) <──┘
//! ```
//! A boot-up message in any phase restarts configuration (the node lost its PDO mapping), and a
//! lost node that comes back is configured again too. After the master's own NMT reset
//! communication a heartbeat does not start configuration, the boot-up does (a heartbeat can
//! predate the reset); a node that heartbeats but never boots is configured after
//! [`MasterConfig::boot_wait`]. Configuration first reads the statusword and position and switches
//! off a drive found powered, and it sets each drive's heartbeat consumer (0x1016) for the
//! master's own heartbeat and the abort connection option (0x6007), see [`Supervision`]. Per SYNC cycle the master sends SYNC, then
//! one RPDO set per operational drive; drives answer with their TPDOs.
//!
//! Bad input never panics: frames that are malformed, from unknown nodes or not meant for a
//! master are counted in [`Counters`]; the first of each kind is reported once as
//! [`Event::FirstOfKind`].

use super::cia402::{self, Mode, Scaling, State, Want};
use super::emcy::{self, Emcy};
use super::heartbeat::{self, HeartbeatConsumer};
use super::nmt::{self, NmtCommand, NmtState};
use super::pdo::{self, PdoLayout, PdoSet, SdoWrite};
use super::sdo::{AbortCode, SdoAbort, SdoClient, SdoDiscard, SdoOutcome};
use super::sync::{self, SyncProducer};
use super::{function_code, node_of, od, NodeId};
use crate::transport::{BusEvent, Frame};
use std::fmt;
use std::time::{Duration, Instant};

/// Capacity of the transmit queue, frames.
pub const TX_QUEUE: usize = 256;
/// Capacity of the event queue.
pub const EVENT_QUEUE: usize = 128;
/// How long a node heard after taut's reset communication may take to boot (CiA 301 leaves the
/// reset time to the device; drives take milliseconds to a few hundred).
pub const DEFAULT_BOOT_WAIT: Duration = Duration::from_millis(1000);
/// Cycles a fault reset is held before giving up.
const FAULT_RESET_CYCLES: u16 = 100;

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
    /// Counts and torque to metres and newtons.
    pub scaling: Scaling,
    /// Largest tension that may be commanded, N.
    pub max_tension_n: f64,
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
            scaling: Scaling { drum_radius_m: 0.05, gear_ratio: 1.0, counts_per_rev: 131_072.0, rated_torque_nm: 1.0, sign: 1.0 },
            max_tension_n: 500.0,
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
        use taut_config::devices::DriveMode;
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
                scaling: Scaling {
                    drum_radius_m: d.drum_radius_m,
                    gear_ratio: d.gear_ratio,
                    counts_per_rev: f64::from(d.counts_per_rev),
                    rated_torque_nm: d.rated_torque_nm,
                    sign: if d.invert { -1.0 } else { 1.0 },
                },
                max_tension_n: d.max_tension_n,
                vendor_id: d.vendor_id,
                product_code: d.product_code,
            };
            if let Some(path) = &d.eds {
                // CiA 306: every object bring-up touches must be in the drive's EDS, checked
                // before a frame is sent.
                let key = format!("cable[{i}].drive.eds");
                let eds = taut_config::eds::Eds::load(path).map_err(|e| problem(key.clone(), e.to_string()))?;
                super::eds_check::check(&node, &eds).map_err(|p| {
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
    pub fn bus_load(&self) -> super::busload::BusLoad {
        // Layouts may differ per node: sum them node by node.
        let cycle = self.sync_period.as_secs_f64();
        let mut load = super::busload::BusLoad::compute(0, &[], cycle, self.bitrate, 0);
        for n in &self.nodes {
            let one = super::busload::BusLoad::compute(1, &n.pdos, cycle, self.bitrate, n.heartbeat_ms);
            let sync_bits = super::busload::frame_bits(0, false);
            load.frames_per_cycle += one.frames_per_cycle - 1;
            load.bits_per_cycle += one.bits_per_cycle - sync_bits;
            load.heartbeat_bits_per_s += one.heartbeat_bits_per_s;
        }
        load.load = (f64::from(load.bits_per_cycle) / cycle + load.heartbeat_bits_per_s) / f64::from(self.bitrate);
        load
    }
}

/// The identity of a node (0x1000, 0x1018).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Identity {
    /// Device type, 0x1000.
    pub device_type: Option<u32>,
    /// Vendor id, 0x1018 sub 1.
    pub vendor: Option<u32>,
    /// Product code, 0x1018 sub 2.
    pub product: Option<u32>,
    /// Revision, 0x1018 sub 3.
    pub revision: Option<u32>,
    /// Serial number, 0x1018 sub 4.
    pub serial: Option<u32>,
}

/// Why a node could not be brought up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeFailure {
    /// The node refused a required SDO transfer.
    Sdo(SdoAbort),
    /// Read back after writing, an object of the PDO configuration did not hold what was written.
    Readback {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Value written.
        expected: u32,
        /// Value read back.
        found: u32,
    },
    /// The identity does not match the configuration.
    WrongDevice {
        /// Object checked (0x1018 sub 1 or 2).
        sub: u8,
        /// Configured value.
        expected: u32,
        /// Value read.
        found: u32,
    },
}

impl fmt::Display for NodeFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeFailure::Sdo(a) => write!(f, "{a}"),
            NodeFailure::Readback { index, sub, expected, found } => write!(
                f,
                "PDO configuration read back from 0x{index:04X}sub{sub} is 0x{found:08X}, 0x{expected:08X} was written: the drive did not take the mapping"
            ),
            NodeFailure::WrongDevice { sub, expected, found } => write!(
                f,
                "identity 0x1018sub{sub} is 0x{found:08X}, the configuration expects 0x{expected:08X}: wrong drive on this node id?"
            ),
        }
    }
}

/// The master's view of a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Not heard from yet.
    Waiting,
    /// Reading its identity and writing its configuration by SDO.
    Configuring,
    /// Configured; NMT start sent, waiting for it to report operational.
    Starting,
    /// Operational: PDOs exchanged every cycle.
    Operational,
    /// Heartbeat timed out.
    Lost,
    /// Configuration failed; waits for a boot-up to try again.
    Failed(NodeFailure),
}

impl Phase {
    /// Short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            Phase::Waiting => "waiting",
            Phase::Configuring => "configuring",
            Phase::Starting => "starting",
            Phase::Operational => "operational",
            Phase::Lost => "LOST",
            Phase::Failed(_) => "FAILED",
        }
    }
}

/// Kinds of bad or unexpected input, each reported once by [`Event::FirstOfKind`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Problem {
    /// A frame of a known node with the wrong length or content.
    Malformed = 0,
    /// A node-specific frame from a node id not in the configuration.
    UnknownNode,
    /// A frame a master does not take (other masters' commands, LSS, extended ids, RTR).
    Ignored,
    /// An SDO transfer aborted.
    SdoAbort,
    /// An SDO transfer timed out.
    SdoTimeout,
    /// An SDO response when none was expected.
    UnexpectedSdo,
    /// An SDO response that does not answer the request in flight (late, duplicated, stale).
    StaleSdo,
    /// A node heartbeating after taut's reset communication sent no boot-up in time.
    BootUpMissing,
    /// A TPDO shorter than its mapping.
    PdoLength,
    /// The CAN interface reported a bus problem.
    Bus,
    /// The transmit queue was full.
    TxOverflow,
    /// The event queue was full.
    EventOverflow,
}

impl Problem {
    /// Description for people.
    pub fn describe(&self) -> &'static str {
        match self {
            Problem::Malformed => "malformed frame from a configured node (wrong length or content)",
            Problem::UnknownNode => "frame from a node id that is not in the configuration",
            Problem::Ignored => "frame not addressed to a master (other master, LSS, extended id, RTR)",
            Problem::SdoAbort => "SDO transfer aborted",
            Problem::SdoTimeout => "SDO transfer timed out",
            Problem::UnexpectedSdo => "SDO response with no transfer in progress",
            Problem::StaleSdo => "SDO response that does not answer the request in flight (late or duplicated), dropped",
            Problem::BootUpMissing => "node heartbeats but sent no boot-up after the reset communication; configuring it anyway",
            Problem::PdoLength => "TPDO shorter than its mapping",
            Problem::Bus => "CAN bus problem reported by the interface",
            Problem::TxOverflow => "transmit queue full, frames dropped",
            Problem::EventOverflow => "event queue full, events dropped",
        }
    }
}

/// Something the application should know about.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// A boot-up message.
    Booted {
        /// Node.
        node: NodeId,
    },
    /// A node that had been configured booted again (power cycle, watchdog, reset).
    Rebooted {
        /// Node.
        node: NodeId,
    },
    /// A drive was found with its power stage on (left so by a previous run, or holding after
    /// its own master-loss reaction) and is being switched off before configuration.
    FoundPowered {
        /// Node.
        node: NodeId,
        /// The state it was found in.
        state: State,
    },
    /// Identity read.
    Identified {
        /// Node.
        node: NodeId,
        /// What it said.
        identity: Identity,
    },
    /// All SDO configuration written; NMT start sent.
    Configured {
        /// Node.
        node: NodeId,
    },
    /// The node reports operational.
    Operational {
        /// Node.
        node: NodeId,
    },
    /// The node could not be configured.
    Failed {
        /// Node.
        node: NodeId,
        /// Why.
        failure: NodeFailure,
    },
    /// Heartbeat timed out.
    HeartbeatLost {
        /// Node.
        node: NodeId,
    },
    /// Heartbeat back after a loss (the node is configured again).
    HeartbeatRecovered {
        /// Node.
        node: NodeId,
    },
    /// An emergency message.
    Emergency {
        /// Node.
        node: NodeId,
        /// The message.
        emcy: Emcy,
    },
    /// The CiA 402 state of a drive changed.
    DriveState {
        /// Node.
        node: NodeId,
        /// New state.
        state: State,
    },
    /// An SDO transfer was aborted (by either side).
    SdoAborted {
        /// Node.
        node: NodeId,
        /// Details.
        abort: SdoAbort,
    },
    /// A bus problem reported by the interface.
    Bus(BusEvent),
    /// The first occurrence of a kind of bad input (later ones are only counted).
    FirstOfKind {
        /// Kind.
        kind: Problem,
        /// The CAN id of the frame, or 0.
        cob_id: u32,
    },
}

impl fmt::Display for Event {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Event::Booted { node } => write!(f, "node {node}: boot-up"),
            Event::Rebooted { node } => write!(f, "node {node}: rebooted, configuring it again"),
            Event::Identified { node, identity: i } => write!(
                f,
                "node {node}: device type 0x{:08X}, vendor 0x{:08X}, product 0x{:08X}",
                i.device_type.unwrap_or(0),
                i.vendor.unwrap_or(0),
                i.product.unwrap_or(0)
            ),
            Event::FoundPowered { node, state } => {
                write!(f, "node {node}: found {} (left by a previous run); switching the power stage off", state.name())
            }
            Event::Configured { node } => write!(f, "node {node}: configured, starting"),
            Event::Operational { node } => write!(f, "node {node}: operational"),
            Event::Failed { node, failure } => write!(f, "node {node}: configuration failed: {failure}"),
            Event::HeartbeatLost { node } => write!(f, "node {node}: heartbeat lost"),
            Event::HeartbeatRecovered { node } => write!(f, "node {node}: heartbeat back"),
            Event::Emergency { node, emcy } => write!(f, "node {node}: {emcy}"),
            Event::DriveState { node, state } => write!(f, "node {node}: drive {}", state.name()),
            Event::SdoAborted { node, abort } => write!(f, "node {node}: {abort}"),
            Event::Bus(e) => write!(f, "{e}"),
            Event::FirstOfKind { kind, cob_id } => {
                write!(f, "{} (first one, id 0x{cob_id:03X}; further ones are only counted)", kind.describe())
            }
        }
    }
}

/// Counts of everything unusual, for `taut probe` and the logs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Frames received.
    pub rx_frames: u64,
    /// Frames queued for sending.
    pub tx_frames: u64,
    /// SYNC cycles run.
    pub sync_cycles: u64,
    /// Malformed frames from configured nodes.
    pub malformed: u64,
    /// Frames from unknown node ids.
    pub unknown_node: u64,
    /// Frames not for a master.
    pub ignored: u64,
    /// SDO aborts (either side).
    pub sdo_aborts: u64,
    /// SDO timeouts.
    pub sdo_timeouts: u64,
    /// SDO responses with no transfer.
    pub unexpected_sdo: u64,
    /// SDO responses dropped because they do not answer the request in flight (late,
    /// duplicated, malformed): never taken as the answer, never answered with an abort.
    pub sdo_discarded: u64,
    /// SDO transfers tried again after the client gave up on them (timeout, oversize).
    pub sdo_retries: u64,
    /// Nodes configured without a boot-up: they heartbeat, but their boot-up after taut's reset
    /// communication never came (lost on the bus, or the node ignores the reset).
    pub boot_ups_missing: u64,
    /// Short TPDOs.
    pub pdo_length: u64,
    /// EMCY messages (not counting "error reset").
    pub emergencies: u64,
    /// Heartbeat losses.
    pub heartbeat_losses: u64,
    /// Reboots of configured nodes.
    pub reboots: u64,
    /// Bus problems reported by the interface.
    pub bus_errors: u64,
    /// Frames dropped because the transmit queue was full.
    pub tx_dropped: u64,
    /// Events dropped because the event queue was full.
    pub events_dropped: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    DeviceType,
    Vendor,
    Product,
    Revision,
    Serial,
    Name,
    /// 0x6041: the CiA 402 state a previous run left the drive in.
    Statusword,
    /// 0x6064: where it stands, so that the first target is that.
    Position,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    Upload {
        index: u16,
        sub: u8,
        field: Field,
        required: bool,
    },
    Download(SdoWrite),
    /// Brings a drive found powered (left enabled by a previous run, or stopped by its own
    /// master-loss reaction) to a power stage off, by SDO before anything else is written:
    /// CiA 402 transition 8 (shutdown) from switched on / operation enabled, 12 (disable
    /// voltage) from quick stop active. Skipped for drives already off or in fault (a fault
    /// stays until the operator resets it).
    PowerOff,
    /// A download a drive may refuse because the object does not exist (an unused PDO).
    Optional(SdoWrite),
    /// Upload and compare with the value: the read-back of the PDO configuration.
    Verify(SdoWrite),
}

/// The CiA 402 side of a node, as the master sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    /// Last statusword.
    pub statusword: u16,
    /// State decoded from it (`None` before the first TPDO).
    pub state: Option<State>,
    /// Position actual value, counts.
    pub position: i32,
    /// Torque actual value, ‰ of rated torque.
    pub torque: i16,
    /// Velocity actual value 0x606C, counts/s (0 unless the map carries it).
    pub velocity: i32,
    /// Mode display (with the `with_mode` layout).
    pub mode_display: Option<Mode>,
    /// Error code 0x603F (with the `with_mode` layout) or from the last EMCY.
    pub error_code: u16,
    /// TPDOs received.
    pub tpdos: u64,
    /// Mode of operation commanded now (the configured one, or the last
    /// [`Operational::set_mode`] with the `with_mode` layout).
    pub mode: Mode,
    want: Want,
    reset_fault: u16,
    target_position: i32,
    target_torque: i16,
}

impl Axis {
    fn new(mode: Mode) -> Self {
        Axis {
            mode,
            statusword: 0,
            state: None,
            position: 0,
            torque: 0,
            velocity: 0,
            mode_display: None,
            error_code: 0,
            tpdos: 0,
            want: Want::Disabled,
            reset_fault: 0,
            target_position: 0,
            target_torque: 0,
        }
    }
}

/// A snapshot of one node for display.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeStatus {
    /// Node id.
    pub node: NodeId,
    /// Cable index.
    pub cable: usize,
    /// Master's phase.
    pub phase: Phase,
    /// Last NMT state heard.
    pub nmt: Option<NmtState>,
    /// Identity read at configuration.
    pub identity: Identity,
    /// CiA 402 side.
    pub axis: Axis,
    /// Position in metres of cable.
    pub position_m: f64,
    /// Tension from the drive's torque, N.
    pub tension_n: f64,
    /// Boot-up messages seen.
    pub boots: u32,
    /// Last emergency (not counting "error reset").
    pub last_emcy: Option<Emcy>,
    /// Mode of operation commanded now.
    pub mode: Mode,
    name: [u8; 32],
    name_len: u8,
}

impl NodeStatus {
    /// The manufacturer device name (0x1008), if read.
    pub fn name(&self) -> &str {
        std::str::from_utf8(&self.name[..usize::from(self.name_len)]).unwrap_or("?")
    }
}

/// The PDO part of a node's configuration steps: every PDO of the map the CiA 301 way, the
/// unused PDOs of the predefined connection set off, the PDO configuration read back, and the
/// mode by SDO when no RPDO carries it.
fn pdo_steps(cfg: &NodeConfig, steps: &mut Vec<Step>) {
    let n = cfg.node_id;
    for p in cfg.pdos.iter() {
        steps.extend(p.config_writes(n).map(Step::Download));
    }
    for dir in [pdo::Direction::Rx, pdo::Direction::Tx] {
        for num in (0..4).filter(|&k| !cfg.pdos.has(dir, k)) {
            steps.push(Step::Optional(pdo::disable_write(dir, num, n)));
        }
    }
    for p in cfg.pdos.iter() {
        steps.extend(p.readback(n).map(Step::Verify));
    }
    if !cfg.pdos.maps_mode() {
        steps.push(Step::Download(SdoWrite::u8(od::MODES_OF_OPERATION, 0, cfg.mode.code() as u8)));
    }
}

struct Node {
    cfg: NodeConfig,
    phase: Phase,
    nmt: Option<NmtState>,
    hb: HeartbeatConsumer,
    sdo: SdoClient,
    steps: Vec<Step>,
    step: usize,
    tries: u8,
    identity: Identity,
    name: [u8; 32],
    name_len: u8,
    axis: Axis,
    boots: u32,
    /// When a heartbeat (not a boot-up) was first seen after taut's reset communication.
    heard_since_reset: Option<Instant>,
    last_emcy: Option<Emcy>,
    /// TPDO COB-IDs, for matching received frames.
    tpdo_ids: [u16; 4],
}

impl Node {
    fn new(cfg: NodeConfig, sdo_timeout: Duration, sup: Supervision) -> Node {
        let n = cfg.node_id;
        let mut steps = vec![
            Step::Upload { index: od::DEVICE_TYPE, sub: 0, field: Field::DeviceType, required: true },
            Step::Upload { index: od::IDENTITY, sub: 1, field: Field::Vendor, required: true },
            Step::Upload { index: od::IDENTITY, sub: 2, field: Field::Product, required: false },
            Step::Upload { index: od::IDENTITY, sub: 3, field: Field::Revision, required: false },
            Step::Upload { index: od::IDENTITY, sub: 4, field: Field::Serial, required: false },
            Step::Upload { index: od::DEVICE_NAME, sub: 0, field: Field::Name, required: false },
            Step::Upload { index: od::STATUSWORD, sub: 0, field: Field::Statusword, required: true },
            Step::Upload { index: od::POSITION_ACTUAL, sub: 0, field: Field::Position, required: true },
            Step::PowerOff,
            Step::Download(SdoWrite::u16(od::HEARTBEAT_PRODUCER, 0, cfg.heartbeat_ms)),
            // Supervision of taut by the drive: abort connection option first, then the consumer
            // (which starts watching at taut's next heartbeat).
            Step::Download(SdoWrite::u16(od::ABORT_CONNECTION, 0, sup.abort_connection as u16)),
            Step::Download(SdoWrite::u32(
                od::HEARTBEAT_CONSUMER,
                1,
                u32::from(sup.node_id & 0x7F) << 16 | u32::from(sup.consumer_time_ms()),
            )),
        ];
        pdo_steps(&cfg, &mut steps);
        let mut tpdo_ids = [0u16; 4];
        for (k, p) in cfg.pdos.iter().filter(|p| p.dir == pdo::Direction::Tx).enumerate().take(4) {
            tpdo_ids[k] = p.cob_id(n);
        }
        let axis = Axis::new(cfg.mode);
        Node {
            hb: HeartbeatConsumer::new(cfg.heartbeat_timeout),
            sdo: SdoClient::new(n, sdo_timeout),
            cfg,
            phase: Phase::Waiting,
            nmt: None,
            steps,
            step: 0,
            tries: 0,
            identity: Identity::default(),
            name: [0; 32],
            name_len: 0,
            axis,
            boots: 0,
            heard_since_reset: None,
            last_emcy: None,
            tpdo_ids,
        }
    }

    fn status(&self) -> NodeStatus {
        NodeStatus {
            node: self.cfg.node_id,
            cable: self.cfg.cable,
            phase: self.phase,
            nmt: self.nmt,
            identity: self.identity,
            axis: self.axis,
            position_m: self.cfg.scaling.counts_to_m(self.axis.position),
            tension_n: self.cfg.scaling.permille_to_n(self.axis.torque),
            boots: self.boots,
            last_emcy: self.last_emcy,
            mode: self.axis.mode,
            name: self.name,
            name_len: self.name_len,
        }
    }
}

/// The master. See the module documentation.
pub struct Master {
    nodes: Vec<Node>,
    /// node id -> index into `nodes` + 1 (0: not configured).
    by_id: [u8; 128],
    sync: SyncProducer,
    cfg_retries: u8,
    reset_on_start: bool,
    started: bool,
    /// How long a node heard after taut's reset communication may take to send its boot-up.
    boot_wait: Duration,
    supervision: Supervision,
    /// When taut's next heartbeat is due.
    next_heartbeat: Option<Instant>,
    tx: heapless::Deque<Frame, TX_QUEUE>,
    events: heapless::Deque<Event, EVENT_QUEUE>,
    counters: Counters,
    reported: u32,
}

impl Master {
    /// A master for the configured drives. Allocates everything it will use.
    pub fn new(cfg: MasterConfig) -> Master {
        let mut by_id = [0u8; 128];
        let mut nodes = Vec::with_capacity(cfg.nodes.len());
        for n in cfg.nodes.into_iter().take(127) {
            let id = usize::from(n.node_id & 0x7F);
            if id == 0 || by_id[id] != 0 {
                continue; // validated by MasterConfig::from_robot; skipped here rather than panic
            }
            nodes.push(Node::new(n, cfg.sdo_timeout, cfg.supervision));
            by_id[id] = nodes.len() as u8;
        }
        Master {
            nodes,
            by_id,
            sync: SyncProducer::new(cfg.sync_period),
            cfg_retries: cfg.sdo_retries,
            reset_on_start: cfg.reset_on_start,
            started: false,
            boot_wait: cfg.boot_wait,
            supervision: cfg.supervision,
            next_heartbeat: None,
            tx: heapless::Deque::new(),
            events: heapless::Deque::new(),
            counters: Counters::default(),
            reported: 0,
        }
    }

    /// Number of drives.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True if no drive is configured.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// A snapshot of drive `i` (in configuration order).
    pub fn status(&self, i: usize) -> Option<NodeStatus> {
        self.nodes.get(i).map(Node::status)
    }

    /// Snapshots of all drives.
    pub fn statuses(&self) -> impl Iterator<Item = NodeStatus> + '_ {
        self.nodes.iter().map(Node::status)
    }

    /// The index of node `id`, if configured.
    pub fn index_of(&self, id: NodeId) -> Option<usize> {
        match self.by_id.get(usize::from(id)) {
            Some(&k) if k > 0 => Some(usize::from(k) - 1),
            _ => None,
        }
    }

    /// True when every drive is operational (PDOs flowing).
    pub fn all_operational(&self) -> bool {
        !self.nodes.is_empty() && self.nodes.iter().all(|n| n.phase == Phase::Operational)
    }

    /// True when every drive is operational and in "operation enabled".
    pub fn all_enabled(&self) -> bool {
        self.all_operational() && self.nodes.iter().all(|n| n.axis.state == Some(State::OperationEnabled))
    }

    /// The next frame to send.
    pub fn poll_tx(&mut self) -> Option<Frame> {
        self.tx.pop_front()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// The earliest time at which [`poll`](Self::poll) has something to do.
    pub fn next_deadline(&self) -> Option<Instant> {
        let mut t = self.sync.next_deadline();
        if let Some(h) = self.next_heartbeat {
            t = Some(t.map_or(h, |x| x.min(h)));
        }
        for n in &self.nodes {
            let boot = if n.phase == Phase::Waiting { n.heard_since_reset.map(|t| t + self.boot_wait) } else { None };
            for d in [n.sdo.next_deadline(), n.hb.deadline(), boot].into_iter().flatten() {
                t = Some(t.map_or(d, |x| x.min(d)));
            }
        }
        t
    }

    /// The SYNC period.
    pub fn sync_period(&self) -> Duration {
        self.sync.period()
    }

    fn push_tx(&mut self, f: Frame) {
        if self.tx.push_back(f).is_err() {
            self.counters.tx_dropped += 1;
            self.problem(Problem::TxOverflow, f.id);
        } else {
            self.counters.tx_frames += 1;
        }
    }

    fn event(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.counters.events_dropped += 1;
            if self.reported & (1 << Problem::EventOverflow as u32) == 0 {
                self.reported |= 1 << Problem::EventOverflow as u32;
                // Make room for the notice itself: the oldest event goes.
                let _ = self.events.pop_front();
                let _ = self.events.push_back(Event::FirstOfKind { kind: Problem::EventOverflow, cob_id: 0 });
            }
        }
    }

    fn problem(&mut self, kind: Problem, cob_id: u32) {
        let bit = 1u32 << kind as u32;
        if self.reported & bit == 0 {
            self.reported |= bit;
            self.event(Event::FirstOfKind { kind, cob_id });
        }
    }

    /// Sends an NMT command (0 = all nodes).
    pub fn send_nmt(&mut self, cmd: NmtCommand, node: NodeId) {
        self.push_tx(nmt::encode(cmd, node));
    }

    /// Reports a bus problem from the transport.
    pub fn on_bus_event(&mut self, e: BusEvent) {
        self.counters.bus_errors += 1;
        self.problem(Problem::Bus, 0);
        // Repeated error-warning/passive reports on a flaky bus would flood the queue; bus-off
        // and overflows always go through.
        if e.is_severe() || self.counters.bus_errors <= 16 {
            self.event(Event::Bus(e));
        }
    }

    /// Handles one received frame.
    pub fn on_frame(&mut self, f: &Frame, now: Instant) {
        self.counters.rx_frames += 1;
        let Some(id) = f.std_id() else {
            self.counters.ignored += 1;
            self.problem(Problem::Ignored, f.id);
            return;
        };
        let fc = function_code(id);
        let node = node_of(id);
        match fc {
            // NMT, SYNC/EMCY with node 0 (another SYNC producer), TIME, RPDOs and SDO
            // requests (another master), LSS (0x7E4/0x7E5 fall in 0x780 with node > 0x63).
            0x000 | 0x100 | 0x200 | 0x300 | 0x400 | 0x500 | 0x600 => return self.ignore(f),
            0x080 if node == 0 => return self.ignore(f),
            0x780 => return self.ignore(f),
            _ => {}
        }
        let Some(k) = self.index_of(node) else {
            self.counters.unknown_node += 1;
            self.problem(Problem::UnknownNode, f.id);
            return;
        };
        match fc {
            0x080 => self.on_emcy(k, f),
            0x180 | 0x280 | 0x380 | 0x480 => self.on_tpdo(k, id, f),
            0x580 => self.on_sdo(k, f, now),
            0x700 => self.on_heartbeat(k, f, now),
            _ => self.ignore(f),
        }
    }

    fn ignore(&mut self, f: &Frame) {
        self.counters.ignored += 1;
        self.problem(Problem::Ignored, f.id);
    }

    fn malformed(&mut self, f: &Frame) {
        self.counters.malformed += 1;
        self.problem(Problem::Malformed, f.id);
    }

    fn on_emcy(&mut self, k: usize, f: &Frame) {
        let Ok(e) = emcy::decode(f.data()) else { return self.malformed(f) };
        let node = self.nodes[k].cfg.node_id;
        if !e.is_reset() {
            self.counters.emergencies += 1;
            self.nodes[k].last_emcy = Some(e);
            self.nodes[k].axis.error_code = e.code;
        }
        self.event(Event::Emergency { node, emcy: e });
    }

    fn on_tpdo(&mut self, k: usize, id: u16, f: &Frame) {
        let n = &mut self.nodes[k];
        let Some(def) = n.cfg.pdos.iter().find(|p| p.dir == pdo::Direction::Tx && p.cob_id(n.cfg.node_id) == id) else {
            return self.ignore(f);
        };
        if !n.tpdo_ids.contains(&id) {
            return self.ignore(f);
        }
        let ax = &mut n.axis;
        let r = pdo::unpack(def.entries(), f.data(), |index, _sub, raw, bits| match index {
            od::STATUSWORD => ax.statusword = raw as u16,
            od::POSITION_ACTUAL => ax.position = pdo::sign_extend(raw, bits) as i32,
            od::VELOCITY_ACTUAL => ax.velocity = pdo::sign_extend(raw, bits) as i32,
            od::TORQUE_ACTUAL => ax.torque = pdo::sign_extend(raw, bits) as i16,
            od::MODES_OF_OPERATION_DISPLAY => ax.mode_display = Some(Mode::from_code(raw as u8 as i8)),
            od::ERROR_CODE => ax.error_code = raw as u16,
            _ => {}
        });
        if r.is_err() {
            self.counters.pdo_length += 1;
            self.counters.malformed += 1;
            return self.problem(Problem::PdoLength, f.id);
        }
        let node = n.cfg.node_id;
        ax.tpdos += 1;
        let new = State::from_statusword(ax.statusword);
        let changed = new != ax.state;
        ax.state = new;
        if new != Some(State::OperationEnabled) {
            // Hold: when the drive becomes enabled, its target is where it stands.
            ax.target_position = ax.position;
            ax.target_torque = 0;
        }
        if ax.reset_fault > 0 && new != Some(State::Fault) {
            ax.reset_fault = 0;
        }
        if matches!(new, Some(State::Fault | State::FaultReactionActive)) {
            // A fault drops the wish to be enabled: re-enabling is a decision for the caller.
            ax.want = Want::Disabled;
        }
        let first_pdo = n.phase == Phase::Starting;
        if first_pdo {
            // TPDOs only flow in operational: no need to wait for the next heartbeat.
            n.phase = Phase::Operational;
            n.nmt = Some(NmtState::Operational);
        }
        if first_pdo {
            self.event(Event::Operational { node });
        }
        if changed {
            if let Some(s) = new {
                self.event(Event::DriveState { node, state: s });
            }
        }
    }

    fn on_sdo(&mut self, k: usize, f: &Frame, now: Instant) {
        if f.dlc != 8 {
            // Not handed to the client: a truncated frame is noise, the real answer or the
            // timeout follows.
            return self.malformed(f);
        }
        match self.nodes[k].sdo.on_response(f.data(), now) {
            Ok(Some(outcome)) => self.on_sdo_outcome(k, outcome, now),
            Ok(None) => self.flush_sdo(k),
            Err(SdoDiscard::Idle) => {
                self.counters.unexpected_sdo += 1;
                self.problem(Problem::UnexpectedSdo, f.id);
            }
            Err(SdoDiscard::Mismatch { .. } | SdoDiscard::Malformed(_)) => {
                self.counters.sdo_discarded += 1;
                self.problem(Problem::StaleSdo, f.id);
            }
        }
        self.flush_sdo(k);
    }

    fn flush_sdo(&mut self, k: usize) {
        while let Some(f) = self.nodes[k].sdo.poll_tx() {
            self.push_tx(f);
        }
    }

    fn on_heartbeat(&mut self, k: usize, f: &Frame, now: Instant) {
        let Ok(state) = heartbeat::decode(f.data()) else { return self.malformed(f) };
        let node = self.nodes[k].cfg.node_id;
        let n = &mut self.nodes[k];
        if state == NmtState::BootUp {
            n.boots += 1;
            let was = n.phase;
            n.nmt = Some(NmtState::PreOperational);
            self.event(Event::Booted { node });
            if !matches!(was, Phase::Waiting) {
                self.counters.reboots += 1;
                self.event(Event::Rebooted { node });
            }
            self.begin_config(k, now);
            return;
        }
        n.nmt = Some(state);
        match n.phase {
            // After taut's own reset communication the node is configured at its boot-up: a
            // heartbeat may have been sent before the reset took effect, and configuring on it
            // would start a second configuration (and a second answer to every request) when the
            // boot-up follows. A node whose boot-up never comes is configured after boot_wait.
            Phase::Waiting if self.reset_on_start => {
                n.heard_since_reset.get_or_insert(now);
            }
            Phase::Waiting => self.begin_config(k, now),
            Phase::Configuring | Phase::Failed(_) => {}
            Phase::Lost => {
                n.hb.on_heartbeat(now);
                self.event(Event::HeartbeatRecovered { node });
                self.begin_config(k, now);
            }
            Phase::Starting => {
                n.hb.on_heartbeat(now);
                if state == NmtState::Operational {
                    n.phase = Phase::Operational;
                    self.event(Event::Operational { node });
                } else {
                    self.send_nmt(NmtCommand::Start, node);
                }
            }
            Phase::Operational => {
                n.hb.on_heartbeat(now);
                if state != NmtState::Operational {
                    // Someone stopped it or it fell back to pre-operational (e.g. its heartbeat
                    // consumer lost taut and it applied 0x6007): start it again, but never
                    // enabled again by itself; that is the application's decision, as after a
                    // fault or a reboot.
                    n.axis.want = Want::Disabled;
                    n.phase = Phase::Starting;
                    self.send_nmt(NmtCommand::Start, node);
                }
            }
        }
    }

    fn begin_config(&mut self, k: usize, now: Instant) {
        let n = &mut self.nodes[k];
        n.heard_since_reset = None;
        n.sdo.cancel();
        n.hb.reset();
        n.phase = Phase::Configuring;
        n.step = 0;
        n.tries = 0;
        n.identity = Identity::default();
        n.axis = Axis::new(n.cfg.mode);
        self.next_step(k, now);
    }

    fn next_step(&mut self, k: usize, now: Instant) {
        let n = &mut self.nodes[k];
        if n.phase != Phase::Configuring || n.sdo.is_busy() {
            return;
        }
        let node = n.cfg.node_id;
        match n.steps.get(n.step).copied() {
            Some(Step::Upload { index, sub, .. } | Step::Verify(SdoWrite { index, sub, .. })) => {
                let _ = n.sdo.upload(index, sub, now);
            }
            Some(Step::PowerOff) => {
                let cw = match n.axis.state {
                    Some(s @ (State::OperationEnabled | State::SwitchedOn)) => Some((s, cia402::CW_SHUTDOWN)),
                    Some(s @ State::QuickStopActive) => Some((s, cia402::CW_DISABLE_VOLTAGE)),
                    _ => None,
                };
                let Some((state, cw)) = cw else {
                    n.step += 1;
                    return self.next_step(k, now);
                };
                let _ = n.sdo.download(od::CONTROLWORD, 0, &cw.to_le_bytes(), false, now);
                self.event(Event::FoundPowered { node, state });
            }
            Some(Step::Download(w) | Step::Optional(w)) => {
                let (b, len) = w.bytes();
                let _ = n.sdo.download(w.index, w.sub, &b[..len], false, now);
            }
            None => {
                n.phase = Phase::Starting;
                // Watch the heartbeat from now on: 0x1017 has been written.
                n.hb.on_heartbeat(now);
                self.event(Event::Configured { node });
                self.send_nmt(NmtCommand::Start, node);
                return;
            }
        }
        self.flush_sdo(k);
    }

    fn on_sdo_outcome(&mut self, k: usize, o: SdoOutcome, now: Instant) {
        let node = self.nodes[k].cfg.node_id;
        let Some(step) = self.nodes[k].steps.get(self.nodes[k].step).copied() else { return };
        if self.nodes[k].phase != Phase::Configuring {
            return;
        }
        match o {
            SdoOutcome::Uploaded { len, .. } => {
                let n = &mut self.nodes[k];
                let d = n.sdo.data();
                let mut b = [0u8; 4];
                b[..len.min(4)].copy_from_slice(&d[..len.min(4)]);
                let v = u32::from_le_bytes(b);
                if let Step::Verify(w) = step {
                    // Compare what the drive holds with what was written, over the written width
                    // (a drive may answer an expedited upload without the size, as 4 bytes). Of a
                    // COB-ID only the valid bit and the 11-bit id count: CiA 301 lets a drive
                    // report bit 30 (no RTR) and bit 29 as it implements them.
                    let cob = w.sub == 1 && matches!(w.index, 0x1400..=0x15FF | 0x1800..=0x19FF);
                    let mask = match (cob, w.len) {
                        (true, _) => pdo::COB_ID_INVALID | 0x7FF,
                        (false, 4..) => u32::MAX,
                        (false, n) => (1u32 << (8 * u32::from(n))) - 1,
                    };
                    if len < usize::from(w.len) || v & mask != w.value & mask {
                        return self.fail(k, NodeFailure::Readback { index: w.index, sub: w.sub, expected: w.value, found: v });
                    }
                }
                if let Step::Upload { field, .. } = step {
                    match field {
                        Field::DeviceType => n.identity.device_type = Some(v),
                        Field::Vendor => n.identity.vendor = Some(v),
                        Field::Product => n.identity.product = Some(v),
                        Field::Revision => n.identity.revision = Some(v),
                        Field::Serial => n.identity.serial = Some(v),
                        Field::Statusword => {
                            n.axis.statusword = v as u16;
                            n.axis.state = State::from_statusword(v as u16);
                        }
                        Field::Position => {
                            // The first RPDO commands where the drive stands.
                            n.axis.position = v as i32;
                            n.axis.target_position = v as i32;
                        }
                        Field::Name => {
                            let m = len.min(32);
                            n.name[..m].copy_from_slice(&d[..m]);
                            // Trim trailing NULs some drives pad with; keep valid UTF-8.
                            let mut m = m;
                            while m > 0 && n.name[m - 1] == 0 {
                                m -= 1;
                            }
                            while std::str::from_utf8(&n.name[..m]).is_err() {
                                m -= 1;
                            }
                            n.name_len = m as u8;
                        }
                    }
                    let check = match field {
                        Field::Vendor => n.cfg.vendor_id.map(|e| (1, e)),
                        Field::Product => n.cfg.product_code.map(|e| (2, e)),
                        _ => None,
                    };
                    if let Some((sub, expected)) = check {
                        if expected != v {
                            return self.fail(k, NodeFailure::WrongDevice { sub, expected, found: v });
                        }
                    }
                    if field == Field::Name {
                        let identity = n.identity;
                        self.event(Event::Identified { node, identity });
                    }
                }
                self.advance(k, now);
            }
            SdoOutcome::Downloaded { .. } => self.advance(k, now),
            SdoOutcome::Aborted(a) => {
                self.counters.sdo_aborts += 1;
                let required = match step {
                    Step::Upload { required, field, .. } => {
                        if field == Field::Name {
                            let identity = self.nodes[k].identity;
                            self.event(Event::Identified { node, identity });
                        }
                        required
                    }
                    Step::Download(_) | Step::PowerOff | Step::Verify(_) => true,
                    // An unused PDO the drive does not have need not be switched off.
                    Step::Optional(_) => !(a.by_server && matches!(a.code, AbortCode::NO_OBJECT | AbortCode::NO_SUBINDEX)),
                };
                if a.code == AbortCode::TIMEOUT && !a.by_server {
                    self.counters.sdo_timeouts += 1;
                    self.problem(Problem::SdoTimeout, u32::from(0x600 + u16::from(node)));
                } else {
                    self.problem(Problem::SdoAbort, u32::from(0x580 + u16::from(node)));
                }
                self.event(Event::SdoAborted { node, abort: a });
                // The client gives up (timeout, garbled answer): try again. The server refuses:
                // trying again would get the same answer.
                if !a.by_server && self.nodes[k].tries < self.cfg_retries {
                    self.nodes[k].tries += 1;
                    self.counters.sdo_retries += 1;
                    self.next_step(k, now);
                } else if required {
                    self.fail(k, NodeFailure::Sdo(a));
                } else {
                    self.advance(k, now);
                }
            }
        }
    }

    fn advance(&mut self, k: usize, now: Instant) {
        self.nodes[k].step += 1;
        self.nodes[k].tries = 0;
        self.next_step(k, now);
    }

    fn fail(&mut self, k: usize, failure: NodeFailure) {
        let n = &mut self.nodes[k];
        n.phase = Phase::Failed(failure);
        n.sdo.cancel();
        let node = n.cfg.node_id;
        self.event(Event::Failed { node, failure });
    }

    /// Runs the timers: start-up reset, SDO timeouts, heartbeat timeouts, and the SYNC cycle
    /// (SYNC, then the RPDOs of every operational drive).
    pub fn poll(&mut self, now: Instant) {
        self.poll_timers(now);
        if self.sync.poll(now) {
            self.cycle();
        }
    }

    /// Runs the timers of [`poll`](Self::poll) without the SYNC cycle: for an application
    /// whose own periodic loop is the SYNC clock and calls [`sync_cycle`](Self::sync_cycle).
    pub fn poll_timers(&mut self, now: Instant) {
        if !self.started {
            self.started = true;
            // taut is a CANopen node too (CiA 302): boot-up, then its heartbeat.
            let id = self.supervision.node_id;
            self.push_tx(heartbeat::encode(id, NmtState::BootUp));
            self.next_heartbeat = Some(now + self.supervision.heartbeat);
            if self.reset_on_start {
                self.send_nmt(NmtCommand::ResetCommunication, 0);
            }
        }
        if let Some(t) = self.next_heartbeat {
            if now >= t {
                let p = self.supervision.heartbeat;
                // After a stall, the next one a full period from now, not a burst.
                self.next_heartbeat = Some(if now - t > p { now + p } else { t + p });
                self.push_tx(heartbeat::encode(self.supervision.node_id, NmtState::Operational));
            }
        }
        for k in 0..self.nodes.len() {
            if let Some(o) = self.nodes[k].sdo.poll(now) {
                self.flush_sdo(k);
                self.on_sdo_outcome(k, o, now);
            }
            self.flush_sdo(k);
            let n = &mut self.nodes[k];
            if n.phase == Phase::Waiting && n.heard_since_reset.is_some_and(|t| now >= t + self.boot_wait) {
                let id = n.cfg.node_id;
                self.counters.boot_ups_missing += 1;
                self.problem(Problem::BootUpMissing, 0x700 + u32::from(id));
                self.begin_config(k, now);
                continue;
            }
            let n = &mut self.nodes[k];
            if matches!(n.phase, Phase::Starting | Phase::Operational) && n.hb.check(now) {
                n.phase = Phase::Lost;
                n.sdo.cancel();
                let node = n.cfg.node_id;
                self.counters.heartbeat_losses += 1;
                self.event(Event::HeartbeatLost { node });
            }
        }
    }

    /// One SYNC cycle now: the RPDOs of every operational drive, then SYNC (synchronous RPDOs
    /// take effect at the SYNC that follows them, CiA 301 7.2.2.3).
    pub fn sync_cycle(&mut self) {
        self.cycle();
    }

    fn cycle(&mut self) {
        self.counters.sync_cycles += 1;
        for k in 0..self.nodes.len() {
            if self.nodes[k].phase != Phase::Operational {
                continue;
            }
            let node = self.nodes[k].cfg.node_id;
            let ax = &mut self.nodes[k].axis;
            let mode = ax.mode.code();
            let state = ax.state.unwrap_or(State::SwitchOnDisabled);
            let reset = ax.reset_fault > 0;
            if reset {
                ax.reset_fault += 1;
                if ax.reset_fault > FAULT_RESET_CYCLES {
                    ax.reset_fault = 0;
                }
            }
            let cw = cia402::next_controlword(state, ax.want, reset);
            let (tp, tt) = (ax.target_position, ax.target_torque);
            for j in 0..self.nodes[k].cfg.pdos.len() {
                // A copy (no allocation) so that the queue can be pushed to in the loop.
                let p = self.nodes[k].cfg.pdos[j];
                if p.dir != pdo::Direction::Rx {
                    continue;
                }
                let mut data = [0u8; 8];
                let dlc = pdo::pack(p.entries(), &mut data, |index, _| match index {
                    od::CONTROLWORD => u64::from(cw),
                    od::TARGET_POSITION => tp as u32 as u64,
                    od::TARGET_TORQUE => tt as u16 as u64,
                    od::MODES_OF_OPERATION => mode as u8 as u64,
                    _ => 0,
                })
                .unwrap_or(0);
                self.push_tx(Frame::new(p.cob_id(node), &data[..usize::from(dlc)]));
            }
        }
        self.push_tx(sync::frame());
    }

    /// The motion interface, only while every drive is operational (NMT) — so code that has not
    /// brought the bus up has nothing to command with.
    pub fn operational(&mut self) -> Option<Operational<'_>> {
        self.all_operational().then_some(Operational { m: self })
    }

    /// Quick stop (`quick`) or disable every drive that is operational now, also while others
    /// are not: a safety reaction reaches every drive that can be reached. Enabling stays with
    /// [`Operational`], which needs them all.
    pub fn stop_reachable(&mut self, quick: bool) {
        for n in self.nodes.iter_mut().filter(|n| n.phase == Phase::Operational) {
            n.axis.want = if quick { Want::QuickStop } else { Want::Disabled };
        }
    }
}

/// Why a motion command was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandError {
    /// No drive with that index.
    NoSuchDrive(usize),
    /// The drive is not in "operation enabled".
    NotEnabled {
        /// Node.
        node: NodeId,
    },
    /// The drive runs in the other mode.
    WrongMode {
        /// Node.
        node: NodeId,
    },
    /// The drive's PDO map does not carry the mode of operation, so it cannot switch.
    ModeNotMapped {
        /// Node.
        node: NodeId,
    },
}

impl fmt::Display for CommandError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CommandError::NoSuchDrive(i) => write!(f, "no drive with index {i}"),
            CommandError::NotEnabled { node } => write!(f, "node {node}: drive is not in operation enabled"),
            CommandError::WrongMode { node } => write!(f, "node {node}: command does not match the drive's mode"),
            CommandError::ModeNotMapped { node } => {
                write!(f, "node {node}: no RPDO carries the mode of operation 0x6060, so it cannot switch modes; configure pdo = \"with_mode\" or map 0x6060")
            }
        }
    }
}

impl std::error::Error for CommandError {}

/// Commands to operational drives. Obtained from [`Master::operational`].
pub struct Operational<'a> {
    m: &'a mut Master,
}

impl Operational<'_> {
    fn axis(&mut self, i: usize) -> Result<(&mut Axis, &NodeConfig), CommandError> {
        let n = self.m.nodes.get_mut(i).ok_or(CommandError::NoSuchDrive(i))?;
        Ok((&mut n.axis, &n.cfg))
    }

    /// Drive `i` to "operation enabled" (holding where it stands).
    pub fn enable(&mut self, i: usize) -> Result<(), CommandError> {
        self.axis(i)?.0.want = Want::Enabled;
        Ok(())
    }

    /// Drive `i` to "ready to switch on" (power stage off).
    pub fn disable(&mut self, i: usize) -> Result<(), CommandError> {
        self.axis(i)?.0.want = Want::Disabled;
        Ok(())
    }

    /// Quick stop of drive `i`.
    pub fn quick_stop(&mut self, i: usize) -> Result<(), CommandError> {
        self.axis(i)?.0.want = Want::QuickStop;
        Ok(())
    }

    /// Asks drive `i` to reset its fault (a rising edge of controlword bit 7).
    pub fn fault_reset(&mut self, i: usize) -> Result<(), CommandError> {
        let ax = self.axis(i)?.0;
        if ax.state == Some(State::Fault) && ax.reset_fault == 0 {
            ax.reset_fault = 1;
        }
        Ok(())
    }

    fn enabled(&mut self, i: usize, mode: Mode) -> Result<(&mut Axis, &NodeConfig), CommandError> {
        let (ax, cfg) = self.axis(i)?;
        if ax.state != Some(State::OperationEnabled) {
            return Err(CommandError::NotEnabled { node: cfg.node_id });
        }
        if ax.mode != mode {
            return Err(CommandError::WrongMode { node: cfg.node_id });
        }
        Ok((ax, cfg))
    }

    /// Switches drive `i` to `mode` (CSP or CST). Only drives with the `with_mode` PDO layout,
    /// which carries 0x6060 in an RPDO, switch; with the compact layout the configured mode is
    /// the only one ([`CommandError::ModeNotMapped`] otherwise). On a switch the targets restart
    /// from where the drive stands (position) and from zero (torque), so nothing jumps.
    pub fn set_mode(&mut self, i: usize, mode: Mode) -> Result<(), CommandError> {
        let n = self.m.nodes.get_mut(i).ok_or(CommandError::NoSuchDrive(i))?;
        if n.axis.mode == mode {
            return Ok(());
        }
        if !n.cfg.pdos.maps_mode() {
            return Err(CommandError::ModeNotMapped { node: n.cfg.node_id });
        }
        n.axis.mode = mode;
        n.axis.target_position = n.axis.position;
        n.axis.target_torque = 0;
        Ok(())
    }

    /// Target position of drive `i`, counts (CSP).
    pub fn set_position_counts(&mut self, i: usize, counts: i32) -> Result<(), CommandError> {
        self.enabled(i, Mode::CyclicPosition)?.0.target_position = counts;
        Ok(())
    }

    /// Target position of drive `i`, metres of cable (CSP).
    pub fn set_position_m(&mut self, i: usize, m: f64) -> Result<(), CommandError> {
        let (ax, cfg) = self.enabled(i, Mode::CyclicPosition)?;
        ax.target_position = cfg.scaling.m_to_counts(m);
        Ok(())
    }

    /// Target tension of drive `i`, N, limited to the configured maximum (CST).
    pub fn set_tension_n(&mut self, i: usize, n: f64) -> Result<(), CommandError> {
        let (ax, cfg) = self.enabled(i, Mode::CyclicTorque)?;
        ax.target_torque = cfg.scaling.n_to_permille(n.clamp(0.0, cfg.max_tension_n));
        Ok(())
    }
}
