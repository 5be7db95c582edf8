//! MCAP recordings: the channels taut writes, their JSON schemas, a crash-tolerant writer and the
//! reader that turns a taut MCAP file back into a [`Recording`].
//!
//! MCAP (<https://mcap.dev>) is what Foxglove, PlotJuggler and rosbag2 open. Every channel is JSON
//! with a JSON schema, so Foxglove shows it without set-up; the pose, transform and scene use
//! Foxglove's well-known schemas so the 3D panel draws the robot.
//!
//! | topic          | schema                  | when                         | content                                     |
//! |----------------|-------------------------|------------------------------|---------------------------------------------|
//! | `/cables`      | `taut.Cables`           | every loop sample            | lengths, tensions, their ages, commands, pose |
//! | `/drives`      | `taut.Drives`           | first sample and on change   | CiA 402 drive state per cable               |
//! | `/pose`        | `foxglove.PoseInFrame`  | every sample with a pose     | tracker pose in frame `world`               |
//! | `/tf`          | `foxglove.FrameTransform` | with `/pose`               | `world` -> `platform`                       |
//! | `/phase`       | `taut.Phase`            | first sample and on change   | motion state, initialisation phase, run     |
//! | `/params`      | `taut.Params`           | each published parameter set | version, anchors, offsets, sigmas, RMS      |
//! | `/calibrator`  | `taut.CalibratorStatus` | on change                    | stage, each outcome with its reason         |
//! | `/faults`      | `taut.Fault`            | when a safety reaction latches | cause, reaction, message                  |
//! | `/scene`       | `foxglove.SceneUpdate`  | 10 Hz                        | anchors and cables as lines                 |
//!
//! Values that are missing (no reading, NaN) are JSON `null`; ages of values never seen are `null`.
//! A metadata record `taut` holds the cable count and the age limits the recorder applied, so
//! [`load`] gives the same [`Recording`] as the CSV of the same run.
//!
//! Power loss: the writer closes a chunk and syncs the file at least every
//! [`FLUSH_INTERVAL`], so an interrupted file keeps every closed chunk (readers that stream,
//! such as `mcap.stream_reader` in Python or `mcap recover`, read them).

use crate::recording::{ErrorKind, ParseReport, Recording, RecordingError, MAX_FILE_BYTES, MAX_RECORDING_CABLES, MAX_TIME_S};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::{Read, Seek, Write};
use std::path::Path;
use std::time::{Duration, Instant};

/// The first bytes of every MCAP file.
pub const MAGIC: &[u8; 8] = crate::recording::MCAP_MAGIC;

/// Longest time between two closed chunks.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(500);

/// Name of the metadata record with the recording's constants.
pub const METADATA_NAME: &str = "taut";

/// Value of `format` in that record.
pub const FORMAT: &str = "taut-mcap v1";

/// The channels, in [`Topic`] order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Topic {
    /// `/cables`
    Cables = 0,
    /// `/drives`
    Drives,
    /// `/pose`
    Pose,
    /// `/tf`
    Tf,
    /// `/phase`
    Phase,
    /// `/params`
    Params,
    /// `/calibrator`
    Calibrator,
    /// `/faults`
    Faults,
    /// `/scene`
    Scene,
}

/// One channel: topic, schema name and JSON schema.
#[derive(Debug, Clone, Copy)]
pub struct ChannelDef {
    /// Topic.
    pub topic: &'static str,
    /// Schema name.
    pub schema_name: &'static str,
    /// JSON schema.
    pub schema: &'static str,
}

/// Every channel, indexed by `Topic as usize`.
pub const CHANNELS: [ChannelDef; 9] = [
    ChannelDef { topic: "/cables", schema_name: "taut.Cables", schema: SCHEMA_CABLES },
    ChannelDef { topic: "/drives", schema_name: "taut.Drives", schema: SCHEMA_DRIVES },
    ChannelDef { topic: "/pose", schema_name: "foxglove.PoseInFrame", schema: SCHEMA_POSE_IN_FRAME },
    ChannelDef { topic: "/tf", schema_name: "foxglove.FrameTransform", schema: SCHEMA_FRAME_TRANSFORM },
    ChannelDef { topic: "/phase", schema_name: "taut.Phase", schema: SCHEMA_PHASE },
    ChannelDef { topic: "/params", schema_name: "taut.Params", schema: SCHEMA_PARAMS },
    ChannelDef { topic: "/calibrator", schema_name: "taut.CalibratorStatus", schema: SCHEMA_CALIBRATOR },
    ChannelDef { topic: "/faults", schema_name: "taut.Fault", schema: SCHEMA_FAULT },
    ChannelDef { topic: "/scene", schema_name: "foxglove.SceneUpdate", schema: SCHEMA_SCENE_UPDATE },
];

impl Topic {
    /// Every topic in order.
    pub const ALL: [Topic; 9] =
        [Topic::Cables, Topic::Drives, Topic::Pose, Topic::Tf, Topic::Phase, Topic::Params, Topic::Calibrator, Topic::Faults, Topic::Scene];

    /// Its channel definition.
    pub fn def(self) -> &'static ChannelDef {
        &CHANNELS[self as usize]
    }
}

macro_rules! num_array {
    () => {
        r#"{"type":"array","items":{"type":["number","null"]}}"#
    };
}

const SCHEMA_CABLES: &str = concat!(
    r#"{"title":"taut.Cables","description":"One loop sample: per-cable readings with their ages, commands and the tracker pose. null: no value.","type":"object","properties":{"#,
    r#""t":{"type":"number","description":"loop time, s"},"#,
    r#""state":{"type":"string","description":"motion state of the loop"},"#,
    r#""phase":{"type":"integer","description":"initialisation phase, -1 outside"},"#,
    r#""run":{"type":"integer","description":"calibration run, 0 = start-up"},"#,
    r#""params_version":{"type":"integer"},"#,
    r#""position_m":"#,
    num_array!(),
    r#","position_age_s":{"type":["number","null"]},"#,
    r#""orientation_wxyz":"#,
    num_array!(),
    r#","length_m":"#,
    num_array!(),
    r#","length_age_s":"#,
    num_array!(),
    r#","tension_n":"#,
    num_array!(),
    r#","tension_age_s":"#,
    num_array!(),
    r#","commanded_length_m":"#,
    num_array!(),
    r#","commanded_tension_n":"#,
    num_array!(),
    r#"},"required":["t","state","phase","length_m","tension_n"]}"#
);

const SCHEMA_DRIVES: &str = r#"{"title":"taut.Drives","type":"object","properties":{"t":{"type":"number"},"state":{"type":"array","items":{"type":"string","enum":["unknown","disabled","enabled","quick-stop","fault"]},"description":"CiA 402 state per cable"}}}"#;

const SCHEMA_PHASE: &str = r#"{"title":"taut.Phase","type":"object","properties":{"t":{"type":"number"},"state":{"type":"string"},"phase":{"type":"integer"},"run":{"type":"integer"}}}"#;

const SCHEMA_PARAMS: &str = concat!(
    r#"{"title":"taut.Params","description":"A parameter set published to the loop (hot-swap)","type":"object","properties":{"#,
    r#""t":{"type":"number"},"version":{"type":"integer"},"source":{"type":"string"},"#,
    r#""anchors_m":{"type":"array","items":{"type":"array","items":{"type":"number"}}},"#,
    r#""anchor_sigma_m":{"type":"array","items":{"type":"array","items":{"type":["number","null"]}}},"#,
    r#""l0_m":{"type":"array","items":{"type":"number"}},"#,
    r#""l0_sigma_m":{"type":"array","items":{"type":["number","null"]}},"#,
    r#""rms_m":{"type":["number","null"]},"heldout_rms_m":{"type":["number","null"]}}}"#
);

const SCHEMA_CALIBRATOR: &str = concat!(
    r#"{"title":"taut.CalibratorStatus","type":"object","properties":{"t":{"type":"number"},"stage":{"type":"string"},"#,
    r#""samples_recorded":{"type":"integer"},"outcome":{"type":["object","null"],"properties":{"#,
    r#""run":{"type":"integer"},"kind":{"type":"string"},"accepted":{"type":"boolean"},"reason":{"type":"string"},"version":{"type":"integer"}}}}}"#
);

const SCHEMA_FAULT: &str = r#"{"title":"taut.Fault","type":"object","properties":{"t":{"type":"number"},"cause":{"type":"string"},"reaction":{"type":"string"},"message":{"type":"string"}}}"#;

macro_rules! vec3 {
    () => {
        r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}}"#
    };
}
macro_rules! quat {
    () => {
        r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}"#
    };
}
macro_rules! time {
    () => {
        r#"{"type":"object","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}}}"#
    };
}

const SCHEMA_POSE_IN_FRAME: &str = concat!(
    r#"{"title":"foxglove.PoseInFrame","description":"A timestamped pose for an object or reference frame in 3D space","type":"object","properties":{"#,
    r#""timestamp":"#,
    time!(),
    r#","frame_id":{"type":"string"},"pose":{"type":"object","properties":{"position":"#,
    vec3!(),
    r#","orientation":"#,
    quat!(),
    r#"}}}}"#
);

const SCHEMA_FRAME_TRANSFORM: &str = concat!(
    r#"{"title":"foxglove.FrameTransform","description":"A transform between two reference frames in 3D space","type":"object","properties":{"#,
    r#""timestamp":"#,
    time!(),
    r#","parent_frame_id":{"type":"string"},"child_frame_id":{"type":"string"},"translation":"#,
    vec3!(),
    r#","rotation":"#,
    quat!(),
    r#"}}"#
);

const SCHEMA_SCENE_UPDATE: &str = concat!(
    r#"{"title":"foxglove.SceneUpdate","description":"An update to the entities displayed in a 3D scene","type":"object","properties":{"#,
    r#""deletions":{"type":"array","items":{"type":"object"}},"entities":{"type":"array","items":{"type":"object","properties":{"#,
    r#""timestamp":"#,
    time!(),
    r#","frame_id":{"type":"string"},"id":{"type":"string"},"lifetime":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"#,
    r#""frame_locked":{"type":"boolean"},"metadata":{"type":"array"},"arrows":{"type":"array"},"cubes":{"type":"array"},"#,
    r#""spheres":{"type":"array","items":{"type":"object","properties":{"pose":{"type":"object"},"size":"#,
    vec3!(),
    r#","color":{"type":"object"}}}},"cylinders":{"type":"array"},"#,
    r#""lines":{"type":"array","items":{"type":"object","properties":{"type":{"type":"integer","enum":[0,1,2],"description":"0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},"#,
    r#""pose":{"type":"object"},"thickness":{"type":"number"},"scale_invariant":{"type":"boolean"},"points":{"type":"array","items":"#,
    vec3!(),
    r#"},"color":{"type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type":"number"}}},"#,
    r#""colors":{"type":"array"},"indices":{"type":"array"}}}},"triangles":{"type":"array"},"texts":{"type":"array"},"models":{"type":"array"}}}}}}"#
);

/// A value or JSON `null` (non-finite).
pub fn opt(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// One loop sample on `/cables`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CablesMsg {
    /// Loop time (or the recording's time), s.
    pub t: f64,
    /// Motion state name (`""` when unknown, e.g. exported from CSV).
    #[serde(default)]
    pub state: String,
    /// Initialisation phase, -1 outside.
    pub phase: i32,
    /// Calibration run.
    #[serde(default)]
    pub run: u32,
    /// Parameter version in use.
    #[serde(default)]
    pub params_version: u64,
    /// Tracker position, m.
    pub position_m: [Option<f64>; 3],
    /// Its age, s (`null`: never seen).
    pub position_age_s: Option<f64>,
    /// Platform orientation (w, x, y, z), when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation_wxyz: Option<[Option<f64>; 4]>,
    /// Encoder lengths, m.
    pub length_m: Vec<Option<f64>>,
    /// Their ages, s.
    pub length_age_s: Vec<Option<f64>>,
    /// Tensions, N.
    pub tension_n: Vec<Option<f64>>,
    /// Their ages, s.
    pub tension_age_s: Vec<Option<f64>>,
    /// Commanded length per cable (position mode), m.
    #[serde(default)]
    pub commanded_length_m: Vec<Option<f64>>,
    /// Commanded tension per cable (torque mode), N.
    #[serde(default)]
    pub commanded_tension_n: Vec<Option<f64>>,
}

/// Foxglove `Time`.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FoxTime {
    /// Seconds.
    pub sec: u64,
    /// Nanoseconds.
    pub nsec: u32,
}

impl FoxTime {
    /// From nanoseconds.
    pub fn from_ns(ns: u64) -> FoxTime {
        FoxTime { sec: ns / 1_000_000_000, nsec: (ns % 1_000_000_000) as u32 }
    }
}

fn xyz(p: [f64; 3]) -> serde_json::Value {
    serde_json::json!({"x": p[0], "y": p[1], "z": p[2]})
}

fn quat_xyzw(q: [f64; 4]) -> serde_json::Value {
    serde_json::json!({"x": q[1], "y": q[2], "z": q[3], "w": q[0]})
}

/// `foxglove.PoseInFrame` of the platform in frame `world` (`q` as w, x, y, z).
pub fn pose_in_frame(ns: u64, p: [f64; 3], q: [f64; 4]) -> Vec<u8> {
    let v = serde_json::json!({"timestamp": FoxTime::from_ns(ns), "frame_id": "world",
        "pose": {"position": xyz(p), "orientation": quat_xyzw(q)}});
    serde_json::to_vec(&v).expect("JSON of numbers")
}

/// `foxglove.FrameTransform` `world` -> `platform`.
pub fn frame_transform(ns: u64, p: [f64; 3], q: [f64; 4]) -> Vec<u8> {
    let v = serde_json::json!({"timestamp": FoxTime::from_ns(ns), "parent_frame_id": "world", "child_frame_id": "platform",
        "translation": xyz(p), "rotation": quat_xyzw(q)});
    serde_json::to_vec(&v).expect("JSON of numbers")
}

/// `foxglove.SceneUpdate` with the anchors as spheres and each cable as a line from its anchor
/// to its platform point (`ends`, in the world frame; a cable without one is not drawn).
pub fn scene_update(ns: u64, anchors: &[[f64; 3]], ends: &[Option<[f64; 3]>]) -> Vec<u8> {
    let ts = FoxTime::from_ns(ns);
    let ident = serde_json::json!({"position": xyz([0.0; 3]), "orientation": quat_xyzw([1.0, 0.0, 0.0, 0.0])});
    let mut points = Vec::new();
    for (a, e) in anchors.iter().zip(ends) {
        if let Some(e) = e {
            points.push(xyz(*a));
            points.push(xyz(*e));
        }
    }
    let spheres: Vec<_> = anchors
        .iter()
        .map(|a| {
            serde_json::json!({"pose": {"position": xyz(*a), "orientation": quat_xyzw([1.0, 0.0, 0.0, 0.0])},
                "size": xyz([0.08; 3]), "color": {"r": 0.85, "g": 0.4, "b": 0.0, "a": 1.0}})
        })
        .collect();
    let v = serde_json::json!({"deletions": [], "entities": [{
        "timestamp": ts, "frame_id": "world", "id": "robot", "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": false,
        "metadata": [], "arrows": [], "cubes": [], "cylinders": [], "triangles": [], "texts": [], "models": [],
        "spheres": spheres,
        "lines": [{"type": 2, "pose": ident, "thickness": 0.01, "scale_invariant": false, "points": points,
            "color": {"r": 0.1, "g": 0.3, "b": 0.8, "a": 1.0}, "colors": [], "indices": []}]
    }]});
    serde_json::to_vec(&v).expect("JSON of numbers")
}

/// The constants a reader needs, written as the `taut` metadata record.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingMeta {
    /// Robot name.
    pub robot: String,
    /// Number of cables.
    pub n_cables: usize,
    /// Poses older than this were not used, s.
    pub tracker_max_age_s: f64,
    /// Tensions older than this were not used, s.
    pub tension_max_age_s: f64,
    /// Who wrote the file (`taut start`, `taut export FILE`).
    pub source: String,
    /// Comment lines of the source recording.
    pub comments: Vec<String>,
}

impl RecordingMeta {
    fn to_map(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("format".into(), FORMAT.into());
        m.insert("robot".into(), self.robot.clone());
        m.insert("n_cables".into(), self.n_cables.to_string());
        m.insert("tracker_max_age_s".into(), format!("{:e}", self.tracker_max_age_s));
        m.insert("tension_max_age_s".into(), format!("{:e}", self.tension_max_age_s));
        m.insert("source".into(), self.source.clone());
        m.insert("comments".into(), self.comments.join("\n"));
        m
    }
}

/// A file whose `flush` also syncs it to the disk: the MCAP writer's `flush` closes a chunk, then
/// this makes it durable.
struct SyncFile(std::io::BufWriter<std::fs::File>);

impl Write for SyncFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush()?;
        self.0.get_ref().sync_data()
    }
}

impl Seek for SyncFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.0.seek(pos)
    }
}

fn io_err(e: mcap::McapError) -> std::io::Error {
    match e {
        mcap::McapError::Io(e) => e,
        e => std::io::Error::other(e.to_string()),
    }
}

/// Writes a taut MCAP file message by message; closes a chunk and syncs at least every
/// [`FLUSH_INTERVAL`] (call [`McapWriter::tick`] when idle), writes the summary on
/// [`McapWriter::finish`].
pub struct McapWriter {
    w: mcap::Writer<SyncFile>,
    ids: [u16; 9],
    seq: [u32; 9],
    last_flush: Instant,
    /// Messages written per topic.
    pub counts: [u64; 9],
}

impl McapWriter {
    /// Creates `path` (and its directory) and writes the header, the `taut` metadata, the
    /// schemas and the channels.
    pub fn create(path: &Path, meta: &RecordingMeta) -> std::io::Result<McapWriter> {
        if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d)?;
        }
        McapWriter::new(std::fs::File::create(path)?, meta)
    }

    /// Writes the header, metadata, schemas and channels into `file`.
    pub fn new(file: std::fs::File, meta: &RecordingMeta) -> std::io::Result<McapWriter> {
        let file = SyncFile(std::io::BufWriter::with_capacity(1 << 16, file));
        let opts = mcap::WriteOptions::new().compression(None).profile("").library(concat!("taut ", env!("CARGO_PKG_VERSION")));
        let mut w = opts.create(file).map_err(io_err)?;
        w.write_metadata(&mcap::records::Metadata { name: METADATA_NAME.into(), metadata: meta.to_map() }).map_err(io_err)?;
        let mut ids = [0u16; 9];
        for (id, def) in ids.iter_mut().zip(&CHANNELS) {
            let schema = w.add_schema(def.schema_name, "jsonschema", def.schema.as_bytes()).map_err(io_err)?;
            *id = w.add_channel(schema, def.topic, "json", &BTreeMap::new()).map_err(io_err)?;
        }
        w.flush().map_err(io_err)?;
        Ok(McapWriter { w, ids, seq: [0; 9], last_flush: Instant::now(), counts: [0; 9] })
    }

    /// Writes one message (JSON) at `log_time_ns`.
    pub fn write(&mut self, topic: Topic, log_time_ns: u64, json: &[u8]) -> std::io::Result<()> {
        let k = topic as usize;
        let header = mcap::records::MessageHeader {
            channel_id: self.ids[k],
            sequence: self.seq[k],
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        self.seq[k] = self.seq[k].wrapping_add(1);
        self.w.write_to_known_channel(&header, json).map_err(io_err)?;
        self.counts[k] += 1;
        self.tick()
    }

    /// Closes the chunk and syncs if [`FLUSH_INTERVAL`] has passed.
    pub fn tick(&mut self) -> std::io::Result<()> {
        if self.last_flush.elapsed() >= FLUSH_INTERVAL {
            self.flush()?;
        }
        Ok(())
    }

    /// Closes the chunk and syncs the file now.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.last_flush = Instant::now();
        self.w.flush().map_err(io_err)
    }

    /// Writes the summary and the footer, and syncs. (A writer dropped without this, on an
    /// error path, is finished by the `mcap` crate's own `Drop`, without the sync.)
    pub fn finish(mut self) -> std::io::Result<()> {
        self.w.finish().map_err(io_err)?;
        self.w.into_inner().flush()
    }
}

/// True if the file starts with the MCAP magic. Reads 8 bytes.
pub fn is_mcap_bytes(head: &[u8]) -> bool {
    head.starts_with(MAGIC)
}

/// Writes `rec` as a taut MCAP file at `path`, atomically (temporary file, then rename):
/// `/cables`, `/pose` and `/tf` per sample and `/phase` on change. The readings' ages are not in
/// a CSV: present values get age 0.
pub fn export(rec: &Recording, path: &Path, source: &str) -> std::io::Result<()> {
    let n = rec.n_cables;
    let meta = RecordingMeta {
        robot: rec
            .comments
            .iter()
            .find_map(|c| c.trim().strip_prefix("robot:").map(|r| r.split(';').next().unwrap_or("").trim().to_string()))
            .unwrap_or_default(),
        n_cables: n,
        tracker_max_age_s: 0.0,
        tension_max_age_s: 0.0,
        source: source.into(),
        comments: rec.comments.clone(),
    };
    crate::atomic::write_atomic_with(path, |f| {
        let mut w = McapWriter::new(f.try_clone()?, &meta)?;
        let mut last_phase = None;
        for i in 0..rec.len() {
            let ns = time_ns(rec.t[i]);
            let p = rec.p[i];
            let q = rec.q.as_ref().map(|q| q[i]);
            let phase = rec.phase.as_ref().map_or(-1, |ph| ph[i]);
            let age = |v: f64| v.is_finite().then_some(0.0);
            let l = rec.lengths(i);
            let f = rec.tensions(i);
            let msg = CablesMsg {
                t: rec.t[i],
                state: String::new(),
                phase,
                run: 0,
                params_version: 0,
                position_m: p.map(opt),
                position_age_s: p.iter().all(|v| v.is_finite()).then_some(0.0),
                orientation_wxyz: q.map(|q| q.map(opt)),
                length_m: l.iter().map(|&v| opt(v)).collect(),
                length_age_s: l.iter().map(|&v| age(v)).collect(),
                tension_n: f.map_or_else(|| vec![None; n], |f| f.iter().map(|&v| opt(v)).collect()),
                tension_age_s: f.map_or_else(|| vec![None; n], |f| f.iter().map(|&v| age(v)).collect()),
                commanded_length_m: vec![],
                commanded_tension_n: vec![],
            };
            w.write(Topic::Cables, ns, &serde_json::to_vec(&msg).map_err(std::io::Error::other)?)?;
            if p.iter().all(|v| v.is_finite()) {
                let q = q.filter(|q| q.iter().all(|v| v.is_finite())).unwrap_or([1.0, 0.0, 0.0, 0.0]);
                w.write(Topic::Pose, ns, &pose_in_frame(ns, p, q))?;
                w.write(Topic::Tf, ns, &frame_transform(ns, p, q))?;
            }
            if last_phase != Some(phase) {
                last_phase = Some(phase);
                let m = serde_json::json!({"t": rec.t[i], "state": "", "phase": phase, "run": 0});
                w.write(Topic::Phase, ns, &serde_json::to_vec(&m).map_err(std::io::Error::other)?)?;
            }
        }
        w.finish()
    })
}

/// A recording time as MCAP log time, ns (negative or non-finite times as 0).
pub fn time_ns(t: f64) -> u64 {
    if t.is_finite() && t > 0.0 {
        (t * 1e9).round() as u64
    } else {
        0
    }
}

/// Reads a taut MCAP file (written by `taut start` or `taut export`) as a recording: the `/cables`
/// channel and the `taut` metadata. Errors name the file and what is wrong.
pub fn load(path: &Path) -> Result<(Recording, ParseReport), RecordingError> {
    let f = crate::input::open(path).map_err(|e| RecordingError {
        file: Some(path.display().to_string()),
        line: 0,
        column: None,
        kind: ErrorKind::Io(e),
    })?;
    read_from(path, f)
}

/// [`load`] from an open reader (`path` names it in errors).
pub fn read_from(path: &Path, mut r: impl Read) -> Result<(Recording, ParseReport), RecordingError> {
    let err = |m: String| RecordingError { file: Some(path.display().to_string()), line: 0, column: None, kind: ErrorKind::Mcap(m) };
    let mut buf = Vec::new();
    (&mut r).take(MAX_FILE_BYTES + 1).read_to_end(&mut buf).map_err(|e| err(format!("cannot read: {e}")))?;
    if buf.len() as u64 > MAX_FILE_BYTES {
        return Err(err(format!("larger than the {} GiB a recording may have; split it into runs", MAX_FILE_BYTES >> 30)));
    }
    parse(&buf).map_err(err)
}

/// A reading error, for a person.
fn read_error(e: mcap::McapError) -> String {
    match e {
        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => format!(
            "the file ends in the middle of a record ({e}): the writer was stopped before it finished the file \
             (power loss, kill). `mcap recover` (the MCAP command-line tool) writes a readable copy of every complete chunk"
        ),
        e => format!("damaged MCAP file: {e}"),
    }
}

/// The records of a file, in order, those of every chunk in the chunk's place: `(opcode, body)`
/// up to the data end (or the footer; `true` when there is one: a file whose writer was stopped
/// between two records has none), every length checked against what holds it, every
/// chunk's CRC checked. Only the records taut reads are then parsed by the `mcap` crate: its
/// readers (0.24 to 0.26) panic on some hostile files (a record length near 2^64, a chunk's
/// record that runs past the chunk's end, an attachment shorter than its header), found by
/// `fuzz/run mcap_read`.
fn records(buf: &[u8]) -> Result<(Vec<RawRecord<'_>>, bool), String> {
    use mcap::records::{op, Record};
    let truncated = || read_error(mcap::McapError::UnexpectedEof);
    let mut out = Vec::new();
    let mut at = MAGIC.len();
    while at < buf.len() {
        let (opcode, body, next) = record_at(buf, at).ok_or_else(truncated)?;
        at = next;
        match opcode {
            op::CHUNK => {
                let Record::Chunk { header, data: std::borrow::Cow::Borrowed(data) } =
                    mcap::parse_record(opcode, body).map_err(read_error)?
                else {
                    return Err("a chunk record that does not read as one".into());
                };
                if !header.compression.is_empty() {
                    return Err(format!(
                        "a chunk is compressed with `{}`, which this reader does not read: taut writes uncompressed chunks \
                         (the `mcap` command-line tool's `mcap compress --compression none` writes such a copy)",
                        crate::recording::excerpt(&header.compression)
                    ));
                }
                if header.uncompressed_crc != 0 && crc32fast::hash(data) != header.uncompressed_crc {
                    return Err(format!("damaged MCAP file: the chunk ending at byte {at} fails its CRC"));
                }
                let mut k = 0;
                while k < data.len() {
                    let (opcode, body, next) = record_at(data, k)
                        .ok_or_else(|| format!("damaged MCAP file: a record of the chunk ending at byte {at} runs past the chunk's end"))?;
                    out.push((opcode, body));
                    k = next;
                }
            }
            op::DATA_END | op::FOOTER => return Ok((out, true)),
            _ => out.push((opcode, body)),
        }
    }
    Ok((out, false))
}

/// A record's opcode and body.
type RawRecord<'a> = (u8, &'a [u8]);

/// The record at byte `at` of `buf`: opcode, body and the byte after it, if it fits.
fn record_at(buf: &[u8], at: usize) -> Option<(u8, &[u8], usize)> {
    let opcode = *buf.get(at)?;
    let len = u64::from_le_bytes(buf.get(at + 1..at + 9)?.try_into().ok()?);
    let end = u64::try_from(at + 9).ok()?.checked_add(len).filter(|&end| end <= buf.len() as u64)? as usize;
    Some((opcode, &buf[at + 9..end], end))
}

/// Parses the bytes of a taut MCAP file. The error says what is wrong, for a person.
pub fn parse(buf: &[u8]) -> Result<(Recording, ParseReport), String> {
    if !is_mcap_bytes(buf) {
        return Err("not an MCAP file (it does not start with the MCAP magic bytes)".into());
    }
    let mut meta: Option<BTreeMap<String, String>> = None;
    let mut schemas: BTreeMap<u16, (String, String)> = BTreeMap::new();
    let mut cables: Option<u16> = None;
    let mut msgs: Vec<(u32, Vec<u8>)> = Vec::new();
    let (records, ended) = records(buf)?;
    for (opcode, body) in records {
        use mcap::records::{op, Record};
        if !matches!(opcode, op::METADATA | op::SCHEMA | op::CHANNEL | op::MESSAGE) {
            continue;
        }
        match mcap::parse_record(opcode, body).map_err(read_error)? {
            Record::Metadata(m) if m.name == METADATA_NAME => meta = Some(m.metadata),
            Record::Schema { header, .. } => {
                schemas.insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) if c.topic == CHANNELS[0].topic && cables.is_none() => {
                let (name, enc) = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                if name != CHANNELS[0].schema_name || enc != "jsonschema" || c.message_encoding != "json" {
                    return Err(format!(
                        "channel /cables has schema `{name}` ({enc}) and message encoding `{}`; taut writes `taut.Cables` (jsonschema) in json: \
                         this file was not written by taut",
                        crate::recording::excerpt(&c.message_encoding)
                    ));
                }
                cables = Some(c.id);
            }
            Record::Message { header, data } if Some(header.channel_id) == cables => msgs.push((header.sequence, data.into_owned())),
            _ => {}
        }
    }
    let Some(meta) = meta else {
        return Err(format!("no `{METADATA_NAME}` metadata record: this MCAP file was not written by taut (taut start, taut export)"));
    };
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(format!(
            "metadata `format` is `{}`, this reader reads `{FORMAT}`",
            crate::recording::excerpt(meta.get("format").map_or("", String::as_str))
        ));
    }
    let num = |k: &str| -> Result<f64, String> {
        let v = meta.get(k).ok_or_else(|| format!("metadata `{k}` is missing"))?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite() && *x >= 0.0)
            .ok_or_else(|| format!("metadata `{k}` = `{}` is not a number >= 0", crate::recording::excerpt(v)))
    };
    let n = num("n_cables")?;
    if n < 1.0 || n > MAX_RECORDING_CABLES as f64 || n.fract() != 0.0 {
        return Err(format!("metadata `n_cables` = {n}: give 1 to {MAX_RECORDING_CABLES}"));
    }
    let n = n as usize;
    let (tracker_max, tension_max) = (num("tracker_max_age_s")?, num("tension_max_age_s")?);
    if cables.is_none() {
        return Err("no /cables channel: a taut recording has one (per-cable lengths and tensions)".into());
    }
    let mut rec = Recording::with_capacity(n, msgs.len(), true, false, true);
    rec.comments = meta.get("comments").map(|c| c.lines().map(str::to_string).collect()).unwrap_or_default();
    let mut report = ParseReport::default();
    let mut q_all: Vec<[f64; 4]> = Vec::new();
    let mut any_q = false;
    let val = |v: &Option<f64>| v.unwrap_or(f64::NAN);
    for (k, (seq, data)) in msgs.iter().enumerate() {
        let m: CablesMsg = serde_json::from_slice(data).map_err(|e| format!("/cables message {} (sequence {seq}): {e}", k + 1))?;
        let arrays = [
            ("length_m", &m.length_m),
            ("length_age_s", &m.length_age_s),
            ("tension_n", &m.tension_n),
            ("tension_age_s", &m.tension_age_s),
        ];
        for (name, a) in arrays {
            if a.len() != n {
                return Err(format!(
                    "/cables message {} (sequence {seq}): `{name}` has {} values, the file has {n} cables",
                    k + 1,
                    a.len()
                ));
            }
        }
        if !m.t.is_finite() || m.t.abs() > MAX_TIME_S {
            return Err(format!("/cables message {} (sequence {seq}): time {} is not a plausible time", k + 1, m.t));
        }
        if rec.t.last().is_some_and(|&t0| m.t < t0) {
            return Err(format!(
                "/cables message {} (sequence {seq}): time {} is earlier than the previous {}",
                k + 1,
                m.t,
                rec.t[rec.len() - 1]
            ));
        }
        let fresh = |age: Option<f64>, max: f64| age.is_some_and(|a| a <= max);
        let pose_ok = fresh(m.position_age_s, tracker_max);
        let p = if pose_ok { m.position_m.map(|v| val(&v)) } else { [f64::NAN; 3] };
        let l: Vec<f64> = m.length_m.iter().map(val).collect();
        let f: Vec<f64> =
            m.tension_n.iter().zip(&m.tension_age_s).map(|(v, a)| if fresh(*a, tension_max) { val(v) } else { f64::NAN }).collect();
        if let Some(q) = m.orientation_wxyz {
            any_q = true;
            q_all.push(q.map(|v| val(&v)));
        } else {
            q_all.push([f64::NAN; 4]);
        }
        report.rows += 1;
        let p_ok = p.iter().all(|v| v.is_finite());
        if !p_ok {
            report.missing_position += 1;
        }
        report.missing_length += l.iter().filter(|v| !v.is_finite()).count();
        report.missing_tension += f.iter().filter(|v| !v.is_finite()).count();
        if p_ok && l.iter().any(|v| v.is_finite()) {
            report.usable_rows += 1;
        }
        rec.push(m.t, p, None, &l, Some(&f), Some(m.phase));
    }
    if any_q {
        rec.q = Some(q_all);
    }
    // The notes the CSV reader gives, in its order and words.
    if rec.f.as_ref().is_some_and(|f| f.iter().all(|v| !v.is_finite())) {
        rec.f = None;
        report.missing_tension = 0;
        report.notes.push("the f columns are empty: no tensions in this recording".into());
    }
    report.note_missing();
    if !ended {
        report.notes.push("the file has no summary (the writer did not finish it); every complete chunk was read".into());
    }
    if report.usable_rows < crate::recording::MIN_USABLE_SAMPLES {
        return Err(format!(
            "only {} usable samples on /cables (with a position and a length), at least {} needed",
            report.usable_rows,
            crate::recording::MIN_USABLE_SAMPLES
        ));
    }
    Ok((rec, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chunk without a CRC whose record claims more bytes than the chunk holds.
    #[test]
    fn a_chunk_record_past_the_chunk_end_is_damage() {
        let mut chunk = Vec::new();
        chunk.extend_from_slice(&[0u8; 24]); // start time, end time, uncompressed size
        chunk.extend_from_slice(&0u32.to_le_bytes()); // no CRC
        chunk.extend_from_slice(&0u32.to_le_bytes()); // compression "" (none)
        let records = [&[mcap::records::op::MESSAGE][..], &100u64.to_le_bytes()].concat();
        chunk.extend_from_slice(&(records.len() as u64).to_le_bytes());
        chunk.extend_from_slice(&records);
        let mut file = MAGIC.to_vec();
        file.push(mcap::records::op::CHUNK);
        file.extend_from_slice(&(chunk.len() as u64).to_le_bytes());
        file.extend_from_slice(&chunk);
        let e = parse(&file).unwrap_err();
        assert!(e.contains("runs past the chunk's end"), "{e}");
        // The same file cut inside the chunk: truncated, not damaged.
        let e = parse(&file[..file.len() - 3]).unwrap_err();
        assert!(e.contains("ends in the middle of a record"), "{e}");
    }
}
