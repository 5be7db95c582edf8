//! Service data objects (CiA 301 7.2.4): the frame codec for both directions, abort codes with
//! their names, and a client for expedited and segmented upload and download.
//!
//! ```text
//! COB-ID 0x600 + node (client -> server), 0x580 + node (server -> client); always 8 bytes.
//! byte 0: command specifier             bytes 1..3: index (LE)  byte 3: sub-index  4..8: data
//!
//! client -> server (ccs = byte0 >> 5)        server -> client (scs = byte0 >> 5)
//! 1 initiate download  001 x nn e s          3 initiate download resp. 011 00000
//! 0 download segment   000 t nnn c (7 data)  1 download segment resp.  001 t 0000
//! 2 initiate upload    010 00000             2 initiate upload resp.   010 x nn e s
//! 3 upload segment     011 t 0000            0 upload segment resp.    000 t nnn c (7 data)
//! 4 abort              100 00000, [4..8] abort code (u32 LE), either direction
//! e: expedited (data in bytes 4..8), s: size indicated, nn: 4 - size (expedited),
//! nnn: 7 - bytes in segment, t: toggle, c: last segment.
//! ```
//! Block transfer (ccs/scs 5, 6) is not supported and is answered with an abort.

use super::NodeId;
use crate::can::Frame;
use std::fmt;
use std::time::{Duration, Instant};

/// Base COB-ID of SDO requests (client -> server).
pub const SDO_RX_BASE: u16 = 0x600;
/// Base COB-ID of SDO responses (server -> client).
pub const SDO_TX_BASE: u16 = 0x580;
/// Largest value the client transfers (a device name, a small domain), bytes.
pub const SDO_BUF: usize = 64;

/// An SDO abort code (CiA 301 table 22).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct AbortCode(pub u32);

impl AbortCode {
    /// Toggle bit not alternated.
    pub const TOGGLE: AbortCode = AbortCode(0x0503_0000);
    /// SDO protocol timed out.
    pub const TIMEOUT: AbortCode = AbortCode(0x0504_0000);
    /// Command specifier not valid or unknown.
    pub const COMMAND: AbortCode = AbortCode(0x0504_0001);
    /// Out of memory.
    pub const OUT_OF_MEMORY: AbortCode = AbortCode(0x0504_0005);
    /// Unsupported access to an object.
    pub const UNSUPPORTED_ACCESS: AbortCode = AbortCode(0x0601_0000);
    /// Attempt to read a write-only object.
    pub const WRITE_ONLY: AbortCode = AbortCode(0x0601_0001);
    /// Attempt to write a read-only object.
    pub const READ_ONLY: AbortCode = AbortCode(0x0601_0002);
    /// Object does not exist.
    pub const NO_OBJECT: AbortCode = AbortCode(0x0602_0000);
    /// Object cannot be mapped to the PDO.
    pub const NOT_MAPPABLE: AbortCode = AbortCode(0x0604_0041);
    /// Mapped objects exceed the PDO length.
    pub const PDO_TOO_LONG: AbortCode = AbortCode(0x0604_0042);
    /// Length of service parameter does not match.
    pub const LENGTH_MISMATCH: AbortCode = AbortCode(0x0607_0010);
    /// Sub-index does not exist.
    pub const NO_SUBINDEX: AbortCode = AbortCode(0x0609_0011);
    /// Invalid value for parameter.
    pub const INVALID_VALUE: AbortCode = AbortCode(0x0609_0030);
    /// General error.
    pub const GENERAL: AbortCode = AbortCode(0x0800_0000);
    /// Data cannot be transferred because of the present device state.
    pub const DEVICE_STATE: AbortCode = AbortCode(0x0800_0022);

    /// The name of the abort code.
    pub fn name(&self) -> &'static str {
        match self.0 {
            0x0503_0000 => "toggle bit not alternated",
            0x0504_0000 => "SDO protocol timed out",
            0x0504_0001 => "client/server command specifier not valid or unknown",
            0x0504_0002 => "invalid block size",
            0x0504_0003 => "invalid sequence number",
            0x0504_0004 => "CRC error",
            0x0504_0005 => "out of memory",
            0x0601_0000 => "unsupported access to an object",
            0x0601_0001 => "attempt to read a write-only object",
            0x0601_0002 => "attempt to write a read-only object",
            0x0602_0000 => "object does not exist in the object dictionary",
            0x0604_0041 => "object cannot be mapped to the PDO",
            0x0604_0042 => "number and length of mapped objects would exceed the PDO length",
            0x0604_0043 => "general parameter incompatibility",
            0x0604_0047 => "general internal incompatibility in the device",
            0x0606_0000 => "access failed due to a hardware error",
            0x0607_0010 => "data type does not match, length of service parameter does not match",
            0x0607_0012 => "data type does not match, length of service parameter too high",
            0x0607_0013 => "data type does not match, length of service parameter too low",
            0x0609_0011 => "sub-index does not exist",
            0x0609_0030 => "invalid value for parameter",
            0x0609_0031 => "value of parameter written too high",
            0x0609_0032 => "value of parameter written too low",
            0x0609_0036 => "maximum value is less than minimum value",
            0x060A_0023 => "resource not available: SDO connection",
            0x0800_0000 => "general error",
            0x0800_0020 => "data cannot be transferred or stored to the application",
            0x0800_0021 => "data cannot be transferred or stored because of local control",
            0x0800_0022 => "data cannot be transferred or stored because of the present device state",
            0x0800_0023 => "object dictionary dynamic generation failed or no object dictionary",
            0x0800_0024 => "no data available",
            _ => "unknown abort code",
        }
    }
}

impl fmt::Debug for AbortCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:08X} ({})", self.0, self.name())
    }
}

impl fmt::Display for AbortCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self, f)
    }
}

/// The data part of an initiate message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Initiate {
    /// Expedited: up to 4 bytes in the message itself.
    Expedited {
        /// Bytes 4..8.
        data: [u8; 4],
        /// Valid bytes, 1..=4 (4 when the size is not indicated).
        len: u8,
    },
    /// Segmented: data follows in segments.
    Segmented {
        /// Total size, when indicated.
        size: Option<u32>,
    },
}

/// A segment of a segmented transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segment {
    /// Toggle bit.
    pub toggle: bool,
    /// Up to 7 bytes.
    pub data: [u8; 7],
    /// Valid bytes, 0..=7.
    pub len: u8,
    /// Last segment.
    pub last: bool,
}

/// A client -> server message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoRequest {
    /// Initiate download (write).
    InitiateDownload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Expedited data or the segmented size.
        kind: Initiate,
    },
    /// Download segment.
    DownloadSegment(Segment),
    /// Initiate upload (read).
    InitiateUpload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// Upload segment request.
    UploadSegment {
        /// Toggle bit.
        toggle: bool,
    },
    /// Abort transfer.
    Abort {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Why.
        code: AbortCode,
    },
}

/// A server -> client message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoResponse {
    /// Initiate download response.
    DownloadInitiated {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// Download segment response.
    DownloadSegmentAck {
        /// Toggle bit.
        toggle: bool,
    },
    /// Initiate upload response.
    UploadInitiated {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Expedited data or the segmented size.
        kind: Initiate,
    },
    /// Upload segment response.
    UploadSegment(Segment),
    /// Abort transfer.
    Abort {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Why.
        code: AbortCode,
    },
}

/// Why an SDO message was not understood.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoParseError {
    /// Not exactly 8 data bytes.
    Length(u8),
    /// Command specifier not known (block transfer, or garbage). The command byte's other bits
    /// are read leniently, as drives in the field set reserved bits.
    Command(u8),
}

impl SdoParseError {
    /// The abort code a server answers with.
    pub fn abort_code(&self) -> AbortCode {
        match self {
            SdoParseError::Length(_) => AbortCode::GENERAL,
            SdoParseError::Command(_) => AbortCode::COMMAND,
        }
    }
}

fn mux(d: &[u8]) -> (u16, u8) {
    (u16::from_le_bytes([d[1], d[2]]), d[3])
}

fn frame8(id: u16, b: [u8; 8]) -> Frame {
    Frame::new(id, &b)
}

fn encode_initiate(cs: u8, index: u16, sub: u8, kind: &Initiate) -> [u8; 8] {
    let i = index.to_le_bytes();
    match *kind {
        Initiate::Expedited { data, len } => {
            let len = len.clamp(1, 4);
            let n = 4 - len;
            [cs << 5 | n << 2 | 0b11, i[0], i[1], sub, data[0], data[1], data[2], data[3]]
        }
        Initiate::Segmented { size: Some(s) } => {
            let s = s.to_le_bytes();
            [cs << 5 | 0b01, i[0], i[1], sub, s[0], s[1], s[2], s[3]]
        }
        Initiate::Segmented { size: None } => [cs << 5, i[0], i[1], sub, 0, 0, 0, 0],
    }
}

fn decode_initiate(b0: u8, d: &[u8]) -> Initiate {
    let e = b0 & 0b10 != 0;
    let s = b0 & 0b01 != 0;
    let mut data = [0u8; 4];
    data.copy_from_slice(&d[4..8]);
    if e {
        let len = if s { 4 - ((b0 >> 2) & 0b11) } else { 4 };
        // Zero the unused bytes so equal transfers compare equal.
        for b in &mut data[usize::from(len)..] {
            *b = 0;
        }
        Initiate::Expedited { data, len }
    } else if s {
        Initiate::Segmented { size: Some(u32::from_le_bytes(data)) }
    } else {
        Initiate::Segmented { size: None }
    }
}

fn encode_segment(cs: u8, s: &Segment) -> [u8; 8] {
    let len = s.len.min(7);
    let mut b = [0u8; 8];
    b[0] = cs << 5 | u8::from(s.toggle) << 4 | (7 - len) << 1 | u8::from(s.last);
    b[1..1 + usize::from(len)].copy_from_slice(&s.data[..usize::from(len)]);
    b
}

fn decode_segment(d: &[u8]) -> Segment {
    let b0 = d[0];
    let len = 7 - ((b0 >> 1) & 0b111);
    let mut data = [0u8; 7];
    data[..usize::from(len)].copy_from_slice(&d[1..1 + usize::from(len)]);
    Segment { toggle: b0 & 0x10 != 0, data, len, last: b0 & 1 != 0 }
}

fn encode_abort(index: u16, sub: u8, code: AbortCode) -> [u8; 8] {
    let i = index.to_le_bytes();
    let c = code.0.to_le_bytes();
    [0x80, i[0], i[1], sub, c[0], c[1], c[2], c[3]]
}

impl SdoRequest {
    /// The frame to server `node`.
    pub fn encode(&self, node: NodeId) -> Frame {
        let id = SDO_RX_BASE + u16::from(node & 0x7F);
        frame8(
            id,
            match self {
                SdoRequest::InitiateDownload { index, sub, kind } => encode_initiate(1, *index, *sub, kind),
                SdoRequest::DownloadSegment(s) => encode_segment(0, s),
                SdoRequest::InitiateUpload { index, sub } => {
                    let i = index.to_le_bytes();
                    [0x40, i[0], i[1], *sub, 0, 0, 0, 0]
                }
                SdoRequest::UploadSegment { toggle } => [0x60 | u8::from(*toggle) << 4, 0, 0, 0, 0, 0, 0, 0],
                SdoRequest::Abort { index, sub, code } => encode_abort(*index, *sub, *code),
            },
        )
    }

    /// Parses the payload of a `0x600 + node` frame. Never panics.
    pub fn decode(d: &[u8]) -> Result<SdoRequest, SdoParseError> {
        if d.len() != 8 {
            return Err(SdoParseError::Length(d.len() as u8));
        }
        let b0 = d[0];
        let (index, sub) = mux(d);
        Ok(match b0 >> 5 {
            1 => SdoRequest::InitiateDownload { index, sub, kind: decode_initiate(b0, d) },
            0 => SdoRequest::DownloadSegment(decode_segment(d)),
            2 => SdoRequest::InitiateUpload { index, sub },
            3 => SdoRequest::UploadSegment { toggle: b0 & 0x10 != 0 },
            4 => SdoRequest::Abort { index, sub, code: AbortCode(u32::from_le_bytes([d[4], d[5], d[6], d[7]])) },
            _ => return Err(SdoParseError::Command(b0)),
        })
    }
}

impl SdoResponse {
    /// The frame from server `node`.
    pub fn encode(&self, node: NodeId) -> Frame {
        let id = SDO_TX_BASE + u16::from(node & 0x7F);
        frame8(
            id,
            match self {
                SdoResponse::DownloadInitiated { index, sub } => {
                    let i = index.to_le_bytes();
                    [0x60, i[0], i[1], *sub, 0, 0, 0, 0]
                }
                SdoResponse::DownloadSegmentAck { toggle } => [0x20 | u8::from(*toggle) << 4, 0, 0, 0, 0, 0, 0, 0],
                SdoResponse::UploadInitiated { index, sub, kind } => encode_initiate(2, *index, *sub, kind),
                SdoResponse::UploadSegment(s) => encode_segment(0, s),
                SdoResponse::Abort { index, sub, code } => encode_abort(*index, *sub, *code),
            },
        )
    }

    /// Parses the payload of a `0x580 + node` frame. Never panics.
    pub fn decode(d: &[u8]) -> Result<SdoResponse, SdoParseError> {
        if d.len() != 8 {
            return Err(SdoParseError::Length(d.len() as u8));
        }
        let b0 = d[0];
        let (index, sub) = mux(d);
        Ok(match b0 >> 5 {
            3 => SdoResponse::DownloadInitiated { index, sub },
            1 => SdoResponse::DownloadSegmentAck { toggle: b0 & 0x10 != 0 },
            2 => SdoResponse::UploadInitiated { index, sub, kind: decode_initiate(b0, d) },
            0 => SdoResponse::UploadSegment(decode_segment(d)),
            4 => SdoResponse::Abort { index, sub, code: AbortCode(u32::from_le_bytes([d[4], d[5], d[6], d[7]])) },
            _ => return Err(SdoParseError::Command(b0)),
        })
    }
}

/// How an SDO transfer ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoOutcome {
    /// A download (write) completed.
    Downloaded {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// An upload (read) completed; the bytes are in [`SdoClient::data`].
    Uploaded {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Bytes read.
        len: usize,
    },
    /// The transfer was aborted.
    Aborted(SdoAbort),
}

/// An aborted transfer, displayed as `abort accessing 0x6064sub0: ...`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoAbort {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Why.
    pub code: AbortCode,
    /// True if the server aborted; false if this client did (timeout, protocol error).
    pub by_server: bool,
}

impl fmt::Display for SdoAbort {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} abort accessing 0x{:04X}sub{}: {}", if self.by_server { "server" } else { "client" }, self.index, self.sub, self.code)
    }
}

/// The client is busy with another transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoBusy;

/// Why a frame from the server was not taken as the answer: it is dropped and counted, never
/// answered (an abort for a stale reply would kill the transfer it does not belong to).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoDiscard {
    /// Not a valid SDO response.
    Malformed(SdoParseError),
    /// No transfer in flight.
    Idle,
    /// A response that does not match the request in flight (command specifier, index,
    /// sub-index or toggle bit): a late, duplicated or stale reply.
    Mismatch {
        /// Its first byte (the command specifier).
        command: u8,
    },
}

/// Frames the client may have queued at once: an abort and the request that follows it.
const CLIENT_TX: usize = 4;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    DownloadInit,
    DownloadSeg,
    UploadInit,
    UploadSeg,
}

/// An SDO client for one server: one transfer at a time, sans-IO.
///
/// Start a transfer with [`download`](Self::download) or [`upload`](Self::upload), send what
/// [`poll_tx`](Self::poll_tx) returns, feed responses to [`on_response`](Self::on_response) and
/// call [`poll`](Self::poll) for the timeout. Every path ends in exactly one [`SdoOutcome`].
///
/// A response is taken only if it answers the request in flight: the matching command
/// specifier, the same index and sub-index for initiate responses and aborts, and the expected
/// toggle bit for segments. Anything else ([`SdoDiscard`]) is dropped without a reply, so a
/// late or duplicated answer can neither be taken for the next one nor abort it; a transfer
/// whose answer never comes ends in the timeout. Frames the client sends (requests and its own
/// aborts) go through a small queue, so an abort is never overwritten by the next request.
#[derive(Debug, Clone)]
pub struct SdoClient {
    node: NodeId,
    timeout: Duration,
    phase: Phase,
    index: u16,
    sub: u8,
    buf: [u8; SDO_BUF],
    len: usize,
    pos: usize,
    toggle: bool,
    expedited: bool,
    deadline: Option<Instant>,
    tx: heapless::Deque<Frame, CLIENT_TX>,
}

impl SdoClient {
    /// A client for server `node` with a per-message `timeout`.
    pub fn new(node: NodeId, timeout: Duration) -> Self {
        SdoClient {
            node,
            timeout,
            phase: Phase::Idle,
            index: 0,
            sub: 0,
            buf: [0; SDO_BUF],
            len: 0,
            pos: 0,
            toggle: false,
            expedited: false,
            deadline: None,
            tx: heapless::Deque::new(),
        }
    }

    /// True while a transfer is in progress.
    pub fn is_busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// The bytes of the last completed upload.
    pub fn data(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// Cancels any transfer without a message (the node was reset: it has forgotten the
    /// transfer). Frames already queued, such as an abort, are still sent.
    pub fn cancel(&mut self) {
        self.phase = Phase::Idle;
        self.deadline = None;
    }

    /// Starts writing `data` to `index:sub`: expedited up to 4 bytes unless `segmented`.
    pub fn download(&mut self, index: u16, sub: u8, data: &[u8], segmented: bool, now: Instant) -> Result<(), SdoBusy> {
        if self.is_busy() || data.len() > SDO_BUF || data.is_empty() {
            return Err(SdoBusy);
        }
        self.index = index;
        self.sub = sub;
        self.buf[..data.len()].copy_from_slice(data);
        self.len = data.len();
        self.pos = 0;
        self.toggle = false;
        self.expedited = data.len() <= 4 && !segmented;
        let kind = if self.expedited {
            let mut d = [0u8; 4];
            d[..data.len()].copy_from_slice(data);
            Initiate::Expedited { data: d, len: data.len() as u8 }
        } else {
            Initiate::Segmented { size: Some(data.len() as u32) }
        };
        self.phase = Phase::DownloadInit;
        self.send(SdoRequest::InitiateDownload { index, sub, kind }, now);
        Ok(())
    }

    /// Starts reading `index:sub`.
    pub fn upload(&mut self, index: u16, sub: u8, now: Instant) -> Result<(), SdoBusy> {
        if self.is_busy() {
            return Err(SdoBusy);
        }
        self.index = index;
        self.sub = sub;
        self.len = 0;
        self.toggle = false;
        self.phase = Phase::UploadInit;
        self.send(SdoRequest::InitiateUpload { index, sub }, now);
        Ok(())
    }

    fn queue(&mut self, f: Frame) {
        if self.tx.is_full() {
            // Only reachable if the owner never drains poll_tx: the oldest frame is stale.
            let _ = self.tx.pop_front();
        }
        let _ = self.tx.push_back(f);
    }

    fn send(&mut self, r: SdoRequest, now: Instant) {
        self.queue(r.encode(self.node));
        self.deadline = Some(now + self.timeout);
    }

    /// The next frame to send, if any (call until `None`).
    pub fn poll_tx(&mut self) -> Option<Frame> {
        self.tx.pop_front()
    }

    /// When the current transfer times out.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.deadline
    }

    fn abort(&mut self, code: AbortCode, by_server: bool) -> SdoOutcome {
        if !by_server {
            self.queue(SdoRequest::Abort { index: self.index, sub: self.sub, code }.encode(self.node));
        }
        self.phase = Phase::Idle;
        self.deadline = None;
        SdoOutcome::Aborted(SdoAbort { index: self.index, sub: self.sub, code, by_server })
    }

    /// Checks the timeout: aborts the transfer (telling the server) when no response came.
    pub fn poll(&mut self, now: Instant) -> Option<SdoOutcome> {
        match self.deadline {
            Some(t) if self.is_busy() && now >= t => Some(self.abort(AbortCode::TIMEOUT, false)),
            _ => None,
        }
    }

    fn next_download_segment(&mut self, now: Instant) {
        let n = (self.len - self.pos).min(7);
        let mut data = [0u8; 7];
        data[..n].copy_from_slice(&self.buf[self.pos..self.pos + n]);
        let last = self.pos + n == self.len;
        self.send(SdoRequest::DownloadSegment(Segment { toggle: self.toggle, data, len: n as u8, last }), now);
    }

    /// True if `r` answers the request in flight (CiA 301 7.2.4.3: the server echoes the
    /// multiplexer in initiate responses and aborts, and the toggle bit in segments).
    fn matches(&self, r: &SdoResponse) -> bool {
        let same = |i: u16, s: u8| i == self.index && s == self.sub;
        match (self.phase, r) {
            (Phase::Idle, _) => false,
            (_, SdoResponse::Abort { index, sub, .. }) => same(*index, *sub),
            (Phase::DownloadInit, SdoResponse::DownloadInitiated { index, sub }) => same(*index, *sub),
            (Phase::DownloadSeg, SdoResponse::DownloadSegmentAck { toggle }) => *toggle == self.toggle,
            (Phase::UploadInit, SdoResponse::UploadInitiated { index, sub, .. }) => same(*index, *sub),
            (Phase::UploadSeg, SdoResponse::UploadSegment(s)) => s.toggle == self.toggle,
            _ => false,
        }
    }

    /// Handles the payload of a `0x580 + node` frame: `Ok(Some(_))` when the transfer ended,
    /// `Ok(None)` when it goes on (the next request is queued), `Err` when the frame is not the
    /// answer to the request in flight and was dropped (see [`SdoDiscard`]).
    pub fn on_response(&mut self, payload: &[u8], now: Instant) -> Result<Option<SdoOutcome>, SdoDiscard> {
        let r = SdoResponse::decode(payload).map_err(SdoDiscard::Malformed)?;
        if !self.is_busy() {
            return Err(SdoDiscard::Idle);
        }
        if !self.matches(&r) {
            return Err(SdoDiscard::Mismatch { command: payload[0] });
        }
        Ok(Some(match r {
            SdoResponse::Abort { code, .. } => self.abort(code, true),
            SdoResponse::DownloadInitiated { .. } => {
                if self.expedited {
                    self.finish_download()
                } else {
                    self.phase = Phase::DownloadSeg;
                    self.next_download_segment(now);
                    return Ok(None);
                }
            }
            SdoResponse::DownloadSegmentAck { .. } => {
                self.pos += (self.len - self.pos).min(7);
                self.toggle = !self.toggle;
                if self.pos == self.len {
                    self.finish_download()
                } else {
                    self.next_download_segment(now);
                    return Ok(None);
                }
            }
            SdoResponse::UploadInitiated { kind, .. } => match kind {
                Initiate::Expedited { data, len } => {
                    let n = usize::from(len);
                    self.buf[..n].copy_from_slice(&data[..n]);
                    self.len = n;
                    self.finish_upload()
                }
                Initiate::Segmented { size } => {
                    if size.is_some_and(|s| s as usize > SDO_BUF) {
                        self.abort(AbortCode::OUT_OF_MEMORY, false)
                    } else {
                        self.phase = Phase::UploadSeg;
                        self.send(SdoRequest::UploadSegment { toggle: self.toggle }, now);
                        return Ok(None);
                    }
                }
            },
            SdoResponse::UploadSegment(s) => {
                let n = usize::from(s.len);
                if self.len + n > SDO_BUF {
                    self.abort(AbortCode::OUT_OF_MEMORY, false)
                } else {
                    self.buf[self.len..self.len + n].copy_from_slice(&s.data[..n]);
                    self.len += n;
                    self.toggle = !self.toggle;
                    if s.last {
                        self.finish_upload()
                    } else {
                        self.send(SdoRequest::UploadSegment { toggle: self.toggle }, now);
                        return Ok(None);
                    }
                }
            }
        }))
    }

    fn finish_download(&mut self) -> SdoOutcome {
        self.phase = Phase::Idle;
        self.deadline = None;
        SdoOutcome::Downloaded { index: self.index, sub: self.sub }
    }

    fn finish_upload(&mut self) -> SdoOutcome {
        self.phase = Phase::Idle;
        self.deadline = None;
        SdoOutcome::Uploaded { index: self.index, sub: self.sub, len: self.len }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn arb_initiate() -> impl Strategy<Value = Initiate> {
        prop_oneof![
            (any::<[u8; 4]>(), 1u8..=4).prop_map(|(mut data, len)| {
                for b in &mut data[usize::from(len)..] {
                    *b = 0;
                }
                Initiate::Expedited { data, len }
            }),
            proptest::option::of(any::<u32>()).prop_map(|size| Initiate::Segmented { size }),
        ]
    }

    fn arb_segment() -> impl Strategy<Value = Segment> {
        (any::<bool>(), any::<[u8; 7]>(), 0u8..=7, any::<bool>()).prop_map(|(toggle, mut data, len, last)| {
            for b in &mut data[usize::from(len)..] {
                *b = 0;
            }
            Segment { toggle, data, len, last }
        })
    }

    fn arb_request() -> impl Strategy<Value = SdoRequest> {
        prop_oneof![
            (any::<u16>(), any::<u8>(), arb_initiate()).prop_map(|(index, sub, kind)| SdoRequest::InitiateDownload { index, sub, kind }),
            arb_segment().prop_map(SdoRequest::DownloadSegment),
            (any::<u16>(), any::<u8>()).prop_map(|(index, sub)| SdoRequest::InitiateUpload { index, sub }),
            any::<bool>().prop_map(|toggle| SdoRequest::UploadSegment { toggle }),
            (any::<u16>(), any::<u8>(), any::<u32>()).prop_map(|(index, sub, c)| SdoRequest::Abort { index, sub, code: AbortCode(c) }),
        ]
    }

    fn arb_response() -> impl Strategy<Value = SdoResponse> {
        prop_oneof![
            (any::<u16>(), any::<u8>()).prop_map(|(index, sub)| SdoResponse::DownloadInitiated { index, sub }),
            any::<bool>().prop_map(|toggle| SdoResponse::DownloadSegmentAck { toggle }),
            (any::<u16>(), any::<u8>(), arb_initiate()).prop_map(|(index, sub, kind)| SdoResponse::UploadInitiated { index, sub, kind }),
            arb_segment().prop_map(SdoResponse::UploadSegment),
            (any::<u16>(), any::<u8>(), any::<u32>()).prop_map(|(index, sub, c)| SdoResponse::Abort { index, sub, code: AbortCode(c) }),
        ]
    }

    proptest! {
        #[test]
        fn request_roundtrip(r in arb_request(), node in 1u8..=127) {
            let f = r.encode(node);
            prop_assert_eq!(f.id, 0x600 + u32::from(node));
            prop_assert_eq!(SdoRequest::decode(f.data()), Ok(r));
        }

        #[test]
        fn response_roundtrip(r in arb_response(), node in 1u8..=127) {
            let f = r.encode(node);
            prop_assert_eq!(f.id, 0x580 + u32::from(node));
            prop_assert_eq!(SdoResponse::decode(f.data()), Ok(r));
        }

        #[test]
        fn arbitrary_bytes_never_panic_the_parsers_or_the_client(
            msgs in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..=9), 0..12),
            upload: bool,
        ) {
            let t0 = Instant::now();
            let mut c = SdoClient::new(5, Duration::from_millis(50));
            if upload { c.upload(0x1008, 0, t0).unwrap(); } else { c.download(0x2000, 0, &[1; 20], false, t0).unwrap(); }
            for m in &msgs {
                let _ = SdoRequest::decode(m);
                let _ = SdoResponse::decode(m);
                let _ = c.on_response(m, t0);
                let _ = c.poll_tx();
            }
        }
    }

    /// A server answering from one buffer, enough to exercise the client's state machine.
    fn serve(req: &Frame, store: &mut Vec<u8>, seg: &mut usize) -> Frame {
        match SdoRequest::decode(req.data()).unwrap() {
            SdoRequest::InitiateUpload { index, sub } => {
                *seg = 0;
                SdoResponse::UploadInitiated { index, sub, kind: Initiate::Segmented { size: Some(store.len() as u32) } }.encode(5)
            }
            SdoRequest::UploadSegment { toggle } => {
                let n = (store.len() - *seg).min(7);
                let mut data = [0; 7];
                data[..n].copy_from_slice(&store[*seg..*seg + n]);
                *seg += n;
                SdoResponse::UploadSegment(Segment { toggle, data, len: n as u8, last: *seg == store.len() }).encode(5)
            }
            SdoRequest::InitiateDownload { index, sub, .. } => {
                store.clear();
                SdoResponse::DownloadInitiated { index, sub }.encode(5)
            }
            SdoRequest::DownloadSegment(s) => {
                store.extend_from_slice(&s.data[..usize::from(s.len)]);
                SdoResponse::DownloadSegmentAck { toggle: s.toggle }.encode(5)
            }
            SdoRequest::Abort { .. } => panic!("unexpected abort"),
        }
    }

    #[test]
    fn segmented_download_then_upload() {
        let t0 = Instant::now();
        let mut c = SdoClient::new(5, Duration::from_millis(50));
        let (mut store, mut seg) = (Vec::new(), 0);
        let payload: Vec<u8> = (0..23).collect();
        c.download(0x2000, 0, &payload, false, t0).unwrap();
        let outcome = loop {
            let req = c.poll_tx().expect("a request");
            if let Some(o) = c.on_response(serve(&req, &mut store, &mut seg).data(), t0).unwrap() {
                break o;
            }
        };
        assert_eq!(outcome, SdoOutcome::Downloaded { index: 0x2000, sub: 0 });
        assert_eq!(store, payload);
        c.upload(0x2000, 0, t0).unwrap();
        let outcome = loop {
            let req = c.poll_tx().expect("a request");
            if let Some(o) = c.on_response(serve(&req, &mut store, &mut seg).data(), t0).unwrap() {
                break o;
            }
        };
        assert_eq!(outcome, SdoOutcome::Uploaded { index: 0x2000, sub: 0, len: 23 });
        assert_eq!(c.data(), &payload[..]);
    }

    #[test]
    fn expedited_abort_and_timeout() {
        let t0 = Instant::now();
        let mut c = SdoClient::new(5, Duration::from_millis(50));
        c.upload(0x6064, 0, t0).unwrap();
        assert_eq!(c.upload(0x6064, 0, t0), Err(SdoBusy));
        let _ = c.poll_tx();
        let r = SdoResponse::UploadInitiated { index: 0x6064, sub: 0, kind: Initiate::Expedited { data: [1, 2, 3, 4], len: 4 } };
        assert_eq!(c.on_response(r.encode(5).data(), t0).unwrap(), Some(SdoOutcome::Uploaded { index: 0x6064, sub: 0, len: 4 }));
        assert_eq!(c.data(), &[1, 2, 3, 4]);

        c.download(0x6041, 0, &[0, 0], false, t0).unwrap();
        let _ = c.poll_tx();
        let r = SdoResponse::Abort { index: 0x6041, sub: 0, code: AbortCode::READ_ONLY };
        let o = c.on_response(r.encode(5).data(), t0).unwrap().unwrap();
        let SdoOutcome::Aborted(a) = o else { panic!("{o:?}") };
        assert_eq!(a.to_string(), "server abort accessing 0x6041sub0: 0x06010002 (attempt to write a read-only object)");
        assert_eq!(c.poll_tx(), None, "no abort is sent back for a server abort");

        c.upload(0x1000, 0, t0).unwrap();
        let _ = c.poll_tx();
        assert_eq!(c.poll(t0 + Duration::from_millis(49)), None);
        let o = c.poll(t0 + Duration::from_millis(50)).unwrap();
        assert!(matches!(o, SdoOutcome::Aborted(SdoAbort { code: AbortCode::TIMEOUT, by_server: false, .. })));
        let abort = SdoRequest::decode(c.poll_tx().unwrap().data()).unwrap();
        assert!(matches!(abort, SdoRequest::Abort { index: 0x1000, code: AbortCode::TIMEOUT, .. }));
        assert!(!c.is_busy());
    }

    #[test]
    fn a_segment_with_the_wrong_toggle_is_discarded_not_aborted() {
        let t0 = Instant::now();
        let mut c = SdoClient::new(5, Duration::from_millis(50));
        c.upload(0x1008, 0, t0).unwrap();
        let _ = c.poll_tx();
        let r = SdoResponse::UploadInitiated { index: 0x1008, sub: 0, kind: Initiate::Segmented { size: None } };
        assert_eq!(c.on_response(r.encode(5).data(), t0).unwrap(), None);
        let _ = c.poll_tx();
        // A duplicate of a segment the client already took (toggle 1 while 0 is expected).
        let s = SdoResponse::UploadSegment(Segment { toggle: true, data: [0; 7], len: 7, last: false });
        assert_eq!(c.on_response(s.encode(5).data(), t0), Err(SdoDiscard::Mismatch { command: 0x10 }));
        assert_eq!(c.poll_tx(), None, "nothing is sent for a discarded frame");
        assert!(c.is_busy());
        let s = SdoResponse::UploadSegment(Segment { toggle: false, data: *b"abc\0\0\0\0", len: 3, last: true });
        assert_eq!(c.on_response(s.encode(5).data(), t0).unwrap(), Some(SdoOutcome::Uploaded { index: 0x1008, sub: 0, len: 3 }));
        assert_eq!(c.data(), b"abc");
    }

    /// A field drive's sequence: the same upload sent twice, the server answers both. The second
    /// answer arrives while the next request is in flight and must not be taken for it.
    #[test]
    fn a_stale_answer_is_neither_taken_nor_answered() {
        let t0 = Instant::now();
        let mut c = SdoClient::new(5, Duration::from_millis(50));
        let dt =
            |v: u32| SdoResponse::UploadInitiated { index: 0x1000, sub: 0, kind: Initiate::Expedited { data: v.to_le_bytes(), len: 4 } };
        c.upload(0x1000, 0, t0).unwrap();
        let _ = c.poll_tx();
        assert_eq!(c.on_response(dt(0x20192).encode(5).data(), t0).unwrap(), Some(SdoOutcome::Uploaded { index: 0x1000, sub: 0, len: 4 }));
        c.upload(0x1018, 1, t0).unwrap();
        let _ = c.poll_tx();
        // Stale: the answer to the earlier request, a duplicate, a download response, an abort
        // of another object, a truncated frame.
        for f in [
            dt(0x20192).encode(5),
            SdoResponse::DownloadInitiated { index: 0x1018, sub: 1 }.encode(5),
            SdoResponse::Abort { index: 0x1017, sub: 0, code: AbortCode::COMMAND }.encode(5),
            SdoResponse::UploadInitiated { index: 0x1018, sub: 2, kind: Initiate::Expedited { data: [0; 4], len: 4 } }.encode(5),
        ] {
            assert!(matches!(c.on_response(f.data(), t0), Err(SdoDiscard::Mismatch { .. })), "{f:?}");
        }
        assert!(matches!(c.on_response(&[0x43, 0x18], t0), Err(SdoDiscard::Malformed(_))));
        assert_eq!(c.poll_tx(), None, "no abort is sent for a stale answer");
        let v = SdoResponse::UploadInitiated { index: 0x1018, sub: 1, kind: Initiate::Expedited { data: 0xACEu32.to_le_bytes(), len: 4 } };
        assert_eq!(c.on_response(v.encode(5).data(), t0).unwrap(), Some(SdoOutcome::Uploaded { index: 0x1018, sub: 1, len: 4 }));
        assert_eq!(c.data(), &0xACEu32.to_le_bytes());
        assert_eq!(c.on_response(v.encode(5).data(), t0), Err(SdoDiscard::Idle));
    }

    #[test]
    fn a_timeout_abort_is_sent_before_the_retry() {
        let t0 = Instant::now();
        let mut c = SdoClient::new(5, Duration::from_millis(50));
        c.download(0x1017, 0, &[100, 0], false, t0).unwrap();
        let _ = c.poll_tx();
        let t1 = t0 + Duration::from_millis(50);
        assert!(matches!(c.poll(t1), Some(SdoOutcome::Aborted(SdoAbort { code: AbortCode::TIMEOUT, .. }))));
        // The owner retries at once, before draining poll_tx: the abort must still go out first.
        c.download(0x1017, 0, &[100, 0], false, t1).unwrap();
        let first = SdoRequest::decode(c.poll_tx().unwrap().data()).unwrap();
        assert_eq!(first, SdoRequest::Abort { index: 0x1017, sub: 0, code: AbortCode::TIMEOUT });
        let second = SdoRequest::decode(c.poll_tx().unwrap().data()).unwrap();
        assert!(matches!(second, SdoRequest::InitiateDownload { index: 0x1017, sub: 0, .. }));
        assert_eq!(c.poll_tx(), None);
    }
}
