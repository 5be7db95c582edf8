//! The operator's side of a running robot, off the real-time path: what `taut ctl watch` follows,
//! where a move is going and whether it got there, where `recalibrate` brings the platform back
//! to, and the daemon's log lines for people.
//!
//! The control thread calls [`Operator::tick`] every round (at most every 50 ms); a host that
//! steps the loop itself (`taut_simrig::Lockstep`) calls it between cycles. A tick:
//!
//! - drains the loop's event queue ([`LoopEvent`]) into a numbered journal of the last
//!   [`JOURNAL`] events, logging each with what comes next and how long it should take;
//! - adds the calibrator's new outcomes, the goal's arrival, the return after a recalibration
//!   and the loop's health (every minute of loop time when it is not clean);
//! - after a recalibration's motion, sends the platform back to where the operator left it.
//!
//! Every time here is the loop's time (`Snapshot::t`), so a run in simulated time gives the
//! same journal for the same seed.

use crossbeam_channel::{Receiver, Sender};
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use taut_calibrator::vocab::{CalibStatus, OutcomeKind};
use taut_rt::cycle::LoopStatus;
use taut_rt::motion::{Command, ResetOutcome, State};

pub use taut_rt::update::LoopEvent;

/// Where the operator's log lines go (stderr in the daemon, a buffer in tests).
pub type LogFn = Arc<dyn Fn(&str) + Send + Sync>;

/// Events kept for `events SEQ` / `taut ctl watch`.
pub const JOURNAL: usize = 512;

/// Events one `events` reply carries at most.
pub const EVENTS_PER_REPLY: usize = 64;

/// Distance within which a goal counts as reached, by default, m.
pub const ARRIVAL_TOLERANCE_M: f64 = 0.005;

/// Loop time the platform gets to settle within the tolerance once its setpoint is at the goal, s.
pub const SETTLE_S: f64 = 1.0;

/// Loop time between two loop-health lines when the loop is not clean, s.
pub const HEALTH_EVERY_S: f64 = 60.0;

/// Loop time between two progress lines during the excitation, s.
pub const PROGRESS_EVERY_S: f64 = 15.0;

/// How long the start-up's motions are expected to take (from the configuration), for the log.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Expected {
    /// One initialisation phase (reel in, reel out, settle), s.
    pub init_phase_s: f64,
    /// The excitation's tour (without the approach to its first point), s.
    pub excitation_s: f64,
    /// The platform's speed in operation, m/s.
    pub move_speed_m_s: f64,
}

impl Expected {
    /// From the robot's `[motion]`.
    pub fn from_robot(cfg: &taut_config::RobotConfig) -> Expected {
        let m = &cfg.motion;
        Expected {
            init_phase_s: 2.0 * m.init_reel_m.abs() / m.init_reel_speed_m_s.max(1e-9) + m.init_settle_s,
            excitation_s: m.excitation_s,
            move_speed_m_s: m.move_speed_m_s,
        }
    }
}

/// Where a goal stands.
#[derive(Debug, Clone, PartialEq)]
pub enum GoalEnd {
    /// The platform is within the tolerance of the goal (`error_m`: tracker to goal; `None`
    /// without a fresh tracker pose: the setpoint is at the goal).
    Arrived {
        /// Distance from the measured position to the goal, m.
        error_m: Option<f64>,
    },
    /// The setpoint reached the goal but the platform stayed further than the tolerance.
    OffTarget {
        /// Distance from the measured position to the goal, m.
        error_m: f64,
    },
    /// Another goal replaced it.
    Superseded {
        /// The new goal's number.
        by: u64,
    },
    /// A safety reaction latched on the way.
    Fault {
        /// The cause's message.
        message: String,
        /// Distance to the goal then, m (None without a pose).
        error_m: Option<f64>,
    },
    /// The robot left operation (a stop, a recalibration, ...) before arriving.
    Interrupted {
        /// The state it went to.
        state: &'static str,
        /// Distance to the goal then, m.
        error_m: Option<f64>,
    },
    /// The loop did not take the move (its state changed between the request and the loop).
    NotTaken,
}

impl GoalEnd {
    /// Short name for JSON and people.
    pub fn name(&self) -> &'static str {
        match self {
            GoalEnd::Arrived { .. } => "arrived",
            GoalEnd::OffTarget { .. } => "off-target",
            GoalEnd::Superseded { .. } => "superseded",
            GoalEnd::Fault { .. } => "fault",
            GoalEnd::Interrupted { .. } => "interrupted",
            GoalEnd::NotTaken => "not-taken",
        }
    }

    /// The goal was reached within the tolerance.
    pub fn arrived(&self) -> bool {
        matches!(self, GoalEnd::Arrived { .. })
    }

    /// The final distance to the goal, m, if known.
    pub fn error_m(&self) -> Option<f64> {
        match self {
            GoalEnd::Arrived { error_m } | GoalEnd::Fault { error_m, .. } | GoalEnd::Interrupted { error_m, .. } => *error_m,
            GoalEnd::OffTarget { error_m } => Some(*error_m),
            _ => None,
        }
    }

    /// One line for people.
    pub fn describe(&self) -> String {
        let mm = |e: &Option<f64>| e.map_or("no tracker pose".to_string(), |e| format!("{:.1} mm from the goal", e * 1e3));
        match self {
            GoalEnd::Arrived { error_m } => format!("arrived, {}", mm(error_m)),
            GoalEnd::OffTarget { error_m } => {
                format!("setpoint at the goal but the platform stayed {:.1} mm away (tolerance exceeded)", error_m * 1e3)
            }
            GoalEnd::Superseded { by } => format!("replaced by goal #{by}"),
            GoalEnd::Fault { message, error_m } => format!("stopped by a safety reaction ({message}), {}", mm(error_m)),
            GoalEnd::Interrupted { state, error_m } => format!("interrupted: the robot went to {state}, {}", mm(error_m)),
            GoalEnd::NotTaken => "the loop did not take the move (its state changed); send it again".into(),
        }
    }

    fn json(&self) -> Value {
        let mut v = json!({"outcome": self.name(), "error_m": self.error_m(), "message": self.describe()});
        if let GoalEnd::Superseded { by } = self {
            v["by"] = json!(by);
        }
        v
    }
}

/// What the goal's progress looks like at one moment: from the loop's status (daemon side) or
/// from a `status` reply (client side, [`GoalView::from_status`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GoalView {
    /// Loop time, s.
    pub t_s: f64,
    /// The goal being followed now (None: no goal).
    pub id: Option<u64>,
    /// Motion state name.
    pub state: String,
    /// The latched fault's message, if any.
    pub fault: Option<String>,
    /// The moving setpoint is at the goal.
    pub reached: bool,
    /// Distance from the tracker's position to the goal, m (None without a fresh pose).
    pub error_m: Option<f64>,
    /// How the goal ended, as the daemon judged it (client side only).
    pub ended: Option<GoalEnd>,
}

impl GoalView {
    /// The goal part of a `status` reply.
    pub fn from_status(v: &Value) -> GoalView {
        let g = &v["goal"];
        let ended = g["ended"]["outcome"].as_str().map(|o| {
            let e = g["ended"]["error_m"].as_f64();
            let msg = g["ended"]["message"].as_str().unwrap_or_default().to_string();
            match o {
                "arrived" => GoalEnd::Arrived { error_m: e },
                "off-target" => GoalEnd::OffTarget { error_m: e.unwrap_or(f64::NAN) },
                "superseded" => GoalEnd::Superseded { by: g["ended"]["by"].as_u64().unwrap_or(0) },
                "fault" => GoalEnd::Fault { message: msg, error_m: e },
                "not-taken" => GoalEnd::NotTaken,
                _ => GoalEnd::Interrupted { state: "another state", error_m: e },
            }
        });
        GoalView {
            t_s: v["t_s"].as_f64().unwrap_or(0.0),
            id: g["id"].as_u64(),
            state: v["state"].as_str().unwrap_or("unknown").to_string(),
            fault: v["fault"]["message"].as_str().map(str::to_string),
            reached: g["reached"].as_bool().unwrap_or(false),
            error_m: g["error_m"].as_f64(),
            ended,
        }
    }
}

/// Follows one goal until it ends: arrival within `tolerance_m`, a fault, another state,
/// another goal. Fed [`GoalView`]s, from the daemon's tick or from `taut ctl move --wait`'s
/// polling of `status`.
#[derive(Debug, Clone)]
pub struct MoveWait {
    /// The goal's number (from the `move` reply).
    pub id: u64,
    /// Within this distance of the goal the move has arrived, m.
    pub tolerance_m: f64,
    /// Loop time the platform gets to come within the tolerance after its setpoint reached the
    /// goal, s.
    pub settle_s: f64,
    reached_at: Option<f64>,
    first_t: Option<f64>,
}

impl MoveWait {
    /// Follows goal `id` with `tolerance_m` and [`SETTLE_S`].
    pub fn new(id: u64, tolerance_m: f64) -> MoveWait {
        MoveWait { id, tolerance_m, settle_s: SETTLE_S, reached_at: None, first_t: None }
    }

    /// Looks at one view; `Some` when the goal has ended.
    pub fn observe(&mut self, v: &GoalView) -> Option<GoalEnd> {
        let first = *self.first_t.get_or_insert(v.t_s);
        if v.id != Some(self.id) {
            return Some(match v.id {
                Some(by) if by > self.id => GoalEnd::Superseded { by },
                _ => GoalEnd::NotTaken,
            });
        }
        if let Some(e) = &v.ended {
            // The daemon's judgement with its own tolerance: a tighter one here still waits
            // for the pose only while the daemon has not given up.
            match e {
                GoalEnd::Arrived { error_m: Some(err) } if *err > self.tolerance_m => {}
                GoalEnd::Arrived { .. } if v.reached => {}
                GoalEnd::OffTarget { .. } if v.reached => {}
                other => return Some(other.clone()),
            }
        }
        if let Some(message) = &v.fault {
            return Some(GoalEnd::Fault { message: message.clone(), error_m: v.error_m });
        }
        match v.state.as_str() {
            "operate" => {}
            // A move from holding switches to operate with the loop's next cycle.
            "holding" if v.t_s - first < 1.0 && !v.reached => return None,
            "holding" if v.reached => {}
            "holding" => return Some(GoalEnd::NotTaken),
            other => {
                let state = STATE_NAMES.iter().find(|s| **s == other).copied().unwrap_or("another state");
                return Some(GoalEnd::Interrupted { state, error_m: v.error_m });
            }
        }
        if !v.reached {
            self.reached_at = None;
            return None;
        }
        let at = *self.reached_at.get_or_insert(v.t_s);
        match v.error_m {
            None => Some(GoalEnd::Arrived { error_m: None }),
            Some(e) if e <= self.tolerance_m => Some(GoalEnd::Arrived { error_m: Some(e) }),
            Some(e) if v.t_s - at >= self.settle_s => Some(GoalEnd::OffTarget { error_m: e }),
            Some(_) => None,
        }
    }
}

const STATE_NAMES: [&str; 10] =
    ["idle", "enabling", "init-phase", "await-initial-estimate", "excitation", "operate", "holding", "faulted", "stopped", "resetting"];

#[derive(Debug, Clone)]
struct Goal {
    id: u64,
    target_m: [f64; 3],
    /// `operator` (a `move` request) or `recalibrate` (the return after a recalibration).
    origin: &'static str,
    t_s: f64,
    wait: MoveWait,
    ended: Option<GoalEnd>,
}

#[derive(Debug, Clone, PartialEq)]
enum ReturnStage {
    /// Recalibration requested; its motion has not begun.
    Requested { t_s: f64 },
    /// The excitation (or dwell poses) runs.
    Moving,
    /// Going back (goal number).
    Returning(u64),
    /// Back within the tolerance.
    Returned { error_m: Option<f64> },
    /// Did not get back: where the platform stopped and why.
    Stopped { at_m: [f64; 3], why: String },
}

#[derive(Debug, Clone)]
struct Return {
    to_m: [f64; 3],
    stage: ReturnStage,
}

struct Inner {
    events: Option<Receiver<LoopEvent>>,
    commands: Option<Sender<Command>>,
    log: LogFn,
    expected: Expected,
    /// Each cable's drive node id and load-cell unit id, where configured (empty: unknown).
    cables: Vec<(Option<u8>, Option<u8>)>,
    journal: VecDeque<Value>,
    next_seq: u64,
    goal: Option<Goal>,
    next_goal: u64,
    ret: Option<Return>,
    outcomes_seen: usize,
    last_anchors: Option<Vec<[f64; 3]>>,
    health_t: f64,
    health_overruns: u64,
    health_max_late_ns: i64,
    last: Option<LoopStatus>,
    /// When the running excitation began and when its last progress line was, loop time, s.
    excitation: Option<(f64, f64)>,
}

/// The operator's bookkeeping; cloneable, shared by the control thread and the daemon.
#[derive(Clone)]
pub struct Operator {
    inner: Arc<Mutex<Inner>>,
}

impl Default for Operator {
    /// No event queue, no command queue (goals are tracked, nothing is sent), no log.
    fn default() -> Self {
        Operator::new(None, None, Expected::default())
    }
}

/// A poisoned lock only means another thread panicked while holding it.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// A point for people: `(1.000, 2.000, 1.500) m`.
pub fn point(p: &[f64; 3]) -> String {
    format!("({:.3}, {:.3}, {:.3}) m", p[0], p[1], p[2])
}

/// The tracker's position when it is fresh (the loop's own age limit is not known here: 0.5 s).
fn pose(ls: &LoopStatus) -> Option<[f64; 3]> {
    let i = &ls.snap.inputs;
    (i.pose_age_s <= 0.5 && i.pose_m.iter().all(|v| v.is_finite())).then_some(i.pose_m)
}

/// The goal's view from the loop's status.
fn view(ls: &LoopStatus, g: &Goal) -> GoalView {
    let s = &ls.snap;
    GoalView {
        t_s: s.t,
        id: Some(g.id),
        state: s.state.name().to_string(),
        fault: s.fault.map(|(c, _)| c.to_string()),
        reached: s.state == State::Operate && dist(&s.target_m, &g.target_m) < 1e-9,
        error_m: pose(ls).map(|p| dist(&p, &g.target_m)),
        ended: None,
    }
}

/// The largest 1-sigma of an anchor coordinate or an offset, m, and what it belongs to.
pub fn worst_sigma(anchor_sigma_m: &[[f64; 3]], l0_sigma_m: &[f64]) -> Option<(f64, String)> {
    let mut worst: Option<(f64, String)> = None;
    let mut see = |v: f64, what: String| {
        if v.is_finite() && worst.as_ref().is_none_or(|(w, _)| v > *w) {
            worst = Some((v, what));
        }
    };
    for (j, s) in anchor_sigma_m.iter().enumerate() {
        for (i, v) in s.iter().enumerate() {
            see(*v, format!("cable {} anchor {}", j + 1, ["x", "y", "z"][i]));
        }
    }
    for (j, v) in l0_sigma_m.iter().enumerate() {
        see(*v, format!("cable {} length offset", j + 1));
    }
    worst
}

impl Operator {
    /// An operator draining `events` (the plugin's event queue) and sending the return moves
    /// on `commands`; its log lines go nowhere until [`Operator::set_log`].
    pub fn new(events: Option<Receiver<LoopEvent>>, commands: Option<Sender<Command>>, expected: Expected) -> Operator {
        Operator {
            inner: Arc::new(Mutex::new(Inner {
                events,
                commands,
                // Silent until a host asks for the lines (the daemon: `DaemonOptions::log`).
                log: Arc::new(|_| {}),
                expected,
                cables: Vec::new(),
                journal: VecDeque::with_capacity(JOURNAL),
                next_seq: 1,
                goal: None,
                next_goal: 1,
                ret: None,
                outcomes_seen: 0,
                last_anchors: None,
                health_t: 0.0,
                health_overruns: 0,
                health_max_late_ns: 0,
                last: None,
                excitation: None,
            })),
        }
    }

    /// Sends the log lines to `log`.
    pub fn set_log(&self, log: LogFn) {
        lock(&self.inner).log = log;
    }

    /// Sets the expected durations the log quotes.
    pub fn set_expected(&self, e: Expected) {
        lock(&self.inner).expected = e;
    }

    /// The cables' drive node ids and load-cell unit ids (`RobotConfig::cable_ids`), for the
    /// log lines and `status`.
    pub fn set_cables(&self, ids: Vec<(Option<u8>, Option<u8>)>) {
        lock(&self.inner).cables = ids;
    }

    /// Each cable's drive node id and load-cell unit id (empty when not set).
    pub fn cables(&self) -> Vec<(Option<u8>, Option<u8>)> {
        lock(&self.inner).cables.clone()
    }

    /// A `move` was handed to the loop: it is the goal now. Returns its number.
    pub fn move_accepted(&self, ls: &LoopStatus, target_m: [f64; 3]) -> u64 {
        let mut s = lock(&self.inner);
        let id = s.new_goal(ls, target_m, "operator");
        // An operator's move replaces a pending return.
        if let Some(r) = &mut s.ret {
            if matches!(r.stage, ReturnStage::Requested { .. } | ReturnStage::Moving | ReturnStage::Returning(_)) {
                let why = format!("the operator sent goal #{id}");
                r.stage = ReturnStage::Stopped { at_m: pose(ls).unwrap_or(ls.snap.target_m), why };
            }
        }
        id
    }

    /// A recalibration was handed to the loop: returns where the platform will be brought back
    /// to afterwards, and logs it.
    pub fn recalibrate_accepted(&self, ls: &LoopStatus) -> [f64; 3] {
        let mut s = lock(&self.inner);
        // Where the operator left it: the goal if it has been reached, else the setpoint.
        let to_m = match &s.goal {
            Some(g) if g.ended.as_ref().is_some_and(GoalEnd::arrived) => g.target_m,
            _ => ls.snap.target_m,
        };
        s.ret = Some(Return { to_m, stage: ReturnStage::Requested { t_s: ls.snap.t } });
        let line =
            format!("recalibrate: the excitation moves the platform away from {}; it comes back there when the motion ends", point(&to_m));
        s.record(ls.snap.t, "recalibrate", json!({"return_to_m": to_m}), &line);
        to_m
    }

    /// Reads the loop's and the calibrator's status, drains the loop's events; journals and logs
    /// what changed, follows the goal, sends the return after a recalibration.
    pub fn tick(&self, ls: &LoopStatus, cs: &CalibStatus) {
        let mut s = lock(&self.inner);
        s.drain_events();
        s.outcomes(ls, cs);
        s.follow_goal(ls);
        s.follow_return(ls);
        s.progress(ls);
        s.health(ls, false);
        s.last = Some(*ls);
    }

    /// The loop has ended: logs its health once more, whatever it is.
    pub fn stopped(&self, ls: &LoopStatus) {
        let mut s = lock(&self.inner);
        s.drain_events();
        s.health(ls, true);
    }

    /// The goal and the return, for `status`.
    pub fn status_json(&self, ls: &LoopStatus) -> (Value, Value) {
        let s = lock(&self.inner);
        let goal = s.goal.as_ref().map_or(Value::Null, |g| {
            let v = view(ls, g);
            json!({
                "id": g.id,
                "target_m": g.target_m,
                "origin": g.origin,
                "since_s": g.t_s,
                "setpoint_m": ls.snap.target_m,
                "remaining_m": dist(&ls.snap.target_m, &g.target_m),
                "error_m": v.error_m,
                "reached": v.reached,
                "tolerance_m": g.wait.tolerance_m,
                "ended": g.ended.as_ref().map(GoalEnd::json),
            })
        });
        let ret = s.ret.as_ref().map_or(Value::Null, |r| {
            let mut v = json!({"return_to_m": r.to_m});
            match &r.stage {
                ReturnStage::Requested { .. } => v["stage"] = json!("requested"),
                ReturnStage::Moving => v["stage"] = json!("moving"),
                ReturnStage::Returning(id) => {
                    v["stage"] = json!("returning");
                    v["goal"] = json!(id);
                }
                ReturnStage::Returned { error_m } => {
                    v["stage"] = json!("returned");
                    v["error_m"] = json!(error_m);
                }
                ReturnStage::Stopped { at_m, why } => {
                    v["stage"] = json!("stopped");
                    v["at_m"] = json!(at_m);
                    v["why"] = json!(why);
                }
            }
            v
        });
        (goal, ret)
    }

    /// The journal from `from` on (at most [`EVENTS_PER_REPLY`]), the next number to ask for,
    /// and how many wanted events were already gone.
    pub fn events_since(&self, from: u64) -> (Vec<Value>, u64, u64) {
        let s = lock(&self.inner);
        let first = s.journal.front().and_then(|e| e["seq"].as_u64()).unwrap_or(s.next_seq);
        let lost = first.saturating_sub(from);
        let out: Vec<Value> = s.journal.iter().filter(|e| e["seq"].as_u64().unwrap_or(0) >= from).take(EVENTS_PER_REPLY).cloned().collect();
        let next = out.last().and_then(|e| e["seq"].as_u64()).map_or(s.next_seq.max(from.min(s.next_seq)), |q| q + 1);
        (out, next, lost)
    }

    /// The number the next event will get.
    pub fn next_seq(&self) -> u64 {
        lock(&self.inner).next_seq
    }
}

impl Inner {
    fn record(&mut self, t_s: f64, event: &str, mut data: Value, line: &str) {
        if self.journal.len() == JOURNAL {
            self.journal.pop_front();
        }
        data["seq"] = json!(self.next_seq);
        data["t_s"] = json!(t_s);
        data["event"] = json!(event);
        data["text"] = json!(line);
        self.next_seq += 1;
        self.journal.push_back(data);
        (self.log)(line);
    }

    fn new_goal(&mut self, ls: &LoopStatus, target_m: [f64; 3], origin: &'static str) -> u64 {
        let id = self.next_goal;
        self.next_goal += 1;
        let t = ls.snap.t;
        if let Some(old) = self.goal.as_mut().filter(|g| g.ended.is_none()) {
            old.ended = Some(GoalEnd::Superseded { by: id });
        }
        let d = dist(&ls.snap.target_m, &target_m);
        let eta =
            if self.expected.move_speed_m_s > 0.0 { format!(", about {:.0} s", d / self.expected.move_speed_m_s) } else { String::new() };
        let line = format!("goal #{id} ({origin}): to {}, {:.3} m away{eta}", point(&target_m), d);
        self.record(t, "goal", json!({"id": id, "target_m": target_m, "origin": origin}), &line);
        self.goal = Some(Goal { id, target_m, origin, t_s: t, wait: MoveWait::new(id, ARRIVAL_TOLERANCE_M), ended: None });
        id
    }

    fn drain_events(&mut self) {
        let Some(rx) = self.events.clone() else { return };
        while let Ok(e) = rx.try_recv() {
            self.event(e);
        }
    }

    fn event(&mut self, e: LoopEvent) {
        let x = self.expected;
        match e {
            LoopEvent::State { t_s, from, to } => {
                let what = match to {
                    State::Enabling => "enabling the drives".to_string(),
                    State::InitPhase => format!("three-phase initialisation, about {:.0} s per phase", x.init_phase_s),
                    State::AwaitInitial => "waiting for the initial estimate (a few seconds)".into(),
                    State::Excitation => {
                        format!(
                            "excitation: about {:.0} s of motion plus the approach, then the calibration (a few seconds)",
                            x.excitation_s
                        )
                    }
                    State::Operate => "operating".into(),
                    State::Holding => "holding".into(),
                    State::Faulted => "faulted: a safety reaction is latched; `taut ctl reset` when it is safe".into(),
                    State::Stopped => "stopped".into(),
                    State::Resetting => "resetting the drives".into(),
                    State::Idle => "idle".into(),
                };
                let line = format!("state {} -> {}: {what}", from.name(), to.name());
                self.record(t_s, "state", json!({"from": from.name(), "to": to.name()}), &line);
            }
            LoopEvent::Phase { t_s, phase } => {
                let line = format!("initialisation phase {} of 3, about {:.0} s", phase + 1, x.init_phase_s);
                self.record(t_s, "phase", json!({"phase": phase}), &line);
            }
            LoopEvent::Fault { t_s, cause, reaction } => {
                let line = format!("safety reaction {}: {cause}", reaction.name());
                self.record(t_s, "fault", json!({"cause": cause.name(), "reaction": reaction.name(), "message": cause.to_string()}), &line);
            }
            LoopEvent::ParamsSwapped { t_s, version } => {
                let line = format!("parameters v{version} taken into use (bumpless ramp)");
                self.record(t_s, "params", json!({"version": version}), &line);
            }
            LoopEvent::Reset { t_s, outcome } => {
                let (name, msg) = match outcome {
                    ResetOutcome::InProgress => ("in-progress", "reset under way".to_string()),
                    ResetOutcome::Done => ("done", "reset done: the drives are enabled, holding".to_string()),
                    ResetOutcome::Refused(why) => ("refused", format!("reset refused: {why}")),
                };
                self.record(t_s, "reset", json!({"outcome": name}), &msg);
            }
        }
    }

    fn outcomes(&mut self, ls: &LoopStatus, cs: &CalibStatus) {
        if cs.outcomes.len() < self.outcomes_seen {
            self.outcomes_seen = 0;
        }
        for k in self.outcomes_seen..cs.outcomes.len() {
            let o = &cs.outcomes[k];
            let kind = match o.kind {
                OutcomeKind::Initial => "initial estimate",
                OutcomeKind::Calibration => "calibration",
            };
            let est = o.estimate.as_ref();
            let worst = est.and_then(|e| worst_sigma(&e.sigma.anchors, &e.sigma.l0));
            let change = match (est, &self.last_anchors) {
                (Some(e), Some(prev)) if prev.len() == e.geometry.anchors.len() => e
                    .geometry
                    .anchors
                    .iter()
                    .zip(prev)
                    .enumerate()
                    .map(|(j, (a, b))| (dist(a, b), j))
                    .fold(None, |m: Option<(f64, usize)>, x| if m.is_none_or(|m| x.0 > m.0) { Some(x) } else { m }),
                _ => None,
            };
            let line = if o.accepted {
                let w =
                    worst.as_ref().map_or("no uncertainty".to_string(), |(w, what)| format!("worst 1-sigma {:.2} mm ({what})", w * 1e3));
                let c = change.map_or("first estimate".to_string(), |(d, j)| {
                    let (node, unit) = self.cables.get(j).copied().unwrap_or_default();
                    let who = taut_config::cable_label_with(j, node, unit);
                    format!("largest anchor change {:.2} mm, {who}", d * 1e3)
                });
                let h = if o.heldout_rms_new_m.is_finite() {
                    format!(", held-out RMS {:.2} mm (was {:.2} mm)", o.heldout_rms_new_m * 1e3, o.heldout_rms_old_m * 1e3)
                } else {
                    String::new()
                };
                format!("outcome #{} (run {}, {kind}): accepted as parameters v{}: {w}, {c}{h}", k + 1, o.run, o.version)
            } else {
                format!("outcome #{} (run {}, {kind}): rejected, v{} stays: {}", k + 1, o.run, ls.snap.params_version, o.reason)
            };
            let data = json!({
                "n": k + 1, "run": o.run, "kind": kind, "accepted": o.accepted, "version": o.version,
                "worst_sigma_m": worst.as_ref().map(|w| w.0),
                "largest_anchor_change_m": change.map(|c| c.0),
                "heldout_rms_m": o.heldout_rms_new_m.is_finite().then_some(o.heldout_rms_new_m),
            });
            if o.accepted {
                if let Some(e) = est {
                    self.last_anchors = Some(e.geometry.anchors.clone());
                }
            }
            self.record(ls.snap.t, "outcome", data, &line);
        }
        self.outcomes_seen = cs.outcomes.len();
    }

    fn follow_goal(&mut self, ls: &LoopStatus) {
        let Some(g) = self.goal.as_mut().filter(|g| g.ended.is_none()) else { return };
        let v = view(ls, g);
        if let Some(end) = g.wait.observe(&v) {
            g.ended = Some(end.clone());
            let (id, target) = (g.id, g.target_m);
            let line = format!("goal #{id} {}: {}", point(&target), end.describe());
            let mut data = end.json();
            data["id"] = json!(id);
            self.record(ls.snap.t, "goal-end", data, &line);
        }
    }

    fn follow_return(&mut self, ls: &LoopStatus) {
        let Some(r) = self.ret.clone() else { return };
        let st = ls.snap.state;
        let here = pose(ls).unwrap_or(ls.snap.target_m);
        let t = ls.snap.t;
        let stopped = |why: String| ReturnStage::Stopped { at_m: here, why };
        let next = match r.stage {
            ReturnStage::Requested { t_s } => {
                if !matches!(st, State::Operate | State::Holding) && ls.snap.fault.is_none() {
                    Some(ReturnStage::Moving)
                } else if t - t_s > 2.0 {
                    Some(stopped("the loop did not start the recalibration (its state changed)".into()))
                } else {
                    None
                }
            }
            ReturnStage::Moving => match st {
                _ if ls.snap.fault.is_some() => {
                    let (c, _) = ls.snap.fault.expect("checked");
                    Some(stopped(format!("a safety reaction latched during the recalibration: {c}")))
                }
                State::Operate => {
                    let sent = self.commands.as_ref().map(|c| c.try_send(Command::MoveTo(r.to_m)));
                    match sent {
                        Some(Ok(())) => {
                            let id = self.new_goal(ls, r.to_m, "recalibrate");
                            Some(ReturnStage::Returning(id))
                        }
                        Some(Err(_)) => Some(stopped("the return move could not be queued".into())),
                        None => Some(stopped("no command queue to send the return move".into())),
                    }
                }
                State::Holding | State::Stopped | State::Faulted | State::Resetting | State::Idle | State::Enabling => {
                    Some(stopped(format!("the robot went to {} before the motion ended", st.name())))
                }
                _ => None,
            },
            ReturnStage::Returning(id) => match self.goal.as_ref().filter(|g| g.id == id).and_then(|g| g.ended.clone()) {
                Some(GoalEnd::Arrived { error_m }) => Some(ReturnStage::Returned { error_m }),
                Some(end) => Some(stopped(end.describe())),
                None if self.goal.as_ref().is_none_or(|g| g.id != id) => Some(stopped("another goal replaced the return".into())),
                None => None,
            },
            ReturnStage::Returned { .. } | ReturnStage::Stopped { .. } => None,
        };
        let Some(stage) = next else { return };
        let line = match &stage {
            ReturnStage::Moving => None,
            ReturnStage::Returning(id) => Some(format!("recalibrate: motion over; returning to {} (goal #{id})", point(&r.to_m))),
            ReturnStage::Returned { error_m } => Some(format!(
                "recalibrate: back at {}{}",
                point(&r.to_m),
                error_m.map_or(String::new(), |e| format!(", {:.1} mm from it", e * 1e3))
            )),
            ReturnStage::Stopped { at_m, why } => {
                Some(format!("recalibrate: the platform did not return to {}; it is at {}: {why}", point(&r.to_m), point(at_m)))
            }
            ReturnStage::Requested { .. } => None,
        };
        if let Some(line) = line {
            let data = match &stage {
                ReturnStage::Returned { error_m } => json!({"stage": "returned", "return_to_m": r.to_m, "error_m": error_m}),
                ReturnStage::Stopped { at_m, why } => json!({"stage": "stopped", "return_to_m": r.to_m, "at_m": at_m, "why": why}),
                _ => json!({"stage": "returning", "return_to_m": r.to_m}),
            };
            self.record(t, "return", data, &line);
        }
        if let Some(x) = self.ret.as_mut() {
            x.stage = stage;
        }
    }

    /// A line every [`PROGRESS_EVERY_S`] of a running excitation: how far it is.
    fn progress(&mut self, ls: &LoopStatus) {
        let t = ls.snap.t;
        if ls.snap.state != State::Excitation {
            self.excitation = None;
            return;
        }
        let (t0, last) = *self.excitation.get_or_insert((t, t));
        if t - last >= PROGRESS_EVERY_S {
            let x = self.expected.excitation_s;
            let line = format!("excitation: {:.0} s so far (the tour is about {x:.0} s, plus the approach)", t - t0);
            self.record(t, "progress", json!({"state": "excitation", "elapsed_s": t - t0, "expected_s": x}), &line);
            self.excitation = Some((t0, t));
        }
    }

    fn health(&mut self, ls: &LoopStatus, at_stop: bool) {
        let t = ls.snap.t;
        if !at_stop && t - self.health_t < HEALTH_EVERY_S {
            return;
        }
        let new_overruns = ls.overruns.saturating_sub(self.health_overruns);
        let clean = new_overruns == 0 && ls.max_late_ns <= self.health_max_late_ns;
        if at_stop || !clean {
            let span = if at_stop { "at stop".to_string() } else { format!("in the last {:.0} s", t - self.health_t) };
            let line = format!(
                "loop health {span}: {new_overruns} overruns ({} in all), worst lateness {:.2} ms, worst compute {:.2} ms, {} samples dropped, {}",
                ls.overruns,
                ls.max_late_ns as f64 * 1e-6,
                ls.max_compute_ns as f64 * 1e-6,
                ls.dropped,
                if ls.realtime { "SCHED_FIFO" } else { "not real-time (no SCHED_FIFO)" },
            );
            let data = json!({"overruns": ls.overruns, "new_overruns": new_overruns, "max_late_us": ls.max_late_ns as f64 * 1e-3,
                              "cycles": ls.cycles, "at_stop": at_stop});
            self.record(t, "loop", data, &line);
        }
        self.health_t = t;
        self.health_overruns = ls.overruns;
        self.health_max_late_ns = ls.max_late_ns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(t_s: f64, id: u64, state: &str, reached: bool, error_m: Option<f64>) -> GoalView {
        GoalView { t_s, id: Some(id), state: state.into(), fault: None, reached, error_m, ended: None }
    }

    #[test]
    fn a_move_arrives_within_the_tolerance_and_not_before() {
        let mut w = MoveWait::new(3, 0.005);
        // From holding, the loop switches to operate within a cycle.
        assert_eq!(w.observe(&view(0.0, 3, "holding", false, Some(1.0))), None);
        assert_eq!(w.observe(&view(0.1, 3, "operate", false, Some(0.5))), None);
        // The setpoint is there but the platform is 8 mm away: it may still settle.
        assert_eq!(w.observe(&view(2.0, 3, "operate", true, Some(0.008))), None);
        assert_eq!(w.observe(&view(2.5, 3, "operate", true, Some(0.004))), Some(GoalEnd::Arrived { error_m: Some(0.004) }));
    }

    #[test]
    fn a_move_that_cannot_settle_faults_or_is_replaced_ends_with_its_reason() {
        let mut w = MoveWait::new(3, 0.001);
        assert_eq!(w.observe(&view(2.0, 3, "operate", true, Some(0.003))), None);
        assert_eq!(w.observe(&view(3.1, 3, "operate", true, Some(0.003))), Some(GoalEnd::OffTarget { error_m: 0.003 }));
        let mut w = MoveWait::new(3, 0.005);
        let mut v = view(1.0, 3, "faulted", false, Some(0.2));
        v.fault = Some("emergency stop".into());
        assert!(matches!(w.observe(&v), Some(GoalEnd::Fault { error_m: Some(e), .. }) if e == 0.2));
        let mut w = MoveWait::new(3, 0.005);
        assert_eq!(w.observe(&view(1.0, 4, "operate", false, None)), Some(GoalEnd::Superseded { by: 4 }));
        let mut w = MoveWait::new(3, 0.005);
        assert!(matches!(w.observe(&view(1.0, 3, "excitation", false, None)), Some(GoalEnd::Interrupted { state: "excitation", .. })));
        // Still holding a second after the move: the loop did not take it.
        let mut w = MoveWait::new(3, 0.005);
        assert_eq!(w.observe(&view(1.0, 3, "holding", false, None)), None);
        assert_eq!(w.observe(&view(2.5, 3, "holding", false, None)), Some(GoalEnd::NotTaken));
    }

    #[test]
    fn the_goal_round_trips_through_the_status_json() {
        let end = GoalEnd::Arrived { error_m: Some(0.002) };
        let st = json!({"t_s": 4.0, "state": "operate", "fault": null,
                        "goal": {"id": 2, "reached": true, "error_m": 0.002, "ended": end.json()}});
        let v = GoalView::from_status(&st);
        assert_eq!((v.id, v.reached, v.error_m, v.ended), (Some(2), true, Some(0.002), Some(end)));
    }

    #[test]
    fn the_journal_is_numbered_bounded_and_says_what_was_lost() {
        let op = Operator::default();
        op.set_log(Arc::new(|_| {}));
        {
            let mut s = lock(&op.inner);
            for k in 0..(JOURNAL + 10) {
                s.record(k as f64, "test", json!({}), "line");
            }
        }
        let (ev, next, lost) = op.events_since(1);
        assert_eq!((ev.len(), lost), (EVENTS_PER_REPLY, 10));
        assert_eq!(ev[0]["seq"], 11);
        assert_eq!(next, 11 + EVENTS_PER_REPLY as u64);
        let (ev, next, lost) = op.events_since(op.next_seq());
        assert_eq!((ev.len(), next, lost), (0, JOURNAL as u64 + 11, 0));
    }
}
