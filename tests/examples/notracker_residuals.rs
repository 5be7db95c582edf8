//! What in a tracker-free start-up's rows disagrees with the static model: the calibration of a
//! kept recording (`TAUT_E2E_KEEP=1` on simtime's `notracker_short` / `notracker_3mm`) redone on the
//! calibrator's own data set, its chi-square split by dwell kind, cable and time in the dwell,
//! and its errors against the simulated site's truth.
//!
//! `cargo run -p taut-tests --example notracker_residuals -- CONFIG.toml RECORDING.csv SEED`
//!
//! The data set is built as the calibrator builds it (`calibrator::push_dwell_row`): labelled
//! rows only, every `daemon.calib_decimation`-th, a tension only when it is a new reading, a
//! row without values where the label changes; the held-out dwells are split off as the daemon
//! does (`notracker::split_dwells`). Printed:
//! - the fit (chi2/dof at its dof, the variance of a dwell mean per kind of reading);
//! - per dwell: whitened length residuals per cable, the whitened force balance (3) or, in a
//!   tare, the tared cables' reading minus the estimated offset;
//! - the chi-square by part (lengths, force balance of pose dwells, force balance of tares, tare
//!   rows) against its expectation;
//! - the same calibration with the first `T` seconds of every dwell left out (T = 2, 5, 10 s):
//!   a settling motion, a lagging tension or a drift after the move lowers the chi2/dof when the
//!   start is cut, pure noise does not;
//! - the calibration with every dwell's first and second half alone (a drift inside the dwells
//!   moves the two apart);
//! - aligned anchor errors against the truth per coordinate in sigmas, and the load-cell offsets
//!   and encoder offsets against the truth.

use taut_calib::selfcal::align::align_translation_yaw;
use taut_calib::selfcal::solve::G;
use taut_calib::selfcal::{self, SelfCalOptions, SelfCalReport};
use taut_config::recording::Recording;
use taut_config::RobotConfig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 4 {
        eprintln!("usage: notracker_residuals CONFIG.toml RECORDING.csv SEED");
        std::process::exit(2);
    }
    let cfg = RobotConfig::load(&args[1]).unwrap_or_else(|e| panic!("{}: {e}", args[1]));
    let (rec, _) = Recording::load(&args[2]).unwrap_or_else(|e| panic!("{}: {e}", args[2]));
    let seed: u64 = args[3].parse().expect("SEED: a number");
    let opts = SelfCalOptions::from_config(&cfg);
    let nominal = cfg.anchors().expect("nominal anchors");
    let platform = cfg.platform_points();
    let so = taut_simrig::SimOptions { seed, ..Default::default() };
    let mut rng = taut_sim::rng(seed, 0);
    let truth = taut_sim::truth::Truth::sample(&cfg, &so.physics, so.site_error_m, so.l0_range_m, &mut rng).expect("the site");

    // The calibrator's start-up set holds the excitation (the dwell plan) only: the rest dwell
    // before it (state `init-phase`) went to the initial estimate.
    let rec = excitation_rows(&rec, &args[2]);
    let set = calibrator_set(&rec, cfg.daemon.calib_decimation.max(1), 0.0, (0.0, 1.0));
    let (train, _) = taut_calibrator::notracker::split_dwells(&set, cfg.calibration.heldout_fraction);
    let r = selfcal::calibrate_without_tracker(&train, &platform, Some(&nominal), &opts).unwrap_or_else(|e| panic!("{e}"));
    let vf = r.chi2 / r.dof as f64;
    println!(
        "{} dwells, chi2/dof {vf:.3} ({:.1} / {}), P(chi2 >= that) {:.1e}; encoder sigma {:.1} um x inflation {:.2}, load-cell sigma {:.3} N x inflation {:.2}",
        r.dwells.len(),
        r.chi2,
        r.dof,
        taut_tests::honesty::chi2_sf(r.chi2, r.dof),
        r.encoder_sigma_m * 1e6,
        r.inflation.0,
        r.loadcell_sigma_n,
        r.inflation.1
    );
    residuals(&r, &platform, &opts);
    errors(&r, &truth);
    at_truth(&r, &truth, &opts, 0.0);
    // The simulated position-mode cable is stiff, not rigid (taut_sim::physics::EA_RIGID): its
    // encoder counts the unstretched length, T L / EA shorter than the geometric one.
    at_truth(&r, &truth, &opts, 1.0 / taut_sim::physics::EA_RIGID);

    println!("\nleaving out the start of every dwell (training dwells as above):");
    for skip in [2.0, 5.0, 10.0] {
        let set = calibrator_set(&rec, cfg.daemon.calib_decimation.max(1), skip, (0.0, 1.0));
        let (train, _) = taut_calibrator::notracker::split_dwells(&set, cfg.calibration.heldout_fraction);
        summary(&format!("first {skip} s left out"), selfcal::calibrate_without_tracker(&train, &platform, Some(&nominal), &opts), &truth);
    }
    // The lengths corrected by the simulated cables' stretch (the truth's offsets and the row's
    // tension): what the fit gives when the rigid-cable model holds.
    let mut stretched = Recording::with_capacity(rec.n_cables, rec.len(), true, false, true);
    for i in 0..rec.len() {
        let f = rec.tensions(i).map(|t| t.to_vec()).unwrap_or_else(|| vec![f64::NAN; rec.n_cables]);
        let l: Vec<f64> = (0..rec.n_cables)
            .map(|j| {
                let t = f[j] - truth.loadcell_offsets[j];
                let l = rec.lengths(i)[j];
                if t.is_finite() {
                    l + (l - truth.l0[j]) * t / taut_sim::physics::EA_RIGID
                } else {
                    l
                }
            })
            .collect();
        stretched.push(rec.t[i], rec.p[i], None, &l, Some(&f), rec.phase.as_ref().map(|p| p[i]));
    }
    let set = calibrator_set(&stretched, cfg.daemon.calib_decimation.max(1), 0.0, (0.0, 1.0));
    let (train, _) = taut_calibrator::notracker::split_dwells(&set, cfg.calibration.heldout_fraction);
    summary(
        "lengths corrected by the cables' stretch T L / EA",
        selfcal::calibrate_without_tracker(&train, &platform, Some(&nominal), &opts),
        &truth,
    );
    for (name, part) in [("first half of every dwell", (0.0, 0.5)), ("second half of every dwell", (0.5, 1.0))] {
        let set = calibrator_set(&rec, cfg.daemon.calib_decimation.max(1), 0.0, part);
        let (train, _) = taut_calibrator::notracker::split_dwells(&set, cfg.calibration.heldout_fraction);
        summary(name, selfcal::calibrate_without_tracker(&train, &platform, Some(&nominal), &opts), &truth);
    }
}

/// The rows of `rec` whose state column (the CSV's last, which `Recording` does not keep) says
/// `excitation`; all of them when the file has no such column.
fn excitation_rows(rec: &Recording, path: &str) -> Recording {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap_or("");
    if !header.trim_end().ends_with(",state") {
        return rec.clone();
    }
    let states: Vec<&str> = lines.map(|l| l.rsplit(',').next().unwrap_or("").trim()).collect();
    assert_eq!(states.len(), rec.len(), "{path}: rows and states differ");
    let mut out = Recording::with_capacity(rec.n_cables, rec.len(), true, false, true);
    for (i, st) in states.iter().enumerate() {
        if *st == "excitation" {
            out.push(rec.t[i], rec.p[i], None, rec.lengths(i), rec.tensions(i), rec.phase.as_ref().map(|p| p[i]));
        }
    }
    out
}

/// The calibrator's data set from a recording: labelled rows, every `decim`-th, tensions only
/// when new, a separator row where the label changes; of each dwell only the rows from `skip_s`
/// on and within the fraction `part` of its (remaining) length.
fn calibrator_set(rec: &Recording, decim: usize, skip_s: f64, part: (f64, f64)) -> Recording {
    let n = rec.n_cables;
    let phase = |i: usize| rec.phase.as_ref().map_or(-1, |p| p[i]);
    let nan = vec![f64::NAN; n];
    let mut out = Recording::with_capacity(n, rec.len(), true, false, true);
    let mut count = 0usize;
    let mut i = 0;
    while i < rec.len() {
        let ph = phase(i);
        let s = i;
        while i < rec.len() && phase(i) == ph {
            i += 1;
        }
        if ph < 0 {
            continue;
        }
        let t0 = rec.t[s] + skip_s;
        let rows: Vec<usize> = (s..i).filter(|&k| rec.t[k] >= t0).collect();
        let (a, b) = ((part.0 * rows.len() as f64) as usize, (part.1 * rows.len() as f64) as usize);
        if !out.is_empty() {
            out.push(rec.t[s], [f64::NAN; 3], None, &nan, Some(&nan), Some(-1));
        }
        for &k in &rows[a..b] {
            let keep = count.is_multiple_of(decim);
            count += 1;
            if !keep {
                continue;
            }
            let f: Vec<f64> = (0..n)
                .map(|j| {
                    let v = rec.tensions(k).map_or(f64::NAN, |t| t[j]);
                    let prev = if k > 0 { rec.tensions(k - 1).map_or(f64::NAN, |t| t[j]) } else { f64::NAN };
                    if v.to_bits() == prev.to_bits() {
                        f64::NAN
                    } else {
                        v
                    }
                })
                .collect();
            out.push(rec.t[k], [f64::NAN; 3], None, rec.lengths(k), Some(&f), Some(ph));
        }
    }
    out
}

fn unit(a: [f64; 3], p: [f64; 3], b: [f64; 3]) -> ([f64; 3], f64) {
    let dv = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
    let rho = (dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]).sqrt();
    ([dv[0] / rho, dv[1] / rho, dv[2] / rho], rho)
}

/// Per dwell whitened residuals and the chi-square by part.
fn residuals(r: &SelfCalReport, platform: &[[f64; 3]], opts: &SelfCalOptions) {
    let n = platform.len();
    let c: Vec<f64> = r.loadcell_offsets.as_ref().map_or(vec![0.0; n], |v| v.iter().map(|e| e.value).collect());
    let var_l = r.encoder_sigma_m.powi(2) * r.inflation.0;
    let var_f = r.loadcell_sigma_n.powi(2) * r.inflation.1;
    // (lengths, pose force balance, tare force balance, tare rows): chi2 and rows.
    let mut parts = [(0.0, 0usize); 4];
    let mut by_cable = vec![0.0; n];
    println!("dwell label rows | length residual / sigma per cable | force balance / sigma (x y z) | tare: reading - offset / sigma");
    for (k, d) in r.dwells.iter().enumerate() {
        let p = r.poses[k];
        let tared = d.tared(opts.min_tension_n);
        let mut fvec = [0.0, 0.0, -opts.mass_kg * G];
        let mut cov = nalgebra::Matrix3::zeros();
        let mut lres = Vec::new();
        let mut tres = Vec::new();
        for j in 0..n {
            if tared[j] {
                let z = (d.f[j] - c[j]) / (var_f / d.nf[j] as f64).sqrt();
                parts[3].0 += z * z;
                parts[3].1 += 1;
                tres.push(format!("c{j} {z:+.1}"));
                lres.push("   - ".to_string());
                continue;
            }
            let (v, rho) = unit(r.params.anchors[j], p, platform[j]);
            let z = (d.l[j] - rho - r.params.l0[j]) / (var_l / d.nl[j] as f64).sqrt();
            parts[0].0 += z * z;
            parts[0].1 += 1;
            by_cable[j] += z * z;
            lres.push(format!("{z:+5.1}"));
            for q in 0..3 {
                fvec[q] += v[q] * (d.f[j] - c[j]);
            }
            let vv = nalgebra::Vector3::from(v);
            cov += vv * vv.transpose() * (var_f / d.nf[j] as f64);
        }
        let zf = cov.cholesky().map(|ch| ch.l().try_inverse().unwrap() * nalgebra::Vector3::from(fvec));
        let zf = zf.map_or([f64::NAN; 3], |v| [v[0], v[1], v[2]]);
        let part = if d.is_tare() { 2 } else { 1 };
        parts[part].0 += zf.iter().map(|z| z * z).sum::<f64>();
        parts[part].1 += 3;
        println!(
            "{k:3} {:3} {:6} | {} | {:+5.1} {:+5.1} {:+5.1} | {}",
            d.label,
            d.end - d.start,
            lres.join(" "),
            zf[0],
            zf[1],
            zf[2],
            tres.join(" ")
        );
    }
    let names = ["lengths", "force balance, pose dwells", "force balance, tares", "tare rows"];
    let rows: usize = parts.iter().map(|p| p.1).sum();
    println!(
        "chi2 by part (the fit takes {} dof of {rows} rows, {:.2} of a row each on average):",
        rows - r.dof,
        (rows - r.dof) as f64 / rows as f64
    );
    for (name, (chi, k)) in names.iter().zip(parts) {
        println!("  {name}: {chi:.1} over {k} rows ({:.2} per row)", chi / k.max(1) as f64);
    }
    println!("  lengths by cable: {}", by_cable.iter().map(|v| format!("{v:.1}")).collect::<Vec<_>>().join(" "));
}

/// Aligned anchor errors in sigmas, offsets against the truth.
fn errors(r: &SelfCalReport, truth: &taut_sim::truth::Truth) {
    let aligned = align_translation_yaw(&r.params.anchors, &truth.anchors);
    println!("anchor errors after the alignment, mm (sigma, mm):");
    let mut worst: f64 = 0.0;
    for (j, (a, t)) in aligned.iter().zip(&truth.anchors).enumerate() {
        let e: Vec<f64> = (0..3).map(|i| a[i] - t[i]).collect();
        worst = worst.max((e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt());
        let s = r.sigma.anchors[j];
        println!(
            "  anchor {j}: {}",
            (0..3).map(|i| format!("{:+.2} ({:.2}, {:+.1} sigma)", e[i] * 1e3, s[i] * 1e3, e[i] / s[i])).collect::<Vec<_>>().join("  ")
        );
    }
    println!("  worst {:.2} mm", worst * 1e3);
    if let Some(c) = &r.loadcell_offsets {
        println!(
            "load-cell offsets - truth, N (sigma): {}",
            c.iter()
                .zip(&truth.loadcell_offsets)
                .map(|(e, t)| format!("{:+.3} ({:.3})", e.value - t, e.sigma))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
}

/// The same dwells against the site's truth (anchors, encoder offsets and scales, load-cell
/// offsets, mass): per dwell the position from its lengths, then the force balance whitened as
/// in the fit. Nothing is fitted but the position (3 of each dwell's 4 lengths' dof), so the
/// force rows' chi2 per row is ~1 for rows that agree with the static model and the noise.
fn at_truth(r: &SelfCalReport, truth: &taut_sim::truth::Truth, opts: &SelfCalOptions, compliance_per_n: f64) {
    let n = truth.anchors.len();
    let var_f = r.loadcell_sigma_n.powi(2) * r.inflation.1;
    let var_l = r.encoder_sigma_m.powi(2) * r.inflation.0;
    let (mut chi_f, mut rows_f, mut chi_l, mut rows_l) = (0.0, 0usize, 0.0, 0usize);
    let mut zs = Vec::new();
    for d in &r.dwells {
        let tared = d.tared(opts.min_tension_n);
        let used: Vec<usize> = (0..n).filter(|&j| !tared[j]).collect();
        // Geometric length from the reading: (l - L0) / scale, stretched by the tension x
        // `compliance_per_n` (0: the static model's rigid cable).
        let len = |j: usize| (d.l[j] - truth.l0[j]) / truth.scale[j] * (1.0 + (d.f[j] - truth.loadcell_offsets[j]) * compliance_per_n);
        let mut p = [0.0; 3];
        for &j in &used {
            for (a, pa) in p.iter_mut().enumerate() {
                *pa += (truth.anchors[j][a] - truth.platform_points[j][a]) / used.len() as f64;
            }
        }
        p[2] -= 1.5;
        for _ in 0..100 {
            let (mut h, mut g) = (nalgebra::Matrix3::zeros(), nalgebra::Vector3::zeros());
            for &j in &used {
                let (u, rho) = unit(truth.anchors[j], p, truth.platform_points[j]);
                // d rho / d p = -u
                let jv = -nalgebra::Vector3::from(u);
                h += jv * jv.transpose();
                g += jv * (len(j) - rho);
            }
            let step = h.lu().solve(&g).unwrap_or_else(nalgebra::Vector3::zeros);
            for a in 0..3 {
                p[a] += step[a];
            }
            if step.norm() < 1e-12 {
                break;
            }
        }
        let mut fvec = [0.0, 0.0, -truth.mass_kg * G];
        let mut cov = nalgebra::Matrix3::zeros();
        for &j in &used {
            let (v, rho) = unit(truth.anchors[j], p, truth.platform_points[j]);
            let z = (len(j) - rho) * truth.scale[j] / (var_l / d.nl[j] as f64).sqrt();
            chi_l += z * z;
            rows_l += 1;
            for q in 0..3 {
                fvec[q] += v[q] * (d.f[j] - truth.loadcell_offsets[j]);
            }
            let vv = nalgebra::Vector3::from(v);
            cov += vv * vv.transpose() * (var_f / d.nf[j] as f64);
        }
        let l = cov.cholesky().map(|c| c.l().try_inverse().unwrap());
        if let Some(l) = l {
            let z = l * nalgebra::Vector3::from(fvec);
            chi_f += z.norm_squared();
            rows_f += 3;
            zs.push(format!(
                "{}{}: {:+.1} {:+.1} {:+.1} ({:+.4} {:+.4} {:+.4} N)",
                if d.is_tare() { "T" } else { "" },
                d.label,
                z[0],
                z[1],
                z[2],
                fvec[0],
                fvec[1],
                fvec[2]
            ));
        }
    }
    println!(
        "at the truth, cable compliance {compliance_per_n:.0e} / N (positions from the lengths): force balance chi2 {chi_f:.1} over {rows_f} rows ({:.2} per row), lengths {chi_l:.1} over {rows_l} rows (positions take {} of them)",
        chi_f / rows_f.max(1) as f64,
        3 * r.dwells.len()
    );
    for z in zs {
        println!("  {z}");
    }
}

fn summary(name: &str, r: Result<SelfCalReport, selfcal::SelfCalError>, truth: &taut_sim::truth::Truth) {
    match r {
        Ok(r) => {
            let aligned = align_translation_yaw(&r.params.anchors, &truth.anchors);
            let worst = aligned
                .iter()
                .zip(&truth.anchors)
                .map(|(a, t)| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt())
                .fold(0.0, f64::max);
            let sig = r.sigma.anchors.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).fold(0.0, f64::max);
            println!(
                "  {name}: chi2/dof {:.3} at {} dof (P {:.1e}), worst anchor {:.2} mm, worst-anchor sigma {:.2} mm",
                r.chi2 / r.dof as f64,
                r.dof,
                taut_tests::honesty::chi2_sf(r.chi2, r.dof),
                worst * 1e3,
                sig * 1e3
            );
        }
        Err(e) => println!("  {name}: {e}"),
    }
}
