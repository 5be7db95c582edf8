//! The honesty of a predicted uncertainty from measured ratios (achieved / predicted sigma over
//! earlier runs): the upper prediction bound of the next ratio (Student's t), for the tests that
//! assert an error limit at a stated failure probability (simtime's `excitation` and `notracker_3mm`), and
//! a chi-square tail.

/// Mean, standard deviation and the upper prediction bound of the next value of `x` at tail
/// probability `tail` (Student's t with n - 1 dof: mean + t sd sqrt(1 + 1/n)).
pub fn upper_prediction_bound(x: &[f64], tail: f64) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let sd = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    // The t quantile by bisection on the tail.
    let (mut lo, mut hi) = (0.0, 200.0);
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if student_t_sf(mid, n - 1.0) > tail {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (mean, sd, mean + hi * sd * (1.0 + 1.0 / n).sqrt())
}

/// P(the next value of `x` exceeds `v`) by the same prediction (Student's t, n - 1 dof).
pub fn exceeds_chance(x: &[f64], v: f64) -> f64 {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let sd = (x.iter().map(|u| (u - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    student_t_sf((v - mean) / (sd * (1.0 + 1.0 / n).sqrt()), n - 1.0)
}

/// P(a correct run fails) when it fails with probability `p_at(c)` at honesty `c` (increasing in
/// `c`) and the next `c` follows the prediction over `x` (Student's t, n - 1 dof, as
/// [`upper_prediction_bound`]): the integral over `c`, bounded above by taking each step's
/// `p_at` at its upper end (steps of 0.25 t units from -6 to 40; the tails beyond count 0 below
/// and 1 above).
pub fn integrated_failure(x: &[f64], p_at: impl Fn(f64) -> f64) -> f64 {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let sd = (x.iter().map(|u| (u - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let w = sd * (1.0 + 1.0 / n).sqrt();
    let (t0, t1, h) = (-6.0, 40.0, 0.25);
    let steps = ((t1 - t0) / h) as usize;
    let mut sf_lo = student_t_sf(t0, n - 1.0);
    let mut p = (1.0 - sf_lo) * p_at(mean + t0 * w);
    for k in 1..=steps {
        let t = t0 + k as f64 * h;
        let sf_hi = student_t_sf(t, n - 1.0);
        p += (sf_lo - sf_hi) * p_at(mean + t * w);
        sf_lo = sf_hi;
    }
    (p + sf_lo).min(1.0)
}

/// P(T > x) for Student's t with `dof` degrees of freedom: the density integrated numerically
/// (t = tan(u), Simpson's rule) and divided by its integral over the line.
pub fn student_t_sf(x: f64, dof: f64) -> f64 {
    let f = |u: f64| {
        let t = u.tan();
        (1.0 + t * t / dof).powf(-(dof + 1.0) / 2.0) / (u.cos() * u.cos())
    };
    let simpson = |a: f64, b: f64| {
        let m = 20_000;
        let h = (b - a) / m as f64;
        // The end points carry no weight where the density (with its sec^2) vanishes.
        let mut s = 0.0;
        for k in 1..m {
            s += if k % 2 == 1 { 4.0 } else { 2.0 } * f(a + k as f64 * h);
        }
        let end = |u: f64| if (u.abs() - std::f64::consts::FRAC_PI_2).abs() < 1e-12 { 0.0 } else { f(u) };
        (s + end(a) + end(b)) * h / 3.0
    };
    let half = std::f64::consts::FRAC_PI_2;
    simpson(x.atan(), half) / simpson(-half, half)
}

/// P(chi2 >= x) at `dof` (Wilson–Hilferty), for the chi-square of a fit's residuals (the
/// tracker-free examples).
pub fn chi2_sf(x: f64, dof: usize) -> f64 {
    let k = dof.max(1) as f64;
    let h = 2.0 / (9.0 * k);
    let z = ((x / k).cbrt() - (1.0 - h)) / h.sqrt();
    // Upper normal tail (Abramowitz-Stegun 26.2.17, |error| < 7.5e-8).
    let t = 1.0 / (1.0 + 0.231_641_9 * z.abs());
    let poly = t * (0.319_381_530 + t * (-0.356_563_782 + t * (1.781_477_937 + t * (-1.821_255_978 + t * 1.330_274_429))));
    let tail = (-z * z / 2.0).exp() / (2.0 * std::f64::consts::PI).sqrt() * poly;
    if z >= 0.0 {
        tail
    } else {
        1.0 - tail
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn student_t_matches_tables() {
        // scipy.stats.t: sf(4.297, 9) = 9.997e-4, sf(8.1, 9) = 1.002e-5, sf(2, 3) = 0.06966.
        assert!((student_t_sf(4.297, 9.0) / 9.997e-4 - 1.0).abs() < 1e-3, "{}", student_t_sf(4.297, 9.0));
        assert!((student_t_sf(8.1, 9.0) / 1.002e-5 - 1.0).abs() < 1e-3, "{}", student_t_sf(8.1, 9.0));
        assert!((student_t_sf(2.0, 3.0) / 0.06966 - 1.0).abs() < 1e-3, "{}", student_t_sf(2.0, 3.0));
        // Ten values 1..=10: mean 5.5, sd 3.0277; t(0.999, 9) = 4.297.
        let x: Vec<f64> = (1..=10).map(f64::from).collect();
        let (m, s, up) = upper_prediction_bound(&x, 1e-3);
        assert!((m - 5.5).abs() < 1e-12 && (s - 3.02765).abs() < 1e-4);
        assert!((up - (5.5 + 4.297 * 3.02765 * 1.1f64.sqrt())).abs() < 1e-2, "{up}");
        assert!((exceeds_chance(&x, up) - 1e-3).abs() < 1e-6);
        // A step at the bound: failing always above it, never below: the integral is its tail.
        let p = integrated_failure(&x, |c| if c > up { 1.0 } else { 0.0 });
        assert!((1e-3..1.1e-3).contains(&p), "{p}");
    }
}
