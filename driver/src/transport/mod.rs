//! CAN transports: the only code in the driver that opens sockets.
//!
//! The protocol code ([`crate::canopen`]) only sees [`Frame`]s; a [`CanTransport`] moves them.
//! Three implementations prove the seam: [`socketcan::SocketCanTransport`] (real hardware and
//! vcan), [`virtual_bus::VirtualBus`] (in-process, deterministic, for the simulator, tests and
//! benchmarks) and [`candump`] (record a session to a `candump -l` log, replay a log).

pub mod candump;
pub mod kernel;
pub mod socketcan;
pub mod virtual_bus;

pub use kernel::IfName;

use std::fmt;
use std::time::Instant;

/// Largest standard (11-bit) identifier.
pub const MAX_STD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXT_ID: u32 = 0x1FFF_FFFF;

/// A classic CAN 2.0 frame. `Copy`, fixed size, no allocation.
///
/// `data[dlc..]` is always zero, so two frames with the same content compare equal.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Frame {
    /// Identifier: 11 bits, or 29 bits when `extended`.
    pub id: u32,
    /// 29-bit identifier format (CAN 2.0B).
    pub extended: bool,
    /// Remote transmission request: no data, `dlc` is the requested length.
    pub rtr: bool,
    /// Data length code, 0..=8.
    pub dlc: u8,
    /// Payload; bytes past `dlc` are zero.
    pub data: [u8; 8],
}

impl Frame {
    /// A standard-id data frame. Ids are masked to 11 bits and data cut to 8 bytes: protocol code
    /// builds frames from constants, so a checked constructor would only add unwraps.
    pub fn new(id: u16, data: &[u8]) -> Frame {
        let n = data.len().min(8);
        let mut d = [0u8; 8];
        d[..n].copy_from_slice(&data[..n]);
        Frame { id: u32::from(id) & MAX_STD_ID, extended: false, rtr: false, dlc: n as u8, data: d }
    }

    /// A data frame from raw parts, checked: `None` if the id does not fit its format or
    /// `data` is longer than 8 bytes.
    pub fn try_new(id: u32, extended: bool, data: &[u8]) -> Option<Frame> {
        let max = if extended { MAX_EXT_ID } else { MAX_STD_ID };
        if id > max || data.len() > 8 {
            return None;
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Some(Frame { id, extended, rtr: false, dlc: data.len() as u8, data: d })
    }

    /// A remote frame (RTR) requesting `dlc` bytes.
    pub fn remote(id: u32, extended: bool, dlc: u8) -> Option<Frame> {
        let max = if extended { MAX_EXT_ID } else { MAX_STD_ID };
        (id <= max && dlc <= 8).then_some(Frame { id, extended, rtr: true, dlc, data: [0; 8] })
    }

    /// The payload, `dlc` bytes (empty for remote frames).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..usize::from(self.dlc.min(8))]
        }
    }

    /// The 11-bit id if this is a standard data frame (what CANopen uses), else `None`.
    pub fn std_id(&self) -> Option<u16> {
        (!self.extended && !self.rtr).then_some(self.id as u16)
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // candump spelling: readable in test failures and greppable in logs.
        if self.extended {
            write!(f, "{:08X}#", self.id)?;
        } else {
            write!(f, "{:03X}#", self.id)?;
        }
        if self.rtr {
            return write!(f, "R{}", self.dlc);
        }
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// A controller or bus problem reported by the CAN interface (SocketCAN error frames,
/// `linux/can/error.h`). The most severe condition of one error frame is reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BusEvent {
    /// The controller went bus-off (TX error counter > 255): it takes no part in bus traffic
    /// until restarted (`ip link set can0 type can restart-ms 100`).
    BusOff,
    /// Error-passive (an error counter > 127): the controller may no longer signal errors.
    ErrorPassive {
        /// TX error counter, if reported.
        tx: u8,
        /// RX error counter, if reported.
        rx: u8,
    },
    /// Error warning level (an error counter > 95).
    ErrorWarning {
        /// TX error counter, if reported.
        tx: u8,
        /// RX error counter, if reported.
        rx: u8,
    },
    /// Back to error-active.
    ErrorActive,
    /// A receive or transmit buffer of the controller overflowed: frames were lost.
    Overflow,
    /// A transmitted frame was not acknowledged: no other node on the bus, or wrong bitrate.
    NoAck,
    /// Protocol violation (bit, stuff, form, CRC error) seen by the controller.
    Protocol,
    /// Transceiver fault (CAN_H / CAN_L wiring).
    Transceiver,
    /// The controller was restarted after bus-off.
    Restarted,
    /// The driver gave up sending a frame.
    TxTimeout,
    /// Lost arbitration (normal on a busy bus, reported only when asked for).
    LostArbitration,
    /// Error class bits this driver does not know.
    Other(u32),
}

impl BusEvent {
    /// Decodes a SocketCAN error frame: `class` is the id without `CAN_ERR_FLAG`, `data` its 8
    /// bytes.
    ///
    /// ```text
    /// id bits (linux/can/error.h)       data
    /// 0x001 TX timeout                   [1] controller: 0x01 rx ovfl, 0x02 tx ovfl,
    /// 0x002 lost arbitration                 0x04/0x08 rx/tx warning, 0x10/0x20 rx/tx passive,
    /// 0x004 controller problem (data[1])     0x40 back to error active
    /// 0x008 protocol violation           [2..3] protocol violation type / location
    /// 0x010 transceiver                  [4] transceiver status
    /// 0x020 no ACK                       [6] TX error counter, [7] RX error counter
    /// 0x040 bus-off   0x080 bus error   0x100 restarted   0x200 counters valid
    /// ```
    pub fn from_error_frame(class: u32, data: &[u8; 8]) -> BusEvent {
        let (tx, rx) = (data[6], data[7]);
        let ctrl = data[1];
        if class & 0x040 != 0 {
            BusEvent::BusOff
        } else if class & 0x004 != 0 && ctrl & 0x30 != 0 {
            BusEvent::ErrorPassive { tx, rx }
        } else if class & 0x004 != 0 && ctrl & 0x0C != 0 {
            BusEvent::ErrorWarning { tx, rx }
        } else if class & 0x004 != 0 && ctrl & 0x03 != 0 {
            BusEvent::Overflow
        } else if class & 0x004 != 0 && ctrl & 0x40 != 0 {
            BusEvent::ErrorActive
        } else if class & 0x100 != 0 {
            BusEvent::Restarted
        } else if class & 0x020 != 0 {
            BusEvent::NoAck
        } else if class & 0x010 != 0 {
            BusEvent::Transceiver
        } else if class & 0x008 != 0 || class & 0x080 != 0 {
            BusEvent::Protocol
        } else if class & 0x001 != 0 {
            BusEvent::TxTimeout
        } else if class & 0x002 != 0 {
            BusEvent::LostArbitration
        } else {
            BusEvent::Other(class)
        }
    }

    /// True for conditions in which frames are being lost (bus-off, overflow).
    pub fn is_severe(&self) -> bool {
        matches!(self, BusEvent::BusOff | BusEvent::Overflow)
    }
}

impl fmt::Display for BusEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusEvent::BusOff => write!(f, "bus-off: the CAN controller stopped; check wiring, termination and bitrate"),
            BusEvent::ErrorPassive { tx, rx } => write!(f, "error-passive (tx errors {tx}, rx errors {rx})"),
            BusEvent::ErrorWarning { tx, rx } => write!(f, "error warning (tx errors {tx}, rx errors {rx})"),
            BusEvent::ErrorActive => write!(f, "back to error-active"),
            BusEvent::Overflow => write!(f, "controller buffer overflow: frames lost"),
            BusEvent::NoAck => write!(f, "no ACK: no other node acknowledged (bus unpowered or wrong bitrate?)"),
            BusEvent::Protocol => write!(f, "protocol violation on the bus"),
            BusEvent::Transceiver => write!(f, "transceiver fault (CAN_H/CAN_L)"),
            BusEvent::Restarted => write!(f, "controller restarted"),
            BusEvent::TxTimeout => write!(f, "transmit timeout"),
            BusEvent::LostArbitration => write!(f, "lost arbitration"),
            BusEvent::Other(c) => write!(f, "unknown CAN error class 0x{c:03X}"),
        }
    }
}

/// What can go wrong moving a frame. `Copy`: no allocation on the real-time path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransportError {
    /// The interface reported a bus or controller problem (an error frame). Not fatal: the
    /// caller counts it and carries on receiving.
    Bus(BusEvent),
    /// The transmit queue is full; the frame was not sent (it is handed back).
    Full(Frame),
    /// The other side is gone (virtual bus dropped, end of a replayed log).
    Closed,
    /// An operating-system error.
    Io(std::io::ErrorKind),
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransportError::Bus(e) => write!(f, "CAN bus: {e}"),
            TransportError::Full(fr) => write!(f, "transmit queue full, frame {fr:?} not sent"),
            TransportError::Closed => write!(f, "transport closed"),
            TransportError::Io(k) => write!(f, "CAN socket I/O error: {k}"),
        }
    }
}

impl std::error::Error for TransportError {}

/// A CAN interface: send a frame, receive without blocking, receive with a deadline.
pub trait CanTransport {
    /// Queues one frame for transmission.
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError>;
    /// Returns a received frame if one is waiting, `Ok(None)` if none is.
    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError>;
    /// Waits for a frame until `deadline`; `Ok(None)` when the deadline passed without one.
    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError>;
    /// The interface's name, for messages about it ("can0: bus-off"). Transports without one
    /// say `can`.
    fn iface(&self) -> IfName {
        IfName::new("can")
    }
}

impl<T: CanTransport + ?Sized> CanTransport for Box<T> {
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        (**self).send(frame)
    }
    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        (**self).try_recv()
    }
    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        (**self).recv_deadline(deadline)
    }
    fn iface(&self) -> IfName {
        (**self).iface()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_constructors_zero_the_tail() {
        let f = Frame::new(0x123, &[1, 2, 3]);
        assert_eq!(f.data(), &[1, 2, 3]);
        assert_eq!(f.data[3..], [0; 5]);
        assert_eq!(format!("{f:?}"), "123#010203");
        assert!(Frame::try_new(0x800, false, &[]).is_none());
        assert!(Frame::try_new(0x800, true, &[]).is_some());
        assert!(Frame::try_new(0x1, false, &[0; 9]).is_none());
        assert_eq!(Frame::remote(0x321, false, 4).unwrap().data(), &[] as &[u8]);
    }

    #[test]
    fn error_frames_decode_most_severe_first() {
        let mut d = [0u8; 8];
        assert_eq!(BusEvent::from_error_frame(0x040 | 0x004, &d), BusEvent::BusOff);
        d[1] = 0x20;
        d[6] = 130;
        assert_eq!(BusEvent::from_error_frame(0x004 | 0x200, &d), BusEvent::ErrorPassive { tx: 130, rx: 0 });
        d[1] = 0x08;
        assert!(matches!(BusEvent::from_error_frame(0x004, &d), BusEvent::ErrorWarning { .. }));
        assert_eq!(BusEvent::from_error_frame(0x020, &[0; 8]), BusEvent::NoAck);
        assert_eq!(BusEvent::from_error_frame(0x400, &[0; 8]), BusEvent::Other(0x400));
    }
}
