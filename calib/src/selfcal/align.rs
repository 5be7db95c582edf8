//! The best alignment of one anchor set onto another by a translation and a rotation about the
//! vertical: how a tracker-free result (whose frame is only fixed up to those) is compared with
//! a reference.
//!
//! ```text
//! minimise sum_j |R_z(theta) (a_j - a_mean) + t - b_j|^2
//! theta = atan2(sum_j (x_j y'_j - y_j x'_j), sum_j (x_j x'_j + y_j y'_j))   (centred a, b)
//! t     = b_mean - R_z(theta) a_mean  (rotation about a_mean)
//! ```

/// `anchors` moved by the translation and rotation about the vertical that best align them
/// (least squares) with `onto`. Same order, same length (the shorter one decides).
pub fn align_translation_yaw(anchors: &[[f64; 3]], onto: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let n = anchors.len().min(onto.len());
    if n == 0 {
        return vec![];
    }
    let mean = |v: &[[f64; 3]]| -> [f64; 3] { std::array::from_fn(|a| v[..n].iter().map(|p| p[a]).sum::<f64>() / n as f64) };
    let (ca, cb) = (mean(anchors), mean(onto));
    let (mut s, mut c) = (0.0, 0.0);
    for j in 0..n {
        let (x, y) = (anchors[j][0] - ca[0], anchors[j][1] - ca[1]);
        let (u, v) = (onto[j][0] - cb[0], onto[j][1] - cb[1]);
        s += x * v - y * u;
        c += x * u + y * v;
    }
    let th = s.atan2(c);
    let (sn, cs) = th.sin_cos();
    anchors[..n]
        .iter()
        .map(|a| {
            let (x, y, z) = (a[0] - ca[0], a[1] - ca[1], a[2] - ca[2]);
            [cs * x - sn * y + cb[0], sn * x + cs * y + cb[1], z + cb[2]]
        })
        .collect()
}

/// Largest distance between `anchors`, aligned onto `truth` ([`align_translation_yaw`]), and
/// `truth`, m.
pub fn worst_aligned_error(anchors: &[[f64; 3]], truth: &[[f64; 3]]) -> f64 {
    align_translation_yaw(anchors, truth)
        .iter()
        .zip(truth)
        .map(|(a, t)| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undoes_a_translation_and_a_yaw() {
        let t = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.1], [-3.5, 1.75, 3.9], [-3.5, -1.75, 4.0]];
        let (sn, cs) = 0.3f64.sin_cos();
        let moved: Vec<[f64; 3]> = t.iter().map(|a| [cs * a[0] - sn * a[1] + 0.4, sn * a[0] + cs * a[1] - 0.2, a[2] + 0.05]).collect();
        assert!(worst_aligned_error(&moved, &t) < 1e-12);
        // A change of shape stays.
        let mut bent = moved.clone();
        bent[0][2] += 0.01;
        let e = worst_aligned_error(&bent, &t);
        assert!(e > 0.005 && e < 0.01, "{e}");
    }
}
