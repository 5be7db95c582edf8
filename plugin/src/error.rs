//! The plugin's errors: [`PluginError`] for the lifecycle calls (configure, activate,
//! deactivate, cleanup; not real-time), [`UpdateError`] (small, `Copy`) for `update`, and
//! [`Refusal`] for operator requests. Each has a stable [`ErrorKind`] for C error codes.

use std::fmt;
use std::path::PathBuf;
use taut_io::robot_io::BringUpError;
use taut_rt::motion::{ControllerConfigError, State};
use taut_rt::safety::{Cause, Reaction};

/// Where the plugin is in its lifecycle (ros2_control's states, without "unconfigured": a
/// [`Plugin`](super::Plugin) exists only once configured).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Lifecycle {
    /// Configured: everything allocated, the calibrator thread running, devices not commanded.
    Inactive = 1,
    /// Active: `update` runs the loop.
    Active = 2,
    /// Cleaned up: threads joined; only dropping is left.
    Finalized = 3,
}

impl Lifecycle {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Lifecycle::Inactive => "inactive",
            Lifecycle::Active => "active",
            Lifecycle::Finalized => "finalized",
        }
    }
}

/// A lifecycle call, for errors that say which call was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Op {
    /// `activate`
    Activate = 1,
    /// `update` / `update_with`
    Update = 2,
    /// `deactivate`
    Deactivate = 3,
    /// `cleanup`
    Cleanup = 4,
}

impl Op {
    /// The call's name.
    pub fn name(self) -> &'static str {
        match self {
            Op::Activate => "activate",
            Op::Update => "update",
            Op::Deactivate => "deactivate",
            Op::Cleanup => "cleanup",
        }
    }
}

/// Who owns the devices (chosen at configure time).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ModeKind {
    /// The plugin: `update(now, period)`.
    Owned = 1,
    /// The host: `update_with(now, period, &inputs, &mut outputs)`.
    Host = 2,
}

impl ModeKind {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            ModeKind::Owned => "plugin-owned",
            ModeKind::Host => "host-owned",
        }
    }
}

/// Error classes, stable numbers for a C ABI (`0` is success there).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(i32)]
pub enum ErrorKind {
    /// The configuration cannot drive the robot.
    Config = 1,
    /// The call is not allowed in the plugin's lifecycle state.
    Lifecycle = 2,
    /// The call does not fit the device mode chosen at configure time.
    Mode = 3,
    /// The devices could not be brought up, or the drives did not come up enabled.
    Device = 4,
    /// A file could not be created or written.
    Io = 5,
    /// A thread could not be started.
    Thread = 6,
    /// An operator request was refused.
    Refused = 7,
    /// A host input was malformed.
    Input = 8,
}

/// Why `update` / `update_with` did not run a cycle. `Copy`, no allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UpdateError {
    /// The plugin is not active.
    NotActive {
        /// Its state.
        state: Lifecycle,
    },
    /// `update` on a host-owned plugin or `update_with` on a plugin-owned one.
    WrongMode {
        /// The mode chosen at configure time.
        mode: ModeKind,
    },
    /// The period is not a finite positive number, or time went backwards.
    BadTime,
}

impl UpdateError {
    /// The error class.
    pub fn kind(self) -> ErrorKind {
        match self {
            UpdateError::NotActive { .. } => ErrorKind::Lifecycle,
            UpdateError::WrongMode { .. } => ErrorKind::Mode,
            UpdateError::BadTime => ErrorKind::Input,
        }
    }
}

impl fmt::Display for UpdateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UpdateError::NotActive { state } => write!(f, "update refused: the plugin is {}; call activate first", state.name()),
            UpdateError::WrongMode { mode: ModeKind::Owned } => {
                f.write_str("update_with refused: the plugin owns the devices (configured plugin-owned); call update")
            }
            UpdateError::WrongMode { mode: ModeKind::Host } => f.write_str(
                "update refused: the host owns the devices (configured host-owned); call update_with with this cycle's readings",
            ),
            UpdateError::BadTime => {
                f.write_str("update refused: now_s and period_s must be finite, period_s > 0 and now_s must not go backwards")
            }
        }
    }
}

impl std::error::Error for UpdateError {}

/// Why an operator request was refused. `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Refusal {
    /// The loop's command queue is full.
    QueueFull,
    /// The loop has ended (or the plugin is gone).
    LoopEnded,
    /// The request needs the robot operating (operate or holding, no latched reaction).
    NotOperating {
        /// The state it is in.
        state: State,
    },
    /// A safety reaction is latched: reset first.
    Faulted {
        /// Its cause.
        cause: Cause,
    },
    /// No calibrated parameters yet.
    NoParameters,
    /// The move target is not finite or outside the workspace box.
    OutsideWorkspace {
        /// The target, m.
        target_m: [f64; 3],
    },
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::QueueFull => f.write_str("refused: the loop's command queue is full; try again"),
            Refusal::LoopEnded => f.write_str("refused: the loop has ended"),
            Refusal::NotOperating { state } => {
                write!(f, "refused: it needs the robot operating (operate or holding) without a fault; it is {}", state.name())
            }
            Refusal::Faulted { cause } => write!(f, "refused: a safety reaction is latched ({cause}); reset first"),
            Refusal::NoParameters => f.write_str("refused: no calibrated parameters yet"),
            Refusal::OutsideWorkspace { target_m } => {
                write!(f, "refused: {target_m:?} m is not finite or outside the workspace box (motion.workspace_min_m / workspace_max_m)")
            }
        }
    }
}

impl std::error::Error for Refusal {}

/// Errors of the lifecycle calls.
#[derive(Debug)]
pub enum PluginError {
    /// The configuration cannot drive the controller.
    Config(ControllerConfigError),
    /// A configuration value the plugin needs is out of range.
    ConfigValue {
        /// The key.
        key: &'static str,
        /// What it must be.
        must: &'static str,
    },
    /// The call is not allowed in this lifecycle state.
    Lifecycle {
        /// The call.
        op: Op,
        /// The plugin's state.
        state: Lifecycle,
    },
    /// The devices could not be brought up (plugin-owned mode). Nothing was enabled; activate
    /// may be retried.
    BringUp(BringUpError),
    /// Activation latched a safety reaction (a drive did not enable within
    /// `motion.enable_timeout_s`, a drive fault, an estop): the reaction was written to the
    /// drives, which are left disabled or stopped. Activate may be retried.
    Activation {
        /// The cause.
        cause: Cause,
        /// The reaction applied.
        reaction: Reaction,
    },
    /// The operator stopped the loop during activation.
    Stopped,
    /// The recording could not be created.
    Recording {
        /// Its path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A thread could not be started.
    Thread {
        /// Its name.
        name: &'static str,
        /// The error.
        source: std::io::Error,
    },
    /// `update` failed (when reported through a lifecycle call).
    Update(UpdateError),
    /// No dwell plan for the tracker-free start-up (`motion.startup = "dwell"`).
    DwellPlan(taut_calib::selfcal::plan::PlanError),
}

impl PluginError {
    /// The error class (C error codes).
    pub fn kind(&self) -> ErrorKind {
        match self {
            PluginError::Config(_) | PluginError::ConfigValue { .. } | PluginError::DwellPlan(_) => ErrorKind::Config,
            PluginError::Lifecycle { .. } => ErrorKind::Lifecycle,
            PluginError::BringUp(_) | PluginError::Activation { .. } | PluginError::Stopped => ErrorKind::Device,
            PluginError::Recording { .. } => ErrorKind::Io,
            PluginError::Thread { .. } => ErrorKind::Thread,
            PluginError::Update(e) => e.kind(),
        }
    }
}

impl fmt::Display for PluginError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PluginError::Config(e) => e.fmt(f),
            PluginError::ConfigValue { key, must } => write!(f, "{key} must be {must}"),
            PluginError::Lifecycle { op, state } => {
                let what = match (op, state) {
                    (_, Lifecycle::Finalized) => "the plugin was cleaned up; configure a new one",
                    (Op::Activate, Lifecycle::Active) => "it is already active",
                    (Op::Update, Lifecycle::Inactive) => "call activate first",
                    (Op::Deactivate, Lifecycle::Inactive) => "it is not active",
                    (Op::Cleanup, Lifecycle::Active) => "deactivate first",
                    _ => "not allowed in this state",
                };
                write!(f, "{} refused: the plugin is {}; {what}", op.name(), state.name())
            }
            PluginError::BringUp(e) => write!(f, "bringing the devices up: {e}"),
            PluginError::Activation { cause, reaction } => write!(
                f,
                "activation failed: {cause}; the drives were told to {} and the robot is held safe; fix the cause and activate again",
                reaction.name()
            ),
            PluginError::Stopped => f.write_str("activation ended: the operator stopped the loop"),
            PluginError::Recording { path, source } => {
                write!(f, "cannot create the recording {}: {source} (daemon.data_dir)", path.display())
            }
            PluginError::Thread { name, source } => write!(f, "cannot start the {name} thread: {source}"),
            PluginError::Update(e) => e.fmt(f),
            PluginError::DwellPlan(e) => write!(f, "the start-up without a tracker (motion.startup = \"dwell\"): {e}"),
        }
    }
}

impl std::error::Error for PluginError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            PluginError::Config(e) => Some(e),
            PluginError::BringUp(e) => Some(e),
            PluginError::Recording { source, .. } | PluginError::Thread { source, .. } => Some(source),
            PluginError::Update(e) => Some(e),
            PluginError::DwellPlan(e) => Some(e),
            _ => None,
        }
    }
}

impl From<ControllerConfigError> for PluginError {
    fn from(e: ControllerConfigError) -> Self {
        PluginError::Config(e)
    }
}

impl From<UpdateError> for PluginError {
    fn from(e: UpdateError) -> Self {
        PluginError::Update(e)
    }
}
