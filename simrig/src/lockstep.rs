//! The simulated robot in simulated time: the whole robot stack in lockstep on one simulated
//! clock, as fast as the CPU allows, the same run for the same seed, bit for bit.
//!
//! ```text
//!  host: clock += period; plugin.update(); plugin.pump_calibrator()        (one thread)
//!          │
//!          └─ Devices::read ── world.advance_to(now) ── every event up to now, in time order:
//!               · CAN frames on the in-memory bus reach the virtual CiA 402 drives at the end
//!                 of their bits (bitrate, worst-case stuffing, one frame at a time), and back
//!               · the plant steps at `site_period`
//!               · a Modbus RTU polling round, one transaction at a time: the driver's master
//!                 against the virtual cells on an in-memory line (character times, t3.5, the
//!                 cell's latency); a cell answers with the plant's tension when its request
//!                 reached it, and the reading reaches the loop when the response is complete
//!               · a tracker pose (100 Hz), parsed by the driver's receiver
//!             then the robot's own device layer (`RobotDevices`) reads, as on hardware
//! ```
//!
//! Nothing of the robot's logic is re-implemented here: only the wires, the devices and the
//! physics are simulated. The calibrator runs without threads in the host's step after each
//! cycle ([`taut_plugin::Plugin::pump_calibrator`]), so a calibration takes no simulated time.
//!
//! Faults are drawn from the seed ([`LockstepFaults`]): lost and late CAN frames, a pause of the
//! load-cell bus, tracker dropouts. Faults a test chooses ([`SimFault`]) land at a simulated
//! instant, from [`LockstepFaults::scheduled`] or [`Lockstep::inject_at`].
//!
//! The master's CAN controller keeps ISO 11898-1 fault confinement and reports it as SocketCAN
//! does: frames reach the master as the kernel's `struct can_frame` bytes through
//! `taut_driver::transport::kernel::decode`, state changes as error frames (`linux/can/error.h`,
//! as the kernel's `can_change_state`, `can_bus_off` and `can_restart` send them):
//!
//! ```text
//!  a failed transmission (bit error): TEC += 8, the controller retries at once (an error-passive
//!  one after 8 more bits); a frame sent: TEC -= 1
//!  TEC >= 96   CAN_ERR_CRTL | CAN_ERR_CNT, data[1] CAN_ERR_CRTL_TX_WARNING, data[6] TEC
//!  TEC >= 128  CAN_ERR_CRTL | CAN_ERR_CNT, data[1] CAN_ERR_CRTL_TX_PASSIVE
//!  TEC > 255   CAN_ERR_BUSOFF | CAN_ERR_CNT: the controller neither sends nor receives; its
//!              queue's frames are lost, a send fails (ENOBUFS: TransportError::Full)
//!  back down   CAN_ERR_CRTL | CAN_ERR_CNT with TX_WARNING or CAN_ERR_CRTL_ACTIVE
//!  restart     after `restart-ms` (the deployed udev rule's 100 ms) or by hand
//!              (`ip link set can0 type can restart`): CAN_ERR_RESTARTED, TEC 0, error-active
//! ```

use crate::{draw_site, BuildError, PlatformTruth, SimFaults, SimOptions, Site, SiteIo, TRACKER_PERIOD_S};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use taut_calibrator::vocab::{CalibStatus, Calibrate};
use taut_config::RobotConfig;
use taut_driver::clock::{Clock, SimClock};
use taut_driver::loadcell::SteppedLoadCells;
use taut_driver::tracker::{TrackerReceiver, TrackerStatsHandle};
use taut_driver::transport::kernel::{self, err, CAN_ERR_FLAG, CAN_MTU};
use taut_io::robot_io::{Peripherals, RobotDevices};
use taut_io::runner::LoopStatus;
use taut_model::MAX_CABLES;
use taut_plugin::{DeviceMode, Plugin, PluginError, PluginOptions, RecordingPath};
use taut_proto::can::{CanTransport, Frame, TransportError};
use taut_proto::devices::{LoadCellBusConfig, Parity, TrackerConfig};
use taut_proto::modbus::link::{LinkError, SerialLink};
use taut_proto::tracker::{format_line, PoseLine, MAX_LINE};
use taut_rt::io::{Devices, Inputs, Outputs};
use taut_sim::Truth;
use taut_vdev::{LoadCellFault, LoadCellResponder, TensionHandle};

/// Faults the simulated devices and wires inject, drawn from the run's seed.
#[derive(Debug, Clone, PartialEq)]
pub struct LockstepFaults {
    /// Probability that a CAN frame is lost (in either direction).
    pub frame_loss: f64,
    /// Probability that a device sends a frame late (its processor was busy), by `frame_late_s`.
    pub frame_late: f64,
    /// How late, s.
    pub frame_late_s: f64,
    /// Probability per pose that a tracker dropout of `tracker_gap_s` starts (occlusion).
    pub tracker_dropout: f64,
    /// Length of a tracker dropout, s.
    pub tracker_gap_s: f64,
    /// The load cells stop answering from `.0` s for `.1` s.
    pub loadcell_silence: Option<(f64, f64)>,
    /// Faults at simulated instants (s since the start), as [`Lockstep::inject_at`].
    pub scheduled: Vec<(f64, SimFault)>,
    /// SocketCAN `restart-ms` of the master's interface (the udev rule's 100 ms); `None`: only by
    /// hand ([`SimFault::CanRestart`]).
    pub can_restart_ms: Option<u32>,
}

impl Default for LockstepFaults {
    /// No faults; the master's controller restarts 100 ms after a bus-off, as deployed.
    fn default() -> Self {
        LockstepFaults {
            frame_loss: 0.0,
            frame_late: 0.0,
            frame_late_s: 0.0,
            tracker_dropout: 0.0,
            tracker_gap_s: 0.0,
            loadcell_silence: None,
            scheduled: Vec::new(),
            can_restart_ms: Some(100),
        }
    }
}

impl LockstepFaults {
    /// Faults a robot rides through, drawn from `seed`: up to 1 lost and 1 late frame (by up to
    /// 0.5 ms) in 1,000, tracker dropouts of 20-200 ms (up to one every 5 s), and one pause of
    /// the load cells of 50-200 ms (shorter than the staleness limit) in the first 60 s. Nothing
    /// scheduled: drive faults, reboots and bus-off are faults the loop must react to, chosen by
    /// a test on purpose.
    pub fn drawn(seed: u64) -> LockstepFaults {
        let mut r = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_FA17);
        LockstepFaults {
            frame_loss: r.gen_range(0.0..1e-3),
            frame_late: r.gen_range(0.0..1e-3),
            frame_late_s: r.gen_range(0.0..5e-4),
            tracker_dropout: r.gen_range(0.0..2e-3),
            tracker_gap_s: r.gen_range(0.02..0.2),
            loadcell_silence: Some((r.gen_range(5.0..60.0), r.gen_range(0.05..0.2))),
            ..LockstepFaults::default()
        }
    }
}

/// A fault of the simulated devices or wires at a chosen simulated instant
/// ([`LockstepFaults::scheduled`], [`Lockstep::inject`], [`Lockstep::inject_at`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimFault {
    /// For `for_s` every frame the master's controller transmits fails with a bit error: its
    /// transmit error counter climbs by 8 per attempt to bus-off (about 32 attempts, 5 ms at
    /// 1 Mbit/s). The drives' frames still arrive while it is not bus-off.
    MasterTxErrors {
        /// How long, s.
        for_s: f64,
    },
    /// The master's controller is restarted by hand (`ip link set can0 type can restart`);
    /// nothing happens unless it is bus-off (the kernel answers EBUSY).
    CanRestart,
    /// The drive of `cable` faults (CiA 402 FAULT) and sends an EMCY with `code`.
    DriveFault {
        /// Cable index.
        cable: usize,
        /// CiA 402 error code (e.g. 0x2310 continuous over-current).
        code: u16,
    },
    /// The drive of `cable` is power cycled: boot-up, NMT pre-operational, configuration gone,
    /// absolute encoder position kept.
    DrivePowerCycle {
        /// Cable index.
        cable: usize,
    },
    /// The drive of `cable` stops sending its heartbeat for `for_s` (PDOs and SDO go on).
    HeartbeatLoss {
        /// Cable index.
        cable: usize,
        /// How long, s; `f64::INFINITY` until [`SimFault::HeartbeatBack`].
        for_s: f64,
    },
    /// The drive of `cable` sends its heartbeat again.
    HeartbeatBack {
        /// Cable index.
        cable: usize,
    },
}

/// Error state of the master's CAN controller (ISO 11898-1 fault confinement, as the kernel
/// names it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum CanState {
    /// Both error counters below 96.
    ErrorActive,
    /// An error counter at 96 or above.
    ErrorWarning,
    /// An error counter at 128 or above.
    ErrorPassive,
    /// The transmit error counter went past 255: off the bus until restarted.
    BusOff,
}

impl CanState {
    fn of(tec: u16) -> CanState {
        match tec {
            256.. => CanState::BusOff,
            128.. => CanState::ErrorPassive,
            96.. => CanState::ErrorWarning,
            _ => CanState::ErrorActive,
        }
    }
}

/// The master's CAN controller now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CanStatus {
    /// Its error state.
    pub state: CanState,
    /// Its transmit error counter (the receive counter stays 0).
    pub tec: u16,
}

/// Counts of the simulated CAN bus.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BusStats {
    /// Frames put on the bus.
    pub frames: u64,
    /// Frames lost (fault injection).
    pub lost: u64,
    /// Frames sent late (fault injection).
    pub late: u64,
    /// Time the bus carried bits, s.
    pub busy_s: f64,
    /// Transmissions of the master's controller that failed (each retried at once).
    pub tx_errors: u64,
    /// Times the master's controller went bus-off.
    pub bus_offs: u64,
    /// Times it was restarted after a bus-off.
    pub restarts: u64,
    /// Frames of the master lost to bus-off (in its queue when it went off, or sent while off).
    pub tx_lost_off: u64,
    /// Frames of the drives the master missed while its controller was off.
    pub rx_missed_off: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Master,
    Rack,
}

/// A frame on its way, as the kernel's `struct can_frame` bytes (error frames among them).
type Wire = (Instant, [u8; CAN_MTU]);

/// The master's CAN controller: its transmit error counter, the state it last reported, and
/// when it is off the bus.
struct Controller {
    tec: u16,
    state: CanState,
    /// Bus-off from `.0` until its restart at `.1` (`None`: until restarted by hand).
    off: Option<(Instant, Option<Instant>)>,
    /// `restart-ms`.
    restart: Option<Duration>,
    /// Its transmissions fail in this span.
    tx_fault: Option<(Instant, Instant)>,
}

impl Controller {
    fn is_off(&self, t: Instant) -> bool {
        self.off.is_some_and(|(from, until)| t >= from && until.is_none_or(|u| t < u))
    }
}

/// Bits a failed transmission takes beyond the frame: the error flag (6) and the error
/// delimiter (8); the intermission is in [`Bus::bits`]. Counted over the whole frame: a bit
/// error found at its end (CRC, ACK delimiter), the longest case.
const ERROR_FRAME_BITS: u32 = 14;
/// Suspend transmission: an error-passive transmitter waits 8 more bits before it tries again.
const SUSPEND_BITS: u32 = 8;

/// The CAN bus in memory: one frame on the wire at a time, each delivered at the end of its
/// bits.
struct Bus {
    clock: SimClock,
    bit: Duration,
    free_at: Instant,
    to_rack: VecDeque<Wire>,
    to_master: VecDeque<Wire>,
    faults: LockstepFaults,
    rng: ChaCha8Rng,
    stats: BusStats,
    ctrl: Controller,
}

fn is_error_frame(b: &[u8; CAN_MTU]) -> bool {
    u32::from_ne_bytes([b[0], b[1], b[2], b[3]]) & CAN_ERR_FLAG != 0
}

/// In time order (a late frame may land behind frames sent after it).
fn insert(q: &mut VecDeque<Wire>, at: Instant, bytes: [u8; CAN_MTU]) {
    let i = q.iter().rposition(|(t, _)| *t <= at).map_or(0, |i| i + 1);
    q.insert(i, (at, bytes));
}

impl Bus {
    /// Bits of a frame on the wire (ISO 11898-1): 47 bits of overhead for a base frame, 67 for an
    /// extended one (3 bits of intermission included), the data, and worst-case bit stuffing.
    fn bits(f: &Frame) -> u32 {
        let data = if f.rtr { 0 } else { 8 * u32::from(f.dlc.min(8)) };
        let (overhead, stuffed) = if f.extended { (67, 54 + data) } else { (47, 34 + data) };
        overhead + data + (stuffed - 1) / 4
    }

    fn send(&mut self, from: Side, f: &Frame) -> Result<(), TransportError> {
        let now = self.clock.now();
        if from == Side::Master {
            self.restart_due(now);
            if self.ctrl.is_off(now) {
                // The interface's queue is stopped while the controller is off (ENOBUFS).
                self.stats.tx_lost_off += 1;
                return Err(TransportError::Full(*f));
            }
            if self.ctrl.is_off(self.free_at.max(now)) || !self.transmit_errors(f, now) {
                // Queued behind a frame that took the controller bus-off: lost with it.
                self.stats.tx_lost_off += 1;
                return Ok(());
            }
        }
        if self.faults.frame_loss > 0.0 && self.rng.gen::<f64>() < self.faults.frame_loss {
            self.stats.lost += 1;
            return Ok(());
        }
        let mut start = self.free_at.max(now);
        if self.faults.frame_late > 0.0 && self.rng.gen::<f64>() < self.faults.frame_late {
            self.stats.late += 1;
            start += Duration::from_secs_f64(self.faults.frame_late_s);
        }
        let on_wire = self.bit * Self::bits(f);
        let end = start + on_wire;
        self.free_at = self.free_at.max(end);
        self.stats.frames += 1;
        self.stats.busy_s += on_wire.as_secs_f64();
        match from {
            Side::Master => {
                insert(&mut self.to_rack, end, kernel::encode(f));
                if self.ctrl.tec > 0 {
                    self.ctrl.tec -= 1;
                    self.report_state(end);
                }
            }
            Side::Rack if self.ctrl.is_off(end) => self.stats.rx_missed_off += 1,
            Side::Rack => insert(&mut self.to_master, end, kernel::encode(f)),
        }
        Ok(())
    }

    /// The master's frame `f` while its transmissions fail: each attempt costs its bits and an
    /// error frame and counts 8. True: the fault span ended and the frame goes out; false: bus-off.
    fn transmit_errors(&mut self, f: &Frame, now: Instant) -> bool {
        let Some((from, to)) = self.ctrl.tx_fault else { return true };
        loop {
            let start = self.free_at.max(now);
            if !(from..to).contains(&start) {
                return true;
            }
            let suspend = if self.ctrl.state >= CanState::ErrorPassive { SUSPEND_BITS } else { 0 };
            let bits = Self::bits(f) + ERROR_FRAME_BITS + suspend;
            let end = start + self.bit * bits;
            self.free_at = end;
            self.stats.busy_s += (self.bit * bits).as_secs_f64();
            self.stats.tx_errors += 1;
            self.ctrl.tec += 8;
            if self.ctrl.tec > 255 {
                self.bus_off(end);
                return false;
            }
            self.report_state(end);
        }
    }

    /// The controller goes bus-off at `at` (`can_bus_off`): what was on its way to the master
    /// is not received, and the interface restarts it after `restart-ms` if set.
    fn bus_off(&mut self, at: Instant) {
        self.ctrl.state = CanState::BusOff;
        let until = self.ctrl.restart.map(|d| at + d);
        self.ctrl.off = Some((at, until));
        self.stats.bus_offs += 1;
        let before = self.to_master.len();
        self.to_master.retain(|(t, b)| is_error_frame(b) || *t < at || until.is_some_and(|u| *t >= u));
        self.stats.rx_missed_off += (before - self.to_master.len()) as u64;
        let tec = self.ctrl.tec.min(255) as u8;
        insert(&mut self.to_master, at, kernel::error_frame(err::BUSOFF | err::CNT, [0, 0, 0, 0, 0, 0, tec, 0]));
    }

    /// A restart that is due (`restart-ms` passed, or by hand): error-active, counters at 0,
    /// `CAN_ERR_RESTARTED` reported at its instant.
    fn restart_due(&mut self, now: Instant) {
        let Some((_, Some(until))) = self.ctrl.off else { return };
        if now < until {
            return;
        }
        self.ctrl.off = None;
        self.ctrl.tec = 0;
        self.ctrl.state = CanState::ErrorActive;
        self.stats.restarts += 1;
        insert(&mut self.to_master, until, kernel::error_frame(err::RESTARTED, [0; 8]));
    }

    /// `ip link set can0 type can restart`: only a controller that is bus-off restarts.
    fn restart(&mut self, now: Instant) {
        if let Some((from, None)) = self.ctrl.off {
            self.ctrl.off = Some((from, Some(now)));
        }
        self.restart_due(now);
    }

    /// Reports a change of the error state at `at` (`can_change_state`: the counters with it).
    fn report_state(&mut self, at: Instant) {
        let new = CanState::of(self.ctrl.tec);
        if new == self.ctrl.state {
            return;
        }
        self.ctrl.state = new;
        let status = match new {
            CanState::ErrorActive => err::CRTL_ACTIVE,
            CanState::ErrorWarning => err::CRTL_TX_WARNING,
            CanState::ErrorPassive | CanState::BusOff => err::CRTL_TX_PASSIVE,
        };
        let tec = self.ctrl.tec.min(255) as u8;
        insert(&mut self.to_master, at, kernel::error_frame(err::CRTL | err::CNT, [0, status, 0, 0, 0, 0, tec, 0]));
    }

    fn queue(&mut self, to: Side) -> &mut VecDeque<Wire> {
        match to {
            Side::Master => &mut self.to_master,
            Side::Rack => &mut self.to_rack,
        }
    }

    fn next_delivery(&mut self, to: Side) -> Option<Instant> {
        self.queue(to).front().map(|(t, _)| *t)
    }

    /// The next frame due for `to`, as the receiving socket decodes it (an error frame is
    /// [`TransportError::Bus`]).
    fn recv(&mut self, to: Side) -> Option<(Instant, Result<Frame, TransportError>)> {
        let now = self.clock.now();
        if to == Side::Master {
            self.restart_due(now);
        }
        let q = self.queue(to);
        if q.front().is_some_and(|(t, _)| *t <= now) {
            q.pop_front().map(|(t, b)| (t, kernel::decode(&b)))
        } else {
            None
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// One end of the in-memory bus. The master's end advances the simulated world while it waits
/// for a frame (the drives' bring-up, before the loop runs).
pub struct LockstepCan {
    bus: Arc<Mutex<Bus>>,
    side: Side,
    world: Option<Arc<Mutex<World>>>,
    last_rx: Option<Instant>,
}

impl CanTransport for LockstepCan {
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        lock(&self.bus).send(self.side, frame)
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        match lock(&self.bus).recv(self.side) {
            Some((t, Ok(f))) => {
                self.last_rx = Some(t);
                Ok(Some(f))
            }
            Some((_, Err(e))) => Err(e),
            None => Ok(None),
        }
    }

    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        loop {
            if let Some(f) = self.try_recv()? {
                return Ok(Some(f));
            }
            let (now, next, clock) = {
                let mut b = lock(&self.bus);
                (b.clock.now(), b.next_delivery(self.side), b.clock.clone())
            };
            if now >= deadline {
                return Ok(None);
            }
            let to = next.map_or(deadline, |t| t.min(deadline)).max(now);
            match &self.world {
                Some(w) => lock(w).advance_to(to),
                None => clock.advance_to(to),
            }
            if clock.now() == now && to == now {
                // A frame is due but not taken (cannot happen with one reader): step, not spin.
                clock.advance(Duration::from_micros(1));
            }
        }
    }

    fn iface(&self) -> taut_driver::transport::IfName {
        taut_driver::transport::IfName::new("simcan")
    }

    fn rx_timestamp(&self) -> Option<Instant> {
        self.last_rx
    }
}

/// The load-cell line's clock during one transaction: it starts where the transaction starts on
/// the line and runs ahead as the bytes take their time.
struct LineClock(Mutex<Instant>);

impl LineClock {
    fn at(t: Instant) -> LineClock {
        LineClock(Mutex::new(t))
    }

    fn advance(&self, d: Duration) {
        *lock(&self.0) += d;
    }

    fn advance_to(&self, t: Instant) {
        let mut now = lock(&self.0);
        *now = (*now).max(t);
    }
}

impl Clock for LineClock {
    fn now(&self) -> Instant {
        *lock(&self.0)
    }

    fn sleep(&self, d: Duration) {
        self.advance(d);
    }
}

/// The tensions at the load cells at the plant's last steps: a cell answers with the tension of
/// the step nearest the instant its request reached it. Not interpolated: that would average
/// away the cells' noise, drawn at each step.
struct PlantTensions {
    n: usize,
    steps: VecDeque<(Instant, [f64; MAX_CABLES])>,
}

impl PlantTensions {
    /// Steps kept: a cycle's and its neighbours', with the world's 1 ns re-steps among them.
    const KEEP: usize = 8;

    fn new(n: usize) -> PlantTensions {
        PlantTensions { n: n.min(MAX_CABLES), steps: VecDeque::with_capacity(Self::KEEP) }
    }

    /// The plant's tensions (`handle`) after its step at `at`.
    fn record(&mut self, at: Instant, handle: &TensionHandle) {
        if self.steps.len() == Self::KEEP {
            self.steps.pop_front();
        }
        let mut t = [0.0; MAX_CABLES];
        for (i, x) in t.iter_mut().enumerate().take(self.n) {
            *x = handle.get(i);
        }
        self.steps.push_back((at, t));
    }

    /// Sets `out` to the tensions of the step nearest `at` (the earlier of two as near).
    fn set_at(&self, at: Instant, out: &TensionHandle) {
        let dist = |t: Instant| if t >= at { t - at } else { at - t };
        let Some((_, step)) = self.steps.iter().fold(None, |best: Option<&(Instant, [f64; MAX_CABLES])>, s| match best {
            Some(b) if dist(b.0) <= dist(s.0) => Some(b),
            _ => Some(s),
        }) else {
            return;
        };
        for (i, v) in step.iter().enumerate().take(self.n) {
            out.set(i, *v);
        }
    }
}

/// The load-cell line in memory: request and answer take their character times, and the
/// addressed cell answers after its latency with the tension when the request reached it.
struct Line<'a> {
    cells: &'a mut LoadCellResponder,
    /// What the cells read (the responder's tensions) and where it comes from.
    reads: &'a TensionHandle,
    plant: &'a PlantTensions,
    clock: &'a LineClock,
    char_time: Duration,
    latency: Duration,
    /// The cells do not answer requests sent in this span.
    silence: Option<(Instant, Instant)>,
    answer: Option<(Instant, [u8; 2 * taut_proto::modbus::rtu::MAX_FRAME], usize)>,
}

impl SerialLink for Line<'_> {
    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.clock.advance(self.char_time * frame.len() as u32);
        let now = self.clock.now();
        let silent = self.silence.is_some_and(|(from, to)| (from..to).contains(&now));
        if !silent {
            self.plant.set_at(now, self.reads);
        }
        self.answer = if silent { None } else { self.cells.answer(frame).map(|(b, n)| (self.clock.now() + self.latency, b, n)) };
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        let now = self.clock.now();
        match self.answer.take() {
            Some((at, bytes, n)) if at <= now + timeout => {
                let n = n.min(buf.len());
                buf[..n].copy_from_slice(&bytes[..n]);
                self.clock.advance_to(at.max(now) + self.char_time * n as u32);
                Ok(n)
            }
            other => {
                self.answer = other;
                self.clock.advance(timeout);
                Ok(0)
            }
        }
    }

    fn discard_input(&mut self) -> Result<(), LinkError> {
        self.answer = None;
        Ok(())
    }
}

/// The load-cell side in lockstep: the robot's stepped bus and the cells' answering code.
struct Cells {
    bus: SteppedLoadCells,
    responder: LoadCellResponder,
    /// The tensions the responder reads, set for each request from `plant`.
    reads: TensionHandle,
    plant: PlantTensions,
    char_time: Duration,
    /// When the next polling round starts.
    next_round: Instant,
    /// When the round under way started.
    round_start: Instant,
    /// The transaction under way: its start on the line, and when its request reaches the cell.
    tx: Option<(Instant, Instant)>,
    silenced: bool,
}

impl Cells {
    /// The next instant the line has work: the request under way reaching its cell, or the
    /// next round's start.
    fn next_event(&self) -> Instant {
        self.tx.map_or(self.next_round, |(_, at)| at)
    }

    /// The line's work due at `now`, one transaction after the other: a transaction whose request
    /// has reached its cell by `now` is run (the plant has been stepped up to it), its answer takes
    /// its time on the line, and the next starts where it ended.
    fn advance(&mut self, now: Instant, silence: Option<(Instant, Instant)>) {
        if self.tx.is_none() && now >= self.next_round {
            self.round_start = now;
            self.tx = Some((now, self.bus.request_complete_at(now)));
        }
        while let Some((start, at)) = self.tx {
            if at > now {
                break;
            }
            let clock = LineClock::at(start);
            let mut line = Line {
                cells: &mut self.responder,
                reads: &self.reads,
                plant: &self.plant,
                clock: &clock,
                char_time: self.char_time,
                latency: CELL_LATENCY,
                silence,
                answer: None,
            };
            let over = self.bus.transaction(&mut line, &clock);
            let end = clock.now();
            self.tx = if over {
                self.next_round = (self.round_start + self.bus.poll_period()).max(end);
                None
            } else {
                Some((end, self.bus.request_complete_at(end)))
            };
        }
        self.bus.release(now);
    }
}

/// Everything outside the robot's computer, advanced event by event.
pub(crate) struct World {
    site: Site<LockstepCan>,
    clock: SimClock,
    t0: Instant,
    bus: Arc<Mutex<Bus>>,
    next_tick: Instant,
    cells: Cells,
    receiver: Option<TrackerReceiver>,
    next_pose: Instant,
    tracker_gap_until: Option<Instant>,
    faults: LockstepFaults,
    rng: ChaCha8Rng,
    /// Faults to apply, in time order.
    schedule: VecDeque<(Instant, SimFault)>,
}

/// How long a simulated drive stays in FAULT REACTION ACTIVE before FAULT: its fault reaction
/// (motor stopped, brake applied), tens of milliseconds on real drives.
const FAULT_REACTION: Duration = Duration::from_millis(20);

/// A Modbus device's time from the end of a request to the start of its answer.
const CELL_LATENCY: Duration = Duration::from_millis(1);

impl World {
    /// Handles every event up to `t`, in time order, and leaves the clock at `t`.
    pub(crate) fn advance_to(&mut self, t: Instant) {
        loop {
            let now = self.clock.now();
            self.handle_due(now);
            match self.next_event() {
                Some(e) if e <= t => self.clock.advance_to(e.max(now + Duration::from_nanos(1))),
                _ => break,
            }
        }
        self.clock.advance_to(t);
        self.handle_due(t.max(self.clock.now()));
    }

    fn next_event(&mut self) -> Option<Instant> {
        let bus = lock(&self.bus).next_delivery(Side::Rack);
        let fault = self.schedule.front().map(|(t, _)| *t);
        [bus, self.site.rack.next_deadline(), Some(self.next_tick), Some(self.cells.next_event()), self.cells.bus.next_release(), fault]
            .into_iter()
            .flatten()
            .chain(self.receiver.is_some().then_some(self.next_pose))
            .min()
    }

    fn handle_due(&mut self, now: Instant) {
        while self.schedule.front().is_some_and(|(t, _)| *t <= now) {
            let (at, f) = self.schedule.pop_front().expect("checked");
            self.apply(at, f);
        }
        while let Ok(Some(f)) = self.site.rack.transport().try_recv() {
            self.site.on_frame(&f);
        }
        self.site.rack.step(now);
        if now >= self.next_tick {
            self.next_tick += self.site.period;
            self.site.inject_faults();
            if self.site.silenced && !self.cells.silenced {
                self.cells.responder.inject(None, LoadCellFault::Silence, u32::MAX);
                self.cells.silenced = true;
            }
            self.site.step_plant(now);
            self.cells.plant.record(now, &self.site.handle);
        }
        let t0 = self.t0;
        let silence =
            self.faults.loadcell_silence.map(|(from, dur)| (t0 + Duration::from_secs_f64(from), t0 + Duration::from_secs_f64(from + dur)));
        self.cells.advance(now, silence);
        if now >= self.next_pose {
            self.next_pose += Duration::from_secs_f64(TRACKER_PERIOD_S);
            self.pose(now);
        }
    }

    /// Puts `fault` on the schedule at `at` (in time order; after those at the same instant).
    fn schedule(&mut self, at: Instant, fault: SimFault) {
        let i = self.schedule.iter().rposition(|(t, _)| *t <= at).map_or(0, |i| i + 1);
        self.schedule.insert(i, (at, fault));
    }

    /// Applies a scheduled fault at its instant `at`.
    fn apply(&mut self, at: Instant, fault: SimFault) {
        let n = self.site.rack.drives().len();
        let drive = |cable: usize| {
            assert!(cable < n, "{fault:?}: the robot has {n} cables");
            cable
        };
        match fault {
            SimFault::MasterTxErrors { for_s } => {
                lock(&self.bus).ctrl.tx_fault = Some((at, at + Duration::from_secs_f64(for_s.max(0.0))));
            }
            SimFault::CanRestart => lock(&self.bus).restart(at),
            SimFault::DriveFault { cable, code } => self.site.rack.drives()[drive(cable)].inject_fault(code),
            SimFault::DrivePowerCycle { cable } => self.site.rack.drives()[drive(cable)].power_cycle(),
            SimFault::HeartbeatLoss { cable, for_s } => {
                self.site.rack.drives()[drive(cable)].set_heartbeat_off(true);
                if for_s.is_finite() {
                    self.schedule(at + Duration::from_secs_f64(for_s.max(0.0)), SimFault::HeartbeatBack { cable });
                }
            }
            SimFault::HeartbeatBack { cable } => self.site.rack.drives()[drive(cable)].set_heartbeat_off(false),
        }
    }

    fn pose(&mut self, now: Instant) {
        let Some(rx) = self.receiver.as_mut() else { return };
        if self.site.faults.tracker_gone.load(Ordering::Relaxed) {
            return;
        }
        if self.tracker_gap_until.is_some_and(|u| now < u) {
            return;
        }
        if self.faults.tracker_dropout > 0.0 && self.rng.gen::<f64>() < self.faults.tracker_dropout {
            self.tracker_gap_until = Some(now + Duration::from_secs_f64(self.faults.tracker_gap_s));
            return;
        }
        let Some(tracker) = self.site.tracker.as_mut() else { return };
        let m = tracker.measure(self.site.plant.position(), &mut self.site.rng);
        if m.iter().all(|v| v.is_finite()) {
            let t = now.saturating_duration_since(self.t0).as_secs_f64();
            let mut buf = [0u8; MAX_LINE];
            let n = format_line(&PoseLine { t, position: m, orientation: None }, &mut buf);
            rx.on_datagram(&buf[..n], now);
        }
    }
}

/// The robot's devices with the world they talk to: each read first lets the world catch up to
/// the clock.
struct LockstepDevices {
    devices: RobotDevices<LockstepCan>,
    world: Arc<Mutex<World>>,
    clock: SimClock,
}

impl Devices for LockstepDevices {
    fn read(&mut self, now_s: f64, inputs: &mut Inputs) {
        lock(&self.world).advance_to(self.clock.now());
        self.devices.read(now_s, inputs)
    }
    fn write(&mut self, now_s: f64, outputs: &Outputs) {
        self.devices.write(now_s, outputs)
    }
}

/// A simulated robot in simulated time, ready for the plugin.
pub struct LockstepRobot {
    /// The site's true parameters (never seen by the robot).
    pub truth: Truth,
    /// Fault switches (as [`crate::SimRobot::faults`]).
    pub faults: Arc<SimFaults>,
    /// The devices for the plugin.
    pub devices: Box<dyn Devices>,
    /// The simulated clock everything runs on.
    pub clock: SimClock,
    /// Where the platform really is.
    pub platform: PlatformTruth,
    /// The tracker receiver's counters.
    pub tracker_stats: Option<TrackerStatsHandle>,
    bus: Arc<Mutex<Bus>>,
    world: Arc<Mutex<World>>,
}

impl LockstepRobot {
    /// Builds the robot of `cfg` with the platform at `p0` on a fresh simulated clock and
    /// brings its drives up through the CANopen master (in simulated time).
    pub fn build(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions, faults: LockstepFaults) -> Result<LockstepRobot, BuildError> {
        let n = cfg.cables.len();
        let clock = SimClock::new();
        let t0 = clock.now();
        let parts = draw_site(cfg, p0, opts)?;
        let truth = parts.truth.clone();
        let bitrate = cfg.can.as_ref().map_or(1_000_000, |c| c.bitrate).max(10_000);
        let bus = Arc::new(Mutex::new(Bus {
            clock: clock.clone(),
            bit: Duration::from_nanos(1_000_000_000 / u64::from(bitrate)),
            free_at: t0,
            to_rack: VecDeque::new(),
            to_master: VecDeque::new(),
            faults: faults.clone(),
            rng: taut_sim::rng(opts.seed, 11),
            stats: BusStats::default(),
            ctrl: Controller {
                tec: 0,
                state: CanState::ErrorActive,
                off: None,
                restart: faults.can_restart_ms.map(|ms| Duration::from_millis(u64::from(ms))),
                tx_fault: None,
            },
        }));
        let rack_end = LockstepCan { bus: bus.clone(), side: Side::Rack, world: None, last_rx: None };
        let mut lc_bus = cfg.loadcells.clone().unwrap_or_else(|| LoadCellBusConfig::new("simulated line"));
        lc_bus.max_age_s = cfg.safety.tension_max_age_s;
        let (stepped, loadcells, reader) = SteppedLoadCells::new(&lc_bus, &parts.cells, n).map_err(BuildError::LoadCells)?;
        let bits = 1 + u32::from(lc_bus.data_bits) + u32::from(lc_bus.parity != Parity::None) + u32::from(lc_bus.stop_bits);
        let char_time = Duration::from_secs_f64(f64::from(bits) / f64::from(lc_bus.baud.max(1)));
        let reads = TensionHandle::new(n);
        let responder = LoadCellResponder::new(parts.cells.iter().map(|c| c.1.clone()).collect(), reads.clone());
        let mut plant_tensions = PlantTensions::new(n);
        plant_tensions.record(t0, &parts.handle);
        let (receiver, pose) = if opts.tracker {
            let mut tcfg = TrackerConfig::new("127.0.0.1:0");
            tcfg.max_age_s = cfg.safety.tracker_max_age_s;
            let rx = TrackerReceiver::detached(&tcfg, t0).map_err(|e| BuildError::Device { what: "tracker receiver", error: e })?;
            let reader = rx.reader();
            (Some(rx), Some(reader))
        } else {
            (None, None)
        };
        let tracker_stats = pose.as_ref().map(|p| p.stats_handle());
        let io = SiteIo { rack_bus: rack_end, vlc: None, sender: None, clock: Arc::new(clock.clone()), now: t0 };
        let mut site = parts.into_site(io, opts);
        for d in site.rack.drives() {
            d.set_fault_reaction(FAULT_REACTION);
        }
        let (sim_faults, platform) = (site.faults.clone(), site.platform.clone());
        let world = Arc::new(Mutex::new(World {
            next_tick: t0,
            site,
            clock: clock.clone(),
            t0,
            bus: bus.clone(),
            cells: Cells {
                bus: stepped,
                responder,
                reads,
                plant: plant_tensions,
                char_time,
                next_round: t0,
                round_start: t0,
                tx: None,
                silenced: false,
            },
            receiver,
            next_pose: t0,
            tracker_gap_until: None,
            faults,
            rng: taut_sim::rng(opts.seed, 13),
            schedule: VecDeque::new(),
        }));
        {
            let mut w = lock(&world);
            for &(at_s, f) in &w.faults.scheduled.clone() {
                w.schedule(t0 + Duration::from_secs_f64(at_s.max(0.0)), f);
            }
        }
        let master_end = LockstepCan { bus: bus.clone(), side: Side::Master, world: Some(world.clone()), last_rx: None };
        let peripherals = Peripherals { loadcells: Some((loadcells, reader)), tracker: None, pose };
        let devices =
            RobotDevices::bring_up_with_clock(cfg, master_end, peripherals, Arc::new(clock.clone())).map_err(BuildError::BringUp)?;
        Ok(LockstepRobot {
            truth,
            faults: sim_faults,
            devices: Box::new(LockstepDevices { devices, world: world.clone(), clock: clock.clone() }),
            clock,
            platform,
            tracker_stats,
            bus,
            world,
        })
    }
}

/// What a start-up in simulated time runs with, beside the robot and the site.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Faults the devices and wires inject.
    pub faults: LockstepFaults,
    /// Where the calibrator records.
    pub recording: RecordingPath,
    /// The most simulated time the start-up may take, s.
    pub budget_s: f64,
}

impl Default for RunOptions {
    /// No faults, no recording, 600 s.
    fn default() -> Self {
        RunOptions { faults: LockstepFaults::default(), recording: RecordingPath::Off, budget_s: 600.0 }
    }
}

/// How a start-up in simulated time ended.
pub struct StartupRun {
    /// The loop's last status.
    pub loop_status: LoopStatus,
    /// The calibrator's last status.
    pub calib_status: CalibStatus,
    /// The site's truth.
    pub truth: Truth,
    /// The start-up finished (well or badly) within the budget.
    pub finished: bool,
    /// Loop cycles run (activation included).
    pub cycles: u64,
    /// Simulated time, s.
    pub sim_s: f64,
    /// Wall-clock time the run took, s (not reproducible).
    pub wall_s: f64,
    /// The simulated CAN bus's counts.
    pub bus: BusStats,
    /// The robot's load-cell bus counters.
    pub loadcells: taut_driver::modbus::master::CounterSnapshot,
    /// Plant steps that found no equilibrium.
    pub plant_failed_steps: u64,
    /// Where the recording is, if any.
    pub recording: Option<std::path::PathBuf>,
}

/// Why a start-up in simulated time could not run.
#[derive(Debug)]
pub enum LockstepError {
    /// The simulated robot could not be built.
    Build(BuildError),
    /// The plugin refused (configuration, activation).
    Plugin(PluginError),
}

impl std::fmt::Display for LockstepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LockstepError::Build(e) => write!(f, "{e}"),
            LockstepError::Plugin(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for LockstepError {}

/// The plugin on the simulated robot in simulated time, stepped by its owner: a host like the
/// robot's controller, with the operator's handle ([`Lockstep::handle`]) for commands between
/// cycles. [`run_startup`] is the start-up on it.
pub struct Lockstep {
    plugin: Plugin,
    clock: SimClock,
    period: Duration,
    cycles: u64,
    truth: Truth,
    faults: Arc<SimFaults>,
    platform: PlatformTruth,
    bus: Arc<Mutex<Bus>>,
    world: Arc<Mutex<World>>,
    recording: Option<std::path::PathBuf>,
    wall: Instant,
}

impl Lockstep {
    /// Builds the robot of `cfg` with the platform at `p0`, configures the plugin on it
    /// (plugin-owned devices, the calibrator stepped inline) and activates it: the drives are
    /// enabled, the start-up begins with the next cycle.
    pub fn start(
        cfg: &RobotConfig,
        p0: [f64; 3],
        opts: &SimOptions,
        run: RunOptions,
        backend: Box<dyn Calibrate>,
    ) -> Result<Lockstep, LockstepError> {
        let wall = Instant::now();
        let robot = LockstepRobot::build(cfg, p0, opts, run.faults).map_err(LockstepError::Build)?;
        let LockstepRobot { truth, faults, devices, clock, platform, bus, world, .. } = robot;
        let popts = PluginOptions { recording: run.recording, backend: Some(backend), event_capacity: 256, sim_clock: Some(clock.clone()) };
        let mut plugin = Plugin::configure(cfg, DeviceMode::ready(devices), popts).map_err(LockstepError::Plugin)?;
        let recording = plugin.recording().map(|p| p.to_path_buf());
        plugin.activate().map_err(LockstepError::Plugin)?;
        let period = Duration::from_secs_f64(1.0 / plugin.rate_hz());
        Ok(Lockstep { plugin, clock, period, cycles: 0, truth, faults, platform, bus, world, recording, wall })
    }

    /// One loop cycle: the clock advances by one period, the plugin reads, computes and writes,
    /// the calibrator does its share. True when the controller has finished (stopped).
    pub fn cycle(&mut self) -> bool {
        self.clock.advance(self.period);
        let tick = self.plugin.update(self.sim_s(), self.period.as_secs_f64());
        self.plugin.pump_calibrator();
        self.cycles += 1;
        tick.is_ok_and(|t| t.finished)
    }

    /// Runs cycles until `done` holds (checked every 0.1 s of simulated time) or `max_s` of
    /// simulated time have passed or the controller has finished; true if `done` held.
    pub fn run_until(&mut self, max_s: f64, mut done: impl FnMut(&LoopStatus, &CalibStatus) -> bool) -> bool {
        let every = ((0.1 / self.period.as_secs_f64()).round() as u64).max(1);
        let end = self.sim_s() + max_s;
        while self.sim_s() < end {
            let finished = self.cycle();
            if finished || self.cycles.is_multiple_of(every) {
                if done(&self.loop_status(), &self.calib_status()) {
                    return true;
                }
                if finished {
                    return false;
                }
            }
        }
        false
    }

    /// Runs cycles for `s` of simulated time.
    pub fn run_for(&mut self, s: f64) {
        self.run_until(s, |_, _| false);
    }

    /// Injects `fault` now; the world applies it at the next cycle's read.
    pub fn inject(&mut self, fault: SimFault) {
        let now = self.clock.now();
        lock(&self.world).schedule(now, fault);
    }

    /// Injects `fault` at the simulated time `at_s` (s since the start; now if that has passed).
    pub fn inject_at(&mut self, at_s: f64, fault: SimFault) {
        let mut w = lock(&self.world);
        let at = self.clock.now().max(w.t0 + Duration::from_secs_f64(at_s.max(0.0)));
        w.schedule(at, fault);
    }

    /// The master's CAN controller now.
    pub fn can(&self) -> CanStatus {
        let mut b = lock(&self.bus);
        let now = b.clock.now();
        b.restart_due(now);
        let state = if b.ctrl.is_off(now) { CanState::BusOff } else { b.ctrl.state };
        CanStatus { state, tec: b.ctrl.tec }
    }

    /// The simulated CAN bus's counts so far.
    pub fn bus_stats(&self) -> BusStats {
        lock(&self.bus).stats
    }

    /// Simulated time since the start, s.
    pub fn sim_s(&self) -> f64 {
        self.clock.elapsed().as_secs_f64()
    }

    /// The operator's handle: commands, recalibration, stop, status.
    pub fn handle(&self) -> &taut_plugin::PluginHandle {
        self.plugin.handle()
    }

    /// The loop's status now.
    pub fn loop_status(&self) -> LoopStatus {
        self.plugin.handle().loop_status()
    }

    /// The calibrator's status now.
    pub fn calib_status(&self) -> CalibStatus {
        self.plugin.handle().calib_status()
    }

    /// The site's truth (never seen by the robot).
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// The simulated devices' fault switches.
    pub fn faults(&self) -> &SimFaults {
        &self.faults
    }

    /// Where the platform really is.
    pub fn platform(&self) -> &PlatformTruth {
        &self.platform
    }

    /// The calibrator's recording, if any.
    pub fn recording(&self) -> Option<&std::path::Path> {
        self.recording.as_deref()
    }

    /// Stops the plugin (the controller's stop cycles, the calibrator's last work) and reports.
    pub fn finish(mut self, finished: bool) -> StartupRun {
        let loop_status = self.loop_status();
        let calib_status = self.calib_status();
        let sim_s = self.sim_s();
        let _ = self.plugin.deactivate();
        let _ = self.plugin.cleanup();
        let bus = lock(&self.bus).stats;
        let loadcells = lock(&self.world).cells.bus.counters();
        StartupRun {
            loop_status,
            calib_status,
            truth: self.truth,
            finished,
            cycles: self.cycles,
            sim_s,
            wall_s: self.wall.elapsed().as_secs_f64(),
            bus,
            loadcells,
            plant_failed_steps: self.faults.plant_failed_steps.load(Ordering::Relaxed),
            recording: self.recording,
        }
    }
}

/// Runs the start-up of `cfg` (three-phase initialisation, excitation or dwell poses,
/// calibration, hot-swap) on the simulated robot in simulated time, `run.budget_s` of simulated
/// time at most. `on_check` sees the loop's and the calibrator's status every 0.1 s of
/// simulated time and may end the run early by returning true.
pub fn run_startup(
    cfg: &RobotConfig,
    p0: [f64; 3],
    opts: &SimOptions,
    run: RunOptions,
    backend: Box<dyn Calibrate>,
    mut on_check: impl FnMut(&LoopStatus, &CalibStatus) -> bool,
) -> Result<StartupRun, LockstepError> {
    let budget_s = run.budget_s;
    let mut host = Lockstep::start(cfg, p0, opts, run, backend)?;
    let mut over = false;
    host.run_until(budget_s, |l, c| {
        over = taut_operator::control::startup_finished(l, c);
        over || on_check(l, c)
    });
    Ok(host.finish(over))
}

#[cfg(test)]
mod tests {
    use super::*;
    use taut_driver::transport::BusEvent;

    fn bus(restart_ms: Option<u32>) -> Bus {
        let clock = SimClock::new();
        let t0 = clock.now();
        Bus {
            clock,
            bit: Duration::from_micros(1),
            free_at: t0,
            to_rack: VecDeque::new(),
            to_master: VecDeque::new(),
            faults: LockstepFaults::default(),
            rng: taut_sim::rng(1, 11),
            stats: BusStats::default(),
            ctrl: Controller {
                tec: 0,
                state: CanState::ErrorActive,
                off: None,
                restart: restart_ms.map(|ms| Duration::from_millis(u64::from(ms))),
                tx_fault: None,
            },
        }
    }

    /// Everything the master's socket has received by now, decoded.
    fn drain(b: &mut Bus) -> Vec<Result<Frame, TransportError>> {
        std::iter::from_fn(|| b.recv(Side::Master).map(|(_, r)| r)).collect()
    }

    fn bus_events(v: &[Result<Frame, TransportError>]) -> Vec<BusEvent> {
        v.iter().filter_map(|r| if let Err(TransportError::Bus(e)) = r { Some(*e) } else { None }).collect()
    }

    /// A burst of transmit errors shorter than bus-off: the counter climbs by 8 per attempt
    /// through error warning (96) to error-passive (128, 16 attempts), and comes back down one
    /// frame sent at a time: warning at 127, error-active at 95.
    #[test]
    fn a_burst_of_transmit_errors_reaches_error_passive_and_comes_back() {
        let mut b = bus(Some(100));
        let t0 = b.clock.now();
        let f = Frame::new(0x201, &[0; 8]);
        // 16 attempts of 135 + 14 bits at 1 us: the 17th starts at 2.384 ms.
        b.ctrl.tx_fault = Some((t0, t0 + Duration::from_micros(2300)));
        b.send(Side::Master, &f).unwrap();
        assert_eq!((b.stats.tx_errors, b.ctrl.tec, b.ctrl.state), (16, 127, CanState::ErrorWarning), "sent at the 17th attempt");
        assert_eq!(b.to_rack.len(), 1);
        for k in 0..32 {
            b.clock.advance(Duration::from_micros(200));
            b.send(Side::Master, &f).unwrap();
            assert_eq!(b.ctrl.state == CanState::ErrorActive, k == 31, "{k}: TEC {}", b.ctrl.tec);
        }
        b.clock.advance(Duration::from_millis(1));
        let got = drain(&mut b);
        assert_eq!(
            bus_events(&got),
            [
                BusEvent::ErrorWarning { tx: 96, rx: 0 },
                BusEvent::ErrorPassive { tx: 128, rx: 0 },
                BusEvent::ErrorWarning { tx: 127, rx: 0 },
                BusEvent::ErrorActive
            ]
        );
        assert_eq!(b.ctrl.tec, 95);
    }

    /// A fault that lasts: warning at 96, error-passive at 128, bus-off past 255, each reported
    /// as the kernel does; nothing received or sent while off; restarted after `restart-ms`.
    #[test]
    fn transmit_errors_take_the_controller_bus_off_and_restart_ms_brings_it_back() {
        let mut b = bus(Some(100));
        let t0 = b.clock.now();
        let f = Frame::new(0x201, &[0; 8]);
        b.ctrl.tx_fault = Some((t0, t0 + Duration::from_secs(1)));
        // The drive's frame before the fault is received; the master's frame goes bus-off, and
        // the one behind it in the queue is lost with it.
        b.send(Side::Rack, &Frame::new(0x181, &[1])).unwrap();
        b.send(Side::Master, &f).unwrap();
        b.send(Side::Master, &f).unwrap();
        assert_eq!((b.stats.tx_errors, b.stats.bus_offs, b.stats.tx_lost_off), (32, 1, 2));
        assert!(b.to_rack.is_empty(), "nobody received a failed frame");
        b.clock.advance(Duration::from_millis(10));
        assert_eq!(b.send(Side::Master, &f), Err(TransportError::Full(f)), "ENOBUFS while off");
        b.send(Side::Rack, &Frame::new(0x181, &[2])).unwrap();
        let got = drain(&mut b);
        assert_eq!(got[0], Ok(Frame::new(0x181, &[1])));
        assert_eq!(
            bus_events(&got),
            [BusEvent::ErrorWarning { tx: 96, rx: 0 }, BusEvent::ErrorPassive { tx: 128, rx: 0 }, BusEvent::BusOff]
        );
        assert_eq!(got.len(), 4, "the drive's frame sent while off is not received: {got:?}");
        assert_eq!(b.stats.rx_missed_off, 1);
        // restart-ms: back 100 ms after the bus-off, counters at 0; the fault still there, the
        // next frame takes it bus-off again.
        b.clock.advance(Duration::from_millis(100));
        assert_eq!(bus_events(&drain(&mut b)), [BusEvent::Restarted]);
        assert_eq!((b.ctrl.tec, b.ctrl.state), (0, CanState::ErrorActive));
        b.send(Side::Master, &f).unwrap();
        assert_eq!(b.stats.bus_offs, 2);
        // After the fault: restarted, and frames go through.
        b.clock.advance(Duration::from_secs(1));
        assert_eq!(bus_events(&drain(&mut b)).last(), Some(&BusEvent::Restarted));
        b.send(Side::Master, &f).unwrap();
        assert_eq!(b.to_rack.len(), 1);
        assert_eq!((b.stats.restarts, b.ctrl.tec), (2, 0));
    }

    /// Without `restart-ms` only a restart by hand brings it back; a restart of a controller
    /// that is not bus-off does nothing.
    #[test]
    fn without_restart_ms_the_controller_stays_off_until_restarted_by_hand() {
        let mut b = bus(None);
        let t0 = b.clock.now();
        b.restart(t0);
        assert!(drain(&mut b).is_empty(), "EBUSY: not bus-off");
        b.ctrl.tx_fault = Some((t0, t0 + Duration::from_millis(10)));
        b.send(Side::Master, &Frame::new(0x80, &[])).unwrap();
        b.clock.advance(Duration::from_secs(10));
        assert_eq!(bus_events(&drain(&mut b)).last(), Some(&BusEvent::BusOff));
        assert!(b.ctrl.is_off(b.clock.now()));
        let now = b.clock.now();
        b.restart(now);
        assert_eq!(bus_events(&drain(&mut b)), [BusEvent::Restarted]);
        b.send(Side::Master, &Frame::new(0x80, &[])).unwrap();
        assert_eq!((b.to_rack.len(), b.stats.restarts), (1, 1));
    }

    /// A polling round on a ramped tension, at 2 ms cycles: each cell answers with the plant's
    /// tension nearest the instant its request reached it, and its reading reaches the loop at the
    /// first cycle after its answer (8 characters, latency, 9 characters, t3.5 between).
    #[test]
    fn each_cell_answers_with_the_tension_of_its_request_and_arrives_at_its_answer() {
        use taut_proto::devices::LoadCellConfig;
        const N: usize = 4;
        let bus_cfg = LoadCellBusConfig::new("simulated line");
        let cells: Vec<(usize, LoadCellConfig)> = (0..N).map(|i| (i, LoadCellConfig::new(i as u8 + 1))).collect();
        let (stepped, _io, mut reader) = SteppedLoadCells::new(&bus_cfg, &cells, N).unwrap();
        let plant = TensionHandle::new(N);
        let reads = TensionHandle::new(N);
        let responder = LoadCellResponder::new(cells.iter().map(|c| c.1.clone()).collect(), reads.clone());
        let timing = taut_driver::modbus::master::MasterConfig::from_bus(&bus_cfg).timing;
        let t0 = Instant::now();
        let mut c = Cells {
            bus: stepped,
            responder,
            reads,
            plant: PlantTensions::new(N),
            char_time: timing.char_time,
            next_round: t0,
            round_start: t0,
            tx: None,
            silenced: false,
        };
        // 10 kN/s from 100 N, a different tension on each cable; the cells report whole newtons.
        let ramp = |k: usize, t: Instant| 100.0 * (k + 1) as f64 + 1e4 * (t - t0).as_secs_f64();
        let cycle = Duration::from_millis(2);
        let mut got: Vec<(usize, f64, Instant, Instant)> = Vec::new();
        let mut now = t0;
        while now < t0 + Duration::from_millis(100) {
            for k in 0..N {
                plant.set(k, ramp(k, now));
            }
            c.plant.record(now, &plant);
            c.advance(now, None);
            reader.update();
            for k in 0..N {
                if let Some((v, t)) = reader.latest(k) {
                    if got.iter().rev().find(|g| g.0 == k).is_none_or(|g| g.2 != t) {
                        got.push((k, v, t, now));
                    }
                }
            }
            now += cycle;
        }
        let (request, answer) = (timing.frame_time(8), timing.frame_time(9));
        assert!(got.len() >= 3 * N, "{} readings", got.len());
        for (i, &(k, v, t, seen)) in got.iter().enumerate() {
            assert_eq!(k, i % N, "the cells in order");
            assert!(seen >= t && seen < t + cycle, "reading {i}: seen at the first cycle after its answer");
            let reached = t - answer - CELL_LATENCY;
            let start = reached - request;
            match i {
                0 => assert_eq!(start, t0),
                _ if i % N == 0 => assert!(
                    start >= got[i - 1].2 && start < got[i - 1].2 + cycle,
                    "reading {i}: a round starts at the cycle after the last"
                ),
                _ => assert_eq!(start, got[i - 1].2 + timing.t35, "reading {i}: one transaction after the other"),
            }
            let nearest = t0 + cycle * ((reached - t0).as_secs_f64() / cycle.as_secs_f64() - 1e-9).round() as u32;
            let want = ramp(k, nearest);
            assert!(
                (v - want).abs() <= 0.5,
                "reading {i} of cell {k}: {v} N, the plant's step nearest its request's instant had {want:.1} N"
            );
        }
    }
}
