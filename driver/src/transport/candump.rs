//! The can-utils `candump -l` log format: a [`Recorder`] that logs a session, a [`Replay`] that
//! feeds a log back through the stack, and the sans-IO line codec both use.
//!
//! ```text
//! (1700000000.123456) can0 123#DEADBEEF        standard id: 3 hex digits
//! (1700000000.123460) can0 1ABCDEF0#0102       extended id: 8 hex digits
//! (1700000000.123470) can0 321#R               remote frame (dlc 0); 321#R4: dlc 4
//! (1700000000.123480) can0 20000040#0000000000000000   error frame (id has CAN_ERR_FLAG)
//! (1700000000.123490) can0 123##1DEAD          CAN FD: not supported on this bus, rejected
//! ```
//! The timestamp is seconds.microseconds; `candump -x` appends a direction (`R`/`T`), which is
//! accepted and ignored. Data bytes may be separated by `.` (the `cansend` spelling).

use super::{BusEvent, CanTransport, Frame, TransportError};
use std::io::{self, BufRead, Write};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// `CAN_ERR_FLAG`: marks an error frame's id in the log.
const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// A frame as logged: a data/remote frame or an error frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoggedFrame {
    /// A CAN 2.0 data or remote frame.
    Can(Frame),
    /// An error frame: error class bits (id without the flag) and its data.
    Error {
        /// `linux/can/error.h` class bits.
        class: u32,
        /// The 8 data bytes.
        data: [u8; 8],
    },
}

/// One parsed log line. Borrows the interface name from the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogLine<'a> {
    /// Timestamp, microseconds since the Unix epoch (or since whatever the log's clock counts).
    pub t_us: u64,
    /// Interface name, e.g. `can0`.
    pub iface: &'a str,
    /// The frame.
    pub frame: LoggedFrame,
}

/// Why a log line could not be parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CandumpError {
    /// The line does not start with `(seconds.micros)`.
    BadTimestamp,
    /// No interface name after the timestamp.
    MissingInterface,
    /// No `id#data` field.
    MissingFrame,
    /// The id is not 3 or 8 hex digits, or does not fit.
    BadId,
    /// Data is not pairs of hex digits, or longer than 8 bytes.
    BadData,
    /// A CAN FD frame (`##`): this stack speaks classic CAN only.
    CanFd,
    /// Unexpected text after the frame.
    TrailingGarbage,
}

impl std::fmt::Display for CandumpError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            CandumpError::BadTimestamp => "expected a timestamp `(seconds.microseconds)` first",
            CandumpError::MissingInterface => "expected an interface name after the timestamp",
            CandumpError::MissingFrame => "expected a frame `id#data` after the interface",
            CandumpError::BadId => "the id must be 3 (standard) or 8 (extended) hex digits",
            CandumpError::BadData => "data must be up to 8 bytes as pairs of hex digits",
            CandumpError::CanFd => "CAN FD frames (`##`) are not supported",
            CandumpError::TrailingGarbage => "unexpected text after the frame",
        };
        f.write_str(s)
    }
}

impl std::error::Error for CandumpError {}

fn hex_val(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

fn parse_hex_u32(s: &str) -> Option<u32> {
    if s.is_empty() || s.len() > 8 {
        return None;
    }
    s.bytes().try_fold(0u32, |acc, c| Some(acc << 4 | u32::from(hex_val(c)?)))
}

/// Parses one `candump -l` line (without or with its trailing newline). Never panics.
pub fn parse_line(line: &str) -> Result<LogLine<'_>, CandumpError> {
    let line = line.trim_end_matches(['\n', '\r']);
    let mut fields = line.split_ascii_whitespace();
    let ts = fields.next().ok_or(CandumpError::BadTimestamp)?;
    let t_us = parse_timestamp(ts).ok_or(CandumpError::BadTimestamp)?;
    let iface = fields.next().ok_or(CandumpError::MissingInterface)?;
    let body = fields.next().ok_or(CandumpError::MissingFrame)?;
    let frame = parse_frame(body)?;
    match fields.next() {
        None | Some("R") | Some("T") => {}
        Some(_) => return Err(CandumpError::TrailingGarbage),
    }
    if fields.next().is_some() {
        return Err(CandumpError::TrailingGarbage);
    }
    Ok(LogLine { t_us, iface, frame })
}

fn parse_timestamp(ts: &str) -> Option<u64> {
    let inner = ts.strip_prefix('(')?.strip_suffix(')')?;
    let (secs, frac) = inner.split_once('.')?;
    if secs.is_empty() || !secs.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    if frac.is_empty() || frac.len() > 9 || !frac.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    let s: u64 = secs.parse().ok()?;
    // Pad or cut the fraction to microseconds: candump writes 6 digits, other tools 3 or 9.
    let mut us: u64 = 0;
    for i in 0..6 {
        us = us * 10 + frac.as_bytes().get(i).map_or(0, |c| u64::from(c - b'0'));
    }
    s.checked_mul(1_000_000)?.checked_add(us)
}

/// Parses the `id#data` field of a log line or of a `cansend` argument.
pub fn parse_frame(body: &str) -> Result<LoggedFrame, CandumpError> {
    let (id_s, rest) = body.split_once('#').ok_or(CandumpError::MissingFrame)?;
    if rest.starts_with('#') {
        return Err(CandumpError::CanFd);
    }
    let id = parse_hex_u32(id_s).ok_or(CandumpError::BadId)?;
    let extended = match id_s.len() {
        3 => false,
        8 => true,
        _ => return Err(CandumpError::BadId),
    };
    if !extended && id > super::MAX_STD_ID {
        return Err(CandumpError::BadId);
    }
    // `_X` after the data is a classic-CAN len8_dlc (dlc 9..15 with 8 bytes): keep the 8 bytes.
    let rest = match rest.split_once('_') {
        Some((d, l)) if l.len() == 1 && hex_val(l.as_bytes()[0]).is_some() => d,
        Some(_) => return Err(CandumpError::BadData),
        None => rest,
    };
    if let Some(r) = rest.strip_prefix(['R', 'r']) {
        let dlc = match r.len() {
            0 => 0,
            1 => hex_val(r.as_bytes()[0]).filter(|&d| d <= 8).ok_or(CandumpError::BadData)?,
            _ => return Err(CandumpError::BadData),
        };
        if extended && id & CAN_ERR_FLAG != 0 {
            return Err(CandumpError::BadId);
        }
        return Frame::remote(id, extended, dlc).map(LoggedFrame::Can).ok_or(CandumpError::BadId);
    }
    let mut data = [0u8; 8];
    let mut n = 0;
    let mut digits = rest.bytes().filter(|&c| c != b'.');
    while let Some(hi) = digits.next() {
        let lo = digits.next().ok_or(CandumpError::BadData)?;
        let b = (hex_val(hi).ok_or(CandumpError::BadData)? << 4) | hex_val(lo).ok_or(CandumpError::BadData)?;
        if n == 8 {
            return Err(CandumpError::BadData);
        }
        data[n] = b;
        n += 1;
    }
    if extended && id & CAN_ERR_FLAG != 0 {
        return Ok(LoggedFrame::Error { class: id & !CAN_ERR_FLAG, data });
    }
    if extended && id > super::MAX_EXT_ID {
        return Err(CandumpError::BadId);
    }
    Frame::try_new(id, extended, &data[..n]).map(LoggedFrame::Can).ok_or(CandumpError::BadId)
}

/// Writes one log line (with newline) in the exact spelling of `candump -l`.
pub fn write_line<W: Write>(out: &mut W, t_us: u64, iface: &str, frame: &Frame) -> io::Result<()> {
    write!(out, "({}.{:06}) {} ", t_us / 1_000_000, t_us % 1_000_000, iface)?;
    if frame.extended {
        write!(out, "{:08X}#", frame.id)?;
    } else {
        write!(out, "{:03X}#", frame.id)?;
    }
    if frame.rtr {
        if frame.dlc > 0 {
            write!(out, "R{}", frame.dlc)?;
        } else {
            write!(out, "R")?;
        }
    } else {
        for b in frame.data() {
            write!(out, "{b:02X}")?;
        }
    }
    writeln!(out)
}

/// Microseconds since the Unix epoch, the clock of `candump -l`.
pub fn wall_clock_us() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

/// A transport that logs every frame it sends and receives to a `candump -l` log, then passes
/// it on. The log is a view of the bus from this endpoint, as candump gives on a real bus.
pub struct Recorder<T, W: Write> {
    inner: T,
    out: W,
    iface: String,
    clock: Box<dyn FnMut() -> u64 + Send>,
    /// The first write error; logging stops after it, the bus keeps working.
    error: Option<io::ErrorKind>,
}

impl<T: CanTransport, W: Write> Recorder<T, W> {
    /// Wraps `inner`, logging to `out` under the interface name `iface`.
    pub fn new(inner: T, out: W, iface: &str) -> Self {
        Self::with_clock(inner, out, iface, Box::new(wall_clock_us))
    }

    /// Like [`new`](Self::new) with timestamps (µs) from `clock`, e.g. a simulation clock.
    pub fn with_clock(inner: T, out: W, iface: &str, clock: Box<dyn FnMut() -> u64 + Send>) -> Self {
        Recorder { inner, out, iface: iface.to_string(), clock, error: None }
    }

    fn log(&mut self, f: &Frame) {
        if self.error.is_none() {
            let t = (self.clock)();
            if let Err(e) = write_line(&mut self.out, t, &self.iface, f) {
                self.error = Some(e.kind());
            }
        }
    }

    /// The first error writing the log, if any.
    pub fn log_error(&self) -> Option<io::ErrorKind> {
        self.error
    }

    /// Flushes the log and hands back the transport and the writer.
    pub fn finish(mut self) -> (T, W, io::Result<()>) {
        let r = self.out.flush();
        (self.inner, self.out, r)
    }
}

impl<T: CanTransport, W: Write> CanTransport for Recorder<T, W> {
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        self.inner.send(frame)?;
        self.log(frame);
        Ok(())
    }
    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        let r = self.inner.try_recv()?;
        if let Some(f) = &r {
            self.log(f);
        }
        Ok(r)
    }
    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        let r = self.inner.recv_deadline(deadline)?;
        if let Some(f) = &r {
            self.log(f);
        }
        Ok(r)
    }
    fn iface(&self) -> super::IfName {
        self.inner.iface()
    }
    fn rx_timestamp(&self) -> Option<Instant> {
        self.inner.rx_timestamp()
    }
}

/// Counts kept by a [`Replay`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplayStats {
    /// Lines read.
    pub lines: u64,
    /// Frames handed out.
    pub frames: u64,
    /// Lines that did not parse (skipped), and the first reason seen.
    pub bad_lines: u64,
    /// Why the first bad line was bad, and its 1-based line number.
    pub first_bad: Option<(u64, CandumpError)>,
    /// Error frames handed out as [`TransportError::Bus`].
    pub error_frames: u64,
    /// Frames the stack sent into the replay (discarded).
    pub sent: u64,
}

/// Replays a `candump -l` log as a transport: each `try_recv` returns the next logged frame,
/// regardless of wall time, so a replay is deterministic; [`Replay::last_t_us`] gives the
/// logged time of the frame just returned, for driving a sans-IO stack's clock. Frames sent
/// into it are discarded. Lines of other interfaces are skipped when a filter is set.
pub struct Replay<R> {
    input: R,
    buf: String,
    iface: Option<String>,
    last_t_us: Option<u64>,
    done: bool,
    stats: ReplayStats,
}

impl<R: BufRead> Replay<R> {
    /// Replays every interface's frames from `input`.
    pub fn new(input: R) -> Self {
        Replay { input, buf: String::new(), iface: None, last_t_us: None, done: false, stats: ReplayStats::default() }
    }

    /// Only replays lines of interface `iface`.
    pub fn only_interface(mut self, iface: &str) -> Self {
        self.iface = Some(iface.to_string());
        self
    }

    /// Counts so far.
    pub fn stats(&self) -> ReplayStats {
        self.stats
    }

    /// Log time of the last frame handed out, µs.
    pub fn last_t_us(&self) -> Option<u64> {
        self.last_t_us
    }

    /// True once the whole log has been read.
    pub fn is_finished(&self) -> bool {
        self.done
    }

    fn next_entry(&mut self) -> Result<Option<Frame>, TransportError> {
        loop {
            if self.done {
                return Err(TransportError::Closed);
            }
            self.buf.clear();
            match self.input.read_line(&mut self.buf) {
                Ok(0) => {
                    self.done = true;
                    return Err(TransportError::Closed);
                }
                Ok(_) => {}
                Err(e) => {
                    self.done = true;
                    return Err(TransportError::Io(e.kind()));
                }
            }
            self.stats.lines += 1;
            if self.buf.trim().is_empty() {
                continue;
            }
            match parse_line(&self.buf) {
                Ok(l) => {
                    if self.iface.as_deref().is_some_and(|i| i != l.iface) {
                        continue;
                    }
                    self.last_t_us = Some(l.t_us);
                    match l.frame {
                        LoggedFrame::Can(f) => {
                            self.stats.frames += 1;
                            return Ok(Some(f));
                        }
                        LoggedFrame::Error { class, data } => {
                            self.stats.error_frames += 1;
                            return Err(TransportError::Bus(BusEvent::from_error_frame(class, &data)));
                        }
                    }
                }
                Err(e) => {
                    self.stats.bad_lines += 1;
                    if self.stats.first_bad.is_none() {
                        self.stats.first_bad = Some((self.stats.lines, e));
                    }
                }
            }
        }
    }
}

impl<R: BufRead> CanTransport for Replay<R> {
    fn send(&mut self, _frame: &Frame) -> Result<(), TransportError> {
        self.stats.sent += 1;
        Ok(())
    }
    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        self.next_entry()
    }
    fn recv_deadline(&mut self, _deadline: Instant) -> Result<Option<Frame>, TransportError> {
        self.next_entry()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parses_the_documented_spellings() {
        let l = parse_line("(1700000000.123456) can0 123#DEADBEEF\n").unwrap();
        assert_eq!(l.t_us, 1_700_000_000_123_456);
        assert_eq!(l.iface, "can0");
        assert_eq!(l.frame, LoggedFrame::Can(Frame::new(0x123, &[0xDE, 0xAD, 0xBE, 0xEF])));
        let l = parse_line("(1.5) vcan0 1ABCDEF0#0102 R").unwrap();
        assert_eq!(l.t_us, 1_500_000);
        assert_eq!(l.frame, LoggedFrame::Can(Frame::try_new(0x1ABC_DEF0, true, &[1, 2]).unwrap()));
        assert_eq!(parse_line("(0.000001) can0 321#R4").unwrap().frame, LoggedFrame::Can(Frame::remote(0x321, false, 4).unwrap()));
        assert_eq!(parse_line("(0.0) c 080#").unwrap().frame, LoggedFrame::Can(Frame::new(0x80, &[])));
        assert_eq!(parse_line("(0.0) c 123#11.22").unwrap().frame, LoggedFrame::Can(Frame::new(0x123, &[0x11, 0x22])));
        assert!(matches!(parse_line("(0.0) c 20000040#0000000000000000").unwrap().frame, LoggedFrame::Error { class: 0x40, .. }));
        assert_eq!(parse_line("(0.0) c 123##1AA"), Err(CandumpError::CanFd));
        assert_eq!(parse_line("(0.0) c 1234#AA"), Err(CandumpError::BadId));
        assert_eq!(parse_line("(0.0) c 800#AA"), Err(CandumpError::BadId));
        assert_eq!(parse_line("(0.0) c 123#AAB"), Err(CandumpError::BadData));
        assert_eq!(parse_line("(0.0) c 123#001122334455667788"), Err(CandumpError::BadData));
        assert_eq!(parse_line("0.0 c 123#"), Err(CandumpError::BadTimestamp));
        assert_eq!(parse_line("(0.0)"), Err(CandumpError::MissingInterface));
        assert_eq!(parse_line("(0.0) can0"), Err(CandumpError::MissingFrame));
        assert_eq!(parse_line("(0.0) c 123# x y"), Err(CandumpError::TrailingGarbage));
    }

    #[test]
    fn agrees_with_the_socketcan_crate_reader() {
        // An independent parser (the socketcan crate's dump::Reader) reads what we write.
        let frames = [
            Frame::new(0x123, &[0xDE, 0xAD]),
            Frame::try_new(0x1ABC_DEF0, true, &[1, 2, 3]).unwrap(),
            Frame::new(0x080, &[]),
            Frame::remote(0x321, false, 0).unwrap(),
        ];
        let mut log = Vec::new();
        for (i, f) in frames.iter().enumerate() {
            write_line(&mut log, 1_700_000_000_000_000 + i as u64, "can0", f).unwrap();
        }
        let recs: Vec<_> = ::socketcan::dump::Reader::from_reader(&log[..]).collect::<Result<_, _>>().unwrap();
        assert_eq!(recs.len(), frames.len());
        use ::socketcan::{EmbeddedFrame, Frame as _};
        for (r, f) in recs.iter().zip(&frames) {
            assert_eq!(r.device, "can0");
            assert_eq!(r.frame.id_word() & 0x1FFF_FFFF, f.id);
            assert_eq!(r.frame.is_extended(), f.extended);
            assert_eq!(r.frame.is_remote_frame(), f.rtr);
            if !f.rtr {
                assert_eq!(r.frame.data(), f.data());
            }
        }
    }

    #[test]
    fn replay_skips_bad_lines_and_counts_them() {
        let log = "(1.000000) can0 701#00\nnot a line\n\n(1.000100) can1 181#01\n(1.000200) can0 20000040#0000000000000000\n(1.000300) can0 182#02\n";
        let mut r = Replay::new(log.as_bytes()).only_interface("can0");
        assert_eq!(r.try_recv().unwrap(), Some(Frame::new(0x701, &[0])));
        assert_eq!(r.try_recv(), Err(TransportError::Bus(BusEvent::BusOff)));
        assert_eq!(r.try_recv().unwrap(), Some(Frame::new(0x182, &[2])));
        assert_eq!(r.last_t_us(), Some(1_000_300));
        assert_eq!(r.try_recv(), Err(TransportError::Closed));
        let s = r.stats();
        assert_eq!((s.frames, s.bad_lines, s.error_frames), (2, 1, 1));
        assert_eq!(s.first_bad, Some((2, CandumpError::BadTimestamp)));
    }

    fn arb_frame() -> impl Strategy<Value = Frame> {
        prop_oneof![
            (0u32..=0x7FF, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::try_new(id, false, &d).unwrap()),
            (0u32..=0x1FFF_FFFF, proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| Frame::try_new(id, true, &d).unwrap()),
            (0u32..=0x7FF, 0u8..=8).prop_map(|(id, n)| Frame::remote(id, false, n).unwrap()),
        ]
    }

    proptest! {
        #[test]
        fn write_then_parse_roundtrips(f in arb_frame(), t in 0u64..=4_000_000_000_000_000, iface in "[a-z]{1,4}[0-9]{0,2}") {
            let mut line = Vec::new();
            write_line(&mut line, t, &iface, &f).unwrap();
            let s = String::from_utf8(line).unwrap();
            let l = parse_line(&s).unwrap();
            prop_assert_eq!(l.t_us, t);
            prop_assert_eq!(l.iface, iface.as_str());
            prop_assert_eq!(l.frame, LoggedFrame::Can(f));
        }

        #[test]
        fn arbitrary_text_never_panics(s in "\\PC{0,80}") {
            let _ = parse_line(&s);
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..64)) {
            let s = String::from_utf8_lossy(&b);
            let _ = parse_line(&s);
        }
    }
}
