//! An in-process CAN bus: every frame sent by one endpoint is delivered to every other endpoint
//! whose acceptance filters match, in send order. Deterministic: no threads or timers of its own,
//! so tests that drive all endpoints from one thread see the same frames in the same order every
//! run. Endpoints are `Send`, so threads may own them too (`recv_deadline` then blocks).
//!
//! Queues are allocated when an endpoint is made; a full receive queue drops the new frame and
//! counts it, like a SocketCAN socket whose buffer is full.
//!
//! ```
//! use taut_driver::transport::{virtual_bus::VirtualBus, CanTransport, Frame};
//! let bus = VirtualBus::new();
//! let (mut a, mut b) = (bus.endpoint(), bus.endpoint());
//! a.send(&Frame::new(0x080, &[])).unwrap();
//! assert_eq!(b.try_recv().unwrap(), Some(Frame::new(0x080, &[])));
//! assert_eq!(a.try_recv().unwrap(), None); // no echo to the sender
//! ```

use super::{CanTransport, Frame, TransportError};
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

/// Receive queue length of an endpoint, frames.
pub const DEFAULT_QUEUE: usize = 4096;

/// An acceptance filter, as SocketCAN's `CAN_RAW_FILTER`: a frame passes when
/// `frame.id & mask == id & mask` and its format (standard/extended) equals `extended`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Filter {
    /// Identifier to compare.
    pub id: u32,
    /// Bits of the identifier that must match.
    pub mask: u32,
    /// Frame format the filter applies to.
    pub extended: bool,
}

impl Filter {
    /// A filter for one standard id.
    pub const fn exact(id: u16) -> Filter {
        Filter { id: id as u32, mask: 0x7FF, extended: false }
    }

    fn accepts(&self, f: &Frame) -> bool {
        f.extended == self.extended && (f.id & self.mask) == (self.id & self.mask)
    }
}

struct Slot {
    alive: bool,
    queue: VecDeque<Frame>,
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
    /// An empty bus.
    pub fn new() -> VirtualBus {
        VirtualBus {
            shared: Arc::new(Shared {
                state: Mutex::new(State { slots: Vec::new(), waiters: 0, sent: 0 }),
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
        });
        VirtualEndpoint { shared: self.shared.clone(), idx: st.slots.len() - 1 }
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
        st.sent += 1;
        for (i, slot) in st.slots.iter_mut().enumerate() {
            if i == self.idx || !slot.alive {
                continue;
            }
            if !slot.filters.is_empty() && !slot.filters.iter().any(|f| f.accepts(frame)) {
                continue;
            }
            if slot.queue.len() >= slot.capacity {
                slot.dropped += 1;
            } else {
                slot.queue.push_back(*frame);
            }
        }
        if st.waiters > 0 {
            self.shared.cv.notify_all();
        }
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        Ok(lock(&self.shared).slots[self.idx].queue.pop_front())
    }

    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        let mut st = lock(&self.shared);
        loop {
            if let Some(f) = st.slots[self.idx].queue.pop_front() {
                return Ok(Some(f));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            st.waiters += 1;
            let (guard, _) = self
                .shared
                .cv
                .wait_timeout(st, deadline - now)
                .unwrap_or_else(|e| e.into_inner());
            st = guard;
            st.waiters -= 1;
        }
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
}
