//! Whether a calibrated parameter set may become the robot's parameters: every number finite
//! (a NaN or infinite sigma or RMS says the statistics broke down, whatever the anchors look
//! like), and every anchor inside a plausible envelope. Used by `taut calibrate` before it
//! writes anything and by the daemon's calibration backend before it offers a set.
//!
//! The envelope: an anchor no more than [`crate::screen::ABSURD_M`] (1 km) from the centroid
//! of the tracked positions (the largest cable robot built spans 600 m), and, when the
//! configuration gives nominal anchors, no more than `max_from_nominal_m` from its nominal one.

use crate::{CalibReport, Geometry, Sigmas};
use std::fmt;
use taut_config::recording::Recording;

/// Why a parameter set is refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Untrusted {
    /// A value that must be a finite number is not.
    NonFinite {
        /// Cable, when the value belongs to one.
        cable: Option<usize>,
        /// Which value.
        what: &'static str,
    },
    /// An anchor absurdly far from everything the tracker saw.
    AnchorAbsurd {
        /// Cable.
        cable: usize,
        /// Distance from the centroid of the tracked positions, m.
        distance_m: f64,
        /// The limit, m.
        limit_m: f64,
    },
    /// An anchor far from the configuration's nominal one.
    FarFromNominal {
        /// Cable.
        cable: usize,
        /// Distance from the nominal anchor, m.
        distance_m: f64,
        /// The limit, m.
        limit_m: f64,
    },
    /// No tracked position to judge the anchors against.
    NoPositions,
}

impl fmt::Display for Untrusted {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Untrusted::NonFinite { cable: Some(j), what } => {
                write!(f, "cable {}: the {what} is not a finite number; the calibration cannot be trusted (look for data problems above, or record again)", j + 1)
            }
            Untrusted::NonFinite { cable: None, what } => {
                write!(f, "the {what} is not a finite number; the calibration cannot be trusted (look for data problems above, or record again)")
            }
            Untrusted::AnchorAbsurd { cable, distance_m, limit_m } => write!(
                f,
                "cable {}: the anchor came out {distance_m:.3e} m from the tracked positions (more than {limit_m:.0} m): not a cable robot; check that the tracker and encoder columns belong together", cable + 1
            ),
            Untrusted::FarFromNominal { cable, distance_m, limit_m } => write!(
                f,
                "cable {}: the anchor came out {distance_m:.3} m from the nominal anchor of the configuration (more than {limit_m:.3} m = 2 x daemon.max_anchor_change_m); check the recording, or correct cable[{cable}].anchor", cable + 1
            ),
            Untrusted::NoPositions => write!(f, "the recording has no tracked position to judge the anchors against"),
        }
    }
}

impl std::error::Error for Untrusted {}

/// A parameter set with its uncertainty, as [`check`] judges it.
#[derive(Debug, Clone, Copy)]
pub struct Candidate<'a> {
    /// Anchors and encoder offsets, m.
    pub params: &'a Geometry,
    /// 1-sigma of the anchors and offsets, m.
    pub sigma: &'a Sigmas,
    /// Co-registration RMS, m.
    pub rms_m: f64,
}

impl<'a> Candidate<'a> {
    /// The parameters and uncertainty of a calibration report.
    pub fn of(r: &'a CalibReport) -> Self {
        Candidate { params: &r.params, sigma: &r.sigma, rms_m: r.rms_m }
    }
}

/// Checks `c` against the positions of `rec` and, if given, the nominal anchors with the
/// largest plausible distance from them.
pub fn check(c: &Candidate, rec: &Recording, nominal: Option<(&[[f64; 3]], f64)>) -> Result<(), Untrusted> {
    for (j, a) in c.params.anchors.iter().enumerate() {
        if !a.iter().all(|v| v.is_finite()) {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "anchor" });
        }
    }
    for (j, v) in c.params.l0.iter().enumerate() {
        if !v.is_finite() {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "encoder offset" });
        }
    }
    for (j, s) in c.sigma.anchors.iter().enumerate() {
        if !s.iter().all(|v| v.is_finite()) {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "anchor 1-sigma" });
        }
    }
    for (j, v) in c.sigma.l0.iter().enumerate() {
        if !v.is_finite() {
            return Err(Untrusted::NonFinite { cable: Some(j), what: "encoder offset 1-sigma" });
        }
    }
    if !c.rms_m.is_finite() {
        return Err(Untrusted::NonFinite { cable: None, what: "co-registration RMS" });
    }
    let (mut sum, mut cnt) = ([0.0; 3], 0usize);
    for p in &rec.p {
        if p.iter().all(|v| v.is_finite() && v.abs() <= crate::screen::ABSURD_M) {
            for k in 0..3 {
                sum[k] += p[k];
            }
            cnt += 1;
        }
    }
    if cnt == 0 {
        return Err(Untrusted::NoPositions);
    }
    let centroid = sum.map(|s| s / cnt as f64);
    for (j, a) in c.params.anchors.iter().enumerate() {
        let d = crate::model::norm(crate::model::sub(*a, centroid));
        if !(d <= crate::screen::ABSURD_M) {
            return Err(Untrusted::AnchorAbsurd { cable: j, distance_m: d, limit_m: crate::screen::ABSURD_M });
        }
        if let Some((nom, limit)) = nominal {
            if let Some(n) = nom.get(j) {
                let d = crate::model::norm(crate::model::sub(*a, *n));
                if !(d <= limit) {
                    return Err(Untrusted::FarFromNominal { cable: j, distance_m: d, limit_m: limit });
                }
            }
        }
    }
    Ok(())
}

/// Cables whose calibrated anchors landed at other cables' nominal anchors: a wiring or
/// column-order mistake (the encoder column, drive or load cell of one cable recorded as
/// another's) rather than a site error.
#[derive(Debug, Clone, PartialEq)]
pub struct Swap {
    /// The cables in the cycle, in order: cable `cables[i]`'s anchor came out at the nominal
    /// anchor of `cables[(i + 1) % len]` (a pair: two cables exchanged).
    pub cables: Vec<usize>,
    /// Per cable of the cycle, the distance from the nominal anchor it landed at, m.
    pub distance_m: Vec<f64>,
    /// Per cable of the cycle, the distance from its own nominal anchor, m.
    pub own_distance_m: Vec<f64>,
}

impl fmt::Display for Swap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.cables;
        if c.len() == 2 {
            write!(f, "cables {} and {} look swapped", c[0] + 1, c[1] + 1)?;
        } else {
            let names: Vec<String> = c.iter().map(|j| (j + 1).to_string()).collect();
            write!(f, "cables {} look permuted", names.join(", "))?;
        }
        let each: Vec<String> = (0..c.len())
            .map(|i| {
                format!(
                    "cable {}'s anchor came out {:.3} m from cable {}'s nominal anchor ({:.3} m from its own)",
                    c[i] + 1,
                    self.distance_m[i],
                    c[(i + 1) % c.len()] + 1,
                    self.own_distance_m[i]
                )
            })
            .collect();
        write!(
            f,
            ": {}; the recording's length columns (or the drives, encoders or load cells) of these cables are in another order than the configuration's [[cable]] tables",
            each.join(", ")
        )
    }
}

/// The swaps of `anchors` against the configuration's `nominal` anchors: cable `j` landed at
/// cable `k`'s nominal anchor when that is the nearest nominal anchor to it, within a third of
/// the distance between the nominal anchors of `j` and `k` (so the site error, small against
/// the robot, cannot make one), and closer than its own by that margin; a swap is the cycle
/// of such cables (two cables exchanged, or more permuted). A cable that landed near another's
/// anchor without closing a cycle is not a swap (two cables at one anchor: the far-from-nominal
/// check refuses that).
pub fn swaps(anchors: &[[f64; 3]], nominal: &[[f64; 3]]) -> Vec<Swap> {
    let n = anchors.len().min(nominal.len());
    let dist = |a: [f64; 3], b: [f64; 3]| crate::model::norm(crate::model::sub(a, b));
    let target: Vec<Option<usize>> = (0..n)
        .map(|j| {
            let a = anchors[j];
            if !a.iter().all(|v| v.is_finite()) {
                return None;
            }
            let k = (0..n).min_by(|&x, &y| dist(a, nominal[x]).total_cmp(&dist(a, nominal[y])))?;
            let sep = dist(nominal[j], nominal[k]);
            (k != j && dist(a, nominal[k]) <= sep / 3.0 && dist(a, nominal[j]) >= 2.0 * sep / 3.0).then_some(k)
        })
        .collect();
    let mut seen = vec![false; n];
    let mut out = vec![];
    for start in 0..n {
        if seen[start] || target[start].is_none() {
            continue;
        }
        let mut cycle = vec![start];
        let mut at = start;
        let closed = loop {
            match target[at] {
                Some(k) if k == start => break true,
                Some(k) if !cycle.contains(&k) => {
                    cycle.push(k);
                    at = k;
                }
                _ => break false,
            }
        };
        if closed {
            for &j in &cycle {
                seen[j] = true;
            }
            let next = |i: usize| cycle[(i + 1) % cycle.len()];
            out.push(Swap {
                distance_m: (0..cycle.len()).map(|i| dist(anchors[cycle[i]], nominal[next(i)])).collect(),
                own_distance_m: cycle.iter().map(|&j| dist(anchors[j], nominal[j])).collect(),
                cables: cycle,
            });
        }
    }
    out
}

/// `nominal` with the cables of `swaps` in the order the recording has them: entry `j` is the
/// nominal anchor cable `j`'s anchor landed at.
pub fn permuted_nominal(nominal: &[[f64; 3]], swaps: &[Swap]) -> Vec<[f64; 3]> {
    let mut out = nominal.to_vec();
    for s in swaps {
        for (i, &j) in s.cables.iter().enumerate() {
            out[j] = nominal[s.cables[(i + 1) % s.cables.len()]];
        }
    }
    out
}

/// The length and tension columns of two cables disagree ([`tension_column_swap`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColumnSwap {
    /// The two cables.
    pub cables: (usize, usize),
    /// How many times smaller the platform's force-balance residual is with their tensions
    /// exchanged.
    pub ratio: f64,
    /// Rows compared.
    pub rows: usize,
}

impl fmt::Display for ColumnSwap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Cables from 1; the recording's columns are named from 0 (l0, f0).
        let (ca, cb) = self.cables;
        let (a, b) = (ca + 1, cb + 1);
        write!(
            f,
            "cables {a} and {b} look swapped: their length columns disagree with their tension columns (l{ca}/f{ca} and l{cb}/f{cb}; the platform's force balance at the calibrated anchors fits {:.0}x better with the tensions of cables {a} and {b} exchanged, over {} rows); the length columns (or the tension columns) of these cables are in another order than the robot's",
            self.ratio, self.rows
        )
    }
}

/// The ratio above which [`tension_column_swap`] calls two cables swapped. Measured on the
/// simulated ARAS-CAM-like robot (`taut simulate`, seeds 5 and 6, 100 Hz): with the length
/// columns 0 and 1 exchanged 14.0 and 15.2; as recorded the best exchange is 8-11x *worse*
/// (0.12, 0.09); in `tests/tests/offline/swapped_cables.rs` (20 Hz) 9x for 4 cables and 13x
/// for 8.
pub const COLUMN_SWAP_RATIO: f64 = 4.0;

/// Without nominal anchors, the data can still say that two cables' length and tension columns
/// belong to different cables: at the calibrated `anchors` the cables' tensions along their
/// directions must hold the platform's weight and accelerate it, `sum_j T_j u_j = m (a - g)`
/// (`m` fitted, `a` the tracker's second difference over about 0.1 s). When the
/// residual with the tensions of some pair `(a, b)` exchanged is more than
/// [`COLUMN_SWAP_RATIO`] times smaller than as recorded, the pair is returned. On rows where
/// every cable is taut (`min_tension_n`), with a pose and every tension; `None` without
/// tensions or with fewer than 50 such rows. A file whose length *and* tension columns are both
/// exchanged is the recording of a robot numbered the other way round: nothing in it tells.
pub fn tension_column_swap(rec: &Recording, platform_points: &[[f64; 3]], anchors: &[[f64; 3]], min_tension_n: f64) -> Option<ColumnSwap> {
    let n = anchors.len();
    let f = rec.f.as_ref()?;
    if n < 2 || platform_points.len() != n || rec.n_cables != n {
        return None;
    }
    // The platform's acceleration by a central second difference over about 0.1 s (the
    // tracker's noise, 1.5 mm, gives ~0.4 m/s^2 there).
    let posed = |i: usize| rec.p[i].iter().all(|v| v.is_finite()) && rec.t[i].is_finite();
    let dt = {
        let mut d: Vec<f64> = rec.t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
        let k = d.len() / 2;
        // The element a sort would put at `k`, without sorting the rest.
        if d.is_empty() {
            f64::NAN
        } else {
            *d.select_nth_unstable_by(k, f64::total_cmp).1
        }
    };
    if !(dt > 0.0) {
        return None;
    }
    let k = ((0.1 / dt).round() as usize).max(1);
    let accel = |i: usize| -> Option<[f64; 3]> {
        if i < k || i + k >= rec.len() || !posed(i - k) || !posed(i + k) {
            return None;
        }
        let (t0, t1, t2) = (rec.t[i - k], rec.t[i], rec.t[i + k]);
        let (h0, h1) = (t1 - t0, t2 - t1);
        if !(h0 > 0.0 && h1 > 0.0) {
            return None;
        }
        let a: [f64; 3] =
            std::array::from_fn(|c| 2.0 * ((rec.p[i + k][c] - rec.p[i][c]) / h1 - (rec.p[i][c] - rec.p[i - k][c]) / h0) / (h0 + h1));
        a.iter().all(|v| v.is_finite()).then_some(a)
    };
    // The usable rows, then every so many of them (at most 5000), with their accelerations
    // computed again (the same function of the same values) rather than kept for every row.
    let usable: Vec<usize> = (0..rec.len())
        .filter(|&i| posed(i) && f[i * n..(i + 1) * n].iter().all(|t| t.is_finite() && *t >= min_tension_n) && accel(i).is_some())
        .collect();
    if usable.len() < 50 {
        return None;
    }
    let rows: Vec<usize> = usable.iter().step_by(usable.len().div_ceil(5000)).copied().collect();
    // What the cables hold: m (a - g), g = -9.81 e_z.
    let acc: Vec<[f64; 3]> = rows.iter().filter_map(|&i| accel(i)).map(|a| [a[0], a[1], a[2] + 9.81]).collect();
    // Unit vectors from each attachment point to its anchor, per row.
    let mut u = Vec::with_capacity(rows.len() * n);
    for &i in &rows {
        let r = rec.q.as_ref().and_then(|q| crate::model::rotation(q[i]));
        for j in 0..n {
            let b = r.as_ref().map_or(platform_points[j], |r| crate::model::mat_vec(r, platform_points[j]));
            let d = crate::model::sub(anchors[j], [rec.p[i][0] + b[0], rec.p[i][1] + b[1], rec.p[i][2] + b[2]]);
            let l = crate::model::norm(d);
            u.push([d[0] / l, d[1] / l, d[2] / l]);
        }
    }
    // The residual of `sum_j T_perm(j) u_j = m (a - g)` with the mass fitted.
    let residual = |perm: &dyn Fn(usize) -> usize| -> f64 {
        let forces: Vec<[f64; 3]> = rows
            .iter()
            .enumerate()
            .map(|(q, &i)| {
                let mut s = [0.0; 3];
                for j in 0..n {
                    let t = f[i * n + perm(j)];
                    for c in 0..3 {
                        s[c] += t * u[q * n + j][c];
                    }
                }
                s
            })
            .collect();
        let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let m = forces.iter().zip(&acc).map(|(s, a)| dot(s, a)).sum::<f64>() / acc.iter().map(|a| dot(a, a)).sum::<f64>();
        forces.iter().zip(&acc).map(|(s, a)| (0..3).map(|c| (s[c] - m * a[c]).powi(2)).sum::<f64>()).sum()
    };
    let base = residual(&|j| j);
    let mut best: Option<(f64, (usize, usize))> = None;
    for a in 0..n {
        for b in a + 1..n {
            let r = residual(&|j| {
                if j == a {
                    b
                } else if j == b {
                    a
                } else {
                    j
                }
            });
            if best.is_none_or(|(v, _)| r < v) {
                best = Some((r, (a, b)));
            }
        }
    }
    let (r, cables) = best?;
    let ratio = base / r.max(f64::MIN_POSITIVE);
    (ratio > COLUMN_SWAP_RATIO).then_some(ColumnSwap { cables, ratio, rows: rows.len() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth;

    #[test]
    fn refuses_non_finite_and_absurd_sets() {
        let truth = synth::aras_cam();
        let rec = synth::box_recording(&synth::Spec::new(truth.clone()), 200, [-1.0; 3], [1.0; 3], 1);
        let sigma = Sigmas::uniform(4, 1e-4);
        let ok = Candidate { params: &truth, sigma: &sigma, rms_m: 1e-3 };
        assert_eq!(check(&ok, &rec, Some((&truth.anchors, 1.0))), Ok(()));
        assert!(matches!(check(&Candidate { rms_m: f64::INFINITY, ..ok }, &rec, None), Err(Untrusted::NonFinite { cable: None, .. })));
        let nan = Sigmas { anchors: vec![[1e-4, f64::NAN, 1e-4]; 4], ..sigma.clone() };
        assert!(matches!(check(&Candidate { sigma: &nan, ..ok }, &rec, None), Err(Untrusted::NonFinite { cable: Some(0), .. })));
        let mut far = truth.clone();
        far.anchors[2] = [1e6, 0.0, 0.0];
        assert!(matches!(check(&Candidate { params: &far, ..ok }, &rec, None), Err(Untrusted::AnchorAbsurd { cable: 2, .. })));
        far.anchors[2] = [-3.0, 1.7, 6.0];
        let e = check(&Candidate { params: &far, ..ok }, &rec, Some((&truth.anchors, 1.0))).unwrap_err();
        assert!(matches!(e, Untrusted::FarFromNominal { cable: 2, .. }), "{e}");
        assert!(e.to_string().contains("cable[2].anchor"));
    }

    /// Two cables exchanged, three permuted, a site error, and two cables at one anchor.
    #[test]
    fn names_swapped_and_permuted_cables() {
        let nominal = synth::aras_cam().anchors;
        let site = |a: [f64; 3]| [a[0] + 0.05, a[1] - 0.04, a[2] + 0.03];
        let mut a: Vec<[f64; 3]> = nominal.iter().map(|&x| site(x)).collect();
        assert!(swaps(&a, &nominal).is_empty());
        a.swap(0, 1);
        let s = swaps(&a, &nominal);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].cables, vec![0, 1]);
        assert!(s[0].to_string().starts_with("cables 1 and 2 look swapped: cable 1's anchor came out 0.071 m from cable 2's"), "{}", s[0]);
        assert_eq!(permuted_nominal(&nominal, &s), vec![nominal[1], nominal[0], nominal[2], nominal[3]]);
        // 0 -> 1 -> 2 -> 0 (cable 0 at 1's anchor, 1 at 2's, 2 at 0's).
        let mut p: Vec<[f64; 3]> = nominal.iter().map(|&x| site(x)).collect();
        (p[0], p[1], p[2]) = (site(nominal[1]), site(nominal[2]), site(nominal[0]));
        let s = swaps(&p, &nominal);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].cables, vec![0, 1, 2]);
        assert!(s[0].to_string().starts_with("cables 1, 2, 3 look permuted"), "{}", s[0]);
        // Cable 0 at cable 1's anchor, cable 1 where it belongs: not a swap.
        let mut q: Vec<[f64; 3]> = nominal.iter().map(|&x| site(x)).collect();
        q[0] = site(nominal[1]);
        assert!(swaps(&q, &nominal).is_empty());
    }
}
