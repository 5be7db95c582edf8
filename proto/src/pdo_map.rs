//! PDO maps of a drive as the configuration gives them: the objects of each RPDO and TPDO
//! (CiA 301 7.2.2), the presets `compact` and `with_mode`, and the rules a map must follow before
//! the master writes it to a drive.
//!
//! ```toml
//! [cable.drive]
//! node_id = 1
//! [[cable.drive.rpdo]]                       # RPDO1 (0x200 + node id), master -> drive
//! map = ["0x6040:0/16", "0x607A:0/32"]      # index:sub/bits; ":sub" and "/bits" may be left out
//! [[cable.drive.tpdo]]                       # TPDO1 (0x180 + node id), drive -> master
//! map = ["0x6041", "0x6064", "0x6077"]
//! [[cable.drive.tpdo]]                       # TPDO2 (0x280 + node id)
//! map = ["0x606C:0/32"]
//! ```
//!
//! The n-th table is PDO n (at most 4 of each), on the COB-ID of the predefined connection set.
//! Rules ([`PdoMaps::check`]):
//!
//! ```text
//! every PDO      1..=8 objects, at most 64 bits
//! RPDO objects   only what taut writes: 0x6040 controlword, 0x607A target position,
//!                0x6071 target torque, 0x6060 modes of operation
//! TPDO objects   any object from 0x2000 on; taut's known ones ([`OBJECTS`]) are decoded, others
//!                need their length and are passed over (an EDS, if given, checks them)
//! lengths        a known object must be mapped with its own length
//! duplicates     an object at most once among the RPDOs and once among the TPDOs
//! required       0x6040 (RPDO), 0x6041 and 0x6064 (TPDO) always; position mode 0x607A;
//!                torque mode 0x6071 and 0x6077; 0x6060 mapped (mode switching) needs all of them
//! ```

use crate::devices::{DriveMode, PdoMapping};
use std::fmt;

/// Access of an object as CiA 301 / CiA 306 name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only.
    Ro,
    /// Write only.
    Wo,
    /// Read and write.
    Rw,
    /// Constant (read only, never changes).
    Const,
}

impl Access {
    /// Can a master read it?
    pub fn readable(self) -> bool {
        !matches!(self, Access::Wo)
    }
    /// Can a master write it?
    pub fn writable(self) -> bool {
        matches!(self, Access::Wo | Access::Rw)
    }
    /// The CiA 306 spelling.
    pub fn name(self) -> &'static str {
        match self {
            Access::Ro => "ro",
            Access::Wo => "wo",
            Access::Rw => "rw",
            Access::Const => "const",
        }
    }
}

/// One object taut knows: its size, access and which PDO may carry it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObjectInfo {
    /// Index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Name for messages.
    pub name: &'static str,
    /// Length, bits.
    pub bits: u8,
    /// Access.
    pub access: Access,
    /// True if the master writes it in an RPDO, false if a drive sends it in a TPDO.
    pub rpdo: bool,
}

/// The CiA 402 objects taut maps or reads from PDOs.
pub const OBJECTS: &[ObjectInfo] = &[
    ObjectInfo { index: 0x603F, sub: 0, name: "error code", bits: 16, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x6040, sub: 0, name: "controlword", bits: 16, access: Access::Rw, rpdo: true },
    ObjectInfo { index: 0x6041, sub: 0, name: "statusword", bits: 16, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x6060, sub: 0, name: "modes of operation", bits: 8, access: Access::Rw, rpdo: true },
    ObjectInfo { index: 0x6061, sub: 0, name: "modes of operation display", bits: 8, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x6064, sub: 0, name: "position actual value", bits: 32, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x606C, sub: 0, name: "velocity actual value", bits: 32, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x6071, sub: 0, name: "target torque", bits: 16, access: Access::Rw, rpdo: true },
    ObjectInfo { index: 0x6077, sub: 0, name: "torque actual value", bits: 16, access: Access::Ro, rpdo: false },
    ObjectInfo { index: 0x607A, sub: 0, name: "target position", bits: 32, access: Access::Rw, rpdo: true },
    ObjectInfo { index: 0x60F4, sub: 0, name: "following error actual value", bits: 32, access: Access::Ro, rpdo: false },
];

/// The entry of [`OBJECTS`] for `index:sub`.
pub fn object(index: u16, sub: u8) -> Option<&'static ObjectInfo> {
    OBJECTS.iter().find(|o| o.index == index && o.sub == sub)
}

/// One object mapped into a PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoObject {
    /// Index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Length, bits (1..=64).
    pub bits: u8,
}

impl PdoObject {
    /// `index:sub` of `bits` bits.
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        PdoObject { index, sub, bits }
    }

    /// Parses `0x6040:0/16` (index in hex, with or without `0x`; sub-index decimal or `0x` hex;
    /// bits decimal). `:sub` defaults to 0, `/bits` to the length of a known object.
    pub fn parse(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let hint = "write an object as \"0x6040:0/16\" (index in hex : sub-index / length in bits)";
        if t.is_empty() || t.len() > 32 {
            return Err(format!("{s:?} is not an object; {hint}"));
        }
        let (head, bits) = match t.split_once('/') {
            Some((h, b)) => (h, Some(b.trim())),
            None => (t, None),
        };
        let (index, sub) = match head.split_once(':') {
            Some((i, s)) => (i.trim(), Some(s.trim())),
            None => (head.trim(), None),
        };
        let hex = index.strip_prefix("0x").or_else(|| index.strip_prefix("0X")).unwrap_or(index);
        let index = u16::from_str_radix(hex, 16)
            .ok()
            .filter(|_| !hex.is_empty() && hex.len() <= 4 && !hex.starts_with('+'))
            .ok_or_else(|| format!("{s:?}: index {index:?} is not a hex number 0x0000..=0xFFFF; {hint}"))?;
        let sub = match sub {
            None => 0,
            Some(x) => parse_int(x)
                .and_then(|v| u8::try_from(v).ok())
                .ok_or_else(|| format!("{s:?}: sub-index {x:?} is not a number 0..=255; {hint}"))?,
        };
        let known = object(index, sub);
        let bits = match bits {
            Some(b) => b
                .parse::<u8>()
                .ok()
                .filter(|v| (1..=64).contains(v) && !b.starts_with('+'))
                .ok_or_else(|| format!("{s:?}: length {b:?} is not a number of bits 1..=64; {hint}"))?,
            None => match known {
                Some(o) => o.bits,
                None => {
                    return Err(format!(
                        "{s:?}: taut does not know the length of 0x{index:04X}:{sub}; give it in bits, e.g. \"0x{index:04X}:{sub}/32\""
                    ))
                }
            },
        };
        Ok(PdoObject { index, sub, bits })
    }
}

fn parse_int(s: &str) -> Option<u32> {
    match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) if !h.is_empty() && !h.starts_with('+') => u32::from_str_radix(h, 16).ok(),
        Some(_) => None,
        None if !s.is_empty() && !s.starts_with('+') => s.parse().ok(),
        None => None,
    }
}

impl fmt::Display for PdoObject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}:{}/{}", self.index, self.sub, self.bits)
    }
}

/// Direction of a PDO, seen from the drive (CiA convention).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dir {
    /// Receive PDO: master -> drive.
    Rx,
    /// Transmit PDO: drive -> master.
    Tx,
}

impl Dir {
    /// `rpdo` or `tpdo`, as in the configuration.
    pub fn key(self) -> &'static str {
        match self {
            Dir::Rx => "rpdo",
            Dir::Tx => "tpdo",
        }
    }
}

/// Largest number of RPDOs (and of TPDOs) taut configures: those of the predefined connection set.
pub const MAX_PDOS: usize = 4;
/// Largest number of objects in one PDO (sub-indices 1..=8 of the mapping parameter).
pub const MAX_ENTRIES: usize = 8;

/// The PDO maps of one drive: `rx[k]` is RPDO k+1, `tx[k]` TPDO k+1.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PdoMaps {
    /// RPDOs, master -> drive.
    pub rx: Vec<Vec<PdoObject>>,
    /// TPDOs, drive -> master.
    pub tx: Vec<Vec<PdoObject>>,
}

/// Where a map is wrong: the key below `[cable.drive]` and, for one object, its position.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MapProblem {
    /// Direction.
    pub dir: Dir,
    /// PDO (0 = first), if the problem is in one PDO.
    pub pdo: Option<usize>,
    /// Object in that PDO (0 = first), if the problem is one object.
    pub entry: Option<usize>,
    /// What is wrong and what to do.
    pub message: String,
}

impl MapProblem {
    /// The key, e.g. `tpdo[1].map[0]`, relative to `[cable.drive]`.
    pub fn key(&self) -> String {
        match (self.pdo, self.entry) {
            (Some(p), Some(e)) => format!("{}[{p}].map[{e}]", self.dir.key()),
            (Some(p), None) => format!("{}[{p}].map", self.dir.key()),
            _ => self.dir.key().to_string(),
        }
    }
}

impl PdoMaps {
    /// The maps of a preset. `compact`: RPDO1 controlword, target position, target torque;
    /// TPDO1 statusword, position actual, torque actual. `with_mode` adds RPDO2 modes of
    /// operation and TPDO2 modes of operation display, error code.
    pub fn preset(p: PdoMapping) -> PdoMaps {
        let o = PdoObject::new;
        let mut m = PdoMaps {
            rx: vec![vec![o(0x6040, 0, 16), o(0x607A, 0, 32), o(0x6071, 0, 16)]],
            tx: vec![vec![o(0x6041, 0, 16), o(0x6064, 0, 32), o(0x6077, 0, 16)]],
        };
        if p == PdoMapping::WithMode {
            m.rx.push(vec![o(0x6060, 0, 8)]);
            m.tx.push(vec![o(0x6061, 0, 8), o(0x603F, 0, 16)]);
        }
        m
    }

    /// The PDOs of one direction.
    pub fn dir(&self, d: Dir) -> &[Vec<PdoObject>] {
        match d {
            Dir::Rx => &self.rx,
            Dir::Tx => &self.tx,
        }
    }

    /// True if `index:sub` is in a PDO of direction `d`.
    pub fn maps(&self, d: Dir, index: u16, sub: u8) -> bool {
        self.dir(d).iter().flatten().any(|o| o.index == index && o.sub == sub)
    }

    /// True if the mode of operation travels in an RPDO, so the drive can switch modes.
    pub fn maps_mode(&self) -> bool {
        self.maps(Dir::Rx, 0x6060, 0)
    }

    /// Checks the rules of the module doc for a drive that runs in `mode`.
    pub fn check(&self, mode: DriveMode) -> Result<(), MapProblem> {
        for d in [Dir::Rx, Dir::Tx] {
            let pdos = self.dir(d);
            let bad = |pdo: Option<usize>, entry: Option<usize>, message: String| MapProblem { dir: d, pdo, entry, message };
            if pdos.is_empty() {
                return Err(bad(None, None, format!("give at least one [[cable.drive.{}]] table with a map", d.key())));
            }
            if pdos.len() > MAX_PDOS {
                return Err(bad(
                    Some(MAX_PDOS),
                    None,
                    format!(
                        "{} {} tables: taut configures at most {MAX_PDOS} (those of the predefined connection set)",
                        pdos.len(),
                        d.key()
                    ),
                ));
            }
            for (p, objs) in pdos.iter().enumerate() {
                if objs.is_empty() || objs.len() > MAX_ENTRIES {
                    return Err(bad(Some(p), None, format!("a PDO maps 1..={MAX_ENTRIES} objects, this one {}", objs.len())));
                }
                let total: u32 = objs.iter().map(|o| u32::from(o.bits)).sum();
                if total > 64 {
                    return Err(bad(
                        Some(p),
                        None,
                        format!("the objects need {total} bits, a PDO carries at most 64 (8 bytes): move some to another PDO"),
                    ));
                }
                for (e, o) in objs.iter().enumerate() {
                    let here = |m: String| bad(Some(p), Some(e), m);
                    match (object(o.index, o.sub), d) {
                        (Some(k), _) if k.bits != o.bits => {
                            return Err(here(format!("{o}: {} is {} bits long, not {}", k.name, k.bits, o.bits)))
                        }
                        (Some(k), Dir::Rx) if !k.rpdo => {
                            return Err(here(format!("{o}: {} is sent by the drive; map it in a tpdo", k.name)))
                        }
                        (None, Dir::Rx) => {
                            return Err(here(format!(
                                "{o}: taut only writes 0x6040, 0x607A, 0x6071 and 0x6060 in RPDOs; another object would be written as 0 every cycle"
                            )))
                        }
                        _ => {}
                    }
                    if o.index < 0x2000 {
                        return Err(here(format!("{o}: objects below 0x2000 (communication area) are not mappable")));
                    }
                    if let Some((p2, e2)) = pdos
                        .iter()
                        .enumerate()
                        .flat_map(|(p2, v)| v.iter().enumerate().map(move |(e2, x)| (p2, e2, x)))
                        .take_while(|&(p2, e2, _)| (p2, e2) < (p, e))
                        .find(|(_, _, x)| x.index == o.index && x.sub == o.sub)
                        .map(|(p2, e2, _)| (p2, e2))
                    {
                        return Err(here(format!("{o} is already mapped at {}[{p2}].map[{e2}]: map each object once", d.key())));
                    }
                }
            }
        }
        let mut need: Vec<(Dir, u16, &str)> = vec![
            (Dir::Rx, 0x6040, "controlword"),
            (Dir::Tx, 0x6041, "statusword"),
            (Dir::Tx, 0x6064, "position actual value (the cable length)"),
        ];
        let switch = self.maps_mode();
        if mode == DriveMode::Position || switch {
            need.push((Dir::Rx, 0x607A, "target position (position mode)"));
        }
        if mode == DriveMode::Torque || switch {
            need.push((Dir::Rx, 0x6071, "target torque (torque mode)"));
            need.push((Dir::Tx, 0x6077, "torque actual value (torque mode)"));
        }
        for (d, index, what) in need {
            if !self.maps(d, index, 0) {
                let why = if switch { " (0x6060 is mapped, so the drive may run in either mode)" } else { "" };
                return Err(MapProblem {
                    dir: d,
                    pdo: None,
                    entry: None,
                    message: format!("0x{index:04X} {what} must be in a {}{why}", d.key()),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_objects() {
        assert_eq!(PdoObject::parse("0x6040:0/16"), Ok(PdoObject::new(0x6040, 0, 16)));
        assert_eq!(PdoObject::parse(" 607a "), Ok(PdoObject::new(0x607A, 0, 32)));
        assert_eq!(PdoObject::parse("0x2001:0x1A/8"), Ok(PdoObject::new(0x2001, 0x1A, 8)));
        for bad in ["", "0x", "0x12345", "0x6040:256", "0x6040/0", "0x6040/65", "zz", "0x2001", "0x6040:-1", "+6040", "0x6040/+8"] {
            assert!(PdoObject::parse(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn presets_pass_and_give_todays_maps() {
        for p in [PdoMapping::Compact, PdoMapping::WithMode] {
            let m = PdoMaps::preset(p);
            m.check(DriveMode::Position).unwrap();
            m.check(DriveMode::Torque).unwrap();
            assert_eq!(m.maps_mode(), p == PdoMapping::WithMode);
        }
    }

    #[test]
    fn rules_name_the_pdo_and_object() {
        let o = PdoObject::new;
        let base = PdoMaps::preset(PdoMapping::Compact);
        let mut m = base.clone();
        m.tx[0].push(o(0x606C, 0, 32));
        let e = m.check(DriveMode::Position).unwrap_err();
        assert_eq!(e.key(), "tpdo[0].map");
        assert!(e.message.contains("96 bits"), "{}", e.message);
        let mut m = base.clone();
        m.tx.push(vec![o(0x6064, 0, 32)]);
        assert_eq!(m.check(DriveMode::Position).unwrap_err().key(), "tpdo[1].map[0]");
        let mut m = base.clone();
        m.rx[0][1] = o(0x6041, 0, 16);
        assert_eq!(m.check(DriveMode::Position).unwrap_err().key(), "rpdo[0].map[1]");
        let mut m = base.clone();
        m.rx[0][1] = o(0x607A, 0, 16);
        assert!(m.check(DriveMode::Position).unwrap_err().message.contains("32 bits long"));
        let mut m = base.clone();
        m.rx[0].truncate(1);
        m.rx[0].push(o(0x6071, 0, 16));
        let e = m.check(DriveMode::Position).unwrap_err();
        assert_eq!(e.key(), "rpdo");
        assert!(e.message.contains("0x607A"), "{}", e.message);
        m.check(DriveMode::Torque).unwrap();
        let mut m = base.clone();
        m.tx[0].pop();
        m.check(DriveMode::Position).unwrap();
        assert!(m.check(DriveMode::Torque).unwrap_err().message.contains("0x6077"));
        let mut m = base.clone();
        m.rx[0][2] = o(0x2000, 0, 16);
        assert_eq!(m.check(DriveMode::Position).unwrap_err().key(), "rpdo[0].map[2]");
        let mut m = base;
        m.tx.push(vec![o(0x1017, 0, 16)]);
        assert_eq!(m.check(DriveMode::Position).unwrap_err().key(), "tpdo[1].map[0]");
        assert!(PdoMaps::default().check(DriveMode::Position).is_err());
    }
}
