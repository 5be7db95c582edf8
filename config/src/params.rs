//! `taut-params v1`: a calibrated parameter set as written by `taut calibrate --out` and by the
//! daemon on every accepted calibration (TOML, written atomically).
//!
//! ```toml
//! format = "taut-params v1"
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
//! ```

use serde::{Deserialize, Serialize};
use std::path::Path;

/// The format tag of a parameter file.
pub const FORMAT: &str = "taut-params v1";

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
        let p: ParamsFile =
            toml::from_str(&text).map_err(|e| err(e.span().map(|s| crate::line_of(&text, s.start)), e.message().trim().to_string()))?;
        if p.format != FORMAT {
            return Err(err(Some(1), format!("format is `{}`, expected `{FORMAT}`", p.format)));
        }
        if p.anchors_m.len() != p.l0_m.len() {
            return Err(err(None, format!("{} anchors but {} offsets", p.anchors_m.len(), p.l0_m.len())));
        }
        let mut p = p;
        let n = p.anchors_m.len();
        if p.anchor_sigma_m.is_empty() {
            p.anchor_sigma_m = vec![[f64::NAN; 3]; n];
        }
        if p.l0_sigma_m.is_empty() {
            p.l0_sigma_m = vec![f64::NAN; n];
        }
        p.check_finite().map_err(|m| err(None, m))?;
        Ok(p)
    }

    /// Every number finite: anchors and offsets always; sigmas and RMS values finite or unknown
    /// (NaN, all of a vector at once), never infinite. The message names the key.
    pub fn check_finite(&self) -> Result<(), String> {
        let n = self.anchors_m.len();
        if let Some(j) = self.anchors_m.iter().position(|a| !a.iter().all(|v| v.is_finite())) {
            return Err(format!("anchors_m[{j}] is not finite: {:?}", self.anchors_m[j]));
        }
        if let Some(j) = self.l0_m.iter().position(|v| !v.is_finite()) {
            return Err(format!("l0_m[{j}] is not finite: {}", self.l0_m[j]));
        }
        let known = |v: &[f64]| v.iter().all(|x| x.is_finite()) || v.iter().all(|x| x.is_nan());
        let flat: Vec<f64> = self.anchor_sigma_m.iter().flatten().copied().collect();
        if self.anchor_sigma_m.len() != n || !known(&flat) {
            return Err(format!("anchor_sigma_m must be {n} finite triples (or absent when unknown): {:?}", self.anchor_sigma_m));
        }
        if self.l0_sigma_m.len() != n || !known(&self.l0_sigma_m) {
            return Err(format!("l0_sigma_m must be {n} finite values (or absent when unknown): {:?}", self.l0_sigma_m));
        }
        for (key, v) in [("rms_m", self.rms_m), ("heldout_rms_m", self.heldout_rms_m), ("created_unix_s", self.created_unix_s)] {
            if v.is_infinite() || (key == "created_unix_s" && v.is_nan()) {
                return Err(format!("{key} is not finite: {v}"));
            }
        }
        Ok(())
    }

    /// Writes the file atomically (temporary file + rename). Refuses (`InvalidData`, naming the
    /// key) a set with a non-finite anchor or offset, or an infinite sigma or RMS.
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
        self.check_finite()
            .map_err(|m| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("refusing to write a parameter file: {m}")))?;
        let text = toml::to_string(self).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
        crate::write_atomic(path.as_ref(), text.as_bytes())
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
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
