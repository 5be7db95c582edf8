//! The first estimate of a robot without a tracker, from the platform at rest: where the
//! measured tensions balance the weight with the nominal anchors, and the encoder offsets that
//! put the measured lengths there.
//!
//! ```text
//! find P:  sum_j f_j v_j(P) + m (0, 0, -g) = 0,   v_j = (A_j - P - b_j) / |A_j - P - b_j|
//! L0_j  =  l_j - |P + b_j - A_j|
//! ```
//!
//! With the nominal anchors a few cm off and the load cells' unknown offsets (~0.5 N), `P` is
//! off by centimetres: enough to move the platform slowly through a dwell plan, which the
//! self-calibration ([`super::calibrate_without_tracker`]) then turns into the robot's geometry.
//! The encoder offsets are consistent with `P`, so the inverse kinematics of this estimate
//! commands the lengths the robot already has at rest: the first move starts without a jump.

use super::dwell;
use crate::Params;
use nalgebra::{Matrix3, Vector3};
use std::fmt;
use taut_config::recording::Recording;

/// What the rest estimate found.
#[derive(Debug, Clone, PartialEq)]
pub struct RestEstimate {
    /// Nominal anchors and the offsets consistent with `position`.
    pub params: Params,
    /// The platform's position at rest, m (nominal frame).
    pub position: [f64; 3],
    /// Force-balance residual at `position`, N.
    pub residual_n: f64,
    /// Readings averaged.
    pub samples: usize,
}

/// Why there is no rest estimate.
#[derive(Debug, Clone, PartialEq)]
pub enum RestError {
    /// No still stretch with every length and tension in the recording.
    NoRest,
    /// The tensions do not balance the weight anywhere below the anchors.
    NoBalance {
        /// Smallest force residual found, N.
        residual_n: f64,
    },
    /// Cable counts differ.
    CableCount,
}

impl fmt::Display for RestError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RestError::NoRest => f.write_str(
                "no still stretch with every encoder and load cell in the rest recording: without a tracker the first estimate needs the platform at rest and every load cell answering",
            ),
            RestError::NoBalance { residual_n } => write!(
                f,
                "the measured tensions do not balance the platform's weight below the nominal anchors (residual {residual_n:.1} N): check robot.mass_kg, the load-cell scales and the nominal anchors"
            ),
            RestError::CableCount => f.write_str("the rest recording, the platform points and the nominal anchors differ in cable count"),
        }
    }
}

impl std::error::Error for RestError {}

/// The force balance for [`crate::lm`]: cost `|F(P)|`, Gauss–Newton on `F`, steps at most
/// 0.3 m and the platform kept below the anchors.
struct Balance<B> {
    balance: B,
    /// Highest platform position, m.
    z_max: f64,
    /// `(F, dF/dP)` at the current point and at the last point evaluated.
    cur: (Vector3<f64>, Matrix3<f64>),
    trial: (Vector3<f64>, Matrix3<f64>),
}

impl<B: Fn(&Vector3<f64>) -> (Vector3<f64>, Matrix3<f64>)> crate::lm::Problem for Balance<B> {
    type X = Vector3<f64>;
    /// The Gauss–Newton step and its length before the bound.
    type Step = (Vector3<f64>, f64);

    fn cost(&mut self, p: &Vector3<f64>) -> f64 {
        self.trial = (self.balance)(p);
        self.trial.0.norm()
    }

    fn accepted(&mut self) {
        self.cur = self.trial;
    }

    fn step(&mut self, _p: &Vector3<f64>, lambda: f64) -> Option<Self::Step> {
        let (f, jac) = self.cur;
        let h = jac.transpose() * jac;
        let mut hd = h;
        for a in 0..3 {
            hd[(a, a)] += lambda * h[(a, a)].max(1e-9);
        }
        let step = hd.lu().solve(&(-(jac.transpose() * f)))?;
        Some((step, step.norm()))
    }

    fn apply(&self, p: &Vector3<f64>, &(step, len): &Self::Step) -> Vector3<f64> {
        let mut q = p + if len > 0.3 { step * (0.3 / len) } else { step };
        q[2] = q[2].min(self.z_max);
        q
    }

    fn small_step(&self, _p: &Vector3<f64>, s: &Self::Step) -> bool {
        s.1 < 1e-9
    }
}

/// The rest estimate from the longest still stretch of `rec` (tracker columns unused).
pub fn rest_estimate(
    rec: &Recording,
    platform: &[[f64; 3]],
    nominal: &[[f64; 3]],
    mass_kg: f64,
    encoder_sigma_m: f64,
) -> Result<RestEstimate, RestError> {
    let n = rec.n_cables;
    if platform.len() != n || nominal.len() != n {
        return Err(RestError::CableCount);
    }
    let found = dwell::find(rec, encoder_sigma_m.max(1e-7), 10);
    let d = found
        .dwells
        .iter()
        .filter(|d| d.nf.iter().all(|&c| c > 0) && d.f.iter().chain(&d.l).all(|v| v.is_finite()))
        .max_by_key(|d| d.end - d.start)
        .ok_or(RestError::NoRest)?;
    let z_top = nominal.iter().map(|a| a[2]).fold(f64::INFINITY, f64::min);
    let centre = Vector3::new(
        nominal.iter().map(|a| a[0]).sum::<f64>() / n as f64,
        nominal.iter().map(|a| a[1]).sum::<f64>() / n as f64,
        z_top - 1.5,
    );
    let balance = |p: &Vector3<f64>| {
        let mut f = Vector3::new(0.0, 0.0, -mass_kg * super::solve::G);
        let mut jac = Matrix3::zeros();
        for j in 0..n {
            let dv = Vector3::from(nominal[j]) - Vector3::from(platform[j]) - p;
            let rho = dv.norm();
            let v = dv / rho;
            f += v * d.f[j];
            jac -= (Matrix3::identity() - v * v.transpose()) * (d.f[j] / rho);
        }
        (f, jac)
    };
    // Damped Newton on the 3x3 balance (least squares when there are more cables).
    let policy =
        crate::lm::Policy { min_lambda: 1e-9, max_lambda: 1e9, singular_stops: true, ..crate::lm::Policy::factors(1e-3, 4.0, 200) };
    let mut problem = Balance { balance, z_max: z_top - 0.05, cur: Default::default(), trial: Default::default() };
    let r = crate::lm::minimize(&mut problem, centre, &policy);
    let (p, f) = (r.x, problem.cur.0);
    // A balance within a few load-cell offsets: 2 N per cable.
    let residual_n = f.norm();
    if residual_n.is_nan() || residual_n > 2.0 * n as f64 || !p.iter().all(|v| v.is_finite()) {
        return Err(RestError::NoBalance { residual_n });
    }
    let l0 = (0..n).map(|j| d.l[j] - (p + Vector3::from(platform[j]) - Vector3::from(nominal[j])).norm()).collect();
    Ok(RestEstimate {
        params: Params { anchors: nominal.to_vec(), l0 },
        position: [p[0], p[1], p[2]],
        residual_n,
        samples: d.end - d.start,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_rest_position_and_consistent_offsets() {
        let nom = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let b = [[0.0; 3]; 4];
        let p = [0.4, -0.2, 1.8];
        let t = super::super::plan::static_tensions(&nom, &b, &[false, false, false, true], 10.0, 3.0, p).unwrap();
        let l0 = [0.3, -1.2, 0.0, 2.0];
        let mut rec = Recording::with_capacity(4, 200, true, false, true);
        for i in 0..200 {
            let l: Vec<f64> = (0..4).map(|j| (Vector3::from(p) - Vector3::from(nom[j])).norm() + l0[j]).collect();
            rec.push(i as f64 * 0.01, [f64::NAN; 3], None, &l, Some(&t), Some(0));
        }
        let r = rest_estimate(&rec, &b, &nom, 3.0, 5e-5).unwrap();
        for a in 0..3 {
            assert!((r.position[a] - p[a]).abs() < 1e-6, "{:?}", r.position);
        }
        for j in 0..4 {
            assert!((r.params.l0[j] - l0[j]).abs() < 1e-6);
        }
        // A wrong mass: the tensions balance nothing near.
        let e = rest_estimate(&rec, &b, &nom, 30.0, 5e-5).unwrap_err();
        assert!(matches!(e, RestError::NoBalance { .. }), "{e}");
    }
}
