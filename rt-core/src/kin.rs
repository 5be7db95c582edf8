//! Parameters as the loop holds them, and the inverse kinematics it runs every cycle.
//!
//! Model (as in `calib`): encoder length `l_j = |P + b_j - A_j| + L0_j` for a platform at `P`
//! without rotation, `b_j` the attachment point in the platform frame, `A_j` the anchor.

use crate::MAX_CABLES;

/// The kinematic parameters the loop uses. `Copy` and fixed size, so publishing one through the
/// triple buffer never allocates or frees on the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopParams {
    /// Increases with every accepted set; 0 before any calibration.
    pub version: u64,
    /// Number of cables.
    pub n: usize,
    /// Anchors `A_j`, m.
    pub anchors: [[f64; 3]; MAX_CABLES],
    /// Encoder offsets `L0_j`, m.
    pub l0: [f64; MAX_CABLES],
    /// Platform attachment points `b_j`, m.
    pub platform: [[f64; 3]; MAX_CABLES],
    /// False until the loop may use these for inverse kinematics (no estimate yet).
    pub valid: bool,
}

impl LoopParams {
    /// Parameters of `n` cables that are not usable yet.
    pub fn invalid(n: usize) -> LoopParams {
        LoopParams { version: 0, n, anchors: [[0.0; 3]; MAX_CABLES], l0: [0.0; MAX_CABLES], platform: [[0.0; 3]; MAX_CABLES], valid: false }
    }

    /// Usable parameters from slices.
    pub fn new(version: u64, anchors: &[[f64; 3]], l0: &[f64], platform: &[[f64; 3]]) -> LoopParams {
        let n = anchors.len();
        assert!(n <= MAX_CABLES && l0.len() == n && platform.len() == n, "one anchor, offset and platform point per cable");
        let mut p = LoopParams::invalid(n);
        p.version = version;
        p.anchors[..n].copy_from_slice(anchors);
        p.l0[..n].copy_from_slice(l0);
        p.platform[..n].copy_from_slice(platform);
        p.valid = true;
        p
    }

    /// Encoder length of cable `j` for the platform at `p`, m.
    #[inline]
    pub fn length(&self, j: usize, p: &[f64; 3]) -> f64 {
        let a = &self.anchors[j];
        let b = &self.platform[j];
        let d = [p[0] + b[0] - a[0], p[1] + b[1] - a[1], p[2] + b[2] - a[2]];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() + self.l0[j]
    }

    /// Encoder lengths of every cable for the platform at `p`, into `out`.
    #[inline]
    pub fn lengths(&self, p: &[f64; 3], out: &mut [f64; MAX_CABLES]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = self.length(j, p);
        }
    }

    /// Root-mean-square co-registration error (measured minus modelled length) over samples with
    /// a tracker position and, where tensions are given, only taut cables; `None` without any.
    pub fn coregistration_rms<'a>(
        &self,
        samples: impl Iterator<Item = (&'a [f64; 3], &'a [f64], Option<&'a [f64]>)>,
        min_tension_n: f64,
    ) -> Option<f64> {
        let (mut sum, mut count) = (0.0, 0usize);
        for (p, l, f) in samples {
            for j in 0..self.n {
                if let Some(e) = self.coregistration_error(j, p, l, f, min_tension_n) {
                    sum += e * e;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| (sum / count as f64).sqrt())
    }

    /// Measured minus modelled length of cable `j` at pose `p`; `None` without a pose, a
    /// length, or with a tension below `min_tension_n` (loose cable).
    pub fn coregistration_error(&self, j: usize, p: &[f64; 3], l: &[f64], f: Option<&[f64]>, min_tension_n: f64) -> Option<f64> {
        let usable = p.iter().all(|x| x.is_finite()) && l[j].is_finite() && f.is_none_or(|f| f[j] >= min_tension_n);
        usable.then(|| l[j] - self.length(j, p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_follow_the_model() {
        let p = LoopParams::new(1, &[[0.0, 0.0, 4.0], [3.0, 0.0, 4.0], [0.0, 4.0, 4.0]], &[0.1, 0.2, 0.0], &[[0.0; 3]; 3]);
        let mut out = [0.0; MAX_CABLES];
        p.lengths(&[0.0, 0.0, 0.0], &mut out);
        assert!((out[0] - 4.1).abs() < 1e-12);
        assert!((out[1] - 5.2).abs() < 1e-12);
        assert!((out[2] - 32f64.sqrt()).abs() < 1e-12);
    }
}
