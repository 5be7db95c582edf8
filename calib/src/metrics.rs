//! How good is a calibration: co-registration errors, a time-blocked held-out split, and the
//! Cramér–Rao bound.
//!
//! ```text
//! co-registration  r_ij = l_ij - (|P_i + R_i b_j - A_j| + L0_j)      measured minus modelled
//! Fisher info      F_j  = sum_i J_ij^T J_ij / sigma_ij^2              over the used readings
//! CRB              Cov(x_j) >= F_j^-1
//! ```
//!
//! The bound uses the same noise model as the calibration ([`crate::noise`]) and treats the
//! variances as known (their small dependence on `x` through `rho` and `u` is left out of `F`);
//! evaluate it at the truth in simulation, at the estimate on real data. An efficient estimator's
//! error is about one CRB sigma per parameter; [`CrbReport::normalised_error`] gives the
//! Mahalanobis distance `sqrt(dx^T F dx)`, which for an efficient estimator is chi-distributed
//! with 4 degrees of freedom (mean ~1.9, 99.9% below ~4.7).

use crate::noise::{self, NoiseModel, ReadingClass, Weighting};
use crate::{model, solver, CalibOptions, Params, RobustLoss};
use taut_config::recording::Recording;

/// Measured minus modelled length per sample and cable, m, row-major like `Recording::l`; NaN
/// where the position, orientation or length is missing.
#[derive(Debug, Clone, PartialEq)]
pub struct Residuals {
    /// Number of cables.
    pub n_cables: usize,
    /// `values[i * n_cables + j]`, m.
    pub values: Vec<f64>,
}

impl Residuals {
    /// Residual of sample `i`, cable `j`.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.values[i * self.n_cables + j]
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.values.len() / self.n_cables.max(1)
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }
}

/// Co-registration error of every reading under `params`.
pub fn co_registration(rec: &Recording, platform_points: &[[f64; 3]], params: &Params) -> Residuals {
    let n = rec.n_cables;
    let rot = noise::rotations(rec);
    let mut values = vec![f64::NAN; rec.len() * n];
    for i in 0..rec.len() {
        let rm = match &rot {
            Some(v) => match &v[i] {
                Some(m) => Some(m),
                None => continue,
            },
            None => None,
        };
        for j in 0..n {
            let x = model::attachment(rec.p[i], rm, platform_points[j]);
            values[i * n + j] = rec.l[i * n + j] - model::cable_length(x, params.anchors[j], params.l0[j]);
        }
    }
    Residuals { n_cables: n, values }
}

/// Which readings to include in a statistic, row-major like [`Residuals`].
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    /// Number of cables.
    pub n_cables: usize,
    /// `keep[i * n_cables + j]`.
    pub keep: Vec<bool>,
}

impl std::ops::Index<usize> for Mask {
    type Output = bool;
    /// Whether reading `k = i * n_cables + j` is kept.
    fn index(&self, k: usize) -> &bool {
        &self.keep[k]
    }
}

impl Mask {
    /// Every reading (missing ones drop out of the statistics anyway).
    pub fn present(rec: &Recording, n_cables: usize) -> Self {
        Mask { n_cables, keep: vec![true; rec.len() * n_cables] }
    }

    /// Restricted to samples `range`.
    pub fn within(mut self, range: std::ops::Range<usize>) -> Self {
        let n = self.n_cables;
        for (i, row) in self.keep.chunks_mut(n.max(1)).enumerate() {
            if !range.contains(&i) {
                row.fill(false);
            }
        }
        self
    }
}

/// The readings the calibration uses under `opts`: present and, when force-aware with tensions,
/// taut.
pub fn taut_mask(rec: &Recording, opts: &CalibOptions) -> Mask {
    let weighting = Weighting::of(rec, opts);
    let rot = noise::rotations(rec);
    let n = rec.n_cables;
    let mut keep = Vec::with_capacity(rec.len() * n);
    for i in 0..rec.len() {
        for j in 0..n {
            keep.push(noise::classify(rec, rot.as_deref(), i, j, opts, weighting) == ReadingClass::Used);
        }
    }
    Mask { n_cables: n, keep }
}

/// RMS and peak of a set of residuals.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RmsPeak {
    /// Root mean square, m (NaN for no readings).
    pub rms: f64,
    /// Largest absolute value, m.
    pub peak: f64,
    /// Number of readings.
    pub n: usize,
}

/// RMS and peak over the kept, non-NaN residuals.
pub fn rms_peak(res: &Residuals, mask: &Mask) -> RmsPeak {
    stats(res.values.iter().zip(&mask.keep).filter(|(r, k)| **k && !r.is_nan()).map(|(r, _)| *r))
}

/// RMS and peak of the co-registration error over every present reading (loose ones included),
/// without materialising the residuals.
pub fn rms_peak_present(rec: &Recording, platform_points: &[[f64; 3]], params: &Params) -> RmsPeak {
    let n = rec.n_cables;
    let rot = noise::rotations(rec);
    let (mut s, mut p, mut cnt) = (0.0, 0.0f64, 0usize);
    for i in 0..rec.len() {
        let rm = match &rot {
            Some(v) => match &v[i] {
                Some(m) => Some(m),
                None => continue,
            },
            None => None,
        };
        for j in 0..n {
            let x = model::attachment(rec.p[i], rm, platform_points[j]);
            let r = rec.l[i * n + j] - model::cable_length(x, params.anchors[j], params.l0[j]);
            if !r.is_nan() {
                s += r * r;
                p = p.max(r.abs());
                cnt += 1;
            }
        }
    }
    RmsPeak { rms: if cnt > 0 { (s / cnt as f64).sqrt() } else { f64::NAN }, peak: p, n: cnt }
}

/// RMS and peak of cable `j` over the kept, non-NaN residuals.
pub fn rms_peak_cable(res: &Residuals, mask: &Mask, j: usize) -> RmsPeak {
    let n = res.n_cables;
    stats((0..res.len()).map(|i| i * n + j).filter(|&k| mask.keep[k] && !res.values[k].is_nan()).map(|k| res.values[k]))
}

fn stats(it: impl Iterator<Item = f64>) -> RmsPeak {
    let (mut s, mut p, mut n) = (0.0, 0.0f64, 0usize);
    for r in it {
        s += r * r;
        p = p.max(r.abs());
        n += 1;
    }
    RmsPeak { rms: if n > 0 { (s / n as f64).sqrt() } else { f64::NAN }, peak: p, n }
}

/// Index of the first held-out sample: the last `fraction` of the recording *in time* (not in
/// sample count, so a recording with a pause still holds out the last part of the motion).
/// `rec.len()` when `fraction` is 0 or the recording is empty.
pub fn heldout_start(rec: &Recording, fraction: f64) -> usize {
    if !(fraction > 0.0) || rec.is_empty() {
        return rec.len();
    }
    let (t0, t1) = (rec.t[0], rec.t[rec.len() - 1]);
    if !(t1 > t0) {
        return ((1.0 - fraction) * rec.len() as f64).round() as usize;
    }
    let ts = t0 + (1.0 - fraction) * (t1 - t0);
    rec.t.partition_point(|&t| t < ts)
}

/// The Cramér–Rao bound of every cable's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct CrbReport {
    /// Bound on the one-sigma of each anchor coordinate, m.
    pub anchor_sigma: Vec<[f64; 3]>,
    /// Bound on the one-sigma of each offset, m.
    pub l0_sigma: Vec<f64>,
    /// Inverse Fisher information of `(A_x, A_y, A_z, L0)` per cable, m^2 (infinite where
    /// singular).
    pub covariance: Vec<[[f64; 4]; 4]>,
    /// Fisher information per cable, 1/m^2.
    pub fisher: Vec<[[f64; 4]; 4]>,
}

impl CrbReport {
    /// Mahalanobis distance `sqrt(dx^T F dx)` of cable `j`'s estimate from the truth, with
    /// `dx = est - truth` as `(A_x, A_y, A_z, L0)`.
    pub fn normalised_error(&self, j: usize, est: [f64; 4], truth: [f64; 4]) -> f64 {
        let f = &self.fisher[j];
        let dx: [f64; 4] = std::array::from_fn(|k| est[k] - truth[k]);
        let mut s = 0.0;
        for a in 0..4 {
            for b in 0..4 {
                s += dx[a] * f[a][b] * dx[b];
            }
        }
        s.max(0.0).sqrt()
    }

    /// Euclidean one-sigma of cable `j`'s anchor position, m: `sqrt(trace)` of its 3x3 block.
    pub fn anchor_sigma_norm(&self, j: usize) -> f64 {
        let c = &self.covariance[j];
        (c[0][0] + c[1][1] + c[2][2]).sqrt()
    }
}

/// Cramér–Rao bound at `params` under the noise model of `opts`, over the readings the
/// calibration would use.
pub fn cramer_rao(rec: &Recording, platform_points: &[[f64; 3]], params: &Params, opts: &CalibOptions) -> CrbReport {
    let mut data = noise::gather(rec, platform_points, opts, Weighting::of(rec, opts));
    cramer_rao_gathered(rec, params, opts, &mut data)
}

/// [`cramer_rao`] on the readings gathered for the calibration (see
/// [`crate::calibrate_gathered`]); their variances are set at `params`.
pub fn cramer_rao_gathered(rec: &Recording, params: &Params, opts: &CalibOptions, data: &mut [noise::CableData]) -> CrbReport {
    let nm = NoiseModel::new(opts, Weighting::of(rec, opts));
    let mut out = CrbReport { anchor_sigma: vec![], l0_sigma: vec![], covariance: vec![], fisher: vec![] };
    let fisher = crate::par::map_mut(opts.threads, data, |j, d| {
        let x = params.cable(j);
        d.set_variances(&x, &nm);
        // The residual-free part of a least-squares pass is exactly F = sum J^T J / sigma^2.
        solver::pass(d, 0, d.len(), &x, RobustLoss::None).h_matrix()
    });
    for h in fisher {
        let mut f4 = [[0.0; 4]; 4];
        for a in 0..4 {
            for b in 0..4 {
                f4[a][b] = h[(a, b)];
            }
        }
        let mut c4 = [[f64::INFINITY; 4]; 4];
        if let Some(c) = h.try_inverse() {
            for a in 0..4 {
                for b in 0..4 {
                    c4[a][b] = c[(a, b)];
                }
            }
        }
        out.anchor_sigma.push([c4[0][0].sqrt(), c4[1][1].sqrt(), c4[2][2].sqrt()]);
        out.l0_sigma.push(c4[3][3].sqrt());
        out.covariance.push(c4);
        out.fisher.push(f4);
    }
    out
}

/// Efficiency ratio: actual error over the CRB sigma (about 1 for an efficient estimator, well
/// above it for one that wastes information or is biased).
pub fn efficiency(actual_error: f64, crb_sigma: f64) -> f64 {
    actual_error / crb_sigma
}

/// Euclidean distance between two anchors, m.
pub fn anchor_error(est: [f64; 3], truth: [f64; 3]) -> f64 {
    model::norm(model::sub(est, truth))
}
