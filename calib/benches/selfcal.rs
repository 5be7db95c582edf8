//! Tracker-free calibration of 200 dwell poses / 20,000 samples: dwell search,
//! averaging, start, Schur-complement LM, covariance, frame-free quantities.
//!
//! The recording: 4 cables on a 7 x 3.5 x 4 m frame (ARAS-CAM), 3 kg point mass, 200 poses
//! spread through the workspace, 100 readings per pose (1 s at 100 Hz), encoders 0.05 mm,
//! load cells 0.3 N with offsets; the anchors start at the nominal ones, 5-20 cm from the truth.
//! Run: `cargo bench -p taut-calib --bench selfcal`.

// Index loops over parallel per-cable arrays, as in the library.
#![allow(clippy::needless_range_loop)]

use criterion::{criterion_group, criterion_main, Criterion};
use taut_calib::selfcal::{calibrate_without_tracker, SelfCalOptions};
use taut_calib::synth::Rng;
use taut_config::recording::Recording;

const NOMINAL: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

/// Static tensions of a 4-cable point mass: the minimum-norm balance of the weight plus the
/// multiple of the null-space direction closest to zero that keeps every tension >= `t_min`
/// (the null direction has mixed signs for upward cables); `None` where none does.
fn tensions(anchors: &[[f64; 3]], p: [f64; 3], mass: f64, t_min: f64) -> Option<[f64; 4]> {
    use nalgebra::{Matrix3x4, Vector3, Vector4};
    let mut u = Matrix3x4::zeros();
    for j in 0..4 {
        let d = Vector3::new(anchors[j][0] - p[0], anchors[j][1] - p[1], anchors[j][2] - p[2]);
        u.set_column(j, &(d / d.norm()));
    }
    let f = Vector3::new(0.0, 0.0, mass * 9.81);
    let pinv = u.transpose() * (u * u.transpose()).try_inverse()?;
    let t0: Vector4<f64> = pinv * f;
    // Null direction: the component of a generic vector outside the row space of U.
    let e = Vector4::new(1.0, -1.0, 1.0, -1.0);
    let null = e - pinv * (u * e);
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for j in 0..4 {
        let b = (t_min - t0[j]) / null[j];
        if null[j] > 1e-9 {
            lo = lo.max(b);
        } else if null[j] < -1e-9 {
            hi = hi.min(b);
        } else if t0[j] < t_min {
            return None;
        }
    }
    if lo > hi {
        return None;
    }
    let t = t0 + null * 0.0f64.clamp(lo, hi);
    Some([t[0], t[1], t[2], t[3]])
}

fn recording(poses: usize, per_pose: usize, seed: u64) -> Recording {
    let mut rng = Rng::new(seed);
    let truth: Vec<[f64; 3]> = NOMINAL
        .iter()
        .map(|a| {
            let v = rng.unit_vector();
            let m = rng.range(0.05, 0.2);
            [a[0] + m * v[0], a[1] + m * v[1], a[2] + m * v[2]]
        })
        .collect();
    let l0: Vec<f64> = (0..4).map(|_| rng.range(-2.0, 2.0)).collect();
    let cell: Vec<f64> = (0..4).map(|_| 0.5 * rng.normal()).collect();
    let mut rec = Recording::with_capacity(4, poses * per_pose, true, false, false);
    let mut k = 0;
    let mut t = 0.0;
    while k < poses {
        let p = [rng.range(-2.5, 2.5), rng.range(-1.2, 1.2), rng.range(0.6, 3.4)];
        let Some(tt) = tensions(&truth, p, 3.0, 5.0) else { continue };
        k += 1;
        for _ in 0..per_pose {
            let mut l = [0.0; 4];
            let mut f = [0.0; 4];
            for j in 0..4 {
                let d = ((p[0] - truth[j][0]).powi(2) + (p[1] - truth[j][1]).powi(2) + (p[2] - truth[j][2]).powi(2)).sqrt();
                l[j] = d + l0[j] + 5e-5 * rng.normal();
                f[j] = tt[j] + cell[j] + 0.3 * rng.normal();
            }
            rec.push(t, [f64::NAN; 3], None, &l, Some(&f), None);
            t += 0.01;
        }
    }
    rec
}

fn bench(c: &mut Criterion) {
    let rec = recording(200, 100, 1);
    let opts = SelfCalOptions {
        encoder_sigma_m: 5e-5,
        loadcell_sigma_n: None,
        min_tension_n: 3.0,
        mass_kg: 3.0,
        estimate_mass: false,
        use_tensions: true,
        weak_sigma_m: 2e-3,
        max_sigma_m: 0.1,
        min_dwell_samples: 20,
        window_s: taut_calib::selfcal::WINDOW_S,
        max_iterations: 200,
        stretch: None,
        priors: None,
    };
    let b = [[0.0; 3]; 4];
    let r = calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts).expect("the bench recording calibrates");
    assert_eq!(r.dwells.len(), 200);
    eprintln!(
        "selfcal bench: {} dwells, {} samples, {} iterations, CRB {:.3} mm, chi2/dof {:.2}",
        r.dwells.len(),
        r.samples_used,
        r.iterations,
        r.anchor_rms_crb_m * 1e3,
        r.chi2 / r.dof as f64
    );
    let mut g = c.benchmark_group("selfcal");
    g.sample_size(10);
    g.bench_function("200 dwells / 20000 samples, 4 cables, load cells", |bch| {
        bch.iter(|| calibrate_without_tracker(&rec, &b, Some(&NOMINAL), &opts).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
