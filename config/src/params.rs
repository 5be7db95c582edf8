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
    /// 1-sigma of the anchors, m.
    pub anchor_sigma_m: Vec<[f64; 3]>,
    /// 1-sigma of the offsets, m.
    pub l0_sigma_m: Vec<f64>,
    /// Co-registration RMS on the calibration data, m.
    pub rms_m: f64,
    /// Co-registration RMS on held-out data, m (NaN if none held out).
    pub heldout_rms_m: f64,
}

impl ParamsFile {
    /// Reads a parameter file; errors name the file, line and key.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, crate::ConfigError> {
        let path = path.as_ref();
        let err = |line, message| crate::ConfigError { file: Some(path.to_path_buf()), line, key: None, message };
        let text = crate::input::read_text(path).map_err(|e| err(None, format!("cannot read the file: {e}")))?;
        let p: ParamsFile = toml::from_str(&text)
            .map_err(|e| err(e.span().map(|s| crate::line_of(&text, s.start)), e.message().trim().to_string()))?;
        if p.format != FORMAT {
            return Err(err(Some(1), format!("format is `{}`, expected `{FORMAT}`", p.format)));
        }
        if p.anchors_m.len() != p.l0_m.len() {
            return Err(err(None, format!("{} anchors but {} offsets", p.anchors_m.len(), p.l0_m.len())));
        }
        Ok(p)
    }

    /// Writes the file atomically (temporary file + rename).
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
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
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
