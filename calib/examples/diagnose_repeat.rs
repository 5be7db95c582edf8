//! Runs the diagnosis benchmark's case (`benches/diagnose.rs`) `N` times and prints each run's
//! wall time, for CPU-time comparisons of two builds on a loaded machine (`/usr/bin/time -f %U`);
//! `DIAGNOSE_WITHOUT=<effect>` leaves one candidate out; `DIAGNOSE_BEFORE=1` leaves the held-out
//! tests' estimation-error term out (`DiagnoseOptions::estimation_error`), to see its cost.
//!
//! ```text
//! cargo run --release -p taut-calib --example diagnose_repeat -- [N, default 5]
//! ```

use taut_calib::diagnose::{diagnose, DiagnoseOptions};
use taut_calib::synth::{self, Spec, Stretch};

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(5);
    let mut spec = Spec::new(synth::aras_cam());
    spec.stretch = Stretch::Physical;
    spec.cable_ea_n = 20_000.0;
    spec.loose_fraction = 0.05;
    let rec = synth::box_recording(&spec, 12_000, [-2.5, -1.2, 0.5], [2.5, 1.2, 2.8], 7);
    let mut opts = DiagnoseOptions::default();
    // `DIAGNOSE_WITHOUT=time-offset` (an effect name) leaves one candidate out, to see its share.
    if let Ok(name) = std::env::var("DIAGNOSE_WITHOUT") {
        opts.library.retain(|e| e.name() != name);
    }
    if std::env::var("DIAGNOSE_BEFORE").is_ok_and(|v| v == "1") {
        opts.estimation_error = false;
    }
    for _ in 0..n {
        let t = std::time::Instant::now();
        let d = diagnose(&rec, &spec.platform_points, None, &opts).expect("diagnosis");
        println!("{:.3} s, {} effects", t.elapsed().as_secs_f64(), d.effects.len());
    }
}
