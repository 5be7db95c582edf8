//! Network management (CiA 301 7.2.8.3.1): commands from the master, node states.
//!
//! ```text
//! NMT command, COB-ID 0x000, 2 bytes:  [0] command specifier  [1] node id (0 = all nodes)
//! ```

use super::NodeId;
use crate::can::Frame;

/// COB-ID of NMT commands.
pub const NMT_COB_ID: u16 = 0x000;

/// An NMT command specifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum NmtCommand {
    /// Start remote node: to Operational.
    Start = 0x01,
    /// Stop remote node: to Stopped.
    Stop = 0x02,
    /// Enter Pre-operational.
    PreOperational = 0x80,
    /// Reset node: application and communication parameters to power-on values.
    ResetNode = 0x81,
    /// Reset communication: communication parameters only.
    ResetCommunication = 0x82,
}

impl NmtCommand {
    /// The command for a specifier byte.
    pub fn from_u8(b: u8) -> Option<NmtCommand> {
        Some(match b {
            0x01 => NmtCommand::Start,
            0x02 => NmtCommand::Stop,
            0x80 => NmtCommand::PreOperational,
            0x81 => NmtCommand::ResetNode,
            0x82 => NmtCommand::ResetCommunication,
            _ => return None,
        })
    }
}

/// Builds an NMT command frame for `node` (0 = broadcast).
pub fn encode(cmd: NmtCommand, node: NodeId) -> Frame {
    Frame::new(NMT_COB_ID, &[cmd as u8, node])
}

/// Decodes an NMT command frame into (command, target node).
pub fn decode(f: &Frame) -> Option<(NmtCommand, NodeId)> {
    if f.std_id() != Some(NMT_COB_ID) || f.dlc != 2 {
        return None;
    }
    Some((NmtCommand::from_u8(f.data[0])?, f.data[1]))
}

/// NMT state of a node as its heartbeat reports it (CiA 301 7.2.8.3.2.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum NmtState {
    /// The boot-up message: the node has just (re)started.
    BootUp = 0x00,
    /// Stopped.
    Stopped = 0x04,
    /// Operational: PDOs exchanged.
    Operational = 0x05,
    /// Pre-operational: SDO only.
    PreOperational = 0x7F,
}

impl NmtState {
    /// Decodes a heartbeat state byte; bit 7 (the node-guarding toggle) is ignored.
    pub fn from_u8(b: u8) -> Option<NmtState> {
        Some(match b & 0x7F {
            0x00 => NmtState::BootUp,
            0x04 => NmtState::Stopped,
            0x05 => NmtState::Operational,
            0x7F => NmtState::PreOperational,
            _ => return None,
        })
    }

    /// Short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            NmtState::BootUp => "boot-up",
            NmtState::Stopped => "stopped",
            NmtState::Operational => "operational",
            NmtState::PreOperational => "pre-operational",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn command_roundtrip(i in 0usize..5, node in 0u8..=127) {
            let cmd = [NmtCommand::Start, NmtCommand::Stop, NmtCommand::PreOperational,
                       NmtCommand::ResetNode, NmtCommand::ResetCommunication][i];
            prop_assert_eq!(decode(&encode(cmd, node)), Some((cmd, node)));
        }

        #[test]
        fn arbitrary_frames_never_panic(id in 0u16..0x800, d in proptest::collection::vec(any::<u8>(), 0..=8)) {
            let _ = decode(&Frame::new(id, &d));
            if let Some(b) = d.first() { let _ = NmtState::from_u8(*b); }
        }
    }

    #[test]
    fn states() {
        assert_eq!(NmtState::from_u8(0x85), Some(NmtState::Operational));
        assert_eq!(NmtState::from_u8(0x7F), Some(NmtState::PreOperational));
        assert_eq!(NmtState::from_u8(0x01), None);
        assert_eq!(decode(&Frame::new(0, &[1])), None);
    }
}
