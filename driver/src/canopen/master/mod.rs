//! The CANopen master: one sans-IO state machine for all drives of the robot.
//!
//! ```text
//!            boot-up / heartbeat           all SDO steps done          heartbeat "operational"
//! Waiting ──────────────────────> Configuring ──────────> Starting ──────────────────> Operational
//!    ^                              │  identity 0x1000, 0x1018, 0x1008 (uploads)          │
//!    │   boot-up again (reboot) ────┤  0x1017 heartbeat, PDO mapping, 0x6060 (downloads)  │
//!    │                              v                                                     v
//!    └──────────────────────── Failed (abort/mismatch)        Lost (heartbeat timeout) <──┘
//! ```
//! A boot-up in any phase restarts configuration (the node lost its PDO mapping), and a lost node
//! that comes back is configured again. After the master's own NMT reset communication only the
//! boot-up starts configuration (a heartbeat can predate the reset); a node that never boots is
//! configured after [`MasterConfig::boot_wait`]. Configuration switches off a drive found
//! powered and sets the drive's supervision of the master ([`Supervision`]: 0x1016, 0x6007).
//! Per SYNC cycle the master sends SYNC and one RPDO set per operational drive; drives answer
//! with their TPDOs.
//!
//! Bad input never panics: frames that are malformed, from unknown nodes or not meant for a
//! master are counted in [`Counters`]; the first of each kind is reported once as
//! [`NodeEvent::FirstOfKind`].

mod config;
mod cycle;
mod events;
mod node;
mod script;

pub use config::{ConfigProblem, MasterConfig, NodeConfig, ObjectUse, Supervision, Use};
pub use cycle::{CommandError, Operational};
pub use events::{Counters, NodeEvent, Problem};
pub use node::{Axis, Identity, NodeFailure, NodeStatus, Phase};

use crate::transport::BusEvent;
use node::Node;
use std::time::{Duration, Instant};
use taut_proto::can::Frame;
use taut_proto::canopen::cia402::{PowerState, Want};
use taut_proto::canopen::emcy;
use taut_proto::canopen::heartbeat;
use taut_proto::canopen::nmt::{self, NmtCommand, NmtState};
use taut_proto::canopen::sdo::SdoDiscard;
use taut_proto::canopen::sync::SyncProducer;
use taut_proto::canopen::{function_code, node_of, NodeId};

/// Capacity of the transmit queue, frames.
pub const TX_QUEUE: usize = 256;
/// Capacity of the event queue.
pub const EVENT_QUEUE: usize = 128;
/// How long a node heard after taut's reset communication may take to boot (CiA 301 leaves the
/// reset time to the device; drives take milliseconds to a few hundred).
pub const DEFAULT_BOOT_WAIT: Duration = Duration::from_millis(1000);
/// Cycles a fault reset is held before giving up.
const FAULT_RESET_CYCLES: u16 = 100;

/// The master. See the module documentation.
pub struct Master {
    nodes: Vec<Node>,
    /// node id -> index into `nodes` + 1 (0: not configured).
    by_id: [u8; 128],
    sync: SyncProducer,
    cfg_retries: u8,
    reset_on_start: bool,
    started: bool,
    /// How long a node heard after taut's reset communication may take to send its boot-up.
    boot_wait: Duration,
    supervision: Supervision,
    /// When taut's next heartbeat is due.
    next_heartbeat: Option<Instant>,
    tx: heapless::Deque<Frame, TX_QUEUE>,
    events: heapless::Deque<NodeEvent, EVENT_QUEUE>,
    counters: Counters,
    reported: u32,
}

impl Master {
    /// A master for the configured drives. Allocates everything it will use.
    pub fn new(cfg: MasterConfig) -> Master {
        let mut by_id = [0u8; 128];
        let mut nodes = Vec::with_capacity(cfg.nodes.len());
        for n in cfg.nodes.into_iter().take(127) {
            let id = usize::from(n.node_id & 0x7F);
            if id == 0 || by_id[id] != 0 {
                continue; // validated by MasterConfig::from_robot; skipped here rather than panic
            }
            nodes.push(Node::new(n, cfg.sdo_timeout, cfg.supervision));
            by_id[id] = nodes.len() as u8;
        }
        Master {
            nodes,
            by_id,
            sync: SyncProducer::new(cfg.sync_period),
            cfg_retries: cfg.sdo_retries,
            reset_on_start: cfg.reset_on_start,
            started: false,
            boot_wait: cfg.boot_wait,
            supervision: cfg.supervision,
            next_heartbeat: None,
            tx: heapless::Deque::new(),
            events: heapless::Deque::new(),
            counters: Counters::default(),
            reported: 0,
        }
    }

    /// Number of drives.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True if no drive is configured.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// A snapshot of drive `i` (in configuration order).
    pub fn status(&self, i: usize) -> Option<NodeStatus> {
        self.nodes.get(i).map(Node::status)
    }

    /// Snapshots of all drives.
    pub fn statuses(&self) -> impl Iterator<Item = NodeStatus> + '_ {
        self.nodes.iter().map(Node::status)
    }

    /// The index of node `id`, if configured.
    pub fn index_of(&self, id: NodeId) -> Option<usize> {
        match self.by_id.get(usize::from(id)) {
            Some(&k) if k > 0 => Some(usize::from(k) - 1),
            _ => None,
        }
    }

    /// True when every drive is operational (PDOs flowing).
    pub fn all_operational(&self) -> bool {
        !self.nodes.is_empty() && self.nodes.iter().all(|n| n.phase == Phase::Operational)
    }

    /// True when every drive is operational and in "operation enabled".
    pub fn all_enabled(&self) -> bool {
        self.all_operational() && self.nodes.iter().all(|n| n.axis.state == Some(PowerState::OperationEnabled))
    }

    /// The next frame to send.
    pub fn poll_tx(&mut self) -> Option<Frame> {
        self.tx.pop_front()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<NodeEvent> {
        self.events.pop_front()
    }

    /// The earliest time at which [`poll`](Self::poll) has something to do.
    pub fn next_deadline(&self) -> Option<Instant> {
        let mut t = self.sync.next_deadline();
        if let Some(h) = self.next_heartbeat {
            t = Some(t.map_or(h, |x| x.min(h)));
        }
        for n in &self.nodes {
            let boot = if n.phase == Phase::Waiting { n.heard_since_reset.map(|t| t + self.boot_wait) } else { None };
            for d in [n.sdo.next_deadline(), n.hb.deadline(), boot].into_iter().flatten() {
                t = Some(t.map_or(d, |x| x.min(d)));
            }
        }
        t
    }

    /// The SYNC period.
    pub fn sync_period(&self) -> Duration {
        self.sync.period()
    }

    fn push_tx(&mut self, f: Frame) {
        if self.tx.push_back(f).is_err() {
            self.counters.tx_dropped += 1;
            self.problem(Problem::TxOverflow, f.id);
        } else {
            self.counters.tx_frames += 1;
        }
    }

    fn event(&mut self, e: NodeEvent) {
        if self.events.push_back(e).is_err() {
            self.counters.events_dropped += 1;
            if self.reported & (1 << Problem::EventOverflow as u32) == 0 {
                self.reported |= 1 << Problem::EventOverflow as u32;
                // Make room for the notice itself: the oldest event goes.
                let _ = self.events.pop_front();
                let _ = self.events.push_back(NodeEvent::FirstOfKind { kind: Problem::EventOverflow, cob_id: 0 });
            }
        }
    }

    fn problem(&mut self, kind: Problem, cob_id: u32) {
        let bit = 1u32 << kind as u32;
        if self.reported & bit == 0 {
            self.reported |= bit;
            self.event(NodeEvent::FirstOfKind { kind, cob_id });
        }
    }

    /// Sends an NMT command (0 = all nodes).
    pub fn send_nmt(&mut self, cmd: NmtCommand, node: NodeId) {
        self.push_tx(nmt::encode(cmd, node));
    }

    /// Reports a bus problem from the transport.
    pub fn on_bus_event(&mut self, e: BusEvent) {
        self.counters.bus_errors += 1;
        self.problem(Problem::Bus, 0);
        // Repeated error-warning/passive reports on a flaky bus would flood the queue; bus-off
        // and overflows always go through.
        if e.is_severe() || self.counters.bus_errors <= 16 {
            self.event(NodeEvent::Bus(e));
        }
    }

    /// Handles one received frame.
    pub fn on_frame(&mut self, f: &Frame, now: Instant) {
        self.counters.rx_frames += 1;
        let Some(id) = f.std_id() else {
            self.counters.ignored += 1;
            self.problem(Problem::Ignored, f.id);
            return;
        };
        let fc = function_code(id);
        let node = node_of(id);
        match fc {
            // NMT, SYNC/EMCY with node 0 (another SYNC producer), TIME, RPDOs and SDO
            // requests (another master), LSS (0x7E4/0x7E5 fall in 0x780 with node > 0x63).
            0x000 | 0x100 | 0x200 | 0x300 | 0x400 | 0x500 | 0x600 => return self.ignore(f),
            0x080 if node == 0 => return self.ignore(f),
            0x780 => return self.ignore(f),
            _ => {}
        }
        let Some(k) = self.index_of(node) else {
            self.counters.unknown_node += 1;
            self.problem(Problem::UnknownNode, f.id);
            return;
        };
        match fc {
            0x080 => self.on_emcy(k, f),
            0x180 | 0x280 | 0x380 | 0x480 => self.on_tpdo(k, id, f),
            0x580 => self.on_sdo(k, f, now),
            0x700 => self.on_heartbeat(k, f, now),
            _ => self.ignore(f),
        }
    }

    fn ignore(&mut self, f: &Frame) {
        self.counters.ignored += 1;
        self.problem(Problem::Ignored, f.id);
    }

    fn malformed(&mut self, f: &Frame) {
        self.counters.malformed += 1;
        self.problem(Problem::Malformed, f.id);
    }

    fn on_emcy(&mut self, k: usize, f: &Frame) {
        let Ok(e) = emcy::decode(f.data()) else { return self.malformed(f) };
        let node = self.nodes[k].cfg.node_id;
        if !e.is_reset() {
            self.counters.emergencies += 1;
            self.nodes[k].last_emcy = Some(e);
            self.nodes[k].axis.error_code = e.code;
        }
        self.event(NodeEvent::Emergency { node, emcy: e });
    }

    fn on_sdo(&mut self, k: usize, f: &Frame, now: Instant) {
        if f.dlc != 8 {
            // Not handed to the client: a truncated frame is noise, the real answer or the
            // timeout follows.
            return self.malformed(f);
        }
        match self.nodes[k].sdo.on_response(f.data(), now) {
            Ok(Some(outcome)) => self.on_sdo_outcome(k, outcome, now),
            Ok(None) => self.flush_sdo(k),
            Err(SdoDiscard::Idle) => {
                self.counters.unexpected_sdo += 1;
                self.problem(Problem::UnexpectedSdo, f.id);
            }
            Err(SdoDiscard::Mismatch { .. } | SdoDiscard::Malformed(_)) => {
                self.counters.sdo_discarded += 1;
                self.problem(Problem::StaleSdo, f.id);
            }
        }
        self.flush_sdo(k);
    }

    fn flush_sdo(&mut self, k: usize) {
        while let Some(f) = self.nodes[k].sdo.poll_tx() {
            self.push_tx(f);
        }
    }

    fn on_heartbeat(&mut self, k: usize, f: &Frame, now: Instant) {
        let Ok(state) = heartbeat::decode(f.data()) else { return self.malformed(f) };
        let node = self.nodes[k].cfg.node_id;
        let n = &mut self.nodes[k];
        if state == NmtState::BootUp {
            n.boots += 1;
            let was = n.phase;
            n.nmt = Some(NmtState::PreOperational);
            self.event(NodeEvent::Booted { node });
            if !matches!(was, Phase::Waiting) {
                self.counters.reboots += 1;
                self.event(NodeEvent::Rebooted { node });
            }
            self.begin_config(k, now);
            return;
        }
        n.nmt = Some(state);
        match n.phase {
            // After taut's own reset communication only the boot-up starts configuration: a
            // heartbeat may predate the reset, and a second configuration would follow the boot-up.
            Phase::Waiting if self.reset_on_start => {
                n.heard_since_reset.get_or_insert(now);
            }
            Phase::Waiting => self.begin_config(k, now),
            Phase::Configuring | Phase::Failed(_) => {}
            Phase::Lost => {
                n.hb.on_heartbeat(now);
                self.event(NodeEvent::HeartbeatRecovered { node });
                self.begin_config(k, now);
            }
            Phase::Starting => {
                n.hb.on_heartbeat(now);
                if state == NmtState::Operational {
                    n.phase = Phase::Operational;
                    self.event(NodeEvent::Operational { node });
                } else {
                    self.send_nmt(NmtCommand::Start, node);
                }
            }
            Phase::Operational => {
                n.hb.on_heartbeat(now);
                if state != NmtState::Operational {
                    // Stopped, or back in pre-operational (e.g. its consumer lost taut and applied
                    // 0x6007): start it again, never enabled by itself (the application decides).
                    n.axis.want = Want::Disabled;
                    n.phase = Phase::Starting;
                    self.send_nmt(NmtCommand::Start, node);
                }
            }
        }
    }

    /// Runs the timers: start-up reset, SDO timeouts, heartbeat timeouts, and the SYNC cycle
    /// (SYNC, then the RPDOs of every operational drive).
    pub fn poll(&mut self, now: Instant) {
        self.poll_timers(now);
        if self.sync.poll(now) {
            self.cycle();
        }
    }

    /// Runs the timers of [`poll`](Self::poll) without the SYNC cycle: for an application
    /// whose own periodic loop is the SYNC clock and calls [`sync_cycle`](Self::sync_cycle).
    pub fn poll_timers(&mut self, now: Instant) {
        if !self.started {
            self.started = true;
            // taut is a CANopen node too (CiA 302): boot-up, then its heartbeat.
            let id = self.supervision.node_id;
            self.push_tx(heartbeat::encode(id, NmtState::BootUp));
            self.next_heartbeat = Some(now + self.supervision.heartbeat);
            if self.reset_on_start {
                self.send_nmt(NmtCommand::ResetCommunication, 0);
            }
        }
        if let Some(t) = self.next_heartbeat {
            if now >= t {
                let p = self.supervision.heartbeat;
                // After a stall, the next one a full period from now, not a burst.
                self.next_heartbeat = Some(if now - t > p { now + p } else { t + p });
                self.push_tx(heartbeat::encode(self.supervision.node_id, NmtState::Operational));
            }
        }
        for k in 0..self.nodes.len() {
            if let Some(o) = self.nodes[k].sdo.poll(now) {
                self.flush_sdo(k);
                self.on_sdo_outcome(k, o, now);
            }
            self.flush_sdo(k);
            let n = &mut self.nodes[k];
            if n.phase == Phase::Waiting && n.heard_since_reset.is_some_and(|t| now >= t + self.boot_wait) {
                let id = n.cfg.node_id;
                self.counters.boot_ups_missing += 1;
                self.problem(Problem::BootUpMissing, 0x700 + u32::from(id));
                self.begin_config(k, now);
                continue;
            }
            let n = &mut self.nodes[k];
            if matches!(n.phase, Phase::Starting | Phase::Operational) && n.hb.check(now) {
                n.phase = Phase::Lost;
                n.sdo.cancel();
                let node = n.cfg.node_id;
                self.counters.heartbeat_losses += 1;
                self.event(NodeEvent::HeartbeatLost { node });
            }
        }
    }
}
