//! The calibrator side's view of a run as MCAP / Foxglove channels ([`taut_config::mcap`]):
//! samples, parameter sets and calibrator progress become JSON frames, encoded once and handed
//! to the MCAP recording and to the live telemetry server.
//!
//! Runs on the calibrator thread (it allocates), as the calibrator's [`RunOutputs`]; the loop
//! only pushes `Copy` samples into the ring.

use std::sync::Arc;
use taut_calibrator::vocab::{CalibrationOutcome, OutcomeKind, RunOutputs};
use taut_config::mcap::{frame_transform, opt, pose_in_frame, scene_update, CablesMsg, McapWriter, Topic};
use taut_config::params::ParamsFile;
use taut_rt::io::{CableCommand, DriveStatus};
use taut_rt::motion::State;
use taut_rt::sample::Sample;
use taut_rt::MAX_CABLES;

/// One encoded message.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Its channel.
    pub topic: Topic,
    /// Log time, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// JSON.
    pub data: Arc<[u8]>,
}

/// Scene updates at most this often (loop time), s: the 3D panel needs no more.
const SCENE_PERIOD_S: f64 = 0.1;

/// Turns the calibrator's inputs into frames. State changes (drives, phase, faults) are sent when
/// they change and with the first sample.
pub struct Encoder {
    n: usize,
    t0_ns: u64,
    platform: Vec<[f64; 3]>,
    anchors: Option<Vec<[f64; 3]>>,
    last_t: f64,
    last_drive: Option<[DriveStatus; MAX_CABLES]>,
    last_phase: Option<(u8, i8, u16)>,
    last_fault: Option<Option<(taut_rt::safety::Cause, taut_rt::safety::Reaction)>>,
    last_scene_t: f64,
    last_pose: [f64; 3],
    last_stage: String,
}

fn drive_name(d: DriveStatus) -> &'static str {
    match d {
        DriveStatus::Unknown => "unknown",
        DriveStatus::Disabled => "disabled",
        DriveStatus::Enabled => "enabled",
        DriveStatus::QuickStop => "quick-stop",
        DriveStatus::Fault => "fault",
    }
}

fn json(v: &impl serde::Serialize) -> Arc<[u8]> {
    serde_json::to_vec(v).expect("JSON of plain data").into()
}

impl Encoder {
    /// An encoder for `n` cables with these platform points; the nominal anchors (if any) are
    /// drawn until a calibrated set replaces them. Log times are the Unix time now plus the
    /// loop time.
    pub fn new(n: usize, platform: Vec<[f64; 3]>, nominal: Option<Vec<[f64; 3]>>) -> Encoder {
        let t0_ns = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
        Encoder {
            n,
            t0_ns,
            platform,
            anchors: nominal,
            last_t: 0.0,
            last_drive: None,
            last_phase: None,
            last_fault: None,
            last_scene_t: f64::NEG_INFINITY,
            last_pose: [f64::NAN; 3],
            last_stage: String::new(),
        }
    }

    fn ns(&self, t: f64) -> u64 {
        self.t0_ns + taut_config::mcap::time_ns(t)
    }

    /// The frames of one loop sample.
    pub fn sample(&mut self, s: &Sample, out: &mut impl FnMut(Frame)) {
        let n = self.n;
        let ns = self.ns(s.t);
        self.last_t = s.t;
        let state = State::from_u8(s.state);
        let cmd_len = |c: &CableCommand| if let CableCommand::Position(x) = c { opt(*x) } else { None };
        let cmd_ten = |c: &CableCommand| if let CableCommand::Tension(x) = c { opt(*x) } else { None };
        let pose_ok = s.pose_m.iter().all(|v| v.is_finite());
        let msg = CablesMsg {
            t: s.t,
            state: state.name().into(),
            phase: i32::from(s.phase),
            run: u32::from(s.run),
            params_version: s.params_version,
            position_m: s.pose_m.map(opt),
            position_age_s: opt(s.pose_age_s),
            orientation_wxyz: None,
            length_m: s.length_m[..n].iter().map(|&v| opt(v)).collect(),
            length_age_s: s.length_age_s[..n].iter().map(|&v| opt(v)).collect(),
            tension_n: s.tension_n[..n].iter().map(|&v| opt(v)).collect(),
            tension_age_s: s.tension_age_s[..n].iter().map(|&v| opt(v)).collect(),
            commanded_length_m: s.cmd[..n].iter().map(cmd_len).collect(),
            commanded_tension_n: s.cmd[..n].iter().map(cmd_ten).collect(),
        };
        out(Frame { topic: Topic::Cables, log_time_ns: ns, data: json(&msg) });
        // The pose when a new one arrived (the tracker is slower than the loop).
        if pose_ok && s.pose_m != self.last_pose {
            self.last_pose = s.pose_m;
            let q = [1.0, 0.0, 0.0, 0.0];
            out(Frame { topic: Topic::Pose, log_time_ns: ns, data: pose_in_frame(ns, s.pose_m, q).into() });
            out(Frame { topic: Topic::Tf, log_time_ns: ns, data: frame_transform(ns, s.pose_m, q).into() });
        }
        if self.last_drive.is_none_or(|d| d[..n] != s.drive[..n]) {
            self.last_drive = Some(s.drive);
            let names: Vec<&str> = s.drive[..n].iter().map(|&d| drive_name(d)).collect();
            out(Frame { topic: Topic::Drives, log_time_ns: ns, data: json(&serde_json::json!({"t": s.t, "state": names})) });
        }
        let ph = (s.state, s.phase, s.run);
        if self.last_phase != Some(ph) {
            self.last_phase = Some(ph);
            let m = serde_json::json!({"t": s.t, "state": state.name(), "phase": s.phase, "run": s.run});
            out(Frame { topic: Topic::Phase, log_time_ns: ns, data: json(&m) });
        }
        if self.last_fault != Some(s.fault) {
            self.last_fault = Some(s.fault);
            let m = match s.fault {
                Some((cause, r)) => {
                    serde_json::json!({"t": s.t, "cause": cause.name(), "reaction": r.name(), "message": cause.to_string()})
                }
                None => serde_json::json!({"t": s.t, "cause": "none", "reaction": "none", "message": "no fault latched"}),
            };
            out(Frame { topic: Topic::Faults, log_time_ns: ns, data: json(&m) });
        }
        if s.t - self.last_scene_t >= SCENE_PERIOD_S {
            if let Some(a) = &self.anchors {
                self.last_scene_t = s.t;
                let ends: Vec<Option<[f64; 3]>> =
                    self.platform.iter().map(|b| pose_ok.then(|| [s.pose_m[0] + b[0], s.pose_m[1] + b[1], s.pose_m[2] + b[2]])).collect();
                out(Frame { topic: Topic::Scene, log_time_ns: ns, data: scene_update(ns, a, &ends).into() });
            }
        }
    }

    /// A parameter set published to the loop (hot-swap): `/params`, and the scene draws it next.
    pub fn params(&mut self, p: &ParamsFile, out: &mut impl FnMut(Frame)) {
        let ns = self.ns(self.last_t);
        let m = serde_json::json!({
            "t": self.last_t, "version": p.version, "source": p.source,
            "anchors_m": p.anchors_m, "anchor_sigma_m": p.anchor_sigma_m.iter().map(|a| a.map(opt)).collect::<Vec<_>>(),
            "l0_m": p.l0_m, "l0_sigma_m": p.l0_sigma_m.iter().map(|&v| opt(v)).collect::<Vec<_>>(),
            "rms_m": opt(p.rms_m), "heldout_rms_m": opt(p.heldout_rms_m),
        });
        out(Frame { topic: Topic::Params, log_time_ns: ns, data: json(&m) });
        self.anchors = Some(p.anchors_m.clone());
        self.last_scene_t = f64::NEG_INFINITY;
    }

    /// The calibrator's stage (sent when it changes) or a new outcome (always sent).
    pub fn calibrator(&mut self, stage: &str, samples_recorded: u64, outcome: Option<&CalibrationOutcome>, out: &mut impl FnMut(Frame)) {
        if outcome.is_none() && stage == self.last_stage {
            return;
        }
        self.last_stage = stage.into();
        let o = outcome.map(|o| {
            serde_json::json!({
                "run": o.run,
                "kind": match o.kind { OutcomeKind::Initial => "initial", OutcomeKind::Calibration => "calibration" },
                "accepted": o.accepted, "reason": o.reason, "version": o.version,
            })
        });
        let m = serde_json::json!({"t": self.last_t, "stage": stage, "samples_recorded": samples_recorded, "outcome": o});
        out(Frame { topic: Topic::Calibrator, log_time_ns: self.ns(self.last_t), data: json(&m) });
    }
}

/// Where the frames go: the MCAP recording and the telemetry server, either optional.
pub struct FrameSinks {
    /// The encoder.
    pub enc: Encoder,
    /// The MCAP recording.
    pub mcap: Option<McapWriter>,
    /// The telemetry server's queue (bounded; a full queue drops the frame for the clients).
    pub live: Option<crossbeam_channel::Sender<Frame>>,
    /// First MCAP write error (the calibrator takes it into its status).
    pub error: Option<std::io::Error>,
    /// Frames the telemetry queue had no room for.
    pub live_dropped: u64,
}

impl FrameSinks {
    fn emit(
        mcap: &mut Option<McapWriter>,
        live: &Option<crossbeam_channel::Sender<Frame>>,
        err: &mut Option<std::io::Error>,
        dropped: &mut u64,
        f: Frame,
    ) {
        if let Some(w) = mcap {
            if let Err(e) = w.write(f.topic, f.log_time_ns, &f.data) {
                err.get_or_insert(e);
            }
        }
        if let Some(tx) = live {
            if tx.try_send(f).is_err() {
                *dropped += 1;
            }
        }
    }

    /// A loop sample.
    pub fn sample(&mut self, s: &Sample) {
        let (m, l, e, d) = (&mut self.mcap, &self.live, &mut self.error, &mut self.live_dropped);
        self.enc.sample(s, &mut |f| Self::emit(m, l, e, d, f));
    }

    /// A published parameter set.
    pub fn params(&mut self, p: &ParamsFile) {
        let (m, l, e, d) = (&mut self.mcap, &self.live, &mut self.error, &mut self.live_dropped);
        self.enc.params(p, &mut |f| Self::emit(m, l, e, d, f));
    }

    /// Calibrator progress.
    pub fn calibrator(&mut self, stage: &str, samples: u64, outcome: Option<&CalibrationOutcome>) {
        let (m, l, e, d) = (&mut self.mcap, &self.live, &mut self.error, &mut self.live_dropped);
        self.enc.calibrator(stage, samples, outcome, &mut |f| Self::emit(m, l, e, d, f));
    }

    /// Closes the MCAP chunk if it is due (call when idle).
    pub fn tick(&mut self) {
        if let Some(w) = &mut self.mcap {
            if let Err(e) = w.tick() {
                self.error.get_or_insert(e);
            }
        }
    }

    /// Finishes the MCAP file (summary and footer).
    pub fn finish(&mut self) {
        if let Some(w) = self.mcap.take() {
            if let Err(e) = w.finish() {
                self.error.get_or_insert(e);
            }
        }
    }
}

impl RunOutputs for FrameSinks {
    fn sample(&mut self, s: &Sample) {
        FrameSinks::sample(self, s);
    }
    fn params(&mut self, p: &ParamsFile) {
        FrameSinks::params(self, p);
    }
    fn calibrator(&mut self, stage: &str, samples: u64, outcome: Option<&CalibrationOutcome>) {
        FrameSinks::calibrator(self, stage, samples, outcome);
    }
    fn tick(&mut self) {
        FrameSinks::tick(self);
    }
    fn take_error(&mut self) -> Option<std::io::Error> {
        self.error.take()
    }
    fn finish(&mut self) {
        FrameSinks::finish(self);
    }
}

/// The MCAP recording at `mcap` and the telemetry server of `cfg.telemetry`, each if asked for
/// (None when neither is). Errors name the file or the configuration key.
pub fn open_frame_sinks(
    c: &taut_calibrator::vocab::CalibratorConfig,
    cfg: &taut_config::RobotConfig,
    mcap: Option<&std::path::Path>,
) -> Result<(Option<FrameSinks>, Option<crate::telemetry::TelemetryServer>), FrameSinksError> {
    let writer = match mcap {
        Some(p) => {
            let meta = taut_config::mcap::RecordingMeta {
                robot: c.robot.clone(),
                n_cables: c.n,
                tracker_max_age_s: c.tracker_max_age_s,
                tension_max_age_s: c.tension_max_age_s,
                source: "taut start".into(),
                comments: vec![format!(" robot: {}; written by taut start", c.robot)],
            };
            Some(McapWriter::create(p, &meta).map_err(|source| FrameSinksError::Mcap { path: p.to_path_buf(), source })?)
        }
        None => None,
    };
    let (server, live) = if cfg.telemetry.enabled {
        let addr = cfg.telemetry.addr().ok_or_else(|| FrameSinksError::TelemetryBind { bind: cfg.telemetry.bind.clone() })?;
        let (server, tx) =
            crate::telemetry::bind(addr, cfg.telemetry.max_clients).map_err(|source| FrameSinksError::Telemetry { addr, source })?;
        (Some(server), Some(tx))
    } else {
        (None, None)
    };
    if writer.is_none() && live.is_none() {
        return Ok((None, server));
    }
    let enc = Encoder::new(c.n, c.platform.clone(), c.nominal.clone());
    Ok((Some(FrameSinks { enc, mcap: writer, live, error: None, live_dropped: 0 }), server))
}

/// Why the MCAP recording or the telemetry server could not be opened. Each names the file or
/// the configuration key.
#[derive(Debug)]
pub enum FrameSinksError {
    /// The MCAP recording could not be created (`daemon.data_dir`).
    Mcap {
        /// The file.
        path: std::path::PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// `telemetry.bind` is not an IP address.
    TelemetryBind {
        /// Its value.
        bind: String,
    },
    /// The telemetry server could not listen (`telemetry.bind`, `telemetry.port`).
    Telemetry {
        /// The address.
        addr: std::net::SocketAddr,
        /// The error.
        source: std::io::Error,
    },
}

impl std::fmt::Display for FrameSinksError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameSinksError::Mcap { path, source } => {
                write!(f, "cannot create the MCAP recording {}: {source} (daemon.data_dir)", path.display())
            }
            FrameSinksError::TelemetryBind { bind } => {
                write!(f, "telemetry.bind {bind:?} is not an IP address; give e.g. \"127.0.0.1\" (this machine only)")
            }
            FrameSinksError::Telemetry { addr, source } => {
                write!(f, "cannot serve telemetry on {addr}: {source} (telemetry.bind, telemetry.port)")
            }
        }
    }
}

impl std::error::Error for FrameSinksError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            FrameSinksError::Mcap { source, .. } | FrameSinksError::Telemetry { source, .. } => Some(source),
            FrameSinksError::TelemetryBind { .. } => None,
        }
    }
}
