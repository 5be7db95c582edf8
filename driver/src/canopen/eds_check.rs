//! The check of a drive's configuration against its EDS (CiA 306), before the bus is touched:
//! every object the master reads, writes or maps must exist, have the access that use needs and,
//! when mapped, allow PDO mapping with the length the map gives it.
//!
//! The list of uses comes from the master's own configuration steps ([`NodeConfig::object_uses`]),
//! so what is checked is exactly what bring-up will do.

use super::master::{NodeConfig, ObjectUse, Use};
use std::fmt;
use taut_proto::eds::{Eds, EdsVar};

/// An object the EDS does not allow for its use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdsProblem {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Line of the object in the EDS, where it is there.
    pub line: Option<usize>,
    /// What is wrong and what to do.
    pub message: String,
}

impl fmt::Display for EdsProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "object 0x{:04X}sub{}: {}", self.index, self.sub, self.message)
    }
}

/// One checked use, for the summary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CheckedUse {
    /// The use.
    pub u: ObjectUse,
    /// The EDS entry, `None` for an optional object the EDS does not list.
    pub var: Option<EdsVar>,
}

/// Checks every object `cfg` uses against `eds`; the first problem, or the list of checked uses.
pub fn check(cfg: &NodeConfig, eds: &Eds) -> Result<Vec<CheckedUse>, EdsProblem> {
    let mut out = Vec::new();
    for u in cfg.object_uses() {
        let bad = |line: Option<usize>, message: String| EdsProblem { index: u.index, sub: u.sub, line, message };
        let Some(v) = eds.var(u.index, u.sub) else {
            if u.optional {
                out.push(CheckedUse { u, var: None });
                continue;
            }
            let line = eds.object_line(u.index);
            let what = match line {
                Some(l) => format!("the EDS lists object 0x{:04X} (line {l}) but not sub-index {}", u.index, u.sub),
                None => format!("not in the EDS, but taut {}", u.kind.verb()),
            };
            return Err(bad(line, format!("{what}: is this the drive's EDS? (node {})", cfg.node_id)));
        };
        let line = Some(v.line);
        let (read, write) = match u.kind {
            Use::Read => (true, false),
            Use::Write { .. } | Use::Rpdo { .. } => (false, true),
            Use::Tpdo { .. } => (true, false),
        };
        if read && !v.access.readable() {
            return Err(bad(line, format!("AccessType={}, but taut {}", v.access.name(), u.kind.verb())));
        }
        if write && !v.access.writable() {
            return Err(bad(line, format!("AccessType={}, but taut {}", v.access.name(), u.kind.verb())));
        }
        let want_bits = match u.kind {
            Use::Write { bytes } => Some(bytes * 8),
            Use::Rpdo { bits } | Use::Tpdo { bits } => Some(bits),
            Use::Read => None,
        };
        if let (Some(w), Some(b)) = (want_bits, v.bits()) {
            if w != b {
                return Err(bad(line, format!("DataType=0x{:04X} is {b} bits, taut {} as {w} bits", v.data_type, u.kind.verb())));
            }
        }
        if matches!(u.kind, Use::Rpdo { .. } | Use::Tpdo { .. }) {
            if !v.pdo_mapping {
                return Err(bad(line, format!("PDOMapping=0, but the configuration {}: map another object or remove it", u.kind.verb())));
            }
            if v.bits().is_none() {
                return Err(bad(line, format!("DataType=0x{:04X} has no fixed length and cannot be mapped", v.data_type)));
            }
        }
        out.push(CheckedUse { u, var: Some(v.clone()) });
    }
    Ok(out)
}

/// A table of the checked uses, for `taut probe --eds-summary`.
pub fn summary(node: u8, file: &str, uses: &[CheckedUse]) -> String {
    let mut s = format!("node {node}: {file}\n");
    for c in uses {
        let (name, access, ty, line) = match &c.var {
            Some(v) => (v.name.as_str(), v.access.name(), format!("0x{:04X}", v.data_type), v.line.to_string()),
            None => ("(not in the EDS, optional)", "-", "-".into(), "-".into()),
        };
        s += &format!(
            "  0x{:04X}sub{:<3} {:<34} {:<5} {:<7} line {:<6} {}\n",
            c.u.index,
            c.u.sub,
            name.chars().take(34).collect::<String>(),
            access,
            ty,
            line,
            c.u.kind.verb()
        );
    }
    s
}
