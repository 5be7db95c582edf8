//! The robot's devices as the loop sees them ([`Devices`]): CiA 402 drives through
//! `taut-driver`'s CANopen [`Master`] on any [`CanTransport`], load cells through the driver's
//! Modbus RTU I/O thread, and the tracker through its UDP receiver. The same code runs on
//! hardware and against the simulated robot; only the transport and the device paths differ.
//!
//! The loop is the SYNC clock: every cycle ends with the RPDOs of every drive and one SYNC
//! ([`Master::sync_cycle`]), and the TPDOs the drives answer with are read at the start of the
//! next cycle. Bring-up (SDO configuration, NMT start) runs before the loop with
//! [`DriveSet::bring_up`], so the loop only ever sees operational drives.
//!
//! ```text
//! read:  drain CAN -> master.on_frame; events -> DeviceFault; positions, drive states;
//!        newest tensions (Modbus thread); newest pose (UDP receiver)
//! write: enable / disable / quick stop, mode (CSP or CST) and target per drive;
//!        master timers; RPDOs + SYNC -> CAN
//! ```
//!
//! The master deals in drive units (counts, ‰ of rated torque); the conversion to metres and
//! newtons ([`Scaling`], per `[cable.drive]` table) and the tension limit are here.
//!
//! Nothing here allocates after [`RobotDevices::bring_up`]: the master's queues are fixed-size
//! (`heapless`), frames are `Copy`, readers are lock-free.

use std::fmt;
use std::time::Instant;
use taut_config::RobotConfig;
use taut_driver::clock::SharedClock;
use taut_driver::{BusEvent, DriveSet, LoadCellIo, Master, MasterConfig, NodeEvent, Phase, PoseReader, TensionReader, TrackerThread};
use taut_proto::can::{CanTransport, TransportError};
use taut_proto::canopen::cia402::{Mode, PowerState};
use taut_proto::devices::DriveConfig;
use taut_rt::io::{
    bus_event_is_fault, BusState, BusStatus, CableCommand, DeviceFault, Devices, DriveRequest, DriveStatus, Inputs, Outputs,
};
use taut_rt::MAX_CABLES;

/// Why the devices could not be brought up. [`BringUpError::key`] names the configuration key
/// or device; the message says what to do.
#[derive(Debug)]
pub enum BringUpError {
    /// More cables than the loop is built for.
    TooManyCables {
        /// Cables in the configuration.
        cables: usize,
    },
    /// A drive setting the CANopen master cannot use (key and what to do).
    MasterConfig(taut_driver::ConfigProblem),
    /// Cable `cable` has no `[cable.drive]`.
    NoDrive {
        /// Cable index.
        cable: usize,
    },
    /// The start-up motion needs the drive of `cable` in a mode its PDO map cannot select
    /// (no RPDO carries the mode of operation 0x6060).
    ModeFixed {
        /// Cable index.
        cable: usize,
        /// The drive's node-ID.
        node: u8,
        /// Needed in cyclic synchronous position mode.
        position: bool,
        /// Needed in cyclic synchronous torque mode.
        torque: bool,
    },
    /// The drives did not come up on the bus.
    Drives(taut_driver::DriveSetError),
    /// The load-cell bus did not start.
    LoadCells(taut_driver::loadcell::SpawnError),
    /// The tracker's UDP port could not be opened.
    Tracker(std::io::Error),
    /// Devices the plugin owns need a `[can]` table.
    NoCan,
    /// The CAN interface could not be opened.
    CanInterface {
        /// `can.interface`.
        interface: String,
        /// `can.bitrate`, bit/s.
        bitrate: u32,
        /// The OS's answer.
        source: std::io::Error,
    },
    /// The devices were handed over once already (a failed bring-up consumes the load-cell
    /// and tracker ports).
    DevicesTaken,
    /// Devices the plugin owns need SocketCAN, which only Linux has.
    Unsupported,
}

impl BringUpError {
    /// The configuration key or device the error is about (`can`, `cable[2].drive.pdo`,
    /// `loadcells`, `tracker.listen`, ...).
    pub fn key(&self) -> String {
        match self {
            BringUpError::TooManyCables { .. } => "cable".into(),
            BringUpError::MasterConfig(p) => p.key.clone(),
            BringUpError::NoDrive { cable } => format!("cable[{cable}].drive"),
            BringUpError::ModeFixed { cable, .. } => format!("cable[{cable}].drive.pdo"),
            BringUpError::Drives(_) | BringUpError::NoCan | BringUpError::Unsupported => "can".into(),
            BringUpError::LoadCells(_) => "loadcells".into(),
            BringUpError::Tracker(_) => "tracker.listen".into(),
            BringUpError::CanInterface { .. } => "can.interface".into(),
            BringUpError::DevicesTaken => "devices".into(),
        }
    }
}

impl fmt::Display for BringUpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: ", self.key())?;
        match self {
            BringUpError::TooManyCables { cables } => write!(f, "{cables} cables: the loop is built for at most {MAX_CABLES}"),
            BringUpError::MasterConfig(p) => write!(f, "{}", p.message),
            BringUpError::NoDrive { .. } => write!(f, "every cable needs a drive: add [cable.drive] with its node_id"),
            BringUpError::ModeFixed { node, position, torque, .. } => write!(
                f,
                "node {node} must run in {} for the start-up motion, but no RPDO of its map carries the mode of \
                 operation 0x6060, so its mode is fixed; set pdo = \"with_mode\" (0x6060 in RPDO2) or map 0x6060",
                match (position, torque) {
                    (true, true) => "position and torque mode",
                    (true, false) => "position mode",
                    _ => "torque mode",
                }
            ),
            BringUpError::Drives(e) => write!(f, "drive bring-up failed: {e}"),
            BringUpError::LoadCells(e) => write!(f, "{e}"),
            BringUpError::Tracker(e) => write!(f, "{e}; check the address and that no other program uses the port"),
            BringUpError::NoCan => write!(f, "devices the plugin owns need a [can] table with the interface of the drives"),
            BringUpError::CanInterface { interface, bitrate, source } => {
                write!(f, "opening CAN interface {interface}: {source}; is it up? `ip link set {interface} up type can bitrate {bitrate}`")
            }
            BringUpError::DevicesTaken => {
                write!(
                    f,
                    "the devices were handed over once already (a failed bring-up consumes the load-cell and tracker ports): start again"
                )
            }
            BringUpError::Unsupported => write!(f, "devices the plugin owns need SocketCAN (Linux)"),
        }
    }
}

impl std::error::Error for BringUpError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BringUpError::MasterConfig(e) => Some(e),
            BringUpError::Drives(e) => Some(e),
            BringUpError::LoadCells(e) => Some(e),
            BringUpError::Tracker(e) => Some(e),
            BringUpError::CanInterface { source, .. } => Some(source),
            _ => None,
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
    /// The scaling of a `[cable.drive]` table.
    pub fn from_drive(d: &DriveConfig) -> Scaling {
        Scaling {
            drum_radius_m: d.drum_radius_m,
            gear_ratio: d.gear_ratio,
            counts_per_rev: f64::from(d.counts_per_rev),
            rated_torque_nm: d.rated_torque_nm,
            sign: if d.invert { -1.0 } else { 1.0 },
        }
    }

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

/// One cable's drive in cable units: its [`Scaling`] and the largest tension it may be commanded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableUnits {
    /// Counts and torque to metres and newtons.
    pub scaling: Scaling,
    /// Largest tension that may be commanded, N (`[cable.drive] max_tension_n`).
    pub max_tension_n: f64,
}

impl CableUnits {
    /// From a `[cable.drive]` table.
    pub fn from_drive(d: &DriveConfig) -> CableUnits {
        CableUnits { scaling: Scaling::from_drive(d), max_tension_n: d.max_tension_n }
    }

    /// Torque command for a tension, N: limited to 0..=`max_tension_n` (a cable only pulls),
    /// then converted.
    pub fn torque_for(&self, n: f64) -> i16 {
        self.scaling.n_to_permille(n.clamp(0.0, self.max_tension_n))
    }
}

/// Where the load cells and the tracker are (usually from the configuration; the simulator
/// puts them on a pseudo-terminal and a loopback port).
pub struct Peripherals {
    /// The load-cell I/O thread and its reader (`None`: tensions from the drives' torque).
    pub loadcells: Option<(LoadCellIo, TensionReader)>,
    /// The tracker receiver (`None`: no tracker, the pose is never fresh).
    pub tracker: Option<TrackerThread>,
    /// Reader of that receiver's newest pose.
    pub pose: Option<PoseReader>,
}

impl Peripherals {
    /// Opens the load-cell bus and the tracker port of `cfg` (either may be absent).
    pub fn from_config(cfg: &RobotConfig) -> Result<Peripherals, BringUpError> {
        let loadcells = match &cfg.loadcells {
            Some(_) => Some(taut_driver::loadcell::spawn_from_config(cfg).map_err(BringUpError::LoadCells)?),
            None => None,
        };
        // The tension readings have the loop's staleness deadline: their I/O thread runs just
        // below the loop, not with the normal scheduler (see taut_driver::sched).
        if let (Some((io, _)), true) = (&loadcells, cfg.rt.priority > 1) {
            if let Err(e) = io.set_realtime(cfg.rt.priority - 1) {
                eprintln!(
                    "taut: SCHED_FIFO priority {} for the load-cell thread refused ({e}): under load its readings may go stale; set LimitRTPRIO=99 (deploy/taut.service) or grant CAP_SYS_NICE",
                    cfg.rt.priority - 1
                );
            }
        }
        let (tracker, pose) = match &cfg.tracker {
            Some(t) => {
                let (th, reader) = taut_driver::tracker::spawn(t).map_err(BringUpError::Tracker)?;
                (Some(th), Some(reader))
            }
            None => (None, None),
        };
        // The poses have the loop's staleness deadline too.
        if let (Some(th), true) = (&tracker, cfg.rt.priority > 1) {
            if let Err(e) = th.set_realtime(cfg.rt.priority - 1) {
                eprintln!(
                    "taut: SCHED_FIFO priority {} for the tracker thread refused ({e}): under load its poses may go stale; set LimitRTPRIO=99 (deploy/taut.service) or grant CAP_SYS_NICE",
                    cfg.rt.priority - 1
                );
            }
        }
        Ok(Peripherals { loadcells, tracker, pose })
    }
}

/// Which modes each cable's drive must run in, for the controller's motions: followers in
/// torque (CST), held and reeled cables in position (CSP). `(position, torque)` per cable.
pub fn modes_needed(cfg: &RobotConfig) -> Vec<(bool, bool)> {
    let n = cfg.cables.len();
    let mut need = vec![(false, false); n];
    for (j, nd) in need.iter_mut().enumerate() {
        // In operation and in each initialisation phase (taut_config::followers).
        let held = std::iter::once(&taut_config::followers::OPERATION_HELD).chain(&cfg.motion.init_phases);
        for h in held {
            if taut_config::followers::follows(j, h) {
                nd.1 = true;
            } else {
                nd.0 = true;
            }
        }
    }
    need
}

/// The robot's devices for the loop. See the module documentation.
pub struct RobotDevices<T: CanTransport> {
    bus: T,
    master: Master,
    n: usize,
    /// Master index of each cable's drive.
    drive: [Option<usize>; MAX_CABLES],
    /// Each cable's drive units.
    units: [Option<CableUnits>; MAX_CABLES],
    /// TPDOs counted at the last read, and when the count last moved.
    tpdos: [u64; MAX_CABLES],
    fresh_at: [Option<Instant>; MAX_CABLES],
    loadcells: Option<(LoadCellIo, TensionReader)>,
    _tracker: Option<TrackerThread>,
    pose: Option<PoseReader>,
    transport_errors: u64,
    /// The bus as the interface reported it.
    bus_status: BusStatus,
    /// A bus event that is a fault, not yet handed to the loop.
    bus_fault: Option<DeviceFault>,
    /// The request of the last write (a fault reset is sent once per reset request).
    last_request: DriveRequest,
    /// A fault reset asked for and not yet handed to the drives (not all operational).
    fault_reset_pending: bool,
    /// When the last SYNC went out: the drives latch their actual values at SYNC, so the
    /// TPDOs that answer it carry values of that instant.
    last_sync: Option<Instant>,
    /// The clock of the readings' ages: the wall clock, or a lockstep simulation's.
    clock: SharedClock,
}

impl<T: CanTransport> RobotDevices<T> {
    /// Brings the drives of `cfg` up on `bus` (identify, configure PDOs and heartbeats, NMT
    /// start; within `can.bringup_timeout_s`), checks that every drive can run the modes the
    /// start-up motion needs, and combines them with `peripherals`.
    pub fn bring_up(cfg: &RobotConfig, bus: T, peripherals: Peripherals) -> Result<Self, BringUpError> {
        Self::bring_up_with_clock(cfg, bus, peripherals, taut_driver::clock::wall())
    }

    /// [`bring_up`](Self::bring_up) on `clock` (a lockstep simulation's; the bring-up's
    /// timeouts and every reading's age are then in simulated time).
    pub fn bring_up_with_clock(cfg: &RobotConfig, bus: T, peripherals: Peripherals, clock: SharedClock) -> Result<Self, BringUpError> {
        let n = cfg.cables.len();
        if n > MAX_CABLES {
            return Err(BringUpError::TooManyCables { cables: n });
        }
        let mcfg = MasterConfig::from_robot(cfg).map_err(BringUpError::MasterConfig)?;
        let mut drive = [None; MAX_CABLES];
        let mut units = [None; MAX_CABLES];
        let need = modes_needed(cfg);
        for (j, c) in cfg.cables.iter().enumerate() {
            let Some(i) = mcfg.nodes.iter().position(|nc| nc.cable == j) else {
                return Err(BringUpError::NoDrive { cable: j });
            };
            drive[j] = Some(i);
            units[j] = c.drive.as_ref().map(CableUnits::from_drive);
            let nc = &mcfg.nodes[i];
            let (pos, tq) = need[j];
            if !nc.pdos.maps_mode() && ((pos && nc.mode != Mode::CyclicPosition) || (tq && nc.mode != Mode::CyclicTorque)) {
                let node = c.drive.as_ref().map_or(0, |d| d.node_id);
                return Err(BringUpError::ModeFixed { cable: j, node, position: pos, torque: tq });
            }
        }
        let set = DriveSet::new(bus, mcfg).with_clock(clock.clone());
        let set = set.bring_up().map_err(|r| BringUpError::Drives(r.error))?;
        let (bus, master) = set.into_parts();
        let bus_iface = bus.iface();
        Ok(RobotDevices {
            bus,
            master,
            n,
            drive,
            units,
            tpdos: [0; MAX_CABLES],
            fresh_at: [None; MAX_CABLES],
            loadcells: peripherals.loadcells,
            _tracker: peripherals.tracker,
            pose: peripherals.pose,
            transport_errors: 0,
            bus_status: BusStatus { iface: bus_iface, ..BusStatus::default() },
            bus_fault: None,
            last_request: DriveRequest::Disable,
            fault_reset_pending: false,
            last_sync: None,
            clock,
        })
    }

    /// The master (status and counters, for logs).
    pub fn master(&self) -> &Master {
        &self.master
    }

    /// Transport errors seen (closed socket, I/O errors); bus problems are in the master's
    /// counters.
    pub fn transport_errors(&self) -> u64 {
        self.transport_errors
    }

    /// The CAN bus as the interface reported it.
    pub fn bus(&self) -> BusStatus {
        self.bus_status
    }

    /// Tracks the controller's error state from its error frames; keeps the first fault for
    /// the next read.
    fn on_bus_event(&mut self, e: BusEvent) {
        self.master.on_bus_event(e);
        let b = &mut self.bus_status;
        b.events = b.events.saturating_add(1);
        b.last = Some(e);
        let was = b.state;
        b.state = match e {
            BusEvent::BusOff => BusState::Off,
            // A restarted controller starts error-active with its counters at 0.
            BusEvent::Restarted | BusEvent::ErrorActive => BusState::Active,
            // Error frames of a controller that is off are stale reports: it stays off.
            _ if was == BusState::Off => BusState::Off,
            BusEvent::ErrorPassive { .. } => BusState::Passive,
            BusEvent::ErrorWarning { .. } => BusState::Warning,
            _ => was,
        };
        if b.state == BusState::Active && was >= BusState::Passive {
            b.recoveries = b.recoveries.saturating_add(1);
        }
        if bus_event_is_fault(e) && self.bus_fault.is_none() {
            self.bus_fault = Some(DeviceFault::Bus { iface: b.iface, event: e });
        }
    }

    /// The interface is gone (unplugged USB adapter, interface down): for the loop that is a
    /// bus-off, and it stays off (no restart will be reported).
    fn on_transport_gone(&mut self) {
        self.transport_errors += 1;
        if self.bus_status.state != BusState::Off {
            self.on_bus_event(BusEvent::BusOff);
        }
    }

    fn drain(&mut self, wall: Instant) {
        loop {
            match self.bus.try_recv() {
                Ok(Some(f)) => self.master.on_frame(&f, wall),
                Ok(None) => return,
                Err(TransportError::Bus(b)) => self.on_bus_event(b),
                Err(TransportError::Full(_)) => {}
                // Bytes that are no CAN frame: counted, the bus goes on.
                Err(TransportError::Io(std::io::ErrorKind::InvalidData)) => self.transport_errors += 1,
                Err(TransportError::Closed | TransportError::Io(_)) => return self.on_transport_gone(),
            }
        }
    }

    fn flush(&mut self) {
        while let Some(f) = self.master.poll_tx() {
            match self.bus.send(&f) {
                Ok(()) | Err(TransportError::Full(_)) => {}
                Err(TransportError::Bus(b)) => self.on_bus_event(b),
                Err(TransportError::Closed | TransportError::Io(_)) => self.on_transport_gone(),
            }
        }
    }
}

fn status_of(state: Option<PowerState>) -> DriveStatus {
    match state {
        None => DriveStatus::Unknown,
        Some(PowerState::OperationEnabled) => DriveStatus::Enabled,
        Some(PowerState::QuickStopActive) => DriveStatus::QuickStop,
        Some(PowerState::Fault | PowerState::FaultReactionActive) => DriveStatus::Fault,
        Some(_) => DriveStatus::Disabled,
    }
}

impl<T: CanTransport + Send> Devices for RobotDevices<T> {
    fn read(&mut self, _now_s: f64, inp: &mut Inputs) {
        // Every age below is against this one `wall`: the loop's `now_s` is the host's time,
        // which need not run with the wall clock.
        let wall = self.clock.now();
        self.drain(wall);
        inp.fault = self.bus_fault.take();
        while let Some(e) = self.master.poll_event() {
            let f = match e {
                // "Error reset / no error" (0x0000) clears, it does not fault.
                NodeEvent::Emergency { node, emcy } if emcy.code != 0 => Some(DeviceFault::Emcy { node, code: emcy.code }),
                NodeEvent::HeartbeatLost { node } => Some(DeviceFault::HeartbeatLost { node }),
                NodeEvent::Rebooted { node } => Some(DeviceFault::Rebooted { node }),
                _ => None,
            };
            if inp.fault.is_none() {
                inp.fault = f;
            }
        }
        if self.bus_status.state == BusState::Off && inp.fault.is_none() {
            inp.fault = Some(DeviceFault::Bus { iface: self.bus_status.iface, event: BusEvent::BusOff });
        }
        inp.bus = self.bus_status;
        if let Some((_, r)) = &mut self.loadcells {
            r.update();
        }
        for j in 0..self.n {
            let (Some(i), Some(u)) = (self.drive[j], self.units[j]) else { continue };
            let Some(s) = self.master.status(i) else { continue };
            if s.axis.tpdos != self.tpdos[j] {
                self.tpdos[j] = s.axis.tpdos;
                // Synchronous TPDOs carry what the drive latched at the SYNC (CiA 301).
                self.fresh_at[j] = Some(self.last_sync.unwrap_or(wall));
            }
            let operational = s.phase == Phase::Operational;
            match self.fresh_at[j] {
                Some(at) if operational => {
                    inp.length_m[j] = u.scaling.counts_to_m(s.axis.position);
                    inp.length_age_s[j] = wall.saturating_duration_since(at).as_secs_f64();
                }
                _ => inp.length_age_s[j] = f64::INFINITY,
            }
            inp.drive[j] = if operational { status_of(s.axis.state) } else { DriveStatus::Unknown };
            match &self.loadcells {
                Some((_, r)) => match r.latest(j) {
                    Some((t, at)) => {
                        inp.tension_n[j] = t;
                        inp.tension_age_s[j] = wall.saturating_duration_since(at).as_secs_f64();
                    }
                    None => inp.tension_age_s[j] = f64::INFINITY,
                },
                None => {
                    // No load cells: the drive's torque is the tension estimate.
                    inp.tension_n[j] = u.scaling.permille_to_n(s.axis.torque);
                    inp.tension_age_s[j] = inp.length_age_s[j];
                }
            }
        }
        if let Some(p) = self.pose.as_ref().and_then(PoseReader::newest) {
            inp.pose_m = p.position;
            // Age from when the tracker measured it, on the wall clock like the other ages, so that
            // `t - age` puts every reading of a sample on one time axis. A pose that arrived after
            // `wall` is 0 s old, never negative (a host-owned plugin refuses a negative age).
            inp.pose_age_s = wall.saturating_duration_since(p.measured).as_secs_f64();
        } else {
            inp.pose_age_s = f64::INFINITY;
        }
    }

    fn write(&mut self, _now_s: f64, out: &Outputs) {
        let wall = self.clock.now();
        if out.request == DriveRequest::FaultReset && self.last_request != DriveRequest::FaultReset {
            // One fault reset per operator request: the rising edge of bit 7 goes out once
            // (the master holds it until the drive leaves FAULT or gives up).
            self.fault_reset_pending = true;
        }
        self.last_request = out.request;
        if !self.master.all_operational() && matches!(out.request, DriveRequest::QuickStop | DriveRequest::Disable) {
            // A drive is away (rebooting, lost): stop the others anyway.
            self.master.stop_reachable(out.request == DriveRequest::QuickStop);
        }
        if let Some(mut op) = self.master.operational() {
            for j in 0..self.n.min(out.n) {
                let (Some(i), Some(u)) = (self.drive[j], self.units[j]) else { continue };
                // Refusals (not yet enabled, mode not mapped: checked at bring-up) leave the
                // drive where it is; the loop sees its state next cycle.
                match out.request {
                    DriveRequest::Disable => {
                        let _ = op.disable(i);
                    }
                    DriveRequest::QuickStop => {
                        let _ = op.quick_stop(i);
                    }
                    DriveRequest::FaultReset => {
                        // Only drives in fault (the master ignores the others).
                        if self.fault_reset_pending {
                            let _ = op.fault_reset(i);
                        }
                    }
                    DriveRequest::Enable => {
                        let _ = op.enable(i);
                        match out.cable[j] {
                            CableCommand::Position(l) if l.is_finite() && op.set_mode(i, Mode::CyclicPosition).is_ok() => {
                                let _ = op.set_position_counts(i, u.scaling.m_to_counts(l));
                            }
                            CableCommand::Tension(t) if t.is_finite() && op.set_mode(i, Mode::CyclicTorque).is_ok() => {
                                let _ = op.set_torque_permille(i, u.torque_for(t));
                            }
                            _ => {}
                        }
                    }
                }
            }
        }
        // Handed over once every drive could take it: all operational, none still braking in
        // "fault reaction active" (it takes a fault reset only once in FAULT).
        if self.fault_reset_pending
            && self.master.all_operational()
            && self.master.statuses().all(|s| s.axis.state != Some(PowerState::FaultReactionActive))
        {
            self.fault_reset_pending = false;
        }
        self.master.poll_timers(wall);
        self.master.sync_cycle();
        self.flush();
        self.last_sync = Some(self.clock.now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use taut_driver::transport::virtual_bus::VirtualBus;

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

    #[test]
    fn commanded_tension_is_limited_to_what_a_cable_can_take() {
        let scaling = Scaling { drum_radius_m: 0.05, gear_ratio: 10.0, counts_per_rev: 131072.0, rated_torque_nm: 1.0, sign: 1.0 };
        let u = CableUnits { scaling, max_tension_n: 100.0 };
        // A cable only pulls: a negative tension is 0 torque; above the limit, the limit.
        assert_eq!(u.torque_for(-50.0), 0);
        assert_eq!(u.torque_for(1e9), scaling.n_to_permille(100.0));
        assert_eq!(u.torque_for(20.0), scaling.n_to_permille(20.0));
        assert_eq!(scaling.n_to_permille(100.0), -500);
    }

    fn robot(pdo: &str, mode3: &str) -> RobotConfig {
        let mut t = String::from("[robot]\nname = \"t\"\nmass_kg = 3.0\n[can]\ninterface = \"can0\"\n");
        for (j, a) in [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]].iter().enumerate() {
            let mode = if j == 3 { mode3 } else { "position" };
            t += &format!(
                "[[cable]]\nanchor = [{}, {}, {}]\n[cable.drive]\nnode_id = {}\npdo = \"{pdo}\"\nmode = \"{mode}\"\n",
                a[0],
                a[1],
                a[2],
                j + 1
            );
        }
        RobotConfig::from_toml_str(&t).unwrap()
    }

    #[test]
    fn a_follower_with_a_fixed_position_mode_is_refused_by_key() {
        let none = || Peripherals { loadcells: None, tracker: None, pose: None };
        let e = RobotDevices::bring_up(&robot("compact", "position"), VirtualBus::new().endpoint(), none()).err().unwrap();
        assert_eq!(e.key(), "cable[3].drive.pdo");
        assert!(matches!(e, BringUpError::ModeFixed { cable: 3, position: false, torque: true, .. }), "{e}");
        assert!(e.to_string().contains("with_mode"), "{e}");
        // The follower in torque mode is fine with compact PDOs: the bring-up itself then fails
        // (nobody on the bus), naming the CAN side.
        let mut cfg = robot("compact", "torque");
        cfg.can.as_mut().unwrap().bringup_timeout_s = 0.2;
        let e = RobotDevices::bring_up(&cfg, VirtualBus::new().endpoint(), none()).err().unwrap();
        assert_eq!(e.key(), "can", "{e}");
        assert!(matches!(e, BringUpError::Drives(_)), "{e}");
        assert!(e.to_string().contains("no boot-up or heartbeat seen"), "{e}");
    }

    #[test]
    fn modes_follow_the_phases() {
        let need = modes_needed(&robot("with_mode", "position"));
        assert_eq!(need, vec![(true, false), (true, false), (true, false), (false, true)]);
    }
}
