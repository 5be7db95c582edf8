//! The loop's view of the robot: what it reads each cycle ([`Inputs`]), what it writes
//! ([`Outputs`]) and the [`Devices`] seam between the two.
//!
//! Everything here is `Copy` and fixed size ([`MAX_CABLES`]): the loop fills and reads these in
//! place and never allocates.

use crate::MAX_CABLES;
pub use taut_model::bus::{BusEvent, IfName};

/// State of one drive as the loop needs it (collapsed from the CiA 402 state machine).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum DriveStatus {
    /// Not (yet) heard from.
    #[default]
    Unknown = 0,
    /// Powered but not enabled (switch on disabled / ready to switch on / switched on).
    Disabled = 1,
    /// Operation enabled: following commands.
    Enabled = 2,
    /// Quick stop active.
    QuickStop = 3,
    /// Fault (or fault reaction active).
    Fault = 4,
}

/// A device problem the loop must react to. `Copy`, with the node or cable it concerns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceFault {
    /// A drive sent an emergency message (CiA 301 EMCY) with this error code.
    Emcy {
        /// CANopen node id.
        node: u8,
        /// EMCY error code (CiA 301 table 21 / CiA 402).
        code: u16,
    },
    /// A drive's heartbeat was not seen within its consumer time.
    HeartbeatLost {
        /// CANopen node id.
        node: u8,
    },
    /// A configured drive booted again (power cycle, watchdog): it was configured again and
    /// comes back disabled.
    Rebooted {
        /// CANopen node id.
        node: u8,
    },
    /// The CAN interface reported a problem the loop reacts to (bus-off, error-passive,
    /// frames lost, transceiver fault; see [`bus_event_is_fault`]).
    Bus {
        /// The interface.
        iface: IfName,
        /// What it reported.
        event: BusEvent,
    },
}

/// Whether a bus event is a fault for the loop. Bus-off (nothing gets through), error-passive
/// (error counter above 127: the next step is bus-off), controller buffer overflows (frames were
/// lost) and transceiver faults are. Error-warning, single protocol errors, missing ACKs, TX
/// timeouts and lost arbitration are counted in [`BusStatus`] only: they happen on healthy
/// buses, and their consequences (stale TPDOs, lost heartbeats) have causes of their own.
pub fn bus_event_is_fault(e: BusEvent) -> bool {
    matches!(e, BusEvent::BusOff | BusEvent::ErrorPassive { .. } | BusEvent::Overflow | BusEvent::Transceiver)
}

/// Error state of the CAN controller (CAN 2.0 fault confinement).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
#[repr(u8)]
pub enum BusState {
    /// Error-active: normal.
    #[default]
    Active = 0,
    /// An error counter above 96.
    Warning = 1,
    /// An error counter above 127.
    Passive = 2,
    /// Bus-off (or the interface is gone): nothing is sent or received until a restart.
    Off = 3,
}

impl BusState {
    /// Lower-case name for status output.
    pub fn name(self) -> &'static str {
        match self {
            BusState::Active => "error-active",
            BusState::Warning => "error-warning",
            BusState::Passive => "error-passive",
            BusState::Off => "bus-off",
        }
    }
}

/// The CAN bus as the loop sees it: the controller's error state and what it reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusStatus {
    /// The interface.
    pub iface: IfName,
    /// Error state now.
    pub state: BusState,
    /// The last event the interface reported.
    pub last: Option<BusEvent>,
    /// Events (error frames) reported so far.
    pub events: u32,
    /// Times the bus came back: restarted after bus-off, or back to error-active after
    /// error-passive.
    pub recoveries: u32,
}

impl Default for BusStatus {
    fn default() -> Self {
        BusStatus { iface: IfName::new("can"), state: BusState::Active, last: None, events: 0, recoveries: 0 }
    }
}

/// What the devices delivered for one cycle. Ages are seconds since the value was measured;
/// `f64::INFINITY` means never.
#[derive(Debug, Clone, Copy)]
pub struct Inputs {
    /// Number of cables in use (the rest of each array is unused).
    pub n: usize,
    /// Encoder cable lengths, m (CiA 402 position actual value converted).
    pub length_m: [f64; MAX_CABLES],
    /// Age of each length, s.
    pub length_age_s: [f64; MAX_CABLES],
    /// Load-cell tensions, N.
    pub tension_n: [f64; MAX_CABLES],
    /// Age of each tension, s.
    pub tension_age_s: [f64; MAX_CABLES],
    /// Drive states.
    pub drive: [DriveStatus; MAX_CABLES],
    /// Tracker position of the platform, m.
    pub pose_m: [f64; 3],
    /// Age of the pose, s.
    pub pose_age_s: f64,
    /// A device problem seen this cycle (the first one, if several).
    pub fault: Option<DeviceFault>,
    /// The CAN bus.
    pub bus: BusStatus,
}

impl Inputs {
    /// Inputs of `n` cables with nothing received yet.
    pub fn new(n: usize) -> Inputs {
        assert!(n <= MAX_CABLES, "at most {MAX_CABLES} cables");
        Inputs {
            n,
            length_m: [f64::NAN; MAX_CABLES],
            length_age_s: [f64::INFINITY; MAX_CABLES],
            tension_n: [f64::NAN; MAX_CABLES],
            tension_age_s: [f64::INFINITY; MAX_CABLES],
            drive: [DriveStatus::Unknown; MAX_CABLES],
            pose_m: [f64::NAN; 3],
            pose_age_s: f64::INFINITY,
            fault: None,
            bus: BusStatus::default(),
        }
    }
}

/// What one cable's drive is told to do.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum CableCommand {
    /// Cyclic synchronous position: reach this encoder length, m.
    Position(f64),
    /// Cyclic synchronous torque: pull with this tension, N.
    Tension(f64),
    /// No command (drive not enabled).
    #[default]
    Idle,
}

/// What the loop asks of the drives as a whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DriveRequest {
    /// Keep drives disabled.
    #[default]
    Disable,
    /// Enable (and keep enabled) and follow the cable commands.
    Enable,
    /// CiA 402 quick stop.
    QuickStop,
    /// Operator reset: a fault reset (rising edge of controlword bit 7, CiA 402 6.3.1) for
    /// every drive in fault; the others stay as they are (disabled or in quick stop).
    FaultReset,
}

/// What the loop writes each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// Number of cables in use.
    pub n: usize,
    /// Drive set request.
    pub request: DriveRequest,
    /// One command per cable.
    pub cable: [CableCommand; MAX_CABLES],
}

impl Outputs {
    /// Outputs of `n` cables, drives disabled.
    pub fn new(n: usize) -> Outputs {
        Outputs { n, request: DriveRequest::Disable, cable: [CableCommand::Idle; MAX_CABLES] }
    }
}

/// The devices as the loop sees them: one `read` at the start of each cycle, one `write` at the
/// end. Implementations must not allocate or block in either (drain queues, poll sockets
/// non-blocking). `now_s` is the loop's monotonic time in seconds since it started.
pub trait Devices: Send {
    /// Fills `inputs` with everything that arrived since the last cycle.
    fn read(&mut self, now_s: f64, inputs: &mut Inputs);
    /// Sends `outputs` (RPDOs, then SYNC).
    fn write(&mut self, now_s: f64, outputs: &Outputs);
}

impl<D: Devices + ?Sized> Devices for Box<D> {
    fn read(&mut self, now_s: f64, inputs: &mut Inputs) {
        (**self).read(now_s, inputs)
    }
    fn write(&mut self, now_s: f64, outputs: &Outputs) {
        (**self).write(now_s, outputs)
    }
}
