//! Process data objects (CiA 301 7.2.2): mapping entries, packing values into a PDO and out of
//! it, the SDO writes that configure a PDO, and the PDO layouts this project uses.
//!
//! ```text
//! mapping entry (objects 0x1600+k / 0x1A00+k, sub 1..=8), u32:
//!   bits 31..16 index   bits 15..8 sub-index   bits 7..0 length in bits
//! communication parameter (0x1400+k / 0x1800+k):
//!   sub 1 COB-ID (u32; bit 31 = PDO disabled)   sub 2 transmission type (u8; 1..=240 = every
//!   n-th SYNC, 254/255 = event driven)
//! payload: mapped objects back to back, little-endian, starting at bit 0 of byte 0
//! ```
//! Presets ([`PdoLayout`]; any other map comes from `[[cable.drive.rpdo]]` / `tpdo` tables and
//! is held, like these, in a [`PdoSet`]):
//!
//! ```text
//! compact    RPDO1 0x200+n: controlword 0x6040 (16) | target position 0x607A (32) | target torque 0x6071 (16)
//!            TPDO1 0x180+n: statusword 0x6041 (16)  | position actual 0x6064 (32) | torque actual 0x6077 (16)
//! with_mode  the above, plus RPDO2 0x300+n: modes of operation 0x6060 (8)
//!                            TPDO2 0x280+n: modes of operation display 0x6061 (8) | error code 0x603F (16)
//! ```

use super::od;
use super::NodeId;

/// COB-ID bit 31: PDO does not exist / is not valid.
pub const COB_ID_INVALID: u32 = 0x8000_0000;
/// Transmission type: synchronous, every SYNC.
pub const TRANSMISSION_SYNC_EVERY: u8 = 1;

/// One object mapped into a PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MapEntry {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Length, bits (1..=64).
    pub bits: u8,
}

impl MapEntry {
    /// An entry for `index:sub` of `bits` bits.
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        MapEntry { index, sub, bits }
    }

    /// The u32 written to a mapping object.
    pub fn encode(&self) -> u32 {
        u32::from(self.index) << 16 | u32::from(self.sub) << 8 | u32::from(self.bits)
    }

    /// Decodes a mapping object value; `None` for a zero length or one over 64 bits.
    pub fn decode(v: u32) -> Option<Self> {
        let bits = (v & 0xFF) as u8;
        (1..=64).contains(&bits).then_some(MapEntry { index: (v >> 16) as u16, sub: (v >> 8) as u8, bits })
    }
}

/// Why a PDO could not be packed or unpacked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PdoError {
    /// The mapped objects need more than 64 bits.
    TooLong {
        /// Bits needed.
        bits: u16,
    },
    /// The received frame is shorter than the mapping (CiA 301: EMCY 0x8210).
    Short {
        /// Bytes the mapping needs.
        expected: u8,
        /// Bytes received.
        received: u8,
    },
}

/// Total length of a mapping, bits.
pub fn total_bits(entries: &[MapEntry]) -> u16 {
    entries.iter().map(|e| u16::from(e.bits)).sum()
}

/// Bytes a PDO with this mapping occupies (its DLC).
pub fn byte_len(entries: &[MapEntry]) -> u8 {
    total_bits(entries).div_ceil(8).min(255) as u8
}

fn mask(bits: u8) -> u64 {
    if bits >= 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    }
}

/// Packs values into a PDO payload; `get(index, sub)` gives each object's raw value (two's
/// complement for signed types, truncated to its bits). Returns the DLC.
pub fn pack(entries: &[MapEntry], out: &mut [u8; 8], mut get: impl FnMut(u16, u8) -> u64) -> Result<u8, PdoError> {
    let bits = total_bits(entries);
    if bits > 64 {
        return Err(PdoError::TooLong { bits });
    }
    let mut word = 0u64;
    let mut shift = 0u32;
    for e in entries {
        word |= (get(e.index, e.sub) & mask(e.bits)) << shift;
        shift += u32::from(e.bits);
    }
    *out = word.to_le_bytes();
    let n = byte_len(entries);
    for b in &mut out[usize::from(n)..] {
        *b = 0;
    }
    Ok(n)
}

/// Unpacks a PDO payload; `set(index, sub, raw, bits)` receives each object's raw value.
/// Extra bytes beyond the mapping are ignored (CiA 301 allows a longer PDO).
pub fn unpack(entries: &[MapEntry], data: &[u8], mut set: impl FnMut(u16, u8, u64, u8)) -> Result<(), PdoError> {
    let bits = total_bits(entries);
    if bits > 64 {
        return Err(PdoError::TooLong { bits });
    }
    let need = byte_len(entries);
    if data.len() < usize::from(need) {
        return Err(PdoError::Short { expected: need, received: data.len() as u8 });
    }
    let mut b = [0u8; 8];
    b[..data.len().min(8)].copy_from_slice(&data[..data.len().min(8)]);
    let word = u64::from_le_bytes(b);
    let mut shift = 0u32;
    for e in entries {
        let v = if shift >= 64 { 0 } else { (word >> shift) & mask(e.bits) };
        set(e.index, e.sub, v, e.bits);
        shift += u32::from(e.bits);
    }
    Ok(())
}

/// Sign-extends a raw value of `bits` bits.
pub fn sign_extend(raw: u64, bits: u8) -> i64 {
    if bits == 0 || bits >= 64 {
        return raw as i64;
    }
    let s = 64 - u32::from(bits);
    ((raw << s) as i64) >> s
}

/// Direction of a PDO, seen from the drive (CiA convention).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Receive PDO: master -> drive.
    Rx,
    /// Transmit PDO: drive -> master.
    Tx,
}

/// One PDO of a drive: its number and mapping (fixed capacity, so a set of them is built once
/// at configuration and read, never allocated, in the cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoDef {
    /// RPDO or TPDO.
    pub dir: Direction,
    /// PDO number 0..=3 (RPDO1 is 0).
    pub num: u8,
    map: [MapEntry; 8],
    count: u8,
}

impl PdoDef {
    /// PDO `num` (0 = first) of direction `dir` mapping `entries` (at most 8; more are dropped:
    /// the configuration refuses such maps before they get here).
    pub fn new(dir: Direction, num: u8, entries: &[MapEntry]) -> Self {
        let mut map = [MapEntry::new(0, 0, 0); 8];
        let n = entries.len().min(8);
        map[..n].copy_from_slice(&entries[..n]);
        PdoDef { dir, num, map, count: n as u8 }
    }

    /// The mapped objects, in order.
    pub fn entries(&self) -> &[MapEntry] {
        &self.map[..usize::from(self.count)]
    }

    /// Default COB-ID of this PDO for `node` (predefined connection set).
    pub fn cob_id(&self, node: NodeId) -> u16 {
        default_cob_id(self.dir, self.num, node)
    }

    /// Communication parameter object.
    pub fn comm_index(&self) -> u16 {
        comm_index(self.dir, self.num)
    }

    /// Mapping parameter object.
    pub fn map_index(&self) -> u16 {
        map_index(self.dir, self.num)
    }

    /// The SDO writes that configure this PDO on `node`, in the order CiA 301 7.2.2.4 asks:
    /// disable, clear the mapping, write the entries, set the count, transmission type, enable.
    pub fn config_writes(&self, node: NodeId) -> impl Iterator<Item = SdoWrite> + '_ {
        let cob = u32::from(self.cob_id(node));
        let (comm, map) = (self.comm_index(), self.map_index());
        let n = self.count;
        [SdoWrite::u32(comm, 1, cob | COB_ID_INVALID), SdoWrite::u8(map, 0, 0)]
            .into_iter()
            .chain(self.entries().iter().enumerate().map(move |(i, e)| SdoWrite::u32(map, i as u8 + 1, e.encode())))
            .chain([SdoWrite::u8(map, 0, n), SdoWrite::u8(comm, 2, TRANSMISSION_SYNC_EVERY), SdoWrite::u32(comm, 1, cob)])
    }

    /// What a drive must answer when the configuration is read back (the values
    /// [`config_writes`](Self::config_writes) left): count, entries, transmission type, COB-ID.
    pub fn readback(&self, node: NodeId) -> impl Iterator<Item = SdoWrite> + '_ {
        let (comm, map) = (self.comm_index(), self.map_index());
        [SdoWrite::u8(map, 0, self.count)]
            .into_iter()
            .chain(self.entries().iter().enumerate().map(move |(i, e)| SdoWrite::u32(map, i as u8 + 1, e.encode())))
            .chain([SdoWrite::u8(comm, 2, TRANSMISSION_SYNC_EVERY), SdoWrite::u32(comm, 1, u32::from(self.cob_id(node)))])
    }
}

/// Default COB-ID of PDO `num` (0 = first) of `dir` for `node` (predefined connection set).
pub fn default_cob_id(dir: Direction, num: u8, node: NodeId) -> u16 {
    let base = match dir {
        Direction::Tx => 0x180,
        Direction::Rx => 0x200,
    };
    base + 0x100 * u16::from(num) + u16::from(node & 0x7F)
}

/// Communication parameter object of PDO `num` of `dir`.
pub fn comm_index(dir: Direction, num: u8) -> u16 {
    let base = match dir {
        Direction::Rx => od::RPDO_COMM,
        Direction::Tx => od::TPDO_COMM,
    };
    base + u16::from(num)
}

/// Mapping parameter object of PDO `num` of `dir`.
pub fn map_index(dir: Direction, num: u8) -> u16 {
    let base = match dir {
        Direction::Rx => od::RPDO_MAP,
        Direction::Tx => od::TPDO_MAP,
    };
    base + u16::from(num)
}

/// The write that switches off PDO `num` of `dir` on `node` (COB-ID bit 31), for PDOs of the
/// predefined connection set that the map does not use: a drive's factory mapping may have them
/// valid, and a TPDO nobody asked for costs bus time every SYNC.
pub fn disable_write(dir: Direction, num: u8, node: NodeId) -> SdoWrite {
    SdoWrite::u32(comm_index(dir, num), 1, u32::from(default_cob_id(dir, num, node)) | COB_ID_INVALID)
}

/// The PDOs of one drive, at most 4 RPDOs and 4 TPDOs, built once at configuration.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PdoSet {
    pdos: heapless::Vec<PdoDef, 8>,
}

impl PdoSet {
    /// The PDOs of checked configuration maps (see `crate::pdo_map`).
    pub fn from_maps(m: &crate::pdo_map::PdoMaps) -> PdoSet {
        let mut pdos = heapless::Vec::new();
        for (dir, list) in [(Direction::Rx, &m.rx), (Direction::Tx, &m.tx)] {
            for (k, objs) in list.iter().enumerate().take(4) {
                let e: heapless::Vec<MapEntry, 8> = objs.iter().take(8).map(|o| MapEntry::new(o.index, o.sub, o.bits)).collect();
                let _ = pdos.push(PdoDef::new(dir, k as u8, &e));
            }
        }
        PdoSet { pdos }
    }

    /// The PDOs.
    pub fn pdos(&self) -> &[PdoDef] {
        &self.pdos
    }

    /// True if `index` (sub 0) travels in a PDO of `dir`.
    pub fn maps(&self, dir: Direction, index: u16) -> bool {
        self.pdos.iter().filter(|p| p.dir == dir).flat_map(|p| p.entries()).any(|e| e.index == index && e.sub == 0)
    }

    /// True if the mode of operation is mapped into an RPDO (so it is not written by SDO at
    /// start-up, and the drive can switch modes while running).
    pub fn maps_mode(&self) -> bool {
        self.maps(Direction::Rx, od::MODES_OF_OPERATION)
    }

    /// True if PDO `num` of `dir` is used.
    pub fn has(&self, dir: Direction, num: u8) -> bool {
        self.pdos.iter().any(|p| p.dir == dir && p.num == num)
    }
}

impl std::ops::Deref for PdoSet {
    type Target = [PdoDef];
    fn deref(&self) -> &[PdoDef] {
        &self.pdos
    }
}

impl From<PdoLayout> for PdoSet {
    fn from(l: PdoLayout) -> PdoSet {
        l.pdos()
    }
}

/// One expedited SDO write of up to 4 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoWrite {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Value (little-endian, `len` bytes of it).
    pub value: u32,
    /// Bytes, 1..=4.
    pub len: u8,
}

impl SdoWrite {
    /// A u8 write.
    pub const fn u8(index: u16, sub: u8, v: u8) -> Self {
        SdoWrite { index, sub, value: v as u32, len: 1 }
    }
    /// A u16 write.
    pub const fn u16(index: u16, sub: u8, v: u16) -> Self {
        SdoWrite { index, sub, value: v as u32, len: 2 }
    }
    /// A u32 write.
    pub const fn u32(index: u16, sub: u8, v: u32) -> Self {
        SdoWrite { index, sub, value: v, len: 4 }
    }
    /// The bytes to send.
    pub fn bytes(&self) -> ([u8; 4], usize) {
        (self.value.to_le_bytes(), usize::from(self.len.clamp(1, 4)))
    }
}

/// The two named presets of the configuration (`pdo = "compact"` / `"with_mode"`); the maps
/// themselves are `crate::pdo_map::PdoMaps::preset`, the one place they are written down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PdoLayout {
    /// One RPDO and one TPDO of 8 bytes per drive; the mode is set by SDO.
    #[default]
    Compact,
    /// Compact plus the mode of operation and the error code in a second pair of PDOs.
    WithMode,
}

impl PdoLayout {
    /// The PDOs of this preset.
    pub fn pdos(&self) -> PdoSet {
        use crate::devices::PdoMapping;
        PdoSet::from_maps(&crate::pdo_map::PdoMaps::preset(match self {
            PdoLayout::Compact => PdoMapping::Compact,
            PdoLayout::WithMode => PdoMapping::WithMode,
        }))
    }

    /// True if the mode of operation is mapped (so it is not written by SDO at start-up).
    pub fn maps_mode(&self) -> bool {
        self.pdos().maps_mode()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn config_sequence_follows_cia301() {
        let w: Vec<_> = PdoLayout::Compact.pdos()[0].config_writes(3).collect();
        assert_eq!(w.first(), Some(&SdoWrite::u32(0x1400, 1, 0x8000_0203)));
        assert_eq!(w[1], SdoWrite::u8(0x1600, 0, 0));
        assert_eq!(w[2], SdoWrite::u32(0x1600, 1, 0x6040_0010));
        assert_eq!(w[3], SdoWrite::u32(0x1600, 2, 0x607A_0020));
        assert_eq!(w[5], SdoWrite::u8(0x1600, 0, 3));
        assert_eq!(w[6], SdoWrite::u8(0x1400, 2, 1));
        assert_eq!(w.last(), Some(&SdoWrite::u32(0x1400, 1, 0x203)));
        assert_eq!(PdoLayout::WithMode.pdos()[3].cob_id(3), 0x283);
        for l in [PdoLayout::Compact, PdoLayout::WithMode] {
            for p in l.pdos().iter() {
                assert!(total_bits(p.entries()) <= 64);
            }
        }
        // The presets' maps, object by object, as the module doc's table gives them.
        let e = |p: &PdoDef| p.entries().iter().map(|e| e.encode()).collect::<Vec<_>>();
        let w = PdoLayout::WithMode.pdos();
        assert_eq!(w.len(), 4);
        assert_eq!((w[0].dir, w[0].num, e(&w[0])), (Direction::Rx, 0, vec![0x6040_0010, 0x607A_0020, 0x6071_0010]));
        assert_eq!((w[1].dir, w[1].num, e(&w[1])), (Direction::Rx, 1, vec![0x6060_0008]));
        assert_eq!((w[2].dir, w[2].num, e(&w[2])), (Direction::Tx, 0, vec![0x6041_0010, 0x6064_0020, 0x6077_0010]));
        assert_eq!((w[3].dir, w[3].num, e(&w[3])), (Direction::Tx, 1, vec![0x6061_0008, 0x603F_0010]));
        let compact: Vec<PdoDef> = w[..1].iter().chain(&w[2..3]).copied().collect();
        assert_eq!(PdoLayout::Compact.pdos()[..], compact[..]);
        let r: Vec<_> = w[0].readback(3).collect();
        let m = |sub, v| SdoWrite::u32(0x1600, sub, v);
        assert_eq!(
            r,
            vec![
                SdoWrite::u8(0x1600, 0, 3),
                m(1, 0x6040_0010),
                m(2, 0x607A_0020),
                m(3, 0x6071_0010),
                SdoWrite::u8(0x1400, 2, 1),
                SdoWrite::u32(0x1400, 1, 0x203)
            ]
        );
        assert_eq!(disable_write(Direction::Tx, 2, 3), SdoWrite::u32(0x1802, 1, 0x8000_0383));
    }

    fn arb_entries() -> impl Strategy<Value = Vec<MapEntry>> {
        proptest::collection::vec((any::<u16>(), any::<u8>(), prop_oneof![Just(8u8), Just(16), Just(32), 1u8..=16]), 0..8)
            .prop_map(|v| v.into_iter().map(|(i, s, b)| MapEntry::new(i, s, b)).collect::<Vec<_>>())
            .prop_filter("fits in 64 bits", |v| total_bits(v) <= 64)
    }

    proptest! {
        #[test]
        fn mapping_entry_roundtrip(index: u16, sub: u8, bits in 1u8..=64) {
            let e = MapEntry::new(index, sub, bits);
            prop_assert_eq!(MapEntry::decode(e.encode()), Some(e));
        }

        #[test]
        fn pack_unpack_roundtrip(entries in arb_entries(), values in proptest::collection::vec(any::<u64>(), 8)) {
            let mut out = [0u8; 8];
            let mut k = 0;
            let dlc = pack(&entries, &mut out, |_, _| { k += 1; values[k - 1] }).unwrap();
            prop_assert_eq!(dlc, byte_len(&entries));
            let mut got = vec![];
            unpack(&entries, &out[..usize::from(dlc)], |_, _, v, _| got.push(v)).unwrap();
            for (i, e) in entries.iter().enumerate() {
                prop_assert_eq!(got[i], values[i] & mask(e.bits));
            }
        }

        #[test]
        fn short_payloads_are_errors_not_panics(entries in arb_entries(), d in proptest::collection::vec(any::<u8>(), 0..=8)) {
            let r = unpack(&entries, &d, |_, _, _, _| {});
            prop_assert_eq!(r.is_ok(), d.len() >= usize::from(byte_len(&entries)));
        }
    }

    #[test]
    fn signed_values() {
        let e = [MapEntry::new(0x6071, 0, 16), MapEntry::new(0x607A, 0, 32)];
        let mut out = [0u8; 8];
        pack(&e, &mut out, |i, _| if i == 0x6071 { (-5i16) as u16 as u64 } else { (-100_000i32) as u32 as u64 }).unwrap();
        let mut got = vec![];
        unpack(&e, &out[..6], |_, _, v, b| got.push(sign_extend(v, b))).unwrap();
        assert_eq!(got, vec![-5, -100_000]);
        assert_eq!(unpack(&e, &out[..5], |_, _, _, _| {}), Err(PdoError::Short { expected: 6, received: 5 }));
    }
}
