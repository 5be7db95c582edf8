//! Static equilibrium of the platform: the minimum of the potential energy
//!
//! ```text
//! U(p) = m g z + sum_j U_j(p + R b_j)
//! ```
//!
//! with `U_j` the energy of cable `j` under its drum command (a stiff elastic cable of fixed
//! unstretched length in position mode, `T * length` for a constant-tension follower; catenaries
//! with sag). The force residual is `r(p) = -grad U = sum_j F_j + m g`.
//!
//! Damped Newton: the stiffness `K = -dr/dp` by forward differences of the forces (symmetrised,
//! Levenberg-regularised until it is positive definite), the step capped to 0.25 m, backtracking
//! until the energy drops (Armijo) or, near convergence where energy differences are round-off,
//! until the residual drops. A warm start (the last equilibrium) converges in a few iterations.
//! The platform's orientation is imposed, not solved for: only the force balance is enforced.

use std::cell::Cell;

use nalgebra::{Matrix3, Vector3};

use crate::catenary::Catenary;
use crate::physics::{CableCommand, CableLoad, CableModel, G};

/// How the equilibrium search ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EquilibriumReport {
    /// Newton iterations taken.
    pub iterations: usize,
    /// Force residual at the end, N.
    pub residual_n: f64,
    /// Whether the residual met the tolerance.
    pub converged: bool,
    /// Whether the stiffness is positive definite there (a stable equilibrium).
    pub stable: bool,
}

impl EquilibriumReport {
    /// True for a converged, stable equilibrium.
    pub fn was_successful(&self) -> bool {
        self.converged && self.stable
    }
}

/// The platform and its cables, borrowed for one solve.
pub struct System<'a> {
    /// Cable models (finite EA for position-mode cables).
    pub models: &'a [CableModel],
    /// Attachment points relative to the platform reference point, world frame (`R b_j`), m.
    pub offsets: &'a [[f64; 3]],
    /// Drum commands.
    pub commands: &'a [CableCommand],
    /// Platform mass, kg.
    pub mass: f64,
    /// Per-cable catenary warm starts (empty: none).
    pub warm: &'a [Cell<Option<Catenary>>],
}

const MAX_ITER: usize = 60;
const MAX_STEP: f64 = 0.25;
const FD_STEP: f64 = 1e-6;

impl System<'_> {
    /// Force residual and energy at `p`; the cable loads are written into `loads` if given.
    pub fn evaluate(&self, p: [f64; 3], mut loads: Option<&mut [CableLoad]>) -> ([f64; 3], f64) {
        let mut r = [0.0, 0.0, -self.mass * G];
        let mut u = self.mass * G * p[2];
        for (j, m) in self.models.iter().enumerate() {
            let o = self.offsets[j];
            let l = m.load_warm([p[0] + o[0], p[1] + o[1], p[2] + o[2]], self.commands[j], self.warm.get(j));
            for k in 0..3 {
                r[k] += l.force[k];
            }
            u += l.energy;
            if let Some(ls) = loads.as_deref_mut() {
                ls[j] = l;
            }
        }
        (r, u)
    }

    /// Forward differences of the residual `r` at `p` (three evaluations: Newton only needs a
    /// good direction, the line search and the residual test guard the result).
    fn stiffness(&self, p: [f64; 3], r: [f64; 3]) -> Matrix3<f64> {
        let mut k = Matrix3::zeros();
        for c in 0..3 {
            let mut pp = p;
            pp[c] += FD_STEP;
            let (rp, _) = self.evaluate(pp, None);
            for row in 0..3 {
                k[(row, c)] = -(rp[row] - r[row]) / FD_STEP;
            }
        }
        0.5 * (k + k.transpose())
    }

    /// Finds the equilibrium nearest (downhill) from `p0`; fills `loads` there.
    pub fn solve(&self, p0: [f64; 3], loads: &mut [CableLoad]) -> ([f64; 3], EquilibriumReport) {
        // 1e-6 m g: with position-mode cables (stiffness ~1e7 N/m) a picometre; the residual's
        // round-off floor is ~1e-8 N.
        let tol = 1e-6 * self.mass * G;
        let mut p = p0;
        let (mut r, mut u) = self.evaluate(p, None);
        let mut it = 0;
        let mut converged = false;
        while it < MAX_ITER {
            let rn = Vector3::from(r).norm();
            if rn < tol {
                converged = true;
                break;
            }
            it += 1;
            let k = self.stiffness(p, r);
            let rv = Vector3::from(r);
            let scale = k.trace().abs().max(self.mass * G);
            let mut mu = 0.0;
            let mut step = None;
            for _ in 0..20 {
                if let Some(ch) = (k + Matrix3::identity() * mu).cholesky() {
                    step = Some(ch.solve(&rv));
                    break;
                }
                mu = if mu == 0.0 { 1e-9 * scale } else { mu * 10.0 };
            }
            let Some(mut d) = step else { break };
            if d.norm() > MAX_STEP {
                d *= MAX_STEP / d.norm();
            }
            let slope = -rv.dot(&d); // dU/dalpha at 0
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..40 {
                let pc = [p[0] + alpha * d[0], p[1] + alpha * d[1], p[2] + alpha * d[2]];
                let (rc, uc) = self.evaluate(pc, None);
                let rcn = Vector3::from(rc).norm();
                if uc <= u + 1e-4 * alpha * slope || rcn < (1.0 - 1e-4 * alpha) * rn {
                    p = pc;
                    r = rc;
                    u = uc;
                    accepted = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !accepted {
                break;
            }
            if alpha * d.norm() < 1e-13 * (1.0 + Vector3::from(p).norm()) {
                converged = Vector3::from(r).norm() < 1e3 * tol;
                break;
            }
        }
        let (r, _) = self.evaluate(p, Some(loads));
        let rn = Vector3::from(r).norm();
        // A line search that stalls at a residual this small has hit round-off, not a wall:
        // 1e-3 m g against position-mode cables of ~1e7 N/m is a few nanometres of position.
        converged = converged || rn < 1e3 * tol;
        let stable = self.stiffness(p, r).cholesky().is_some();
        (p, EquilibriumReport { iterations: it, residual_n: rn, converged, stable })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::Physics;

    #[test]
    fn three_held_cables_hang_the_platform_at_their_lengths() {
        let anchors = [[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]];
        let target = [0.2, -0.1, 1.2];
        let models: Vec<_> = anchors.iter().map(|a| CableModel::new(*a, [0.0, 0.0, 1.0], &Physics::ideal()).rigidified()).collect();
        let cmds: Vec<_> = anchors
            .iter()
            .map(|a| {
                let d = [a[0] - target[0], a[1] - target[1], a[2] - target[2]];
                CableCommand::Length((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
            })
            .collect();
        let sys = System { models: &models, offsets: &[[0.0; 3]; 3], commands: &cmds, mass: 2.0, warm: &[] };
        let mut loads = [CableLoad { force: [0.0; 3], energy: 0.0, tension: 0.0, drum_length: 0.0, slack: false }; 3];
        // From a start 30 cm off, with all cables slack: it falls into the cables.
        let (p, rep) = sys.solve([0.0, 0.0, 1.5], &mut loads);
        assert!(rep.was_successful(), "{rep:?}");
        for k in 0..3 {
            // Stretch under ~10 N at EA 1e8: well below a micron.
            assert!((p[k] - target[k]).abs() < 1e-6, "{p:?}");
        }
        assert!(loads.iter().all(|l| l.tension > 1.0 && !l.slack));
    }
}
