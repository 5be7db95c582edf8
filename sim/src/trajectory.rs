//! Excitation trajectories: smooth motion through the workspace below the anchors, with
//! excursions towards its edge where cables go loose.
//!
//! * The **workspace** is the horizontal convex hull of the anchors, below the lowest one. The
//!   base motion stays in an axis-aligned ellipse inscribed in the hull (scaled by 0.75), heights
//!   in [0.2, 0.65] x the lowest anchor height.
//! * The **base motion** is a sum of three sinusoids per axis (periods 8-45 s, slow enough that
//!   no cable goes loose), mapped from the square to the ellipse by a smooth square-to-disk map,
//!   and blended in from the start (the centre, or where the three-phase motion ended) over the
//!   first 5 s.
//! * An **excursion** blends (minimum-jerk, 2.5 s) to a point 10-25 % of the inscribed radius
//!   inside a hull edge, low in the workspace, and oscillates there along the edge normal with a
//!   peak acceleration of 2.5-4.5 m/s^2: while it accelerates outwards, the cables on the far side
//!   cannot hold their share and go loose (as where the paper's robot "could not follow").
//!
//! The number of loose samples grows with the excursions' duration, which
//! [`crate::scenario`] tunes by bisection to reach the requested fraction.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The horizontal hull of the anchors and the heights below them.
#[derive(Debug, Clone, PartialEq)]
pub struct Workspace {
    /// Centre (mean of the anchors), horizontal, m.
    pub center: [f64; 2],
    /// Semi-axes of the axis-aligned ellipse inscribed in the hull, m.
    pub semi: [f64; 2],
    /// Hull edges, counter-clockwise: start, end, outward unit normal.
    pub edges: Vec<([f64; 2], [f64; 2], [f64; 2])>,
    /// Height of the lowest anchor, m.
    pub z_top: f64,
}

impl Workspace {
    /// The workspace of these anchors (at least three not on a line).
    pub fn from_anchors(anchors: &[[f64; 3]]) -> Workspace {
        let n = anchors.len() as f64;
        let center = [anchors.iter().map(|a| a[0]).sum::<f64>() / n, anchors.iter().map(|a| a[1]).sum::<f64>() / n];
        let z_top = anchors.iter().map(|a| a[2]).fold(f64::INFINITY, f64::min);
        // Gift wrapping, counter-clockwise, from the lowest-x point.
        let pts: Vec<[f64; 2]> = anchors.iter().map(|a| [a[0], a[1]]).collect();
        let start = (0..pts.len()).min_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]).then(pts[a][1].total_cmp(&pts[b][1]))).unwrap();
        let mut hull = vec![start];
        loop {
            let cur = *hull.last().unwrap();
            let mut next = (cur + 1) % pts.len();
            for k in 0..pts.len() {
                let cross =
                    (pts[next][0] - pts[cur][0]) * (pts[k][1] - pts[cur][1]) - (pts[next][1] - pts[cur][1]) * (pts[k][0] - pts[cur][0]);
                if cross < 0.0 {
                    next = k;
                }
            }
            if next == start || hull.len() > pts.len() {
                break;
            }
            hull.push(next);
        }
        let edges: Vec<_> = (0..hull.len())
            .map(|i| {
                let (a, b) = (pts[hull[i]], pts[hull[(i + 1) % hull.len()]]);
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let l = dx.hypot(dy);
                (a, b, [dy / l, -dx / l])
            })
            .collect();
        // Ellipse with the hull's bounding-box aspect, as large as fits every edge:
        // max over the ellipse of n.(x - c) = sqrt((n_x a_x)^2 + (n_y a_y)^2) <= distance.
        let (xs, ys) = (pts.iter().map(|p| p[0]), pts.iter().map(|p| p[1]));
        let wx = xs.clone().fold(f64::NEG_INFINITY, f64::max) - xs.fold(f64::INFINITY, f64::min);
        let wy = ys.clone().fold(f64::NEG_INFINITY, f64::max) - ys.fold(f64::INFINITY, f64::min);
        let mut s = f64::INFINITY;
        for (a, _, nrm) in &edges {
            let d = nrm[0] * (a[0] - center[0]) + nrm[1] * (a[1] - center[1]);
            s = s.min(d / (nrm[0] * wx).hypot(nrm[1] * wy));
        }
        Workspace { center, semi: [s * wx, s * wy], edges, z_top }
    }

    /// The central position the motions start from, m.
    pub fn center_point(&self) -> [f64; 3] {
        [self.center[0], self.center[1], 0.425 * self.z_top]
    }

    /// Smaller semi-axis, m.
    pub fn radius(&self) -> f64 {
        self.semi[0].min(self.semi[1])
    }
}

/// Minimum-jerk blend 0 -> 1 over [0, 1], clamped outside.
fn blend(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Wave {
    amp: f64,
    omega: f64,
    phase: f64,
}

impl Wave {
    fn at(&self, t: f64) -> f64 {
        self.amp * (self.omega * t + self.phase).sin()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Excursion {
    t_mid: f64,
    target: [f64; 3],
    normal: [f64; 2],
    osc: Wave,
}

/// A seeded excitation trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Excitation {
    ws: Workspace,
    base: [[Wave; 3]; 3],
    tilt: [Wave; 3],
    excursions: Vec<Excursion>,
    excursion_s: f64,
    slot_s: f64,
    duration_s: f64,
    start: [f64; 3],
    accel_scale: f64,
}

/// Time to blend in from the centre at the start, s.
const START_RAMP_S: f64 = 5.0;
/// Blend into and out of an excursion, s.
const EXCURSION_RAMP_S: f64 = 2.5;

impl Excitation {
    /// Draws a trajectory of `duration_s` in `ws`; excursions are off until
    /// [`Excitation::set_excursion_duration`].
    pub fn new(ws: &Workspace, duration_s: f64, rng: &mut ChaCha8Rng) -> Self {
        let tau = std::f64::consts::TAU;
        let mut wave =
            |amp: f64, period: (f64, f64)| Wave { amp, omega: tau / rng.gen_range(period.0..period.1), phase: rng.gen_range(0.0..tau) };
        // Sum of amplitudes 1 per axis: the normalised coordinate stays in [-1, 1].
        let base = std::array::from_fn(|_| [wave(0.65, (25.0, 45.0)), wave(0.28, (14.0, 22.0)), wave(0.07, (8.0, 12.0))]);
        let deg = std::f64::consts::PI / 180.0;
        let tilt = [wave(2.0 * deg, (15.0, 40.0)), wave(2.0 * deg, (15.0, 40.0)), wave(4.0 * deg, (20.0, 50.0))];
        let active = (duration_s - START_RAMP_S).max(0.0);
        let k = ((active / 20.0).round() as usize).max(1);
        let slot_s = active / k as f64;
        let r = ws.radius();
        let excursions = (0..k)
            .map(|i| {
                let jitter = rng.gen_range(-0.1..0.1) * slot_s;
                let (a, b, normal) = ws.edges[rng.gen_range(0..ws.edges.len())];
                let lambda = rng.gen_range(0.25..0.75);
                let inset = rng.gen_range(0.06..0.14) * r;
                let z = rng.gen_range(0.2..0.45) * ws.z_top;
                let target = [a[0] + lambda * (b[0] - a[0]) - inset * normal[0], a[1] + lambda * (b[1] - a[1]) - inset * normal[1], z];
                let amp = 0.6 * inset;
                let peak_acc = rng.gen_range(2.5..4.5);
                Excursion {
                    t_mid: START_RAMP_S + (i as f64 + 0.5) * slot_s + jitter,
                    target,
                    normal,
                    osc: Wave { amp, omega: (peak_acc / amp).sqrt(), phase: 0.0 },
                }
            })
            .collect();
        Excitation {
            ws: ws.clone(),
            base,
            tilt,
            excursions,
            excursion_s: 0.0,
            slot_s,
            duration_s,
            start: ws.center_point(),
            accel_scale: 1.0,
        }
    }

    /// Starts the motion (at rest) from `p` instead of the workspace centre.
    pub fn set_start(&mut self, p: [f64; 3]) {
        self.start = p;
    }

    /// Sets how long each excursion lasts, s (0: none); capped to 80 % of its time slot.
    pub fn set_excursion_duration(&mut self, d: f64) {
        self.excursion_s = d.clamp(0.0, 0.8 * self.slot_s);
    }

    /// Scales the excursions' peak accelerations (1: as drawn, 2.5-4.5 m/s^2; the amplitude is
    /// kept, the frequency grows with the square root).
    pub fn set_accel_scale(&mut self, k: f64) {
        self.accel_scale = k.max(0.0);
    }

    /// The longest excursion duration allowed, s.
    pub fn max_excursion_duration(&self) -> f64 {
        0.8 * self.slot_s
    }

    /// Duration of the trajectory, s.
    pub fn duration(&self) -> f64 {
        self.duration_s
    }

    fn base(&self, t: f64) -> [f64; 3] {
        let u: [f64; 3] = std::array::from_fn(|k| self.base[k].iter().map(|w| w.at(t)).sum::<f64>());
        // Square -> disk, smooth: (x sqrt(1 - y^2/2), y sqrt(1 - x^2/2)).
        let dx = u[0] * (1.0 - 0.5 * u[1] * u[1]).sqrt();
        let dy = u[1] * (1.0 - 0.5 * u[0] * u[0]).sqrt();
        let c = self.ws.center_point();
        let s = 0.75;
        let p = [
            self.ws.center[0] + s * self.ws.semi[0] * dx,
            self.ws.center[1] + s * self.ws.semi[1] * dy,
            c[2] + 0.225 * self.ws.z_top * u[2],
        ];
        let r = blend(t / START_RAMP_S);
        std::array::from_fn(|k| self.start[k] + r * (p[k] - self.start[k]))
    }

    /// Platform position at `t`, m.
    pub fn position(&self, t: f64) -> [f64; 3] {
        let mut p = self.base(t);
        if self.excursion_s <= 0.0 {
            return p;
        }
        let d = self.excursion_s;
        let ramp = EXCURSION_RAMP_S.min(d / 3.0);
        for e in &self.excursions {
            let t0 = e.t_mid - 0.5 * d;
            if t < t0 || t > t0 + d {
                continue;
            }
            let w = blend((t - t0) / ramp).min(blend((t0 + d - t) / ramp));
            let o = e.osc.amp * (e.osc.omega * self.accel_scale.sqrt() * (t - t0)).sin();
            let goal = [e.target[0] + o * e.normal[0], e.target[1] + o * e.normal[1], e.target[2]];
            for k in 0..3 {
                p[k] += w * (goal[k] - p[k]);
            }
        }
        p
    }

    /// Platform acceleration at `t` (central differences of the smooth path), m/s^2.
    pub fn acceleration(&self, t: f64) -> [f64; 3] {
        let h = 1e-3;
        let (a, b, c) = (self.position(t - h), self.position(t), self.position(t + h));
        std::array::from_fn(|k| (a[k] - 2.0 * b[k] + c[k]) / (h * h))
    }

    /// Platform orientation at `t`: small slow tilts (roll, pitch 2 deg, yaw 4 deg), unit
    /// quaternion (w, x, y, z).
    pub fn orientation(&self, t: f64) -> [f64; 4] {
        let r = blend(t / START_RAMP_S);
        let [roll, pitch, yaw] = std::array::from_fn(|k| r * self.tilt[k].at(t));
        let (cr, sr) = ((0.5 * roll).cos(), (0.5 * roll).sin());
        let (cp, sp) = ((0.5 * pitch).cos(), (0.5 * pitch).sin());
        let (cy, sy) = ((0.5 * yaw).cos(), (0.5 * yaw).sin());
        [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]
    }
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
pub fn rotation(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// `r b`.
pub fn rotate(r: &[[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * b[0] + r[i][1] * b[1] + r[i][2] * b[2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn workspace_of_a_rectangle_and_a_triangle() {
        let ws = Workspace::from_anchors(&[[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]]);
        assert_eq!(ws.edges.len(), 4);
        assert!((ws.semi[0] - 3.5).abs() < 1e-9 && (ws.semi[1] - 1.75).abs() < 1e-9, "{:?}", ws.semi);
        let tri = Workspace::from_anchors(&[[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]]);
        assert_eq!(tri.edges.len(), 3);
        // The inscribed ellipse touches but does not cross the edges.
        for (a, _, n) in &tri.edges {
            let d = n[0] * (a[0] - tri.center[0]) + n[1] * (a[1] - tri.center[1]);
            assert!((n[0] * tri.semi[0]).hypot(n[1] * tri.semi[1]) <= d + 1e-12);
        }
    }

    #[test]
    fn base_motion_stays_inside_and_is_smooth() {
        let ws = Workspace::from_anchors(&[[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]]);
        let ex = Excitation::new(&ws, 120.0, &mut ChaCha8Rng::seed_from_u64(3));
        let mut t = 0.0;
        while t < 120.0 {
            let p = ex.position(t);
            for (a, _, n) in &ws.edges {
                assert!(n[0] * (p[0] - a[0]) + n[1] * (p[1] - a[1]) < 0.0, "outside at {t}");
            }
            assert!(p[2] > 0.15 * ws.z_top && p[2] < 0.7 * ws.z_top);
            let a = ex.acceleration(t);
            assert!((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt() < 0.5, "{a:?} at {t}");
            t += 0.37;
        }
    }
}
