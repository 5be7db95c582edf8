//! The `[recording]` and `[telemetry]` tables: what `taut start` writes and what it serves live.
//!
//! ```toml
//! [recording]
//! format = "both"        # "csv" | "mcap" | "both" (default): cdpr-recording v1 CSV and/or MCAP
//!
//! [telemetry]
//! enabled = false        # Foxglove WebSocket server (off by default)
//! bind = "127.0.0.1"     # an IP address; anything but loopback exposes the robot's data
//! port = 8765            # Foxglove's default
//! ```

use serde::{Deserialize, Serialize};

/// Which files a run is recorded to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum RecordingFormat {
    /// `cdpr-recording v1` CSV only.
    Csv,
    /// MCAP only (Foxglove, PlotJuggler, rosbag2).
    Mcap,
    /// Both, side by side (`start-T.csv` and `start-T.mcap`).
    #[default]
    Both,
}

impl RecordingFormat {
    /// A CSV is written.
    pub fn csv(self) -> bool {
        matches!(self, RecordingFormat::Csv | RecordingFormat::Both)
    }
    /// An MCAP file is written.
    pub fn mcap(self) -> bool {
        matches!(self, RecordingFormat::Mcap | RecordingFormat::Both)
    }
}

/// The `[recording]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingConfig {
    /// `"csv"`, `"mcap"` or `"both"`.
    pub format: RecordingFormat,
}

/// The `[telemetry]` table: live channels over the Foxglove WebSocket protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TelemetryConfig {
    /// Serve telemetry (default false).
    pub enabled: bool,
    /// IP address to listen on (default `127.0.0.1`: this machine only).
    pub bind: String,
    /// TCP port (default 8765, Foxglove's default; 0 picks a free port, printed at start).
    pub port: u16,
    /// Most clients served at once (default 4).
    pub max_clients: usize,
}

impl Default for TelemetryConfig {
    fn default() -> Self {
        TelemetryConfig { enabled: false, bind: "127.0.0.1".into(), port: 8765, max_clients: 4 }
    }
}

impl TelemetryConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.bind.parse::<std::net::IpAddr>().is_err() {
            return Err((
                "bind".into(),
                format!(
                    "`{}` is not an IP address; give e.g. \"127.0.0.1\" (this machine only) or \"0.0.0.0\" (every interface)",
                    crate::recording::excerpt(&self.bind)
                ),
            ));
        }
        if !(1..=64).contains(&self.max_clients) {
            return Err(("max_clients".into(), format!("{} is out of range; give 1 to 64", self.max_clients)));
        }
        Ok(())
    }

    /// The socket address to listen on (after [`TelemetryConfig::validate`]).
    pub fn addr(&self) -> Option<std::net::SocketAddr> {
        Some(std::net::SocketAddr::new(self.bind.parse().ok()?, self.port))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_off_and_local_and_bad_values_are_named() {
        let t = TelemetryConfig::default();
        assert!(!t.enabled);
        assert!(t.addr().unwrap().ip().is_loopback());
        assert_eq!(RecordingConfig::default().format, RecordingFormat::Both);
        let bad = TelemetryConfig { bind: "localhost:80".into(), ..t.clone() };
        assert_eq!(bad.validate().unwrap_err().0, "bind");
        let bad = TelemetryConfig { max_clients: 0, ..t };
        assert_eq!(bad.validate().unwrap_err().0, "max_clients");
    }
}
