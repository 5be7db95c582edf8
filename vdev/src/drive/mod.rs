//! Virtual CiA 402 servo drives: CANopen slaves on the master's transport trait, so the master,
//! `taut probe --sim` and the tests run the code they run against real drives. Each
//! [`VirtualDrive`] is sans-IO; a [`DriveRack`] puts several on one endpoint, and [`spawn_rack`]
//! runs a rack on its own thread.
//!
//! Object dictionary (see `taut_proto::canopen::od` for types and units):
//!
//! ```text
//! 0x1000 device type (0x00020192)     0x1008 device name (segmented upload)   0x1017 heartbeat ms
//! 0x1016 sub 1 heartbeat consumer     0x6007 abort connection option code (on master loss)
//! 0x1018 identity 1..4                0x1400..3 / 0x1800..3 PDO comm (1 COB-ID, 2 transmission type)
//! 0x1600..3 / 0x1A00..3 PDO mapping   0x2000 scratch domain, 32 bytes (segmented download tests)
//! 0x603F error code   0x6040 controlword   0x6041 statusword   0x6060/0x6061 mode / display
//! 0x6064 position actual   0x6071 target torque   0x6077 torque actual   0x607A target position
//! ```
//! The PDO mapping can only be changed the CiA 301 way (PDO invalid, count 0, entries, count,
//! valid), so a master that skips a step gets the abort a real drive would give:
//!
//! ```text
//! 0x14xx/0x18xx sub 1  COB-ID changed while valid, bits 11..29 set, enabled with count 0  0x06090030
//!               sub 2  transmission type 241..=251 (reserved)                             0x06090030
//! 0x16xx/0x1Axx        written while the PDO is valid, or an entry while sub 0 != 0        0x06010000
//!               entry  object does not exist                                              0x06020000
//!                      sub-index does not exist                                           0x06090011
//!                      object not mappable in this direction, or length not its size      0x06040041
//!               sub 0  more than 8 entries, or more than 64 bits                          0x06040042
//!                      an entry in 1..=n is empty                                         0x06040043
//! ```
//! Like a real drive, its factory mapping is not taut's (see `factory_pdos`), so a master that
//! does not write its own gets other objects, on other COB-IDs.
//!
//! Motion: without the plant, CSP follows the target as a first-order lag with a speed limit,
//! and CST reports the target torque. With the plant coupled ([`VirtualDrive::set_external`]),
//! the plant reads [`VirtualDrive::target`] and writes [`VirtualDrive::set_actual`].
//!
//! One file per job: `dictionary`, `sdo_server` (CiA 301 7.2.4), `pdo_engine` (mapping rules,
//! RPDOs, SYNC-driven TPDOs), `nmt_heartbeat` (NMT, heartbeat consumer, loss of the master),
//! `state_machine` (CiA 402 power states and the motion model) and `rack`.

mod dictionary;
mod nmt_heartbeat;
mod pdo_engine;
mod rack;
mod sdo_server;
mod state_machine;

pub use rack::{rack_filters, spawn_rack, DriveRack, RackHandle};

use pdo_engine::PdoSlot;
use sdo_server::SdoServer;
use state_machine::error_register;
use std::collections::VecDeque;
use std::time::{Duration, Instant};
use taut_proto::can::Frame;
use taut_proto::canopen::cia402::{Mode, PowerState};
use taut_proto::canopen::emcy::{self, Emcy};
use taut_proto::canopen::heartbeat;
use taut_proto::canopen::nmt::{self, NmtCommand, NmtState};
use taut_proto::canopen::pdo::COB_ID_INVALID;
use taut_proto::canopen::sync;
use taut_proto::canopen::NodeId;

/// Fixed properties of a virtual drive.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveParams {
    /// CANopen node id.
    pub node_id: NodeId,
    /// 0x1018 sub 1.
    pub vendor_id: u32,
    /// 0x1018 sub 2.
    pub product_code: u32,
    /// 0x1018 sub 3.
    pub revision: u32,
    /// 0x1018 sub 4.
    pub serial: u32,
    /// 0x1008.
    pub name: String,
    /// Speed limit of the internal motion model, counts/s.
    pub max_speed_counts_s: f64,
    /// Time constant of the internal position follower, s.
    pub time_constant_s: f64,
    /// Torque (‰) per count of following error in the internal model.
    pub torque_per_count: f64,
    /// Producer heartbeat time in non-volatile memory, ms: 0x1017 at power-on and at every NMT
    /// reset communication (CiA 301 7.2.8.3.2.2), so the drive heartbeats before a master speaks.
    pub stored_heartbeat_ms: u16,
    /// How long the drive takes to answer an SDO request. Answers leave in request order; one
    /// computed before a reset is still sent after it (already in the transmit buffer).
    pub sdo_delay: Duration,
    /// Every n-th SDO answer is sent twice (0: never), as a CAN controller that wrongly retries.
    pub sdo_duplicate_every: u32,
    /// Power-on value of 0x6007 abort connection option code (CiA 402): 0 no action, 1 fault,
    /// 2 disable voltage, 3 quick stop.
    pub abort_connection_default: i16,
    /// How long an NMT reset takes to take effect; until then the drive goes on as before.
    pub reset_latency: Duration,
    /// Time in FAULT REACTION ACTIVE (0x605E reaction) before FAULT (CiA 402 transition 14); zero:
    /// straight to FAULT. A fault reset is taken only in FAULT.
    pub fault_reaction: Duration,
}

impl DriveParams {
    /// Defaults for node `node_id`: vendor 0x00000ACE, product 0x0402, serial = 1000 + node id.
    pub fn new(node_id: NodeId) -> Self {
        DriveParams {
            node_id,
            vendor_id: 0x0000_0ACE,
            product_code: 0x0000_0402,
            revision: 0x0001_0000,
            serial: 1000 + u32::from(node_id),
            name: "taut virtual drive".into(),
            max_speed_counts_s: 400_000.0,
            time_constant_s: 0.01,
            torque_per_count: 0.01,
            stored_heartbeat_ms: 0,
            sdo_delay: Duration::ZERO,
            sdo_duplicate_every: 0,
            abort_connection_default: 0,
            reset_latency: Duration::ZERO,
            fault_reaction: Duration::ZERO,
        }
    }
}

/// What the drive is asked to do, for coupling a plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Target {
    /// Mode of operation.
    pub mode: Mode,
    /// Target position, counts.
    pub position: i32,
    /// Target torque, ‰.
    pub torque: i16,
    /// True in "operation enabled" (the motor holds torque).
    pub enabled: bool,
}

/// Counters of a virtual drive.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DriveCounters {
    /// Frames taken.
    pub rx: u64,
    /// Frames sent.
    pub tx: u64,
    /// SYNCs processed in operational.
    pub syncs: u64,
    /// RPDOs shorter than their mapping (answered with EMCY 0x8210).
    pub short_rpdos: u64,
    /// SDO requests answered with an abort.
    pub sdo_aborts: u64,
    /// Boot-ups sent.
    pub boots: u64,
    /// Boot-ups lost on the bus (fault injection).
    pub boots_lost: u64,
    /// SDO answers sent twice.
    pub sdo_duplicates: u64,
    /// Heartbeat consumer timeouts (the master's heartbeat stopped).
    pub consumer_timeouts: u64,
    /// Abort connection actions applied (0x6007).
    pub abort_connection_actions: u64,
}

/// One virtual CiA 402 drive. See the module documentation.
pub struct VirtualDrive {
    p: DriveParams,
    nmt: NmtState,
    boot_pending: bool,
    heartbeat_ms: u16,
    next_hb: Option<Instant>,
    rpdo: [PdoSlot; 4],
    tpdo: [PdoSlot; 4],
    latched: [Option<([u8; 8], u8)>; 4],
    sync_count: [u8; 4],
    controlword: u16,
    state: PowerState,
    mode: i8,
    position: f64,
    torque: i16,
    velocity: i32,
    target_position: i32,
    target_torque: i16,
    error_code: u16,
    scratch: [u8; 32],
    scratch_len: usize,
    last_sync: Option<Instant>,
    external: bool,
    sdo: SdoServer,
    tx: VecDeque<Frame>,
    silent: bool,
    heartbeat_off: bool,
    counters: DriveCounters,
    /// The time of the last frame or poll, for delayed SDO answers.
    clock: Option<Instant>,
    /// SDO answers waiting for their time.
    delayed: VecDeque<(Instant, Frame)>,
    sdo_answers: u32,
    lose_boot_ups: u32,
    /// 0x1016 sub 1: consumer heartbeat time, node id in bits 16..23, time (ms) in 0..16.
    hb_consumer: u32,
    consumer_last: Option<Instant>,
    consumer_lost: bool,
    /// 0x6007.
    abort_option: i16,
    /// An NMT reset waiting for [`DriveParams::reset_latency`].
    pending_reset: Option<(NmtCommand, Instant)>,
    /// The end of the fault reaction (FAULT REACTION ACTIVE -> FAULT).
    fault_reaction_until: Option<Instant>,
}

impl VirtualDrive {
    /// A drive that will send its boot-up message at the first poll.
    pub fn new(p: DriveParams) -> Self {
        let mut d = VirtualDrive {
            p,
            nmt: NmtState::PreOperational,
            boot_pending: true,
            heartbeat_ms: 0,
            next_hb: None,
            rpdo: [PdoSlot { cob_id: COB_ID_INVALID, trans_type: 255, map: [0; 8], count: 0 }; 4],
            tpdo: [PdoSlot { cob_id: COB_ID_INVALID, trans_type: 255, map: [0; 8], count: 0 }; 4],
            latched: [None; 4],
            sync_count: [0; 4],
            controlword: 0,
            state: PowerState::SwitchOnDisabled,
            mode: 0,
            position: 0.0,
            torque: 0,
            velocity: 0,
            target_position: 0,
            target_torque: 0,
            error_code: 0,
            scratch: [0; 32],
            scratch_len: 0,
            last_sync: None,
            external: false,
            sdo: SdoServer::Idle,
            tx: VecDeque::with_capacity(64),
            silent: false,
            heartbeat_off: false,
            counters: DriveCounters::default(),
            clock: None,
            delayed: VecDeque::new(),
            sdo_answers: 0,
            lose_boot_ups: 0,
            hb_consumer: 0,
            consumer_last: None,
            consumer_lost: false,
            abort_option: 0,
            pending_reset: None,
            fault_reaction_until: None,
        };
        d.abort_option = d.p.abort_connection_default;
        d.reset_communication();
        d
    }

    /// Node id.
    pub fn node_id(&self) -> NodeId {
        self.p.node_id
    }

    /// NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.nmt
    }

    /// CiA 402 state.
    pub fn state(&self) -> PowerState {
        self.state
    }

    /// Position actual, counts.
    pub fn position(&self) -> i32 {
        self.position.round() as i32
    }

    /// Counters.
    pub fn counters(&self) -> DriveCounters {
        self.counters
    }

    /// What the drive is asked to do (for the plant).
    pub fn target(&self) -> Target {
        Target {
            mode: Mode::from_code(self.mode),
            position: self.target_position,
            torque: self.target_torque,
            enabled: self.state == PowerState::OperationEnabled,
        }
    }

    /// Lets the plant own position and torque: the internal motion model stops.
    pub fn set_external(&mut self, on: bool) {
        self.external = on;
    }

    /// Position (counts) and torque (‰) from the plant.
    pub fn set_actual(&mut self, position_counts: i32, torque: i16) {
        self.position = f64::from(position_counts);
        self.torque = torque;
    }

    /// Power cycle: everything back to power-on values, boot-up at the next poll.
    pub fn power_cycle(&mut self) {
        let keep_pos = self.position;
        let p = self.p.clone();
        let (silent, external, counters, lose) = (self.silent, self.external, self.counters, self.lose_boot_ups);
        let delayed = std::mem::take(&mut self.delayed);
        *self = VirtualDrive::new(p);
        self.lose_boot_ups = lose;
        // Answers already in the transmit buffer still leave.
        self.delayed = delayed;
        // The encoder is absolute (multi-turn): the position survives a power cycle.
        self.position = keep_pos;
        self.silent = silent;
        self.external = external;
        self.counters = counters;
    }

    /// Sets [`DriveParams::fault_reaction`] (kept across power cycles).
    pub fn set_fault_reaction(&mut self, d: Duration) {
        self.p.fault_reaction = d;
    }

    /// Fault injection: a drive fault with this CiA 402 error code (EMCY + fault state, after
    /// [`DriveParams::fault_reaction`] in FAULT REACTION ACTIVE once the drive has been polled).
    pub fn inject_fault(&mut self, code: u16) {
        self.error_code = code;
        self.fault_reaction_until = self.clock.filter(|_| !self.p.fault_reaction.is_zero()).map(|t| t + self.p.fault_reaction);
        self.state = if self.fault_reaction_until.is_some() { PowerState::FaultReactionActive } else { PowerState::Fault };
        self.torque = 0;
        self.send(emcy::encode(self.p.node_id, &Emcy { code, register: error_register(code), vendor: [0; 5] }));
    }

    /// The drive as a previous run left it: CiA 402 `state` (with `error_code` for a fault), NMT
    /// operational, power-on PDOs. NMT commands and power cycles do not change the CiA 402 state
    /// (CiA 402 6.3), except through 0x6007.
    pub fn left_by_previous_run(&mut self, state: PowerState, error_code: u16) {
        self.state = state;
        self.error_code = error_code;
        self.mode = Mode::CyclicPosition.code();
        self.target_position = self.position();
        self.nmt = NmtState::Operational;
        self.boot_pending = false;
        self.next_hb = None;
    }

    /// Fault injection: the next `n` boot-up messages are lost on the bus.
    pub fn lose_boot_ups(&mut self, n: u32) {
        self.lose_boot_ups = n;
    }

    /// 0x6007 abort connection option code now.
    pub fn abort_connection_option(&self) -> i16 {
        self.abort_option
    }

    /// 0x1016 sub 1 now (consumer heartbeat time).
    pub fn heartbeat_consumer(&self) -> u32 {
        self.hb_consumer
    }

    /// Fault injection: stop (or resume) the heartbeat only; PDOs and SDO go on.
    pub fn set_heartbeat_off(&mut self, off: bool) {
        self.heartbeat_off = off;
    }

    /// Fault injection: the drive neither receives nor sends anything (unplugged cable).
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// Fault injection: queues malformed frames from this node (heartbeat, EMCY, SDO response
    /// and TPDO of the wrong length, an invalid NMT state).
    pub fn queue_malformed(&mut self) {
        let n = u16::from(self.p.node_id);
        for f in [
            Frame::new(0x700 + n, &[0x05, 0x05]),
            Frame::new(0x700 + n, &[0x33]),
            Frame::new(0x080 + n, &[0x10, 0x00, 0x01]),
            Frame::new(0x580 + n, &[0x43, 0x00, 0x10]),
            Frame::new(0x180 + n, &[0x27]),
        ] {
            self.send(f);
        }
    }

    fn send(&mut self, f: Frame) {
        if !self.silent {
            self.counters.tx += 1;
            self.tx.push_back(f);
        }
    }

    /// The next frame to send.
    pub fn poll_tx(&mut self) -> Option<Frame> {
        self.tx.pop_front()
    }

    /// Runs the heartbeat producer and sends a pending boot-up.
    pub fn poll(&mut self, now: Instant) {
        if self.silent {
            return;
        }
        self.clock = Some(now);
        if self.fault_reaction_until.is_some_and(|t| now >= t) {
            self.fault_reaction_until = None;
            if self.state == PowerState::FaultReactionActive {
                self.state = PowerState::Fault;
            }
        }
        if let Some((cmd, t)) = self.pending_reset {
            if now >= t {
                self.pending_reset = None;
                self.on_nmt(cmd);
            }
        }
        while self.delayed.front().is_some_and(|(t, _)| *t <= now) {
            let (_, f) = self.delayed.pop_front().expect("checked");
            self.send(f);
        }
        self.poll_consumer(now);
        if self.boot_pending {
            self.boot_pending = false;
            self.counters.boots += 1;
            if self.lose_boot_ups > 0 {
                self.lose_boot_ups -= 1;
                self.counters.boots_lost += 1;
            } else {
                self.send(heartbeat::encode(self.p.node_id, NmtState::BootUp));
            }
            self.next_hb = (self.heartbeat_ms > 0).then(|| now + Duration::from_millis(u64::from(self.heartbeat_ms)));
        }
        if self.heartbeat_ms == 0 {
            self.next_hb = None;
            return;
        }
        let period = Duration::from_millis(u64::from(self.heartbeat_ms));
        match self.next_hb {
            None => self.next_hb = Some(now + period),
            Some(t) if now >= t => {
                self.next_hb = Some(if now - t > period { now + period } else { t + period });
                if !self.heartbeat_off {
                    self.send(heartbeat::encode(self.p.node_id, self.nmt));
                }
            }
            Some(_) => {}
        }
    }

    /// When [`poll`](Self::poll) has something to do next.
    pub fn next_deadline(&self) -> Option<Instant> {
        [
            self.next_hb,
            self.delayed.front().map(|(t, _)| *t),
            self.consumer_deadline().map(|t| t + Duration::from_millis(1)),
            self.pending_reset.map(|(_, t)| t),
            self.fault_reaction_until,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Handles one frame from the bus.
    pub fn on_frame(&mut self, f: &Frame, now: Instant) {
        if self.silent {
            return;
        }
        let Some(id) = f.std_id() else { return };
        self.counters.rx += 1;
        self.clock = Some(now);
        let n = u16::from(self.p.node_id);
        let producer = ((self.hb_consumer >> 16) & 0x7F) as u16;
        if producer != 0 && self.hb_consumer & 0xFFFF != 0 && id == 0x700 + producer && producer != n {
            // Any heartbeat state counts; a boot-up of the master too (it restarted).
            self.consumer_last = Some(now);
            self.consumer_lost = false;
            return;
        }
        if let Some((cmd, target)) = nmt::decode(f) {
            if target == 0 || target == self.p.node_id {
                let reset = matches!(cmd, NmtCommand::ResetNode | NmtCommand::ResetCommunication);
                if reset && !self.p.reset_latency.is_zero() {
                    self.pending_reset.get_or_insert((cmd, now + self.p.reset_latency));
                } else {
                    self.on_nmt(cmd);
                }
            }
        } else if sync::is_sync(f) {
            if self.nmt == NmtState::Operational {
                self.on_sync(now);
            }
        } else if id == 0x600 + n {
            if self.nmt != NmtState::Stopped {
                self.on_sdo(f.data());
            }
        } else if self.nmt == NmtState::Operational {
            for k in 0..4 {
                let slot = self.rpdo[k];
                if slot.valid() && (slot.cob_id & 0x7FF) as u16 == id {
                    self.on_rpdo(k, f);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use taut_proto::canopen::sdo::{AbortCode, Initiate, SdoRequest, SdoResponse};

    fn sdo(d: &mut VirtualDrive, req: SdoRequest, now: Instant) -> SdoResponse {
        d.on_frame(&req.encode(d.node_id()), now);
        let f = d.poll_tx().expect("a response");
        SdoResponse::decode(f.data()).unwrap()
    }

    #[test]
    fn boots_and_answers_sdo() {
        let t = Instant::now();
        let mut d = VirtualDrive::new(DriveParams::new(3));
        d.poll(t);
        assert_eq!(d.poll_tx(), Some(Frame::new(0x703, &[0])));
        let r = sdo(&mut d, SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }, t);
        assert_eq!(
            r,
            SdoResponse::UploadInitiated {
                index: 0x1000,
                sub: 0,
                kind: Initiate::Expedited { data: 0x0002_0192u32.to_le_bytes(), len: 4 }
            }
        );
        let r = sdo(&mut d, SdoRequest::InitiateDownload { index: 0x6041, sub: 0, kind: Initiate::Expedited { data: [0; 4], len: 2 } }, t);
        assert_eq!(r, SdoResponse::Abort { index: 0x6041, sub: 0, code: AbortCode::READ_ONLY });
        let r = sdo(&mut d, SdoRequest::InitiateUpload { index: 0x5555, sub: 0 }, t);
        assert_eq!(r, SdoResponse::Abort { index: 0x5555, sub: 0, code: AbortCode::NO_OBJECT });
        // Mapping a valid PDO is refused, as CiA 301 requires.
        let r = sdo(&mut d, SdoRequest::InitiateDownload { index: 0x1A00, sub: 0, kind: Initiate::Expedited { data: [0; 4], len: 1 } }, t);
        assert_eq!(r, SdoResponse::Abort { index: 0x1A00, sub: 0, code: AbortCode::UNSUPPORTED_ACCESS });
    }

    #[test]
    fn heartbeat_consumer_and_abort_connection_objects_are_strict() {
        let t = Instant::now();
        let mut d = VirtualDrive::new(DriveParams::new(3));
        d.poll(t);
        let _ = d.poll_tx();
        let w = |index: u16, sub: u8, v: u32, len: u8| SdoRequest::InitiateDownload {
            index,
            sub,
            kind: Initiate::Expedited { data: v.to_le_bytes(), len },
        };
        let abort = |index: u16, sub: u8, code: AbortCode| SdoResponse::Abort { index, sub, code };
        assert_eq!(sdo(&mut d, w(0x6007, 0, 4, 2), t), abort(0x6007, 0, AbortCode::INVALID_VALUE), "0..=3 only");
        assert_eq!(sdo(&mut d, w(0x6007, 0, 3, 1), t), abort(0x6007, 0, AbortCode::LENGTH_MISMATCH), "INTEGER16");
        assert_eq!(sdo(&mut d, w(0x1016, 0, 2, 1), t), abort(0x1016, 0, AbortCode::READ_ONLY));
        assert_eq!(sdo(&mut d, w(0x1016, 2, 0, 4), t), abort(0x1016, 2, AbortCode::NO_SUBINDEX));
        assert_eq!(sdo(&mut d, w(0x1016, 1, 1 << 24 | 127 << 16 | 300, 4), t), abort(0x1016, 1, AbortCode::INVALID_VALUE), "reserved bits");
        assert_eq!(sdo(&mut d, w(0x1016, 1, 300, 4), t), abort(0x1016, 1, AbortCode::INVALID_VALUE), "node 0 with a time");
        assert_eq!(sdo(&mut d, w(0x1016, 1, 127 << 16 | 300, 4), t), SdoResponse::DownloadInitiated { index: 0x1016, sub: 1 });
        assert_eq!(sdo(&mut d, w(0x6007, 0, 3, 2), t), SdoResponse::DownloadInitiated { index: 0x6007, sub: 0 });
        // Not watching before the producer's first heartbeat.
        d.poll(t + Duration::from_secs(5));
        assert_eq!(d.counters().consumer_timeouts, 0);
        d.on_frame(&heartbeat::encode(127, NmtState::Operational), t + Duration::from_secs(5));
        d.poll(t + Duration::from_millis(5300));
        assert_eq!(d.counters().consumer_timeouts, 0, "on time");
        d.poll(t + Duration::from_millis(5301));
        assert_eq!(d.counters().consumer_timeouts, 1);
        assert_eq!(d.poll_tx(), Some(emcy::encode(3, &Emcy { code: 0x8130, register: 0x11, vendor: [0; 5] })));
        assert_eq!(d.counters().abort_connection_actions, 0, "not enabled: nothing to stop");
        // Reset communication: 0x1016 back to its power-on value, 0x6007 kept (application).
        d.on_frame(&nmt::encode(NmtCommand::ResetCommunication, 0), t + Duration::from_secs(6));
        assert_eq!((d.heartbeat_consumer(), d.abort_connection_option()), (0, 3));
    }

    #[test]
    fn an_existing_object_that_cannot_be_mapped_is_not_mappable_not_missing() {
        let t = Instant::now();
        let mut d = VirtualDrive::new(DriveParams::new(3));
        d.poll(t);
        let _ = d.poll_tx();
        // TPDO 3 is invalid and empty at the factory: its entries may be written.
        let entry =
            |v: u32| SdoRequest::InitiateDownload { index: 0x1A02, sub: 1, kind: Initiate::Expedited { data: v.to_le_bytes(), len: 4 } };
        let abort = |code: AbortCode| SdoResponse::Abort { index: 0x1A02, sub: 1, code };
        // 0x6007 (abort connection option), 0x1016 sub 1 (heartbeat consumer), 0x1400 sub 1: in
        // the dictionary, not mappable.
        for v in [0x6007_0010, 0x1016_0120, 0x1400_0120] {
            assert_eq!(sdo(&mut d, entry(v), t), abort(AbortCode::NOT_MAPPABLE), "{v:#010x}");
        }
        assert_eq!(sdo(&mut d, entry(0x5555_0010), t), abort(AbortCode::NO_OBJECT));
        assert_eq!(sdo(&mut d, entry(0x6064_0020), t), SdoResponse::DownloadInitiated { index: 0x1A02, sub: 1 });
    }

    /// A fault with a fault reaction: EMCY at once, FAULT REACTION ACTIVE (statusword 0x0F),
    /// which takes no fault reset, then FAULT, which does.
    #[test]
    fn a_fault_passes_through_fault_reaction_active() {
        let t = Instant::now();
        let mut p = DriveParams::new(3);
        p.fault_reaction = Duration::from_millis(20);
        let mut d = VirtualDrive::new(p);
        d.poll(t);
        let _ = d.poll_tx();
        d.inject_fault(0x2310);
        assert_eq!(d.poll_tx(), Some(emcy::encode(3, &Emcy { code: 0x2310, register: 0x03, vendor: [0; 5] })));
        assert_eq!((d.state(), d.statusword() & 0x6F), (PowerState::FaultReactionActive, 0x0F));
        assert_eq!(d.next_deadline(), Some(t + Duration::from_millis(20)));
        d.on_controlword(0x0080);
        assert_eq!(d.state(), PowerState::FaultReactionActive, "no fault reset while reacting");
        d.on_controlword(0x0000);
        d.poll(t + Duration::from_millis(19));
        assert_eq!(d.state(), PowerState::FaultReactionActive);
        d.poll(t + Duration::from_millis(20));
        assert_eq!(d.state(), PowerState::Fault);
        d.on_controlword(0x0080);
        assert_eq!(d.state(), PowerState::SwitchOnDisabled);
        // Kept across a power cycle; zero is straight to FAULT.
        d.power_cycle();
        d.poll(t + Duration::from_millis(30));
        d.inject_fault(0x2310);
        assert_eq!(d.state(), PowerState::FaultReactionActive);
        d.set_fault_reaction(Duration::ZERO);
        d.on_controlword(0);
        d.poll(t + Duration::from_millis(50));
        d.inject_fault(0x2310);
        assert_eq!(d.state(), PowerState::Fault);
    }

    #[test]
    fn garbage_sdo_is_aborted_not_panicked() {
        let t = Instant::now();
        let mut d = VirtualDrive::new(DriveParams::new(3));
        for data in [&[0xE0u8, 0, 0, 0, 0, 0, 0, 0][..], &[1, 2, 3], &[], &[0x60, 0, 0, 0, 0, 0, 0, 0], &[0x00; 8]] {
            d.on_frame(&Frame::new(0x603, data), t);
            while d.poll_tx().is_some() {}
        }
        assert!(d.counters().sdo_aborts >= 3);
    }
}
