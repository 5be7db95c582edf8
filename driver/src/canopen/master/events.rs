//! What the master reports: [`NodeEvent`]s, the kinds of bad input ([`Problem`]) and the [`Counters`].

use super::{Identity, NodeFailure};
use crate::transport::BusEvent;
use std::fmt;
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::emcy::Emcy;
use taut_proto::canopen::sdo::SdoAbort;
use taut_proto::canopen::NodeId;

/// Kinds of bad or unexpected input, each reported once by [`NodeEvent::FirstOfKind`].
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
pub enum NodeEvent {
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
        state: PowerState,
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
        state: PowerState,
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

impl fmt::Display for NodeEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeEvent::Booted { node } => write!(f, "node {node}: boot-up"),
            NodeEvent::Rebooted { node } => write!(f, "node {node}: rebooted, configuring it again"),
            NodeEvent::Identified { node, identity: i } => write!(
                f,
                "node {node}: device type 0x{:08X}, vendor 0x{:08X}, product 0x{:08X}",
                i.device_type.unwrap_or(0),
                i.vendor.unwrap_or(0),
                i.product.unwrap_or(0)
            ),
            NodeEvent::FoundPowered { node, state } => {
                write!(f, "node {node}: found {} (left by a previous run); switching the power stage off", state.name())
            }
            NodeEvent::Configured { node } => write!(f, "node {node}: configured, starting"),
            NodeEvent::Operational { node } => write!(f, "node {node}: operational"),
            NodeEvent::Failed { node, failure } => write!(f, "node {node}: configuration failed: {failure}"),
            NodeEvent::HeartbeatLost { node } => write!(f, "node {node}: heartbeat lost"),
            NodeEvent::HeartbeatRecovered { node } => write!(f, "node {node}: heartbeat back"),
            NodeEvent::Emergency { node, emcy } => write!(f, "node {node}: {emcy}"),
            NodeEvent::DriveState { node, state } => write!(f, "node {node}: drive {}", state.name()),
            NodeEvent::SdoAborted { node, abort } => write!(f, "node {node}: {abort}"),
            NodeEvent::Bus(e) => write!(f, "{e}"),
            NodeEvent::FirstOfKind { kind, cob_id } => {
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
