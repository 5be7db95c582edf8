//! Classic CAN frames and the transport seam: [`Frame`] (`Copy`, 8 data bytes), the
//! [`CanTransport`] trait that moves them, [`TransportError`], and the acceptance [`Filter`].
//!
//! No transport opens anything here: the implementations live with the master
//! (`taut_driver::transport`: SocketCAN, the in-process bus, candump logs) and the device side
//! takes any of them through the trait. The bus status types come from `taut-model`, where the
//! real-time loop can name them too.

use taut_model::bus::{BusEvent, IfName};

use std::fmt;
use std::time::Instant;

/// Largest standard (11-bit) identifier.
pub const MAX_STD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXT_ID: u32 = 0x1FFF_FFFF;

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

    /// Whether `f` passes this filter.
    pub fn accepts(&self, f: &Frame) -> bool {
        f.extended == self.extended && (f.id & self.mask) == (self.id & self.mask)
    }
}

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
    /// When the frame returned last by `try_recv` or `recv_deadline` was on the bus, if the
    /// transport knows (the kernel's `SO_TIMESTAMP`; the in-process bus stamps every frame as it
    /// is sent); `None` otherwise, and then the receiver's own clock is the best there is.
    fn rx_timestamp(&self) -> Option<Instant> {
        None
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
    fn rx_timestamp(&self) -> Option<Instant> {
        (**self).rx_timestamp()
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
