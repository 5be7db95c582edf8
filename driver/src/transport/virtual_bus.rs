//! An in-process CAN bus: every frame sent by one endpoint is delivered to every other endpoint
//! whose acceptance filters match, in send order. Deterministic: no threads or timers of its own,
//! so tests that drive all endpoints from one thread see the same frames in the same order every
//! run. Endpoints are `Send`, so threads may own them too (`recv_deadline` then blocks).
//!
//! Queues are allocated when an endpoint is made; a full receive queue drops the new frame and
//! counts it, like a SocketCAN socket whose buffer is full.
//!
//! Every frame carries the instant it was sent, which is when it was on the wire (no
//! arbitration delay): [`CanTransport::rx_timestamp`] hands it out, as the kernel's
//! `SO_TIMESTAMP` does.
//!
//! Frames travel as the kernel's `struct can_frame` bytes through [`kernel::decode`], the parser
//! of SocketCAN reads. Each endpoint's [`CanController`] injects error frames
//! (`linux/can/error.h`), bus-off and restarts as the kernel's CAN drivers report them.
//!
//! ```
//! use taut_driver::transport::virtual_bus::VirtualBus;
//! use taut_proto::can::{CanTransport, Frame};
//! let bus = VirtualBus::new();
//! let (mut a, mut b) = (bus.endpoint(), bus.endpoint());
//! a.send(&Frame::new(0x080, &[])).unwrap();
//! assert_eq!(b.try_recv().unwrap(), Some(Frame::new(0x080, &[])));
//! assert_eq!(a.try_recv().unwrap(), None); // no echo to the sender
//! ```

use super::kernel::{self, err, CAN_MTU};
use super::{CanTransport, Filter, Frame, IfName, TransportError};
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

/// Receive queue length of an endpoint, frames.
pub const DEFAULT_QUEUE: usize = 4096;

struct Slot {
    alive: bool,
    /// `struct can_frame` bytes, decoded on receipt, and the instant they were sent.
    queue: VecDeque<([u8; CAN_MTU], Instant)>,
    /// The endpoint's controller is bus-off: it neither sends nor receives.
    bus_off: bool,
    /// Frames not sent because the controller was bus-off.
    tx_lost: u64,
    capacity: usize,
    filters: Vec<Filter>,
    dropped: u64,
}

struct State {
    slots: Vec<Slot>,
    /// Endpoints blocked in `recv_deadline`; the sender notifies only when there are any, so the
    /// single-threaded (test, benchmark) case makes no futex call.
    waiters: usize,
    sent: u64,
    name: IfName,
}

struct Shared {
    state: Mutex<State>,
    cv: Condvar,
}

/// The bus: a factory of endpoints. Cheap to clone (all clones are the same bus).
#[derive(Clone)]
pub struct VirtualBus {
    shared: Arc<Shared>,
}

impl Default for VirtualBus {
    fn default() -> Self {
        Self::new()
    }
}

impl VirtualBus {
    /// An empty bus named `virtual`.
    pub fn new() -> VirtualBus {
        Self::named("virtual")
    }

    /// An empty bus whose endpoints call their interface `name` (at most 15 bytes are kept).
    pub fn named(name: &str) -> VirtualBus {
        VirtualBus {
            shared: Arc::new(Shared {
                state: Mutex::new(State { slots: Vec::new(), waiters: 0, sent: 0, name: IfName::new(name) }),
                cv: Condvar::new(),
            }),
        }
    }

    /// Connects a new endpoint that accepts every frame.
    pub fn endpoint(&self) -> VirtualEndpoint {
        self.endpoint_with(DEFAULT_QUEUE, &[])
    }

    /// Connects a new endpoint with a receive queue of `capacity` frames and acceptance
    /// `filters` (none: accept all).
    pub fn endpoint_with(&self, capacity: usize, filters: &[Filter]) -> VirtualEndpoint {
        let mut st = lock(&self.shared);
        st.slots.push(Slot {
            alive: true,
            queue: VecDeque::with_capacity(capacity),
            capacity,
            filters: filters.to_vec(),
            dropped: 0,
            bus_off: false,
            tx_lost: 0,
        });
        VirtualEndpoint { shared: self.shared.clone(), idx: st.slots.len() - 1, rx_at: None }
    }

    /// Frames sent on the bus so far.
    pub fn frames_sent(&self) -> u64 {
        lock(&self.shared).sent
    }
}

fn lock(shared: &Shared) -> MutexGuard<'_, State> {
    // A panic in another endpoint's thread must not take the bus down with it: the state is a
    // set of queues that stays consistent between operations.
    shared.state.lock().unwrap_or_else(|e| e.into_inner())
}

/// One node's connection to a [`VirtualBus`].
pub struct VirtualEndpoint {
    shared: Arc<Shared>,
    idx: usize,
    /// When the frame received last was sent.
    rx_at: Option<Instant>,
}

impl VirtualEndpoint {
    /// Replaces the acceptance filters (none: accept all). Allocates: call at start-up.
    pub fn set_filters(&mut self, filters: &[Filter]) {
        lock(&self.shared).slots[self.idx].filters = filters.to_vec();
    }

    /// Frames dropped because this endpoint's queue was full.
    pub fn dropped(&self) -> u64 {
        lock(&self.shared).slots[self.idx].dropped
    }

    /// Frames waiting in this endpoint's queue.
    pub fn pending(&self) -> usize {
        lock(&self.shared).slots[self.idx].queue.len()
    }

    /// A handle on this endpoint's CAN controller, for fault injection from another thread.
    pub fn controller(&self) -> CanController {
        CanController { shared: self.shared.clone(), idx: self.idx }
    }
}

/// The CAN controller of one endpoint, as a test drives it: error frames in the kernel's
/// format, bus-off and restart. Cheap to clone; `Send`.
#[derive(Clone)]
pub struct CanController {
    shared: Arc<Shared>,
    idx: usize,
}

impl CanController {
    /// Delivers an error frame (`struct can_frame` bytes with `CAN_ERR_FLAG`, see
    /// [`kernel::error_frame`]) to the endpoint. Error frames pass the acceptance filters and
    /// reach a bus-off endpoint; any 16 bytes are taken and decoded by the endpoint's reader.
    pub fn inject(&self, frame: [u8; CAN_MTU]) {
        let mut st = lock(&self.shared);
        let slot = &mut st.slots[self.idx];
        if slot.queue.len() >= slot.capacity {
            slot.dropped += 1;
        } else {
            slot.queue.push_back((frame, Instant::now()));
        }
        if st.waiters > 0 {
            self.shared.cv.notify_all();
        }
    }

    /// The controller goes bus-off: the endpoint sends nothing (sends fail with
    /// [`TransportError::Full`]) and receives only error frames, the first `CAN_ERR_BUSOFF`.
    pub fn bus_off(&self) {
        lock(&self.shared).slots[self.idx].bus_off = true;
        self.inject(kernel::error_frame(err::BUSOFF | err::CNT, [0, 0, 0, 0, 0, 0, 255, 0]));
    }

    /// The controller is restarted after bus-off (`restart-ms`, or `ip link set can0 type can
    /// restart`): it takes part in traffic again, and the driver reports `CAN_ERR_RESTARTED`.
    pub fn restart(&self) {
        lock(&self.shared).slots[self.idx].bus_off = false;
        self.inject(kernel::error_frame(err::RESTARTED, [0; 8]));
    }

    /// True while the controller is bus-off.
    pub fn is_bus_off(&self) -> bool {
        lock(&self.shared).slots[self.idx].bus_off
    }

    /// Frames the endpoint could not send because its controller was bus-off.
    pub fn tx_lost(&self) -> u64 {
        lock(&self.shared).slots[self.idx].tx_lost
    }
}

impl Drop for VirtualEndpoint {
    fn drop(&mut self) {
        let mut st = lock(&self.shared);
        let slot = &mut st.slots[self.idx];
        slot.alive = false;
        slot.queue = VecDeque::new();
    }
}

impl CanTransport for VirtualEndpoint {
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        let mut st = lock(&self.shared);
        if st.slots[self.idx].bus_off {
            st.slots[self.idx].tx_lost += 1;
            return Err(TransportError::Full(*frame));
        }
        st.sent += 1;
        let bytes = (kernel::encode(frame), Instant::now());
        for (i, slot) in st.slots.iter_mut().enumerate() {
            if i == self.idx || !slot.alive || slot.bus_off {
                continue;
            }
            if !slot.filters.is_empty() && !slot.filters.iter().any(|f| f.accepts(frame)) {
                continue;
            }
            if slot.queue.len() >= slot.capacity {
                slot.dropped += 1;
            } else {
                slot.queue.push_back(bytes);
            }
        }
        if st.waiters > 0 {
            self.shared.cv.notify_all();
        }
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        let popped = lock(&self.shared).slots[self.idx].queue.pop_front();
        popped.map(|(b, at)| self.received(&b, at)).transpose()
    }

    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        let mut st = lock(&self.shared);
        loop {
            if let Some((b, at)) = st.slots[self.idx].queue.pop_front() {
                drop(st);
                return self.received(&b, at).map(Some);
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            st.waiters += 1;
            let (guard, _) = self.shared.cv.wait_timeout(st, deadline - now).unwrap_or_else(|e| e.into_inner());
            st = guard;
            st.waiters -= 1;
        }
    }

    fn iface(&self) -> IfName {
        lock(&self.shared).name
    }

    fn rx_timestamp(&self) -> Option<Instant> {
        self.rx_at
    }
}

impl VirtualEndpoint {
    fn received(&mut self, bytes: &[u8; CAN_MTU], sent: Instant) -> Result<Frame, TransportError> {
        self.rx_at = Some(sent);
        kernel::decode(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn every_other_endpoint_gets_every_frame_in_order() {
        let bus = VirtualBus::new();
        let mut eps: Vec<_> = (0..3).map(|_| bus.endpoint()).collect();
        for i in 0..10u8 {
            eps[(i % 3) as usize].send(&Frame::new(0x100 + u16::from(i), &[i])).unwrap();
        }
        for (k, ep) in eps.iter_mut().enumerate() {
            let mut got = vec![];
            while let Some(f) = ep.try_recv().unwrap() {
                got.push(f.data[0]);
            }
            let want: Vec<u8> = (0..10).filter(|i| (i % 3) as usize != k).collect();
            assert_eq!(got, want);
        }
        assert_eq!(bus.frames_sent(), 10);
    }

    #[test]
    fn filters_and_overflow() {
        let bus = VirtualBus::new();
        let mut tx = bus.endpoint();
        let mut rx = bus.endpoint_with(2, &[Filter::exact(0x181)]);
        for _ in 0..3 {
            tx.send(&Frame::new(0x181, &[1])).unwrap();
            tx.send(&Frame::new(0x182, &[2])).unwrap();
        }
        assert_eq!(rx.pending(), 2);
        assert_eq!(rx.dropped(), 1);
        assert_eq!(rx.try_recv().unwrap().unwrap().id, 0x181);
    }

    #[test]
    fn recv_deadline_wakes_on_a_frame_from_another_thread() {
        let bus = VirtualBus::new();
        let mut rx = bus.endpoint();
        let mut tx = bus.endpoint();
        let t = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            tx.send(&Frame::new(0x7, &[7])).unwrap();
        });
        let got = rx.recv_deadline(Instant::now() + Duration::from_secs(10)).unwrap();
        assert_eq!(got, Some(Frame::new(0x7, &[7])));
        t.join().unwrap();
        assert_eq!(rx.recv_deadline(Instant::now() + Duration::from_millis(5)).unwrap(), None);
    }

    /// A frame read late still says when it was on the bus (the simulated drives latch at it).
    #[test]
    fn a_frame_carries_its_send_instant() {
        let bus = VirtualBus::new();
        let (mut tx, mut rx) = (bus.endpoint(), bus.endpoint());
        assert_eq!(rx.rx_timestamp(), None);
        let before = Instant::now();
        tx.send(&Frame::new(0x080, &[])).unwrap();
        let after = Instant::now();
        std::thread::sleep(Duration::from_millis(20));
        assert!(rx.recv_deadline(Instant::now() + Duration::from_secs(1)).unwrap().is_some());
        let at = rx.rx_timestamp().expect("stamped");
        assert!(at >= before && at <= after, "stamped at sending, not at reading");
        tx.send(&Frame::new(0x081, &[])).unwrap();
        std::thread::sleep(Duration::from_millis(5));
        assert!(rx.try_recv().unwrap().is_some());
        assert!(rx.rx_timestamp().unwrap() > after);
    }

    #[test]
    fn a_bus_off_endpoint_neither_sends_nor_receives_until_restarted() {
        use crate::transport::BusEvent;
        let bus = VirtualBus::named("can7");
        let mut master = bus.endpoint_with(16, &[Filter::exact(0x181)]);
        let mut drive = bus.endpoint();
        assert_eq!(master.iface().as_str(), "can7");
        let ctl = master.controller();
        ctl.bus_off();
        // The error frame passes the id filters and comes out through the kernel-frame parser.
        assert_eq!(master.try_recv(), Err(TransportError::Bus(BusEvent::BusOff)));
        drive.send(&Frame::new(0x181, &[1])).unwrap();
        assert_eq!(master.try_recv().unwrap(), None, "nothing received while off");
        let f = Frame::new(0x201, &[2]);
        assert_eq!(master.send(&f), Err(TransportError::Full(f)));
        assert_eq!(drive.try_recv().unwrap(), None, "nothing sent while off");
        assert_eq!(ctl.tx_lost(), 1);
        ctl.restart();
        assert_eq!(master.try_recv(), Err(TransportError::Bus(BusEvent::Restarted)));
        master.send(&f).unwrap();
        assert_eq!(drive.try_recv().unwrap(), Some(f));
        // Garbage bytes injected as a frame are refused by the parser, not trusted.
        ctl.inject([0xFF; 16]);
        assert!(matches!(master.try_recv(), Err(TransportError::Bus(_)) | Err(TransportError::Io(_))));
    }
}
