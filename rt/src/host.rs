//! Host-owned devices: the plain structs a host fills with each cycle's readings
//! ([`HostInputs`]) and takes the commands from ([`HostOutputs`]).
//!
//! Both are `#[repr(C)]`, fixed size ([`MAX_CABLES`] per array; entries past the configured
//! cable count are ignored and written as idle), with `f64` values and `u8` codes, so that a C
//! header can declare them field for field:
//!
//! ```text
//! HostInputs                       unit   "missing"
//!   length_m[8]       f64          m      NaN, age +inf   encoder cable length (drum side)
//!   length_age_s[8]   f64          s      +inf            age of that reading
//!   tension_n[8]      f64          N      NaN, age +inf   load-cell tension
//!   tension_age_s[8]  f64          s      +inf
//!   pose_m[3]         f64          m      NaN, age +inf   tracker position of the platform
//!   pose_age_s        f64          s      +inf
//!   drive[8]          u8           DRIVE_* (CiA 402 state collapsed: 0 unknown .. 4 fault)
//!   fault_kind        u8           FAULT_* (0 none); fault_node u8, fault_code u16 (EMCY code)
//!   bus_state         u8           BUS_* (CAN fault confinement state)
//!
//! HostOutputs
//!   setpoint[8]       f64          m in MODE_POSITION, N (cable tension) in MODE_TENSION, NaN idle
//!   mode[8]           u8           MODE_IDLE / MODE_POSITION (CSP) / MODE_TENSION (CST)
//!   request           u8           REQUEST_* controlword intent for all drives
//!   n_cables          u8           cables in use
//! ```
//!
//! Units are the robot's (metres, newtons): converting to encoder counts and per-mille torque
//! (drum radius, gear ratio, CiA 402 objects) is the host's device layer, as taut's own
//! `robot_io` does for its CANopen master.
//!
//! Hostile values are not trusted: an age that is negative or NaN, or a fresh (finite age)
//! value that is not finite, makes that reading count as missing (age +inf) for this cycle; an
//! unknown drive code counts as [`DriveStatus::Unknown`] (not enabled); an unknown fault kind
//! counts as a drive fault (EMCY 0xFF00, "device specific") of `fault_node`; an unknown bus
//! state counts as bus-off. The loop's own checks then react (stale reading, drive not
//! enabled, fault). The first such field is reported in [`crate::update::Tick::bad_input`].

use crate::io::{BusEvent, BusState, CableCommand, DeviceFault, DriveRequest, DriveStatus, IfName, Inputs, Outputs};
use crate::MAX_CABLES;

/// `drive[]` code: not heard from.
pub const DRIVE_UNKNOWN: u8 = DriveStatus::Unknown as u8;
/// `drive[]` code: powered, not enabled.
pub const DRIVE_DISABLED: u8 = DriveStatus::Disabled as u8;
/// `drive[]` code: operation enabled.
pub const DRIVE_ENABLED: u8 = DriveStatus::Enabled as u8;
/// `drive[]` code: quick stop active.
pub const DRIVE_QUICK_STOP: u8 = DriveStatus::QuickStop as u8;
/// `drive[]` code: fault (or fault reaction active).
pub const DRIVE_FAULT: u8 = DriveStatus::Fault as u8;

/// `fault_kind`: none this cycle.
pub const FAULT_NONE: u8 = 0;
/// `fault_kind`: a drive's EMCY (`fault_node`, `fault_code`).
pub const FAULT_EMCY: u8 = 1;
/// `fault_kind`: a drive's heartbeat was lost (`fault_node`).
pub const FAULT_HEARTBEAT_LOST: u8 = 2;
/// `fault_kind`: a drive booted again (`fault_node`).
pub const FAULT_REBOOTED: u8 = 3;
/// `fault_kind`: the CAN controller went bus-off.
pub const FAULT_BUS_OFF: u8 = 4;
/// `fault_kind`: the CAN controller went error-passive.
pub const FAULT_BUS_PASSIVE: u8 = 5;
/// `fault_kind`: a CAN controller buffer overflowed (frames lost).
pub const FAULT_BUS_OVERFLOW: u8 = 6;
/// `fault_kind`: the CAN transceiver reported a fault.
pub const FAULT_BUS_TRANSCEIVER: u8 = 7;

/// `bus_state`: error-active.
pub const BUS_ACTIVE: u8 = BusState::Active as u8;
/// `bus_state`: error-warning.
pub const BUS_WARNING: u8 = BusState::Warning as u8;
/// `bus_state`: error-passive.
pub const BUS_PASSIVE: u8 = BusState::Passive as u8;
/// `bus_state`: bus-off.
pub const BUS_OFF: u8 = BusState::Off as u8;

/// `mode[]`: no command (drive not enabled).
pub const MODE_IDLE: u8 = 0;
/// `mode[]`: cyclic synchronous position, `setpoint` in m.
pub const MODE_POSITION: u8 = 1;
/// `mode[]`: cyclic synchronous torque, `setpoint` is the cable tension in N.
pub const MODE_TENSION: u8 = 2;

/// `request`: keep the drives disabled.
pub const REQUEST_DISABLE: u8 = 0;
/// `request`: enable (and keep enabled) and follow the commands.
pub const REQUEST_ENABLE: u8 = 1;
/// `request`: CiA 402 quick stop.
pub const REQUEST_QUICK_STOP: u8 = 2;
/// `request`: fault reset of the drives in fault (rising edge of controlword bit 7).
pub const REQUEST_FAULT_RESET: u8 = 3;

/// One cycle's readings from a host that owns the devices.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HostInputs {
    /// Encoder cable lengths, m.
    pub length_m: [f64; MAX_CABLES],
    /// Age of each length, s (+inf: never measured).
    pub length_age_s: [f64; MAX_CABLES],
    /// Load-cell tensions, N.
    pub tension_n: [f64; MAX_CABLES],
    /// Age of each tension, s.
    pub tension_age_s: [f64; MAX_CABLES],
    /// Tracker position of the platform, m.
    pub pose_m: [f64; 3],
    /// Age of the pose, s.
    pub pose_age_s: f64,
    /// Drive states (`DRIVE_*`).
    pub drive: [u8; MAX_CABLES],
    /// A device problem seen this cycle (`FAULT_*`).
    pub fault_kind: u8,
    /// The drive's CANopen node id (EMCY, heartbeat, reboot).
    pub fault_node: u8,
    /// The EMCY error code (CiA 301 / CiA 402).
    pub fault_code: u16,
    /// The CAN controller's state (`BUS_*`).
    pub bus_state: u8,
}

impl Default for HostInputs {
    /// Nothing received yet.
    fn default() -> Self {
        HostInputs {
            length_m: [f64::NAN; MAX_CABLES],
            length_age_s: [f64::INFINITY; MAX_CABLES],
            tension_n: [f64::NAN; MAX_CABLES],
            tension_age_s: [f64::INFINITY; MAX_CABLES],
            pose_m: [f64::NAN; 3],
            pose_age_s: f64::INFINITY,
            drive: [DRIVE_UNKNOWN; MAX_CABLES],
            fault_kind: FAULT_NONE,
            fault_node: 0,
            fault_code: 0,
            bus_state: BUS_ACTIVE,
        }
    }
}

/// Which host input was malformed (the first one of the cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BadInput {
    /// `length_m[cable]` / `length_age_s[cable]`.
    Length {
        /// Cable.
        cable: u8,
    },
    /// `tension_n[cable]` / `tension_age_s[cable]`.
    Tension {
        /// Cable.
        cable: u8,
    },
    /// `pose_m` / `pose_age_s`.
    Pose,
    /// `drive[cable]` is not a `DRIVE_*` code.
    Drive {
        /// Cable.
        cable: u8,
        /// The code.
        code: u8,
    },
    /// `fault_kind` is not a `FAULT_*` code.
    FaultKind {
        /// The code.
        code: u8,
    },
    /// `bus_state` is not a `BUS_*` code.
    BusState {
        /// The code.
        code: u8,
    },
}

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BadInput::Length { cable } => write!(f, "length_m[{cable}]: a negative or NaN age, or a fresh value that is not finite"),
            BadInput::Tension { cable } => write!(f, "tension_n[{cable}]: a negative or NaN age, or a fresh value that is not finite"),
            BadInput::Pose => f.write_str("pose_m: a negative or NaN age, or a fresh value that is not finite"),
            BadInput::Drive { cable, code } => write!(f, "drive[{cable}] = {code} is not a DRIVE_* code (0..=4)"),
            BadInput::FaultKind { code } => write!(f, "fault_kind = {code} is not a FAULT_* code (0..=7)"),
            BadInput::BusState { code } => write!(f, "bus_state = {code} is not a BUS_* code (0..=3)"),
        }
    }
}

/// The interface name host-reported bus faults carry (the host knows its bus by its own name).
const HOST_BUS: &str = "host-bus";

fn fresh_ok(v: f64, age: f64) -> bool {
    // NaN ages fail both tests; +inf (never) is fine whatever the value.
    age >= 0.0 && (age == f64::INFINITY || v.is_finite())
}

impl HostInputs {
    /// The readings of `inputs` (a host that uses taut's own device layer, and tests).
    pub fn from_inputs(inputs: &Inputs) -> HostInputs {
        let (fault_kind, fault_node, fault_code) = match inputs.fault {
            None => (FAULT_NONE, 0, 0),
            Some(DeviceFault::Emcy { node, code }) => (FAULT_EMCY, node, code),
            Some(DeviceFault::HeartbeatLost { node }) => (FAULT_HEARTBEAT_LOST, node, 0),
            Some(DeviceFault::Rebooted { node }) => (FAULT_REBOOTED, node, 0),
            Some(DeviceFault::Bus { event, .. }) => match event {
                BusEvent::ErrorPassive { .. } => (FAULT_BUS_PASSIVE, 0, 0),
                BusEvent::Overflow => (FAULT_BUS_OVERFLOW, 0, 0),
                BusEvent::Transceiver => (FAULT_BUS_TRANSCEIVER, 0, 0),
                _ => (FAULT_BUS_OFF, 0, 0),
            },
        };
        HostInputs {
            length_m: inputs.length_m,
            length_age_s: inputs.length_age_s,
            tension_n: inputs.tension_n,
            tension_age_s: inputs.tension_age_s,
            pose_m: inputs.pose_m,
            pose_age_s: inputs.pose_age_s,
            drive: inputs.drive.map(|d| d as u8),
            fault_kind,
            fault_node,
            fault_code,
            bus_state: inputs.bus.state as u8,
        }
    }

    /// Copies the first `inputs.n` cables' readings into the loop's `inputs`, each malformed
    /// value taken as missing (see the module documentation); returns the first malformed
    /// field. Allocates nothing.
    pub fn load_into(&self, inputs: &mut Inputs) -> Option<BadInput> {
        let mut bad = None;
        let mut note = |b: BadInput| {
            if bad.is_none() {
                bad = Some(b);
            }
        };
        for j in 0..inputs.n {
            let c = j as u8;
            if fresh_ok(self.length_m[j], self.length_age_s[j]) {
                inputs.length_m[j] = self.length_m[j];
                inputs.length_age_s[j] = self.length_age_s[j];
            } else {
                note(BadInput::Length { cable: c });
                inputs.length_m[j] = f64::NAN;
                inputs.length_age_s[j] = f64::INFINITY;
            }
            if fresh_ok(self.tension_n[j], self.tension_age_s[j]) {
                inputs.tension_n[j] = self.tension_n[j];
                inputs.tension_age_s[j] = self.tension_age_s[j];
            } else {
                note(BadInput::Tension { cable: c });
                inputs.tension_n[j] = f64::NAN;
                inputs.tension_age_s[j] = f64::INFINITY;
            }
            inputs.drive[j] = match self.drive[j] {
                DRIVE_UNKNOWN => DriveStatus::Unknown,
                DRIVE_DISABLED => DriveStatus::Disabled,
                DRIVE_ENABLED => DriveStatus::Enabled,
                DRIVE_QUICK_STOP => DriveStatus::QuickStop,
                DRIVE_FAULT => DriveStatus::Fault,
                code => {
                    note(BadInput::Drive { cable: c, code });
                    DriveStatus::Unknown
                }
            };
        }
        if self.pose_m.iter().all(|&v| fresh_ok(v, self.pose_age_s)) {
            inputs.pose_m = self.pose_m;
            inputs.pose_age_s = self.pose_age_s;
        } else {
            note(BadInput::Pose);
            inputs.pose_m = [f64::NAN; 3];
            inputs.pose_age_s = f64::INFINITY;
        }
        let bus = |event| Some(DeviceFault::Bus { iface: IfName::new(HOST_BUS), event });
        inputs.fault = match self.fault_kind {
            FAULT_NONE => None,
            FAULT_EMCY => Some(DeviceFault::Emcy { node: self.fault_node, code: self.fault_code }),
            FAULT_HEARTBEAT_LOST => Some(DeviceFault::HeartbeatLost { node: self.fault_node }),
            FAULT_REBOOTED => Some(DeviceFault::Rebooted { node: self.fault_node }),
            FAULT_BUS_OFF => bus(BusEvent::BusOff),
            FAULT_BUS_PASSIVE => bus(BusEvent::ErrorPassive { tx: 128, rx: 0 }),
            FAULT_BUS_OVERFLOW => bus(BusEvent::Overflow),
            FAULT_BUS_TRANSCEIVER => bus(BusEvent::Transceiver),
            code => {
                note(BadInput::FaultKind { code });
                // CiA 301 EMCY 0xFF00: device specific.
                Some(DeviceFault::Emcy { node: self.fault_node, code: 0xFF00 })
            }
        };
        inputs.bus.iface = IfName::new(HOST_BUS);
        inputs.bus.state = match self.bus_state {
            BUS_ACTIVE => BusState::Active,
            BUS_WARNING => BusState::Warning,
            BUS_PASSIVE => BusState::Passive,
            BUS_OFF => BusState::Off,
            code => {
                note(BadInput::BusState { code });
                BusState::Off
            }
        };
        bad
    }
}

/// One cycle's commands for a host that owns the devices.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HostOutputs {
    /// Per cable: m in `MODE_POSITION`, N in `MODE_TENSION`, NaN in `MODE_IDLE`.
    pub setpoint: [f64; MAX_CABLES],
    /// Per cable: `MODE_*`.
    pub mode: [u8; MAX_CABLES],
    /// Controlword intent for all drives: `REQUEST_*`.
    pub request: u8,
    /// Cables in use.
    pub n_cables: u8,
}

impl Default for HostOutputs {
    /// Drives disabled, every cable idle.
    fn default() -> Self {
        HostOutputs { setpoint: [f64::NAN; MAX_CABLES], mode: [MODE_IDLE; MAX_CABLES], request: REQUEST_DISABLE, n_cables: 0 }
    }
}

impl HostOutputs {
    /// The loop's outputs as plain codes. Allocates nothing.
    pub fn store(&mut self, out: &Outputs) {
        self.n_cables = out.n as u8;
        self.request = match out.request {
            DriveRequest::Disable => REQUEST_DISABLE,
            DriveRequest::Enable => REQUEST_ENABLE,
            DriveRequest::QuickStop => REQUEST_QUICK_STOP,
            DriveRequest::FaultReset => REQUEST_FAULT_RESET,
        };
        for j in 0..MAX_CABLES {
            let c = if j < out.n { out.cable[j] } else { CableCommand::Idle };
            (self.mode[j], self.setpoint[j]) = match c {
                CableCommand::Position(m) => (MODE_POSITION, m),
                CableCommand::Tension(n) => (MODE_TENSION, n),
                CableCommand::Idle => (MODE_IDLE, f64::NAN),
            };
        }
    }

    /// Back to the loop's outputs (a host that uses taut's own device layer, and tests).
    /// Unknown codes are idle cables and a disable request.
    pub fn to_outputs(&self) -> Outputs {
        let n = usize::from(self.n_cables).min(MAX_CABLES);
        let mut out = Outputs::new(n);
        out.request = match self.request {
            REQUEST_ENABLE => DriveRequest::Enable,
            REQUEST_QUICK_STOP => DriveRequest::QuickStop,
            REQUEST_FAULT_RESET => DriveRequest::FaultReset,
            _ => DriveRequest::Disable,
        };
        for j in 0..n {
            out.cable[j] = match self.mode[j] {
                MODE_POSITION => CableCommand::Position(self.setpoint[j]),
                MODE_TENSION => CableCommand::Tension(self.setpoint[j]),
                _ => CableCommand::Idle,
            };
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inputs_round_trip_and_hostile_values_count_as_missing() {
        let mut i = Inputs::new(4);
        for j in 0..4 {
            i.length_m[j] = 1.0 + j as f64;
            i.length_age_s[j] = 0.001;
            i.tension_n[j] = 20.0;
            i.tension_age_s[j] = 0.01;
            i.drive[j] = DriveStatus::Enabled;
        }
        i.pose_m = [0.1, 0.2, 1.5];
        i.pose_age_s = 0.02;
        i.fault = Some(DeviceFault::Emcy { node: 3, code: 0x2310 });
        let h = HostInputs::from_inputs(&i);
        let mut back = Inputs::new(4);
        assert_eq!(h.load_into(&mut back), None);
        assert_eq!((&back.length_m[..4], back.drive, back.pose_m, back.fault), (&i.length_m[..4], i.drive, i.pose_m, i.fault));

        let mut bad = h;
        bad.tension_age_s[2] = f64::NAN;
        bad.length_m[1] = f64::INFINITY;
        bad.drive[0] = 9;
        bad.fault_kind = 200;
        bad.bus_state = 7;
        bad.pose_age_s = -1.0;
        let mut back = Inputs::new(4);
        assert_eq!(bad.load_into(&mut back), Some(BadInput::Drive { cable: 0, code: 9 }));
        assert!(back.length_age_s[1].is_infinite() && back.tension_age_s[2].is_infinite() && back.pose_age_s.is_infinite());
        assert_eq!(back.drive[0], DriveStatus::Unknown);
        assert_eq!(back.fault, Some(DeviceFault::Emcy { node: 3, code: 0xFF00 }));
        assert_eq!(back.bus.state, BusState::Off);
        // A never-measured reading may hold anything.
        let mut never = HostInputs::default();
        never.length_m[0] = f64::NAN;
        assert_eq!(never.load_into(&mut Inputs::new(1)), None);
    }

    #[test]
    fn outputs_round_trip() {
        let mut o = Outputs::new(3);
        o.request = DriveRequest::QuickStop;
        o.cable[0] = CableCommand::Position(2.5);
        o.cable[1] = CableCommand::Tension(40.0);
        let mut h = HostOutputs::default();
        h.store(&o);
        assert_eq!((h.n_cables, h.request, h.mode[..4].to_vec()), (3, REQUEST_QUICK_STOP, vec![1, 2, 0, 0]));
        assert_eq!(h.to_outputs(), o);
    }
}
