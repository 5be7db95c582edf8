//! Deterministic Monte Carlo for the acceptance budgets: P(a Gaussian error vector's worst part
//! exceeds a limit), from a fixed generator so that every call returns the same numbers (the
//! tests assert these probabilities at compile-time-fixed bounds).

use nalgebra::{DMatrix, DVector};

/// SplitMix64 with Box–Muller normals: a small deterministic generator for the Monte Carlo.
pub(crate) struct SplitMix(pub(crate) u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f64 {
        ((self.next() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }

    pub(crate) fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// P(`exceeds(e)`) for `e` Gaussian with the row-major `k x k` covariance `cov` times `scale^2`:
/// `draws` draws of [`SplitMix`] from `seed` (the same numbers on every call), `e = C^(1/2) z`
/// through the covariance's eigen-decomposition (its gauge directions, if any, have zero
/// variance). Returns the fraction exceeding and its one-sided 99.9 % upper confidence bound
/// (`p + 3.1 sqrt(p (1 - p) / draws) + 10 / draws`, conservative where few exceed); `(1, 1)` when
/// the covariance is not `k x k` or there are no draws.
pub(crate) fn gaussian_exceeds(
    cov: &[f64],
    k: usize,
    scale: f64,
    draws: usize,
    seed: u64,
    mut exceeds: impl FnMut(&DVector<f64>) -> bool,
) -> (f64, f64) {
    if cov.len() != k * k || draws == 0 {
        return (1.0, 1.0);
    }
    let cov = DMatrix::from_row_slice(k, k, cov) * (scale * scale);
    let eig = cov.symmetric_eigen();
    let mut root = eig.eigenvectors.clone();
    for c in 0..k {
        let s = eig.eigenvalues[c].max(0.0).sqrt();
        for r in 0..k {
            root[(r, c)] *= s;
        }
    }
    let mut rng = SplitMix(seed);
    let mut z = DVector::zeros(k);
    let mut over = 0usize;
    for _ in 0..draws {
        for i in 0..k {
            z[i] = rng.normal();
        }
        let e = &root * &z;
        if exceeds(&e) {
            over += 1;
        }
    }
    let p = over as f64 / draws as f64;
    (p, (p + 3.1 * (p * (1.0 - p) / draws as f64).sqrt() + 10.0 / draws as f64).min(1.0))
}
