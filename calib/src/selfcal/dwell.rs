//! Dwells: stretches of a recording where every encoder is still, averaged into one static pose.
//!
//! ```text
//! still(i)   <=>  |l_ij - l_(i-1)j| <= 6 sqrt(2) sigma_enc   for every cable j
//! run        =  maximal stretch of still samples, >= min_samples long
//! drift test:   |mean(first half) - mean(second half)|_j <= 5 sigma_enc sqrt(4 / m)  for every j
//! ```
//!
//! Two readings of a still encoder differ by `N(0, 2 sigma^2)`: the 6-sigma step test splits a
//! dwell by mistake with probability ~2e-9 per reading and cable. A slow creep (e.g. 1 mm/s at
//! 100 Hz: 10 µm per step) passes the step test; the halves' means then differ by far more than
//! their 5-sigma band (false alarm ~6e-7 per cable), and the run's first half (the settling after
//! a move) is dropped and the test repeated once; a run that still drifts is not a dwell.
//!
//! The step test passes every speed below 6 sqrt(2) sigma per reading (212 mm/s at 500 Hz), so
//! without labels a run also holds the end of the move before a rest and the start of the move
//! after it (a trapezoid's deceleration and acceleration), and a rest of 0.5-1 s fails the drift
//! test with them inside. Such a run is cut into stretches whose readings stay within
//! `6 sigma sqrt(1 + 1 / 8)` (0.32 mm at 50 µm) of the mean of their first 8 readings, each
//! starting where the previous one left that band; the longest is the rest when it holds more
//! than half of the rows of all stretches of `min_samples` or more (a creep leaves the band
//! again and again, in stretches of equal length) and passes the drift test.
//!
//! A recording with phase labels (the loop's dwell plan labels each recorded dwell with its
//! pose's index, the moves and the settling after them with -1) is split where the label
//! changes, and only labelled rows form dwells: the loop knows when the platform has settled,
//! and a tension reading taken during the move can be a few rows old when the encoders already
//! stand still. A label from [`TARE_LABEL_BASE`] on marks a tare: the followers were commanded
//! to zero tension while the position-controlled cables held the platform; a cable of such a
//! dwell whose mean reading is below the loose threshold carries no tension, so its reading is
//! its load cell's offset ([`Dwell::tared`]).
//!
//! Two readings at each end of a dwell are dropped (the start or end of a smooth move).
//! A dwell's readings are averaged per cable (`NaN`s skipped): the mean is the sufficient
//! statistic of a static pose under white noise, and its variance is `sigma^2 / m`. The
//! within-dwell scatter of the tensions gives the load cells' noise when it is not configured.
//!
//! Consecutive rows are not independent readings in general: a load cell polled at ~120 Hz
//! recorded by a 500 Hz loop repeats each reading over ~4 rows (sample and hold), an encoder
//! whose drive missed a SYNC repeats its last value, a sensor's own filter correlates its
//! readings. The variance of a dwell mean is then `sigma_lr^2 / m` with the long-run variance
//! `sigma_lr^2 = sigma^2 (1 + 2 sum_k rho_k)`, not `sigma^2 / m`. It is estimated by batch
//! means, pooled over the dwells and cables of one kind:
//!
//! ```text
//! each dwell (>= 40 rows): B = 10 batches of b = floor(m / B) rows
//! sigma_lr^2  = sum b (batch mean - dwell mean)^2 / sum (B - 1)
//! sigma_row^2 = sum (row - dwell mean)^2 / sum (B b - 1)
//! inflation   = max(1, sigma_lr^2 / sigma_row^2)       (var of a dwell mean: inflation sigma^2 / m)
//! ```
//!
//! A batch of `b` rows (>= 4, 50 ms at 500 Hz in a 2 s dwell) is long against a hold of a few
//! rows, so the batch means are nearly independent. With ~50 dwells x cables the pooled
//! estimate has ~450 degrees of freedom (relative 1-sigma ~7 %).

use crate::diagnose::dataq::median;
use taut_config::recording::Recording;

/// One static pose of the platform: the averaged readings of a still stretch.
#[derive(Debug, Clone, PartialEq)]
pub struct Dwell {
    /// First sample (inclusive).
    pub start: usize,
    /// Last sample (exclusive).
    pub end: usize,
    /// Mean encoder reading per cable, m (NaN: no reading).
    pub l: Vec<f64>,
    /// Readings averaged per cable.
    pub nl: Vec<usize>,
    /// Mean tension per cable, N (NaN: none).
    pub f: Vec<f64>,
    /// Tension readings averaged per cable.
    pub nf: Vec<usize>,
    /// Sum of squared deviations of the tensions from their dwell mean, per cable, N^2.
    pub f_ss: Vec<f64>,
    /// The phase label of the dwell's rows (-1: none).
    pub label: i32,
    /// The platform's mean acceleration over the dwell, m/s²: zero at a rest; on a moving window
    /// ([`windows`]) estimated from the path, so that the equilibrium balances `m (a - g)`.
    pub accel: [f64; 3],
    /// On a moving window: each cable's rate of change and second derivative at the window's mean
    /// time, m/s and m/s² (its readings' quadratic in time); empty at a rest.
    pub l_rate: Vec<f64>,
    /// See [`Dwell::l_rate`].
    pub l_curve: Vec<f64>,
}

/// Phase labels from this on mark a tare dwell (`label - TARE_LABEL_BASE`: the pose's index);
/// equal to the loop's `MAX_DWELL_POSES`.
pub const TARE_LABEL_BASE: i32 = 64;

impl Dwell {
    /// True when this is a tare dwell ([`TARE_LABEL_BASE`]).
    pub fn is_tare(&self) -> bool {
        self.label >= TARE_LABEL_BASE
    }

    /// Cables known to carry no tension in this dwell: in a tare, those whose mean reading is
    /// below `loose_n` (the followers commanded to zero; the position-controlled cables hold
    /// the platform well above it).
    pub fn tared(&self, loose_n: f64) -> Vec<bool> {
        self.f.iter().map(|&f| self.is_tare() && f < loose_n).collect()
    }
}

/// What the dwell search found.
#[derive(Debug, Clone, PartialEq)]
pub struct Dwells {
    /// The dwells, in time order.
    pub dwells: Vec<Dwell>,
    /// Samples inside a dwell.
    pub samples: usize,
    /// Runs dropped because the encoders crept through them (moving windows: those holding a
    /// jerk, [`windows`]).
    pub drifting: usize,
    /// Variance of a dwell's mean encoder reading over white noise's (`sigma_lr^2 /
    /// sigma_row^2`, at least 1; module documentation).
    pub length_inflation: f64,
    /// The same for the tensions (1 without tensions).
    pub tension_inflation: f64,
    /// Pooled within-dwell standard deviation of one encoder row, m (`None`: no dwell long
    /// enough).
    pub length_row_sigma: Option<f64>,
}

impl Dwells {
    /// Nothing found yet.
    fn none() -> Dwells {
        Dwells { dwells: Vec::new(), samples: 0, drifting: 0, length_inflation: 1.0, tension_inflation: 1.0, length_row_sigma: None }
    }

    /// Pooled within-dwell standard deviation of one tension reading, N (`None` without tensions).
    pub fn loadcell_sigma(&self) -> Option<f64> {
        let (mut ss, mut dof) = (0.0, 0usize);
        for d in &self.dwells {
            for j in 0..d.nf.len() {
                if d.nf[j] >= 2 {
                    ss += d.f_ss[j];
                    dof += d.nf[j] - 1;
                }
            }
        }
        (dof > 0).then(|| (ss / dof as f64).sqrt())
    }
}

/// Readings averaged into a run's reference (module documentation).
const REF_ROWS: usize = 8;

/// Finds the dwells of `rec`; `sigma_enc` is one encoder reading's 1-sigma, m.
pub fn find(rec: &Recording, sigma_enc: f64, min_samples: usize) -> Dwells {
    let n = rec.n_cables;
    let min_samples = min_samples.max(4);
    let band = 6.0 * sigma_enc * (1.0 + 1.0 / REF_ROWS as f64).sqrt();
    let step = 6.0 * std::f64::consts::SQRT_2 * sigma_enc;
    let label = |i: usize| rec.phase.as_ref().map_or(-1, |p| p[i]);
    let labelled = rec.phase.as_ref().is_some_and(|p| p.iter().any(|&x| x >= 0));
    let finite = |i: usize| rec.lengths(i).iter().all(|v| v.is_finite());
    let mut out = Dwells::none();
    let still =
        |i: usize| finite(i) && label(i) == label(i - 1) && (0..n).all(|j| (rec.lengths(i)[j] - rec.lengths(i - 1)[j]).abs() <= step);
    let mut i = 0;
    while i < rec.len() {
        if !finite(i) {
            i += 1;
            continue;
        }
        let s = i;
        i += 1;
        while i < rec.len() && still(i) {
            i += 1;
        }
        if i - s < min_samples || (labelled && label(s) < 0) {
            continue;
        }
        let mut lo = s;
        let mut hi = i;
        let mut ok = drift_free(rec, lo, hi, sigma_enc);
        if !ok && (i - s) / 2 >= min_samples {
            lo = s + (i - s) / 2;
            ok = drift_free(rec, lo, hi, sigma_enc);
        }
        if !ok && !labelled {
            // A short rest between two moves (module documentation): the one stretch of the run
            // that stays within the band of its start, if it holds most of such stretches' rows
            // (a creep leaves the band again and again) and is free of drift.
            if let Some((a, b)) = rest_within(rec, s, i, band, min_samples) {
                (lo, hi) = (a, b);
                ok = drift_free(rec, lo, hi, sigma_enc);
            }
        }
        if !ok {
            out.drifting += 1;
            continue;
        }
        // The first and last readings of a run may already be a few tenths of a millimetre into
        // the move (a smooth start is slower than the step test): left out.
        let (lo, hi) = if hi - lo >= min_samples + 4 { (lo + 2, hi - 2) } else { (lo, hi) };
        out.samples += hi - lo;
        out.dwells.push(average(rec, lo, hi));
    }
    let l = inflation(&out.dwells, |i, j| rec.lengths(i)[j], n);
    out.length_inflation = l.0;
    out.length_row_sigma = l.1;
    if rec.f.is_some() {
        out.tension_inflation = inflation(&out.dwells, |i, j| rec.tensions(i).map_or(f64::NAN, |t| t[j]), n).0;
    }
    out
}

/// Batches per dwell in the long-run variance estimate.
const BATCHES: usize = 10;

/// `(inflation, row sigma)` of one kind of reading (`get(row, cable)`, NaN: none in that row)
/// over the dwells by pooled batch means of the readings present (module documentation);
/// `(1, None)` when no dwell is long enough.
fn inflation(dwells: &[Dwell], get: impl Fn(usize, usize) -> f64, n: usize) -> (f64, Option<f64>) {
    let (mut ss_b, mut dof_b, mut ss_r, mut dof_r) = (0.0, 0usize, 0.0, 0usize);
    for d in dwells {
        let b = (d.end - d.start) / BATCHES;
        if b < 4 {
            continue;
        }
        for j in 0..n {
            let rows = d.start..d.start + BATCHES * b;
            let vals = || rows.clone().map(|i| get(i, j)).filter(|v| v.is_finite());
            let count = vals().count();
            if count < 2 * BATCHES {
                continue;
            }
            let m = vals().sum::<f64>() / count as f64;
            // Batch k: its readings' count and mean; the variance of the dwell mean is
            // estimated by sum c_k (mean_k - m)^2 / (B - 1) / count (equal to the usual
            // batch-means estimate when every row has a reading).
            let mut used = 0;
            for k in 0..BATCHES {
                let lo = d.start + k * b;
                let (s, c) = (lo..lo + b).map(|i| get(i, j)).filter(|v| v.is_finite()).fold((0.0, 0usize), |(s, c), v| (s + v, c + 1));
                if c > 0 {
                    ss_b += c as f64 * (s / c as f64 - m).powi(2);
                    used += 1;
                }
            }
            ss_r += vals().map(|v| (v - m).powi(2)).sum::<f64>();
            dof_b += used - 1;
            dof_r += count - 1;
        }
    }
    if dof_b == 0 || ss_r <= 0.0 {
        return (1.0, (dof_r > 0).then(|| (ss_r / dof_r.max(1) as f64).sqrt()));
    }
    let row = ss_r / dof_r as f64;
    ((ss_b / dof_b as f64 / row).max(1.0), Some(row.sqrt()))
}

/// The stretches of rows `s..e` whose readings stay within `band` of the mean of their first
/// [`REF_ROWS`] readings (each starts where the previous one left the band); the longest, if it
/// has at least `min_samples` rows and more than half of the rows of all stretches that long.
fn rest_within(rec: &Recording, s: usize, e: usize, band: f64, min_samples: usize) -> Option<(usize, usize)> {
    let n = rec.n_cables;
    let mut runs = Vec::new();
    let mut i = s;
    while i < e {
        let a = i;
        let reference: Vec<f64> = (0..n).map(|j| mean_l(rec, a, e.min(a + REF_ROWS), j)).collect();
        while i < e && (0..n).all(|j| (rec.lengths(i)[j] - reference[j]).abs() <= band) {
            i += 1;
        }
        i = i.max(a + 1);
        if i - a >= min_samples {
            runs.push((a, i));
        }
    }
    let total: usize = runs.iter().map(|(a, b)| b - a).sum();
    runs.into_iter().max_by_key(|(a, b)| b - a).filter(|(a, b)| 2 * (b - a) > total)
}

fn mean_l(rec: &Recording, lo: usize, hi: usize, j: usize) -> f64 {
    (lo..hi).map(|i| rec.lengths(i)[j]).sum::<f64>() / (hi - lo) as f64
}

fn drift_free(rec: &Recording, lo: usize, hi: usize, sigma: f64) -> bool {
    let mid = lo + (hi - lo) / 2;
    let band = 5.0 * sigma * (4.0 / (hi - lo) as f64).sqrt();
    (0..rec.n_cables).all(|j| (mean_l(rec, lo, mid, j) - mean_l(rec, mid, hi, j)).abs() <= band)
}

fn average(rec: &Recording, lo: usize, hi: usize) -> Dwell {
    let n = rec.n_cables;
    let l: Vec<f64> = (0..n).map(|j| mean_l(rec, lo, hi, j)).collect();
    let (mut f, mut nf, mut f_ss) = (vec![f64::NAN; n], vec![0usize; n], vec![0.0; n]);
    if rec.f.is_some() {
        for j in 0..n {
            let vals = (lo..hi).filter_map(|i| rec.tensions(i).map(|t| t[j])).filter(|v| v.is_finite());
            let (mut s, mut c) = (0.0, 0usize);
            for v in vals.clone() {
                s += v;
                c += 1;
            }
            if c > 0 {
                let m = s / c as f64;
                f[j] = m;
                nf[j] = c;
                f_ss[j] = vals.map(|v| (v - m) * (v - m)).sum();
            }
        }
    }
    Dwell {
        start: lo,
        end: hi,
        l,
        nl: vec![hi - lo; n],
        f,
        nf,
        f_ss,
        label: rec.phase.as_ref().map_or(-1, |p| p[lo]),
        accel: [0.0; 3],
        l_rate: Vec::new(),
        l_curve: Vec::new(),
    }
}

/// A moving recording cut into consecutive windows of `window_s`, each averaged as one pose
/// (slow continuous motion without rests).
///
/// ```text
/// window  = consecutive rows spanning less than window_s, every encoder present, and no
///           length more than max_travel_m from its first reading
/// pose    = means of the window's lengths and tensions; each cable's rate and second
///           derivative at the mean time from its quadratic ([`Dwell::l_rate`]), from which the
///           calibration takes the platform's velocity and acceleration and the mean length's
///           excess over the length at the mean pose (the curvature of |P - A|)
/// scatter = about each cable's quadratic trend over the window's time (the motion's own change
///           is not noise); the tensions' residual variance (c - 3 dof over the rows) times the
///           readings' count less one, so that [`Dwells::loadcell_sigma`]'s pooled dof weigh it
/// count   = tensions: the distinct readings (a load cell polled 62 times a second and recorded
///           at 500 Hz repeats each reading over ~8 rows), their inflation from the windows'
///           second differences (`window_inflation`); lengths: the rows, with their inflation by
///           batch means
/// ```
///
/// A window whose lengths do not follow their quadratic within the encoder noise (`sigma_enc`,
/// 1-sigma of one reading) holds a jerk and is left out, counted in [`Dwells::drifting`]. Loose
/// cables and the platform's acceleration are the solver's business: a window's
/// [`Dwell::accel`] is zero until the calibration estimates it from the solved path. Rows with a
/// missing length end a window.
pub fn windows(rec: &Recording, sigma_enc: f64, window_s: f64, max_travel_m: f64, min_samples: usize) -> Dwells {
    let n = rec.n_cables;
    let min_samples = min_samples.max(4);
    let finite = |i: usize| rec.lengths(i).iter().all(|v| v.is_finite());
    let mut out = Dwells::none();
    // Detrended lengths (row-major like the recording's; NaN outside every window), for the
    // inflation estimate.
    let mut det_l = vec![f64::NAN; rec.len() * n];
    // Each window with its lengths' residual sum of squares about their quadratics and its dof.
    let mut found: Vec<(Dwell, f64, usize)> = Vec::new();
    let mut i = 0;
    while i < rec.len() {
        if !finite(i) {
            i += 1;
            continue;
        }
        let s = i;
        let near = |i: usize| (0..n).all(|j| (rec.lengths(i)[j] - rec.lengths(s)[j]).abs() <= max_travel_m);
        while i < rec.len() && finite(i) && rec.t[i] - rec.t[s] < window_s && near(i) {
            i += 1;
        }
        if i - s < min_samples {
            continue;
        }
        let mut d = average(rec, s, i);
        d.label = -1;
        let tm = rec.t[s..i].iter().sum::<f64>() / (i - s) as f64;
        let (mut ss_l, mut dof_l) = (0.0, 0usize);
        for j in 0..n {
            let (ss, c, coef) = detrend(s..i, |k| rec.t[k] - tm, |k| rec.lengths(k)[j], |k, v| det_l[k * n + j] = v);
            d.l_rate.push(coef[1]);
            d.l_curve.push(2.0 * coef[2]);
            ss_l += ss;
            dof_l += c.saturating_sub(3);
            if rec.f.is_some() {
                let (ss, c, _) = detrend(s..i, |k| rec.t[k] - tm, |k| rec.tensions(k).map_or(f64::NAN, |t| t[j]), |_, _| {});
                // The readings, not the rows: a held reading repeats (module documentation).
                d.nf[j] = runs(s..i, |k| rec.tensions(k).map_or(f64::NAN, |t| t[j]));
                d.f_ss[j] = if c > 3 { ss / (c - 3) as f64 * d.nf[j].saturating_sub(1) as f64 } else { 0.0 };
            }
        }
        found.push((d, ss_l, dof_l));
    }
    // A window whose lengths leave their quadratics by more than the encoders' noise holds a
    // jerk (a move starting or stopping, a knock): its mean is not the length at a pose that a
    // constant acceleration reached, and its tensions step with the inertia. Tested at a 1e-3
    // false-alarm rate against the configured noise or, when the readings are noisier, the
    // median window's (robust to the jerky minority).
    let mut ratios: Vec<f64> = found.iter().filter(|w| w.2 > 0).map(|w| w.1 / w.2 as f64).collect();
    let var = match ratios.is_empty() {
        true => sigma_enc * sigma_enc,
        false => (sigma_enc * sigma_enc).max(median(&mut ratios)),
    };
    for (d, ss, dof) in found {
        if dof > 0 && ss / var > super::chi2_quantile(dof, 3.09) {
            out.drifting += 1;
            continue;
        }
        out.samples += d.end - d.start;
        out.dwells.push(d);
    }
    let l = inflation(&out.dwells, |i, j| det_l[i * n + j], n);
    out.length_inflation = l.0;
    out.length_row_sigma = l.1;
    if let Some(row) = out.loadcell_sigma() {
        out.tension_inflation = window_inflation(&out.dwells, row * row);
    }
    out
}

/// The variance of a moving window's mean tension over `row_var / readings`, pooled over the
/// cables and the windows joined to both neighbours, from the second differences of their
/// means: along a smooth path `f_(k-1) - 2 f_k + f_(k+1)` is the noise alone (the path's own
/// curvature over 0.2 s windows is a few mN), with variance `row_var (1/n_(k-1) + 4/n_k +
/// 1/n_(k+1))` times the inflation when the readings are independent. A platform that
/// vibrates between the readings (or faster than the cell reads, aliased) correlates them over
/// a window. The median of the triples' ratios, so that the few where the inertia steps do not
/// count; a few hundred triples give the inflation to some 10 %. At least 1.
fn window_inflation(w: &[Dwell], row_var: f64) -> f64 {
    let mut ratios = Vec::new();
    for k in 1..w.len().saturating_sub(1) {
        if w[k - 1].end != w[k].start || w[k].end != w[k + 1].start {
            continue;
        }
        for j in 0..w[k].f.len() {
            let (a, b, c) = (&w[k - 1], &w[k], &w[k + 1]);
            if a.nf[j] == 0 || b.nf[j] == 0 || c.nf[j] == 0 {
                continue;
            }
            let r = a.f[j] - 2.0 * b.f[j] + c.f[j];
            let expect = row_var * (1.0 / a.nf[j] as f64 + 4.0 / b.nf[j] as f64 + 1.0 / c.nf[j] as f64);
            if r.is_finite() && expect > 0.0 {
                ratios.push(r * r / expect);
            }
        }
    }
    if ratios.is_empty() {
        return 1.0;
    }
    // The median over chi-square(1)'s (0.4549): robust to the triples where the inertia steps
    // (a move starting or stopping between two windows).
    (median(&mut ratios) / 0.4549).max(1.0)
}

/// The number of distinct readings among the finite `value(k)` over `rows`: runs of an
/// identical value count once (a reading held over several rows).
fn runs(rows: std::ops::Range<usize>, value: impl Fn(usize) -> f64) -> usize {
    let mut last = f64::NAN;
    let mut count = 0;
    for k in rows {
        let v = value(k);
        if v.is_finite() {
            if v != last {
                count += 1;
            }
            last = v;
        }
    }
    count
}

/// Least-squares quadratic of the finite `value(k)` against `x(k)` over `rows`; `put(k, mean +
/// residual)` for each, the residual scaled for the 3 dof the fit took (the mean kept, the
/// path's change over the window removed: a line leaves an accelerating platform's `a t^2 / 2`
/// in the scatter). Returns the residuals' sum of squares (unscaled), their count and the
/// quadratic's coefficients `[c0, c1, c2]` (`c0 + c1 x + c2 x^2`).
fn detrend(
    rows: std::ops::Range<usize>,
    x: impl Fn(usize) -> f64,
    value: impl Fn(usize) -> f64,
    mut put: impl FnMut(usize, f64),
) -> (f64, usize, [f64; 3]) {
    let mut c = 0usize;
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    for k in rows.clone() {
        let y = value(k);
        if y.is_finite() {
            let u = x(k);
            let b = nalgebra::Vector3::new(1.0, u, u * u);
            m += b * b.transpose();
            r += b * y;
            c += 1;
        }
    }
    if c == 0 {
        return (0.0, 0, [0.0; 3]);
    }
    let mean = r[0] / c as f64;
    // Fewer than three distinct times: the mean alone.
    let coef = m.cholesky().map_or(nalgebra::Vector3::new(mean, 0.0, 0.0), |ch| ch.solve(&r));
    // The residuals scaled by sqrt((c - 1) / (c - 3)): their scatter then estimates the
    // readings' with the c - 1 dof that the pooled row variance counts.
    let scale = if c > 3 { ((c - 1) as f64 / (c - 3) as f64).sqrt() } else { 1.0 };
    let mut ss = 0.0;
    for k in rows {
        let y = value(k);
        if y.is_finite() {
            let u = x(k);
            let res = y - coef[0] - coef[1] * u - coef[2] * u * u;
            ss += res * res;
            put(k, mean + scale * res);
        }
    }
    (ss, c, [coef[0], coef[1], coef[2]])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(lengths: &[f64]) -> Recording {
        let mut r = Recording::with_capacity(1, lengths.len(), false, false, false);
        for (i, &l) in lengths.iter().enumerate() {
            r.push(i as f64 * 0.01, [f64::NAN; 3], None, &[l], None, None);
        }
        r
    }

    #[test]
    fn finds_still_stretches_and_rejects_creep() {
        let mut l = vec![1.0; 50];
        l.extend((0..30).map(|i| 1.0 + 0.01 * (i + 1) as f64)); // a move, 1 cm per sample
        l.extend(vec![1.3; 40]);
        l.extend((0..20).map(|i| 1.3 + 0.01 * (i + 1) as f64)); // another move
        l.extend((0..100).map(|i| 1.5 + 1e-5 * i as f64)); // creep: 10 µm per sample
        let d = find(&rec(&l), 5e-5, 20);
        assert_eq!(d.dwells.len(), 2, "{d:?}");
        assert_eq!((d.dwells[0].start, d.dwells[0].end), (2, 48));
        assert_eq!((d.dwells[1].start, d.dwells[1].end), (81, 118));
        assert!((d.dwells[1].l[0] - 1.3).abs() < 1e-12);
        assert_eq!(d.drifting, 1, "the creep is not a dwell");
    }

    /// Standard normal variates from a fixed-seed xorshift generator (Box–Muller).
    fn normals(seed: u64) -> impl FnMut() -> f64 {
        let mut x = seed;
        let mut u = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        move || (-2.0 * u().ln()).sqrt() * (std::f64::consts::TAU * u()).cos()
    }

    #[test]
    fn repeated_readings_inflate_the_variance_of_a_dwell_mean() {
        // 40 labelled dwells of 500 rows (a 500 Hz loop, 1 s) of 4 cables: encoders fresh every
        // row (white), load cells read every 4th row and held (sample and hold, as a ~120 Hz
        // Modbus poll recorded at 500 Hz). The variance of a dwell's mean tension is then 4x
        // the white-noise value: the estimate pools 40 x 4 x 9 = 1440 batch dof (relative
        // 1-sigma ~4 %, batch-means bias ~-3 % for a hold of 4 in batches of 50), so the bands
        // below are > 4 sigma wide: the test fails by chance with probability < 1e-4, and it
        // fails for an estimator that ignores the repetition (inflation 1).
        let n = 4;
        let mut g = normals(0x9e37_79b9_7f4a_7c15);
        let mut r = Recording::with_capacity(n, 40 * 520, true, false, true);
        let mut t = 0.0;
        let mut held = [0.0; 4];
        for k in 0..40 {
            let base_l = 1.0 + 0.1 * k as f64;
            for i in 0..520 {
                // 20 separator rows (moving, label -1), then 500 still rows with the label.
                let moving = i < 20;
                let l: Vec<f64> = (0..n).map(|j| base_l + j as f64 + if moving { 0.01 * i as f64 } else { 0.2 } + 5e-5 * g()).collect();
                if i % 4 == 0 {
                    for (j, h) in held.iter_mut().enumerate() {
                        *h = 20.0 + j as f64 + 0.3 * g();
                    }
                }
                r.push(t, [f64::NAN; 3], None, &l, Some(&held), Some(if moving { -1 } else { k }));
                t += 0.002;
            }
        }
        let d = find(&r, 5e-5, 20);
        assert_eq!(d.dwells.len(), 40, "one dwell per label");
        assert!(d.dwells.iter().enumerate().all(|(k, w)| w.label == k as i32 && !w.is_tare()));
        assert!((3.4..4.6).contains(&d.tension_inflation), "tension inflation {}", d.tension_inflation);
        assert!((1.0..1.15).contains(&d.length_inflation), "length inflation {}", d.length_inflation);
        let s = d.length_row_sigma.unwrap();
        assert!((s - 5e-5).abs() < 5e-6, "row sigma {s}");
    }

    #[test]
    fn a_tare_dwell_names_the_slack_cables() {
        let d = Dwell {
            start: 0,
            end: 100,
            l: vec![1.0; 4],
            nl: vec![100; 4],
            f: vec![20.0, 30.0, 25.0, 0.4],
            nf: vec![25; 4],
            f_ss: vec![0.0; 4],
            label: TARE_LABEL_BASE + 3,
            accel: [0.0; 3],
            l_rate: Vec::new(),
            l_curve: Vec::new(),
        };
        assert_eq!(d.tared(5.0), vec![false, false, false, true]);
        let normal = Dwell { label: 3, ..d };
        assert_eq!(normal.tared(5.0), vec![false; 4], "a low tension outside a tare is not known to be zero");
    }
}
