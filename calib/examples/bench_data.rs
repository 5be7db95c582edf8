//! Writes the benchmark recording: 100 000 samples x 4 cables of an ARAS-CAM-like robot
//! (1.5 mm tracker noise, 0.2% tracker outliers of 5 cm, 5% loose readings, tensions), plus the
//! initial guess the benchmark starts from, so that every solver sees the same data.
//!
//! ```text
//! cargo run --release -p taut-calib --example bench_data -- OUT.csv [SAMPLES]
//! ```
//! The initial guess goes to `OUT.csv.init` as `A_x A_y A_z L0` per line.

use taut_calib::synth::bench_recording;

fn main() {
    let mut args = std::env::args().skip(1);
    let out = args.next().unwrap_or_else(|| "bench-100k.csv".into());
    let n: usize = args.next().map(|s| s.parse().expect("SAMPLES must be a number")).unwrap_or(100_000);
    let (rec, init) = bench_recording(n);
    rec.save_atomic(&out).unwrap_or_else(|e| panic!("writing {out}: {e}"));
    let text: String = (0..init.n_cables())
        .map(|j| {
            let c = init.cable(j);
            format!("{:.9} {:.9} {:.9} {:.9}\n", c[0], c[1], c[2], c[3])
        })
        .collect();
    std::fs::write(format!("{out}.init"), text).unwrap_or_else(|e| panic!("writing {out}.init: {e}"));
    eprintln!("wrote {out} ({n} samples x {} cables) and {out}.init", rec.n_cables);
}
