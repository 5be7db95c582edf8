//! `taut demo`: a simulated ARAS-CAM-like robot calibrating itself, end to end.

use crate::calibrate::{pipeline, progress};
use crate::report;
use crate::simulate::{scenario, SimulateArgs};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `taut demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    sim: SimulateArgs,
    /// Write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write figures (SVG and PNG) into this directory.
    #[arg(long)]
    plot: Option<PathBuf>,
}

pub fn run(a: &DemoArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = a.sim.config.iter().map(|p| p.as_path()).collect();
    let files: Vec<crate::outputs::Output> =
        [("--output", Some(&a.sim.output)), ("--json", a.json.as_ref()), ("--truth", a.sim.truth.as_ref())]
            .into_iter()
            .filter_map(|(f, p)| p.map(|p| (f, p.as_path())))
            .collect();
    let dirs: Vec<crate::outputs::Output> = a.plot.iter().map(|p| ("--plot", p.as_path())).collect();
    crate::outputs::check(&files, &dirs, &inputs)?;
    let s = scenario(&a.sim)?;
    println!(
        "taut demo: simulated {} ({} cables), seed {}, {:.0} s excitation at {:.0} Hz, loose-cable excursions {:.0}%",
        s.robot.robot.name,
        s.robot.cables.len(),
        a.sim.seed,
        s.duration_s,
        s.rate_hz,
        s.loose_fraction * 100.0
    );
    println!("taut demo: writing the recording to {} (-o FILE for elsewhere)", a.sim.output.display());
    let pb = progress(5);
    pb.set_message("simulating");
    let run = taut_sim::try_simulate(&s).map_err(|e| anyhow::anyhow!("cannot simulate this robot: {e}"))?;
    pb.inc(1);
    let rec = &run.recording;
    run.recording.save_atomic(&a.sim.output).with_context(|| format!("writing {}", a.sim.output.display()))?;
    if let Some(t) = &a.sim.truth {
        crate::simulate::write_truth(t, &s, a.sim.seed, &run)?;
    }
    // Read back what was written: the demo calibrates the file, as `taut calibrate` would.
    let (rec_file, parse) = taut_config::recording::Recording::load(&a.sim.output)?;
    debug_assert_eq!(rec_file.len(), rec.len());
    // The demo shows what force weighting changes: it always runs the unweighted comparison.
    let out = pipeline(&rec_file, &s.robot, true, &pb)?;
    pb.finish_and_clear();
    let phases = rec.phase.as_ref().map(|p| p.iter().filter(|&&k| k >= 0).count()).unwrap_or(0);
    println!(
        "recorded {} ({} samples: {} in the three-phase initialisation, {} with a loose cable)",
        a.sim.output.display(),
        rec.len(),
        phases,
        run.loose_samples
    );
    println!();
    let truth = run.truth.geometry();
    report::print_calibration(&rec_file, &parse, &out, Some(&truth));
    if let Some(j) = &a.json {
        let v = report::json(&rec_file, &parse, &out, Some(&truth));
        taut_config::write_atomic(j, serde_json::to_string_pretty(&v)?.as_bytes()).with_context(|| format!("writing {}", j.display()))?;
    }
    if let Some(dir) = &a.plot {
        report::plots(dir, &inputs, &rec_file, &s.robot, &out)?;
        println!("figures written to {}", dir.display());
    }
    Ok(())
}
