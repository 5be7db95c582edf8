//! A piecewise-straight excitation path, fixed size and `Copy`: designed by `taut-calib`'s
//! `design` (non-real-time, at configure time) and evaluated by the loop (`taut-rt`) every
//! cycle without allocation.

/// Most waypoints of a tour.
pub const MAX_WAYPOINTS: usize = 32;

/// A piecewise-straight path through waypoints, each segment driven with a trapezoidal speed
/// profile (rest at every waypoint), repeated cyclically after the last waypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tour {
    /// Waypoints, m (the first `n` are used).
    pub waypoints: [[f64; 3]; MAX_WAYPOINTS],
    /// Number of waypoints (at least 2).
    pub n: usize,
    /// Cruise speed, m/s.
    pub speed_m_s: f64,
    /// Acceleration and deceleration, m/s^2.
    pub accel_m_s2: f64,
}

/// Duration of a straight move of length `len` with the trapezoidal profile, s.
pub fn segment_time(len: f64, v: f64, a: f64) -> f64 {
    if len <= v * v / a {
        2.0 * (len / a).sqrt()
    } else {
        len / v + v / a
    }
}

/// Distance covered after `t` on a move of length `len` (duration `dur`), m.
pub fn segment_distance(t: f64, len: f64, dur: f64, v: f64, a: f64) -> f64 {
    let t = t.clamp(0.0, dur);
    let ta = (v / a).min(dur / 2.0);
    let vp = a * ta;
    if t < ta {
        0.5 * a * t * t
    } else if t > dur - ta {
        len - 0.5 * a * (dur - t) * (dur - t)
    } else {
        0.5 * a * ta * ta + vp * (t - ta)
    }
}

impl Tour {
    /// The first waypoint (where the path starts), m.
    pub fn start(&self) -> [f64; 3] {
        self.waypoints[0]
    }

    fn seg(&self, k: usize) -> ([f64; 3], [f64; 3], f64) {
        let p0 = self.waypoints[k % self.n];
        let p1 = self.waypoints[(k + 1) % self.n];
        let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
        (p0, p1, len)
    }

    /// The waypoint nearest `p` and the time the tour reaches it, s (the tour repeats: it may
    /// be started there, `point(t + time)`, and still covers the same loop). No allocation.
    pub fn nearest_waypoint(&self, p: &[f64; 3]) -> (usize, f64) {
        let (mut best, mut best_d, mut best_t, mut t) = (0, f64::INFINITY, 0.0, 0.0);
        for k in 0..self.n {
            let w = self.waypoints[k];
            let d = (w[0] - p[0]).powi(2) + (w[1] - p[1]).powi(2) + (w[2] - p[2]).powi(2);
            if d < best_d {
                (best, best_d, best_t) = (k, d, t);
            }
            t += segment_time(self.seg(k).2, self.speed_m_s, self.accel_m_s2);
        }
        (best, best_t)
    }

    /// Time of one pass through all waypoints and back to the first, s.
    pub fn period_s(&self) -> f64 {
        (0..self.n).map(|k| segment_time(self.seg(k).2, self.speed_m_s, self.accel_m_s2)).sum()
    }

    /// Position at time `t` after the start, m. No allocation; at most `n` segments are scanned.
    pub fn point(&self, t: f64) -> [f64; 3] {
        let period = self.period_s();
        let mut t = if period > 0.0 && t > 0.0 { t % period } else { 0.0 };
        for k in 0..self.n {
            let (p0, p1, len) = self.seg(k);
            let dur = segment_time(len, self.speed_m_s, self.accel_m_s2);
            if t <= dur || k + 1 == self.n {
                if len <= 0.0 {
                    return p0;
                }
                let s = segment_distance(t, len, dur, self.speed_m_s, self.accel_m_s2) / len;
                return std::array::from_fn(|i| p0[i] + s * (p1[i] - p0[i]));
            }
            t -= dur;
        }
        self.waypoints[0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joining_at_the_nearest_waypoint_continues_the_same_loop() {
        let mut t = Tour { waypoints: [[0.0; 3]; MAX_WAYPOINTS], n: 4, speed_m_s: 0.8, accel_m_s2: 1.0 };
        t.waypoints[..4].copy_from_slice(&[[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [2.0, 1.0, 2.0], [0.0, 1.0, 2.0]]);
        let (k, t0) = t.nearest_waypoint(&[1.9, 1.1, 1.8]);
        assert_eq!(k, 2);
        assert!((t0 - segment_time(2.0, 0.8, 1.0) - segment_time(2f64.sqrt(), 0.8, 1.0)).abs() < 1e-12);
        let p = t.point(t0);
        assert!((0..3).all(|i| (p[i] - t.waypoints[2][i]).abs() < 1e-9), "{p:?}");
        // One period later it is there again.
        let q = t.point(t0 + t.period_s());
        assert!((0..3).all(|i| (q[i] - p[i]).abs() < 1e-9), "{q:?}");
    }
}
