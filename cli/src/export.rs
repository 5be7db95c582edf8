//! `taut export REC --mcap OUT.mcap`: a recording (cdpr-recording v1 CSV, or an MCAP file taut
//! wrote) as an MCAP file for Foxglove, PlotJuggler and rosbag2 (channels in
//! `taut_config::mcap`).

use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `taut export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    /// The recording (cdpr-recording v1 CSV; an MCAP file is recognised by its first bytes).
    pub recording: PathBuf,
    /// Write the recording as MCAP to this file, atomically (the only output format).
    #[arg(long, value_name = "OUT.mcap")]
    pub mcap: PathBuf,
}

/// Runs `taut export`.
pub fn run(a: &ExportArgs) -> Result<()> {
    let out = &a.mcap;
    taut_config::atomic::check_output(out, &[a.recording.as_path()]).with_context(|| format!("--mcap {}", out.display()))?;
    let (rec, rep) = crate::calibrate::load_recording(&a.recording)?;
    let source = format!("taut export {}", a.recording.display());
    taut_config::mcap::export(&rec, out, &source).with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{} samples ({} usable, {} cables{}) -> {}",
        rep.rows,
        rep.usable_rows,
        rec.n_cables,
        if rec.f.is_some() { ", with tensions" } else { ", no tensions" },
        out.display()
    );
    Ok(())
}
