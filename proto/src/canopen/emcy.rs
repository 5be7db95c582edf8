//! Emergency messages (CiA 301 7.2.7) with error codes named after CiA 301 table 21 and the
//! CiA 402 drive error codes.
//!
//! ```text
//! COB-ID 0x080 + node, 8 bytes:
//! [0..2] error code (u16 LE, 0x0000 = error reset / no error)
//! [2]    error register (object 0x1001: bit0 generic, 1 current, 2 voltage, 3 temperature,
//!        4 communication, 5 device profile, 7 manufacturer)
//! [3..8] manufacturer-specific
//! ```

use super::NodeId;
use crate::can::Frame;
use std::fmt;

/// Base COB-ID of EMCY.
pub const EMCY_BASE: u16 = 0x080;

/// A decoded emergency message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emcy {
    /// Error code.
    pub code: u16,
    /// Error register (0x1001).
    pub register: u8,
    /// Manufacturer-specific bytes.
    pub vendor: [u8; 5],
}

/// Why an EMCY frame was not understood.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EmcyError {
    /// Not exactly 8 data bytes.
    Length(u8),
}

impl Emcy {
    /// True for the "error reset / no error" message a node sends when its errors are cleared.
    pub fn is_reset(&self) -> bool {
        self.code == 0
    }

    /// The name of the error code.
    pub fn name(&self) -> &'static str {
        error_code_name(self.code)
    }
}

impl fmt::Display for Emcy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "EMCY 0x{:04X} {} (error register 0x{:02X})", self.code, self.name(), self.register)
    }
}

/// Builds the EMCY frame of `node`.
pub fn encode(node: NodeId, e: &Emcy) -> Frame {
    let c = e.code.to_le_bytes();
    let v = e.vendor;
    Frame::new(EMCY_BASE + u16::from(node & 0x7F), &[c[0], c[1], e.register, v[0], v[1], v[2], v[3], v[4]])
}

/// Decodes the payload of a `0x080 + node` frame.
pub fn decode(data: &[u8]) -> Result<Emcy, EmcyError> {
    if data.len() != 8 {
        return Err(EmcyError::Length(data.len() as u8));
    }
    let mut vendor = [0u8; 5];
    vendor.copy_from_slice(&data[3..8]);
    Ok(Emcy { code: u16::from_le_bytes([data[0], data[1]]), register: data[2], vendor })
}

/// The name of an emergency error code: the exact code where known, else its class.
pub fn error_code_name(code: u16) -> &'static str {
    match code {
        0x0000 => "error reset or no error",
        0x1000 => "generic error",
        0x2211 => "internal current, short circuit",
        0x2220 => "continuous over-current (device inside)",
        0x2310 => "continuous over-current (motor side)",
        0x2320 => "short circuit or earth leakage (motor side)",
        0x3110 => "mains over-voltage",
        0x3120 => "mains under-voltage",
        0x3210 => "DC link over-voltage",
        0x3220 => "DC link under-voltage",
        0x4210 => "excess temperature, device",
        0x4310 => "excess temperature, drive",
        0x4410 => "excess temperature, supply",
        0x5113 => "supply low voltage",
        0x5530 => "data storage (non-volatile memory) error",
        0x6010 => "software reset (watchdog)",
        0x6320 => "parameter error",
        0x7121 => "motor blocked",
        0x7122 => "motor error or commutation malfunction",
        0x7305 => "incremental sensor 1 fault (encoder)",
        0x7500 => "communication error",
        0x8110 => "CAN overrun (objects lost)",
        0x8120 => "CAN in error-passive mode",
        0x8130 => "life guard or heartbeat error",
        0x8140 => "recovered from bus-off",
        0x8141 => "bus-off",
        0x8150 => "CAN-ID collision",
        0x8210 => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        0x8250 => "RPDO timeout",
        0x8611 => "following error",
        0x8612 => "reference limit",
        0x8A00 => "position controller error",
        0x9000 => "external error",
        0xF001 => "deceleration",
        0xFF00..=0xFFFF => "device specific",
        _ => match code >> 12 {
            0x1 => "generic error",
            0x2 => "current",
            0x3 => "voltage",
            0x4 => "temperature",
            0x5 => "device hardware",
            0x6 => "device software",
            0x7 => "additional modules",
            0x8 => match code >> 8 {
                0x81 => "communication",
                0x82 => "protocol error",
                0x86 => "positioning controller",
                _ => "monitoring",
            },
            0x9 => "external error",
            0xF => "additional functions",
            _ => "unknown error code",
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn roundtrip(code: u16, register: u8, vendor: [u8; 5], node in 1u8..=127) {
            let e = Emcy { code, register, vendor };
            let f = encode(node, &e);
            prop_assert_eq!(f.id, 0x80 + u32::from(node));
            prop_assert_eq!(decode(f.data()), Ok(e));
            prop_assert!(!e.name().is_empty());
        }

        #[test]
        fn arbitrary_payloads_never_panic(d in proptest::collection::vec(any::<u8>(), 0..=8)) {
            match decode(&d) {
                Ok(e) => { prop_assert_eq!(d.len(), 8); let _ = e.to_string(); }
                Err(EmcyError::Length(n)) => prop_assert_eq!(usize::from(n), d.len()),
            }
        }
    }

    #[test]
    fn names() {
        assert_eq!(error_code_name(0x8611), "following error");
        assert_eq!(error_code_name(0x2399), "current");
        assert_eq!(error_code_name(0x8199), "communication");
        assert_eq!(decode(&[0; 7]), Err(EmcyError::Length(7)));
    }
}
