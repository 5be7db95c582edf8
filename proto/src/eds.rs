//! Electronic data sheets (CiA 306): the INI file a drive vendor ships that lists the drive's
//! object dictionary.
//!
//! ```text
//! [1000]                     object 0x1000 (hex, no 0x)
//! ParameterName=Device type
//! ObjectType=0x7             7 VAR, 8 ARRAY, 9 RECORD (default 7)
//! DataType=0x0007            CiA 301 data type index (0x0007 UNSIGNED32)
//! AccessType=ro              ro, wo, rw, rwr, rww, const
//! PDOMapping=0               1: may be mapped into a PDO
//! DefaultValue=0x00020192
//! [1018]                     a RECORD: SubNumber=5 and one [1018subN] section per sub-index
//! [1018sub1]                 (N in hex)
//! ```
//!
//! The file is read as bytes (vendors write Latin-1 as often as UTF-8). Section and key names
//! are case-insensitive; blank lines, lines starting with `;` and CRLF line ends are taken.
//! Anything else that is not `[section]` or `key=value` inside a section, a duplicate section or
//! key, a number that does not parse, or an object without the keys it needs is an error with the
//! file and line. Sections other than objects (`[FileInfo]`, `[DeviceInfo]`, ..) are kept as
//! key/value pairs. Caps: 4 MiB, 200 000 lines, 65 536 sections.

use crate::pdo_map::Access;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest EDS file read, bytes.
pub const MAX_BYTES: usize = 4 << 20;
/// Most lines read.
pub const MAX_LINES: usize = 200_000;
/// Most sections.
pub const MAX_SECTIONS: usize = 65_536;

/// An EDS that could not be read, with where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdsError {
    /// The file.
    pub file: Option<PathBuf>,
    /// 1-based line, where known.
    pub line: Option<usize>,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for EdsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.file {
            Some(p) => write!(f, "{}", p.display())?,
            None => write!(f, "<eds>")?,
        }
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for EdsError {}

/// One variable of the object dictionary (a VAR object, or one sub-index of an ARRAY/RECORD).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdsVar {
    /// Index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// ParameterName.
    pub name: String,
    /// DataType (CiA 301 data type index).
    pub data_type: u16,
    /// AccessType.
    pub access: Access,
    /// PDOMapping.
    pub pdo_mapping: bool,
    /// DefaultValue as written.
    pub default: Option<String>,
    /// Line of its section header.
    pub line: usize,
}

impl EdsVar {
    /// Length in bits of its data type, for the basic types CiA 301 7.4.7 defines.
    pub fn bits(&self) -> Option<u8> {
        data_type_bits(self.data_type)
    }
}

/// Length in bits of a CiA 301 basic data type; `None` for strings, domains and unknown types.
pub fn data_type_bits(t: u16) -> Option<u8> {
    Some(match t {
        0x0001 => 1,                    // BOOLEAN
        0x0002 | 0x0005 => 8,           // INTEGER8, UNSIGNED8
        0x0003 | 0x0006 => 16,          // INTEGER16, UNSIGNED16
        0x0010 | 0x0016 => 24,          // INTEGER24, UNSIGNED24
        0x0004 | 0x0007 | 0x0008 => 32, // INTEGER32, UNSIGNED32, REAL32
        0x0012 | 0x0018 => 40,          // INTEGER40, UNSIGNED40
        0x0013 | 0x0019 => 48,          // INTEGER48, UNSIGNED48
        0x0014 | 0x001A => 56,          // INTEGER56, UNSIGNED56
        0x0011 | 0x0015 | 0x001B => 64, // REAL64, INTEGER64, UNSIGNED64
        _ => return None,
    })
}

/// A parsed EDS.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Eds {
    /// The file it came from.
    pub file: Option<PathBuf>,
    vars: BTreeMap<(u16, u8), EdsVar>,
    /// Object index -> line of its section, for every object (VAR, ARRAY, RECORD).
    objects: BTreeMap<u16, usize>,
    /// `[DeviceInfo]` keys (lower case) and values.
    pub device_info: BTreeMap<String, String>,
}

struct Section {
    name: String,
    line: usize,
    keys: BTreeMap<String, (String, usize)>,
}

impl Eds {
    /// Reads and parses `path`.
    pub fn load(path: impl AsRef<Path>) -> Result<Eds, EdsError> {
        let path = path.as_ref();
        let err = |m: String| EdsError { file: Some(path.to_path_buf()), line: None, message: m };
        let meta = std::fs::metadata(path).map_err(|e| err(format!("cannot read the EDS file: {e}")))?;
        if meta.len() > MAX_BYTES as u64 {
            return Err(err(format!("{} bytes: an EDS over {MAX_BYTES} bytes is refused", meta.len())));
        }
        let bytes = std::fs::read(path).map_err(|e| err(format!("cannot read the EDS file: {e}")))?;
        Eds::parse(&bytes)
            .map_err(|mut e| {
                e.file = Some(path.to_path_buf());
                e
            })
            .map(|mut eds| {
                eds.file = Some(path.to_path_buf());
                eds
            })
    }

    /// Parses EDS text (bytes; see the module doc).
    pub fn parse(bytes: &[u8]) -> Result<Eds, EdsError> {
        let bad = |line: usize, m: String| EdsError { file: None, line: Some(line), message: m };
        if bytes.len() > MAX_BYTES {
            return Err(EdsError { file: None, line: None, message: format!("an EDS over {MAX_BYTES} bytes is refused") });
        }
        // Latin-1 and UTF-8 alike: non-ASCII bytes only ever occur inside names and comments.
        let text: String = bytes.iter().map(|&b| b as char).collect();
        let mut sections: Vec<Section> = Vec::new();
        let mut seen: BTreeMap<String, usize> = BTreeMap::new();
        for (i, raw) in text.split('\n').enumerate() {
            let line = i + 1;
            if line > MAX_LINES {
                return Err(bad(line, format!("more than {MAX_LINES} lines: not an EDS taut reads")));
            }
            let l = raw.trim_end_matches('\r').trim();
            if l.is_empty() || l.starts_with(';') {
                continue;
            }
            if let Some(rest) = l.strip_prefix('[') {
                let name = rest
                    .strip_suffix(']')
                    .map(|n| n.trim().to_ascii_lowercase())
                    .filter(|n| !n.is_empty() && !n.contains(['[', ']']))
                    .ok_or_else(|| bad(line, format!("malformed section header {l:?}: write [name]")))?;
                if let Some(first) = seen.insert(name.clone(), line) {
                    return Err(bad(line, format!("section [{name}] again (first on line {first})")));
                }
                if sections.len() >= MAX_SECTIONS {
                    return Err(bad(line, format!("more than {MAX_SECTIONS} sections")));
                }
                sections.push(Section { name, line, keys: BTreeMap::new() });
                continue;
            }
            let Some((k, v)) = l.split_once('=') else {
                return Err(bad(line, format!("{l:?} is neither [section] nor key=value")));
            };
            let k = k.trim().to_ascii_lowercase();
            if k.is_empty() {
                return Err(bad(line, "a key=value line without a key".into()));
            }
            let Some(s) = sections.last_mut() else {
                return Err(bad(line, format!("key {k:?} before the first [section]")));
            };
            if let Some((_, first)) = s.keys.insert(k.clone(), (v.trim().to_string(), line)) {
                return Err(bad(line, format!("key {k} again in [{}] (first on line {first})", s.name)));
            }
        }
        let mut eds = Eds::default();
        for s in &sections {
            if s.name == "deviceinfo" {
                eds.device_info = s.keys.iter().map(|(k, (v, _))| (k.clone(), v.clone())).collect();
            }
            let Some((index, sub)) = object_section(&s.name) else { continue };
            let get = |k: &str| s.keys.get(k);
            let num = |k: &str| -> Result<Option<u32>, EdsError> {
                match get(k) {
                    None => Ok(None),
                    Some((v, l)) => parse_number(v).map(Some).ok_or_else(|| bad(*l, format!("{k} = {v:?} is not a number"))),
                }
            };
            let object_type = match num("objecttype")? {
                None => 7,
                Some(t @ (2 | 5 | 6 | 7 | 8 | 9)) => t,
                Some(t) => {
                    return Err(bad(get("objecttype").map_or(s.line, |x| x.1), format!("ObjectType {t} is not one CiA 306 defines")))
                }
            };
            if sub.is_none() {
                eds.objects.insert(index, s.line);
            }
            if object_type != 7 {
                if sub.is_none() && matches!(object_type, 8 | 9) && get("subnumber").is_none() && get("compactsubobj").is_none() {
                    return Err(bad(s.line, format!("[{}]: an ARRAY/RECORD needs SubNumber (and [{}subN] sections)", s.name, s.name)));
                }
                continue;
            }
            let need = |k: &str| get(k).ok_or_else(|| bad(s.line, format!("[{}]: a variable needs {k}", s.name)));
            let (dt, dl) = need("datatype")?;
            let data_type = parse_number(dt)
                .and_then(|v| u16::try_from(v).ok())
                .ok_or_else(|| bad(*dl, format!("DataType = {dt:?} is not a data type index")))?;
            let (at, al) = need("accesstype")?;
            let access = match at.to_ascii_lowercase().as_str() {
                "ro" => Access::Ro,
                "wo" => Access::Wo,
                "rw" | "rwr" | "rww" => Access::Rw,
                "const" => Access::Const,
                _ => return Err(bad(*al, format!("AccessType = {at:?}: use ro, wo, rw, rwr, rww or const"))),
            };
            let pdo_mapping = match num("pdomapping")? {
                None | Some(0) => false,
                Some(1) => true,
                Some(v) => return Err(bad(get("pdomapping").map_or(s.line, |x| x.1), format!("PDOMapping = {v}: must be 0 or 1"))),
            };
            let name = get("parametername").map(|x| x.0.clone()).unwrap_or_default();
            if name.len() > 241 {
                return Err(bad(s.line, "ParameterName longer than 241 characters (CiA 306 limit)".into()));
            }
            let v = EdsVar {
                index,
                sub: sub.unwrap_or(0),
                name,
                data_type,
                access,
                pdo_mapping,
                default: get("defaultvalue").map(|x| x.0.clone()),
                line: s.line,
            };
            eds.vars.insert((index, v.sub), v);
        }
        Ok(eds)
    }

    /// The variable `index:sub`.
    pub fn var(&self, index: u16, sub: u8) -> Option<&EdsVar> {
        self.vars.get(&(index, sub))
    }

    /// Line of object `index`'s section, if the EDS lists it.
    pub fn object_line(&self, index: u16) -> Option<usize> {
        self.objects.get(&index).copied()
    }

    /// Every variable, in index order.
    pub fn vars(&self) -> impl Iterator<Item = &EdsVar> {
        self.vars.values()
    }
}

/// `1000` -> (0x1000, None); `1018sub2` -> (0x1018, Some(2)); anything else `None`.
fn object_section(name: &str) -> Option<(u16, Option<u8>)> {
    let hex = |s: &str| {
        (!s.is_empty() && s.len() <= 4 && s.bytes().all(|b| b.is_ascii_hexdigit())).then(|| u16::from_str_radix(s, 16).ok()).flatten()
    };
    match name.split_once("sub") {
        Some((i, s)) => {
            let sub = (!s.is_empty() && s.len() <= 2 && s.bytes().all(|b| b.is_ascii_hexdigit()))
                .then(|| u8::from_str_radix(s, 16).ok())
                .flatten()?;
            Some((hex(i)?, Some(sub)))
        }
        None => Some((hex(name)?, None)),
    }
}

/// A CiA 306 number: `0x` hex, a leading `0` octal, else decimal; `$NODEID+` forms are not
/// numbers here (the caller reports them).
fn parse_number(s: &str) -> Option<u32> {
    let s = s.trim();
    if let Some(h) = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        return (!h.is_empty() && h.bytes().all(|b| b.is_ascii_hexdigit())).then(|| u32::from_str_radix(h, 16).ok()).flatten();
    }
    if !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()) {
        return if s.len() > 1 && s.starts_with('0') { u32::from_str_radix(&s[1..], 8).ok() } else { s.parse().ok() };
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = "; a drive\r\n[DeviceInfo]\r\nProductName=Test\r\n\r\n[6064]\r\nParameterName=Position actual value\r\nObjectType=0x7\r\nDataType=0x0004\r\nAccessType=RO\r\nPDOMapping=1\r\n[1018]\r\nObjectType=0x9\r\nSubNumber=2\r\n[1018SUB1]\r\nDataType=0x0007\r\naccesstype=ro\r\n";

    #[test]
    fn parses_case_comments_and_crlf() {
        let e = Eds::parse(SMALL.as_bytes()).unwrap();
        let v = e.var(0x6064, 0).unwrap();
        assert_eq!((v.access, v.pdo_mapping, v.bits(), v.line), (Access::Ro, true, Some(32), 5));
        assert_eq!(e.var(0x1018, 1).unwrap().bits(), Some(32));
        assert!(e.var(0x1018, 0).is_none());
        assert_eq!(e.object_line(0x1018), Some(11));
        assert_eq!(e.device_info.get("productname").map(String::as_str), Some("Test"));
    }

    #[test]
    fn malformed_input_names_the_line() {
        for (text, line) in [
            ("[6064\nDataType=4\n", 1),
            ("DataType=4\n", 1),
            ("[6064]\nDataType=0x0004\nwhat\n", 3),
            ("[6064]\nDataType=0x0004\nAccessType=ro\n[6064]\n", 4),
            ("[6064]\nDataType=0x0004\ndatatype=0x0004\n", 3),
            ("[6064]\nDataType=zz\nAccessType=ro\n", 2),
            ("[6064]\nDataType=0x0004\nAccessType=rx\n", 3),
            ("[6064]\nDataType=0x0004\nAccessType=ro\nPDOMapping=2\n", 4),
            ("[6064]\nAccessType=ro\n", 1),
            ("[1018]\nObjectType=9\n", 1),
            ("[1018]\nObjectType=3\n", 2),
        ] {
            let e = Eds::parse(text.as_bytes()).unwrap_err();
            assert_eq!(e.line, Some(line), "{text:?}: {e}");
        }
    }

    #[test]
    fn numbers() {
        assert_eq!(parse_number("0x1A"), Some(26));
        assert_eq!(parse_number("010"), Some(8));
        assert_eq!(parse_number("10"), Some(10));
        assert_eq!(parse_number("$NODEID+0x180"), None);
        assert_eq!(parse_number("0x"), None);
    }
}
