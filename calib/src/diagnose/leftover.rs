//! What the named effects leave: generic smooth functions of what a missing effect could follow,
//! fitted per cable to the final model's training residuals and tested on the held-out blocks
//! with the candidates' held-out test (`diagnose`'s step 5). A significant one means structure
//! remains that no effect in the library explains, and says what it follows.
//!
//! The families are deliberately not physical models: a periodic function of each cable's
//! reading (an eccentric drum, a cam in the guide, a winding pattern repeat at the drum's
//! circumference) and smooth functions of the platform's position (a frame or tracker
//! distortion, a length error that follows the height). Each is fitted on the training blocks
//! only, so the held-out test is as honest for them as for an effect.

use nalgebra::{DMatrix, DVector};

use crate::effects::model::Prepared;

/// What a leftover follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Follows {
    /// A sinusoid in each cable's encoder reading (its wavelength chosen per cable on the
    /// training blocks, 30 mm to 1 m).
    PeriodicInLength,
    /// A quadratic in the platform's height alone.
    Height,
    /// A quadratic in the platform's position (x, y, z and their products).
    Position,
    /// A smooth function of each cable's encoder reading (piecewise linear, knots every
    /// [`KNOT_SPACING_M`] or closer over the training range).
    Length,
}

impl Follows {
    /// The families tested, in the order reported.
    pub const ALL: [Follows; 4] = [Follows::PeriodicInLength, Follows::Height, Follows::Position, Follows::Length];

    /// Words for people.
    pub fn words(self) -> &'static str {
        match self {
            Follows::PeriodicInLength => "is periodic in the cable's length",
            Follows::Height => "follows the platform's height",
            Follows::Position => "follows the platform's position",
            Follows::Length => "follows the cable's paid-out length (as a drum's or a winding's irregularity would)",
        }
    }
}

/// Shortest and longest wavelength of the periodic family, m, and the grid's size.
const WAVELENGTHS: (f64, f64, usize) = (0.03, 1.0, 60);

/// Widest knot spacing of the length family, m; at most `MAX_KNOTS` knots span a cable's
/// training range.
pub const KNOT_SPACING_M: f64 = 0.02;
const MAX_KNOTS: usize = 40;

/// One family fitted to every cable's training residuals.
#[derive(Debug, Clone, PartialEq)]
pub struct Nuisance {
    /// The family.
    pub follows: Follows,
    /// The held-out residuals with the fitted function removed, in the layout of `r0` in
    /// [`fit`].
    pub heldout: Vec<f64>,
    /// Per cable, the RMS of the fitted function on its held-out readings, m.
    pub removed_m: Vec<f64>,
    /// Per cable, the fitted basis and its coefficients (`None`: too few training readings).
    fitted: Vec<Option<(Basis, Vec<f64>)>>,
}

impl Nuisance {
    /// Per cable, the periodic family's wavelength, m (NaN for the other families or a cable
    /// without training data).
    pub fn wavelengths_m(&self) -> Vec<f64> {
        self.fitted
            .iter()
            .map(|f| match f {
                Some((Basis::Sinusoid { lambda }, _)) => *lambda,
                _ => f64::NAN,
            })
            .collect()
    }

    /// Cable `j`'s regressors at sample `i` in the basis fitted for it (`None`: no fit), so that
    /// the family can be refitted with the model ([`crate::diagnose`]'s joint fit).
    pub fn regressors(&self, prep: &Prepared, i: usize, j: usize) -> Option<Vec<f64>> {
        self.fitted[j].as_ref().map(|(basis, _)| basis.at(prep, i, j))
    }

    /// The fitted function of cable `j` at sample `i` of `prep` (the one it was fitted on), m;
    /// 0 where the cable had none.
    pub fn value(&self, prep: &Prepared, i: usize, j: usize) -> f64 {
        self.fitted[j].as_ref().map_or(0.0, |(basis, c)| basis.at(prep, i, j).iter().zip(c).map(|(a, b)| a * b).sum())
    }
}

/// Fits `follows` per cable to the residuals `res[j][i]` on the `train` samples and returns the
/// held-out residuals without it. The held-out layout is that of the diagnosis's tests: for each
/// sample of `heldout` in turn, its usable cables in order.
pub fn fit(prep: &Prepared, res: &[Vec<f64>], train: &[usize], heldout: &[usize], follows: Follows) -> Nuisance {
    let n = prep.n;
    let centre = centroid(prep, train);
    let mut fitted: Vec<Option<(Basis, Vec<f64>)>> = vec![None; n];
    for (j, f) in fitted.iter_mut().enumerate() {
        let rows: Vec<usize> = train.iter().copied().filter(|&i| prep.usable[j][i] && res[j][i].is_finite()).collect();
        if rows.len() < 30 {
            continue;
        }
        let basis = match follows {
            Follows::PeriodicInLength => {
                *f = best_wavelength(prep, res, &rows, j).map(|(c, lambda)| (Basis::Sinusoid { lambda }, c));
                continue;
            }
            Follows::Height => Basis::Height(centre),
            Follows::Position => Basis::Position(centre),
            Follows::Length => {
                let (lo, hi) =
                    rows.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &i| (a.min(prep.l[j][i]), b.max(prep.l[j][i])));
                let k = (((hi - lo) / KNOT_SPACING_M).ceil() as usize).clamp(1, MAX_KNOTS - 1);
                Basis::Hats { first: lo, spacing: (hi - lo).max(1e-6) / k as f64, count: k + 1 }
            }
        };
        *f = solve(&rows, |i| basis.at(prep, i, j), |i| res[j][i]).map(|c| (basis, c));
    }
    let mut nuisance = Nuisance { follows, heldout: vec![], removed_m: vec![], fitted };
    let (mut sq, mut cnt) = (vec![0.0; n], vec![0usize; n]);
    for &i in heldout {
        for j in (0..n).filter(|&j| prep.usable[j][i]) {
            let f = nuisance.value(prep, i, j);
            nuisance.heldout.push(res[j][i] - f);
            sq[j] += f * f;
            cnt[j] += 1;
        }
    }
    nuisance.removed_m = sq.iter().zip(&cnt).map(|(s, &k)| if k > 0 { (s / k as f64).sqrt() } else { f64::NAN }).collect();
    nuisance
}

/// The mean platform attachment point of cable 0 on `samples` (the families' origin).
fn centroid(prep: &Prepared, samples: &[usize]) -> [f64; 3] {
    let mut c = [0.0; 3];
    let mut k = 0.0;
    for &i in samples {
        let x = prep.x[0][i];
        if x.iter().all(|v| v.is_finite()) {
            for a in 0..3 {
                c[a] += x[a];
            }
            k += 1.0;
        }
    }
    c.map(|v| if k > 0.0 { v / k } else { 0.0 })
}

/// One cable's regressors in a family, with what fixes them on the training blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Basis {
    /// `1, sin, cos` of `2 pi l / lambda`, `lambda` in m.
    Sinusoid { lambda: f64 },
    /// `1, dz, dz^2` about the centre.
    Height([f64; 3]),
    /// The quadratic in `dx, dy, dz` about the centre.
    Position([f64; 3]),
    /// Hat functions in the reading on `count` knots from `first` every `spacing` m, the
    /// reading clamped to their span.
    Hats { first: f64, spacing: f64, count: usize },
}

impl Basis {
    /// The regressors at sample `i` of cable `j`.
    fn at(self, prep: &Prepared, i: usize, j: usize) -> Vec<f64> {
        let x = prep.x[j][i];
        let from = |c: [f64; 3]| [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
        match self {
            Basis::Sinusoid { lambda } => {
                let (sn, cs) = (std::f64::consts::TAU * prep.l[j][i] / lambda).sin_cos();
                vec![1.0, sn, cs]
            }
            Basis::Height(c) => {
                let d = from(c);
                vec![1.0, d[2], d[2] * d[2]]
            }
            Basis::Position(c) => {
                let d = from(c);
                vec![1.0, d[0], d[1], d[2], d[0] * d[0], d[1] * d[1], d[2] * d[2], d[0] * d[1], d[0] * d[2], d[1] * d[2]]
            }
            Basis::Hats { first, spacing, count } => {
                let mut v = vec![0.0; count];
                let u = ((prep.l[j][i] - first) / spacing).clamp(0.0, (count - 1) as f64);
                let k = (u.floor() as usize).min(count.saturating_sub(2));
                let f = u - k as f64;
                v[k] = 1.0 - f;
                if count > 1 {
                    v[k + 1] = f;
                }
                v
            }
        }
    }
}

/// The wavelength whose sinusoid removes the most of cable `j`'s training residual, with its
/// coefficients: the best of a log-spaced grid, refined by golden-section search between its
/// neighbours.
fn best_wavelength(prep: &Prepared, res: &[Vec<f64>], rows: &[usize], j: usize) -> Option<(Vec<f64>, f64)> {
    let yy: f64 = rows.iter().map(|&i| res[j][i] * res[j][i]).sum();
    // The residual sum of squares from the normal equations, `y'y - c'b`: one pass per wavelength.
    let at = |lambda: f64| {
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut b = nalgebra::Vector3::<f64>::zeros();
        for &i in rows {
            let (sn, cs) = (std::f64::consts::TAU * prep.l[j][i] / lambda).sin_cos();
            let f = nalgebra::Vector3::new(1.0, sn, cs);
            a += f * f.transpose();
            b += f * res[j][i];
        }
        let c = a.cholesky()?.solve(&b);
        Some((yy - c.dot(&b), vec![c[0], c[1], c[2]]))
    };
    let (lo, hi, k) = WAVELENGTHS;
    let step = (hi / lo).powf(1.0 / (k - 1) as f64);
    let grid = (0..k).map(|s| lo * step.powi(s as i32));
    let (mut ss, mut c, lambda) = grid.filter_map(|l| at(l).map(|(ss, c)| (ss, c, l))).min_by(|a, b| a.0.total_cmp(&b.0))?;
    // Golden section on ln(lambda) over the grid's neighbours.
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut b) = ((lambda / step).ln(), (lambda * step).ln());
    let mut best_l = lambda;
    for _ in 0..24 {
        let (x1, x2) = (b - g * (b - a), a + g * (b - a));
        let (f1, f2) = (at(x1.exp()), at(x2.exp()));
        let (s1, s2) = (f1.as_ref().map_or(f64::INFINITY, |f| f.0), f2.as_ref().map_or(f64::INFINITY, |f| f.0));
        if s1 < s2 {
            b = x2;
        } else {
            a = x1;
        }
        for (s, f, x) in [(s1, f1, x1), (s2, f2, x2)] {
            if let Some((_, cf)) = f.filter(|_| s < ss) {
                (ss, c, best_l) = (s, cf, x.exp());
            }
        }
    }
    Some((c, best_l))
}

/// Least squares of `y(i)` on `phi(i)` over `rows` (normal equations with a relative ridge of
/// 1e-10, by Cholesky); `None` if singular.
fn solve(rows: &[usize], phi: impl Fn(usize) -> Vec<f64>, y: impl Fn(usize) -> f64) -> Option<Vec<f64>> {
    let p = phi(rows[0]).len();
    let mut a = DMatrix::<f64>::zeros(p, p);
    let mut b = DVector::<f64>::zeros(p);
    for &i in rows {
        let f = phi(i);
        let v = y(i);
        for r in 0..p {
            b[r] += f[r] * v;
            for c in 0..p {
                a[(r, c)] += f[r] * f[c];
            }
        }
    }
    let ridge = 1e-10 * (0..p).map(|r| a[(r, r)]).sum::<f64>() / p as f64;
    for r in 0..p {
        a[(r, r)] += ridge;
    }
    a.cholesky().map(|ch| ch.solve(&b).iter().copied().collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_periodic_family_finds_the_wavelength_of_a_sinusoid_in_the_length() {
        let m = 2000;
        let lambda = 0.157;
        let l: Vec<f64> = (0..m).map(|i| 1.0 + 0.6 * (i as f64 * 0.01).sin()).collect();
        let prep = Prepared {
            n: 1,
            t: (0..m).map(|i| i as f64 * 0.01).collect(),
            rows: (0..m).collect(),
            x: vec![(0..m).map(|i| [0.0, 0.0, l[i]]).collect()],
            l: vec![l.clone()],
            f: vec![vec![f64::NAN; m]],
            vel: vec![vec![0.0; m]],
            dir: vec![vec![0.0; m]],
            play: Default::default(),
            usable: vec![vec![true; m]],
            loose: vec![vec![false; m]],
            segment: vec![0; m],
            heldout: vec![false; m],
            hold_weight: vec![],
            eiv: None,
            pulley_axis: vec![],
            priors: vec![],
        };
        let res = vec![l.iter().map(|v| 1e-3 * (std::f64::consts::TAU * v / lambda + 0.3).sin()).collect::<Vec<f64>>()];
        let train: Vec<usize> = (0..m).filter(|i| i % 5 != 0).collect();
        let held: Vec<usize> = (0..m).filter(|i| i % 5 == 0).collect();
        let fitted = fit(&prep, &res, &train, &held, Follows::PeriodicInLength);
        let w = fitted.wavelengths_m()[0];
        assert!((w - lambda).abs() < 0.01 * lambda, "wavelength {w}");
        assert!(fitted.heldout.iter().all(|r| r.abs() < 1e-4), "left {:?}", fitted.heldout.iter().fold(0.0f64, |a, b| a.max(b.abs())));
        assert!((fitted.removed_m[0] - 1e-3 / 2f64.sqrt()).abs() < 1e-4);
    }
}
