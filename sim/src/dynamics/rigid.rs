//! The dynamic plant's rigid platform: translation and rotation under the cables' pulls.
//!
//! With [`Dynamics::rigid_body`] set, the platform is a rigid body of mass `m` (kg) with its
//! centre of mass at `c` (platform frame, from the reference point, m) and inertia tensor `I`
//! about the centre of mass (platform frame, kg m²). Its state is the centre of mass `x`, its
//! velocity `v`, the orientation `q` (unit quaternion w, x, y, z; rotation matrix `R`) and the
//! angular momentum `L` about the centre of mass (world frame). Cable `j` pulls at its attachment
//! point `a_j = x + r_j`, `r_j = R (b_j - c)`, with the tension of [`crate::dynamics`]'s
//! Kelvin-Voigt cable; the dashpot sees the attachment point's velocity `v + w x r_j`:
//!
//! ```text
//! m dv/dt = sum_j T_j u_j + m g - d_v v,              dx/dt = v
//! dL/dt   = sum_j r_j x T_j u_j - d_w w,              w = R I^-1 R^T L,     dq/dt = (0, w) q / 2
//! ```
//!
//! with the drags `d_v` ([`RigidBody::drag_n_s_m`]) and `d_w` ([`RigidBody::angular_drag_n_m_s`]),
//! zero by default. The cables' dashpots damp only motions that stretch a cable; a platform on
//! fewer than six taut cables keeps modes that stretch none (to first order), which only the
//! drags damp.
//!
//! The reference point (what the tracker reports) is `p = x - R c`. Gravity acts at the centre
//! of mass, so it exerts no moment about it.
//!
//! # Integrator
//!
//! The point-mass plant's semi-implicit Euler extended to rotation: per sub-step `h`, with the
//! forces and moments at the sub-step's start, `v += h F / m`, `x += h v`, `L += h tau`, then
//! `w = R I^-1 R^T L` and the rotation by `w h` applied exactly (`q <- exp(w h / 2) q`,
//! renormalised). Without moments `L` is kept to round-off; the energy of a free spin drifts
//! with the first-order error of `w` over a sub-step. The stability limit of the point-mass plant
//! (see [`crate::dynamics`]) takes each cable's stiffness times `1 / m + |r_j|² / I_min` (the
//! inverse of the effective mass a pull at `r_j` meets, bounded with the smallest principal
//! moment `I_min`) instead of `1 / m`.

use nalgebra::{Matrix3, Vector3};

use crate::physics::{CableCommand, CableLoad, G};

use super::{Body, Dynamics};

/// A rigid platform's mass distribution beyond its mass. Units in each field's name.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidBody {
    /// Inertia tensor about the centre of mass, platform frame, kg m² (symmetric, positive
    /// definite).
    pub inertia_kg_m2: [[f64; 3]; 3],
    /// Centre of mass, platform frame, from the reference point, m.
    pub com_m: [f64; 3],
    /// Viscous drag on the centre of mass's velocity (air, a hanging tool's hose), N s/m.
    /// Default 0. The cables' dashpots act along the cables only: with fewer than six taut
    /// cables the platform has modes that stretch no cable, and only this drag damps them.
    pub drag_n_s_m: f64,
    /// Viscous drag on the angular velocity, N m s. Default 0 (see `drag_n_s_m`).
    pub angular_drag_n_m_s: f64,
}

impl RigidBody {
    /// A uniform box of mass `mass_kg` and edges `size_m` (x, y, z) centred at `com_m`.
    pub fn uniform_box(mass_kg: f64, size_m: [f64; 3], com_m: [f64; 3]) -> Self {
        let [a, b, c] = size_m.map(|s| s * s);
        let k = mass_kg / 12.0;
        RigidBody {
            inertia_kg_m2: [[k * (b + c), 0.0, 0.0], [0.0, k * (a + c), 0.0], [0.0, 0.0, k * (a + b)]],
            com_m,
            drag_n_s_m: 0.0,
            angular_drag_n_m_s: 0.0,
        }
    }
}

/// Rotation matrix of the unit quaternion `q` (w, x, y, z).
pub(crate) fn matrix(q: [f64; 4]) -> Matrix3<f64> {
    let r = crate::trajectory::rotation(q);
    Matrix3::from_fn(|i, k| r[i][k])
}

/// The quaternion product `a b`.
fn mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

/// `exp(phi / 2)`: the unit quaternion of a rotation by the vector `phi` (rad).
fn exp(phi: Vector3<f64>) -> [f64; 4] {
    let a = phi.norm();
    if a < 1e-12 {
        return [1.0, 0.5 * phi[0], 0.5 * phi[1], 0.5 * phi[2]];
    }
    let s = (0.5 * a).sin() / a;
    [(0.5 * a).cos(), s * phi[0], s * phi[1], s * phi[2]]
}

fn normalised(q: [f64; 4]) -> [f64; 4] {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.map(|x| x / n)
}

/// The rotational state of a rigid platform.
#[derive(Debug, Clone)]
pub(crate) struct RigidState {
    /// Drags: translation (N s/m), rotation (N m s).
    drag: f64,
    angular_drag: f64,
    /// Centre of mass, platform frame, m.
    com: Vector3<f64>,
    /// Inertia about the centre of mass and its inverse, platform frame.
    inertia: Matrix3<f64>,
    inv_inertia: Matrix3<f64>,
    /// Smallest principal moment, kg m².
    i_min: f64,
    /// Orientation (w, x, y, z).
    pub q: [f64; 4],
    /// Angular momentum about the centre of mass, world frame, N m s.
    pub l: Vector3<f64>,
}

impl RigidState {
    /// At rest, orientation `q`.
    ///
    /// # Panics
    /// If the inertia tensor is not symmetric positive definite.
    pub fn new(body: &RigidBody, q: [f64; 4]) -> Self {
        let inertia = Matrix3::from_fn(|i, k| body.inertia_kg_m2[i][k]);
        let sym = 0.5 * (inertia + inertia.transpose());
        assert!((inertia - sym).norm() <= 1e-12 * sym.norm(), "the inertia tensor must be symmetric");
        let i_min = sym.symmetric_eigenvalues().min();
        assert!(i_min > 0.0, "the inertia tensor must be positive definite");
        let inv_inertia = sym.try_inverse().expect("positive definite");
        RigidState {
            drag: body.drag_n_s_m,
            angular_drag: body.angular_drag_n_m_s,
            com: Vector3::from(body.com_m),
            inertia: sym,
            inv_inertia,
            i_min,
            q: normalised(q),
            l: Vector3::zeros(),
        }
    }

    /// Angular velocity, world frame, rad/s.
    pub fn omega(&self) -> Vector3<f64> {
        let r = matrix(self.q);
        r * self.inv_inertia * r.transpose() * self.l
    }

    /// Adds `dw` (world frame, rad/s) to the angular velocity.
    pub fn add_omega(&mut self, dw: [f64; 3]) {
        let r = matrix(self.q);
        self.l += r * self.inertia * r.transpose() * Vector3::from(dw);
    }

    /// The centre of mass's offset from the reference point, world frame, m.
    pub fn com_offset(&self) -> Vector3<f64> {
        matrix(self.q) * self.com
    }

    /// Rotational kinetic energy, J.
    pub fn kinetic(&self) -> f64 {
        0.5 * self.l.dot(&self.omega())
    }
}

/// The attachment points relative to the centre of mass, world frame, for orientation `q`.
pub(super) fn arms(rs: &RigidState, body: &Body<'_>, r: &Matrix3<f64>, out: &mut [[f64; 3]]) {
    for (o, b) in out.iter_mut().zip(body.points) {
        let a = r * (Vector3::from(*b) - rs.com);
        *o = [a[0], a[1], a[2]];
    }
}

impl super::DynState {
    /// Cable forces on the rigid platform with centre of mass `x`: fills `loads` and the world
    /// offsets `offsets` (`R b_j`); returns the net force (with gravity, N) and the moment about
    /// the centre of mass (N m).
    pub(super) fn rigid_forces(
        &self,
        rs: &RigidState,
        body: &Body<'_>,
        x: Vector3<f64>,
        arm: &mut [[f64; 3]],
        loads: &mut [CableLoad],
    ) -> (Vector3<f64>, Vector3<f64>) {
        let r = matrix(rs.q);
        arms(rs, body, &r, arm);
        let w = rs.omega();
        let v = Vector3::from(self.v);
        let mut f = Vector3::new(0.0, 0.0, -body.mass * G) - rs.drag * v;
        let mut tau = -rs.angular_drag * w;
        for (j, m) in body.models.iter().enumerate() {
            let rj = Vector3::from(arm[j]);
            let a = x + rj;
            let path = m.path([a[0], a[1], a[2]]);
            let ell_dot = -Vector3::from(path.dir).dot(&(v + w.cross(&rj)));
            loads[j] = self.cable_load(j, m.ea, body.mass, path.length(), ell_dot, path.dir);
            let pull = Vector3::from(loads[j].force);
            f += pull;
            tau += rj.cross(&pull);
        }
        (f, tau)
    }

    /// The longest stable sub-step of the rigid platform (see the module doc), s.
    pub(super) fn rigid_substep_limit(
        &self,
        rs: &RigidState,
        body: &Body<'_>,
        x: Vector3<f64>,
        arm: &[[f64; 3]],
        cmds: &[CableCommand],
        loads: &[CableLoad],
    ) -> f64 {
        let half = |w: f64, z: f64| ((1.0 + z * z).sqrt() - z) / w;
        let (mut w2, mut csum) = (0.0, 0.0);
        let mut limit = self.params.max_substep_s;
        for (j, m) in body.models.iter().enumerate() {
            let rj = Vector3::from(arm[j]);
            let a = x + rj;
            let path = m.path([a[0], a[1], a[2]]);
            let k = m.ea / self.drum[j].max(1e-6);
            let c = self.params.damping(k, body.mass);
            let t = loads[j].tension.max(0.0);
            let inv_m = 1.0 / body.mass + rj.norm_squared() / rs.i_min;
            w2 += (k + 2.0 * t / path.straight.max(1e-6)) * inv_m + t * rj.norm() / rs.i_min;
            csum += c * inv_m;
            if let CableCommand::Tension(_) = cmds[j] {
                let md = self.params.drum_mass_kg.max(1e-9);
                let w = (k / md).sqrt();
                limit = limit.min(half(w, (c + self.params.drum_friction_n_s_m) / (2.0 * md * w)));
            }
        }
        let w = w2.sqrt();
        limit.min(half(w, csum / (2.0 * w)))
    }

    /// One sub-step `h` of the rigid platform with centre of mass `x` (in and out).
    pub(super) fn rigid_substep(&mut self, body: &Body<'_>, x: &mut Vector3<f64>, h: f64, arm: &mut [[f64; 3]], loads: &mut [CableLoad]) {
        let mut rs = self.rigid.take().expect("rigid");
        let (f, tau) = self.rigid_forces(&rs, body, *x, arm, loads);
        let v = Vector3::from(self.v) + h * f / body.mass;
        *x += h * v;
        self.v = [v[0], v[1], v[2]];
        rs.l += h * tau;
        let w = rs.omega();
        rs.q = normalised(mul(exp(h * w), rs.q));
        self.rigid = Some(rs);
    }
}

/// The reference point `x - R c` of a centre of mass `x`.
pub(crate) fn reference_point(rs: &RigidState, x: Vector3<f64>) -> [f64; 3] {
    let p = x - rs.com_offset();
    [p[0], p[1], p[2]]
}

/// The centre of mass `p + R c` of a reference point `p`.
pub(crate) fn centre_of_mass(rs: &RigidState, p: [f64; 3]) -> Vector3<f64> {
    Vector3::from(p) + rs.com_offset()
}

impl Dynamics {
    /// True when the platform is a rigid body ([`Dynamics::rigid_body`]).
    pub fn is_rigid(&self) -> bool {
        self.rigid_body.is_some()
    }
}
