//! The diagnosis hot path: a 4-cable, 12,000-sample recording with concealed elasticity and 5 %
//! loose readings, diagnosed from scratch (initialisation, baseline, screening of every effect,
//! refits). Goal: under 2 s on one core (BENCHMARKS.md).

use criterion::{criterion_group, criterion_main, Criterion};
use std::time::Duration;
use taut_calib::diagnose::{diagnose, DiagnoseOptions};
use taut_calib::synth::{self, Spec, Stretch};

fn bench(c: &mut Criterion) {
    let mut spec = Spec::new(synth::aras_cam());
    spec.stretch = Stretch::Physical;
    spec.cable_ea_n = 20_000.0;
    spec.loose_fraction = 0.05;
    let rec = synth::box_recording(&spec, 12_000, [-2.5, -1.2, 0.5], [2.5, 1.2, 2.8], 7);
    let opts = DiagnoseOptions::default();
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("4 cables x 12000 samples", |b| b.iter(|| diagnose(&rec, &spec.platform_points, None, &opts).expect("diagnosis")));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
