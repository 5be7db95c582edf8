//! Per-dwell, per-cable residuals of a tracker-free calibration, and what the readings inside
//! each dwell look like (how many are distinct, how correlated consecutive ones are): the tool
//! that explains a chi2/dof above 1.
//!
//! `cargo run -p taut-calib --example selfcal_residuals -- CONFIG.toml RECORDING.csv`
//!
//! Prints, per dwell: its rows, the distinct tension and length readings per cable (a reading
//! held over several rows counts once), the lag-1 autocorrelation of the tensions over rows,
//! the whitened length residuals per cable and the whitened force-balance residual; then the
//! chi-square split into its length and force parts.

use taut_calib::selfcal::{self, dwell, SelfCalOptions};
use taut_config::recording::Recording;
use taut_config::RobotConfig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: selfcal_residuals CONFIG.toml RECORDING.csv");
        std::process::exit(2);
    }
    let cfg = RobotConfig::load(&args[1]).unwrap_or_else(|e| panic!("{}: {e}", args[1]));
    let (rec, _) = Recording::load(&args[2]).unwrap_or_else(|e| panic!("{}: {e}", args[2]));
    let n = rec.n_cables;
    let nominal = cfg.anchors().expect("nominal anchors");
    let platform = cfg.platform_points();
    let opts = SelfCalOptions::from_config(&cfg);
    let r = selfcal::calibrate_without_tracker(&rec, &platform, Some(&nominal), &opts).unwrap_or_else(|e| panic!("{e}"));
    println!(
        "{} dwells, chi2/dof {:.2} ({:.0} / {}), load-cell sigma {:.3} N, encoder sigma {:.1} um",
        r.dwells.len(),
        r.chi2 / r.dof as f64,
        r.chi2,
        r.dof,
        r.loadcell_sigma_n,
        opts.encoder_sigma_m * 1e6
    );
    let c: Vec<f64> = r.loadcell_offsets.as_ref().map_or(vec![0.0; n], |v| v.iter().map(|e| e.value).collect());
    let (mut chi_l, mut chi_f, mut rows_l, mut rows_f) = (0.0, 0.0, 0usize, 0usize);
    let (mut chi_l_d, mut chi_f_d) = (0.0, 0.0);
    let var_l = opts.encoder_sigma_m.powi(2);
    let var_f = r.loadcell_sigma_n.powi(2);
    println!("dwell rows | distinct f per cable | distinct l | rho1(f) | length residual/sigma per cable | force residual/sigma (whitened, 3) | same with distinct counts");
    for (k, d) in r.dwells.iter().enumerate() {
        let p = r.poses[k];
        let distinct = |get: &dyn Fn(usize) -> f64| (d.start + 1..d.end).filter(|&i| get(i) != get(i - 1)).count() + 1;
        let df: Vec<usize> = (0..n).map(|j| distinct(&|i| rec.tensions(i).map_or(f64::NAN, |t| t[j]))).collect();
        let dl: Vec<usize> = (0..n).map(|j| distinct(&|i| rec.lengths(i)[j])).collect();
        let rho1: Vec<f64> = (0..n)
            .map(|j| {
                let v: Vec<f64> = (d.start..d.end).map(|i| rec.tensions(i).map_or(f64::NAN, |t| t[j])).collect();
                let m = v.iter().sum::<f64>() / v.len() as f64;
                let c0 = v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
                let c1 = v.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum::<f64>();
                c1 / c0
            })
            .collect();
        let mut lres = Vec::new();
        let mut lres_d = Vec::new();
        let mut fvec = [0.0, 0.0, -opts.mass_kg * 9.81];
        let mut vs = Vec::new();
        for j in 0..n {
            let a = r.params.anchors[j];
            let b = platform[j];
            let dv = [a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]];
            let rho = (dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]).sqrt();
            let v = [dv[0] / rho, dv[1] / rho, dv[2] / rho];
            let e = d.l[j] - rho - r.params.l0[j];
            let z = e / (var_l / d.nl[j] as f64).sqrt();
            let zd = e / (var_l / dl[j] as f64).sqrt();
            chi_l += z * z;
            chi_l_d += zd * zd;
            rows_l += 1;
            lres.push(z);
            lres_d.push(zd);
            for q in 0..3 {
                fvec[q] += v[q] * (d.f[j] - c[j]);
            }
            vs.push(v);
        }
        let whiten = |counts: &dyn Fn(usize) -> f64| {
            let mut cov = nalgebra::Matrix3::zeros();
            for (j, v) in vs.iter().enumerate() {
                let v = nalgebra::Vector3::from(*v);
                cov += v * v.transpose() * (var_f / counts(j));
            }
            let l = cov.cholesky().unwrap().l().try_inverse().unwrap();
            l * nalgebra::Vector3::from(fvec)
        };
        let zf = whiten(&|j| d.nf[j] as f64);
        let zf_d = whiten(&|j| df[j] as f64);
        chi_f += zf.norm_squared();
        chi_f_d += zf_d.norm_squared();
        rows_f += 3;
        println!(
            "{k:3} L{:<3} f {:?} {:5} | {:?} | {:?} | {} | {} | {:+.1} {:+.1} {:+.1} | {:+.1} {:+.1} {:+.1}",
            d.label,
            d.f.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>(),
            d.end - d.start,
            df,
            dl,
            rho1.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" "),
            lres.iter().map(|x| format!("{x:+.1}")).collect::<Vec<_>>().join(" "),
            zf[0],
            zf[1],
            zf[2],
            zf_d[0],
            zf_d[1],
            zf_d[2]
        );
        let _ = &lres_d;
    }
    println!(
        "chi2 split (rows as the fit counts them): lengths {:.0} over {} rows ({:.2} per row), forces {:.0} over {} rows ({:.2} per row)",
        chi_l,
        rows_l,
        chi_l / rows_l as f64,
        chi_f,
        rows_f,
        chi_f / rows_f as f64
    );
    println!(
        "with distinct readings as the counts: lengths {:.0} ({:.2} per row), forces {:.0} ({:.2} per row); per-row chi2 of a correct model is below 1 (the fit absorbs dof)",
        chi_l_d,
        chi_l_d / rows_l as f64,
        chi_f_d,
        chi_f_d / rows_f as f64
    );
    let found = dwell::find(&rec, opts.encoder_sigma_m, opts.min_dwell_samples);
    println!("dwell search: {} dwells, {} samples, {} drifting", found.dwells.len(), found.samples, found.drifting);
    // The calibrator's data set keeps each tension only when it is a new reading: the same
    // recording with repeated tension values blanked.
    let mut dd = Recording::with_capacity(n, rec.len(), true, false, true);
    for i in 0..rec.len() {
        let f: Vec<f64> = (0..n)
            .map(|j| {
                let v = rec.tensions(i).map_or(f64::NAN, |t| t[j]);
                if i > 0 && rec.tensions(i - 1).map_or(f64::NAN, |t| t[j]) == v {
                    f64::NAN
                } else {
                    v
                }
            })
            .collect();
        dd.push(rec.t[i], rec.p[i], None, rec.lengths(i), Some(&f), rec.phase.as_ref().map(|p| p[i]));
    }
    let found = dwell::find(&dd, opts.encoder_sigma_m, opts.min_dwell_samples);
    println!(
        "repeats blanked: {} dwells, inflation lengths {:.2} tensions {:.2}",
        found.dwells.len(),
        found.length_inflation,
        found.tension_inflation
    );
    // As the calibrator builds its data set: labelled rows only, a row without lengths where
    // the label changes.
    let mut cs = Recording::with_capacity(n, rec.len(), true, false, true);
    let nan = vec![f64::NAN; n];
    for i in 0..dd.len() {
        let ph = dd.phase.as_ref().map_or(-1, |p| p[i]);
        if ph < 0 {
            continue;
        }
        if i > 0 && dd.phase.as_ref().map_or(-1, |p| p[i - 1]) != ph && !cs.is_empty() {
            cs.push(dd.t[i], [f64::NAN; 3], None, &nan, Some(&nan), Some(-1));
        }
        cs.push(dd.t[i], dd.p[i], None, dd.lengths(i), dd.tensions(i), Some(ph));
    }
    let found = dwell::find(&cs, opts.encoder_sigma_m, opts.min_dwell_samples);
    println!(
        "as the calibrator's set: {} dwells ({:?})",
        found.dwells.len(),
        found.dwells.iter().map(|d| (d.label, d.end - d.start)).collect::<Vec<_>>()
    );
    match selfcal::calibrate_without_tracker(&dd, &platform, Some(&nominal), &opts) {
        Ok(r) => println!("repeats blanked: chi2/dof {:.2}, sigma_f {:.3}", r.chi2 / r.dof as f64, r.loadcell_sigma_n),
        Err(e) => println!("repeats blanked: {e}"),
    }
}
