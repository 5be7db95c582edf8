//! Residual analysis: which cables, which stretches of time, which part of the workspace, and
//! which measured or derived quantity the residual follows.

use super::fit::Prepared;

/// A candidate quantity the residual may follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Regressor {
    /// Tension T.
    Tension,
    /// Cable length L (geometric).
    Length,
    /// T x L (elastic stretch).
    TensionLength,
    /// Cable velocity from the encoder.
    Velocity,
    /// Direction of the last motion (+1 / -1).
    Direction,
    /// Elevation angle of the cable above the horizontal (pulley wrap).
    Elevation,
    /// L^3 cos^2(elev) / T^2 (small-sag excess).
    SagTerm,
    /// 1 / T^2.
    InvTension2,
    /// Time.
    Time,
}

impl Regressor {
    /// All regressors.
    pub const ALL: [Regressor; 9] = [
        Regressor::Tension,
        Regressor::Length,
        Regressor::TensionLength,
        Regressor::Velocity,
        Regressor::Direction,
        Regressor::Elevation,
        Regressor::SagTerm,
        Regressor::InvTension2,
        Regressor::Time,
    ];

    /// Name for people.
    pub fn name(self) -> &'static str {
        match self {
            Regressor::Tension => "tension T",
            Regressor::Length => "length L",
            Regressor::TensionLength => "T*L",
            Regressor::Velocity => "cable velocity",
            Regressor::Direction => "direction of motion",
            Regressor::Elevation => "cable elevation angle",
            Regressor::SagTerm => "L^3 cos^2(elev)/T^2",
            Regressor::InvTension2 => "1/T^2",
            Regressor::Time => "time",
        }
    }

    /// Unit for axis labels.
    pub fn unit(self) -> &'static str {
        match self {
            Regressor::Tension => "N",
            Regressor::Length => "m",
            Regressor::TensionLength => "N m",
            Regressor::Velocity => "m/s",
            Regressor::Direction => "-",
            Regressor::Elevation => "deg",
            Regressor::SagTerm => "m^3/N^2",
            Regressor::InvTension2 => "1/N^2",
            Regressor::Time => "s",
        }
    }

    /// Needs tensions.
    pub fn needs_tension(self) -> bool {
        matches!(self, Regressor::Tension | Regressor::TensionLength | Regressor::SagTerm | Regressor::InvTension2)
    }

    /// Value for cable `j` at sample `i` given the anchor. NaN when not available.
    pub fn value(self, prep: &Prepared, anchor: [f64; 3], i: usize, j: usize) -> f64 {
        let x = prep.x[j][i];
        let d = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let horiz = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let t = prep.f[j][i];
        match self {
            Regressor::Tension => t,
            Regressor::Length => l,
            Regressor::TensionLength => t * l,
            Regressor::Velocity => prep.vel[j][i],
            Regressor::Direction => prep.dir[j][i],
            Regressor::Elevation => (-d[2]).atan2(horiz).to_degrees(),
            Regressor::SagTerm => {
                let c = horiz / l;
                l * l * l * c * c / (t * t)
            }
            Regressor::InvTension2 => 1.0 / (t * t),
            Regressor::Time => prep.t[i],
        }
    }
}

/// Pearson correlation of the finite pairs; NaN with fewer than 10 pairs or no spread.
pub fn correlation(x: &[f64], y: &[f64]) -> f64 {
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        if a.is_finite() && b.is_finite() {
            n += 1.0;
            sx += a;
            sy += b;
        }
    }
    if n < 10.0 {
        return f64::NAN;
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut cxy, mut cxx, mut cyy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        if a.is_finite() && b.is_finite() {
            cxy += (a - mx) * (b - my);
            cxx += (a - mx) * (a - mx);
            cyy += (b - my) * (b - my);
        }
    }
    if cxx <= 0.0 || cyy <= 0.0 {
        return f64::NAN;
    }
    cxy / (cxx * cyy).sqrt()
}

/// RMS of the finite values; NaN if none.
pub fn rms(v: &[f64]) -> f64 {
    let (s, n) = v.iter().filter(|x| x.is_finite()).fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

/// White-noise level of a residual series: std of consecutive differences / sqrt(2). Structure
/// that changes slowly from sample to sample does not enter it.
pub fn noise_level(r: &[f64]) -> f64 {
    let d: Vec<f64> = r.windows(2).map(|w| w[1] - w[0]).filter(|x| x.is_finite()).collect();
    rms(&d) / std::f64::consts::SQRT_2
}

/// Where the mismatch is and what it follows.
#[derive(Debug, Clone, PartialEq)]
pub struct Mismatch {
    /// RMS per cable, m.
    pub per_cable_rms_m: Vec<f64>,
    /// White-noise level per cable, m.
    pub per_cable_noise_m: Vec<f64>,
    /// For each cable, the regressors sorted by |r|, strongest first: (regressor, r).
    pub correlations: Vec<Vec<(Regressor, f64)>>,
    /// RMS in each of 10 time blocks, m, with the block's time span.
    pub time_blocks: Vec<(f64, f64, f64)>,
    /// Worst workspace octant: (description, its RMS, RMS elsewhere), m.
    pub region: Option<(String, f64, f64)>,
    /// The findings in words.
    pub words: Vec<String>,
}

/// Analyses residuals `res[j][k]` (k indexes `samples`), the anchors of the fit that made them.
pub fn analyse(prep: &Prepared, samples: &[usize], res: &[Vec<f64>], anchors: &[[f64; 3]], has_tension: &[bool]) -> Mismatch {
    let n = prep.n;
    let per_cable_rms_m: Vec<f64> = res.iter().map(|r| rms(r)).collect();
    let per_cable_noise_m: Vec<f64> = res.iter().map(|r| noise_level(r)).collect();
    let mut correlations = vec![];
    for j in 0..n {
        let mut cs = vec![];
        for reg in Regressor::ALL {
            if reg.needs_tension() && !has_tension[j] {
                continue;
            }
            let x: Vec<f64> = samples.iter().map(|&i| reg.value(prep, anchors[j], i, j)).collect();
            let r = correlation(&x, &res[j]);
            if r.is_finite() {
                cs.push((reg, r));
            }
        }
        cs.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        correlations.push(cs);
    }
    // Time blocks.
    let nb = 10.min(samples.len().max(1));
    let mut time_blocks = vec![];
    for b in 0..nb {
        let lo = b * samples.len() / nb;
        let hi = (b + 1) * samples.len() / nb;
        if hi <= lo {
            continue;
        }
        let mut all = vec![];
        for r in res {
            all.extend_from_slice(&r[lo..hi]);
        }
        time_blocks.push((prep.t[samples[lo]], prep.t[samples[hi - 1]], rms(&all)));
    }
    // Workspace octants by the median of each platform coordinate (cable 0's attachment is
    // close enough to the platform reference for this).
    let mut med = [0.0; 3];
    for (k, m) in med.iter_mut().enumerate() {
        let mut v: Vec<f64> = samples.iter().map(|&i| prep.x[0][i][k]).collect();
        v.sort_by(|a, b| a.total_cmp(b));
        *m = v.get(v.len() / 2).copied().unwrap_or(0.0);
    }
    let mut oct = [(0.0, 0usize); 8];
    for (k, &i) in samples.iter().enumerate() {
        let p = prep.x[0][i];
        let o = (p[0] > med[0]) as usize | ((p[1] > med[1]) as usize) << 1 | ((p[2] > med[2]) as usize) << 2;
        for r in res {
            if r[k].is_finite() {
                oct[o].0 += r[k] * r[k];
                oct[o].1 += 1;
            }
        }
    }
    let total: (f64, usize) = oct.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let region =
        (0..8).filter(|&o| oct[o].1 > 20).max_by(|&a, &b| (oct[a].0 / oct[a].1 as f64).total_cmp(&(oct[b].0 / oct[b].1 as f64))).map(|o| {
            let inside = (oct[o].0 / oct[o].1 as f64).sqrt();
            let rest_n = total.1 - oct[o].1;
            let outside = if rest_n > 0 { ((total.0 - oct[o].0) / rest_n as f64).sqrt() } else { f64::NAN };
            let side = |bit: usize, axis: &str, m: f64| {
                if o & bit != 0 {
                    format!("{axis} > {m:.2}")
                } else {
                    format!("{axis} < {m:.2}")
                }
            };
            (format!("{}, {}, {} m", side(1, "x", med[0]), side(2, "y", med[1]), side(4, "z", med[2])), inside, outside)
        });

    let mut words = vec![];
    let overall = rms(&res.concat());
    let noise = {
        let mut v: Vec<f64> = per_cable_noise_m.iter().copied().filter(|x| x.is_finite()).collect();
        v.sort_by(|a, b| a.total_cmp(b));
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    words.push(format!("residual {:.2} mm RMS against a sample-to-sample noise level of {:.2} mm", overall * 1e3, noise * 1e3));
    let worst = (0..n).max_by(|&a, &b| per_cable_rms_m[a].total_cmp(&per_cable_rms_m[b]));
    let best = (0..n).min_by(|&a, &b| per_cable_rms_m[a].total_cmp(&per_cable_rms_m[b]));
    if let (Some(w), Some(b)) = (worst, best) {
        if per_cable_rms_m[w] > 1.5 * per_cable_rms_m[b] {
            words.push(format!(
                "cable {} carries most of it ({:.2} mm RMS; cable {}: {:.2} mm)",
                w + 1,
                per_cable_rms_m[w] * 1e3,
                b + 1,
                per_cable_rms_m[b] * 1e3
            ));
        }
    }
    let mut tb: Vec<f64> = time_blocks.iter().map(|b| b.2).filter(|x| x.is_finite()).collect();
    tb.sort_by(|a, b| a.total_cmp(b));
    if let Some(&mid) = tb.get(tb.len() / 2) {
        if let Some(b) = time_blocks.iter().filter(|b| b.2 > 2.0 * mid).max_by(|a, b| a.2.total_cmp(&b.2)) {
            words.push(format!("largest in t = {:.1}-{:.1} s ({:.2} mm RMS, {:.2} mm typical)", b.0, b.1, b.2 * 1e3, mid * 1e3));
        }
    }
    if let Some((d, inside, outside)) = &region {
        if *inside > 1.5 * outside {
            words.push(format!("largest where {d} ({:.2} mm RMS, {:.2} mm elsewhere)", inside * 1e3, outside * 1e3));
        }
    }
    // What it follows: the regressor with the largest |r| summed over cables.
    let mut score: Vec<(Regressor, f64, Vec<f64>)> = vec![];
    for reg in Regressor::ALL {
        let rs: Vec<f64> = correlations.iter().map(|c| c.iter().find(|x| x.0 == reg).map_or(f64::NAN, |x| x.1)).collect();
        let s: f64 = rs.iter().filter(|x| x.is_finite()).map(|x| x.abs()).sum();
        score.push((reg, s, rs));
    }
    score.sort_by(|a, b| b.1.total_cmp(&a.1));
    for (reg, _, rs) in score.iter().take(2) {
        let strong: Vec<usize> = (0..n).filter(|&j| rs[j].abs() >= 0.3).collect();
        if strong.is_empty() {
            continue;
        }
        let lo = strong.iter().map(|&j| rs[j]).fold(f64::INFINITY, f64::min);
        let hi = strong.iter().map(|&j| rs[j]).fold(f64::NEG_INFINITY, f64::max);
        let which = if strong.len() == n { "every cable".to_string() } else { taut_config::cable_list(&strong) };
        words.push(format!("follows {} on {which} (r = {lo:.2} .. {hi:.2})", reg.name()));
    }
    Mismatch { per_cable_rms_m, per_cable_noise_m, correlations, time_blocks, region, words }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn correlation_of_a_line_is_one() {
        let x: Vec<f64> = (0..100).map(|k| k as f64).collect();
        let y: Vec<f64> = x.iter().map(|v| -2.0 * v + 1.0).collect();
        assert!((correlation(&x, &y) + 1.0).abs() < 1e-12);
    }

    #[test]
    fn noise_level_ignores_slow_structure() {
        let r: Vec<f64> = (0..1000).map(|k| (k as f64 * 0.01).sin() * 0.01 + if k % 2 == 0 { 1e-3 } else { -1e-3 }).collect();
        let nl = noise_level(&r);
        assert!((nl - 1.414e-3).abs() < 2e-4, "{nl}");
    }
}
