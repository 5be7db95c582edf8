//! The Linux kernel's classic CAN frame (`struct can_frame`, `linux/can.h`) as bytes, and the
//! name of a CAN interface.
//!
//! Every frame a `CAN_RAW` socket hands out is these 16 bytes, error frames included.
//! [`decode`] is their one parser: SocketCAN reads and the virtual bus (with the error frames a
//! test injects) go through it, so an injected bus-off takes the path a real one takes.
//!
//! ```text
//! offset  size  field (struct can_frame)
//!  0      4     can_id   host byte order: bits 0..28 id, 29 CAN_ERR_FLAG, 30 CAN_RTR_FLAG,
//!                        31 CAN_EFF_FLAG; in an error frame bits 0..28 are the error class
//!  4      1     len      payload length 0..=8 (CAN_ERR_DLC = 8 for error frames)
//!  5      1     __pad
//!  6      1     __res0
//!  7      1     len8_dlc (classic CAN with 8 bytes: DLC 9..15, unused here)
//!  8      8     data     (error frames: [1] controller, [2..3] protocol, [4] transceiver,
//!                         [6] TX error counter, [7] RX error counter)
//! ```

use super::{BusEvent, Frame, TransportError, MAX_EXT_ID, MAX_STD_ID};

/// `CAN_MTU`: size of `struct can_frame`.
pub const CAN_MTU: usize = 16;
/// `CAN_EFF_FLAG`: 29-bit identifier.
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// `CAN_RTR_FLAG`: remote frame.
pub const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// `CAN_ERR_FLAG`: error frame.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// `CAN_ERR_MASK`: error class bits of an error frame's id.
pub const CAN_ERR_MASK: u32 = 0x1FFF_FFFF;

/// Error class bits and controller status bytes of `linux/can/error.h`, for building error
/// frames in tests and simulations.
pub mod err {
    /// Controller problem; details in data\[1\].
    pub const CRTL: u32 = 0x0004;
    /// Bus-off.
    pub const BUSOFF: u32 = 0x0040;
    /// Controller restarted.
    pub const RESTARTED: u32 = 0x0100;
    /// data\[6\], data\[7\] hold the TX/RX error counters.
    pub const CNT: u32 = 0x0200;
    /// data\[1\]: RX buffer overflow.
    pub const CRTL_RX_OVERFLOW: u8 = 0x01;
    /// data\[1\]: reached warning level for TX errors.
    pub const CRTL_TX_WARNING: u8 = 0x08;
    /// data\[1\]: reached error-passive status TX.
    pub const CRTL_TX_PASSIVE: u8 = 0x20;
    /// data\[1\]: recovered to error-active state.
    pub const CRTL_ACTIVE: u8 = 0x40;
}

/// Encodes a data or remote frame as `struct can_frame` (host byte order, as the kernel
/// wants it on `write(2)`).
pub fn encode(f: &Frame) -> [u8; CAN_MTU] {
    let mut id = f.id & if f.extended { MAX_EXT_ID } else { MAX_STD_ID };
    if f.extended {
        id |= CAN_EFF_FLAG;
    }
    if f.rtr {
        id |= CAN_RTR_FLAG;
    }
    let mut b = [0u8; CAN_MTU];
    b[..4].copy_from_slice(&id.to_ne_bytes());
    b[4] = f.dlc.min(8);
    if !f.rtr {
        b[8..].copy_from_slice(&f.data);
    }
    b
}

/// Builds an error frame as the kernel sends it: `class` bits of `linux/can/error.h` (see
/// [`err`]) and the 8 data bytes.
pub fn error_frame(class: u32, data: [u8; 8]) -> [u8; CAN_MTU] {
    let mut b = [0u8; CAN_MTU];
    b[..4].copy_from_slice(&(CAN_ERR_FLAG | (class & CAN_ERR_MASK)).to_ne_bytes());
    b[4] = 8;
    b[8..].copy_from_slice(&data);
    b
}

/// Decodes `struct can_frame` bytes: a data or remote frame, or, for an error frame,
/// [`TransportError::Bus`] with the decoded [`BusEvent`]. Bytes that are no classic CAN frame
/// (short read, length above 8, an id with bits outside its format) are
/// [`TransportError::Io`]`(InvalidData)`: they come from outside and are not trusted.
pub fn decode(b: &[u8]) -> Result<Frame, TransportError> {
    let bad = TransportError::Io(std::io::ErrorKind::InvalidData);
    if b.len() != CAN_MTU {
        return Err(bad);
    }
    let word = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
    let len = b[4];
    let mut data = [0u8; 8];
    data.copy_from_slice(&b[8..16]);
    if word & CAN_ERR_FLAG != 0 {
        return Err(TransportError::Bus(BusEvent::from_error_frame(word & CAN_ERR_MASK, &data)));
    }
    if len > 8 {
        return Err(bad);
    }
    let extended = word & CAN_EFF_FLAG != 0;
    let id = word & CAN_ERR_MASK;
    if !extended && id > MAX_STD_ID {
        return Err(bad);
    }
    if word & CAN_RTR_FLAG != 0 {
        return Frame::remote(id, extended, len).ok_or(bad);
    }
    Frame::try_new(id, extended, &data[..usize::from(len)]).ok_or(bad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::IfName;
    use proptest::prelude::*;

    #[test]
    fn error_frames_decode_to_bus_events() {
        let off = error_frame(err::BUSOFF, [0; 8]);
        assert_eq!(decode(&off), Err(TransportError::Bus(BusEvent::BusOff)));
        let passive = error_frame(err::CRTL | err::CNT, [0, err::CRTL_TX_PASSIVE, 0, 0, 0, 0, 136, 3]);
        assert_eq!(decode(&passive), Err(TransportError::Bus(BusEvent::ErrorPassive { tx: 136, rx: 3 })));
        assert_eq!(decode(&error_frame(err::RESTARTED, [0; 8])), Err(TransportError::Bus(BusEvent::Restarted)));
        let active = error_frame(err::CRTL, [0, err::CRTL_ACTIVE, 0, 0, 0, 0, 0, 0]);
        assert_eq!(decode(&active), Err(TransportError::Bus(BusEvent::ErrorActive)));
        // The same bytes the socketcan crate builds for a kernel error frame.
        let e = ::socketcan::CanErrorFrame::new_error(err::BUSOFF, &[]).unwrap();
        use ::socketcan::Frame as _;
        assert_eq!(e.id_word(), u32::from_ne_bytes([off[0], off[1], off[2], off[3]]));
    }

    #[test]
    fn bytes_that_are_no_frame_are_refused() {
        let bad = Err(TransportError::Io(std::io::ErrorKind::InvalidData));
        assert_eq!(decode(&[0u8; 15]), bad);
        let mut b = encode(&Frame::new(0x181, &[1, 2]));
        b[4] = 9;
        assert_eq!(decode(&b), bad);
        let mut b = encode(&Frame::new(0x181, &[]));
        b[..4].copy_from_slice(&0x800u32.to_ne_bytes());
        assert_eq!(decode(&b), bad);
    }

    #[test]
    fn interface_names_are_cut_to_ifnamsiz() {
        assert_eq!(IfName::new("can0").to_string(), "can0");
        assert_eq!(IfName::new("a-very-long-interface-name").as_str(), "a-very-long-int");
        assert_eq!(IfName::new("ééééééééé").as_str(), "ééééééé");
    }

    fn arb_frame() -> impl Strategy<Value = Frame> {
        prop_oneof![
            (0u32..=MAX_STD_ID, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::try_new(id, false, &d).unwrap()),
            (0u32..=MAX_EXT_ID, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::try_new(id, true, &d).unwrap()),
            (0u32..=MAX_STD_ID, 0u8..=8).prop_map(|(id, n)| Frame::remote(id, false, n).unwrap()),
        ]
    }

    proptest! {
        #[test]
        fn frames_round_trip(f in arb_frame()) {
            prop_assert_eq!(decode(&encode(&f)), Ok(f));
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..20)) {
            let _ = decode(&b);
        }
    }
}
