//! `taut calibrate REC.csv` on a recording without a tracker: self-calibration from the dwell
//! poses, the encoders and the load cells (`taut_calib::selfcal`).
//!
//! Chosen when the tracker columns are empty in every row. A recording with the tracker in some
//! rows only is calibrated with the tracker, on those rows (said in a note): a tracked pose is
//! worth far more than an untracked one, and mixing the two models is left for later.

use anyhow::{Context, Result};
use taut_calib::selfcal::{self, Frame, SelfCalOptions, SelfCalReport};
use taut_config::recording::{ParseReport, Recording};
use taut_config::RobotConfig;

use crate::calibrate::CalibrateArgs;

/// True when no row has a tracker position.
pub fn tracker_absent(rec: &Recording) -> bool {
    rec.p.iter().all(|p| !p.iter().any(|v| v.is_finite()))
}

/// Rows without a tracker position (any coordinate missing).
pub fn untracked_rows(rec: &Recording) -> usize {
    rec.p.iter().filter(|p| !p.iter().all(|v| v.is_finite())).count()
}

/// Calibrates without the tracker, prints the result, writes the outputs asked for.
pub fn run(a: &CalibrateArgs, rec: &Recording, parse: &ParseReport, cfg: &RobotConfig) -> Result<()> {
    let opts = SelfCalOptions::from_config(cfg);
    let screen = taut_calib::screen::screen(rec, &taut_calib::screen::ScreenOptions::new(opts.min_tension_n));
    let rec = screen.recording(rec);
    crate::calibrate::print_wild(&screen);
    let nominal = cfg.anchors();
    let r = selfcal::calibrate_without_tracker(rec, &cfg.platform_points(), nominal.as_deref(), &opts)
        .context("calibration without a tracker failed")?;
    print(rec, parse, &r);
    // Nothing is written from a set that cannot be trusted: far from the nominal anchors means a
    // wrong nominal geometry, a wrong mass or a recording of another robot.
    let limit = 2.0 * cfg.daemon.max_anchor_change_m;
    if let Some(nom) = &nominal {
        for (j, (e, n)) in r.params.anchors.iter().zip(nom).enumerate() {
            let d = ((e[0] - n[0]).powi(2) + (e[1] - n[1]).powi(2) + (e[2] - n[2]).powi(2)).sqrt();
            if d > limit {
                let u = taut_calib::trust::Untrusted::FarFromNominal { cable: j, distance_m: d, limit_m: limit };
                anyhow::bail!("calibration refused, nothing written: {u}");
            }
        }
    }
    if let Some(j) = &a.json {
        taut_config::write_atomic(j, serde_json::to_string_pretty(&json(&r, &screen))?.as_bytes())
            .with_context(|| format!("writing {}", j.display()))?;
    }
    if a.plot.is_some() {
        eprintln!("note: no figures: they compare the model with the tracker, and this recording has none");
    }
    if let Some(p) = &a.out {
        params_file(cfg, &a.recording.display().to_string(), &r).save_atomic(p).with_context(|| format!("writing {}", p.display()))?;
        eprintln!("parameters written to {}", p.display());
    }
    Ok(())
}

/// What the `source` of the parameters file says about how they were made.
pub fn method(r: &SelfCalReport) -> &'static str {
    match (r.used_tensions, r.frame) {
        (true, Frame::DesignPriors) => "without tracker: encoders + load cells, design priors, frame = the design's",
        (false, Frame::DesignPriors) => "without tracker: encoders only, design priors, frame = the design's",
        (true, _) => "without tracker: encoders + load cells, frame = nominal anchors (translation, yaw)",
        (false, _) => "without tracker: encoders only, frame = nominal anchors (translation, rotation)",
    }
}

fn params_file(cfg: &RobotConfig, source: &str, r: &SelfCalReport) -> taut_config::params::ParamsFile {
    taut_config::params::ParamsFile {
        version: 1,
        created_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0),
        robot: cfg.robot.name.clone(),
        source: format!("{source} ({})", method(r)),
        ..taut_config::params::ParamsFile::from_geometry(&r.params, &r.sigma)
    }
}

fn print(rec: &Recording, parse: &ParseReport, r: &SelfCalReport) {
    println!(
        "recording: {} samples, {} cables, {:.1} s; no tracker in any row",
        parse.rows,
        rec.n_cables,
        rec.t.last().unwrap_or(&0.0) - rec.t.first().unwrap_or(&0.0)
    );
    println!("calibrated WITHOUT a tracker ({})", method(r));
    println!(
        "{}: {} {}, {} samples; load-cell noise {:.2} N; chi2/dof {:.2} ({}); {} iterations",
        if r.moving { "poses" } else { "dwells" },
        r.dwells.len(),
        if r.moving { "moving windows (no rests)" } else { "static poses" },
        r.samples_used,
        r.loadcell_sigma_n,
        r.chi2 / r.dof as f64,
        if r.chi2_ok { "consistent with the noise" } else { "FAILS the chi-square test" },
        r.iterations
    );
    let frame = match r.frame {
        Frame::NominalTranslationYaw => "anchors best aligned with the nominal ones by a translation and a rotation about the vertical",
        Frame::NominalRigid => "anchors best aligned with the nominal ones by a translation and a rotation",
        Frame::DesignPriors => "the configuration's, fixed by the design's priors on the anchors",
    };
    println!("frame: {frame}");
    println!("cable  anchor x/y/z (m)                 1-sigma (mm)            L0 (m)      1-sigma (mm)");
    for j in 0..rec.n_cables {
        let (a, s) = (r.params.anchors[j], r.sigma.anchors[j]);
        println!(
            "{:>5}  {:>9.4} {:>9.4} {:>9.4}   {:>6.2} {:>6.2} {:>6.2}   {:>9.4}   {:>6.2}",
            j + 1,
            a[0],
            a[1],
            a[2],
            s[0] * 1e3,
            s[1] * 1e3,
            s[2] * 1e3,
            r.params.l0[j],
            r.sigma.l0[j] * 1e3
        );
    }
    if r.data_share.iter().flatten().any(|v| v.is_finite()) {
        println!("share from the data (the rest from the design's prior; - where no prior):");
        println!("cable  anchor x     y     z   L0");
        let pct = |v: f64| if v.is_finite() { format!("{:>5.0}%", 100.0 * v) } else { "     -".to_string() };
        for (j, s) in r.data_share.iter().enumerate() {
            println!("{:>5}  {}{}{}{}", j + 1, pct(s[0]), pct(s[1]), pct(s[2]), pct(s[3]));
        }
    }
    println!("Cramér–Rao bound on the anchors: {:.2} mm RMS after the frame alignment", r.anchor_rms_crb_m * 1e3);
    println!("frame-free quantities:");
    for (i, j, e) in &r.distances {
        println!("  distance anchor {} - anchor {}: {:.4} m +- {:.2} mm", i + 1, j + 1, e.value, e.sigma * 1e3);
    }
    if let Some(h) = &r.heights {
        for (j, e) in h.iter().enumerate().skip(1) {
            println!("  height of anchor {} above anchor 1: {:.4} m +- {:.2} mm", j + 1, e.value, e.sigma * 1e3);
        }
    }
    if let Some(c) = &r.loadcell_offsets {
        for (j, e) in c.iter().enumerate() {
            println!("  load-cell offset of cable {}: {:.3} N +- {:.3} N", j + 1, e.value, e.sigma);
        }
    }
    if let Some(m) = &r.mass {
        println!("  platform mass: {:.4} kg +- {:.4} kg", m.value, m.sigma);
    }
    if let Some(ea) = &r.cable_ea_n {
        for (j, e) in ea.iter().enumerate() {
            println!("  stiffness EA of cable {} (stretch modelled): {:.4} MN +- {:.4} MN", j + 1, e.value * 1e-6, e.sigma * 1e-6);
        }
    }
    for n in &r.notes {
        println!("note: {n}");
    }
}

fn json(r: &SelfCalReport, screen: &taut_calib::screen::Screen) -> serde_json::Value {
    let est = |e: &selfcal::Estimate| serde_json::json!({ "value": e.value, "sigma": e.sigma, "crb": e.crb });
    serde_json::json!({
        "method": "selfcal",
        "tracker": false,
        "description": method(r),
        "anchors_m": r.params.anchors,
        "anchor_sigma_m": r.sigma.anchors,
        "l0_m": r.params.l0,
        "l0_sigma_m": r.sigma.l0,
        // Per cable [A_x, A_y, A_z, L0]: the share of the estimate from the data, 0-1 (null where
        // the configuration gives no prior).
        "data_share": r.data_share.iter().map(|c| c.map(|v| v.is_finite().then_some(v))).collect::<Vec<_>>(),
        "anchor_rms_crb_m": r.anchor_rms_crb_m,
        "distances_m": r.distances.iter().map(|(i, j, e)| serde_json::json!({ "i": i, "j": j, "distance": est(e) })).collect::<Vec<_>>(),
        "heights_m": r.heights.as_ref().map(|h| h.iter().map(est).collect::<Vec<_>>()),
        "loadcell_offsets_n": r.loadcell_offsets.as_ref().map(|h| h.iter().map(est).collect::<Vec<_>>()),
        "mass_kg": r.mass.as_ref().map(est),
        "cable_ea_n": r.cable_ea_n.as_ref().map(|h| h.iter().map(est).collect::<Vec<_>>()),
        "dwells": r.dwells.len(),
        "poses_from": if r.moving { "moving_windows" } else { "rests" },
        "samples_used": r.samples_used,
        "chi2": r.chi2,
        "dof": r.dof,
        "chi2_ok": r.chi2_ok,
        "notes": r.notes,
        "data_problems": crate::calibrate::wild_json(screen),
    })
}
