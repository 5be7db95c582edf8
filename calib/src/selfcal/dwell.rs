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
    /// Runs dropped because the encoders crept through them.
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
    let mut out =
        Dwells { dwells: Vec::new(), samples: 0, drifting: 0, length_inflation: 1.0, tension_inflation: 1.0, length_row_sigma: None };
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
    Dwell { start: lo, end: hi, l, nl: vec![hi - lo; n], f, nf, f_ss, label: rec.phase.as_ref().map_or(-1, |p| p[lo]) }
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
        };
        assert_eq!(d.tared(5.0), vec![false, false, false, true]);
        let normal = Dwell { label: 3, ..d };
        assert_eq!(normal.tared(5.0), vec![false; 4], "a low tension outside a tare is not known to be zero");
    }
}
