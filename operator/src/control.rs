//! Operator control over a Unix domain socket: request lines in, one JSON line out for each.
//!
//! ```text
//! request         reply
//! status          {"ok":true,"state":"operate","goal":{..},"calibration":{..},...}   (bounded size)
//! params          {"ok":true,"params":{"version":3,"anchors_m":[[..]],...}}
//! recalibrate     {"ok":true,"accepted":"recalibrate","return_to_m":[X,Y,Z],"message":..}
//! estop | stop    {"ok":true,"accepted":"estop"}         (urgent: a flag the loop tests every cycle)
//! reset           {"ok":true,"accepted":"reset"}
//! move X Y Z      {"ok":true,"accepted":"move","target_m":[X,Y,Z],"goal":7}
//! events [SEQ]    {"ok":true,"events":[{"seq":..,"t_s":..,"event":"state",..}],"next":..,"lost":0}
//! outcome N       {"ok":true,"outcome":{..every data problem..}}
//! help            {"ok":true,"requests":[{"request":"status","what":..},..]}
//! anything else   {"ok":false,"error":"<what was wrong and what to send>"}
//! ```
//!
//! A refused request says why: `move` is refused when a coordinate is not a finite number, when
//! the point is outside the workspace box, or when the robot is not operating (a latched fault,
//! a state other than operate/holding, no calibrated parameters yet). "Accepted" means handed to
//! the loop, which may still decline a move if its state changed in between.
//!
//! `status` lists the newest [`STATUS_OUTCOMES`] calibration outcomes in short; `outcome N`
//! gives one in full. Goals, the return after a recalibration and the event journal are the
//! [`Operator`]'s ([`crate::operator`]).
//!
//! The server ([`ControlServer`]) serves many clients with a line length limit and a deadline
//! per request, on a socket of mode 0660 (the operator group); the loop sees only [`Command`]s
//! from a bounded channel and the [`Urgent`] flags.

use crate::operator::Operator;
use crossbeam_channel::Sender;
use serde_json::{json, Value};
use std::fmt;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use taut_calibrator::vocab::{CalibStatus, OutcomeKind, SharedCalibStatus};
use taut_driver::tracker::TrackerStatsHandle;
use taut_rt::cycle::LoopStatus;
use taut_rt::motion::{Command, ResetOutcome, State};
use taut_rt::triple::Reader;
use taut_rt::urgent::Urgent;

pub use crate::ctl_server::{ControlServer, ServerLimits, ServerStats};

/// Shared handle on the loop's status reader.
pub type SharedLoopStatus = Arc<Mutex<Reader<LoopStatus>>>;

fn finite(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        Value::Null
    }
}

/// Outcomes listed in `status` (the newest; the others by number with `outcome N`).
pub const STATUS_OUTCOMES: usize = 4;

/// Longest rejection reason quoted in `status`, characters (the whole one: `outcome N`).
const REASON_CHARS: usize = 240;

fn drive_name(d: taut_rt::io::DriveStatus) -> &'static str {
    use taut_rt::io::DriveStatus::*;
    match d {
        Unknown => "unknown",
        Disabled => "disabled",
        Enabled => "enabled",
        QuickStop => "quick-stop",
        Fault => "fault",
    }
}

/// One outcome in full (`outcome N`): the estimate, its sigmas, every data problem.
pub fn outcome_json(n: usize, o: &taut_calibrator::vocab::CalibrationOutcome) -> Value {
    let est = o.estimate.as_ref().map(|e| {
        json!({"anchors_m": e.geometry.anchors, "l0_m": e.geometry.l0, "anchor_sigma_m": e.sigma.anchors.iter().map(|s| s.map(finite)).collect::<Vec<_>>(),
               "l0_sigma_m": e.sigma.l0.iter().map(|&s| finite(s)).collect::<Vec<_>>(), "note": e.note,
               "model_consistent": e.model_consistent})
    });
    json!({
        "n": n,
        "run": o.run,
        "kind": match o.kind { OutcomeKind::Initial => "initial", OutcomeKind::Calibration => "calibration" },
        "accepted": o.accepted,
        "reason": o.reason,
        "version": o.version,
        "samples": o.samples,
        "heldout_rms_new_m": finite(o.heldout_rms_new_m),
        "heldout_rms_old_m": finite(o.heldout_rms_old_m),
        "heldout_outliers": o.heldout_outliers,
        "heldout_rows": o.heldout_rows,
        "estimate": est,
        "data_problems": o.data_problems,
    })
}

/// An outcome in short (`status`): the numbers, the reason cut, the data problems counted.
fn outcome_summary(n: usize, o: &taut_calibrator::vocab::CalibrationOutcome) -> Value {
    json!({
        "n": n,
        "run": o.run,
        "kind": match o.kind { OutcomeKind::Initial => "initial", OutcomeKind::Calibration => "calibration" },
        "accepted": o.accepted,
        "reason": excerpt(&o.reason, REASON_CHARS),
        "version": o.version,
        "samples": o.samples,
        "heldout_rms_new_m": finite(o.heldout_rms_new_m),
        "heldout_rms_old_m": finite(o.heldout_rms_old_m),
        "heldout_outliers": o.heldout_outliers,
        "worst_sigma_m": o.estimate.as_ref().and_then(|e| crate::operator::worst_sigma(&e.sigma.anchors, &e.sigma.l0)).map(|w| w.0),
        "model_consistent": o.estimate.as_ref().and_then(|e| e.model_consistent),
        "data_problems": o.data_problems.len(),
    })
}

/// The status as JSON. Its size is bounded: the newest [`STATUS_OUTCOMES`] outcomes in short
/// (`outcomes_total` counts them all; `outcome N` gives one in full).
pub fn status_json(loop_status: &LoopStatus, calib: &taut_calibrator::vocab::CalibStatus) -> Value {
    let s = &loop_status.snap;
    let n = s.inputs.n;
    let fault = s.fault.map(|(c, r)| json!({"cause": c.name(), "reaction": r.name(), "message": c.to_string()}));
    let total = calib.outcomes.len();
    let outcomes: Vec<Value> =
        calib.outcomes.iter().enumerate().skip(total.saturating_sub(STATUS_OUTCOMES)).map(|(k, o)| outcome_summary(k + 1, o)).collect();
    let reset = s.last_reset.map(|r| match r {
        ResetOutcome::InProgress => json!({"outcome": "in-progress"}),
        ResetOutcome::Done => json!({"outcome": "done"}),
        ResetOutcome::Refused(why) => json!({"outcome": "refused", "message": why.to_string()}),
    });
    let bus = &s.inputs.bus;
    let current = calib.current.as_ref().map(|p| {
        let worst = crate::operator::worst_sigma(&p.anchor_sigma_m, &p.l0_sigma_m);
        json!({"version": p.version, "source": p.source, "worst_sigma_m": worst.as_ref().map(|w| w.0),
               "worst_sigma_of": worst.map(|w| w.1), "heldout_rms_m": finite(p.heldout_rms_m)})
    });
    json!({
        "ok": true,
        "t_s": s.t,
        "reset": {"last": reset, "resets": s.resets, "reenable_step_m": s.reenable_step_m},
        "bus": {"iface": bus.iface.as_str(), "state": bus.state.name(), "last": bus.last.map(|e| e.to_string()),
                "events": bus.events, "recoveries": bus.recoveries},
        "state": s.state.name(),
        "phase": s.phase,
        "phases_completed": s.phases_completed,
        "run": s.run,
        "fault": fault,
        "params_version": s.params_version,
        "swap_active": s.swap_active,
        "swaps": s.swaps,
        "max_swap_step_m": s.max_swap_step_m,
        "target_m": s.target_m,
        "pose_m": s.inputs.pose_m.map(finite),
        "pose_age_s": finite(s.inputs.pose_age_s),
        "lengths_m": s.inputs.length_m[..n].iter().map(|&v| finite(v)).collect::<Vec<_>>(),
        "tensions_n": s.inputs.tension_n[..n].iter().map(|&v| finite(v)).collect::<Vec<_>>(),
        "tension_age_s": s.inputs.tension_age_s[..n].iter().map(|&v| finite(v)).collect::<Vec<_>>(),
        "drives": s.inputs.drive[..n].iter().map(|&d| drive_name(d)).collect::<Vec<_>>(),
        "loop": {
            "cycles": loop_status.cycles,
            "overruns": loop_status.overruns,
            "max_late_us": loop_status.max_late_ns as f64 * 1e-3,
            "max_compute_us": loop_status.max_compute_ns as f64 * 1e-3,
            "samples_dropped": loop_status.dropped,
            "realtime": loop_status.realtime,
        },
        "calibration": {
            "stage": calib.stage,
            "samples_recorded": calib.samples_recorded,
            "dataset_samples": calib.dataset_samples,
            "recording": calib.recording.as_ref().map(|p| p.display().to_string()),
            "recorder_error": calib.recorder_error.as_ref().map(ToString::to_string),
            "current": current,
            "outcomes_total": total,
            "outcomes": outcomes,
            "excitation": crate::control::excitation_json(calib),
        },
    })
}

/// A parsed request line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// `status`
    Status,
    /// `params`
    Params,
    /// `recalibrate`
    Recalibrate,
    /// `stop` (urgent: bypasses the command queue)
    Stop,
    /// `estop` (urgent: bypasses the command queue)
    Estop,
    /// `reset`
    Reset,
    /// `move X Y Z`, finite coordinates, m
    Move([f64; 3]),
    /// `events [SEQ]`: the journal from event SEQ on (default: the next one; see
    /// [`crate::operator`])
    Events(Option<u64>),
    /// `outcome N`: the calibrator's N-th outcome in full (1 is the first)
    CalibrationOutcome(usize),
    /// `help`: the requests and what they do
    Help,
}

impl Request {
    /// Estop and stop are answered ahead of everything else.
    pub fn is_urgent(self) -> bool {
        matches!(self, Request::Estop | Request::Stop)
    }
}

const VERBS: &str = "status | params | recalibrate | stop | estop | reset | move X Y Z | events [SEQ] | outcome N | help";

/// What each request does (the reply to `help`).
pub const HELP: &[(&str, &str)] = &[
    ("status", "state, goal, calibration, drives, load cells, tracker, faults, loop health (bounded size)"),
    ("params", "the parameters in force: anchors, offsets, their 1-sigma"),
    ("recalibrate", "run the excitation again, calibrate, hot-swap if better; the platform comes back afterwards"),
    ("move X Y Z", "move the platform to X Y Z (m) in a straight line; the reply's goal number is followed in status"),
    ("estop", "emergency stop: quick stop, latched until reset (answered first)"),
    ("stop", "controlled stop: hold, disable, end the daemon (answered first)"),
    ("reset", "clear a latched safety reaction, re-enable the drives holding where they stand"),
    ("events [SEQ]", "the event journal from number SEQ on (at most 64 per reply; `next` is the one to ask for next)"),
    ("outcome N", "the calibrator's N-th outcome in full: estimate, sigmas, every data problem"),
    ("help", "this list"),
];

/// At most `n` characters of `s` for an error message, with `...` when cut.
fn excerpt(s: &str, n: usize) -> String {
    match s.char_indices().nth(n) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s.to_string(),
    }
}

/// Why a request line was refused. Its `Display` is the reply's `error` message; words quoted
/// from the request are cut to 40 characters.
#[derive(Debug, Clone, PartialEq)]
pub enum RequestError {
    /// Not UTF-8.
    NotUtf8 {
        /// Byte offset of the first bad byte.
        offset: usize,
    },
    /// A control character other than tab.
    ControlChar {
        /// The character.
        c: char,
        /// Its byte offset.
        offset: usize,
    },
    /// Nothing but white space.
    Empty,
    /// A verb that takes no arguments got some.
    UnexpectedArguments {
        /// The verb.
        verb: &'static str,
        /// The arguments (quoted, cut).
        args: String,
    },
    /// `move` without exactly three numbers.
    MoveArity {
        /// How many came (4 means four or more).
        got: usize,
    },
    /// A `move` coordinate that does not parse as a number.
    NotANumber {
        /// `X`, `Y` or `Z`.
        axis: &'static str,
        /// The word (quoted, cut).
        word: String,
    },
    /// A number argument (`events SEQ`, `outcome N`) that is not a whole number in range.
    BadCount {
        /// The verb.
        verb: &'static str,
        /// The word (quoted, cut).
        word: String,
    },
    /// A `move` coordinate that is NaN or infinite.
    NotFinite {
        /// `X`, `Y` or `Z`.
        axis: &'static str,
        /// The word (quoted, cut).
        word: String,
    },
    /// An unknown verb.
    UnknownVerb {
        /// The verb (quoted, cut).
        verb: String,
    },
}

impl fmt::Display for RequestError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RequestError::NotUtf8 { offset } => write!(f, "the request is not UTF-8 text (bad byte at offset {offset})"),
            RequestError::ControlChar { c, offset } => {
                write!(f, "the request has a control character {c:?} at offset {offset}; send one line of text: {VERBS}")
            }
            RequestError::Empty => write!(f, "empty request; send one of: {VERBS}"),
            RequestError::UnexpectedArguments { verb, args } => write!(f, "{verb} takes no arguments, got {args:?}"),
            RequestError::MoveArity { got } => {
                write!(f, "move needs exactly three numbers: move X Y Z (m), got {}{}", got, if *got > 3 { " or more" } else { "" })
            }
            RequestError::NotANumber { axis, word } => write!(f, "move: {axis} = {word:?} is not a number"),
            RequestError::NotFinite { axis, word } => write!(f, "move refused: {axis} = {word:?} is not a finite number (m)"),
            RequestError::BadCount { verb, word } => {
                write!(
                    f,
                    "{verb}: {word:?} is not a whole number{}",
                    if *verb == "outcome" { " from 1 (outcome N)" } else { " (events SEQ)" }
                )
            }
            RequestError::UnknownVerb { verb } => write!(f, "unknown request {verb:?}: {VERBS}"),
        }
    }
}

impl std::error::Error for RequestError {}

/// Parses one request line (without its line end). The error's `Display` is the reply's message.
pub fn parse_request(line: &[u8]) -> Result<Request, RequestError> {
    let text = std::str::from_utf8(line).map_err(|e| RequestError::NotUtf8 { offset: e.valid_up_to() })?;
    if let Some((offset, c)) = text.char_indices().find(|&(_, c)| c.is_control() && c != '\t') {
        return Err(RequestError::ControlChar { c, offset });
    }
    let mut words = text.split_whitespace();
    let Some(verb) = words.next() else {
        return Err(RequestError::Empty);
    };
    let rest: Vec<&str> = words.take(5).collect();
    let simple = |r: Request, verb: &'static str| {
        if rest.is_empty() {
            Ok(r)
        } else {
            Err(RequestError::UnexpectedArguments { verb, args: excerpt(&rest.join(" "), 40) })
        }
    };
    match verb {
        "status" => simple(Request::Status, "status"),
        "params" => simple(Request::Params, "params"),
        "recalibrate" => simple(Request::Recalibrate, "recalibrate"),
        "stop" => simple(Request::Stop, "stop"),
        "estop" => simple(Request::Estop, "estop"),
        "reset" => simple(Request::Reset, "reset"),
        "help" => simple(Request::Help, "help"),
        "events" => match rest.as_slice() {
            [] => Ok(Request::Events(None)),
            [w] => w.parse().map(|q| Request::Events(Some(q))).map_err(|_| RequestError::BadCount { verb: "events", word: excerpt(w, 40) }),
            _ => Err(RequestError::BadCount { verb: "events", word: excerpt(&rest.join(" "), 40) }),
        },
        "outcome" => match rest.as_slice() {
            [w] => match w.parse::<usize>() {
                Ok(k) if k >= 1 => Ok(Request::CalibrationOutcome(k)),
                _ => Err(RequestError::BadCount { verb: "outcome", word: excerpt(w, 40) }),
            },
            _ => Err(RequestError::BadCount { verb: "outcome", word: excerpt(&rest.join(" "), 40) }),
        },
        "move" => {
            if rest.len() != 3 {
                return Err(RequestError::MoveArity { got: rest.len().min(4) });
            }
            let mut p = [0.0; 3];
            for (i, w) in rest.iter().enumerate() {
                let axis = ["X", "Y", "Z"][i];
                let v: f64 = w.parse().map_err(|_| RequestError::NotANumber { axis, word: excerpt(w, 40) })?;
                if !v.is_finite() {
                    return Err(RequestError::NotFinite { axis, word: excerpt(w, 40) });
                }
                p[i] = v;
            }
            Ok(Request::Move(p))
        }
        _ => Err(RequestError::UnknownVerb { verb: excerpt(verb, 40) }),
    }
}

/// What requests act on: the loop's inputs and the status readers.
#[derive(Clone)]
pub struct ControlLinks {
    /// Commands to the loop (bounded; a full queue refuses the request).
    pub commands: Sender<Command>,
    /// Estop and stop, without the queue.
    pub urgent: Arc<Urgent>,
    /// The loop's status.
    pub loop_status: SharedLoopStatus,
    /// The calibrator's status.
    pub calib: SharedCalibStatus,
    /// The workspace box a move must stay in, m (`motion.workspace_min_m` / `workspace_max_m`).
    pub workspace: [[f64; 3]; 2],
    /// The tracker receiver's counters, for `status` (`None`: no tracker).
    pub tracker: Option<TrackerStatsHandle>,
    /// Goals, the return after a recalibration, the event journal, the log lines.
    pub operator: Operator,
}

/// A poisoned lock only means another thread panicked while holding it; the data is plain
/// status, still worth showing.
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl ControlLinks {
    /// Answers one parsed request. Never blocks on the loop: urgent requests set a flag, others
    /// go through the bounded queue with `try_send`.
    pub fn handle(&self, req: Request) -> Value {
        let send = |c: Command, what: &str| match self.commands.try_send(c) {
            Ok(()) => json!({"ok": true, "accepted": what}),
            Err(crossbeam_channel::TrySendError::Full(_)) => {
                json!({"ok": false, "error": format!("{what} refused: the loop's command queue is full; try again")})
            }
            Err(crossbeam_channel::TrySendError::Disconnected(_)) => {
                json!({"ok": false, "error": format!("{what} refused: the loop has ended")})
            }
        };
        match req {
            Request::Estop => {
                self.urgent.estop();
                json!({"ok": true, "accepted": "estop"})
            }
            Request::Stop => {
                self.urgent.stop();
                json!({"ok": true, "accepted": "stop"})
            }
            Request::Status => {
                let ls = *lock(&self.loop_status).read();
                let cs = lock(&self.calib).clone();
                let mut v = status_json(&ls, &cs);
                let (goal, ret) = self.operator.status_json(&ls);
                v["goal"] = goal;
                v["recalibrate"] = ret;
                v["events_next"] = json!(self.operator.next_seq());
                // How people name the cables (from 1) and the devices behind them; the arrays
                // above are indexed from 0 in the same order.
                let ids = self.operator.cables();
                v["cables"] = json!((0..ls.snap.inputs.n)
                    .map(|j| {
                        let (node, unit) = ids.get(j).copied().unwrap_or_default();
                        json!({"name": taut_config::cable_name(j), "node_id": node, "unit_id": unit})
                    })
                    .collect::<Vec<_>>());
                if let Some(t) = &self.tracker {
                    let s = t.stats();
                    v["tracker"] = json!({
                        "pose_age_s": finite(ls.snap.inputs.pose_age_s),
                        "received": s.received, "accepted": s.accepted, "malformed": s.malformed, "late": s.late,
                        "out_of_order": s.out_of_order, "restarts": s.restarts, "foreign": s.foreign,
                    });
                }
                v
            }
            Request::Params => {
                let cs = lock(&self.calib);
                match &cs.current {
                    Some(p) => json!({"ok": true, "params": {
                        "version": p.version, "created_unix_s": p.created_unix_s, "source": p.source,
                        "anchors_m": p.anchors_m, "l0_m": p.l0_m, "anchor_sigma_m": p.anchor_sigma_m,
                        "l0_sigma_m": p.l0_sigma_m, "rms_m": finite(p.rms_m), "heldout_rms_m": finite(p.heldout_rms_m)}}),
                    None => json!({"ok": true, "params": null}),
                }
            }
            Request::Recalibrate => {
                let ls = *lock(&self.loop_status).read();
                if !matches!(ls.snap.state, State::Operate | State::Holding) || ls.snap.fault.is_some() {
                    return json!({"ok": false, "error": format!("recalibrate refused: it needs the robot operating without a fault; it is {}", ls.snap.state.name())});
                }
                match send(Command::Recalibrate, "recalibrate") {
                    v if v["ok"] == true => {
                        let to = self.operator.recalibrate_accepted(&ls);
                        json!({"ok": true, "accepted": "recalibrate", "return_to_m": to,
                               "message": format!("the excitation moves the platform; it comes back to {} afterwards (see status: recalibrate)", crate::operator::point(&to))})
                    }
                    v => v,
                }
            }
            Request::Events(from) => {
                let from = from.unwrap_or_else(|| self.operator.next_seq());
                let (events, next, lost) = self.operator.events_since(from);
                json!({"ok": true, "events": events, "next": next, "lost": lost})
            }
            Request::CalibrationOutcome(k) => {
                let cs = lock(&self.calib);
                match cs.outcomes.get(k - 1) {
                    Some(o) => json!({"ok": true, "outcome": outcome_json(k, o)}),
                    None => {
                        json!({"ok": false, "error": format!("outcome {k}: there are {} outcomes so far (1 to {})", cs.outcomes.len(), cs.outcomes.len())})
                    }
                }
            }
            Request::Help => {
                json!({"ok": true, "requests": HELP.iter().map(|(r, what)| json!({"request": r, "what": what})).collect::<Vec<_>>()})
            }
            Request::Reset => send(Command::Reset, "reset"),
            Request::Move(p) => {
                let w = &self.workspace;
                if (0..3).any(|i| p[i] < w[0][i] || p[i] > w[1][i]) {
                    return json!({"ok": false, "error": format!(
                        "move refused: {p:?} m is outside the workspace box {:?} .. {:?} m (motion.workspace_min_m / workspace_max_m)", w[0], w[1])});
                }
                let s = lock(&self.loop_status).read().snap;
                if let Some((cause, _)) = s.fault {
                    return json!({"ok": false, "error": format!("move refused: the robot is not operating: a safety reaction is latched ({cause}); `reset` first")});
                }
                if !matches!(s.state, State::Operate | State::Holding) {
                    return json!({"ok": false, "error": format!("move refused: the robot is not operating (state {}); moves are taken in operate or holding", s.state.name())});
                }
                if s.params_version == 0 {
                    return json!({"ok": false, "error": "move refused: the robot is not operating: no calibrated parameters yet"});
                }
                match send(Command::MoveTo(p), "move") {
                    v if v["ok"] == true => {
                        let ls = *lock(&self.loop_status).read();
                        let goal = self.operator.move_accepted(&ls, p);
                        json!({"ok": true, "accepted": "move", "target_m": p, "goal": goal})
                    }
                    v => v,
                }
            }
        }
    }

    /// The operator's periodic work ([`Operator::tick`]): the control thread calls it every
    /// round; a host that steps the loop itself calls it between cycles.
    pub fn tick(&self) {
        let ls = *lock(&self.loop_status).read();
        let cs = lock(&self.calib);
        self.operator.tick(&ls, &cs);
    }

    /// Parses and answers one request line (a convenience for tests and one-shot callers).
    pub fn handle_line(&self, line: &str) -> Value {
        match parse_request(line.trim().as_bytes()) {
            Ok(r) => self.handle(r),
            Err(e) => json!({"ok": false, "error": e.to_string()}),
        }
    }
}

/// Sends one request and returns the reply (client side of `taut ctl`). Errors say which step
/// failed: connecting (kind `NotFound` / `ConnectionRefused`: nothing serves the socket), no reply
/// within `timeout` (`TimedOut`), the connection closed without a reply (`UnexpectedEof`), or a
/// reply that is not JSON (`InvalidData`).
pub fn request(path: &Path, req: &str, timeout: Duration) -> std::io::Result<Value> {
    use std::io::{Error, ErrorKind};
    let mut s = UnixStream::connect(path)?;
    s.set_read_timeout(Some(timeout))?;
    s.set_write_timeout(Some(timeout))?;
    writeln!(s, "{req}").map_err(|e| Error::new(e.kind(), format!("sending the request: {e}")))?;
    let mut line = String::new();
    match BufReader::new(s).read_line(&mut line) {
        Ok(0) => return Err(Error::new(ErrorKind::UnexpectedEof, "the daemon closed the connection without a reply")),
        Ok(_) => {}
        Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
            return Err(Error::new(
                ErrorKind::TimedOut,
                format!("the daemon accepted the connection but sent no reply within {:.1} s", timeout.as_secs_f64()),
            ))
        }
        Err(e) => return Err(Error::new(e.kind(), format!("reading the reply: {e}"))),
    }
    serde_json::from_str(&line)
        .map_err(|e| Error::new(ErrorKind::InvalidData, format!("the reply is not JSON ({e}): {:?}", excerpt(line.trim_end(), 80))))
}

/// True when the start-up is over, well or badly: a fault, a stop, a refused start-up
/// calibration, or the accepted one hot-swapped into the loop.
pub fn startup_finished(l: &LoopStatus, c: &CalibStatus) -> bool {
    if l.snap.fault.is_some() || l.snap.state == State::Stopped {
        return true;
    }
    if c.outcomes.iter().any(|o| o.run == 0 && !o.accepted) {
        return true;
    }
    match c.outcomes.iter().find(|o| o.run == 0 && o.kind == OutcomeKind::Calibration && o.accepted) {
        Some(o) => l.snap.params_version == o.version && !l.snap.swap_active,
        None => false,
    }
}

/// A `params` reply for people: the version, when it was made (local ISO 8601) and from what,
/// then per cable (from 1) the anchor and the encoder offset rounded to their 1-sigma.
pub fn params_text(v: &Value) -> String {
    use taut_config::numfmt::{rounded, sig2};
    let p = &v["params"];
    if p.is_null() {
        return "no parameters yet: the start-up calibration has not finished\n".into();
    }
    let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
    let mm = |x: &Value| x.as_f64().filter(|m| m.is_finite()).map_or("-".to_string(), |m| format!("{:.2} mm", m * 1e3));
    let created = p["created_unix_s"].as_f64().filter(|t| t.is_finite() && *t > 0.0).map_or("at an unknown time".to_string(), |t| {
        format!("on {}", crate::localtime::iso8601(std::time::UNIX_EPOCH + std::time::Duration::from_secs_f64(t)))
    });
    let mut out = format!(
        "parameters v{} ({}), made {created}; RMS {}, held-out RMS {}\n",
        p["version"],
        p["source"].as_str().unwrap_or("?"),
        mm(&p["rms_m"]),
        mm(&p["heldout_rms_m"])
    );
    let list = |x: &Value| x.as_array().cloned().unwrap_or_default();
    let (anchors, sig, l0, l0s) = (list(&p["anchors_m"]), list(&p["anchor_sigma_m"]), list(&p["l0_m"]), list(&p["l0_sigma_m"]));
    for (j, a) in anchors.iter().enumerate() {
        let a = list(a);
        let s = sig.get(j).map(list).unwrap_or_default();
        let xyz: Vec<String> = (0..3).map(|k| rounded(a.get(k).map_or(f64::NAN, f), s.get(k).map_or(f64::NAN, f))).collect();
        let sxyz: Vec<String> = (0..3).map(|k| sig2(s.get(k).map_or(f64::NAN, f) * 1e3)).collect();
        let (o, os) = (l0.get(j).map_or(f64::NAN, f), l0s.get(j).map_or(f64::NAN, f));
        out.push_str(&format!(
            "{}: anchor [{}] m ± [{}] mm; L0 {} m ± {} mm\n",
            taut_config::cable_name(j),
            xyz.join(", "),
            sxyz.join(", "),
            rounded(o, os),
            sig2(os * 1e3)
        ));
    }
    out
}

/// A `status` reply for people: one line per subject (state, fault, goal, recalibration,
/// calibration, outcomes, drives, load cells, tracker, loop). Cables are numbered from 1, with
/// the drive's CANopen node id or the load cell's Modbus unit id beside them where configured.
pub fn status_text(v: &Value) -> String {
    let mut out = String::new();
    let mut line = |k: &str, text: String| out.push_str(&format!("{k:<12} {text}\n"));
    let mm = |x: &Value| x.as_f64().map_or("-".to_string(), |m| format!("{:.2} mm", m * 1e3));
    let pt = |x: &Value| {
        let a: Vec<f64> = x.as_array().map_or(Vec::new(), |a| a.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect());
        if a.len() == 3 && a.iter().all(|v| v.is_finite()) {
            crate::operator::point(&[a[0], a[1], a[2]])
        } else {
            "unknown".into()
        }
    };
    let state = v["state"].as_str().unwrap_or("unknown");
    let phase = v["phase"].as_i64().filter(|p| *p >= 0).map_or(String::new(), |p| format!(" (phase {} of 3)", p + 1));
    let swap = if v["swap_active"] == true { ", swap ramp running" } else { "" };
    line("state", format!("{state}{phase}, parameters v{}{swap}", v["params_version"]));
    line(
        "fault",
        match v["fault"]["message"].as_str() {
            Some(m) => format!("{}: {m} (`taut ctl reset` when it is safe)", v["fault"]["reaction"].as_str().unwrap_or("latched")),
            None => "none".into(),
        },
    );
    let g = &v["goal"];
    line(
        "goal",
        match g["id"].as_u64() {
            None => format!("none; setpoint {}", pt(&v["target_m"])),
            Some(id) => {
                let how = match g["ended"]["message"].as_str() {
                    Some(m) => m.to_string(),
                    None if g["reached"] == true => format!("setpoint there, settling ({} from it)", mm(&g["error_m"])),
                    None => format!("moving, {} to go (setpoint {})", mm(&g["remaining_m"]), pt(&g["setpoint_m"])),
                };
                format!("#{id} {} ({}): {how}", pt(&g["target_m"]), g["origin"].as_str().unwrap_or("operator"))
            }
        },
    );
    let r = &v["recalibrate"];
    if let Some(stage) = r["stage"].as_str() {
        let to = pt(&r["return_to_m"]);
        line(
            "recalibrate",
            match stage {
                "returned" => format!("back at {to} ({} from it)", mm(&r["error_m"])),
                "stopped" => format!("did not return to {to}: stopped at {}: {}", pt(&r["at_m"]), r["why"].as_str().unwrap_or("")),
                "returning" => format!("returning to {to}"),
                _ => format!("under way; the platform comes back to {to} afterwards"),
            },
        );
    }
    let c = &v["calibration"];
    let cur = &c["current"];
    line(
        "calibration",
        if cur.is_null() {
            format!("no parameters yet; calibrator {}", c["stage"].as_str().unwrap_or("?"))
        } else {
            format!(
                "v{} ({}), worst 1-sigma {} ({}), held-out RMS {}; calibrator {}",
                cur["version"],
                cur["source"].as_str().unwrap_or("?"),
                mm(&cur["worst_sigma_m"]),
                cur["worst_sigma_of"].as_str().unwrap_or("-"),
                mm(&cur["heldout_rms_m"]),
                c["stage"].as_str().unwrap_or("?")
            )
        },
    );
    if let Some(o) = c["outcomes"].as_array().and_then(|a| a.last()) {
        let verdict = if o["accepted"] == true {
            format!("accepted as v{}", o["version"])
        } else {
            format!("rejected: {}", o["reason"].as_str().unwrap_or(""))
        };
        line(
            "outcomes",
            format!(
                "{} in all; latest #{} (run {}, {}) {verdict}; details: taut ctl outcome N",
                c["outcomes_total"],
                o["n"],
                o["run"],
                o["kind"].as_str().unwrap_or("?")
            ),
        );
    }
    let list = |x: &Value| x.as_array().cloned().unwrap_or_default();
    // The cables from 1, with the drive's node id or the load cell's unit id beside them.
    let cables = list(&v["cables"]);
    let name = |j: usize, id: &str, what: &str| match cables.get(j).and_then(|c| c[id].as_u64()) {
        Some(k) => format!("{} ({what} {k})", taut_config::cable_name(j)),
        None => taut_config::cable_name(j),
    };
    let drives = list(&v["drives"]);
    let bus = &v["bus"];
    line(
        "drives",
        format!(
            "{}; bus {} {}",
            drives
                .iter()
                .enumerate()
                .map(|(j, d)| format!("{}: {}", name(j, "node_id", "node"), d.as_str().unwrap_or("?")))
                .collect::<Vec<_>>()
                .join(", "),
            bus["iface"].as_str().unwrap_or("?"),
            bus["state"].as_str().unwrap_or("?")
        ),
    );
    let ages = list(&v["tension_age_s"]);
    line(
        "load cells",
        list(&v["tensions_n"])
            .iter()
            .enumerate()
            .map(|(j, t)| match (t.as_f64(), ages.get(j).and_then(Value::as_f64)) {
                (Some(t), Some(a)) => format!("{}: {t:.0} N ({a:.2} s old)", name(j, "unit_id", "unit")),
                (Some(t), None) => format!("{}: {t:.0} N", name(j, "unit_id", "unit")),
                _ => format!("{}: no reading", name(j, "unit_id", "unit")),
            })
            .collect::<Vec<_>>()
            .join(", "),
    );
    let t = &v["tracker"];
    line(
        "tracker",
        match (v["pose_age_s"].as_f64(), t.is_null()) {
            (None, true) => "none".into(),
            (age, _) => {
                let age = age.map_or("no pose yet".to_string(), |a| format!("{a:.2} s old"));
                let counts = if t.is_null() {
                    String::new()
                } else {
                    format!(
                        "; {} received, {} malformed, {} late, {} from foreign senders",
                        t["received"], t["malformed"], t["late"], t["foreign"]
                    )
                };
                format!("pose {} ({age}){counts}", pt(&v["pose_m"]))
            }
        },
    );
    let l = &v["loop"];
    line(
        "loop",
        format!(
            "{} cycles, {} overruns, worst lateness {:.2} ms, worst compute {:.2} ms, {} samples dropped, {}",
            l["cycles"],
            l["overruns"],
            l["max_late_us"].as_f64().unwrap_or(0.0) * 1e-3,
            l["max_compute_us"].as_f64().unwrap_or(0.0) * 1e-3,
            l["samples_dropped"],
            if l["realtime"] == true { "SCHED_FIFO" } else { "not real-time" }
        ),
    );
    out
}

/// The excitation's part of `ctl status`: the path, the predicted worst anchor 1-sigma and the
/// achieved one (of the last calibration that produced an estimate), m.
pub fn excitation_json(calib: &CalibStatus) -> Value {
    let Some(plan) = &calib.excitation else { return Value::Null };
    let finite = |v: f64| if v.is_finite() { Some(v) } else { None };
    let achieved = calib
        .outcomes
        .iter()
        .rev()
        .filter(|o| o.kind == OutcomeKind::Calibration)
        .find_map(|o| o.estimate.as_ref())
        .map(|e| taut_calibrator::excite::worst_anchor_sigma_m(&e.sigma.anchors));
    json!({
        "path": plan.path,
        "waypoints": plan.waypoints,
        "predicted_worst_anchor_sigma_m": finite(plan.predicted_worst_m()),
        "achieved_worst_anchor_sigma_m": achieved.and_then(finite),
        "note": plan.note,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_journal_and_outcome_requests_parse_and_bad_numbers_are_refused_clearly() {
        assert_eq!(parse_request(b"events"), Ok(Request::Events(None)));
        assert_eq!(parse_request(b"events 12"), Ok(Request::Events(Some(12))));
        assert_eq!(parse_request(b"outcome 3"), Ok(Request::CalibrationOutcome(3)));
        assert_eq!(parse_request(b"help"), Ok(Request::Help));
        for (line, says) in [
            ("outcome 0", "\"0\" is not a whole number from 1"),
            ("outcome", "outcome N"),
            ("outcome x", "\"x\" is not a whole number"),
            ("events -1", "(events SEQ)"),
            ("events 1 2", "\"1 2\" is not a whole number (events SEQ)"),
            ("help me", "help takes no arguments"),
            ("watch", "unknown request \"watch\": status | params"),
        ] {
            let e = parse_request(line.as_bytes()).unwrap_err().to_string();
            assert!(e.contains(says), "{line:?}: {e}");
        }
    }

    #[test]
    fn the_human_params_round_to_the_sigma_and_count_cables_from_1() {
        let text = params_text(&json!({"ok": true, "params": {
            "version": 3, "created_unix_s": 1_795_921_205.0, "source": "recalibration", "anchors_m": [[3.5090237, -1.78101, 3.98640]],
            "anchor_sigma_m": [[0.00063, 0.00038, 0.00064]], "l0_m": [-1.06265], "l0_sigma_m": [0.00091], "rms_m": 0.0015, "heldout_rms_m": 0.00154,
        }}));
        assert!(text.starts_with("parameters v3 (recalibration), made on 2026-11-"), "{text}");
        assert!(text.contains("RMS 1.50 mm, held-out RMS 1.54 mm"), "{text}");
        assert!(text.contains("cable 1: anchor [3.50902, -1.78101, 3.98640] m ± [0.63, 0.38, 0.64] mm; L0 -1.06265 m ± 0.91 mm"), "{text}");
        assert!(params_text(&json!({"ok": true, "params": null})).starts_with("no parameters yet"));
    }

    #[test]
    fn the_human_status_has_a_line_per_subject_even_when_empty() {
        let text = status_text(&json!({"ok": true, "state": "enabling", "phase": -1, "params_version": 0}));
        for key in ["state", "fault", "goal", "calibration", "drives", "load cells", "tracker", "loop"] {
            assert!(text.lines().any(|l| l.starts_with(key)), "{key}: {text}");
        }
        assert!(text.contains("no parameters yet") && text.contains("fault        none"), "{text}");
        let text = status_text(&json!({
            "ok": true, "state": "operate", "drives": ["enabled", "enabled"], "tensions_n": [20.0, null],
            "cables": [{"name": "cable 1", "node_id": 5, "unit_id": 7}, {"name": "cable 2", "node_id": null, "unit_id": null}],
        }));
        assert!(text.contains("drives       cable 1 (node 5): enabled, cable 2: enabled"), "{text}");
        assert!(text.contains("load cells   cable 1 (unit 7): 20 N, cable 2: no reading"), "{text}");
    }

    /// The wiring check's cause as `taut ctl status` shows it: the reaction, the cause naming the
    /// cables, what to do.
    #[test]
    fn the_human_status_names_a_miswiring() {
        use taut_rt::safety::{Cause, Miswiring};
        let c = Cause::Miswired {
            fault: Miswiring::DrivesSwapped,
            cable: 0,
            other: 3,
            reeled: 2,
            measured: 0.0,
            predicted: 150.4,
            for_other: -0.2,
            angle_deg: 73.2,
        };
        let r = c.reaction();
        let text = status_text(&json!({"ok": true, "state": "faulted", "phase": 0, "params_version": 0,
            "fault": {"cause": c.name(), "reaction": r.name(), "message": c.to_string()}}));
        let line = text.lines().find(|l| l.starts_with("fault")).unwrap();
        assert_eq!(
            line,
            "fault        hold: drives of cables 0 and 3 look swapped: reeling cable 2 moved the platform 73° from the direction the nominal \
             geometry predicts, and cable 0's encoder changed +0 mm, which the tracked motion predicts for cable 3 (+0 mm; for cable 0 \
             +150 mm); check the drives' node ids and motor cables (`taut ctl reset` when it is safe)"
        );
        assert_eq!(c.name(), "miswired");
    }
}
