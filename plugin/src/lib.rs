//! taut as a controller plugin: the loop, the start-up routine and the calibrator behind a
//! lifecycle a robot's own controller drives, the way ros2_control's controller manager drives
//! a hardware component.
//!
//! ```text
//!   Plugin::configure ──> Inactive ──activate──> Active ──deactivate──> Inactive ──cleanup──> Finalized
//!   (parse, validate,        ^    (devices up,      | update(now, period)   |
//!    allocate, start the     |     drives enabled    | every cycle         |
//!    calibrator thread;      |     holding)          v                     |
//!    no bus traffic)         └───── a failed activate stays Inactive ──────┘ (retry)
//! ```
//!
//! Devices are met in one of two ways, chosen at configure time ([`DeviceMode`]):
//! - **plugin-owned** ([`DeviceMode::Owned`]): taut's CANopen master, Modbus load cells and
//!   tracker input (or the simulated robot) behind [`Devices`]; `activate` brings them up and
//!   enables the drives, each [`Plugin::update`] reads, computes and writes.
//! - **host-owned** ([`DeviceMode::Host`]): the host reads its devices, passes the readings
//!   in and applies the commands ([`Plugin::update_with`], the C-shaped structs of
//!   [`taut_rt::host`]). `activate` only arms the loop: the first cycles ask for the drives to be
//!   enabled, and the start-up begins once the host reports them enabled.
//!
//! The start-up routine (three initialisation phases, initial estimate, excitation,
//! calibration, bumpless hot-swap) runs inside `update` as in `taut start`, itself a host of this
//! plugin ([`daemon`]).
//!
//! # What may run in the real-time thread
//!
//! Only [`Plugin::update`] / [`Plugin::update_with`] (and [`Plugin::set_timing`],
//! [`Plugin::finished`]). They allocate nothing, free nothing, take no lock and make no
//! blocking call: parameters and status go through triple buffers, samples through a
//! fixed-capacity ring, commands and events through bounded queues (full: dropped and
//! counted), estop and stop are atomic flags. Plugin-owned devices obey the same rule
//! ([`Devices`]). `tests/tests/memory/plugin_alloc.rs` proves it with a counting allocator.
//!
//! Everything else is for non-real-time threads: `configure` (allocates, starts the calibrator
//! thread), `activate` (may block on SDO configuration and drive enabling), `deactivate`,
//! `cleanup` (joins the calibrator thread), and every [`PluginHandle`] method (they take status
//! mutexes the loop never takes).
//!
//! ```no_run
//! use taut_plugin::{DeviceMode, HostInputs, HostOutputs, Plugin, PluginOptions};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! let mut p = Plugin::configure(&cfg, DeviceMode::Host, PluginOptions::default()).unwrap();
//! let operator = p.handle().clone(); // to a non-real-time thread
//! p.activate().unwrap();
//! let (mut inp, mut out) = (HostInputs::default(), HostOutputs::default());
//! for k in 0..1000 {
//!     // ... fill `inp` from the drives, load cells and tracker ...
//!     let tick = p.update_with(k as f64 * 0.002, 0.002, &inp, &mut out).unwrap();
//!     // ... send `out` to the drives ...
//!     if tick.finished { break; }
//! }
//! p.deactivate().unwrap();
//! p.cleanup().unwrap();
//! ```
#![deny(missing_docs)]

pub mod daemon;
mod error;
mod handle;

pub use error::{ErrorKind, Lifecycle, ModeKind, Op, PluginError, Refusal, UpdateError};
pub use handle::{LoopEvent, PluginHandle, Status};
pub use taut_rt::host::{BadInput, HostInputs, HostOutputs};
pub use taut_rt::update::Tick;

use handle::EventTx;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::calibrator::Calibrator;
use taut_calibrator::vocab::{CalibStatus, Calibrate, CalibratorConfig, SharedCalibStatus};
use taut_config::runtime::RtConfig;
use taut_config::RobotConfig;
use taut_driver::clock::{Clock, SimClock};
use taut_io::robot_io::BringUpError;
use taut_io::rtsys::Periodic;
use taut_io::runner::{LoopCore, LoopStatus, LoopTiming};
use taut_operator::control::SharedLoopStatus;
use taut_rt::io::{DriveStatus, Inputs};
use taut_rt::kin::LoopParams;
use taut_rt::motion::{Controller, ControllerConfig, State};
use taut_rt::sample::{sample_ring, SampleRx};
use taut_rt::triple::{triple_buffer, Writer};
use taut_rt::update::{BadTime, DeviceSlot, UpdatePath};
use taut_rt::urgent::Urgent;

pub use taut_rt::io::Devices;

/// Brings plugin-owned devices up, from [`Plugin::activate`] on a non-real-time thread (it may
/// block), again on a retry. Once it has succeeded the plugin keeps the devices until `cleanup`.
pub trait DeviceSource: Send {
    /// The devices, up (configured, operational, drives not enabled).
    fn bring_up(&mut self) -> Result<Box<dyn Devices>, BringUpError>;
}

/// Devices that are already up (the simulated robot, or a bus the host configured itself).
struct Ready(Option<Box<dyn Devices>>);

impl DeviceSource for Ready {
    fn bring_up(&mut self) -> Result<Box<dyn Devices>, BringUpError> {
        self.0.take().ok_or(BringUpError::DevicesTaken)
    }
}

/// Who owns the devices.
pub enum DeviceMode {
    /// The plugin: `activate` brings them up through the source, `update` reads and writes
    /// them.
    Owned(Box<dyn DeviceSource>),
    /// The host: it passes each cycle's readings to `update_with` and applies the commands.
    Host,
}

impl DeviceMode {
    /// Plugin-owned devices that are already up.
    pub fn ready(devices: Box<dyn Devices>) -> DeviceMode {
        DeviceMode::Owned(Box::new(Ready(Some(devices))))
    }

    fn kind(&self) -> ModeKind {
        match self {
            DeviceMode::Owned(_) => ModeKind::Owned,
            DeviceMode::Host => ModeKind::Host,
        }
    }
}

/// Where the calibrator records the sample stream.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum RecordingPath {
    /// `daemon.data_dir/recordings/start-<local time, ISO 8601 basic>.csv`
    /// (`start-20261129T041005+0100.csv`).
    #[default]
    Default,
    /// This file.
    At(PathBuf),
    /// No recording.
    Off,
}

/// Options beyond the configuration.
pub struct PluginOptions {
    /// The recording.
    pub recording: RecordingPath,
    /// The calibration backend (default: taut-calib, [`TautCalib`]).
    pub backend: Option<Box<dyn Calibrate>>,
    /// Capacity of the event queue (full: events are dropped and counted).
    pub event_capacity: usize,
    /// Simulated time (lockstep): the plugin's own cycles advance this clock by one period, and
    /// the calibrator runs without threads, in [`Plugin::pump_calibrator`] after every cycle.
    pub sim_clock: Option<SimClock>,
}

impl Default for PluginOptions {
    fn default() -> Self {
        PluginOptions { recording: RecordingPath::Default, backend: None, event_capacity: 256, sim_clock: None }
    }
}

/// A configured plugin that has created no file and started no thread yet, so a host can claim
/// its own resources first (the daemon binds the control socket here).
pub struct PluginBuilder {
    ccfg: ControllerConfig,
    rt: RtConfig,
    mode: DeviceMode,
    path: UpdatePath<Box<dyn Devices>, EventTx>,
    handle: PluginHandle,
    calib_cfg: CalibratorConfig,
    calib_status: SharedCalibStatus,
    sample_rx: SampleRx,
    params_tx: Writer<LoopParams>,
    backend: Box<dyn Calibrate>,
    recording: Option<PathBuf>,
    csv: bool,
    outputs: Option<taut_operator::channels::FrameSinks>,
    sim_clock: Option<SimClock>,
}

impl PluginBuilder {
    /// Whether the calibrator writes the CSV recording (default: yes, when there is a path).
    pub fn with_csv(mut self, on: bool) -> PluginBuilder {
        self.csv = on;
        self
    }

    /// Also sends every sample, parameter set and stage to `o` (MCAP recording, telemetry), from
    /// the calibrator thread.
    pub fn with_outputs(mut self, o: taut_operator::channels::FrameSinks) -> PluginBuilder {
        self.outputs = Some(o);
        self
    }

    /// The operator's handle.
    pub fn handle(&self) -> &PluginHandle {
        &self.handle
    }

    /// Where the recording will be.
    pub fn recording(&self) -> Option<&Path> {
        self.recording.as_deref()
    }

    /// Creates the recording and starts the calibrator thread: the plugin, inactive.
    pub fn build(self) -> Result<Plugin, PluginError> {
        let b = self;
        let csv = if b.csv { b.recording.clone() } else { None };
        let calibrator = Calibrator::new(b.calib_cfg, b.sample_rx, b.params_tx, b.backend, csv, b.calib_status)
            .map_err(|source| PluginError::Recording { path: b.recording.clone().unwrap_or_default(), source })?;
        let calibrator = match b.outputs {
            Some(o) => calibrator.with_outputs(o),
            None => calibrator,
        };
        let calib_quit = Arc::new(AtomicBool::new(false));
        let (calib_thread, inline_calibrator) = if b.sim_clock.is_some() {
            (None, Some(calibrator.inline()))
        } else {
            let q = calib_quit.clone();
            let t = std::thread::Builder::new()
                .name("taut-calibrator".into())
                .spawn(move || calibrator.run(q))
                .map_err(|source| PluginError::Thread { name: "taut-calibrator", source })?;
            (Some(t), None)
        };
        Ok(Plugin {
            state: Lifecycle::Inactive,
            mode: b.mode.kind(),
            source: match b.mode {
                DeviceMode::Owned(s) => Some(s),
                DeviceMode::Host => None,
            },
            ccfg: b.ccfg,
            rt: b.rt,
            path: b.path,
            handle: b.handle,
            calib_thread,
            inline_calibrator,
            sim_clock: b.sim_clock,
            calib_quit,
            recording: b.recording,
            rearm: false,
        })
    }
}

/// The plugin. See the module documentation for the lifecycle and the real-time rule.
pub struct Plugin {
    state: Lifecycle,
    mode: ModeKind,
    source: Option<Box<dyn DeviceSource>>,
    ccfg: ControllerConfig,
    rt: RtConfig,
    /// The per-cycle path (taut-rt): loop core, status, events, plugin time.
    path: UpdatePath<Box<dyn Devices>, EventTx>,
    handle: PluginHandle,
    calib_thread: Option<JoinHandle<()>>,
    /// The calibrator in simulated time: stepped by [`Plugin::pump_calibrator`].
    inline_calibrator: Option<Calibrator>,
    sim_clock: Option<SimClock>,
    calib_quit: Arc<AtomicBool>,
    recording: Option<PathBuf>,
    /// The controller must go back to Idle before the next activation.
    rearm: bool,
}

impl Plugin {
    /// Parses and validates `cfg`, allocates everything, creates the recording and starts the
    /// calibrator thread. No bus traffic.
    pub fn configure(cfg: &RobotConfig, devices: DeviceMode, opts: PluginOptions) -> Result<Plugin, PluginError> {
        Plugin::builder(cfg, devices, opts)?.build()
    }

    /// The first half of [`Plugin::configure`]: validated and allocated, nothing created or
    /// started ([`PluginBuilder::build`] does that).
    pub fn builder(cfg: &RobotConfig, devices: DeviceMode, opts: PluginOptions) -> Result<PluginBuilder, PluginError> {
        let mut ccfg = crate::controller_config(cfg)?;
        // Planned at configure time so the loop gets a fixed-size path; a tracker-free start-up
        // dwells instead.
        let excitation = ccfg.dwell.is_none().then(|| taut_calibrator::excite::plan(cfg, &mut ccfg));
        let n = ccfg.n;
        let rt = cfg.rt.clone();
        if !(rt.rate_hz.is_finite() && rt.rate_hz >= 1.0) {
            return Err(PluginError::ConfigValue { key: "rt.rate_hz", must: "a loop rate of at least 1 Hz" });
        }
        if rt.ring_capacity < 16 {
            return Err(PluginError::ConfigValue { key: "rt.ring_capacity", must: "at least 16 samples" });
        }
        if rt.command_capacity == 0 {
            return Err(PluginError::ConfigValue { key: "rt.command_capacity", must: "at least 1" });
        }
        if n == 0 {
            return Err(PluginError::ConfigValue { key: "cable", must: "at least one [[cable]] table" });
        }
        let (params_tx, params_rx) = triple_buffer(LoopParams::invalid(n));
        let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(rt.command_capacity);
        let (sample_tx, sample_rx) = sample_ring(rt.ring_capacity);
        let urgent = Arc::new(Urgent::default());
        let controller = Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx).with_urgent(urgent.clone());
        let init_status = LoopStatus::initial(controller.snapshot(0.0, &Inputs::new(n)));
        let (status_tx, status_rx) = triple_buffer(init_status);
        let loop_status: SharedLoopStatus = Arc::new(Mutex::new(status_rx));
        let calib_status: SharedCalibStatus =
            Arc::new(Mutex::new(CalibStatus { excitation: excitation.clone(), ..CalibStatus::default() }));
        let (handle, events) = PluginHandle::new(
            cmd_tx,
            urgent,
            loop_status,
            calib_status.clone(),
            opts.event_capacity,
            ccfg.workspace,
            taut_operator::operator::Expected::from_robot(cfg),
        );
        handle.operator().set_cables((0..n).map(|j| cfg.cable_ids(j)).collect());
        let recording = match opts.recording {
            RecordingPath::Off => None,
            RecordingPath::At(p) => Some(p),
            RecordingPath::Default => {
                let t = taut_operator::localtime::iso8601_basic(std::time::SystemTime::now());
                Some(PathBuf::from(&cfg.daemon.data_dir).join("recordings").join(format!("start-{t}.csv")))
            }
        };
        let devs = match devices {
            DeviceMode::Owned(_) => DeviceSlot::Down,
            DeviceMode::Host => DeviceSlot::Host(Box::new(Inputs::new(n))),
        };
        let core = LoopCore::new(n, devs, controller, sample_tx);
        Ok(PluginBuilder {
            ccfg,
            rt,
            mode: devices,
            path: UpdatePath::new(core, status_tx, init_status, events),
            handle,
            calib_cfg: CalibratorConfig { excitation, ..CalibratorConfig::from_robot(cfg) },
            calib_status,
            sample_rx,
            params_tx,
            backend: opts.backend.unwrap_or_else(|| Box::new(TautCalib::from_config(cfg))),
            recording,
            csv: true,
            outputs: None,
            sim_clock: opts.sim_clock,
        })
    }

    /// The operator's handle (clone it for other threads).
    pub fn handle(&self) -> &PluginHandle {
        &self.handle
    }

    /// The lifecycle state.
    pub fn lifecycle(&self) -> Lifecycle {
        self.state
    }

    /// The device mode.
    pub fn mode(&self) -> ModeKind {
        self.mode
    }

    /// Number of cables.
    pub fn cables(&self) -> usize {
        self.ccfg.n
    }

    /// The recording, if any.
    pub fn recording(&self) -> Option<&Path> {
        self.recording.as_deref()
    }

    /// The loop rate the configuration asks for, Hz (`rt.rate_hz`).
    pub fn rate_hz(&self) -> f64 {
        self.rt.rate_hz
    }

    /// The real-time settings of the configuration (for a host that runs the thread).
    pub fn rt_config(&self) -> &RtConfig {
        &self.rt
    }

    /// True once the loop has stopped (an operator stop).
    pub fn finished(&self) -> bool {
        self.path.core.controller.finished()
    }

    /// The host's timing of the cycle about to run (wake-up lateness, overruns, compute time),
    /// shown in status. Optional; real-time safe.
    pub fn set_timing(&mut self, t: LoopTiming) {
        self.path.set_timing(t);
    }

    /// Inactive -> Active. Plugin-owned: brings the devices up if they are not yet, then runs
    /// cycles on the calling thread (at `rt.rate_hz`) until every drive reports operation
    /// enabled, each cable commanded where it stands. Host-owned: arms the loop (the drives
    /// are enabled by the first `update_with` cycles). On failure the plugin stays inactive,
    /// the drives are left disabled or stopped, and `activate` may be called again.
    pub fn activate(&mut self) -> Result<(), PluginError> {
        if self.state != Lifecycle::Inactive {
            return Err(PluginError::Lifecycle { op: Op::Activate, state: self.state });
        }
        if self.rearm {
            self.path.core.controller.rearm();
            self.rearm = false;
        }
        if self.mode == ModeKind::Owned {
            if matches!(self.path.core.devices, DeviceSlot::Down) {
                let src = self.source.as_mut().expect("plugin-owned mode has a device source");
                self.path.core.devices = DeviceSlot::Owned(src.bring_up().map_err(PluginError::BringUp)?);
            }
            if let Err(e) = self.enable_owned() {
                self.rearm = true;
                return Err(e);
            }
        }
        // Plugin time runs on from the last cycle whatever clock the host uses from now on.
        self.path.restart_clock();
        self.state = Lifecycle::Active;
        Ok(())
    }

    /// Cycles on the calling thread until the drives are enabled (plugin-owned activation).
    fn enable_owned(&mut self) -> Result<(), PluginError> {
        let period = 1.0 / self.rt.rate_hz;
        let mut timer = Periodic::new((period * 1e9).round() as i64);
        let n = self.ccfg.n;
        loop {
            self.pace(&mut timer, period);
            let t = self.path.t_last() + period;
            self.path.read(t);
            let inp = &self.path.core.inputs;
            let up = (0..n).all(|j| inp.drive[j] == DriveStatus::Enabled && inp.length_m[j].is_finite());
            if up && self.path.core.controller.state() == State::Enabling {
                // The next cycle (the host's first update) starts the first phase; until then
                // the drives hold the positions last commanded.
                return Ok(());
            }
            self.path.step(t, period);
            if let Some((cause, reaction)) = self.path.core.controller.fault() {
                self.settle_after_failure(&mut timer, period);
                return Err(PluginError::Activation { cause, reaction });
            }
            if self.path.core.controller.finished() {
                return Err(PluginError::Stopped);
            }
        }
    }

    /// After a reaction latched during activation: keep cycling (the reaction's commands) until
    /// no drive reports enabled, at most 0.5 s, so that the drives have taken the reaction
    /// before the plugin stops writing.
    fn settle_after_failure(&mut self, timer: &mut Periodic, period: f64) {
        let until = self.now() + Duration::from_millis(500);
        while self.now() < until {
            self.pace(timer, period);
            let t = self.path.t_last() + period;
            self.path.read(t);
            self.path.step(t, period);
            let inp = &self.path.core.inputs;
            if (0..self.ccfg.n).all(|j| inp.drive[j] != DriveStatus::Enabled) {
                break;
            }
        }
    }

    /// Active -> Inactive. Plugin-owned: stops the loop (hold, then disable) running the stop
    /// cycles on the calling thread. Host-owned: the host disables its drives (the last
    /// outputs stand until it does). The next `activate` runs the start-up from its first phase.
    pub fn deactivate(&mut self) -> Result<(), PluginError> {
        if self.state != Lifecycle::Active {
            return Err(PluginError::Lifecycle { op: Op::Deactivate, state: self.state });
        }
        if self.mode == ModeKind::Owned && !self.path.core.controller.finished() {
            self.handle.stop();
            let period = 1.0 / self.rt.rate_hz;
            let mut timer = Periodic::new((period * 1e9).round() as i64);
            let until = self.now() + Duration::from_secs(2);
            while !self.path.core.controller.finished() && self.now() < until {
                self.pace(&mut timer, period);
                let t = self.path.t_last() + period;
                self.path.read(t);
                self.path.step(t, period);
            }
        }
        self.state = Lifecycle::Inactive;
        self.rearm = true;
        Ok(())
    }

    /// Inactive -> Finalized: stops the calibrator (it drains the samples already pushed,
    /// finishes the recording) and joins its thread; releases plugin-owned devices.
    pub fn cleanup(&mut self) -> Result<(), PluginError> {
        if self.state != Lifecycle::Inactive {
            return Err(PluginError::Lifecycle { op: Op::Cleanup, state: self.state });
        }
        self.stop_calibrator();
        self.path.core.devices = DeviceSlot::Down;
        self.source = None;
        self.state = Lifecycle::Finalized;
        Ok(())
    }

    /// Waits for the next of the plugin's own cycles: one period of the wall clock, or of the
    /// simulated clock (with the calibrator's step of the cycle before).
    fn pace(&mut self, timer: &mut Periodic, period: f64) {
        match &self.sim_clock {
            Some(c) => {
                c.advance(Duration::from_secs_f64(period));
                self.pump_calibrator();
            }
            None => {
                timer.wait();
            }
        }
    }

    fn now(&self) -> Instant {
        self.sim_clock.as_ref().map_or_else(Instant::now, |c| c.now())
    }

    /// In simulated time ([`PluginOptions::sim_clock`]): the calibrator's work for the cycles run
    /// so far. Not real-time: call it between cycles. Does nothing when the calibrator has its own
    /// thread.
    pub fn pump_calibrator(&mut self) {
        if let Some(c) = &mut self.inline_calibrator {
            c.step();
        }
    }

    fn stop_calibrator(&mut self) {
        if let Some(mut c) = self.inline_calibrator.take() {
            c.finish();
        }
        // Release: the calibrator's Acquire load then sees every sample pushed before.
        self.calib_quit.store(true, Ordering::Release);
        if let Some(t) = self.calib_thread.take() {
            let _ = t.join();
        }
    }

    fn check(&self, mode: ModeKind) -> Result<(), UpdateError> {
        if self.state != Lifecycle::Active {
            return Err(UpdateError::NotActive { state: self.state });
        }
        if self.mode != mode {
            return Err(UpdateError::WrongMode { mode: self.mode });
        }
        Ok(())
    }

    /// One cycle with plugin-owned devices: read -> update -> write. `now_s` is the host's
    /// monotonic time (any origin), `period_s` the measured period. Real-time safe.
    pub fn update(&mut self, now_s: f64, period_s: f64) -> Result<Tick, UpdateError> {
        self.check(ModeKind::Owned)?;
        self.path.update(now_s, period_s).map_err(|BadTime| UpdateError::BadTime)
    }

    /// One cycle with host-owned devices: `inputs` are this cycle's readings, `outputs` receive
    /// the commands. Real-time safe.
    pub fn update_with(&mut self, now_s: f64, period_s: f64, inputs: &HostInputs, outputs: &mut HostOutputs) -> Result<Tick, UpdateError> {
        self.check(ModeKind::Host)?;
        self.path.update_with(now_s, period_s, inputs, outputs).map_err(|BadTime| UpdateError::BadTime)
    }
}

impl Drop for Plugin {
    fn drop(&mut self) {
        if self.state == Lifecycle::Active {
            let _ = self.deactivate();
        }
        self.stop_calibrator();
    }
}

/// The controller configuration of `cfg`, with the dwell plan when the start-up runs without a
/// tracker.
pub fn controller_config(cfg: &RobotConfig) -> Result<ControllerConfig, PluginError> {
    let ccfg = <ControllerConfig as taut_io::FromRobot>::from_robot(cfg)?;
    if !taut_calibrator::notracker::is_dwell(cfg) {
        return Ok(ccfg);
    }
    let p = taut_calibrator::notracker::dwell_plan(cfg, &ccfg).map_err(PluginError::DwellPlan)?;
    let m = &cfg.motion;
    Ok(ccfg.with_dwell_plan(&p.poses, m.dwell_s, m.dwell_settle_s, m.dwell_speed_m_s).with_dwell_tares(&p.tare))
}
