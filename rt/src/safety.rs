//! Safety causes and reactions. Each cause has one defined reaction; the worst reaction seen wins
//! and stays latched until an operator resets it.
//!
//! | cause                          | reaction   |
//! |--------------------------------|------------|
//! | tension above `max_tension_n`  | hold       |
//! | reeled cable loose (init)      | hold       |
//! | stale tension / tracker data   | hold       |
//! | speed or workspace limit       | hold       |
//! | drive enable timeout           | disable    |
//! | drive EMCY / drive in fault    | quick stop |
//! | lost heartbeat                 | quick stop |
//! | drive rebooted                 | quick stop |
//! | CAN bus-off                    | disable    |
//! | CAN error-passive, overflow,   | hold       |
//! | transceiver fault              |            |
//! | operator estop                 | quick stop |
//!
//! A CAN cause names the interface ("can0: bus-off"). Bus-off disables: the drives cannot be
//! reached, and once the bus is back nothing may move before the operator says so. The milder
//! bus problems hold: the bus still works but is degraded, so motion stops while the drives stay
//! enabled and keep the platform where it is.

use crate::io::{BusEvent, IfName};
use std::fmt;

/// What the loop does about a cause. Ordered: a worse reaction replaces a milder one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum Reaction {
    /// Every cable holds its current length in position mode.
    Hold = 1,
    /// CiA 402 quick stop on every drive.
    QuickStop = 2,
    /// Drives disabled.
    Disable = 3,
}

impl Reaction {
    /// Lower-case name for status output.
    pub fn name(self) -> &'static str {
        match self {
            Reaction::Hold => "hold",
            Reaction::QuickStop => "quick-stop",
            Reaction::Disable => "disable",
        }
    }
}

/// Why the loop stopped the motion. `Copy`, with the cable or node and the value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Cause {
    /// A cable's tension exceeded the limit.
    TensionHigh {
        /// Cable index.
        cable: u8,
        /// Measured tension, N.
        tension_n: f32,
    },
    /// The reeled cable of an initialisation phase went loose.
    CableLoose {
        /// Cable index.
        cable: u8,
        /// Measured tension, N.
        tension_n: f32,
    },
    /// No fresh tension reading of a cable.
    TensionStale {
        /// Cable index.
        cable: u8,
    },
    /// No fresh tracker pose while one is needed.
    TrackerStale,
    /// A commanded cable speed above the limit.
    SpeedLimit {
        /// Cable index.
        cable: u8,
        /// Commanded speed, m/s.
        speed_m_s: f32,
    },
    /// The platform left the workspace box (plus margin).
    Workspace,
    /// Drives did not all reach "operation enabled" in time.
    EnableTimeout {
        /// First cable whose drive did not.
        cable: u8,
    },
    /// A drive reported an emergency (EMCY) or is in fault.
    DriveFault {
        /// CANopen node id (0 when only the state showed it).
        node: u8,
        /// EMCY error code (0 when only the state showed it).
        code: u16,
    },
    /// A drive's heartbeat was lost.
    HeartbeatLost {
        /// CANopen node id.
        node: u8,
    },
    /// A drive booted again (power cycle, watchdog) and came back disabled.
    DriveRebooted {
        /// CANopen node id.
        node: u8,
    },
    /// The CAN interface reported a problem: bus-off, error-passive, frames lost, transceiver.
    Bus {
        /// The interface.
        iface: IfName,
        /// What it reported.
        event: BusEvent,
    },
    /// The operator asked for an emergency stop.
    Estop,
}

impl Cause {
    /// The defined reaction to this cause.
    pub fn reaction(self) -> Reaction {
        match self {
            Cause::TensionHigh { .. }
            | Cause::CableLoose { .. }
            | Cause::TensionStale { .. }
            | Cause::TrackerStale
            | Cause::SpeedLimit { .. }
            | Cause::Workspace => Reaction::Hold,
            Cause::DriveFault { .. } | Cause::HeartbeatLost { .. } | Cause::DriveRebooted { .. } | Cause::Estop => Reaction::QuickStop,
            Cause::Bus { event: BusEvent::BusOff, .. } => Reaction::Disable,
            Cause::Bus { .. } => Reaction::Hold,
            Cause::EnableTimeout { .. } => Reaction::Disable,
        }
    }

    /// A short machine-readable name.
    pub fn name(self) -> &'static str {
        match self {
            Cause::TensionHigh { .. } => "tension-high",
            Cause::CableLoose { .. } => "cable-loose",
            Cause::TensionStale { .. } => "tension-stale",
            Cause::TrackerStale => "tracker-stale",
            Cause::SpeedLimit { .. } => "speed-limit",
            Cause::Workspace => "workspace",
            Cause::EnableTimeout { .. } => "enable-timeout",
            Cause::DriveFault { .. } => "drive-fault",
            Cause::HeartbeatLost { .. } => "heartbeat-lost",
            Cause::DriveRebooted { .. } => "drive-rebooted",
            Cause::Bus { event: BusEvent::BusOff, .. } => "bus-off",
            Cause::Bus { .. } => "can-bus",
            Cause::Estop => "estop",
        }
    }
}

impl fmt::Display for Cause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Cause::TensionHigh { cable, tension_n } => {
                write!(f, "cable {} tension {tension_n:.1} N above the limit (safety.max_tension_n)", cable + 1)
            }
            Cause::CableLoose { cable, tension_n } => {
                write!(f, "reeled cable {} went loose ({tension_n:.1} N, safety.loose_tension_n)", cable + 1)
            }
            Cause::TensionStale { cable } => {
                write!(f, "no fresh tension reading of cable {}: check its load cell and the RS-485 bus", cable + 1)
            }
            Cause::TrackerStale => write!(f, "no fresh tracker pose: check the tracker and its UDP stream"),
            Cause::SpeedLimit { cable, speed_m_s } => {
                write!(f, "cable {} commanded at {speed_m_s:.2} m/s, above safety.max_cable_speed_m_s", cable + 1)
            }
            Cause::Workspace => write!(f, "platform outside the workspace box (motion.workspace_*_m plus safety.workspace_margin_m)"),
            Cause::EnableTimeout { cable } => write!(f, "drive of cable {} did not enable within motion.enable_timeout_s", cable + 1),
            Cause::DriveFault { node, code } => write!(f, "drive node {node} fault, EMCY code 0x{code:04X}"),
            Cause::HeartbeatLost { node } => write!(f, "heartbeat of drive node {node} lost: check its power and the CAN cable"),
            Cause::DriveRebooted { node } => write!(
                f,
                "drive node {node} rebooted (power cycle or watchdog); it was configured again and is disabled: `taut ctl reset` enables it"
            ),
            Cause::Bus { iface, event } => write!(f, "{iface}: {event}"),
            Cause::Estop => write!(f, "emergency stop requested by the operator"),
        }
    }
}
