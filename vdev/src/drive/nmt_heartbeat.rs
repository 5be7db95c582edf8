//! NMT (CiA 301 7.2.8): commands, reset communication, the heartbeat consumer (0x1016) and
//! what the drive does when it loses its master (CiA 402 0x6007).

use super::pdo_engine::factory_pdos;
use super::sdo_server::SdoServer;
use super::VirtualDrive;
use std::time::{Duration, Instant};
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::emcy::{self, Emcy};
use taut_proto::canopen::nmt::{NmtCommand, NmtState};

impl VirtualDrive {
    pub(super) fn reset_communication(&mut self) {
        self.heartbeat_ms = self.p.stored_heartbeat_ms;
        self.next_hb = None;
        (self.rpdo, self.tpdo) = factory_pdos(self.p.node_id);
        self.latched = [None; 4];
        self.sync_count = [0; 4];
        self.sdo = SdoServer::Idle;
        self.nmt = NmtState::PreOperational;
        self.boot_pending = true;
        // 0x1016 is a communication parameter: back to its power-on value, no consumer.
        self.hb_consumer = 0;
        self.consumer_last = None;
        self.consumer_lost = false;
    }

    /// CiA 402 0x6007: what the drive does when it loses the master (heartbeat consumer timeout,
    /// NMT stop, reset communication or node), only from operation enabled.
    pub(super) fn abort_connection(&mut self) {
        if self.state != PowerState::OperationEnabled || self.abort_option == 0 {
            return;
        }
        self.counters.abort_connection_actions += 1;
        self.state = match self.abort_option {
            1 => {
                // Fault signal: the fault reaction, then FAULT until the operator resets it.
                self.error_code = 0x8130;
                PowerState::Fault
            }
            2 => PowerState::SwitchOnDisabled,
            _ => PowerState::QuickStopActive,
        };
        // Stop where the motor stands (quick stop holds there; the others drop torque).
        self.target_position = self.position();
        if self.state != PowerState::QuickStopActive {
            self.torque = 0;
        }
    }

    /// The heartbeat consumer (CiA 301 7.2.8.3.2.2, 0x1016): watching starts at the first
    /// heartbeat of the configured producer; a timeout raises EMCY 0x8130 (heartbeat error),
    /// applies 0x6007, and (0x1029 error behaviour, default 0) falls back from operational to
    /// pre-operational.
    pub(super) fn poll_consumer(&mut self, now: Instant) {
        let Some(deadline) = self.consumer_deadline() else { return };
        if now <= deadline {
            return;
        }
        self.consumer_lost = true;
        self.counters.consumer_timeouts += 1;
        self.send(emcy::encode(self.p.node_id, &Emcy { code: 0x8130, register: 0x11, vendor: [0; 5] }));
        self.abort_connection();
        if self.nmt == NmtState::Operational {
            self.nmt = NmtState::PreOperational;
        }
    }

    pub(super) fn consumer_deadline(&self) -> Option<Instant> {
        let ms = self.hb_consumer & 0xFFFF;
        match self.consumer_last {
            Some(t) if ms > 0 && !self.consumer_lost => Some(t + Duration::from_millis(u64::from(ms))),
            _ => None,
        }
    }

    pub(super) fn on_nmt(&mut self, cmd: NmtCommand) {
        if matches!(cmd, NmtCommand::Stop | NmtCommand::ResetNode | NmtCommand::ResetCommunication) {
            self.abort_connection();
        }
        match cmd {
            NmtCommand::Start => self.nmt = NmtState::Operational,
            NmtCommand::Stop => self.nmt = NmtState::Stopped,
            NmtCommand::PreOperational => self.nmt = NmtState::PreOperational,
            NmtCommand::ResetNode => self.power_cycle(),
            NmtCommand::ResetCommunication => self.reset_communication(),
        }
    }
}
