//! The project's data formats and files: the TOML robot description ([`RobotConfig`]), the
//! `cdpr-recording v1` CSV interchange format ([`recording`]), MCAP recordings (`mcap`, feature),
//! parameter files ([`params`]), atomic output ([`atomic`]) and input opening ([`input`]).
//!
//! They are read by people as much as by programs, so every error names the file, the line and
//! the key or column that is wrong, and says what to do.
//!
//! ```no_run
//! let cfg = taut_config::RobotConfig::load("config/examples/aras-cam.toml").unwrap();
//! println!("{} has {} cables", cfg.robot.name, cfg.cables.len());
//! ```
#![deny(missing_docs)]

pub mod atomic;
mod exact;
pub mod followers;
pub mod geometry;
pub mod input;
pub mod live;
pub mod loadcell_timing;
#[cfg(feature = "mcap")]
pub mod mcap;
pub mod numfmt;
pub mod params;
pub mod recording;
pub mod runtime;

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};
use taut_proto::devices;

pub use atomic::write_atomic;

/// A robot description as read from a TOML file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// The `[robot]` table.
    pub robot: Robot,
    /// The `[[cable]]` tables, in cable order.
    #[serde(rename = "cable")]
    pub cables: Vec<Cable>,
    /// The `[calibration]` table (optional; defaults as in the paper).
    #[serde(default)]
    pub calibration: CalibrationConfig,
    /// The `[can]` table: CANopen bus of the servo drives (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub can: Option<devices::CanConfig>,
    /// The `[loadcells]` table: Modbus RTU load cells (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loadcells: Option<devices::LoadCellBusConfig>,
    /// The `[tracker]` table: external position tracker input (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracker: Option<devices::TrackerConfig>,
    /// The `[rt]` table: the real-time loop (optional).
    #[serde(default)]
    pub rt: runtime::RtConfig,
    /// The `[motion]` table: the guided start-up motion (optional).
    #[serde(default)]
    pub motion: runtime::MotionConfig,
    /// The `[safety]` table: limits checked every cycle (optional).
    #[serde(default)]
    pub safety: runtime::SafetyConfig,
    /// The `[daemon]` table: control socket and data files of `taut start` (optional).
    #[serde(default)]
    pub daemon: runtime::DaemonConfig,
    /// The `[recording]` table: CSV, MCAP or both (optional).
    #[serde(default)]
    pub recording: live::RecordingConfig,
    /// The `[telemetry]` table: live Foxglove WebSocket server (optional, off by default).
    #[serde(default)]
    pub telemetry: live::TelemetryConfig,
}

/// The `[robot]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Robot {
    /// A name for logs and file names.
    pub name: String,
    /// Mass of the end-effector / platform, kg.
    pub mass_kg: f64,
}

/// One `[[cable]]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cable {
    /// Nominal anchor (cable exit point) in the tracker frame, m. Optional: the calibration does
    /// not need it.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::opt_three")]
    pub anchor: Option<[f64; 3]>,
    /// The design's tolerance of `anchor`, 1-sigma per axis, m: one number or `[x, y, z]`. With
    /// it the calibrations estimate the anchor with the design as a prior (maximum a posteriori)
    /// and say how much of each coordinate came from the data; without it `anchor` is only a
    /// start value.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::opt_sigma_three")]
    pub anchor_sigma_m: Option<[f64; 3]>,
    /// Nominal encoder offset `L0_j`, m (optional): the reading of this cable's encoder minus
    /// its length, e.g. from a measured cable. Without it the start value comes from the data.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub l0_m: Option<f64>,
    /// Tolerance of `l0_m`, 1-sigma, m: the offset's prior, as `anchor_sigma_m` is the anchor's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub l0_sigma_m: Option<f64>,
    /// Attachment point `b_j` on the platform, m, platform frame.
    #[serde(default, deserialize_with = "exact::three")]
    pub platform_point: [f64; 3],
    /// Direction of the swivel axis of the pulley at `anchor`, tracker frame: `[x, y, z]`,
    /// pointing from the anchor towards where the cable comes from (its winch). Any finite
    /// non-zero vector, normalised when read ([`Cable::unit_pulley_axis`]), as URDF normalises a
    /// joint's `<axis xyz>`. Optional: vertical, `[0, 0, 1]` (the cable comes down from above).
    /// Used where a pulley radius is modelled (`taut diagnose`, the `pulley` effect).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::opt_three")]
    pub pulley_axis: Option<[f64; 3]>,
    /// The `[cable.drive]` sub-table: the servo drive that winds this cable (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive: Option<devices::DriveConfig>,
    /// The `[cable.loadcell]` sub-table: the load cell that measures this cable (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loadcell: Option<devices::LoadCellConfig>,
}

/// The shortest `pulley_axis` taken for a direction: anything shorter is a zero vector (or a
/// value written in the wrong unit), not an axis.
pub const PULLEY_AXIS_MIN_NORM: f64 = 1e-6;

impl Cable {
    /// The swivel-pulley axis as a unit vector: `pulley_axis` normalised, or vertical
    /// (`[0, 0, 1]`, [`taut_model::VERTICAL_AXIS`]) when not given. A validated configuration's
    /// axis is finite and at least [`PULLEY_AXIS_MIN_NORM`] long.
    pub fn unit_pulley_axis(&self) -> [f64; 3] {
        match self.pulley_axis {
            None => taut_model::VERTICAL_AXIS,
            Some(v) => {
                let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                [v[0] / n, v[1] / n, v[2] / n]
            }
        }
    }
}

/// The `[calibration]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationConfig {
    /// Samples of a cable with less tension than this are loose and excluded, N.
    pub min_tension_n: f64,
    /// Tracker noise, 1-sigma per axis, m.
    pub tracker_sigma_m: f64,
    /// Encoder length noise, 1-sigma, m.
    pub encoder_sigma_m: f64,
    /// Expected axial stiffness EA of the cables, N. Sets how fast the variance of a length reading
    /// grows with tension x length (unobserved stretch T·L/EA).
    pub cable_ea_n: f64,
    /// 1-sigma of `cable_ea_n`, N: the datasheet's tolerance of the cables' stiffness. 0 (the
    /// default): `cable_ea_n` is a guess and only sets the variance above. Above 0: the
    /// stiffness is known, and the calibration models each reading's stretch `T L / EA` (with a
    /// tracker the tension-tagged samples, without one the dwells' means) instead of leaving it
    /// to the anchors, with each cable's EA fitted within this prior (docs/effects.md).
    #[serde(skip_serializing_if = "is_zero")]
    pub cable_ea_sigma_n: f64,
    /// Fraction of the recording held out for validation (with a tracker: the ends of eight
    /// time blocks of the excitation; without: every `1/fraction`-th dwell).
    pub heldout_fraction: f64,
    /// A calibrated parameter whose 1-sigma exceeds this is returned with a warning that it is
    /// weakly determined, m.
    pub weak_sigma_m: f64,
    /// A calibration with a parameter whose 1-sigma exceeds this is refused, m (the estimate is
    /// then too uncertain to be worth using, even as a start).
    pub max_sigma_m: f64,
    /// Effects the daemon's calibration fits together with the anchors and offsets (a fixed
    /// model: no selection in the running robot), by their `taut diagnose` names: `elasticity`,
    /// `scale`, `pulley`, `backlash`, `time-offset`. Empty: the ideal model (and whatever effects
    /// a parameter file given to `taut start --params` carries). See docs/effects.md.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub effects: Vec<String>,
    /// Load-cell noise, 1-sigma of one tension reading, N. `taut diagnose` predicts stretch and
    /// sag from the measured tensions: with this, a reading whose prediction the tension noise
    /// moves counts by its total variance (errors in variables; docs/diagnosis.md). 0 (the
    /// default): the tensions are taken as exact. Here rather than in `[cable.loadcell]`: like
    /// `tracker_sigma_m` and `encoder_sigma_m` it is the noise model of the estimators, which a
    /// recording-only configuration (no devices) needs too.
    #[serde(skip_serializing_if = "is_zero")]
    pub loadcell_sigma_n: f64,
    /// 1-sigma of each load cell's unknown constant offset (its zero), N: added to the
    /// uncertainty `taut diagnose` reports for stretch and sag. 0 (the default): the cells are
    /// taken as zeroed exactly.
    #[serde(skip_serializing_if = "is_zero")]
    pub loadcell_offset_n: f64,
}

/// A default 0 is not written (configurations written before the key existed stay the same).
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// The largest load-cell 1-sigma (`[calibration] loadcell_sigma_n`, `loadcell_offset_n`) taken,
/// N: above a kilonewton of noise a reading says nothing about a cable robot's tension; such a
/// value is a unit mistake (mN, raw counts), not a load cell.
pub const LOADCELL_SIGMA_MAX_N: f64 = 1000.0;

/// Checks a load-cell 1-sigma in newtons (`[calibration] loadcell_sigma_n` / `loadcell_offset_n`,
/// `taut diagnose --loadcell-sigma` / `--loadcell-offset`): finite, 0 to [`LOADCELL_SIGMA_MAX_N`].
/// The error says what is allowed; the caller adds where the value came from.
pub fn check_loadcell_sigma(v: f64) -> Result<(), String> {
    if v.is_finite() && (0.0..=LOADCELL_SIGMA_MAX_N).contains(&v) {
        Ok(())
    } else {
        Err(format!(
            "must be a load cell's 1-sigma in newtons, 0 (exact) to {LOADCELL_SIGMA_MAX_N}, got {v}; give the noise of one reading in N"
        ))
    }
}

/// The effects the running robot can model (`[calibration] effects`): sag is left out (the
/// catenary at the measured tension is too costly for the loop and matters on large robots
/// only), slack is a data problem, not a model.
pub const MODELLED_EFFECTS: [&str; 7] = ["elasticity", "scale", "spool-buildup", "compliance", "pulley", "backlash", "time-offset"];

/// Other names the configuration and the command line accept for an effect, with the name the
/// reports use: `drum-buildup` for the spool build-up, `spool-buildup` in the JSON;
/// `load-cell-gain` for `loadcell-gain`.
pub const EFFECT_ALIASES: [(&str, &str); 2] = [("drum-buildup", "spool-buildup"), ("load-cell-gain", "loadcell-gain")];

/// The reports' name of an effect named `name` (itself unless it is an alias in
/// [`EFFECT_ALIASES`]).
pub fn canonical_effect_name(name: &str) -> &str {
    EFFECT_ALIASES.iter().find(|a| a.0 == name).map_or(name, |a| a.1)
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        CalibrationConfig {
            min_tension_n: 3.0,
            tracker_sigma_m: 1.5e-3,
            encoder_sigma_m: 0.05e-3,
            cable_ea_n: 2.0e5,
            cable_ea_sigma_n: 0.0,
            heldout_fraction: 0.2,
            weak_sigma_m: 2e-3,
            // An estimate known to 10 cm still improves on a tape-measured nominal geometry
            // (10-20 cm): refusing it would leave the robot with no start at all.
            max_sigma_m: 0.1,
            effects: Vec::new(),
            loadcell_sigma_n: 0.0,
            loadcell_offset_n: 0.0,
        }
    }
}

/// An error in a configuration file, with where it is and what to do.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// The file, if the text came from one.
    pub file: Option<PathBuf>,
    /// 1-based line, where known.
    pub line: Option<usize>,
    /// The key path, e.g. `cable[2].anchor`, where known.
    pub key: Option<String>,
    /// What is wrong and what to do.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.file {
            Some(p) => write!(f, "{}", p.display())?,
            None => write!(f, "<config>")?,
        }
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if let Some(k) = &self.key {
            write!(f, ": key `{k}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for ConfigError {}

/// How people are shown cable `j` (0-based index into `[[cable]]`): `cable 1` for the first.
/// Node ids and Modbus unit ids count from 1, so do the cables in every text for people (reports,
/// `taut ctl status`, the daemon's log); machine-facing JSON indices stay 0-based where their
/// documentation says so.
pub fn cable_name(j: usize) -> String {
    format!("cable {}", j + 1)
}

/// Several cables for people, from 1: `cable 2`, `cables 1 and 3`, `cables 1, 2 and 4`.
pub fn cable_list(js: &[usize]) -> String {
    let names: Vec<String> = js.iter().map(|j| (j + 1).to_string()).collect();
    match names.len() {
        0 => "no cable".into(),
        1 => format!("cable {}", names[0]),
        k => format!("cables {} and {}", names[..k - 1].join(", "), names[k - 1]),
    }
}

/// [`cable_name`] with the devices behind the cable where known: `cable 1 (drive node 3, load
/// cell unit 2)`; just `cable 1` without either.
pub fn cable_label_with(j: usize, node_id: Option<u8>, unit_id: Option<u8>) -> String {
    let mut parts = Vec::new();
    if let Some(n) = node_id {
        parts.push(format!("drive node {n}"));
    }
    if let Some(u) = unit_id {
        parts.push(format!("load cell unit {u}"));
    }
    if parts.is_empty() {
        cable_name(j)
    } else {
        format!("{} ({})", cable_name(j), parts.join(", "))
    }
}

impl RobotConfig {
    /// The CANopen node id of cable `j`'s drive and the Modbus unit id of its load cell, where
    /// the configuration gives them.
    pub fn cable_ids(&self, j: usize) -> (Option<u8>, Option<u8>) {
        self.cables.get(j).map_or((None, None), |c| (c.drive.as_ref().map(|d| d.node_id), c.loadcell.as_ref().map(|l| l.unit_id)))
    }

    /// [`cable_label_with`] from the configuration: `cable 1 (drive node 3, load cell unit 2)`.
    pub fn cable_label(&self, j: usize) -> String {
        let (n, u) = self.cable_ids(j);
        cable_label_with(j, n, u)
    }

    /// Reads and validates a configuration file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = input::read_text(path).map_err(|e| ConfigError {
            file: Some(path.to_path_buf()),
            line: None,
            key: None,
            message: format!("cannot read the file: {e}"),
        })?;
        let mut cfg = Self::from_toml_str(&text).map_err(|mut e| {
            e.file = Some(path.to_path_buf());
            e
        })?;
        // `eds` paths are relative to the configuration file.
        let dir = path.parent().unwrap_or(Path::new(""));
        for d in cfg.cables.iter_mut().filter_map(|c| c.drive.as_mut()) {
            if let Some(e) = &mut d.eds {
                if Path::new(e.as_str()).is_relative() {
                    *e = dir.join(&*e).to_string_lossy().into_owned();
                }
            }
        }
        Ok(cfg)
    }

    /// Parses and validates configuration text.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let cfg: RobotConfig = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            ConfigError {
                file: None,
                line,
                key: line.and_then(|l| key_path_at(text, l)),
                // toml's message names the key and what was expected; drop its own
                // "TOML parse error at line.." preamble and source excerpt, we print the line.
                message: e.message().trim().to_string(),
            }
        })?;
        cfg.validate(text)?;
        Ok(cfg)
    }

    /// A point-mass robot with `n` cables and no nominal geometry: what `taut calibrate` assumes
    /// when no configuration is given.
    pub fn point_mass(n: usize) -> Self {
        RobotConfig {
            robot: Robot { name: "unnamed".into(), mass_kg: 1.0 },
            cables: (0..n)
                .map(|_| Cable {
                    anchor: None,
                    anchor_sigma_m: None,
                    l0_m: None,
                    l0_sigma_m: None,
                    platform_point: [0.0; 3],
                    pulley_axis: None,
                    drive: None,
                    loadcell: None,
                })
                .collect(),
            calibration: CalibrationConfig::default(),
            can: None,
            loadcells: None,
            tracker: None,
            rt: Default::default(),
            motion: Default::default(),
            safety: Default::default(),
            daemon: Default::default(),
            recording: Default::default(),
            telemetry: Default::default(),
        }
    }

    /// Nominal anchors, if every cable has one.
    pub fn anchors(&self) -> Option<Vec<[f64; 3]>> {
        self.cables.iter().map(|c| c.anchor).collect()
    }

    /// The design's priors per cable: `(mean, 1-sigma)` of `[A_x, A_y, A_z, L0]`, a sigma of
    /// infinity where the configuration gives none. `None` when no cable has a tolerance.
    pub fn priors(&self) -> Option<Vec<([f64; 4], [f64; 4])>> {
        if self.cables.iter().all(|c| c.anchor_sigma_m.is_none() && c.l0_sigma_m.is_none()) {
            return None;
        }
        Some(
            self.cables
                .iter()
                .map(|c| {
                    let a = c.anchor.unwrap_or([f64::NAN; 3]);
                    let sa = c.anchor_sigma_m.unwrap_or([f64::INFINITY; 3]);
                    ([a[0], a[1], a[2], c.l0_m.unwrap_or(f64::NAN)], [sa[0], sa[1], sa[2], c.l0_sigma_m.unwrap_or(f64::INFINITY)])
                })
                .collect(),
        )
    }

    /// Platform attachment points `b_j`.
    pub fn platform_points(&self) -> Vec<[f64; 3]> {
        self.cables.iter().map(|c| c.platform_point).collect()
    }

    /// Every cable's swivel-pulley axis, a unit vector ([`Cable::unit_pulley_axis`]).
    pub fn pulley_axes(&self) -> Vec<[f64; 3]> {
        self.cables.iter().map(Cable::unit_pulley_axis).collect()
    }

    /// Writes the configuration as TOML, atomically (temporary file + rename).
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
        let text = toml::to_string_pretty(self).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
        write_atomic(path.as_ref(), text.as_bytes())
    }

    fn validate(&self, text: &str) -> Result<(), ConfigError> {
        let cable_lines = table_header_lines(text, "[[cable]]");
        let err = |line: Option<usize>, key: String, message: String| ConfigError { file: None, line, key: Some(key), message };
        let (m_lo, m_hi) = geometry::MASS_KG;
        if !(self.robot.mass_kg.is_finite() && self.robot.mass_kg >= m_lo && self.robot.mass_kg <= m_hi) {
            return Err(err(
                key_line(text, "[robot]", "mass_kg"),
                "robot.mass_kg".into(),
                format!("must be the platform's mass in kg, {m_lo} to {m_hi}, got {:e}", self.robot.mass_kg),
            ));
        }
        if self.cables.len() > geometry::MAX_CABLES {
            return Err(err(
                cable_lines.get(geometry::MAX_CABLES).copied(),
                "cable".into(),
                format!(
                    "{} [[cable]] tables; taut drives at most {} cables (the real-time loop's fixed arrays)",
                    self.cables.len(),
                    geometry::MAX_CABLES
                ),
            ));
        }
        if self.cables.len() < 3 {
            return Err(err(
                None,
                "cable".into(),
                format!("a suspended cable robot needs at least 3 [[cable]] tables, found {}", self.cables.len()),
            ));
        }
        for (i, c) in self.cables.iter().enumerate() {
            let line = cable_lines.get(i).copied();
            let finite = |v: &[f64; 3]| v.iter().all(|x| x.is_finite());
            if let Some(a) = &c.anchor {
                if !finite(a) {
                    return Err(err(line, format!("cable[{i}].anchor"), "must be three finite numbers (m)".into()));
                }
            }
            let tolerance = |v: f64| v.is_finite() && v > 0.0 && v <= 1000.0;
            if let Some(s) = &c.anchor_sigma_m {
                if c.anchor.is_none() {
                    return Err(err(
                        line,
                        format!("cable[{i}].anchor_sigma_m"),
                        "a tolerance without its value: give cable.anchor too".into(),
                    ));
                }
                if !s.iter().all(|&v| tolerance(v)) {
                    return Err(err(
                        line,
                        format!("cable[{i}].anchor_sigma_m"),
                        format!("must be positive and finite (m, 1-sigma), got {s:?}"),
                    ));
                }
            }
            if let Some(l) = c.l0_m {
                if !(l.is_finite() && l.abs() <= 1000.0) {
                    return Err(err(line, format!("cable[{i}].l0_m"), format!("must be a finite offset within 1000 m, got {l}")));
                }
            }
            if let Some(s) = c.l0_sigma_m {
                if c.l0_m.is_none() {
                    return Err(err(line, format!("cable[{i}].l0_sigma_m"), "a tolerance without its value: give cable.l0_m too".into()));
                }
                if !tolerance(s) {
                    return Err(err(line, format!("cable[{i}].l0_sigma_m"), format!("must be positive and finite (m, 1-sigma), got {s}")));
                }
            }
            if !finite(&c.platform_point) {
                return Err(err(line, format!("cable[{i}].platform_point"), "must be three finite numbers (m)".into()));
            }
            if let Some(u) = &c.pulley_axis {
                let at = cable_key_line(text, i, "pulley_axis").or(line);
                let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
                if !finite(u) || !norm.is_finite() {
                    return Err(err(
                        at,
                        format!("cable[{i}].pulley_axis"),
                        format!("must be three finite numbers (a direction, e.g. [1, 0, 0]), got {u:?}"),
                    ));
                }
                if norm < PULLEY_AXIS_MIN_NORM {
                    return Err(err(
                        at,
                        format!("cable[{i}].pulley_axis"),
                        format!(
                            "is a zero vector ({u:?}, length {norm:e}); give the swivel axis's direction from the anchor towards the winch, e.g. [0, 0, 1] (vertical, the default) or [1, 0, 0]"
                        ),
                    ));
                }
            }
            if let Some(d) = &c.drive {
                // The PDO tables first: their errors point at the bad object's own line.
                d.pdo_maps().map_err(|(k, span, m)| {
                    let at = span.filter(|s| !s.is_empty()).map(|s| line_of(text, s.start)).or(line);
                    err(at, format!("cable[{i}].drive.{k}"), m)
                })?;
                d.validate().map_err(|(k, m)| err(line, format!("cable[{i}].drive.{k}"), m))?;
            }
            if let Some(l) = &c.loadcell {
                l.validate().map_err(|(k, m)| err(line, format!("cable[{i}].loadcell.{k}"), m))?;
            }
        }
        let anchors: Vec<Option<[f64; 3]>> = self.cables.iter().map(|c| c.anchor).collect();
        geometry::check(&anchors, &self.platform_points())
            .map_err(|(i, k, m)| err(cable_lines.get(i).copied(), format!("cable[{i}].{k}"), m))?;
        let section = |name: &str| table_header_lines(text, &format!("[{name}]")).first().copied();
        if let Some(c) = &self.can {
            c.validate().map_err(|(k, m)| err(section("can"), format!("can.{k}"), m))?;
        }
        if let Some(l) = &self.loadcells {
            l.validate().map_err(|(k, m)| err(section("loadcells"), format!("loadcells.{k}"), m))?;
        }
        if let Some(t) = &self.tracker {
            t.validate().map_err(|(k, m)| err(section("tracker"), format!("tracker.{k}"), m))?;
        }
        devices::validate_unit_ids(self.cables.iter().map(|c| c.loadcell.as_ref()))
            .map_err(|(i, m)| err(cable_lines.get(i).copied(), format!("cable[{i}].loadcell.unit_id"), m))?;
        let mut node_seen = [None::<usize>; 128];
        for (i, c) in self.cables.iter().enumerate() {
            if let Some(d) = &c.drive {
                if let Some(first) = node_seen[d.node_id as usize & 127].replace(i) {
                    return Err(err(
                        cable_lines.get(i).copied(),
                        format!("cable[{i}].drive.node_id"),
                        format!("node id {} is already used by cable[{first}]; every drive needs its own", d.node_id),
                    ));
                }
                if let Some(can) = self.can.as_ref().filter(|can| can.master_node_id == d.node_id) {
                    return Err(err(
                        cable_lines.get(i).copied(),
                        format!("cable[{i}].drive.node_id"),
                        format!(
                            "node id {} is taut's own ([can] master_node_id, its heartbeat); give the drive or taut another id",
                            can.master_node_id
                        ),
                    ));
                }
            }
        }
        let cal = &self.calibration;
        let cal_line = table_header_lines(text, "[calibration]").first().copied();
        for (k, v) in [
            ("min_tension_n", cal.min_tension_n),
            ("tracker_sigma_m", cal.tracker_sigma_m),
            ("encoder_sigma_m", cal.encoder_sigma_m),
            ("cable_ea_n", cal.cable_ea_n),
            ("cable_ea_sigma_n", cal.cable_ea_sigma_n),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(err(cal_line, format!("calibration.{k}"), format!("must be a finite non-negative number, got {v}")));
            }
        }
        // A stiffness known to its tolerance needs a stiffness, and a tolerance below it (a
        // sigma of EA or more says nothing of the stretch).
        if cal.cable_ea_sigma_n > 0.0 && !(cal.cable_ea_n > 0.0 && cal.cable_ea_sigma_n < cal.cable_ea_n) {
            return Err(err(
                key_line(text, "[calibration]", "cable_ea_sigma_n").or(cal_line),
                "calibration.cable_ea_sigma_n".into(),
                format!(
                    "the stiffness's 1-sigma {} N must be below calibration.cable_ea_n = {} N (a datasheet's tolerance, e.g. 15 % of it); 0 leaves the stretch unmodelled",
                    cal.cable_ea_sigma_n, cal.cable_ea_n
                ),
            ));
        }
        if !(cal.heldout_fraction >= 0.0 && cal.heldout_fraction < 0.9) {
            return Err(err(cal_line, "calibration.heldout_fraction".into(), format!("must be in [0, 0.9), got {}", cal.heldout_fraction)));
        }
        for (k, v) in [("weak_sigma_m", cal.weak_sigma_m), ("max_sigma_m", cal.max_sigma_m)] {
            if !(v.is_finite() && v > 0.0 && v <= 10.0) {
                return Err(err(cal_line, format!("calibration.{k}"), format!("must be a 1-sigma in metres in (0, 10], got {v}")));
            }
        }
        // Both are finite here (checked above).
        if cal.weak_sigma_m > cal.max_sigma_m {
            return Err(err(
                cal_line,
                "calibration.weak_sigma_m".into(),
                format!(
                    "the warning level {} m is above the refusal tolerance calibration.max_sigma_m = {} m; make weak_sigma_m <= max_sigma_m",
                    cal.weak_sigma_m, cal.max_sigma_m
                ),
            ));
        }
        for (k, v) in [("loadcell_sigma_n", cal.loadcell_sigma_n), ("loadcell_offset_n", cal.loadcell_offset_n)] {
            check_loadcell_sigma(v).map_err(|m| err(key_line(text, "[calibration]", k), format!("calibration.{k}"), m))?;
        }
        for (k, e) in cal.effects.iter().enumerate() {
            let key = format!("calibration.effects[{k}]");
            if !MODELLED_EFFECTS.contains(&canonical_effect_name(e)) {
                let shown: String = e.chars().take(40).collect();
                return Err(err(
                    cal_line,
                    key,
                    format!("`{shown}` is not an effect the robot models; use some of {}", MODELLED_EFFECTS.join(", ")),
                ));
            }
            if cal.effects[..k].iter().any(|p| canonical_effect_name(p) == canonical_effect_name(e)) {
                return Err(err(cal_line, key, format!("`{e}` is named twice; name each effect once")));
            }
        }
        let first_line = |h: &str| table_header_lines(text, h).first().copied();
        self.rt.validate().map_err(|(k, m)| err(first_line("[rt]"), format!("rt.{k}"), m))?;
        self.motion.validate(self.cables.len()).map_err(|(k, m)| err(first_line("[motion]"), format!("motion.{k}"), m))?;
        self.safety.validate().map_err(|(k, m)| err(first_line("[safety]"), format!("safety.{k}"), m))?;
        if let Some(bus) = &self.loadcells {
            // A tension older than safety.tension_max_age_s stops the loop: it must outlast one
            // failed reading (loadcell_timing). The polled cells: the cables with a load cell.
            let cells = self.cables.iter().filter(|c| c.loadcell.is_some()).count();
            loadcell_timing::check_tension_age(self.safety.tension_max_age_s, bus, cells)
                .map_err(|m| err(key_line(text, "[safety]", "tension_max_age_s"), "safety.tension_max_age_s".into(), m))?;
        }
        self.daemon.validate().map_err(|(k, m)| err(first_line("[daemon]"), format!("daemon.{k}"), m))?;
        self.telemetry.validate().map_err(|(k, m)| err(first_line("[telemetry]"), format!("telemetry.{k}"), m))?;
        Ok(())
    }
}

/// 1-based line number of byte offset `pos` in `text`.
pub fn line_of(text: &str, pos: usize) -> usize {
    // A position at the end of a text that ends in a newline (a string left open to the end of
    // the file) is on the last line, not on the empty one after it.
    let pos = if pos >= text.len() { text.trim_end_matches('\n').len() } else { pos };
    text[..pos].bytes().filter(|&b| b == b'\n').count() + 1
}

/// 1-based line of `key = ...` in the first table `header`, or of the header if the key is not
/// written there.
fn key_line(text: &str, header: &str, key: &str) -> Option<usize> {
    let start = *table_header_lines(text, header).first()?;
    Some(key_line_from(text, start, key).unwrap_or(start))
}

/// 1-based line of `key = ...` in the table whose header is on the 1-based line `start`, before
/// the next header; `None` if the key is not written there.
fn key_line_from(text: &str, start: usize, key: &str) -> Option<usize> {
    for (i, l) in text.lines().enumerate().skip(start) {
        let l = l.trim_start();
        if l.starts_with('[') {
            break;
        }
        if l.split('=').next().is_some_and(|k| k.trim() == key) {
            return Some(i + 1);
        }
    }
    None
}

/// 1-based line of `key = ...` in the `index`-th (0-based) `[[cable]]` table, before any of its
/// sub-tables; `None` if the key is not written there.
fn cable_key_line(text: &str, index: usize, key: &str) -> Option<usize> {
    key_line_from(text, *table_header_lines(text, "[[cable]]").get(index)?, key)
}

/// The key path (`cable[2].anchor`, `robot.mass_kg`) of a `key = value` line, from the table
/// headers above it; for errors the TOML parser reports with a place but no key.
fn key_path_at(text: &str, line: usize) -> Option<String> {
    let lines: Vec<&str> = text.lines().collect();
    let this = lines.get(line.checked_sub(1)?)?.trim_start();
    let key = this.split_once('=').map(|(k, _)| k.trim()).filter(|k| !k.is_empty() && !k.starts_with('['))?;
    let mut cables = 0usize;
    let mut table = String::new();
    for l in &lines[..line - 1] {
        let l = l.trim();
        if l.starts_with("[[cable]]") {
            cables += 1;
            table = format!("cable[{}]", cables - 1);
        } else if let Some(sub) = l.strip_prefix("[cable.").and_then(|r| r.split(']').next()) {
            table = format!("cable[{}].{sub}", cables.saturating_sub(1));
        } else if let Some(name) = l.strip_prefix('[').and_then(|r| r.split(']').next()) {
            table = name.trim_start_matches('[').to_string();
        }
    }
    Some(if table.is_empty() { key.to_string() } else { format!("{table}.{key}") })
}

/// 1-based lines on which a table header such as `[[cable]]` appears.
fn table_header_lines(text: &str, header: &str) -> Vec<usize> {
    text.lines().enumerate().filter(|(_, l)| l.trim_start().starts_with(header)).map(|(i, _)| i + 1).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn example_configs_load() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                RobotConfig::load(&p).unwrap_or_else(|e| panic!("{e}"));
                n += 1;
            }
        }
        assert!(n >= 2, "expected the example configs in {}", dir.display());
    }

    #[test]
    fn cables_are_shown_from_1_with_their_devices() {
        let text = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[cable.drive]\nnode_id = 5\n[cable.loadcell]\nunit_id = 7\n[[cable]]\n[cable.drive]\nnode_id = 6\n[[cable]]\n";
        let cfg = RobotConfig::from_toml_str(text).unwrap();
        assert_eq!(cfg.cable_label(0), "cable 1 (drive node 5, load cell unit 7)");
        assert_eq!(cfg.cable_label(1), "cable 2 (drive node 6)");
        assert_eq!(cfg.cable_label(2), "cable 3");
        assert_eq!(cable_name(0), "cable 1");
        assert_eq!(cable_list(&[1]), "cable 2");
        assert_eq!(cable_list(&[0, 2]), "cables 1 and 3");
        assert_eq!(cable_list(&[0, 1, 3]), "cables 1, 2 and 4");
    }

    #[test]
    fn unknown_key_names_line_and_key() {
        let text = "[robot]\nname = \"x\"\nmass_kg = 3.0\nmas_kg = 1\n";
        let e = RobotConfig::from_toml_str(text).unwrap_err();
        assert_eq!(e.line, Some(4), "{e}");
        assert!(e.message.contains("mas_kg"), "{e}");
    }

    #[test]
    fn bad_value_names_cable_and_key() {
        let text = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\nanchor = [1, 2]\n";
        let e = RobotConfig::from_toml_str(text).unwrap_err();
        assert_eq!(e.line, Some(7), "{e}");
        let text = "[robot]\nname = \"x\"\nmass_kg = -3.0\n[[cable]]\n[[cable]]\n[[cable]]\n";
        let e = RobotConfig::from_toml_str(text).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("robot.mass_kg"), "{e}");
        let text = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n";
        let e = RobotConfig::from_toml_str(text).unwrap_err();
        assert!(e.message.contains("at least 3"), "{e}");
    }

    #[test]
    fn device_sections_are_validated_with_their_key() {
        let base = "[robot]\nname = \"x\"\nmass_kg = 3.0\n";
        let cables = "[[cable]]\n[cable.drive]\nnode_id = 1\n[[cable]]\n[cable.drive]\nnode_id = 1\n[[cable]]\n";
        let e = RobotConfig::from_toml_str(&format!("{base}{cables}")).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("cable[1].drive.node_id"), "{e}");
        assert_eq!(e.line, Some(7), "{e}");
        // A drive on taut's own node id (127 by default) is refused with its line.
        let e = RobotConfig::from_toml_str(&format!(
            "{base}[can]\ninterface = \"can0\"\n[[cable]]\n[cable.drive]\nnode_id = 127\n[[cable]]\n[[cable]]\n"
        ))
        .unwrap_err();
        assert_eq!((e.key.as_deref(), e.line), (Some("cable[0].drive.node_id"), Some(6)), "{e}");
        assert!(e.message.contains("master_node_id"), "{e}");
        let e = RobotConfig::from_toml_str(&format!("{base}[tracker]\nlisten = \"not an address\"\n[[cable]]\n[[cable]]\n[[cable]]\n"))
            .unwrap_err();
        assert!(e.key.as_deref().is_some_and(|k| k.starts_with("tracker.")), "{e}");
        assert_eq!(e.line, Some(4), "{e}");
    }

    #[test]
    fn physical_bounds_name_the_key() {
        let robot = |m: &str| format!("[robot]\nname = \"x\"\nmass_kg = {m}\n");
        let cables = |anchors: &[&str]| -> String { anchors.iter().map(|a| format!("[[cable]]\nanchor = {a}\n")).collect() };
        let good = ["[3, -2, 4]", "[3, 2, 4]", "[-3, 2, 4]", "[-3, -2, 4]"];
        RobotConfig::from_toml_str(&format!("{}{}", robot("3.0"), cables(&good))).unwrap();
        let long = format!("[{}]", vec!["1.0"; 1000].join(", "));
        for (text, key, line, words) in [
            (format!("{}{}", robot("3.0"), cables(&["[3, -2, 4, 9]", "[3, 2, 4]", "[-3, 2, 4]"])), "cable[0].anchor", 5, "found 4"),
            (format!("{}{}", robot("3.0"), cables(&["[3, -2, 4]", &long, "[-3, 2, 4]"])), "cable[1].anchor", 7, "found 1000"),
            (format!("{}{}", robot("1e-9"), cables(&good)), "robot.mass_kg", 3, "0.01 to 5000"),
            (format!("{}{}", robot("1e308"), cables(&good)), "robot.mass_kg", 3, "0.01 to 5000"),
            (format!("{}{}", robot("3.0"), cables(&["[3, -2, 4]", "[3, -2, 4]", "[-3, 2, 4]"])), "cable[1].anchor", 6, "apart"),
            (format!("{}{}", robot("3.0"), cables(&["[0, 0, 1]", "[0.1, 0, 1]", "[0, 0.1, 1]"])), "cable[0].anchor", 4, "span only"),
            (format!("{}{}", robot("3.0"), cables(&["[0, 0, 4]", "[1, 0, 4]", "[2, 0, 4]"])), "cable[0].anchor", 4, "one line"),
            (format!("{}{}", robot("3.0"), cables(&["[1e6, 0, 4]", "[1, 0, 4]", "[2, 1, 4]"])), "cable[0].anchor", 4, "1000 m"),
            (format!("{}{}", robot("3.0"), cables(&good.repeat(3)[..9])), "cable", 20, "at most 8"),
        ] {
            let e = RobotConfig::from_toml_str(&text).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some(key), Some(line)), "{e}\n{text}");
            assert!(e.to_string().contains(words), "{e}");
        }
    }

    #[test]
    fn sigma_tolerances_are_validated() {
        let base = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\n[calibration]\n";
        let c = RobotConfig::from_toml_str(&format!("{base}weak_sigma_m = 0.005\nmax_sigma_m = 0.02\n")).unwrap();
        assert_eq!((c.calibration.weak_sigma_m, c.calibration.max_sigma_m), (0.005, 0.02));
        for (extra, key, words) in [
            ("max_sigma_m = 0.0\n", "calibration.max_sigma_m", "(0, 10]"),
            ("weak_sigma_m = -1.0\n", "calibration.weak_sigma_m", "(0, 10]"),
            ("max_sigma_m = 1e9\n", "calibration.max_sigma_m", "(0, 10]"),
            ("weak_sigma_m = 0.2\nmax_sigma_m = 0.1\n", "calibration.weak_sigma_m", "weak_sigma_m <= max_sigma_m"),
        ] {
            let e = RobotConfig::from_toml_str(&format!("{base}{extra}")).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some(key), Some(7)), "{e}");
            assert!(e.to_string().contains(words), "{e}");
        }
    }

    #[test]
    fn a_known_cable_stiffness_is_validated_on_its_line() {
        let base = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\n[calibration]\ncable_ea_n = 1e6\n";
        assert_eq!(RobotConfig::from_toml_str(base).unwrap().calibration.cable_ea_sigma_n, 0.0);
        let c = RobotConfig::from_toml_str(&format!("{base}cable_ea_sigma_n = 1.5e5\n")).unwrap();
        assert_eq!(c.calibration.cable_ea_sigma_n, 1.5e5);
        for (extra, words) in
            [("cable_ea_sigma_n = 2e6\n", "must be below calibration.cable_ea_n"), ("cable_ea_sigma_n = -1.0\n", "non-negative")]
        {
            let e = RobotConfig::from_toml_str(&format!("{base}{extra}")).unwrap_err();
            assert_eq!(e.key.as_deref(), Some("calibration.cable_ea_sigma_n"), "{e}");
            assert!(e.to_string().contains(words), "{e}");
        }
        let e = RobotConfig::from_toml_str(&format!("{base}cable_ea_sigma_n = 2e6\n")).unwrap_err();
        assert_eq!(e.line, Some(9), "{e}");
    }

    #[test]
    fn loadcell_noise_keys_are_read_and_validated_on_their_line() {
        let base = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\n[calibration]\nmin_tension_n = 10.0\n";
        let c = RobotConfig::from_toml_str(base).unwrap();
        assert_eq!((c.calibration.loadcell_sigma_n, c.calibration.loadcell_offset_n), (0.0, 0.0));
        let c = RobotConfig::from_toml_str(&format!("{base}loadcell_sigma_n = 0.3\nloadcell_offset_n = 0.5\n")).unwrap();
        assert_eq!((c.calibration.loadcell_sigma_n, c.calibration.loadcell_offset_n), (0.3, 0.5));
        let c = RobotConfig::from_toml_str(&format!("{base}loadcell_sigma_n = 1000.0\n")).unwrap();
        assert_eq!(c.calibration.loadcell_sigma_n, LOADCELL_SIGMA_MAX_N);
        for (extra, key, line, words) in [
            ("loadcell_sigma_n = -0.3\n", "calibration.loadcell_sigma_n", 9, "got -0.3"),
            ("loadcell_sigma_n = nan\n", "calibration.loadcell_sigma_n", 9, "got NaN"),
            ("loadcell_offset_n = inf\n", "calibration.loadcell_offset_n", 9, "got inf"),
            ("loadcell_sigma_n = 0.3\nloadcell_offset_n = 1e6\n", "calibration.loadcell_offset_n", 10, "0 (exact) to 1000"),
            ("loadcell_sigma_n = 1000.001\n", "calibration.loadcell_sigma_n", 9, "0 (exact) to 1000"),
        ] {
            let e = RobotConfig::from_toml_str(&format!("{base}{extra}")).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some(key), Some(line)), "{e}");
            assert!(e.to_string().contains(words), "{e}");
        }
        // A string is the TOML reader's error, on the key's line.
        let e = RobotConfig::from_toml_str(&format!("{base}loadcell_sigma_n = \"0.3 N\"\n")).unwrap_err();
        assert_eq!((e.key.as_deref(), e.line), (Some("calibration.loadcell_sigma_n"), Some(9)), "{e}");
    }

    #[test]
    fn defaults_apply() {
        let text = "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\n";
        let c = RobotConfig::from_toml_str(text).unwrap();
        assert_eq!(c.calibration.min_tension_n, 3.0);
        assert_eq!(c.cables[0].platform_point, [0.0; 3]);
        assert!(c.anchors().is_none());
    }

    /// The design's tolerances: one number or three, beside their values; the priors they give.
    #[test]
    fn design_tolerances_become_priors() {
        let head = "[robot]\nname = \"x\"\nmass_kg = 3.0\n";
        let cable = |a: &str, extra: &str| format!("[[cable]]\nanchor = {a}\n{extra}");
        let text = format!(
            "{head}{}{}{}",
            cable("[1, 2, 3]", "anchor_sigma_m = 0.02\n"),
            cable("[-1, 2, 3]", "anchor_sigma_m = [0.01, 0.02, 0.05]\nl0_m = 2.5\nl0_sigma_m = 0.005\n"),
            cable("[1, -2, 3]", "")
        );
        let c = RobotConfig::from_toml_str(&text).unwrap();
        let p = c.priors().unwrap();
        assert_eq!(p[0].1[..3], [0.02; 3]);
        assert_eq!(p[1], ([-1.0, 2.0, 3.0, 2.5], [0.01, 0.02, 0.05, 0.005]));
        assert!(p[2].1.iter().all(|s| s.is_infinite()) && p[0].0[3].is_nan());
        assert!(RobotConfig::point_mass(3).priors().is_none());
        for (extra, words) in [
            ("anchor_sigma_m = [0.01, 0.02]\n", "exactly three"),
            ("anchor_sigma_m = -0.01\n", "positive"),
            ("l0_sigma_m = 0.01\n", "give cable.l0_m"),
        ] {
            let text = format!("{head}{}{}{}", cable("[1, 2, 3]", extra), cable("[-1, 2, 3]", ""), cable("[1, -2, 3]", ""));
            let e = RobotConfig::from_toml_str(&text).unwrap_err();
            assert!(e.to_string().contains(words), "{e}");
        }
    }

    /// `pulley_axis`: any finite non-zero direction, normalised; vertical without it; a zero,
    /// NaN, infinite or wrongly sized vector refused on its own line with its key.
    #[test]
    fn pulley_axes_are_normalised_and_validated_on_their_line() {
        let head = "[robot]\nname = \"x\"\nmass_kg = 3.0\n";
        let cable = |a: &str, extra: &str| format!("[[cable]]\nanchor = {a}\n{extra}");
        let text = |extra: &str| {
            format!("{head}{}{}{}", cable("[1, 2, 3]", ""), cable("[-1, 2, 3]", extra), cable("[1, -2, 3]", "pulley_axis = [0, 0, 2]\n"))
        };
        let c = RobotConfig::from_toml_str(&text("pulley_axis = [3, 0, 4]\n")).unwrap();
        assert_eq!(c.pulley_axes(), vec![[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.0, 1.0]]);
        assert_eq!(c.cables[0].unit_pulley_axis(), taut_model::VERTICAL_AXIS);
        assert_eq!(RobotConfig::point_mass(3).pulley_axes(), vec![taut_model::VERTICAL_AXIS; 3]);
        for (extra, words) in [
            ("pulley_axis = [0, 0, 0]\n", "zero vector"),
            ("pulley_axis = [1e-9, 0, 0]\n", "zero vector"),
            ("pulley_axis = [nan, 0, 1]\n", "finite"),
            ("pulley_axis = [inf, 0, 1]\n", "finite"),
            ("pulley_axis = [1e200, 1e200, 0]\n", "finite"),
            ("pulley_axis = [1, 0]\n", "found 2"),
        ] {
            let e = RobotConfig::from_toml_str(&text(&format!("l0_m = 0.1\n{extra}"))).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some("cable[1].pulley_axis"), Some(9)), "{e}");
            assert!(e.to_string().contains(words), "{e}");
        }
        // Written back, the configuration keeps the axis as given.
        let back = RobotConfig::from_toml_str(&toml::to_string_pretty(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn atomic_write_round_trips() {
        let dir = std::env::temp_dir().join(format!("taut-config-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("cfg.toml");
        let c = RobotConfig::point_mass(4);
        c.save_atomic(&p).unwrap();
        let back = RobotConfig::load(&p).unwrap();
        assert_eq!(back, c);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
