//! The Modbus RTU master's transaction: request out, response in, with the inter-frame silence,
//! the response timeout, retries, and every failure counted by kind.
//!
//! It runs on the load-cell I/O thread ([`crate::loadcell`]), never on the real-time loop: it
//! blocks on the link. The framing underneath is the sans-IO [`taut_proto::modbus::rtu`].
//!
//! How the end of a response is found: the serial-line spec delimits frames by 3.5 character
//! times of silence, which USB adapters (1-16 ms latency) cannot keep. So the master reads the
//! length a response announces in its header (5 + byte count, or 5 for an exception) and stops
//! as soon as a frame with a good CRC from the addressed unit is in the buffer, skipping line
//! noise in front of it. Silence only ends a reception that does not start like our answer.

use crate::clock::{Clock, WallClock};
use std::fmt;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};
use taut_proto::modbus::link::{LinkError, SerialLink};
use taut_proto::modbus::rtu::{self, ExceptionCode, Registers, Request, Response, RtuError, Timing, MAX_FRAME};

/// Why one transaction failed. `Copy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransactionError {
    /// No byte came back within the response timeout.
    Timeout {
        /// Unit id addressed.
        unit: u8,
    },
    /// A frame that starts like the answer but whose CRC is wrong.
    Crc {
        /// Unit id addressed.
        unit: u8,
    },
    /// Bytes that are not a valid answer to the request.
    Garbage {
        /// Unit id addressed.
        unit: u8,
        /// Bytes received.
        len: usize,
        /// What was wrong with them, when a frame could be cut out.
        error: Option<RtuError>,
    },
    /// The device answered with an exception.
    Exception {
        /// Unit id addressed.
        unit: u8,
        /// The device's reason.
        code: ExceptionCode,
    },
    /// The port failed; the caller must reopen it.
    Link(LinkError),
}

impl fmt::Display for TransactionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransactionError::Timeout { unit } => write!(f, "unit {unit}: no response (timeout)"),
            TransactionError::Crc { unit } => write!(f, "unit {unit}: response with a bad CRC"),
            TransactionError::Garbage { unit, len, error: Some(e) } => write!(f, "unit {unit}: {len} bytes of garbage ({e})"),
            TransactionError::Garbage { unit, len, error: None } => write!(f, "unit {unit}: {len} bytes of garbage"),
            TransactionError::Exception { unit, code } => write!(f, "unit {unit}: {code}"),
            TransactionError::Link(e) => write!(f, "{e}"),
        }
    }
}

/// Kinds of events the load-cell bus counts; the first of each kind is logged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum LoadCellBusEvent {
    /// A response with a bad CRC.
    Crc,
    /// No response in time.
    Timeout,
    /// An exception response.
    Exception,
    /// Bytes that were no valid answer.
    Garbage,
    /// A retried transaction.
    Retry,
    /// A reading given up after all retries.
    Failed,
    /// The open port failed (USB unplug).
    LinkLost,
    /// The port could not be opened.
    OpenFailed,
    /// The port was opened again after it had been lost.
    Reconnect,
    /// The ring buffer to the real-time loop was full and a sample was dropped.
    Overflow,
    /// A reading that decoded to NaN / infinity.
    InvalidValue,
}

const EVENTS: usize = 11;

/// Counters of the load-cell bus events, shared between the I/O thread (writer) and whoever reports them.
///
/// Every counter is a statistic read on its own, so `Relaxed` is enough throughout: nothing else
/// is published through them.
#[derive(Debug, Default)]
pub struct Counters {
    ok: AtomicU64,
    events: [AtomicU64; EVENTS],
    logged: AtomicU32,
}

/// A copy of the counters at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CounterSnapshot {
    /// Successful transactions.
    pub ok: u64,
    /// Responses with a bad CRC.
    pub crc_errors: u64,
    /// Tries that got no answer.
    pub timeouts: u64,
    /// Exception responses.
    pub exceptions: u64,
    /// Receptions that were no valid answer.
    pub garbage: u64,
    /// Tries repeated after a failure.
    pub retries: u64,
    /// Readings given up after every try.
    pub failed: u64,
    /// Times the open port failed.
    pub links_lost: u64,
    /// Failed attempts to open the port.
    pub open_failures: u64,
    /// Times the port was opened again after a loss.
    pub reconnects: u64,
    /// Samples dropped because the ring buffer was full.
    pub overflows: u64,
    /// Readings that were NaN or infinite.
    pub invalid_values: u64,
}

impl Counters {
    /// Counts one successful transaction.
    pub fn ok(&self) {
        self.ok.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts an event; logs it on stderr if it is the first of its kind, saying that later ones
    /// are only counted. Called from the I/O thread only, where printing is fine.
    pub fn count(&self, event: LoadCellBusEvent, detail: fmt::Arguments<'_>) {
        self.events[event as usize].fetch_add(1, Ordering::Relaxed);
        let bit = 1u32 << (event as u32);
        if self.logged.fetch_or(bit, Ordering::Relaxed) & bit == 0 {
            eprintln!("taut load cells: {detail} (first {event:?} event; further ones are only counted)");
        }
    }

    /// Counts an event without logging it (one that is expected where it happens).
    pub fn count_quietly(&self, event: LoadCellBusEvent) {
        self.events[event as usize].fetch_add(1, Ordering::Relaxed);
    }

    /// Reads every counter.
    pub fn snapshot(&self) -> CounterSnapshot {
        let e = |k: LoadCellBusEvent| self.events[k as usize].load(Ordering::Relaxed);
        CounterSnapshot {
            ok: self.ok.load(Ordering::Relaxed),
            crc_errors: e(LoadCellBusEvent::Crc),
            timeouts: e(LoadCellBusEvent::Timeout),
            exceptions: e(LoadCellBusEvent::Exception),
            garbage: e(LoadCellBusEvent::Garbage),
            retries: e(LoadCellBusEvent::Retry),
            failed: e(LoadCellBusEvent::Failed),
            links_lost: e(LoadCellBusEvent::LinkLost),
            open_failures: e(LoadCellBusEvent::OpenFailed),
            reconnects: e(LoadCellBusEvent::Reconnect),
            overflows: e(LoadCellBusEvent::Overflow),
            invalid_values: e(LoadCellBusEvent::InvalidValue),
        }
    }
}

/// Timing and retry settings of a master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MasterConfig {
    /// Character and inter-frame times of the line.
    pub timing: Timing,
    /// Wait for the first byte of a response after the request has left.
    pub response_timeout: Duration,
    /// Further tries after a timeout, CRC error, garbage or transient exception.
    pub retries: u8,
}

impl MasterConfig {
    /// Settings of a configured bus.
    pub fn from_bus(bus: &taut_proto::devices::LoadCellBusConfig) -> MasterConfig {
        let parity = u32::from(bus.parity != taut_proto::devices::Parity::None);
        let bits = 1 + u32::from(bus.data_bits) + parity + u32::from(bus.stop_bits);
        MasterConfig {
            timing: Timing::new(bus.baud, bits),
            response_timeout: Duration::from_secs_f64(bus.response_timeout_s),
            retries: bus.retries,
        }
    }
}

/// A Modbus RTU master on one link.
pub struct Master<'c, L> {
    link: L,
    cfg: MasterConfig,
    counters: &'c Counters,
    /// When the line last carried a frame: the next request waits t3.5 after it.
    last_activity: Option<Instant>,
    rx: [u8; 2 * MAX_FRAME],
    clock: &'c dyn Clock,
}

/// Who a transaction is for, in the counted events' messages: `cable 1, ` (from 1) or nothing.
struct Who(Option<u16>);

impl fmt::Display for Who {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(c) => write!(f, "cable {}, ", u32::from(c) + 1),
            None => Ok(()),
        }
    }
}

/// The wall clock of masters made with [`Master::new`].
static WALL: WallClock = WallClock;

impl<'c, L: SerialLink> Master<'c, L> {
    /// A master on `link`, counting into `counters`.
    pub fn new(link: L, cfg: MasterConfig, counters: &'c Counters) -> Self {
        Master::with_clock(link, cfg, counters, &WALL)
    }

    /// A master that reads `clock` for the inter-frame silence and the response timeout (a
    /// simulated line advances a simulated clock as its bytes take their time).
    pub fn with_clock(link: L, cfg: MasterConfig, counters: &'c Counters, clock: &'c dyn Clock) -> Self {
        Master { link, cfg, counters, last_activity: None, rx: [0; 2 * MAX_FRAME], clock }
    }

    /// The link, e.g. to drop it after a failure.
    pub fn into_link(self) -> L {
        self.link
    }

    /// Reads registers, retrying as configured. Returns the first success, or the last failure;
    /// a [`TransactionError::Link`] returns at once (the port must be reopened).
    pub fn read(&mut self, req: &Request) -> Result<Registers, TransactionError> {
        self.read_for(req, None)
    }

    /// [`Master::read`] for the load cell of `cable` (0-based): the counted events' messages
    /// name it for people, from 1, beside the unit (`cable 1, unit 1: no response (timeout)`).
    pub fn read_for(&mut self, req: &Request, cable: Option<u16>) -> Result<Registers, TransactionError> {
        let who = Who(cable);
        let mut attempt = 0u8;
        loop {
            let err = match self.try_once(req) {
                Ok(r) => {
                    self.counters.ok();
                    return Ok(r);
                }
                Err(e) => e,
            };
            let retry = match err {
                TransactionError::Link(_) => return Err(err),
                TransactionError::Timeout { .. } => {
                    self.counters.count(LoadCellBusEvent::Timeout, format_args!("{who}{err}"));
                    true
                }
                TransactionError::Crc { .. } => {
                    self.counters.count(LoadCellBusEvent::Crc, format_args!("{who}{err}"));
                    true
                }
                TransactionError::Garbage { .. } => {
                    self.counters.count(LoadCellBusEvent::Garbage, format_args!("{who}{err}"));
                    true
                }
                TransactionError::Exception { code, .. } => {
                    self.counters.count(LoadCellBusEvent::Exception, format_args!("{who}{err}"));
                    // An illegal address or function will be refused every time: no retry.
                    code.is_transient()
                }
            };
            if !retry || attempt >= self.cfg.retries {
                self.counters.count(LoadCellBusEvent::Failed, format_args!("{who}gave up on a reading after {} tries: {err}", attempt + 1));
                return Err(err);
            }
            attempt += 1;
            self.counters.count(LoadCellBusEvent::Retry, format_args!("{who}retrying after: {err}"));
        }
    }

    fn try_once(&mut self, req: &Request) -> Result<Registers, TransactionError> {
        let link = |e| TransactionError::Link(e);
        // Modbus over Serial Line 2.5.1.1: at least t3.5 of silence before a new frame.
        if let Some(t) = self.last_activity {
            let ready = t + self.cfg.timing.t35;
            let now = self.clock.now();
            if ready > now {
                self.clock.sleep(ready - now);
            }
        }
        self.link.discard_input().map_err(link)?;
        let mut tx = [0u8; MAX_FRAME];
        let n = rtu::encode(req, &mut tx);
        self.link.send(&tx[..n]).map_err(link)?;
        let sent = self.clock.now();
        // The request takes its own time on the wire before the device can start answering.
        let deadline = sent + self.cfg.timing.frame_time(n) + self.cfg.response_timeout;
        let silence = self.cfg.timing.t35.max(Duration::from_millis(2));
        let (unit, fc) = (req.unit, req.function.code());
        let mut len = 0usize;
        let result = loop {
            if len == self.rx.len() {
                break None;
            }
            // Past the deadline, still take what has already arrived: a preempted thread's
            // lateness is not the device's silence, and a retry would leave a late copy to
            // spoil the next exchange.
            let now = self.clock.now();
            let header_ok = len >= 2 && self.rx[0] == unit && (self.rx[1] & 0x7F) == fc;
            let wait = if len == 0 || header_ok {
                deadline.saturating_duration_since(now)
            } else {
                silence.min(deadline.saturating_duration_since(now))
            };
            let got = self.link.recv(&mut self.rx[len..], wait).map_err(link)?;
            if got == 0 {
                // Timeout with nothing, or silence after bytes that are not our answer.
                break None;
            }
            len += got;
            if let Some((start, flen)) = rtu::find_response(&self.rx[..len], unit, req.function) {
                break Some((start, flen));
            }
            // Our header, announced length complete, still no valid frame: the CRC is bad.
            if let (true, Some(expect)) = (self.rx[0] == unit && (self.rx[1] & 0x7F) == fc, rtu::response_len(&self.rx[..len])) {
                if len >= expect {
                    self.last_activity = Some(self.clock.now());
                    return Err(if rtu::decode(&self.rx[..expect]).is_err_and(|e| matches!(e, RtuError::Crc { .. })) {
                        TransactionError::Crc { unit }
                    } else {
                        TransactionError::Garbage { unit, len, error: rtu::decode(&self.rx[..expect]).err() }
                    });
                }
            }
        };
        self.last_activity = Some(self.clock.now());
        let Some((start, flen)) = result else {
            return Err(if len == 0 { TransactionError::Timeout { unit } } else { TransactionError::Garbage { unit, len, error: None } });
        };
        match rtu::decode(&self.rx[start..start + flen]) {
            Ok(Response::Registers(r)) if r.function == req.function && r.values().len() == usize::from(req.quantity) => Ok(r),
            Ok(Response::Registers(_)) => Err(TransactionError::Garbage { unit, len, error: None }),
            Ok(Response::Exception { code, .. }) => Err(TransactionError::Exception { unit, code }),
            Err(e) => Err(TransactionError::Garbage { unit, len, error: Some(e) }),
        }
    }
}

/// Exponential back-off between reopen attempts: `min`, 2·`min`, 4·`min`, ... up to `max`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    min: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    /// Starts at `min`.
    pub fn new(min: Duration, max: Duration) -> Backoff {
        let max = max.max(min);
        Backoff { min, max, next: min }
    }

    /// The wait before the next attempt; doubles the one after.
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }

    /// Back to `min`, after a success.
    pub fn reset(&mut self) {
        self.next = self.min;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;
    use taut_proto::modbus::rtu::Function;

    /// An expected-transaction mock (embedded-hal-mock style): each request must match the next
    /// expectation, which supplies the reply chunks; unmet expectations fail on drop.
    struct Script {
        steps: VecDeque<(Vec<u8>, Vec<Vec<u8>>)>,
        pending: VecDeque<Vec<u8>>,
    }

    impl Script {
        fn new(steps: Vec<(Vec<u8>, Vec<Vec<u8>>)>) -> Script {
            Script { steps: steps.into(), pending: VecDeque::new() }
        }
    }

    impl Drop for Script {
        fn drop(&mut self) {
            if !std::thread::panicking() {
                assert!(self.steps.is_empty(), "unmet expectations: {:02X?}", self.steps);
            }
        }
    }

    impl SerialLink for &mut Script {
        fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
            let (want, reply) = self.steps.pop_front().expect("unexpected request");
            assert_eq!(frame, &want[..]);
            self.pending = reply.into();
            Ok(())
        }
        fn recv(&mut self, buf: &mut [u8], _timeout: Duration) -> Result<usize, LinkError> {
            match self.pending.pop_front() {
                Some(c) if c == b"GONE" => Err(LinkError::Gone(std::io::ErrorKind::BrokenPipe)),
                Some(c) => {
                    buf[..c.len()].copy_from_slice(&c);
                    Ok(c.len())
                }
                None => Ok(0),
            }
        }
        fn discard_input(&mut self) -> Result<(), LinkError> {
            Ok(())
        }
    }

    fn cfg() -> MasterConfig {
        MasterConfig { timing: Timing::new(115_200, 10), response_timeout: Duration::from_millis(5), retries: 2 }
    }

    fn req() -> Request {
        Request { unit: 2, function: Function::ReadInputRegisters, address: 0, quantity: 2 }
    }

    fn enc_req(r: &Request) -> Vec<u8> {
        let mut b = [0; MAX_FRAME];
        let n = rtu::encode(r, &mut b);
        b[..n].to_vec()
    }

    fn enc(r: &Response) -> Vec<u8> {
        let mut b = [0; MAX_FRAME];
        let n = rtu::encode_response(r, &mut b);
        b[..n].to_vec()
    }

    #[test]
    fn split_response_with_noise_in_front() {
        let good = enc(&Response::Registers(Registers::new(2, Function::ReadInputRegisters, &[0, 42])));
        let chunks = vec![vec![0xFF, 0x00], good[..4].to_vec(), good[4..].to_vec()];
        let mut s = Script::new(vec![(enc_req(&req()), chunks)]);
        let c = Counters::default();
        let mut m = Master::new(&mut s, cfg(), &c);
        assert_eq!(m.read(&req()).unwrap().values(), &[0, 42]);
        assert_eq!(c.snapshot().ok, 1);
    }

    #[test]
    fn bad_crc_then_timeout_then_success() {
        let good = enc(&Response::Registers(Registers::new(2, Function::ReadInputRegisters, &[1, 2])));
        let mut bad = good.clone();
        *bad.last_mut().unwrap() ^= 0xFF;
        let r = enc_req(&req());
        let mut s = Script::new(vec![(r.clone(), vec![bad]), (r.clone(), vec![]), (r, vec![good])]);
        let c = Counters::default();
        let mut m = Master::new(&mut s, cfg(), &c);
        assert!(m.read(&req()).is_ok());
        let snap = c.snapshot();
        assert_eq!((snap.crc_errors, snap.timeouts, snap.retries, snap.failed, snap.ok), (1, 1, 2, 0, 1));
    }

    #[test]
    fn illegal_address_is_not_retried() {
        let e = enc(&Response::Exception { unit: 2, function: 4, code: ExceptionCode::IllegalDataAddress });
        let mut s = Script::new(vec![(enc_req(&req()), vec![e])]);
        let c = Counters::default();
        let mut m = Master::new(&mut s, cfg(), &c);
        assert_eq!(m.read(&req()), Err(TransactionError::Exception { unit: 2, code: ExceptionCode::IllegalDataAddress }));
        assert_eq!((c.snapshot().exceptions, c.snapshot().failed), (1, 1));
    }

    #[test]
    fn garbage_is_retried_and_counted() {
        let r = enc_req(&req());
        let mut s =
            Script::new(vec![(r.clone(), vec![vec![0x55; 7]]), (r.clone(), vec![vec![0x02, 0x04, 0x04, 1]]), (r, vec![b"GONE".to_vec()])]);
        let c = Counters::default();
        let mut m = Master::new(&mut s, cfg(), &c);
        assert!(matches!(m.read(&req()), Err(TransactionError::Link(LinkError::Gone(_)))));
        // The truncated answer with our header runs into the deadline: garbage, not CRC.
        assert_eq!(c.snapshot().garbage, 2);
    }

    #[test]
    fn backoff_doubles_to_max() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(500));
        let d: Vec<_> = (0..5).map(|_| b.next_delay().as_millis()).collect();
        assert_eq!(d, [100, 200, 400, 500, 500]);
        b.reset();
        assert_eq!(b.next_delay().as_millis(), 100);
    }
}
