//! What people and programs see of a calibration: the table, the JSON, the figures, the
//! parameter file.

use crate::calibrate::Outcome;
use anyhow::Result;
use serde_json::json;
use std::path::Path;
use taut_calib::{CalibReport, Geometry, Params};
use taut_config::params::ParamsFile;
use taut_config::recording::{ParseReport, Recording};
use taut_config::RobotConfig;

fn mm(v: f64) -> String {
    if v.is_finite() {
        format!("{:.2}", v * 1e3)
    } else {
        "-".into()
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// RMS over cables of the anchor position error, m.
pub fn anchor_rms_error(p: &Params, truth: &Geometry) -> f64 {
    let s: f64 = p.anchors.iter().zip(&truth.anchors).map(|(a, t)| dist(a, t).powi(2)).sum();
    (s / p.anchors.len() as f64).sqrt()
}

fn fmt3(v: &[f64; 3]) -> String {
    format!("[{:8.4} {:8.4} {:8.4}]", v[0], v[1], v[2])
}

/// Prints the table in the spirit of the paper's Table I and Fig. 7-9.
pub fn print_calibration(rec: &Recording, parse: &ParseReport, out: &Outcome, truth: Option<&Geometry>) {
    let f = &out.force;
    let n = rec.n_cables;
    println!(
        "recording: {} samples, {} cables, {:.1} s; {} with a tracker dropout",
        parse.rows,
        n,
        rec.t.last().unwrap_or(&0.0) - rec.t.first().unwrap_or(&0.0),
        parse.missing_position
    );
    println!("initialisation: {}", out.init.method);
    println!(
        "calibration: {} after {} iterations ({}); {} samples used, {} excluded{}",
        if f.termination.was_successful() { "converged" } else { "NOT converged" },
        f.iterations,
        crate::html::termination_words(f.termination),
        f.samples_used,
        f.samples_excluded,
        if f.used_tensions { "" } else { " (no tensions: uniform weights)" }
    );
    for note in &f.notes {
        println!("  note: {note}");
    }
    match &f.consistency {
        Some(c) if c.consistent => println!("model check: consistent with the noise model: {}", c.numbers()),
        Some(c) => println!(
            "model check: INCONSISTENT, the model does not explain the data: {}; run `taut diagnose` on this recording",
            c.numbers()
        ),
        None => println!("model check: not made (a cable's cross-fit is singular: too few readings)"),
    }
    println!();
    println!("anchors A_j, m (tracker frame)");
    println!(
        "  {:<5} {:<28} {:<28} {:<22}{}",
        "cable",
        "initial",
        "calibrated",
        "1-sigma, mm",
        if truth.is_some() { "  truth                          error, mm (init -> calib)" } else { "" }
    );
    for j in 0..n {
        let s = f.sigma.anchors[j];
        print!(
            "  {:<5} {:<28} {:<28} {:<22}",
            j + 1,
            fmt3(&out.init.params.anchors[j]),
            fmt3(&f.params.anchors[j]),
            format!("{} {} {}", mm(s[0]), mm(s[1]), mm(s[2]))
        );
        if let Some(t) = truth {
            print!(
                "  {:<30} {} -> {}",
                fmt3(&t.anchors[j]),
                mm(dist(&out.init.params.anchors[j], &t.anchors[j])),
                mm(dist(&f.params.anchors[j], &t.anchors[j]))
            );
        }
        println!();
    }
    println!();
    println!("encoder offsets L0_j, m");
    for j in 0..n {
        print!("  {:<5} initial {:9.4}  calibrated {:9.4} +- {} mm", j + 1, out.init.params.l0[j], f.params.l0[j], mm(f.sigma.l0[j]));
        if let Some(t) = truth {
            print!("   truth {:9.4}  error {} mm", t.l0[j], mm((f.params.l0[j] - t.l0[j]).abs()));
        }
        println!();
    }
    println!();
    println!("co-registration error (measured - modelled cable length), mm, taut samples");
    println!("  {:<34} {:>9} {:>9} {:>14}", "", "RMS", "peak", "held-out RMS");
    println!("  {:<34} {:>9} {:>9} {:>14}", "before calibration (initial)", mm(out.before.rms), mm(out.before.peak), "");
    if let Some(p) = &out.plain {
        println!("  {:<34} {:>9} {:>9} {:>14}", "after, without force weighting", mm(p.rms_m), mm(p.peak_m), mm(p.heldout_rms_m));
    }
    println!("  {:<34} {:>9} {:>9} {:>14}", "after, force-aware", mm(f.rms_m), mm(f.peak_m), mm(f.heldout_rms_m));
    if let Some(t) = truth {
        println!();
        let ef = anchor_rms_error(&f.params, t);
        let crb = rms_sigma(&out.crb.anchor_sigma);
        println!(
            "anchor RMS error vs truth: initial {} mm, force-aware {} mm (Cramér-Rao bound {} mm, ratio {:.2})",
            mm(anchor_rms_error(&out.init.params, t)),
            mm(ef),
            mm(crb),
            ef / crb
        );
        if let Some(p) = &out.plain {
            let ep = anchor_rms_error(&p.params, t);
            println!(
                "                           without force weighting {} mm: force weighting is {:.1}x closer to the truth",
                mm(ep),
                ep / ef
            );
        }
    }
}

/// RMS of per-cable 3D sigmas: sqrt(mean over cables of sx^2 + sy^2 + sz^2).
pub fn rms_sigma(s: &[[f64; 3]]) -> f64 {
    (s.iter().map(|v| v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sum::<f64>() / s.len() as f64).sqrt()
}

fn report_json(r: &CalibReport) -> serde_json::Value {
    json!({
        "anchors_m": r.params.anchors,
        "l0_m": r.params.l0,
        "anchor_sigma_m": r.sigma.anchors,
        "l0_sigma_m": r.sigma.l0,
        "rms_m": r.rms_m,
        "peak_m": r.peak_m,
        "heldout_rms_m": r.heldout_rms_m,
        "samples_used": r.samples_used,
        "samples_excluded": r.samples_excluded,
        "iterations": r.iterations,
        "termination": format!("{:?}", r.termination),
        "singular_values": r.singular_values,
        "used_tensions": r.used_tensions,
        // Per cable [A_x, A_y, A_z, L0]: the share of the estimate from the data, 0-1 (null where
        // the configuration gives no prior).
        "data_share": r.per_cable.iter().map(|c| c.data_share.map(|v| v.is_finite().then_some(v))).collect::<Vec<_>>(),
        "model_consistent": r.model_consistent(),
        "model_check": r.consistency.map(|c| json!({
            "consistent": c.consistent,
            "alpha": c.alpha,
            "p_value": c.p_value,
            "statistic": c.statistic,
            "dof": c.dof,
            "chi2_ratio": c.ratio,
            "heldout_rms_m": c.heldout_rms_m,
            "expected_rms_m": c.expected_rms_m,
            "samples": c.samples,
            "readings": c.readings,
            "outliers": c.outliers,
        })),
    })
}

/// The `--json` document.
pub fn json(rec: &Recording, parse: &ParseReport, out: &Outcome, truth: Option<&Geometry>) -> serde_json::Value {
    let f = &out.force;
    let mut v = report_json(f);
    let o = v.as_object_mut().expect("object");
    o.insert("cables".into(), json!(rec.n_cables));
    o.insert("samples".into(), json!(parse.rows));
    o.insert("init_method".into(), json!(out.init.method.json_name()));
    o.insert("initial_anchors_m".into(), json!(out.init.params.anchors));
    o.insert("initial_l0_m".into(), json!(out.init.params.l0));
    o.insert("before".into(), json!({"rms_m": out.before.rms, "peak_m": out.before.peak}));
    o.insert("crb".into(), json!({"anchor_sigma_m": out.crb.anchor_sigma, "l0_sigma_m": out.crb.l0_sigma}));
    o.insert("notes".into(), json!(f.notes.iter().chain(&parse.notes).collect::<Vec<_>>()));
    if let Some(p) = &out.plain {
        o.insert("unweighted".into(), report_json(p));
    }
    if let Some(t) = truth {
        o.insert("truth_anchors_m".into(), json!(t.anchors));
        o.insert("truth_l0_m".into(), json!(t.l0));
        o.insert("anchor_rms_error_m".into(), json!(anchor_rms_error(&f.params, t)));
        o.insert("initial_anchor_rms_error_m".into(), json!(anchor_rms_error(&out.init.params, t)));
        if let Some(p) = &out.plain {
            o.insert("unweighted_anchor_rms_error_m".into(), json!(anchor_rms_error(&p.params, t)));
        }
        o.insert("crb_anchor_rms_m".into(), json!(rms_sigma(&out.crb.anchor_sigma)));
    }
    v
}

/// The parameter file of a calibration.
pub fn params_file(cfg: &RobotConfig, source: &str, r: &CalibReport) -> ParamsFile {
    ParamsFile {
        version: 1,
        created_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0),
        robot: cfg.robot.name.clone(),
        source: source.into(),
        rms_m: r.rms_m,
        heldout_rms_m: r.heldout_rms_m,
        ..ParamsFile::from_geometry(&r.params, &r.sigma)
    }
}

/// The calibration figures (`crate::figures::calibration`) into `dir`, all or nothing (none of
/// them may replace one of `inputs`).
pub fn plots(dir: &Path, inputs: &[&Path], rec: &Recording, cfg: &RobotConfig, out: &Outcome) -> Result<()> {
    let mut set = crate::outputs::figures(dir, inputs)?;
    draw_figures(&mut set, rec, cfg, out)?;
    Ok(set.commit()?)
}

fn draw_figures(set: &mut taut_config::atomic::Staging, rec: &Recording, cfg: &RobotConfig, out: &Outcome) -> Result<()> {
    for fig in crate::figures::calibration::figures(rec, cfg, out) {
        fig.write(set)?;
    }
    Ok(())
}
