//! Where the start-up excitation's information comes from and what bounds it, on the simulated
//! ARAS-CAM-like robot (config/examples/aras-cam-sim.toml: 30 s, tracker 1.5 mm at 100 Hz, 80 %
//! of the rows for training, encoder 0.05 mm).
//!
//! `cargo run --release -p taut-calib --example design_study`
//!
//! Prints the design's prediction for today's settings and each candidate change, and the
//! *bound*: the best worst-anchor sigma any distribution of the same number of training samples
//! over the box could give (an optimal design over a grid of points, travel ignored).

use nalgebra::DMatrix;
use taut_calib::design::{self, information, DesignInput};

fn input() -> DesignInput {
    DesignInput {
        anchors: vec![[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]],
        platform: vec![[0.0; 3]; 4],
        workspace: [[-1.75, -0.875, 1.0], [1.75, 0.875, 3.0]],
        margin_m: 0.05,
        speed_m_s: 0.8,
        accel_m_s2: 1.0,
        duration_s: 30.0,
        sample_hz: 100.0,
        used_fraction: 0.8,
        heldout_blocks: 8,
        tracker_sigma_m: 1.5e-3,
        length_sigma_m: 5e-5,
        mass_kg: 3.0,
        follower: vec![false, false, false, true],
        follower_tension_n: 10.0,
        min_tension_n: 3.0,
        max_tension_n: 500.0,
    }
}

/// Worst anchor trace of `info^-1` (m^2) and per-anchor traces.
fn traces(info: &DMatrix<f64>, n: usize) -> Option<Vec<f64>> {
    let c = info.clone().cholesky()?.inverse();
    Some((0..n).map(|j| (0..3).map(|i| c[(4 * j + i, 4 * j + i)]).sum()).collect())
}

/// Optimal weights over `pts` (one information matrix each, per sample) minimising the worst
/// anchor's trace for `samples` samples: multiplicative iterations on a p-norm of the traces.
fn optimal(infos: &[DMatrix<f64>], n: usize, samples: f64) -> (f64, Vec<f64>) {
    let k = infos.len();
    let mut w = vec![1.0 / k as f64; k];
    let dim = 4 * n;
    let mut best = f64::INFINITY;
    for it in 0..3000 {
        let mut m = DMatrix::<f64>::zeros(dim, dim);
        for (wi, ii) in w.iter().zip(infos) {
            m += ii * *wi;
        }
        let Some(ch) = m.clone().cholesky() else { break };
        let c = ch.inverse();
        let t: Vec<f64> = (0..n).map(|j| (0..3).map(|i| c[(4 * j + i, 4 * j + i)]).sum()).collect();
        let tmax = t.iter().cloned().fold(0.0, f64::max);
        best = best.min(tmax);
        let p = 8.0 + it as f64 / 50.0;
        // Selector M = sum_j (t_j / tmax)^(p-1) S_j.
        let mut sel = DMatrix::<f64>::zeros(dim, dim);
        for j in 0..n {
            for i in 0..3 {
                sel[(4 * j + i, 4 * j + i)] = (t[j] / tmax).powf(p - 1.0);
            }
        }
        let cmc = &c * &sel * &c;
        let g: Vec<f64> = infos.iter().map(|ii| (cmc.component_mul(ii)).sum()).collect();
        let gw: f64 = g.iter().zip(&w).map(|(a, b)| a * b).sum();
        for (wi, gi) in w.iter_mut().zip(&g) {
            *wi *= (gi / gw).max(0.0).sqrt();
        }
        let s: f64 = w.iter().sum();
        w.iter_mut().for_each(|x| *x /= s);
    }
    ((best / samples).sqrt(), w)
}

fn grid(lo: [f64; 3], hi: [f64; 3], m: usize) -> Vec<[f64; 3]> {
    let mut v = vec![];
    for a in 0..m {
        for b in 0..m {
            for c in 0..m {
                let f = |i: usize, k: usize| lo[i] + (hi[i] - lo[i]) * k as f64 / (m - 1) as f64;
                v.push([f(0, a), f(1, b), f(2, c)]);
            }
        }
    }
    v
}

fn main() {
    if std::env::args().any(|a| a == "knobs") {
        return study_knobs();
    }
    if std::env::args().any(|a| a == "tensions") {
        return study_tensions();
    }
    if std::env::args().any(|a| a == "paths") {
        return study_paths();
    }
    let inp = input();
    let n = inp.anchors.len();
    let d = design::design(&inp).unwrap();
    println!(
        "today: {} waypoints, period {:.1} s, predicted worst anchor {:.3} mm, per anchor {:?}",
        d.tour.n,
        d.tour.period_s(),
        d.predicted.worst_anchor_sigma_m() * 1e3,
        d.predicted.anchor_sigma.iter().map(|s| s.map(|x| (x * 1e5).round() / 100.0)).collect::<Vec<_>>()
    );
    for k in 0..d.tour.n {
        println!("  waypoint {k}: {:?}", d.tour.waypoints[k]);
    }
    let samples = (inp.duration_s * inp.sample_hz * inp.used_fraction).floor();
    let lo: [f64; 3] = std::array::from_fn(|i| inp.workspace[0][i] + inp.margin_m);
    let hi: [f64; 3] = std::array::from_fn(|i| inp.workspace[1][i] - inp.margin_m);
    for m in [2usize, 3, 5] {
        let pts = grid(lo, hi, m);
        let infos: Vec<DMatrix<f64>> = pts.iter().map(|p| information(&inp, std::iter::once(p))).collect();
        let (s, w) = optimal(&infos, n, samples);
        println!("bound, {m}^3 grid in the box (margin {} m), {samples} samples: worst anchor {:.3} mm", inp.margin_m, s * 1e3);
        let mut idx: Vec<usize> = (0..pts.len()).collect();
        idx.sort_by(|a, b| w[*b].total_cmp(&w[*a]));
        for &i in idx.iter().take(12) {
            if w[i] > 0.01 {
                println!("   {:?} weight {:.3}", pts[i], w[i]);
            }
        }
    }
    // Uniform over the 8 corners (dwelling there, no travel).
    let pts = grid(lo, hi, 2);
    let mut info = DMatrix::<f64>::zeros(4 * n, 4 * n);
    for p in &pts {
        info += information(&inp, std::iter::once(p)) * (samples / 8.0);
    }
    let t = traces(&info, n).unwrap();
    println!("8 corners, equal dwell, no travel: worst anchor {:.3} mm", t.iter().cloned().fold(0.0, f64::max).sqrt() * 1e3);
    // Without the tracker's information per sample (lengths alone pin the shape?), and with
    // the encoder noise only (no tracker at all would leave the frame free).
    for (name, ts, ls) in [("tracker 0.5 mm", 0.5e-3, 5e-5), ("tracker 3 mm", 3e-3, 5e-5), ("encoder 0.025 mm", 1.5e-3, 2.5e-5)] {
        let i2 = DesignInput { tracker_sigma_m: ts, length_sigma_m: ls, ..input() };
        let infos: Vec<DMatrix<f64>> = pts.iter().map(|p| information(&i2, std::iter::once(p))).collect();
        let (s, _) = optimal(&infos, n, samples);
        println!("bound, corners, {name}: {:.3} mm", s * 1e3);
    }
}

/// A closed path through `pts` with a hold of `dwell_s` at each, segment `k` at speed `v[k]`.
struct Path {
    pts: Vec<[f64; 3]>,
    v: Vec<f64>,
    a: f64,
    dwell_s: f64,
}

impl Path {
    fn seg(&self, k: usize) -> ([f64; 3], [f64; 3], f64, f64) {
        let (p0, p1) = (self.pts[k], self.pts[(k + 1) % self.pts.len()]);
        let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
        (p0, p1, len, design::segment_time(len, self.v[k], self.a))
    }
    fn period(&self) -> f64 {
        (0..self.pts.len()).map(|k| self.seg(k).3 + self.dwell_s).sum()
    }
    fn start_of(&self, k: usize) -> f64 {
        (0..k).map(|i| self.seg(i).3 + self.dwell_s).sum()
    }
    fn point(&self, t: f64) -> [f64; 3] {
        let mut t = t % self.period();
        for k in 0..self.pts.len() {
            let (p0, p1, len, dur) = self.seg(k);
            if t < self.dwell_s {
                return p0;
            }
            t -= self.dwell_s;
            if t <= dur {
                let s = design::segment_distance(t, len, dur, self.v[k], self.a) / len;
                return std::array::from_fn(|i| p0[i] + s * (p1[i] - p0[i]));
            }
            t -= dur;
        }
        self.pts[0]
    }
}

/// Largest cable speed per unit platform speed along the straight move `p0 -> p1`.
fn cable_gain(inp: &DesignInput, p0: &[f64; 3], p1: &[f64; 3]) -> f64 {
    let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
    let dir: [f64; 3] = std::array::from_fn(|i| (p1[i] - p0[i]) / len);
    let mut g: f64 = 0.0;
    for s in 0..=50 {
        let f = s as f64 / 50.0;
        let p: [f64; 3] = std::array::from_fn(|i| p0[i] + f * (p1[i] - p0[i]));
        for (a, b) in inp.anchors.iter().zip(&inp.platform) {
            let d: [f64; 3] = std::array::from_fn(|i| p[i] + b[i] - a[i]);
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            g = g.max(((d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2]) / l).abs());
        }
    }
    g
}

/// Worst prediction over the joins at each waypoint.
fn predict_path(inp: &DesignInput, path: &Path) -> (f64, Vec<f64>) {
    let mut worst = (0.0, vec![]);
    for k in 0..path.pts.len() {
        let t0 = path.start_of(k);
        let p = design::predict(inp, |t| path.point(t + t0)).unwrap();
        let w = p.worst_anchor_sigma_m();
        if w > worst.0 {
            worst = (w, p.anchor_sigma.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).collect());
        }
    }
    worst
}

fn study_paths() {
    let inp = input();
    let lo: [f64; 3] = std::array::from_fn(|i| inp.workspace[0][i] + inp.margin_m);
    let hi: [f64; 3] = std::array::from_fn(|i| inp.workspace[1][i] - inp.margin_m);
    let c = |x: usize, y: usize, z: usize| {
        [if x == 1 { hi[0] } else { lo[0] }, if y == 1 { hi[1] } else { lo[1] }, if z == 1 { hi[2] } else { lo[2] }]
    };
    let centre: [f64; 3] = std::array::from_fn(|i| (lo[i] + hi[i]) / 2.0);
    // The shortest cycle of the 8 corners along the box's edges.
    let ham = vec![c(0, 0, 0), c(0, 1, 0), c(0, 1, 1), c(0, 0, 1), c(1, 0, 1), c(1, 1, 1), c(1, 1, 0), c(1, 0, 0)];
    // A cycle with two space diagonals through the centre.
    let diag = vec![c(0, 0, 0), c(0, 1, 0), c(1, 0, 1), c(1, 1, 1), c(1, 1, 0), c(1, 0, 0), c(0, 1, 1), c(0, 0, 1)];
    for (name, pts) in [("edge cycle", ham.clone()), ("diagonal cycle", diag.clone())] {
        for cable_limited in [false, true] {
            for a in [1.0, 2.0] {
                for dwell in [0.0, 0.5, 1.0, 2.0] {
                    let v: Vec<f64> = (0..pts.len())
                        .map(|k| if cable_limited { 0.8 / cable_gain(&inp, &pts[k], &pts[(k + 1) % pts.len()]) } else { 0.8 })
                        .collect();
                    let path = Path { pts: pts.clone(), v: v.clone(), a, dwell_s: dwell };
                    let (w, per) = predict_path(&inp, &path);
                    println!(
                        "{name}, {} speeds {:?}, a {a}, dwell {dwell} s: period {:.1} s, worst {:.3} mm, per anchor {:?}",
                        if cable_limited { "cable-limited" } else { "0.8 m/s" },
                        v.iter().map(|x| (x * 100.0).round() / 100.0).collect::<Vec<_>>(),
                        path.period(),
                        w * 1e3,
                        per.iter().map(|x| (x * 1e5).round() / 100.0).collect::<Vec<_>>()
                    );
                }
            }
        }
    }
    let _ = centre;
}

/// Held cables' tensions at `p` (followers at their tension), N: `None` if singular.
fn tensions(inp: &DesignInput, p: &[f64; 3], acc: &[f64; 3]) -> Option<[f64; 3]> {
    use nalgebra::{Matrix3, Vector3};
    let n = inp.anchors.len();
    let held: Vec<usize> = (0..n).filter(|j| !inp.follower[*j]).collect();
    let unit = |j: usize| {
        let a = inp.anchors[j];
        let b = inp.platform[j];
        let d = Vector3::new(a[0] - p[0] - b[0], a[1] - p[1] - b[1], a[2] - p[2] - b[2]);
        d / d.norm()
    };
    let mut rhs = Vector3::new(acc[0], acc[1], acc[2] + 9.81) * inp.mass_kg;
    for j in 0..n {
        if !held.contains(&j) {
            rhs -= unit(j) * inp.follower_tension_n;
        }
    }
    let a = Matrix3::from_columns(&[unit(held[0]), unit(held[1]), unit(held[2])]);
    let t = a.try_inverse()? * rhs;
    Some([t[0], t[1], t[2]])
}

fn study_tensions() {
    let inp = input();
    let lo: [f64; 3] = std::array::from_fn(|i| inp.workspace[0][i] + inp.margin_m);
    let hi: [f64; 3] = std::array::from_fn(|i| inp.workspace[1][i] - inp.margin_m);
    for p in grid(lo, hi, 2) {
        println!("corner {p:?}: static held tensions {:?}", tensions(&inp, &p, &[0.0; 3]).unwrap().map(|x| (x * 10.0).round() / 10.0));
    }
    for ft in [10.0, 5.0, 2.0] {
        let i2 = DesignInput { follower_tension_n: ft, ..input() };
        let pts = grid(lo, hi, 9);
        let feas: Vec<[f64; 3]> =
            pts.iter().filter(|p| tensions(&i2, p, &[0.0; 3]).unwrap().iter().all(|t| *t >= i2.min_tension_n)).cloned().collect();
        let infos: Vec<DMatrix<f64>> = feas.iter().map(|p| information(&i2, std::iter::once(p))).collect();
        let (s, w) = optimal(&infos, 4, 2400.0);
        println!("follower {ft} N: {} of {} grid points statically feasible; bound {:.3} mm", feas.len(), pts.len(), s * 1e3);
        let mut idx: Vec<usize> = (0..feas.len()).collect();
        idx.sort_by(|a, b| w[*b].total_cmp(&w[*a]));
        for &i in idx.iter().take(14) {
            if w[i] > 0.01 {
                println!("   {:?} weight {:.3}", feas[i], w[i]);
            }
        }
    }
}

/// The design's prediction when one input changes.
fn study_knobs() {
    let show = |name: &str, inp: DesignInput| match design::design(&inp) {
        Ok(d) => println!(
            "{name}: {} waypoints, period {:.1} s, worst anchor {:.3} mm",
            d.tour.n,
            d.tour.period_s(),
            d.predicted.worst_anchor_sigma_m() * 1e3
        ),
        Err(e) => println!("{name}: {e}"),
    };
    show("today (0.8 m/s, 1 m/s^2, margin 5 cm, 80 % training)", input());
    for v in [0.4, 0.6, 1.0] {
        show(&format!("speed {v} m/s"), DesignInput { speed_m_s: v, ..input() });
    }
    for a in [0.5, 2.0, 4.0] {
        show(&format!("acceleration {a} m/s^2"), DesignInput { accel_m_s2: a, ..input() });
    }
    for m in [0.0, 0.15] {
        show(&format!("margin {m} m"), DesignInput { margin_m: m, ..input() });
    }
    for f in [0.9, 1.0] {
        show(&format!("training fraction {f}"), DesignInput { used_fraction: f, ..input() });
    }
    for ft in [5.0, 20.0] {
        show(&format!("follower tension {ft} N"), DesignInput { follower_tension_n: ft, ..input() });
    }
    show("no tension check", DesignInput { mass_kg: 0.0, ..input() });
    show("tracker 200 Hz", DesignInput { sample_hz: 200.0, ..input() });
    show("60 s", DesignInput { duration_s: 60.0, ..input() });
}
