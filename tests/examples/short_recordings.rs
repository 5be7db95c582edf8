//! Power and size of `taut diagnose` on recordings shaped like a real robot's logger makes them
//! (issue 28): 1,000 rows at about 4 Hz, irregular intervals, 9 % stale rows, a 6-DoF platform,
//! no tensions ([`taut_sim::field`]). Per seed, one recording with a time offset drawn in
//! 10-50 ms and one effect-free; prints one line per recording and the table of BENCHMARKS.md.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example short_recordings -- [seeds, default 50] [rows, default 1000]
//! ```
//!
//! `SHORT_BEFORE=1`: stale rows kept, as before issue 28; `SHORT_TRACKER_PHI=0.99`: AR(1) tracker
//! noise (per 50 Hz grid sample: 0.88 from one row to the next); `SHORT_GRID_HZ`, `SHORT_FIRST`
//! (first seed), `SHORT_HELDOUT` (held-out fraction), `SHORT_VERBOSE=1` (data problems and every
//! held-out test).

use std::time::Instant;
use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::field::{field_robot, field_scenario, try_field_recording, Logger};
use taut_sim::Physics;

fn main() {
    let seeds: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(50);
    let rows: usize = std::env::args().nth(2).and_then(|a| a.parse().ok()).unwrap_or(1000);
    let grid_hz: f64 = std::env::var("SHORT_GRID_HZ").ok().and_then(|v| v.parse().ok()).unwrap_or(Logger::default().grid_hz);
    let logger = Logger { rows, grid_hz, ..Logger::default() };
    let mut sim_secs = 0.0;
    // SHORT_TRACKER_PHI: the tracker noise's lag-1 correlation per grid sample (0: white).
    let tracker_phi: f64 = std::env::var("SHORT_TRACKER_PHI").ok().and_then(|v| v.parse().ok()).unwrap_or(0.0);
    let cfg = field_robot();
    // SHORT_BEFORE=1: stale rows kept, as before issue 28 (`DiagnoseOptions::stale_rows`).
    let before = std::env::var("SHORT_BEFORE").is_ok_and(|v| v == "1");
    let mut opts = DiagnoseOptions { stale_rows: !before, ..DiagnoseOptions::from_config(&cfg.calibration) };
    // SHORT_HELDOUT: the held-out fraction (default the configuration's, 0.2).
    if let Some(f) = std::env::var("SHORT_HELDOUT").ok().and_then(|v| v.parse().ok()) {
        opts.heldout_fraction = f;
    }
    // Offset bins: [lo, hi) ms -> (recordings, named, named within 20 %).
    let bins = [(10.0, 20.0), (20.0, 35.0), (35.0, 50.01)];
    let mut counts = vec![(0usize, 0usize, 0usize); bins.len()];
    let (mut null_n, mut null_claims) = (0usize, 0usize);
    let t0 = Instant::now();
    let first: u64 = std::env::var("SHORT_FIRST").ok().and_then(|v| v.parse().ok()).unwrap_or(1);
    for seed in first..first + seeds {
        // 10-50 ms, spread evenly over the seeds (deterministic).
        let offset_ms = 10.0 + 40.0 * ((seed - first) as f64 + 0.5) / seeds as f64;
        for with in [true, false] {
            let physics = Physics { time_offset_s: if with { offset_ms * 1e-3 } else { 0.0 }, ..Physics::ideal() };
            let t = Instant::now();
            let mut sc = field_scenario(seed, &logger);
            sc.physics = physics;
            sc.noise.tracker_phi = tracker_phi;
            let run = try_field_recording(&sc, &logger).expect("simulation");
            sim_secs += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let d = diagnose(&run.recording, &run.sim.truth.platform_points, None, &opts).expect("diagnosis");
            let secs = t.elapsed().as_secs_f64();
            let named: Vec<Effect> = d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect();
            let off = d.effects.iter().find(|f| f.effect == Effect::TimeOffset).map(|f| f.values[0]);
            let p1 = d.tests.iter().find(|c| c.round == 1 && c.effect == Effect::TimeOffset).and_then(|c| c.test);
            let stale =
                d.data_problems.iter().filter(|p| p.kind == taut_calib::diagnose::ProblemKind::StaleRow).map(|p| p.samples).sum::<usize>();
            println!(
                "seed {seed:3} offset {:5.1} ms: named {:?} offset {} | stale {stale}/{} | round-1 time-offset test {} | {secs:.2} s",
                if with { offset_ms } else { 0.0 },
                named.iter().map(|e| e.name()).collect::<Vec<_>>(),
                off.map_or("-".into(), |v| format!("{:.1} ms", v * 1e3)),
                run.stale.iter().filter(|&&s| s).count(),
                p1.map_or("-".into(), |t| t.to_string()),
            );
            if std::env::var("SHORT_VERBOSE").is_ok() {
                for p in &d.data_problems {
                    println!("    {}", p.description);
                }
                for t in &d.tests {
                    println!("    round {} {}: {}", t.round, t.effect.name(), t.test.map_or("-".into(), |t| t.to_string()));
                }
            }
            if with {
                let b = bins.iter().position(|b| offset_ms >= b.0 && offset_ms < b.1).expect("bin");
                counts[b].0 += 1;
                if named.contains(&Effect::TimeOffset) {
                    counts[b].1 += 1;
                    if off.is_some_and(|v| (v * 1e3 / offset_ms - 1.0).abs() <= 0.2) {
                        counts[b].2 += 1;
                    }
                }
            } else {
                null_n += 1;
                null_claims += usize::from(!named.is_empty());
            }
        }
    }
    println!();
    println!("| recordings | offset | named | named, offset within 20 % |");
    println!("|---|---|---|---|");
    for (b, c) in bins.iter().zip(&counts) {
        println!(
            "| {} | {:.0}-{:.0} ms | {} ({:.0} %) | {} ({:.0} %) |",
            c.0,
            b.0,
            b.1.floor(),
            c.1,
            100.0 * c.1 as f64 / c.0.max(1) as f64,
            c.2,
            100.0 * c.2 as f64 / c.0.max(1) as f64
        );
    }
    println!("| {null_n} | none | {null_claims} claims ({:.0} %) | |", 100.0 * null_claims as f64 / null_n.max(1) as f64);
    println!(
        "({} rows per recording on a {} Hz grid, tracker noise phi {} per grid sample, stale rows {}, {:.0} s in all, {:.0} s of it simulating)",
        rows,
        grid_hz,
        tracker_phi,
        if before { "kept (before)" } else { "found and left out" },
        t0.elapsed().as_secs_f64(),
        sim_secs
    );
}
