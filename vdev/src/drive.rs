//! Virtual CiA 402 servo drives: CANopen slaves on the same transport trait as the master, so
//! the master, `taut probe --sim` and the tests run the same code against them as against real
//! drives.
//!
//! Each [`VirtualDrive`] is sans-IO (frames and time in, frames out); a [`DriveRack`] puts
//! several on one transport endpoint, and [`spawn_rack`] runs a rack on its own thread for
//! wall-clock use (probe, vcan tests).
//!
//! Object dictionary (see `taut_driver::canopen::od` for types and units):
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

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use taut_driver::canopen::cia402::{self, Command, Mode, State};
use taut_driver::canopen::emcy::{self, Emcy};
use taut_driver::canopen::heartbeat;
use taut_driver::canopen::nmt::{self, NmtCommand, NmtState};
use taut_driver::canopen::od;
use taut_driver::canopen::pdo::{self, MapEntry, COB_ID_INVALID};
use taut_driver::canopen::sdo::{AbortCode, Initiate, SdoRequest, SdoResponse, Segment};
use taut_driver::canopen::sync;
use taut_driver::transport::virtual_bus::Filter;
use taut_driver::{CanTransport, Frame, NodeId, TransportError};

/// Largest object the SDO server moves in one transfer, bytes.
const SDO_MAX: usize = 64;

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
    /// Producer heartbeat time stored in the drive's non-volatile memory, ms: the value 0x1017
    /// takes at power-on and at every NMT reset communication (CiA 301 7.2.8.3.2.2). Real drives
    /// usually ship with one (100 ms is common), so they heartbeat before any master speaks.
    pub stored_heartbeat_ms: u16,
    /// How long the drive takes to answer an SDO request (slow firmware: tens of ms are common).
    /// Answers leave in request order; one computed before a reset is still sent after it, as
    /// a frame already in the controller's transmit buffer would be.
    pub sdo_delay: Duration,
    /// Every n-th SDO answer is sent twice (0: never), as a drive whose CAN controller retries
    /// a frame it wrongly believes lost does.
    pub sdo_duplicate_every: u32,
    /// Power-on value of 0x6007 abort connection option code (CiA 402): 0 no action, 1 fault,
    /// 2 disable voltage, 3 quick stop. 0 is what the drives of issue 9 did: nothing on the
    /// drive side noticed that the master had gone.
    pub abort_connection_default: i16,
    /// How long an NMT reset (communication or node) takes to take effect: until then the drive
    /// goes on as before (its heartbeat timer may fire, SDO requests are answered), as firmware
    /// that handles NMT in its main loop does.
    pub reset_latency: Duration,
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

/// CiA 301: general parameter incompatibility (here: sub 0 counts an empty mapping entry).
const PARAM_INCOMPATIBLE: AbortCode = AbortCode(0x0604_0043);

/// Following error actual value, counts.
const FOLLOWING_ERROR: u16 = 0x60F4;

/// The drive's mappable objects: index, sub-index, bits, mappable into an RPDO, into a TPDO.
const MAPPABLE: &[(u16, u8, u8, bool, bool)] = &[
    (od::ERROR_CODE, 0, 16, false, true),
    (od::CONTROLWORD, 0, 16, true, false),
    (od::STATUSWORD, 0, 16, false, true),
    (od::MODES_OF_OPERATION, 0, 8, true, false),
    (od::MODES_OF_OPERATION_DISPLAY, 0, 8, false, true),
    (od::POSITION_ACTUAL, 0, 32, false, true),
    (od::VELOCITY_ACTUAL, 0, 32, false, true),
    (od::TARGET_TORQUE, 0, 16, true, false),
    (od::TORQUE_ACTUAL, 0, 16, false, true),
    (od::TARGET_POSITION, 0, 32, true, true),
    (FOLLOWING_ERROR, 0, 32, false, true),
];

#[derive(Debug, Clone, Copy)]
struct PdoSlot {
    cob_id: u32,
    trans_type: u8,
    map: [u32; 8],
    count: u8,
}

impl PdoSlot {
    fn valid(&self) -> bool {
        self.cob_id & COB_ID_INVALID == 0
    }
    fn entries(&self) -> heapless::Vec<MapEntry, 8> {
        self.map[..usize::from(self.count.min(8))].iter().filter_map(|&v| MapEntry::decode(v)).collect()
    }

    fn with(cob_id: u32, trans_type: u8, entries: &[MapEntry]) -> PdoSlot {
        let mut map = [0u32; 8];
        for (m, e) in map.iter_mut().zip(entries) {
            *m = e.encode();
        }
        PdoSlot { cob_id, trans_type, map, count: entries.len() as u8 }
    }

    /// CiA 301 7.5.2.35 / 7.5.2.37: a write to the communication parameter.
    fn write_comm(&mut self, sub: u8, v: u32) -> Result<(), AbortCode> {
        match sub {
            1 => {
                let valid = v & COB_ID_INVALID == 0;
                // 11-bit ids only (bit 29 = extended frame), the id fixed while valid, and no
                // valid PDO without a mapping.
                if v & 0x3FFF_F800 != 0 || (valid && self.valid() && (v & 0x7FF) != (self.cob_id & 0x7FF)) || (valid && self.count == 0) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.cob_id = v;
                Ok(())
            }
            2 => {
                let t = v as u8;
                if (241..=251).contains(&t) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.trans_type = t;
                Ok(())
            }
            0 => Err(AbortCode::READ_ONLY),
            _ => Err(AbortCode::NO_SUBINDEX),
        }
    }

    /// CiA 301 7.5.2.36 / 7.5.2.38: a write to the mapping parameter.
    fn write_map(&mut self, rx: bool, sub: u8, v: u32) -> Result<(), AbortCode> {
        if sub > 8 {
            return Err(AbortCode::NO_SUBINDEX);
        }
        // The mapping changes only while the PDO is invalid, and entries only while sub 0 is 0.
        if self.valid() || (sub > 0 && self.count != 0) {
            return Err(AbortCode::UNSUPPORTED_ACCESS);
        }
        if sub == 0 {
            let n = v as u8;
            if n > 8 {
                return Err(AbortCode::PDO_TOO_LONG);
            }
            let mut bits = 0u32;
            for &m in &self.map[..usize::from(n)] {
                if MapEntry::decode(m).is_none() {
                    return Err(PARAM_INCOMPATIBLE);
                }
                bits += m & 0xFF;
            }
            if bits > 64 {
                return Err(AbortCode::PDO_TOO_LONG);
            }
            self.count = n;
            return Ok(());
        }
        if v != 0 {
            let e = MapEntry::decode(v).ok_or(AbortCode::NOT_MAPPABLE)?;
            mapping_check(rx, e)?;
        }
        self.map[usize::from(sub - 1)] = v;
        Ok(())
    }
}

/// Whether `e` may be mapped into an RPDO (`rx`) or a TPDO of this drive.
fn mapping_check(rx: bool, e: MapEntry) -> Result<(), AbortCode> {
    match MAPPABLE.iter().find(|m| m.0 == e.index && m.1 == e.sub) {
        Some(&(_, _, bits, r, t)) if bits == e.bits && if rx { r } else { t } => Ok(()),
        Some(_) => Err(AbortCode::NOT_MAPPABLE),
        None if MAPPABLE.iter().any(|m| m.0 == e.index) => Err(AbortCode::NO_SUBINDEX),
        None if object_exists(e.index) => Err(AbortCode::NOT_MAPPABLE),
        None => Err(AbortCode::NO_OBJECT),
    }
}

fn object_exists(index: u16) -> bool {
    matches!(index, 0x1000 | 0x1008 | 0x1017 | 0x1018 | 0x1400..=0x1403 | 0x1600..=0x1603 | 0x1800..=0x1803 | 0x1A00..=0x1A03 | 0x2000)
        || MAPPABLE.iter().any(|m| m.0 == index)
}

/// The factory PDO configuration (what reset communication restores): deliberately not taut's,
/// as on real drives. RPDO1 0x200+n controlword + mode, RPDO2 0x300+n controlword + target
/// position, TPDO1 0x180+n statusword + mode display (event driven), TPDO2 0x280+n statusword +
/// position actual on every SYNC; PDOs 3 and 4 invalid and empty.
fn factory_pdos(node: NodeId) -> ([PdoSlot; 4], [PdoSlot; 4]) {
    let n = u32::from(node);
    let e = MapEntry::new;
    let mut rpdo = [PdoSlot { cob_id: COB_ID_INVALID, trans_type: 255, map: [0; 8], count: 0 }; 4];
    let mut tpdo = rpdo;
    for k in 0..4u32 {
        rpdo[k as usize].cob_id = (0x200 + 0x100 * k + n) | COB_ID_INVALID;
        tpdo[k as usize].cob_id = (0x180 + 0x100 * k + n) | COB_ID_INVALID;
    }
    rpdo[0] = PdoSlot::with(0x200 + n, 255, &[e(od::CONTROLWORD, 0, 16), e(od::MODES_OF_OPERATION, 0, 8)]);
    rpdo[1] = PdoSlot::with(0x300 + n, 255, &[e(od::CONTROLWORD, 0, 16), e(od::TARGET_POSITION, 0, 32)]);
    tpdo[0] = PdoSlot::with(0x180 + n, 255, &[e(od::STATUSWORD, 0, 16), e(od::MODES_OF_OPERATION_DISPLAY, 0, 8)]);
    tpdo[1] = PdoSlot::with(0x280 + n, 1, &[e(od::STATUSWORD, 0, 16), e(od::POSITION_ACTUAL, 0, 32)]);
    (rpdo, tpdo)
}

#[derive(Debug, Clone)]
enum SdoServer {
    Idle,
    Download { index: u16, sub: u8, buf: [u8; SDO_MAX], len: usize, toggle: bool },
    Upload { index: u16, sub: u8, buf: [u8; SDO_MAX], len: usize, pos: usize, toggle: bool },
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
    state: State,
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
            state: State::SwitchOnDisabled,
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
    pub fn state(&self) -> State {
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
            enabled: self.state == State::OperationEnabled,
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

    /// Fault injection: a drive fault with this CiA 402 error code (EMCY + fault state).
    pub fn inject_fault(&mut self, code: u16) {
        self.error_code = code;
        self.state = State::Fault;
        self.torque = 0;
        self.send(emcy::encode(self.p.node_id, &Emcy { code, register: error_register(code), vendor: [0; 5] }));
    }

    /// The drive as a previous run left it: its CiA 402 `state` (e.g. operation enabled in CSP,
    /// or fault with `error_code`) and NMT operational, with the power-on PDOs. A restarted
    /// master finds drives like this; power cycles and NMT commands do not change the CiA 402
    /// state (that is the application's, CiA 402 6.3), except through 0x6007.
    pub fn left_by_previous_run(&mut self, state: State, error_code: u16) {
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

    fn reset_communication(&mut self) {
        self.heartbeat_ms = self.p.stored_heartbeat_ms;
        self.next_hb = None;
        (self.rpdo, self.tpdo) = factory_pdos(self.p.node_id);
        self.latched = [None; 4];
        self.sync_count = [0; 4];
        self.sdo = SdoServer::Idle;
        self.nmt = NmtState::PreOperational;
        self.boot_pending = true;
        // 0x1016 is a communication parameter: back to its power-on value, no consumer.
        self.hb_consumer = 0;
        self.consumer_last = None;
        self.consumer_lost = false;
    }

    /// CiA 402 0x6007: what the drive does when its connection to the master is lost
    /// (heartbeat consumer timeout, NMT stop, reset communication, reset node), applied only
    /// from operation enabled (the power stage holding the load).
    fn abort_connection(&mut self) {
        if self.state != State::OperationEnabled || self.abort_option == 0 {
            return;
        }
        self.counters.abort_connection_actions += 1;
        self.state = match self.abort_option {
            1 => {
                // Fault signal: the fault reaction, then FAULT until the operator resets it.
                self.error_code = 0x8130;
                State::Fault
            }
            2 => State::SwitchOnDisabled,
            _ => State::QuickStopActive,
        };
        // Stop where the motor stands (quick stop holds there; the others drop torque).
        self.target_position = self.position();
        if self.state != State::QuickStopActive {
            self.torque = 0;
        }
    }

    /// Runs the heartbeat producer and sends a pending boot-up.
    pub fn poll(&mut self, now: Instant) {
        if self.silent {
            return;
        }
        self.clock = Some(now);
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

    /// The heartbeat consumer (CiA 301 7.2.8.3.2.2, 0x1016): watching starts at the first
    /// heartbeat of the configured producer; a timeout raises EMCY 0x8130 (heartbeat error),
    /// applies 0x6007, and (0x1029 error behaviour, default 0) falls back from operational to
    /// pre-operational.
    fn poll_consumer(&mut self, now: Instant) {
        let Some(deadline) = self.consumer_deadline() else { return };
        if now <= deadline {
            return;
        }
        self.consumer_lost = true;
        self.counters.consumer_timeouts += 1;
        self.send(emcy::encode(self.p.node_id, &Emcy { code: 0x8130, register: 0x11, vendor: [0; 5] }));
        self.abort_connection();
        if self.nmt == NmtState::Operational {
            self.nmt = NmtState::PreOperational;
        }
    }

    fn consumer_deadline(&self) -> Option<Instant> {
        let ms = self.hb_consumer & 0xFFFF;
        match self.consumer_last {
            Some(t) if ms > 0 && !self.consumer_lost => Some(t + Duration::from_millis(u64::from(ms))),
            _ => None,
        }
    }

    /// When [`poll`](Self::poll) has something to do next.
    pub fn next_deadline(&self) -> Option<Instant> {
        [
            self.next_hb,
            self.delayed.front().map(|(t, _)| *t),
            self.consumer_deadline().map(|t| t + Duration::from_millis(1)),
            self.pending_reset.map(|(_, t)| t),
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

    fn on_nmt(&mut self, cmd: NmtCommand) {
        if matches!(cmd, NmtCommand::Stop | NmtCommand::ResetNode | NmtCommand::ResetCommunication) {
            self.abort_connection();
        }
        match cmd {
            NmtCommand::Start => self.nmt = NmtState::Operational,
            NmtCommand::Stop => self.nmt = NmtState::Stopped,
            NmtCommand::PreOperational => self.nmt = NmtState::PreOperational,
            NmtCommand::ResetNode => self.power_cycle(),
            NmtCommand::ResetCommunication => self.reset_communication(),
        }
    }

    fn on_rpdo(&mut self, k: usize, f: &Frame) {
        let entries = self.rpdo[k].entries();
        if f.data().len() < usize::from(pdo::byte_len(&entries)) {
            // CiA 301 7.2.2.2: a too-short RPDO is not processed; report it.
            self.counters.short_rpdos += 1;
            self.send(emcy::encode(self.p.node_id, &Emcy { code: 0x8210, register: 0x11, vendor: [0; 5] }));
            return;
        }
        let mut d = [0u8; 8];
        d[..f.data().len()].copy_from_slice(f.data());
        if self.rpdo[k].trans_type >= 254 {
            self.apply_rpdo(k, &d, f.dlc);
        } else {
            self.latched[k] = Some((d, f.dlc));
        }
    }

    fn apply_rpdo(&mut self, k: usize, d: &[u8; 8], dlc: u8) {
        let entries = self.rpdo[k].entries();
        let mut vals: heapless::Vec<(u16, u64, u8), 8> = heapless::Vec::new();
        let _ = pdo::unpack(&entries, &d[..usize::from(dlc)], |index, _, raw, bits| {
            let _ = vals.push((index, raw, bits));
        });
        for (index, raw, bits) in vals {
            match index {
                od::CONTROLWORD => self.on_controlword(raw as u16),
                od::TARGET_POSITION => self.target_position = pdo::sign_extend(raw, bits) as i32,
                od::TARGET_TORQUE => self.target_torque = pdo::sign_extend(raw, bits) as i16,
                od::MODES_OF_OPERATION => self.mode = raw as u8 as i8,
                _ => {}
            }
        }
    }

    fn on_controlword(&mut self, cw: u16) {
        let rising_reset = cw & 0x80 != 0 && self.controlword & 0x80 == 0;
        self.controlword = cw;
        let cmd = Command::from_controlword(cw);
        use State::*;
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

    fn on_sync(&mut self, now: Instant) {
        self.counters.syncs += 1;
        for k in 0..4 {
            if let Some((d, dlc)) = self.latched[k].take() {
                self.apply_rpdo(k, &d, dlc);
            }
        }
        let dt = self.last_sync.map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64().min(0.1));
        self.last_sync = Some(now);
        let before = self.position;
        if !self.external {
            self.step_motion(dt);
        }
        // Velocity over the last SYNC period (also when the plant owns the position).
        if dt > 0.0 {
            self.velocity = ((self.position - before) / dt).round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        }
        for k in 0..4 {
            let slot = self.tpdo[k];
            if !slot.valid() || !(1..=240).contains(&slot.trans_type) {
                continue;
            }
            self.sync_count[k] += 1;
            if self.sync_count[k] < slot.trans_type {
                continue;
            }
            self.sync_count[k] = 0;
            let entries = slot.entries();
            let mut data = [0u8; 8];
            let sw = self.statusword();
            let (pos, tq, mode, err) = (self.position() as u32 as u64, self.torque as u16 as u64, self.mode as u8 as u64, self.error_code);
            if let Ok(dlc) = pdo::pack(&entries, &mut data, |index, _| match index {
                od::STATUSWORD => u64::from(sw),
                od::POSITION_ACTUAL => pos,
                od::TORQUE_ACTUAL => tq,
                od::MODES_OF_OPERATION_DISPLAY => mode,
                od::ERROR_CODE => u64::from(err),
                od::TARGET_POSITION => self.target_position as u32 as u64,
                od::VELOCITY_ACTUAL => self.velocity as u32 as u64,
                FOLLOWING_ERROR => (self.target_position.wrapping_sub(self.position())) as u32 as u64,
                _ => 0,
            }) {
                self.send(Frame::new((slot.cob_id & 0x7FF) as u16, &data[..usize::from(dlc)]));
            }
        }
    }

    fn step_motion(&mut self, dt: f64) {
        if self.state != State::OperationEnabled {
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
        if self.state == State::OperationEnabled {
            sw |= cia402::SW_FOLLOWING;
            if (f64::from(self.target_position) - self.position).abs() < 2.0 {
                sw |= 1 << 10;
            }
        }
        sw
    }

    // ---- SDO server (CiA 301 7.2.4) ------------------------------------------------------

    fn respond(&mut self, r: SdoResponse) {
        if let SdoResponse::Abort { .. } = r {
            self.counters.sdo_aborts += 1;
        }
        self.sdo_answers = self.sdo_answers.wrapping_add(1);
        let twice = self.p.sdo_duplicate_every > 0 && self.sdo_answers.is_multiple_of(self.p.sdo_duplicate_every);
        let f = r.encode(self.p.node_id);
        for _ in 0..1 + usize::from(twice) {
            match self.clock {
                Some(now) if !self.p.sdo_delay.is_zero() => self.delayed.push_back((now + self.p.sdo_delay, f)),
                _ => self.send(f),
            }
        }
        if twice {
            self.counters.sdo_duplicates += 1;
        }
    }

    fn on_sdo(&mut self, data: &[u8]) {
        let req = match SdoRequest::decode(data) {
            Ok(r) => r,
            Err(e) => {
                self.sdo = SdoServer::Idle;
                let (index, sub) = if data.len() >= 4 { (u16::from_le_bytes([data[1], data[2]]), data[3]) } else { (0, 0) };
                return self.respond(SdoResponse::Abort { index, sub, code: e.abort_code() });
            }
        };
        match (req, self.sdo.clone()) {
            (SdoRequest::Abort { .. }, _) => self.sdo = SdoServer::Idle,
            (SdoRequest::InitiateUpload { index, sub }, _) => {
                self.sdo = SdoServer::Idle;
                match self.read(index, sub) {
                    Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    Ok((buf, len)) if len <= 4 => {
                        let mut d = [0u8; 4];
                        d[..len].copy_from_slice(&buf[..len]);
                        self.respond(SdoResponse::UploadInitiated { index, sub, kind: Initiate::Expedited { data: d, len: len as u8 } })
                    }
                    Ok((buf, len)) => {
                        self.sdo = SdoServer::Upload { index, sub, buf, len, pos: 0, toggle: false };
                        self.respond(SdoResponse::UploadInitiated { index, sub, kind: Initiate::Segmented { size: Some(len as u32) } })
                    }
                }
            }
            (SdoRequest::UploadSegment { toggle }, SdoServer::Upload { index, sub, buf, len, pos, toggle: t }) => {
                if toggle != t {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::TOGGLE });
                }
                let n = (len - pos).min(7);
                let mut d = [0u8; 7];
                d[..n].copy_from_slice(&buf[pos..pos + n]);
                let last = pos + n == len;
                self.sdo = if last { SdoServer::Idle } else { SdoServer::Upload { index, sub, buf, len, pos: pos + n, toggle: !t } };
                self.respond(SdoResponse::UploadSegment(Segment { toggle, data: d, len: n as u8, last }))
            }
            (SdoRequest::InitiateDownload { index, sub, kind }, _) => {
                self.sdo = SdoServer::Idle;
                match kind {
                    Initiate::Expedited { data, len } => match self.write(index, sub, &data[..usize::from(len)]) {
                        Ok(()) => self.respond(SdoResponse::DownloadInitiated { index, sub }),
                        Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    },
                    Initiate::Segmented { size } => {
                        if size.is_some_and(|s| s as usize > SDO_MAX) {
                            return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::OUT_OF_MEMORY });
                        }
                        self.sdo = SdoServer::Download { index, sub, buf: [0; SDO_MAX], len: 0, toggle: false };
                        self.respond(SdoResponse::DownloadInitiated { index, sub })
                    }
                }
            }
            (SdoRequest::DownloadSegment(s), SdoServer::Download { index, sub, mut buf, len, toggle }) => {
                let n = usize::from(s.len);
                if s.toggle != toggle {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::TOGGLE });
                }
                if len + n > SDO_MAX {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::OUT_OF_MEMORY });
                }
                buf[len..len + n].copy_from_slice(&s.data[..n]);
                if s.last {
                    self.sdo = SdoServer::Idle;
                    match self.write(index, sub, &buf[..len + n]) {
                        Ok(()) => self.respond(SdoResponse::DownloadSegmentAck { toggle }),
                        Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    }
                } else {
                    self.sdo = SdoServer::Download { index, sub, buf, len: len + n, toggle: !toggle };
                    self.respond(SdoResponse::DownloadSegmentAck { toggle })
                }
            }
            (_, _) => {
                self.sdo = SdoServer::Idle;
                self.respond(SdoResponse::Abort { index: 0, sub: 0, code: AbortCode::COMMAND })
            }
        }
    }

    fn read(&self, index: u16, sub: u8) -> Result<([u8; SDO_MAX], usize), AbortCode> {
        let mut b = [0u8; SDO_MAX];
        let mut put = |bytes: &[u8]| {
            b[..bytes.len()].copy_from_slice(bytes);
            Ok((b, bytes.len()))
        };
        match (index, sub) {
            (od::DEVICE_TYPE, 0) => put(&od::DEVICE_TYPE_CIA402_SERVO.to_le_bytes()),
            (od::DEVICE_NAME, 0) => {
                let n = self.p.name.len().min(SDO_MAX);
                put(&self.p.name.as_bytes()[..n])
            }
            (od::HEARTBEAT_PRODUCER, 0) => put(&self.heartbeat_ms.to_le_bytes()),
            (od::HEARTBEAT_CONSUMER, 0) => put(&[1]),
            (od::HEARTBEAT_CONSUMER, 1) => put(&self.hb_consumer.to_le_bytes()),
            (od::ABORT_CONNECTION, 0) => put(&self.abort_option.to_le_bytes()),
            (od::IDENTITY, 0) => put(&[4]),
            (od::IDENTITY, 1) => put(&self.p.vendor_id.to_le_bytes()),
            (od::IDENTITY, 2) => put(&self.p.product_code.to_le_bytes()),
            (od::IDENTITY, 3) => put(&self.p.revision.to_le_bytes()),
            (od::IDENTITY, 4) => put(&self.p.serial.to_le_bytes()),
            (0x1400..=0x1403, _) | (0x1800..=0x1803, _) => {
                let slot = if index < 0x1800 { &self.rpdo[usize::from(index - 0x1400)] } else { &self.tpdo[usize::from(index - 0x1800)] };
                match sub {
                    0 => put(&[2]),
                    1 => put(&slot.cob_id.to_le_bytes()),
                    2 => put(&[slot.trans_type]),
                    _ => Err(AbortCode::NO_SUBINDEX),
                }
            }
            (0x1600..=0x1603, _) | (0x1A00..=0x1A03, _) => {
                let slot = if index < 0x1A00 { &self.rpdo[usize::from(index - 0x1600)] } else { &self.tpdo[usize::from(index - 0x1A00)] };
                match sub {
                    0 => put(&[slot.count]),
                    1..=8 => put(&slot.map[usize::from(sub - 1)].to_le_bytes()),
                    _ => Err(AbortCode::NO_SUBINDEX),
                }
            }
            (0x2000, 0) => put(&self.scratch[..self.scratch_len]),
            (od::ERROR_CODE, 0) => put(&self.error_code.to_le_bytes()),
            (od::CONTROLWORD, 0) => put(&self.controlword.to_le_bytes()),
            (od::STATUSWORD, 0) => put(&self.statusword().to_le_bytes()),
            (od::MODES_OF_OPERATION, 0) => put(&[self.mode as u8]),
            (od::MODES_OF_OPERATION_DISPLAY, 0) => put(&[self.mode as u8]),
            (od::POSITION_ACTUAL, 0) => put(&self.position().to_le_bytes()),
            (od::TARGET_TORQUE, 0) => put(&self.target_torque.to_le_bytes()),
            (od::TORQUE_ACTUAL, 0) => put(&self.torque.to_le_bytes()),
            (od::TARGET_POSITION, 0) => put(&self.target_position.to_le_bytes()),
            (od::VELOCITY_ACTUAL, 0) => put(&self.velocity.to_le_bytes()),
            (FOLLOWING_ERROR, 0) => put(&self.target_position.wrapping_sub(self.position()).to_le_bytes()),
            (0x1000 | 0x1008 | 0x1016 | 0x1017 | 0x1018 | 0x2000 | 0x6007 | 0x603F..=0x60F4, _) if self.exists(index) => {
                Err(AbortCode::NO_SUBINDEX)
            }
            _ => Err(AbortCode::NO_OBJECT),
        }
    }

    fn exists(&self, index: u16) -> bool {
        matches!(
            index,
            0x1000
                | 0x1008
                | 0x1016
                | 0x1017
                | 0x1018
                | 0x2000
                | 0x6007
                | 0x603F
                | 0x6040
                | 0x6041
                | 0x6060
                | 0x6061
                | 0x6064
                | 0x606C
                | 0x6071
                | 0x6077
                | 0x607A
                | 0x60F4
        )
    }

    fn write(&mut self, index: u16, sub: u8, d: &[u8]) -> Result<(), AbortCode> {
        let u = |d: &[u8], n: usize| -> Result<u32, AbortCode> {
            if d.len() != n {
                return Err(AbortCode::LENGTH_MISMATCH);
            }
            let mut b = [0u8; 4];
            b[..n].copy_from_slice(d);
            Ok(u32::from_le_bytes(b))
        };
        match (index, sub) {
            (od::HEARTBEAT_PRODUCER, 0) => {
                self.heartbeat_ms = u(d, 2)? as u16;
                self.next_hb = None;
                Ok(())
            }
            (od::HEARTBEAT_CONSUMER, 1) => {
                let v = u(d, 4)?;
                // Bits 24..31 reserved, node id 1..=127 when a time is given (CiA 301 7.5.2.36).
                let node = (v >> 16) & 0xFF;
                if v >> 24 != 0 || (v & 0xFFFF != 0 && !(1..=127).contains(&node)) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.hb_consumer = v;
                // Monitoring starts again at the producer's next heartbeat.
                self.consumer_last = None;
                self.consumer_lost = false;
                Ok(())
            }
            (od::HEARTBEAT_CONSUMER, 0) => Err(AbortCode::READ_ONLY),
            (od::ABORT_CONNECTION, 0) => {
                let v = u(d, 2)? as u16 as i16;
                if !(0..=3).contains(&v) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.abort_option = v;
                Ok(())
            }
            (0x1400..=0x1403, _) | (0x1800..=0x1803, _) => {
                let rx = index < 0x1800;
                let slot = if rx { &mut self.rpdo[usize::from(index - 0x1400)] } else { &mut self.tpdo[usize::from(index - 0x1800)] };
                let v = match sub {
                    1 => u(d, 4)?,
                    2 => u(d, 1)?,
                    _ => 0,
                };
                slot.write_comm(sub, v)
            }
            (0x1600..=0x1603, _) | (0x1A00..=0x1A03, _) => {
                let rx = index < 0x1A00;
                let slot = if rx { &mut self.rpdo[usize::from(index - 0x1600)] } else { &mut self.tpdo[usize::from(index - 0x1A00)] };
                let v = match sub {
                    0 => u(d, 1)?,
                    1..=8 => u(d, 4)?,
                    _ => 0,
                };
                slot.write_map(rx, sub, v)
            }
            (0x2000, 0) => {
                if d.len() > self.scratch.len() {
                    return Err(AbortCode(0x0607_0012));
                }
                self.scratch[..d.len()].copy_from_slice(d);
                self.scratch_len = d.len();
                Ok(())
            }
            (od::CONTROLWORD, 0) => {
                let v = u(d, 2)? as u16;
                self.on_controlword(v);
                Ok(())
            }
            (od::MODES_OF_OPERATION, 0) => {
                let v = u(d, 1)? as u8 as i8;
                if !matches!(v, 8 | 10) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.mode = v;
                Ok(())
            }
            (od::TARGET_TORQUE, 0) => {
                self.target_torque = u(d, 2)? as u16 as i16;
                Ok(())
            }
            (od::TARGET_POSITION, 0) => {
                self.target_position = u(d, 4)? as i32;
                Ok(())
            }
            (0x1000 | 0x1008 | 0x1018 | 0x603F | 0x6041 | 0x6061 | 0x6064 | 0x606C | 0x6077 | 0x60F4, _) => Err(AbortCode::READ_ONLY),
            _ if self.exists(index) => Err(AbortCode::NO_SUBINDEX),
            _ => Err(AbortCode::NO_OBJECT),
        }
    }
}

fn error_register(code: u16) -> u8 {
    // 0x1001: bit 0 generic, 1 current, 2 voltage, 3 temperature, 4 communication, 5 profile.
    1 | match code >> 12 {
        0x2 => 0x02,
        0x3 => 0x04,
        0x4 => 0x08,
        0x8 => 0x10,
        _ => 0x20,
    }
}

/// Several virtual drives on one transport endpoint.
pub struct DriveRack<T: CanTransport> {
    bus: T,
    drives: Vec<VirtualDrive>,
    /// Transport errors seen (the rack keeps going).
    pub transport_errors: u64,
}

impl<T: CanTransport> DriveRack<T> {
    /// Drives `drives` on `bus`.
    pub fn new(bus: T, drives: Vec<VirtualDrive>) -> Self {
        DriveRack { bus, drives, transport_errors: 0 }
    }

    /// Drives with default parameters for the given node ids.
    pub fn with_nodes(bus: T, nodes: &[NodeId]) -> Self {
        Self::new(bus, nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect())
    }

    /// The drives.
    pub fn drives(&mut self) -> &mut [VirtualDrive] {
        &mut self.drives
    }

    /// The drive with node id `n`.
    pub fn drive(&mut self, n: NodeId) -> Option<&mut VirtualDrive> {
        self.drives.iter_mut().find(|d| d.node_id() == n)
    }

    /// The transport.
    pub fn transport(&mut self) -> &mut T {
        &mut self.bus
    }

    /// Receives everything waiting, runs every drive's timers, sends what they produced.
    pub fn step(&mut self, now: Instant) {
        loop {
            match self.bus.try_recv() {
                Ok(Some(f)) => {
                    for d in &mut self.drives {
                        d.on_frame(&f, now);
                    }
                }
                Ok(None) => break,
                Err(TransportError::Bus(_)) => self.transport_errors += 1,
                Err(_) => {
                    self.transport_errors += 1;
                    break;
                }
            }
        }
        for d in &mut self.drives {
            d.poll(now);
            while let Some(f) = d.poll_tx() {
                if self.bus.send(&f).is_err() {
                    self.transport_errors += 1;
                }
            }
        }
    }

    /// When a drive's timers next need a [`step`](Self::step).
    pub fn next_deadline(&self) -> Option<Instant> {
        self.drives.iter().filter_map(VirtualDrive::next_deadline).min()
    }
}

/// Acceptance filters for a rack of these node ids on a virtual bus: NMT, SYNC, and each
/// node's RPDOs and SDO requests, as a drive's CAN controller would filter.
pub fn rack_filters(nodes: &[NodeId]) -> Vec<Filter> {
    // NMT, SYNC, and every heartbeat (0x700..0x77F): the heartbeat consumer needs the master's.
    let mut f = vec![Filter::exact(0x000), Filter::exact(0x080), Filter { id: 0x700, mask: 0x780, extended: false }];
    for &n in nodes {
        for base in [0x200u16, 0x300, 0x400, 0x500, 0x600] {
            f.push(Filter::exact(base + u16::from(n)));
        }
    }
    f
}

/// A rack running on its own thread in wall-clock time.
pub struct RackHandle {
    drives: Arc<Mutex<Vec<VirtualDrive>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl RackHandle {
    /// Runs `f` on the drives (fault injection, reading state) between two steps.
    pub fn with<R>(&self, f: impl FnOnce(&mut [VirtualDrive]) -> R) -> R {
        let mut g = self.drives.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut g)
    }

    /// Runs `f` on the drive with node id `n`.
    pub fn with_drive<R>(&self, n: NodeId, f: impl FnOnce(&mut VirtualDrive) -> R) -> Option<R> {
        self.with(|ds| ds.iter_mut().find(|d| d.node_id() == n).map(f))
    }

    /// Stops the thread.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        // Relaxed is enough: the flag carries no data, and join() below synchronises.
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for RackHandle {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Runs `drives` on `bus` on a new thread until the handle is stopped or dropped. The thread
/// wakes on every frame and at least every millisecond.
pub fn spawn_rack<T: CanTransport + Send + 'static>(mut bus: T, drives: Vec<VirtualDrive>) -> RackHandle {
    let drives = Arc::new(Mutex::new(drives));
    let stop = Arc::new(AtomicBool::new(false));
    let (d2, s2) = (drives.clone(), stop.clone());
    let thread = std::thread::Builder::new()
        .name("virtual-drives".into())
        .spawn(move || {
            while !s2.load(Ordering::Relaxed) {
                let deadline = Instant::now() + Duration::from_millis(1);
                let first = bus.recv_deadline(deadline);
                let now = Instant::now();
                let mut ds = d2.lock().unwrap_or_else(|e| e.into_inner());
                let deliver = |f: Frame, ds: &mut Vec<VirtualDrive>| {
                    for d in ds.iter_mut() {
                        d.on_frame(&f, now);
                    }
                };
                if let Ok(Some(f)) = first {
                    deliver(f, &mut ds);
                    while let Ok(Some(f)) = bus.try_recv() {
                        deliver(f, &mut ds);
                    }
                }
                for d in ds.iter_mut() {
                    d.poll(now);
                    while let Some(f) = d.poll_tx() {
                        let _ = bus.send(&f);
                    }
                }
            }
        })
        .expect("spawning the virtual drive thread");
    RackHandle { drives, stop, thread: Some(thread) }
}

#[cfg(test)]
mod tests {
    use super::*;

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
