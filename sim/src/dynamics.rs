//! The plant's dynamic mode: the platform's mass swinging on elastic, damped cables.
//!
//! Switched on with [`Physics::dynamics`] (`Some(Dynamics::default())`); [`crate::Plant`] keeps
//! its API, its sensors and its outputs, only the physics behind them changes.
//!
//! # Model
//!
//! By default the platform is a point mass `m` (kg) at its reference point `p` (m). Its
//! orientation is imposed, as in the quasi-static plant ([`crate::Plant::set_orientation`]): the
//! cables pull at the attachment points `p + R b_j`, but their moments are not integrated, so the
//! platform has no rotational inertia. With [`Dynamics::rigid_body`] it is a rigid body that
//! also turns under the cables' moments (see [`rigid`]: the same cables, forces and drums). The
//! point mass obeys
//!
//! ```text
//! m dv/dt = sum_j T_j u_j + m g,     dp/dt = v
//! ```
//!
//! with `g = (0, 0, -9.81)` m/s² and `u_j` the unit vector from the attachment point towards the
//! cable's exit point at the anchor (its pulley's tangent point with a pulley). Cable `j` is a
//! massless spring and dashpot in parallel (Kelvin-Voigt) between the drum and the platform:
//!
//! ```text
//! s_j = L_j - D_j                                  stretch, m
//! T_j = max(0, k_j s_j + c_j ds_j/dt)  if s_j > 0, else 0      N
//! k_j = EA / D_j                                   N/m
//! c_j = 2 zeta sqrt(k_j m)                         N s/m
//! ```
//!
//! `L_j` is the geometric path length (pulley wrap plus straight span, m), `D_j` the unstretched
//! length paid out by the drum (m, what the encoder counts), `EA` the cable's axial stiffness
//! ([`Physics::elasticity`], else [`Dynamics::ea_n`]) and `zeta` [`Dynamics::damping_ratio`]:
//! the damping ratio the platform would have hanging vertically on that cable alone. A cable
//! only pulls: it is slack (zero tension) while shorter than its unstretched length, and also
//! when it shortens fast enough that the dashpot would push. At a constant drum `ds/dt` is the
//! rate of the geometric length, `dL_j/dt = -u_j . v`.
//!
//! The drums:
//! - [`CableCommand::Length`] (position mode): the drive's position loop moves the drum to the
//!   commanded length. Within a [`crate::Plant::step`] the target moves at constant speed from
//!   the last command to the new one (the drive's interpolation of cyclic targets, CiA 402 CSP),
//!   and the drum follows it as a critically damped second-order servo of bandwidth
//!   [`Dynamics::position_bandwidth_hz`] (`w_s`):
//!
//!   ```text
//!   dw_j/dt = w_s² (x_j - D_j) - 2 w_s w_j,     dD_j/dt = w_j
//!   ```
//!
//!   It lags a constant speed `v` by `2 v / w_s` (the following error the encoder shows) and
//!   smooths the staircase of quantised or unevenly timed targets as a real drive does; the
//!   cable's pull does not move it (the loop is stiff against load).
//! - [`CableCommand::Tension`] (torque mode): the drum is a mass on the cable. Its motor pulls
//!   the cable in with the commanded tension `T_cmd`; the cable pulls it out with `T_j`:
//!
//!   ```text
//!   m_d dw_j/dt = T_j - T_cmd - b_d w_j,     dD_j/dt = w_j,     |w_j| <= w_max
//!   ```
//!
//!   with `m_d` the drum's and motor's inertia seen at the cable ([`Dynamics::drum_mass_kg`],
//!   `J / r²`), `b_d` the drive's viscous friction ([`Dynamics::drum_friction_n_s_m`]) and `w_max`
//!   its speed limit ([`Dynamics::drum_max_speed_m_s`], CiA 402 0x6080). At rest the tension is the
//!   command. A slack cable's drum reels in at `T_cmd / m_d` up to the speed limit, as a real drive
//!   does; following a platform that accelerates at `a` costs a tension error of about `m_d a`.
//!   The dashpot term uses the drum speed `w_j`. When a drum leaves position mode it keeps the
//!   speed it had.
//!
//! # Integrator
//!
//! Semi-implicit (symplectic) Euler: `v += h a(p, v, D)`, `p += h v`, then the torque-mode drums
//! `w += h dw/dt`, `D += h w`. A step of `dt` is cut into equal sub-steps `h` no longer than
//! [`Dynamics::max_substep_s`] (1 ms) and inside the stability limit. For an oscillator of angular
//! frequency `w` and damping ratio `z` the method is stable for `h < 2 (sqrt(1 + z²) - z) / w`;
//! the plant bounds the highest frequency by `w_max² <= trace(K) / m` (stiffness `K` below, with
//! every cable counted as taut) and takes half that limit; likewise for each torque-mode drum on
//! its cable (`w² = k_j / m_d`). With 40 kN cables of a few metres on a few kg, `w_max` is
//! ~100-300 rad/s and the 1 ms cap decides. The outputs are the state at the end of the step; the
//! tensions reported are the ones the next sub-step accelerates with (up to the change of a
//! position-mode drum's speed at the next command), so `sum_j T_j u_j + m g` is `m a` of the
//! positions' second difference.
//!
//! The very first step of a dynamic plant places the platform at rest in the static equilibrium
//! of its commands (the quasi-static plant's solver, [`crate::equilibrium`]); later steps
//! integrate.
//!
//! # Linearised modes
//!
//! About an equilibrium with tensions `T_j`, held drums and small motion:
//!
//! ```text
//! M x'' + C x' + K x = 0,   M = m I,
//! K = sum_j [k_j u_j u_j^T + (T_j / l_j) (I - u_j u_j^T)],   C = sum_j c_j u_j u_j^T
//! ```
//!
//! with `l_j` the straight span. [`predicted_modes`] and [`crate::Plant::predicted_modes`] return
//! the three modes from the eigenvalues of the first-order system `[[0, I], [-K/m, -C/m]]`
//! (`lambda = -zeta w_n +- i w_d`).
//!
//! # Neglected
//!
//! Cable mass and sag (the dynamic plant ignores [`Physics::sag`]: straight cables), the cables'
//! own vibration (transverse and axial waves), platform rotation and rotational inertia (unless
//! [`Dynamics::rigid_body`]; the linearised modes are the translational ones either way), the
//! cable's pull on a drum in position mode (its servo is stiff against load) and that drum's
//! speed limit, the drives' torque limits, friction on the pulleys, the pulley's wrap changing
//! the transverse stiffness (the span `l_j` is used), aerodynamic drag.

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3};

pub use rigid::RigidBody;

use crate::equilibrium::EquilibriumReport;
use crate::physics::{CableCommand, CableLoad, CableModel, Physics, G};
use crate::truth::Truth;

/// Options of the dynamic plant. Units in each field's name.
#[derive(Debug, Clone, PartialEq)]
pub struct Dynamics {
    /// Axial stiffness EA of every cable when [`Physics::elasticity`] is off, N. Default 1 MN: a
    /// 5 mm steel wire rope (about 10 mm² of steel). A 2 mm rope or a Dyneema braid is nearer
    /// 100-200 kN, and its stretch then needs the `elasticity` effect in the calibration.
    pub ea_n: f64,
    /// Damping ratio `zeta` of each cable: `c_j = 2 zeta sqrt(k_j m)`, N s/m. Default 0.05.
    pub damping_ratio: f64,
    /// Inertia of a drum with its motor and gear, seen at the cable (`J / r²`), kg. Default 1 kg:
    /// a 30 mm drum on a small servo through a gear. Only torque-mode drums move by it.
    pub drum_mass_kg: f64,
    /// Viscous friction of a torque-mode drum, N s/m. Default 5.
    pub drum_friction_n_s_m: f64,
    /// Speed limit of a torque-mode drum, m/s. Default 2.
    pub drum_max_speed_m_s: f64,
    /// Bandwidth of a drive's position loop, Hz: a position-mode drum follows its target through
    /// it. Default 40 Hz.
    pub position_bandwidth_hz: f64,
    /// Longest integration sub-step, s (shorter when the stability limit requires). Default 1 ms.
    pub max_substep_s: f64,
    /// The platform as a rigid body that rotates under the cables' moments (see [`rigid`]).
    /// `None` (the default): a point mass whose orientation is imposed.
    pub rigid_body: Option<RigidBody>,
}

impl Default for Dynamics {
    fn default() -> Self {
        Dynamics {
            ea_n: 1_000_000.0,
            damping_ratio: 0.05,
            drum_mass_kg: 1.0,
            drum_friction_n_s_m: 5.0,
            drum_max_speed_m_s: 2.0,
            position_bandwidth_hz: 40.0,
            max_substep_s: 1e-3,
            rigid_body: None,
        }
    }
}

impl Dynamics {
    /// Damping coefficient of a cable of stiffness `k` (N/m) holding mass `mass` (kg), N s/m.
    pub fn damping(&self, k: f64, mass: f64) -> f64 {
        2.0 * self.damping_ratio * (k * mass).max(0.0).sqrt()
    }
}

/// One mode of the linearised platform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    /// Undamped natural frequency `w_n / 2 pi`, Hz.
    pub natural_hz: f64,
    /// Damped frequency `w_n sqrt(1 - zeta²) / 2 pi` (0 when overdamped), Hz: what an oscillation
    /// shows between zero crossings.
    pub damped_hz: f64,
    /// Damping ratio `zeta` (1 or more: overdamped).
    pub damping_ratio: f64,
    /// Undamped mode shape: unit eigenvector of `K` (sign arbitrary).
    pub shape: [f64; 3],
}

/// The cable models of the dynamic plant: the physics' anchors and pulleys, no sag, the
/// dynamics' EA when elasticity is off.
pub(crate) fn models(truth: &Truth, physics: &Physics, dynamics: &Dynamics) -> Vec<CableModel> {
    truth
        .cable_models(physics)
        .into_iter()
        .map(|mut m| {
            m.w = 0.0;
            if !m.ea.is_finite() {
                m.ea = dynamics.ea_n;
            }
            m
        })
        .collect()
}

/// The predicted modes of the true robot with `physics` (dynamic options from
/// [`Physics::dynamics`], else [`Dynamics::default`]) at rest at `p` with platform-end tensions
/// `tensions` (N), drums held, platform unrotated. Sorted by natural frequency.
pub fn predicted_modes(truth: &Truth, physics: &Physics, p: [f64; 3], tensions: &[f64]) -> [Mode; 3] {
    let dynamics = physics.dynamics.clone().unwrap_or_default();
    let models = models(truth, physics, &dynamics);
    let (k, c) = linearise(&models, &truth.platform_points, truth.mass_kg, &dynamics, p, tensions);
    modes(&k, &c, truth.mass_kg)
}

/// Stiffness and damping matrices at `p` with tensions `tensions` (see the module doc); a cable
/// without tension counts as slack.
pub(crate) fn linearise(
    models: &[CableModel],
    offsets: &[[f64; 3]],
    mass: f64,
    dynamics: &Dynamics,
    p: [f64; 3],
    tensions: &[f64],
) -> (Matrix3<f64>, Matrix3<f64>) {
    let mut k = Matrix3::zeros();
    let mut c = Matrix3::zeros();
    for (j, m) in models.iter().enumerate() {
        let t = tensions[j];
        if t <= 0.0 {
            continue;
        }
        let o = offsets[j];
        let path = m.path([p[0] + o[0], p[1] + o[1], p[2] + o[2]]);
        let u = Vector3::from(path.dir);
        let uu = u * u.transpose();
        let d = path.length() / (1.0 + t / m.ea);
        let kj = m.ea / d;
        k += uu * kj + (Matrix3::identity() - uu) * (t / path.straight);
        c += uu * dynamics.damping(kj, mass);
    }
    (k, c)
}

/// The three modes of `m x'' + c x' + k x = 0`, sorted by natural frequency.
pub(crate) fn modes(k: &Matrix3<f64>, c: &Matrix3<f64>, mass: f64) -> [Mode; 3] {
    let mut a = Matrix6::zeros();
    for r in 0..3 {
        a[(r, r + 3)] = 1.0;
        for col in 0..3 {
            a[(r + 3, col)] = -k[(r, col)] / mass;
            a[(r + 3, col + 3)] = -c[(r, col)] / mass;
        }
    }
    let ev = a.complex_eigenvalues();
    // (w_n, zeta) per mode: complex pairs from their upper member, real eigenvalues paired in order.
    let mut found: Vec<(f64, f64)> = Vec::with_capacity(3);
    let mut reals: Vec<f64> = Vec::new();
    for l in ev.iter() {
        let w = l.norm();
        if l.im.abs() > 1e-9 * w.max(1e-300) {
            if l.im > 0.0 {
                found.push((w, -l.re / w));
            }
        } else {
            reals.push(l.re);
        }
    }
    reals.sort_by(|x, y| y.total_cmp(x));
    for pair in reals.chunks(2) {
        if let [l1, l2] = *pair {
            let wn = (l1 * l2).max(0.0).sqrt();
            found.push((wn, if wn > 0.0 { -(l1 + l2) / (2.0 * wn) } else { f64::INFINITY }));
        }
    }
    found.sort_by(|x, y| x.0.total_cmp(&y.0));
    let sym = SymmetricEigen::new(*k);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&x, &y| sym.eigenvalues[x].total_cmp(&sym.eigenvalues[y]));
    let tau = 2.0 * std::f64::consts::PI;
    std::array::from_fn(|i| {
        let (wn, z) = found.get(i).copied().unwrap_or((f64::NAN, f64::NAN));
        let v = sym.eigenvectors.column(order[i]);
        Mode {
            natural_hz: wn / tau,
            damped_hz: if z < 1.0 { wn * (1.0 - z * z).sqrt() / tau } else { 0.0 },
            damping_ratio: z,
            shape: [v[0], v[1], v[2]],
        }
    })
}

/// The dynamic state of a plant: velocity and drums.
#[derive(Debug, Clone)]
pub(crate) struct DynState {
    pub params: Dynamics,
    /// Platform velocity, m/s.
    pub v: [f64; 3],
    /// Unstretched lengths paid out, m.
    drum: Vec<f64>,
    /// Drum lengths at the start of the step, m.
    start: Vec<f64>,
    /// The last position-mode target, m (NaN while the drum was not in position mode).
    target: Vec<f64>,
    /// Drum speeds, m/s: a position-mode drum's over the step, a torque-mode drum's state.
    rate: Vec<f64>,
    /// Whether the first step placed the platform.
    pub started: bool,
    /// The rigid platform's rotation (`None`: a point mass).
    pub rigid: Option<rigid::RigidState>,
    /// Attachment points from the centre of mass, world frame, m (scratch of the rigid platform).
    arm: Vec<[f64; 3]>,
}

/// The platform and its cables, borrowed for one step.
pub(crate) struct Body<'a> {
    pub models: &'a [CableModel],
    pub offsets: &'a [[f64; 3]],
    /// Attachment points, platform frame (used by the rigid platform), m.
    pub points: &'a [[f64; 3]],
    pub mass: f64,
}

impl DynState {
    /// At rest; a rigid platform with orientation `q`.
    pub fn new(params: Dynamics, n: usize, q: [f64; 4]) -> Self {
        DynState {
            rigid: params.rigid_body.as_ref().map(|b| rigid::RigidState::new(b, q)),
            arm: vec![[0.0; 3]; n],
            params,
            v: [0.0; 3],
            drum: vec![0.0; n],
            start: vec![0.0; n],
            target: vec![f64::NAN; n],
            rate: vec![0.0; n],
            started: false,
        }
    }

    /// At rest with the drums of `loads` (an equilibrium).
    pub fn start_at_rest(&mut self, loads: &[CableLoad]) {
        for (d, l) in self.drum.iter_mut().zip(loads) {
            *d = l.drum_length;
        }
        self.target.copy_from_slice(&self.drum);
        self.v = [0.0; 3];
        if let Some(r) = &mut self.rigid {
            r.l = Vector3::zeros();
        }
        self.rate.fill(0.0);
        self.started = true;
    }

    /// Cable forces at `p` with the current velocity, drums and drum speeds; fills `loads`,
    /// returns the net force including gravity, N.
    fn forces(&self, body: &Body<'_>, p: [f64; 3], loads: &mut [CableLoad]) -> [f64; 3] {
        let mut f = [0.0, 0.0, -body.mass * G];
        let v = self.v;
        for (j, m) in body.models.iter().enumerate() {
            let o = body.offsets[j];
            let path = m.path([p[0] + o[0], p[1] + o[1], p[2] + o[2]]);
            let u = path.dir;
            let ell_dot = -(u[0] * v[0] + u[1] * v[1] + u[2] * v[2]);
            loads[j] = self.cable_load(j, m.ea, body.mass, path.length(), ell_dot, u);
            for a in 0..3 {
                f[a] += loads[j].force[a];
            }
        }
        f
    }

    /// Cable `j`'s Kelvin-Voigt pull (axial stiffness `ea`, N; the platform's `mass`, kg) at
    /// geometric length `ell` (m) lengthening at `ell_dot` (m/s) along the unit direction `u`
    /// (from the platform towards the anchor), against its drum's length and speed.
    fn cable_load(&self, j: usize, ea: f64, mass: f64, ell: f64, ell_dot: f64, u: [f64; 3]) -> CableLoad {
        let d = self.drum[j].max(1e-6);
        let s = ell - d;
        let k = ea / d;
        let c = self.params.damping(k, mass);
        let t = if s > 0.0 { (k * s + c * (ell_dot - self.rate[j])).max(0.0) } else { 0.0 };
        CableLoad {
            force: [t * u[0], t * u[1], t * u[2]],
            energy: 0.5 * k * s.max(0.0).powi(2),
            tension: t,
            drum_length: self.drum[j],
            slack: t <= 0.0,
        }
    }

    /// The longest stable sub-step at `p` (see the module doc), s.
    fn substep_limit(&self, body: &Body<'_>, p: [f64; 3], cmds: &[CableCommand], loads: &[CableLoad]) -> f64 {
        // Half the limit `2 (sqrt(1 + z²) - z) / w` of an oscillator.
        let half = |w: f64, z: f64| ((1.0 + z * z).sqrt() - z) / w;
        let (mut trace, mut csum) = (0.0, 0.0);
        let mut limit = self.params.max_substep_s;
        for (j, m) in body.models.iter().enumerate() {
            let o = body.offsets[j];
            let path = m.path([p[0] + o[0], p[1] + o[1], p[2] + o[2]]);
            let k = m.ea / self.drum[j].max(1e-6);
            let c = self.params.damping(k, body.mass);
            trace += k + 2.0 * loads[j].tension.max(0.0) / path.straight.max(1e-6);
            csum += c;
            if let CableCommand::Tension(_) = cmds[j] {
                let md = self.params.drum_mass_kg.max(1e-9);
                let w = (k / md).sqrt();
                limit = limit.min(half(w, (c + self.params.drum_friction_n_s_m) / (2.0 * md * w)));
            }
        }
        let w = (trace / body.mass).sqrt();
        limit.min(half(w, csum / (2.0 * body.mass * w)))
    }

    /// One sub-step `i` (of length `h`, in a step of `dt`) of the drums under `cmds`.
    fn drum_substep(&mut self, i: usize, h: f64, dt: f64, cmds: &[CableCommand], loads: &[CableLoad]) {
        let ws = 2.0 * std::f64::consts::PI * self.params.position_bandwidth_hz;
        let (md, b, w_max) = (self.params.drum_mass_kg.max(1e-9), self.params.drum_friction_n_s_m, self.params.drum_max_speed_m_s);
        for j in 0..cmds.len() {
            let w = match cmds[j] {
                CableCommand::Length(l) => {
                    // The drive's interpolated target and its speed over this step.
                    let from = if self.target[j].is_finite() { self.target[j] } else { self.start[j] };
                    let vt = (l - from) / dt;
                    let xt = from + vt * (i as f64 + 1.0) * h;
                    self.rate[j] + h * (ws * ws * (xt - self.drum[j]) - 2.0 * ws * self.rate[j])
                }
                CableCommand::Tension(tc) => {
                    let w = self.rate[j] + h * (loads[j].tension - tc - b * self.rate[j]) / md;
                    w.clamp(-w_max, w_max)
                }
            };
            self.rate[j] = w;
            self.drum[j] += h * w;
        }
    }

    /// Integrates `dt` under `cmds`; `p` and `loads` in and out. A non-finite result restores
    /// the state of the step's start and reports no convergence.
    pub fn advance(
        &mut self,
        body: &Body<'_>,
        p: &mut [f64; 3],
        dt: f64,
        cmds: &[CableCommand],
        loads: &mut [CableLoad],
    ) -> EquilibriumReport {
        if self.rigid.is_some() {
            return self.advance_rigid(body, p, dt, cmds, loads);
        }
        let (p0, v0) = (*p, self.v);
        self.start.copy_from_slice(&self.drum);
        let mut steps = 0usize;
        if dt > 0.0 {
            // The limit at the step's start, with the tensions of the last step's end.
            let h_max = self.substep_limit(body, *p, cmds, loads);
            steps = ((dt / h_max).ceil() as usize).clamp(1, 1_000_000);
            let h = dt / steps as f64;
            for i in 0..steps {
                let f = self.forces(body, *p, loads);
                for a in 0..3 {
                    self.v[a] += h * f[a] / body.mass;
                    p[a] += h * self.v[a];
                }
                self.drum_substep(i, h, dt, cmds, loads);
            }
        }
        // The loads at the step's end: what the next sub-step accelerates with.
        let f = self.forces(body, *p, loads);
        let ok = p.iter().chain(&self.v).chain(&self.drum).all(|x| x.is_finite());
        if !ok {
            *p = p0;
            self.v = v0;
            self.drum.copy_from_slice(&self.start);
            self.rate.fill(0.0);
            self.forces(body, *p, loads);
        } else if dt > 0.0 {
            self.keep_targets(cmds);
        }
        EquilibriumReport { iterations: steps, residual_n: Vector3::from(f).norm(), converged: ok, stable: ok }
    }

    /// A step of no time changes nothing; the next one interpolates from the last target.
    fn keep_targets(&mut self, cmds: &[CableCommand]) {
        for (t, c) in self.target.iter_mut().zip(cmds) {
            *t = match *c {
                CableCommand::Length(l) => l,
                CableCommand::Tension(_) => f64::NAN,
            };
        }
    }

    /// [`DynState::advance`] of the rigid platform (see [`rigid`]); `p` is the reference point.
    fn advance_rigid(
        &mut self,
        body: &Body<'_>,
        p: &mut [f64; 3],
        dt: f64,
        cmds: &[CableCommand],
        loads: &mut [CableLoad],
    ) -> EquilibriumReport {
        let (p0, v0, r0) = (*p, self.v, self.rigid.clone());
        self.start.copy_from_slice(&self.drum);
        let mut arm = std::mem::take(&mut self.arm);
        let mut x = rigid::centre_of_mass(self.rigid.as_ref().expect("rigid"), *p);
        let mut steps = 0usize;
        if dt > 0.0 {
            // The limit at the step's start, with the tensions of the last step's end.
            let rs = self.rigid.as_ref().expect("rigid");
            rigid::arms(rs, body, &rigid::matrix(rs.q), &mut arm);
            let h_max = self.rigid_substep_limit(rs, body, x, &arm, cmds, loads);
            steps = ((dt / h_max).ceil() as usize).clamp(1, 1_000_000);
            let h = dt / steps as f64;
            for i in 0..steps {
                self.rigid_substep(body, &mut x, h, &mut arm, loads);
                self.drum_substep(i, h, dt, cmds, loads);
            }
        }
        let rs = self.rigid.take().expect("rigid");
        // The loads at the step's end: what the next sub-step accelerates with.
        let (mut f, _) = self.rigid_forces(&rs, body, x, &mut arm, loads);
        *p = rigid::reference_point(&rs, x);
        let ok = p.iter().chain(&self.v).chain(&self.drum).chain(&rs.q).chain(rs.l.iter()).all(|x| x.is_finite());
        self.rigid = Some(rs);
        if !ok {
            *p = p0;
            self.v = v0;
            self.rigid = r0;
            self.drum.copy_from_slice(&self.start);
            self.rate.fill(0.0);
            let rs = self.rigid.take().expect("rigid");
            (f, _) = self.rigid_forces(&rs, body, rigid::centre_of_mass(&rs, *p), &mut arm, loads);
            self.rigid = Some(rs);
        } else if dt > 0.0 {
            self.keep_targets(cmds);
        }
        self.arm = arm;
        EquilibriumReport { iterations: steps, residual_n: f.norm(), converged: ok, stable: ok }
    }
}

pub mod rigid;

#[cfg(test)]
mod tests;
