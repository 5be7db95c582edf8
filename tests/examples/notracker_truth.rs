//! A tracker-free start-up's dwell readings against the simulated site's truth: whether what the
//! devices and the loop deliver in a dwell is the static truth plus white noise, from its first
//! second on.
//!
//! `TAUT_E2E_KEEP=1 TAUT_E2E_TRUTH=1 cargo test -p taut-tests --test simtime notracker_3mm -- --ignored --nocapture`
//! keeps the recording and `truth.csv` (the site's platform position, true tensions and drum
//! lengths every 5 ms of wall clock); then
//! `cargo run -p taut-tests --example notracker_truth -- CONFIG.toml RECORDING.csv TRUTH.csv SEED`.
//!
//! Per recorded dwell (labelled rows of the excitation, as the calibrator takes them: a tension
//! only when its value changed): the truth samples taken while the platform stood there (every
//! cable's noise-free encoder value within 30 um and its true tension within 0.2 N of the dwell's
//! mean reading), how much the
//! platform and the tensions moved among them, and the dwell's mean readings minus the truth in
//! units of their standard error (sigma of one reading / sqrt(readings), the encoders' by batch
//! means for repeated rows). Then the same residuals by second from the dwell's first labelled
//! row: a settling platform, a tension read before the dwell or a lagging load cell shows in the
//! first seconds; white noise gives z ~ N(0, 1) everywhere.

use taut_config::recording::Recording;
use taut_config::RobotConfig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 5 {
        eprintln!("usage: notracker_truth CONFIG.toml RECORDING.csv TRUTH.csv SEED");
        std::process::exit(2);
    }
    let cfg = RobotConfig::load(&args[1]).unwrap_or_else(|e| panic!("{}: {e}", args[1]));
    let (rec, _) = Recording::load(&args[2]).unwrap_or_else(|e| panic!("{}: {e}", args[2]));
    let seed: u64 = args[4].parse().expect("SEED: a number");
    let n = rec.n_cables;
    let so = taut_simrig::SimOptions { seed, ..Default::default() };
    let mut rng = taut_sim::rng(seed, 0);
    let truth = taut_sim::truth::Truth::sample(&cfg, &so.physics, so.site_error_m, so.l0_range_m, &mut rng).expect("the site");
    let text = std::fs::read_to_string(&args[3]).unwrap_or_else(|e| panic!("{}: {e}", args[3]));
    // wall s, p (3), tension (n), drum (n); a torn last line is skipped.
    let samples: Vec<Vec<f64>> = text
        .lines()
        .map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap_or(f64::NAN)).collect::<Vec<f64>>())
        .filter(|v| v.len() == 4 + 2 * n && v.iter().all(|x| x.is_finite()))
        .collect();
    let enc = |s: &Vec<f64>, j: usize| truth.encoder(j, s[4 + n + j]);
    let phase = |i: usize| rec.phase.as_ref().map_or(-1, |p| p[i]);
    let states = states(&args[2], rec.len());
    println!("{} truth samples, {} recorded rows", samples.len(), rec.len());
    println!("dwell label rows truth | platform moved (um) | true tension moved (mN) | length z per cable | tension z per cable");
    // By second from the dwell's start: (sum of residual / sigma, count) per kind.
    let bins = 40;
    let mut by_s = vec![[(0.0f64, 0usize); 4]; bins];
    // By second: the largest distance of the true platform and the largest change of a true
    // tension from their values in the dwell's middle half, over the dwells.
    let mut stray = vec![(0.0f64, 0.0f64); bins];
    let (mut chi_l, mut k_l, mut chi_f, mut k_f) = (0.0, 0usize, 0.0, 0usize);
    // Per (dwell, cable): length mean - truth, its white-noise variance, its batch-means variance.
    let mut lcells: Vec<(f64, f64, f64)> = Vec::new();
    let mut segs = Vec::new();
    let mut i = 0;
    while i < rec.len() {
        let ph = phase(i);
        let s = i;
        while i < rec.len() && phase(i) == ph {
            i += 1;
        }
        if ph >= 0 && states[s] == "excitation" && i - s >= 100 {
            segs.push((s, i, ph));
        }
    }
    // The truth's wall clock against the recording's: each dwell's last truth sample whose
    // lengths and tensions match the dwell's means, against the dwell's last row (the move or the
    // tare's ramp starts there); the median over the dwells.
    let mut ends: Vec<f64> = segs
        .iter()
        .filter_map(|&(s, i, _)| {
            let lm: Vec<f64> = (0..n).map(|j| (s..i).map(|k| rec.lengths(k)[j]).sum::<f64>() / (i - s) as f64).collect();
            let fm: Vec<f64> = (0..n)
                .map(|j| {
                    let v: Vec<f64> = (s..i).filter_map(|k| rec.tensions(k).map(|t| t[j])).filter(|v| v.is_finite()).collect();
                    v.iter().sum::<f64>() / v.len().max(1) as f64
                })
                .collect();
            samples
                .iter()
                .filter(|smp| {
                    (0..n).all(|j| (enc(smp, j) - lm[j]).abs() < 3e-5 && (smp[4 + j] + truth.loadcell_offsets[j] - fm[j]).abs() < 0.2)
                })
                .map(|smp| smp[0])
                .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.max(t))))
                .map(|t| t - rec.t[i - 1])
        })
        .collect();
    ends.sort_by(f64::total_cmp);
    let offset = ends[ends.len() / 2];
    println!(
        "truth clock - recording clock: {offset:.3} s (median over {} dwells; quartiles {:+.3} / {:+.3} s from it)",
        ends.len(),
        ends[ends.len() / 4] - offset,
        ends[3 * ends.len() / 4] - offset
    );
    for &(s, i, ph) in &segs {
        // The dwell's readings (tensions new by value, as the calibrator keeps them).
        let lens: Vec<Vec<f64>> = (0..n).map(|j| (s..i).map(|k| rec.lengths(k)[j]).collect()).collect();
        let tens: Vec<Vec<(f64, f64)>> = (0..n)
            .map(|j| {
                (s..i)
                    .filter_map(|k| {
                        let v = rec.tensions(k).map_or(f64::NAN, |t| t[j]);
                        let prev = if k > 0 { rec.tensions(k - 1).map_or(f64::NAN, |t| t[j]) } else { f64::NAN };
                        (v.is_finite() && v.to_bits() != prev.to_bits()).then_some((rec.t[k] - rec.t[s], v))
                    })
                    .collect()
            })
            .collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let lm: Vec<f64> = lens.iter().map(|v| mean(v)).collect();
        // The truth while the dwell's rows were recorded (the clocks aligned above).
        let (t_a, t_b) = (rec.t[s] + offset, rec.t[i - 1] + offset);
        let matched: Vec<&Vec<f64>> = samples.iter().filter(|smp| smp[0] >= t_a && smp[0] <= t_b).collect();
        if matched.is_empty() {
            println!("{ph:3}: no truth sample in the dwell's time");
            continue;
        }
        // How far the truth strays from its value in the dwell's middle half, by second.
        let mid: Vec<&&Vec<f64>> = matched[matched.len() / 4..3 * matched.len() / 4].iter().collect();
        let p_mid: Vec<f64> = (0..3 + n).map(|c| mid.iter().map(|smp| smp[1 + c]).sum::<f64>() / mid.len() as f64).collect();
        for smp in &matched {
            let sec = ((smp[0] - t_a) as usize).min(bins - 1);
            let dp = (0..3).map(|a| (smp[1 + a] - p_mid[a]).powi(2)).sum::<f64>().sqrt();
            let df = (0..n).map(|j| (smp[4 + j] - p_mid[3 + j]).abs()).fold(0.0, f64::max);
            stray[sec].0 = stray[sec].0.max(dp);
            stray[sec].1 = stray[sec].1.max(df);
        }
        let spread = |f: &dyn Fn(&Vec<f64>) -> f64| {
            let (lo, hi) = matched.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| (lo.min(f(s)), hi.max(f(s))));
            hi - lo
        };
        let moved = (0..3).map(|a| spread(&|s: &Vec<f64>| s[1 + a])).fold(0.0, f64::max);
        let tmoved = (0..n).map(|j| spread(&|s: &Vec<f64>| s[4 + j])).fold(0.0, f64::max);
        // The truth's values in the dwell's middle half (the clocks are aligned to tens of ms
        // only: the window's ends may reach into the move or the tare's ramp).
        let t_true: Vec<f64> = (0..n).map(|j| mid.iter().map(|s| s[4 + j]).sum::<f64>() / mid.len() as f64).collect();
        let e_true: Vec<f64> = (0..n).map(|j| mid.iter().map(|s| enc(s, j)).sum::<f64>() / mid.len() as f64).collect();
        let (mut zl, mut zf) = (Vec::new(), Vec::new());
        for j in 0..n {
            // Lengths: the standard error of the mean by 10 batch means (repeated rows).
            let v = &lens[j];
            let b = v.len() / 10;
            let bm: Vec<f64> = (0..10).map(|k| mean(&v[k * b..(k + 1) * b])).collect();
            let m10 = mean(&bm);
            let se_l = (bm.iter().map(|x| (x - m10).powi(2)).sum::<f64>() / 9.0 / 10.0).sqrt();
            let sd_l = (v.iter().map(|x| (x - lm[j]).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
            let z = (lm[j] - e_true[j]) / se_l.max(sd_l / (v.len() as f64).sqrt());
            chi_l += z * z;
            k_l += 1;
            lcells.push((lm[j] - e_true[j], sd_l * sd_l / v.len() as f64, se_l * se_l));
            if std::env::var_os("TAUT_TRUTH_CELLS").is_some() {
                eprintln!("cell {ph} {j} {:.7} {:+.3} {:.3}", lm[j], (lm[j] - e_true[j]) * 1e6, sd_l / (v.len() as f64).sqrt() * 1e6);
            }
            zl.push(format!("{z:+5.1}"));
            // Tensions: new readings, independent draws.
            let f = &tens[j];
            let vals: Vec<f64> = f.iter().map(|x| x.1).collect();
            let fm = mean(&vals);
            let sd_f = (vals.iter().map(|x| (x - fm).powi(2)).sum::<f64>() / (vals.len() - 1) as f64).sqrt();
            let z = (fm - t_true[j] - truth.loadcell_offsets[j]) / (sd_f / (vals.len() as f64).sqrt());
            chi_f += z * z;
            k_f += 1;
            zf.push(format!("{z:+5.1}"));
            // By second: residual / sigma of one reading, summed over the dwell's second, and
            // that second's z^2 (its sign differs between cables and dwells).
            let mut cell = vec![[(0.0f64, 0usize); 2]; bins];
            for (k, &x) in v.iter().enumerate() {
                let sec = ((rec.t[s + k] - rec.t[s]) as usize).min(bins - 1);
                cell[sec][0].0 += (x - e_true[j]) / sd_l;
                cell[sec][0].1 += 1;
            }
            for &(dt, x) in f {
                let sec = (dt as usize).min(bins - 1);
                cell[sec][1].0 += (x - t_true[j] - truth.loadcell_offsets[j]) / sd_f;
                cell[sec][1].1 += 1;
            }
            for (b, c) in by_s.iter_mut().zip(&cell) {
                for kind in 0..2 {
                    if c[kind].1 > 0 {
                        b[kind].0 += c[kind].0 / (c[kind].1 as f64).sqrt();
                        b[kind].1 += 1;
                        b[kind + 2].0 += c[kind].0 * c[kind].0 / c[kind].1 as f64;
                        b[kind + 2].1 += 1;
                    }
                }
            }
        }
        println!(
            "{ph:3} {:6} {:5} | {:7.2} | {:7.2} | {} | {}",
            i - s,
            matched.len(),
            moved * 1e6,
            tmoved * 1e3,
            zl.join(" "),
            zf.join(" ")
        );
    }
    // The lengths' variance inflation for repeated rows pooled over every dwell and cable (as
    // the fit pools it), then the chi-square with it.
    let infl = (lcells.iter().map(|c| c.2).sum::<f64>() / lcells.iter().map(|c| c.1).sum::<f64>()).max(1.0);
    let chi_lp: f64 = lcells.iter().map(|c| c.0 * c.0 / (c.1 * infl)).sum();
    println!(
        "lengths with the pooled batch-means inflation {infl:.3}: chi2 {chi_lp:.1} over {} ({:.2} each)",
        lcells.len(),
        chi_lp / lcells.len().max(1) as f64
    );
    println!(
        "dwell means against the truth (each z by its own 10 batch means for the lengths: Student t, 9 dof, E z^2 = 1.29): lengths chi2 {chi_l:.1} over {k_l} ({:.2} each), tensions chi2 {chi_f:.1} over {k_f} ({:.2} each)",
        chi_l / k_l.max(1) as f64,
        chi_f / k_f.max(1) as f64
    );
    println!("by second from the dwell's first labelled row, over every dwell and cable: each (dwell, cable, second)'s z = sum(residual / sigma) / sqrt(readings); mean z and mean z^2 (white noise: 0 +- 1/sqrt(cells), 1; lengths not corrected for repeated rows)");
    for (sec, b) in by_s.iter().enumerate() {
        if b[0].1 == 0 && b[1].1 == 0 {
            continue;
        }
        let m = |x: (f64, usize)| x.0 / x.1.max(1) as f64;
        println!(
            "  {sec:2} s: truth moved <= {:6.2} um, tensions <= {:6.1} mN; lengths mean z {:+5.2}, mean z^2 {:5.2} ({} cells); tensions mean z {:+5.2}, mean z^2 {:5.2} ({} cells)",
            stray[sec].0 * 1e6,
            stray[sec].1 * 1e3,
            m(b[0]),
            m(b[2]),
            b[0].1,
            m(b[1]),
            m(b[3]),
            b[1].1
        );
    }
}

/// The state column (the CSV's last) of each row.
fn states(path: &str, rows: usize) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let _header = lines.next();
    let v: Vec<String> = lines.map(|l| l.rsplit(',').next().unwrap_or("").trim().to_string()).collect();
    assert_eq!(v.len(), rows, "{path}: rows and states differ");
    v
}
