//! The physics of one cable: the switchable effects ([`Physics`]) and the cable between its anchor
//! and the platform ([`CableModel`]).
//!
//! What an encoder counts is the *unstretched* cable paid out by the drum. The model here turns a
//! platform attachment point `B` and a tension into that length, and a drum command (a length in
//! position mode or a tension in torque mode) into the force on the platform and a potential
//! energy for the equilibrium solver.
//!
//! ```text
//!          | swivel axis (vertical, through the nominal anchor A)
//!          |   ___
//!     A -> |  /   \  pulley of radius r, centre C = A + r u_h, turned to face B
//!          |  \___/
//!            \_ exit point E (tangent), wrap arc r*beta from A to E
//!               \
//!                \  straight (or catenary) span E -> B
//!                 B  platform attachment
//! ```
//!
//! Without a pulley `E = A`. The cable reaches the pulley along the swivel axis from above; the
//! part above `A` has a constant length and is absorbed in the encoder offset.
//!
//! A compliant winch, frame or anchor ([`Physics::compliance_m_per_n`]) is a spring in series
//! with the cable at the drum's end: under the tension `T` there it gives `k T`, so the drum
//! holds that much less cable than the path needs, whatever the cable's length.

use std::cell::Cell;

use crate::catenary::{self, CableSpec, Catenary, End};
use crate::dynamics::Dynamics;

/// Axial stiffness used for a cable in position mode when elasticity is switched off, N: stiff
/// enough that its stretch (T L / EA ~ microns) is below the encoder resolution, soft enough for
/// the equilibrium solver's finite differences.
pub const EA_RIGID: f64 = 1e8;

/// The drums' effective radius at the cable length zero (drum build-up, see
/// [`Physics::drum_buildup_m_per_turn`]), m.
pub const DRUM_RADIUS_M: f64 = 0.025;

/// Standard gravity, m/s^2.
pub const G: f64 = 9.81;

/// Switchable cable physics. Everything is off by default except slack cables, which the
/// excitation's excursions cause.
#[derive(Debug, Clone, PartialEq)]
pub struct Physics {
    /// Axial stiffness EA of every cable, N: the encoder counts the unstretched length
    /// `geometric / (1 + T/EA)`.
    pub elasticity: Option<f64>,
    /// Cable weight per length, N/m: the cable hangs in a catenary whose arc is longer than the
    /// chord (solved exactly).
    pub sag: Option<f64>,
    /// Radius of a swivel pulley at every anchor, m.
    pub pulley: Option<f64>,
    /// Per-cable encoder scale (drum radius error): reading = scale x length + offset.
    pub scale: Option<Vec<f64>>,
    /// Drum build-up: the change of every drum's effective radius per turn paid out, m (a
    /// multi-layer winding: minus the cable diameter over the turns a layer holds; `None` or 0: a
    /// single-layer drum). The drums have the radius [`DRUM_RADIUS_M`] at the cable length zero
    /// the encoder offsets refer to, and the encoder converts its angle at that radius (see
    /// [`crate::sensors::Drum`]).
    pub drum_buildup_m_per_turn: Option<f64>,
    /// Compliance of every winch, its frame and anchor, m/N: a spring in series with the cable
    /// at the drum's end that gives `k T` under the tension `T` there, independent of the cable's
    /// length. `None` or 0: rigid.
    pub compliance_m_per_n: Option<f64>,
    /// Drum eccentricity, m: each drum turns about an axis this far off its centre, so the cable
    /// it pays out runs ahead of and behind the encoder's count by up to this much, periodic in
    /// the paid-out length with the drum's circumference (`2 pi DRUM_RADIUS_M`), each cable's
    /// drum at its own phase ([`Physics::eccentricity`]). calib's effect library has no such
    /// effect. `None` or 0: off.
    pub drum_eccentricity_m: Option<f64>,
    /// A length error that follows the platform's height, 1/m: every encoder reads `k z^2` more,
    /// `z` the platform's height in the robot frame (m). calib's effect library has no such effect.
    /// Applied wherever readings are made along the platform's path (excitation, dwell and plant
    /// recordings); a position-mode drive's hold ([`crate::sensors::Encoder::drum_for`]) does not
    /// see it. `None` or 0: off.
    pub height_error_per_m: Option<f64>,
    /// Encoder readings lag the tracker by this, s (the encoder value at `t` is the length at
    /// `t - time_offset_s`). Zero is off.
    pub time_offset_s: f64,
    /// Play in the drive train, m: the reading follows the length through a hysteresis (play
    /// operator) of this width. Zero is off.
    pub backlash_m: f64,
    /// Loose cables: where the trajectory demands a negative tension the cable goes slack and its
    /// drum pays out extra cable.
    pub slack: bool,
    /// Load-cell gain per cable: the cell reads `gain x tension + offset` (`None`: 1).
    pub loadcell_gain: Option<Vec<f64>>,
    /// Friction between the platform and the load cell at the winch, `mu theta` of every cable
    /// (capstan: the cell reads the platform-end tension times `exp(mu theta)` while the cable
    /// reels in, `exp(-mu theta)` while it pays out; see [`crate::sensors::capstan_factor`]).
    /// `None` or 0: off.
    pub friction_mu_theta: Option<f64>,
    /// A dynamic plant: the platform's mass swings on elastic, damped cables (see
    /// [`crate::dynamics`]). `None` (the default): the quasi-static plant. Read by
    /// [`crate::Plant`] (and so by the three-phase motion, which steps a plant); the excitation
    /// recordings of [`crate::simulate`] stay quasi-static.
    pub dynamics: Option<Dynamics>,
}

impl Default for Physics {
    fn default() -> Self {
        Physics {
            elasticity: None,
            sag: None,
            pulley: None,
            scale: None,
            drum_buildup_m_per_turn: None,
            compliance_m_per_n: None,
            drum_eccentricity_m: None,
            height_error_per_m: None,
            loadcell_gain: None,
            friction_mu_theta: None,
            time_offset_s: 0.0,
            backlash_m: 0.0,
            slack: true,
            dynamics: None,
        }
    }
}

impl Physics {
    /// Ideal cables: every effect off, slack too.
    pub fn ideal() -> Self {
        Physics { slack: false, ..Physics::default() }
    }

    /// The drums' build-up (`None`: off).
    pub fn drum(&self) -> Option<crate::sensors::Drum> {
        self.drum_buildup_m_per_turn.filter(|g| *g != 0.0).map(|g| crate::sensors::Drum::new(DRUM_RADIUS_M, g))
    }

    /// Cable `j`'s drum eccentricity: (amplitude m, phase rad); `None`: off. The phases are
    /// spread over the cables (`0.7 + 2.4 j` rad) so that no two drums run in step.
    pub fn eccentricity(&self, j: usize) -> Option<crate::sensors::Eccentric> {
        self.drum_eccentricity_m.filter(|e| *e != 0.0).map(|e| crate::sensors::Eccentric {
            amplitude_m: e,
            radius_m: DRUM_RADIUS_M,
            phase: 0.7 + 2.4 * j as f64,
        })
    }

    /// The height-dependent reading error at platform height `z` (m), m (0 when off).
    pub fn height_error(&self, z: f64) -> f64 {
        self.height_error_per_m.map_or(0.0, |k| k * z * z)
    }

    /// The load-cell gain of cable `j` (1 when the effect is off).
    pub fn gain_of(&self, j: usize) -> f64 {
        self.loadcell_gain.as_ref().and_then(|g| g.get(j).copied()).unwrap_or(1.0)
    }

    /// The encoder scale of cable `j` (1 when the effect is off).
    pub fn scale_of(&self, j: usize) -> f64 {
        self.scale.as_ref().and_then(|s| s.get(j).copied()).unwrap_or(1.0)
    }
}

/// A drum command: what the drive of one cable does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CableCommand {
    /// Position mode: the drum has paid out this unstretched length, m.
    Length(f64),
    /// Torque mode: the drum holds this tension on the cable, N (at the anchor side).
    Tension(f64),
}

/// Geometry of the cable path from the anchor to a platform point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathGeom {
    /// Where the cable leaves the anchor (the pulley's tangent point, or the anchor itself), m.
    pub exit: [f64; 3],
    /// Arc wrapped on the pulley, m.
    pub wrap: f64,
    /// Straight distance from the exit point to the platform point, m.
    pub straight: f64,
    /// Unit vector from the platform point towards the exit point.
    pub dir: [f64; 3],
}

impl PathGeom {
    /// Path length (wrap + straight), m.
    pub fn length(&self) -> f64 {
        self.wrap + self.straight
    }
}

/// A taut cable of known tension: what the encoder counts and where the cable pulls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Taut {
    /// Unstretched length from the anchor to the platform, m.
    pub unstretched: f64,
    /// Unit direction of the force on the platform.
    pub dir: [f64; 3],
}

/// What a cable does to the platform under a drum command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableLoad {
    /// Force on the platform, N.
    pub force: [f64; 3],
    /// Potential energy of the cable (and its drive, in torque mode), J.
    pub energy: f64,
    /// Tension at the platform end, N.
    pub tension: f64,
    /// Unstretched length paid out by the drum, m.
    pub drum_length: f64,
    /// True when a position-mode cable is longer than the path (no tension).
    pub slack: bool,
}

/// One cable: anchor and the effects that shape its length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableModel {
    /// Anchor (cable exit point without pulley; the point where the swivel axis touches the
    /// pulley with one), m.
    pub anchor: [f64; 3],
    /// Pulley radius, m (0: no pulley).
    pub pulley_r: f64,
    /// Unit vector of the pulley's swivel axis through the anchor, pointing towards where the
    /// cable comes from (`[0, 0, 1]`: down from above).
    pub axis: [f64; 3],
    /// Axial stiffness, N (`f64::INFINITY`: inextensible).
    pub ea: f64,
    /// Weight per length, N/m (0: no sag).
    pub w: f64,
    /// Compliance of the winch, frame and anchor in series with the cable, m/N (0: rigid).
    pub k: f64,
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

fn scale3(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Some unit vector normal to the unit vector `w`: the pulley's plane when the platform point is
/// on the swivel axis (any plane then; the wrap is the same).
fn any_normal(w: [f64; 3]) -> [f64; 3] {
    // Cross with the coordinate axis least aligned with w.
    let e = if w[0].abs() <= w[1].abs() && w[0].abs() <= w[2].abs() {
        [1.0, 0.0, 0.0]
    } else if w[1].abs() <= w[2].abs() {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let c = [w[1] * e[2] - w[2] * e[1], w[2] * e[0] - w[0] * e[2], w[0] * e[1] - w[1] * e[0]];
    scale3(c, 1.0 / norm(c))
}

impl CableModel {
    /// The model of a cable anchored at `anchor`, its pulley (if `physics` has one) swivelling
    /// about the unit vector `axis`, with the effects of `physics`.
    pub fn new(anchor: [f64; 3], axis: [f64; 3], physics: &Physics) -> Self {
        CableModel {
            anchor,
            pulley_r: physics.pulley.unwrap_or(0.0),
            axis,
            ea: physics.elasticity.unwrap_or(f64::INFINITY),
            w: physics.sag.unwrap_or(0.0),
            k: physics.compliance_m_per_n.unwrap_or(0.0),
        }
    }

    /// The same cable with [`EA_RIGID`] when it is inextensible: what a drive in position mode
    /// needs to produce a tension.
    pub fn rigidified(mut self) -> Self {
        if !self.ea.is_finite() {
            self.ea = EA_RIGID;
        }
        self
    }

    /// Path geometry to the platform point `b`.
    pub fn path(&self, b: [f64; 3]) -> PathGeom {
        let a = self.anchor;
        let d = sub(b, a);
        if self.pulley_r <= 0.0 {
            let l = norm(d);
            return PathGeom { exit: a, wrap: 0.0, straight: l, dir: scale3(d, -1.0 / l) };
        }
        let r = self.pulley_r;
        let w = self.axis;
        // The pulley plane: through the swivel axis w, containing b. Its in-plane directions
        // are w and uh, the unit vector from the axis towards b (a Gram-Schmidt step).
        let along = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
        let perp = [d[0] - along * w[0], d[1] - along * w[1], d[2] - along * w[2]];
        // hypot and division: with a vertical axis these are exactly the horizontal distance
        // d_x.hypot(d_y) and direction, the same bits as the plane of a vertical swivel.
        let rho = perp[0].hypot(perp[1]).hypot(perp[2]);
        let uh = if rho > 1e-12 { [perp[0] / rho, perp[1] / rho, perp[2] / rho] } else { any_normal(w) };
        // b relative to the pulley centre, in (along uh, along w).
        let (x, z) = (rho - r, along);
        let dc = x.hypot(z);
        let psi = z.atan2(x);
        let alpha = (r / dc).min(1.0).acos();
        // The cable comes in along the axis at angle pi and wraps counter-clockwise (in the
        // (uh, w) plane) to the tangent point at psi - alpha.
        let phi = psi - alpha;
        let beta = (phi - std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI);
        let c = [a[0] + r * uh[0], a[1] + r * uh[1], a[2] + r * uh[2]];
        let (cp, sp) = (r * phi.cos(), r * phi.sin());
        let exit = [c[0] + cp * uh[0] + sp * w[0], c[1] + cp * uh[1] + sp * w[1], c[2] + cp * uh[2] + sp * w[2]];
        let e = sub(exit, b);
        let straight = norm(e);
        PathGeom { exit, wrap: r * beta, straight, dir: scale3(e, 1.0 / straight) }
    }

    /// Catenary span from `b` to the exit point: horizontal distance, rise, and the horizontal
    /// unit vector towards the exit.
    fn span(b: [f64; 3], exit: [f64; 3]) -> (f64, f64, [f64; 3]) {
        let d = sub(exit, b);
        let h = d[0].hypot(d[1]);
        let eh = if h > 1e-12 { [d[0] / h, d[1] / h, 0.0] } else { [1.0, 0.0, 0.0] };
        (h.max(1e-9), d[2], eh)
    }

    fn spec(&self) -> CableSpec {
        CableSpec { w: self.w, ea: self.ea }
    }

    /// The taut cable from the anchor to `b` with tension `t` at the platform end.
    ///
    /// With sag, the cable on the pulley is taken as inextensible (its stretch, wrap x T/EA, is
    /// microns) and the pulley's tangent point is that of the chord.
    pub fn taut(&self, b: [f64; 3], t: f64) -> Result<Taut, catenary::CatenaryError> {
        let path = self.path(b);
        if self.w > 0.0 {
            let (h, v, eh) = Self::span(b, path.exit);
            let spec = self.spec();
            let s = catenary::solve_given_tension(h, v, t, End::Lower, &spec)?;
            let f = [s.h_force * eh[0], s.h_force * eh[1], s.v0];
            // The winch gives way under the tension at the cable's upper end.
            return Ok(Taut { unstretched: s.l0 + path.wrap - self.k * s.t1(&spec), dir: scale3(f, 1.0 / s.t0()) });
        }
        let k = if self.ea.is_finite() { t / self.ea } else { 0.0 };
        Ok(Taut { unstretched: path.length() / (1.0 + k) - self.k * t, dir: path.dir })
    }

    /// The cable's action on the platform point `b` under `cmd`.
    ///
    /// Position mode needs a finite EA (see [`CableModel::rigidified`]). Energies are relative
    /// (constant terms dropped) and meant for the equilibrium solver's line search.
    pub fn load(&self, b: [f64; 3], cmd: CableCommand) -> CableLoad {
        self.load_warm(b, cmd, None)
    }

    /// [`CableModel::load`] with a catenary warm start: `warm` holds the last catenary of this
    /// cable and receives the new one (no effect without sag).
    pub fn load_warm(&self, b: [f64; 3], cmd: CableCommand, warm: Option<&Cell<Option<Catenary>>>) -> CableLoad {
        let path = self.path(b);
        let ell = path.length();
        if self.w > 0.0 {
            if let Some(l) = self.load_catenary(b, &path, cmd, warm) {
                return l;
            }
            // The catenary failed (degenerate span): fall through to the straight cable.
        }
        match cmd {
            CableCommand::Length(lu) => {
                // The cable (lu / EA per newton) and the winch's spring (k) in series.
                let give = lu / self.ea + self.k;
                if ell > lu {
                    let t = (ell - lu) / give;
                    CableLoad {
                        force: scale3(path.dir, t),
                        energy: 0.5 * (ell - lu) * (ell - lu) / give,
                        tension: t,
                        drum_length: lu,
                        slack: false,
                    }
                } else {
                    CableLoad { force: [0.0; 3], energy: 0.0, tension: 0.0, drum_length: lu, slack: true }
                }
            }
            CableCommand::Tension(t) => {
                let k = if self.ea.is_finite() { t / self.ea } else { 0.0 };
                CableLoad {
                    force: scale3(path.dir, t),
                    energy: t * ell,
                    tension: t,
                    drum_length: ell / (1.0 + k) - self.k * t,
                    slack: false,
                }
            }
        }
    }

    fn load_catenary(&self, b: [f64; 3], path: &PathGeom, cmd: CableCommand, warm: Option<&Cell<Option<Catenary>>>) -> Option<CableLoad> {
        let (h, v, eh) = Self::span(b, path.exit);
        let spec = self.spec();
        let guess = warm.and_then(Cell::get);
        let keep = |s: Catenary| {
            if let Some(w) = warm {
                w.set(Some(s));
            }
            s
        };
        let force = |s: &Catenary| [s.h_force * eh[0], s.h_force * eh[1], s.v0];
        match cmd {
            CableCommand::Length(lu) => {
                let lo = lu - path.wrap;
                let mut s = catenary::solve_given_length_from(h, v, lo, &spec, guess).ok()?;
                let (mut free, mut spring) = (lo, 0.0);
                if self.k > 0.0 {
                    // A compliant winch lets out k T_upper more than the drum holds: the root of
                    // g(L) = L - lo - k T_upper(L), increasing in L (the tension falls as the
                    // span lengthens), bracketed by [lo, lo + k T_upper(lo)]; a stiff short span
                    // makes k dT/dL exceed 1, so no fixed-point iteration. Illinois regula falsi.
                    let g = |l: f64, s: &Catenary| l - lo - self.k * s.t1(&spec);
                    let (mut a, mut ga) = (lo, g(lo, &s));
                    let mut b = lo + self.k * s.t1(&spec);
                    let mut sb = catenary::solve_given_length_from(h, v, b, &spec, Some(s)).ok()?;
                    let mut gb = g(b, &sb);
                    let mut side = 0;
                    for _ in 0..100 {
                        if gb.abs() < 1e-13 || (b - a).abs() < 1e-15 {
                            break;
                        }
                        let c = (a * gb - b * ga) / (gb - ga);
                        let sc = catenary::solve_given_length_from(h, v, c, &spec, Some(sb)).ok()?;
                        let gc = g(c, &sc);
                        if gc * gb < 0.0 {
                            (a, ga) = (b, gb);
                            side = 0;
                        } else if side == 1 {
                            ga *= 0.5;
                        } else {
                            side = 1;
                        }
                        (b, gb, sb) = (c, gc, sc);
                    }
                    (free, s) = (b, sb);
                    spring = 0.5 * self.k * s.t1(&spec).powi(2);
                }
                let s = keep(s);
                Some(CableLoad {
                    force: force(&s),
                    // Gravity of the whole cable at the platform's height plus the catenary's
                    // own energy: its gradient in b is minus the force (checked in catenary);
                    // the winch's spring adds its own (to first order in k).
                    energy: s.energy_rel(&spec) + self.w * free * b[2] + spring,
                    tension: s.t0(),
                    drum_length: lu,
                    slack: false,
                })
            }
            CableCommand::Tension(t) => {
                let s = keep(catenary::solve_given_tension_from(h, v, t, End::Upper, &spec, guess).ok()?);
                // Drive work t*L plus the cable's energy measured from the exit height, whose
                // derivative in L at fixed ends is -T_upper (inextensible): stationary in L.
                Some(CableLoad {
                    force: force(&s),
                    energy: t * (s.l0 + path.wrap) + s.energy_rel(&spec) - self.w * s.l0 * v,
                    tension: s.t0(),
                    drum_length: s.l0 + path.wrap - self.k * t,
                    slack: false,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const UP: [f64; 3] = [0.0, 0.0, 1.0];

    /// A compliant winch: the drum holds `k T` less than the rigid winch's cable at the same
    /// tension, straight or sagging, whatever the length; a position-mode drum that holds that
    /// length sees the same tension.
    #[test]
    fn a_compliant_winch_holds_k_t_less_cable_at_every_length() {
        let a = [3.5, -1.75, 4.0];
        let k = 2e-6;
        for base in
            [Physics { elasticity: Some(2e5), ..Physics::ideal() }, Physics { sag: Some(0.3), elasticity: Some(5e5), ..Physics::ideal() }]
        {
            let rigid = CableModel::new(a, UP, &base);
            let soft = CableModel::new(a, UP, &Physics { compliance_m_per_n: Some(k), ..base.clone() });
            for (b, t) in [([0.3, 0.2, 1.5], 150.0), ([-2.0, 1.5, 0.5], 400.0), ([3.0, -1.5, 3.5], 60.0)] {
                let (lr, ls) = (rigid.taut(b, t).unwrap().unstretched, soft.taut(b, t).unwrap().unstretched);
                // With sag the winch feels the upper end's tension, a little more than `t`.
                let t_upper = if base.sag.is_some() { t + 0.3 * (a[2] - b[2]) } else { t };
                assert!((lr - ls - k * t_upper).abs() < 0.02 * k * t, "{base:?} {b:?}: {}", (lr - ls) / k);
                let held = soft.load(b, CableCommand::Length(ls));
                assert!((held.tension - t).abs() < 1e-3 * t, "{base:?} {b:?}: {} N", held.tension);
            }
        }
    }

    #[test]
    fn pulley_path_limits_and_tangency() {
        let a = [1.0, 2.0, 4.0];
        let b = [3.0, -1.0, 1.0];
        let straight = CableModel::new(a, UP, &Physics::ideal()).path(b);
        assert!((straight.length() - norm(sub(b, a))).abs() < 1e-12);
        let tiny = CableModel::new(a, UP, &Physics { pulley: Some(1e-9), ..Physics::ideal() }).path(b);
        assert!((tiny.length() - straight.length()).abs() < 1e-8);
        let r = 0.1;
        let p = CableModel::new(a, UP, &Physics { pulley: Some(r), ..Physics::ideal() }).path(b);
        // The exit point is on the pulley circle, the straight segment is tangent there.
        let rho = sub(b, a)[0].hypot(sub(b, a)[1]);
        let uh = [sub(b, a)[0] / rho, sub(b, a)[1] / rho, 0.0];
        let c = [a[0] + r * uh[0], a[1] + r * uh[1], a[2]];
        let ce = sub(p.exit, c);
        assert!((norm(ce) - r).abs() < 1e-12);
        let dot = ce[0] * p.dir[0] + ce[1] * p.dir[1] + ce[2] * p.dir[2];
        assert!(dot.abs() < 1e-12, "segment not tangent: {dot}");
        // The wrap is between 0 and a half turn for a platform below the anchor, and the path is
        // longer than the distance from the anchor's tangent point to b minus the radius.
        assert!(p.wrap > 0.0 && p.wrap < std::f64::consts::PI * r);
        // Gradient of the path length is minus the direction (the exit point slides freely).
        let e = 1e-6;
        for k in 0..3 {
            let mut bp = b;
            let mut bm = b;
            bp[k] += e;
            bm[k] -= e;
            let m = CableModel::new(a, UP, &Physics { pulley: Some(r), ..Physics::ideal() });
            let g = (m.path(bp).length() - m.path(bm).length()) / (2.0 * e);
            assert!((g + p.dir[k]).abs() < 1e-7, "axis {k}: {g} vs {}", -p.dir[k]);
        }
    }

    /// A horizontal swivel axis: the cable comes in along it, wraps in the plane that holds the
    /// axis and the platform point, and leaves tangent to the pulley; by hand for a quarter turn.
    #[test]
    fn a_horizontal_axis_turns_the_pulley_plane() {
        let w = [1.0, 0.0, 0.0];
        let m = CableModel::new([0.0; 3], w, &Physics { pulley: Some(1.0), ..Physics::ideal() });
        // In the plane (w, down): centre 1 m below the anchor, b 1 m beyond it and 2 m down.
        let p = m.path([-1.0, 0.0, -2.0]);
        assert!((p.wrap - std::f64::consts::FRAC_PI_2).abs() < 1e-12, "{p:?}");
        assert!((p.straight - 1.0).abs() < 1e-12 && norm(sub(p.exit, [-1.0, 0.0, -1.0])) < 1e-12, "{p:?}");
        // Any axis: the exit point is on the circle about the centre in the plane of w and b,
        // and the free segment is tangent there.
        let a = [3.5, -1.75, 4.0];
        let n = 3.5f64.hypot(1.75);
        for w in [[3.5 / n, -1.75 / n, 0.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0]] {
            let r = 0.04;
            let m = CableModel::new(a, w, &Physics { pulley: Some(r), ..Physics::ideal() });
            for b in [[0.3, 0.2, 1.5], [-1.0, 1.0, 0.5], [2.0, -1.0, 3.0]] {
                let p = m.path(b);
                let d = sub(b, a);
                let along = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
                let perp = [d[0] - along * w[0], d[1] - along * w[1], d[2] - along * w[2]];
                let uh = scale3(perp, 1.0 / norm(perp));
                let c = [a[0] + r * uh[0], a[1] + r * uh[1], a[2] + r * uh[2]];
                let ce = sub(p.exit, c);
                assert!((norm(ce) - r).abs() < 1e-12);
                assert!(
                    (ce[0] * w[1] * uh[2] - ce[0] * w[2] * uh[1]
                        + ce[1] * (w[2] * uh[0] - w[0] * uh[2])
                        + ce[2] * (w[0] * uh[1] - w[1] * uh[0]))
                        .abs()
                        < 1e-12,
                    "exit out of the plane"
                );
                let dot = ce[0] * p.dir[0] + ce[1] * p.dir[1] + ce[2] * p.dir[2];
                assert!(dot.abs() < 1e-12, "segment not tangent: {dot}");
                assert!(p.wrap > 0.0 && p.length() > norm(d) - 1e-12);
            }
        }
    }

    /// Every load's energy gradient is minus its force (finite differences), for each effect.
    #[test]
    fn load_energy_gradient_is_minus_force() {
        let a = [3.5, -1.75, 4.0];
        let b = [0.3, 0.2, 1.5];
        let physics = [
            Physics::ideal(),
            Physics { elasticity: Some(2e5), ..Physics::ideal() },
            Physics { pulley: Some(0.05), ..Physics::ideal() },
            Physics { sag: Some(0.8), ..Physics::ideal() },
            Physics { sag: Some(0.8), elasticity: Some(5e4), pulley: Some(0.05), ..Physics::ideal() },
            Physics { compliance_m_per_n: Some(2e-6), elasticity: Some(2e5), ..Physics::ideal() },
        ];
        let out = [3.5 / 3.5f64.hypot(1.75), -1.75 / 3.5f64.hypot(1.75), 0.0];
        for (ph, w) in physics.iter().map(|p| (p, UP)).chain(physics[2..].iter().map(|p| (p, out))) {
            let m = CableModel::new(a, w, ph).rigidified();
            let lu = m.taut(b, 40.0).unwrap().unstretched;
            for (cmd, weight_at_platform) in [(CableCommand::Length(lu), false), (CableCommand::Tension(40.0), true)] {
                let l0 = m.load(b, cmd);
                // A follower holds 40 N at the anchor; at the platform a heavy cable pulls less by
                // about its weight per length times the rise.
                let weight = if weight_at_platform { m.w * (a[2] - b[2]) } else { 0.0 };
                assert!((l0.tension + weight - 40.0).abs() < 0.5, "{ph:?} {cmd:?}: {l0:?}");
                let e = 1e-6;
                for k in 0..3 {
                    let mut bp = b;
                    let mut bm = b;
                    bp[k] += e;
                    bm[k] -= e;
                    let g = (m.load(bp, cmd).energy - m.load(bm, cmd).energy) / (2.0 * e);
                    assert!((g + l0.force[k]).abs() < 2e-3 * 40.0, "{ph:?} {cmd:?} axis {k}: {g} vs {}", -l0.force[k]);
                }
            }
        }
    }
}
