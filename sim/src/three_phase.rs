//! The guided three-phase initialisation motion (paper, section III).
//!
//! Three cables are in position mode, the others follow at a low constant tension. From a rest
//! position near the centre, phase `k` reels `cables[k]` in by `reel_m` at `speed_m_s` while the
//! other two hold their lengths, then reels it back out (labelled -1) to the rest position. The
//! platform is the static equilibrium of the [`Plant`] at every sample: it moves on the circle
//! where the spheres of the two held cables meet, its height set by the reeled cable. Reeling
//! *in* keeps the held cables taut: the platform rises towards the reeled anchor and the two
//! others keep carrying their share; a sample where a position-mode cable loses its tension is an
//! error.
//!
//! The default pairing (`cables = [0, 1, 2]`) works for three and four cables: with four, cable 3
//! follows.

use crate::physics::{CableCommand, CableModel, Physics, G};
use crate::plant::Plant;
use crate::trajectory::Workspace;
use crate::truth::Truth;
use crate::SimError;

/// A three-phase initialisation motion.
#[derive(Debug, Clone, PartialEq)]
pub struct ThreePhasePlan {
    /// Length reeled in during each phase, m.
    pub reel_m: f64,
    /// Reeling speed, m/s.
    pub speed_m_s: f64,
    /// Tension of the follower cables (torque mode), N.
    pub follower_tension_n: f64,
    /// The three position-mode cables; phase `k` reels `cables[k]`.
    pub cables: [usize; 3],
    /// Rest at the start position before each phase, s.
    pub dwell_s: f64,
    /// Start (rest) position, m; `None`: searched near the workspace centre (see
    /// [`simulate`]).
    pub start: Option<[f64; 3]>,
}

impl Default for ThreePhasePlan {
    fn default() -> Self {
        ThreePhasePlan { reel_m: 0.5, speed_m_s: 0.1, follower_tension_n: 10.0, cables: [0, 1, 2], dwell_s: 1.0, start: None }
    }
}

/// The sampled motion: true positions, drum lengths and tensions.
#[derive(Debug, Clone, PartialEq)]
pub struct ThreePhaseMotion {
    /// Sample times from the start of the motion, s.
    pub t: Vec<f64>,
    /// Platform positions, m.
    pub p: Vec<[f64; 3]>,
    /// Unstretched drum lengths, row-major per sample, m.
    pub drum: Vec<f64>,
    /// Platform-end tensions, row-major per sample, N.
    pub tension: Vec<f64>,
    /// Phase per sample (-1 outside).
    pub phase: Vec<i32>,
    /// Drum lengths at the start (the held lengths), m.
    pub rest_lengths: Vec<f64>,
    /// The start (rest) position, m.
    pub start: [f64; 3],
    /// The least tension of a position-mode cable during the motion, N.
    pub margin_n: f64,
}

/// Tensions that hold the platform at `c` with the followers at `tf`: the 3x3 force balance of
/// the position-mode cables, with their force directions refined for sag.
fn rest_tensions(truth: &Truth, physics: &Physics, plan: &ThreePhasePlan, c: [f64; 3]) -> Result<Vec<f64>, SimError> {
    let n = truth.n_cables();
    let models: Vec<_> = truth.cable_models(physics).into_iter().map(CableModel::rigidified).collect();
    let b: Vec<[f64; 3]> = truth.platform_points.iter().map(|o| [c[0] + o[0], c[1] + o[1], c[2] + o[2]]).collect();
    let mut t: Vec<f64> = (0..n).map(|_| plan.follower_tension_n).collect();
    let mut dirs: Vec<[f64; 3]> = (0..n).map(|j| models[j].path(b[j]).dir).collect();
    for _ in 0..4 {
        let mut rhs = nalgebra::Vector3::new(0.0, 0.0, truth.mass_kg * G);
        for j in (0..n).filter(|&j| taut_config::followers::follows(j, &plan.cables)) {
            rhs -= plan.follower_tension_n * nalgebra::Vector3::from(dirs[j]);
        }
        let m = nalgebra::Matrix3::from_fn(|r, k| dirs[plan.cables[k]][r]);
        let x = m
            .lu()
            .solve(&rhs)
            .ok_or(SimError::ThreePhaseInfeasible { reason: "the three position-mode cables are coplanar at the centre" })?;
        for k in 0..3 {
            t[plan.cables[k]] = x[k];
        }
        if t.iter().any(|&x| x <= 1.0) {
            return Err(SimError::ThreePhaseInfeasible {
                reason: "at the centre a position-mode cable would carry less than 1 N: lower the follower tension or change the pairing",
            });
        }
        // Sag tilts the force at the platform end: refine the directions.
        for j in 0..n {
            if let Ok(taut) = models[j].taut(b[j], t[j]) {
                dirs[j] = taut.dir;
            }
        }
    }
    Ok(t)
}

/// Simulates the motion at `rate_hz`.
///
/// Without a start in the plan, the start is the position near the workspace centre (a 3 x 3 x 3
/// grid over +-30 % of the inscribed ellipse and 30-55 % of the anchor height) where the
/// position-mode cables keep the most tension during the whole motion: on a rectangle the
/// follower's pull unbalances the reeled cable's phase, and the centre itself leaves little
/// margin.
pub fn simulate(
    truth: &Truth,
    physics: &Physics,
    plan: &ThreePhasePlan,
    ws: &Workspace,
    rate_hz: f64,
) -> Result<ThreePhaseMotion, SimError> {
    if let Some(c) = plan.start {
        return run(truth, physics, plan, c, rate_hz);
    }
    let c = ws.center_point();
    let mut best: Option<([f64; 3], f64)> = None;
    let mut first_err = None;
    // The centre first: on ties it wins.
    for (fz, fx, fy) in [(0.425, 0.0, 0.0)].into_iter().chain(
        [0.425, 0.3, 0.55]
            .into_iter()
            .flat_map(|fz| [0.0, -0.3, 0.3].into_iter().flat_map(move |fx| [0.0, -0.3, 0.3].map(|fy| (fz, fx, fy)))),
    ) {
        let p = [c[0] + fx * ws.semi[0], c[1] + fy * ws.semi[1], fz * ws.z_top];
        match run(truth, physics, plan, p, 4.0) {
            Ok(m) => {
                if best.is_none_or(|(_, b)| m.margin_n > b) {
                    best = Some((p, m.margin_n));
                }
            }
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    match best {
        Some((p, _)) => run(truth, physics, plan, p, rate_hz),
        None => Err(first_err.unwrap_or(SimError::ThreePhaseInfeasible { reason: "no start position works" })),
    }
}

/// Simulates the motion at `rate_hz` from the rest position `c`.
fn run(truth: &Truth, physics: &Physics, plan: &ThreePhasePlan, c: [f64; 3], rate_hz: f64) -> Result<ThreePhaseMotion, SimError> {
    let n = truth.n_cables();
    if plan.cables.iter().any(|&j| j >= n)
        || plan.cables[0] == plan.cables[1]
        || plan.cables[1] == plan.cables[2]
        || plan.cables[0] == plan.cables[2]
    {
        return Err(SimError::ThreePhaseInfeasible { reason: "the plan needs three distinct cables of the robot" });
    }
    if !(plan.reel_m.is_finite() && plan.speed_m_s > 0.0 && rate_hz > 0.0) {
        return Err(SimError::ThreePhaseInfeasible { reason: "reel length, speed and rate must be positive" });
    }
    // The plant's timing is exact; the scenario applies the encoder time offset itself.
    let plant_physics = Physics { time_offset_s: 0.0, backlash_m: 0.0, scale: None, ..physics.clone() };
    let mut plant = Plant::new(truth, &plant_physics, c);
    let tens = rest_tensions(truth, &plant_physics, plan, c)?;
    let rest = plant.lengths_holding(c, &tens)?;
    let dt = 1.0 / rate_hz;
    let reel_s = plan.reel_m.abs() / plan.speed_m_s;
    // Timeline: per phase a dwell, the reel-in, the reel-out; a final dwell.
    let phase_s = plan.dwell_s + 2.0 * reel_s;
    let total = 3.0 * phase_s + plan.dwell_s;
    let samples = (total * rate_hz).round() as usize + 1;
    let mut m = ThreePhaseMotion {
        t: Vec::with_capacity(samples),
        p: Vec::with_capacity(samples),
        drum: Vec::with_capacity(samples * n),
        tension: Vec::with_capacity(samples * n),
        phase: Vec::with_capacity(samples),
        rest_lengths: rest.clone(),
        start: c,
        margin_n: f64::INFINITY,
    };
    let mut cmds: Vec<CableCommand> = (0..n)
        .map(|j| {
            if taut_config::followers::follows(j, &plan.cables) {
                CableCommand::Tension(plan.follower_tension_n)
            } else {
                CableCommand::Length(rest[j])
            }
        })
        .collect();
    for i in 0..samples {
        let t = i as f64 * dt;
        let k = ((t / phase_s).floor() as usize).min(3);
        let tau = t - k as f64 * phase_s - plan.dwell_s;
        let (delta, phase) = if k < 3 && tau >= 0.0 {
            if tau <= reel_s {
                (plan.reel_m * tau / reel_s, k as i32)
            } else {
                (plan.reel_m * ((2.0 * reel_s - tau) / reel_s).max(0.0), -1)
            }
        } else {
            (0.0, -1)
        };
        for (idx, &j) in plan.cables.iter().enumerate() {
            let reeled = if idx == k { delta } else { 0.0 };
            cmds[j] = CableCommand::Length(rest[j] - reeled);
        }
        let out = plant.step(dt, &cmds);
        if !out.report.converged {
            return Err(SimError::Equilibrium { t, residual_n: out.report.residual_n });
        }
        for &j in &plan.cables {
            if out.tension_n[j] < 1.0 {
                return Err(SimError::ThreePhaseSlack { phase, cable: j, t, tension_n: out.tension_n[j] });
            }
            m.margin_n = m.margin_n.min(out.tension_n[j]);
        }
        m.t.push(t);
        m.p.push(out.position);
        m.drum.extend_from_slice(out.drum_m);
        m.tension.extend_from_slice(out.tension_n);
        m.phase.push(phase);
    }
    Ok(m)
}
