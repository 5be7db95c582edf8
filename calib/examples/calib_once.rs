//! Times `taut_calib::calibrate` on a recording: the median of several runs, one core.
//!
//! ```text
//! cargo run --release -p taut-calib --example calib_once -- REC.csv [RUNS]
//! ```
//! Starts from `REC.csv.init` (written by the `bench_data` example) or, without it, from the
//! multilateration initialisation. Prints one line `calibrate_median_ms=...` for scripts, the
//! same with the held-out solve switched off, and the parameters.

use std::time::Instant;
use taut_calib::{calibrate, init, CalibOptions, Params};
use taut_config::recording::Recording;

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().expect("usage: calib_once REC.csv [RUNS]");
    let runs: usize = args.next().map(|s| s.parse().expect("RUNS must be a number")).unwrap_or(15);
    let (rec, _) = Recording::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let b = vec![[0.0; 3]; rec.n_cables];
    let opts = CalibOptions::default();
    let start = match std::fs::read_to_string(format!("{path}.init")) {
        Ok(text) => {
            let rows: Vec<Vec<f64>> =
                text.lines().map(|l| l.split_whitespace().map(|v| v.parse().expect("number in .init")).collect()).collect();
            Params::from_cables(&rows.iter().map(|r| [r[0], r[1], r[2], r[3]]).collect::<Vec<_>>())
        }
        Err(_) => init::initialise(&rec, &b, &opts).unwrap_or_else(|e| panic!("{e}")).params,
    };
    // Wall time, and this thread's CPU time (what the calibration itself costs when other
    // processes share the cores; Linux /proc/thread-self/schedstat, ns).
    let time = |opts: &CalibOptions| -> (f64, f64, taut_calib::CalibReport) {
        let mut wall = Vec::with_capacity(runs);
        let mut cpu = Vec::with_capacity(runs);
        let mut last = None;
        for _ in 0..runs {
            let c0 = thread_cpu_ns();
            let t0 = Instant::now();
            let r = calibrate(&rec, &b, &start, opts).unwrap_or_else(|e| panic!("{e}"));
            wall.push(t0.elapsed().as_secs_f64() * 1e3);
            cpu.push((thread_cpu_ns() - c0) * 1e-6);
            last = Some(r);
        }
        (median(wall), median(cpu), last.expect("at least one run"))
    };
    let (full_ms, full_cpu, rep) = time(&opts);
    let (solve_ms, solve_cpu, _) = time(&CalibOptions { heldout_fraction: 0.0, model_check: false, ..opts.clone() });
    println!("samples={} cables={} runs={runs}", rec.len(), rec.n_cables);
    println!("calibrate_median_ms={full_ms:.3}");
    println!("calibrate_median_cpu_ms={full_cpu:.3}");
    println!("calibrate_no_heldout_median_ms={solve_ms:.3}");
    println!("calibrate_no_heldout_median_cpu_ms={solve_cpu:.3}");
    println!(
        "iterations_max={} termination={:?} rms_mm={:.3} heldout_rms_mm={:.3}",
        rep.iterations,
        rep.termination,
        rep.rms_m * 1e3,
        rep.heldout_rms_m * 1e3
    );
    println!("iterations_per_cable={:?}", rep.per_cable.iter().map(|c| c.iterations).collect::<Vec<_>>());
    for j in 0..rec.n_cables {
        let c = rep.params.cable(j);
        println!("param {j} {:.9} {:.9} {:.9} {:.9}", c[0], c[1], c[2], c[3]);
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// CPU time of the calling thread, ns (NaN where /proc is not available).
fn thread_cpu_ns() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse::<f64>().ok()))
        .unwrap_or(f64::NAN)
}
