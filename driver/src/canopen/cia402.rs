//! CiA 402 drive profile: the power state machine (statusword in, controlword out), modes of
//! operation, and the conversion between encoder counts and metres of cable.
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
pub enum State {
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

impl State {
    /// Decodes a statusword; `None` for patterns that are no state.
    pub fn from_statusword(sw: u16) -> Option<State> {
        Some(match (sw & 0x4F, sw & 0x6F) {
            (0x00, _) => State::NotReadyToSwitchOn,
            (0x40, _) => State::SwitchOnDisabled,
            (0x0F, _) => State::FaultReactionActive,
            (0x08, _) => State::Fault,
            (_, 0x21) => State::ReadyToSwitchOn,
            (_, 0x23) => State::SwitchedOn,
            (_, 0x27) => State::OperationEnabled,
            (_, 0x07) => State::QuickStopActive,
            _ => return None,
        })
    }

    /// The statusword bits of this state (bits 0..6; bit 4 "voltage enabled" set when powered).
    pub fn statusword_bits(&self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x00,
            State::SwitchOnDisabled => 0x40,
            State::ReadyToSwitchOn => 0x21,
            State::SwitchedOn => 0x23 | 0x10,
            State::OperationEnabled => 0x27 | 0x10,
            State::QuickStopActive => 0x07 | 0x10,
            State::FaultReactionActive => 0x0F,
            State::Fault => 0x08,
        }
    }

    /// Short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            State::NotReadyToSwitchOn => "not ready",
            State::SwitchOnDisabled => "switch on disabled",
            State::ReadyToSwitchOn => "ready to switch on",
            State::SwitchedOn => "switched on",
            State::OperationEnabled => "operation enabled",
            State::QuickStopActive => "quick stop",
            State::FaultReactionActive => "fault reaction",
            State::Fault => "FAULT",
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
pub fn next_controlword(state: State, want: Want, reset_fault: bool) -> u16 {
    match (state, want) {
        (State::Fault, _) if reset_fault => CW_FAULT_RESET,
        (State::Fault | State::FaultReactionActive | State::NotReadyToSwitchOn, _) => CW_DISABLE_VOLTAGE,
        (_, Want::QuickStop) => CW_QUICK_STOP,
        (State::QuickStopActive, _) => CW_DISABLE_VOLTAGE,
        (State::SwitchOnDisabled, _) => CW_SHUTDOWN,
        (State::ReadyToSwitchOn, Want::Disabled) => CW_SHUTDOWN,
        (State::ReadyToSwitchOn, Want::Enabled) => CW_SWITCH_ON,
        (State::SwitchedOn, Want::Enabled) | (State::OperationEnabled, Want::Enabled) => CW_ENABLE_OPERATION,
        (State::SwitchedOn | State::OperationEnabled, Want::Disabled) => CW_SHUTDOWN,
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

/// Converts between drive units and cable units for one winch.
///
/// ```text
/// cable length change  dL = counts / (counts_per_rev * gear_ratio) * 2 pi r   (r: drum radius)
/// cable tension        T  = torque_motor * gear_ratio / r,
///                      torque_motor = permille / 1000 * rated_torque          (ideal gearbox)
/// ```
/// `gear_ratio` is motor revolutions per drum revolution; the encoder is on the motor. `sign`
/// is +1 when positive counts pay cable out, -1 when they reel it in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scaling {
    /// Drum radius, m (to the cable's centre line).
    pub drum_radius_m: f64,
    /// Motor revolutions per drum revolution.
    pub gear_ratio: f64,
    /// Encoder counts per motor revolution.
    pub counts_per_rev: f64,
    /// Rated motor torque (the 1000 ‰ of 0x6071/0x6077), N·m.
    pub rated_torque_nm: f64,
    /// +1 or -1.
    pub sign: f64,
}

impl Scaling {
    /// Metres of cable per encoder count.
    pub fn metres_per_count(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.drum_radius_m / (self.counts_per_rev * self.gear_ratio)
    }

    /// Counts to metres.
    pub fn counts_to_m(&self, counts: i32) -> f64 {
        self.sign * f64::from(counts) * self.metres_per_count()
    }

    /// Metres to the nearest count, saturated to the i32 range.
    pub fn m_to_counts(&self, m: f64) -> i32 {
        let c = (self.sign * m / self.metres_per_count()).round();
        if c.is_nan() {
            0
        } else {
            c.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
        }
    }

    /// Torque in ‰ of rated torque to cable tension, N (sign as the cable sees it: positive
    /// pulls).
    pub fn permille_to_n(&self, permille: i16) -> f64 {
        -self.sign * f64::from(permille) / 1000.0 * self.rated_torque_nm * self.gear_ratio / self.drum_radius_m
    }

    /// Cable tension, N, to torque in ‰ of rated torque, saturated to the i16 range.
    pub fn n_to_permille(&self, n: f64) -> i16 {
        let p = (-self.sign * n * self.drum_radius_m / (self.gear_ratio * self.rated_torque_nm) * 1000.0).round();
        if p.is_nan() {
            0
        } else {
            p.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const ALL: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];

    #[test]
    fn statusword_roundtrip_with_extra_bits() {
        for s in ALL {
            for extra in [0u16, SW_REMOTE, SW_WARNING | SW_FOLLOWING | 0x8000] {
                assert_eq!(State::from_statusword(s.statusword_bits() | extra), Some(s), "{s:?} {extra:x}");
            }
        }
    }

    #[test]
    fn controlwords_drive_a_model_to_enabled_and_back() {
        // A minimal drive obeying table 28 reaches the wanted state from anywhere but fault.
        let step = |s: State, cw: u16| match (s, Command::from_controlword(cw)) {
            (State::SwitchOnDisabled, Command::Shutdown) => State::ReadyToSwitchOn,
            (State::ReadyToSwitchOn, Command::SwitchOn) => State::SwitchedOn,
            (State::SwitchedOn, Command::EnableOperation) => State::OperationEnabled,
            (State::OperationEnabled, Command::Shutdown) | (State::SwitchedOn, Command::Shutdown) => State::ReadyToSwitchOn,
            (State::QuickStopActive, Command::DisableVoltage) => State::SwitchOnDisabled,
            (State::Fault, Command::FaultReset) => State::SwitchOnDisabled,
            (s, _) => s,
        };
        let mut s = State::SwitchOnDisabled;
        for _ in 0..5 {
            s = step(s, next_controlword(s, Want::Enabled, false));
        }
        assert_eq!(s, State::OperationEnabled);
        for _ in 0..5 {
            s = step(s, next_controlword(s, Want::Disabled, false));
        }
        assert_eq!(s, State::ReadyToSwitchOn);
        assert_eq!(next_controlword(State::Fault, Want::Enabled, false), CW_DISABLE_VOLTAGE);
        assert_eq!(step(State::Fault, next_controlword(State::Fault, Want::Disabled, true)), State::SwitchOnDisabled);
        assert_eq!(Command::from_controlword(0x1F), Command::EnableOperation);
    }

    fn scaling() -> impl Strategy<Value = Scaling> {
        (
            0.005f64..0.5,
            1.0f64..100.0,
            prop_oneof![Just(4096.0), Just(131072.0), Just(1048576.0)],
            0.1f64..20.0,
            prop_oneof![Just(1.0), Just(-1.0)],
        )
            .prop_map(|(drum_radius_m, gear_ratio, counts_per_rev, rated_torque_nm, sign)| Scaling {
                drum_radius_m,
                gear_ratio,
                counts_per_rev,
                rated_torque_nm,
                sign,
            })
    }

    proptest! {
        #[test]
        fn counts_metres_roundtrip(s in scaling(), c in -1_000_000i32..1_000_000) {
            prop_assert_eq!(s.m_to_counts(s.counts_to_m(c)), c);
        }

        #[test]
        fn metres_within_half_a_count(s in scaling(), m in -20.0f64..20.0) {
            let c = s.m_to_counts(m);
            if c > i32::MIN && c < i32::MAX {
                prop_assert!((s.counts_to_m(c) - m).abs() <= 0.5 * s.metres_per_count() + 1e-12);
            }
        }

        #[test]
        fn torque_tension_roundtrip(s in scaling(), p in -3000i16..3000) {
            prop_assert_eq!(s.n_to_permille(s.permille_to_n(p)), p);
        }

        #[test]
        fn any_statusword_decodes_without_panic(sw: u16, cw: u16) {
            let _ = State::from_statusword(sw);
            let _ = Command::from_controlword(cw);
        }
    }

    #[test]
    fn drum_example() {
        // 50 mm drum, 10:1 gearbox, 2^17 counts/rev: one drum turn = 0.314 m of cable.
        let s = Scaling { drum_radius_m: 0.05, gear_ratio: 10.0, counts_per_rev: 131072.0, rated_torque_nm: 1.0, sign: 1.0 };
        assert!((s.counts_to_m(1_310_720) - 0.1 * std::f64::consts::PI).abs() < 1e-12);
        // 1 N.m motor torque x 10 / 0.05 m = 200 N; pulling is negative torque with sign +1.
        assert!((s.permille_to_n(-1000) - 200.0).abs() < 1e-9);
        assert_eq!(s.m_to_counts(f64::NAN), 0);
        assert_eq!(s.m_to_counts(1e30), i32::MAX);
    }
}
