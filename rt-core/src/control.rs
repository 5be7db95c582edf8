//! Operator control over a Unix domain socket: one request line in, one JSON line out.
//!
//! ```text
//! request         reply
//! status          {"ok":true,"state":"operate","phase":-1,"fault":null,"calibration":{...},...}
//! params          {"ok":true,"params":{"version":3,"anchors_m":[[..]],...}}
//! recalibrate     {"ok":true,"accepted":"recalibrate"}   (progress: see status)
//! stop | estop | reset
//! move X Y Z      {"ok":true,...}
//! ```
//!
//! The socket is created with mode 0660, so the operator group may use it; the loop sees only
//! [`Command`]s from a bounded channel.

use crate::calibrator::{OutcomeKind, SharedCalibStatus};
use crate::motion::Command;
use crate::runner::LoopStatus;
use crate::triple::Reader;
use crossbeam_channel::Sender;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

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
                "data_problems": o.data_problems,
            })
        })
        .collect();
    json!({
        "ok": true,
        "t_s": s.t,
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
            "recorder_error": calib.recorder_error,
            "outcomes": outcomes,
        },
    })
}

/// The control server; runs on its own thread.
pub struct ControlServer {
    listener: UnixListener,
    path: PathBuf,
    commands: Sender<Command>,
    loop_status: SharedLoopStatus,
    calib: SharedCalibStatus,
}

impl ControlServer {
    /// Binds the socket at `path` (replacing a stale one) with mode 0660.
    pub fn bind(path: &Path, commands: Sender<Command>, loop_status: SharedLoopStatus, calib: SharedCalibStatus) -> std::io::Result<ControlServer> {
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)?;
        }
        if path.exists() {
            // A socket nobody answers on is left over from a crash; a live one means a second daemon.
            if UnixStream::connect(path).is_ok() {
                return Err(std::io::Error::new(std::io::ErrorKind::AddrInUse, format!("{} is in use: is taut start already running?", path.display())));
            }
            std::fs::remove_file(path)?;
        }
        let listener = UnixListener::bind(path)?;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
        listener.set_nonblocking(true)?;
        Ok(ControlServer { listener, path: path.to_path_buf(), commands, loop_status, calib })
    }

    /// Serves until `quit`; removes the socket file at the end.
    pub fn run(self, quit: Arc<AtomicBool>) {
        // Relaxed: only ends the polling; no data is handed over with it.
        while !quit.load(Ordering::Relaxed) {
            match self.listener.accept() {
                Ok((stream, _)) => {
                    let _ = self.serve(stream);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(10)),
                Err(_) => std::thread::sleep(Duration::from_millis(10)),
            }
        }
        let _ = std::fs::remove_file(&self.path);
    }

    fn serve(&self, stream: UnixStream) -> std::io::Result<()> {
        stream.set_nonblocking(false)?;
        stream.set_read_timeout(Some(Duration::from_secs(2)))?;
        let mut reader = BufReader::new(stream.try_clone()?);
        let mut line = String::new();
        reader.read_line(&mut line)?;
        let reply = self.handle(line.trim());
        let mut w = stream;
        writeln!(w, "{reply}")?;
        w.flush()
    }

    /// Handles one request line.
    pub fn handle(&self, req: &str) -> Value {
        let words: Vec<&str> = req.split_whitespace().collect();
        let send = |c: Command, what: &str| match self.commands.try_send(c) {
            Ok(()) => json!({"ok": true, "accepted": what}),
            Err(_) => json!({"ok": false, "error": "the loop's command queue is full or closed; try again"}),
        };
        match words.as_slice() {
            ["status"] => {
                let ls = *self.loop_status.lock().unwrap().read();
                let cs = self.calib.lock().unwrap().clone();
                status_json(&ls, &cs)
            }
            ["params"] => {
                let cs = self.calib.lock().unwrap();
                match &cs.current {
                    Some(p) => json!({"ok": true, "params": {
                        "version": p.version, "created_unix_s": p.created_unix_s, "source": p.source,
                        "anchors_m": p.anchors_m, "l0_m": p.l0_m, "anchor_sigma_m": p.anchor_sigma_m,
                        "l0_sigma_m": p.l0_sigma_m, "rms_m": finite(p.rms_m), "heldout_rms_m": finite(p.heldout_rms_m)}}),
                    None => json!({"ok": true, "params": null}),
                }
            }
            ["recalibrate"] => {
                let ls = *self.loop_status.lock().unwrap().read();
                use crate::motion::State;
                if !matches!(ls.snap.state, State::Operate | State::Holding) || ls.snap.fault.is_some() {
                    return json!({"ok": false, "error": format!("recalibrate needs the robot operating without a fault; it is {}", ls.snap.state.name())});
                }
                send(Command::Recalibrate, "recalibrate")
            }
            ["stop"] => send(Command::Stop, "stop"),
            ["estop"] => send(Command::Estop, "estop"),
            ["reset"] => send(Command::Reset, "reset"),
            ["move", x, y, z] => match (x.parse::<f64>(), y.parse::<f64>(), z.parse::<f64>()) {
                (Ok(x), Ok(y), Ok(z)) => send(Command::MoveTo([x, y, z]), "move"),
                _ => json!({"ok": false, "error": "move needs three numbers: move X Y Z (m)"}),
            },
            _ => json!({"ok": false, "error": format!("unknown request {req:?}: status | params | recalibrate | stop | estop | reset | move X Y Z")}),
        }
    }
}

/// Sends one request and returns the reply (client side of `taut ctl`).
pub fn request(path: &Path, req: &str, timeout: Duration) -> std::io::Result<Value> {
    let mut s = UnixStream::connect(path)?;
    s.set_read_timeout(Some(timeout))?;
    writeln!(s, "{req}")?;
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line)?;
    serde_json::from_str(&line).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}
