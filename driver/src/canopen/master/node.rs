//! Per-node state: the phase of bring-up, identity, the CiA 402 side ([`Axis`]) and the snapshot
//! the application reads ([`NodeStatus`]).

use super::script::{script, Step};
use super::{NodeConfig, Supervision};
use std::fmt;
use std::time::{Duration, Instant};
use taut_proto::canopen::cia402::{Mode, PowerState, Want};
use taut_proto::canopen::emcy::Emcy;
use taut_proto::canopen::heartbeat::HeartbeatConsumer;
use taut_proto::canopen::nmt::NmtState;
use taut_proto::canopen::pdo;
use taut_proto::canopen::sdo::{SdoAbort, SdoClient};
use taut_proto::canopen::NodeId;

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

/// The CiA 402 side of a node, as the master sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    /// Last statusword.
    pub statusword: u16,
    /// The power state decoded from it (`None` before the first TPDO).
    pub state: Option<PowerState>,
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
    /// [`Operational::set_mode`](super::Operational::set_mode) with the `with_mode` layout).
    pub mode: Mode,
    pub(super) want: Want,
    pub(super) reset_fault: u16,
    pub(super) target_position: i32,
    pub(super) target_torque: i16,
}

impl Axis {
    pub(super) fn new(mode: Mode) -> Self {
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

pub(super) struct Node {
    pub(super) cfg: NodeConfig,
    pub(super) phase: Phase,
    pub(super) nmt: Option<NmtState>,
    pub(super) hb: HeartbeatConsumer,
    pub(super) sdo: SdoClient,
    pub(super) steps: Vec<Step>,
    pub(super) step: usize,
    pub(super) tries: u8,
    pub(super) identity: Identity,
    pub(super) name: [u8; 32],
    pub(super) name_len: u8,
    pub(super) axis: Axis,
    pub(super) boots: u32,
    /// When a heartbeat (not a boot-up) was first seen after taut's reset communication.
    pub(super) heard_since_reset: Option<Instant>,
    pub(super) last_emcy: Option<Emcy>,
    /// TPDO COB-IDs, for matching received frames.
    pub(super) tpdo_ids: [u16; 4],
}

impl Node {
    pub(super) fn new(cfg: NodeConfig, sdo_timeout: Duration, sup: Supervision) -> Node {
        let n = cfg.node_id;
        let steps = script(&cfg, sup);
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

    pub(super) fn status(&self) -> NodeStatus {
        NodeStatus {
            node: self.cfg.node_id,
            cable: self.cfg.cable,
            phase: self.phase,
            nmt: self.nmt,
            identity: self.identity,
            axis: self.axis,
            boots: self.boots,
            last_emcy: self.last_emcy,
            mode: self.axis.mode,
            name: self.name,
            name_len: self.name_len,
        }
    }
}
