//! `taut-params v5`: a calibrated parameter set as written by `taut calibrate --out`, `taut
//! diagnose --out` and by the daemon on every accepted calibration (TOML, written atomically).
//! Version 4 files (the same without `compliance_m_per_n`), version 3 files (also without the
//! tension side's `loadcell_gain` and `friction_mu_theta`), version 2 files (also without
//! `drum_buildup_per_m`) and version 1 files (without `[effects]`) are still read; files are
//! written as v5.
//!
//! ```toml
//! format = "taut-params v5"
//! version = 3                      # increases with every accepted set
//! created_unix_s = 1795000000.0
//! robot = "aras-cam"
//! source = "rec.csv"
//! anchors_m = [[3.49, -1.76, 4.01], ...]
//! l0_m = [0.12, ...]
//! anchor_sigma_m = [[0.0002, 0.0002, 0.0004], ...]
//! l0_sigma_m = [0.0003, ...]
//! rms_m = 0.0015
//! heldout_rms_m = 0.0016
//!
//! [effects]                        # optional: only the effects that are modelled
//! ea_n = [21000.0, 19500.0, ...]   # axial stiffness EA per cable, N (stretch T L / EA)
//! ea_sigma_n = [300.0, ...]        # every value may have its 1-sigma beside it (`*_sigma*`)
//! drum_scale = [1.003, ...]        # encoder reading per metre of cable (drum radius error)
//! pulley_radius_m = [0.05, ...]    # swivel pulley radius; the anchor is where the cable
//!                                  # enters the pulley, the swivel axis (the configuration's
//!                                  # `[[cable]] pulley_axis`, vertical by default) through it
//! backlash_m = [0.002, ...]        # play in the drive train (width)
//! drum_buildup_per_m = [-0.01, ...] # drum build-up q: true length u + q u^2 of the encoder's u
//! compliance_m_per_n = [1.5e-6, ...] # length-independent compliance (winch, frame, anchor):
//!                                  # the encoder reads c T less than the cable's path
//! time_offset_s = 0.012            # the encoders lag the tracker by this
//! loadcell_gain = [1.02, ...]      # load-cell gain: the cell reads gain x tension (+ its offset)
//! friction_mu_theta = [0.1, ...]   # capstan friction mu theta of the guides before the cell
//! ```
//!
//! The model of an encoder reading (as in `taut_calib::diagnose::effects`): the path `G` from
//! the anchor over the pulley to the platform, unstretched `U = G / (1 + T / EA)`, less the
//! deflection `compliance_m_per_n * T`, reading `drum_scale * U + L0`, through a play of width
//! `backlash_m`. A load cell reads
//! `loadcell_gain * T * exp(-friction_mu_theta * tanh(v / 5 mm/s))` of the cable's tension `T`
//! at length rate `v` (> 0 paying out): `taut_model::cell_tension` inverts it, in the loop and in
//! the diagnosis.

use serde::{Deserialize, Serialize};
use std::path::Path;
use taut_model::geometry::{Field, GeometryError};
/// The shared geometry types, re-exported for the crates that see the configuration but not
/// the model crate (the simulator holds its truth as plain data: it must not see the formulas).
pub use taut_model::geometry::{Geometry, Sigmas};

/// The format tag of a parameter file as written.
pub const FORMAT: &str = "taut-params v5";
/// The format tag of version 4 files (no `compliance_m_per_n`), still read.
pub const FORMAT_V4: &str = "taut-params v4";
/// The format tag of version 3 files (no `loadcell_gain`, `friction_mu_theta`), still read.
pub const FORMAT_V3: &str = "taut-params v3";
/// The format tag of version 2 files (no `drum_buildup_per_m`), still read.
pub const FORMAT_V2: &str = "taut-params v2";
/// The format tag of version 1 files (no `[effects]`), still read.
pub const FORMAT_V1: &str = "taut-params v1";

/// Plausible ranges of the effect values: (key, low, high, unit). A value outside is not a
/// physical cable (or a typo), and the file is refused naming the key.
pub const EFFECT_RANGES: [(&str, f64, f64, &str); 9] = [
    // An elastic cord (1 kN) to a thick steel rope (10 GN is far beyond any; stiffer is rigid).
    ("ea_n", 1e3, 1e10, "N"),
    // A drum radius error of +-10 %.
    ("drum_scale", 0.9, 1.1, ""),
    ("pulley_radius_m", 0.0, 0.5, "m"),
    ("backlash_m", 0.0, 0.05, "m"),
    ("time_offset_s", -1.0, 1.0, "s"),
    // Drum build-up q = b / (2 r^2): a 2 mm cable five turns a layer on a 25 mm drum is 0.05.
    ("drum_buildup_per_m", -0.1, 0.1, "1/m"),
    // A cell more than a factor 2 off its data sheet is a wiring or scaling fault, not a gain.
    ("loadcell_gain", 0.5, 2.0, ""),
    // mu theta of 2 is a coefficient of 0.3 over more than a full turn of guides.
    ("friction_mu_theta", 0.0, 2.0, ""),
    // Deflection per newton of a winch, frame or anchor: 1 mm/N would be a spring, not a frame.
    ("compliance_m_per_n", 0.0, 1e-3, "m/N"),
];

/// Physical effects beyond the ideal model, fitted by `taut diagnose` or the daemon's
/// calibration. An absent key is an effect that is not modelled. Per-cable vectors have one
/// value per cable; sigmas are 1-sigma, absent when unknown.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    /// Axial stiffness EA per cable, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ea_n: Option<Vec<f64>>,
    /// 1-sigma of `ea_n`, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ea_sigma_n: Option<Vec<f64>>,
    /// Encoder scale per cable (reading per metre of unstretched cable; 1 is exact).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drum_scale: Option<Vec<f64>>,
    /// 1-sigma of `drum_scale`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drum_scale_sigma: Option<Vec<f64>>,
    /// Swivel-pulley radius per cable, m (its axis through the anchor is the configuration's
    /// `[[cable]] pulley_axis`, vertical by default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulley_radius_m: Option<Vec<f64>>,
    /// 1-sigma of `pulley_radius_m`, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulley_radius_sigma_m: Option<Vec<f64>>,
    /// Backlash (play) width per cable, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backlash_m: Option<Vec<f64>>,
    /// 1-sigma of `backlash_m`, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backlash_sigma_m: Option<Vec<f64>>,
    /// The encoders lag the tracker by this, s (robot-wide).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_offset_s: Option<f64>,
    /// 1-sigma of `time_offset_s`, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_offset_sigma_s: Option<f64>,
    /// Drum build-up per cable, 1/m: the true paid-out length is `u + q u^2` of the encoder's
    /// `u = reading - L0` (version 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drum_buildup_per_m: Option<Vec<f64>>,
    /// 1-sigma of `drum_buildup_per_m`, 1/m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drum_buildup_sigma_per_m: Option<Vec<f64>>,
    /// Load-cell gain per cable: the cell reads `gain` times the tension (plus its offset)
    /// (version 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loadcell_gain: Option<Vec<f64>>,
    /// 1-sigma of `loadcell_gain`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loadcell_gain_sigma: Option<Vec<f64>>,
    /// Capstan friction `mu theta` per cable of the guides between the platform and the load
    /// cell (version 4; `taut_model::cell_tension`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_mu_theta: Option<Vec<f64>>,
    /// 1-sigma of `friction_mu_theta`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_mu_theta_sigma: Option<Vec<f64>>,
    /// Compliance per cable that does not scale with its length (winch, frame or anchor
    /// deflection), m/N: the encoder reads `c T` less than the cable's path (version 5).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compliance_m_per_n: Option<Vec<f64>>,
    /// 1-sigma of `compliance_m_per_n`, m/N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compliance_sigma_m_per_n: Option<Vec<f64>>,
}

impl Effects {
    /// No effect modelled.
    pub fn is_empty(&self) -> bool {
        self.ea_n.is_none()
            && self.drum_scale.is_none()
            && self.pulley_radius_m.is_none()
            && self.backlash_m.is_none()
            && self.time_offset_s.is_none()
            && self.ea_sigma_n.is_none()
            && self.drum_scale_sigma.is_none()
            && self.pulley_radius_sigma_m.is_none()
            && self.backlash_sigma_m.is_none()
            && self.time_offset_sigma_s.is_none()
            && self.drum_buildup_per_m.is_none()
            && self.drum_buildup_sigma_per_m.is_none()
            && self.compliance_m_per_n.is_none()
            && self.compliance_sigma_m_per_n.is_none()
            && self.tension_side_is_empty()
    }

    /// No tension-side effect (load-cell gain, friction) modelled.
    pub fn tension_side_is_empty(&self) -> bool {
        self.loadcell_gain.is_none()
            && self.loadcell_gain_sigma.is_none()
            && self.friction_mu_theta.is_none()
            && self.friction_mu_theta_sigma.is_none()
    }

    /// The names of the modelled effects (`taut-diagnosis v1` names: elasticity, scale,
    /// pulley, backlash, time-offset, spool-buildup, compliance, loadcell-gain, friction).
    pub fn names(&self) -> Vec<&'static str> {
        let mut v = vec![];
        for (on, name) in [
            (self.ea_n.is_some(), "elasticity"),
            (self.drum_scale.is_some(), "scale"),
            (self.pulley_radius_m.is_some(), "pulley"),
            (self.backlash_m.is_some(), "backlash"),
            (self.time_offset_s.is_some(), "time-offset"),
            (self.drum_buildup_per_m.is_some(), "spool-buildup"),
            (self.compliance_m_per_n.is_some(), "compliance"),
            (self.loadcell_gain.is_some(), "loadcell-gain"),
            (self.friction_mu_theta.is_some(), "friction"),
        ] {
            if on {
                v.push(name);
            }
        }
        v
    }

    /// Every value finite and inside [`EFFECT_RANGES`], vectors of `n` values, sigmas finite,
    /// non-negative and only beside their value. Err: (key, message).
    pub fn check(&self, n: usize) -> Result<(), (String, String)> {
        let range = |key: &str| EFFECT_RANGES.iter().find(|r| r.0 == key).copied().expect("every effect key has a range");
        // (value key, values, sigma key, sigmas)
        type Keyed<'a> = (&'a str, &'a Option<Vec<f64>>, &'a str, &'a Option<Vec<f64>>);
        let vectors: [Keyed; 8] = [
            ("ea_n", &self.ea_n, "ea_sigma_n", &self.ea_sigma_n),
            ("drum_scale", &self.drum_scale, "drum_scale_sigma", &self.drum_scale_sigma),
            ("pulley_radius_m", &self.pulley_radius_m, "pulley_radius_sigma_m", &self.pulley_radius_sigma_m),
            ("backlash_m", &self.backlash_m, "backlash_sigma_m", &self.backlash_sigma_m),
            ("drum_buildup_per_m", &self.drum_buildup_per_m, "drum_buildup_sigma_per_m", &self.drum_buildup_sigma_per_m),
            ("loadcell_gain", &self.loadcell_gain, "loadcell_gain_sigma", &self.loadcell_gain_sigma),
            ("friction_mu_theta", &self.friction_mu_theta, "friction_mu_theta_sigma", &self.friction_mu_theta_sigma),
            ("compliance_m_per_n", &self.compliance_m_per_n, "compliance_sigma_m_per_n", &self.compliance_sigma_m_per_n),
        ];
        let value = |key: &str, v: f64| -> Result<(), String> {
            let (_, lo, hi, unit) = range(key);
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(format!("{v} is outside the physical range {lo} to {hi}{}{unit}", if unit.is_empty() { "" } else { " " }));
            }
            Ok(())
        };
        let sigma = |v: f64| -> Result<(), String> {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("a 1-sigma must be finite and non-negative, got {v}"));
            }
            Ok(())
        };
        for (key, vals, skey, sigmas) in vectors {
            if let Some(v) = vals {
                if v.len() != n {
                    return Err((format!("effects.{key}"), format!("{} values for {n} cables: give one per cable", v.len())));
                }
                for (j, &x) in v.iter().enumerate() {
                    value(key, x).map_err(|m| (format!("effects.{key}[{j}]"), m))?;
                }
            }
            if let Some(s) = sigmas {
                if vals.is_none() {
                    return Err((format!("effects.{skey}"), format!("a sigma without its value: give effects.{key} too")));
                }
                if s.len() != n {
                    return Err((format!("effects.{skey}"), format!("{} values for {n} cables: give one per cable", s.len())));
                }
                for (j, &x) in s.iter().enumerate() {
                    sigma(x).map_err(|m| (format!("effects.{skey}[{j}]"), m))?;
                }
            }
        }
        if let Some(d) = self.time_offset_s {
            value("time_offset_s", d).map_err(|m| ("effects.time_offset_s".to_string(), m))?;
        }
        if let Some(s) = self.time_offset_sigma_s {
            if self.time_offset_s.is_none() {
                return Err(("effects.time_offset_sigma_s".into(), "a sigma without its value: give effects.time_offset_s too".into()));
            }
            sigma(s).map_err(|m| ("effects.time_offset_sigma_s".to_string(), m))?;
        }
        Ok(())
    }
}

/// 1-based line of the first line in `text` that sets `key` (`key =` after optional spaces),
/// after the `[effects]` header when the key is an effect's.
fn key_line(text: &str, key: &str) -> Option<usize> {
    let (table, bare) = match key.strip_prefix("effects.") {
        Some(k) => (Some("[effects]"), k),
        None => (None, key),
    };
    let bare = bare.split('[').next().unwrap_or(bare);
    let mut inside = table.is_none();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        if let Some(h) = table {
            if t.starts_with('[') {
                inside = t.starts_with(h);
                continue;
            }
        }
        if inside && t.strip_prefix(bare).is_some_and(|r| r.trim_start().starts_with('=')) {
            return Some(i + 1);
        }
    }
    None
}

/// Largest magnitude of an anchor coordinate or an encoder offset a parameter file may hold, m.
/// The largest cable robots span tens of metres; a value beyond this is a unit or a typing error.
pub const PLAUSIBLE_M: f64 = 1000.0;

/// A calibrated parameter set with its provenance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamsFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// Increases with every accepted parameter set.
    pub version: u64,
    /// When the set was made, seconds since the Unix epoch.
    pub created_unix_s: f64,
    /// Robot name from the configuration.
    pub robot: String,
    /// Where the data came from (recording path, or `start-up` / `recalibration`).
    pub source: String,
    /// Anchors `A_j`, m, tracker frame.
    pub anchors_m: Vec<[f64; 3]>,
    /// Encoder offsets `L0_j`, m.
    pub l0_m: Vec<f64>,
    /// 1-sigma of the anchors, m (all NaN when unknown: then not written).
    #[serde(default, skip_serializing_if = "all_nan3")]
    pub anchor_sigma_m: Vec<[f64; 3]>,
    /// 1-sigma of the offsets, m (all NaN when unknown: then not written).
    #[serde(default, skip_serializing_if = "all_nan")]
    pub l0_sigma_m: Vec<f64>,
    /// Co-registration RMS on the calibration data, m (NaN when unknown: then not written).
    #[serde(default = "nan", skip_serializing_if = "is_nan")]
    pub rms_m: f64,
    /// Co-registration RMS on held-out data, m (NaN if none held out: then not written).
    #[serde(default = "nan", skip_serializing_if = "is_nan")]
    pub heldout_rms_m: f64,
    /// The modelled effects (v2; none in a v1 file). Last: it is a TOML table.
    #[serde(default, skip_serializing_if = "Effects::is_empty")]
    pub effects: Effects,
}

// An unknown value is NaN in memory and absent from the file: no `nan` or `inf` is ever written.
fn nan() -> f64 {
    f64::NAN
}
fn is_nan(v: &f64) -> bool {
    v.is_nan()
}
fn all_nan(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_nan())
}
fn all_nan3(v: &[[f64; 3]]) -> bool {
    v.iter().flatten().all(|x| x.is_nan())
}

impl ParamsFile {
    /// Reads a parameter file; errors name the file, line and key.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, crate::ConfigError> {
        let path = path.as_ref();
        let err = |line, message| crate::ConfigError { file: Some(path.to_path_buf()), line, key: None, message };
        let text = crate::input::read_text(path).map_err(|e| err(None, format!("cannot read the file: {e}")))?;
        Self::parse(path, &text)
    }

    /// Parses the text of a parameter file; `path` names it in errors, which name the line and
    /// key.
    pub fn parse(path: &Path, text: &str) -> Result<Self, crate::ConfigError> {
        let err = |line, message| crate::ConfigError { file: Some(path.to_path_buf()), line, key: None, message };
        let p: ParamsFile =
            toml::from_str(text).map_err(|e| err(e.span().map(|s| crate::line_of(text, s.start)), e.message().trim().to_string()))?;
        if ![FORMAT, FORMAT_V4, FORMAT_V3, FORMAT_V2, FORMAT_V1].contains(&p.format.as_str()) {
            return Err(err(
                Some(1),
                format!("format is `{}`, expected `{FORMAT}` (or `{FORMAT_V4}`, `{FORMAT_V3}`, `{FORMAT_V2}`, `{FORMAT_V1}`)", p.format),
            ));
        }
        if p.format != FORMAT && (p.effects.compliance_m_per_n.is_some() || p.effects.compliance_sigma_m_per_n.is_some()) {
            let key = if p.effects.compliance_m_per_n.is_some() { "compliance_m_per_n" } else { "compliance_sigma_m_per_n" };
            return Err(crate::ConfigError {
                file: Some(path.to_path_buf()),
                line: key_line(text, &format!("effects.{key}")),
                key: Some(format!("effects.{key}")),
                message: format!("`{}` has no {key}: write format = \"{FORMAT}\"", p.format),
            });
        }
        if (p.format == FORMAT_V3 || p.format == FORMAT_V2) && !p.effects.tension_side_is_empty() {
            let e = &p.effects;
            let key = [
                ("loadcell_gain", e.loadcell_gain.is_some()),
                ("loadcell_gain_sigma", e.loadcell_gain_sigma.is_some()),
                ("friction_mu_theta", e.friction_mu_theta.is_some()),
                ("friction_mu_theta_sigma", e.friction_mu_theta_sigma.is_some()),
            ]
            .into_iter()
            .find(|k| k.1)
            .map_or("loadcell_gain", |k| k.0);
            return Err(crate::ConfigError {
                file: Some(path.to_path_buf()),
                line: key_line(text, &format!("effects.{key}")),
                key: Some(format!("effects.{key}")),
                message: format!("`{}` has no {key}: write format = \"{FORMAT}\"", p.format),
            });
        }
        if p.format == FORMAT_V2 && (p.effects.drum_buildup_per_m.is_some() || p.effects.drum_buildup_sigma_per_m.is_some()) {
            let key = if p.effects.drum_buildup_per_m.is_some() { "drum_buildup_per_m" } else { "drum_buildup_sigma_per_m" };
            return Err(crate::ConfigError {
                file: Some(path.to_path_buf()),
                line: key_line(text, &format!("effects.{key}")),
                key: Some(format!("effects.{key}")),
                message: format!("`{FORMAT_V2}` has no {key}: write format = \"{FORMAT}\""),
            });
        }
        if p.format == FORMAT_V1 && !p.effects.is_empty() {
            return Err(crate::ConfigError {
                file: Some(path.to_path_buf()),
                line: text.lines().position(|l| l.trim_start().starts_with("[effects]")).map(|i| i + 1),
                key: Some("effects".into()),
                message: format!("`{FORMAT_V1}` has no [effects] table: write format = \"{FORMAT}\""),
            });
        }
        // The cable count first: the effects' vectors are judged against it.
        if p.anchors_m.len() != p.l0_m.len() {
            return Err(crate::ConfigError {
                file: Some(path.to_path_buf()),
                line: key_line(text, "l0_m"),
                key: Some("l0_m".into()),
                message: format!("{} anchors but {} offsets: give one offset per anchor", p.anchors_m.len(), p.l0_m.len()),
            });
        }
        p.effects.check(p.anchors_m.len()).map_err(|(key, message)| crate::ConfigError {
            file: Some(path.to_path_buf()),
            line: key_line(text, &key),
            key: Some(key),
            message,
        })?;
        let mut p = p;
        // A v1 file is a v5 file without effects, a v2 one without the drum build-up, the
        // tension side and the compliance, a v3 one without the last two, a v4 one without the
        // compliance: held (and written back) as v5.
        p.format = FORMAT.into();
        let n = p.anchors_m.len();
        if p.anchor_sigma_m.is_empty() {
            p.anchor_sigma_m = vec![[f64::NAN; 3]; n];
        }
        if p.l0_sigma_m.is_empty() {
            p.l0_sigma_m = vec![f64::NAN; n];
        }
        p.check_finite().map_err(|m| {
            // The key the message starts with, for its line.
            let key = m.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).next().unwrap_or("");
            err(key_line(text, key), m)
        })?;
        Ok(p)
    }

    /// The file's geometry: the one conversion from the file's keys (`anchors_m`, `l0_m`).
    pub fn geometry(&self) -> Geometry {
        Geometry { anchors: self.anchors_m.clone(), l0: self.l0_m.clone() }
    }

    /// The file's 1-sigma values (`anchor_sigma_m`, `l0_sigma_m`; NaN when unknown).
    pub fn sigmas(&self) -> Sigmas {
        Sigmas { anchors: self.anchor_sigma_m.clone(), l0: self.l0_sigma_m.clone() }
    }

    /// A file holding `geometry` and `sigma`: the one conversion to the file's keys. Version 0,
    /// no provenance, RMS values unknown and no effects: callers set those with
    /// `ParamsFile { version, robot, .. ParamsFile::from_geometry(g, s) }`.
    pub fn from_geometry(geometry: &Geometry, sigma: &Sigmas) -> ParamsFile {
        ParamsFile {
            format: FORMAT.into(),
            version: 0,
            created_unix_s: 0.0,
            robot: String::new(),
            source: String::new(),
            anchors_m: geometry.anchors.clone(),
            l0_m: geometry.l0.clone(),
            anchor_sigma_m: sigma.anchors.clone(),
            l0_sigma_m: sigma.l0.clone(),
            rms_m: f64::NAN,
            heldout_rms_m: f64::NAN,
            effects: Effects::default(),
        }
    }

    /// Every number finite: anchors and offsets always; sigmas and RMS values finite and
    /// non-negative, or unknown (NaN, all of a vector at once), never infinite. The message
    /// names the key. The geometry and its sigmas are checked by [`Geometry::check`] and
    /// [`Sigmas::check`] (the one validation of them); this names the file's keys.
    pub fn check_finite(&self) -> Result<(), String> {
        let n = self.anchors_m.len();
        match self.geometry().check() {
            Ok(()) | Err(GeometryError::NoCables) => {}
            Err(GeometryError::NotFinite { cable: j, field: Field::Anchor }) => {
                return Err(format!("anchors_m[{j}] is not finite: {:?}", self.anchors_m[j]));
            }
            Err(GeometryError::NotFinite { cable: j, .. }) => return Err(format!("l0_m[{j}] is not finite: {}", self.l0_m[j])),
            Err(e) => return Err(format!("l0_m: {e}")),
        }
        // Finite is not enough: a robot's anchors and cable offsets are metres, not kilometres.
        if let Some((j, a)) = self.anchors_m.iter().enumerate().find(|(_, a)| a.iter().any(|v| v.abs() > PLAUSIBLE_M)) {
            return Err(format!(
                "anchors_m[{j}] = {a:?} m is more than {PLAUSIBLE_M} m from the origin: a parameter file holds metres in the tracker's frame"
            ));
        }
        if let Some((j, l)) = self.l0_m.iter().enumerate().find(|(_, l)| l.abs() > PLAUSIBLE_M) {
            return Err(format!("l0_m[{j}] = {l} m is more than {PLAUSIBLE_M} m: an encoder offset is a cable length in metres"));
        }
        match self.sigmas().check(n) {
            Ok(()) => {}
            Err(GeometryError::Length { field: Field::AnchorSigma, .. })
            | Err(GeometryError::NotFinite { field: Field::AnchorSigma, .. })
            | Err(GeometryError::NegativeSigma { field: Field::AnchorSigma, .. }) => {
                return Err(format!(
                    "anchor_sigma_m must be {n} finite non-negative triples (or absent when unknown): {:?}",
                    self.anchor_sigma_m
                ));
            }
            Err(_) => {
                return Err(format!("l0_sigma_m must be {n} finite non-negative values (or absent when unknown): {:?}", self.l0_sigma_m))
            }
        }
        for (key, v) in [("rms_m", self.rms_m), ("heldout_rms_m", self.heldout_rms_m), ("created_unix_s", self.created_unix_s)] {
            if v.is_infinite() || (key == "created_unix_s" && v.is_nan()) {
                return Err(format!("{key} is not finite: {v}"));
            }
        }
        self.effects.check(n).map_err(|(k, m)| format!("{k}: {m}"))?;
        Ok(())
    }

    /// Writes the file atomically (temporary file + rename). Refuses (`InvalidData`, naming the
    /// key) a set with a non-finite anchor or offset, or an infinite sigma or RMS.
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
        self.check_finite()
            .map_err(|m| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("refusing to write a parameter file: {m}")))?;
        let text = self.to_text().map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
        crate::write_atomic(path.as_ref(), text.as_bytes())
    }

    /// The file's text, as [`ParamsFile::save_atomic`] writes it.
    pub fn to_text(&self) -> Result<String, String> {
        toml::to_string(self).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_bad_format() {
        let dir = std::env::temp_dir().join(format!("taut-params-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = ParamsFile {
            format: FORMAT.into(),
            version: 2,
            created_unix_s: 1.5e9,
            robot: "r".into(),
            source: "x.csv".into(),
            anchors_m: vec![[1.0, 2.0, 3.0]; 3],
            l0_m: vec![0.1; 3],
            anchor_sigma_m: vec![[1e-4; 3]; 3],
            l0_sigma_m: vec![1e-4; 3],
            rms_m: 1e-3,
            heldout_rms_m: 1.1e-3,
            effects: Effects::default(),
        };
        let f = dir.join("p.toml");
        p.save_atomic(&f).unwrap();
        assert_eq!(ParamsFile::load(&f).unwrap(), p);
        std::fs::write(&f, "format = \"other\"\n").unwrap();
        assert!(ParamsFile::load(&f).is_err());
        // Unknown values are NaN in memory and absent from the file; nothing non-finite is written.
        let unknown = ParamsFile {
            anchor_sigma_m: vec![[f64::NAN; 3]; 3],
            l0_sigma_m: vec![f64::NAN; 3],
            rms_m: f64::NAN,
            heldout_rms_m: f64::NAN,
            ..p.clone()
        };
        unknown.save_atomic(&f).unwrap();
        let text = std::fs::read_to_string(&f).unwrap();
        assert!(!text.contains("nan") && !text.contains("inf"), "{text}");
        let back = ParamsFile::load(&f).unwrap();
        assert!(back.rms_m.is_nan() && back.l0_sigma_m.len() == 3 && back.anchor_sigma_m[2][1].is_nan());
        for bad in [
            ParamsFile { rms_m: f64::INFINITY, ..p.clone() },
            ParamsFile { anchors_m: vec![[1.0, f64::NAN, 3.0]; 3], ..p.clone() },
            ParamsFile { l0_m: vec![0.1, 1e308 * 10.0, 0.1], ..p.clone() },
            ParamsFile { l0_sigma_m: vec![1e-4, f64::NAN, 1e-4], ..p.clone() },
        ] {
            let e = bad.save_atomic(&f).unwrap_err();
            assert_eq!(e.kind(), std::io::ErrorKind::InvalidData, "{e}");
        }
        assert_eq!(std::fs::read_to_string(&f).unwrap(), text, "a refused write leaves the file as it was");
        assert!(text.contains("l0_m = [0.1,"), "{text}");
        std::fs::write(&f, text.replace("l0_m = [0.1,", "l0_m = [inf,")).unwrap();
        let e = ParamsFile::load(&f).unwrap_err();
        assert!(e.to_string().contains("l0_m[0]"), "{e}");
        // Finite but not metres of a robot: refused, naming the key, its line and the file.
        for (from, to, key) in
            [("anchors_m = [[1.0,", "anchors_m = [[-1e300,", "anchors_m[0]"), ("l0_m = [0.1,", "l0_m = [-1e6,", "l0_m[0]")]
        {
            std::fs::write(&f, text.replace(from, to)).unwrap();
            let e = ParamsFile::load(&f).unwrap_err();
            let line = text.lines().position(|l| l.starts_with(key.split('[').next().unwrap())).unwrap() + 1;
            assert_eq!(e.line, Some(line), "{e}");
            assert!(e.to_string().contains(key) && e.to_string().contains("p.toml"), "{e}");
        }
        // Three anchors and four offsets: the offsets are blamed, not an effect.
        std::fs::write(&f, text.replace("l0_m = [0.1,", "l0_m = [0.1, 0.1,")).unwrap();
        let e = ParamsFile::load(&f).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("l0_m"), "{e}");
        assert!(e.to_string().contains("3 anchors but 4 offsets"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Version 3 carries the drum build-up; a version 2 file is still read (without it), and a
    /// version 2 file that sets it is refused naming the key and its line.
    #[test]
    fn version_3_carries_drum_buildup_and_version_2_is_still_read() {
        let v2 = "format = \"taut-params v2\"\nversion = 3\ncreated_unix_s = 1.5e9\nrobot = \"r\"\nsource = \"x.csv\"\n\
                  anchors_m = [[1.0, 2.0, 3.0], [-1.0, 2.0, 3.0]]\nl0_m = [0.1, 0.2]\n\n[effects]\ndrum_scale = [1.003, 0.998]\n";
        let p = ParamsFile::parse(Path::new("v2.toml"), v2).unwrap();
        assert_eq!(p.format, FORMAT, "read as the current format (written back as v5)");
        assert_eq!(p.effects.drum_scale, Some(vec![1.003, 0.998]));
        assert_eq!(p.effects.drum_buildup_per_m, None);
        let set = format!("{v2}drum_buildup_per_m = [-0.01, 0.02]\n");
        let e = ParamsFile::parse(Path::new("v2.toml"), &set).unwrap_err();
        assert_eq!((e.key.as_deref(), e.line), (Some("effects.drum_buildup_per_m"), Some(11)), "{e}");
        let v3 = set.replace(FORMAT_V2, FORMAT_V3);
        let p = ParamsFile::parse(Path::new("v3.toml"), &v3).unwrap();
        assert_eq!(p.effects.drum_buildup_per_m, Some(vec![-0.01, 0.02]));
        assert_eq!(p.effects.names(), vec!["scale", "spool-buildup"]);
        assert_eq!(ParamsFile::parse(Path::new("v3.toml"), &p.to_text().unwrap()).unwrap().effects, p.effects);
        let e = ParamsFile::parse(Path::new("v3.toml"), &v3.replace("-0.01,", "-0.5,")).unwrap_err();
        assert!(e.to_string().contains("drum_buildup_per_m[0]"), "{e}");
    }

    /// Version 4 carries the tension side (load-cell gain, friction) with their sigmas; a
    /// version 3 file that sets them is refused naming the key and its line; hostile values
    /// name the key and the cable.
    #[test]
    fn version_4_carries_the_tension_side_and_version_3_is_still_read() {
        let v3 = "format = \"taut-params v3\"\nversion = 3\ncreated_unix_s = 1.5e9\nrobot = \"r\"\nsource = \"x.csv\"\n\
                  anchors_m = [[1.0, 2.0, 3.0], [-1.0, 2.0, 3.0]]\nl0_m = [0.1, 0.2]\n\n[effects]\ndrum_buildup_per_m = [-0.01, 0.02]\n";
        let p = ParamsFile::parse(Path::new("v3.toml"), v3).unwrap();
        assert_eq!((p.format.as_str(), p.effects.loadcell_gain.as_ref()), (FORMAT, None));
        let tension = "loadcell_gain = [1.04, 0.97]\nloadcell_gain_sigma = [0.002, 0.003]\nfriction_mu_theta = [0.2, 0.15]\n\
                       friction_mu_theta_sigma = [0.01, 0.01]\n";
        let set = format!("{v3}{tension}");
        let e = ParamsFile::parse(Path::new("v3.toml"), &set).unwrap_err();
        assert_eq!((e.key.as_deref(), e.line), (Some("effects.loadcell_gain"), Some(11)), "{e}");
        let v4 = set.replace(FORMAT_V3, FORMAT_V4);
        let p = ParamsFile::parse(Path::new("v4.toml"), &v4).unwrap();
        assert_eq!(p.effects.loadcell_gain, Some(vec![1.04, 0.97]));
        assert_eq!(p.effects.friction_mu_theta_sigma, Some(vec![0.01, 0.01]));
        assert_eq!(p.effects.names(), vec!["spool-buildup", "loadcell-gain", "friction"]);
        assert_eq!(ParamsFile::parse(Path::new("v4.toml"), &p.to_text().unwrap()).unwrap().effects, p.effects);
        // (replace, by, the key named, its line)
        for (a, b, key, line) in [
            ("[1.04,", "[0.0,", "effects.loadcell_gain[0]", 11),
            ("[1.04,", "[-1.04,", "effects.loadcell_gain[0]", 11),
            ("0.97]", "30.0]", "effects.loadcell_gain[1]", 11),
            ("[1.04, 0.97]", "[1.04]", "effects.loadcell_gain", 11),
            ("[0.2,", "[-0.2,", "effects.friction_mu_theta[0]", 13),
            ("0.15]", "5.0]", "effects.friction_mu_theta[1]", 13),
            ("0.15]", "nan]", "effects.friction_mu_theta[1]", 13),
            ("[0.2, 0.15]", "[0.2, 0.15, 0.1]", "effects.friction_mu_theta", 13),
            ("[0.01, 0.01]", "[-0.01, 0.01]", "effects.friction_mu_theta_sigma[0]", 14),
        ] {
            let e = ParamsFile::parse(Path::new("v4.toml"), &v4.replace(a, b)).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some(key), Some(line)), "{a} -> {b}: {e}");
            assert!(e.to_string().contains("v4.toml"), "{e}");
        }
        let e = ParamsFile::parse(Path::new("v4.toml"), &v4.replace("friction_mu_theta = [0.2, 0.15]\n", "")).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("effects.friction_mu_theta_sigma"), "a sigma without its value: {e}");
    }

    /// Version 5 carries the length-independent compliance with its sigma; a version 4 (or older)
    /// file that sets it is refused naming the key and its line; hostile values name the key and
    /// the cable.
    #[test]
    fn version_5_carries_the_compliance_and_version_4_is_still_read() {
        let v4 = "format = \"taut-params v4\"\nversion = 3\ncreated_unix_s = 1.5e9\nrobot = \"r\"\nsource = \"x.csv\"\n\
                  anchors_m = [[1.0, 2.0, 3.0], [-1.0, 2.0, 3.0]]\nl0_m = [0.1, 0.2]\n\n[effects]\nloadcell_gain = [1.04, 0.97]\n";
        let p = ParamsFile::parse(Path::new("v4.toml"), v4).unwrap();
        assert_eq!((p.format.as_str(), p.effects.compliance_m_per_n.as_ref()), (FORMAT, None));
        let set = format!("{v4}compliance_m_per_n = [1.5e-6, 0.0]\ncompliance_sigma_m_per_n = [1e-7, 1e-7]\n");
        for old in [FORMAT_V4, FORMAT_V3, FORMAT_V2] {
            let text = set.replace(FORMAT_V4, old).replace("loadcell_gain = [1.04, 0.97]\n", "");
            let e = ParamsFile::parse(Path::new("old.toml"), &text).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some("effects.compliance_m_per_n"), Some(10)), "{old}: {e}");
            assert!(e.to_string().contains("old.toml"), "{e}");
        }
        let v5 = set.replace(FORMAT_V4, FORMAT);
        let p = ParamsFile::parse(Path::new("v5.toml"), &v5).unwrap();
        assert_eq!(p.effects.compliance_m_per_n, Some(vec![1.5e-6, 0.0]));
        assert_eq!(p.effects.names(), vec!["compliance", "loadcell-gain"]);
        assert_eq!(ParamsFile::parse(Path::new("v5.toml"), &p.to_text().unwrap()).unwrap().effects, p.effects);
        // (replace, by, the key named, its line)
        for (a, b, key, line) in [
            ("[1.5e-6,", "[-1.5e-6,", "effects.compliance_m_per_n[0]", 11),
            ("0.0]\n", "0.5]\n", "effects.compliance_m_per_n[1]", 11),
            ("0.0]\n", "nan]\n", "effects.compliance_m_per_n[1]", 11),
            ("0.0]\n", "inf]\n", "effects.compliance_m_per_n[1]", 11),
            ("[1.5e-6, 0.0]", "[1.5e-6]", "effects.compliance_m_per_n", 11),
            ("[1e-7, 1e-7]", "[-1e-7, 1e-7]", "effects.compliance_sigma_m_per_n[0]", 12),
        ] {
            let e = ParamsFile::parse(Path::new("v5.toml"), &v5.replacen(a, b, 1)).unwrap_err();
            assert_eq!((e.key.as_deref(), e.line), (Some(key), Some(line)), "{a} -> {b}: {e}");
            assert!(e.to_string().contains("v5.toml"), "{e}");
        }
        let e = ParamsFile::parse(Path::new("v5.toml"), &v5.replace("compliance_m_per_n = [1.5e-6, 0.0]\n", "")).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("effects.compliance_sigma_m_per_n"), "a sigma without its value: {e}");
    }

    /// The one conversion between the file and the shared geometry types, both ways, and the
    /// shared validation naming the file's keys.
    #[test]
    fn geometry_conversion_round_trips_and_names_the_key() {
        let g = Geometry::new(vec![[1.0, 2.0, 3.0], [-1.0, 2.0, 3.5]], vec![0.1, -0.2]).unwrap();
        let s = Sigmas { anchors: vec![[1e-4, 2e-4, 3e-4]; 2], l0: vec![5e-4; 2] };
        let f = ParamsFile { version: 7, robot: "r".into(), ..ParamsFile::from_geometry(&g, &s) };
        assert_eq!(
            (f.anchors_m.clone(), f.l0_m.clone(), f.anchor_sigma_m.clone(), f.l0_sigma_m.clone()),
            (g.anchors.clone(), g.l0.clone(), s.anchors.clone(), s.l0.clone())
        );
        assert_eq!((f.format.as_str(), f.version, f.effects.is_empty()), (FORMAT, 7, true));
        assert!(f.rms_m.is_nan() && f.heldout_rms_m.is_nan());
        assert_eq!((f.geometry(), f.sigmas()), (g.clone(), s.clone()));
        assert_eq!(f.check_finite(), Ok(()));
        let unknown = ParamsFile::from_geometry(&g, &Sigmas::unknown(2));
        assert_eq!(unknown.check_finite(), Ok(()));
        let mut neg = f.clone();
        neg.l0_sigma_m[1] = -1e-4;
        assert!(neg.check_finite().unwrap_err().starts_with("l0_sigma_m"), "a negative sigma is refused");
        let mut neg = f.clone();
        neg.anchor_sigma_m[0][2] = f64::INFINITY;
        assert!(neg.check_finite().unwrap_err().starts_with("anchor_sigma_m"));
        let mut short = f.clone();
        short.l0_m.pop();
        assert!(short.check_finite().unwrap_err().starts_with("l0_m"));
    }
}
