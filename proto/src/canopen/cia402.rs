//! CiA 402 drive profile: the power state machine (statusword in, controlword out) and the modes
//! of operation.
//!
//! ```text
//! statusword 0x6041 (CiA 402 6.3.2, table 30)        controlword 0x6040 commands
//! mask   value  state                                 0x0006 shutdown          -> ready to switch on
//! 0x4F   0x00   not ready to switch on                0x0007 switch on         -> switched on
//! 0x4F   0x40   switch on disabled                    0x000F enable operation  -> operation enabled
//! 0x6F   0x21   ready to switch on                    0x0007 disable operation -> switched on
//! 0x6F   0x23   switched on                           0x0000 disable voltage   -> switch on disabled
//! 0x6F   0x27   operation enabled                     0x0002 quick stop        -> quick stop active
//! 0x6F   0x07   quick stop active                     0x0080 fault reset (rising edge of bit 7)
//! 0x4F   0x0F   fault reaction active
//! 0x4F   0x08   fault
//! ```

/// Controlword: shutdown.
pub const CW_SHUTDOWN: u16 = 0x0006;
/// Controlword: switch on (also "disable operation").
pub const CW_SWITCH_ON: u16 = 0x0007;
/// Controlword: enable operation.
pub const CW_ENABLE_OPERATION: u16 = 0x000F;
/// Controlword: disable voltage.
pub const CW_DISABLE_VOLTAGE: u16 = 0x0000;
/// Controlword: quick stop.
pub const CW_QUICK_STOP: u16 = 0x0002;
/// Controlword: fault reset (bit 7; acts on its rising edge).
pub const CW_FAULT_RESET: u16 = 0x0080;

/// Statusword bit 3: fault.
pub const SW_FAULT: u16 = 1 << 3;
/// Statusword bit 7: warning.
pub const SW_WARNING: u16 = 1 << 7;
/// Statusword bit 9: remote (controlword is obeyed).
pub const SW_REMOTE: u16 = 1 << 9;
/// Statusword bit 12 in CSP/CST: target value ignored (0) / followed (1).
pub const SW_FOLLOWING: u16 = 1 << 12;

/// The power state of a drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PowerState {
    /// Initialising.
    NotReadyToSwitchOn,
    /// Power stage off; waits for "shutdown".
    SwitchOnDisabled,
    /// Ready; waits for "switch on".
    ReadyToSwitchOn,
    /// Power stage on, no torque.
    SwitchedOn,
    /// Following the target.
    OperationEnabled,
    /// Stopping with the quick-stop ramp.
    QuickStopActive,
    /// Reacting to a fault (braking).
    FaultReactionActive,
    /// Fault: waits for a fault reset.
    Fault,
}

impl PowerState {
    /// Decodes a statusword; `None` for patterns that are no state.
    pub fn from_statusword(sw: u16) -> Option<PowerState> {
        Some(match (sw & 0x4F, sw & 0x6F) {
            (0x00, _) => PowerState::NotReadyToSwitchOn,
            (0x40, _) => PowerState::SwitchOnDisabled,
            (0x0F, _) => PowerState::FaultReactionActive,
            (0x08, _) => PowerState::Fault,
            (_, 0x21) => PowerState::ReadyToSwitchOn,
            (_, 0x23) => PowerState::SwitchedOn,
            (_, 0x27) => PowerState::OperationEnabled,
            (_, 0x07) => PowerState::QuickStopActive,
            _ => return None,
        })
    }

    /// The statusword bits of this state (bits 0..6; bit 4 "voltage enabled" set when powered).
    pub fn statusword_bits(&self) -> u16 {
        match self {
            PowerState::NotReadyToSwitchOn => 0x00,
            PowerState::SwitchOnDisabled => 0x40,
            PowerState::ReadyToSwitchOn => 0x21,
            PowerState::SwitchedOn => 0x23 | 0x10,
            PowerState::OperationEnabled => 0x27 | 0x10,
            PowerState::QuickStopActive => 0x07 | 0x10,
            PowerState::FaultReactionActive => 0x0F,
            PowerState::Fault => 0x08,
        }
    }

    /// Short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            PowerState::NotReadyToSwitchOn => "not ready",
            PowerState::SwitchOnDisabled => "switch on disabled",
            PowerState::ReadyToSwitchOn => "ready to switch on",
            PowerState::SwitchedOn => "switched on",
            PowerState::OperationEnabled => "operation enabled",
            PowerState::QuickStopActive => "quick stop",
            PowerState::FaultReactionActive => "fault reaction",
            PowerState::Fault => "FAULT",
        }
    }
}

/// A controlword command, as a drive decodes it (CiA 402 6.3.1, table 28).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Shutdown.
    Shutdown,
    /// Switch on / disable operation.
    SwitchOn,
    /// Enable operation.
    EnableOperation,
    /// Disable voltage.
    DisableVoltage,
    /// Quick stop.
    QuickStop,
    /// Fault reset (bit 7 set; the drive acts on its rising edge).
    FaultReset,
}

impl Command {
    /// Decodes a controlword.
    pub fn from_controlword(cw: u16) -> Command {
        if cw & 0x80 != 0 {
            Command::FaultReset
        } else if cw & 0x02 == 0 {
            Command::DisableVoltage
        } else if cw & 0x04 == 0 {
            Command::QuickStop
        } else if cw & 0x01 == 0 {
            Command::Shutdown
        } else if cw & 0x08 == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        }
    }
}

/// What the master wants a drive to be.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Want {
    /// Ready to switch on, power stage off.
    #[default]
    Disabled,
    /// Operation enabled.
    Enabled,
    /// Quick stop.
    QuickStop,
}

/// The controlword that moves a drive in `state` one step towards `want`. A fault is reset
/// only when `reset_fault` (the caller asks for it explicitly, and sends a 0 first so bit 7
/// rises).
pub fn next_controlword(state: PowerState, want: Want, reset_fault: bool) -> u16 {
    match (state, want) {
        (PowerState::Fault, _) if reset_fault => CW_FAULT_RESET,
        (PowerState::Fault | PowerState::FaultReactionActive | PowerState::NotReadyToSwitchOn, _) => CW_DISABLE_VOLTAGE,
        (_, Want::QuickStop) => CW_QUICK_STOP,
        (PowerState::QuickStopActive, _) => CW_DISABLE_VOLTAGE,
        (PowerState::SwitchOnDisabled, _) => CW_SHUTDOWN,
        (PowerState::ReadyToSwitchOn, Want::Disabled) => CW_SHUTDOWN,
        (PowerState::ReadyToSwitchOn, Want::Enabled) => CW_SWITCH_ON,
        (PowerState::SwitchedOn, Want::Enabled) | (PowerState::OperationEnabled, Want::Enabled) => CW_ENABLE_OPERATION,
        (PowerState::SwitchedOn | PowerState::OperationEnabled, Want::Disabled) => CW_SHUTDOWN,
    }
}

/// Modes of operation (0x6060 / 0x6061, CiA 402 6.6.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Mode {
    /// Cyclic synchronous position (8): holding and reeling cables.
    #[default]
    CyclicPosition,
    /// Cyclic synchronous torque (10): a follower cable at low tension.
    CyclicTorque,
    /// Any other mode the drive reports.
    Other(i8),
}

impl Mode {
    /// The 0x6060 value.
    pub fn code(&self) -> i8 {
        match self {
            Mode::CyclicPosition => 8,
            Mode::CyclicTorque => 10,
            Mode::Other(c) => *c,
        }
    }

    /// The mode for a 0x6060 / 0x6061 value.
    pub fn from_code(c: i8) -> Mode {
        match c {
            8 => Mode::CyclicPosition,
            10 => Mode::CyclicTorque,
            c => Mode::Other(c),
        }
    }

    /// Short name.
    pub fn name(&self) -> &'static str {
        match self {
            Mode::CyclicPosition => "CSP",
            Mode::CyclicTorque => "CST",
            Mode::Other(_) => "other",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const ALL: [PowerState; 8] = [
        PowerState::NotReadyToSwitchOn,
        PowerState::SwitchOnDisabled,
        PowerState::ReadyToSwitchOn,
        PowerState::SwitchedOn,
        PowerState::OperationEnabled,
        PowerState::QuickStopActive,
        PowerState::FaultReactionActive,
        PowerState::Fault,
    ];

    #[test]
    fn statusword_roundtrip_with_extra_bits() {
        for s in ALL {
            for extra in [0u16, SW_REMOTE, SW_WARNING | SW_FOLLOWING | 0x8000] {
                assert_eq!(PowerState::from_statusword(s.statusword_bits() | extra), Some(s), "{s:?} {extra:x}");
            }
        }
    }

    #[test]
    fn controlwords_drive_a_model_to_enabled_and_back() {
        // A minimal drive obeying table 28 reaches the wanted state from anywhere but fault.
        let step = |s: PowerState, cw: u16| match (s, Command::from_controlword(cw)) {
            (PowerState::SwitchOnDisabled, Command::Shutdown) => PowerState::ReadyToSwitchOn,
            (PowerState::ReadyToSwitchOn, Command::SwitchOn) => PowerState::SwitchedOn,
            (PowerState::SwitchedOn, Command::EnableOperation) => PowerState::OperationEnabled,
            (PowerState::OperationEnabled, Command::Shutdown) | (PowerState::SwitchedOn, Command::Shutdown) => PowerState::ReadyToSwitchOn,
            (PowerState::QuickStopActive, Command::DisableVoltage) => PowerState::SwitchOnDisabled,
            (PowerState::Fault, Command::FaultReset) => PowerState::SwitchOnDisabled,
            (s, _) => s,
        };
        let mut s = PowerState::SwitchOnDisabled;
        for _ in 0..5 {
            s = step(s, next_controlword(s, Want::Enabled, false));
        }
        assert_eq!(s, PowerState::OperationEnabled);
        for _ in 0..5 {
            s = step(s, next_controlword(s, Want::Disabled, false));
        }
        assert_eq!(s, PowerState::ReadyToSwitchOn);
        assert_eq!(next_controlword(PowerState::Fault, Want::Enabled, false), CW_DISABLE_VOLTAGE);
        assert_eq!(step(PowerState::Fault, next_controlword(PowerState::Fault, Want::Disabled, true)), PowerState::SwitchOnDisabled);
        assert_eq!(Command::from_controlword(0x1F), Command::EnableOperation);
    }

    proptest! {
        #[test]
        fn any_statusword_decodes_without_panic(sw: u16, cw: u16) {
            let _ = PowerState::from_statusword(sw);
            let _ = Command::from_controlword(cw);
        }
    }
}
