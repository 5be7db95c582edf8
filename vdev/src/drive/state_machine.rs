//! The CiA 402 power state machine (controlword in, statusword out) and the internal motion
//! model used when no plant is coupled.

use super::VirtualDrive;
use taut_proto::canopen::cia402::{self, Command, Mode, PowerState};
use taut_proto::canopen::emcy::{self, Emcy};

impl VirtualDrive {
    pub(super) fn on_controlword(&mut self, cw: u16) {
        let rising_reset = cw & 0x80 != 0 && self.controlword & 0x80 == 0;
        self.controlword = cw;
        let cmd = Command::from_controlword(cw);
        use PowerState::*;
        self.state = match (self.state, cmd) {
            (Fault, Command::FaultReset) if rising_reset => {
                self.error_code = 0;
                self.send(emcy::encode(self.p.node_id, &Emcy { code: 0, register: 0, vendor: [0; 5] }));
                SwitchOnDisabled
            }
            (Fault | FaultReactionActive, _) => self.state,
            (_, Command::FaultReset) => self.state,
            (NotReadyToSwitchOn, _) => SwitchOnDisabled,
            (SwitchOnDisabled, Command::Shutdown) => ReadyToSwitchOn,
            (ReadyToSwitchOn, Command::SwitchOn) => SwitchedOn,
            (ReadyToSwitchOn, Command::EnableOperation) => SwitchedOn,
            (SwitchedOn, Command::EnableOperation) => OperationEnabled,
            (OperationEnabled, Command::SwitchOn) => SwitchedOn,
            (SwitchedOn | OperationEnabled, Command::Shutdown) => ReadyToSwitchOn,
            (OperationEnabled, Command::QuickStop) => QuickStopActive,
            (ReadyToSwitchOn | SwitchedOn, Command::QuickStop) => SwitchOnDisabled,
            (QuickStopActive, Command::EnableOperation) => OperationEnabled,
            (QuickStopActive, Command::QuickStop) => QuickStopActive,
            (_, Command::DisableVoltage) => SwitchOnDisabled,
            (s, _) => s,
        };
        if self.state != OperationEnabled {
            // Hold where the motor stands when enabled again.
            self.target_position = self.position();
        }
    }

    pub(super) fn step_motion(&mut self, dt: f64) {
        if self.state != PowerState::OperationEnabled {
            self.torque = 0;
            return;
        }
        match Mode::from_code(self.mode) {
            Mode::CyclicPosition => {
                let err = f64::from(self.target_position) - self.position;
                let alpha = if self.p.time_constant_s > 0.0 { (dt / self.p.time_constant_s).min(1.0) } else { 1.0 };
                let vmax = self.p.max_speed_counts_s * dt;
                self.position += (err * alpha).clamp(-vmax, vmax);
                let left = f64::from(self.target_position) - self.position;
                self.torque = (left * self.p.torque_per_count).clamp(-3000.0, 3000.0) as i16;
            }
            Mode::CyclicTorque => self.torque = self.target_torque,
            Mode::Other(_) => self.torque = 0,
        }
    }

    /// The statusword: state bits, remote, target reached (bit 10), following (bit 12).
    pub fn statusword(&self) -> u16 {
        let mut sw = self.state.statusword_bits() | cia402::SW_REMOTE;
        if self.state == PowerState::OperationEnabled {
            sw |= cia402::SW_FOLLOWING;
            if (f64::from(self.target_position) - self.position).abs() < 2.0 {
                sw |= 1 << 10;
            }
        }
        sw
    }
}

pub(super) fn error_register(code: u16) -> u8 {
    // 0x1001: bit 0 generic, 1 current, 2 voltage, 3 temperature, 4 communication, 5 profile.
    1 | match code >> 12 {
        0x2 => 0x02,
        0x3 => 0x04,
        0x4 => 0x08,
        0x8 => 0x10,
        _ => 0x20,
    }
}
