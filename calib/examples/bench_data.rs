//! Writes the benchmark recording: 100 000 samples x 4 cables of an ARAS-CAM-like robot
//! (1.5 mm tracker noise, 0.2% tracker outliers of 5 cm, 5% loose readings, tensions), plus the
//! initial guess the benchmark starts from, so that every solver sees the same data.
//!
//! ```text
//! cargo run --release -p taut-calib --example bench_data -- OUT.csv [SAMPLES]
//! ```
//! The initial guess goes to `OUT.csv.init` as `A_x A_y A_z L0` per line.

use taut_calib::synth::{self, Spec};

fn main() {
    let mut args = std::env::args().skip(1);
    let out = args.next().unwrap_or_else(|| "bench-100k.csv".into());
    let n: usize = args.next().map(|s| s.parse().expect("SAMPLES must be a number")).unwrap_or(100_000);
    let (rec, init) = bench_recording(n);
    rec.save_atomic(&out).unwrap_or_else(|e| panic!("writing {out}: {e}"));
    let text: String = (0..init.n_cables()).map(|j| {
        let c = init.cable(j);
        format!("{:.9} {:.9} {:.9} {:.9}\n", c[0], c[1], c[2], c[3])
    }).collect();
    std::fs::write(format!("{out}.init"), text).unwrap_or_else(|e| panic!("writing {out}.init: {e}"));
    eprintln!("wrote {out} ({n} samples x {} cables) and {out}.init", rec.n_cables);
}

/// The benchmark recording and its initial guess (truth moved by 5-10 cm, as after a
/// multilateration on a short recording or a tape-measured set-up).
pub fn bench_recording(n: usize) -> (taut_config::recording::Recording, taut_calib::Params) {
    let truth = synth::aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.05;
    spec.outlier_prob = 0.002;
    let rec = synth::box_recording(&spec, n, [-2.5, -1.25, 0.5], [2.5, 1.25, 2.5], 2024);
    let mut init = truth;
    for (j, a) in init.anchors.iter_mut().enumerate() {
        let s = if j % 2 == 0 { 1.0 } else { -1.0 };
        a[0] += 0.08 * s;
        a[1] -= 0.05 * s;
        a[2] += 0.06;
        init.l0[j] -= 0.07;
    }
    (rec, init)
}
