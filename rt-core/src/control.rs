//! Operator control over a Unix domain socket: request lines in, one JSON line out for each.
//!
//! ```text
//! request         reply
//! status          {"ok":true,"state":"operate","phase":-1,"fault":null,"calibration":{...},...}
//! params          {"ok":true,"params":{"version":3,"anchors_m":[[..]],...}}
//! recalibrate     {"ok":true,"accepted":"recalibrate"}   (progress: see status)
//! estop | stop    {"ok":true,"accepted":"estop"}         (urgent: a flag the loop tests every cycle)
//! reset           {"ok":true,"accepted":"reset"}
//! move X Y Z      {"ok":true,"accepted":"move","target_m":[X,Y,Z]}
//! anything else   {"ok":false,"error":"<what was wrong and what to send>"}
//! ```
//!
//! A refused request says why: `move` is refused when a coordinate is not a finite number, when
//! the point is outside the workspace box, or when the robot is not operating (a latched fault,
//! a state other than operate/holding, no calibrated parameters yet). "Accepted" means handed to
//! the loop, which may still decline a move if its state changed in between.
//!
//! The server ([`ControlServer`], `ctl_server.rs`) serves many clients at once with a line
//! length limit and a deadline per request. The socket is created with mode 0660, so the
//! operator group may use it; the loop sees only [`Command`]s from a bounded channel and the
//! [`Urgent`] flags.

use crate::calibrator::{CalibStatus, OutcomeKind, SharedCalibStatus};
use crate::motion::{Command, ResetOutcome, State};
use crate::runner::LoopStatus;
use crate::triple::Reader;
use crate::urgent::Urgent;
use crossbeam_channel::Sender;
use serde_json::{json, Value};
use std::fmt;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use taut_driver::tracker::TrackerStatsHandle;

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

/// The status as JSON.
pub fn status_json(loop_status: &LoopStatus, calib: &crate::calibrator::CalibStatus) -> Value {
    let s = &loop_status.snap;
    let n = s.inputs.n;
    let fault = s.fault.map(|(c, r)| json!({"cause": c.name(), "reaction": r.name(), "message": c.to_string()}));
    let outcomes: Vec<Value> = calib
        .outcomes
        .iter()
        .map(|o| {
            json!({
                "run": o.run,
                "kind": match o.kind { OutcomeKind::Initial => "initial", OutcomeKind::Calibration => "calibration" },
                "accepted": o.accepted,
                "reason": o.reason,
                "version": o.version,
                "samples": o.samples,
                "heldout_rms_new_m": finite(o.heldout_rms_new_m),
                "heldout_rms_old_m": finite(o.heldout_rms_old_m),
                "heldout_outliers": o.heldout_outliers,
                "model_consistent": o.estimate.as_ref().and_then(|e| e.model_consistent),
                "data_problems": o.data_problems,
            })
        })
        .collect();
    let reset = s.last_reset.map(|r| match r {
        ResetOutcome::InProgress => json!({"outcome": "in-progress"}),
        ResetOutcome::Done => json!({"outcome": "done"}),
        ResetOutcome::Refused(why) => json!({"outcome": "refused", "message": why.to_string()}),
    });
    let bus = &s.inputs.bus;
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
        "lengths_m": s.inputs.length_m[..n].iter().map(|&v| finite(v)).collect::<Vec<_>>(),
        "tensions_n": s.inputs.tension_n[..n].iter().map(|&v| finite(v)).collect::<Vec<_>>(),
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
            "outcomes": outcomes,
            "excitation": crate::excite::status_json(calib),
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
}

impl Request {
    /// Estop and stop are answered ahead of everything else.
    pub fn is_urgent(self) -> bool {
        matches!(self, Request::Estop | Request::Stop)
    }
}

const VERBS: &str = "status | params | recalibrate | stop | estop | reset | move X Y Z";

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
                if let Some(t) = &self.tracker {
                    let s = t.stats();
                    v["tracker"] = json!({
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
                send(Command::Recalibrate, "recalibrate")
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
                    v if v["ok"] == true => json!({"ok": true, "accepted": "move", "target_m": p}),
                    v => v,
                }
            }
        }
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
