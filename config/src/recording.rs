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

/// The first comment line of a file written by this project.
pub const MAGIC: &str = "# cdpr-recording v1";

/// Fewer usable samples (rows with a position and at least one length) than this is an error.
pub const MIN_USABLE_SAMPLES: usize = 10;

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
        let path = path.as_ref();
        let file = std::fs::File::open(path).map_err(|e| RecordingError {
            file: Some(path.display().to_string()),
            line: 0,
            column: None,
            kind: ErrorKind::Io(e.to_string()),
        })?;
        parse(std::io::BufReader::new(file)).map_err(|mut e| {
            e.file = Some(path.display().to_string());
            e
        })
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
    /// Rows with a position and at least one length.
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
    /// Time is missing, or earlier than on the previous row.
    Time(String),
    /// Too few rows with a position and a length.
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
            write!(f, ": column `{c}`")?;
        }
        match &self.kind {
            ErrorKind::Io(e) => write!(f, ": cannot read: {e}"),
            ErrorKind::NoHeader => write!(f, ": no header line; expected e.g. `t,px,py,pz,l0,l1,l2,f0,f1,f2`"),
            ErrorKind::MissingColumn(c) => write!(f, ": the header has no `{c}` column; a cdpr-recording v1 needs t, px, py, pz and l0..l(n-1)"),
            ErrorKind::DuplicateColumn(c) => write!(f, ": column `{c}` appears twice in the header"),
            ErrorKind::CableColumns(m) => write!(f, ": {m}"),
            ErrorKind::FieldCount { expected, found } => write!(f, ": {found} fields, but the header has {expected}; check for a stray or missing comma"),
            ErrorKind::NotANumber(s) => write!(f, ": `{s}` is not a number (a missing value is an empty field or `nan`)"),
            ErrorKind::Time(m) => write!(f, ": {m}"),
            ErrorKind::TooFewSamples { usable, needed } => write!(f, ": only {usable} usable samples (rows with a position and a length), at least {needed} needed"),
        }
    }
}

impl std::error::Error for RecordingError {}

/// Where each field of the format sits in a row.
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
        _ => {
            return Err(err(
                None,
                ErrorKind::CableColumns("an orientation needs all four columns qw, qx, qy, qz".into()),
            ))
        }
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
        report.notes.push(format!("ignored unknown columns: {}", report.ignored_columns.join(", ")));
    }
    Ok(Columns {
        t,
        p,
        q,
        l: ls.into_iter().map(|x| x.1).collect(),
        f: fs.into_iter().map(|x| x.1).collect(),
        phase,
        width: fields.len(),
    })
}

/// Parses one field: empty or `nan` (any case) is missing (NaN).
fn field(s: &str) -> Result<f64, ()> {
    let s = s.trim();
    if s.is_empty() || s.eq_ignore_ascii_case("nan") {
        return Ok(f64::NAN);
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(()),
    }
}

/// Parses a `cdpr-recording v1` from a reader.
pub fn parse<R: BufRead>(reader: R) -> Result<(Recording, ParseReport), RecordingError> {
    let mut report = ParseReport::default();
    let mut comments = Vec::new();
    let mut cols: Option<Columns> = None;
    let mut rec = Recording::default();
    let mut last_t = f64::NEG_INFINITY;
    let mut lvals = Vec::new();
    let mut fvals = Vec::new();
    for (i, line) in reader.lines().enumerate() {
        let lineno = i + 1;
        let line = line.map_err(|e| RecordingError { file: None, line: lineno, column: None, kind: ErrorKind::Io(e.to_string()) })?;
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        if let Some(comment) = line.strip_prefix('#') {
            if cols.is_none() {
                comments.push(comment.to_string());
            }
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let c = match &cols {
            None => {
                let c = parse_header(&fields, lineno, &mut report)?;
                let n = c.l.len();
                rec = Recording::with_capacity(n, 1024, !c.f.is_empty(), c.q.is_some(), c.phase.is_some());
                rec.comments = std::mem::take(&mut comments);
                cols = Some(c);
                continue;
            }
            Some(c) => c,
        };
        if fields.len() != c.width {
            return Err(RecordingError {
                file: None,
                line: lineno,
                column: None,
                kind: ErrorKind::FieldCount { expected: c.width, found: fields.len() },
            });
        }
        let get = |col: usize| -> Result<f64, RecordingError> {
            field(fields[col]).map_err(|_| RecordingError {
                file: None,
                line: lineno,
                column: Some(header_name(c, col)),
                kind: ErrorKind::NotANumber(fields[col].to_string()),
            })
        };
        let t = get(c.t)?;
        let terr = |m: String| RecordingError { file: None, line: lineno, column: Some("t".into()), kind: ErrorKind::Time(m) };
        if t.is_nan() {
            return Err(terr("time is missing; every row needs a time".into()));
        }
        if t < last_t {
            return Err(terr(format!("time goes backwards: {t} after {last_t}")));
        }
        last_t = t;
        let p = [get(c.p[0])?, get(c.p[1])?, get(c.p[2])?];
        let q = match c.q {
            Some(qc) => Some([get(qc[0])?, get(qc[1])?, get(qc[2])?, get(qc[3])?]),
            None => None,
        };
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
                let s = fields[col];
                if s.is_empty() {
                    Some(-1)
                } else {
                    Some(s.parse::<i32>().map_err(|_| RecordingError {
                        file: None,
                        line: lineno,
                        column: Some("phase".into()),
                        kind: ErrorKind::NotANumber(s.to_string()),
                    })?)
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
        if pos_ok && nl < lvals.len() {
            report.usable_rows += 1;
        }
        rec.push(t, p, q, &lvals, (!fvals.is_empty()).then_some(&fvals[..]), phase);
    }
    if cols.is_none() {
        return Err(RecordingError { file: None, line: 0, column: None, kind: ErrorKind::NoHeader });
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
    if report.missing_position > 0 {
        report.notes.push(format!("{} rows without a tracker position (dropouts)", report.missing_position));
    }
    if report.missing_length > 0 {
        report.notes.push(format!("{} missing length readings", report.missing_length));
    }
    if report.missing_tension > 0 {
        report.notes.push(format!("{} missing tension readings", report.missing_tension));
    }
    Ok((rec, report))
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
        assert_eq!(rep.usable_rows, 13);
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
    fn error_message_is_readable() {
        let e = RecordingError { file: Some("rec.csv".into()), line: 12, column: Some("l2".into()), kind: ErrorKind::NotANumber("x".into()) };
        assert_eq!(e.to_string(), "rec.csv:12: column `l2`: `x` is not a number (a missing value is an empty field or `nan`)");
    }
}
