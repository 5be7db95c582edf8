//! The motion state machine and the safety checks: the `update` step of the loop.
//!
//! ```text
//! Idle -> Enabling -> InitPhase 0 -> 1 -> 2 -> AwaitInitial -> Excitation -> Operate
//!                                                                  ^            |  recalibrate
//!                                                                  +------------+
//! any state --(cause)--> Faulted {hold | quick stop | disable}
//! Faulted --reset--> Resetting --(drives operational, faults reset, all enabled)--> Holding
//!                       └──(bus off, a drive still in fault / away / not enabled in time,
//!                           a new cause)--> Faulted, the refusal in `last_reset`
//! any state --stop--> Stopped
//! ```
//!
//! A reset is the only way out of a latched reaction, and it happens only on the operator's
//! request ([`Command::Reset`], `taut ctl reset`): the drives' faults are reset (CiA 402 fault
//! reset), rebooted drives (configured again by the master) and stopped ones are enabled again,
//! and each cable is held where its drive stands when it comes back, so nothing jumps; the
//! parameters in use are not touched. [`Snapshot::reenable_step_m`] is the largest per-cycle
//! change of a commanded length from the reset on (the first step measured from where the
//! drive stood), until the operator moves the robot again.
//!
//! In each initialisation phase two cables hold their length in position mode, one is reeled by
//! `motion.init_reel_m` at `motion.init_reel_speed_m_s` and back, and every other cable follows in
//! torque mode at `motion.init_follower_tension_n`. The phase is aborted (hold) when a held cable
//! exceeds `safety.max_tension_n` or the reeled one goes loose, or when the wiring check
//! ([`crate::wiring`]: encoders against the tracked motion, load cells against the statics, with
//! the nominal geometry) finds a swapped drive or load cell or an inverted encoder
//! ([`Cause::Miswired`]). The calibrator watches the states in the sample stream: the end of the
//! phases asks it for the initial estimate, the end of an excitation for a calibration; whatever
//! it publishes is picked up at a cycle boundary and faded in by the swap ramp.
//!
//! Everything here is fixed size; `update` never allocates.

use crate::io::{BusState, CableCommand, DeviceFault, DriveRequest, DriveStatus, Inputs, Outputs};
use crate::kin::LoopParams;
use crate::ramp::Ramp;
use crate::safety::{Cause, Reaction};
use crate::triple::Reader;
use crate::urgent::Urgent;
use crate::wiring::{Phase, WiringCheck, MIN_REEL_M};
use crate::MAX_CABLES;
use std::sync::Arc;

/// Motion states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum State {
    /// Not started.
    Idle = 0,
    /// Waiting for every drive to reach "operation enabled".
    Enabling = 1,
    /// One of the three initialisation phases ([`Controller::phase`]).
    InitPhase = 2,
    /// Holding while the calibrator computes the initial estimate.
    AwaitInitial = 3,
    /// Following the excitation trajectory.
    Excitation = 4,
    /// Following operator targets by inverse kinematics (also while a calibration runs).
    Operate = 5,
    /// Holding encoder lengths after a reset.
    Holding = 6,
    /// A safety reaction is latched ([`Controller::fault`]).
    Faulted = 7,
    /// Stopped by the operator; the loop ends.
    Stopped = 8,
    /// Bringing the drives back after a latched reaction, on the operator's reset.
    Resetting = 9,
}

impl State {
    /// From the `u8` carried in samples.
    pub fn from_u8(v: u8) -> State {
        match v {
            1 => State::Enabling,
            2 => State::InitPhase,
            3 => State::AwaitInitial,
            4 => State::Excitation,
            5 => State::Operate,
            6 => State::Holding,
            7 => State::Faulted,
            8 => State::Stopped,
            9 => State::Resetting,
            _ => State::Idle,
        }
    }

    /// Lower-case name for status output.
    pub fn name(self) -> &'static str {
        match self {
            State::Idle => "idle",
            State::Enabling => "enabling",
            State::InitPhase => "init-phase",
            State::AwaitInitial => "await-initial-estimate",
            State::Excitation => "excitation",
            State::Operate => "operate",
            State::Holding => "holding",
            State::Faulted => "faulted",
            State::Stopped => "stopped",
            State::Resetting => "resetting",
        }
    }
}

/// Commands from the control side. `Copy`; the loop takes them from a [`CommandSource`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Emergency stop (quick stop), in every state.
    Estop,
    /// Controlled stop: hold, disable, end the loop.
    Stop,
    /// Run the excitation again; the calibrator recalibrates from it.
    Recalibrate,
    /// Clear a latched safety reaction: reset drive faults, enable the drives again and hold
    /// where they stand (see the module documentation).
    Reset,
    /// Move the platform to this position, m (in operate or holding).
    MoveTo([f64; 3]),
}

/// Where the loop takes the control side's commands from, each cycle, until it returns `None`.
///
/// Runs in the real-time thread: `try_next` must not block, take a lock or allocate. taut's
/// hosts pass a closure over the receiving end of a bounded lock-free channel
/// (`move || rx.try_recv().ok()`, in `taut-plugin`, which owns the channel); a host without
/// one can use this crate's own [`spsc`](crate::spsc) ring, whose [`Consumer`](crate::spsc::Consumer)
/// is a source (with the producer behind the host's own hand-over).
pub trait CommandSource: Send {
    /// The next command, or `None` when none is waiting. Never waits.
    fn try_next(&mut self) -> Option<Command>;
}

impl<F: FnMut() -> Option<Command> + Send> CommandSource for F {
    #[inline]
    fn try_next(&mut self) -> Option<Command> {
        self()
    }
}

impl CommandSource for crate::spsc::Consumer<Command> {
    #[inline]
    fn try_next(&mut self) -> Option<Command> {
        self.pop()
    }
}

/// Why a reset did not bring the robot back. The reaction stays latched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResetRefusal {
    /// There is no latched reaction to reset.
    NothingToReset,
    /// The CAN bus is still off: nothing can reach the drives.
    BusOff {
        /// The interface.
        iface: crate::io::IfName,
    },
    /// A drive did not come back to NMT operational in time (still rebooting or lost).
    NotOperational {
        /// Cable.
        cable: u8,
        /// CANopen node id.
        node: u8,
    },
    /// A drive is still in fault after the fault reset: its cause is still there.
    StillInFault {
        /// Cable.
        cable: u8,
        /// CANopen node id.
        node: u8,
        /// The last EMCY code it sent (0: none seen).
        code: u16,
    },
    /// A drive did not reach "operation enabled" in time.
    NotEnabled {
        /// Cable.
        cable: u8,
        /// CANopen node id.
        node: u8,
    },
    /// A new cause appeared during the reset.
    NewCause(Cause),
}

impl std::fmt::Display for ResetRefusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            ResetRefusal::NothingToReset => write!(f, "nothing to reset: no safety reaction is latched"),
            ResetRefusal::BusOff { iface } => write!(
                f,
                "{iface} is still bus-off: fix the bus (wiring, termination, bitrate), let the controller restart (restart-ms), then reset again"
            ),
            ResetRefusal::NotOperational { cable, node } => write!(
                f,
                "drive node {node} (cable {}) is not operational: it is still booting or being configured, or its heartbeat is lost; check its power and CAN cable, then reset again", cable + 1
            ),
            ResetRefusal::StillInFault { cable, node, code } => write!(
                f,
                "drive node {node} (cable {}) is still in fault after a fault reset (last EMCY 0x{code:04X}): its cause is still present; see the drive's error, then reset again", cable + 1
            ),
            ResetRefusal::NotEnabled { cable, node } => {
                write!(f, "drive node {node} (cable {}) did not reach operation enabled within motion.enable_timeout_s", cable + 1)
            }
            ResetRefusal::NewCause(c) => write!(f, "a new cause during the reset: {c}"),
        }
    }
}

/// What became of the last [`Command::Reset`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResetOutcome {
    /// Under way.
    InProgress,
    /// The robot is back, holding.
    Done,
    /// Refused; the reaction stays latched.
    Refused(ResetRefusal),
}

/// The numbers the controller needs, resolved from the configuration at start-up.
#[derive(Debug, Clone, Copy)]
pub struct ControllerConfig {
    /// Number of cables.
    pub n: usize,
    /// CANopen node id of each cable's drive (for causes).
    pub node_ids: [u8; MAX_CABLES],
    /// Cables that follow in torque mode outside the initialisation (redundant cables).
    pub follower: [bool; MAX_CABLES],
    /// Their tension, N: the least they hold; more where the statics need it to keep the
    /// position cables taut ([`crate::follower`]).
    pub follower_tension_n: f64,
    /// Platform mass, kg (the statics of the follower tension).
    pub mass_kg: f64,
    /// Swing of the follower tension over the excitation, N (0: none): when elasticity is
    /// modelled, the tension the cables carry varies independently of their length, so that
    /// the calibration can tell stretch from drum scale.
    pub excitation_tension_swing_n: f64,
    /// `[held_a, held_b, reeled]` per phase.
    pub phases: [[usize; 3]; 3],
    /// Reel length, m (signed).
    pub reel_m: f64,
    /// Reel speed, m/s.
    pub reel_speed_m_s: f64,
    /// Reel acceleration, m/s²: the reel starts and stops on a trapezoidal speed profile, so that
    /// the platform is not jerked into a swing the followers cannot follow.
    pub reel_accel_m_s2: f64,
    /// Torque-mode tension of followers in the phases, N.
    pub init_follower_tension_n: f64,
    /// Pause after each phase, s.
    pub settle_s: f64,
    /// The phases check the wiring ([`crate::wiring`]; also needs `nominal_statics`).
    pub wiring_check: bool,
    /// A held cable below this tension ends the reeling early (the platform would leave the
    /// circle the three-phase method fits), N.
    pub held_min_tension_n: f64,
    /// Drive enable timeout, s.
    pub enable_timeout_s: f64,
    /// Excitation duration, s.
    pub excitation_s: f64,
    /// Excitation speed limit, m/s.
    pub excitation_speed_m_s: f64,
    /// Workspace box, m.
    pub workspace: [[f64; 3]; 2],
    /// Swap ramp time, s.
    pub swap_ramp_s: f64,
    /// Operator move speed, m/s.
    pub move_speed_m_s: f64,
    /// Tension limit, N.
    pub max_tension_n: f64,
    /// Loose threshold, N.
    pub loose_tension_n: f64,
    /// Tension age limit, s; infinite when the robot has no load cells.
    pub tension_max_age_s: f64,
    /// Tracker age limit, s.
    pub tracker_max_age_s: f64,
    /// Cable speed limit, m/s.
    pub max_cable_speed_m_s: f64,
    /// Workspace margin, m.
    pub workspace_margin_m: f64,
    /// The tracker-free start-up's dwell plan (`motion.startup = "dwell"`); `None`: the
    /// three-phase start-up with a tracker. Set by [`ControllerConfig::with_dwell_plan`].
    pub dwell: Option<DwellLoopPlan>,
    /// The designed excitation path (`crate::excite`); `None`: the fixed Lissajous curve.
    pub tour: Option<taut_model::tour::Tour>,
    /// The design's geometry (nominal anchors and platform points; offsets unknown, so not
    /// valid for lengths), for the statics of the initialisation's follower tension before any
    /// parameters exist. `None` without nominal anchors.
    pub nominal_statics: Option<LoopParams>,
}

/// Most dwell poses the loop holds.
/// (Equal to `taut_config::runtime::MAX_DWELL_POSES`, which bounds `motion.dwell_poses`: a test in
/// taut-io (`rt_config`) keeps the two equal.)
pub const MAX_DWELL_POSES: usize = 64;

/// The shortest recording of the tracker-free start-up's first rest, s: the rest estimate
/// averages it, also when the plan's poses are passed without a dwell (`dwell_s` 0, a continuous
/// motion calibrated from moving windows).
pub const MIN_REST_S: f64 = 1.0;

/// The dwell plan as the loop holds it: fixed size, computed before the loop starts
/// (`taut_calib::selfcal::plan`).
///
/// Without a tracker the start-up is: hold at rest for `settle_s`, record `dwell_s` (phase 0:
/// the rest estimate), then visit `poses` in order: move, hold `settle_s`, record `dwell_s` (the
/// sample's phase is the pose's index). Moves are trapezoids in speed, up to `speed_m_s`, at the
/// start-up's acceleration (`ControllerConfig::reel_accel_m_s2`). Recalibration
/// visits the poses again. At the poses with a `tare` mask, the dwell is followed by a tare: the
/// cables of the mask are ramped to zero tension (torque mode, a smoothstep over the first half
/// of `settle_s`) while the others hold the platform where it is in position mode (a follower
/// that is not in the mask holds the length it had when the tare began), held `settle_s`,
/// recorded `dwell_s` (phase `MAX_DWELL_POSES + index`): the slack cables' load cells then read
/// their offsets. Then the slack cables are ramped back to the tension they carried before
/// (`settle_s`) and the next move begins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DwellLoopPlan {
    /// The poses, m (the first `count`).
    pub poses: [[f64; 3]; MAX_DWELL_POSES],
    /// Poses used.
    pub count: usize,
    /// Recorded time at each pose, s.
    pub dwell_s: f64,
    /// Hold before recording, s.
    pub settle_s: f64,
    /// Mean platform speed of a move, m/s.
    pub speed_m_s: f64,
    /// Cables slackened in the tare after each pose, bit `j` for cable `j` (0: no tare; the
    /// first `count`).
    pub tare: [u8; MAX_DWELL_POSES],
}

/// Why a configuration cannot drive the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControllerConfigError {
    /// More cables than the loop is built for.
    TooManyCables {
        /// Cables configured.
        n: usize,
    },
    /// No workspace box and no nominal anchors to derive one from.
    NoWorkspace,
}

impl std::fmt::Display for ControllerConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ControllerConfigError::TooManyCables { n } => write!(f, "{n} cables: the real-time loop is built for at most {MAX_CABLES}"),
            ControllerConfigError::NoWorkspace => {
                f.write_str("no workspace box: set motion.workspace_min_m and motion.workspace_max_m, or give every cable a nominal anchor")
            }
        }
    }
}

impl std::error::Error for ControllerConfigError {}

impl ControllerConfig {
    /// Runs the tracker-free start-up through `poses` (at most [`MAX_DWELL_POSES`], the rest
    /// ignored) instead of the three phases and the excitation.
    pub fn with_dwell_plan(mut self, poses: &[[f64; 3]], dwell_s: f64, settle_s: f64, speed_m_s: f64) -> ControllerConfig {
        let mut p = [[0.0; 3]; MAX_DWELL_POSES];
        let count = poses.len().min(MAX_DWELL_POSES);
        p[..count].copy_from_slice(&poses[..count]);
        self.dwell = Some(DwellLoopPlan { poses: p, count, dwell_s, settle_s, speed_m_s, tare: [0; MAX_DWELL_POSES] });
        self
    }

    /// The cables slackened in a tare after each dwell pose (`tare[k]`, a bit mask, for pose
    /// `k`; see [`DwellLoopPlan`]). Without a dwell plan, nothing.
    pub fn with_dwell_tares(mut self, tare: &[u8]) -> ControllerConfig {
        if let Some(d) = self.dwell.as_mut() {
            let k = tare.len().min(MAX_DWELL_POSES);
            d.tare[..k].copy_from_slice(&tare[..k]);
        }
        self
    }
}

/// Segments of an initialisation phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Segment {
    Lead,
    Reel,
    /// The reel ended early: the reeled cable decelerates to rest before it returns.
    Brake,
    Return,
    Settle,
}

/// A snapshot for status output, published by the loop every cycle.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot {
    /// Loop time, s.
    pub t: f64,
    /// Motion state.
    pub state: State,
    /// Initialisation phase, -1 outside.
    pub phase: i8,
    /// Phases completed so far.
    pub phases_completed: u8,
    /// Calibration run.
    pub run: u16,
    /// Latched cause and reaction.
    pub fault: Option<(Cause, Reaction)>,
    /// Version of the parameters in use.
    pub params_version: u64,
    /// True while a parameter swap is being faded in.
    pub swap_active: bool,
    /// Parameter swaps done.
    pub swaps: u32,
    /// Largest per-cycle change of a commanded length during any swap so far, m.
    pub max_swap_step_m: f64,
    /// Platform target (operate), m.
    pub target_m: [f64; 3],
    /// Latest inputs.
    pub inputs: Inputs,
    /// Latest commanded lengths (position mode cables), m.
    pub cmd_m: [f64; MAX_CABLES],
    /// The last reset and how it ended.
    pub last_reset: Option<ResetOutcome>,
    /// Resets that brought the robot back.
    pub resets: u32,
    /// Largest per-cycle change of a commanded length since the last reset, m (see the module
    /// documentation).
    pub reenable_step_m: f64,
    /// The start-up's wiring check ([`crate::wiring`]): the largest normalised residual of the
    /// configured wiring so far, encoders and load cells (1: at the tolerance).
    pub wiring_worst: [f64; 2],
}

/// The motion state machine and safety checks.
pub struct Controller {
    cfg: ControllerConfig,
    commands: Box<dyn CommandSource>,
    params_rx: Reader<LoopParams>,
    params: LoopParams,
    /// The tension inverse kinematics stretches each cable by, N (see [`Controller::track_tension`]).
    ik_tension: [f64; MAX_CABLES],
    /// The followers' commanded tension, N ([`Controller::follower_tension`]); held in
    /// holding states.
    follower_n: f64,
    state: State,
    state_t0: f64,
    phase: i8,
    phases_completed: u8,
    segment: Segment,
    segment_t0: f64,
    reel_start_m: f64,
    reel_peak_m: f64,
    /// Where and how fast the reel was when it ended early (m, m/s, signed).
    brake_from: (f64, f64),
    /// The held cables' tensions averaged over [`HELD_TENSION_TAU_S`] during the reel, N.
    held_avg_n: [f64; 2],
    /// The dwell plan's position cables' tensions averaged over [`HELD_TENSION_TAU_S`], N: a
    /// swinging platform makes them oscillate about their trend, and only the trend says that
    /// the plan does not hold the platform.
    dwell_avg_n: [f64; MAX_CABLES],
    /// The followers' tension in the initialisation phases, N ([`Controller::init_follower_tension`]).
    init_follower_n: f64,
    /// While enabling: the cables whose drive is enabled and whose hold length is latched.
    enable_latched: [bool; MAX_CABLES],
    run: u16,
    fault: Option<(Cause, Reaction)>,
    hold_m: [f64; MAX_CABLES],
    cmd: [f64; MAX_CABLES],
    cmd_valid: bool,
    // excitation
    start_m: [f64; 3],
    lissajous_start: [f64; 3],
    /// Where in the tour the excitation joins it (its waypoint nearest the start), s.
    tour_t0: f64,
    approach_s: f64,
    omega: [f64; 3],
    amp: [f64; 3],
    centre: [f64; 3],
    // operate
    target: [f64; 3],
    goal: [f64; 3],
    transfer: Ramp,
    swap: Ramp,
    swaps: u32,
    awaited_version: u64,
    stop_cycles: u32,
    urgent: Option<Arc<Urgent>>,
    reset: ResetRun,
    dwell: DwellRun,
    /// In a tare: each cable's measured length when it began (a follower not in the tare
    /// holds it in position mode), m.
    tare_hold_m: [f64; MAX_CABLES],
    /// Sum and count of each cable's length readings over the current dwell's record, m: where
    /// a follower that holds in position mode for a tare is held (one reading is off by its
    /// noise, which a stiff cable turns into tension).
    rec_sum_m: [f64; MAX_CABLES],
    rec_n: [u32; MAX_CABLES],
    /// In a tare: each cable's tension when it began (the slack cables ramp from it to zero
    /// and back), N.
    tare_from_n: [f64; MAX_CABLES],
    /// The start-up's wiring check ([`crate::wiring`]).
    wiring: WiringCheck,
    /// Each cable's length rate from its encoder, low-passed over [`CABLE_SPEED_TAU_S`], m/s
    /// (> 0 paying out; NaN: unknown). The friction correction's direction.
    cable_v: [f64; MAX_CABLES],
    /// Each encoder's previous reading, m (NaN: none).
    prev_len: [f64; MAX_CABLES],
}

/// Where the dwell plan is (see [`DwellLoopPlan`]).
#[derive(Debug, Clone, Copy)]
struct DwellRun {
    /// Pose being approached or held.
    k: usize,
    seg: DwellSeg,
    t0: f64,
    from: [f64; 3],
    move_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DwellSeg {
    Move,
    Settle,
    Record,
    /// The tare's cables ramped to zero tension, then held there.
    TareSettle,
    /// The tare recorded.
    Tare,
    /// The tare's cables ramped back to their tension.
    TareReturn,
}

/// The bookkeeping of the operator's reset.
#[derive(Debug, Clone, Copy)]
struct ResetRun {
    last: Option<ResetOutcome>,
    done: u32,
    /// Faults have been reset; the drives are being enabled.
    enabling: bool,
    /// Cable's drive has been seen enabled during this reset (its hold length is fixed then).
    back: [bool; MAX_CABLES],
    /// Last EMCY code per cable.
    emcy: [u16; MAX_CABLES],
    /// Step measurement: the previous command per cable (NaN: not measured).
    prev: [f64; MAX_CABLES],
    measuring: bool,
    max_step_m: f64,
}

impl ResetRun {
    fn new() -> Self {
        ResetRun {
            last: None,
            done: 0,
            enabling: false,
            back: [false; MAX_CABLES],
            emcy: [0; MAX_CABLES],
            prev: [f64::NAN; MAX_CABLES],
            measuring: false,
            max_step_m: 0.0,
        }
    }
}

/// Swing of the follower tension over an excitation that calibrates elasticity, N. At EA
/// 20 kN and 4 m of cable 60 N stretches a cable by 12 mm, several times the tracker's noise,
/// while the cables' tensions stay far below a drive's or a cable's limit (the statics keep
/// them under half of `safety.max_tension_n`, see `Controller::follower_tension`).
pub const EXCITATION_TENSION_SWING_N: f64 = 60.0;

/// Period of the tension swing, s (rounded so a whole number of swings fits the excitation):
/// several times faster than the Lissajous motion (periods of 25-40 s), so that tension and
/// length are not correlated over the run.
const EXCITATION_TENSION_PERIOD_S: f64 = 6.0;

/// Phases of the fixed Lissajous excitation's three axes, rad (`excite` predicts its uncertainty).
pub const LISSAJOUS_PHASE: [f64; 3] = [0.0, std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_4];
/// Frequency ratios of the fixed Lissajous excitation's three axes.
pub const LISSAJOUS_RATIO: [f64; 3] = [1.0, 0.77, 0.59];

fn smoothstep(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

impl Controller {
    /// A controller in `Idle`. Commands come from `commands` (see [`CommandSource`]), the
    /// parameters through `params_rx` (they may be invalid until the calibrator publishes an
    /// estimate). Allocates once, here (the command source is boxed).
    pub fn new(cfg: ControllerConfig, commands: impl CommandSource + 'static, mut params_rx: Reader<LoopParams>) -> Controller {
        let params = *params_rx.read();
        let centre = [
            (cfg.workspace[0][0] + cfg.workspace[1][0]) / 2.0,
            (cfg.workspace[0][1] + cfg.workspace[1][1]) / 2.0,
            (cfg.workspace[0][2] + cfg.workspace[1][2]) / 2.0,
        ];
        let mut amp = [0.0; 3];
        let mut omega = [0.0; 3];
        for i in 0..3 {
            // 80% of the half-size; |a_i w_i| <= v / sqrt(3) keeps the speed under v.
            amp[i] = 0.8 * (cfg.workspace[1][i] - cfg.workspace[0][i]) / 2.0;
            omega[i] = LISSAJOUS_RATIO[i] * cfg.excitation_speed_m_s / (3f64.sqrt() * amp[i].max(1e-3));
        }
        Controller {
            cfg,
            commands: Box::new(commands),
            params_rx,
            params,
            ik_tension: [f64::NAN; MAX_CABLES],
            follower_n: cfg.follower_tension_n,
            state: State::Idle,
            state_t0: 0.0,
            phase: -1,
            phases_completed: 0,
            segment: Segment::Reel,
            segment_t0: 0.0,
            reel_start_m: 0.0,
            reel_peak_m: 0.0,
            brake_from: (0.0, 0.0),
            held_avg_n: [f64::NAN; 2],
            dwell_avg_n: [f64::NAN; MAX_CABLES],
            init_follower_n: cfg.init_follower_tension_n,
            enable_latched: [false; MAX_CABLES],
            run: 0,
            fault: None,
            hold_m: [0.0; MAX_CABLES],
            cmd: [0.0; MAX_CABLES],
            cmd_valid: false,
            start_m: centre,
            lissajous_start: centre,
            tour_t0: 0.0,
            approach_s: 1.0,
            omega,
            amp,
            centre,
            target: centre,
            goal: centre,
            transfer: Ramp::new(cfg.swap_ramp_s),
            swap: Ramp::new(cfg.swap_ramp_s),
            swaps: 0,
            awaited_version: 0,
            stop_cycles: 0,
            reset: ResetRun::new(),
            urgent: None,
            dwell: DwellRun { k: 0, seg: DwellSeg::Move, t0: 0.0, from: centre, move_s: 1.0 },
            tare_hold_m: [f64::NAN; MAX_CABLES],
            rec_sum_m: [0.0; MAX_CABLES],
            rec_n: [0; MAX_CABLES],
            tare_from_n: [0.0; MAX_CABLES],
            wiring: WiringCheck::new(),
            cable_v: [f64::NAN; MAX_CABLES],
            prev_len: [f64::NAN; MAX_CABLES],
        }
    }

    /// Takes estop and stop also from `urgent` (set by the control server without the command
    /// queue), tested every cycle and before each queued command.
    pub fn with_urgent(mut self, urgent: Arc<Urgent>) -> Controller {
        self.urgent = Some(urgent);
        self
    }

    fn take_urgent(&mut self, inp: &Inputs, now: f64) {
        let (estop, stop) = match &self.urgent {
            Some(u) => (u.take_estop(), u.take_stop()),
            None => return,
        };
        if estop {
            self.handle_command(Command::Estop, inp, now);
            // What is queued was sent before the estop or just with it: a reset or a move must
            // not undo or follow an estop the operator has not seen latched. Only a stop (it ends
            // the loop, which is what shutdown waits for) is still honoured.
            while let Some(c) = self.commands.try_next() {
                if c == Command::Stop {
                    self.handle_command(c, inp, now);
                }
            }
        }
        if stop {
            self.handle_command(Command::Stop, inp, now);
        }
    }

    /// Back to `Idle`, as before the first cycle, keeping the parameters in use: the plugin's
    /// retry after a failed activation and its re-activation after a deactivation. The latched
    /// reaction is cleared (the caller has left the drives disabled or stopped); the next
    /// `update` asks for the drives to be enabled again and runs the start-up from its first
    /// phase.
    pub fn rearm(&mut self) {
        self.state = State::Idle;
        self.phase = -1;
        self.fault = None;
        self.stop_cycles = 0;
        self.cmd_valid = false;
        self.phases_completed = 0;
        self.reset.measuring = false;
        self.transfer.cancel();
        self.swap.cancel();
    }

    /// The current state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The initialisation phase, -1 outside.
    pub fn phase(&self) -> i8 {
        self.phase
    }

    /// The phase label of this cycle's sample: the phase while its cable is reeled and returned,
    /// -1 otherwise (settling before and after).
    pub fn phase_label(&self) -> i8 {
        if self.state == State::Excitation && self.cfg.dwell.is_some() {
            // Without a tracker: the index of the pose while its dwell is recorded.
            return match self.dwell.seg {
                DwellSeg::Record => self.dwell.k.min(i8::MAX as usize) as i8,
                DwellSeg::Tare => (MAX_DWELL_POSES + self.dwell.k).min(i8::MAX as usize) as i8,
                _ => -1,
            };
        }
        if self.state == State::InitPhase && matches!(self.segment, Segment::Reel | Segment::Brake | Segment::Return) {
            self.phase
        } else {
            -1
        }
    }

    /// The calibration run (0: start-up).
    pub fn run(&self) -> u16 {
        self.run
    }

    /// The latched cause and reaction, if any.
    pub fn fault(&self) -> Option<(Cause, Reaction)> {
        self.fault
    }

    /// The parameters in use.
    pub fn params(&self) -> &LoopParams {
        &self.params
    }

    /// True once the loop may end (stopped and drives told to disable).
    pub fn finished(&self) -> bool {
        self.state == State::Stopped && self.stop_cycles >= 10
    }

    /// Largest per-cycle change of a commanded length during any parameter swap, m.
    pub fn max_swap_step_m(&self) -> f64 {
        self.swap.max_step_m
    }

    /// A snapshot for status output.
    pub fn snapshot(&self, t: f64, inputs: &Inputs) -> Snapshot {
        Snapshot {
            t,
            state: self.state,
            phase: self.phase,
            phases_completed: self.phases_completed,
            run: self.run,
            fault: self.fault,
            params_version: self.params.version,
            swap_active: self.swap.active(),
            swaps: self.swaps,
            max_swap_step_m: self.swap.max_step_m,
            target_m: self.target,
            inputs: *inputs,
            cmd_m: self.cmd,
            last_reset: self.reset.last,
            resets: self.reset.done,
            reenable_step_m: self.reset.max_step_m,
            wiring_worst: self.wiring.worst(),
        }
    }

    fn enter(&mut self, s: State, now: f64) {
        self.state = s;
        self.state_t0 = now;
        if s != State::InitPhase {
            self.phase = -1;
        }
    }

    fn latch(&mut self, cause: Cause, inp: &Inputs, now: f64) {
        let reaction = cause.reaction();
        if self.state == State::Stopped {
            return;
        }
        // Commands come from the reaction now, not from the re-enable.
        self.reset.measuring = false;
        if self.state == State::Resetting {
            // The reset is over: the reaction comes back, the worse of the two.
            self.reset.last = Some(ResetOutcome::Refused(ResetRefusal::NewCause(cause)));
            self.enter(State::Faulted, now);
        }
        match self.fault {
            Some((_, r)) if r >= reaction => return,
            _ => {}
        }
        if self.fault.is_none() {
            // Hold where the cables are, or where they were last commanded if not measured.
            for j in 0..self.cfg.n {
                self.hold_m[j] = if inp.length_m[j].is_finite() { inp.length_m[j] } else { self.cmd[j] };
            }
        }
        self.fault = Some((cause, reaction));
        self.transfer.cancel();
        self.swap.cancel();
        self.enter(State::Faulted, now);
    }

    fn hold_here(&mut self, inp: &Inputs) {
        for j in 0..self.cfg.n {
            self.hold_m[j] = if inp.length_m[j].is_finite() { inp.length_m[j] } else { self.cmd[j] };
        }
    }

    fn handle_command(&mut self, c: Command, inp: &Inputs, now: f64) {
        match c {
            Command::Estop => self.latch(Cause::Estop, inp, now),
            Command::Stop => {
                if self.fault.is_none() {
                    self.hold_here(inp);
                }
                self.transfer.cancel();
                self.swap.cancel();
                self.enter(State::Stopped, now);
            }
            Command::Recalibrate => {
                if matches!(self.state, State::Operate | State::Holding) && self.params.valid && self.fault.is_none() {
                    self.reset.measuring = false;
                    self.run = self.run.wrapping_add(1);
                    self.start_excitation(inp, now);
                }
            }
            Command::Reset => self.start_reset(inp, now),
            Command::MoveTo(p) => {
                // The operator moves the robot: the re-enable is over.
                self.reset.measuring = false;
                let inside = (0..3).all(|i| p[i] >= self.cfg.workspace[0][i] && p[i] <= self.cfg.workspace[1][i]);
                if !inside || !self.params.valid {
                    return;
                }
                match self.state {
                    State::Operate => self.goal = p,
                    State::Holding => {
                        self.target = if inp.pose_age_s <= self.cfg.tracker_max_age_s { inp.pose_m } else { self.goal };
                        self.goal = p;
                        self.enter_ik(State::Operate, now);
                    }
                    _ => {}
                }
            }
        }
    }

    /// Switches to a state whose commands come from inverse kinematics; the difference to the
    /// last command is faded out by the transfer ramp.
    fn enter_ik(&mut self, s: State, now: f64) {
        let mut next = [0.0; MAX_CABLES];
        self.params.lengths_at(&self.target, &self.ik_tension, &mut next);
        if self.cmd_valid {
            self.transfer.start(self.cfg.n, &self.cmd, &next);
        }
        self.enter(s, now);
    }

    fn start_excitation(&mut self, inp: &Inputs, now: f64) {
        if let Some(plan) = self.cfg.dwell {
            return self.start_dwell_plan(&plan, inp, now);
        }
        let p0 = if inp.pose_age_s <= self.cfg.tracker_max_age_s { inp.pose_m } else { self.target };
        self.start_m = p0;
        self.tour_t0 = 0.0;
        self.lissajous_start = match &self.cfg.tour {
            // Joined at the waypoint nearest the platform: a short approach.
            Some(tour) => {
                let (k, t0) = tour.nearest_waypoint(&p0);
                self.tour_t0 = t0;
                tour.waypoints[k]
            }
            None => std::array::from_fn(|i| self.centre[i] + self.amp[i] * LISSAJOUS_PHASE[i].sin()),
        };
        let d = (0..3).map(|i| (self.lissajous_start[i] - p0[i]).powi(2)).sum::<f64>().sqrt();
        // Smoothstep peaks at 1.5 x the mean speed: at the tour's cruise speed when there is one
        // (the approach's data are used for the calibration too, but the tour's are worth more).
        let v = self.cfg.tour.map_or(self.cfg.excitation_speed_m_s, |t| t.speed_m_s.max(self.cfg.excitation_speed_m_s));
        self.approach_s = (1.5 * d / v).max(1.0);
        self.target = p0;
        self.enter_ik(State::Excitation, now);
    }

    fn excitation_point(&self, t: f64) -> [f64; 3] {
        if t < self.approach_s {
            let w = smoothstep(t / self.approach_s);
            std::array::from_fn(|i| self.start_m[i] + w * (self.lissajous_start[i] - self.start_m[i]))
        } else if let Some(tour) = &self.cfg.tour {
            tour.point(t - self.approach_s + self.tour_t0)
        } else {
            let tt = t - self.approach_s;
            let mut p = [0.0; 3];
            for i in 0..3 {
                p[i] = self.centre[i] + self.amp[i] * (self.omega[i] * tt + LISSAJOUS_PHASE[i]).sin();
            }
            p
        }
    }

    /// One cycle: `now` is the loop time, `dt` the measured period. Reads `inp`, writes `out`.
    pub fn update(&mut self, now: f64, dt: f64, inp: &Inputs, out: &mut Outputs) {
        let n = self.cfg.n;
        self.take_urgent(inp, now);
        while let Some(c) = self.commands.try_next() {
            // An estop set before this command was sent is acted on first (see urgent.rs).
            self.take_urgent(inp, now);
            self.handle_command(c, inp, now);
        }

        // New parameters are taken at this cycle boundary only.
        let mut swapped = false;
        if self.params_rx.update() {
            let p = *self.params_rx.current();
            if p.valid && p.version != self.params.version {
                self.params = p;
                swapped = true;
            }
        }

        // From here on a tension is the cable's, not its cell's reading: the statics, the
        // stretch and the safety limits all judge the cable.
        self.track_cable_speed(inp, dt);
        let corrected;
        let inp = if self.params.effects.corrects_tensions() {
            corrected = self.cable_tensions(inp);
            &corrected
        } else {
            inp
        };
        self.track_tension(inp, dt);
        self.track_dwell_slack(inp, now, dt);
        self.check_devices(inp, now);
        if self.state == State::InitPhase && self.cfg.dwell.is_none() {
            if let Some(cause) = self.check_wiring(inp, dt) {
                self.latch(cause, inp, now);
            }
        }
        if !matches!(self.state, State::Idle | State::Faulted | State::Stopped) {
            self.check_limits(inp, now);
        }

        let mut next = self.cmd;
        let mut modes = [CableCommand::Idle; MAX_CABLES];
        out.request = DriveRequest::Enable;
        match self.state {
            State::Idle => {
                out.request = DriveRequest::Disable;
                self.enable_latched = [false; MAX_CABLES];
                self.enter(State::Enabling, now);
                next[..n].copy_from_slice(&inp.length_m[..n]);
            }
            State::Enabling => {
                // A drive holds where it was when it came up: one latched reading, not every
                // cycle's (a noisy encoder would shake a stiff cable). The cables that follow
                // in the first motion come up in torque mode: four stiff cables held in
                // position fight over the platform.
                for j in 0..n {
                    let enabled = inp.drive[j] == DriveStatus::Enabled;
                    if !(enabled && self.enable_latched[j]) {
                        self.hold_m[j] = inp.length_m[j];
                        self.enable_latched[j] = enabled && inp.length_m[j].is_finite();
                    }
                    next[j] = self.hold_m[j];
                    modes[j] = if self.enabling_follower(j) {
                        CableCommand::Tension(self.cfg.init_follower_tension_n)
                    } else {
                        CableCommand::Position(next[j])
                    };
                }
                let first_off = (0..n).find(|&j| inp.drive[j] != DriveStatus::Enabled);
                // The phases need fresh tensions and poses: the I/O threads may still be starting.
                let stale_tension = (0..n).find(|&j| inp.tension_age_s[j] > self.cfg.tension_max_age_s);
                let stale_pose = self.cfg.dwell.is_none() && inp.pose_age_s > self.cfg.tracker_max_age_s;
                let waited = now - self.state_t0 > self.cfg.enable_timeout_s;
                match first_off {
                    None if waited && stale_tension.is_some() => {
                        self.latch(Cause::TensionStale { cable: stale_tension.unwrap_or(0) as u8 }, inp, now)
                    }
                    None if waited && stale_pose => self.latch(Cause::TrackerStale, inp, now),
                    None if stale_tension.is_some() || stale_pose => {}
                    None if (0..n).all(|j| inp.length_m[j].is_finite()) => {
                        self.hold_here(inp);
                        self.start_phase(0, inp, now);
                        if self.cfg.dwell.is_some() {
                            // The rest dwell instead of the reeling: nothing is reeled.
                            self.segment = Segment::Lead;
                        }
                    }
                    Some(j) if now - self.state_t0 > self.cfg.enable_timeout_s => {
                        self.latch(Cause::EnableTimeout { cable: j as u8 }, inp, now)
                    }
                    _ => {}
                }
            }
            State::InitPhase if self.cfg.dwell.is_some() => self.rest_dwell(now, &mut next, &mut modes),
            State::InitPhase => {
                let k = self.phase as usize;
                let [a, b, r] = self.cfg.phases[k];
                let ts = now - self.segment_t0;
                let (speed, accel) = (self.cfg.reel_speed_m_s, self.cfg.reel_accel_m_s2);
                let travel_s = trapezoid_s(self.cfg.reel_m.abs(), speed, accel);
                let reel = match self.segment {
                    Segment::Lead => {
                        // Let the platform settle with the followers in torque mode first.
                        if ts >= self.cfg.settle_s {
                            self.segment = Segment::Reel;
                            self.segment_t0 = now;
                            self.held_avg_n = [f64::NAN; 2];
                        }
                        0.0
                    }
                    Segment::Reel => {
                        let r = self.cfg.reel_m.signum() * trapezoid_at(self.cfg.reel_m.abs(), speed, accel, ts);
                        // A held cable going slack ends the reeling early: the platform would
                        // leave the circle about the held anchors.
                        // Only readings taken during the reel count (see `measured_after`).
                        // A platform that swings makes the held tensions oscillate about
                        // their trend; only the trend says that it leaves the circle.
                        let w = (dt / HELD_TENSION_TAU_S).clamp(0.0, 1.0);
                        for (i, &j) in [a, b].iter().enumerate() {
                            let t = inp.tension_n[j];
                            let avg = &mut self.held_avg_n[i];
                            if !measured_after(inp, j, ts, REEL_GRACE_S) || !t.is_finite() {
                                continue;
                            }
                            *avg = if avg.is_finite() { *avg + w * (t - *avg) } else { t };
                        }
                        let slack =
                            self.cfg.tension_max_age_s.is_finite() && self.held_avg_n.iter().any(|&t| t < self.cfg.held_min_tension_n);
                        if ts >= travel_s {
                            self.segment = Segment::Return;
                            self.segment_t0 = now;
                            self.reel_peak_m = r;
                        } else if slack {
                            // Decelerate to rest: a drum stopped dead would jerk the platform.
                            let v = self.cfg.reel_m.signum() * trapezoid_speed(self.cfg.reel_m.abs(), speed, accel, ts);
                            self.segment = Segment::Brake;
                            self.segment_t0 = now;
                            self.brake_from = (r, v);
                        }
                        r
                    }
                    Segment::Brake => {
                        let (r0, v0) = self.brake_from;
                        let stop_s = if accel > 0.0 { v0.abs() / accel } else { 0.0 };
                        let t = ts.min(stop_s);
                        let r = r0 + v0 * t - 0.5 * v0.signum() * accel * t * t;
                        if ts >= stop_s {
                            self.segment = Segment::Return;
                            self.segment_t0 = now;
                            self.reel_peak_m = r;
                        }
                        r
                    }
                    Segment::Return => {
                        let peak = self.reel_peak_m.abs();
                        if ts >= trapezoid_s(peak, speed, accel) {
                            self.segment = Segment::Settle;
                            self.segment_t0 = now;
                        }
                        self.reel_peak_m.signum() * (peak - trapezoid_at(peak, speed, accel, ts))
                    }
                    Segment::Settle => 0.0,
                };
                let follower_n = self.init_follower_tension([a, b, r], inp, dt);
                for j in 0..n {
                    if j == a || j == b {
                        next[j] = self.hold_m[j];
                        modes[j] = CableCommand::Position(next[j]);
                    } else if j == r {
                        next[j] = self.reel_start_m + reel;
                        modes[j] = CableCommand::Position(next[j]);
                    } else {
                        next[j] = inp.length_m[j];
                        modes[j] = CableCommand::Tension(follower_n);
                    }
                }
                if self.segment == Segment::Settle {
                    // Everyone holds while the platform settles; the phase's data has ended.
                    if now - self.segment_t0 >= self.cfg.settle_s {
                        self.phases_completed += 1;
                        self.hold_here(inp);
                        if k + 1 < 3 {
                            self.start_phase(k + 1, inp, now);
                        } else {
                            self.awaited_version = self.params.version;
                            self.enter(State::AwaitInitial, now);
                        }
                    }
                }
            }
            State::AwaitInitial => {
                for j in 0..n {
                    next[j] = self.hold_m[j];
                    modes[j] = self.hold_mode(j, next[j]);
                }
                if self.params.valid && self.params.version != self.awaited_version {
                    swapped = false; // taken over by the transfer ramp below
                    self.start_excitation(inp, now);
                    next = self.ik_command(&mut modes, 0.0);
                }
            }
            State::Excitation if self.cfg.dwell.is_some() => {
                let was = self.dwell.seg;
                self.step_dwell_plan(now);
                if self.dwell.seg == DwellSeg::Record {
                    if was != DwellSeg::Record {
                        self.rec_sum_m = [0.0; MAX_CABLES];
                        self.rec_n = [0; MAX_CABLES];
                    }
                    for j in 0..n {
                        if inp.length_m[j].is_finite() {
                            self.rec_sum_m[j] += inp.length_m[j];
                            self.rec_n[j] += 1;
                        }
                    }
                }
                if was == DwellSeg::Record && self.dwell.seg == DwellSeg::TareSettle {
                    // The tare begins: what each cable carries and where it is.
                    for j in 0..n {
                        let fresh = inp.tension_n[j].is_finite() && inp.tension_age_s[j] <= self.cfg.tension_max_age_s;
                        self.tare_from_n[j] = if self.cfg.follower[j] {
                            self.follower_n
                        } else if fresh {
                            inp.tension_n[j].clamp(0.0, 0.5 * self.cfg.max_tension_n)
                        } else {
                            0.0
                        };
                        self.tare_hold_m[j] = if self.rec_n[j] > 0 {
                            self.rec_sum_m[j] / f64::from(self.rec_n[j])
                        } else if inp.length_m[j].is_finite() {
                            inp.length_m[j]
                        } else {
                            self.cmd[j]
                        };
                    }
                    // A follower that holds in position mode starts from where it is: its last
                    // command was a tension (the inverse kinematics' length, by the running
                    // parameters, is not where the cable is), so the speed limit judges its
                    // position commands from its measured length.
                    let mask = self.cfg.dwell.as_ref().map_or(0, |p| p.tare[self.dwell.k.min(MAX_DWELL_POSES - 1)]);
                    for j in (0..n).filter(|&j| self.cfg.follower[j] && mask & (1 << j) == 0) {
                        self.cmd[j] = self.tare_hold_m[j];
                    }
                }
                let ramp_follower = self.follower_n;
                next = self.ik_command(&mut modes, 0.0);
                if let Some(w) = self.tare_weight(now) {
                    self.tare_modes(w, ramp_follower, &mut next, &mut modes);
                }
            }
            State::Excitation => {
                let t = now - self.state_t0;
                self.target = self.excitation_point(t);
                let total = self.approach_s + self.cfg.excitation_s;
                if t >= total {
                    self.goal = self.target;
                    self.enter(State::Operate, now);
                }
                // The tension swing: sin^2 with a whole number of periods, so it starts and
                // ends at zero (no step into the excitation or into operation).
                let swings = (total / EXCITATION_TENSION_PERIOD_S).round().max(1.0);
                let s = (std::f64::consts::PI * swings * (t / total).min(1.0)).sin();
                next = self.ik_command(&mut modes, self.cfg.excitation_tension_swing_n * s * s);
            }
            State::Operate => {
                // Straight-line moves towards the goal at the configured speed.
                let d: [f64; 3] = std::array::from_fn(|i| self.goal[i] - self.target[i]);
                let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let step = self.cfg.move_speed_m_s * dt;
                if dist > step {
                    for (x, di) in self.target.iter_mut().zip(d) {
                        *x += di * step / dist;
                    }
                } else {
                    self.target = self.goal;
                }
                next = self.ik_command(&mut modes, 0.0);
            }
            State::Holding => {
                for j in 0..n {
                    next[j] = self.hold_m[j];
                    modes[j] = self.hold_mode(j, next[j]);
                }
            }
            State::Resetting => {
                out.request = self.step_reset(inp, now);
                for j in 0..n {
                    // Position mode where the drive stands while it comes back, then at the
                    // length fixed when it was back; the followers go back to torque mode in
                    // Holding, once every drive is enabled.
                    let here = inp.length_m[j];
                    next[j] = if self.reset.back[j] || !here.is_finite() { self.hold_m[j] } else { here };
                    modes[j] = CableCommand::Position(next[j]);
                }
            }
            State::Faulted => {
                let reaction = self.fault.map_or(Reaction::Hold, |f| f.1);
                out.request = match reaction {
                    Reaction::Hold => DriveRequest::Enable,
                    Reaction::QuickStop => DriveRequest::QuickStop,
                    Reaction::Disable => DriveRequest::Disable,
                };
                for j in 0..n {
                    next[j] = self.hold_m[j];
                    modes[j] = self.hold_mode(j, next[j]);
                }
            }
            State::Stopped => {
                self.stop_cycles = self.stop_cycles.saturating_add(1);
                out.request = if self.stop_cycles > 2 { DriveRequest::Disable } else { DriveRequest::Enable };
                for j in 0..n {
                    next[j] = self.hold_m[j];
                    modes[j] = self.hold_mode(j, next[j]);
                }
            }
        }

        // A new parameter set while commands come from inverse kinematics: fade the jump in.
        let ik = matches!(self.state, State::Excitation | State::Operate);
        if swapped {
            self.swaps += 1;
            if ik && self.cmd_valid {
                self.swap.start(n, &self.cmd, &next);
            }
        }
        if ik {
            let positional: [bool; MAX_CABLES] = std::array::from_fn(|j| matches!(modes[j], CableCommand::Position(_)));
            self.transfer.apply(n, dt, &mut next, &positional);
            self.swap.apply(n, dt, &mut next, &positional);
            for j in 0..n {
                if let CableCommand::Position(_) = modes[j] {
                    modes[j] = CableCommand::Position(next[j]);
                }
            }
            // Speed limit on what is about to be commanded.
            if self.cmd_valid && dt > 0.0 {
                for j in 0..n {
                    if let CableCommand::Position(_) = modes[j] {
                        let v = (next[j] - self.cmd[j]) / dt;
                        if v.abs() > self.cfg.max_cable_speed_m_s {
                            self.latch(Cause::SpeedLimit { cable: j as u8, speed_m_s: v as f32 }, inp, now);
                            for jj in 0..n {
                                next[jj] = self.hold_m[jj];
                                modes[jj] = self.hold_mode(jj, next[jj]);
                            }
                            break;
                        }
                    }
                }
            }
        }
        if self.reset.measuring {
            self.measure_reenable_step(inp, &next, &modes);
        }
        self.cmd = next;
        self.cmd_valid = (0..n).all(|j| next[j].is_finite());
        out.n = n;
        out.cable = modes;
    }

    /// The operator's reset: checks what can be checked at once, then runs
    /// [`step_reset`](Self::step_reset) each cycle.
    fn start_reset(&mut self, inp: &Inputs, now: f64) {
        if self.state == State::Resetting {
            return; // already under way
        }
        if self.state != State::Faulted || self.fault.is_none() {
            self.reset.last = Some(ResetOutcome::Refused(ResetRefusal::NothingToReset));
            return;
        }
        if inp.bus.state == BusState::Off {
            self.reset.last = Some(ResetOutcome::Refused(ResetRefusal::BusOff { iface: inp.bus.iface }));
            return;
        }
        self.reset.last = Some(ResetOutcome::InProgress);
        self.reset.enabling = false;
        self.reset.measuring = true;
        self.reset.max_step_m = 0.0;
        for j in 0..self.cfg.n {
            // A drive that stayed enabled (hold reaction) keeps its command; the others are
            // measured from where they stand once they are back.
            let on = inp.drive[j] == DriveStatus::Enabled;
            self.reset.back[j] = on;
            self.reset.prev[j] = if on { self.cmd[j] } else { f64::NAN };
        }
        self.transfer.cancel();
        self.swap.cancel();
        self.enter(State::Resetting, now);
    }

    /// One cycle of the reset: the request to the drives. Stage 1 resets the faults of drives
    /// in fault (and waits for rebooted ones to be operational again); stage 2 enables every
    /// drive and fixes each cable's hold length at the first cycle its drive is enabled.
    fn step_reset(&mut self, inp: &Inputs, now: f64) -> DriveRequest {
        let n = self.cfg.n;
        let waited = now - self.state_t0 > self.cfg.enable_timeout_s;
        let node = |j: usize| self.cfg.node_ids[j];
        if inp.bus.state == BusState::Off {
            self.refuse_reset(ResetRefusal::BusOff { iface: inp.bus.iface }, now);
            return DriveRequest::Disable;
        }
        if !self.reset.enabling {
            let away = (0..n).find(|&j| inp.drive[j] == DriveStatus::Unknown);
            let faulted = (0..n).find(|&j| inp.drive[j] == DriveStatus::Fault);
            match (away, faulted) {
                (None, None) => self.reset.enabling = true,
                (Some(j), _) if waited => {
                    self.refuse_reset(ResetRefusal::NotOperational { cable: j as u8, node: node(j) }, now);
                    return DriveRequest::Disable;
                }
                (None, Some(j)) if waited => {
                    let code = self.reset.emcy[j];
                    self.refuse_reset(ResetRefusal::StillInFault { cable: j as u8, node: node(j), code }, now);
                    return DriveRequest::Disable;
                }
                _ => return DriveRequest::FaultReset,
            }
        }
        for j in 0..n {
            if !self.reset.back[j] && inp.drive[j] == DriveStatus::Enabled {
                // Back: hold where it stands (its target is its position when it enables).
                self.reset.back[j] = true;
                if inp.length_m[j].is_finite() {
                    self.hold_m[j] = inp.length_m[j];
                }
            }
        }
        match (0..n).find(|&j| !self.reset.back[j] || inp.drive[j] != DriveStatus::Enabled) {
            None => {
                self.fault = None;
                self.reset.last = Some(ResetOutcome::Done);
                self.reset.done += 1;
                self.enter(State::Holding, now);
            }
            Some(j) if waited => {
                let why = match inp.drive[j] {
                    DriveStatus::Unknown => ResetRefusal::NotOperational { cable: j as u8, node: node(j) },
                    DriveStatus::Fault => ResetRefusal::StillInFault { cable: j as u8, node: node(j), code: self.reset.emcy[j] },
                    _ => ResetRefusal::NotEnabled { cable: j as u8, node: node(j) },
                };
                self.refuse_reset(why, now);
                return DriveRequest::Disable;
            }
            Some(_) => {}
        }
        DriveRequest::Enable
    }

    /// The reset did not succeed: back to the latched reaction, with the reason.
    fn refuse_reset(&mut self, why: ResetRefusal, now: f64) {
        self.reset.last = Some(ResetOutcome::Refused(why));
        self.reset.measuring = false;
        self.enter(State::Faulted, now);
    }

    /// Per-cycle step of the position commands after a reset: from the command before, or for
    /// a drive just back, from where it stands.
    fn measure_reenable_step(&mut self, inp: &Inputs, next: &[f64; MAX_CABLES], modes: &[CableCommand; MAX_CABLES]) {
        for j in 0..self.cfg.n {
            let positional = matches!(modes[j], CableCommand::Position(_));
            if !positional || inp.drive[j] != DriveStatus::Enabled {
                // Not commanded in position (refused while not enabled; followers in torque).
                self.reset.prev[j] = f64::NAN;
                continue;
            }
            let prev = if self.reset.prev[j].is_finite() { self.reset.prev[j] } else { inp.length_m[j] };
            let step = (next[j] - prev).abs();
            if step.is_finite() {
                self.reset.max_step_m = self.reset.max_step_m.max(step);
            }
            self.reset.prev[j] = next[j];
        }
    }

    /// Each cable's length rate from its encoder readings ([`Controller::cable_speed`]).
    fn track_cable_speed(&mut self, inp: &Inputs, dt: f64) {
        let k = if dt.is_finite() && dt > 0.0 { (dt / CABLE_SPEED_TAU_S).clamp(0.0, 1.0) } else { 0.0 };
        for j in 0..self.cfg.n {
            let l = inp.length_m[j];
            if !l.is_finite() {
                self.cable_v[j] = f64::NAN;
            } else if self.prev_len[j].is_finite() && k > 0.0 {
                let raw = (l - self.prev_len[j]) / dt;
                let v = &mut self.cable_v[j];
                *v = if v.is_finite() { *v + k * (raw - *v) } else { raw };
            }
            self.prev_len[j] = l;
        }
    }

    /// Cable `j`'s length rate from its encoder, low-passed over [`CABLE_SPEED_TAU_S`], m/s
    /// (> 0 paying out; NaN before two readings or without one).
    pub fn cable_speed(&self, j: usize) -> f64 {
        self.cable_v[j]
    }

    /// `inp` with every load cell's reading turned into its cable's tension (the parameters'
    /// gain and friction at the cable's length rate). A copy on the stack: allocates nothing.
    fn cable_tensions(&self, inp: &Inputs) -> Inputs {
        let mut out = *inp;
        let e = &self.params.effects;
        for j in 0..self.cfg.n {
            out.tension_n[j] = e.cable_tension(j, inp.tension_n[j], self.cable_v[j]);
        }
        out
    }

    /// The tension inverse kinematics stretches each cable by (with an elasticity model): the
    /// measured tension, low-passed over [`IK_TENSION_TAU_S`] so load-cell noise does not move
    /// the drums; when the reading is stale, a torque-mode cable's commanded tension, else the
    /// last filtered value (what the cable is expected to carry); NaN (no stretch) before any.
    fn track_tension(&mut self, inp: &Inputs, dt: f64) {
        let k = if dt.is_finite() { (dt / IK_TENSION_TAU_S).clamp(0.0, 1.0) } else { 1.0 };
        for j in 0..self.cfg.n {
            let fresh = inp.tension_age_s[j] <= self.cfg.tension_max_age_s && inp.tension_n[j].is_finite();
            let v = &mut self.ik_tension[j];
            if fresh {
                *v = if v.is_finite() { *v + k * (inp.tension_n[j] - *v) } else { inp.tension_n[j] };
            } else if self.cfg.follower[j] && matches!(self.state, State::Operate | State::Holding | State::Excitation) {
                *v = self.follower_n;
            }
        }
    }

    /// The dwell plan's position cables' tension trend ([`Controller::dwell_avg_n`]), from the
    /// readings taken since the plan began (a reading from before says nothing about it).
    fn track_dwell_slack(&mut self, inp: &Inputs, now: f64, dt: f64) {
        if self.cfg.dwell.is_none() || self.state != State::Excitation {
            self.dwell_avg_n = [f64::NAN; MAX_CABLES];
            return;
        }
        let w = if dt.is_finite() { (dt / HELD_TENSION_TAU_S).clamp(0.0, 1.0) } else { 1.0 };
        for j in 0..self.cfg.n {
            let t = inp.tension_n[j];
            if !self.dwell_position_cable(j) || !t.is_finite() || !measured_after(inp, j, now - self.state_t0, REEL_GRACE_S) {
                continue;
            }
            let avg = &mut self.dwell_avg_n[j];
            *avg = if avg.is_finite() { *avg + w * (t - *avg) } else { t };
        }
    }

    /// Holding: position mode at `len`, except the redundant cables, which keep their last
    /// tension (four rigid position-mode cables would fight over the platform; the last
    /// tension is what the statics needed where the platform stands).
    /// Whether cable `j` follows in torque mode in the first motion after enabling: the first
    /// initialisation phase's, or with the rest dwell the operation's.
    fn enabling_follower(&self, j: usize) -> bool {
        if self.cfg.dwell.is_some() {
            self.cfg.follower[j]
        } else {
            !self.cfg.phases[0].contains(&j)
        }
    }

    fn hold_mode(&self, j: usize, len: f64) -> CableCommand {
        if self.cfg.follower[j] {
            CableCommand::Tension(self.follower_n)
        } else {
            CableCommand::Position(len)
        }
    }

    /// Inverse kinematics at the target, the followers at [`Controller::follower_tension`]
    /// plus `extra_n`.
    fn ik_command(&mut self, modes: &mut [CableCommand; MAX_CABLES], extra_n: f64) -> [f64; MAX_CABLES] {
        let mut next = [0.0; MAX_CABLES];
        self.params.lengths_at(&self.target, &self.ik_tension, &mut next);
        self.follower_n = self.follower_tension(extra_n);
        for j in 0..self.cfg.n {
            modes[j] = if self.cfg.follower[j] { CableCommand::Tension(self.follower_n) } else { CableCommand::Position(next[j]) };
        }
        next
    }

    /// The followers' tension at the target: the configured one plus `extra_n`, raised where
    /// the statics need more to keep every position cable at `held_min_tension_n` and capped
    /// where a position cable would pass half of `max_tension_n` ([`crate::follower`]). Without
    /// usable statics (no valid parameters, not three position cables) the configured one.
    fn follower_tension(&self, extra_n: f64) -> f64 {
        let want = self.cfg.follower_tension_n + extra_n.max(0.0);
        let min_n = self.cfg.held_min_tension_n.max(2.0 * self.cfg.loose_tension_n);
        let range = crate::follower::distribute(
            &self.params,
            &self.cfg.follower,
            &self.target,
            self.cfg.mass_kg,
            min_n,
            0.5 * self.cfg.max_tension_n,
        );
        match range {
            Some(r) if r.lo_n.is_finite() => r.clamp(want).min(0.5 * self.cfg.max_tension_n).max(self.cfg.follower_tension_n),
            _ => self.cfg.follower_tension_n,
        }
    }

    /// The followers' tension in an initialisation phase that holds `[a, b]` and reels `r`:
    /// the configured one, raised where the statics at the tracked pose need more to keep the
    /// three position cables at twice `held_min_tension_n` (the held cables' tension falls as
    /// the reel moves the platform; a slack one would end the reel), at most half of
    /// `max_tension_n`, and changing by at most [`INIT_FOLLOWER_SLEW_N_S`] per second so that
    /// it does not set the platform swinging. The configured one without a fresh pose or usable
    /// statics.
    fn init_follower_tension(&mut self, [a, b, r]: [usize; 3], inp: &Inputs, dt: f64) -> f64 {
        let base = self.cfg.init_follower_tension_n;
        let mut follower = [false; MAX_CABLES];
        for (j, f) in follower.iter_mut().enumerate().take(self.cfg.n) {
            *f = j != a && j != b && j != r;
        }
        let fresh = inp.pose_age_s <= self.cfg.tracker_max_age_s && inp.pose_m.iter().all(|x| x.is_finite());
        let statics = if self.params.valid { Some(&self.params) } else { self.cfg.nominal_statics.as_ref() };
        let range = if let (true, Some(params)) = (fresh, statics) {
            crate::follower::distribute(
                params,
                &follower,
                &inp.pose_m,
                self.cfg.mass_kg,
                2.0 * self.cfg.held_min_tension_n,
                0.5 * self.cfg.max_tension_n,
            )
        } else {
            None
        };
        // Only where some follower tension keeps every position cable in range: where none does,
        // pulling harder only loads the others (the held-tension check ends the reel instead).
        let want = match range {
            Some(r) if r.lo_n.is_finite() && r.feasible() => r.clamp(base).min(0.5 * self.cfg.max_tension_n).max(base),
            _ => base,
        };
        let step = INIT_FOLLOWER_SLEW_N_S * dt.clamp(0.0, 0.1);
        self.init_follower_n += (want - self.init_follower_n).clamp(-step, step);
        self.init_follower_n
    }

    fn start_phase(&mut self, k: usize, inp: &Inputs, now: f64) {
        self.enter(State::InitPhase, now);
        self.phase = k as i8;
        self.wiring.restart();
        self.segment = Segment::Lead;
        self.segment_t0 = now;
        let r = self.cfg.phases[k][2];
        self.reel_start_m = if inp.length_m[r].is_finite() { inp.length_m[r] } else { self.hold_m[r] };
    }

    /// Without a tracker, the initialisation is one dwell at rest: hold (followers in torque
    /// mode) for `settle_s`, record for `dwell_s` but at least [`MIN_REST_S`] (phase 0), then
    /// wait for the rest estimate.
    fn rest_dwell(&mut self, now: f64, next: &mut [f64; MAX_CABLES], modes: &mut [CableCommand; MAX_CABLES]) {
        // Two scalars, not the plan: a copy of the plan is its whole pose table, every cycle.
        let Some((settle_s, dwell_s)) = self.cfg.dwell.as_ref().map(|p| (p.settle_s, p.dwell_s)) else { return };
        for j in 0..self.cfg.n {
            next[j] = self.hold_m[j];
            modes[j] = self.hold_mode(j, next[j]);
        }
        let ts = now - self.segment_t0;
        match self.segment {
            Segment::Lead if ts >= settle_s => {
                self.segment = Segment::Reel;
                self.segment_t0 = now;
            }
            Segment::Reel if ts >= dwell_s.max(MIN_REST_S) => {
                self.segment = Segment::Settle;
                self.phases_completed += 1;
                self.awaited_version = self.params.version;
                self.enter(State::AwaitInitial, now);
            }
            _ => {}
        }
    }

    /// In a tare segment: the slack cables' share of their tension before the tare (1 at its
    /// start and end, 0 while recorded); `None` outside a tare.
    fn tare_weight(&self, now: f64) -> Option<f64> {
        let plan = self.cfg.dwell.as_ref()?;
        let t = now - self.dwell.t0;
        let half = (0.5 * plan.settle_s).max(1e-3);
        match self.dwell.seg {
            DwellSeg::TareSettle => Some(1.0 - smoothstep(t / half)),
            DwellSeg::Tare => Some(0.0),
            DwellSeg::TareReturn => Some(smoothstep(t / plan.settle_s.max(1e-3))),
            _ => None,
        }
    }

    /// The cables of the current tare's mask in torque mode at `w` x their tension before the
    /// tare; a follower not in the mask in position mode at its length when the tare began (the
    /// three others hold the platform); `follower_n`: the followers' tension before this cycle.
    fn tare_modes(&mut self, w: f64, follower_n: f64, next: &mut [f64; MAX_CABLES], modes: &mut [CableCommand; MAX_CABLES]) {
        let Some(plan) = self.cfg.dwell.as_ref() else { return };
        let mask = plan.tare[self.dwell.k.min(MAX_DWELL_POSES - 1)];
        for j in 0..self.cfg.n {
            if mask & (1 << j) != 0 {
                let f = w * self.tare_from_n[j];
                modes[j] = CableCommand::Tension(f);
                if self.cfg.follower[j] {
                    self.follower_n = f;
                }
            } else if self.cfg.follower[j] {
                next[j] = self.tare_hold_m[j];
                modes[j] = CableCommand::Position(next[j]);
                self.follower_n = follower_n;
            }
        }
    }

    /// True when cable `j` is position controlled in this cycle of the dwell plan: the
    /// position-controlled cables, except the one slackened in a tare, and the followers held in
    /// position mode while a position cable is tared.
    fn dwell_position_cable(&self, j: usize) -> bool {
        let mask = match (self.cfg.dwell.as_ref(), self.dwell.seg) {
            (Some(plan), DwellSeg::TareSettle | DwellSeg::Tare | DwellSeg::TareReturn) => plan.tare[self.dwell.k.min(MAX_DWELL_POSES - 1)],
            _ => 0,
        };
        if mask & (1 << j) != 0 {
            false
        } else {
            !self.cfg.follower[j] || mask != 0
        }
    }

    /// Starts the dwell plan from where the platform is by the running parameters (forward
    /// kinematics of the measured lengths: there is no tracker).
    fn start_dwell_plan(&mut self, plan: &DwellLoopPlan, inp: &Inputs, now: f64) {
        self.target = self.forward(inp);
        self.dwell = DwellRun {
            k: 0,
            seg: DwellSeg::Move,
            t0: now,
            from: self.target,
            move_s: move_time(self.target, plan.poses[0], plan.speed_m_s, self.cfg.reel_accel_m_s2),
        };
        self.enter_ik(State::Excitation, now);
    }

    /// One cycle of the dwell plan: the target, and the next segment when this one is over.
    fn step_dwell_plan(&mut self, now: f64) {
        // What this cycle needs of the plan, not a copy of its pose table.
        let Some(plan) = self.cfg.dwell.as_ref() else { return };
        let d = &mut self.dwell;
        let to = plan.poses[d.k.min(plan.count.saturating_sub(1))];
        let after = plan.poses[(d.k + 1).min(MAX_DWELL_POSES - 1)];
        let (count, settle_s, dwell_s, speed_m_s) = (plan.count, plan.settle_s, plan.dwell_s, plan.speed_m_s);
        let accel = self.cfg.reel_accel_m_s2;
        let t = now - d.t0;
        match d.seg {
            DwellSeg::Move => {
                let dist = distance(d.from, to);
                let w = if dist > 0.0 { trapezoid_at(dist, speed_m_s, accel, t) / dist } else { 1.0 };
                self.target = std::array::from_fn(|i| d.from[i] + w * (to[i] - d.from[i]));
                if t >= d.move_s {
                    d.seg = DwellSeg::Settle;
                    d.t0 = now;
                }
            }
            DwellSeg::Settle => {
                self.target = to;
                if t >= settle_s {
                    d.seg = DwellSeg::Record;
                    d.t0 = now;
                }
            }
            DwellSeg::Record if t >= plan.dwell_s && plan.tare[d.k.min(MAX_DWELL_POSES - 1)] != 0 => {
                self.target = to;
                d.seg = DwellSeg::TareSettle;
                d.t0 = now;
            }
            DwellSeg::TareSettle => {
                self.target = to;
                if t >= plan.settle_s {
                    d.seg = DwellSeg::Tare;
                    d.t0 = now;
                }
            }
            DwellSeg::Tare => {
                self.target = to;
                if t >= dwell_s {
                    d.seg = DwellSeg::TareReturn;
                    d.t0 = now;
                }
            }
            DwellSeg::Record | DwellSeg::TareReturn => {
                self.target = to;
                let over = if d.seg == DwellSeg::Record { dwell_s } else { settle_s };
                if t >= over {
                    d.k += 1;
                    if d.k >= count {
                        self.goal = self.target;
                        self.enter(State::Operate, now);
                    } else {
                        *d = DwellRun { k: d.k, seg: DwellSeg::Move, t0: now, from: to, move_s: move_time(to, after, speed_m_s, accel) };
                    }
                }
            }
        }
    }

    /// The platform position that explains the measured lengths with the running parameters
    /// (Gauss–Newton from the last target, fixed iteration count, ideal model); the last target
    /// where the lengths do not determine it.
    fn forward(&self, inp: &Inputs) -> [f64; 3] {
        let n = self.cfg.n;
        let pr = &self.params;
        let mut p = self.target;
        for _ in 0..20 {
            let mut h = [[0.0; 3]; 3];
            let mut r = [0.0; 3];
            for j in 0..n {
                if !inp.length_m[j].is_finite() {
                    continue;
                }
                let d: [f64; 3] = std::array::from_fn(|i| p[i] + pr.platform[j][i] - pr.anchors[j][i]);
                let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if rho < 1e-9 {
                    continue;
                }
                let u: [f64; 3] = std::array::from_fn(|i| d[i] / rho);
                let e = inp.length_m[j] - pr.length(j, &p);
                for a in 0..3 {
                    r[a] += u[a] * e;
                    for b in 0..3 {
                        h[a][b] += u[a] * u[b];
                    }
                }
            }
            let Some(step) = solve3(h, r) else { return self.target };
            for a in 0..3 {
                p[a] += step[a];
            }
            if step.iter().map(|s| s * s).sum::<f64>() < 1e-18 {
                break;
            }
        }
        if p.iter().all(|v| v.is_finite()) {
            p
        } else {
            self.target
        }
    }

    fn check_devices(&mut self, inp: &Inputs, now: f64) {
        if let Some(f) = inp.fault {
            let cause = match f {
                DeviceFault::Emcy { node, code } => {
                    if let Some(j) = (0..self.cfg.n).find(|&j| self.cfg.node_ids[j] == node) {
                        self.reset.emcy[j] = code;
                    }
                    Cause::DriveFault { node, code }
                }
                DeviceFault::HeartbeatLost { node } => Cause::HeartbeatLost { node },
                DeviceFault::Rebooted { node } => Cause::DriveRebooted { node },
                DeviceFault::Bus { iface, event } => Cause::Bus { iface, event },
            };
            if self.state != State::Idle {
                self.latch(cause, inp, now);
            }
        }
        if matches!(self.state, State::InitPhase | State::AwaitInitial | State::Excitation | State::Operate | State::Holding) {
            for j in 0..self.cfg.n {
                if inp.drive[j] == DriveStatus::Fault {
                    self.latch(Cause::DriveFault { node: self.cfg.node_ids[j], code: 0 }, inp, now);
                    break;
                }
            }
        }
    }

    fn check_limits(&mut self, inp: &Inputs, now: f64) {
        if let Some(cause) = self.limit_breach(inp, now) {
            // A limit the reel breaks while the wiring check is forming a verdict: the
            // miswiring is the cause (the reaction is the same hold).
            let wiring = match cause {
                Cause::TensionHigh { .. } | Cause::CableLoose { .. } | Cause::Workspace if self.state == State::InitPhase => {
                    self.wiring.pending()
                }
                _ => None,
            };
            self.latch(wiring.unwrap_or(cause), inp, now);
        }
    }

    /// The wiring check of an initialisation phase ([`crate::wiring`]): filters every cycle of
    /// the phase, compares the load cells from the lead on, takes its reference when the reel
    /// begins, compares the encoders (and may stop the robot) once the reel has gone far
    /// enough. Off without nominal anchors.
    fn check_wiring(&mut self, inp: &Inputs, dt: f64) -> Option<Cause> {
        if !self.cfg.wiring_check {
            return None;
        }
        let params = self.cfg.nominal_statics.as_ref()?;
        let k = self.phase.clamp(0, 2);
        let cables = self.cfg.phases[k as usize];
        self.wiring.track(self.cfg.n, inp, self.init_follower_n, dt);
        let reel = matches!(self.segment, Segment::Reel | Segment::Brake | Segment::Return);
        if !(reel || self.segment == Segment::Lead) {
            self.wiring.idle();
            return None;
        }
        if reel {
            self.wiring.mark();
        }
        // What was commanded last cycle: the reel so far.
        let progress_m = if reel { self.cmd[cables[2]] - self.reel_start_m } else { 0.0 };
        let ph = Phase {
            params,
            n: self.cfg.n,
            cables,
            progress_m,
            mass_kg: self.cfg.mass_kg,
            loads: self.cfg.tension_max_age_s.is_finite(),
            loose_n: self.cfg.loose_tension_n,
            // Before the reel has gone far enough: the load cells only, a verdict held for a
            // limit the reel may break first.
            encoders: progress_m.abs() >= MIN_REEL_M.min(0.5 * self.cfg.reel_m.abs()),
        };
        self.wiring.judge(&ph, dt)
    }

    /// The first limit `inp` breaks, if any. Takes `&self` so that the configuration is read in
    /// place: `ControllerConfig` is kilobytes (dwell table, tour), and copying it out to call
    /// `latch` would cost a memcpy every cycle.
    fn limit_breach(&self, inp: &Inputs, now: f64) -> Option<Cause> {
        let c = &self.cfg;
        for j in 0..c.n {
            // While enabling, stale data delays the start instead (see Enabling).
            if inp.tension_age_s[j] > c.tension_max_age_s && self.state != State::Enabling {
                return Some(Cause::TensionStale { cable: j as u8 });
            }
            if inp.tension_n[j] > c.max_tension_n {
                return Some(Cause::TensionHigh { cable: j as u8, tension_n: inp.tension_n[j] as f32 });
            }
        }
        let tracker_needed = c.dwell.is_none() && matches!(self.state, State::InitPhase | State::Excitation);
        let pose_fresh = inp.pose_age_s <= c.tracker_max_age_s;
        if tracker_needed && !pose_fresh {
            return Some(Cause::TrackerStale);
        }
        if c.dwell.is_some() && self.state == State::Excitation && c.tension_max_age_s.is_finite() {
            // Without a tracker the robot moves with its nominal geometry: a position-controlled
            // cable going loose means the plan does not hold the platform as planned.
            for j in 0..c.n {
                if self.dwell_position_cable(j) && self.dwell_avg_n[j] < c.loose_tension_n {
                    return Some(Cause::CableLoose { cable: j as u8, tension_n: self.dwell_avg_n[j] as f32 });
                }
            }
        }
        if c.dwell.is_none()
            && self.state == State::InitPhase
            && matches!(self.segment, Segment::Reel | Segment::Brake | Segment::Return)
            && c.tension_max_age_s.is_finite()
        {
            let r = c.phases[self.phase as usize][2];
            // Give the reeled cable a moment after the phase starts before calling it loose, and
            // judge it only on a reading taken since then.
            let grace = if self.segment == Segment::Reel { REEL_GRACE_S } else { 0.0 };
            if measured_after(inp, r, now - self.segment_t0, grace) && inp.tension_n[r] < c.loose_tension_n {
                return Some(Cause::CableLoose { cable: r as u8, tension_n: inp.tension_n[r] as f32 });
            }
        }
        // The approach of the excitation may start outside the box; it leads into it.
        let in_box_motion = match self.state {
            State::Excitation => now - self.state_t0 >= self.approach_s,
            State::Operate => true,
            _ => false,
        };
        if in_box_motion && pose_fresh {
            let m = c.workspace_margin_m;
            let p = inp.pose_m;
            if (0..3).any(|i| p[i] < c.workspace[0][i] - m || p[i] > c.workspace[1][i] + m) {
                return Some(Cause::Workspace);
            }
        }
        None
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Duration of a dwell plan's move from `a` to `b`: the trapezoid of [`trapezoid_s`] at up to
/// `v` with acceleration `accel` (the start-up's, `motion.init_reel_accel_m_s2`), s. A swinging
/// platform needs the bounded acceleration: a smoothstep peaks at 6 d / T^2, 5 m/s^2 for 0.3 m
/// at 0.5 m/s, enough to loosen a position cable of the dynamic plant.
pub fn move_time(a: [f64; 3], b: [f64; 3], v: f64, accel: f64) -> f64 {
    trapezoid_s(distance(a, b), v.max(1e-3), accel)
}

/// Solves the 3x3 system `h x = r` by Cramer's rule; `None` when singular.
pub fn solve3(h: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(h);
    if d.is_nan() || d.abs() <= 1e-12 {
        return None;
    }
    let mut x = [0.0; 3];
    for (c, xc) in x.iter_mut().enumerate() {
        let mut m = h;
        for (row, rv) in m.iter_mut().zip(r) {
            row[c] = rv;
        }
        *xc = det(m) / d;
    }
    Some(x)
}

/// Time constant of the tension inverse kinematics stretches the cables by, s: long against
/// the load cells' noise, short against the platform's motion.
pub const IK_TENSION_TAU_S: f64 = 0.05;

/// Time constant of the cables' length rate from their encoders (the friction correction's
/// direction), s: long against an encoder's count steps at the loop's rate, short against a
/// reversal (the direction turns over within a few mm/s, `taut_model::FRICTION_V_BAND_M_S`).
pub const CABLE_SPEED_TAU_S: f64 = 0.02;

/// Time after the start of a reel before the reeled and the held cables' tensions are judged, s.
const REEL_GRACE_S: f64 = 0.2;

/// Fastest change of the followers' tension in the initialisation phases, N/s.
pub const INIT_FOLLOWER_SLEW_N_S: f64 = 20.0;

/// Time constant of the held cables' tension average during a reel, s: long against a
/// platform's swing (2-10 Hz), short against the reel.
pub const HELD_TENSION_TAU_S: f64 = 0.25;

/// Duration of a move over `dist` (m) at up to `speed` (m/s) with acceleration and deceleration
/// `accel` (m/s²): a trapezoidal speed profile, triangular when `dist` is too short to reach
/// `speed`. A non-positive `accel` moves at `speed` from the start. Seconds.
pub fn trapezoid_s(dist: f64, speed: f64, accel: f64) -> f64 {
    if accel.is_nan() || accel <= 0.0 {
        return dist / speed;
    }
    if dist * accel >= speed * speed {
        dist / speed + speed / accel
    } else {
        2.0 * (dist / accel).sqrt()
    }
}

/// Speed after `t` seconds of the move of [`trapezoid_s`], m/s (0 once it ended).
pub fn trapezoid_speed(dist: f64, speed: f64, accel: f64, t: f64) -> f64 {
    let total = trapezoid_s(dist, speed, accel);
    if !(0.0..total).contains(&t) {
        return 0.0;
    }
    if accel.is_nan() || accel <= 0.0 {
        return speed;
    }
    let peak = speed.min((dist * accel).sqrt());
    peak.min(accel * t).min(accel * (total - t))
}

/// Distance covered after `t` seconds of the move of [`trapezoid_s`], m (`dist` once it ended).
pub fn trapezoid_at(dist: f64, speed: f64, accel: f64, t: f64) -> f64 {
    let total = trapezoid_s(dist, speed, accel);
    if t >= total {
        return dist;
    }
    if accel.is_nan() || accel <= 0.0 {
        return speed * t.max(0.0);
    }
    let t = t.max(0.0);
    let peak = speed.min((dist * accel).sqrt());
    let ramp = peak / accel;
    if t < ramp {
        0.5 * accel * t * t
    } else if t < total - ramp {
        0.5 * accel * ramp * ramp + peak * (t - ramp)
    } else {
        let left = total - t;
        dist - 0.5 * accel * left * left
    }
}

/// Whether cable `j`'s tension reading was measured more than `grace` s after a segment that
/// began `since_start` s ago. A reading from before a reel began says nothing about the reel:
/// after a stall of the loop (or of the load-cell thread) the newest reading can be old, still
/// within `safety.tension_max_age_s`, and from a moment when the cable was loose at rest.
fn measured_after(inp: &Inputs, j: usize, since_start: f64, grace: f64) -> bool {
    since_start - inp.tension_age_s[j] > grace
}

#[cfg(test)]
mod tests {
    use super::{trapezoid_at, trapezoid_s, trapezoid_speed};

    /// The reel profile starts and ends at rest, never exceeds its speed or acceleration, and
    /// covers the distance: long moves (trapezoid) and short ones (triangle).
    #[test]
    fn trapezoid_is_continuous_and_bounded() {
        for &(dist, speed, accel) in &[(0.85, 0.25, 0.5), (0.01, 0.25, 0.5), (0.5, 0.1, 0.0)] {
            let total = trapezoid_s(dist, speed, accel);
            let h = 1e-4;
            let mut prev = (0.0, 0.0);
            let steps = (total / h).ceil() as usize + 10;
            for k in 1..=steps {
                let t = k as f64 * h;
                let (x, v) = (trapezoid_at(dist, speed, accel, t), trapezoid_speed(dist, speed, accel, t));
                assert!(v <= speed + 1e-12 && v >= 0.0, "speed {v} at {t}");
                let fd = (x - prev.0) / h;
                // Without acceleration the speed steps at the ends.
                let step = accel == 0.0 && (t - total).abs() < h;
                assert!(step || (fd - v).abs() < speed.max(accel * h) * 0.02 + accel * h, "{dist}: speed {v} vs {fd} at {t}");
                if accel > 0.0 {
                    assert!((v - prev.1).abs() <= accel * h * 1.0001, "acceleration at {t}");
                }
                prev = (x, v);
            }
            assert!((prev.0 - dist).abs() < 1e-12 && prev.1 == 0.0);
            if accel > 0.0 {
                assert!(trapezoid_speed(dist, speed, accel, 1e-6) < 1e-5, "starts at rest");
            }
        }
        // Triangle: the 1 cm move never reaches 0.25 m/s.
        assert!((trapezoid_s(0.01, 0.25, 0.5) - 2.0 * (0.02f64).sqrt()).abs() < 1e-12);
    }
}
