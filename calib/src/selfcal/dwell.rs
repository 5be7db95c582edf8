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
//! Two readings at each end of a dwell are dropped (the start or end of a smooth move).
//! A dwell's readings are averaged per cable (`NaN`s skipped): the mean is the sufficient
//! statistic of a static pose under white noise, and its variance is `sigma^2 / m`. The
//! within-dwell scatter of the tensions gives the load cells' noise when it is not configured.

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

/// Finds the dwells of `rec`; `sigma_enc` is one encoder reading's 1-sigma, m.
pub fn find(rec: &Recording, sigma_enc: f64, min_samples: usize) -> Dwells {
    let n = rec.n_cables;
    let min_samples = min_samples.max(4);
    let step = 6.0 * std::f64::consts::SQRT_2 * sigma_enc;
    let still = |i: usize| {
        let (a, b) = (rec.lengths(i - 1), rec.lengths(i));
        (0..n).all(|j| (b[j] - a[j]).abs() <= step)
    };
    let mut out = Dwells { dwells: Vec::new(), samples: 0, drifting: 0 };
    let mut i = 0;
    while i < rec.len() {
        if !rec.lengths(i).iter().all(|v| v.is_finite()) {
            i += 1;
            continue;
        }
        let s = i;
        i += 1;
        while i < rec.len() && rec.lengths(i).iter().all(|v| v.is_finite()) && still(i) {
            i += 1;
        }
        if i - s < min_samples {
            continue;
        }
        let mut lo = s;
        let mut ok = drift_free(rec, lo, i, sigma_enc);
        if !ok && (i - s) / 2 >= min_samples {
            lo = s + (i - s) / 2;
            ok = drift_free(rec, lo, i, sigma_enc);
        }
        if !ok {
            out.drifting += 1;
            continue;
        }
        // The first and last readings of a run may already be a few tenths of a millimetre into
        // the move (a smooth start is slower than the step test): left out.
        let (lo, hi) = if i - lo >= min_samples + 4 { (lo + 2, i - 2) } else { (lo, i) };
        out.samples += hi - lo;
        out.dwells.push(average(rec, lo, hi));
    }
    out
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
    Dwell { start: lo, end: hi, l, nl: vec![hi - lo; n], f, nf, f_ss }
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
}
