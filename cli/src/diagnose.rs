//! `taut diagnose REC.csv`: find the physics the ideal model leaves out, name it, model it, and
//! show the fit improve. The work is in `taut_calib::diagnose`; this module prints, writes the
//! `taut-diagnosis v1` JSON and draws the before/after figures.

use crate::calibrate::{config_for, load_recording};
use anyhow::{Context, Result};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect, Finding, Sharing, TensionEnd};

/// Arguments of `taut diagnose`.
#[derive(clap::Args)]
pub struct DiagnoseArgs {
    /// The recording: cdpr-recording v1 CSV, or an MCAP file taut wrote.
    pub recording: PathBuf,
    /// Robot configuration (platform points, noise model). Without it: point-mass platform.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write the diagnosis as JSON (taut-diagnosis v1) to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write figures (SVG and PNG) into this directory.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write a self-contained HTML report (verdict, tables, figures) to this file, atomically.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Where the load cells measure the tension: `platform` (at the attachment, the default) or `anchor` (at the winch).
    #[arg(long, default_value = "platform")]
    pub tension_at: String,
    /// Write the final model's anchors and offsets with the named effects' parameters
    /// (taut-params v5 TOML, for `taut start --params`) to this file, atomically.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Load-cell noise, 1-sigma of one reading, N (errors-in-variables weights for stretch and
    /// sag). Default: `[calibration] loadcell_sigma_n` of --config, else 0 (tensions exact).
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    pub loadcell_sigma: Option<f64>,
    /// 1-sigma of each load cell's constant offset, N (widens the stretch and sag sigmas).
    /// Default: `[calibration] loadcell_offset_n` of --config, else 0 (cells zeroed exactly).
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    pub loadcell_offset: Option<f64>,
    /// Also test the load cells against the platform's weight and inertia (the tension side:
    /// load-cell gain, friction, inertia), with the platform's mass `[robot] mass_kg` of --config.
    /// Its tests join the length side's family (each test's level becomes family_alpha / (11 x 3)).
    #[arg(long, requires = "config")]
    pub tension_side: bool,
}

/// The diagnosis options: the `[calibration]` table of `cfg` and its cables' swivel-pulley
/// axes (vertical without a configuration), then the arguments (which win).
fn options(a: &DiagnoseArgs, cfg: &taut_config::RobotConfig) -> Result<DiagnoseOptions> {
    let mut opts = DiagnoseOptions::from_robot(cfg);
    // A round's candidates are independent fits: on the cores the machine gives.
    opts.threads = taut_calib::par::available(crate::calibrate::MAX_THREADS);
    opts.tension_end = match a.tension_at.as_str() {
        "anchor" => TensionEnd::Anchor,
        "platform" => TensionEnd::Platform,
        other => anyhow::bail!("--tension-at `{other}`: use `anchor` (load cell at the winch) or `platform`"),
    };
    for (flag, given, opt) in [
        ("--loadcell-sigma", a.loadcell_sigma, &mut opts.loadcell_sigma_n),
        ("--loadcell-offset", a.loadcell_offset, &mut opts.loadcell_offset_n),
    ] {
        if let Some(v) = given {
            taut_config::check_loadcell_sigma(v).map_err(|m| anyhow::anyhow!("{flag} {v}: {m}"))?;
            *opt = v;
        }
    }
    if a.tension_side {
        opts.platform_mass_kg = Some(cfg.robot.mass_kg);
    }
    Ok(opts)
}

/// JSON number, `null` for NaN / infinite.
fn num(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        Value::Null
    }
}

fn param_value(f: &Finding, vals: &[f64]) -> Value {
    match f.effect.sharing() {
        Sharing::Shared => num(vals[0]),
        Sharing::PerCable => Value::Array(vals.iter().map(|v| num(*v)).collect()),
    }
}

/// The `taut-diagnosis v1` document.
pub fn to_json(d: &Diagnosis) -> Value {
    let effects: Vec<Value> = d
        .effects
        .iter()
        .map(|f| {
            let (params, sigmas) = if f.effect == Effect::Slack {
                (
                    json!({"threshold_N": num(f.values[0]), "samples": f.samples.unwrap_or(0)}),
                    json!({}),
                )
            } else {
                (
                    json!({ f.effect.parameter(): param_value(f, &f.values) }),
                    json!({ f.effect.parameter(): param_value(f, &f.sigmas) }),
                )
            };
            json!({
                "effect": f.effect.name(),
                "cables": f.cables,
                "parameters": params,
                "parameters_sigma": sigmas,
                "rms_before_m": num(f.rms_before_m),
                "rms_after_m": num(f.rms_after_m),
                "heldout_rms_before_m": num(f.heldout_rms_before_m),
                "heldout_rms_after_m": num(f.heldout_rms_after_m),
                "evidence": f.evidence,
                "equally_good": f.equally_good.iter().map(|(e, r)| json!({"effect": e.name(), "heldout_rms_m": num(*r)})).collect::<Vec<_>>(),
                "test": f.test.map(test_json),
                "joint": f.joint.iter().map(|j| json!({
                    "with": j.with.map_or("anchors", |w| w.name()), "both_named": j.both_named,
                    "correlation": num(j.correlation), "sigmas": j.sigmas.iter().map(|v| num(*v)).collect::<Vec<_>>(),
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let mut doc = json!({
        "format": "taut-diagnosis v1",
        "cables": d.cables,
        "samples": d.samples,
        "used_tensions": d.used_tensions,
        "baseline": {
            "rms_m": num(d.baseline.rms_m),
            "heldout_rms_m": num(d.baseline.heldout_rms_m),
            "per_cable_rms_m": d.baseline.per_cable_rms_m.iter().map(|v| num(*v)).collect::<Vec<_>>(),
            "anchors_m": d.baseline.params.anchors,
            "l0_m": d.baseline.params.l0,
        },
        "mismatch": {
            "summary": d.mismatch.words,
            "per_cable_rms_m": d.mismatch.per_cable_rms_m.iter().map(|v| num(*v)).collect::<Vec<_>>(),
            "per_cable_noise_m": d.mismatch.per_cable_noise_m.iter().map(|v| num(*v)).collect::<Vec<_>>(),
            "correlations": d.mismatch.correlations.iter().map(|c| {
                c.iter().map(|(r, v)| json!({"quantity": r.name(), "r": num(*v)})).collect::<Vec<_>>()
            }).collect::<Vec<_>>(),
            "time_blocks": d.mismatch.time_blocks.iter().map(|b| json!({"t_start_s": b.0, "t_end_s": b.1, "rms_m": num(b.2)})).collect::<Vec<_>>(),
        },
        "effects": effects,
        "final": {
            "rms_m": num(d.final_fit.rms_m),
            "heldout_rms_m": num(d.final_fit.heldout_rms_m),
            "per_cable_rms_m": d.final_fit.per_cable_rms_m.iter().map(|v| num(*v)).collect::<Vec<_>>(),
            "anchors_m": d.final_fit.params.anchors,
            "anchor_sigma_m": d.final_fit.sigma.anchors,
            "l0_m": d.final_fit.params.l0,
            "l0_sigma_m": d.final_fit.sigma.l0,
        },
        "unexplained": d.unexplained,
        "data_problems": d.data_problems.iter().map(|p| json!({
            "problem": p.kind.name(), "cable": p.cable, "t_start_s": p.t_start, "t_end_s": p.t_end,
            "samples": p.samples, "description": p.description,
        })).collect::<Vec<_>>(),
        "not_named": d.rejected,
        "family_alpha": d.family_alpha,
        "tests": d.tests.iter().map(|t| json!({
            "round": t.round, "effect": t.effect.name(), "alpha": t.alpha, "decision": format!("{:?}", t.decision),
            "test": t.test.map(test_json),
        })).collect::<Vec<_>>(),
        "notes": d.notes,
    });
    // Only with the tension side: without it the document has no `tension` key at all.
    if let (Some(t), Some(o)) = (&d.tension, doc.as_object_mut()) {
        o.insert("tension".into(), tension_json(t));
    }
    doc
}

/// The tension side (`taut diagnose --tension-side`), parameters in SI units.
fn tension_json(t: &taut_calib::diagnose::tension::TensionDiagnosis) -> Value {
    json!({
        "windows": t.rows,
        "mass_kg": num(t.mass_kg),
        "loadcell_sigma_N": num(t.loadcell_sigma_n),
        "loadcell_sigma_estimated": t.sigma_estimated,
        "accel_half_window_s": num(t.accel_window_s),
        "offsets_N": t.offsets_n.iter().map(|v| num(*v)).collect::<Vec<_>>(),
        "offsets_sigma_N": t.offset_sigmas_n.iter().map(|v| num(*v)).collect::<Vec<_>>(),
        "rms_before_N": num(t.rms_before_n),
        "heldout_rms_before_N": num(t.heldout_rms_before_n),
        "rms_after_N": num(t.rms_after_n),
        "heldout_rms_after_N": num(t.heldout_rms_after_n),
        "leads": t.leads.iter().take(8).map(|l| json!({
            "cable": l.cable, "follows": format!("{:?}", l.follows), "coefficient": num(l.coefficient), "t": num(l.t),
        })).collect::<Vec<_>>(),
        "effects": t.effects.iter().map(|f| json!({
            "effect": f.effect.name(),
            "parameters": { f.effect.model().parameter(): f.values.iter().map(|v| num(*v)).collect::<Vec<_>>() },
            "parameters_sigma": { f.effect.model().parameter(): f.sigmas.iter().map(|v| num(*v)).collect::<Vec<_>>() },
            "evidence": f.evidence,
            "test": test_json(f.test),
        })).collect::<Vec<_>>(),
        "tests": t.tests.iter().map(|x| json!({
            "round": x.round, "effect": x.effect.name(), "alpha": x.alpha, "decision": format!("{:?}", x.decision),
            "test": x.test.map(test_json),
        })).collect::<Vec<_>>(),
        "notes": t.notes,
    })
}

/// One held-out test (see `taut_calib::diagnose::select`).
fn test_json(t: taut_calib::diagnose::HeldoutTest) -> Value {
    json!({
        "heldout_ss_gain": num(t.gain), "weight": num(t.weight), "t": num(t.statistic), "dof": t.dof,
        "n": t.n, "n_eff": num(t.n_eff), "p_value": num(t.p_value), "estimation_share": num(t.estimation_share),
    })
}

/// Prints the diagnosis for people.
pub fn print(d: &Diagnosis) {
    let mm = |v: f64| v * 1e3;
    println!("recording: {} samples, {} cables{}", d.samples, d.cables, if d.used_tensions { "" } else { ", no tensions" });
    for p in &d.data_problems {
        println!("data problem ({}): {}", p.kind.name(), p.description);
    }
    println!("ideal model: RMS {:.2} mm, held out {:.2} mm", mm(d.baseline.rms_m), mm(d.baseline.heldout_rms_m));
    for w in &d.mismatch.words {
        println!("  {w}");
    }
    if d.effects.is_empty() {
        println!("no effect found");
    }
    for f in &d.effects {
        println!(
            "{}: RMS {:.2} -> {:.2} mm, held out {:.2} -> {:.2} mm",
            f.effect.name(),
            mm(f.rms_before_m),
            mm(f.rms_after_m),
            mm(f.heldout_rms_before_m),
            mm(f.heldout_rms_after_m)
        );
        println!("  {}", f.evidence);
    }
    println!("final model: RMS {:.2} mm, held out {:.2} mm", mm(d.final_fit.rms_m), mm(d.final_fit.heldout_rms_m));
    for (j, (a, s)) in d.final_fit.params.anchors.iter().zip(&d.final_fit.sigma.anchors).enumerate() {
        println!(
            "  cable {}: anchor [{:.4}, {:.4}, {:.4}] m (1-sigma {:.2} {:.2} {:.2} mm), L0 {:.4} m",
            j + 1,
            a[0],
            a[1],
            a[2],
            mm(s[0]),
            mm(s[1]),
            mm(s[2]),
            d.final_fit.params.l0[j]
        );
    }
    if let Some(u) = &d.unexplained {
        println!("{u}");
    }
    for r in &d.rejected {
        println!("  not named: {r}");
    }
    for n in &d.notes {
        println!("note: {n}");
    }
    if let Some(t) = &d.tension {
        println!(
            "tension side ({} windows, mass {} kg, cells {:.2} N): balance RMS {:.3} N, held out {:.3} -> {:.3} N",
            t.rows, t.mass_kg, t.loadcell_sigma_n, t.rms_before_n, t.heldout_rms_before_n, t.heldout_rms_after_n
        );
        for l in t.leads.iter().take(3) {
            let who = l.cable.map_or("the platform".to_string(), |j| format!("cable {}", j + 1));
            println!("  departs at {who}, following {} (t = {:.1})", l.follows.words(), l.t);
        }
        for f in &t.effects {
            println!("{}: {}", f.effect.name(), f.evidence);
        }
        if t.effects.is_empty() {
            println!("  no tension effect found");
        }
    }
}

/// Figures: the residual against time, before and after; and per effect the residual against
/// the quantity that revealed it, before and after, per cable.
pub fn plots(dir: &Path, inputs: &[&Path], d: &Diagnosis) -> Result<()> {
    let mut set = crate::outputs::figures(dir, inputs)?;
    draw_figures(&mut set, d)?;
    Ok(set.commit()?)
}

fn draw_figures(set: &mut taut_config::atomic::Staging, d: &Diagnosis) -> Result<()> {
    for fig in crate::figures::diagnosis::figures(d) {
        fig.write(set)?;
    }
    Ok(())
}

pub fn run(a: &DiagnoseArgs) -> Result<()> {
    crate::heap::keep_freed_memory();
    let inputs = crate::outputs::check_analysis(
        &a.recording,
        a.config.as_deref(),
        a.json.as_deref(),
        a.out.as_deref(),
        a.report.as_deref(),
        a.plot.as_deref(),
    )?;
    let (mut rec, _parse) = load_recording(&a.recording)?;
    crate::calibrate::require_motion(&a.recording, &rec)?;
    crate::calibrate::drop_dead_load_cells(&a.recording, &mut rec, true);
    let cfg = config_for(a.config.as_deref(), &rec)?;
    let opts = options(a, &cfg)?;
    let d = diagnose(&rec, &cfg.platform_points(), None, &opts).with_context(|| format!("diagnosing {}", a.recording.display()))?;
    print(&d);
    // The wild values are excluded before the fit; should the model still come out non-finite
    // or absurd, say so and fail rather than hand out such numbers.
    let fin = &d.final_fit;
    let cand = taut_calib::trust::Candidate { params: &fin.params, sigma: &fin.sigma, rms_m: fin.rms_m };
    let trusted = taut_calib::trust::check(&cand, &rec, None);
    let write_report = |refused: Option<String>| -> Result<()> {
        let Some(r) = &a.report else { return Ok(()) };
        let html = crate::html::diagnosis(&d, &a.recording.display().to_string(), &cfg, refused)?;
        taut_config::write_atomic(r, html.as_bytes()).with_context(|| format!("writing {}", r.display()))
    };
    if let Err(e) = &trusted {
        if let Some(r) = &a.report {
            // The report says why; nothing else is written.
            write_report(Some(e.to_string()))?;
            anyhow::bail!("diagnosis refused, no model written (the report {} says why): {e}", r.display());
        }
    }
    trusted.map_err(|e| anyhow::anyhow!("diagnosis refused, nothing written: {e}"))?;
    if let Some(j) = &a.json {
        let mut v = to_json(&d);
        v["robot"] = json!(cfg.robot.name);
        v["verdict"] = crate::html::diagnosis_verdict(&d, &cfg, &a.recording.display().to_string(), None).json();
        taut_config::write_atomic(j, serde_json::to_string_pretty(&v)?.as_bytes()).with_context(|| format!("writing {}", j.display()))?;
    }
    if let Some(p) = &a.out {
        let (effects, notes) = taut_calib::effect_fit::effects_of(&d);
        for n in notes {
            eprintln!("--out: {n}");
        }
        let file = taut_config::params::ParamsFile {
            version: 1,
            created_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64()),
            robot: cfg.robot.name.clone(),
            source: format!("taut diagnose {}", a.recording.display()),
            rms_m: fin.rms_m,
            heldout_rms_m: fin.heldout_rms_m,
            effects,
            ..taut_config::params::ParamsFile::from_geometry(&fin.params, &fin.sigma)
        };
        file.save_atomic(p).with_context(|| format!("writing {}", p.display()))?;
        eprintln!(
            "parameters with {} written to {}",
            if file.effects.is_empty() { "no effects".into() } else { file.effects.names().join(", ") },
            p.display()
        );
    }
    if let Some(dir) = &a.plot {
        plots(dir, &inputs, &d)?;
        eprintln!("figures written to {}", dir.display());
    }
    if let Some(r) = &a.report {
        write_report(None)?;
        eprintln!("report written to {}", r.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: DiagnoseArgs,
    }

    fn args(extra: &[&str]) -> DiagnoseArgs {
        Cli::try_parse_from(["taut", "rec.csv"].iter().chain(extra)).unwrap().args
    }

    #[test]
    fn load_cell_noise_from_the_config_then_the_arguments() {
        let mut cfg = taut_config::RobotConfig::point_mass(4);
        let o = options(&args(&[]), &cfg).unwrap();
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.0, 0.0));
        cfg.calibration.loadcell_sigma_n = 0.3;
        cfg.calibration.loadcell_offset_n = 0.5;
        let o = options(&args(&[]), &cfg).unwrap();
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.3, 0.5));
        let o = options(&args(&["--loadcell-sigma", "0.2"]), &cfg).unwrap();
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.2, 0.5));
        let o = options(&args(&["--loadcell-offset", "0", "--loadcell-sigma", "0"]), &cfg).unwrap();
        assert_eq!((o.loadcell_sigma_n, o.loadcell_offset_n), (0.0, 0.0));
        for (flag, v) in
            [("--loadcell-sigma", "nan"), ("--loadcell-sigma", "-1"), ("--loadcell-offset", "inf"), ("--loadcell-offset", "1e9")]
        {
            let e = options(&args(&[flag, v]), &cfg).unwrap_err().to_string();
            assert!(e.starts_with(flag) && e.contains("0 (exact) to 1000"), "{e}");
        }
    }

    /// `--tension-side` takes the platform's mass from --config (and needs one); without it the
    /// tension side does not run.
    #[test]
    fn tension_side_takes_the_mass_from_the_config() {
        let mut cfg = taut_config::RobotConfig::point_mass(4);
        cfg.robot.mass_kg = 3.5;
        assert_eq!(options(&args(&[]), &cfg).unwrap().platform_mass_kg, None);
        let o = options(&args(&["--config", "robot.toml", "--tension-side"]), &cfg).unwrap();
        assert_eq!(o.platform_mass_kg, Some(3.5));
        assert!(Cli::try_parse_from(["taut", "rec.csv", "--tension-side"]).is_err(), "--tension-side without --config");
    }
}
