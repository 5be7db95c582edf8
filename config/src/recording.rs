//! `cdpr-recording v1`: the project's one interchange format for recordings (CSV).
//!
//! ```text
//! # cdpr-recording v1                      optional comment lines starting with '#'
//! t,px,py,pz,qw,qx,qy,qz,l0,l1,l2,l3,f0,f1,f2,f3,phase
//! 0.00,0.1,0.2,1.5,1,0,0,0,4.10,4.21,4.05,3.99,12.1,11.7,13.0,12.4,0
//! ```
//!
//! | column            | unit | meaning                                                              |
//! |-------------------|------|----------------------------------------------------------------------|
//! | `t`               | s    | sample time, non-decreasing                                          |
//! | `px,py,pz`        | m    | tracker position of the platform reference point                    |
//! | `qw,qx,qy,qz`     | -    | optional platform orientation, unit quaternion, platform -> tracker  |
//! | `l0..l{n-1}`      | m    | encoder cable lengths, incremental (any per-cable offset)            |
//! | `f0..f{n-1}`      | N    | load-cell tensions; may be empty for a whole recording               |
//! | `phase`           | -    | optional initialisation phase, -1 outside                            |
//!
//! Columns are found by name, in any order; unknown columns are ignored with a note. An empty field
//! or `nan` is a missing value. Rows are kept in memory column-wise, missing values as NaN.

use std::fmt;
use std::io::{BufRead, Write};
use std::path::Path;

mod pieces;

/// The first comment line of a file written by this project.
pub const MAGIC: &str = "# cdpr-recording v1";

/// Read buffer of [`Recording::load`], bytes.
const READ_BUFFER_BYTES: usize = 256 * 1024;

/// Fewer usable samples (rows with at least one length; the tracker position may be missing, a
/// recording without a tracker is calibrated from the lengths and tensions) than this is an error.
pub const MIN_USABLE_SAMPLES: usize = 10;

/// Longest line the reader accepts, bytes. A row of 64 cables with 20-character numbers is under
/// 3 KiB; anything this long is not a recording (`/dev/zero`, a binary file, a lost newline).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Most lines (rows, comments and blank lines) the reader accepts: 10 million, a 1 kHz recording of
/// 2.7 hours, about 2 GB in memory at 12 cables.
pub const MAX_LINES: usize = 10_000_000;

/// Largest file `Recording::load` opens, bytes (checked before reading a regular file).
pub const MAX_FILE_BYTES: u64 = 4 << 30;

/// Largest file [`Recording::load_with`] reads whole to parse on several threads, bytes (a
/// 1 kHz 12-cable recording of about 40 minutes); a larger one is read as a stream.
pub const MAX_IN_MEMORY_BYTES: u64 = 512 << 20;

/// Most cables (`l` columns) a recording may have.
pub const MAX_RECORDING_CABLES: usize = 64;

/// Largest plausible sample time, s: seconds from the start of a run or Unix time (1.8e9 in 2027)
/// both fit; 1e308 does not.
pub const MAX_TIME_S: f64 = 1e10;

/// Comment lines kept for provenance; further ones are counted in a note.
const MAX_COMMENTS: usize = 200;

/// Characters of a field echoed in a message; longer fields are cut with "…".
const ECHO_CHARS: usize = 40;

/// A field as it may be shown to a person: at most `ECHO_CHARS` (40) characters, control characters
/// escaped, and the length said when cut.
pub fn excerpt(s: &str) -> String {
    let mut out = String::new();
    for (n, c) in s.chars().enumerate() {
        if n == ECHO_CHARS {
            out.push_str(&format!("… ({} bytes)", s.len()));
            return out;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// A recording in memory, column-wise. Missing values are NaN.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// Number of cables `n`.
    pub n_cables: usize,
    /// Sample times, s.
    pub t: Vec<f64>,
    /// Tracker positions, m.
    pub p: Vec<[f64; 3]>,
    /// Platform orientations (w, x, y, z), if the recording has them.
    pub q: Option<Vec<[f64; 4]>>,
    /// Encoder lengths, m, row-major: sample `i`, cable `j` at `i * n_cables + j`.
    pub l: Vec<f64>,
    /// Tensions, N, row-major like `l`; `None` when the recording has no tensions at all.
    pub f: Option<Vec<f64>>,
    /// Initialisation phase per sample (-1 outside), if the recording has a phase column.
    pub phase: Option<Vec<i32>>,
    /// Comment lines (without the leading `#`), for provenance.
    pub comments: Vec<String>,
}

impl Recording {
    /// An empty recording of `n` cables with room for `capacity` samples.
    pub fn with_capacity(n: usize, capacity: usize, tensions: bool, orientation: bool, phase: bool) -> Self {
        Recording {
            n_cables: n,
            t: Vec::with_capacity(capacity),
            p: Vec::with_capacity(capacity),
            q: orientation.then(|| Vec::with_capacity(capacity)),
            l: Vec::with_capacity(capacity * n),
            f: tensions.then(|| Vec::with_capacity(capacity * n)),
            phase: phase.then(|| Vec::with_capacity(capacity)),
            comments: Vec::new(),
        }
    }

    /// Tries to make room for `additional` more samples in every column; on failure (an
    /// estimate from a hostile file's size) the columns simply grow as rows come.
    fn try_reserve(&mut self, additional: usize) {
        let n = self.n_cables;
        let _ =
            self.t.try_reserve(additional).and_then(|_| self.p.try_reserve(additional)).and_then(|_| self.l.try_reserve(additional * n));
        if let Some(q) = &mut self.q {
            let _ = q.try_reserve(additional);
        }
        if let Some(f) = &mut self.f {
            let _ = f.try_reserve(additional * n);
        }
        if let Some(ph) = &mut self.phase {
            let _ = ph.try_reserve(additional);
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Encoder lengths of sample `i`.
    pub fn lengths(&self, i: usize) -> &[f64] {
        &self.l[i * self.n_cables..(i + 1) * self.n_cables]
    }

    /// Tensions of sample `i`, if the recording has tensions.
    pub fn tensions(&self, i: usize) -> Option<&[f64]> {
        self.f.as_ref().map(|f| &f[i * self.n_cables..(i + 1) * self.n_cables])
    }

    /// Appends one sample. `q`, `f` and `phase` are ignored when the recording lacks that column
    /// and must be given when it has it (missing values as NaN).
    pub fn push(&mut self, t: f64, p: [f64; 3], q: Option<[f64; 4]>, l: &[f64], f: Option<&[f64]>, phase: Option<i32>) {
        assert_eq!(l.len(), self.n_cables, "one length per cable");
        self.t.push(t);
        self.p.push(p);
        if let Some(qs) = &mut self.q {
            qs.push(q.unwrap_or([f64::NAN; 4]));
        }
        self.l.extend_from_slice(l);
        if let Some(fs) = &mut self.f {
            match f {
                Some(f) => {
                    assert_eq!(f.len(), self.n_cables, "one tension per cable");
                    fs.extend_from_slice(f);
                }
                None => fs.extend(std::iter::repeat_n(f64::NAN, self.n_cables)),
            }
        }
        if let Some(ph) = &mut self.phase {
            ph.push(phase.unwrap_or(-1));
        }
    }

    /// A recording of the samples `range` (comments kept).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Recording {
        let n = self.n_cables;
        Recording {
            n_cables: n,
            t: self.t[range.clone()].to_vec(),
            p: self.p[range.clone()].to_vec(),
            q: self.q.as_ref().map(|q| q[range.clone()].to_vec()),
            l: self.l[range.start * n..range.end * n].to_vec(),
            f: self.f.as_ref().map(|f| f[range.start * n..range.end * n].to_vec()),
            phase: self.phase.as_ref().map(|p| p[range.clone()].to_vec()),
            comments: self.comments.clone(),
        }
    }

    /// A recording of the samples in `ranges`, in that order (comments kept): for a split into
    /// interleaved time blocks. Ranges must lie within the recording.
    pub fn gather(&self, ranges: &[std::ops::Range<usize>]) -> Recording {
        let n = self.n_cables;
        let rows: usize = ranges.iter().map(|r| r.len()).sum();
        let mut out = Recording {
            n_cables: n,
            t: Vec::with_capacity(rows),
            p: Vec::with_capacity(rows),
            q: self.q.as_ref().map(|_| Vec::with_capacity(rows)),
            l: Vec::with_capacity(rows * n),
            f: self.f.as_ref().map(|_| Vec::with_capacity(rows * n)),
            phase: self.phase.as_ref().map(|_| Vec::with_capacity(rows)),
            comments: self.comments.clone(),
        };
        for r in ranges {
            out.t.extend_from_slice(&self.t[r.clone()]);
            out.p.extend_from_slice(&self.p[r.clone()]);
            if let (Some(o), Some(q)) = (&mut out.q, &self.q) {
                o.extend_from_slice(&q[r.clone()]);
            }
            out.l.extend_from_slice(&self.l[r.start * n..r.end * n]);
            if let (Some(o), Some(f)) = (&mut out.f, &self.f) {
                o.extend_from_slice(&f[r.start * n..r.end * n]);
            }
            if let (Some(o), Some(ph)) = (&mut out.phase, &self.phase) {
                o.extend_from_slice(&ph[r.clone()]);
            }
        }
        out
    }

    /// Writes the recording as `cdpr-recording v1` CSV.
    pub fn write_csv<W: Write>(&self, mut w: W) -> std::io::Result<()> {
        let n = self.n_cables;
        writeln!(w, "{MAGIC}")?;
        for c in &self.comments {
            if c.trim() != MAGIC.trim_start_matches('#').trim() {
                writeln!(w, "#{c}")?;
            }
        }
        let mut header = String::from("t,px,py,pz");
        if self.q.is_some() {
            header.push_str(",qw,qx,qy,qz");
        }
        for j in 0..n {
            header.push_str(&format!(",l{j}"));
        }
        if self.f.is_some() {
            for j in 0..n {
                header.push_str(&format!(",f{j}"));
            }
        }
        if self.phase.is_some() {
            header.push_str(",phase");
        }
        writeln!(w, "{header}")?;
        let mut line = String::with_capacity(256);
        for i in 0..self.len() {
            line.clear();
            push_num(&mut line, self.t[i], 6);
            for v in self.p[i] {
                line.push(',');
                push_num(&mut line, v, 6);
            }
            if let Some(q) = &self.q {
                for v in q[i] {
                    line.push(',');
                    push_num(&mut line, v, 9);
                }
            }
            for &v in self.lengths(i) {
                line.push(',');
                push_num(&mut line, v, 7);
            }
            if let Some(f) = self.tensions(i) {
                for &v in f {
                    line.push(',');
                    push_num(&mut line, v, 3);
                }
            }
            if let Some(ph) = &self.phase {
                line.push_str(&format!(",{}", ph[i]));
            }
            line.push('\n');
            w.write_all(line.as_bytes())?;
        }
        w.flush()
    }

    /// Writes the recording to `path` atomically (temporary file + rename).
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
        let mut buf = Vec::with_capacity(self.len() * (16 + 24 * self.n_cables));
        self.write_csv(&mut buf)?;
        crate::write_atomic(path.as_ref(), &buf)
    }

    /// Reads a recording from a file; errors name the file, line and column.
    pub fn load(path: impl AsRef<Path>) -> Result<(Recording, ParseReport), RecordingError> {
        Self::load_with(path, 1)
    }

    /// [`Recording::load`] on up to `threads` threads: a regular file of at most
    /// [`MAX_IN_MEMORY_BYTES`] is read whole and its rows cut into pieces, one per thread; the
    /// recording, the report and every error are those of [`Recording::load`].
    pub fn load_with(path: impl AsRef<Path>, threads: usize) -> Result<(Recording, ParseReport), RecordingError> {
        let path = path.as_ref();
        let err = |kind| RecordingError { file: Some(path.display().to_string()), line: 0, column: None, kind };
        let file = crate::input::open(path).map_err(|e| err(ErrorKind::Io(e)))?;
        if let Ok(m) = file.metadata() {
            if m.is_dir() {
                return Err(err(ErrorKind::Io("is a directory; give the path of a recording (CSV)".into())));
            }
            if m.is_file() && m.len() > MAX_FILE_BYTES {
                return Err(err(ErrorKind::TooLarge(format!(
                    "{} bytes, more than the {} GiB a recording may have; split it into runs",
                    m.len(),
                    MAX_FILE_BYTES >> 30
                ))));
            }
        }
        // MCAP by its magic bytes, whatever the file is called.
        let size = file.metadata().ok().filter(|m| m.is_file()).map(|m| m.len());
        // Large reads: a recording is read front to back once.
        let mut file = std::io::BufReader::with_capacity(READ_BUFFER_BYTES, file);
        if file.fill_buf().map_err(|e| err(ErrorKind::Io(e.to_string())))?.starts_with(MCAP_MAGIC) {
            #[cfg(feature = "mcap")]
            return crate::mcap::read_from(path, file);
            #[cfg(not(feature = "mcap"))]
            return Err(err(ErrorKind::Mcap(
                "this program was built without MCAP support (taut-config feature `mcap`); read it with `taut`, which has it".into(),
            )));
        }
        let parsed = match size {
            Some(size) if threads > 1 && size <= MAX_IN_MEMORY_BYTES => {
                // A file whose size changed since it was taken is read as a stream.
                match pieces::read_whole(file.get_ref(), size as usize, threads).map_err(|e| err(ErrorKind::Io(e.to_string())))? {
                    Some(bytes) => pieces::parse_bytes(&bytes, threads, pieces::MIN_PIECE_BYTES),
                    None => parse_sized(file, Some(size)),
                }
            }
            _ => parse_sized(file, size),
        };
        parsed.map_err(|mut e| {
            e.file = Some(path.display().to_string());
            e
        })
    }
}

/// Entry points for the fuzz targets (`fuzz/`), compiled only with `--cfg fuzzing`.
#[cfg(fuzzing)]
#[doc(hidden)]
pub mod fuzzing {
    use super::{ParseReport, Recording, RecordingError};

    /// The reader [`Recording::load_with`] uses for a file in memory: the rows after the header
    /// cut into pieces of at least `min_piece` bytes, read on up to `threads` threads.
    pub fn parse_in_pieces(bytes: &[u8], threads: usize, min_piece: usize) -> Result<(Recording, ParseReport), RecordingError> {
        super::pieces::parse_bytes(bytes, threads, min_piece)
    }
}

fn push_num(s: &mut String, v: f64, decimals: usize) {
    use std::fmt::Write as _;
    if v.is_nan() {
        // An empty field is a missing value.
    } else {
        let _ = write!(s, "{v:.decimals$}");
    }
}

/// What the parser skipped or noticed: nothing is dropped silently.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParseReport {
    /// Data rows read.
    pub rows: usize,
    /// Rows with at least one length (with or without a tracker position).
    pub usable_rows: usize,
    /// Rows whose tracker position is missing (dropout).
    pub missing_position: usize,
    /// Missing length values (cells).
    pub missing_length: usize,
    /// Missing tension values (cells), when the recording has tensions.
    pub missing_tension: usize,
    /// Columns not part of the format, ignored.
    pub ignored_columns: Vec<String>,
    /// Human-readable notes (ignored columns, no tensions, ...).
    pub notes: Vec<String>,
}

impl ParseReport {
    /// The notes on missing values, in the words every reader uses (CSV and MCAP alike).
    pub(crate) fn note_missing(&mut self) {
        if self.missing_position > 0 {
            self.notes.push(format!("{} rows without a tracker position (dropouts)", self.missing_position));
        }
        if self.missing_length > 0 {
            self.notes.push(format!("{} missing length readings", self.missing_length));
        }
        if self.missing_tension > 0 {
            self.notes.push(format!("{} missing tension readings", self.missing_tension));
        }
    }
}

/// What is wrong with a recording.
#[derive(Debug, Clone, PartialEq)]
pub enum ErrorKind {
    /// The file could not be read.
    Io(String),
    /// No header line.
    NoHeader,
    /// A required column is absent.
    MissingColumn(String),
    /// A column appears twice.
    DuplicateColumn(String),
    /// `l` columns are not `l0..l{n-1}` or `f` columns do not match them.
    CableColumns(String),
    /// A row has a different number of fields than the header.
    FieldCount {
        /// Fields in the header.
        expected: usize,
        /// Fields in this row.
        found: usize,
    },
    /// A field is not a number.
    NotANumber(String),
    /// A field is a number but not finite (`inf`, `1e400`).
    NotFinite(String),
    /// A `phase` field is not an integer phase id.
    Phase(String),
    /// A line longer than [`MAX_LINE_BYTES`].
    LineTooLong,
    /// A NUL byte at this 1-based byte of the line: a binary file.
    Binary(usize),
    /// Not UTF-8 text: the first bad byte, 1-based within the line.
    NotUtf8(usize),
    /// A `# cdpr-recording vN` tag with a version this reader does not know.
    UnknownVersion(String),
    /// The header is separated by something other than commas (named).
    Separator(&'static str),
    /// Quoted fields (`"t"`), which the format does not have.
    Quoted(String),
    /// More than the reader's size limits.
    TooLarge(String),
    /// Time is missing, or earlier than on the previous row.
    Time(String),
    /// An MCAP file that is not a readable taut recording (what is wrong, for a person).
    Mcap(String),
    /// Too few rows with a length.
    TooFewSamples {
        /// Usable rows found.
        usable: usize,
        /// Rows needed.
        needed: usize,
    },
}

/// A parse error with its place: file, 1-based line, column name.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingError {
    /// File name, when read from a file.
    pub file: Option<String>,
    /// 1-based line (0 when not about one line).
    pub line: usize,
    /// Column name, when about one field.
    pub column: Option<String>,
    /// What is wrong.
    pub kind: ErrorKind,
}

impl fmt::Display for RecordingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.as_deref().unwrap_or("<recording>"))?;
        if self.line > 0 {
            write!(f, ":{}", self.line)?;
        }
        if let Some(c) = &self.column {
            write!(f, ": column `{}`", excerpt(c))?;
        }
        match &self.kind {
            ErrorKind::Io(e) => write!(f, ": cannot read: {e}"),
            ErrorKind::NoHeader => write!(f, ": no header line; expected e.g. `t,px,py,pz,l0,l1,l2,f0,f1,f2`"),
            ErrorKind::MissingColumn(c) => {
                write!(f, ": the header has no `{c}` column; a cdpr-recording v1 needs t, px, py, pz and l0..l(n-1)")
            }
            ErrorKind::DuplicateColumn(c) => write!(f, ": column `{}` appears twice in the header", excerpt(c)),
            ErrorKind::CableColumns(m) => write!(f, ": {m}"),
            ErrorKind::FieldCount { expected, found } => {
                write!(f, ": {found} fields, but the header has {expected}; check for a stray or missing comma")
            }
            ErrorKind::NotANumber(s) => write!(f, ": `{}` is not a number (a missing value is an empty field or `nan`)", excerpt(s)),
            ErrorKind::NotFinite(s) => write!(f, ": `{}` is not a finite number (a missing value is an empty field or `nan`)", excerpt(s)),
            ErrorKind::Phase(s) => write!(
                f,
                ": `{}` is not a phase id; `phase` is an integer: 0, 1, 2, ... in the initialisation, -1 or empty outside",
                excerpt(s)
            ),
            ErrorKind::LineTooLong => write!(
                f,
                ": line longer than {} KiB; a recording row is a few hundred bytes (is this a recording? a lost newline?)",
                MAX_LINE_BYTES / 1024
            ),
            ErrorKind::Binary(b) => write!(f, ": NUL byte at byte {b}: this is a binary file, not a CSV recording"),
            ErrorKind::NotUtf8(b) => write!(f, ": byte {b} is not UTF-8 text; save the recording as UTF-8 (plain ASCII numbers)"),
            ErrorKind::UnknownVersion(v) => write!(
                f,
                ": format version `{}` is not known; this reader reads `{MAGIC}` only (use the taut that wrote the file, or convert it)",
                excerpt(v)
            ),
            ErrorKind::Separator(sep) => {
                write!(f, ": the fields are separated by {sep}; a cdpr-recording separates fields with commas and uses `.` for decimals")
            }
            ErrorKind::Quoted(s) => write!(
                f,
                ": quoted field `{}`; a cdpr-recording has no quotes: write names and numbers bare, separated by commas",
                excerpt(s)
            ),
            ErrorKind::TooLarge(m) => write!(f, ": too large: {m}"),
            ErrorKind::Time(m) => write!(f, ": {m}"),
            ErrorKind::Mcap(m) => write!(f, ": MCAP: {m}"),
            ErrorKind::TooFewSamples { usable, needed } => {
                write!(f, ": only {usable} usable samples (rows with a length), at least {needed} needed")
            }
        }
    }
}

impl std::error::Error for RecordingError {}

/// Where each field of the format sits in a row.
#[derive(Clone)]
struct Columns {
    t: usize,
    p: [usize; 3],
    q: Option<[usize; 4]>,
    l: Vec<usize>,
    f: Vec<usize>,
    phase: Option<usize>,
    width: usize,
}

fn parse_header(fields: &[&str], line: usize, report: &mut ParseReport) -> Result<Columns, RecordingError> {
    let err = |column: Option<String>, kind| RecordingError { file: None, line, column, kind };
    // What a spreadsheet export does to a CSV, named before "no `t` column" could mislead.
    if let Some(q) = fields.iter().find(|f| f.starts_with(['"', '\'']) || f.ends_with(['"', '\''])) {
        return Err(err(None, ErrorKind::Quoted(q.to_string())));
    }
    if !fields.contains(&"t") {
        let joined = fields.join(",");
        for (sep, name) in [(';', "semicolons (`;`)"), ('\t', "tabs"), ('|', "`|`")] {
            if joined.split(sep).any(|f| f.trim() == "t") {
                return Err(err(None, ErrorKind::Separator(name)));
            }
        }
        if joined.split_whitespace().any(|f| f == "t") && joined.split_whitespace().any(|f| f == "px") {
            return Err(err(None, ErrorKind::Separator("spaces")));
        }
    }
    let mut seen = std::collections::HashSet::new();
    for f in fields {
        if !seen.insert(*f) {
            return Err(err(Some(f.to_string()), ErrorKind::DuplicateColumn(f.to_string())));
        }
    }
    let find = |name: &str| fields.iter().position(|f| *f == name);
    let need = |name: &str| find(name).ok_or_else(|| err(None, ErrorKind::MissingColumn(name.into())));
    let t = need("t")?;
    let p = [need("px")?, need("py")?, need("pz")?];
    let qn = ["qw", "qx", "qy", "qz"].map(find);
    let q = match qn {
        [Some(a), Some(b), Some(c), Some(d)] => Some([a, b, c, d]),
        [None, None, None, None] => None,
        _ => return Err(err(None, ErrorKind::CableColumns("an orientation needs all four columns qw, qx, qy, qz".into()))),
    };
    let numbered = |prefix: char| -> Vec<(usize, usize)> {
        fields
            .iter()
            .enumerate()
            .filter_map(|(col, f)| {
                let rest = f.strip_prefix(prefix)?;
                if rest.is_empty() || !rest.bytes().all(|b| b.is_ascii_digit()) {
                    return None;
                }
                Some((rest.parse().ok()?, col))
            })
            .collect()
    };
    let mut ls = numbered('l');
    let mut fs = numbered('f');
    ls.sort();
    fs.sort();
    if ls.is_empty() {
        return Err(err(None, ErrorKind::MissingColumn("l0".into())));
    }
    if ls.len() > MAX_RECORDING_CABLES {
        return Err(err(
            None,
            ErrorKind::CableColumns(format!("{} length columns; a recording may have at most {MAX_RECORDING_CABLES} cables", ls.len())),
        ));
    }
    for (k, (idx, _)) in ls.iter().enumerate() {
        if *idx != k {
            return Err(err(
                Some(format!("l{idx}")),
                ErrorKind::CableColumns(format!("length columns must be l0..l{}, found l{idx} where l{k} was expected", ls.len() - 1)),
            ));
        }
    }
    if !fs.is_empty() {
        if fs.len() != ls.len() {
            return Err(err(
                None,
                ErrorKind::CableColumns(format!(
                    "{} length columns (l0..l{}) but {} tension columns; give one f column per cable or none",
                    ls.len(),
                    ls.len() - 1,
                    fs.len()
                )),
            ));
        }
        for (k, (idx, _)) in fs.iter().enumerate() {
            if *idx != k {
                return Err(err(
                    Some(format!("f{idx}")),
                    ErrorKind::CableColumns(format!("tension columns must be f0..f{}, found f{idx}", fs.len() - 1)),
                ));
            }
        }
    }
    let phase = find("phase");
    let mut known = vec![t, p[0], p[1], p[2]];
    known.extend(q.iter().flatten());
    known.extend(ls.iter().map(|x| x.1));
    known.extend(fs.iter().map(|x| x.1));
    known.extend(phase);
    for (col, f) in fields.iter().enumerate() {
        if !known.contains(&col) {
            report.ignored_columns.push(f.to_string());
        }
    }
    if !report.ignored_columns.is_empty() {
        let k = report.ignored_columns.len();
        let shown: Vec<String> = report.ignored_columns.iter().take(10).map(|c| excerpt(c)).collect();
        let more = if k > 10 { format!(" and {} more", k - 10) } else { String::new() };
        report.notes.push(format!("ignored unknown columns: {}{more}", shown.join(", ")));
    }
    Ok(Columns { t, p, q, l: ls.into_iter().map(|x| x.1).collect(), f: fs.into_iter().map(|x| x.1).collect(), phase, width: fields.len() })
}

/// Powers of ten that are exact in an f64 (10^22 < 2^53 * 2^22).
const EXACT_POW10: [f64; 23] =
    [1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22];

/// The common case of a recording's field, `[-+]?digits[.digits]`, without going through the
/// general parser: the digits as an integer `m` and the count of decimals `e`. When `m < 2^53`
/// and `e <= 22` both are exact in an f64 and `m / 10^e` is one correctly rounded division,
/// the same value `str::parse` gives (Clinger's fast path). Anything else (exponents, more
/// digits, `nan`, empty, spaces, junk) returns `None` and goes to [`field`], which validates it.
#[inline]
fn fast_field(b: &[u8]) -> Option<f64> {
    let (neg, digits) = match b.first()? {
        b'-' => (true, &b[1..]),
        b'+' => (false, &b[1..]),
        _ => (false, b),
    };
    let (mut m, mut n, mut decimals, mut dot) = (0u64, 0usize, 0usize, false);
    for &c in digits {
        match c {
            b'0'..=b'9' => {
                if n == 19 {
                    return None;
                }
                m = m * 10 + (c - b'0') as u64;
                n += 1;
                decimals += dot as usize;
            }
            b'.' if !dot => dot = true,
            _ => return None,
        }
    }
    if n == 0 || m >= 1 << 53 || decimals >= EXACT_POW10.len() {
        return None;
    }
    let v = m as f64 / EXACT_POW10[decimals];
    Some(if neg { -v } else { v })
}

/// The line at the start of `text` (up to its first `\n`, or all of it) when it is a row of
/// `width` fields as [`fast_field`] reads them: its length, the values in `vals` and the field
/// bounds (from the line's start) in `spans`, in one pass over the bytes (the digits are read as
/// the commas are found, eight at a time where the text has eight more bytes); `None` (with
/// `vals` and `spans` unspecified) when a field is not a plain decimal or the count is not
/// `width`. The values are those the general path gives (a plain decimal is left as it is by
/// trimming, and read by the same fast path there): the same digits make the same integer `m`
/// and the same count of decimals, whichever way they are read.
#[inline]
fn fast_row(text: &[u8], width: usize, vals: &mut Vec<f64>, spans: &mut Vec<(usize, usize)>) -> Option<usize> {
    vals.clear();
    spans.clear();
    let n = text.len();
    let mut k = 0;
    loop {
        let start = k;
        let neg = k < n && text[k] == b'-';
        if k < n && (text[k] == b'-' || text[k] == b'+') {
            k += 1;
        }
        let (mut m, mut digits) = (0u64, 0usize);
        k = digit_run(text, k, &mut m, &mut digits)?;
        let mut decimals = 0;
        if k < n && text[k] == b'.' {
            let before = digits;
            k = digit_run(text, k + 1, &mut m, &mut digits)?;
            decimals = digits - before;
        }
        let end_of_line = k == n || text[k] == b'\n';
        if !end_of_line && text[k] != b',' {
            return None;
        }
        if digits == 0 || m >= 1 << 53 || decimals >= EXACT_POW10.len() || vals.len() == width {
            return None;
        }
        let v = m as f64 / EXACT_POW10[decimals];
        vals.push(if neg { -v } else { v });
        spans.push((start, k));
        if end_of_line {
            return (vals.len() == width).then_some(k);
        }
        k += 1;
    }
}

/// Powers of ten as integers, for appending `d <= 8` digits to an integer.
const POW10_U64: [u64; 9] = [1, 10, 100, 1_000, 10_000, 100_000, 1_000_000, 10_000_000, 100_000_000];

/// Reads the digits of `text` from `k` on into `m` (`m * 10 + digit` each, as the one-digit loop
/// does) and counts them in `digits`: the index of the first byte that is not a digit, or
/// `None` when the number would have more than 19 digits (the fast path's limit: `m` stays
/// below 10^19 < 2^64). Eight bytes at a time while eight are left (SWAR: a bit per byte says
/// which bytes are digits; the leading digits are turned into their integer in three
/// multiplications), then one byte at a time.
#[inline]
fn digit_run(text: &[u8], mut k: usize, m: &mut u64, digits: &mut usize) -> Option<usize> {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGH: u64 = 0x8080_8080_8080_8080;
    let n = text.len();
    while k + 8 <= n {
        let x = u64::from_le_bytes(text[k..k + 8].try_into().expect("eight bytes"));
        // A byte is a digit when its high bit is clear and 0x30 <= b < 0x3A; with the high bit
        // masked off, adding 0x50 or 0x46 to a byte cannot carry into the next one.
        let low = x & !HIGH;
        let ge_0 = low.wrapping_add(0x50 * ONES) & HIGH;
        let ge_colon = low.wrapping_add(0x46 * ONES) & HIGH;
        let not_digit = !(ge_0 & !ge_colon & !x) & HIGH;
        // The first byte is the lowest: the count of digits before the first other byte.
        let d = (not_digit.trailing_zeros() / 8) as usize;
        if d > 0 {
            if *digits + d > 19 {
                return None;
            }
            // The d digits as values 0-9 in the top d bytes, zeros (leading zero digits) below:
            // the digit bytes do not borrow, and whatever the others borrow is shifted out.
            let v = x.wrapping_sub(0x30 * ONES) << (8 * (8 - d));
            // Eight digits, the lowest byte the most significant, to their integer.
            let v = (v & 0x0F0F_0F0F_0F0F_0F0F).wrapping_mul(2561) >> 8;
            let v = (v & 0x00FF_00FF_00FF_00FF).wrapping_mul(6_553_601) >> 16;
            let v = (v & 0x0000_FFFF_0000_FFFF).wrapping_mul(42_949_672_960_001) >> 32;
            *m = *m * POW10_U64[d] + v;
            *digits += d;
            k += d;
        }
        if d < 8 {
            return Some(k);
        }
    }
    while k < n && text[k].is_ascii_digit() {
        if *digits == 19 {
            return None;
        }
        *m = *m * 10 + (text[k] - b'0') as u64;
        *digits += 1;
        k += 1;
    }
    Some(k)
}

/// Parses one field: empty or `nan` (any case) is missing (NaN).
fn field(s: &str) -> Result<f64, ErrorKind> {
    let s = s.trim();
    if s.is_empty() || s.eq_ignore_ascii_case("nan") {
        return Ok(f64::NAN);
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(ErrorKind::NotFinite(s.to_string())),
        Err(_) if s.starts_with(['"', '\'']) => Err(ErrorKind::Quoted(s.to_string())),
        Err(_) => Err(ErrorKind::NotANumber(s.to_string())),
    }
}

/// One line read with [`read_line_capped`].
enum Line {
    /// End of input.
    Eof,
    /// A line (without its newline) is in the buffer.
    Complete,
    /// The line is longer than [`MAX_LINE_BYTES`]; the buffer holds its first bytes.
    TooLong,
}

/// Reads one line into `buf` without ever holding more than [`MAX_LINE_BYTES`] of it.
fn read_line_capped<R: BufRead>(r: &mut R, buf: &mut Vec<u8>) -> std::io::Result<Line> {
    buf.clear();
    loop {
        let avail = match r.fill_buf() {
            Ok(a) => a,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if avail.is_empty() {
            return Ok(if buf.is_empty() { Line::Eof } else { Line::Complete });
        }
        let (take, newline) = match avail.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (avail.len(), false),
        };
        let room = MAX_LINE_BYTES - buf.len();
        if take > room {
            buf.extend_from_slice(&avail[..room]);
            return Ok(Line::TooLong);
        }
        buf.extend_from_slice(&avail[..take]);
        r.consume(take + newline as usize);
        if newline {
            return Ok(Line::Complete);
        }
    }
}

/// The fields of one row: byte ranges into the line, each trimmed when read.
struct Fields<'a> {
    line: &'a str,
    spans: &'a [(usize, usize)],
}

impl<'a> Fields<'a> {
    fn len(&self) -> usize {
        self.spans.len()
    }

    fn get(&self, k: usize) -> &'a str {
        let (a, b) = self.spans[k];
        self.line[a..b].trim()
    }

    fn iter(&self) -> impl Iterator<Item = &'a str> + '_ {
        (0..self.len()).map(|k| self.get(k))
    }
}

/// Parses a `cdpr-recording v1` from a reader. Lines are capped at [`MAX_LINE_BYTES`] and the
/// input at [`MAX_LINES`], so no input makes the reader allocate without bound.
pub fn parse<R: BufRead>(reader: R) -> Result<(Recording, ParseReport), RecordingError> {
    parse_sized(reader, None)
}

/// [`parse`] of an input of `size` bytes, if known (see [`Parser`]).
fn parse_sized<R: BufRead>(mut reader: R, size: Option<u64>) -> Result<(Recording, ParseReport), RecordingError> {
    let mut p = Parser::new(size);
    let mut buf = Vec::with_capacity(1024);
    loop {
        let read = read_line_capped(&mut reader, &mut buf).map_err(|e| RecordingError {
            file: None,
            line: p.lineno + 1,
            column: None,
            kind: ErrorKind::Io(e.to_string()),
        })?;
        if !p.line(read, &buf)? {
            return p.finish();
        }
    }
}

/// The reader between two lines: [`Parser::line`] takes each line as [`read_line_capped`]
/// reads it, [`Parser::finish`] makes the recording at the end. When the input's `size` is
/// known, the columns are sized once from the bytes after the header and the first row's length
/// (room for 10 % more rows than that suggests, never more than [`MAX_LINES`]) instead of growing
/// by doubling (copies and page faults of 100,000-row columns).
struct Parser {
    size: Option<u64>,
    report: ParseReport,
    comments: Vec<String>,
    dropped_comments: usize,
    cols: Option<Columns>,
    rec: Recording,
    /// The last two rows' times and the last row's line, to blame a time outlier on its own row.
    last_t: f64,
    before_last_t: f64,
    last_line: usize,
    lvals: Vec<f64>,
    fvals: Vec<f64>,
    spans: Vec<(usize, usize)>,
    vals: Vec<f64>,
    /// Lines read so far: the 1-based number of the last one.
    lineno: usize,
    /// Bytes of the lines before this one (for sizing the columns).
    consumed: u64,
}

impl Parser {
    fn new(size: Option<u64>) -> Parser {
        Parser {
            size,
            report: ParseReport::default(),
            comments: Vec::new(),
            dropped_comments: 0,
            cols: None,
            rec: Recording::default(),
            last_t: f64::NEG_INFINITY,
            before_last_t: f64::NEG_INFINITY,
            last_line: 0,
            lvals: Vec::new(),
            fvals: Vec::new(),
            spans: Vec::with_capacity(64),
            vals: Vec::with_capacity(64),
            lineno: 0,
            consumed: 0,
        }
    }

    /// One line, `buf` without its newline, as `read` says; false at the end of the input.
    fn line(&mut self, read: Line, buf: &[u8]) -> Result<bool, RecordingError> {
        let at = |line: usize, kind| RecordingError { file: None, line, column: None, kind };
        self.lineno += 1;
        let lineno = self.lineno;
        let (report, rec, vals, spans) = (&mut self.report, &mut self.rec, &mut self.vals, &mut self.spans);
        // A row of plain decimals (nearly every row of a recording) in one pass: such a line
        // has no NUL, no byte-order mark, is ASCII, neither blank nor a comment, so the checks
        // below pass; anything else (spaces, `nan`, empty fields, junk) takes the general path.
        let fast = matches!(read, Line::Complete) && self.cols.as_ref().is_some_and(|c| fast_row(buf, c.width, vals, spans).is_some());
        if !fast {
            if let Some(i) = buf.iter().position(|&b| b == 0) {
                return Err(at(lineno, ErrorKind::Binary(i + 1)));
            }
        }
        match read {
            Line::Eof => return Ok(false),
            Line::TooLong => return Err(at(lineno, ErrorKind::LineTooLong)),
            Line::Complete => {}
        }
        if lineno > MAX_LINES {
            return Err(at(lineno, ErrorKind::TooLarge(format!("more than {MAX_LINES} lines; split the recording into runs"))));
        }
        if fast && report.rows == 0 {
            if let Some(size) = self.size {
                let rest = size.saturating_sub(self.consumed) / (buf.len() as u64 + 1);
                rec.try_reserve((rest + rest / 10).min(MAX_LINES as u64) as usize);
            }
        }
        self.consumed += buf.len() as u64 + 1;
        let mut bytes = buf;
        if lineno == 1 {
            if let Some(rest) = bytes.strip_prefix(b"\xEF\xBB\xBF") {
                bytes = rest;
                report.notes.push("the file starts with a UTF-8 byte-order mark; ignored".into());
            }
        }
        let line = std::str::from_utf8(bytes).map_err(|e| at(lineno, ErrorKind::NotUtf8(e.valid_up_to() + 1)))?;
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() {
            return Ok(true);
        }
        if let Some(comment) = line.strip_prefix('#') {
            if self.cols.is_none() {
                check_version(comment).map_err(|k| at(lineno, k))?;
                if self.comments.len() < MAX_COMMENTS {
                    self.comments.push(comment.to_string());
                } else {
                    self.dropped_comments += 1;
                }
            }
            return Ok(true);
        }
        let c = match &self.cols {
            None => {
                let fields: Vec<&str> = line.split(',').map(str::trim).collect();
                let c = parse_header(&fields, lineno, report)?;
                let n = c.l.len();
                *rec = Recording::with_capacity(n, 1024, !c.f.is_empty(), c.q.is_some(), c.phase.is_some());
                rec.comments = std::mem::take(&mut self.comments);
                self.cols = Some(c);
                return Ok(true);
            }
            Some(c) => c,
        };
        // Field bounds into a buffer kept across rows (no allocation per row).
        if !fast {
            spans.clear();
            let mut start = 0;
            for (k, _) in line.match_indices(',') {
                spans.push((start, k));
                start = k + 1;
            }
            spans.push((start, line.len()));
        }
        let fields = Fields { line, spans };
        if fields.len() != c.width {
            if let Some(q) = fields.iter().find(|f| f.starts_with(['"', '\''])) {
                return Err(at(lineno, ErrorKind::Quoted(q.to_string())));
            }
            return Err(RecordingError {
                file: None,
                line: lineno,
                column: None,
                kind: ErrorKind::FieldCount { expected: c.width, found: fields.len() },
            });
        }
        let get = |col: usize| -> Result<f64, RecordingError> {
            if fast {
                return Ok(vals[col]);
            }
            let f = fields.get(col);
            if let Some(v) = fast_field(f.as_bytes()) {
                return Ok(v);
            }
            field(f).map_err(|kind| RecordingError { file: None, line: lineno, column: Some(header_name(c, col)), kind })
        };
        let t = get(c.t)?;
        let (last_t, before_last_t) = (self.last_t, self.before_last_t);
        let terr = |line: usize, m: String| RecordingError { file: None, line, column: Some("t".into()), kind: ErrorKind::Time(m) };
        if t.is_nan() {
            return Err(terr(lineno, "time is missing; every row needs a time in s (`nan` and empty are not allowed here)".into()));
        }
        if t.abs() > MAX_TIME_S {
            return Err(terr(
                lineno,
                format!(
                    "t = {t:e} s is not a plausible sample time; times are seconds from the start or Unix time, at most {MAX_TIME_S:e}"
                ),
            ));
        }
        if t < last_t {
            // One row far ahead of both neighbours is that row's fault, not the next one's.
            if t >= before_last_t && before_last_t.is_finite() {
                return Err(terr(
                    self.last_line,
                    format!("time jumps ahead to {last_t} s between {before_last_t} s on the row before and {t} s on the row after"),
                ));
            }
            return Err(terr(lineno, format!("time goes backwards: {t} after {last_t}")));
        }
        self.before_last_t = last_t;
        self.last_t = t;
        self.last_line = lineno;
        let p = [get(c.p[0])?, get(c.p[1])?, get(c.p[2])?];
        let q = match c.q {
            Some(qc) => Some([get(qc[0])?, get(qc[1])?, get(qc[2])?, get(qc[3])?]),
            None => None,
        };
        let (lvals, fvals) = (&mut self.lvals, &mut self.fvals);
        lvals.clear();
        for &col in &c.l {
            lvals.push(get(col)?);
        }
        fvals.clear();
        for &col in &c.f {
            fvals.push(get(col)?);
        }
        let phase = match c.phase {
            Some(col) => {
                let s = fields.get(col);
                if s.is_empty() {
                    Some(-1)
                } else {
                    let perr =
                        || RecordingError { file: None, line: lineno, column: Some("phase".into()), kind: ErrorKind::Phase(s.to_string()) };
                    match s.parse::<i32>() {
                        Ok(k) if k >= -1 => Some(k),
                        _ => return Err(perr()),
                    }
                }
            }
            None => None,
        };
        report.rows += 1;
        let pos_ok = p.iter().all(|v| !v.is_nan()) && q.is_none_or(|q| q.iter().all(|v| !v.is_nan()));
        if !pos_ok {
            report.missing_position += 1;
        }
        let nl = lvals.iter().filter(|v| v.is_nan()).count();
        report.missing_length += nl;
        report.missing_tension += fvals.iter().filter(|v| v.is_nan()).count();
        if nl < lvals.len() {
            report.usable_rows += 1;
        }
        rec.push(t, p, q, lvals, (!fvals.is_empty()).then_some(&fvals[..]), phase);
        Ok(true)
    }

    /// The recording at the end of the input, with the checks that need all of it.
    fn finish(self) -> Result<(Recording, ParseReport), RecordingError> {
        let Parser { mut report, dropped_comments, cols, mut rec, .. } = self;
        if cols.is_none() {
            return Err(RecordingError { file: None, line: 0, column: None, kind: ErrorKind::NoHeader });
        }
        if dropped_comments > 0 {
            report.notes.push(format!("{dropped_comments} comment lines after the first {MAX_COMMENTS} not kept"));
        }
        if report.usable_rows < MIN_USABLE_SAMPLES {
            return Err(RecordingError {
                file: None,
                line: 0,
                column: None,
                kind: ErrorKind::TooFewSamples { usable: report.usable_rows, needed: MIN_USABLE_SAMPLES },
            });
        }
        // A tension column that is empty for the whole recording means: no load cells.
        if rec.f.as_ref().is_some_and(|f| f.iter().all(|v| v.is_nan())) {
            rec.f = None;
            report.missing_tension = 0;
            report.notes.push("the f columns are empty: no tensions in this recording".into());
        } else if rec.f.is_none() {
            report.notes.push("no f columns: no tensions in this recording".into());
        }
        report.note_missing();
        Ok((rec, report))
    }
}

/// Refuses a `# cdpr-recording vN` tag of another version than this reader's.
fn check_version(comment: &str) -> Result<(), ErrorKind> {
    const TAG: &str = "cdpr-recording";
    let c = comment.trim();
    // The tag is the word `cdpr-recording` on its own (`# cdpr-recordings of May` is a comment).
    let rest = c.get(TAG.len()..).filter(|_| c.get(..TAG.len()).is_some_and(|h| h.eq_ignore_ascii_case(TAG)));
    if let Some(rest) = rest.filter(|r| r.is_empty() || r.starts_with(char::is_whitespace)) {
        let version = rest.trim();
        if version != "v1" {
            return Err(ErrorKind::UnknownVersion(if version.is_empty() { "(none)".into() } else { version.into() }));
        }
    }
    Ok(())
}

fn header_name(c: &Columns, col: usize) -> String {
    if col == c.t {
        return "t".into();
    }
    if let Some(k) = c.p.iter().position(|&x| x == col) {
        return ["px", "py", "pz"][k].into();
    }
    if let Some(k) = c.q.and_then(|q| q.iter().position(|&x| x == col)) {
        return ["qw", "qx", "qy", "qz"][k].into();
    }
    if let Some(k) = c.l.iter().position(|&x| x == col) {
        return format!("l{k}");
    }
    if let Some(k) = c.f.iter().position(|&x| x == col) {
        return format!("f{k}");
    }
    format!("#{}", col + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(n: usize) -> String {
        (0..n).map(|i| format!("{},{},0,1,2.0,2.1,2.2,5,6,7\n", i as f64 * 0.01, i as f64 * 0.01)).collect()
    }

    fn parse_str(s: &str) -> Result<(Recording, ParseReport), RecordingError> {
        parse(std::io::Cursor::new(s))
    }

    #[test]
    fn round_trip() {
        let text = format!("{MAGIC}\n# robot: test\nt,px,py,pz,l0,l1,l2,f0,f1,f2\n{}", rows(20));
        let (rec, rep) = parse_str(&text).unwrap();
        assert_eq!(rec.len(), 20);
        assert_eq!(rep.usable_rows, 20);
        assert_eq!(rec.n_cables, 3);
        let mut out = Vec::new();
        rec.write_csv(&mut out).unwrap();
        let (back, _) = parse_str(std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(back, rec);
    }

    #[test]
    fn columns_in_any_order_and_unknown_noted() {
        let mut text = String::from("l1,pz,t,extra,px,l0,py,l2,phase\n");
        for i in 0..12 {
            text.push_str(&format!("2.1,1,{i},x,0,2.0,0,2.2,1\n"));
        }
        let (rec, rep) = parse_str(&text).unwrap();
        assert_eq!(rec.lengths(3), &[2.0, 2.1, 2.2]);
        assert_eq!(rep.ignored_columns, vec!["extra".to_string()]);
        assert!(rec.f.is_none());
        assert_eq!(rec.phase.as_ref().unwrap()[0], 1);
    }

    #[test]
    fn missing_values_counted() {
        let mut text = String::from("t,px,py,pz,l0,l1,l2,f0,f1,f2\n");
        text.push_str(&rows(12));
        text.push_str("1.0,,0,1,2,2,2,5,6,7\n1.1,0,0,1,nan,2,2,5,,7\n");
        let (rec, rep) = parse_str(&text).unwrap();
        assert_eq!(rep.rows, 14);
        assert_eq!(rep.missing_position, 1);
        assert_eq!(rep.missing_length, 1);
        assert_eq!(rep.missing_tension, 1);
        // The row without a position still has lengths: usable (calibration without a tracker).
        assert_eq!(rep.usable_rows, 14);
        assert!(rec.p[12][0].is_nan());
    }

    #[test]
    fn empty_tension_columns_mean_no_tensions() {
        let mut text = String::from("t,px,py,pz,l0,l1,l2,f0,f1,f2\n");
        for i in 0..12 {
            text.push_str(&format!("{i},0,0,1,2,2,2,,,\n"));
        }
        let (rec, rep) = parse_str(&text).unwrap();
        assert!(rec.f.is_none());
        assert!(rep.notes.iter().any(|n| n.contains("no tensions")));
    }

    fn err_of(text: &str) -> RecordingError {
        parse_str(text).unwrap_err()
    }

    #[test]
    fn bad_inputs_name_line_and_column() {
        let head = "t,px,py,pz,l0,l1,l2,f0,f1,f2\n";
        // non-numeric
        let e = err_of(&format!("{head}{}0.5,0,abc,1,2,2,2,5,6,7\n", rows(3)));
        assert_eq!((e.line, e.column.as_deref()), (5, Some("py")), "{e}");
        assert!(matches!(e.kind, ErrorKind::NotANumber(_)));
        // wrong field count
        let e = err_of(&format!("{head}{}0.5,0,0,1,2,2,2,5,6\n", rows(2)));
        assert_eq!(e.line, 4, "{e}");
        assert!(matches!(e.kind, ErrorKind::FieldCount { expected: 10, found: 9 }));
        // l/f count mismatch
        let e = err_of("t,px,py,pz,l0,l1,l2,f0,f1\n");
        assert!(matches!(e.kind, ErrorKind::CableColumns(_)), "{e}");
        assert_eq!(e.line, 1);
        // gap in l columns
        let e = err_of("t,px,py,pz,l0,l2\n");
        assert_eq!(e.column.as_deref(), Some("l2"), "{e}");
        // time going backwards
        let e = err_of(&format!("{head}{}0.0,0,0,1,2,2,2,5,6,7\n", rows(5)));
        assert_eq!((e.line, e.column.as_deref()), (7, Some("t")), "{e}");
        assert!(matches!(e.kind, ErrorKind::Time(_)));
        // too few usable samples
        let e = err_of(&format!("{head}{}", rows(5)));
        assert!(matches!(e.kind, ErrorKind::TooFewSamples { usable: 5, needed: 10 }), "{e}");
        // missing required column, duplicate column, no header
        assert!(matches!(err_of("t,px,py,l0\n").kind, ErrorKind::MissingColumn(ref c) if c == "pz"));
        assert!(matches!(err_of("t,px,py,pz,l0,l0\n").kind, ErrorKind::DuplicateColumn(_)));
        assert!(matches!(err_of("# only comments\n").kind, ErrorKind::NoHeader));
        // partial quaternion
        assert!(matches!(err_of("t,px,py,pz,qw,qx,l0\n").kind, ErrorKind::CableColumns(_)));
        // infinite values are not numbers
        let e = err_of(&format!("{head}{}0.5,inf,0,1,2,2,2,5,6,7\n", rows(1)));
        assert_eq!(e.column.as_deref(), Some("px"));
    }

    #[test]
    fn hostile_bytes_are_named() {
        let head = "t,px,py,pz,l0,l1,l2,f0,f1,f2\n";
        // A file of NUL bytes without a newline (`/dev/zero`) ends at the first line.
        let zeros = std::io::Read::take(std::io::repeat(0), 10 * MAX_LINE_BYTES as u64);
        let e = parse(std::io::BufReader::new(zeros)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::Binary(1)) && e.line == 1, "{e}");
        let long = std::io::Read::take(std::io::repeat(b'7'), 10 * MAX_LINE_BYTES as u64);
        let e = parse(std::io::BufReader::new(long)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::LineTooLong) && e.line == 1, "{e}");
        // A BOM is accepted and noted.
        let (_, rep) = parse_str(&format!("\u{feff}{head}{}", rows(12))).unwrap();
        assert!(rep.notes.iter().any(|n| n.contains("byte-order mark")));
        // Separators, quotes, versions.
        let e = err_of(&format!("{}\n", head.trim().replace(',', ";")));
        assert!(matches!(e.kind, ErrorKind::Separator(_)), "{e}");
        let e = err_of(&format!("{}\n", head.trim().replace(',', "\t")));
        assert!(matches!(e.kind, ErrorKind::Separator(_)), "{e}");
        let e = err_of("\"t\",\"px\",\"py\",\"pz\",\"l0\"\n");
        assert!(matches!(e.kind, ErrorKind::Quoted(_)), "{e}");
        let e = err_of(&format!("{head}{}\"0.5\",0,0,1,2,2,2,5,6,7\n", rows(2)));
        assert!(matches!(e.kind, ErrorKind::Quoted(_)) && e.line == 4, "{e}");
        parse_str(&format!("# cdpr-recordings of May\n#cdpr-recording v1\n{head}{}", rows(12))).unwrap();
        let e = err_of(&format!("# cdpr-recording v2\n{head}{}", rows(12)));
        assert!(matches!(e.kind, ErrorKind::UnknownVersion(ref v) if v == "v2") && e.line == 1, "{e}");
        // Non-UTF-8.
        let mut bytes = format!("{head}{}", rows(3)).into_bytes();
        bytes.extend_from_slice(b"0.5,0,0,1,2,\xff,2,5,6,7\n");
        let e = parse(std::io::Cursor::new(bytes)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::NotUtf8(13)) && e.line == 5, "{e}");
    }

    #[test]
    fn field_errors_say_what_is_allowed() {
        let head = "t,px,py,pz,l0,l1,l2,phase\n";
        let ok = |i: usize| format!("{},0,0,1,2,2,2,0\n", i as f64 * 0.01);
        let body: String = (0..12).map(ok).collect();
        for (bad, want) in [("1.5", "integer"), ("nan", "integer"), ("-7", "integer"), ("1e3", "integer")] {
            let e = err_of(&format!("{head}{body}0.2,0,0,1,2,2,2,{bad}\n"));
            assert!(matches!(e.kind, ErrorKind::Phase(_)) && e.column.as_deref() == Some("phase"), "{e}");
            assert!(e.to_string().contains(want), "{e}");
        }
        let e = err_of(&format!("{head}{body}nan,0,0,1,2,2,2,0\n"));
        assert!(matches!(e.kind, ErrorKind::Time(_)) && e.line == 14, "{e}");
        // A time outlier is blamed on its own row, not the good row after it.
        let e = err_of(&format!("{head}{body}1e9,0,0,1,2,2,2,0\n0.13,0,0,1,2,2,2,0\n"));
        assert_eq!((e.line, e.column.as_deref()), (14, Some("t")), "{e}");
        let e = err_of(&format!("{head}{body}1e308,0,0,1,2,2,2,0\n"));
        assert_eq!(e.line, 14, "{e}");
        assert!(e.to_string().contains("plausible"), "{e}");
        // A long field is cut in the message.
        let long = "x".repeat(50_000);
        let e = err_of(&format!("{head}{body}0.2,{long},0,1,2,2,2,0\n"));
        let m = e.to_string();
        assert!(m.len() < 300 && m.contains('…') && m.contains("50000 bytes"), "{m}");
        let e = err_of(&format!("{head}{body}0.2,0,0,1,2,inf,2,0\n"));
        assert!(matches!(e.kind, ErrorKind::NotFinite(_)) && e.column.as_deref() == Some("l1"), "{e}");
    }

    #[test]
    fn error_message_is_readable() {
        let e =
            RecordingError { file: Some("rec.csv".into()), line: 12, column: Some("l2".into()), kind: ErrorKind::NotANumber("x".into()) };
        assert_eq!(e.to_string(), "rec.csv:12: column `l2`: `x` is not a number (a missing value is an empty field or `nan`)");
    }
}

#[cfg(test)]
mod fast_field_tests {
    use super::{fast_field, fast_row};

    /// The fast path gives the value `str::parse` gives, bit for bit, or declines.
    fn same(s: &str) {
        if let Some(v) = fast_field(s.as_bytes()) {
            let w: f64 = s.parse().unwrap();
            assert_eq!(v.to_bits(), w.to_bits(), "`{s}`: fast {v:e} vs parse {w:e}");
        }
    }

    #[test]
    fn agrees_with_the_standard_parser() {
        for s in ["0", "-0", "+0.5", "1.", ".25", "3.1415926", "-12.000001", "0.1", "0.3", "9007199254740991", "12345.678901"] {
            assert!(fast_field(s.as_bytes()).is_some(), "`{s}` should take the fast path");
            same(s);
        }
        // Deterministic pseudo-random decimals of every length the writer and other tools produce.
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let digits = (x % 19 + 1) as usize;
            let mut s = String::new();
            if x & (1 << 20) != 0 {
                s.push('-');
            }
            let mut y = x >> 24;
            let dot = (x >> 8) as usize % (digits + 1);
            for k in 0..digits {
                if k == dot {
                    s.push('.');
                }
                s.push((b'0' + (y % 10) as u8) as char);
                y = (y / 10) ^ (x >> (k % 40));
            }
            same(&s);
        }
    }

    #[test]
    fn declines_what_it_does_not_know() {
        for s in [
            "",
            "nan",
            "NaN",
            "1e5",
            "1E-3",
            "inf",
            "-",
            ".",
            "+",
            "1.2.3",
            "1,5",
            " 1",
            "1 ",
            "0x10",
            "12345678901234567890",
            "9007199254740993",
            "1.00000000000000000000001",
        ] {
            assert_eq!(fast_field(s.as_bytes()), None, "`{s}`");
        }
    }

    /// The one-pass row reader takes a row exactly when every comma-separated field takes
    /// [`fast_field`], with the same values and field bounds.
    #[test]
    fn fast_row_is_fast_field_per_field() {
        let pieces =
            ["0", "-0", "+0.5", "1.", ".25", "3.1415926", "-12.000001", "", " 1", "nan", "1e5", "1.2.3", "-", "\r", "9007199254740993"];
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let (mut vals, mut spans) = (vec![], vec![]);
        let mut taken = 0;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let count = (x % 5 + 1) as usize;
            let fields: Vec<&str> =
                (0..count).map(|k| pieces[((x >> (8 + 5 * k)) % 10 + if x & (1 << 60) != 0 { 5 } else { 0 }) as usize]).collect();
            let line = fields.join(",");
            let width = if x & (1 << 61) != 0 { count } else { count + 1 };
            let want: Option<Vec<f64>> = line.split(',').map(|f| fast_field(f.as_bytes())).collect();
            let got = fast_row(line.as_bytes(), width, &mut vals, &mut spans);
            match want {
                Some(v) if v.len() == width => {
                    assert_eq!(got, Some(line.len()), "`{line}` should take the fast path");
                    assert_eq!(
                        vals.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        v.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "`{line}`"
                    );
                    let bounds: Vec<&str> = spans.iter().map(|&(a, b)| &line[a..b]).collect();
                    assert_eq!(bounds, line.split(',').collect::<Vec<_>>(), "`{line}`");
                    taken += 1;
                }
                _ => assert_eq!(got, None, "`{line}` must take the general path"),
            }
        }
        assert!(taken > 1000, "only {taken} rows took the fast path: the test does not exercise it");
    }

    /// A row reader that reads one byte at a time (the line given without its newline): the
    /// reference the eight-at-a-time one must equal.
    fn fast_row_bytewise(line: &[u8], width: usize, vals: &mut Vec<f64>, spans: &mut Vec<(usize, usize)>) -> bool {
        vals.clear();
        spans.clear();
        let n = line.len();
        let mut k = 0;
        loop {
            let start = k;
            let neg = k < n && line[k] == b'-';
            if k < n && (line[k] == b'-' || line[k] == b'+') {
                k += 1;
            }
            let (mut m, mut digits, mut decimals, mut dot) = (0u64, 0usize, 0usize, false);
            while k < n {
                match line[k] {
                    c @ b'0'..=b'9' => {
                        if digits == 19 {
                            return false;
                        }
                        m = m * 10 + (c - b'0') as u64;
                        digits += 1;
                        decimals += dot as usize;
                    }
                    b'.' if !dot => dot = true,
                    b',' => break,
                    _ => return false,
                }
                k += 1;
            }
            if digits == 0 || m >= 1 << 53 || decimals >= super::EXACT_POW10.len() || vals.len() == width {
                return false;
            }
            let v = m as f64 / super::EXACT_POW10[decimals];
            vals.push(if neg { -v } else { v });
            spans.push((start, k));
            if k == n {
                return vals.len() == width;
            }
            k += 1;
        }
    }

    /// Rows of long and short fields (up to 22 digits, so runs of eight and the 19-digit limit
    /// fall anywhere in a field), bytes that are not digits next to digits (including bytes
    /// above 0x7F and the neighbours of '0' and '9'), and text after the line's newline: the
    /// eight-at-a-time reader takes exactly the rows the byte-wise one takes, with the same
    /// bits, bounds and line length.
    #[test]
    fn eight_digits_at_a_time_is_one_at_a_time() {
        let odd = [b'/', b':', b'.', b'-', b'+', b' ', b'e', b'\r', 0x80, 0xB0, 0xBA, 0xFF, 0xC3, 0x00, b'\n', b','];
        let mut x = 0x5DEE_CE66_D1CE_4E5Bu64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let (mut vals, mut spans, mut vals2, mut spans2) = (vec![], vec![], vec![], vec![]);
        let (mut taken, mut declined) = (0, 0);
        for case in 0..200_000 {
            let width = (next() % 12 + 1) as usize;
            let mut line: Vec<u8> = vec![];
            for f in 0..width {
                if f > 0 {
                    line.push(b',');
                }
                let r = next();
                match r % 4 {
                    0 => line.push(b'-'),
                    1 if r & 64 != 0 => line.push(b'+'),
                    _ => {}
                }
                let int = ((r >> 2) % 12) as usize;
                let frac = if r & (1 << 9) != 0 { Some(((r >> 10) % 12) as usize) } else { None };
                for _ in 0..int {
                    line.push(b'0' + (next() % 10) as u8);
                }
                if let Some(frac) = frac {
                    line.push(b'.');
                    for _ in 0..frac {
                        line.push(b'0' + (next() % 10) as u8);
                    }
                }
            }
            // One byte in three lines replaced or inserted by one that is not a digit.
            if case % 3 == 0 && !line.is_empty() {
                let at = (next() % line.len() as u64) as usize;
                let b = odd[(next() % odd.len() as u64) as usize];
                if next() % 2 == 0 {
                    line[at] = b;
                } else {
                    line.insert(at, b);
                }
            }
            let claimed = if case % 5 == 0 { width + 1 } else { width };
            // The line as the reference sees it: up to its first newline.
            let len = line.iter().position(|&b| b == b'\n').unwrap_or(line.len());
            let want = fast_row_bytewise(&line[..len], claimed, &mut vals2, &mut spans2);
            // What follows a line: another line, or the end of the text.
            if case % 2 == 0 && len == line.len() {
                line.extend_from_slice(b"\n12345678,9\n");
            }
            let got = fast_row(&line, claimed, &mut vals, &mut spans);
            if want {
                assert_eq!(got, Some(len), "{:?}", String::from_utf8_lossy(&line));
                assert_eq!(vals.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), vals2.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
                assert_eq!(spans, spans2);
                taken += 1;
            } else {
                assert_eq!(got, None, "{:?}", String::from_utf8_lossy(&line));
                declined += 1;
            }
        }
        // Both outcomes are exercised, each many times.
        assert!(taken > 20_000 && declined > 20_000, "{taken} taken, {declined} declined");
    }
}

/// The first bytes of an MCAP file (how [`Recording::load`] tells MCAP from CSV).
pub const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
