//! Deterministic synthetic recordings with a known truth, for tests, benchmarks and examples.
//!
//! The generator is the noise model of [`crate::noise`] run forwards: tracker positions with
//! isotropic Gaussian noise (and rare gross outliers), encoder readings with Gaussian noise,
//! loose cables that read long by a slack of several cm at a tension below the threshold, and an
//! elastic stretch either drawn as a Gaussian of one-sigma `T rho / EA` (what the calibration
//! assumes), applied physically (the encoder counts unstretched cable), or left out. A seeded
//! xoshiro256** generator makes every recording reproducible without external crates.

use crate::model;
use crate::Params;
use taut_config::recording::Recording;

/// xoshiro256** seeded through splitmix64: small, fast, reproducible across platforms.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        let mut z = seed;
        let mut next = || {
            z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut x = z;
            x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            x ^ (x >> 31)
        };
        Rng { s: [next(), next(), next(), next()] }
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let out = s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        out
    }

    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[a, b)`.
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// Uniform on the unit sphere.
    pub fn unit_vector(&mut self) -> [f64; 3] {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, 2.0 * std::f64::consts::PI);
        let s = (1.0 - z * z).sqrt();
        [s * phi.cos(), s * phi.sin(), z]
    }
}

/// How the elastic stretch of a taut cable shows in the encoder reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stretch {
    /// No stretch (rigid cables).
    None,
    /// A zero-mean Gaussian error of one-sigma `T rho / EA`: exactly the calibration's noise model.
    Gaussian,
    /// Physical: the encoder counts unstretched cable, `l = rho EA / (EA + T) + L0`.
    Physical,
}

/// What a synthetic recording looks like.
#[derive(Debug, Clone)]
pub struct Spec {
    /// The true parameters.
    pub truth: Params,
    /// Platform attachment points `b_j`.
    pub platform_points: Vec<[f64; 3]>,
    /// Largest random platform tilt, degrees; 0 writes no orientation columns.
    pub tilt_deg: f64,
    /// Tracker noise, 1-sigma per axis, m.
    pub tracker_sigma_m: f64,
    /// Per-axis factors on `tracker_sigma_m` (an anisotropic tracker, e.g. worse in depth).
    pub tracker_axis_scale: [f64; 3],
    /// Probability of a gross tracker outlier per sample.
    pub outlier_prob: f64,
    /// Size of a gross tracker outlier (random direction), m.
    pub outlier_m: f64,
    /// Encoder noise, 1-sigma, m.
    pub encoder_sigma_m: f64,
    /// Cable stiffness EA, N.
    pub cable_ea_n: f64,
    /// Stretch model.
    pub stretch: Stretch,
    /// Probability that a reading is of a loose cable.
    pub loose_fraction: f64,
    /// Slack of a loose reading, m (uniform in the range); the encoder reads long by this.
    pub slack_m: (f64, f64),
    /// Tension of a loose reading, N (uniform).
    pub loose_tension_n: (f64, f64),
    /// Tension of a taut reading, N (uniform).
    pub taut_tension_n: (f64, f64),
    /// Write tension columns.
    pub tensions: bool,
    /// Sample rate, Hz.
    pub rate_hz: f64,
}

impl Spec {
    /// A point-mass robot with the project's default noise (1.5 mm tracker, 0.05 mm encoder,
    /// EA 2e5 N, Gaussian stretch), no loose readings, no outliers, tensions recorded.
    pub fn new(truth: Params) -> Self {
        let n = truth.n_cables();
        Spec {
            truth,
            platform_points: vec![[0.0; 3]; n],
            tilt_deg: 0.0,
            tracker_sigma_m: 1.5e-3,
            tracker_axis_scale: [1.0; 3],
            outlier_prob: 0.0,
            outlier_m: 0.05,
            encoder_sigma_m: 0.05e-3,
            cable_ea_n: 2.0e5,
            stretch: Stretch::Gaussian,
            loose_fraction: 0.0,
            slack_m: (0.02, 0.08),
            loose_tension_n: (0.0, 2.0),
            taut_tension_n: (5.0, 60.0),
            tensions: true,
            rate_hz: 100.0,
        }
    }
}

/// An ARAS-CAM-like truth: four anchors near the top corners of a 7 m x 3.5 m x 4 m frame (a few
/// cm off the nominal ones, as built) and arbitrary encoder offsets.
pub fn aras_cam() -> Params {
    Params {
        anchors: vec![[3.512, -1.738, 3.987], [3.493, 1.761, 4.012], [-3.506, 1.744, 3.995], [-3.489, -1.757, 4.021]],
        l0: vec![0.812, -0.334, 1.207, 0.058],
    }
}

/// A small three-cable truth: anchors on a 2 m triangle, 3 m up.
pub fn tri3() -> Params {
    Params { anchors: vec![[2.01, 0.02, 3.0], [-0.98, 1.74, 2.97], [-1.03, -1.72, 3.02]], l0: vec![0.35, -0.12, 0.61] }
}

/// The benchmark recording: `n` samples x 4 cables of [`aras_cam`] in a 5 m x 2.5 m x 2 m box
/// (1.5 mm tracker noise, 0.2% tracker outliers of 5 cm, 5% loose readings, tensions), and the
/// initial guess every solver starts from (the truth moved by 5-10 cm per coordinate, as after a
/// multilateration on a short recording or a tape-measured set-up).
pub fn bench_recording(n: usize) -> (Recording, Params) {
    let truth = aras_cam();
    let mut spec = Spec::new(truth.clone());
    spec.loose_fraction = 0.05;
    spec.outlier_prob = 0.002;
    let rec = box_recording(&spec, n, [-2.5, -1.25, 0.5], [2.5, 1.25, 2.5], 2024);
    let mut init = truth;
    for (j, a) in init.anchors.iter_mut().enumerate() {
        let s = if j % 2 == 0 { 1.0 } else { -1.0 };
        a[0] += 0.08 * s;
        a[1] -= 0.05 * s;
        a[2] += 0.06;
        init.l0[j] -= 0.07;
    }
    (rec, init)
}

/// A random rotation of at most `max_deg` degrees.
fn random_rotation(rng: &mut Rng, max_deg: f64) -> [f64; 4] {
    let axis = rng.unit_vector();
    let angle = rng.range(0.0, max_deg.to_radians());
    let s = (angle / 2.0).sin();
    [(angle / 2.0).cos(), axis[0] * s, axis[1] * s, axis[2] * s]
}

/// Generates one sample at true pose `(p, q)`; `taut_tension` overrides the taut tension range
/// and `force_taut` the loose draw per cable (used by the three-phase generator for held cables).
struct SampleGen<'a> {
    spec: &'a Spec,
    rng: Rng,
    l: Vec<f64>,
    f: Vec<f64>,
}

impl SampleGen<'_> {
    fn sample(&mut self, rec: &mut Recording, t: f64, p: [f64; 3], phase: Option<i32>, taut: &dyn Fn(usize) -> Option<(f64, f64)>) {
        let s = self.spec;
        let n = s.truth.n_cables();
        let q = (s.tilt_deg > 0.0).then(|| random_rotation(&mut self.rng, s.tilt_deg));
        let r = q.and_then(model::rotation);
        self.l.clear();
        self.f.clear();
        for j in 0..n {
            let x = model::attachment(p, r.as_ref(), s.platform_points[j]);
            let rho = model::norm(model::sub(x, s.truth.anchors[j]));
            let forced = taut(j);
            let loose = forced.is_none() && self.rng.uniform() < s.loose_fraction;
            let (tension, slack) = if loose {
                (self.rng.range(s.loose_tension_n.0, s.loose_tension_n.1), self.rng.range(s.slack_m.0, s.slack_m.1))
            } else {
                let (a, b) = forced.unwrap_or(s.taut_tension_n);
                (self.rng.range(a, b), 0.0)
            };
            let stretch = match s.stretch {
                Stretch::None => 0.0,
                Stretch::Gaussian if !loose => self.rng.normal() * tension * rho / s.cable_ea_n,
                Stretch::Physical if !loose => -rho * tension / (s.cable_ea_n + tension),
                _ => 0.0,
            };
            self.l.push(rho + s.truth.l0[j] + slack + stretch + s.encoder_sigma_m * self.rng.normal());
            self.f.push(tension);
        }
        let mut pm = [0.0; 3];
        for k in 0..3 {
            pm[k] = p[k] + s.tracker_sigma_m * s.tracker_axis_scale[k] * self.rng.normal();
        }
        if self.rng.uniform() < s.outlier_prob {
            let d = self.rng.unit_vector();
            for k in 0..3 {
                pm[k] += s.outlier_m * d[k];
            }
        }
        rec.push(t, pm, q, &self.l, s.tensions.then_some(&self.f[..]), phase);
    }
}

/// `n` samples at uniformly random positions in the box `lo..hi` (time order = draw order).
pub fn box_recording(spec: &Spec, n: usize, lo: [f64; 3], hi: [f64; 3], seed: u64) -> Recording {
    let nc = spec.truth.n_cables();
    let mut rec = Recording::with_capacity(nc, n, spec.tensions, spec.tilt_deg > 0.0, false);
    rec.comments.push(format!(" synthetic: {n} samples in a box, seed {seed}"));
    let mut g = SampleGen { spec, rng: Rng::new(seed), l: Vec::with_capacity(nc), f: Vec::with_capacity(nc) };
    for i in 0..n {
        let p = [g.rng.range(lo[0], hi[0]), g.rng.range(lo[1], hi[1]), g.rng.range(lo[2], hi[2])];
        g.sample(&mut rec, i as f64 / spec.rate_hz, p, None, &|_| None);
    }
    rec
}

/// One phase of the three-phase initialisation experiment.
#[derive(Debug, Clone, Copy)]
pub struct PhaseSpec {
    /// The two cables held at fixed length.
    pub held: [usize; 2],
    /// The cable that is reeled in.
    pub reeled: usize,
    /// Where the platform starts (sets the held lengths).
    pub start: [f64; 3],
    /// Arc length travelled, m.
    pub arc_m: f64,
}

/// The circle on which a point mass held by cables of lengths `|start - a1|` and `|start - a2|`
/// from anchors `a1`, `a2` moves: `(centre, unit normal a1 -> a2, radius)`.
pub fn held_circle(a1: [f64; 3], a2: [f64; 3], start: [f64; 3]) -> ([f64; 3], [f64; 3], f64) {
    let r1 = model::norm(model::sub(start, a1));
    let r2 = model::norm(model::sub(start, a2));
    let d = model::norm(model::sub(a2, a1));
    let n = model::sub(a2, a1).map(|v| v / d);
    let a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d);
    let c = [a1[0] + a * n[0], a1[1] + a * n[1], a1[2] + a * n[2]];
    (c, n, (r1 * r1 - a * a).max(0.0).sqrt())
}

/// A three-phase recording: in each phase the platform moves on the circle where the spheres
/// around the two held anchors intersect, away from its start in the direction that shortens the
/// reeled cable; held cables are taut (20-40 N), the reeled one taut, the others follow at low
/// tension (4-8 N). Phase column = phase index. Point-mass platform.
pub fn three_phase_recording(spec: &Spec, phases: &[PhaseSpec], n_per_phase: usize, seed: u64) -> Recording {
    let nc = spec.truth.n_cables();
    let mut rec = Recording::with_capacity(nc, n_per_phase * phases.len(), spec.tensions, spec.tilt_deg > 0.0, true);
    rec.comments.push(format!(" synthetic three-phase experiment, seed {seed}"));
    let mut g = SampleGen { spec, rng: Rng::new(seed), l: Vec::with_capacity(nc), f: Vec::with_capacity(nc) };
    let a = &spec.truth.anchors;
    let mut t = 0.0;
    for (k, ph) in phases.iter().enumerate() {
        let (c, n, r) = held_circle(a[ph.held[0]], a[ph.held[1]], ph.start);
        let e1 = model::sub(ph.start, c).map(|v| v / r);
        let e2 = model::cross(n, e1);
        let at = |phi: f64| -> [f64; 3] { std::array::from_fn(|i| c[i] + r * (phi.cos() * e1[i] + phi.sin() * e2[i])) };
        let dist = |p: [f64; 3]| model::norm(model::sub(p, a[ph.reeled]));
        let sign = if dist(at(1e-3)) < dist(at(-1e-3)) { 1.0 } else { -1.0 };
        let span = ph.arc_m / r;
        for i in 0..n_per_phase {
            let phi = sign * span * i as f64 / (n_per_phase - 1).max(1) as f64;
            let held = ph.held;
            let reeled = ph.reeled;
            g.sample(&mut rec, t, at(phi), Some(k as i32), &|j| {
                if held.contains(&j) {
                    Some((20.0, 40.0))
                } else if j == reeled {
                    Some((10.0, 30.0))
                } else {
                    Some((4.0, 8.0))
                }
            });
            t += 1.0 / spec.rate_hz;
        }
    }
    rec
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_has_unit_variance() {
        let mut r = Rng::new(7);
        let n = 100_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        // Standard errors: mean 1/sqrt(n) = 0.003, variance sqrt(2/n) = 0.0045.
        assert!(mean.abs() < 0.015, "{mean}");
        assert!((var - 1.0).abs() < 0.025, "{var}");
    }

    #[test]
    fn held_circle_lies_on_both_spheres() {
        let t = aras_cam();
        let start = [0.3, -0.2, 1.0];
        let (c, n, r) = held_circle(t.anchors[0], t.anchors[1], start);
        let e1 = model::sub(start, c).map(|v| v / r);
        let e2 = model::cross(n, e1);
        for phi in [0.0, 0.3, -0.5] {
            let p: [f64; 3] = std::array::from_fn(|i| c[i] + r * (f64::cos(phi) * e1[i] + f64::sin(phi) * e2[i]));
            for h in 0..2 {
                let d0 = model::norm(model::sub(start, t.anchors[h]));
                assert!((model::norm(model::sub(p, t.anchors[h])) - d0).abs() < 1e-12);
            }
        }
    }
}
