//! The operational cycle: TPDOs in, RPDOs and SYNC out, and the motion commands
//! ([`Operational`]) that fill the RPDOs.

use super::node::Axis;
use super::{Master, NodeConfig, NodeEvent, Phase, Problem, FAULT_RESET_CYCLES};
use std::fmt;
use taut_proto::can::Frame;
use taut_proto::canopen::cia402::{self, Mode, PowerState, Want};
use taut_proto::canopen::nmt::NmtState;
use taut_proto::canopen::pdo;
use taut_proto::canopen::sync;
use taut_proto::canopen::{od, NodeId};

impl Master {
    pub(super) fn on_tpdo(&mut self, k: usize, id: u16, f: &Frame) {
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
        let new = PowerState::from_statusword(ax.statusword);
        let changed = new != ax.state;
        ax.state = new;
        if new != Some(PowerState::OperationEnabled) {
            // Hold: when the drive becomes enabled, its target is where it stands.
            ax.target_position = ax.position;
            ax.target_torque = 0;
        }
        if ax.reset_fault > 0 && new != Some(PowerState::Fault) {
            ax.reset_fault = 0;
        }
        if matches!(new, Some(PowerState::Fault | PowerState::FaultReactionActive)) {
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
            self.event(NodeEvent::Operational { node });
        }
        if changed {
            if let Some(s) = new {
                self.event(NodeEvent::DriveState { node, state: s });
            }
        }
    }

    /// One SYNC cycle now: the RPDOs of every operational drive, then SYNC (synchronous RPDOs
    /// take effect at the SYNC that follows them, CiA 301 7.2.2.3).
    pub fn sync_cycle(&mut self) {
        self.cycle();
    }

    pub(super) fn cycle(&mut self) {
        self.counters.sync_cycles += 1;
        for k in 0..self.nodes.len() {
            if self.nodes[k].phase != Phase::Operational {
                continue;
            }
            let node = self.nodes[k].cfg.node_id;
            let ax = &mut self.nodes[k].axis;
            let mode = ax.mode.code();
            let state = ax.state.unwrap_or(PowerState::SwitchOnDisabled);
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
        if ax.state == Some(PowerState::Fault) && ax.reset_fault == 0 {
            ax.reset_fault = 1;
        }
        Ok(())
    }

    fn enabled(&mut self, i: usize, mode: Mode) -> Result<(&mut Axis, &NodeConfig), CommandError> {
        let (ax, cfg) = self.axis(i)?;
        if ax.state != Some(PowerState::OperationEnabled) {
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

    /// Target torque of drive `i`, ‰ of its rated torque (CST), sent as given (the robot I/O layer
    /// limits it). Also taken on the way to "operation enabled": the drive applies 0x6071 once
    /// enabled, and a cable enabled into torque mode needs its tension from the first cycle.
    pub fn set_torque_permille(&mut self, i: usize, permille: i16) -> Result<(), CommandError> {
        let (ax, cfg) = self.axis(i)?;
        let enabling = matches!(
            ax.state,
            Some(PowerState::SwitchOnDisabled | PowerState::ReadyToSwitchOn | PowerState::SwitchedOn | PowerState::OperationEnabled)
        );
        if !enabling {
            return Err(CommandError::NotEnabled { node: cfg.node_id });
        }
        if ax.mode != Mode::CyclicTorque {
            return Err(CommandError::WrongMode { node: cfg.node_id });
        }
        ax.target_torque = permille;
        Ok(())
    }
}
