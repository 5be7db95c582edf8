//! 32-bit readings in two registers, and their conversion to newtons.
//!
//! ```text
//! register  address a      address a+1
//! big       high word      low word       (ABCD: value = a << 16 | a+1)
//! little    low word       high word      (CDAB, "word swapped")
//! ```
//! Inside each register the bytes are big-endian, as Modbus sends them. A float32 is the IEEE 754
//! bit pattern of those 32 bits. Tension = raw * scale + offset, N.

use crate::devices::{LoadCellConfig, ValueFormat, WordOrder};

/// The 32 bits of two registers in the given word order.
pub fn join_words(regs: [u16; 2], order: WordOrder) -> u32 {
    let (hi, lo) = match order {
        WordOrder::Big => (regs[0], regs[1]),
        WordOrder::Little => (regs[1], regs[0]),
    };
    u32::from(hi) << 16 | u32::from(lo)
}

/// The two registers holding `bits` in the given word order.
pub fn split_words(bits: u32, order: WordOrder) -> [u16; 2] {
    let (hi, lo) = ((bits >> 16) as u16, bits as u16);
    match order {
        WordOrder::Big => [hi, lo],
        WordOrder::Little => [lo, hi],
    }
}

/// The raw value of two registers.
pub fn raw_value(regs: [u16; 2], format: ValueFormat, order: WordOrder) -> f64 {
    let bits = join_words(regs, order);
    match format {
        ValueFormat::Int32 => f64::from(bits as i32),
        ValueFormat::Float32 => f64::from(f32::from_bits(bits)),
    }
}

/// Tension in newtons from the two registers of a cell, or `None` when a float32 reading is NaN
/// or infinite (what some amplifiers send on overload).
pub fn newtons(regs: [u16; 2], cell: &LoadCellConfig) -> Option<f64> {
    let n = raw_value(regs, cell.format, cell.word_order) * cell.scale + cell.offset;
    n.is_finite().then_some(n)
}

/// The two registers a cell shows for `newtons` (the inverse of [`newtons`], for simulated
/// devices). Int32 readings round to the nearest count and saturate.
pub fn registers_for(newtons: f64, cell: &LoadCellConfig) -> [u16; 2] {
    let raw = (newtons - cell.offset) / cell.scale;
    let bits = match cell.format {
        // `as` saturates and maps NaN to 0: what a real amplifier's clamp does.
        ValueFormat::Int32 => raw.round() as i32 as u32,
        ValueFormat::Float32 => (raw as f32).to_bits(),
    };
    split_words(bits, cell.word_order)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn pymodbus_encodings() {
        // pymodbus' INT32 / FLOAT32 data types put the high word first.
        let c = LoadCellConfig::new(1);
        assert_eq!(newtons([0xFFFF, 0xE4A8], &c), Some(-7000.0));
        let f = LoadCellConfig { format: ValueFormat::Float32, ..c.clone() };
        assert_eq!(newtons([0x4144, 0x0000], &f), Some(12.25));
        let sw = LoadCellConfig { word_order: WordOrder::Little, ..f.clone() };
        assert_eq!(newtons([0x0000, 0x4144], &sw), Some(12.25));
        assert_eq!(newtons([0x7FC0, 0x0000], &f), None);
        let scaled = LoadCellConfig { scale: 0.01, offset: -2.0, ..c };
        assert!((newtons([0, 1234], &scaled).unwrap() - 10.34).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn int32_round_trip(raw in any::<i32>(), little in any::<bool>(), scale in prop_oneof![Just(1.0), Just(0.01), Just(-0.5)]) {
            let order = if little { WordOrder::Little } else { WordOrder::Big };
            let c = LoadCellConfig { word_order: order, scale, offset: 3.0, ..LoadCellConfig::new(1) };
            let n = f64::from(raw) * scale + 3.0;
            prop_assert_eq!(registers_for(n, &c), split_words(raw as u32, order));
        }

        #[test]
        fn float32_round_trip(x in -1e6f32..1e6, little in any::<bool>()) {
            let order = if little { WordOrder::Little } else { WordOrder::Big };
            let c = LoadCellConfig { format: ValueFormat::Float32, word_order: order, ..LoadCellConfig::new(1) };
            prop_assert_eq!(newtons(registers_for(f64::from(x), &c), &c), Some(f64::from(x)));
        }
    }
}
