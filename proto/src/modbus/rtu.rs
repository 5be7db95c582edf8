//! Modbus RTU framing, sans-IO: requests and responses to and from bytes, CRC, frame lengths and
//! the inter-frame timing of the serial line spec. No port is touched here.
//!
//! Only the two functions a load cell needs are spoken: read holding registers (0x03) and read
//! input registers (0x04). Any other function code decodes to [`RtuError::UnsupportedFunction`]
//! (a server answers it with exception 01, illegal function).
//!
//! ```text
//! Request, 8 bytes (Modbus Application Protocol V1.1b3, 6.3 and 6.4):
//!   off  size  field
//!   0    1     unit id (slave address) 1..=247, 0 = broadcast (not used for reads)
//!   1    1     function code: 0x03 holding registers, 0x04 input registers
//!   2    2     starting address, big-endian
//!   4    2     quantity of registers 1..=125, big-endian
//!   6    2     CRC-16, low byte first
//!
//! Normal response, 5 + 2N bytes:
//!   0    1     unit id (echoed)
//!   1    1     function code (echoed)
//!   2    1     byte count = 2N
//!   3    2N    register values, each big-endian
//!   3+2N 2     CRC-16, low byte first
//!
//! Exception response, 5 bytes:
//!   0    1     unit id
//!   1    1     function code | 0x80
//!   2    1     exception code (01 illegal function, 02 illegal data address, ...)
//!   3    2     CRC-16, low byte first
//! ```

use super::crc::crc16;
use std::fmt;
use std::time::Duration;

/// Largest RTU frame (ADU): 1 address + 253 PDU + 2 CRC (Modbus over Serial Line 2.5.1.1).
pub const MAX_FRAME: usize = 256;
/// Most registers one read may ask for: 125 x 2 bytes fill the 250-byte data field.
pub const MAX_REGISTERS: usize = 125;
/// Length of a read request frame.
pub const REQUEST_LEN: usize = 8;
/// Length of an exception response frame.
pub const EXCEPTION_LEN: usize = 5;

/// A register-reading function code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Function {
    /// 0x03, read holding registers.
    ReadHoldingRegisters,
    /// 0x04, read input registers.
    ReadInputRegisters,
}

impl Function {
    /// The function code byte.
    pub fn code(self) -> u8 {
        match self {
            Function::ReadHoldingRegisters => 0x03,
            Function::ReadInputRegisters => 0x04,
        }
    }

    /// The function of a code byte, if it is one we speak.
    pub fn from_code(code: u8) -> Option<Function> {
        match code {
            0x03 => Some(Function::ReadHoldingRegisters),
            0x04 => Some(Function::ReadInputRegisters),
            _ => None,
        }
    }
}

/// A read-registers request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Request {
    /// Unit id of the addressed device.
    pub unit: u8,
    /// Which register table.
    pub function: Function,
    /// First register address, 0-based as on the wire.
    pub address: u16,
    /// Number of registers, 1..=125.
    pub quantity: u16,
}

/// A Modbus exception code (Modbus Application Protocol V1.1b3, 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExceptionCode {
    /// 01: the function code is not supported by the device.
    IllegalFunction,
    /// 02: the register range is not in the device.
    IllegalDataAddress,
    /// 03: a value in the request is not allowed (e.g. quantity out of range).
    IllegalDataValue,
    /// 04: the device failed while performing the action.
    ServerDeviceFailure,
    /// 05: accepted, will take long; poll again later.
    Acknowledge,
    /// 06: busy with a long command; retry later.
    ServerDeviceBusy,
    /// 08: memory parity error.
    MemoryParityError,
    /// 0A: gateway could not route the request.
    GatewayPathUnavailable,
    /// 0B: gateway got no answer from the target device.
    GatewayTargetFailedToRespond,
    /// Any other code.
    Other(u8),
}

impl ExceptionCode {
    /// The code of a byte.
    pub fn from_code(code: u8) -> ExceptionCode {
        use ExceptionCode::*;
        match code {
            0x01 => IllegalFunction,
            0x02 => IllegalDataAddress,
            0x03 => IllegalDataValue,
            0x04 => ServerDeviceFailure,
            0x05 => Acknowledge,
            0x06 => ServerDeviceBusy,
            0x08 => MemoryParityError,
            0x0A => GatewayPathUnavailable,
            0x0B => GatewayTargetFailedToRespond,
            c => Other(c),
        }
    }

    /// The code byte.
    pub fn code(self) -> u8 {
        use ExceptionCode::*;
        match self {
            IllegalFunction => 0x01,
            IllegalDataAddress => 0x02,
            IllegalDataValue => 0x03,
            ServerDeviceFailure => 0x04,
            Acknowledge => 0x05,
            ServerDeviceBusy => 0x06,
            MemoryParityError => 0x08,
            GatewayPathUnavailable => 0x0A,
            GatewayTargetFailedToRespond => 0x0B,
            Other(c) => c,
        }
    }

    /// The spec's name, for people.
    pub fn name(self) -> &'static str {
        use ExceptionCode::*;
        match self {
            IllegalFunction => "illegal function",
            IllegalDataAddress => "illegal data address",
            IllegalDataValue => "illegal data value",
            ServerDeviceFailure => "server device failure",
            Acknowledge => "acknowledge",
            ServerDeviceBusy => "server device busy",
            MemoryParityError => "memory parity error",
            GatewayPathUnavailable => "gateway path unavailable",
            GatewayTargetFailedToRespond => "gateway target device failed to respond",
            Other(_) => "unknown exception",
        }
    }

    /// Whether asking again later can succeed (busy / acknowledge / gateway), as opposed to a
    /// request the device will always refuse.
    pub fn is_transient(self) -> bool {
        use ExceptionCode::*;
        matches!(self, Acknowledge | ServerDeviceBusy | GatewayTargetFailedToRespond | ServerDeviceFailure)
    }
}

impl fmt::Display for ExceptionCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exception {:02X} ({})", self.code(), self.name())
    }
}

/// Register values of a normal read response. `Copy`, fixed size.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Registers {
    /// Unit id of the answering device.
    pub unit: u8,
    /// The function answered.
    pub function: Function,
    len: u8,
    values: [u16; MAX_REGISTERS],
}

impl Registers {
    /// A response carrying `values` (at most 125; more are cut).
    pub fn new(unit: u8, function: Function, values: &[u16]) -> Registers {
        let n = values.len().min(MAX_REGISTERS);
        let mut v = [0u16; MAX_REGISTERS];
        v[..n].copy_from_slice(&values[..n]);
        Registers { unit, function, len: n as u8, values: v }
    }

    /// The register values.
    pub fn values(&self) -> &[u16] {
        &self.values[..usize::from(self.len)]
    }
}

impl fmt::Debug for Registers {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Registers").field("unit", &self.unit).field("function", &self.function).field("values", &self.values()).finish()
    }
}

/// A decoded response frame.
// Fixed size on purpose (no heap on the I/O path): the 250-byte register array is the point.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response {
    /// Register values.
    Registers(Registers),
    /// The device refused the request.
    Exception {
        /// Unit id of the answering device.
        unit: u8,
        /// The function code of the refused request (without the 0x80 flag).
        function: u8,
        /// Why.
        code: ExceptionCode,
    },
}

impl Response {
    /// Unit id of the answering device.
    pub fn unit(&self) -> u8 {
        match self {
            Response::Registers(r) => r.unit,
            Response::Exception { unit, .. } => *unit,
        }
    }
}

/// Why bytes are not a valid frame. `Copy`; no allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RtuError {
    /// Fewer bytes than the smallest frame of this kind.
    TooShort {
        /// Bytes present.
        len: usize,
    },
    /// More bytes than [`MAX_FRAME`].
    TooLong {
        /// Bytes present.
        len: usize,
    },
    /// The CRC over the frame does not match its last two bytes.
    Crc {
        /// CRC computed over the frame.
        computed: u16,
        /// CRC carried by the frame.
        received: u16,
    },
    /// A function code other than 0x03 / 0x04.
    UnsupportedFunction {
        /// The code byte.
        function: u8,
    },
    /// The frame length does not match what its header announces.
    Length {
        /// Length the header announces.
        expected: usize,
        /// Bytes present.
        len: usize,
    },
    /// A normal response whose byte count is odd or zero, or over 250.
    ByteCount {
        /// The byte count field.
        count: u8,
    },
    /// A request for 0 or more than 125 registers, or past address 65535.
    Quantity {
        /// The quantity field.
        quantity: u16,
    },
}

impl fmt::Display for RtuError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RtuError::TooShort { len } => write!(f, "frame too short ({len} bytes)"),
            RtuError::TooLong { len } => write!(f, "frame too long ({len} bytes, max {MAX_FRAME})"),
            RtuError::Crc { computed, received } => {
                write!(f, "CRC mismatch: computed {computed:04X}, frame carries {received:04X}")
            }
            RtuError::UnsupportedFunction { function } => write!(f, "unsupported function code {function:02X}"),
            RtuError::Length { expected, len } => write!(f, "frame of {len} bytes, header announces {expected}"),
            RtuError::ByteCount { count } => write!(f, "invalid byte count {count}"),
            RtuError::Quantity { quantity } => write!(f, "invalid register quantity {quantity}"),
        }
    }
}

impl std::error::Error for RtuError {}

fn put_crc(buf: &mut [u8; MAX_FRAME], len: usize) -> usize {
    let crc = crc16(&buf[..len]);
    buf[len..len + 2].copy_from_slice(&crc.to_le_bytes());
    len + 2
}

/// Checks and strips the CRC: the frame without its last two bytes.
fn check_crc(frame: &[u8]) -> Result<&[u8], RtuError> {
    if frame.len() > MAX_FRAME {
        return Err(RtuError::TooLong { len: frame.len() });
    }
    if frame.len() < 4 {
        return Err(RtuError::TooShort { len: frame.len() });
    }
    let (body, crc) = frame.split_at(frame.len() - 2);
    let received = u16::from_le_bytes([crc[0], crc[1]]);
    let computed = crc16(body);
    if computed != received {
        return Err(RtuError::Crc { computed, received });
    }
    Ok(body)
}

/// Writes the request frame into `buf`; returns its length ([`REQUEST_LEN`]).
pub fn encode(req: &Request, buf: &mut [u8; MAX_FRAME]) -> usize {
    buf[0] = req.unit;
    buf[1] = req.function.code();
    buf[2..4].copy_from_slice(&req.address.to_be_bytes());
    buf[4..6].copy_from_slice(&req.quantity.to_be_bytes());
    put_crc(buf, 6)
}

/// Decodes a response frame (the master's side).
pub fn decode(frame: &[u8]) -> Result<Response, RtuError> {
    let body = check_crc(frame)?;
    // Every response has address, function and at least one byte (an exception's code, a
    // register response's byte count) before its CRC: a 4-byte frame whose last two bytes are
    // the CRC of the first two would pass `check_crc`.
    if body.len() < 3 {
        return Err(RtuError::TooShort { len: frame.len() });
    }
    let (unit, fc) = (body[0], body[1]);
    if fc & 0x80 != 0 {
        if body.len() != 3 {
            return Err(RtuError::Length { expected: EXCEPTION_LEN, len: frame.len() });
        }
        return Ok(Response::Exception { unit, function: fc & 0x7F, code: ExceptionCode::from_code(body[2]) });
    }
    let function = Function::from_code(fc).ok_or(RtuError::UnsupportedFunction { function: fc })?;
    let count = body[2];
    if count == 0 || count % 2 != 0 || usize::from(count) > 2 * MAX_REGISTERS {
        return Err(RtuError::ByteCount { count });
    }
    let expected = 5 + usize::from(count);
    if frame.len() != expected {
        return Err(RtuError::Length { expected, len: frame.len() });
    }
    let mut values = [0u16; MAX_REGISTERS];
    for (v, pair) in values.iter_mut().zip(body[3..].chunks_exact(2)) {
        *v = u16::from_be_bytes([pair[0], pair[1]]);
    }
    Ok(Response::Registers(Registers { unit, function, len: count / 2, values }))
}

/// Decodes a request frame (the server's side).
pub fn decode_request(frame: &[u8]) -> Result<Request, RtuError> {
    let body = check_crc(frame)?;
    let fc = body[1];
    let function = Function::from_code(fc).ok_or(RtuError::UnsupportedFunction { function: fc })?;
    if frame.len() != REQUEST_LEN {
        return Err(RtuError::Length { expected: REQUEST_LEN, len: frame.len() });
    }
    let address = u16::from_be_bytes([body[2], body[3]]);
    let quantity = u16::from_be_bytes([body[4], body[5]]);
    if quantity == 0 || usize::from(quantity) > MAX_REGISTERS {
        return Err(RtuError::Quantity { quantity });
    }
    Ok(Request { unit: body[0], function, address, quantity })
}

/// Writes a response frame into `buf`; returns its length.
pub fn encode_response(resp: &Response, buf: &mut [u8; MAX_FRAME]) -> usize {
    match resp {
        Response::Registers(r) => {
            let v = r.values();
            buf[0] = r.unit;
            buf[1] = r.function.code();
            buf[2] = (2 * v.len()) as u8;
            for (i, x) in v.iter().enumerate() {
                buf[3 + 2 * i..5 + 2 * i].copy_from_slice(&x.to_be_bytes());
            }
            put_crc(buf, 3 + 2 * v.len())
        }
        Response::Exception { unit, function, code } => {
            buf[0] = *unit;
            buf[1] = function | 0x80;
            buf[2] = code.code();
            put_crc(buf, 3)
        }
    }
}

/// Length of the response frame that starts with `prefix`, once its header says so: `None` while
/// fewer bytes than the header are present or when the function code is not one we speak (then
/// only the line going silent ends the frame).
pub fn response_len(prefix: &[u8]) -> Option<usize> {
    match prefix {
        [_, fc, ..] if fc & 0x80 != 0 => Some(EXCEPTION_LEN),
        [_, 0x03 | 0x04, count, ..] => Some(5 + usize::from(*count)),
        _ => None,
    }
}

/// Where a plausible response from `unit` to `function` starts in `buf` and how long it is: the
/// first offset whose header matches, whose announced length is present and whose CRC checks.
/// Lets the master find its answer behind line noise without waiting for silence.
pub fn find_response(buf: &[u8], unit: u8, function: Function) -> Option<(usize, usize)> {
    let fc = function.code();
    (0..buf.len().saturating_sub(1)).find_map(|i| {
        let rest = &buf[i..];
        if rest[0] != unit || (rest[1] != fc && rest[1] != fc | 0x80) {
            return None;
        }
        let n = response_len(rest)?;
        (n <= rest.len() && n <= MAX_FRAME && crc16(&rest[..n]) == 0).then_some((i, n))
    })
}

/// Serial character and inter-frame times of Modbus over Serial Line V1.02, 2.5.1.1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// Time of one character on the wire.
    pub char_time: Duration,
    /// t1.5: longest gap allowed inside a frame.
    pub t15: Duration,
    /// t3.5: least silence between frames.
    pub t35: Duration,
}

impl Timing {
    /// Times for `baud` with `bits_per_char` bits per character (start + data + parity + stop;
    /// the spec counts 11 for RTU, 10 for the common 8N1). Above 19200 baud the spec fixes
    /// t1.5 = 750 µs and t3.5 = 1.75 ms, since shorter gaps are hard to time on a PC.
    pub fn new(baud: u32, bits_per_char: u32) -> Timing {
        let baud = u64::from(baud.max(1));
        let char_ns = u64::from(bits_per_char) * 1_000_000_000 / baud;
        let char_time = Duration::from_nanos(char_ns);
        if baud > 19_200 {
            Timing { char_time, t15: Duration::from_micros(750), t35: Duration::from_micros(1750) }
        } else {
            Timing { char_time, t15: Duration::from_nanos(char_ns * 3 / 2), t35: Duration::from_nanos(char_ns * 7 / 2) }
        }
    }

    /// Time on the wire of a frame of `len` bytes.
    pub fn frame_time(&self, len: usize) -> Duration {
        self.char_time * len as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn request_known_frame() {
        let req = Request { unit: 1, function: Function::ReadHoldingRegisters, address: 0, quantity: 10 };
        let mut buf = [0u8; MAX_FRAME];
        let n = encode(&req, &mut buf);
        assert_eq!(&buf[..n], &[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD]);
        assert_eq!(decode_request(&buf[..n]), Ok(req));
    }

    #[test]
    fn response_from_pymodbus_trace() {
        // Bytes a pymodbus 3.16 server sent for input registers 0..4 of unit 1 holding
        // INT32 -7000 and FLOAT32 12.25.
        let f = [0x01, 0x04, 0x08, 0xFF, 0xFF, 0xE4, 0xA8, 0x41, 0x44, 0x00, 0x00, 0x46, 0x13];
        let Response::Registers(r) = decode(&f).unwrap() else { panic!() };
        assert_eq!(r.values(), &[0xFFFF, 0xE4A8, 0x4144, 0x0000]);
        assert_eq!(response_len(&f[..3]), Some(f.len()));
    }

    #[test]
    fn exception_decodes_with_name() {
        let mut buf = [0u8; MAX_FRAME];
        let e = Response::Exception { unit: 7, function: 0x04, code: ExceptionCode::IllegalDataAddress };
        let n = encode_response(&e, &mut buf);
        assert_eq!(n, EXCEPTION_LEN);
        assert_eq!(buf[1], 0x84);
        assert_eq!(decode(&buf[..n]), Ok(e));
        assert_eq!(ExceptionCode::from_code(2).to_string(), "exception 02 (illegal data address)");
    }

    #[test]
    fn errors() {
        assert_eq!(decode(&[1, 3]), Err(RtuError::TooShort { len: 2 }));
        // Address and function with their own CRC: four bytes that pass the CRC check.
        assert_eq!(decode(&[0xFF, 0x03, 0x00, 0x41]), Err(RtuError::TooShort { len: 4 }));
        let mut f = [0x01, 0x03, 0x02, 0x00, 0x2A, 0, 0];
        let crc = crc16(&f[..5]).to_le_bytes();
        f[5..].copy_from_slice(&crc);
        assert!(decode(&f).is_ok());
        f[3] ^= 0x10;
        assert!(matches!(decode(&f), Err(RtuError::Crc { .. })));
        let mut buf = [0u8; MAX_FRAME];
        buf[..4].copy_from_slice(&[1, 0x10, 0, 0]);
        let n = put_crc(&mut buf, 4);
        assert_eq!(decode(&buf[..n]), Err(RtuError::UnsupportedFunction { function: 0x10 }));
    }

    #[test]
    fn timing_per_spec() {
        let t = Timing::new(9600, 11);
        assert_eq!(t.t35.as_micros(), 4010); // 3.5 * 11 / 9600 s
        let t = Timing::new(115_200, 10);
        assert_eq!(t.t35, Duration::from_micros(1750));
        assert_eq!(t.t15, Duration::from_micros(750));
        assert_eq!(t.frame_time(8).as_micros(), 694);
    }

    #[test]
    fn finds_response_behind_noise() {
        let mut buf = [0u8; MAX_FRAME];
        let r = Response::Registers(Registers::new(3, Function::ReadInputRegisters, &[1, 2]));
        let n = encode_response(&r, &mut buf);
        let mut line = vec![0x03, 0x04, 0xFF, 0x55];
        line.extend_from_slice(&buf[..n]);
        assert_eq!(find_response(&line, 3, Function::ReadInputRegisters), Some((4, n)));
        assert_eq!(find_response(&line, 4, Function::ReadInputRegisters), None);
    }

    fn function() -> impl Strategy<Value = Function> {
        prop_oneof![Just(Function::ReadHoldingRegisters), Just(Function::ReadInputRegisters)]
    }

    proptest! {
        #[test]
        fn request_round_trip(unit in any::<u8>(), f in function(), address in any::<u16>(), quantity in 1u16..=125) {
            let req = Request { unit, function: f, address, quantity };
            let mut buf = [0u8; MAX_FRAME];
            let n = encode(&req, &mut buf);
            prop_assert_eq!(n, REQUEST_LEN);
            prop_assert_eq!(decode_request(&buf[..n]), Ok(req));
        }

        #[test]
        fn response_round_trip(unit in any::<u8>(), f in function(), values in proptest::collection::vec(any::<u16>(), 1..=125)) {
            let resp = Response::Registers(Registers::new(unit, f, &values));
            let mut buf = [0u8; MAX_FRAME];
            let n = encode_response(&resp, &mut buf);
            prop_assert_eq!(n, 5 + 2 * values.len());
            prop_assert_eq!(response_len(&buf[..3]), Some(n));
            prop_assert_eq!(decode(&buf[..n]), Ok(resp));
            prop_assert_eq!(find_response(&buf[..n], unit, f), Some((0, n)));
        }

        #[test]
        fn exception_round_trip(unit in any::<u8>(), function in 1u8..0x80, code in any::<u8>()) {
            let resp = Response::Exception { unit, function, code: ExceptionCode::from_code(code) };
            let mut buf = [0u8; MAX_FRAME];
            let n = encode_response(&resp, &mut buf);
            prop_assert_eq!(decode(&buf[..n]), Ok(resp));
            prop_assert_eq!(ExceptionCode::from_code(code).code(), code);
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = decode(&bytes);
            let _ = decode_request(&bytes);
            let _ = response_len(&bytes);
            let _ = find_response(&bytes, bytes.first().copied().unwrap_or(1), Function::ReadInputRegisters);
        }

        #[test]
        fn single_bit_flip_is_caught(values in proptest::collection::vec(any::<u16>(), 1..=8), bit in 0usize..(8 * 21)) {
            let resp = Response::Registers(Registers::new(1, Function::ReadInputRegisters, &values));
            let mut buf = [0u8; MAX_FRAME];
            let n = encode_response(&resp, &mut buf);
            let bit = bit % (8 * n);
            buf[bit / 8] ^= 1 << (bit % 8);
            prop_assert_ne!(decode(&buf[..n]), Ok(resp));
        }
    }
}
