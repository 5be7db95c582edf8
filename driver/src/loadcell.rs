//! The load-cell I/O thread: polls every cell over Modbus RTU and hands timestamped tensions to
//! the real-time loop through a lock-free single-producer single-consumer ring (`ringbuf`).
//!
//! ```text
//!  I/O thread (blocking serial I/O)          real-time loop (never blocks)
//!  for each cell: Master::read -> newtons -> [SPSC ring] -> TensionReader::update()
//!  port lost -> reopen with back-off                         tension(cable, now): None if stale
//! ```
//!
//! The loop side allocates nothing after [`spawn`]: the ring and the per-cable latest values are
//! sized there. A reading older than `max_age_s` counts as missing, so a silent cell, a vanished
//! adapter and a stopped thread all look the same to the loop: no tension for that cable.
//!
//! ```no_run
//! let cfg = taut_config::RobotConfig::load("config/examples/aras-cam-hw.toml").unwrap();
//! let (io, mut tensions) = taut_driver::loadcell::spawn_from_config(&cfg).unwrap();
//! // In the loop: read -> update -> write.
//! tensions.update();
//! let t0 = tensions.tension(0, std::time::Instant::now());
//! # let _ = (io, t0);
//! ```

use crate::clock::{Clock, WallClock};
use crate::modbus::link::SerialPortLink;
use crate::modbus::master::{Backoff, CounterSnapshot, Counters, LoadCellBusEvent, Master, MasterConfig};
use ringbuf::traits::{Consumer, Producer, Split};
use ringbuf::{HeapCons, HeapProd, HeapRb};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_proto::devices::{LoadCellBusConfig, LoadCellConfig, RegisterKind};
use taut_proto::modbus::link::{LinkError, SerialLink};
use taut_proto::modbus::rtu::{Function, Request};
use taut_proto::modbus::value;

/// One tension reading. `Copy`, fixed size: what goes through the ring.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TensionSample {
    /// Index of the cable in the configuration.
    pub cable: u16,
    /// Tension, N.
    pub newtons: f64,
    /// When the response arrived.
    pub t: Instant,
}

/// Ring capacity: enough for several polling rounds of every cell if the loop misses cycles.
const RING_PER_CELL: usize = 16;

/// Why the load-cell bus could not start.
#[derive(Debug, Clone, PartialEq)]
pub enum SpawnError {
    /// A configuration value is wrong: key and message.
    Config(String, String),
    /// The OS would not start the thread.
    Thread,
}

impl std::fmt::Display for SpawnError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SpawnError::Config(k, m) => write!(f, "load cells: key `{k}`: {m}"),
            SpawnError::Thread => write!(f, "load cells: could not start the I/O thread"),
        }
    }
}

impl std::error::Error for SpawnError {}

/// Handle of the running I/O thread; stops it on drop.
pub struct LoadCellIo {
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    thread: Option<JoinHandle<()>>,
}

impl LoadCellIo {
    /// The bus counters (CRC errors, timeouts, exceptions, reconnects, ...).
    pub fn counters(&self) -> CounterSnapshot {
        self.counters.snapshot()
    }

    /// Runs the I/O thread under `SCHED_FIFO` at `priority` (see [`crate::sched`]).
    pub fn set_realtime(&self, priority: i32) -> std::io::Result<()> {
        match &self.thread {
            Some(t) => crate::sched::set_fifo(t, priority),
            None => Ok(()),
        }
    }

    /// Stops the thread and waits for it (at most one transaction plus one back-off slice).
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        // Release pairs with the thread's Acquire load: nothing else is published, but the stop
        // must not be reordered before writes the owner made to shared state.
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for LoadCellIo {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The loop's side: latest tension per cable, with age.
pub struct TensionReader {
    cons: HeapCons<TensionSample>,
    latest: Box<[Option<(f64, Instant)>]>,
    max_age: Duration,
    missing: u64,
    /// Set once the loop has taken a reading: from then on a full ring is worth a warning.
    taken: Arc<AtomicBool>,
    told: bool,
}

impl TensionReader {
    /// Takes every sample waiting in the ring; returns how many. No allocation, no lock.
    pub fn update(&mut self) -> usize {
        let mut n = 0;
        while let Some(s) = self.cons.try_pop() {
            if let Some(slot) = self.latest.get_mut(usize::from(s.cable)) {
                *slot = Some((s.newtons, s.t));
            }
            n += 1;
        }
        if n > 0 && !self.told {
            // Relaxed: only decides whether a full ring is reported; no data goes with it.
            self.taken.store(true, Ordering::Relaxed);
            self.told = true;
        }
        n
    }

    /// Latest tension of `cable` if it is at most `max_age` old at `now`, else `None` (counted
    /// as missing).
    pub fn tension(&mut self, cable: usize, now: Instant) -> Option<f64> {
        let fresh = match self.latest.get(cable).copied().flatten() {
            Some((n, t)) if now.saturating_duration_since(t) <= self.max_age => Some(n),
            _ => None,
        };
        if fresh.is_none() {
            self.missing += 1;
        }
        fresh
    }

    /// Latest tension and its arrival time, whatever its age.
    pub fn latest(&self, cable: usize) -> Option<(f64, Instant)> {
        self.latest.get(cable).copied().flatten()
    }

    /// Readings asked for with [`tension`](Self::tension) that were missing or stale.
    pub fn missing(&self) -> u64 {
        self.missing
    }

    /// Number of cables (configured cable count).
    pub fn cables(&self) -> usize {
        self.latest.len()
    }
}

/// One polled cell.
#[derive(Debug, Clone)]
struct Cell {
    cable: u16,
    cfg: LoadCellConfig,
    req: Request,
}

/// Starts the bus of a robot configuration: every cable with a `[cable.loadcell]` table.
pub fn spawn_from_config(cfg: &taut_config::RobotConfig) -> Result<(LoadCellIo, TensionReader), SpawnError> {
    let bus = cfg
        .loadcells
        .as_ref()
        .ok_or_else(|| SpawnError::Config("loadcells".into(), "no [loadcells] table: add one with the serial port".into()))?;
    let cells: Vec<_> = cfg.cables.iter().enumerate().filter_map(|(i, c)| c.loadcell.clone().map(|l| (i, l))).collect();
    spawn(bus, &cells, cfg.cables.len())
}

/// Starts the bus on a real serial port. `cells` pairs a cable index with its load cell;
/// `cables` is the number of cables (the reader's slots).
pub fn spawn(bus: &LoadCellBusConfig, cells: &[(usize, LoadCellConfig)], cables: usize) -> Result<(LoadCellIo, TensionReader), SpawnError> {
    let port = bus.clone();
    spawn_with(bus, cells, cables, move || SerialPortLink::open(&port))
}

/// Starts the bus on links made by `open` (called again after every link failure).
pub fn spawn_with<L, F>(
    bus: &LoadCellBusConfig,
    cells: &[(usize, LoadCellConfig)],
    cables: usize,
    open: F,
) -> Result<(LoadCellIo, TensionReader), SpawnError>
where
    L: SerialLink,
    F: FnMut() -> Result<L, LinkError> + Send + 'static,
{
    let (polled, prod, cons) = prepare(bus, cells, cables)?;
    let stop = Arc::new(AtomicBool::new(false));
    let counters = Arc::new(Counters::default());
    let worker =
        Worker { bus: bus.clone(), mcfg: MasterConfig::from_bus(bus), cells: polled, prod, stop: stop.clone(), counters: counters.clone() };
    let thread =
        std::thread::Builder::new().name("taut-loadcells".into()).spawn(move || worker.run(open)).map_err(|_| SpawnError::Thread)?;
    Ok((LoadCellIo { stop, counters, thread: Some(thread) }, reader(bus, cons, cables)))
}

fn reader(bus: &LoadCellBusConfig, (cons, taken): (HeapCons<TensionSample>, Arc<AtomicBool>), cables: usize) -> TensionReader {
    TensionReader {
        cons,
        latest: vec![None; cables].into_boxed_slice(),
        max_age: Duration::from_secs_f64(bus.max_age_s),
        missing: 0,
        taken,
        told: false,
    }
}

/// The I/O side of the ring, and whether the loop has taken a reading yet.
struct Ring {
    prod: HeapProd<TensionSample>,
    taken: Arc<AtomicBool>,
}

/// Validates the bus and the cells and makes the ring between the I/O side and the reader.
#[allow(clippy::type_complexity)]
fn prepare(
    bus: &LoadCellBusConfig,
    cells: &[(usize, LoadCellConfig)],
    cables: usize,
) -> Result<(Vec<Cell>, Ring, (HeapCons<TensionSample>, Arc<AtomicBool>)), SpawnError> {
    bus.validate().map_err(|(k, m)| SpawnError::Config(format!("loadcells.{k}"), m))?;
    let mut polled = Vec::with_capacity(cells.len());
    for (cable, c) in cells {
        c.validate().map_err(|(k, m)| SpawnError::Config(format!("cable[{cable}].loadcell.{k}"), m))?;
        if *cable >= cables || *cable > usize::from(u16::MAX) {
            return Err(SpawnError::Config(format!("cable[{cable}]"), format!("cable index out of range (robot has {cables})")));
        }
        let function = match c.registers {
            RegisterKind::Input => Function::ReadInputRegisters,
            RegisterKind::Holding => Function::ReadHoldingRegisters,
        };
        polled.push(Cell {
            cable: *cable as u16,
            cfg: c.clone(),
            req: Request { unit: c.unit_id, function, address: c.register, quantity: 2 },
        });
    }
    taut_proto::devices::validate_unit_ids(cells.iter().map(|(_, c)| Some(c)))
        .map_err(|(i, m)| SpawnError::Config(format!("cable[{}].loadcell.unit_id", cells[i].0), m))?;

    let rb = HeapRb::<TensionSample>::new((RING_PER_CELL * cells.len()).max(16));
    let (prod, cons) = rb.split();
    let taken = Arc::new(AtomicBool::new(false));
    Ok((polled, Ring { prod, taken: taken.clone() }, (cons, taken)))
}

/// The load-cell bus without its thread, for a lockstep simulation: the caller runs each
/// transaction ([`SteppedLoadCells::transaction`]) on its own link and clock, with the I/O
/// thread's master and reading code. Readings reach the [`TensionReader`] at
/// [`SteppedLoadCells::release`] at or after the instant their response was complete.
pub struct SteppedLoadCells {
    port: String,
    mcfg: MasterConfig,
    cells: Vec<Cell>,
    prod: Ring,
    counters: Arc<Counters>,
    pending: std::collections::VecDeque<TensionSample>,
    period: Duration,
    /// The cell the next transaction polls (index in `cells`).
    next: usize,
    /// The end of the last transaction of the round under way: the next request waits t3.5 of
    /// silence after it.
    last: Option<Instant>,
}

impl SteppedLoadCells {
    /// The bus of `bus` and `cells` (as [`spawn`]), its counters' handle and the loop's reader.
    pub fn new(
        bus: &LoadCellBusConfig,
        cells: &[(usize, LoadCellConfig)],
        cables: usize,
    ) -> Result<(SteppedLoadCells, LoadCellIo, TensionReader), SpawnError> {
        let (polled, prod, cons) = prepare(bus, cells, cables)?;
        let counters = Arc::new(Counters::default());
        let io = LoadCellIo { stop: Arc::new(AtomicBool::new(false)), counters: counters.clone(), thread: None };
        let stepped = SteppedLoadCells {
            port: bus.port.clone(),
            mcfg: MasterConfig::from_bus(bus),
            cells: polled,
            prod,
            counters,
            pending: std::collections::VecDeque::with_capacity(4 * cells.len().max(1)),
            period: Duration::from_secs_f64(bus.poll_period_s),
            next: 0,
            last: None,
        };
        Ok((stepped, io, reader(bus, cons, cables)))
    }

    /// `loadcells.poll_period_s`: from the start of one round to the start of the next.
    pub fn poll_period(&self) -> Duration {
        self.period
    }

    /// When the request of the next transaction, started on the line at `now`, has reached its
    /// cell whole (after t3.5 and its character times): when a simulator lets the cell answer.
    pub fn request_complete_at(&self, now: Instant) -> Instant {
        let Some(cell) = self.cells.get(self.next) else { return now };
        let start = self.last.filter(|_| self.next > 0).map_or(now, |t| now.max(t + self.mcfg.timing.t35));
        let mut tx = [0u8; taut_proto::modbus::rtu::MAX_FRAME];
        start + self.mcfg.timing.frame_time(taut_proto::modbus::rtu::encode(&cell.req, &mut tx))
    }

    /// One transaction of the polling round: the next cell, on `link`, timed by `clock` (which
    /// the line advances as the bytes take their time). True when the round is over (last cell
    /// read, or the link failed), so that the next transaction starts a new round.
    pub fn transaction<L: SerialLink>(&mut self, link: &mut L, clock: &dyn Clock) -> bool {
        let Some(cell) = self.cells.get(self.next) else { return true };
        if let Some(t) = self.last.filter(|_| self.next > 0) {
            let (ready, now) = (t + self.mcfg.timing.t35, clock.now());
            if ready > now {
                clock.sleep(ready - now);
            }
        }
        let counters = self.counters.clone();
        let mut master = Master::with_clock(link, self.mcfg, &counters, clock);
        let pending = &mut self.pending;
        let ok = poll_round(&self.port, std::slice::from_ref(cell), &mut master, &counters, clock, |s| pending.push_back(s)).is_ok();
        self.last = Some(clock.now());
        self.next = if ok { self.next + 1 } else { self.cells.len() };
        if self.next >= self.cells.len() {
            self.next = 0;
            return true;
        }
        false
    }

    /// Hands the readings complete at `now` to the reader.
    pub fn release(&mut self, now: Instant) {
        while self.pending.front().is_some_and(|s| s.t <= now) {
            let s = self.pending.pop_front().expect("checked");
            push(&mut self.prod, &self.counters, s);
        }
    }

    /// The bus counters (as [`LoadCellIo::counters`]).
    pub fn counters(&self) -> CounterSnapshot {
        self.counters.snapshot()
    }

    /// When the next held reading becomes visible.
    pub fn next_release(&self) -> Option<Instant> {
        self.pending.front().map(|s| s.t)
    }
}

/// Pushes one reading into the ring (full: counted). A full ring is reported once, and only
/// after the loop has taken its first reading: before that (bring-up) it is expected.
fn push(ring: &mut Ring, counters: &Counters, s: TensionSample) {
    if ring.prod.try_push(s).is_err() {
        // Relaxed: see `TensionReader::update`.
        if ring.taken.load(Ordering::Relaxed) {
            counters
                .count(LoadCellBusEvent::Overflow, format_args!("tension ring full: the real-time loop has stopped taking the readings"));
        } else {
            counters.count_quietly(LoadCellBusEvent::Overflow);
        }
    }
}

/// The link failed during a round: reopen it.
struct LinkLost;

/// One polling round: every cell once, in order, each reading stamped with `clock` when its
/// response was complete and handed to `out`.
fn poll_round<L: SerialLink>(
    port: &str,
    cells: &[Cell],
    master: &mut Master<'_, L>,
    counters: &Counters,
    clock: &dyn Clock,
    mut out: impl FnMut(TensionSample),
) -> Result<(), LinkLost> {
    for cell in cells {
        match master.read_for(&cell.req, Some(cell.cable)) {
            Ok(regs) => {
                let t = clock.now();
                let v = regs.values();
                match value::newtons([v[0], v[1]], &cell.cfg) {
                    Some(newtons) => out(TensionSample { cable: cell.cable, newtons, t }),
                    None => counters.count(
                        LoadCellBusEvent::InvalidValue,
                        format_args!("cable {}, unit {}: reading is NaN or infinite", u32::from(cell.cable) + 1, cell.cfg.unit_id),
                    ),
                }
            }
            Err(crate::modbus::master::TransactionError::Link(e)) => {
                counters.count(LoadCellBusEvent::LinkLost, format_args!("{port}: {e}; reopening with back-off"));
                return Err(LinkLost);
            }
            // Counted and logged by the master; the reading of this round is missing.
            Err(_) => {}
        }
    }
    Ok(())
}

struct Worker {
    bus: LoadCellBusConfig,
    mcfg: MasterConfig,
    cells: Vec<Cell>,
    prod: Ring,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
}

impl Worker {
    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    /// Sleeps `d` in short slices so a stop request is seen within ~20 ms.
    fn sleep(&self, d: Duration) {
        let end = Instant::now() + d;
        while !self.stopped() {
            let now = Instant::now();
            if now >= end {
                break;
            }
            std::thread::sleep((end - now).min(Duration::from_millis(20)));
        }
    }

    fn run<L: SerialLink, F: FnMut() -> Result<L, LinkError>>(mut self, mut open: F) {
        let mut backoff =
            Backoff::new(Duration::from_secs_f64(self.bus.reconnect_min_s), Duration::from_secs_f64(self.bus.reconnect_max_s));
        let period = Duration::from_secs_f64(self.bus.poll_period_s);
        let mut was_connected = false;
        while !self.stopped() {
            let link = match open() {
                Ok(l) => l,
                Err(e) => {
                    self.counters
                        .count(LoadCellBusEvent::OpenFailed, format_args!("cannot open {}: {e}; retrying with back-off", self.bus.port));
                    let d = backoff.next_delay();
                    self.sleep(d);
                    continue;
                }
            };
            if was_connected {
                self.counters.count(LoadCellBusEvent::Reconnect, format_args!("{} reopened", self.bus.port));
            }
            was_connected = true;
            backoff.reset();
            let counters = self.counters.clone();
            let mut master = Master::new(link, self.mcfg, &counters);
            'poll: while !self.stopped() {
                let round = Instant::now();
                if poll_round(&self.bus.port, &self.cells, &mut master, &self.counters, &WallClock, |s| {
                    push(&mut self.prod, &self.counters, s)
                })
                .is_err()
                {
                    break 'poll;
                }
                if !period.is_zero() {
                    self.sleep(period.saturating_sub(round.elapsed()));
                }
            }
            drop(master);
            if !self.stopped() {
                let d = backoff.next_delay();
                self.sleep(d);
            }
        }
    }
}
