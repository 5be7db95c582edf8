//! CRC-16/MODBUS: polynomial 0x8005 reflected (0xA001), initial value 0xFFFF, no final XOR.
//!
//! Modbus over Serial Line V1.02, 6.2.2 and appendix B. On the wire the CRC goes low byte
//! first, the one exception to Modbus' big-endian rule.

/// Byte-at-a-time table, built at compile time.
const TABLE: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u16;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xA001 } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// CRC-16/MODBUS of `bytes`.
///
/// ```
/// use taut_proto::modbus::crc::crc16;
/// // Read 10 holding registers from unit 1: the CRC goes out as C5 CD.
/// assert_eq!(crc16(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A]).to_le_bytes(), [0xC5, 0xCD]);
/// ```
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in bytes {
        crc = (crc >> 8) ^ TABLE[usize::from((crc as u8) ^ b)];
    }
    crc
}

/// The bit-by-bit form of the spec's appendix B, kept to check the table against.
#[cfg(test)]
fn crc16_bitwise(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in bytes {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xA001 } else { crc >> 1 };
        }
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn known_vectors() {
        // Spec-style request frames and their CRCs as they appear on the wire (low byte first).
        let cases: &[(&[u8], [u8; 2])] = &[
            (&[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A], [0xC5, 0xCD]),
            (&[0x01, 0x04, 0x00, 0x00, 0x00, 0x04], [0xF1, 0xC9]),
            (&[0x02, 0x03, 0x00, 0x00, 0x00, 0x04], [0x44, 0x3A]),
            (&[0x03, 0x03, 0x00, 0x00, 0x00, 0x04], [0x45, 0xEB]),
        ];
        for (frame, crc) in cases {
            assert_eq!(crc16(frame).to_le_bytes(), *crc, "{frame:02X?}");
        }
        // The CRC-16/MODBUS check value of the CRC catalogue.
        assert_eq!(crc16(b"123456789"), 0x4B37);
        assert_eq!(crc16(&[]), 0xFFFF);
    }

    proptest! {
        #[test]
        fn table_matches_bitwise(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            prop_assert_eq!(crc16(&bytes), crc16_bitwise(&bytes));
        }

        #[test]
        fn frame_with_its_crc_checks_to_zero(bytes in proptest::collection::vec(any::<u8>(), 0..254)) {
            // Appending the CRC low byte first makes the CRC over the whole frame 0.
            let mut f = bytes.clone();
            f.extend_from_slice(&crc16(&bytes).to_le_bytes());
            prop_assert_eq!(crc16(&f), 0);
        }
    }
}
