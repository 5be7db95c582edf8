//! CAN bus load of the cyclic traffic, computed at start-up from the PDO layout, the number of
//! drives, the cycle and the bitrate.
//!
//! A classic CAN data frame with `n` data bytes has `47 + 8n` bits (11-bit id) or `67 + 8n`
//! (29-bit id), including 3 bits of interframe space. Bit stuffing inserts one bit after five equal
//! ones in the `34 + 8n` (`54 + 8n`) bits from SOF to the CRC; the worst case is
//! `floor((34 + 8n - 1) / 4)` stuff bits (Davis, Burns, Bril, Lukkien 2007, eq. 2). So an 8-byte
//! PDO is at most 135 bits, a SYNC 55.

#[cfg(test)]
use taut_proto::canopen::pdo::PdoLayout;
use taut_proto::canopen::pdo::{byte_len, PdoDef};

/// Worst-case length of a frame on the wire, bits.
pub fn frame_bits(data_bytes: u8, extended: bool) -> u32 {
    let n = u32::from(data_bytes.min(8));
    let (fixed, stuffable) = if extended { (67, 54) } else { (47, 34) };
    fixed + 8 * n + (stuffable + 8 * n - 1) / 4
}

/// Above this fraction of the bitrate the cyclic traffic leaves too little room for SDO,
/// EMCY and retransmissions; `taut probe` warns.
pub const WARN_LOAD: f64 = 0.70;

/// The load of the configured cyclic traffic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusLoad {
    /// Frames per SYNC cycle (SYNC + all PDOs).
    pub frames_per_cycle: u32,
    /// Worst-case bits per SYNC cycle.
    pub bits_per_cycle: u32,
    /// Heartbeats, bits per second (all drives).
    pub heartbeat_bits_per_s: f64,
    /// Fraction of the bitrate used, worst case (1.0 = saturated).
    pub load: f64,
}

impl BusLoad {
    /// Load of `drives` drives with the PDOs `pdos`, a SYNC every `cycle_s`, heartbeats every
    /// `heartbeat_ms` (0: none), at `bitrate` bit/s.
    pub fn compute(drives: usize, pdos: &[PdoDef], cycle_s: f64, bitrate: u32, heartbeat_ms: u16) -> BusLoad {
        let mut bits = frame_bits(0, false);
        let mut frames = 1;
        for p in pdos {
            bits += drives as u32 * frame_bits(byte_len(p.entries()), false);
            frames += drives as u32;
        }
        let hb = if heartbeat_ms > 0 { drives as f64 * f64::from(frame_bits(1, false)) * 1000.0 / f64::from(heartbeat_ms) } else { 0.0 };
        let per_s = f64::from(bits) / cycle_s + hb;
        BusLoad { frames_per_cycle: frames, bits_per_cycle: bits, heartbeat_bits_per_s: hb, load: per_s / f64::from(bitrate) }
    }

    /// True above [`WARN_LOAD`].
    pub fn is_high(&self) -> bool {
        self.load > WARN_LOAD
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_match_the_literature() {
        assert_eq!(frame_bits(8, false), 135);
        assert_eq!(frame_bits(0, false), 55);
        assert_eq!(frame_bits(8, true), 160);
    }

    #[test]
    fn four_drives_at_500_hz_on_1_mbit() {
        let l = BusLoad::compute(4, &PdoLayout::Compact.pdos(), 0.002, 1_000_000, 100);
        assert_eq!(l.frames_per_cycle, 9);
        assert_eq!(l.bits_per_cycle, 55 + 8 * 135);
        // 1135 bits / 2 ms = 567.5 kbit/s, plus 4 x 65 bits x 10/s of heartbeats.
        assert!((l.load - (567_500.0 + 2_600.0) / 1e6).abs() < 1e-9, "{}", l.load);
        assert!(!l.is_high());
        assert!(BusLoad::compute(8, &PdoLayout::Compact.pdos(), 0.002, 1_000_000, 100).is_high());
    }
}
