//! Virtual Modbus RTU load cells: a server on one end of a pseudo-terminal pair, answering with
//! the tensions the simulator sets, with faults to inject.
//!
//! The line can also be one end of a Unix stream socket pair ([`VirtualLoadCells::spawn_socket`]):
//! the same RTU bytes, master and I/O thread ([`SocketLink`]), without the kernel's terminal
//! layer, which passes a pseudo-terminal's bytes on at the normal scheduler's priority whatever
//! the threads at either end run at (BENCHMARKS.md). The simulated robot's wall-clock start-ups
//! use the socket; the serial-port tests open the pseudo-terminal.
//!
//! The master opens [`VirtualLoadCells::path`], a symlink to the pseudo-terminal's slave end, as
//! it opens `/dev/taut-loadcells` on the robot. [`unplug`](VirtualLoadCells::unplug) closes the
//! pseudo-terminal as a USB unplug does; [`replug`](VirtualLoadCells::replug) makes a new pair
//! behind the same path.
//!
//! Register map of each cell: its two registers at `register` in its table (`registers =
//! "input"` or `"holding"`), encoded as its config says (int32/float32, word order, scale,
//! offset). Other addresses answer exception 02, other function codes exception 01, a
//! quantity of 0 or over 125 exception 03; requests with a bad CRC or for other unit ids get
//! no answer, as on a real RS-485 line.
//!
//! ```no_run
//! use taut_proto::devices::LoadCellConfig;
//! use taut_vdev::{LoadCellFault, TensionHandle, VirtualLoadCells};
//! let tensions = TensionHandle::new(2);
//! let server = VirtualLoadCells::spawn(vec![LoadCellConfig::new(1), LoadCellConfig::new(2)], tensions.clone()).unwrap();
//! tensions.set(0, 42.0);
//! server.inject(Some(2), LoadCellFault::BadCrc, 3);
//! println!("master: open {}", server.path().display());
//! ```

use serialport::{SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_proto::devices::{LoadCellConfig, RegisterKind};
use taut_proto::modbus::link::{LinkError, SerialLink};
use taut_proto::modbus::rtu::{self, ExceptionCode, Function, Registers, Response, RtuError, MAX_FRAME};
use taut_proto::modbus::value;

/// Tensions of the simulated cells, N, shared between the simulator (writer) and the server.
/// One `f64` per cell as atomic bits: each value stands alone, so `Relaxed` suffices.
#[derive(Debug, Clone)]
pub struct TensionHandle(Arc<[AtomicU64]>);

impl TensionHandle {
    /// `n` cells at 0 N.
    pub fn new(n: usize) -> TensionHandle {
        TensionHandle((0..n).map(|_| AtomicU64::new(0f64.to_bits())).collect())
    }

    /// Sets the tension of cell `i` (index in the server's cell list); ignored out of range.
    pub fn set(&self, i: usize, newtons: f64) {
        if let Some(a) = self.0.get(i) {
            a.store(newtons.to_bits(), Ordering::Relaxed);
        }
    }

    /// Sets all cells from a slice (extra values are ignored).
    pub fn set_all(&self, newtons: &[f64]) {
        for (i, n) in newtons.iter().enumerate() {
            self.set(i, *n);
        }
    }

    /// Tension of cell `i`.
    pub fn get(&self, i: usize) -> f64 {
        self.0.get(i).map_or(0.0, |a| f64::from_bits(a.load(Ordering::Relaxed)))
    }
}

/// A fault for the next answers of a unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoadCellFault {
    /// The answer with its CRC corrupted.
    BadCrc,
    /// No answer.
    Silence,
    /// Seven bytes of noise instead of the answer.
    Garbage,
    /// Noise, then the correct answer.
    NoiseThenAnswer,
    /// An exception response with this code.
    Exception(u8),
}

#[derive(Debug)]
struct Injected {
    unit: Option<u8>,
    fault: LoadCellFault,
    left: u32,
}

/// Server counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ServerStats {
    /// Valid requests addressed to one of our units.
    pub requests: u64,
    /// Normal answers sent.
    pub answered: u64,
    /// Faults applied.
    pub faults: u64,
    /// Received frames that were no valid request (bad CRC, noise): ignored.
    pub bad_frames: u64,
}

#[derive(Default)]
struct Shared {
    stop: AtomicBool,
    faults: Mutex<Vec<Injected>>,
    plug: Mutex<Option<bool>>,
    /// Socket mode: the robot's end of the current socket pair, until the robot opens it.
    socket_port: Mutex<Option<UnixStream>>,
    requests: AtomicU64,
    answered: AtomicU64,
    faults_applied: AtomicU64,
    bad_frames: AtomicU64,
}

/// The running server; stops on drop.
pub struct VirtualLoadCells {
    shared: Arc<Shared>,
    path: PathBuf,
    /// The pseudo-terminal's directory; `None` in socket mode.
    dir: Option<PathBuf>,
    thread: Option<JoinHandle<()>>,
}

struct Pty {
    master: TTYPort,
    /// Kept open so the master end never sees a hang-up while no client has the port open.
    _slave: TTYPort,
}

/// The server's end of the line.
enum Line {
    Pty(Pty),
    Socket(UnixStream),
}

/// How long the server waits for bytes before it looks at its controls again.
const SERVER_POLL: Duration = Duration::from_millis(5);

impl Line {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Line::Pty(p) => p.master.read(buf),
            Line::Socket(s) => s.read(buf),
        }
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        match self {
            Line::Pty(p) => p.master.write_all(buf),
            Line::Socket(s) => s.write_all(buf),
        }
    }
}

/// A new socket pair: the server's end as a [`Line`], the robot's end into `slot`.
fn open_socket(slot: &Mutex<Option<UnixStream>>) -> io::Result<Line> {
    let (ours, theirs) = UnixStream::pair()?;
    ours.set_read_timeout(Some(SERVER_POLL))?;
    *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(theirs);
    Ok(Line::Socket(ours))
}

/// The robot's side of a socket-mode line ([`VirtualLoadCells::spawn_socket`]): what the
/// load-cell I/O thread opens in place of the serial port.
#[derive(Clone)]
pub struct SocketPort {
    shared: Arc<Shared>,
}

impl SocketPort {
    /// Takes the line's current robot end, as opening the serial port does. Unplugged (or
    /// already open): [`LinkError::NotFound`].
    pub fn open(&self) -> Result<SocketLink, LinkError> {
        let s = self.shared.socket_port.lock().unwrap_or_else(|e| e.into_inner()).take().ok_or(LinkError::NotFound)?;
        Ok(SocketLink { s, nonblocking: false, timeout: None })
    }
}

/// A Modbus RTU line carried by a Unix stream socket: [`SerialLink`] as on a serial port (the
/// response timeout on each read, input discarded before each request).
pub struct SocketLink {
    s: UnixStream,
    nonblocking: bool,
    timeout: Option<Duration>,
}

impl SocketLink {
    fn set_nonblocking(&mut self, on: bool) -> Result<(), LinkError> {
        if self.nonblocking != on {
            self.s.set_nonblocking(on).map_err(|e| LinkError::Gone(e.kind()))?;
            self.nonblocking = on;
        }
        Ok(())
    }
}

fn would_block(e: &io::Error) -> bool {
    matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut)
}

impl SerialLink for SocketLink {
    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.set_nonblocking(false)?;
        self.s.write_all(frame).map_err(|e| LinkError::Gone(e.kind()))
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        if buf.is_empty() {
            return Ok(0);
        }
        if timeout.is_zero() {
            // Only what has already arrived (a zero read timeout is not allowed).
            self.set_nonblocking(true)?;
        } else {
            self.set_nonblocking(false)?;
            if self.timeout != Some(timeout) {
                self.s.set_read_timeout(Some(timeout)).map_err(|_| LinkError::Settings)?;
                self.timeout = Some(timeout);
            }
        }
        loop {
            match self.s.read(buf) {
                Ok(0) => return Err(LinkError::Gone(io::ErrorKind::UnexpectedEof)),
                Ok(n) => return Ok(n),
                Err(e) if would_block(&e) => return Ok(0),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(LinkError::Gone(e.kind())),
            }
        }
    }

    fn discard_input(&mut self) -> Result<(), LinkError> {
        self.set_nonblocking(true)?;
        let mut scratch = [0u8; 64];
        loop {
            match self.s.read(&mut scratch) {
                Ok(0) => return Err(LinkError::Gone(io::ErrorKind::UnexpectedEof)),
                Ok(_) => {}
                Err(e) if would_block(&e) => return Ok(()),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(LinkError::Gone(e.kind())),
            }
        }
    }
}

fn open_pty(link: &Path) -> io::Result<Pty> {
    let (mut master, slave) = TTYPort::pair().map_err(io::Error::from)?;
    master.set_timeout(SERVER_POLL).map_err(io::Error::from)?;
    let target = slave.name().ok_or_else(|| io::Error::other("pseudo-terminal has no name"))?;
    // Replace the symlink atomically: a client never sees a half-made path.
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&target, &tmp)?;
    std::fs::rename(&tmp, link)?;
    Ok(Pty { master, _slave: slave })
}

/// Puts the server thread under `SCHED_FIFO` at `priority` (1..=99). The master's I/O thread
/// has its own (`taut_driver::sched`): the device side does not link the master.
fn set_fifo<T>(thread: &JoinHandle<T>, priority: i32) -> io::Result<()> {
    use std::os::unix::thread::JoinHandleExt;
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: the pthread_t belongs to a thread that has not been joined (we hold its handle);
    // `param` outlives the call.
    let rc = unsafe { libc::pthread_setschedparam(thread.as_pthread_t(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::from_raw_os_error(rc))
    }
}

impl VirtualLoadCells {
    /// Starts a server for `cells` (cell `i` reads tension `i` of `tensions`) behind a fresh
    /// symlink in the temporary directory.
    pub fn spawn(cells: Vec<LoadCellConfig>, tensions: TensionHandle) -> io::Result<VirtualLoadCells> {
        static N: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!("taut-vlc-{}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed)));
        std::fs::create_dir_all(&dir)?;
        let path = dir.join("ttyLOADCELLS");
        let pty = open_pty(&path)?;
        let shared = Arc::new(Shared::default());
        let server = Server { cells, tensions, shared: shared.clone(), link: Some(path.clone()), noise: 0x2545_F491 };
        let thread = std::thread::Builder::new().name("taut-sim-loadcells".into()).spawn(move || server.run(Some(Line::Pty(pty))))?;
        Ok(VirtualLoadCells { shared, path, dir: Some(dir), thread: Some(thread) })
    }

    /// Starts a server for `cells` on a Unix stream socket pair (module doc); the robot opens the
    /// other end with [`Self::socket_port`], and [`path`](Self::path) is only a name for messages.
    /// Unplug and replug work as with the pseudo-terminal.
    pub fn spawn_socket(cells: Vec<LoadCellConfig>, tensions: TensionHandle) -> io::Result<VirtualLoadCells> {
        let shared = Arc::new(Shared::default());
        let line = open_socket(&shared.socket_port)?;
        let server = Server { cells, tensions, shared: shared.clone(), link: None, noise: 0x2545_F491 };
        let thread = std::thread::Builder::new().name("taut-sim-loadcells".into()).spawn(move || server.run(Some(line)))?;
        Ok(VirtualLoadCells { shared, path: PathBuf::from("virtual-loadcells (socket pair)"), dir: None, thread: Some(thread) })
    }

    /// The robot's side of a socket-mode server ([`Self::spawn_socket`]); `None` on a
    /// pseudo-terminal.
    pub fn socket_port(&self) -> Option<SocketPort> {
        self.dir.is_none().then(|| SocketPort { shared: self.shared.clone() })
    }

    /// Runs the server thread under `SCHED_FIFO` at `priority`: the cells stand in for hardware
    /// with its own processor, which a loaded robot computer does not slow down.
    pub fn set_realtime(&self, priority: i32) -> io::Result<()> {
        match &self.thread {
            Some(t) => set_fifo(t, priority),
            None => Ok(()),
        }
    }

    /// Path the master opens (a symlink to the pseudo-terminal's slave end).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Applies `fault` to the next `count` answers of `unit` (`None`: any unit).
    pub fn inject(&self, unit: Option<u8>, fault: LoadCellFault, count: u32) {
        self.shared.faults.lock().unwrap_or_else(|e| e.into_inner()).push(Injected { unit, fault, left: count });
    }

    /// Removes all pending faults.
    pub fn clear_faults(&self) {
        self.shared.faults.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }

    /// Closes the pseudo-terminal and removes the path, as a USB unplug does.
    pub fn unplug(&self) {
        self.set_plug(false);
    }

    /// A new pseudo-terminal behind the same path, as plugging the adapter back in.
    pub fn replug(&self) {
        self.set_plug(true);
    }

    fn set_plug(&self, on: bool) {
        *self.shared.plug.lock().unwrap_or_else(|e| e.into_inner()) = Some(on);
        // Wait until the server thread has done it, so tests can act on the new state.
        let t0 = Instant::now();
        while self.shared.plug.lock().unwrap_or_else(|e| e.into_inner()).is_some() && t0.elapsed() < Duration::from_secs(2) {
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> ServerStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        ServerStats {
            requests: l(&self.shared.requests),
            answered: l(&self.shared.answered),
            faults: l(&self.shared.faults_applied),
            bad_frames: l(&self.shared.bad_frames),
        }
    }
}

impl Drop for VirtualLoadCells {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if let Some(dir) = &self.dir {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// The load cells' answers without a line or a thread (sans-IO), for a lockstep simulation; the
/// same code answers behind [`VirtualLoadCells`].
pub struct LoadCellResponder {
    server: Server,
}

impl LoadCellResponder {
    /// Cells `cells` (cell `i` reads tension `i` of `tensions`).
    pub fn new(cells: Vec<LoadCellConfig>, tensions: TensionHandle) -> LoadCellResponder {
        LoadCellResponder { server: Server { cells, tensions, shared: Arc::new(Shared::default()), link: None, noise: 0x2545_F491 } }
    }

    /// The answer to one received request frame, if the addressed cell answers (a fault may
    /// silence it or spoil the answer). Allocates nothing.
    pub fn answer(&mut self, frame: &[u8]) -> Option<([u8; 2 * MAX_FRAME], usize)> {
        self.server.answer(frame)
    }

    /// Applies `fault` to the next `count` answers of `unit` (`None`: any unit).
    pub fn inject(&self, unit: Option<u8>, fault: LoadCellFault, count: u32) {
        self.server.shared.faults.lock().unwrap_or_else(|e| e.into_inner()).push(Injected { unit, fault, left: count });
    }

    /// Counters so far.
    pub fn stats(&self) -> ServerStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let sh = &self.server.shared;
        ServerStats { requests: l(&sh.requests), answered: l(&sh.answered), faults: l(&sh.faults_applied), bad_frames: l(&sh.bad_frames) }
    }
}

struct Server {
    cells: Vec<LoadCellConfig>,
    tensions: TensionHandle,
    shared: Arc<Shared>,
    /// The pseudo-terminal's symlink; `None`: a socket pair.
    link: Option<PathBuf>,
    noise: u32,
}

impl Server {
    fn run(mut self, mut pty: Option<Line>) {
        let mut buf = [0u8; 2 * MAX_FRAME];
        let mut len = 0usize;
        let mut last_byte = Instant::now();
        while !self.shared.stop.load(Ordering::Relaxed) {
            let plug = self.shared.plug.lock().unwrap_or_else(|e| e.into_inner()).take();
            match plug {
                Some(false) => {
                    pty = None;
                    match &self.link {
                        Some(link) => {
                            let _ = std::fs::remove_file(link);
                        }
                        None => *self.shared.socket_port.lock().unwrap_or_else(|e| e.into_inner()) = None,
                    }
                    len = 0;
                }
                Some(true) if pty.is_none() => pty = self.open_line().ok(),
                _ => {}
            }
            let Some(p) = pty.as_mut() else {
                std::thread::sleep(Duration::from_millis(2));
                continue;
            };
            match p.read(&mut buf[len..]) {
                Ok(n) if n > 0 => {
                    len += n;
                    last_byte = Instant::now();
                }
                Ok(_) if self.link.is_none() => {
                    // The robot closed its end (its port failed and it reopens, or it
                    // stopped): a new pair to open, as a serial port can be opened again.
                    pty = self.open_line().ok();
                    len = 0;
                    continue;
                }
                Ok(_) => {}
                Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(2)),
            }
            // A read request is 8 bytes; anything else ends with silence (here 3 ms, above the
            // spec's t3.5 at 19200 baud and up).
            let frame_len = if len >= rtu::REQUEST_LEN && matches!(buf[1], 0x03 | 0x04) {
                rtu::REQUEST_LEN
            } else if len > 0 && (last_byte.elapsed() > Duration::from_millis(3) || len == buf.len()) {
                len
            } else {
                continue;
            };
            let mut frame = [0u8; 2 * MAX_FRAME];
            frame[..frame_len].copy_from_slice(&buf[..frame_len]);
            buf.copy_within(frame_len..len, 0);
            len -= frame_len;
            if let Some((out, n)) = self.answer(&frame[..frame_len]) {
                let _ = p.write_all(&out[..n]);
            }
        }
    }

    /// A new line of this server's kind (a pseudo-terminal behind its symlink, or a socket pair).
    fn open_line(&self) -> io::Result<Line> {
        match &self.link {
            Some(link) => open_pty(link).map(Line::Pty),
            None => open_socket(&self.shared.socket_port),
        }
    }

    /// The bytes to send for one received frame, if any.
    fn answer(&mut self, frame: &[u8]) -> Option<([u8; 2 * MAX_FRAME], usize)> {
        let mut out = [0u8; 2 * MAX_FRAME];
        let mut tx = [0u8; MAX_FRAME];
        let exception = |unit, function, code| Response::Exception { unit, function, code };
        let resp = match rtu::decode_request(frame) {
            Ok(req) => {
                let (i, cell) = self.cells.iter().enumerate().find(|(_, c)| c.unit_id == req.unit)?;
                self.shared.requests.fetch_add(1, Ordering::Relaxed);
                let table = match cell.registers {
                    RegisterKind::Input => Function::ReadInputRegisters,
                    RegisterKind::Holding => Function::ReadHoldingRegisters,
                };
                let (lo, hi) = (u32::from(req.address), u32::from(req.address) + u32::from(req.quantity));
                let (r0, r1) = (u32::from(cell.register), u32::from(cell.register) + 2);
                if req.function != table || lo < r0 || hi > r1 {
                    exception(req.unit, req.function.code(), ExceptionCode::IllegalDataAddress)
                } else {
                    let regs = value::registers_for(self.tensions.get(i), cell);
                    let vals = &regs[(lo - r0) as usize..(hi - r0) as usize];
                    Response::Registers(Registers::new(req.unit, req.function, vals))
                }
            }
            Err(RtuError::UnsupportedFunction { function }) if self.cells.iter().any(|c| c.unit_id == frame[0]) => {
                self.shared.requests.fetch_add(1, Ordering::Relaxed);
                exception(frame[0], function & 0x7F, ExceptionCode::IllegalFunction)
            }
            Err(RtuError::Quantity { .. }) if self.cells.iter().any(|c| c.unit_id == frame[0]) => {
                self.shared.requests.fetch_add(1, Ordering::Relaxed);
                exception(frame[0], frame[1], ExceptionCode::IllegalDataValue)
            }
            Err(_) => {
                self.shared.bad_frames.fetch_add(1, Ordering::Relaxed);
                return None;
            }
        };
        let unit = resp.unit();
        let fault = {
            let mut faults = self.shared.faults.lock().unwrap_or_else(|e| e.into_inner());
            let hit = faults.iter_mut().find(|f| f.left > 0 && f.unit.is_none_or(|u| u == unit));
            let fault = hit.map(|f| {
                f.left -= 1;
                f.fault
            });
            faults.retain(|f| f.left > 0);
            fault
        };
        let n = match fault {
            None => {
                if matches!(resp, Response::Registers(_)) {
                    self.shared.answered.fetch_add(1, Ordering::Relaxed);
                }
                let n = rtu::encode_response(&resp, &mut tx);
                out[..n].copy_from_slice(&tx[..n]);
                n
            }
            Some(f) => {
                self.shared.faults_applied.fetch_add(1, Ordering::Relaxed);
                match f {
                    LoadCellFault::Silence => return None,
                    LoadCellFault::BadCrc => {
                        let n = rtu::encode_response(&resp, &mut tx);
                        out[..n].copy_from_slice(&tx[..n]);
                        out[n - 1] ^= 0x5A;
                        n
                    }
                    LoadCellFault::Garbage => {
                        self.fill_noise(&mut out[..7]);
                        7
                    }
                    LoadCellFault::NoiseThenAnswer => {
                        self.fill_noise(&mut out[..3]);
                        let n = rtu::encode_response(&resp, &mut tx);
                        out[3..3 + n].copy_from_slice(&tx[..n]);
                        3 + n
                    }
                    LoadCellFault::Exception(code) => {
                        let function = frame.get(1).copied().unwrap_or(0) & 0x7F;
                        let n = rtu::encode_response(&exception(unit, function, ExceptionCode::from_code(code)), &mut tx);
                        out[..n].copy_from_slice(&tx[..n]);
                        n
                    }
                }
            }
        };
        Some((out, n))
    }

    /// Deterministic noise (xorshift32).
    fn fill_noise(&mut self, out: &mut [u8]) {
        for b in out {
            self.noise ^= self.noise << 13;
            self.noise ^= self.noise >> 17;
            self.noise ^= self.noise << 5;
            *b = self.noise as u8;
        }
    }
}
