//! Reading a recording held in memory on several threads ([`Recording::load_with`] of a regular
//! file).
//!
//! The comments and the header are read by the ordinary line-by-line [`Parser`]. The rows after
//! them are cut into pieces at line starts, one per thread. Each thread counts its piece's lines
//! and the recording's columns are made with room for all of them, each piece owning the part
//! that follows the pieces before it; then each piece is read by [`fast_piece`] (the first on
//! the calling thread) straight into its part. [`fast_piece`] takes only rows of plain decimals
//! ([`fast_row`]) that pass every row check on their own (a plausible time, not decreasing
//! within the piece; a phase that is an integer >= -1) and stops at the first line that is
//! anything else. When every piece was taken whole (every line a row), each piece's first time
//! is not before the last row before it and the line limit allows them, the parts are the
//! recording as it stands: nothing is copied. Otherwise the pieces are joined in order as
//! separate rows: a piece's rows are appended when its first time is not before the last row
//! before it and the line limit allows them; every line that no piece took (all of a piece whose
//! rows do not join, and whatever follows a piece's first other line) is read by the ordinary
//! reader. So the recording, the report and every error are the ones the one-thread reader
//! gives: what the pieces take are exactly rows on which its checks pass, read by the same
//! [`fast_row`].

use super::{fast_row, Columns, Line, ParseReport, Parser, Recording, RecordingError, MAX_LINES, MAX_LINE_BYTES, MAX_TIME_S};

/// Below this many bytes of rows per thread the threads cost more than they save.
pub(super) const MIN_PIECE_BYTES: usize = 256 * 1024;

/// The lines of a text in memory, as [`super::read_line_capped`] reads them from a stream.
struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Lines<'a> {
    fn next_line(&mut self) -> (Line, &'a [u8]) {
        let rest = &self.bytes[self.pos..];
        if rest.is_empty() {
            return (Line::Eof, rest);
        }
        let (len, newline) = match rest.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (rest.len(), false),
        };
        if len > MAX_LINE_BYTES {
            // An error at this line: the reader does not go on.
            return (Line::TooLong, &rest[..MAX_LINE_BYTES]);
        }
        self.pos += len + newline as usize;
        (Line::Complete, &rest[..len])
    }
}

/// A piece's part of the recording's columns: room for one row per line of the piece (`q`,
/// `f` and `phase` empty when the recording has no such column).
struct Part<'a> {
    t: &'a mut [f64],
    p: &'a mut [[f64; 3]],
    q: &'a mut [[f64; 4]],
    l: &'a mut [f64],
    f: &'a mut [f64],
    phase: &'a mut [i32],
}

/// The recording's columns with room for `rows` rows, zeroed (the allocator's fresh zero pages:
/// each thread faults in the pages of its own part as it writes them).
struct Columnar {
    t: Vec<f64>,
    p: Vec<[f64; 3]>,
    q: Vec<[f64; 4]>,
    l: Vec<f64>,
    f: Vec<f64>,
    phase: Vec<i32>,
}

impl Columnar {
    fn new(rows: usize, c: &Columns) -> Columnar {
        let if_has = |has: bool| if has { rows } else { 0 };
        Columnar {
            t: vec![0.0; rows],
            p: vec![[0.0; 3]; rows],
            q: vec![[0.0; 4]; if_has(c.q.is_some())],
            l: vec![0.0; rows * c.l.len()],
            f: vec![0.0; rows * c.f.len()],
            phase: vec![0; if_has(c.phase.is_some())],
        }
    }

    /// The parts of `rows[0]`, `rows[1]`, ... rows, in order.
    fn parts(&mut self, rows: &[usize], c: &Columns) -> Vec<Part<'_>> {
        let (nl, nf) = (c.l.len(), c.f.len());
        let (has_q, has_phase) = (c.q.is_some() as usize, c.phase.is_some() as usize);
        let (mut t, mut p, mut q) = (&mut self.t[..], &mut self.p[..], &mut self.q[..]);
        let (mut l, mut f, mut phase) = (&mut self.l[..], &mut self.f[..], &mut self.phase[..]);
        let mut out = Vec::with_capacity(rows.len());
        for &k in rows {
            let (t0, t1) = std::mem::take(&mut t).split_at_mut(k);
            let (p0, p1) = std::mem::take(&mut p).split_at_mut(k);
            let (q0, q1) = std::mem::take(&mut q).split_at_mut(k * has_q);
            let (l0, l1) = std::mem::take(&mut l).split_at_mut(k * nl);
            let (f0, f1) = std::mem::take(&mut f).split_at_mut(k * nf);
            let (h0, h1) = std::mem::take(&mut phase).split_at_mut(k * has_phase);
            out.push(Part { t: t0, p: p0, q: q0, l: l0, f: f0, phase: h0 });
            (t, p, q, l, f, phase) = (t1, p1, q1, l1, f1, h1);
        }
        out
    }
}

/// The lines of `bytes` (the last one may lack its newline): the most rows a piece can hold.
fn count_lines(bytes: &[u8]) -> usize {
    // Counted 64 bytes at a time in a byte (at most 64 fits), which the compiler turns into
    // vector compares and adds; a count per byte in a `usize` does not vectorise as well.
    let chunks = bytes.chunks_exact(64);
    let tail = chunks.remainder();
    let newlines: usize = chunks.map(|c| c.iter().map(|&b| (b == b'\n') as u8).sum::<u8>() as usize).sum::<usize>()
        + tail.iter().filter(|&&b| b == b'\n').count();
    newlines + bytes.last().is_some_and(|&b| b != b'\n') as usize
}

/// How much of its piece [`fast_piece`] took: its first `rows` rows, up to byte `taken_end`.
#[derive(Clone, Copy, Debug)]
struct Taken {
    taken_end: usize,
    rows: usize,
}

/// Reads the rows of `bytes[start..end]` (whole lines) into `part` up to the first line that
/// is not a row of plain decimals passing the row checks (see the module doc) or when `part`
/// is full.
fn fast_piece(bytes: &[u8], start: usize, end: usize, c: &Columns, part: &mut Part<'_>) -> Taken {
    let (nl, nf) = (c.l.len(), c.f.len());
    let (mut vals, mut spans) = (Vec::with_capacity(c.width), Vec::with_capacity(c.width));
    let mut pos = start;
    let mut r = 0;
    let mut last_t = f64::NEG_INFINITY;
    while pos < end && r < part.t.len() {
        // The line's end is found by the row reader itself (one pass over the bytes).
        let Some(len) = fast_row(&bytes[pos..end], c.width, &mut vals, &mut spans) else { break };
        if len > MAX_LINE_BYTES {
            break;
        }
        let line = &bytes[pos..pos + len];
        let t = vals[c.t];
        // A fast field is finite: the reader's checks are a time beyond MAX_TIME_S and one
        // before the last.
        if t.abs() > MAX_TIME_S || t < last_t {
            break;
        }
        let phase = match c.phase {
            Some(col) => {
                let (a, b) = spans[col];
                match std::str::from_utf8(&line[a..b]).ok().and_then(|s| s.parse::<i32>().ok()) {
                    Some(k) if k >= -1 => Some(k),
                    _ => break,
                }
            }
            None => None,
        };
        last_t = t;
        part.t[r] = t;
        part.p[r] = c.p.map(|col| vals[col]);
        if let Some(qc) = c.q {
            part.q[r] = qc.map(|col| vals[col]);
        }
        for (o, &col) in part.l[r * nl..(r + 1) * nl].iter_mut().zip(&c.l) {
            *o = vals[col];
        }
        for (o, &col) in part.f[r * nf..(r + 1) * nf].iter_mut().zip(&c.f) {
            *o = vals[col];
        }
        if let Some(k) = phase {
            part.phase[r] = k;
        }
        r += 1;
        pos = (pos + len + 1).min(end);
    }
    Taken { taken_end: pos, rows: r }
}

/// The rows a piece took, as separate columns (for joining them one by one).
struct Piece {
    taken_end: usize,
    rows: usize,
    cols: Columnar,
}

impl Piece {
    fn of(part: &Part<'_>, taken: Taken, c: &Columns) -> Piece {
        let r = taken.rows;
        let (nq, nh) = (if c.q.is_some() { r } else { 0 }, if c.phase.is_some() { r } else { 0 });
        Piece {
            taken_end: taken.taken_end,
            rows: r,
            cols: Columnar {
                t: part.t[..r].to_vec(),
                p: part.p[..r].to_vec(),
                q: part.q[..nq].to_vec(),
                l: part.l[..r * c.l.len()].to_vec(),
                f: part.f[..r * c.f.len()].to_vec(),
                phase: part.phase[..nh].to_vec(),
            },
        }
    }
}

/// Line starts cutting `bytes[from..]` into up to `threads` pieces of about equal size, each of
/// at least `min_piece` bytes: `[from, s1, ..., bytes.len()]`.
fn cuts(bytes: &[u8], from: usize, threads: usize, min_piece: usize) -> Vec<usize> {
    let len = bytes.len();
    let pieces = threads.min((len - from) / min_piece.max(1)).max(1);
    let mut out = vec![from];
    for k in 1..pieces {
        let target = from + (len - from) / pieces * k;
        // The first line start at or after `target`.
        let Some(i) = bytes[target - 1..].iter().position(|&b| b == b'\n') else { break };
        let s = target + i;
        if s < len && s > *out.last().unwrap_or(&0) {
            out.push(s);
        }
    }
    out.push(len);
    out
}

impl Parser {
    /// Appends `piece` (taken from the next lines of the input) when the one-thread reader
    /// would take its rows as they are: its first time is not before the last row's and its
    /// lines stay within [`MAX_LINES`].
    fn join(&mut self, piece: Piece) -> bool {
        let k = piece.rows;
        let piece = piece.cols;
        if k == 0 || piece.t[0] < self.last_t || self.lineno + k > MAX_LINES {
            return false;
        }
        let rec = &mut self.rec;
        if rec.t.is_empty() {
            // The first rows: the piece's columns become the recording's.
            self.adopt(piece);
            return self.counted(k);
        }
        rec.t.extend_from_slice(&piece.t);
        rec.p.extend_from_slice(&piece.p);
        if let Some(q) = &mut rec.q {
            q.extend_from_slice(&piece.q);
        }
        rec.l.extend_from_slice(&piece.l);
        if let Some(f) = &mut rec.f {
            f.extend_from_slice(&piece.f);
        }
        if let Some(ph) = &mut rec.phase {
            ph.extend_from_slice(&piece.phase);
        }
        self.counted(k)
    }

    /// Takes `cols` (the rows of every piece, each taken whole, in order; left empty) as the
    /// recording's rows when the one-thread reader would take them as they are: each piece's
    /// first time is not before the last row before it and the lines stay within [`MAX_LINES`].
    fn whole(&mut self, cols: &mut Columnar, rows: &[usize], c: &Columns) -> bool {
        let total: usize = rows.iter().sum();
        let mut last_t = self.last_t;
        let mut at = 0;
        for &k in rows {
            if k == 0 || cols.t[at] < last_t {
                return false;
            }
            at += k;
            last_t = cols.t[at - 1];
        }
        if self.lineno + total > MAX_LINES {
            return false;
        }
        self.adopt(std::mem::replace(cols, Columnar::new(0, c)));
        debug_assert!(self.rec.t.len() == total && self.rec.l.len() == total * c.l.len());
        self.counted(total)
    }

    /// `cols` become the recording's columns (the optional ones only where the header has them).
    fn adopt(&mut self, cols: Columnar) {
        let rec = &mut self.rec;
        let Columnar { t, p, q, l, f, phase } = cols;
        rec.t = t;
        rec.p = p;
        rec.q = rec.q.take().map(|_| q);
        rec.l = l;
        rec.f = rec.f.take().map(|_| f);
        rec.phase = rec.phase.take().map(|_| phase);
    }

    /// Counts `k` rows of plain decimals just taken, whose times are the last `k` of the
    /// recording.
    fn counted(&mut self, k: usize) -> bool {
        let t = &self.rec.t;
        // What the reader counts for a row of plain decimals: nothing missing, usable.
        self.report.rows += k;
        self.report.usable_rows += k;
        self.before_last_t = if k >= 2 { t[t.len() - 2] } else { self.last_t };
        self.last_t = t[t.len() - 1];
        self.lineno += k;
        self.last_line = self.lineno;
        true
    }
}

/// The `size` bytes of `file`, read in one piece per thread (each thread faults in its own
/// part of the buffer); `None` when the file is no longer `size` bytes long.
pub(super) fn read_whole(file: &std::fs::File, size: usize, threads: usize) -> std::io::Result<Option<Vec<u8>>> {
    use std::os::unix::fs::FileExt;
    let mut bytes = vec![0u8; size];
    let chunk = size.div_ceil(threads.min(size / MIN_PIECE_BYTES).max(1)).max(1);
    let read = |k: usize, part: &mut [u8]| match file.read_exact_at(part, (k * chunk) as u64) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    };
    let whole = std::thread::scope(|s| {
        let mut parts = bytes.chunks_mut(chunk).enumerate();
        let first = parts.next();
        let helpers: Vec<_> = parts.map(|(k, part)| s.spawn(move || read(k, part))).collect();
        let mut whole = first.map_or(Ok(true), |(k, part)| read(k, part))?;
        for h in helpers {
            whole &= h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))?;
        }
        Ok::<_, std::io::Error>(whole)
    })?;
    // Nothing after the end either (a file that grew is read as a stream).
    Ok((whole && file.read_at(&mut [0u8], size as u64)? == 0).then_some(bytes))
}

/// Parses a whole input in memory on up to `threads` threads, pieces of at least `min_piece`
/// bytes ([`MIN_PIECE_BYTES`]; see the module doc).
pub(super) fn parse_bytes(bytes: &[u8], threads: usize, min_piece: usize) -> Result<(Recording, ParseReport), RecordingError> {
    let mut p = Parser::new(Some(bytes.len() as u64));
    let mut lines = Lines { bytes, pos: 0 };
    // The comments and the header by the ordinary reader: the pieces need the columns.
    while p.cols.is_none() {
        let (read, line) = lines.next_line();
        if !p.line(read, line)? {
            return p.finish();
        }
    }
    let cols = p.cols.clone().expect("the header was read");
    let cuts = cuts(bytes, lines.pos, threads, min_piece);
    let ranges: Vec<(usize, usize)> = cuts.windows(2).map(|w| (w[0], w[1])).collect();
    // Each piece's lines, counted on its own thread: the room its rows need. Never more than
    // a row of `width` fields can fill (at least 2 * width - 1 bytes and its newline: a file of
    // empty lines gets no room for them) nor than MAX_LINES; a piece whose part is full stops
    // there and the rest is read by the ordinary reader.
    let width = cols.width.max(1);
    let room_of = |a: usize, b: usize| count_lines(&bytes[a..b]).min((b - a + 1) / (2 * width)).min(MAX_LINES);
    let room: Vec<usize> = std::thread::scope(|s| {
        let helpers: Vec<_> = ranges[1..].iter().map(|&(a, b)| s.spawn(move || room_of(a, b))).collect();
        let first = room_of(ranges[0].0, ranges[0].1);
        std::iter::once(first).chain(helpers.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))).collect()
    });
    let mut columns = Columnar::new(room.iter().sum(), &cols);
    let mut parts = columns.parts(&room, &cols);
    let taken: Vec<Taken> = std::thread::scope(|s| {
        let cols = &cols;
        let mut parts = parts.iter_mut();
        let first_part = parts.next().expect("one piece at least");
        let helpers: Vec<_> =
            ranges[1..].iter().zip(parts).map(|(&(a, b), part)| s.spawn(move || fast_piece(bytes, a, b, cols, part))).collect();
        // The first piece on this thread.
        let first = fast_piece(bytes, ranges[0].0, ranges[0].1, cols, first_part);
        std::iter::once(first).chain(helpers.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))).collect()
    });
    // Every line of every piece a row: the parts are the recording's rows, in place.
    let all_taken = taken.iter().zip(&room).zip(&ranges).all(|((tk, &k), &(_, end))| tk.rows == k && tk.taken_end == end);
    let pieces: Vec<Piece> = if all_taken {
        drop(parts);
        if p.whole(&mut columns, &room, &cols) {
            lines.pos = bytes.len();
            vec![]
        } else {
            // Not taken as one: the same rows, joined piece by piece below.
            parts = columns.parts(&room, &cols);
            parts.iter().zip(&taken).map(|(part, &tk)| Piece::of(part, tk, &cols)).collect()
        }
    } else {
        parts.iter().zip(&taken).map(|(part, &tk)| Piece::of(part, tk, &cols)).collect()
    };
    let read = || -> Result<(), RecordingError> {
        for (&(start, _), piece) in ranges.iter().zip(pieces) {
            while lines.pos < start {
                let (read, line) = lines.next_line();
                if !p.line(read, line)? {
                    return Ok(());
                }
            }
            let end = piece.taken_end;
            if p.join(piece) {
                lines.pos = end;
            }
        }
        loop {
            let (read, line) = lines.next_line();
            if !p.line(read, line)? {
                return Ok(());
            }
        }
    };
    read()?;
    p.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Everything the reader returns, comparable (NaN as text, so a missing value equals itself).
    fn outcome(r: Result<(Recording, ParseReport), RecordingError>) -> String {
        format!("{r:?}")
    }

    fn one_thread(text: &[u8]) -> String {
        outcome(super::super::parse_sized(std::io::Cursor::new(text), Some(text.len() as u64)))
    }

    /// A small deterministic generator (xorshift), so a failure can be replayed.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    /// A recording's lines: header variants (orientation, tensions, phase, an unknown column),
    /// rows of plain decimals with a non-decreasing time.
    fn lines(rng: &mut Rng, rows: usize) -> (Vec<String>, usize) {
        let q = rng.below(2) == 0;
        let f = rng.below(3) != 0;
        let phase = rng.below(2) == 0;
        let mut head = vec!["t", "px", "py", "pz"];
        if q {
            head.extend(["qw", "qx", "qy", "qz"]);
        }
        head.extend(["l0", "l1", "l2"]);
        if f {
            head.extend(["f0", "f1", "f2"]);
        }
        if phase {
            head.push("phase");
        }
        if rng.below(4) == 0 {
            head.insert(2, "extra");
        }
        let width = head.len();
        let mut out = vec!["# cdpr-recording v1".to_string(), "# robot: test".to_string(), head.join(",")];
        for i in 0..rows {
            let row: Vec<String> = head
                .iter()
                .enumerate()
                .map(|(k, h)| match *h {
                    // Repeated times are allowed (non-decreasing).
                    "t" => format!("{:.3}", (i - i % 3) as f64 * 0.01),
                    "phase" => format!("{}", (i / 50) as i32 - 1),
                    _ => format!("{:.6}", ((i * 7 + k * 13) % 1000) as f64 * 0.0137 - 3.0),
                })
                .collect();
            out.push(row.join(","));
        }
        (out, width)
    }

    /// One hostile change to data line `i` (or before it).
    fn mutate(rng: &mut Rng, lines: &mut Vec<String>, width: usize, i: usize) {
        let col = rng.below(width);
        let mut fields: Vec<String> = lines[i].split(',').map(str::to_string).collect();
        let junk =
            ["abc", "nan", "", " 1.5 ", "inf", "1e5", "-1e308", "1.5", "-7", "\"1\"", "0x10", "12345678901234567890", "+0.5", ".25", "1."];
        match rng.below(12) {
            0..=3 => {
                if col < fields.len() {
                    fields[col] = junk[rng.below(junk.len())].to_string();
                }
                lines[i] = fields.join(",");
            }
            // Time backwards, far ahead, implausible.
            4 => {
                fields[0] = ["0", "1e9", "1e308", "-5"][rng.below(4)].to_string();
                lines[i] = fields.join(",");
            }
            5 => lines.insert(i, ["# a comment", "", "   ", "\r"][rng.below(4)].to_string()),
            6 => {
                fields.push("1".into());
                lines[i] = fields.join(",");
            }
            7 => {
                fields.pop();
                lines[i] = fields.join(",");
            }
            8 => lines[i].push('\r'),
            9 => {
                let at = rng.below(lines[i].len() + 1);
                lines[i].insert(at, ['\0', 'é', ';', ' '][rng.below(4)]);
            }
            10 => lines[i] = "7".repeat(MAX_LINE_BYTES + 10),
            _ => lines.truncate(i),
        }
    }

    fn text(lines: &[String], newline_at_end: bool) -> Vec<u8> {
        let mut t = lines.join("\n");
        if newline_at_end {
            t.push('\n');
        }
        t.into_bytes()
    }

    /// The line index of each byte offset's line.
    fn line_of(bytes: &[u8], at: usize) -> usize {
        bytes[..at].iter().filter(|&&b| b == b'\n').count()
    }

    #[test]
    fn pieces_give_what_one_thread_gives() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let (mut clean, mut cases) = (0, 0);
        for case in 0..3000 {
            let threads = 2 + rng.below(4);
            let min_piece = [1, 64, 1000][rng.below(3)];
            let most = [40, 300][rng.below(2)];
            let rows = 10 + rng.below(most);
            let (mut lines, width) = lines(&mut rng, rows);
            // Where the pieces start in the clean text: the changes go there half of the time
            // (the joins are what can go wrong), anywhere otherwise.
            let plain = text(&lines, true);
            let header_end = plain.iter().enumerate().filter(|(_, b)| **b == b'\n').nth(2).map_or(plain.len(), |(i, _)| i + 1);
            let starts: Vec<usize> = cuts(&plain, header_end, threads, min_piece).iter().map(|&c| line_of(&plain, c)).collect();
            for _ in 0..case % 4 {
                let i = if rng.below(2) == 0 {
                    (starts[rng.below(starts.len())] + rng.below(3)).saturating_sub(1)
                } else {
                    3 + rng.below(lines.len().saturating_sub(3).max(1))
                };
                if (3..lines.len()).contains(&i) {
                    mutate(&mut rng, &mut lines, width, i);
                }
            }
            let mut bytes = text(&lines, rng.below(5) != 0);
            if case % 13 == 0 {
                // Not UTF-8.
                let at = bytes.len() / 2 + rng.below(bytes.len() / 2);
                bytes[at] = 0xff;
            }
            let want = one_thread(&bytes);
            let got = outcome(parse_bytes(&bytes, threads, min_piece));
            assert_eq!(got, want, "case {case}, {threads} threads, pieces of >= {min_piece} bytes");
            clean += want.starts_with("Ok") as usize;
            cases += 1;
        }
        // Both outcomes are exercised: clean readings and errors.
        assert!(clean > cases / 4 && clean < cases * 3 / 4, "{clean} of {cases} cases read without error");
    }

    #[test]
    fn lines_are_counted_as_one_by_one() {
        let mut rng = Rng(3);
        for len in (0..300).chain([4096, 4097, 10_000]) {
            let bytes: Vec<u8> = (0..len).map(|_| [b'\n', b'1', b',', 0x8a, 0x0a ^ 0x80][rng.below(5)]).collect();
            let want = bytes.split(|&b| b == b'\n').count() - bytes.last().is_none_or(|&b| b == b'\n') as usize;
            assert_eq!(count_lines(&bytes), want, "{len} bytes");
        }
    }

    /// Runs of empty lines give a piece less room than lines (a row needs 2 * width bytes): a
    /// part that fills up stops its piece there, and the rest is read as the one-thread reader
    /// reads it.
    #[test]
    fn empty_lines_do_not_get_room_and_change_nothing() {
        let mut rng = Rng(5);
        let (mut lines, _) = lines(&mut rng, 3000);
        for at in [1500, 2900] {
            for _ in 0..5000 {
                lines.insert(at, String::new());
            }
        }
        let bytes = text(&lines, true);
        for threads in [2, 3, 4] {
            assert_eq!(outcome(parse_bytes(&bytes, threads, 1000)), one_thread(&bytes), "{threads} threads");
        }
    }

    #[test]
    fn every_piece_is_taken_from_a_clean_recording() {
        let mut rng = Rng(7);
        let (lines, _) = lines(&mut rng, 5000);
        let bytes = text(&lines, true);
        let from = bytes.iter().enumerate().filter(|(_, b)| **b == b'\n').nth(2).map(|(i, _)| i + 1).unwrap();
        let cuts = cuts(&bytes, from, 4, 1000);
        assert_eq!(cuts.len(), 5, "{cuts:?}");
        let mut p = Parser::new(None);
        let mut l = Lines { bytes: &bytes, pos: 0 };
        while p.cols.is_none() {
            let (read, line) = l.next_line();
            assert!(p.line(read, line).unwrap());
        }
        let cols = p.cols.clone().unwrap();
        let ranges: Vec<(usize, usize)> = cuts.windows(2).map(|w| (w[0], w[1])).collect();
        let room: Vec<usize> = ranges.iter().map(|&(a, b)| count_lines(&bytes[a..b])).collect();
        assert_eq!(room.iter().sum::<usize>(), 5000);
        let mut columns = Columnar::new(5000, &cols);
        for ((part, &(a, b)), &k) in columns.parts(&room, &cols).iter_mut().zip(&ranges).zip(&room) {
            let taken = fast_piece(&bytes, a, b, &cols, part);
            assert_eq!(taken.taken_end, b, "the piece is taken whole");
            assert_eq!(taken.rows, k);
            assert!(taken.rows > 1000);
        }
        // The parts are the recording, in place (no join of separate pieces).
        assert!(p.whole(&mut columns, &room, &cols));
        let want = super::super::parse_sized(std::io::Cursor::new(&bytes[..]), None).unwrap().0;
        assert_eq!(format!("{:?}", p.rec), format!("{want:?}"));
        assert_eq!(outcome(parse_bytes(&bytes, 4, 1000)), one_thread(&bytes));
    }

    /// `Recording::load_with` reads a file in pieces (larger than two [`MIN_PIECE_BYTES`]) and
    /// gives what `Recording::load` gives, for a clean file and one with an error far in.
    #[test]
    fn a_file_read_in_pieces_is_the_file_read_as_a_stream() {
        let mut rng = Rng(11);
        let (mut lines, _) = lines(&mut rng, 12_000);
        let dir = std::env::temp_dir().join(format!("taut-pieces-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rec.csv");
        for bad in [None, Some(9_000), Some(4_000)] {
            if let Some(i) = bad {
                lines[i] = lines[i].replacen(',', ",x", 1);
            }
            let bytes = text(&lines, true);
            assert!(bytes.len() > 3 * MIN_PIECE_BYTES, "{} bytes", bytes.len());
            std::fs::write(&path, &bytes).unwrap();
            let want = outcome(Recording::load(&path));
            assert_eq!(want.starts_with("Ok"), bad.is_none(), "{}", &want[..want.len().min(300)]);
            for threads in [2, 3] {
                assert_eq!(outcome(Recording::load_with(&path, threads)), want, "{threads} threads, error at {bad:?}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
