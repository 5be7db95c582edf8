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
use std::sync::Arc;
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
            Weighting::UniformNoTensions => NoiseModel { enc2: opts.encoder_sigma_m * opts.encoder_sigma_m, cov, inv_ea: 0.0, iso: None },
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

    /// The variance without the geometry: encoder plus the mean tracker variance
    /// (`tr(Sigma_P) / 3`), no stretch, m^2.
    pub fn uniform_variance(&self) -> f64 {
        self.enc2 + (self.cov[0][0] + self.cov[1][1] + self.cov[2][2]) / 3.0
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

/// [`CableData::class`]: the reading enters the calibration.
pub const USED: u8 = 0;
/// [`CableData::class`]: the reading is of a loose cable (excluded, kept for statistics).
pub const LOOSE: u8 = 1;
/// [`CableData::class`]: a value is missing (or the sample is outside a selection).
pub const MISSING: u8 = 2;

/// One cable's readings, one slot per sample of the recording, stored column-wise so that the
/// solver's pass is a tight loop over contiguous arrays. Readings that do not enter the
/// calibration keep their slot with weight zero (`iv = 0`): no compaction, so the attachment
/// points of a point-mass platform are shared by all cables (`Arc`), the time order is the slot
/// order, and a time block is a slot range.
#[derive(Debug, Clone, Default)]
pub struct CableData {
    /// Attachment point x per sample (tracker frame; 0 where missing), m.
    pub x: Arc<[f64]>,
    /// Attachment point y, m.
    pub y: Arc<[f64]>,
    /// Attachment point z, m.
    pub z: Arc<[f64]>,
    /// Encoder reading (0 where missing), m.
    pub l: Vec<f64>,
    /// Tension for the stretch term (0 when unknown or unused), N.
    pub t: Vec<f64>,
    /// [`USED`], [`LOOSE`] or [`MISSING`].
    pub class: Vec<u8>,
    /// Inverse variance `1 / sigma^2` of each used reading, 0 for the others, 1/m^2; set by
    /// [`CableData::set_variances`].
    pub iv: Vec<f64>,
    /// Shortest cable (`min rho` over used readings) when the variances were last set, m.
    pub rho_min: f64,
    /// Readings used.
    pub used: usize,
    /// Readings excluded as loose.
    pub loose: usize,
    /// Readings skipped as missing.
    pub missing: usize,
    /// The design's prior on `[A_x, A_y, A_z, L0]`: means and 1-sigmas (infinite: none for that
    /// parameter). Every pass of the solver adds it as four pseudo-readings ([`crate::solver`]).
    pub prior: Option<([f64; 4], [f64; 4])>,
}

impl CableData {
    /// Readings from explicit points, lengths and tensions, all used (for tests and tools).
    pub fn from_points(points: &[[f64; 3]], l: &[f64], t: &[f64]) -> Self {
        let col = |k: usize| -> Arc<[f64]> { points.iter().map(|p| p[k]).collect() };
        CableData {
            x: col(0),
            y: col(1),
            z: col(2),
            l: l.to_vec(),
            t: t.to_vec(),
            class: vec![USED; l.len()],
            iv: Vec::new(),
            rho_min: f64::NAN,
            used: l.len(),
            loose: 0,
            missing: 0,
            prior: None,
        }
    }

    /// Number of slots (samples).
    pub fn len(&self) -> usize {
        self.l.len()
    }

    /// True when there are no slots.
    pub fn is_empty(&self) -> bool {
        self.l.is_empty()
    }

    /// Attachment point of slot `k`.
    pub fn point(&self, k: usize) -> [f64; 3] {
        [self.x[k], self.y[k], self.z[k]]
    }

    /// True when slot `k` is used.
    pub fn is_used(&self, k: usize) -> bool {
        self.class[k] == USED
    }

    /// Slots of the used readings.
    pub fn used_slots(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.len()).filter(|&k| self.class[k] == USED)
    }

    /// Used readings among slots `range`.
    pub fn used_in(&self, range: std::ops::Range<usize>) -> usize {
        self.class[range].iter().filter(|&&c| c == USED).count()
    }

    /// The same readings with only the slots where `keep(slot)` holds still used (the others
    /// become [`MISSING`]); the point columns are shared, not copied.
    pub fn restricted(&self, keep: impl Fn(usize) -> bool) -> Self {
        let mut d = self.clone();
        for k in 0..d.len() {
            if d.class[k] == USED && !keep(k) {
                d.class[k] = MISSING;
                d.used -= 1;
                d.missing += 1;
            }
        }
        d.iv.clear();
        d
    }

    /// Sets every used reading's inverse variance to `1 / var` (0 for the others): the weights
    /// before the geometry is known well enough for the direction- and length-dependent terms.
    pub fn set_uniform_variance(&mut self, var: f64) {
        let iv = 1.0 / var;
        self.iv.clear();
        self.iv.extend(self.class.iter().map(|&c| if c == USED { iv } else { 0.0 }));
    }

    /// Sets each used reading's inverse variance from the noise model at parameters `x` (for
    /// the direction `u` and length `rho` it depends on), 0 for the others. Returns the largest
    /// relative change of a variance, so a caller can tell whether a solve at the old variances
    /// is still right (infinite the first time).
    pub fn set_variances(&mut self, x: &[f64; 4], nm: &NoiseModel) -> f64 {
        self.iv.resize(self.l.len(), 0.0);
        let a = [x[0], x[1], x[2]];
        let cols = Cols { x: &self.x, y: &self.y, z: &self.z, t: &self.t, class: &self.class };
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU supports the features `variances_avx2` is compiled for.
                let (change, rho_min) = unsafe { variances_avx2(&cols, &mut self.iv, a, nm) };
                self.rho_min = rho_min;
                return change;
            }
        }
        let (change, rho_min) = variances(&cols, &mut self.iv, a, nm);
        self.rho_min = rho_min;
        change
    }
}

/// The columns the variance computation reads.
struct Cols<'a> {
    x: &'a [f64],
    y: &'a [f64],
    z: &'a [f64],
    t: &'a [f64],
    class: &'a [u8],
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn variances_avx2(c: &Cols, iv: &mut [f64], a: [f64; 3], nm: &NoiseModel) -> (f64, f64) {
    variances(c, iv, a, nm)
}

/// Writes `1 / sigma^2` of every used reading into `iv` (0 for the others); returns the largest
/// relative change of a variance (`|var_new / var_old - 1| = |var_new iv_old - 1|`, no
/// division) and the shortest cable. Eight lanes of running extrema keep the loop free of a
/// loop-carried dependence (SIMD).
#[inline(always)]
fn variances(c: &Cols, iv: &mut [f64], a: [f64; 3], nm: &NoiseModel) -> (f64, f64) {
    match nm.iso {
        Some(c0) => {
            let k = nm.inv_ea;
            variances_with(c, iv, a, |_, rho, t| {
                let s = t * rho * k;
                c0 + s * s
            })
        }
        None => variances_with(c, iv, a, |d: [f64; 3], rho, t| {
            let inv = 1.0 / rho;
            nm.variance([d[0] * inv, d[1] * inv, d[2] * inv], rho, t)
        }),
    }
}

#[inline(always)]
fn variances_with(c: &Cols, iv: &mut [f64], a: [f64; 3], var: impl Fn([f64; 3], f64, f64) -> f64) -> (f64, f64) {
    let mut mx = [0.0f64; 8];
    let mut mn = [f64::INFINITY; 8];
    let one = |k: usize, old: f64| -> (f64, f64, f64) {
        let d = [c.x[k] - a[0], c.y[k] - a[1], c.z[k] - a[2]];
        let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let v = var(d, rho, c.t[k]);
        let used = c.class[k] == USED;
        // A fresh buffer holds zeros: an infinite change.
        let ch = if !used {
            0.0
        } else if old > 0.0 {
            (v * old - 1.0).abs()
        } else {
            f64::INFINITY
        };
        (if used { 1.0 / v } else { 0.0 }, ch, if used { rho } else { f64::INFINITY })
    };
    let full = iv.len() / 8 * 8;
    for base in (0..full).step_by(8) {
        for i in 0..8 {
            let (v, ch, rho) = one(base + i, iv[base + i]);
            iv[base + i] = v;
            mx[i] = if ch > mx[i] { ch } else { mx[i] };
            mn[i] = if rho < mn[i] { rho } else { mn[i] };
        }
    }
    let mut change = mx.iter().fold(0.0f64, |m, &c| if c > m { c } else { m });
    let mut rho_min = mn.iter().fold(f64::INFINITY, |m, &r| if r < m { r } else { m });
    for k in full..iv.len() {
        let (v, ch, rho) = one(k, iv[k]);
        iv[k] = v;
        change = if ch > change { ch } else { change };
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

/// Every cable's readings, classified as [`classify`] does (one pass over the recording per
/// column; the point columns are built once and shared when the platform is a point mass
/// without orientation).
pub fn gather(rec: &Recording, platform_points: &[[f64; 3]], opts: &CalibOptions, weighting: Weighting) -> Vec<CableData> {
    let n = rec.n_cables;
    let m = rec.len();
    let rot = rotations(rec);
    let tensions = if weighting.uses_tensions() { rec.f.as_deref() } else { None };
    let pose_ok: Vec<bool> = (0..m).map(|i| !rec.p[i].iter().any(|v| v.is_nan()) && rot.as_ref().is_none_or(|r| r[i].is_some())).collect();
    // Axis `a` of platform point `b`'s positions, written straight into the shared column
    // (collecting a counted range allocates the `Arc` once; a `Vec` turned into one is copied).
    let column = |b: [f64; 3], a: usize| -> Arc<[f64]> {
        let pt = |i: usize| -> [f64; 3] {
            if !pose_ok[i] {
                return [0.0; 3];
            }
            model::attachment(rec.p[i], rot.as_ref().and_then(|r| r[i].as_ref()), b)
        };
        (0..m).map(|i| pt(i)[a]).collect()
    };
    let columns = |b: [f64; 3]| -> [Arc<[f64]>; 3] { [column(b, 0), column(b, 1), column(b, 2)] };
    let shared = (rot.is_none() && platform_points.iter().all(|b| *b == [0.0; 3])).then(|| {
        // One point for every cable: its three columns on the threads.
        let mut axes = crate::par::map(opts.threads, 3, |a| column([0.0; 3], a)).into_iter();
        [(); 3].map(|_| axes.next().expect("three axes"))
    });
    crate::par::map(opts.threads, n, |j| {
        let [x, y, z] = match &shared {
            Some(c) => c.clone(),
            None => columns(platform_points[j]),
        };
        // Branch-free classification over zipped rows (no bounds checks, no pushes).
        let mut l = vec![0.0; m];
        let mut t = vec![0.0; m];
        let mut class = vec![MISSING; m];
        let min_t = opts.min_tension_n;
        let has_t = tensions.is_some();
        let zeros = [0.0f64];
        let frows: Box<dyn Iterator<Item = &[f64]>> = match tensions {
            Some(f) => Box::new(f.chunks_exact(n)),
            None => Box::new(std::iter::repeat(&zeros[..])),
        };
        let tj = if has_t { j } else { 0 };
        let (mut used, mut loose) = (0usize, 0usize);
        for ((((lo, to), co), (row, frow)), ok) in
            l.iter_mut().zip(t.iter_mut()).zip(class.iter_mut()).zip(rec.l.chunks_exact(n).zip(frows)).zip(&pose_ok)
        {
            let (li, ti) = (row[j], frow[tj]);
            let miss = !*ok || li.is_nan() || ti.is_nan();
            let is_loose = !miss && has_t && ti < min_t;
            let is_used = !miss && !is_loose;
            *co = if miss {
                MISSING
            } else if is_loose {
                LOOSE
            } else {
                USED
            };
            *lo = if li.is_nan() { 0.0 } else { li };
            *to = if is_used { ti } else { 0.0 };
            used += is_used as usize;
            loose += is_loose as usize;
        }
        let missing = m - used - loose;
        CableData { x, y, z, l, t, class, iv: Vec::new(), rho_min: f64::NAN, used, loose, missing, prior: None }
    })
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
