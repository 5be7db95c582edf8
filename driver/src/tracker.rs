//! Tracker input: poses of the platform from an external position tracker, one UDP datagram per
//! pose, parsed, checked for age and order, and handed to the real-time loop without a lock.
//!
//! # Datagram format
//!
//! One ASCII line per datagram, `t px py pz [qw qx qy qz]`: `taut_proto::tracker` parses and
//! writes it (`docs/tracker.md` has the full description).
//!
//! # What is dropped, and counted
//!
//! - **foreign**: from a sender not in `[tracker] sources` (when the list is not empty); the
//!   datagram is not even parsed;
//! - **malformed**: not ASCII, wrong field count, a number that does not parse or is not finite,
//!   a quaternion whose norm is off 1 by more than 1 % (accepted ones are normalised);
//! - **out of order**: `t` not later than the last accepted pose's (UDP may reorder and
//!   duplicate). Five in a row that are in order among themselves mean the tracker restarted
//!   its clock: the stream is taken up again from them (counted as a restart);
//! - **late**: the datagram spent more than `max_age_s` longer in transit than the fastest
//!   one. The tracker clock and ours differ by an unknown offset, so transit time is measured
//!   relative to the smallest `arrival - t` seen, an estimate that may creep up by 100 ppm of
//!   elapsed time to follow clock drift.
//!
//! The loop reads the newest accepted pose through a [`PoseReader`]; one older than `max_age_s`
//! on our clock counts as missing.
//!
//! ```no_run
//! let mut cfg = taut_proto::devices::TrackerConfig::new("192.168.10.1:5005");
//! cfg.sources = vec!["192.168.10.20".into()];
//! let (rx, mut poses) = taut_driver::tracker::spawn(&cfg).unwrap();
//! if let Some(p) = poses.latest(std::time::Instant::now()) {
//!     println!("platform at {:?}", p.position);
//! }
//! # drop(rx);
//! ```

use std::fmt;
use std::io;
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{fence, AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_proto::devices::TrackerConfig;
use taut_proto::tracker::{parse_line, PoseLine, MAX_LINE};

/// A pose accepted for the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Tracker time stamp, s.
    pub t: f64,
    /// Position, m.
    pub position: [f64; 3],
    /// Orientation `[w, x, y, z]`, if the tracker sends one.
    pub orientation: Option<[f64; 4]>,
    /// When the datagram arrived, our clock.
    pub arrival: Instant,
    /// When the pose was measured, our clock: the tracker's time stamp plus the clock offset
    /// estimated from the fastest datagram (transit jitter removed; the fixed part of the
    /// transit, unknowable from one side, is counted as zero). Never after `arrival`.
    pub measured: Instant,
}

/// Why an accepted-format datagram was dropped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Drop {
    /// Not later than the last accepted pose.
    OutOfOrder {
        /// Its time stamp.
        t: f64,
        /// The last accepted time stamp.
        last: f64,
    },
    /// Spent `latency_s` longer in transit than the fastest datagram, over the limit.
    Late {
        /// Extra transit time, s.
        latency_s: f64,
    },
}

/// Datagrams out of order but in order among themselves that mean a tracker clock restart.
const RESTART_RUN: u32 = 5;
/// How fast the clock-offset estimate may creep up, per second of elapsed time (clock drift).
const DRIFT: f64 = 1e-4;

/// The age and order checks, sans-IO: arrival times are passed in.
#[derive(Debug, Clone)]
pub struct PoseFilter {
    max_age_s: f64,
    epoch: Instant,
    last_t: Option<f64>,
    /// Smallest `arrival - t` seen (leaky): the offset between the tracker clock and ours.
    offset: Option<(f64, f64)>,
    /// Run of out-of-order datagrams that are in order among themselves.
    run: u32,
    run_last_t: f64,
    restarts: u64,
}

impl PoseFilter {
    /// A filter dropping datagrams more than `max_age_s` late.
    pub fn new(max_age_s: f64, epoch: Instant) -> PoseFilter {
        PoseFilter { max_age_s, epoch, last_t: None, offset: None, run: 0, run_last_t: f64::NEG_INFINITY, restarts: 0 }
    }

    /// Times the tracker clock was seen to restart.
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Checks a parsed line that arrived at `arrival`.
    pub fn accept(&mut self, line: &PoseLine, arrival: Instant) -> Result<Pose, Drop> {
        let a = arrival.saturating_duration_since(self.epoch).as_secs_f64();
        if let Some(last) = self.last_t {
            if line.t <= last {
                if line.t > self.run_last_t {
                    self.run += 1;
                } else {
                    self.run = 1;
                }
                self.run_last_t = line.t;
                if self.run < RESTART_RUN {
                    return Err(Drop::OutOfOrder { t: line.t, last });
                }
                // Tracker clock restarted: forget the old clock.
                self.restarts += 1;
                self.offset = None;
            }
        }
        self.run = 0;
        self.run_last_t = f64::NEG_INFINITY;
        let sample = a - line.t;
        let min = match self.offset {
            // Creep up with elapsed time so a slowly drifting clock is followed.
            Some((off, at)) => (off + (a - at).max(0.0) * DRIFT).min(sample),
            None => sample,
        };
        self.offset = Some((min, a));
        // The order point advances even for a late datagram: an older one can only be later.
        self.last_t = Some(line.t);
        let latency_s = sample - min;
        if latency_s > self.max_age_s {
            return Err(Drop::Late { latency_s });
        }
        let measured = self.epoch + Duration::from_secs_f64((line.t + min).clamp(0.0, a));
        Ok(Pose { t: line.t, position: line.position, orientation: line.orientation, arrival, measured })
    }
}

/// The newest pose, written by one thread and read by another without a lock (a seqlock over
/// atomics: the reader retries if a write overlapped its read). No `unsafe`.
#[derive(Debug)]
pub struct PoseSlot {
    epoch: Instant,
    seq: AtomicU64,
    /// t, px, py, pz, qw, qx, qy, qz as f64 bits; arrival in ns since `epoch`; flags; measured
    /// in ns since `epoch`.
    words: [AtomicU64; 11],
}

impl PoseSlot {
    /// An empty slot.
    pub fn new(epoch: Instant) -> PoseSlot {
        PoseSlot { epoch, seq: AtomicU64::new(0), words: Default::default() }
    }

    /// Publishes a pose. Single writer only.
    pub fn store(&self, p: &Pose) {
        let s = self.seq.load(Ordering::Relaxed);
        // Odd sequence = write in progress. The Release fence keeps the data stores below from
        // moving above this mark (the crossbeam seqlock pattern).
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        let q = p.orientation.unwrap_or([0.0; 4]);
        let vals = [p.t, p.position[0], p.position[1], p.position[2], q[0], q[1], q[2], q[3]];
        for (w, v) in self.words.iter().zip(vals) {
            w.store(v.to_bits(), Ordering::Relaxed);
        }
        let ns = p.arrival.saturating_duration_since(self.epoch).as_nanos() as u64;
        self.words[8].store(ns, Ordering::Relaxed);
        self.words[9].store(1 | (u64::from(p.orientation.is_some()) << 1), Ordering::Relaxed);
        let ns = p.measured.saturating_duration_since(self.epoch).as_nanos() as u64;
        self.words[10].store(ns, Ordering::Relaxed);
        // Release: a reader that sees the even value sees all data stores above.
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// The newest pose, if any was stored. Lock-free; retries only while a write overlaps.
    pub fn load(&self) -> Option<Pose> {
        loop {
            // Acquire pairs with the writer's final Release store.
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let w: [u64; 11] = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            // Acquire fence: the data loads above complete before the re-check below.
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) != s1 {
                continue;
            }
            if w[9] & 1 == 0 {
                return None;
            }
            let f = |i: usize| f64::from_bits(w[i]);
            return Some(Pose {
                t: f(0),
                position: [f(1), f(2), f(3)],
                orientation: (w[9] & 2 != 0).then(|| [f(4), f(5), f(6), f(7)]),
                arrival: self.epoch + Duration::from_nanos(w[8]),
                measured: self.epoch + Duration::from_nanos(w[10]),
            });
        }
    }
}

/// Tracker counters. Each is a statistic read alone: `Relaxed` throughout.
#[derive(Debug, Default)]
pub struct TrackerCounters {
    received: AtomicU64,
    accepted: AtomicU64,
    malformed: AtomicU64,
    late: AtomicU64,
    out_of_order: AtomicU64,
    restarts: AtomicU64,
    foreign: AtomicU64,
    logged: AtomicU64,
}

/// A copy of the tracker counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TrackerStats {
    /// Datagrams received.
    pub received: u64,
    /// Poses handed to the loop.
    pub accepted: u64,
    /// Malformed datagrams dropped.
    pub malformed: u64,
    /// Late datagrams dropped.
    pub late: u64,
    /// Out-of-order or duplicate datagrams dropped.
    pub out_of_order: u64,
    /// Tracker clock restarts seen.
    pub restarts: u64,
    /// Datagrams from senders not in `[tracker] sources`, dropped.
    pub foreign: u64,
}

impl TrackerCounters {
    /// Reads every counter.
    pub fn snapshot(&self) -> TrackerStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        TrackerStats {
            received: l(&self.received),
            accepted: l(&self.accepted),
            malformed: l(&self.malformed),
            late: l(&self.late),
            out_of_order: l(&self.out_of_order),
            restarts: l(&self.restarts),
            foreign: l(&self.foreign),
        }
    }

    fn bump(&self, c: &AtomicU64, kind: u64, detail: fmt::Arguments<'_>) {
        c.fetch_add(1, Ordering::Relaxed);
        if self.logged.fetch_or(1 << kind, Ordering::Relaxed) & (1 << kind) == 0 {
            eprintln!("taut tracker: {detail} (first of its kind; further ones are only counted)");
        }
    }
}

/// Which senders are taken (`[tracker] sources`): an empty list takes any.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SourceFilter {
    /// Allowed senders; port 0 means any port of that address.
    allowed: Vec<SocketAddr>,
}

/// IPv4-mapped IPv6 (`::ffff:a.b.c.d`, what a dual-stack socket reports) compares as IPv4.
fn canonical(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    }
}

impl SourceFilter {
    /// From the configuration's `sources` (checked by `TrackerConfig::validate`).
    pub fn from_config(cfg: &TrackerConfig) -> io::Result<SourceFilter> {
        let allowed = cfg
            .sources
            .iter()
            .enumerate()
            .map(|(i, s)| {
                taut_proto::devices::parse_tracker_source(s)
                    .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, format!("tracker.sources[{i}]: {s:?} is not an address")))
            })
            .collect::<io::Result<Vec<_>>>()?;
        Ok(SourceFilter { allowed })
    }

    /// True if a datagram from `from` is taken. No allocation.
    pub fn allows(&self, from: SocketAddr) -> bool {
        self.allowed.is_empty()
            || self.allowed.iter().any(|a| canonical(a.ip()) == canonical(from.ip()) && (a.port() == 0 || a.port() == from.port()))
    }
}

/// The receiving end: a non-blocking UDP socket, the filter, the slot. Drive it with
/// [`poll`](Self::poll) from any loop, or let [`spawn`] run it on its own thread.
pub struct TrackerReceiver {
    /// `None`: a receiver fed by [`TrackerReceiver::on_datagram`] only (a lockstep simulation).
    socket: Option<UdpSocket>,
    filter: PoseFilter,
    slot: Arc<PoseSlot>,
    counters: Arc<TrackerCounters>,
    max_age: Duration,
    sources: SourceFilter,
}

impl TrackerReceiver {
    /// Binds the configured address.
    pub fn bind(cfg: &TrackerConfig) -> io::Result<TrackerReceiver> {
        cfg.validate().map_err(|(k, m)| io::Error::new(io::ErrorKind::InvalidInput, format!("tracker.{k}: {m}")))?;
        let addr: SocketAddr = cfg.listen.parse().map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        let detached = TrackerReceiver::detached(cfg, Instant::now())?;
        let socket = UdpSocket::bind(addr)?;
        socket.set_nonblocking(true)?;
        Ok(TrackerReceiver { socket: Some(socket), ..detached })
    }

    /// A receiver without a socket, whose datagrams come through
    /// [`on_datagram`](Self::on_datagram) with their arrival instants on the caller's clock
    /// (`epoch` is that clock's now). The same filter, slot and counters as a bound one.
    pub fn detached(cfg: &TrackerConfig, epoch: Instant) -> io::Result<TrackerReceiver> {
        cfg.validate().map_err(|(k, m)| io::Error::new(io::ErrorKind::InvalidInput, format!("tracker.{k}: {m}")))?;
        let sources = SourceFilter::from_config(cfg)?;
        Ok(TrackerReceiver {
            socket: None,
            filter: PoseFilter::new(cfg.max_age_s, epoch),
            slot: Arc::new(PoseSlot::new(epoch)),
            counters: Arc::new(TrackerCounters::default()),
            max_age: Duration::from_secs_f64(cfg.max_age_s),
            sources,
        })
    }

    /// The address actually bound (port 0 in the config picks a free one).
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        match &self.socket {
            Some(s) => s.local_addr(),
            None => Err(io::Error::new(io::ErrorKind::NotConnected, "a detached tracker receiver has no socket")),
        }
    }

    /// A reader of the poses this receiver accepts.
    pub fn reader(&self) -> PoseReader {
        PoseReader { slot: self.slot.clone(), counters: self.counters.clone(), max_age: self.max_age, missing: 0 }
    }

    /// Takes every datagram waiting on the socket; returns how many poses were accepted.
    pub fn poll(&mut self) -> io::Result<usize> {
        let mut buf = [0u8; MAX_LINE + 1];
        let mut accepted = 0;
        loop {
            let Some(socket) = &self.socket else { return Ok(0) };
            let (n, from) = match socket.recv_from(&mut buf) {
                Ok(x) => x,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(accepted),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                // ICMP port unreachable from an earlier send etc.: not fatal for a receiver.
                Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => continue,
                Err(e) => return Err(e),
            };
            if self.on_datagram_from(&buf[..n], from, Instant::now()) {
                accepted += 1;
            }
        }
    }

    /// Handles one datagram from `from` that arrived at `arrival`; `true` if accepted. One
    /// from a sender outside `[tracker] sources` is counted as foreign and not parsed.
    pub fn on_datagram_from(&mut self, bytes: &[u8], from: SocketAddr, arrival: Instant) -> bool {
        if !self.sources.allows(from) {
            let c = &self.counters;
            c.received.fetch_add(1, Ordering::Relaxed);
            c.bump(&c.foreign, 4, format_args!("datagram from {from} dropped: not in tracker.sources"));
            return false;
        }
        self.on_datagram(bytes, arrival)
    }

    /// Handles one datagram that arrived at `arrival`, whoever sent it; `true` if accepted.
    pub fn on_datagram(&mut self, bytes: &[u8], arrival: Instant) -> bool {
        let c = &self.counters;
        c.received.fetch_add(1, Ordering::Relaxed);
        // A datagram longer than the buffer was cut; recv told us MAX_LINE + 1 bytes.
        let line = match parse_line(bytes) {
            Ok(l) => l,
            Err(e) => {
                c.bump(&c.malformed, 0, format_args!("malformed datagram dropped: {e}"));
                return false;
            }
        };
        let restarts = self.filter.restarts();
        let r = self.filter.accept(&line, arrival);
        if self.filter.restarts() != restarts {
            c.bump(&c.restarts, 3, format_args!("tracker clock restarted (t went back to {})", line.t));
        }
        match r {
            Ok(p) => {
                self.slot.store(&p);
                c.accepted.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(Drop::Late { latency_s }) => {
                c.bump(&c.late, 1, format_args!("late datagram dropped ({:.1} ms over the fastest)", latency_s * 1e3));
                false
            }
            Err(Drop::OutOfOrder { t, last }) => {
                c.bump(&c.out_of_order, 2, format_args!("out-of-order datagram dropped (t = {t} after {last})"));
                false
            }
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> TrackerStats {
        self.counters.snapshot()
    }
}

/// The loop's side: the newest pose, if it is fresh.
#[derive(Debug)]
pub struct PoseReader {
    slot: Arc<PoseSlot>,
    counters: Arc<TrackerCounters>,
    max_age: Duration,
    missing: u64,
}

impl PoseReader {
    /// The newest accepted pose if it arrived at most `max_age_s` before `now`; `None` (and
    /// counted as missing) otherwise. Lock-free, no allocation.
    pub fn latest(&mut self, now: Instant) -> Option<Pose> {
        let p = self.slot.load().filter(|p| now.saturating_duration_since(p.arrival) <= self.max_age);
        if p.is_none() {
            self.missing += 1;
        }
        p
    }

    /// The newest accepted pose, whatever its age.
    pub fn newest(&self) -> Option<Pose> {
        self.slot.load()
    }

    /// Calls of [`latest`](Self::latest) that found no fresh pose.
    pub fn missing(&self) -> u64 {
        self.missing
    }

    /// Receiver counters.
    pub fn stats(&self) -> TrackerStats {
        self.counters.snapshot()
    }

    /// A handle on the receiver's counters for status output (another thread).
    pub fn stats_handle(&self) -> TrackerStatsHandle {
        TrackerStatsHandle(self.counters.clone())
    }
}

/// Shared read access to a tracker receiver's counters.
#[derive(Debug, Clone)]
pub struct TrackerStatsHandle(Arc<TrackerCounters>);

impl TrackerStatsHandle {
    /// The counters now.
    pub fn stats(&self) -> TrackerStats {
        self.0.snapshot()
    }
}

/// The receiver thread; stops on drop.
pub struct TrackerThread {
    stop: Arc<AtomicBool>,
    addr: SocketAddr,
    thread: Option<JoinHandle<io::Result<()>>>,
}

impl TrackerThread {
    /// The bound address.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Runs the receiver thread under `SCHED_FIFO` at `priority` (see [`crate::sched`]).
    pub fn set_realtime(&self, priority: i32) -> io::Result<()> {
        match &self.thread {
            Some(t) => crate::sched::set_fifo(t, priority),
            None => Ok(()),
        }
    }
}

impl std::ops::Drop for TrackerThread {
    fn drop(&mut self) {
        // Release/Acquire: the flag alone is published; ordering is for clarity, not need.
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Binds the configured address and runs the receiver on its own thread, waking on each datagram
/// (poll(2) with a 50 ms timeout to see a stop).
pub fn spawn(cfg: &TrackerConfig) -> io::Result<(TrackerThread, PoseReader)> {
    let mut rx = TrackerReceiver::bind(cfg)?;
    let reader = rx.reader();
    let addr = rx.local_addr()?;
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let thread = std::thread::Builder::new().name("taut-tracker".into()).spawn(move || {
        use std::os::fd::AsRawFd;
        let fd = rx.socket.as_ref().map_or(-1, |s| s.as_raw_fd());
        while !stop2.load(Ordering::Acquire) {
            let mut pfd = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
            // SAFETY: one valid pollfd for the duration of the call.
            let r = unsafe { libc::poll(&mut pfd, 1, 50) };
            if r < 0 {
                let e = io::Error::last_os_error();
                if e.kind() != io::ErrorKind::Interrupted {
                    return Err(e);
                }
            }
            rx.poll()?;
        }
        Ok(())
    })?;
    Ok((TrackerThread { stop, addr, thread: Some(thread) }, reader))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filter_orders_and_ages() {
        let e = Instant::now();
        let at = |s: f64| e + Duration::from_secs_f64(s);
        let l = |t: f64| PoseLine { t, position: [0.0; 3], orientation: None };
        let mut f = PoseFilter::new(0.05, e);
        // Tracker clock 100 s ahead of ours; 2 ms transit.
        assert!(f.accept(&l(100.0), at(0.002)).is_ok());
        assert!(f.accept(&l(100.01), at(0.012)).is_ok());
        assert!(matches!(f.accept(&l(100.005), at(0.013)), Err(Drop::OutOfOrder { .. })));
        assert!(matches!(f.accept(&l(100.01), at(0.014)), Err(Drop::OutOfOrder { .. })));
        // 80 ms more transit than the fastest: late.
        assert!(matches!(f.accept(&l(100.02), at(0.102)), Err(Drop::Late { .. })));
        assert!(f.accept(&l(100.11), at(0.112)).is_ok());
        // Tracker restart: t back to 0, in order from there.
        for k in 0..4 {
            assert!(f.accept(&l(0.01 * f64::from(k)), at(0.2 + 0.01 * f64::from(k))).is_err());
        }
        assert!(f.accept(&l(0.04), at(0.24)).is_ok());
        assert_eq!(f.restarts(), 1);
        assert!(f.accept(&l(0.05), at(0.25)).is_ok());
    }

    #[test]
    fn slot_round_trip() {
        let e = Instant::now();
        let s = PoseSlot::new(e);
        assert_eq!(s.load(), None);
        let p = Pose {
            t: 1.5,
            position: [1.0, 2.0, 3.0],
            orientation: Some([1.0, 0.0, 0.0, 0.0]),
            arrival: e + Duration::from_millis(7),
            measured: e + Duration::from_millis(5),
        };
        s.store(&p);
        assert_eq!(s.load(), Some(p));
        let p2 = Pose { orientation: None, ..p };
        s.store(&p2);
        assert_eq!(s.load(), Some(p2));
    }

    #[test]
    fn slot_never_tears() {
        // A writer stores poses whose fields all equal k; a reader must never see a mix.
        let e = Instant::now();
        let s = Arc::new(PoseSlot::new(e));
        let w = s.clone();
        let h = std::thread::spawn(move || {
            for k in 0..100_000u32 {
                let x = f64::from(k);
                w.store(&Pose { t: x, position: [x; 3], orientation: Some([x; 4]), arrival: e, measured: e });
            }
        });
        let mut seen = 0;
        while !h.is_finished() || seen == 0 {
            if let Some(p) = s.load() {
                assert!(p.position.iter().chain(p.orientation.unwrap().iter()).all(|&v| v == p.t), "{p:?}");
                seen += 1;
            }
        }
        h.join().unwrap();
    }
}
