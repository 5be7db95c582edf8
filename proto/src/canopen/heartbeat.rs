//! Heartbeat protocol (CiA 301 7.2.8.3.2.2): producer frames and a per-node consumer.
//!
//! ```text
//! COB-ID 0x700 + node, 1 byte: [0] NMT state (0x00 boot-up, 0x04 stopped, 0x05 operational,
//!                                             0x7F pre-operational)
//! ```

use super::nmt::NmtState;
use super::NodeId;
use crate::can::Frame;
use std::time::{Duration, Instant};

/// Base COB-ID of heartbeat / boot-up messages.
pub const HEARTBEAT_BASE: u16 = 0x700;

/// Builds the heartbeat (or boot-up, with [`NmtState::BootUp`]) of `node`.
pub fn encode(node: NodeId, state: NmtState) -> Frame {
    Frame::new(HEARTBEAT_BASE + u16::from(node & 0x7F), &[state as u8])
}

/// Why a heartbeat frame was not understood.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeartbeatError {
    /// Not exactly 1 data byte.
    Length(u8),
    /// A state byte that is no NMT state.
    State(u8),
}

/// Decodes the payload of a `0x700 + node` frame.
pub fn decode(data: &[u8]) -> Result<NmtState, HeartbeatError> {
    if data.len() != 1 {
        return Err(HeartbeatError::Length(data.len() as u8));
    }
    NmtState::from_u8(data[0]).ok_or(HeartbeatError::State(data[0]))
}

/// Watches one producer: it is lost when no heartbeat came within `timeout`.
#[derive(Debug, Clone, Copy)]
pub struct HeartbeatConsumer {
    timeout: Duration,
    last: Option<Instant>,
    lost: bool,
}

impl HeartbeatConsumer {
    /// A consumer that is not yet watching (it starts at the first heartbeat).
    pub fn new(timeout: Duration) -> Self {
        HeartbeatConsumer { timeout, last: None, lost: false }
    }

    /// Records a heartbeat. Returns true if the producer had been lost and is back.
    pub fn on_heartbeat(&mut self, now: Instant) -> bool {
        self.last = Some(now);
        std::mem::replace(&mut self.lost, false)
    }

    /// Checks the timeout. Returns true once, at the moment the producer is declared lost.
    pub fn check(&mut self, now: Instant) -> bool {
        match self.last {
            Some(t) if !self.lost && now.saturating_duration_since(t) > self.timeout => {
                self.lost = true;
                true
            }
            _ => false,
        }
    }

    /// True while the producer is lost.
    pub fn is_lost(&self) -> bool {
        self.lost
    }

    /// When the producer will be declared lost if nothing comes, if watching.
    pub fn deadline(&self) -> Option<Instant> {
        match self.last {
            Some(t) if !self.lost => Some(t + self.timeout),
            _ => None,
        }
    }

    /// Stops watching (e.g. the node was reset on purpose).
    pub fn reset(&mut self) {
        self.last = None;
        self.lost = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_errors() {
        for s in [NmtState::BootUp, NmtState::Stopped, NmtState::Operational, NmtState::PreOperational] {
            let f = encode(5, s);
            assert_eq!(f.id, 0x705);
            assert_eq!(decode(f.data()), Ok(s));
        }
        assert_eq!(decode(&[]), Err(HeartbeatError::Length(0)));
        assert_eq!(decode(&[5, 5]), Err(HeartbeatError::Length(2)));
        assert_eq!(decode(&[0x33]), Err(HeartbeatError::State(0x33)));
    }

    #[test]
    fn consumer_times_out_once_and_recovers() {
        let t0 = Instant::now();
        let mut c = HeartbeatConsumer::new(Duration::from_millis(100));
        assert!(!c.check(t0 + Duration::from_secs(10)), "not watching before the first heartbeat");
        c.on_heartbeat(t0);
        assert!(!c.check(t0 + Duration::from_millis(100)));
        assert!(c.check(t0 + Duration::from_millis(101)));
        assert!(!c.check(t0 + Duration::from_millis(200)), "reported once");
        assert!(c.is_lost());
        assert!(c.on_heartbeat(t0 + Duration::from_millis(300)));
        assert!(!c.is_lost());
    }
}
