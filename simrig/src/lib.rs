//! The simulated robot for `taut start --sim`: `taut-sim`'s [`Plant`] behind the same device
//! interfaces as the real robot, so the loop runs [`RobotDevices`] — the hardware code path —
//! against it:
//!
//! ```text
//!  loop ── RobotDevices ──CANopen master── CAN (virtual bus, or vcan via SocketCAN) ──┐
//!   │                                                                                 │
//!   │     ┌──────────────── "sim-robot" thread (1 kHz, wall clock) ─────────────────┐ │
//!   │     │ virtual CiA 402 drives (taut-vdev) <── targets / actuals ──> Plant       │◄┘
//!   │     │ tensions ──> virtual Modbus RTU load cells on a pty                      │
//!   │     │ tracker (100 Hz, noise, outliers, dropouts) ──> UDP on loopback          │
//!   │     └──────────────────────────────────────────────────────────────────────────┘
//!   ├── Modbus RTU master I/O thread (taut-driver) <── pty
//!   └── tracker receiver thread (taut-driver) <── UDP
//! ```
//!
//! The drives run in cyclic synchronous position or torque as the master switches them; before
//! they are enabled, in quick stop and in fault, their brakes hold the drums. Unit conversions
//! are the simulator's own (from the `[cable.drive]` tables), not the driver's.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_config::RobotConfig;
use taut_driver::transport::virtual_bus::{CanController, VirtualBus};
use taut_io::robot_io::{Peripherals, RobotDevices};
use taut_model::MAX_CABLES;
use taut_proto::can::CanTransport;
use taut_proto::canopen::cia402::Mode;
use taut_proto::canopen::NodeId;
use taut_proto::devices::{DriveConfig, LoadCellBusConfig, LoadCellConfig, TrackerConfig};
use taut_rt::io::{Devices, Inputs, Outputs};
use taut_sim::sensors::Tracker;
use taut_sim::{CableCommand as SimCommand, Noise, Physics, Plant, Truth};
use taut_vdev::{rack_filters, DriveParams, DriveRack, LoadCellFault, TensionHandle, TrackerSender, VirtualDrive, VirtualLoadCells};

/// Faults to inject into the simulated devices (set from any thread).
#[derive(Debug, Default)]
pub struct SimFaults {
    /// Load cells stop answering.
    pub loadcell_silent: AtomicBool,
    /// The tracker stops sending.
    pub tracker_gone: AtomicBool,
    /// Drive of cable 1 reports an EMCY (0x2310, continuous over-current) and faults.
    pub drive_emcy: AtomicBool,
    /// Drive of cable 1 stops sending heartbeats (and sends them again when cleared).
    pub heartbeat_lost: AtomicBool,
    /// Drive of cable 1 is power cycled (once per `true`; the switch goes back to `false`):
    /// it boots with its power-on settings and keeps its absolute position.
    pub drive_power_cycle: AtomicBool,
    /// Drive of cable 1 has a fault whose cause stays while this is set: it faults (EMCY
    /// 0x2310), and after each fault reset it faults again at once.
    pub drive_fault_persists: AtomicBool,
    /// Plant steps that found no equilibrium (the plant kept the last one), for tests to print.
    pub plant_failed_steps: AtomicU64,
}

/// A simulated robot ready for the daemon.
pub struct SimRobot {
    /// The site's true parameters (for the summary; the daemon never sees them).
    pub truth: Truth,
    /// Fault switches.
    pub faults: Arc<SimFaults>,
    /// The devices to hand to the daemon.
    pub devices: Box<dyn Devices>,
    /// The tracker receiver's counters.
    pub tracker_stats: taut_driver::tracker::TrackerStatsHandle,
    /// The master's endpoint on the in-process bus, to inject error frames and bus-off (`None`
    /// on SocketCAN, where the kernel reports them).
    pub can: Option<CanController>,
    /// Where the platform really is (the daemon never sees it).
    pub platform: PlatformTruth,
    /// How late the site thread handled the SYNCs (for tests and measurements).
    pub sync_stats: Arc<SyncStats>,
}

/// The plant's platform position, and each cable's true tension and drum length, published by
/// the site thread after every step.
#[derive(Debug, Clone, Default)]
pub struct PlatformTruth(Arc<[AtomicU64; 3 + 2 * MAX_CABLES]>);

impl PlatformTruth {
    fn set(&self, p: [f64; 3]) {
        for (a, v) in self.0.iter().zip(p) {
            // Relaxed: three independent readings for people and tests; a torn triple is off by
            // one plant step (microns), which no caller resolves.
            a.store(v.to_bits(), Ordering::Relaxed);
        }
    }

    fn set_cables(&self, tension_n: &[f64], drum_m: &[f64]) {
        for (j, (t, d)) in tension_n.iter().zip(drum_m).enumerate().take(MAX_CABLES) {
            // Relaxed: see `set`.
            self.0[3 + j].store(t.to_bits(), Ordering::Relaxed);
            self.0[3 + MAX_CABLES + j].store(d.to_bits(), Ordering::Relaxed);
        }
    }

    /// The platform's true position, m.
    pub fn position(&self) -> [f64; 3] {
        // Relaxed: see `set`.
        std::array::from_fn(|i| f64::from_bits(self.0[i].load(Ordering::Relaxed)))
    }

    /// Each cable's true platform-end tension (no load-cell offset or noise), N, and drum length
    /// (the unstretched cable paid out, no encoder effects), m; zero past the cable count.
    pub fn cables(&self) -> ([f64; MAX_CABLES], [f64; MAX_CABLES]) {
        // Relaxed: see `set`.
        let get = |i: usize| f64::from_bits(self.0[i].load(Ordering::Relaxed));
        (std::array::from_fn(|j| get(3 + j)), std::array::from_fn(|j| get(3 + MAX_CABLES + j)))
    }
}

/// How long after a SYNC was on the bus the site thread handled it: the wake-up latency a real
/// drive (its own processor) does not have. Upper bucket bounds in [`SyncStats::BOUNDS_US`]; the
/// last bucket counts the rest.
#[derive(Debug, Default)]
pub struct SyncStats {
    buckets: [AtomicU64; 8],
    max_ns: AtomicU64,
    sum_ns: AtomicU64,
    /// Tracker poses sent, and the delay from the instant they describe to their sending: a
    /// transit the receiver cannot see, which shifts its `measured` instants later.
    poses: AtomicU64,
    pose_delay_sum_ns: AtomicU64,
    pose_delay_min_ns: AtomicU64,
    /// SYNCs handled more than one SYNC period after they were on the bus.
    overrun: AtomicU64,
}

impl SyncStats {
    /// Upper bounds of the latency buckets, µs.
    pub const BOUNDS_US: [u64; 7] = [50, 100, 250, 500, 1000, 2000, 5000];

    fn record(&self, latency: Duration, overrun: bool) {
        let us = latency.as_micros() as u64;
        let k = Self::BOUNDS_US.iter().position(|&b| us < b).unwrap_or(Self::BOUNDS_US.len());
        // Relaxed: counters for people and tests, read after the fact.
        self.buckets[k].fetch_add(1, Ordering::Relaxed);
        let ns = latency.as_nanos() as u64;
        self.sum_ns.fetch_add(ns, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
        if overrun {
            self.overrun.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn record_pose(&self, delay: Duration) {
        let ns = delay.as_nanos() as u64;
        // Relaxed: see `record`. The minimum starts at 0 = "none yet".
        let n = self.poses.fetch_add(1, Ordering::Relaxed);
        self.pose_delay_sum_ns.fetch_add(ns, Ordering::Relaxed);
        if n == 0 {
            self.pose_delay_min_ns.store(ns, Ordering::Relaxed);
        } else {
            self.pose_delay_min_ns.fetch_min(ns, Ordering::Relaxed);
        }
    }

    /// Tracker poses sent, the mean and the smallest delay from their instant to their sending, s.
    pub fn pose_delay_s(&self) -> (u64, f64, f64) {
        let n = self.poses.load(Ordering::Relaxed);
        let mean = self.pose_delay_sum_ns.load(Ordering::Relaxed) as f64 * 1e-9 / n.max(1) as f64;
        (n, mean, self.pose_delay_min_ns.load(Ordering::Relaxed) as f64 * 1e-9)
    }

    /// SYNCs handled.
    pub fn count(&self) -> u64 {
        self.buckets.iter().map(|b| b.load(Ordering::Relaxed)).sum()
    }

    /// Counts per bucket (see [`SyncStats::BOUNDS_US`]).
    pub fn buckets(&self) -> [u64; 8] {
        std::array::from_fn(|k| self.buckets[k].load(Ordering::Relaxed))
    }

    /// Mean and largest latency, s.
    pub fn mean_max_s(&self) -> (f64, f64) {
        let n = self.count().max(1) as f64;
        (self.sum_ns.load(Ordering::Relaxed) as f64 * 1e-9 / n, self.max_ns.load(Ordering::Relaxed) as f64 * 1e-9)
    }

    /// SYNCs handled only after the next SYNC was on the bus.
    pub fn overruns(&self) -> u64 {
        self.overrun.load(Ordering::Relaxed)
    }
}

impl std::fmt::Display for SyncStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (mean, max) = self.mean_max_s();
        write!(f, "{} SYNCs handled {:.3} ms (mean) / {:.3} ms (max) after the bus instant; <", self.count(), mean * 1e3, max * 1e3)?;
        let b = self.buckets();
        for (k, us) in Self::BOUNDS_US.iter().enumerate() {
            write!(f, " {us}us:{}", b[k])?;
        }
        let (n, mean, min) = self.pose_delay_s();
        write!(
            f,
            " more:{}; overruns {}; {n} poses sent {:.3} ms (mean) / {:.3} ms (min) after their instant",
            b[7],
            self.overruns(),
            mean * 1e3,
            min * 1e3
        )
    }
}

/// Options of the simulated site.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Random seed of the site and the noise.
    pub seed: u64,
    /// How far the true anchors are from the nominal ones, at most, m.
    pub site_error_m: f64,
    /// Encoder offsets drawn in +- this, m.
    pub l0_range_m: f64,
    /// Sensor noise.
    pub noise: Noise,
    /// SocketCAN interface (e.g. `vcan0`) for the virtual drives and the master; `None`: an
    /// in-process virtual CAN bus.
    pub can: Option<String>,
    /// Physics step of the simulated site (wall clock); also stepped at every SYNC.
    pub site_period: Duration,
    /// The site's cable physics: effects concealed from the robot (elasticity, drum scale,
    /// swivel pulleys...). The default has none but loose cables.
    pub physics: Physics,
    /// The site has a tracker (default). `false`: no pose is ever sent and the robot gets no
    /// tracker input (`taut start --sim --no-tracker`).
    pub tracker: bool,
    /// What carries the load cells' RS-485 line in wall-clock time ([`build`]).
    pub load_cell_line: LoadCellLine,
    /// How the drives and load cells are really wired to the cables (default: as configured).
    pub wiring: Wiring,
}

/// What carries the simulated load cells' Modbus RTU line to the robot's load-cell I/O thread
/// in wall-clock time (the same bytes, master and thread either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LoadCellLine {
    /// A Unix stream socket pair: no kernel terminal layer to delay the answers on a loaded
    /// machine.
    #[default]
    Socket,
    /// A pseudo-terminal, opened by path as the robot opens its serial port.
    Pty,
}

/// How the simulated site's drives and load cells are really wired to its cables: a wiring
/// mistake the robot is not told of. Empty vectors: as configured.
///
/// - `drive_of_cable[j] = c`: the drive configured for cable `j` really winds cable `c`'s drum
///   (targets, torque and encoder).
/// - `load_cell_of_cable[j] = c`: the load cell configured for cable `j` really measures cable
///   `c`'s tension.
/// - `encoder_inverted[j]`: cable `j`'s drive counts opposite to the configured encoder map; it
///   closes its position loop on those counts, so it turns the drum the other way and reports
///   what was commanded. Counts are mirrored about the reading at build time.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Wiring {
    /// The cable each configured cable's drive really winds (a permutation; empty: identity).
    pub drive_of_cable: Vec<usize>,
    /// The cable each configured cable's load cell really measures (a permutation; empty:
    /// identity).
    pub load_cell_of_cable: Vec<usize>,
    /// Each configured cable's drive counts opposite to the encoder map (empty: none).
    pub encoder_inverted: Vec<bool>,
}

impl Wiring {
    /// As configured.
    pub fn correct() -> Wiring {
        Wiring::default()
    }

    /// The drives of cables `i` and `j` of an `n`-cable robot exchanged (each winds the other's
    /// drum).
    pub fn swapped_drives(n: usize, i: usize, j: usize) -> Wiring {
        Wiring { drive_of_cable: swapped(n, i, j), ..Wiring::default() }
    }

    /// The load cells of cables `i` and `j` exchanged (each measures the other's tension).
    pub fn swapped_load_cells(n: usize, i: usize, j: usize) -> Wiring {
        Wiring { load_cell_of_cable: swapped(n, i, j), ..Wiring::default() }
    }

    /// The encoder of cable `j`'s drive counting the other way.
    pub fn inverted_encoder(n: usize, j: usize) -> Wiring {
        Wiring { encoder_inverted: (0..n).map(|k| k == j).collect(), ..Wiring::default() }
    }

    /// The wiring resolved for `n` cables: `None` when a map is not a permutation of `0..n`
    /// (or has another length).
    fn resolve(&self, n: usize) -> Option<Wires> {
        let perm = |v: &[usize]| -> Option<[usize; MAX_CABLES]> {
            let mut out: [usize; MAX_CABLES] = std::array::from_fn(|j| j);
            if v.is_empty() {
                return Some(out);
            }
            let mut seen = [false; MAX_CABLES];
            if v.len() != n {
                return None;
            }
            for (j, &c) in v.iter().enumerate() {
                if c >= n || seen[c] {
                    return None;
                }
                seen[c] = true;
                out[j] = c;
            }
            Some(out)
        };
        if !(self.encoder_inverted.is_empty() || self.encoder_inverted.len() == n) {
            return None;
        }
        Some(Wires {
            drive_on: perm(&self.drive_of_cable)?,
            cell_on: perm(&self.load_cell_of_cable)?,
            inverted: std::array::from_fn(|j| self.encoder_inverted.get(j).copied().unwrap_or(false)),
            mirror_m: [0.0; MAX_CABLES],
        })
    }
}

fn swapped(n: usize, i: usize, j: usize) -> Vec<usize> {
    let mut v: Vec<usize> = (0..n).collect();
    v.swap(i, j);
    v
}

/// [`Wiring`] as the site applies it.
#[derive(Debug, Clone, Copy)]
struct Wires {
    /// The plant cable of each drive.
    drive_on: [usize; MAX_CABLES],
    /// The plant cable of each load cell.
    cell_on: [usize; MAX_CABLES],
    /// Per drive: its counts run opposite to the encoder map.
    inverted: [bool; MAX_CABLES],
    /// Per inverted drive: the reading its counts are mirrored about, m.
    mirror_m: [f64; MAX_CABLES],
}

impl Wires {
    /// What drive `d` reports for its drum's true reading `reading`, m of the encoder map.
    fn reported(&self, d: usize, reading: f64) -> f64 {
        if self.inverted[d] {
            2.0 * self.mirror_m[d] - reading
        } else {
            reading
        }
    }

    /// The drum's true reading at which drive `d` reports `reported` (the inverse).
    fn true_reading(&self, d: usize, reported: f64) -> f64 {
        // The mirror is its own inverse.
        self.reported(d, reported)
    }

    /// The load cells' tensions from the plant's cables'.
    fn cells(&self, plant_n: &[f64], out: &mut [f64]) {
        for (j, t) in out.iter_mut().enumerate() {
            *t = plant_n[self.cell_on[j]];
        }
    }
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            seed: 1,
            site_error_m: 0.2,
            l0_range_m: 2.0,
            noise: Noise::default(),
            can: None,
            site_period: Duration::from_millis(1),
            physics: Physics::default(),
            tracker: true,
            load_cell_line: LoadCellLine::default(),
            wiring: Wiring::default(),
        }
    }
}

/// The simulated site's true parameters for `cfg` and `opts`: what [`build`] and
/// [`Lockstep::start`] build the robot on.
pub fn site_truth(cfg: &RobotConfig, opts: &SimOptions) -> Result<Truth, taut_sim::SimError> {
    Truth::sample(cfg, &opts.physics, opts.site_error_m, opts.l0_range_m, &mut taut_sim::rng(opts.seed, 0))
}

/// Where an operator would park the platform before the start-up: the simulator's rest position
/// for the three-phase motion of `cfg.motion` (most tension margin for the held cables), or
/// `fallback` if it finds none.
pub fn rest_position(cfg: &RobotConfig, opts: &SimOptions, fallback: [f64; 3]) -> [f64; 3] {
    let physics = opts.physics.clone();
    let Ok(truth) = site_truth(cfg, opts) else { return fallback };
    let m = &cfg.motion;
    // Phase k of the plan reels cables[k]; ours reels init_phases[k][2].
    let mut cables = [0usize; 3];
    for (k, ph) in m.init_phases.iter().take(3).enumerate() {
        cables[k] = ph[2];
    }
    let plan = taut_sim::ThreePhasePlan {
        reel_m: m.init_reel_m.abs(),
        speed_m_s: m.init_reel_speed_m_s,
        follower_tension_n: m.init_follower_tension_n,
        cables,
        dwell_s: 0.5,
        start: None,
    };
    let nominal = cfg.anchors().unwrap_or_else(|| truth.anchors.clone());
    let ws = taut_sim::trajectory::Workspace::from_anchors(&nominal);
    taut_sim::three_phase::simulate(&truth, &physics, &plan, &ws, 20.0).map_or(fallback, |mo| mo.start)
}

/// Why the simulated robot could not be built. `Display` names the cable, interface or device
/// and what to do.
#[derive(Debug)]
pub enum BuildError {
    /// More cables than the loop handles.
    TooManyCables {
        /// Cables in the configuration.
        n: usize,
    },
    /// A cable without a `[cable.drive]` table.
    NoDrive {
        /// Index of the cable.
        cable: usize,
    },
    /// The simulated site could not be drawn or placed (`what` says which step).
    Site {
        /// The step, e.g. `no rest position at [..]`; empty for the drawing of the site.
        what: String,
        /// The simulator's reason.
        error: taut_sim::SimError,
    },
    /// `SimOptions::wiring` is not a permutation of the robot's cables.
    Wiring {
        /// Cables in the configuration.
        n: usize,
    },
    /// The platform cannot hang at `p0` with every cable in tension.
    NoRest {
        /// The asked position, m.
        p0: [f64; 3],
    },
    /// A SocketCAN interface could not be opened.
    Can {
        /// Who opens it (`virtual drives`, `CANopen master`).
        who: &'static str,
        /// The interface.
        iface: String,
        /// The operating system's reason.
        error: std::io::Error,
    },
    /// SocketCAN asked for off Linux.
    NoSocketCan {
        /// The interface.
        iface: String,
    },
    /// A simulated device or its robot-side reader did not start (`what` names it).
    Device {
        /// `virtual load cells`, `tracker receiver`, ...
        what: &'static str,
        /// The operating system's reason.
        error: std::io::Error,
    },
    /// The robot's load-cell bus (on the simulated cells' pseudo-terminal) did not start.
    LoadCells(taut_driver::loadcell::SpawnError),
    /// The robot's devices did not come up.
    BringUp(taut_io::robot_io::BringUpError),
}

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BuildError::TooManyCables { n } => write!(f, "{n} cables: at most {MAX_CABLES}"),
            BuildError::NoDrive { cable } => write!(f, "cable[{cable}]: the simulated robot needs a [cable.drive] table with a node_id"),
            BuildError::Site { what, error } if what.is_empty() => write!(f, "simulated site: {error}"),
            BuildError::Site { what, error } => write!(f, "simulated site: {what}: {error}"),
            BuildError::Wiring { n } => {
                write!(f, "simulated site: the wiring's maps must be permutations of the {n} cables (and one inversion flag per cable)")
            }
            BuildError::NoRest { p0 } => write!(f, "simulated site: the platform cannot rest at {p0:?} with positive tensions"),
            BuildError::Can { who, iface, error } => {
                write!(f, "{who} on CAN interface {iface}: {error} (is it up? `ip link set {iface} up`)")
            }
            BuildError::NoSocketCan { iface } => write!(f, "CAN interface {iface}: SocketCAN needs Linux"),
            BuildError::Device { what, error } => write!(f, "{what}: {error}"),
            BuildError::LoadCells(e) => write!(f, "{e}"),
            BuildError::BringUp(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for BuildError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BuildError::Site { error, .. } => Some(error),
            BuildError::Can { error, .. } | BuildError::Device { error, .. } => Some(error),
            BuildError::LoadCells(e) => Some(e),
            BuildError::BringUp(e) => Some(e),
            BuildError::TooManyCables { .. }
            | BuildError::NoDrive { .. }
            | BuildError::Wiring { .. }
            | BuildError::NoRest { .. }
            | BuildError::NoSocketCan { .. } => None,
        }
    }
}

/// Builds the simulated robot of `cfg` (a `[cable.drive]` per cable) with the platform at `p0`,
/// starts it, and brings its drives up through the CANopen master, on an in-process bus or on
/// the SocketCAN interface `opts.can`.
pub fn build(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions) -> Result<SimRobot, BuildError> {
    match &opts.can {
        None => {
            let bus = VirtualBus::named("vcan-sim");
            let nodes = node_ids(cfg)?;
            let rack_end = bus.endpoint_with(1024, &rack_filters(&nodes));
            let master_end = bus.endpoint_with(1024, &[]);
            let can = master_end.controller();
            let mut sim = build_on(cfg, p0, opts, rack_end, master_end)?;
            sim.can = Some(can);
            Ok(sim)
        }
        Some(iface) => {
            #[cfg(target_os = "linux")]
            {
                use taut_driver::transport::socketcan::SocketCanTransport;
                let open = |who: &'static str| {
                    SocketCanTransport::open(iface).map_err(|error| BuildError::Can { who, iface: iface.clone(), error })
                };
                build_on(cfg, p0, opts, open("virtual drives")?, open("CANopen master")?)
            }
            #[cfg(not(target_os = "linux"))]
            {
                Err(BuildError::NoSocketCan { iface: iface.clone() })
            }
        }
    }
}

/// The simulated site alone, for a robot side that opens its devices itself (plugin-owned mode,
/// `taut start` on the configuration): drives on the SocketCAN interface `opts.can`, load cells
/// on [`SiteOnly::loadcell_port`], tracker datagrams to `tracker_to` (when `opts.tracker`).
/// The site stops when the value is dropped.
#[cfg(target_os = "linux")]
pub fn build_site(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions, tracker_to: std::net::SocketAddr) -> Result<SiteOnly, BuildError> {
    use taut_driver::transport::socketcan::SocketCanTransport;
    let Some(iface) = &opts.can else { return Err(BuildError::NoSocketCan { iface: String::new() }) };
    let rack_bus =
        SocketCanTransport::open(iface).map_err(|error| BuildError::Can { who: "virtual drives", iface: iface.clone(), error })?;
    let parts = draw_site(cfg, p0, opts)?;
    let truth = parts.truth.clone();
    let cell_cfgs = parts.cells.iter().map(|c| c.1.clone()).collect();
    let vlc = VirtualLoadCells::spawn(cell_cfgs, parts.handle.clone())
        .map_err(|e| BuildError::Device { what: "virtual load cells", error: e })?;
    let loadcell_port = vlc.path().to_path_buf();
    if let Err(e) = vlc.set_realtime(sim_cells_priority(cfg)) {
        eprintln!("taut-simrig: SCHED_FIFO for the simulated load cells refused ({e})");
    }
    let sender = match opts.tracker {
        true => Some(TrackerSender::new(tracker_to).map_err(|e| BuildError::Device { what: "tracker sender", error: e })?),
        false => None,
    };
    let io = SiteIo { rack_bus, vlc: Some(vlc), sender, clock: taut_driver::clock::wall(), now: Instant::now() };
    let running = parts.run(io, opts, cfg)?;
    Ok(SiteOnly { truth, faults: running.faults, loadcell_port, _site: running.thread })
}

/// A running simulated site without the robot's side ([`build_site`]).
pub struct SiteOnly {
    /// The site's true parameters.
    pub truth: Truth,
    /// Fault switches.
    pub faults: Arc<SimFaults>,
    /// The pseudo-terminal the virtual load cells answer on.
    pub loadcell_port: std::path::PathBuf,
    _site: SiteThread,
}

fn node_ids(cfg: &RobotConfig) -> Result<Vec<NodeId>, BuildError> {
    cfg.cables.iter().enumerate().map(|(j, c)| c.drive.as_ref().map(|d| d.node_id).ok_or(BuildError::NoDrive { cable: j })).collect()
}

/// The simulator's view of a drive's units (its own arithmetic, from the configuration).
#[derive(Debug, Clone, Copy)]
struct DriveUnits {
    /// Encoder counts per metre of cable (signed).
    counts_per_m: f64,
    /// Cable tension, N, per ‰ of rated torque (signed: a motor pulling the cable in gives
    /// negative torque with `invert = false`).
    n_per_permille: f64,
}

impl DriveUnits {
    fn of(d: &DriveConfig) -> DriveUnits {
        let sign = if d.invert { -1.0 } else { 1.0 };
        let drum_circumference = std::f64::consts::TAU * d.drum_radius_m;
        DriveUnits {
            counts_per_m: sign * f64::from(d.counts_per_rev) * d.gear_ratio / drum_circumference,
            n_per_permille: -sign * d.rated_torque_nm / 1000.0 * d.gear_ratio / d.drum_radius_m,
        }
    }
}

/// The simulated site before any device exists: its truth, the plant settled on the brakes at
/// `p0`, the virtual drives reading the plant's encoders, and the cells' tensions.
struct SiteParts {
    truth: Truth,
    plant: Plant,
    units: Vec<DriveUnits>,
    brake: Vec<f64>,
    cmds: Vec<SimCommand>,
    drives: Vec<VirtualDrive>,
    cells: Vec<(usize, LoadCellConfig)>,
    handle: TensionHandle,
    wires: Wires,
}

fn draw_site(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions) -> Result<SiteParts, BuildError> {
    let n = cfg.cables.len();
    if n > MAX_CABLES {
        return Err(BuildError::TooManyCables { n });
    }
    let nodes = node_ids(cfg)?;
    let mut wires = opts.wiring.resolve(n).ok_or(BuildError::Wiring { n })?;
    let units: Vec<DriveUnits> = cfg.cables.iter().map(|c| DriveUnits::of(c.drive.as_ref().expect("checked by node_ids"))).collect();
    let physics = opts.physics.clone();
    let truth = site_truth(cfg, opts).map_err(|error| BuildError::Site { what: String::new(), error })?;
    let mut plant = Plant::new(&truth, &physics, p0).with_noise(&opts.noise, opts.seed);
    let tensions = rest_tensions(&truth.anchors, p0, truth.mass_kg, cfg.motion.init_follower_tension_n).ok_or(BuildError::NoRest { p0 })?;
    let brake =
        plant.lengths_holding(p0, &tensions).map_err(|error| BuildError::Site { what: format!("no rest position at {p0:?}"), error })?;
    let cmds: Vec<SimCommand> = brake.iter().map(|&d| SimCommand::Length(d)).collect();
    let mut enc = vec![0.0; n];
    let mut ten = vec![0.0; n];
    for _ in 0..5 {
        let out = plant.step(0.002, &cmds);
        enc.copy_from_slice(out.encoder_m);
        ten.copy_from_slice(out.tension_n);
    }
    // The plant owns each drive's position and torque, on the drum it is wired to.
    for d in 0..n {
        wires.mirror_m[d] = enc[wires.drive_on[d]];
    }
    let drives: Vec<VirtualDrive> = nodes
        .iter()
        .zip(&units)
        .enumerate()
        .map(|(k, (&id, u))| {
            let mut d = VirtualDrive::new(DriveParams::new(id));
            d.set_external(true);
            d.set_actual(counts(wires.reported(k, enc[wires.drive_on[k]]) * u.counts_per_m), 0);
            d
        })
        .collect();
    let cells: Vec<(usize, LoadCellConfig)> =
        cfg.cables.iter().enumerate().map(|(j, c)| (j, c.loadcell.clone().unwrap_or_else(|| LoadCellConfig::new(j as u8 + 1)))).collect();
    let handle = TensionHandle::new(n);
    let mut cell_n = vec![0.0; n];
    wires.cells(&ten, &mut cell_n);
    handle.set_all(&cell_n);
    Ok(SiteParts { truth, plant, units, brake, cmds, drives, cells, handle, wires })
}

/// What the site's devices and its clock are.
struct SiteIo<R: CanTransport> {
    rack_bus: R,
    vlc: Option<VirtualLoadCells>,
    sender: Option<TrackerSender>,
    clock: taut_driver::clock::SharedClock,
    now: Instant,
}

/// A simulated site running on its own thread ([`SiteParts::run`]).
struct RunningSite {
    thread: SiteThread,
    faults: Arc<SimFaults>,
    platform: PlatformTruth,
    sync_stats: Arc<SyncStats>,
}

impl SiteParts {
    /// The site on its own thread, `SCHED_FIFO` where allowed: the drives, plant and tracker stand
    /// in for hardware with its own processors, which a loaded robot computer does not slow down.
    fn run<R: CanTransport + Send + 'static>(self, io: SiteIo<R>, opts: &SimOptions, cfg: &RobotConfig) -> Result<RunningSite, BuildError> {
        let mut site = self.into_site(io, opts);
        let (faults, stop, platform, sync_stats) = (site.faults.clone(), site.stop.clone(), site.platform.clone(), site.sync_stats.clone());
        let thread = std::thread::Builder::new()
            .name("sim-robot".into())
            .spawn(move || site.run())
            .map_err(|e| BuildError::Device { what: "starting the simulated robot", error: e })?;
        if let Err(e) = taut_driver::sched::set_fifo(&thread, sim_cells_priority(cfg)) {
            eprintln!(
                "taut-simrig: SCHED_FIFO for the simulated robot refused ({e}): on a loaded machine the drives may answer late; run as root or grant CAP_SYS_NICE"
            );
        }
        Ok(RunningSite { thread: SiteThread { stop, thread: Some(thread) }, faults, platform, sync_stats })
    }

    fn into_site<R: CanTransport>(self, io: SiteIo<R>, opts: &SimOptions) -> Site<R> {
        let platform = PlatformTruth::default();
        platform.set(self.plant.position());
        let now = io.now;
        Site {
            platform,
            ramps: self.brake.iter().map(|&d| Ramp { from: d, to: d, target: None, start: now, dur_s: 0.0 }).collect(),
            last_step: now,
            prev_step: None,
            last_enc: [0.0; MAX_CABLES],
            last_tq: [0; MAX_CABLES],
            last_sync: None,
            sync_period_s: None,
            sync_clock: None,
            sync_stats: Arc::new(SyncStats::default()),
            rack: DriveRack::new(io.rack_bus, self.drives),
            plant: self.plant,
            units: self.units,
            drum: self.brake,
            cmds: self.cmds,
            vlc: io.vlc,
            handle: self.handle,
            wires: self.wires,
            sender: io.sender,
            clock: io.clock,
            tracker: opts.tracker.then(|| Tracker::new(&opts.noise)),
            rng: taut_sim::rng(opts.seed, 7),
            faults: Arc::new(SimFaults::default()),
            stop: Arc::new(AtomicBool::new(false)),
            period: opts.site_period,
            silenced: false,
            emcy_sent: false,
            hb_off: false,
        }
    }
}

fn build_on<R, M>(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions, rack_bus: R, master_bus: M) -> Result<SimRobot, BuildError>
where
    R: CanTransport + Send + 'static,
    M: CanTransport + Send + 'static,
{
    let n = cfg.cables.len();
    let parts = draw_site(cfg, p0, opts)?;
    let truth = parts.truth.clone();
    let cells = parts.cells.clone();
    let cell_cfgs = cells.iter().map(|c| c.1.clone()).collect();
    let vlc = match opts.load_cell_line {
        LoadCellLine::Socket => VirtualLoadCells::spawn_socket(cell_cfgs, parts.handle.clone()),
        LoadCellLine::Pty => VirtualLoadCells::spawn(cell_cfgs, parts.handle.clone()),
    }
    .map_err(|e| BuildError::Device { what: "virtual load cells", error: e })?;
    let mut lc_bus = cfg.loadcells.clone().unwrap_or_else(|| LoadCellBusConfig::new(""));
    lc_bus.port = vlc.path().display().to_string();
    lc_bus.max_age_s = cfg.safety.tension_max_age_s;
    let loadcells = match vlc.socket_port() {
        Some(port) => taut_driver::loadcell::spawn_with(&lc_bus, &cells, n, move || port.open()),
        None => taut_driver::loadcell::spawn(&lc_bus, &cells, n),
    }
    .map_err(BuildError::LoadCells)?;
    loadcells_realtime(cfg, &vlc, &loadcells.0);
    let mut tcfg = TrackerConfig::new("127.0.0.1:0");
    tcfg.max_age_s = cfg.safety.tracker_max_age_s;
    let (tracker, pose) = taut_driver::tracker::spawn(&tcfg).map_err(|e| BuildError::Device { what: "tracker receiver", error: e })?;
    if cfg.rt.priority > 1 {
        // The robot's rule (taut_io::robot_io::Peripherals): just below a real-time loop.
        if let Err(e) = tracker.set_realtime(cfg.rt.priority - 1) {
            eprintln!("taut-simrig: SCHED_FIFO priority {} for the tracker thread refused ({e})", cfg.rt.priority - 1);
        }
    }
    let sender = TrackerSender::new(tracker.local_addr()).map_err(|e| BuildError::Device { what: "tracker sender", error: e })?;

    let io = SiteIo { rack_bus, vlc: Some(vlc), sender: Some(sender), clock: taut_driver::clock::wall(), now: Instant::now() };
    let RunningSite { thread: site, faults, platform, sync_stats } = parts.run(io, opts, cfg)?;
    let tracker_stats = pose.stats_handle();
    let peripherals = if opts.tracker {
        Peripherals { loadcells: Some(loadcells), tracker: Some(tracker), pose: Some(pose) }
    } else {
        // No tracker: the receiver is stopped (its counters stay at zero) and nothing is sent.
        drop((tracker, pose));
        Peripherals { loadcells: Some(loadcells), tracker: None, pose: None }
    };
    let devices = RobotDevices::bring_up(cfg, master_bus, peripherals).map_err(BuildError::BringUp)?;
    Ok(SimRobot { truth, faults, devices: Box::new(SimDevices { devices, _site: site }), tracker_stats, can: None, platform, sync_stats })
}

/// `SCHED_FIFO` priority of the virtual load cells' server thread: above the robot's load-cell
/// thread when that one is real-time too (the loop's priority - 1), at least 2.
fn sim_cells_priority(cfg: &RobotConfig) -> i32 {
    cfg.rt.priority.max(2)
}

/// Scheduling of the two ends of the simulated load-cell bus. The cells stand in for hardware
/// with its own processor, so their server always runs `SCHED_FIFO` (under the normal scheduler
/// a loaded machine delayed answers into the next exchange). The robot's end follows the
/// robot's rule (`taut_io::robot_io::Peripherals`); a refused priority is a warning.
fn loadcells_realtime(cfg: &RobotConfig, vlc: &VirtualLoadCells, io: &taut_driver::loadcell::LoadCellIo) {
    if let Err(e) = vlc.set_realtime(sim_cells_priority(cfg)) {
        eprintln!(
            "taut-simrig: SCHED_FIFO for the simulated load cells refused ({e}): on a loaded machine their answers may come late and the loop stop on stale tensions; run as root or grant CAP_SYS_NICE"
        );
    }
    if cfg.rt.priority > 1 {
        if let Err(e) = io.set_realtime(cfg.rt.priority - 1) {
            eprintln!("taut-simrig: SCHED_FIFO priority {} for the load-cell thread refused ({e})", cfg.rt.priority - 1);
        }
    }
}

fn counts(x: f64) -> i32 {
    x.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}

fn permille(x: f64) -> i16 {
    x.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// The loop's devices plus the simulated site they talk to (stopped after them).
struct SimDevices<T: CanTransport> {
    devices: RobotDevices<T>,
    _site: SiteThread,
}

impl<T: CanTransport + Send> Devices for SimDevices<T> {
    fn read(&mut self, now_s: f64, inputs: &mut Inputs) {
        self.devices.read(now_s, inputs)
    }
    fn write(&mut self, now_s: f64, outputs: &Outputs) {
        self.devices.write(now_s, outputs)
    }
}

struct SiteThread {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for SiteThread {
    fn drop(&mut self) {
        // Relaxed: the flag carries no data; join() synchronises.
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Everything on the simulator's side of the wires.
struct Site<R: CanTransport> {
    rack: DriveRack<R>,
    plant: Plant,
    units: Vec<DriveUnits>,
    drum: Vec<f64>,
    cmds: Vec<SimCommand>,
    /// The simulated load cells (`None` in lockstep, where the world answers the master itself).
    vlc: Option<VirtualLoadCells>,
    handle: TensionHandle,
    /// How the drives and load cells are really wired (see [`Wiring`]).
    wires: Wires,
    /// UDP to the tracker receiver (`None` in lockstep).
    sender: Option<TrackerSender>,
    /// When a frame is handled: the wall clock, or the lockstep simulation's.
    clock: taut_driver::clock::SharedClock,
    tracker: Option<Tracker>,
    rng: rand_chacha::ChaCha8Rng,
    faults: Arc<SimFaults>,
    platform: PlatformTruth,
    /// Per cable: the drum's motion from its last target to the new one (CSP).
    ramps: Vec<Ramp>,
    /// When the plant was last stepped to, and the encoder counts and torques there.
    last_step: Instant,
    /// The step before: (instant, encoder counts, torques), to latch at an instant between.
    prev_step: Option<(Instant, [f64; MAX_CABLES], [i16; MAX_CABLES])>,
    /// Encoder counts (unrounded) and torques at `last_step`.
    last_enc: [f64; MAX_CABLES],
    last_tq: [i16; MAX_CABLES],
    /// Bus instant of the last SYNC, and the interval before it, s.
    last_sync: Option<Instant>,
    sync_period_s: Option<f64>,
    /// The drives' SYNC clock: last SYNC instant and period (s), locked to the frames' arrival
    /// like a CSP drive's PLL, so a SYNC delayed on a busy bus does not bend the drums' paths.
    sync_clock: Option<(Instant, f64)>,
    sync_stats: Arc<SyncStats>,
    stop: Arc<AtomicBool>,
    period: Duration,
    silenced: bool,
    emcy_sent: bool,
    hb_off: bool,
}

mod lockstep;
pub use lockstep::{
    run_startup, BusStats, CanState, CanStatus, Lockstep, LockstepCan, LockstepError, LockstepFaults, LockstepRobot, RunOptions, SimFault,
    StartupRun,
};

/// Tracker period, s (100 Hz).
const TRACKER_PERIOD_S: f64 = 0.01;

impl<R: CanTransport> Site<R> {
    fn run(&mut self) {
        let t0 = Instant::now();
        let mut next = t0;
        self.last_step = t0;
        let mut next_pose = 0.0;
        // Relaxed: the flag carries no data.
        while !self.stop.load(Ordering::Relaxed) {
            // Every frame is handled here as it comes: `DriveRack::step` would drain the rest
            // of a burst (RPDOs and SYNC together) without the SYNC's latch.
            let mut sync = false;
            let mut first = self.rack.transport().recv_deadline(next);
            while let Ok(Some(f)) = first {
                sync |= self.on_frame(&f);
                first = self.rack.transport().try_recv();
            }
            let now = Instant::now();
            self.rack.step(now);
            if now < next || sync {
                continue;
            }
            next += self.period;
            if next < now {
                // Starved (loaded machine): skip ahead rather than run a burst of steps.
                next = now + self.period;
            }
            self.inject_faults();
            self.step_plant(now);
            let t = now.saturating_duration_since(t0).as_secs_f64();
            let due = t >= next_pose && !self.faults.tracker_gone.load(Ordering::Relaxed);
            if let (true, Some(tracker)) = (due, self.tracker.as_mut()) {
                next_pose = (next_pose + TRACKER_PERIOD_S).max(t);
                // The platform where it is at `now`, stamped `now` (the plant was stepped to it).
                let m = tracker.measure(self.plant.position(), &mut self.rng);
                if let (true, Some(sender)) = (m.iter().all(|v| v.is_finite()), &self.sender) {
                    let _ = sender.send_pose(t, m, None);
                    self.sync_stats.record_pose(now.elapsed());
                }
            }
        }
    }

    /// Delivers one frame to the drives at the instant it was on the bus; true for a SYNC.
    fn on_frame(&mut self, f: &taut_proto::can::Frame) -> bool {
        let now = self.clock.now();
        // When the frame was on the bus: a real drive sees it then, whatever this thread was
        // doing (SocketCAN without time stamps: when it was read).
        let at = self.rack.transport().rx_timestamp().map_or(now, |t| t.min(now));
        let sync = f.std_id() == Some(0x080);
        if sync {
            self.latch_at(at, now);
        }
        for d in self.rack.drives() {
            d.on_frame(f, at);
        }
        self.follow_targets(at);
        sync
    }

    /// A SYNC that was on the bus at `at`, handled at `now`: the drives' actual values become
    /// the plant's state at `at` (CiA 301 7.2.5: synchronous TPDOs carry what the drive sampled
    /// at the SYNC; the master stamps them with the SYNC's send time).
    fn latch_at(&mut self, at: Instant, now: Instant) {
        let latency = now.saturating_duration_since(at);
        let overrun = self.sync_period_s.is_some_and(|p| latency.as_secs_f64() > p);
        self.sync_stats.record(latency, overrun);
        if let Some(s) = self.last_sync.filter(|&s| at > s) {
            self.sync_period_s = Some(at.duration_since(s).as_secs_f64().clamp(2e-4, 0.02));
        }
        self.last_sync = Some(self.last_sync.map_or(at, |s| s.max(at)));
        let period_s = self.sync_period_s.unwrap_or(self.period.as_secs_f64());
        self.sync_clock = Some(match self.sync_clock {
            Some((t, p)) => {
                let predicted = t + Duration::from_secs_f64(p);
                let err =
                    if at >= predicted { at.duration_since(predicted).as_secs_f64() } else { -predicted.duration_since(at).as_secs_f64() };
                if err.abs() > 0.5 * p {
                    // A SYNC lost or the master restarted: lock again.
                    (at, period_s)
                } else {
                    let t = if err >= 0.0 {
                        predicted + Duration::from_secs_f64(0.1 * err)
                    } else {
                        predicted - Duration::from_secs_f64(-0.1 * err)
                    };
                    (t, (p + 0.02 * err).clamp(2e-4, 0.02))
                }
            }
            None => (at, period_s),
        });
        if at > self.last_step {
            self.step_plant(at);
            return;
        }
        // A tick stepped the plant past the SYNC before it was read: the encoders at `at`,
        // linearly between the last two steps.
        let Some((tp, enc_p, tq_p)) = self.prev_step else { return };
        let span = self.last_step.saturating_duration_since(tp).as_secs_f64();
        let s = if span > 0.0 { (at.saturating_duration_since(tp).as_secs_f64() / span).clamp(0.0, 1.0) } else { 1.0 };
        for j in 0..self.units.len() {
            let c = enc_p[j] + s * (self.last_enc[j] - enc_p[j]);
            let tq = if s < 0.5 { tq_p[j] } else { self.last_tq[j] };
            self.rack.drives()[j].set_actual(counts(c), tq);
        }
    }

    /// Starts a drum ramp for every cable whose position target changed (at bus instant `at`).
    fn follow_targets(&mut self, at: Instant) {
        // One SYNC period: the interval between the last two SYNCs, or the site's tick.
        let period_s = self.period.as_secs_f64();
        for j in 0..self.units.len() {
            let t = self.rack.drives()[j].target();
            if !(t.enabled && t.mode == Mode::CyclicPosition) {
                self.ramps[j].target = None;
                continue;
            }
            if self.ramps[j].target == Some(t.position) {
                continue;
            }
            let u = self.units[j];
            // The target is the drum length whose noise-free reading it is, on the wired drum.
            let c = self.wires.drive_on[j];
            let to = self.plant.drum_for_reading(c, self.wires.true_reading(j, f64::from(t.position) / u.counts_per_m));
            // The ramp runs on the drives' SYNC clock, not the frame's arrival.
            let (start, sync_s) = self.sync_clock.map_or((at, period_s), |(t, p)| (t, p));
            let r = &mut self.ramps[j];
            let from = if r.target.is_some() { r.at(start) } else { self.drum[c] };
            let dur_s = r.target.map_or(0.0, |_| CSP_INTERPOLATION_PERIODS * sync_s);
            *r = Ramp { from, to, target: Some(t.position), start, dur_s };
        }
    }

    fn inject_faults(&mut self) {
        // Relaxed: independent switches polled each tick.
        if self.faults.loadcell_silent.load(Ordering::Relaxed) && !self.silenced {
            if let Some(v) = &self.vlc {
                v.inject(None, LoadCellFault::Silence, u32::MAX);
            }
            self.silenced = true;
        }
        let second = 1.min(self.units.len() - 1);
        if self.faults.drive_emcy.load(Ordering::Relaxed) && !self.emcy_sent {
            self.rack.drives()[second].inject_fault(0x2310);
            self.emcy_sent = true;
        }
        let hb_lost = self.faults.heartbeat_lost.load(Ordering::Relaxed);
        if hb_lost != self.hb_off {
            self.rack.drives()[second].set_heartbeat_off(hb_lost);
            self.hb_off = hb_lost;
        }
        if self.faults.drive_power_cycle.swap(false, Ordering::Relaxed) {
            self.rack.drives()[second].power_cycle();
        }
        let persists = self.faults.drive_fault_persists.load(Ordering::Relaxed);
        let d = &mut self.rack.drives()[second];
        use taut_proto::canopen::cia402::PowerState;
        if persists && !matches!(d.state(), PowerState::Fault | PowerState::FaultReactionActive) {
            // The cause persists: a fault reset is followed by the same fault.
            d.inject_fault(0x2310);
        }
    }

    /// Steps the physics to `at` (not before the last step): the drums where their ramps are
    /// at `at`, the plant's equilibrium there, and the drives' actual values from it.
    fn step_plant(&mut self, at: Instant) {
        let n = self.units.len();
        let dt = at.saturating_duration_since(self.last_step).as_secs_f64().min(0.02);
        for j in 0..n {
            let t = self.rack.drives()[j].target();
            let u = self.units[j];
            let c = self.wires.drive_on[j];
            self.cmds[c] = match (t.enabled, t.mode, self.ramps[j].target) {
                (true, Mode::CyclicPosition, Some(_)) => {
                    self.drum[c] = self.ramps[j].at(at);
                    SimCommand::Length(self.drum[c])
                }
                (true, Mode::CyclicTorque, _) => SimCommand::Tension((f64::from(t.torque) * u.n_per_permille).max(0.0)),
                // Brakes hold the drum where it is.
                _ => SimCommand::Length(self.drum[c]),
            };
        }
        let o = self.plant.step(dt, &self.cmds);
        let mut cell_n = [0.0; MAX_CABLES];
        self.wires.cells(o.tension_n, &mut cell_n[..n]);
        self.handle.set_all(&cell_n[..n]);
        let mut enc = [0.0; MAX_CABLES];
        let mut tq = [0i16; MAX_CABLES];
        for j in 0..n {
            // A drum in torque mode pays out whatever the platform pulls.
            self.drum[j] = o.drum_m[j];
        }
        for j in 0..n {
            let (u, c) = (self.units[j], self.wires.drive_on[j]);
            enc[j] = self.wires.reported(j, o.encoder_m[c]) * u.counts_per_m;
            tq[j] = permille(o.tension_n[c] / u.n_per_permille);
        }
        for j in 0..n {
            self.rack.drives()[j].set_actual(counts(enc[j]), tq[j]);
        }
        self.prev_step = Some((self.last_step, self.last_enc, self.last_tq));
        (self.last_step, self.last_enc, self.last_tq) = (at, enc, tq);
        self.faults.plant_failed_steps.store(self.plant.failed_steps(), Ordering::Relaxed);
        self.platform.set(self.plant.position());
        let mut true_n = [0.0; MAX_CABLES];
        for (j, t) in true_n.iter_mut().enumerate().take(n) {
            *t = self.plant.true_tension(j);
        }
        self.platform.set_cables(&true_n[..n], &self.drum[..n]);
    }
}

/// Over how many SYNC periods a drive in cyclic synchronous position moves its drum from one
/// set-point to the next (CiA 402 CSP: the drive interpolates between set-points), so that
/// encoders and tracker sample one continuous motion. 0 would be a staircase, which shifts the
/// lengths half a SYNC period against the poses.
const CSP_INTERPOLATION_PERIODS: f64 = 1.0;

/// A drum in cyclic synchronous position: from its last target to the new one, linearly, over
/// [`CSP_INTERPOLATION_PERIODS`] SYNC periods from the SYNC that applied it.
#[derive(Debug, Clone, Copy)]
struct Ramp {
    from: f64,
    to: f64,
    /// The target (counts) ramped to; `None` when the drive is not in CSP.
    target: Option<i32>,
    start: Instant,
    dur_s: f64,
}

impl Ramp {
    /// The drum length at `t`, m.
    fn at(&self, t: Instant) -> f64 {
        if self.dur_s <= 0.0 {
            return self.to;
        }
        // Past the period without a new target (it missed its SYNC), the interpolator keeps the
        // speed for at most one more period, as drives that extrapolate do: holding would stop
        // the drum dead and start it again, a jerk a stiff cable turns into a tension spike.
        let s = (t.saturating_duration_since(self.start).as_secs_f64() / self.dur_s).min(2.0);
        self.from + s * (self.to - self.from)
    }
}

/// Tensions that hold a point mass at `p` as the controller does in operation: the followers
/// (taut_config::followers) at `follower_n`, the held cables solving the force balance. `None`
/// if one would be below 1 N.
fn rest_tensions(anchors: &[[f64; 3]], p: [f64; 3], mass_kg: f64, follower_n: f64) -> Option<Vec<f64>> {
    use taut_config::followers::{follows_in_operation, OPERATION_HELD};
    let unit = |a: &[f64; 3]| {
        let d = [a[0] - p[0], a[1] - p[1], a[2] - p[2]];
        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / r, d[1] / r, d[2] / r]
    };
    let mut rhs = [0.0, 0.0, mass_kg * 9.81];
    for a in anchors.iter().enumerate().filter(|(j, _)| follows_in_operation(*j)).map(|(_, a)| a) {
        let u = unit(a);
        for i in 0..3 {
            rhs[i] -= follower_n * u[i];
        }
    }
    let u: Vec<[f64; 3]> = OPERATION_HELD.iter().map(|&j| unit(&anchors[j])).collect();
    // Columns u0 u1 u2; Cramer's rule.
    let det = |c0: [f64; 3], c1: [f64; 3], c2: [f64; 3]| {
        c0[0] * (c1[1] * c2[2] - c1[2] * c2[1]) - c1[0] * (c0[1] * c2[2] - c0[2] * c2[1]) + c2[0] * (c0[1] * c1[2] - c0[2] * c1[1])
    };
    let d = det(u[0], u[1], u[2]);
    if d.abs() < 1e-9 {
        return None;
    }
    let t = [det(rhs, u[1], u[2]) / d, det(u[0], rhs, u[2]) / d, det(u[0], u[1], rhs) / d];
    if t.iter().any(|&x| x < 1.0) {
        return None;
    }
    let mut out = vec![follower_n; anchors.len()];
    for (k, &j) in OPERATION_HELD.iter().enumerate() {
        out[j] = t[k];
    }
    Some(out)
}
