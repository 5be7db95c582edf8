//! The drives of the robot on a transport, with the lifecycle in types:
//!
//! ```text
//! DriveSet<T, Configuring> --bring_up()--> DriveSet<T, Operational> --enable()--> DriveSet<T, Enabled>
//!                                               ^   fault_reset()                     │ set_positions_counts()
//!                                               └───────────── disable() ─────────────┘ set_torques_permille()
//! ```
//! Only `DriveSet<_, Enabled>` has methods that move cables. This layer reads the clock (wall or
//! simulated: [`DriveSet::with_clock`]) and pumps the transport; the protocol is in [`Master`].
//! Drive units (counts, ‰ of rated torque), as in the master.
//!
//! ```no_run
//! use taut_driver::canopen::drive_set::DriveSet;
//! use taut_driver::canopen::master::MasterConfig;
//! use taut_driver::transport::socketcan::SocketCanTransport;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let cfg = taut_config::RobotConfig::load("robot.toml")?;
//! let bus = SocketCanTransport::open("can0")?;
//! let set = DriveSet::new(bus, MasterConfig::from_robot(&cfg)?);
//! let set = set.bring_up().map_err(|e| e.error)?;
//! let mut set = set.enable(std::time::Duration::from_secs(2)).map_err(|e| e.error)?;
//! set.set_positions_counts(&[131_072, 150_000, 120_000, 140_000])?;
//! set.cycle()?;
//! # Ok(()) }
//! ```

use super::master::{CommandError, Master, MasterConfig, NodeEvent, NodeStatus, Phase};
use crate::clock::{self, SharedClock};
use std::fmt;
use std::marker::PhantomData;
use std::time::{Duration, Instant};
use taut_proto::can::{CanTransport, TransportError};
use taut_proto::canopen::cia402::PowerState;
use taut_proto::canopen::NodeId;

/// Typestate: drives being found and configured.
pub struct Configuring;
/// Typestate: all drives operational (PDOs flowing), power stages off.
pub struct Operational;
/// Typestate: all drives in "operation enabled": cables can be moved.
pub struct Enabled;

/// Why a transition did not happen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriveSetError {
    /// These nodes did not get there in time (first one named; `count` in all).
    Timeout {
        /// A node that is not there.
        node: NodeId,
        /// Its phase.
        phase: Phase,
        /// Its drive state, if known.
        state: Option<PowerState>,
        /// How many nodes are not there.
        count: usize,
    },
    /// A drive is in fault.
    Fault {
        /// Node.
        node: NodeId,
        /// Error code (EMCY / 0x603F).
        code: u16,
    },
    /// A drive dropped out of operational (heartbeat lost, reboot).
    NotOperational {
        /// Node.
        node: NodeId,
        /// Its phase.
        phase: Phase,
    },
    /// A drive left "operation enabled" while the set was enabled: it rebooted (and came back
    /// configured but disabled) or was disabled locally (enable input, drive panel).
    Disabled {
        /// Node.
        node: NodeId,
        /// Its drive state now, if known.
        state: Option<PowerState>,
    },
    /// A command was refused.
    Command(CommandError),
    /// The transport failed.
    Transport(TransportError),
}

impl fmt::Display for DriveSetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DriveSetError::Timeout { node, phase, state, count } => {
                write!(f, "{count} drive(s) not ready in time; node {node} is {}", phase.name())?;
                if let Some(s) = state {
                    write!(f, " (drive {})", s.name())?;
                }
                if let Phase::Failed(why) = phase {
                    write!(f, ": {why}")?;
                }
                if *phase == Phase::Waiting {
                    write!(f, ": no boot-up or heartbeat seen; check power, wiring, node id and bitrate")?;
                }
                Ok(())
            }
            DriveSetError::Fault { node, code } => {
                write!(f, "node {node}: drive fault 0x{code:04X} ({})", taut_proto::canopen::emcy::error_code_name(*code))
            }
            DriveSetError::NotOperational { node, phase } => write!(f, "node {node}: no longer operational ({})", phase.name()),
            DriveSetError::Disabled { node, state } => write!(
                f,
                "node {node}: left operation enabled (now {}); it rebooted or was disabled locally: disable the set and enable it again",
                state.map_or("unknown", |s| s.name())
            ),
            DriveSetError::Command(e) => write!(f, "{e}"),
            DriveSetError::Transport(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DriveSetError {}

impl From<CommandError> for DriveSetError {
    fn from(e: CommandError) -> Self {
        DriveSetError::Command(e)
    }
}

/// A failed transition hands the set back in its old state.
pub struct Refused<S> {
    /// The set, unchanged in type.
    pub set: S,
    /// Why.
    pub error: DriveSetError,
}

impl<S> fmt::Debug for Refused<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.error)
    }
}

/// The drives on one bus.
pub struct DriveSet<T: CanTransport, S> {
    bus: T,
    master: Master,
    bringup_timeout: Duration,
    last_transport_error: Option<TransportError>,
    clock: SharedClock,
    _state: PhantomData<S>,
}

impl<T: CanTransport, S> DriveSet<T, S> {
    fn into_state<S2>(self) -> DriveSet<T, S2> {
        DriveSet {
            bus: self.bus,
            master: self.master,
            bringup_timeout: self.bringup_timeout,
            last_transport_error: self.last_transport_error,
            clock: self.clock,
            _state: PhantomData,
        }
    }

    /// The master (status, counters).
    pub fn master(&self) -> &Master {
        &self.master
    }

    /// Snapshots of all drives.
    pub fn statuses(&self) -> Vec<NodeStatus> {
        self.master.statuses().collect()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<NodeEvent> {
        self.master.poll_event()
    }

    /// The last transport error (bus problems are passed to the master and counted there).
    pub fn last_transport_error(&self) -> Option<TransportError> {
        self.last_transport_error
    }

    /// The transport.
    pub fn transport(&mut self) -> &mut T {
        &mut self.bus
    }

    /// Runs the protocol until `until`: receive, update, send. Returns early on a fatal
    /// transport error.
    pub fn run_until(&mut self, until: Instant) -> Result<(), DriveSetError> {
        loop {
            let now = self.clock.now();
            self.master.poll(now);
            self.flush()?;
            if now >= until {
                return Ok(());
            }
            let wake = self.master.next_deadline().map_or(until, |d| d.min(until));
            match self.bus.recv_deadline(wake) {
                Ok(Some(f)) => {
                    self.master.on_frame(&f, self.clock.now());
                    // Drain what else is waiting before polling again.
                    self.drain()?;
                }
                Ok(None) => {}
                Err(e) => self.transport_error(e)?,
            }
        }
    }

    fn drain(&mut self) -> Result<(), DriveSetError> {
        loop {
            match self.bus.try_recv() {
                Ok(Some(f)) => self.master.on_frame(&f, self.clock.now()),
                Ok(None) => return Ok(()),
                Err(e) => self.transport_error(e)?,
            }
        }
    }

    fn transport_error(&mut self, e: TransportError) -> Result<(), DriveSetError> {
        self.last_transport_error = Some(e);
        match e {
            TransportError::Bus(b) => {
                self.master.on_bus_event(b);
                Ok(())
            }
            TransportError::Full(_) => Ok(()),
            TransportError::Closed | TransportError::Io(_) => Err(DriveSetError::Transport(e)),
        }
    }

    fn flush(&mut self) -> Result<(), DriveSetError> {
        while let Some(f) = self.master.poll_tx() {
            match self.bus.send(&f) {
                Ok(()) => {}
                Err(TransportError::Full(_)) => {
                    // The interface queue is full (bus-off or saturated): drop, count, go on.
                    self.last_transport_error = Some(TransportError::Full(f));
                }
                Err(e) => self.transport_error(e)?,
            }
        }
        Ok(())
    }

    /// Runs the protocol for `d`.
    pub fn run_for(&mut self, d: Duration) -> Result<(), DriveSetError> {
        self.run_until(self.clock.now() + d)
    }

    fn wait_for(&mut self, timeout: Duration, mut done: impl FnMut(&Master) -> Result<bool, DriveSetError>) -> Result<(), DriveSetError> {
        let end = self.clock.now() + timeout;
        loop {
            if done(&self.master)? {
                return Ok(());
            }
            if self.clock.now() >= end {
                return Err(self.not_ready());
            }
            let step = (self.clock.now() + self.master.sync_period()).min(end);
            self.run_until(step)?;
        }
    }

    fn not_ready(&self) -> DriveSetError {
        let bad: Vec<NodeStatus> = self
            .master
            .statuses()
            .filter(|s| s.phase != Phase::Operational || s.axis.state != Some(PowerState::OperationEnabled))
            .collect();
        let first = bad.iter().find(|s| s.phase != Phase::Operational).or(bad.first());
        match first {
            Some(s) => DriveSetError::Timeout { node: s.node, phase: s.phase, state: s.axis.state, count: bad.len() },
            None => DriveSetError::Timeout { node: 0, phase: Phase::Waiting, state: None, count: 0 },
        }
    }

    fn check_operational(&self) -> Result<(), DriveSetError> {
        for s in self.master.statuses() {
            if s.phase != Phase::Operational {
                return Err(DriveSetError::NotOperational { node: s.node, phase: s.phase });
            }
        }
        Ok(())
    }
}

impl<T: CanTransport> DriveSet<T, Configuring> {
    /// The drives of `cfg` on `bus`. Nothing is sent until [`bring_up`](Self::bring_up).
    pub fn new(bus: T, cfg: MasterConfig) -> Self {
        let bringup_timeout = cfg.bringup_timeout;
        DriveSet { bus, master: Master::new(cfg), bringup_timeout, last_transport_error: None, clock: clock::wall(), _state: PhantomData }
    }

    /// Reads `clock` instead of the wall clock (a lockstep simulation).
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = clock;
        self
    }

    /// Finds, identifies and configures every drive and starts them (NMT operational), within
    /// the configured bring-up timeout.
    // The refusal hands the whole set back, as large as the Ok value: boxing it would save nothing.
    #[allow(clippy::result_large_err)]
    pub fn bring_up(mut self) -> Result<DriveSet<T, Operational>, Refused<Self>> {
        let t = self.bringup_timeout;
        match self.wait_for(t, |m| Ok(m.all_operational())) {
            Ok(()) => Ok(self.into_state()),
            Err(error) => Err(Refused { set: self, error }),
        }
    }
}

impl<T: CanTransport> DriveSet<T, Operational> {
    /// The transport and the master, for an application that runs the cycle from its own
    /// periodic loop (the real-time loop: [`Master::poll_timers`], [`Master::sync_cycle`]).
    /// Only a brought-up set comes apart, so the loop starts with every drive operational.
    pub fn into_parts(self) -> (T, Master) {
        (self.bus, self.master)
    }

    /// Enables every drive (holding position) and waits until all are in operation enabled.
    // The refusal hands the whole set back, as large as the Ok value: boxing it would save nothing.
    #[allow(clippy::result_large_err)]
    pub fn enable(mut self, timeout: Duration) -> Result<DriveSet<T, Enabled>, Refused<Self>> {
        let n = self.master.len();
        if let Some(mut op) = self.master.operational() {
            for i in 0..n {
                let _ = op.enable(i);
            }
        }
        let r = self.wait_for(timeout, |m| {
            for s in m.statuses() {
                if s.phase != Phase::Operational {
                    return Err(DriveSetError::NotOperational { node: s.node, phase: s.phase });
                }
                if s.axis.state == Some(PowerState::Fault) {
                    return Err(DriveSetError::Fault { node: s.node, code: s.axis.error_code });
                }
            }
            Ok(m.all_enabled())
        });
        match r {
            Ok(()) => Ok(self.into_state()),
            Err(error) => Err(Refused { set: self, error }),
        }
    }

    /// Resets the faults of every faulted drive and waits until none is in fault.
    pub fn fault_reset(&mut self, timeout: Duration) -> Result<(), DriveSetError> {
        let n = self.master.len();
        if let Some(mut op) = self.master.operational() {
            for i in 0..n {
                let _ = op.fault_reset(i);
            }
        }
        self.wait_for(timeout, |m| Ok(m.statuses().all(|s| s.axis.state.is_some_and(|st| st != PowerState::Fault))))
    }

    /// Runs one SYNC cycle (waits for it).
    pub fn cycle(&mut self) -> Result<(), DriveSetError> {
        let p = self.master.sync_period();
        self.run_for(p)?;
        self.check_operational()
    }
}

impl<T: CanTransport> DriveSet<T, Enabled> {
    fn check(&self) -> Result<(), DriveSetError> {
        self.check_operational()?;
        for s in self.master.statuses() {
            if matches!(s.axis.state, Some(PowerState::Fault | PowerState::FaultReactionActive)) {
                return Err(DriveSetError::Fault { node: s.node, code: s.axis.error_code });
            }
            // A drive that rebooted fast enough to be configured and operational again between
            // two checks is only seen here: its power stage came back off.
            if s.axis.state != Some(PowerState::OperationEnabled) {
                return Err(DriveSetError::Disabled { node: s.node, state: s.axis.state });
            }
        }
        Ok(())
    }

    /// Target positions, encoder counts (CSP drives; in cable order of the drives).
    pub fn set_positions_counts(&mut self, counts: &[i32]) -> Result<(), DriveSetError> {
        self.check()?;
        let mut op = self.master.operational().ok_or(DriveSetError::NotOperational { node: 0, phase: Phase::Lost })?;
        for (i, &x) in counts.iter().enumerate() {
            op.set_position_counts(i, x)?;
        }
        Ok(())
    }

    /// Target torques, ‰ of each drive's rated torque (CST drives).
    pub fn set_torques_permille(&mut self, permille: &[i16]) -> Result<(), DriveSetError> {
        self.check()?;
        let mut op = self.master.operational().ok_or(DriveSetError::NotOperational { node: 0, phase: Phase::Lost })?;
        for (i, &x) in permille.iter().enumerate() {
            op.set_torque_permille(i, x)?;
        }
        Ok(())
    }

    /// Runs one SYNC cycle (waits for it). Fails if a drive faulted or dropped out: the caller
    /// decides (usually [`disable`](Self::disable), then fault reset).
    pub fn cycle(&mut self) -> Result<(), DriveSetError> {
        let p = self.master.sync_period();
        self.run_for(p)?;
        self.check()
    }

    /// Position actual values, counts, in drive order.
    pub fn positions_counts(&self) -> Vec<i32> {
        self.master.statuses().map(|s| s.axis.position).collect()
    }

    /// Disables every drive (power stages off) and hands back the operational set.
    pub fn disable(mut self) -> DriveSet<T, Operational> {
        let n = self.master.len();
        if let Some(mut op) = self.master.operational() {
            for i in 0..n {
                let _ = op.disable(i);
            }
        }
        let _ = self.run_for(self.master.sync_period() * 4);
        self.into_state()
    }
}
