//! The elastic catenary: a heavy, stretchable cable hanging between a lower end (the platform) and
//! an upper end (the anchor or pulley exit), solved exactly, not with the parabolic approximation.
//!
//! ```text
//! plane of the cable: x horizontal from the lower end B towards the upper end E, z up
//!
//!              E = (h, v)      s: unstretched arc length from B (0) to E (L)
//!             /                w: weight per unstretched length, N/m
//!           ./                 H: horizontal force, constant along the cable
//!     B ---'                   V(s) = V0 + w s: vertical force at s
//!  (0, 0)                      T(s) = sqrt(H^2 + V(s)^2)
//! ```
//!
//! The cable pulls the platform with `(H, V0)` (towards E, up). Integrating
//! `dx/ds = H/T (1 + T/EA)` and `dz/ds = V/T (1 + T/EA)` from 0 to L (Irvine, *Cable Structures*):
//!
//! ```text
//! h = H L/EA + (H/w) [asinh(V1/H) - asinh(V0/H)]
//! v = (V0 L + w L^2/2)/EA + (1/w) [T1 - T0]              V1 = V0 + w L
//! ```
//!
//! With `EA = inf` this is the inextensible catenary. The module solves these equations for the
//! unknown forces given the unstretched length ([`solve_given_length`], a cable held by a drive in
//! position mode) or for the forces and length given the tension at one end
//! ([`solve_given_tension`], a cable whose tension is known), by damped Newton with the analytic
//! Jacobian.

/// Cable properties for the catenary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableSpec {
    /// Weight per unstretched length, N/m (> 0).
    pub w: f64,
    /// Axial stiffness EA, N; `f64::INFINITY` for an inextensible cable.
    pub ea: f64,
}

/// A solved catenary: the forces at the lower end and the unstretched length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Catenary {
    /// Horizontal force, N (> 0).
    pub h_force: f64,
    /// Vertical force the cable exerts on the lower end, N, positive up.
    pub v0: f64,
    /// Unstretched length, m.
    pub l0: f64,
}

/// Which end's tension is given to [`solve_given_tension`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// The lower end (the platform attachment: what a load cell there reads).
    Lower,
    /// The upper end (the anchor side: what a drive in torque mode holds).
    Upper,
}

/// Why a catenary could not be solved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CatenaryError {
    /// The inputs are not finite or not positive where they must be.
    BadInput,
    /// An inextensible cable shorter than the chord cannot span it.
    TooShort {
        /// Unstretched length, m.
        l0: f64,
        /// Chord, m.
        chord: f64,
    },
    /// Newton did not converge; `residual` is the remaining end-point mismatch, m.
    NoConvergence {
        /// Remaining residual norm (m, or N for the tension equation).
        residual: f64,
    },
}

impl std::fmt::Display for CatenaryError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CatenaryError::BadInput => write!(f, "catenary: inputs must be finite and positive"),
            CatenaryError::TooShort { l0, chord } => {
                write!(f, "catenary: an inextensible cable of {l0} m cannot span a {chord} m chord")
            }
            CatenaryError::NoConvergence { residual } => {
                write!(f, "catenary: Newton did not converge (residual {residual:e})")
            }
        }
    }
}

impl std::error::Error for CatenaryError {}

/// `1/EA`, zero for an inextensible cable.
fn compliance(ea: f64) -> f64 {
    if ea.is_finite() {
        1.0 / ea
    } else {
        0.0
    }
}

impl Catenary {
    /// Vertical force at the upper end, N (what holds the cable up there).
    pub fn v1(&self, c: &CableSpec) -> f64 {
        self.v0 + c.w * self.l0
    }

    /// Tension at the lower end, N.
    pub fn t0(&self) -> f64 {
        self.h_force.hypot(self.v0)
    }

    /// Tension at the upper end, N.
    pub fn t1(&self, c: &CableSpec) -> f64 {
        self.h_force.hypot(self.v1(c))
    }

    /// The upper end relative to the lower end, `(h, v)`, m.
    pub fn end(&self, c: &CableSpec) -> (f64, f64) {
        let (hf, v0, l) = (self.h_force, self.v0, self.l0);
        let k = compliance(c.ea);
        let v1 = v0 + c.w * l;
        let x = hf * l * k + (hf / c.w) * ((v1 / hf).asinh() - (v0 / hf).asinh());
        let z = (v0 * l + 0.5 * c.w * l * l) * k + (hf.hypot(v1) - hf.hypot(v0)) / c.w;
        (x, z)
    }

    /// Jacobian of [`Catenary::end`]: rows `(h, v)`, columns `(H, V0, L)`.
    pub fn end_jacobian(&self, c: &CableSpec) -> [[f64; 3]; 2] {
        let (hf, v0, l, w) = (self.h_force, self.v0, self.l0, c.w);
        let k = compliance(c.ea);
        let v1 = v0 + w * l;
        let (t0, t1) = (hf.hypot(v0), hf.hypot(v1));
        let dx_dh = l * k + ((v1 / hf).asinh() - (v0 / hf).asinh() - v1 / t1 + v0 / t0) / w;
        let dx_dv = (hf / w) * (1.0 / t1 - 1.0 / t0);
        let dx_dl = hf * k + hf / t1;
        let dz_dh = (hf / t1 - hf / t0) / w;
        let dz_dv = l * k + (v1 / t1 - v0 / t0) / w;
        let dz_dl = v1 * k + v1 / t1;
        [[dx_dh, dx_dv, dx_dl], [dz_dh, dz_dv, dz_dl]]
    }

    /// Stretched arc length, m (equals `l0` for an inextensible cable).
    pub fn arc_length(&self, c: &CableSpec) -> f64 {
        // ds_stretched = (1 + T/EA) ds; integral of T ds over V (dV = w ds).
        let k = compliance(c.ea);
        let v1 = self.v1(c);
        let prim = |v: f64| {
            let t = self.h_force.hypot(v);
            0.5 * (v * t + self.h_force * self.h_force * (v / self.h_force).asinh())
        };
        self.l0 + k * (prim(v1) - prim(self.v0)) / c.w
    }

    /// Potential energy of the cable, J: strain energy plus gravity, with the height measured from
    /// the lower end. The gravity of the whole cable at the lower end's height (`w L z_lower`) is
    /// left to the caller.
    ///
    /// For a cable of fixed unstretched length the gradient of (this + `w L z_lower`) with respect
    /// to the lower end is minus the force on the lower end, which the tests check.
    pub fn energy_rel(&self, c: &CableSpec) -> f64 {
        let (hf, v0, l, w) = (self.h_force, self.v0, self.l0, c.w);
        let k = compliance(c.ea);
        let v1 = v0 + w * l;
        let (_, v) = self.end(c);
        // Gravity: w * int_0^L (z(s) - z(0)) ds = w * (L v - int_0^L s z'(s) ds), the last
        // integral by Gauss-Legendre quadrature (no 1/w^2 cancellation for light cables).
        let mut i_sz = 0.0;
        for (x, wt) in GL16 {
            let s = 0.5 * l * (1.0 + x);
            let vv = v0 + w * s;
            let t = hf.hypot(vv);
            i_sz += wt * s * (vv / t + vv * k);
        }
        i_sz *= 0.5 * l;
        let strain = 0.5 * k * (hf * hf * l + (v1.powi(3) - v0.powi(3)) / (3.0 * w));
        strain + w * (l * v - i_sz)
    }
}

/// 16-point Gauss-Legendre nodes and weights on [-1, 1].
const GL16: [(f64, f64); 16] = [
    (-0.989_400_934_991_649_9, 0.027_152_459_411_754_1),
    (-0.944_575_023_073_232_6, 0.062_253_523_938_647_9),
    (-0.865_631_202_387_831_7, 0.095_158_511_682_492_8),
    (-0.755_404_408_355_003, 0.124_628_971_255_533_9),
    (-0.617_876_244_402_643_7, 0.149_595_988_816_576_7),
    (-0.458_016_777_657_227_4, 0.169_156_519_395_002_5),
    (-0.281_603_550_779_258_9, 0.182_603_415_044_923_6),
    (-0.095_012_509_837_637_4, 0.189_450_610_455_068_5),
    (0.095_012_509_837_637_4, 0.189_450_610_455_068_5),
    (0.281_603_550_779_258_9, 0.182_603_415_044_923_6),
    (0.458_016_777_657_227_4, 0.169_156_519_395_002_5),
    (0.617_876_244_402_643_7, 0.149_595_988_816_576_7),
    (0.755_404_408_355_003, 0.124_628_971_255_533_9),
    (0.865_631_202_387_831_7, 0.095_158_511_682_492_8),
    (0.944_575_023_073_232_6, 0.062_253_523_938_647_9),
    (0.989_400_934_991_649_9, 0.027_152_459_411_754_1),
];

const MAX_ITER: usize = 60;

/// Solves for the forces of a cable of unstretched length `l0` spanning `(h, v)`.
pub fn solve_given_length(h: f64, v: f64, l0: f64, c: &CableSpec) -> Result<Catenary, CatenaryError> {
    solve_given_length_from(h, v, l0, c, None)
}

/// [`solve_given_length`] warm-started from the forces of `guess` (e.g. the last solution of a
/// nearby span).
pub fn solve_given_length_from(h: f64, v: f64, l0: f64, c: &CableSpec, guess: Option<Catenary>) -> Result<Catenary, CatenaryError> {
    match (length_inner(h, v, l0, c, guess), guess) {
        // A poor warm start must not fail where a cold one succeeds.
        (Err(_), Some(_)) => length_inner(h, v, l0, c, None),
        (r, _) => r,
    }
}

fn length_inner(h: f64, v: f64, l0: f64, c: &CableSpec, guess: Option<Catenary>) -> Result<Catenary, CatenaryError> {
    if !(h.is_finite() && v.is_finite() && l0 > 0.0 && h > 0.0 && c.w > 0.0 && c.ea > 0.0) {
        return Err(CatenaryError::BadInput);
    }
    let chord = h.hypot(v);
    if !c.ea.is_finite() && l0 <= chord {
        return Err(CatenaryError::TooShort { l0, chord });
    }
    let mut st = if let Some(g) = guess.filter(|g| g.h_force > 0.0 && g.h_force.is_finite() && g.v0.is_finite()) {
        Catenary { h_force: g.h_force, v0: g.v0, l0 }
    } else if l0 > chord * (1.0 + 1e-9) {
        inextensible_guess(h, v, l0, c.w)
    } else {
        if !c.ea.is_finite() {
            return Err(CatenaryError::TooShort { l0, chord });
        }
        // Taut: the straight elastic cable's tension, the weight shared between the ends.
        let t = c.ea * (chord / l0 - 1.0) + c.w * l0;
        Catenary { h_force: t * h / chord, v0: t * v / chord - 0.5 * c.w * l0, l0 }
    };
    let scale = chord;
    let res = |s: &Catenary| {
        let (x, z) = s.end(c);
        [x - h, z - v]
    };
    let mut r = res(&st);
    for _ in 0..MAX_ITER {
        let norm = r[0].hypot(r[1]);
        if norm < 1e-12 * scale {
            return Ok(st);
        }
        let j = st.end_jacobian(c);
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.is_finite() && det != 0.0) {
            break;
        }
        let mut dh = -(j[1][1] * r[0] - j[0][1] * r[1]) / det;
        let mut dv = -(-j[1][0] * r[0] + j[0][0] * r[1]) / det;
        // Keep H positive: never step more than 90 % of the way to zero.
        if st.h_force + dh < 0.1 * st.h_force {
            let f = 0.9 * st.h_force / -dh;
            dh *= f;
            dv *= f;
        }
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..30 {
            let cand = Catenary { h_force: st.h_force + alpha * dh, v0: st.v0 + alpha * dv, l0 };
            let rc = res(&cand);
            let nc = rc[0].hypot(rc[1]);
            if nc.is_finite() && nc < norm * (1.0 - 1e-4 * alpha) {
                st = cand;
                r = rc;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            break;
        }
    }
    let norm = r[0].hypot(r[1]);
    if norm < 1e-9 * scale {
        Ok(st)
    } else {
        Err(CatenaryError::NoConvergence { residual: norm })
    }
}

/// A starting point for a cable longer than its chord: the inextensible catenary of that length,
/// found by bisection (both equations are monotone in the unknown they are solved for).
fn inextensible_guess(h: f64, v: f64, l0: f64, w: f64) -> Catenary {
    // sqrt(L^2 - v^2) = (2H/w) sinh(w h / (2H)), decreasing in H towards h.
    let target = (l0 * l0 - v * v).max(h * h * (1.0 + 1e-12)).sqrt();
    let f = |hf: f64| {
        let a = w * h / (2.0 * hf);
        // Large a: compare logarithms to avoid overflow.
        if a > 300.0 {
            (a + (hf / (w * h)).ln()) - target.ln()
        } else {
            ((2.0 * hf / w) * a.sinh()).ln() - target.ln()
        }
    };
    let (mut lo, mut hi) = (1e-9 * w * l0, 1e9 * w * l0);
    for _ in 0..200 {
        let mid = (lo * hi).sqrt();
        if f(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi / lo < 1.0 + 1e-9 {
            break;
        }
    }
    let hf = (lo * hi).sqrt();
    // v = (T1 - T0)/w, increasing in V0.
    let g = |v0: f64| (hf.hypot(v0 + w * l0) - hf.hypot(v0)) / w - v;
    let (mut a, mut b) = (-w * l0 - 1e3 * hf - 1.0, 1e3 * hf + 1.0);
    while g(a) > 0.0 {
        a *= 2.0;
    }
    while g(b) < 0.0 {
        b *= 2.0;
    }
    for _ in 0..80 {
        let m = 0.5 * (a + b);
        if g(m) > 0.0 {
            b = m;
        } else {
            a = m;
        }
    }
    Catenary { h_force: hf, v0: 0.5 * (a + b), l0 }
}

/// Solves for the forces and the unstretched length of a cable spanning `(h, v)` whose tension at
/// `end` is `t`.
pub fn solve_given_tension(h: f64, v: f64, t: f64, end: End, c: &CableSpec) -> Result<Catenary, CatenaryError> {
    solve_given_tension_from(h, v, t, end, c, None)
}

/// [`solve_given_tension`] warm-started from `guess`.
pub fn solve_given_tension_from(
    h: f64,
    v: f64,
    t: f64,
    end: End,
    c: &CableSpec,
    guess: Option<Catenary>,
) -> Result<Catenary, CatenaryError> {
    match (tension_inner(h, v, t, end, c, guess), guess) {
        (Err(_), Some(_)) => tension_inner(h, v, t, end, c, None),
        (r, _) => r,
    }
}

fn tension_inner(h: f64, v: f64, t: f64, end: End, c: &CableSpec, guess: Option<Catenary>) -> Result<Catenary, CatenaryError> {
    if !(h.is_finite() && v.is_finite() && t > 0.0 && h > 0.0 && c.w > 0.0 && c.ea > 0.0) {
        return Err(CatenaryError::BadInput);
    }
    let chord = h.hypot(v);
    let k = compliance(c.ea);
    let mut st = match guess.filter(|g| g.h_force > 0.0 && g.l0 > 0.0 && g.h_force.is_finite() && g.v0.is_finite()) {
        Some(g) => g,
        None => {
            // Start from the straight cable with the tension along the chord.
            let l = chord / (1.0 + t * k);
            let share = if end == End::Upper { 1.0 } else { 0.5 };
            Catenary { h_force: t * h / chord, v0: t * v / chord - share * c.w * l, l0: l }
        }
    };
    let res = |s: &Catenary| {
        let (x, z) = s.end(c);
        let te = match end {
            End::Lower => s.t0(),
            End::Upper => s.t1(c),
        };
        [x - h, z - v, (te - t) / t * chord]
    };
    let mut r = res(&st);
    for _ in 0..MAX_ITER {
        let norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        if norm < 1e-12 * chord {
            return Ok(st);
        }
        let je = st.end_jacobian(c);
        let (hf, v0) = (st.h_force, st.v0);
        let jt = match end {
            End::Lower => {
                let t0 = st.t0();
                [hf / t0, v0 / t0, 0.0]
            }
            End::Upper => {
                let (v1, t1) = (st.v1(c), st.t1(c));
                [hf / t1, v1 / t1, c.w * v1 / t1]
            }
        };
        let m = nalgebra::Matrix3::new(
            je[0][0],
            je[0][1],
            je[0][2],
            je[1][0],
            je[1][1],
            je[1][2],
            jt[0] / t * chord,
            jt[1] / t * chord,
            jt[2] / t * chord,
        );
        let Some(d) = m.lu().solve(&nalgebra::Vector3::new(-r[0], -r[1], -r[2])) else {
            break;
        };
        let mut d = [d[0], d[1], d[2]];
        // Keep H and L positive.
        let mut f: f64 = 1.0;
        if st.h_force + d[0] < 0.1 * st.h_force {
            f = f.min(0.9 * st.h_force / -d[0]);
        }
        if st.l0 + d[2] < 0.5 * st.l0 {
            f = f.min(0.5 * st.l0 / -d[2]);
        }
        for x in &mut d {
            *x *= f;
        }
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..30 {
            let cand = Catenary { h_force: hf + alpha * d[0], v0: v0 + alpha * d[1], l0: st.l0 + alpha * d[2] };
            let rc = res(&cand);
            let nc = (rc[0] * rc[0] + rc[1] * rc[1] + rc[2] * rc[2]).sqrt();
            if nc.is_finite() && nc < norm * (1.0 - 1e-4 * alpha) {
                st = cand;
                r = rc;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            break;
        }
    }
    let norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if norm < 1e-9 * chord {
        Ok(st)
    } else {
        Err(CatenaryError::NoConvergence { residual: norm })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Integrates the inextensible cable's shape ODE z'' = (w/H) sqrt(1 + z'^2) over x with RK4
    /// from the lower end, returning the end height and the arc length (fine-step quadrature of
    /// sqrt(1 + z'^2)): independent of the closed-form equations above.
    fn integrate_shape(hf: f64, v0: f64, w: f64, h: f64, steps: usize) -> (f64, f64) {
        let f = |y: [f64; 3]| {
            let s = (1.0 + y[1] * y[1]).sqrt();
            [y[1], w / hf * s, s]
        };
        let dx = h / steps as f64;
        let mut y = [0.0, v0 / hf, 0.0];
        for _ in 0..steps {
            let k1 = f(y);
            let k2 = f(std::array::from_fn(|i| y[i] + 0.5 * dx * k1[i]));
            let k3 = f(std::array::from_fn(|i| y[i] + 0.5 * dx * k2[i]));
            let k4 = f(std::array::from_fn(|i| y[i] + dx * k3[i]));
            y = std::array::from_fn(|i| y[i] + dx / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
        }
        (y[0], y[2])
    }

    #[test]
    fn arc_length_matches_integrated_curve() {
        let c = CableSpec { w: 1.2, ea: f64::INFINITY };
        // An outdoor span, a shallow and a steep cable, low and high tension.
        for &(h, v, t) in &[(14.0, 9.0, 150.0), (14.0, 9.0, 20.0), (3.0, 2.5, 30.0), (20.0, -1.0, 60.0)] {
            let s = solve_given_tension(h, v, t, End::Lower, &c).unwrap();
            assert!((s.t0() - t).abs() < 1e-8 * t);
            let (z_end, arc) = integrate_shape(s.h_force, s.v0, c.w, h, 20_000);
            assert!((z_end - v).abs() < 1e-8, "end height {z_end} vs {v}");
            assert!((arc - s.l0).abs() < 1e-8, "arc {arc} vs {} (h {h} v {v} t {t})", s.l0);
            assert!(s.l0 > h.hypot(v), "a hanging cable is longer than its chord");
        }
    }

    #[test]
    fn length_and_tension_solvers_agree() {
        for ea in [f64::INFINITY, 2e5] {
            let c = CableSpec { w: 0.8, ea };
            let s = solve_given_tension(10.0, 6.0, 80.0, End::Upper, &c).unwrap();
            assert!((s.t1(&c) - 80.0).abs() < 1e-8);
            let back = solve_given_length(10.0, 6.0, s.l0, &c).unwrap();
            assert!((back.h_force - s.h_force).abs() < 1e-6, "{back:?} vs {s:?}");
            assert!((back.v0 - s.v0).abs() < 1e-6);
        }
        // Very slack and nearly taut inextensible cables.
        let c = CableSpec { w: 0.5, ea: f64::INFINITY };
        for l in [12.0, 30.0, 11.662] {
            let s = solve_given_length(10.0, 6.0, l, &c).unwrap();
            let (x, z) = s.end(&c);
            assert!((x - 10.0).abs() < 1e-9 && (z - 6.0).abs() < 1e-9);
        }
        assert!(matches!(solve_given_length(10.0, 6.0, 11.0, &c), Err(CatenaryError::TooShort { .. })));
    }

    #[test]
    fn elastic_stretch_matches_hooke_for_a_light_cable() {
        let c = CableSpec { w: 1e-4, ea: 1e5 };
        let s = solve_given_tension(3.0, 4.0, 100.0, End::Lower, &c).unwrap();
        let expected = 5.0 / (1.0 + 100.0 / 1e5);
        assert!((s.l0 - expected).abs() < 1e-6, "{} vs {expected}", s.l0);
        assert!((s.arc_length(&c) - 5.0).abs() < 1e-6);
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        for ea in [f64::INFINITY, 3e4] {
            let c = CableSpec { w: 2.0, ea };
            let s = Catenary { h_force: 40.0, v0: -5.0, l0: 9.0 };
            let j = s.end_jacobian(&c);
            let eps = [1e-5, 1e-5, 1e-7];
            for col in 0..3 {
                let mut p = [s.h_force, s.v0, s.l0];
                let mut m = p;
                p[col] += eps[col];
                m[col] -= eps[col];
                let ep = Catenary { h_force: p[0], v0: p[1], l0: p[2] }.end(&c);
                let em = Catenary { h_force: m[0], v0: m[1], l0: m[2] }.end(&c);
                let fd = [(ep.0 - em.0) / (2.0 * eps[col]), (ep.1 - em.1) / (2.0 * eps[col])];
                for row in 0..2 {
                    assert!((fd[row] - j[row][col]).abs() < 1e-6 * (1.0 + fd[row].abs()), "d{row}/d{col}: {} vs {}", fd[row], j[row][col]);
                }
            }
        }
    }

    #[test]
    fn energy_gradient_is_minus_the_end_force() {
        for ea in [f64::INFINITY, 5e4] {
            let c = CableSpec { w: 1.5, ea };
            let (h, v, l) = (8.0, 5.0, 9.6);
            // Total energy as a function of the lower end's position (x_b, z_b); upper end fixed.
            let u = |xb: f64, zb: f64| {
                let s = solve_given_length(h - xb, v - zb, l, &c).unwrap();
                s.energy_rel(&c) + c.w * l * zb
            };
            let s = solve_given_length(h, v, l, &c).unwrap();
            let e = 1e-5;
            let gx = (u(e, 0.0) - u(-e, 0.0)) / (2.0 * e);
            let gz = (u(0.0, e) - u(0.0, -e)) / (2.0 * e);
            assert!((gx + s.h_force).abs() < 1e-4 * s.h_force, "{gx} vs {}", -s.h_force);
            assert!((gz + s.v0).abs() < 1e-4 * s.t0(), "{gz} vs {}", -s.v0);
        }
    }
}
