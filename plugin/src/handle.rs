//! The operator's side of the plugin: a cloneable `Send + Sync` [`PluginHandle`] for any
//! non-real-time thread. Requests reach the loop through the bounded command queue (never
//! waited on) or, for estop and stop, through the [`Urgent`] flags; status comes from the loop's
//! triple buffer and the calibrator's status; events from a bounded queue the loop fills
//! without blocking (full: the event is dropped and counted).

use super::error::Refusal;
use crossbeam_channel::{Receiver, Sender, TrySendError};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use taut_calibrator::vocab::{CalibStatus, SharedCalibStatus};
use taut_config::params::ParamsFile;
use taut_io::runner::LoopStatus;
use taut_operator::control::{ControlLinks, SharedLoopStatus};
use taut_operator::operator::{Expected, Operator};
use taut_rt::motion::{Command, State};
use taut_rt::safety::{Cause, Reaction};
use taut_rt::update::EventSink;
use taut_rt::urgent::Urgent;

pub use taut_rt::update::LoopEvent;

/// The loop's side of the event queue.
pub(crate) struct EventTx {
    tx: Sender<LoopEvent>,
    dropped: Arc<AtomicU64>,
}

impl EventTx {}

impl EventSink for EventTx {
    /// Never blocks, never allocates (a bounded array channel); a full queue drops the event.
    fn push(&mut self, e: LoopEvent) {
        if let Err(TrySendError::Full(_)) = self.tx.try_send(e) {
            // Relaxed: a counter read for display only.
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Status for the operator, copied out of the loop's and the calibrator's status.
#[derive(Debug, Clone)]
pub struct Status {
    /// Motion state.
    pub state: State,
    /// Initialisation phase (-1 outside).
    pub phase: i8,
    /// Initialisation phases completed.
    pub phases_completed: u8,
    /// Latched cause and reaction.
    pub fault: Option<(Cause, Reaction)>,
    /// Version of the parameters in use by the loop (0: none yet).
    pub params_version: u64,
    /// A swap is being faded in.
    pub swap_active: bool,
    /// The calibrator's stage (`waiting`, `recording`, `calibrating`, ...).
    pub calibrator: String,
    /// Samples recorded.
    pub samples_recorded: u64,
    /// Standard uncertainty of each anchor of the current parameters, m (empty: none yet).
    pub anchor_sigma_m: Vec<[f64; 3]>,
    /// Standard uncertainty of each cable's length offset, m.
    pub l0_sigma_m: Vec<f64>,
    /// Cycles run.
    pub cycles: u64,
    /// Samples the loop dropped because the calibrator's ring was full.
    pub samples_dropped: u64,
    /// Events dropped because the event queue was full.
    pub events_dropped: u64,
}

struct Shared {
    commands: Sender<Command>,
    urgent: Arc<Urgent>,
    loop_status: SharedLoopStatus,
    calib: SharedCalibStatus,
    events: Receiver<LoopEvent>,
    events_dropped: Arc<AtomicU64>,
    workspace: [[f64; 3]; 2],
    operator: Operator,
}

/// The operator's handle: clone it into any non-real-time thread. Every call returns at once.
#[derive(Clone)]
pub struct PluginHandle {
    s: Arc<Shared>,
}

/// A poisoned lock only means another thread panicked while holding it; the data is plain
/// status, still worth showing.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl PluginHandle {
    pub(crate) fn new(
        commands: Sender<Command>,
        urgent: Arc<Urgent>,
        loop_status: SharedLoopStatus,
        calib: SharedCalibStatus,
        event_capacity: usize,
        workspace: [[f64; 3]; 2],
        expected: Expected,
    ) -> (PluginHandle, EventTx) {
        let (tx, events) = crossbeam_channel::bounded(event_capacity.max(1));
        let events_dropped = Arc::new(AtomicU64::new(0));
        let operator = Operator::new(Some(events.clone()), Some(commands.clone()), expected);
        let h = PluginHandle {
            s: Arc::new(Shared {
                commands,
                urgent,
                loop_status,
                calib,
                events,
                events_dropped: events_dropped.clone(),
                workspace,
                operator,
            }),
        };
        (h, EventTx { tx, dropped: events_dropped })
    }

    /// The loop's latest status (controller snapshot, cycle counts, timing).
    pub fn loop_status(&self) -> LoopStatus {
        *lock(&self.s.loop_status).read()
    }

    /// A copy of the calibrator's status (stage, outcomes, current parameters).
    pub fn calib_status(&self) -> CalibStatus {
        lock(&self.s.calib).clone()
    }

    /// Status: phase, calibrator state, parameter version, sigmas.
    pub fn status(&self) -> Status {
        let l = self.loop_status();
        let c = lock(&self.s.calib);
        let (anchor_sigma_m, l0_sigma_m) =
            c.current.as_ref().map_or((Vec::new(), Vec::new()), |p| (p.anchor_sigma_m.clone(), p.l0_sigma_m.clone()));
        Status {
            state: l.snap.state,
            phase: l.snap.phase,
            phases_completed: l.snap.phases_completed,
            fault: l.snap.fault,
            params_version: l.snap.params_version,
            swap_active: l.snap.swap_active,
            calibrator: c.stage.clone(),
            samples_recorded: c.samples_recorded,
            anchor_sigma_m,
            l0_sigma_m,
            cycles: l.cycles,
            samples_dropped: l.dropped,
            events_dropped: self.events_dropped(),
        }
    }

    /// The parameters the calibrator published last (the loop may still be fading them in).
    pub fn params(&self) -> Option<ParamsFile> {
        lock(&self.s.calib).current.clone()
    }

    fn send(&self, c: Command) -> Result<(), Refusal> {
        self.s.commands.try_send(c).map_err(|e| match e {
            TrySendError::Full(_) => Refusal::QueueFull,
            TrySendError::Disconnected(_) => Refusal::LoopEnded,
        })
    }

    fn operating(&self) -> Result<LoopStatus, Refusal> {
        let l = self.loop_status();
        if let Some((cause, _)) = l.snap.fault {
            return Err(Refusal::Faulted { cause });
        }
        if !matches!(l.snap.state, State::Operate | State::Holding) {
            return Err(Refusal::NotOperating { state: l.snap.state });
        }
        Ok(l)
    }

    /// Runs the excitation again; the calibrator recalibrates from it and the result is
    /// hot-swapped if it is better. Refused unless operating without a fault.
    pub fn request_recalibration(&self) -> Result<(), Refusal> {
        let l = self.operating()?;
        self.send(Command::Recalibrate)?;
        // Where the platform is brought back to afterwards (by the operator's tick).
        self.s.operator.recalibrate_accepted(&l);
        Ok(())
    }

    /// Emergency stop: quick stop, latched, at the loop's next cycle. Never refused.
    pub fn estop(&self) {
        self.s.urgent.estop();
    }

    /// Controlled stop: hold, disable, end the loop (`update` reports `finished`).
    pub fn stop(&self) {
        self.s.urgent.stop();
    }

    /// Clears a latched reaction (see `motion`): drives' faults reset, drives enabled again
    /// holding where they stand. The outcome shows in status and as an [`LoopEvent::Reset`].
    pub fn reset(&self) -> Result<(), Refusal> {
        self.send(Command::Reset)
    }

    /// Moves the platform to `target_m` (workspace box, operating, calibrated).
    pub fn move_to(&self, target_m: [f64; 3]) -> Result<(), Refusal> {
        let w = &self.s.workspace;
        if !(0..3).all(|i| target_m[i].is_finite() && target_m[i] >= w[0][i] && target_m[i] <= w[1][i]) {
            return Err(Refusal::OutsideWorkspace { target_m });
        }
        let l = self.operating()?;
        if l.snap.params_version == 0 {
            return Err(Refusal::NoParameters);
        }
        self.send(Command::MoveTo(target_m))?;
        // The goal that status shows and the operator's tick follows.
        self.s.operator.move_accepted(&l, target_m);
        Ok(())
    }

    /// The operator's bookkeeping (goals, the return after a recalibration, the event journal,
    /// the log lines), shared with every [`ControlLinks`] of this handle. Its
    /// [`Operator::tick`] takes the events from the queue [`PluginHandle::poll_event`] reads:
    /// a host uses one or the other.
    pub fn operator(&self) -> &Operator {
        &self.s.operator
    }

    /// The next event, if any.
    pub fn poll_event(&self) -> Option<LoopEvent> {
        self.s.events.try_recv().ok()
    }

    /// Events dropped because nobody polled them in time.
    pub fn events_dropped(&self) -> u64 {
        // Relaxed: a counter for display.
        self.s.events_dropped.load(Ordering::Relaxed)
    }

    /// What the control socket acts on (the daemon serves it with these).
    pub fn control_links(&self, tracker: Option<taut_driver::tracker::TrackerStatsHandle>) -> ControlLinks {
        ControlLinks {
            commands: self.s.commands.clone(),
            urgent: self.s.urgent.clone(),
            loop_status: self.s.loop_status.clone(),
            calib: self.s.calib.clone(),
            workspace: self.s.workspace,
            tracker,
            operator: self.s.operator.clone(),
        }
    }
}
