//! Cost of handing one sample over the sample ring (push on the loop's side, pop on the
//! calibrator's), taut's own SPSC ring against `ringbuf`'s `HeapRb` and `rtrb`'s `RingBuffer`, the two
//! standard crates. One thread, so this is the instruction cost of the two
//! calls, not cross-core cache traffic.
//!
//! `cargo bench -p taut-io --bench sample_ring`

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use ringbuf::traits::{Consumer, Producer, Split};
use ringbuf::HeapRb;
use taut_rt::sample::{sample_ring, Sample};

fn push_pop(c: &mut Criterion) {
    let mut g = c.benchmark_group("sample push+pop");
    let mut s = Sample::empty(8);

    let (mut tx, mut rx) = sample_ring(16_384);
    g.bench_function("taut SampleTx/SampleRx (with counters)", |b| {
        b.iter(|| {
            s.t += 1.0;
            assert!(tx.push(black_box(&s)));
            black_box(rx.pop().unwrap());
        })
    });

    let (mut prod, mut cons) = HeapRb::<Sample>::new(16_384).split();
    g.bench_function("ringbuf HeapRb", |b| {
        b.iter(|| {
            s.t += 1.0;
            assert!(prod.try_push(*black_box(&s)).is_ok());
            black_box(cons.try_pop().unwrap());
        })
    });

    let (mut tx, mut rx) = taut_rt::spsc::ring::<Sample>(16_384);
    g.bench_function("taut spsc (bare)", |b| {
        b.iter(|| {
            s.t += 1.0;
            assert!(tx.push(*black_box(&s)).is_ok());
            black_box(rx.pop().unwrap());
        })
    });

    let (mut prod, mut cons) = rtrb::RingBuffer::<Sample>::new(16_384);
    g.bench_function("rtrb RingBuffer", |b| {
        b.iter(|| {
            s.t += 1.0;
            assert!(prod.push(*black_box(&s)).is_ok());
            black_box(cons.pop().unwrap());
        })
    });

    // Full ring: the refused push the loop sees when the calibrator falls behind. The bare
    // rings side by side, then `SampleTx::push`, which also counts the drop.
    let (mut tx, _rx) = taut_rt::spsc::ring::<Sample>(16);
    while tx.push(s).is_ok() {}
    g.bench_function("taut spsc, full", |b| b.iter(|| assert!(tx.push(*black_box(&s)).is_err())));
    let (mut tx, _rx) = sample_ring(16);
    while tx.push(&s) {}
    g.bench_function("taut SampleTx, full (drop counted)", |b| b.iter(|| assert!(!tx.push(black_box(&s)))));
    let (mut prod, _cons) = HeapRb::<Sample>::new(16).split();
    while prod.try_push(s).is_ok() {}
    g.bench_function("ringbuf HeapRb, full", |b| b.iter(|| assert!(prod.try_push(*black_box(&s)).is_err())));
    let (mut prod, _cons) = rtrb::RingBuffer::<Sample>::new(16);
    while prod.push(s).is_ok() {}
    g.bench_function("rtrb RingBuffer, full", |b| b.iter(|| assert!(prod.push(*black_box(&s)).is_err())));
    g.finish();
}

criterion_group!(benches, push_pop);
criterion_main!(benches);
