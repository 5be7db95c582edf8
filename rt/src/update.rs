//! The plugin's per-cycle path: what `Plugin::update` and `Plugin::update_with` (in
//! `taut_plugin`) run on the host's real-time thread once their lifecycle check has
//! passed.
//!
//! ```text
//!  host time -> plugin time (clock) -> read (plugin-owned devices, or the host's HostInputs
//!  staged) -> Controller::update -> write (devices, or HostOutputs) -> sample into the ring
//!  -> LoopStatus into the triple buffer -> Events into the sink -> Tick
//! ```
//!
//! [`UpdatePath`] owns the [`LoopCore`], the status writer and the event sink; the plugin owns
//! it and keeps what needs the operating system (the calibrator thread, the activation loops
//! with their timer, the device bring-up). Nothing here allocates, frees, locks or blocks: the
//! status is a `Copy` value written into a triple buffer, events go to an [`EventSink`] that
//! must not block (the plugin's is a bounded array queue that drops and counts when full).

use crate::cycle::{LoopCore, LoopStatus, LoopTiming};
use crate::host::{BadInput, HostInputs, HostOutputs};
use crate::io::{Devices, Inputs, Outputs};
use crate::motion::{ResetOutcome, Snapshot, State};
use crate::safety::{Cause, Reaction};
use crate::triple::Writer;

/// Something the loop did, for the operator. `Copy`; `t_s` is the plugin's loop time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LoopEvent {
    /// The motion state changed.
    State {
        /// Loop time, s.
        t_s: f64,
        /// Before.
        from: State,
        /// After.
        to: State,
    },
    /// An initialisation phase began.
    Phase {
        /// Loop time, s.
        t_s: f64,
        /// Phase 0, 1 or 2.
        phase: i8,
    },
    /// A safety reaction was latched (or replaced by a worse one).
    Fault {
        /// Loop time, s.
        t_s: f64,
        /// Why.
        cause: Cause,
        /// What the loop does.
        reaction: Reaction,
    },
    /// New parameters were taken into use (the swap ramp starts).
    ParamsSwapped {
        /// Loop time, s.
        t_s: f64,
        /// Their version.
        version: u64,
    },
    /// A reset ended.
    Reset {
        /// Loop time, s.
        t_s: f64,
        /// How.
        outcome: ResetOutcome,
    },
}

/// Where the loop's events go. Called on the real-time thread: must not block, allocate or
/// lock (a full queue drops the event and counts it).
pub trait EventSink: Send {
    /// Hands one event on, or drops it.
    fn push(&mut self, e: LoopEvent);
}

/// What one cycle did. `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tick {
    /// Motion state after the cycle.
    pub state: State,
    /// Initialisation phase (-1 outside).
    pub phase: i8,
    /// A safety reaction is latched.
    pub faulted: bool,
    /// The loop has stopped (an operator stop): the drives were told to disable; deactivate.
    pub finished: bool,
    /// The first malformed host input of this cycle (host-owned mode; it was taken as
    /// missing, see [`crate::host`]).
    pub bad_input: Option<BadInput>,
}

/// The host's time is unusable: not finite, a period that is not positive, or a step back in
/// time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BadTime;

/// The devices inside the plugin's loop core.
pub enum DeviceSlot<D> {
    /// Plugin-owned, not up yet: reads leave the inputs as they are, writes go nowhere.
    Down,
    /// Plugin-owned, up.
    Owned(D),
    /// Host-owned: this cycle's readings, staged by [`UpdatePath::update_with`] (boxed at
    /// construction so that the slot stays small).
    Host(Box<Inputs>),
}

impl<D: Devices> Devices for DeviceSlot<D> {
    fn read(&mut self, now_s: f64, inputs: &mut Inputs) {
        match self {
            DeviceSlot::Down => {}
            DeviceSlot::Owned(d) => d.read(now_s, inputs),
            DeviceSlot::Host(staged) => *inputs = **staged,
        }
    }
    fn write(&mut self, now_s: f64, outputs: &Outputs) {
        if let DeviceSlot::Owned(d) = self {
            d.write(now_s, outputs)
        }
    }
}

/// What the previous cycle published, for events.
#[derive(Clone, Copy)]
struct Seen {
    state: State,
    phase: i8,
    fault: Option<(Cause, Reaction)>,
    version: u64,
    reset: Option<ResetOutcome>,
}

impl Seen {
    fn of(s: &Snapshot) -> Seen {
        Seen { state: s.state, phase: s.phase, fault: s.fault, version: s.params_version, reset: s.last_reset }
    }
}

/// The per-cycle path of the plugin: plugin time, read, controller, write, status and events.
pub struct UpdatePath<D: Devices, E: EventSink> {
    /// The loop core (devices in their slot, controller, inputs, outputs, sample ring).
    pub core: LoopCore<DeviceSlot<D>>,
    status_tx: Writer<LoopStatus>,
    st: LoopStatus,
    events: E,
    seen: Seen,
    /// Plugin time of the last cycle, s.
    t_last: f64,
    /// Plugin time minus the host's `now_s`, fixed at the first cycle after each
    /// [`UpdatePath::restart_clock`] so that plugin time runs on by one period.
    offset: Option<f64>,
    timing: LoopTiming,
}

impl<D: Devices, E: EventSink> UpdatePath<D, E> {
    /// The path around `core`; `init` is the status published before the first cycle (the
    /// value the status triple buffer was created with).
    pub fn new(core: LoopCore<DeviceSlot<D>>, status_tx: Writer<LoopStatus>, init: LoopStatus, events: E) -> Self {
        UpdatePath {
            core,
            status_tx,
            seen: Seen::of(&init.snap),
            st: init,
            events,
            t_last: 0.0,
            offset: None,
            timing: LoopTiming::default(),
        }
    }

    /// The host's timing of the cycle about to run, shown in status.
    pub fn set_timing(&mut self, t: LoopTiming) {
        self.timing = t;
    }

    /// Plugin time of the last cycle, s.
    pub fn t_last(&self) -> f64 {
        self.t_last
    }

    /// From the next cycle on, plugin time runs on from the last cycle by one period whatever
    /// clock the host uses (called at each activation).
    pub fn restart_clock(&mut self) {
        self.offset = None;
    }

    /// Plugin time of a cycle at the host's `now_s`.
    pub fn clock(&mut self, now_s: f64, period_s: f64) -> Result<f64, BadTime> {
        if !(now_s.is_finite() && period_s.is_finite() && period_s > 0.0) {
            return Err(BadTime);
        }
        let off = *self.offset.get_or_insert(self.t_last + period_s - now_s);
        let t = now_s + off;
        if t < self.t_last {
            return Err(BadTime);
        }
        Ok(t)
    }

    /// The read of a cycle at plugin time `t`.
    #[inline]
    pub fn read(&mut self, t: f64) {
        self.core.read(t);
    }

    /// The rest of a cycle after [`UpdatePath::read`]: controller, write, sample, status and
    /// events.
    pub fn step(&mut self, t: f64, period_s: f64) {
        self.core.step(t, period_s);
        self.t_last = t;
        self.publish(t);
    }

    /// One cycle with plugin-owned devices: read -> update -> write.
    pub fn update(&mut self, now_s: f64, period_s: f64) -> Result<Tick, BadTime> {
        let t = self.clock(now_s, period_s)?;
        self.read(t);
        self.step(t, period_s);
        Ok(self.tick(None))
    }

    /// One cycle with host-owned devices: `inputs` are this cycle's readings (staged, hostile
    /// values taken as missing), `outputs` receive the commands.
    pub fn update_with(&mut self, now_s: f64, period_s: f64, inputs: &HostInputs, outputs: &mut HostOutputs) -> Result<Tick, BadTime> {
        let t = self.clock(now_s, period_s)?;
        let bad = match &mut self.core.devices {
            DeviceSlot::Host(staged) => inputs.load_into(staged),
            _ => None,
        };
        self.read(t);
        self.step(t, period_s);
        outputs.store(&self.core.outputs);
        Ok(self.tick(bad))
    }

    /// What the last cycle did.
    pub fn tick(&self, bad_input: Option<BadInput>) -> Tick {
        let c = &self.core.controller;
        Tick { state: c.state(), phase: c.phase(), faulted: c.fault().is_some(), finished: c.finished(), bad_input }
    }

    /// Status and events after a cycle. No allocation: `Copy` values into a triple buffer and
    /// the event sink.
    fn publish(&mut self, t: f64) {
        let snap = self.core.controller.snapshot(t, &self.core.inputs);
        let tm = self.timing;
        self.st = LoopStatus {
            snap,
            cycles: self.st.cycles + 1,
            overruns: tm.overruns,
            late_ns: tm.late_ns,
            max_late_ns: tm.max_late_ns,
            max_compute_ns: tm.max_compute_ns,
            dropped: self.core.dropped(),
            realtime: tm.realtime,
        };
        // The displaced value is a Copy struct: nothing is freed here.
        self.status_tx.write(self.st);
        let now = Seen::of(&snap);
        let was = self.seen;
        if now.state != was.state {
            self.events.push(LoopEvent::State { t_s: t, from: was.state, to: now.state });
        }
        if now.phase >= 0 && now.phase != was.phase {
            self.events.push(LoopEvent::Phase { t_s: t, phase: now.phase });
        }
        if let Some((cause, reaction)) = now.fault {
            if was.fault != now.fault {
                self.events.push(LoopEvent::Fault { t_s: t, cause, reaction });
            }
        }
        if now.version != was.version {
            self.events.push(LoopEvent::ParamsSwapped { t_s: t, version: now.version });
        }
        if let Some(outcome) = now.reset {
            if was.reset != now.reset && outcome != ResetOutcome::InProgress {
                self.events.push(LoopEvent::Reset { t_s: t, outcome });
            }
        }
        self.seen = now;
    }
}
