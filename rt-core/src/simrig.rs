//! The simulated robot for `taut start --sim`: `taut-sim`'s [`Plant`] stepped by the loop's own
//! cycle, with its encoders, load cells and tracker, and faults a test can inject.
//!
//! The load cells are `taut-sim`'s virtual Modbus RTU cells on a pseudo-terminal, read by
//! `taut-driver`'s load-cell I/O thread (the hardware code path); the tracker is the simulator's
//! (100 Hz, with its noise, outliers and dropouts) sent as UDP datagrams over loopback to
//! `taut-driver`'s tracker receiver. The drives follow the loop's commands like CiA 402 drives in
//! cyclic synchronous position (encoder length -> drum length through the true offset and scale)
//! or torque mode, coupled to the plant in-process; before they are enabled, and in quick stop,
//! their brakes hold the drums.

use crate::io::{CableCommand, DeviceFault, DriveRequest, DriveStatus, Devices, Inputs, Outputs};
use crate::MAX_CABLES;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use taut_config::RobotConfig;
use std::time::Instant;
use taut_config::devices::{LoadCellBusConfig, LoadCellConfig, TrackerConfig};
use taut_driver::loadcell::{LoadCellIo, TensionReader};
use taut_driver::tracker::{PoseReader, TrackerReceiver};
use taut_sim::devices::loadcell::{Fault, TensionHandle, VirtualLoadCells};
use taut_sim::devices::tracker::TrackerSender;
use taut_sim::sensors::Tracker;
use taut_sim::{CableCommand as SimCommand, Noise, Physics, Plant, Truth};

/// Faults to inject into the simulated devices (set from any thread).
#[derive(Debug, Default)]
pub struct SimFaults {
    /// Load cells stop answering.
    pub loadcell_silent: AtomicBool,
    /// The tracker stops sending.
    pub tracker_gone: AtomicBool,
    /// Drive of cable 1 reports an EMCY (0x2310, continuous over-current) and faults.
    pub drive_emcy: AtomicBool,
    /// Drive of cable 1 stops sending heartbeats.
    pub heartbeat_lost: AtomicBool,
}

/// A simulated robot ready for the daemon.
pub struct SimRobot {
    /// The site's true parameters (for the summary; the daemon never sees them).
    pub truth: Truth,
    /// Fault switches.
    pub faults: Arc<SimFaults>,
    /// The devices to hand to the daemon.
    pub devices: Box<dyn Devices>,
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
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions { seed: 1, site_error_m: 0.2, l0_range_m: 2.0, noise: Noise::default() }
    }
}

/// Where an operator would park the platform before the start-up: the simulator's rest position
/// for the three-phase motion of `cfg.motion` (most tension margin for the held cables), or
/// `fallback` if it finds none.
pub fn rest_position(cfg: &RobotConfig, opts: &SimOptions, fallback: [f64; 3]) -> [f64; 3] {
    let physics = Physics::default();
    let mut rng = taut_sim::rng(opts.seed, 0);
    let Ok(truth) = Truth::sample(cfg, &physics, opts.site_error_m, opts.l0_range_m, &mut rng) else { return fallback };
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

/// Builds the simulated robot of `cfg` (nominal anchors needed) with the platform at `p0`.
pub fn build(cfg: &RobotConfig, p0: [f64; 3], opts: &SimOptions) -> Result<SimRobot, String> {
    let n = cfg.cables.len();
    if n > MAX_CABLES {
        return Err(format!("{n} cables: at most {MAX_CABLES}"));
    }
    let physics = Physics::default();
    let mut rng = taut_sim::rng(opts.seed, 0);
    let truth = Truth::sample(cfg, &physics, opts.site_error_m, opts.l0_range_m, &mut rng).map_err(|e| format!("simulated site: {e}"))?;
    let mut plant = Plant::new(&truth, &physics, p0).with_noise(&opts.noise, opts.seed);
    let tensions = rest_tensions(&truth.anchors, p0, truth.mass_kg, cfg.motion.init_follower_tension_n)
        .ok_or_else(|| format!("simulated site: the platform cannot rest at {p0:?} with positive tensions"))?;
    let brake = plant.lengths_holding(p0, &tensions).map_err(|e| format!("simulated site: no rest position at {p0:?}: {e}"))?;
    let mut drum = [0.0; MAX_CABLES];
    drum[..n].copy_from_slice(&brake);
    let mut cmds = [SimCommand::Length(0.0); MAX_CABLES];
    for j in 0..n {
        cmds[j] = SimCommand::Length(drum[j]);
    }
    // Settle on the brakes before anything is read.
    let mut enc = [0.0; MAX_CABLES];
    let mut ten = [0.0; MAX_CABLES];
    let mut pos = p0;
    for _ in 0..5 {
        let out = plant.step(0.002, &cmds[..n]);
        enc[..n].copy_from_slice(out.encoder_m);
        ten[..n].copy_from_slice(out.tension_n);
        pos = out.position;
    }
    let faults = Arc::new(SimFaults::default());
    let mut l0 = [0.0; MAX_CABLES];
    let mut scale = [1.0; MAX_CABLES];
    l0[..n].copy_from_slice(&truth.l0);
    scale[..n].copy_from_slice(&truth.scale);
    // Load cells: virtual Modbus RTU server on a pty <- driver's I/O thread.
    let cells: Vec<(usize, LoadCellConfig)> =
        cfg.cables.iter().enumerate().map(|(j, c)| (j, c.loadcell.clone().unwrap_or_else(|| LoadCellConfig::new(j as u8 + 1)))).collect();
    let handle = TensionHandle::new(n);
    handle.set_all(&ten[..n]);
    let vlc = VirtualLoadCells::spawn(cells.iter().map(|c| c.1.clone()).collect(), handle.clone()).map_err(|e| format!("virtual load cells: {e}"))?;
    let mut bus = cfg.loadcells.clone().unwrap_or_else(|| LoadCellBusConfig::new(""));
    bus.port = vlc.path().display().to_string();
    bus.max_age_s = cfg.safety.tension_max_age_s;
    let (lc_io, lc_reader) = taut_driver::loadcell::spawn(&bus, &cells, n).map_err(|e| e.to_string())?;
    // Tracker: simulator -> UDP on loopback -> driver's receiver.
    let mut tcfg = TrackerConfig::new("127.0.0.1:0");
    tcfg.max_age_s = cfg.safety.tracker_max_age_s;
    let receiver = TrackerReceiver::bind(&tcfg).map_err(|e| format!("tracker receiver: {e}"))?;
    let pose_reader = receiver.reader();
    let sender = TrackerSender::new(receiver.local_addr().map_err(|e| e.to_string())?).map_err(|e| format!("tracker sender: {e}"))?;
    let devices = PlantDevices {
        handle,
        vlc,
        _lc_io: lc_io,
        lc_reader,
        receiver,
        pose_reader,
        sender,
        epoch: Instant::now(),
        silenced: false,
        n,
        plant,
        tracker: Tracker::new(&opts.noise),
        rng: taut_sim::rng(opts.seed, 7),
        faults: faults.clone(),
        cmds,
        drum,
        l0,
        scale,
        enc,
        ten,
        pos,
        enabled: false,
        last_now: 0.0,
        pose: [f64::NAN; 3],
        pose_t: f64::NEG_INFINITY,
        tension_t: 0.0,
        cycles: 0,
        node_ids: std::array::from_fn(|j| cfg.cables.get(j).and_then(|c| c.drive.as_ref()).map_or(j as u8 + 1, |d| d.node_id)),
    };
    Ok(SimRobot { truth, faults, devices: Box::new(devices) })
}

struct PlantDevices {
    handle: TensionHandle,
    vlc: VirtualLoadCells,
    _lc_io: LoadCellIo,
    lc_reader: TensionReader,
    receiver: TrackerReceiver,
    pose_reader: PoseReader,
    sender: TrackerSender,
    epoch: Instant,
    silenced: bool,
    n: usize,
    plant: Plant,
    tracker: Tracker,
    rng: rand_chacha::ChaCha8Rng,
    faults: Arc<SimFaults>,
    cmds: [SimCommand; MAX_CABLES],
    drum: [f64; MAX_CABLES],
    l0: [f64; MAX_CABLES],
    scale: [f64; MAX_CABLES],
    enc: [f64; MAX_CABLES],
    ten: [f64; MAX_CABLES],
    pos: [f64; 3],
    enabled: bool,
    last_now: f64,
    pose: [f64; 3],
    pose_t: f64,
    tension_t: f64,
    cycles: u64,
    node_ids: [u8; MAX_CABLES],
}

impl Devices for PlantDevices {
    fn read(&mut self, now: f64, inp: &mut Inputs) {
        let n = self.n;
        // Relaxed: independent switches polled each cycle; no data travels with them.
        let silent = self.faults.loadcell_silent.load(Ordering::Relaxed);
        let gone = self.faults.tracker_gone.load(Ordering::Relaxed);
        let emcy = self.faults.drive_emcy.load(Ordering::Relaxed);
        let hb = self.faults.heartbeat_lost.load(Ordering::Relaxed);
        if silent && !self.silenced {
            // Every cell stops answering: the driver's reader sees no fresh readings.
            self.vlc.inject(None, Fault::Silence, u32::MAX);
            self.silenced = true;
        }
        let _ = gone;
        let wall = Instant::now();
        self.lc_reader.update();
        let _ = self.receiver.poll();
        if let Some(p) = self.pose_reader.newest() {
            self.pose = p.position;
            self.pose_t = now - wall.saturating_duration_since(p.arrival).as_secs_f64();
        }
        let _ = self.epoch;
        let _ = self.tension_t;
        for j in 0..n {
            inp.length_m[j] = self.enc[j];
            inp.length_age_s[j] = 0.0;
            match self.lc_reader.latest(j) {
                Some((f, at)) => {
                    inp.tension_n[j] = f;
                    inp.tension_age_s[j] = wall.saturating_duration_since(at).as_secs_f64();
                }
                None => inp.tension_age_s[j] = f64::INFINITY,
            }
            inp.drive[j] = if self.enabled { DriveStatus::Enabled } else { DriveStatus::Disabled };
        }
        inp.pose_m = self.pose;
        inp.pose_age_s = now - self.pose_t;
        inp.fault = None;
        if emcy {
            inp.drive[1.min(n - 1)] = DriveStatus::Fault;
            inp.fault = Some(DeviceFault::Emcy { node: self.node_ids[1.min(n - 1)], code: 0x2310 });
        } else if hb {
            inp.fault = Some(DeviceFault::HeartbeatLost { node: self.node_ids[1.min(n - 1)] });
        }
    }

    fn write(&mut self, now: f64, out: &Outputs) {
        let n = self.n;
        let dt = (now - self.last_now).clamp(1e-4, 0.05);
        self.last_now = now;
        // Relaxed: as in read.
        let emcy = self.faults.drive_emcy.load(Ordering::Relaxed);
        self.enabled = out.request == DriveRequest::Enable && !emcy;
        for j in 0..n {
            self.cmds[j] = if self.enabled {
                match out.cable[j] {
                    CableCommand::Position(l) if l.is_finite() => {
                        self.drum[j] = (l - self.l0[j]) / self.scale[j];
                        SimCommand::Length(self.drum[j])
                    }
                    CableCommand::Tension(t) => SimCommand::Tension(t),
                    _ => SimCommand::Length(self.drum[j]),
                }
            } else {
                // Brakes hold the drum where it is.
                SimCommand::Length(self.drum[j])
            };
        }
        let o = self.plant.step(dt, &self.cmds[..n]);
        self.enc[..n].copy_from_slice(o.encoder_m);
        self.ten[..n].copy_from_slice(o.tension_n);
        self.pos = o.position;
        self.handle.set_all(&self.ten[..n]);
        // 100 Hz tracker over UDP; dropouts send nothing.
        // Relaxed: an independent switch.
        if self.cycles % 5 == 0 && !self.faults.tracker_gone.load(Ordering::Relaxed) {
            let m = self.tracker.measure(self.pos, &mut self.rng);
            if m.iter().all(|v| v.is_finite()) {
                let _ = self.sender.send_pose(now, m, None);
            }
        }
        self.cycles += 1;
        for j in 0..n {
            // A drum in torque mode pays out whatever the platform pulls.
            self.drum[j] = o.drum_m[j];
        }
    }
}

/// Tensions that hold a point mass at `p`: cables 3.. at `follower_n`, cables 0..3 solving the
/// force balance. `None` if one would be below 1 N.
fn rest_tensions(anchors: &[[f64; 3]], p: [f64; 3], mass_kg: f64, follower_n: f64) -> Option<Vec<f64>> {
    let unit = |a: &[f64; 3]| {
        let d = [a[0] - p[0], a[1] - p[1], a[2] - p[2]];
        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / r, d[1] / r, d[2] / r]
    };
    let mut rhs = [0.0, 0.0, mass_kg * 9.81];
    for a in &anchors[3..] {
        let u = unit(a);
        for i in 0..3 {
            rhs[i] -= follower_n * u[i];
        }
    }
    let u: Vec<[f64; 3]> = anchors[..3].iter().map(unit).collect();
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
    let mut out = t.to_vec();
    out.extend(std::iter::repeat(follower_n).take(anchors.len() - 3));
    Some(out)
}
