//! CAN bus status vocabulary shared by the transports (`taut-driver`, which decodes SocketCAN
//! error frames into it) and the real-time loop (`taut-rt`, whose safety causes carry it). Both
//! are `Copy` and fixed size so that they can ride in causes and events on the real-time path.

use std::fmt;

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

/// A network interface name (`IFNAMSIZ` = 16 with the NUL: at most 15 bytes), `Copy` so it
/// can ride in causes and events on the real-time path. Longer names are cut at 15 bytes (on
/// a character boundary).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct IfName {
    len: u8,
    bytes: [u8; 15],
}

impl IfName {
    /// The name `s`, cut to 15 bytes.
    pub fn new(s: &str) -> IfName {
        let mut n = s.len().min(15);
        while !s.is_char_boundary(n) {
            n -= 1;
        }
        let mut bytes = [0u8; 15];
        bytes[..n].copy_from_slice(&s.as_bytes()[..n]);
        IfName { len: n as u8, bytes }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        // Built from a &str cut on a character boundary.
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("?")
    }
}

impl fmt::Display for IfName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for IfName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}
