//! The calibration hot path: 100 000 samples x 4 cables, force-aware, from a start 5-10 cm off.
//!
//! `calibrate` = gather + per-cable LM (least squares then Huber) + covariance and statistics +
//! the held-out solve on the training block; `no_heldout` leaves the last one out.

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use taut_calib::{calibrate, synth, CalibOptions};

fn bench(c: &mut Criterion) {
    let (rec, init) = synth::bench_recording(100_000);
    let b = vec![[0.0; 3]; rec.n_cables];
    let opts = CalibOptions::default();
    let no_heldout = CalibOptions { heldout_fraction: 0.0, model_check: false, ..opts.clone() };
    let mut g = c.benchmark_group("calibrate_100k_x4");
    g.sample_size(20);
    g.bench_function("calibrate", |bch| bch.iter(|| calibrate(black_box(&rec), &b, &init, &opts).expect("calibrates")));
    g.bench_function("no_heldout", |bch| bch.iter(|| calibrate(black_box(&rec), &b, &init, &no_heldout).expect("calibrates")));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
