//! The tracker's datagram format: one ASCII line per pose, parsed and written without
//! allocating. The receiver that checks age and order and hands poses to the loop is
//! `taut_driver::tracker`; the simulated tracker (`taut-vdev`) writes these lines.
//!
//! ```text
//! t px py pz [qw qx qy qz]\n
//!
//!   field        unit  meaning
//!   t            s     time stamp of the measurement, tracker clock (any epoch, increasing)
//!   px py pz     m     platform position in the tracker frame
//!   qw qx qy qz  -     optional orientation, unit quaternion, scalar first
//!
//! Fields are separated by spaces or tabs; the newline (LF or CRLF) is optional. Numbers are
//! decimal floating point as Rust's f64 parser reads them ("1", "-0.25", "1e-3").
//! Exactly 4 or 8 fields; at most 256 bytes; everything else is malformed.
//! Example: "12.345000 0.101 -0.250 1.732 1 0 0 0\n"
//! ```
//!
//! `docs/tracker.md` has the full description.

use std::fmt;
use std::io;

/// Longest datagram accepted.
pub const MAX_LINE: usize = 256;

/// A parsed pose line (tracker time, not yet checked for age or order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseLine {
    /// Tracker time stamp, s.
    pub t: f64,
    /// Position, m.
    pub position: [f64; 3],
    /// Orientation `[w, x, y, z]`, normalised, if sent.
    pub orientation: Option<[f64; 4]>,
}

/// Why a datagram is not a pose line. `Copy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParseError {
    /// No fields.
    Empty,
    /// Longer than [`MAX_LINE`].
    TooLong {
        /// Bytes received.
        len: usize,
    },
    /// A byte that is not printable ASCII or blank.
    NotAscii {
        /// Its offset.
        offset: usize,
    },
    /// Not 4 or 8 fields (or a second line).
    FieldCount {
        /// Fields found (counting stops at 9).
        found: usize,
    },
    /// A field that is no number.
    BadNumber {
        /// 0-based field index.
        field: usize,
    },
    /// A field that is NaN or infinite.
    NotFinite {
        /// 0-based field index.
        field: usize,
    },
    /// The quaternion is not of unit norm (within 1 %).
    NotUnitQuaternion,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParseError::Empty => write!(f, "empty datagram"),
            ParseError::TooLong { len } => write!(f, "datagram of {len} bytes, at most {MAX_LINE}"),
            ParseError::NotAscii { offset } => write!(f, "byte {offset} is not printable ASCII"),
            ParseError::FieldCount { found } => write!(f, "{found} fields, expected 4 (t px py pz) or 8 (t px py pz qw qx qy qz)"),
            ParseError::BadNumber { field } => write!(f, "field {field} is not a number"),
            ParseError::NotFinite { field } => write!(f, "field {field} is not finite"),
            ParseError::NotUnitQuaternion => write!(f, "quaternion norm is not 1"),
        }
    }
}

/// Parses one datagram. Never panics, never allocates.
pub fn parse_line(bytes: &[u8]) -> Result<PoseLine, ParseError> {
    if bytes.len() > MAX_LINE {
        return Err(ParseError::TooLong { len: bytes.len() });
    }
    // One trailing line end is allowed; any other control byte (a second line too) is not.
    let body = bytes.strip_suffix(b"\n").unwrap_or(bytes);
    let body = body.strip_suffix(b"\r").unwrap_or(body);
    if let Some(offset) = body.iter().position(|&b| !(b == b' ' || b == b'\t' || b.is_ascii_graphic())) {
        return Err(if body[offset] == b'\n' { ParseError::FieldCount { found: 9 } } else { ParseError::NotAscii { offset } });
    }
    let mut v = [0f64; 8];
    let mut n = 0usize;
    for field in body.split(|&b| b == b' ' || b == b'\t').filter(|f| !f.is_empty()) {
        if n == v.len() {
            return Err(ParseError::FieldCount { found: n + 1 });
        }
        // Checked ASCII above, so this cannot fail; no unwrap on outside bytes all the same.
        let s = std::str::from_utf8(field).map_err(|_| ParseError::BadNumber { field: n })?;
        let x: f64 = s.parse().map_err(|_| ParseError::BadNumber { field: n })?;
        if !x.is_finite() {
            return Err(ParseError::NotFinite { field: n });
        }
        v[n] = x;
        n += 1;
    }
    let orientation = match n {
        0 => return Err(ParseError::Empty),
        4 => None,
        8 => {
            let q = [v[4], v[5], v[6], v[7]];
            let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm.is_nan() || (norm - 1.0).abs() > 0.01 {
                return Err(ParseError::NotUnitQuaternion);
            }
            Some(q.map(|x| x / norm))
        }
        found => return Err(ParseError::FieldCount { found }),
    };
    Ok(PoseLine { t: v[0], position: [v[1], v[2], v[3]], orientation })
}

/// Writes a pose line (what a tracker, or the simulator, sends); returns its length. Uses
/// Rust's shortest round-trip float formatting, so [`parse_line`] gives back the same numbers.
pub fn format_line(p: &PoseLine, buf: &mut [u8; MAX_LINE]) -> usize {
    use std::io::Write;
    let mut c = io::Cursor::new(&mut buf[..]);
    let [x, y, z] = p.position;
    // 8 shortest-form f64s take at most 8 * 24 + 8 bytes < MAX_LINE: the writes cannot fail.
    let _ = match p.orientation {
        Some([qw, qx, qy, qz]) => writeln!(c, "{:?} {x:?} {y:?} {z:?} {qw:?} {qx:?} {qy:?} {qz:?}", p.t),
        None => writeln!(c, "{:?} {x:?} {y:?} {z:?}", p.t),
    };
    c.position() as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parses_both_forms() {
        let p = parse_line(b"12.5 0.1 -0.25 1.75\n").unwrap();
        assert_eq!(p, PoseLine { t: 12.5, position: [0.1, -0.25, 1.75], orientation: None });
        let p = parse_line(b"1\t0 0 0  0.7071068 0 0.7071068 0\r\n").unwrap();
        let q = p.orientation.unwrap();
        assert!((q.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn malformed_lines() {
        use ParseError::*;
        let cases: &[(&[u8], ParseError)] = &[
            (b"", Empty),
            (b"  \n", Empty),
            (b"1 2 3", FieldCount { found: 3 }),
            (b"1 2 3 4 5", FieldCount { found: 5 }),
            (b"1 2 3 4 5 6 7 8 9", FieldCount { found: 9 }),
            (b"1 2 x 4", BadNumber { field: 2 }),
            (b"1 2 NaN 4", NotFinite { field: 2 }),
            (b"1 2 inf 4", NotFinite { field: 2 }),
            (b"1 2 3 4 2 0 0 0", NotUnitQuaternion),
            (b"1 2 3 4 0 0 0 0", NotUnitQuaternion),
            (b"1 2 3 4\n1 2 3 4\n", FieldCount { found: 9 }),
            (b"1 2 \xC3\xA9 4", NotAscii { offset: 4 }),
            (b"1 2 3\x004", NotAscii { offset: 5 }),
        ];
        for (b, e) in cases {
            assert_eq!(parse_line(b), Err(*e), "{:?}", String::from_utf8_lossy(b));
        }
        assert_eq!(parse_line(&[b'1'; 300]), Err(TooLong { len: 300 }));
    }

    proptest! {
        #[test]
        fn line_round_trip(t in -1e9f64..1e9, p in proptest::array::uniform3(-1e3f64..1e3), q in proptest::option::of(proptest::array::uniform4(-1.0f64..1.0))) {
            let q = q.and_then(|q| {
                let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
                (n > 1e-3).then(|| q.map(|x| x / n))
            });
            let line = PoseLine { t, position: p, orientation: q };
            let mut buf = [0u8; MAX_LINE];
            let n = format_line(&line, &mut buf);
            let back = parse_line(&buf[..n]).unwrap();
            prop_assert_eq!(back.t, t);
            prop_assert_eq!(back.position, p);
            if let (Some(a), Some(b)) = (back.orientation, q) {
                for i in 0..4 { prop_assert!((a[i] - b[i]).abs() < 1e-12); }
            } else {
                prop_assert_eq!(back.orientation.is_some(), q.is_some());
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = parse_line(&bytes);
        }

        #[test]
        fn arbitrary_text_never_panics(s in "[0-9eE+\\-. \\tinfa\\n]{0,80}") {
            let _ = parse_line(s.as_bytes());
        }
    }
}
