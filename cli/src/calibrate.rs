//! `taut calibrate REC.csv`: initialise and calibrate from any recording, with no prior geometry.
//! Without a tracker in any row: self-calibration from dwell poses (`crate::notracker`).

use crate::report;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use taut_calib::{init, metrics, CalibOptions, CalibReport};
use taut_config::recording::{ParseReport, Recording};
use taut_config::RobotConfig;

/// Arguments of `taut calibrate`.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The recording: cdpr-recording v1 CSV, or an MCAP file taut wrote (recognised by its
    /// first bytes).
    pub recording: PathBuf,
    /// Robot configuration (platform points, noise model). Without it: point-mass platform.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write the results as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write figures (SVG and PNG) into this directory.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the calibrated parameters (taut-params v5 TOML: anchors, offsets, their 1-sigma) to
    /// this file, atomically.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write a self-contained HTML report (verdict, tables, figures) to this file, atomically.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Also calibrate without force weighting, to show what force weighting changes (tables,
    /// JSON `unweighted`, figures). Off by default: it doubles the solve.
    #[arg(long)]
    pub compare: bool,
    /// Calibrate cables whose anchors land at other cables' nominal anchors (a swapped pair of
    /// length columns or drives) as recorded, instead of refusing: the nominal anchors they
    /// are checked against follow the swap.
    #[arg(long)]
    pub allow_swapped: bool,
}

/// Most threads `taut calibrate` uses: the work comes in pieces of one cable or one channel
/// (4-11 on a four-cable robot), so more threads than that only wait.
pub(crate) const MAX_THREADS: usize = 8;

/// Everything one calibration run produced: the initial estimate, the calibration with and
/// without force weighting, and the metrics that compare them.
pub struct Outcome {
    /// The initial estimate.
    pub init: init::InitResult,
    /// Force-aware calibration.
    pub force: CalibReport,
    /// Unweighted calibration (no loose-cable exclusion, uniform variance), for comparison.
    pub plain: Option<CalibReport>,
    /// Co-registration RMS and peak of the initial estimate on all taut samples, m.
    pub before: metrics::RmsPeak,
    /// Cramér–Rao bound at the force-aware estimate.
    pub crb: metrics::CrbReport,
    /// The wild values found and excluded before everything else (its `recording` is the one
    /// calibrated: stale rows' lengths set missing, wild values removed).
    pub screen: taut_calib::screen::Screen,
    /// Rows found stale before the screen and left out (`taut_calib::diagnose::dataq::stale_rows`:
    /// every encoder repeats the previous row while the platform moves).
    pub stale_rows: usize,
    /// Without nominal anchors in the configuration: length columns that disagree with the
    /// tension columns at the force-aware anchors (`taut_calib::trust::tension_column_swap`).
    pub column_swap: Option<taut_calib::trust::ColumnSwap>,
}

/// Loads a recording (on every core: the same recording) and says what was skipped.
pub fn load_recording(path: &Path) -> Result<(Recording, ParseReport)> {
    let (rec, rep) = Recording::load_with(path, taut_calib::par::available(MAX_THREADS))?;
    for n in &rep.notes {
        eprintln!("note: {}: {n}", path.display());
    }
    Ok((rec, rep))
}

/// Refuses a recording in which nothing moves: every row's pose (where tracked) and lengths the
/// same as the first's. It holds no information on any parameter, and the solvers would only
/// report an unexcited first parameter.
pub fn require_motion(path: &Path, rec: &Recording) -> Result<()> {
    let n = rec.n_cables;
    let same = |i: usize| {
        let p_same = rec.p[i].iter().zip(&rec.p[0]).all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
        let l_same = rec.l[i * n..(i + 1) * n].iter().zip(&rec.l[..n]).all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
        p_same && l_same
    };
    if rec.len() > 1 && (1..rec.len()).all(same) {
        anyhow::bail!(
            "{}: all {} rows have the same pose and cable lengths: the platform never moved, so nothing can be calibrated or diagnosed; record while the robot moves",
            path.display(),
            rec.len()
        );
    }
    Ok(())
}

/// Below this magnitude in every row a load cell's column is not a reading, N.
pub const DEAD_LOAD_CELL_N: f64 = 1e-3;

/// Load cells that read nothing usable: every tension of the column missing or below
/// [`DEAD_LOAD_CELL_N`] in magnitude (a dead cell, a wrong scale, an unwired channel). A data
/// problem, the same for `calibrate` and `diagnose`, said with the file, the cable and what to
/// check. With `per_cable` (the diagnosis, which weighs each cable on its own) the column is
/// left out, its readings made missing; otherwise (the calibration's force-aware weighting
/// needs every cable's tension: a cable without one would have no taut readings) and when no
/// load cell is left, the recording is taken as one without tensions (uniform weights), not
/// refused as if the cables were loose. Returns the cables (from 0) left out.
pub fn drop_dead_load_cells(path: &Path, rec: &mut Recording, per_cable: bool) -> Vec<usize> {
    let n = rec.n_cables;
    let Some(f) = rec.f.as_mut() else { return Vec::new() };
    let m = f.len() / n.max(1);
    let dead: Vec<usize> = (0..n)
        .filter(|&j| (0..m).map(|i| f[i * n + j]).all(|v| !v.is_finite() || v.abs() < DEAD_LOAD_CELL_N))
        .filter(|&j| (0..m).any(|i| f[i * n + j].is_finite()))
        .collect();
    if dead.is_empty() {
        return dead;
    }
    let live = (0..n).filter(|&j| (0..m).any(|i| f[i * n + j].is_finite() && f[i * n + j].abs() >= DEAD_LOAD_CELL_N)).count();
    let names: Vec<String> = dead.iter().map(|j| format!("f{j} (cable {})", j + 1)).collect();
    eprintln!(
        "data problem: {}: load-cell column{} {} read{} below {DEAD_LOAD_CELL_N} N in every row: not a tension (a dead load cell, a wrong scale or an unwired channel); check the cell and its configuration",
        path.display(),
        if dead.len() > 1 { "s" } else { "" },
        names.join(", "),
        if dead.len() > 1 { "" } else { "s" },
    );
    if live == 0 || !per_cable {
        eprintln!(
            "note: {}: {}: treated as a recording without tensions (uniform weights; loose cables are not excluded)",
            path.display(),
            if live == 0 { "no load cell left" } else { "the force-aware weighting needs every cable's tension" }
        );
        rec.f = None;
    } else {
        for &j in &dead {
            for i in 0..m {
                f[i * n + j] = f64::NAN;
            }
        }
        eprintln!("note: {}: the readings of {} are left out as missing", path.display(), names.join(", "));
    }
    dead
}

/// The robot's name as the recording's comments give it: `# robot: NAME; written by taut start`
/// (the daemon's recordings) or `# simulated by taut-sim: robot NAME, seed ...` (taut-sim's).
pub fn robot_name(rec: &Recording) -> Option<String> {
    rec.comments.iter().find_map(|c| {
        let c = c.trim();
        let rest =
            c.strip_prefix("robot: ").or_else(|| c.split_once("robot ").filter(|(pre, _)| pre.ends_with("taut-sim: ")).map(|x| x.1))?;
        let name = rest.split([';', ',']).next()?.trim();
        (!name.is_empty() && name.len() <= 100 && !name.chars().any(char::is_control)).then(|| name.to_string())
    })
}

/// The configuration to use for a recording: the given file, or a point-mass robot named as the
/// recording names its robot.
pub fn config_for(path: Option<&Path>, rec: &Recording) -> Result<RobotConfig> {
    let cfg = match path {
        Some(p) => RobotConfig::load(p)?,
        None => {
            let mut c = RobotConfig::point_mass(rec.n_cables);
            if let Some(name) = robot_name(rec) {
                c.robot.name = name;
            }
            c
        }
    };
    anyhow::ensure!(
        cfg.cables.len() == rec.n_cables,
        "{}: the configuration has {} [[cable]] tables but the recording has {} length columns (l0..l{}); use the configuration of the robot that made the recording",
        path.map_or("(no --config)".into(), |p| p.display().to_string()),
        cfg.cables.len(),
        rec.n_cables,
        rec.n_cables - 1
    );
    Ok(cfg)
}

/// Screens out wild values, then initialises and calibrates (force-aware, and with `compare`
/// unweighted too) on the cleaned recording (`Outcome::screen.recording(rec)`).
pub fn pipeline(rec: &Recording, cfg: &RobotConfig, compare: bool, progress: &indicatif::ProgressBar) -> Result<Outcome> {
    let b = cfg.platform_points();
    // A one-shot command: the cables and the screened channels on every core (same results).
    let threads = taut_calib::par::available(MAX_THREADS);
    let opts = CalibOptions { threads, priors: cfg.priors(), ..CalibOptions::from_config(&cfg.calibration) };
    progress.set_message("screening for wild values");
    // Stale rows first (as the diagnosis does): their lengths belong to an earlier pose; the
    // screen would take some of them for wild readings of one cable and keep the others.
    let stale = taut_calib::diagnose::dataq::stale_rows(rec, opts.tracker_sigma_m, opts.encoder_sigma_m);
    let stale_rows = stale.iter().filter(|s| **s).count();
    let unstale = taut_calib::diagnose::dataq::without_lengths(rec, &stale);
    let mut screen = taut_calib::screen::screen(
        unstale.as_ref().unwrap_or(rec),
        &taut_calib::screen::ScreenOptions { threads, ..taut_calib::screen::ScreenOptions::new(opts.min_tension_n) },
    );
    if screen.cleaned.is_none() {
        screen.cleaned = unstale;
    }
    let rec = screen.recording(rec);
    progress.set_message("initialising");
    // The readings as the initialisation, the calibration and the bound use them, gathered once.
    let mut data = taut_calib::noise::gather(rec, &b, &opts, taut_calib::Weighting::of(rec, &opts));
    // With the design's anchors as priors the calibration starts there: a recording that excites
    // too little for the initialisation (a locked winch, a short swing) is still calibrated.
    let design: Option<Vec<[f64; 4]>> = opts
        .priors
        .as_ref()
        .filter(|p| p.iter().all(|(m, _)| m[..3].iter().all(|v| v.is_finite())))
        .map(|p| p.iter().map(|(m, _)| *m).collect());
    let init = match &design {
        Some(d) => init::from_design(rec, &b, d, &data).context("initialisation from the design failed")?,
        None => init::initialise_gathered(rec, &b, &opts, &data).context("initialisation failed")?,
    };
    progress.inc(1);
    progress.set_message("calibrating (force-aware)");
    let force = taut_calib::calibrate_gathered(rec, &b, &init.params, &opts, &mut data).context("calibration failed")?;
    progress.inc(1);
    progress.set_message("calibrating (unweighted)");
    let plain = if compare && force.used_tensions {
        let plain_opts = CalibOptions { force_aware: false, ..opts.clone() };
        Some(taut_calib::calibrate(rec, &b, &init.params, &plain_opts).context("unweighted calibration failed")?)
    } else {
        None
    };
    progress.inc(1);
    // Without nominal anchors, length columns that disagree with the tension columns: beside
    // the metrics, not after them.
    let nominal = cfg.anchors().is_some();
    let column_swap = || {
        if nominal {
            None
        } else {
            taut_calib::trust::tension_column_swap(rec, &b, &force.params.anchors, cfg.calibration.min_tension_n)
        }
    };
    let ((res, mask), (crb, column_swap)) = taut_calib::par::join(
        threads,
        || taut_calib::par::join(threads, || metrics::co_registration(rec, &b, &init.params), || metrics::taut_mask(rec, &opts)),
        || taut_calib::par::join(threads, || metrics::cramer_rao_gathered(rec, &force.params, &opts, &mut data), column_swap),
    );
    let before = metrics::rms_peak(&res, &mask);
    progress.inc(1);
    Ok(Outcome { init, force, plain, before, crb, screen, stale_rows, column_swap })
}

/// A progress bar on a terminal; hidden when stderr is piped.
pub fn progress(steps: u64) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::with_draw_target(Some(steps), indicatif::ProgressDrawTarget::stderr());
    pb.set_style(
        indicatif::ProgressStyle::with_template("{spinner} [{bar:30}] {pos}/{len} {msg}").expect("static template").progress_chars("=> "),
    );
    pb
}

pub fn run(a: &CalibrateArgs) -> Result<()> {
    crate::heap::keep_freed_memory();
    let inputs = crate::outputs::check_analysis(
        &a.recording,
        a.config.as_deref(),
        a.json.as_deref(),
        a.out.as_deref(),
        a.report.as_deref(),
        a.plot.as_deref(),
    )?;
    let (mut rec, parse) = load_recording(&a.recording)?;
    require_motion(&a.recording, &rec)?;
    drop_dead_load_cells(&a.recording, &mut rec, false);
    let cfg = config_for(a.config.as_deref(), &rec)?;
    if crate::notracker::tracker_absent(&rec) {
        return crate::notracker::run(a, &rec, &parse, &cfg);
    }
    let untracked = crate::notracker::untracked_rows(&rec);
    if untracked > 0 {
        eprintln!(
            "note: {}: {untracked} of {} rows have no tracker position: calibrating with the tracker, on the rows that have one",
            a.recording.display(),
            rec.len()
        );
    }
    let pb = progress(4);
    let out = pipeline(&rec, &cfg, a.compare, &pb).with_context(|| format!("calibrating {}", a.recording.display()))?;
    pb.finish_and_clear();
    let rec = out.screen.recording(&rec);
    if out.stale_rows > 0 {
        println!(
            "data problem (stale-row): {} rows repeat every encoder reading of the row before while the platform moves (a new pose logged beside old lengths); left out",
            out.stale_rows
        );
    }
    print_wild(&out.screen);
    report::print_calibration(rec, &parse, &out, None);
    // Cables recorded in another order than the configuration's: named, and refused unless
    // --allow-swapped (then checked against the nominal anchors in the recording's order).
    let mut nominal = cfg.anchors();
    let swaps = nominal.as_deref().map(|n| taut_calib::trust::swaps(&out.force.params.anchors, n)).unwrap_or_default();
    // Without nominal anchors: length columns that disagree with the tension columns.
    let column_swap = out.column_swap;
    if !swaps.is_empty() || column_swap.is_some() {
        let words: Vec<String> = swaps.iter().map(|s| s.to_string()).chain(column_swap.map(|c| c.to_string())).collect();
        if !a.allow_swapped {
            let why = format!(
                "{}; correct the column order (or the wiring) and calibrate again, or give --allow-swapped to calibrate the cables as recorded",
                words.join("; ")
            );
            if let Some(r) = &a.report {
                write_report(a, r, rec, &parse, &cfg, &out, Some(why.clone()))?;
                anyhow::bail!("calibration refused, no parameters written (the report {} says why): {why}", r.display());
            }
            anyhow::bail!("calibration refused, nothing written: {why}");
        }
        for w in &words {
            println!("swapped (--allow-swapped, calibrated as recorded): {w}");
        }
        nominal = nominal.map(|n| taut_calib::trust::permuted_nominal(&n, &swaps));
    }
    // Nothing is written from a set that cannot be trusted.
    let limit = 2.0 * cfg.daemon.max_anchor_change_m;
    let trusted = taut_calib::trust::check(&taut_calib::trust::Candidate::of(&out.force), rec, nominal.as_deref().map(|n| (n, limit)));
    if let Err(e) = &trusted {
        // The report says why, so that a refusal is not just an exit code; nothing else is written.
        if let Some(r) = &a.report {
            write_report(a, r, rec, &parse, &cfg, &out, Some(e.to_string()))?;
            anyhow::bail!("calibration refused, no parameters written (the report {} says why): {e}", r.display());
        }
    }
    trusted.map_err(|e| anyhow::anyhow!("calibration refused, nothing written: {e}"))?;
    if let Some(j) = &a.json {
        let mut v = report::json(rec, &parse, &out, None);
        v["data_problems"] = wild_json(&out.screen);
        v["stale_rows"] = serde_json::json!(out.stale_rows);
        v["robot"] = serde_json::json!(cfg.robot.name);
        let source = a.recording.display().to_string();
        let params_out = a.out.as_ref().map(|p| p.display().to_string());
        let ctx = crate::html::CalibrationContext { source: &source, config: None, refused: None, params_out: params_out.as_deref() };
        v["verdict"] = crate::html::calibration_verdict(&cfg, &out, &ctx).json();
        v["swapped"] = serde_json::json!(swaps
            .iter()
            .map(|s| serde_json::json!({"cables": s.cables, "message": s.to_string()}))
            .chain(column_swap.map(|c| serde_json::json!({"cables": [c.cables.0, c.cables.1], "message": c.to_string()})))
            .collect::<Vec<_>>());
        taut_config::write_atomic(j, serde_json::to_string_pretty(&v)?.as_bytes()).with_context(|| format!("writing {}", j.display()))?;
    }
    if let Some(dir) = &a.plot {
        report::plots(dir, &inputs, rec, &cfg, &out)?;
        eprintln!("figures written to {}", dir.display());
    }
    if let Some(p) = &a.out {
        report::params_file(&cfg, &a.recording.display().to_string(), &out.force)
            .save_atomic(p)
            .with_context(|| format!("writing {}", p.display()))?;
        eprintln!("parameters written to {}", p.display());
    }
    if let Some(r) = &a.report {
        write_report(a, r, rec, &parse, &cfg, &out, None)?;
        eprintln!("report written to {}", r.display());
    }
    Ok(())
}

/// Writes the HTML report atomically.
fn write_report(
    a: &CalibrateArgs,
    path: &Path,
    rec: &Recording,
    parse: &ParseReport,
    cfg: &RobotConfig,
    out: &Outcome,
    refused: Option<String>,
) -> Result<()> {
    let source = a.recording.display().to_string();
    let config = a.config.as_ref().map(|p| p.display().to_string());
    let params_out = a.out.as_ref().map(|p| p.display().to_string());
    let ctx = crate::html::CalibrationContext { source: &source, config: config.as_deref(), refused, params_out: params_out.as_deref() };
    let html = crate::html::calibration(rec, parse, cfg, out, &ctx)?;
    taut_config::write_atomic(path, html.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

/// Prints the wild values the screen excluded, one line each (the first 20).
pub fn print_wild(sc: &taut_calib::screen::Screen) {
    for w in sc.findings.iter().take(20) {
        println!("data problem ({}): {w}", w.kind.name());
    }
    if sc.findings.len() > 20 {
        println!("data problem: and {} more wild values", sc.findings.len() - 20);
    }
}

/// The wild values as JSON (rows 0-based, as in the messages).
pub fn wild_json(sc: &taut_calib::screen::Screen) -> serde_json::Value {
    let num = |v: f64| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null };
    sc.findings
        .iter()
        .map(|w| {
            serde_json::json!({
                "problem": w.kind.name(), "row": w.row, "t_s": num(w.t), "cable": w.cable, "axis": w.axis,
                "value": num(w.value), "description": w.to_string(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_robot_is_named_as_the_recording_names_it() {
        let mut rec = Recording::default();
        assert_eq!(robot_name(&rec), None);
        rec.comments = vec![" robot: aras-cam; written by taut start; state column: motion state of the loop".into()];
        assert_eq!(robot_name(&rec).as_deref(), Some("aras-cam"));
        rec.comments = vec![" tracker noise".into(), " simulated by taut-sim: robot aras-cam-sim, seed 3, 100 Hz".into()];
        assert_eq!(robot_name(&rec).as_deref(), Some("aras-cam-sim"));
        rec.comments = vec![" the robot arm was moved".into()];
        assert_eq!(robot_name(&rec), None);
    }
}
