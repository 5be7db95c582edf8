//! Reading a recording: taut's reader against the field's standard crates on the same bytes.
//!
//! The input is 100,000 rows x 4 cables as `taut start` writes them (`t, px, py, pz, l0..l3,
//! f0..f3, phase`, 11 MB), in memory or in a file:
//! - `taut_parse`: `recording::parse`, the line-by-line reader (every row checked: width, times
//!   that do not go back, plausible values, the report of what was skipped);
//! - `taut_load_1`, `taut_load_2`: `Recording::load_with` on a file, one thread and two;
//! - `csv_fast_float2`: the `csv` crate's byte records with `fast-float2` for every field, into the
//!   same columns, without any of those checks.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use taut_config::recording::{parse, Recording};

const ROWS: usize = 100_000;
const CABLES: usize = 4;

/// A recording shaped like the simulated robot's: smooth motion at 100 Hz, millimetre lengths,
/// tensions with three decimals.
fn bytes() -> Vec<u8> {
    let mut rec = Recording::with_capacity(CABLES, ROWS, true, false, true);
    for i in 0..ROWS {
        let t = i as f64 * 0.01;
        let p = [1.0 + 0.4 * (0.31 * t).sin(), 0.5 + 0.3 * (0.23 * t).cos(), 2.0 + 0.2 * (0.17 * t).sin()];
        let l: Vec<f64> = (0..CABLES).map(|j| 4.0 + j as f64 * 0.7 + 0.3 * (0.29 * t + j as f64).sin()).collect();
        let f: Vec<f64> = (0..CABLES).map(|j| 15.0 + 5.0 * (0.41 * t + j as f64).cos()).collect();
        rec.push(t, p, None, &l, Some(&f), Some(if i < 3000 { (i / 1000) as i32 } else { -1 }));
    }
    let mut out = Vec::new();
    rec.write_csv(&mut out).unwrap();
    out
}

/// The `csv` crate and `fast-float2`: comment lines skipped, the header read, every field of
/// every row parsed as a float (an empty field as NaN) into row-major columns.
fn csv_fast_float2(bytes: &[u8]) -> (usize, Vec<f64>) {
    let mut r = csv::ReaderBuilder::new().comment(Some(b'#')).has_headers(true).from_reader(bytes);
    let width = r.byte_headers().unwrap().len();
    let mut vals = Vec::with_capacity(ROWS * width);
    let mut row = csv::ByteRecord::new();
    while r.read_byte_record(&mut row).unwrap() {
        for field in row.iter() {
            vals.push(if field.is_empty() { f64::NAN } else { fast_float2::parse(field).unwrap() });
        }
    }
    (width, vals)
}

fn bench(c: &mut Criterion) {
    let bytes = bytes();
    let dir = std::env::temp_dir().join(format!("taut-recording-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("rec.csv");
    std::fs::write(&path, &bytes).unwrap();
    // Both read every value alike.
    let (rec, _) = parse(&bytes[..]).unwrap();
    let (width, vals) = csv_fast_float2(&bytes);
    assert_eq!((rec.len(), width), (ROWS, 1 + 3 + 2 * CABLES + 1));
    assert_eq!(vals[width * 7 + 4], rec.lengths(7)[0]);
    let mut g = c.benchmark_group("recording_100k_x4");
    g.sample_size(20);
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.bench_function("taut_parse", |b| b.iter(|| parse(black_box(&bytes[..])).unwrap()));
    g.bench_function("taut_load_1", |b| b.iter(|| Recording::load_with(black_box(&path), 1).unwrap()));
    g.bench_function("taut_load_2", |b| b.iter(|| Recording::load_with(black_box(&path), 2).unwrap()));
    g.bench_function("csv_fast_float2", |b| b.iter(|| csv_fast_float2(black_box(&bytes))));
    g.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
