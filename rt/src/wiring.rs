//! The start-up's wiring check: in each initialisation phase, while cable `r` is
//! reeled with cables `a` and `b` held, the loop compares what the sensors report with what the
//! tracked motion and the nominal geometry predict, and stops the robot when they disagree,
//! naming the cable and the miswiring that explains what it saw.
//!
//! What is compared, from the start of the reel (every quantity low-passed over
//! [`WIRING_TAU_S`] alike, so that a swinging platform and the readings' lags cancel):
//!
//! - **Encoders.** Each cable's encoder length change `Δl_j` against the change of its straight
//!   length `|P + b_j - A_j|` between the tracked poses, with the nominal anchors `A_j`: the
//!   reeled cable must show the reel, the held ones nothing, the followers what the motion pays
//!   out. Tolerance `LENGTH_TOL_M + LENGTH_TOL_REL |ΔP|` (nominal anchors a few cm off turn the
//!   directions by a few per cent of the displacement).
//! - **Load cells.** Each cable's tension against the statics at the tracked pose
//!   ([`crate::follower::statics`]: the followers at their commanded tension, the three
//!   position cables from the force balance with the nominal anchors). Tolerance
//!   `TENSION_TOL_N + TENSION_TOL_REL T` (the swing's `m a` that the low-pass leaves, a
//!   torque-mode drum's friction) plus, for the position cables, what anchors
//!   [`ANCHOR_TOL_M`] off do to the statics there (large where the three cables' directions are
//!   nearly coplanar; the followers' tension does not depend on the geometry). Tensions, not
//!   their changes over the reel: on the dynamic plant the swing a reel starts changes the held
//!   cables' tensions by as much as the reel does (5 N of 0.4 N predicted, measured), while the
//!   levels of held and following cables differ by 10-15 N.
//!
//! When a comparison fails, the check tries the single miswirings that could explain it: one
//! encoder's sign inverted (its change matches with the sign flipped), two drives swapped (each
//! encoder matches the other's predicted change), two load cells swapped; the first that brings
//! every cable within its tolerance is named, otherwise the worst cable. A verdict must hold for
//! [`PERSIST_S`] before the robot stops (reaction: hold). The encoders are compared once the
//! reel has gone `min(MIN_REEL_M, |reel_m| / 2)`, the load cells from the phase's lead on (the
//! platform at rest); before the reel has gone that far a verdict is only held
//! ([`WiringCheck::pending`]): the loop names it when a limit the reel breaks comes first.
//!
//! The platform's direction of motion is reported beside the verdict: with `a` and `b` held it
//! moves on the circle about `A_a`, `A_b`, to first order along `±u_a × u_b` (unit vectors from
//! the platform to the anchors), the sign set by `u_r`: a reel that moves the platform the other
//! way (an inverted encoder on the reeled cable) shows as 180°.
//!
//! What cannot be seen in a phase: a swap of its two held cables (both hold, nothing changes)
//! and a swap of two load cells whose cables carry the same tension change (two followers). The
//! next phase that reels or lets follow one of them sees the first; the second does not matter
//! while they follow alike, and shows as soon as one of them holds.
//!
//! Fixed size; nothing here allocates.

use crate::io::Inputs;
use crate::kin::LoopParams;
use crate::safety::{Cause, Miswiring};
use crate::MAX_CABLES;

/// Time constant of the low-pass on the pose, lengths, tensions and follower tension, s: long
/// against a platform's swing, short against the reel.
pub const WIRING_TAU_S: f64 = 0.25;

/// Absolute tolerance of an encoder change, m.
pub const LENGTH_TOL_M: f64 = 0.03;

/// Tolerance of an encoder change per metre of the platform's displacement.
pub const LENGTH_TOL_REL: f64 = 0.15;

/// How far the nominal anchors may be from the true ones for the load cells' comparison, m
/// (the simulated sites' `site_error_m`, 0.2 m): sets how much the statics may be off
/// (`statics_spread`).
pub const ANCHOR_TOL_M: f64 = 0.2;

/// Absolute tolerance of a tension, N.
pub const TENSION_TOL_N: f64 = 3.0;

/// Tolerance of a tension per newton of the predicted tension.
pub const TENSION_TOL_REL: f64 = 0.3;

/// How long a verdict must hold before the robot stops, s.
pub const PERSIST_S: f64 = 0.1;

/// The reel after which the comparison starts (at most half the phase's reel), m.
pub const MIN_REEL_M: f64 = 0.15;

/// The filtered state of the check in one phase.
#[derive(Debug, Clone, Copy)]
pub struct WiringCheck {
    /// Filters started (the first cycle of the phase).
    started: bool,
    /// Reference taken (the first cycle of the reel).
    have_ref: bool,
    p: [f64; 3],
    l: [f64; MAX_CABLES],
    t: [f64; MAX_CABLES],
    tf: f64,
    ref_p: [f64; 3],
    ref_l: [f64; MAX_CABLES],
    /// How long the current verdict has held, s.
    bad_s: f64,
    /// Time since the phase's filters started, s.
    age_s: f64,
    /// The current verdict (not yet held for [`PERSIST_S`]).
    pending: Option<Cause>,
    /// Largest normalised residual of the wiring as configured, over the start-up so far:
    /// encoders, load cells (1: at the tolerance).
    worst: [f64; 2],
}

impl Default for WiringCheck {
    fn default() -> Self {
        WiringCheck::new()
    }
}

/// What one comparison needs beside the filtered readings.
#[derive(Debug, Clone, Copy)]
pub struct Phase<'a> {
    /// The nominal geometry (anchors and platform points).
    pub params: &'a LoopParams,
    /// Cables.
    pub n: usize,
    /// `[held_a, held_b, reeled]`.
    pub cables: [usize; 3],
    /// Commanded reel since the reel began, m (signed: negative reels in).
    pub progress_m: f64,
    /// Platform mass, kg.
    pub mass_kg: f64,
    /// The robot has load cells.
    pub loads: bool,
    /// Below this tension a cable is slack and its encoder is not compared, N.
    pub loose_n: f64,
    /// The reel has gone far enough to compare the encoders (and to stop the robot). Before,
    /// the load cells are compared and a verdict only held ([`WiringCheck::pending`]).
    pub encoders: bool,
}

impl WiringCheck {
    /// A check that has seen nothing.
    pub const fn new() -> WiringCheck {
        WiringCheck {
            started: false,
            have_ref: false,
            p: [0.0; 3],
            l: [0.0; MAX_CABLES],
            t: [0.0; MAX_CABLES],
            tf: 0.0,
            ref_p: [0.0; 3],
            ref_l: [0.0; MAX_CABLES],
            bad_s: 0.0,
            age_s: 0.0,
            pending: None,
            worst: [0.0; 2],
        }
    }

    /// Largest normalised residuals of the configured wiring so far (encoders, load cells; 1 is
    /// the tolerance, where the check would stop the robot if it held for [`PERSIST_S`]).
    pub fn worst(&self) -> [f64; 2] {
        self.worst
    }

    /// The verdict that has held for [`PERSIST_S`] before the reel went far enough to stop the
    /// robot on it: the cause to name when a limit breaks meanwhile.
    pub fn pending(&self) -> Option<Cause> {
        self.pending.filter(|_| self.bad_s >= PERSIST_S)
    }

    /// Starts a phase afresh: new filters, no reference, no verdict (the worst residuals are
    /// kept).
    pub fn restart(&mut self) {
        self.started = false;
        self.have_ref = false;
        self.age_s = 0.0;
        self.bad_s = 0.0;
        self.pending = None;
    }

    /// Low-passes this cycle's pose, lengths, tensions and the followers' commanded tension.
    pub fn track(&mut self, n: usize, inp: &Inputs, follower_n: f64, dt: f64) {
        let w = if self.started { (dt / WIRING_TAU_S).clamp(0.0, 1.0) } else { 1.0 };
        let f = |x: &mut f64, v: f64| {
            if v.is_finite() {
                *x = if x.is_finite() { *x + w * (v - *x) } else { v };
            }
        };
        if !self.started {
            self.p = [f64::NAN; 3];
            self.l = [f64::NAN; MAX_CABLES];
            self.t = [f64::NAN; MAX_CABLES];
            self.tf = f64::NAN;
        }
        for i in 0..3 {
            f(&mut self.p[i], inp.pose_m[i]);
        }
        for j in 0..n {
            f(&mut self.l[j], inp.length_m[j]);
            f(&mut self.t[j], inp.tension_n[j]);
        }
        f(&mut self.tf, follower_n);
        self.age_s += if self.started { dt } else { 0.0 };
        self.started = true;
    }

    /// Takes the reference the reel is compared with (the first cycle of the reel).
    pub fn mark(&mut self) {
        if !self.have_ref {
            (self.ref_p, self.ref_l) = (self.p, self.l);
            self.have_ref = true;
        }
    }

    /// Forgets the verdict being formed (the reel is too short to judge).
    pub fn idle(&mut self) {
        self.bad_s = 0.0;
        self.pending = None;
    }

    /// Compares the readings with the prediction (once the filters have run [`WIRING_TAU_S`]);
    /// the cause once a verdict has held for [`PERSIST_S`] and `ph.encoders`.
    pub fn judge(&mut self, ph: &Phase<'_>, dt: f64) -> Option<Cause> {
        if self.age_s < WIRING_TAU_S || (ph.encoders && !self.have_ref) {
            return None;
        }
        let verdict = self.verdict(ph);
        match verdict {
            Some(c) => {
                self.bad_s += dt;
                self.pending = Some(c);
                (ph.encoders && self.bad_s >= PERSIST_S).then_some(c)
            }
            None => {
                self.idle();
                None
            }
        }
    }

    /// This cycle's verdict, and the worst residuals kept.
    fn verdict(&mut self, ph: &Phase<'_>) -> Option<Cause> {
        let n = ph.n.min(MAX_CABLES);
        let prm = ph.params;
        let rho = |j: usize, p: &[f64; 3]| {
            let d: [f64; 3] = std::array::from_fn(|i| p[i] + prm.platform[j][i] - prm.anchors[j][i]);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        };
        let dp: [f64; 3] = if self.have_ref { std::array::from_fn(|i| self.p[i] - self.ref_p[i]) } else { [0.0; 3] };
        let disp = norm(dp);
        if !disp.is_finite() {
            return None;
        }
        let [a, b, r] = ph.cables;
        let angle = self.angle_deg(ph, dp, disp);
        // Encoders: measured and predicted changes, m.
        let mut dl = [0.0; MAX_CABLES];
        let mut drho = [0.0; MAX_CABLES];
        let mut used = [false; MAX_CABLES];
        for j in 0..n {
            dl[j] = self.l[j] - self.ref_l[j];
            drho[j] = rho(j, &self.p) - rho(j, &self.ref_p);
            // A slack cable's encoder says nothing about the straight length.
            let slack = ph.loads && self.t[j].is_finite() && self.t[j] < ph.loose_n;
            used[j] = ph.encoders && dl[j].is_finite() && drho[j].is_finite() && !slack;
        }
        let tol = LENGTH_TOL_M + LENGTH_TOL_REL * disp;
        let z = |m: f64, p: f64| (m - p).abs() / tol;
        // Cable `j`'s encoder residual with the drives of cables `i` and `k` exchanged.
        let z_exchanged = |i: usize, k: usize, j: usize| {
            let other = if j == i {
                k
            } else if j == k {
                i
            } else {
                j
            };
            z(dl[j], drho[other])
        };
        let (worst0, j0) = worst_of(n, &used, |j| z(dl[j], drho[j]));
        self.worst[0] = self.worst[0].max(worst0);
        // `+ 0.0` turns a -0 into 0 for the text.
        let cause = |fault, cable: usize, other: usize, measured: f64, predicted: f64, for_other: f64| Cause::Miswired {
            fault,
            cable: cable as u8,
            other: other as u8,
            reeled: r as u8,
            measured: measured as f32 + 0.0,
            predicted: predicted as f32 + 0.0,
            for_other: for_other as f32 + 0.0,
            angle_deg: angle as f32,
        };
        if worst0 > 1.0 {
            // The single miswiring that explains every encoder, the best if several do.
            let mut best = (f64::INFINITY, Miswiring::Encoder, j0, j0);
            for k in (0..n).filter(|&k| used[k]) {
                let s = worst_of(n, &used, |j| if j == k { z(-dl[j], drho[j]) } else { z(dl[j], drho[j]) }).0;
                if s < best.0 {
                    best = (s, Miswiring::EncoderInverted, k, k);
                }
            }
            for i in (0..n).filter(|&i| used[i]) {
                for k in (i + 1..n).filter(|&k| used[k]) {
                    let s = worst_of(n, &used, |j| z_exchanged(i, k, j)).0;
                    if s < best.0 {
                        best = (s, Miswiring::DrivesSwapped, i, k);
                    }
                }
            }
            let (fault, i, k) = if best.0 <= 1.0 { (best.1, best.2, best.3) } else { (Miswiring::Encoder, j0, j0) };
            return Some(cause(fault, i, k, dl[i] * 1e3, drho[i] * 1e3, drho[k] * 1e3));
        }
        if !ph.loads {
            return None;
        }
        // Load cells: measured tensions against the statics at the tracked pose, N.
        let mut follower = [false; MAX_CABLES];
        for (j, f) in follower.iter_mut().enumerate().take(n) {
            *f = j != a && j != b && j != r;
        }
        let want = crate::follower::statics(prm, &follower, &self.p, ph.mass_kg, self.tf)?;
        let mut usable = [false; MAX_CABLES];
        for j in 0..n {
            usable[j] = self.t[j].is_finite() && want[j].is_finite();
        }
        let t = self.t;
        let spread = statics_spread(prm, ph.cables, n, &self.p, &want);
        // Cable `j`'s reading against cable `k`'s prediction, in `k`'s tolerance.
        let zt = |j: usize, k: usize| (t[j] - want[k]).abs() / (TENSION_TOL_N + TENSION_TOL_REL * want[k].abs() + spread[k]);
        let (worst1, j1) = worst_of(n, &usable, |j| zt(j, j));
        self.worst[1] = self.worst[1].max(worst1);
        if worst1 <= 1.0 {
            return None;
        }
        let mut best = (f64::INFINITY, j1, j1);
        for i in (0..n).filter(|&i| usable[i]) {
            for k in (i + 1..n).filter(|&k| usable[k]) {
                let s = worst_of(n, &usable, |j| {
                    if j == i {
                        zt(i, k)
                    } else if j == k {
                        zt(k, i)
                    } else {
                        zt(j, j)
                    }
                })
                .0;
                if s < best.0 {
                    best = (s, i, k);
                }
            }
        }
        if best.0 > 1.0 {
            return Some(cause(Miswiring::LoadCell, j1, j1, t[j1], want[j1], want[j1]));
        }
        let (i, k) = (best.1, best.2);
        // A follower's drive swapped with a position cable's puts the same tensions on the
        // two cells as the two cells swapped; the encoders tell them apart unless the two
        // cables' length changes are alike in this motion (a pair symmetric about it), or are
        // not compared yet.
        let drives_too = follower[i] != follower[k] && {
            let s = worst_of(n, &used, |j| z_exchanged(i, k, j));
            s.0 <= 1.0
        };
        let fault = if drives_too { Miswiring::DrivesOrLoadCellsSwapped } else { Miswiring::LoadCellsSwapped };
        Some(cause(fault, i, k, t[i], want[i], want[k]))
    }

    /// Angle between the tracked displacement `dp` and the direction reeling the phase's cable
    /// with its two cables held predicts, degrees; NaN when either is undefined.
    fn angle_deg(&self, ph: &Phase<'_>, dp: [f64; 3], disp: f64) -> f64 {
        let prm = ph.params;
        let u = |j: usize| {
            let d: [f64; 3] = std::array::from_fn(|i| prm.anchors[j][i] - self.ref_p[i] - prm.platform[j][i]);
            let r = norm(d);
            [d[0] / r, d[1] / r, d[2] / r]
        };
        let [a, b, r] = ph.cables;
        let (ua, ub, ur) = (u(a), u(b), u(r));
        let nrm = [ua[1] * ub[2] - ua[2] * ub[1], ua[2] * ub[0] - ua[0] * ub[2], ua[0] * ub[1] - ua[1] * ub[0]];
        let g = ur[0] * nrm[0] + ur[1] * nrm[1] + ur[2] * nrm[2];
        // d rho_r = -u_r . dP; along s * nrm: s = -progress / (u_r . nrm).
        let s = -ph.progress_m / g;
        let len = norm(nrm);
        if !(disp > 1e-2 && g.abs() > 1e-6 && len > 1e-9 && s.is_finite()) {
            return f64::NAN;
        }
        let c = s.signum() * (dp[0] * nrm[0] + dp[1] * nrm[1] + dp[2] * nrm[2]) / (len * disp);
        c.clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// How far the statics' tensions of the three position cables `cables` may be off when every
/// anchor may be [`ANCHOR_TOL_M`] from its nominal place, N (0 for the followers): each cable's
/// direction turns by up to `ANCHOR_TOL_M / rho_j`, which changes the force balance
/// `M t_P = w` by `dM t_P + dw`; to first order `dt_P = -M^-1 (dM t_P + dw)`, bounded row by
/// row, doubled for what the first order leaves out. Near a pose where the three directions
/// are nearly coplanar `M^-1` is large and so is the spread: the statics say little there.
fn statics_spread(prm: &LoopParams, cables: [usize; 3], n: usize, p: &[f64; 3], t: &[f64; MAX_CABLES]) -> [f64; MAX_CABLES] {
    let mut out = [0.0; MAX_CABLES];
    let dir = |j: usize| {
        let d: [f64; 3] = std::array::from_fn(|i| prm.anchors[j][i] - p[i] - prm.platform[j][i]);
        let r = norm(d);
        ([d[0] / r, d[1] / r, d[2] / r], r)
    };
    // The size of dM t_P + dw: every cable's pull turned by its angle.
    let push: f64 = t.iter().take(n).enumerate().map(|(j, tj)| ANCHOR_TOL_M / dir(j).1 * tj.abs()).sum();
    let (c0, c1, c2) = (dir(cables[0]).0, dir(cables[1]).0, dir(cables[2]).0);
    // Rows of M^-1 (columns c0 c1 c2): the cross products over the determinant.
    let cross = |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let rows = [cross(c1, c2), cross(c2, c0), cross(c0, c1)];
    let det = c0[0] * rows[0][0] + c0[1] * rows[0][1] + c0[2] * rows[0][2];
    for (k, row) in rows.iter().enumerate() {
        let s = 2.0 * norm(*row) / det.abs() * push;
        out[cables[k]] = if s.is_finite() { s } else { f64::INFINITY };
    }
    out
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The largest `f(j)` over the cables `used`, and its cable (0, 0 if none).
fn worst_of(n: usize, used: &[bool; MAX_CABLES], f: impl Fn(usize) -> f64) -> (f64, usize) {
    let mut w = (0.0, 0);
    for j in (0..n).filter(|&j| used[j]) {
        let v = f(j);
        if v > w.0 || v.is_nan() {
            w = (if v.is_nan() { f64::INFINITY } else { v }, j);
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::follower::statics;

    /// The ARAS-CAM-like robot's nominal anchors.
    const NOMINAL: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

    /// A platform heavy enough that the held cables carry three times the follower's 10 N.
    const MASS_KG: f64 = 6.0;

    fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
        norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]])
    }

    /// Rotates `p` about the axis through `a` and `b` by `th` (Rodrigues).
    fn rotate(p: [f64; 3], a: [f64; 3], b: [f64; 3], th: f64) -> [f64; 3] {
        let k = {
            let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let l = norm(d);
            [d[0] / l, d[1] / l, d[2] / l]
        };
        let v = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
        let kv = [k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]];
        let kd = k[0] * v[0] + k[1] * v[1] + k[2] * v[2];
        let (c, s) = (th.cos(), th.sin());
        std::array::from_fn(|i| a[i] + v[i] * c + kv[i] * s + k[i] * kd * (1.0 - c))
    }

    /// A quasi-static reel of cable 2 with cables 0 and 1 held on a site whose anchors are off
    /// the nominal ones by a few cm, fed to the check as 500 Hz inputs with `miswire` applied
    /// to them; the first cause.
    fn reel(miswire: impl Fn(&mut Inputs, &Inputs)) -> Option<Cause> {
        let truth: Vec<[f64; 3]> = NOMINAL
            .iter()
            .enumerate()
            .map(|(j, a)| [a[0] + 0.03 * (j as f64 - 1.5), a[1] - 0.02 * j as f64, a[2] + 0.04 * (j % 2) as f64])
            .collect();
        let nominal = LoopParams::new(0, &NOMINAL, &[0.0; 4], &[[0.0; 3]; 4]);
        let site = LoopParams::new(0, &truth, &[0.0; 4], &[[0.0; 3]; 4]);
        let follower: [bool; MAX_CABLES] = std::array::from_fn(|j| j == 3);
        let p0 = [0.3, 0.1, 1.6];
        // The direction that shortens cable 2.
        let sign = if dist(rotate(p0, truth[0], truth[1], 1e-3), truth[2]) < dist(p0, truth[2]) { 1.0 } else { -1.0 };
        let mut check = WiringCheck::new();
        let dt = 0.002;
        let mut clean = Inputs::new(4);
        let mut first_set = clean;
        for k in 0..2000 {
            let t = k as f64 * dt;
            // 0.5 s at rest, then 3 s of a smooth reel.
            let w = ((t - 0.5) / 3.0).clamp(0.0, 1.0);
            let th = sign * 0.35 * w * w * (3.0 - 2.0 * w);
            let p = rotate(p0, truth[0], truth[1], th);
            let tensions = statics(&site, &follower, &p, MASS_KG, 10.0).expect("statics");
            clean.pose_m = p;
            for j in 0..4 {
                clean.length_m[j] = dist(p, truth[j]) + 1.0;
                clean.tension_n[j] = tensions[j];
            }
            if k == 0 {
                first_set = clean;
            }
            let mut fed = clean;
            miswire(&mut fed, &first_set);
            check.track(4, &fed, 10.0, dt);
            if t >= 0.5 {
                check.mark();
            }
            let progress_m = clean.length_m[2] - first_set.length_m[2];
            let encoders = progress_m.abs() >= MIN_REEL_M;
            let ph = Phase { params: &nominal, n: 4, cables: [0, 1, 2], progress_m, mass_kg: MASS_KG, loads: true, loose_n: 1.0, encoders };
            if let Some(c) = check.judge(&ph, dt) {
                assert!(encoders, "stopped before the reel went {MIN_REEL_M} m: {c}");
                return Some(c);
            }
        }
        assert!(check.worst()[0] < 0.5 && check.worst()[1] < 0.5, "margins {:?}", check.worst());
        None
    }

    fn kind(c: Option<Cause>) -> (Miswiring, u8, u8) {
        match c {
            Some(Cause::Miswired { fault, cable, other, .. }) => (fault, cable, other),
            other => panic!("{other:?}"),
        }
    }

    /// Wired as configured, nothing is found, with the nominal anchors a few cm off; each
    /// miswiring of the readings is named.
    #[test]
    fn the_check_names_what_the_readings_show() {
        assert_eq!(reel(|_, _| {}), None);
        // The follower's encoder counting the other way, mirrored about its first reading.
        let inverted = kind(reel(|i, first| i.length_m[3] = 2.0 * first.length_m[3] - i.length_m[3]));
        assert_eq!(inverted, (Miswiring::EncoderInverted, 3, 3));
        // Two load cells exchanged: a held cable's and the follower's.
        let cells = kind(reel(|i, _| i.tension_n.swap(1, 3)));
        assert_eq!(cells, (Miswiring::LoadCellsSwapped, 1, 3));
        // Two encoders' readings exchanged (a held cable's and the follower's).
        let drives = kind(reel(|i, _| i.length_m.swap(0, 3)));
        assert_eq!(drives, (Miswiring::DrivesSwapped, 0, 3));
        // A load cell that reads nothing like any cable: named, unexplained.
        let odd = kind(reel(|i, _| i.tension_n[1] += 40.0));
        assert_eq!(odd, (Miswiring::LoadCell, 1, 1));
    }
}
