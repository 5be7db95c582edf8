//! One cycle of the loop without the clock: `read -> update -> write -> push sample`.
//!
//! [`LoopCore`] is what every host runs once per period (the daemon's loop thread through
//! `taut_io::runner::run_periodic`, the plugin's `update`, the allocation tests and the
//! benchmarks); the clock, the thread and its real-time set-up belong to the host. Its
//! configuration is the [`Controller`], built from plain data on the non-real-time side.

use crate::io::{Devices, Inputs, Outputs};
use crate::motion::{Controller, Snapshot};
use crate::sample::{Sample, SampleTx};

/// What the loop publishes for status output, every cycle.
#[derive(Debug, Clone, Copy)]
pub struct LoopStatus {
    /// The controller's view.
    pub snap: Snapshot,
    /// Cycles run.
    pub cycles: u64,
    /// Periods missed.
    pub overruns: u64,
    /// Latest wake-up lateness, ns.
    pub late_ns: i64,
    /// Largest wake-up lateness, ns.
    pub max_late_ns: i64,
    /// Largest compute time of one cycle (read + update + write + push), ns.
    pub max_compute_ns: i64,
    /// Samples dropped because the ring was full.
    pub dropped: u64,
    /// `SCHED_FIFO` in effect.
    pub realtime: bool,
}

impl LoopStatus {
    /// The status before the first cycle: the controller's first snapshot, no counts yet.
    pub fn initial(snap: Snapshot) -> LoopStatus {
        LoopStatus { snap, cycles: 0, overruns: 0, late_ns: 0, max_late_ns: 0, max_compute_ns: 0, dropped: 0, realtime: false }
    }
}

/// One cycle's work without the clock: what the loop thread, the allocation test and the
/// benchmarks run.
pub struct LoopCore<D: Devices> {
    /// The devices.
    pub devices: D,
    /// The controller.
    pub controller: Controller,
    /// Inputs, filled in place.
    pub inputs: Inputs,
    /// Outputs, filled in place.
    pub outputs: Outputs,
    tx: SampleTx,
    sample: Sample,
}

impl<D: Devices> LoopCore<D> {
    /// A core of `n` cables.
    pub fn new(n: usize, devices: D, controller: Controller, tx: SampleTx) -> Self {
        LoopCore { devices, controller, inputs: Inputs::new(n), outputs: Outputs::new(n), tx, sample: Sample::empty(n) }
    }

    /// read -> update -> write, then one sample into the ring.
    #[inline]
    pub fn cycle(&mut self, now: f64, dt: f64) {
        self.read(now);
        self.step(now, dt);
    }

    /// The read of a cycle: this cycle's inputs from the devices.
    #[inline]
    pub fn read(&mut self, now: f64) {
        self.inputs.fault = None;
        self.devices.read(now, &mut self.inputs);
    }

    /// The rest of a cycle after [`LoopCore::read`]: update -> write, then one sample into the
    /// ring.
    #[inline]
    pub fn step(&mut self, now: f64, dt: f64) {
        self.controller.update(now, dt, &self.inputs, &mut self.outputs);
        self.devices.write(now, &self.outputs);
        let s = &mut self.sample;
        let i = &self.inputs;
        s.t = now;
        s.state = self.controller.state() as u8;
        s.phase = self.controller.phase_label();
        s.run = self.controller.run();
        s.length_m = i.length_m;
        s.length_age_s = i.length_age_s;
        s.tension_n = i.tension_n;
        s.tension_age_s = i.tension_age_s;
        s.drive = i.drive;
        s.pose_m = i.pose_m;
        s.pose_age_s = i.pose_age_s;
        s.cmd = self.outputs.cable;
        s.fault = self.controller.fault();
        s.params_version = self.controller.params().version;
        self.tx.push(s);
    }

    /// Samples dropped so far.
    pub fn dropped(&self) -> u64 {
        self.tx.dropped()
    }
}

/// The host's view of the loop's timing, handed to each cycle: what [`LoopStatus`] shows
/// beside the controller's snapshot.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopTiming {
    /// Cycles run before this one.
    pub cycles: u64,
    /// Periods missed.
    pub overruns: u64,
    /// This cycle's wake-up lateness, ns.
    pub late_ns: i64,
    /// Largest wake-up lateness, ns.
    pub max_late_ns: i64,
    /// Largest compute time of one cycle so far (the previous cycles), ns.
    pub max_compute_ns: i64,
    /// `SCHED_FIFO` in effect.
    pub realtime: bool,
}

impl LoopTiming {
    /// `st` with this timing (cycles counted with this one).
    pub fn apply(&self, st: LoopStatus) -> LoopStatus {
        LoopStatus {
            cycles: self.cycles + 1,
            overruns: self.overruns,
            late_ns: self.late_ns,
            max_late_ns: self.max_late_ns,
            max_compute_ns: self.max_compute_ns,
            realtime: self.realtime,
            ..st
        }
    }
}
