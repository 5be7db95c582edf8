//! The force-aware noise model: which length readings are used, and the variance of each.
//!
//! ```text
//! reading (i, j) is
//!   missing  if P_i, q_i (when the recording has orientations), l_ij, or T_ij (when the recording
//!            has tensions and force weighting is on) is NaN, or q_i is not a rotation
//!   loose    if force-aware and T_ij < min_tension_n          (excluded: the encoder reads slack)
//!   used     otherwise
//!
//! var_ij = sigma_enc^2                         encoder quantisation / noise
//!        + u_ij^T Sigma_P u_ij                 tracker noise projected on the cable direction
//!        + (T_ij rho_ij / EA)^2                unobserved elastic stretch T L / EA as one sigma
//!                                              (paper eq. 10: K = EA / L, dL = T / K)
//! ```
//!
//! `Sigma_P` is the tracker's 3x3 position covariance; for an isotropic tracker
//! (`tracker_sigma_m^2 I`) the projection is `tracker_sigma_m^2` whatever the direction.
//! Orientation noise of the tracker is not modelled (it would add `|R b x u|^2 sigma_theta^2`,
//! see [`crate::model::jacobian_orientation`]); for a point-mass platform it is zero anyway.
//!
//! Without tensions (or with `force_aware: false`) no reading is loose and the variance is the
//! uniform `sigma_enc^2 + tr(Sigma_P) / 3`: ordinary least squares, the paper's baseline.

use crate::model::{self, Mat3};
use crate::CalibOptions;
use taut_config::recording::Recording;

/// How the readings were weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weighting {
    /// Tensions used: loose readings excluded, tension-dependent variance.
    ForceAware,
    /// The recording has no tensions: uniform variance, nothing excluded.
    UniformNoTensions,
    /// Force weighting switched off by option (`force_aware: false`).
    UniformByOption,
}

impl Weighting {
    /// The weighting a recording gets under `opts`.
    pub fn of(rec: &Recording, opts: &CalibOptions) -> Self {
        if !opts.force_aware {
            Weighting::UniformByOption
        } else if rec.f.is_none() {
            Weighting::UniformNoTensions
        } else {
            Weighting::ForceAware
        }
    }

    /// True when tensions enter the weights.
    pub fn uses_tensions(self) -> bool {
        self == Weighting::ForceAware
    }
}

/// The variance model with everything that does not depend on the sample precomputed.
#[derive(Debug, Clone, Copy)]
pub struct NoiseModel {
    /// `sigma_enc^2`, m^2.
    pub enc2: f64,
    /// Tracker covariance `Sigma_P`, m^2 (isotropic `sigma^2 I` by default).
    pub cov: Mat3,
    /// `1 / EA`, 1/N; zero switches the stretch term off.
    pub inv_ea: f64,
    /// `sigma_enc^2 + sigma^2` when the tracker covariance is isotropic (the projection is then
    /// the same for every direction and need not be computed per reading).
    pub iso: Option<f64>,
}

impl NoiseModel {
    /// The model `opts` describes under `weighting`.
    pub fn new(opts: &CalibOptions, weighting: Weighting) -> Self {
        let mut nm = Self::new_general(opts, weighting);
        let c = &nm.cov;
        let off = [c[0][1], c[0][2], c[1][0], c[1][2], c[2][0], c[2][1]];
        if off.iter().all(|v| *v == 0.0) && c[0][0] == c[1][1] && c[1][1] == c[2][2] {
            nm.iso = Some(nm.enc2 + c[0][0]);
        }
        nm
    }

    fn new_general(opts: &CalibOptions, weighting: Weighting) -> Self {
        let cov = opts.tracker_cov_m2.unwrap_or_else(|| {
            let s2 = opts.tracker_sigma_m * opts.tracker_sigma_m;
            [[s2, 0.0, 0.0], [0.0, s2, 0.0], [0.0, 0.0, s2]]
        });
        match weighting {
            Weighting::ForceAware => NoiseModel {
                enc2: opts.encoder_sigma_m * opts.encoder_sigma_m,
                cov,
                inv_ea: if opts.cable_ea_n > 0.0 && opts.cable_ea_n.is_finite() { 1.0 / opts.cable_ea_n } else { 0.0 },
                iso: None,
            },
            Weighting::UniformNoTensions => NoiseModel {
                enc2: opts.encoder_sigma_m * opts.encoder_sigma_m,
                cov,
                inv_ea: 0.0,
                iso: None,
            },
            Weighting::UniformByOption => {
                let s2 = (cov[0][0] + cov[1][1] + cov[2][2]) / 3.0;
                NoiseModel {
                    enc2: opts.encoder_sigma_m * opts.encoder_sigma_m,
                    cov: [[s2, 0.0, 0.0], [0.0, s2, 0.0], [0.0, 0.0, s2]],
                    inv_ea: 0.0,
                    iso: None,
                }
            }
        }
    }

    /// Variance of one reading, m^2: `u` the unit cable direction, `rho` the geometric length,
    /// `tension` in N (0 when unknown or unused).
    #[inline(always)]
    pub fn variance(&self, u: [f64; 3], rho: f64, tension: f64) -> f64 {
        let c = &self.cov;
        let proj = u[0] * (c[0][0] * u[0] + c[0][1] * u[1] + c[0][2] * u[2])
            + u[1] * (c[1][0] * u[0] + c[1][1] * u[1] + c[1][2] * u[2])
            + u[2] * (c[2][0] * u[0] + c[2][1] * u[1] + c[2][2] * u[2]);
        let s = tension * rho * self.inv_ea;
        self.enc2 + proj + s * s
    }
}

/// What happened to one length reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadingClass {
    /// Enters the calibration.
    Used,
    /// Tension below `min_tension_n`: the cable was slack, the encoder does not measure the
    /// geometric length. Excluded.
    Loose,
    /// A position, orientation, length or (when needed) tension is missing. Skipped.
    Missing,
}

/// The readings of one cable that enter the calibration, stored column-wise so that the solver's
/// pass over them is a tight loop over contiguous arrays.
#[derive(Debug, Clone, Default)]
pub struct CableData {
    /// Attachment point x, y, z (tracker frame), m.
    pub x: Vec<f64>,
    /// Attachment point y, m.
    pub y: Vec<f64>,
    /// Attachment point z, m.
    pub z: Vec<f64>,
    /// Encoder reading, m.
    pub l: Vec<f64>,
    /// Tension for the stretch term, N (0 when not used).
    pub t: Vec<f64>,
    /// Inverse variance `1 / sigma^2` of each reading, 1/m^2, set by [`CableData::set_variances`].
    pub iv: Vec<f64>,
    /// Shortest cable (`min rho`) when the variances were last set, m.
    pub rho_min: f64,
    /// Index of the sample in the recording (increasing).
    pub sample: Vec<u32>,
    /// Readings excluded as loose.
    pub loose: usize,
    /// The loose readings themselves, `(x, y, z, l)`, for the co-registration error of all
    /// readings (a few percent of the data; kept out of the solver's arrays).
    pub loose_readings: Vec<[f64; 4]>,
    /// Readings skipped as missing.
    pub missing: usize,
}

impl CableData {
    /// Number of used readings.
    pub fn len(&self) -> usize {
        self.l.len()
    }

    /// True when no reading is used.
    pub fn is_empty(&self) -> bool {
        self.l.is_empty()
    }

    /// Attachment point of used reading `k`.
    pub fn point(&self, k: usize) -> [f64; 3] {
        [self.x[k], self.y[k], self.z[k]]
    }

    /// Sets each reading's inverse variance from the noise model at parameters `x` (for the
    /// direction `u` and length `rho` it depends on). Returns the largest relative change of a
    /// variance, so a caller can tell whether a solve at the old variances is still right.
    pub fn set_variances(&mut self, x: &[f64; 4], nm: &NoiseModel) -> f64 {
        self.iv.resize(self.l.len(), 0.0);
        let a = [x[0], x[1], x[2]];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU supports the features `variances_avx2` is compiled for.
                let (change, rho_min) = unsafe { variances_avx2(&self.x, &self.y, &self.z, &self.t, &mut self.iv, a, nm) };
                self.rho_min = rho_min;
                return change;
            }
        }
        let (change, rho_min) = variances(&self.x, &self.y, &self.z, &self.t, &mut self.iv, a, nm);
        self.rho_min = rho_min;
        change
    }

    /// Number of used readings whose sample index is below `sample`.
    pub fn count_before(&self, sample: usize) -> usize {
        self.sample.partition_point(|&s| (s as usize) < sample)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn variances_avx2(xs: &[f64], ys: &[f64], zs: &[f64], ts: &[f64], iv: &mut [f64], a: [f64; 3], nm: &NoiseModel) -> (f64, f64) {
    variances(xs, ys, zs, ts, iv, a, nm)
}

/// Writes `1 / sigma^2` of every reading into `iv`; returns the largest relative change of a
/// variance (`|var_new / var_old - 1| = |var_new iv_old - 1|`, no division) and the shortest
/// cable. Eight lanes of running extrema keep the loop free of a loop-carried dependence (SIMD).
#[inline(always)]
fn variances(xs: &[f64], ys: &[f64], zs: &[f64], ts: &[f64], iv: &mut [f64], a: [f64; 3], nm: &NoiseModel) -> (f64, f64) {
    match nm.iso {
        Some(c0) => {
            let k = nm.inv_ea;
            variances_with(xs, ys, zs, ts, iv, a, |_, rho, t| {
                let s = t * rho * k;
                c0 + s * s
            })
        }
        None => variances_with(xs, ys, zs, ts, iv, a, |d: [f64; 3], rho, t| {
            let inv = 1.0 / rho;
            nm.variance([d[0] * inv, d[1] * inv, d[2] * inv], rho, t)
        }),
    }
}

#[inline(always)]
fn variances_with(
    xs: &[f64],
    ys: &[f64],
    zs: &[f64],
    ts: &[f64],
    iv: &mut [f64],
    a: [f64; 3],
    var: impl Fn([f64; 3], f64, f64) -> f64,
) -> (f64, f64) {
    let mut mx = [0.0f64; 8];
    let mut mn = [f64::INFINITY; 8];
    let one = |k: usize, old: f64| -> (f64, f64, f64) {
        let d = [xs[k] - a[0], ys[k] - a[1], zs[k] - a[2]];
        let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let v = var(d, rho, ts[k]);
        // A fresh buffer holds zeros: report an infinite change.
        let c = if old > 0.0 { (v * old - 1.0).abs() } else { f64::INFINITY };
        (1.0 / v, c, rho)
    };
    let full = iv.len() / 8 * 8;
    for base in (0..full).step_by(8) {
        for i in 0..8 {
            let (v, c, rho) = one(base + i, iv[base + i]);
            iv[base + i] = v;
            mx[i] = if c > mx[i] { c } else { mx[i] };
            mn[i] = if rho < mn[i] { rho } else { mn[i] };
        }
    }
    let mut change = mx.iter().fold(0.0f64, |m, &c| if c > m { c } else { m });
    let mut rho_min = mn.iter().fold(f64::INFINITY, |m, &r| if r < m { r } else { m });
    for k in full..iv.len() {
        let (v, c, rho) = one(k, iv[k]);
        iv[k] = v;
        change = if c > change { c } else { change };
        rho_min = if rho < rho_min { rho } else { rho_min };
    }
    (change, rho_min)
}

/// Rotations of all samples (`None` for all when the recording has no orientation; a NaN entry
/// where the quaternion is missing).
pub fn rotations(rec: &Recording) -> Option<Vec<Option<Mat3>>> {
    rec.q.as_ref().map(|qs| qs.iter().map(|q| model::rotation(*q)).collect())
}

/// Classifies reading `(i, j)`; `rot` from [`rotations`].
pub fn classify(
    rec: &Recording,
    rot: Option<&[Option<Mat3>]>,
    i: usize,
    j: usize,
    opts: &CalibOptions,
    weighting: Weighting,
) -> ReadingClass {
    let n = rec.n_cables;
    let p = rec.p[i];
    if p.iter().any(|v| v.is_nan()) || rec.l[i * n + j].is_nan() {
        return ReadingClass::Missing;
    }
    if let Some(r) = rot {
        if r[i].is_none() {
            return ReadingClass::Missing;
        }
    }
    if weighting.uses_tensions() {
        let t = rec.f.as_ref().map_or(f64::NAN, |f| f[i * n + j]);
        if t.is_nan() {
            // Without its tension we cannot tell a taut reading from a slack one.
            return ReadingClass::Missing;
        }
        if t < opts.min_tension_n {
            return ReadingClass::Loose;
        }
    }
    ReadingClass::Used
}

/// Gathers the used readings of every cable (one pass over the recording; the same
/// classification as [`classify`], hoisted so the per-sample checks run once per sample).
pub fn gather(rec: &Recording, platform_points: &[[f64; 3]], opts: &CalibOptions, weighting: Weighting) -> Vec<CableData> {
    let n = rec.n_cables;
    let rot = rotations(rec);
    let m = rec.len();
    let mut out: Vec<CableData> = (0..n)
        .map(|_| CableData {
            x: Vec::with_capacity(m),
            y: Vec::with_capacity(m),
            z: Vec::with_capacity(m),
            l: Vec::with_capacity(m),
            t: Vec::with_capacity(m),
            iv: Vec::new(),
            rho_min: f64::NAN,
            sample: Vec::with_capacity(m),
            loose: 0,
            loose_readings: Vec::new(),
            missing: 0,
        })
        .collect();
    let tensions = if weighting.uses_tensions() { rec.f.as_deref() } else { None };
    let point_mass = platform_points.iter().all(|b| *b == [0.0; 3]);
    // Sample-major: the recording is read once, row by row (measured faster than cable-major,
    // which reads it n times).
    for i in 0..m {
        let p = rec.p[i];
        let r = match &rot {
            Some(v) => v[i].as_ref(),
            None => None,
        };
        if p.iter().any(|v| v.is_nan()) || (rot.is_some() && r.is_none()) {
            for d in out.iter_mut() {
                d.missing += 1;
            }
            continue;
        }
        let ls = &rec.l[i * n..(i + 1) * n];
        for (j, d) in out.iter_mut().enumerate() {
            let l = ls[j];
            let t = match tensions {
                Some(f) => f[i * n + j],
                None => 0.0,
            };
            if l.is_nan() || t.is_nan() {
                d.missing += 1;
                continue;
            }
            let x = if point_mass && r.is_none() { p } else { model::attachment(p, r, platform_points[j]) };
            if tensions.is_some() && t < opts.min_tension_n {
                d.loose += 1;
                d.loose_readings.push([x[0], x[1], x[2], l]);
                continue;
            }
            d.x.push(x[0]);
            d.y.push(x[1]);
            d.z.push(x[2]);
            d.l.push(l);
            d.t.push(t);
            d.sample.push(i as u32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isotropic_tracker_projects_to_its_variance() {
        let opts = CalibOptions::default();
        let nm = NoiseModel::new(&opts, Weighting::ForceAware);
        let s2 = opts.tracker_sigma_m.powi(2) + opts.encoder_sigma_m.powi(2);
        for u in [[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.48, 0.6, 0.64]] {
            assert!((nm.variance(u, 4.0, 0.0) - s2).abs() < 1e-18);
        }
    }

    #[test]
    fn anisotropic_tracker_projects_on_the_cable_direction() {
        // A stereo tracker that is 10x worse in depth (z): a vertical cable sees the depth noise,
        // a horizontal one does not.
        let opts = CalibOptions {
            tracker_cov_m2: Some([[1e-6, 0.0, 0.0], [0.0, 1e-6, 0.0], [0.0, 0.0, 1e-4]]),
            encoder_sigma_m: 0.0,
            ..CalibOptions::default()
        };
        let nm = NoiseModel::new(&opts, Weighting::ForceAware);
        assert!((nm.variance([0.0, 0.0, 1.0], 3.0, 0.0) - 1e-4).abs() < 1e-18);
        assert!((nm.variance([1.0, 0.0, 0.0], 3.0, 0.0) - 1e-6).abs() < 1e-18);
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!((nm.variance([s, 0.0, s], 3.0, 0.0) - 0.5 * (1e-4 + 1e-6)).abs() < 1e-15);
    }

    #[test]
    fn stretch_term_is_tension_times_length_over_ea() {
        let opts = CalibOptions { tracker_sigma_m: 0.0, encoder_sigma_m: 0.0, cable_ea_n: 2e5, ..CalibOptions::default() };
        let nm = NoiseModel::new(&opts, Weighting::ForceAware);
        // 40 N on 5 m of EA 2e5 N stretches 1 mm.
        assert!((nm.variance([0.0, 0.0, 1.0], 5.0, 40.0).sqrt() - 1e-3).abs() < 1e-12);
        let nm = NoiseModel::new(&opts, Weighting::UniformNoTensions);
        assert_eq!(nm.variance([0.0, 0.0, 1.0], 5.0, 40.0), 0.0);
    }
}
