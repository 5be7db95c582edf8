//! A simulated robot for C hosts (feature `sim`): `taut-sim`'s [`Plant`] (cable physics,
//! encoders with the site's true offsets and scales, load cells, tracker with noise, outliers and
//! dropouts), stepped by the host's cycle. The host reads its sensors into [`TautInputs`], calls
//! `taut_update`, and applies the [`TautCommands`] to its drives:
//!
//! ```text
//!  taut_sim_read(now) -> TautInputs -> taut_update -> TautCommands -> taut_sim_write(now, period)
//! ```
//!
//! The drives follow the controlword intent as CiA 402 drives do: enabling walks "switch on
//! disabled -> ready to switch on -> switched on -> operation enabled", one state per cycle
//! (CiA 402 6.3.1); while a drive is not enabled (or in quick stop) its brake holds the drum.
//! In position mode the target encoder length is reached through the site's true offset and
//! scale; in torque mode the drum pays out whatever the platform pulls at the commanded tension.
//! Time is the host's: the plant advances by `period` in each `taut_sim_write`.

use crate::error::{self, TautError};
use crate::{TautCableMode, TautCommands, TautDriveRequest, TautDriveState, TautInputs, TAUT_MAX_CABLES};
use std::ffi::c_char;
use taut_config::RobotConfig;
use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;
use taut_sim::sensors::Tracker;
use taut_sim::{CableCommand, Physics, Plant, Truth};
use taut_simrig::{self as simrig, SimOptions};

/// Tracker period, s (100 Hz, as the simulated tracker of `taut start --sim`).
const TRACKER_PERIOD_S: f64 = 0.01;

/// CiA 402 power states the simulated drive walks through (6.3.1), in enabling order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd)]
enum Power {
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStop,
}

/// The simulated robot (opaque in C).
pub struct TautSim {
    truth: Truth,
    plant: Plant,
    tracker: Tracker,
    rng: rand_chacha::ChaCha8Rng,
    n: usize,
    drives: [Power; TAUT_MAX_CABLES],
    /// Drum lengths the brakes (or position mode) hold, m.
    drum: Vec<f64>,
    cmds: Vec<CableCommand>,
    encoder_m: [f64; TAUT_MAX_CABLES],
    tension_n: [f64; TAUT_MAX_CABLES],
    /// Host time the plant has been stepped to, s (NaN before the first write).
    t_plant: f64,
    pose_m: [f64; 3],
    /// Host time of the newest tracker pose, s.
    t_pose: f64,
    next_pose: f64,
}

/// The simulated site's true parameters, for a host's final check.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TautSimTruth {
    /// Cables.
    pub n_cables: u32,
    /// True anchors, m.
    pub anchors_m: [[f64; 3]; TAUT_MAX_CABLES],
    /// True encoder offsets, m.
    pub l0_m: [f64; TAUT_MAX_CABLES],
    /// Platform position now, m.
    pub position_m: [f64; 3],
}

/// Why the simulated robot could not be set up from a configuration.
#[derive(Debug, Clone)]
enum SimSetupError {
    /// Fewer than 4 or more than [`TAUT_MAX_CABLES`] cables.
    CableCount {
        /// Cables configured.
        n: usize,
    },
    /// The configuration cannot drive the controller.
    Controller(taut_rt::motion::ControllerConfigError),
    /// No simulated site from the configuration.
    Site(taut_sim::SimError),
    /// The platform has no rest position at its parking place.
    NoRest {
        /// The parking place, m.
        p0: [f64; 3],
        /// Why.
        error: taut_sim::SimError,
    },
}

impl std::fmt::Display for SimSetupError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SimSetupError::CableCount { n } => write!(f, "{n} cables: the simulated robot needs 4..={TAUT_MAX_CABLES}"),
            SimSetupError::Controller(e) => e.fmt(f),
            SimSetupError::Site(e) => write!(f, "simulated site: {e}"),
            SimSetupError::NoRest { p0, error } => write!(f, "simulated site: no rest position at {p0:?}: {error}"),
        }
    }
}

impl std::error::Error for SimSetupError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SimSetupError::CableCount { .. } => None,
            SimSetupError::Controller(e) => Some(e),
            SimSetupError::Site(e) | SimSetupError::NoRest { error: e, .. } => Some(e),
        }
    }
}

impl TautSim {
    fn new(cfg: &RobotConfig, seed: u64) -> Result<TautSim, SimSetupError> {
        let n = cfg.cables.len();
        if !(4..=TAUT_MAX_CABLES).contains(&n) {
            return Err(SimSetupError::CableCount { n });
        }
        let opts = SimOptions { seed, ..SimOptions::default() };
        let w = ControllerConfig::from_robot(cfg).map_err(SimSetupError::Controller)?.workspace;
        let centre = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
        // Where an operator parks the platform before the start-up (as `taut start --sim`).
        let p0 = simrig::rest_position(cfg, &opts, centre);
        let physics = Physics::default();
        let mut rng = taut_sim::rng(seed, 0);
        let truth = Truth::sample(cfg, &physics, opts.site_error_m, opts.l0_range_m, &mut rng).map_err(SimSetupError::Site)?;
        let mut plant = Plant::new(&truth, &physics, p0).with_noise(&opts.noise, seed);
        let drum = plant.lengths_at_rest(p0, cfg.motion.init_follower_tension_n).map_err(|error| SimSetupError::NoRest { p0, error })?;
        let cmds: Vec<CableCommand> = drum.iter().map(|&d| CableCommand::Length(d)).collect();
        let mut encoder_m = [f64::NAN; TAUT_MAX_CABLES];
        let mut tension_n = [f64::NAN; TAUT_MAX_CABLES];
        // Settle on the brakes before anything is read.
        for _ in 0..5 {
            let o = plant.step(0.002, &cmds);
            encoder_m[..n].copy_from_slice(o.encoder_m);
            tension_n[..n].copy_from_slice(o.tension_n);
        }
        let pose_m = plant.position();
        Ok(TautSim {
            truth,
            plant,
            tracker: Tracker::new(&opts.noise),
            rng: taut_sim::rng(seed, 7),
            n,
            drives: [Power::SwitchOnDisabled; TAUT_MAX_CABLES],
            drum,
            cmds,
            encoder_m,
            tension_n,
            t_plant: f64::NAN,
            pose_m,
            t_pose: f64::NEG_INFINITY,
            next_pose: f64::NEG_INFINITY,
        })
    }

    fn read(&self, now: f64, out: &mut TautInputs) {
        let n = self.n;
        // Before the first step the readings are "now".
        let age = if self.t_plant.is_nan() { 0.0 } else { (now - self.t_plant).max(0.0) };
        *out = TautInputs { n_cables: n as u32, ..TautInputs::default() };
        for j in 0..n {
            out.length_m[j] = self.encoder_m[j];
            out.length_age_s[j] = age;
            out.tension_n[j] = self.tension_n[j];
            out.tension_age_s[j] = age;
            out.drive[j] = match self.drives[j] {
                Power::OperationEnabled => TautDriveState::Enabled,
                Power::QuickStop => TautDriveState::QuickStop,
                _ => TautDriveState::Disabled,
            } as u8;
        }
        if self.t_pose.is_finite() {
            out.pose_m = self.pose_m;
            out.pose_age_s = (now - self.t_pose).max(0.0);
        }
    }

    fn write(&mut self, now: f64, period: f64, c: &TautCommands) -> Result<(), TautError> {
        const NAME: &str = "taut_sim_write";
        let n = self.n;
        if c.n_cables as usize != n {
            return Err(error::fail(
                TautError::InvalidArgument,
                format_args!("{NAME}: commands.n_cables is {}, the robot has {n}", c.n_cables),
            ));
        }
        let request = match c.request {
            0 => TautDriveRequest::Disable,
            1 => TautDriveRequest::Enable,
            2 => TautDriveRequest::QuickStop,
            3 => TautDriveRequest::FaultReset,
            r => {
                return Err(error::fail(
                    TautError::InvalidArgument,
                    format_args!("{NAME}: commands.request = {r} is not a TautDriveRequest"),
                ))
            }
        };
        for j in 0..n {
            let d = &mut self.drives[j];
            *d = match (request, *d) {
                // CiA 402: shutdown, switch on, enable operation: one transition per controlword.
                (TautDriveRequest::Enable, Power::SwitchOnDisabled) => Power::ReadyToSwitchOn,
                (TautDriveRequest::Enable, Power::ReadyToSwitchOn) => Power::SwitchedOn,
                (TautDriveRequest::Enable, Power::SwitchedOn) => Power::OperationEnabled,
                (TautDriveRequest::Enable, p) => p,
                (TautDriveRequest::QuickStop, Power::OperationEnabled) => Power::QuickStop,
                (TautDriveRequest::QuickStop, p) => p,
                (TautDriveRequest::Disable, _) => Power::SwitchOnDisabled,
                // No fault in this drive model: a fault reset changes nothing.
                (TautDriveRequest::FaultReset, p) => p,
            };
            let mode = c.mode[j];
            self.cmds[j] = match (self.drives[j], mode) {
                (Power::OperationEnabled, m) if m == TautCableMode::Position as u8 => {
                    let x = c.setpoint[j];
                    if !x.is_finite() {
                        return Err(error::fail(
                            TautError::InvalidArgument,
                            format_args!("{NAME}: commands.setpoint[{j}] = {x} m (position)"),
                        ));
                    }
                    // Encoder length -> drum length through the site's true offset and scale.
                    self.drum[j] = (x - self.truth.l0[j]) / self.truth.scale[j];
                    CableCommand::Length(self.drum[j])
                }
                (Power::OperationEnabled, m) if m == TautCableMode::Tension as u8 => {
                    let f = c.setpoint[j];
                    if !f.is_finite() {
                        return Err(error::fail(
                            TautError::InvalidArgument,
                            format_args!("{NAME}: commands.setpoint[{j}] = {f} N (tension)"),
                        ));
                    }
                    CableCommand::Tension(f.max(0.0))
                }
                (_, m) if m > TautCableMode::Tension as u8 => {
                    return Err(error::fail(
                        TautError::InvalidArgument,
                        format_args!("{NAME}: commands.mode[{j}] = {m} is not a TautCableMode"),
                    ))
                }
                // Brakes (or an idle enabled drive) hold the drum where it is.
                _ => CableCommand::Length(self.drum[j]),
            };
        }
        if !(period.is_finite() && period > 0.0 && period <= 1.0 && now.is_finite()) {
            return Err(error::fail(
                TautError::InvalidArgument,
                format_args!("{NAME}: now = {now} s, period = {period} s (0 < period <= 1)"),
            ));
        }
        let o = self.plant.step(period, &self.cmds);
        self.encoder_m[..n].copy_from_slice(o.encoder_m);
        self.tension_n[..n].copy_from_slice(o.tension_n);
        for j in 0..n {
            // A drum in torque mode pays out whatever the platform pulls.
            self.drum[j] = o.drum_m[j];
        }
        let t = now + period;
        self.t_plant = t;
        if t >= self.next_pose {
            self.next_pose = if self.next_pose.is_finite() { (self.next_pose + TRACKER_PERIOD_S).max(t) } else { t + TRACKER_PERIOD_S };
            let m = self.tracker.measure(self.plant.position(), &mut self.rng);
            // A dropout (NaN) leaves the last pose, which ages.
            if m.iter().all(|v| v.is_finite()) {
                self.pose_m = m;
                self.t_pose = t;
            }
        }
        Ok(())
    }
}

/// Builds the simulated robot of the configuration at `config_path` (4..=8 cables, nominal
/// anchors): a site with anchors off by up to 0.2 m and unknown encoder offsets drawn from
/// `seed`, the platform resting where an operator would park it, drives disabled on their brakes.
///
/// # Safety
/// `config_path` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn taut_sim_new(config_path: *const c_char, seed: u64, out: *mut *mut TautSim) -> TautError {
    const NAME: &str = "taut_sim_new";
    crate::guard(NAME, || {
        if out.is_null() {
            return error::fail(TautError::NullPointer, format_args!("{NAME}: out is NULL"));
        }
        // SAFETY: checked non-NULL.
        unsafe { *out = std::ptr::null_mut() };
        let path = match unsafe { crate::c_str(config_path, NAME, "config_path") } {
            Ok(Some(p)) => p,
            Ok(None) => return error::fail(TautError::NullPointer, format_args!("{NAME}: config_path is NULL")),
            Err(e) => return e,
        };
        let cfg = match RobotConfig::load(path) {
            Ok(c) => c,
            Err(e) => return error::fail(TautError::Config, format_args!("{e}")),
        };
        match TautSim::new(&cfg, seed) {
            Ok(s) => {
                // SAFETY: checked non-NULL.
                unsafe { *out = Box::into_raw(Box::new(s)) };
                TautError::Ok
            }
            Err(e) => error::fail(TautError::Config, format_args!("{NAME}: {path}: {e}")),
        }
    })
}

/// The sensors at host time `now_s`: encoder lengths and load-cell tensions of the last plant
/// step (aged by the time since), drive states, the newest tracker pose (100 Hz) and its age.
///
/// # Safety
/// `sim` is NULL or a live simulator; `out` NULL or a writable `TautInputs`.
#[no_mangle]
pub unsafe extern "C" fn taut_sim_read(sim: *const TautSim, now_s: f64, out: *mut TautInputs) -> TautError {
    crate::guard("taut_sim_read", || {
        let (Some(s), Some(o)) = (unsafe { sim.as_ref() }, unsafe { out.as_mut() }) else {
            return error::fail(TautError::NullPointer, format_args!("taut_sim_read: sim or out is NULL"));
        };
        s.read(now_s, o);
        TautError::Ok
    })
}

/// Applies the commands (controlword intent per drive, position or tension per cable) and
/// advances the physics by `period_s` to `now_s + period_s`.
///
/// # Safety
/// `sim` is NULL or a live simulator; `commands` NULL or a readable `TautCommands`.
#[no_mangle]
pub unsafe extern "C" fn taut_sim_write(sim: *mut TautSim, now_s: f64, period_s: f64, commands: *const TautCommands) -> TautError {
    crate::guard("taut_sim_write", || {
        let (Some(s), Some(c)) = (unsafe { sim.as_mut() }, unsafe { commands.as_ref() }) else {
            return error::fail(TautError::NullPointer, format_args!("taut_sim_write: sim or commands is NULL"));
        };
        match s.write(now_s, period_s, c) {
            Ok(()) => TautError::Ok,
            Err(e) => e,
        }
    })
}

/// The site's true anchors and encoder offsets and the platform's position, for a host to
/// judge the calibration.
///
/// # Safety
/// `sim` is NULL or a live simulator; `out` NULL or a writable `TautSimTruth`.
#[no_mangle]
pub unsafe extern "C" fn taut_sim_truth(sim: *const TautSim, out: *mut TautSimTruth) -> TautError {
    crate::guard("taut_sim_truth", || {
        let (Some(s), Some(o)) = (unsafe { sim.as_ref() }, unsafe { out.as_mut() }) else {
            return error::fail(TautError::NullPointer, format_args!("taut_sim_truth: sim or out is NULL"));
        };
        let mut t = TautSimTruth {
            n_cables: s.n as u32,
            anchors_m: [[f64::NAN; 3]; TAUT_MAX_CABLES],
            l0_m: [f64::NAN; TAUT_MAX_CABLES],
            position_m: s.plant.position(),
        };
        t.anchors_m[..s.n].copy_from_slice(&s.truth.anchors);
        t.l0_m[..s.n].copy_from_slice(&s.truth.l0);
        *o = t;
        TautError::Ok
    })
}

/// Frees the simulator (NULL allowed).
///
/// # Safety
/// `sim` is NULL or a live simulator, not used afterwards.
#[no_mangle]
pub unsafe extern "C" fn taut_sim_free(sim: *mut TautSim) {
    let _ = crate::guard("taut_sim_free", || {
        if !sim.is_null() {
            // SAFETY: ownership handed back by the caller.
            drop(unsafe { Box::from_raw(sim) });
        }
        TautError::Ok
    });
}
