//! Dwell-pose recordings: the platform is moved from one static pose to the next and held still
//! at each, the way a robot without a tracker calibrates itself (encoders and load cells only).
//!
//! At every instant the platform is in quasi-static equilibrium (the moves are slow): the
//! controller's tension distribution ([`crate::tension`]) balances the weight, each taut cable's
//! encoder counts the unstretched length of that tension ([`crate::physics`]: elasticity, sag,
//! pulley when switched on), the load cells read the tension with their offset and noise. The
//! tracker columns are written empty (NaN) in every row: there is no tracker. Nothing here uses
//! `taut-calib`.

use rand::Rng;

use crate::physics::{CableModel, G};
use crate::scenario::{Scenario, SimRun};
use crate::sensors::{Encoder, LoadCell};
use crate::tension::{distribute, MAX_SIM_CABLES};
use crate::{rng, SimError, STREAM_ENCODER, STREAM_LOADCELL, STREAM_TRAJECTORY};
use taut_config::recording::Recording;

/// Where the platform dwells and for how long.
#[derive(Debug, Clone, PartialEq)]
pub struct DwellPlan {
    /// Dwell positions, m, in the order visited.
    pub poses: Vec<[f64; 3]>,
    /// Time held still at each pose, s.
    pub dwell_s: f64,
    /// Time of each move between poses (minimum-jerk), s.
    pub move_s: f64,
}

impl DwellPlan {
    /// `count` poses drawn uniformly in the box spanned by the workspace (`width` x its
    /// horizontal semi-axes around the centre; heights from `z_lo` x to `z_hi` x the lowest
    /// anchor), keeping only poses where every cable of the *true* robot holds at least
    /// `min_tension_n` at rest. The robot's nominal anchors define the box, as a planner would.
    pub fn spread(s: &Scenario, count: usize, width: f64, z_lo: f64, z_hi: f64, dwell_s: f64, move_s: f64) -> Result<Self, SimError> {
        let truth = s.truth()?;
        let ws = s.workspace()?;
        let models: Vec<CableModel> = truth.cable_models(&s.physics);
        let mut r = rng(s.seed, STREAM_TRAJECTORY);
        let mut poses = Vec::with_capacity(count);
        let mut tries = 0usize;
        while poses.len() < count {
            tries += 1;
            if tries > 1000 * count.max(1) {
                return Err(SimError::BadScenario("no feasible dwell poses in that box; widen it or lower min_tension_n"));
            }
            let p = [
                ws.center[0] + width * ws.semi[0] * r.gen_range(-1.0..1.0),
                ws.center[1] + width * ws.semi[1] * r.gen_range(-1.0..1.0),
                ws.z_top * r.gen_range(z_lo..z_hi),
            ];
            if static_tensions(&models, &truth.platform_points, truth.mass_kg, p, s.min_tension_n).is_some() {
                poses.push(p);
            }
        }
        Ok(DwellPlan { poses, dwell_s, move_s })
    }
}

/// Static tensions holding the platform at `p`, or `None` where the floor cannot be kept.
fn static_tensions(models: &[CableModel], b: &[[f64; 3]], mass: f64, p: [f64; 3], t_min: f64) -> Option<([f64; MAX_SIM_CABLES], usize)> {
    let (t, feasible) = tensions_at(models, b, mass, p, t_min);
    feasible.then_some((t, models.len()))
}

/// The controller's static tensions at `p` and whether every cable keeps the floor (where not,
/// some cables are loose or below it).
fn tensions_at(models: &[CableModel], b: &[[f64; 3]], mass: f64, p: [f64; 3], t_min: f64) -> ([f64; MAX_SIM_CABLES], bool) {
    let n = models.len();
    let mut dirs = [[0.0; 3]; MAX_SIM_CABLES];
    for j in 0..n {
        let x = [p[0] + b[j][0], p[1] + b[j][1], p[2] + b[j][2]];
        dirs[j] = models[j].path(x).dir;
    }
    let mut t = [0.0; MAX_SIM_CABLES];
    let d = distribute(&dirs[..n], [0.0, 0.0, mass * G], t_min, &mut t[..n]);
    (t, d.feasible)
}

/// Simulates the plan on the scenario's true robot at `s.rate_hz`: lengths and tensions, no
/// tracker. The truth (poses, tensions, unstretched lengths) comes back in the [`SimRun`];
/// `excitation_start` is 0 and `recording.phase` is absent.
pub fn simulate(s: &Scenario, plan: &DwellPlan) -> Result<SimRun, SimError> {
    if !(s.rate_hz > 0.0 && s.rate_hz.is_finite() && plan.dwell_s > 0.0 && plan.move_s >= 0.0 && !plan.poses.is_empty()) {
        return Err(SimError::BadScenario("a dwell plan needs poses, a positive dwell time and a non-negative move time"));
    }
    let truth = s.truth()?;
    let n = truth.n_cables();
    let models: Vec<CableModel> = truth.cable_models(&s.physics);
    let dt = 1.0 / s.rate_hz;
    let n_dwell = (plan.dwell_s * s.rate_hz).round().max(1.0) as usize;
    let n_move = (plan.move_s * s.rate_hz).round() as usize;
    let total = plan.poses.len() * n_dwell + (plan.poses.len() - 1) * n_move;
    let mut run = SimRun {
        recording: Recording::with_capacity(n, total, s.with_tensions, false, false),
        truth: truth.clone(),
        loose_samples: 0,
        positions: Vec::with_capacity(total),
        orientations: Vec::with_capacity(total),
        tensions: Vec::with_capacity(total * n),
        loose: Vec::with_capacity(total * n),
        drum_lengths: Vec::with_capacity(total * n),
        excitation_start: 0,
        excursion_s: 0.0,
        three_phase_start: None,
    };
    for (k, &p) in plan.poses.iter().enumerate() {
        if k > 0 {
            let q = plan.poses[k - 1];
            for i in 0..n_move {
                let x = (i + 1) as f64 / (n_move + 1) as f64;
                let w = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x);
                run.positions.push([q[0] + w * (p[0] - q[0]), q[1] + w * (p[1] - q[1]), q[2] + w * (p[2] - q[2])]);
            }
        }
        run.positions.extend(std::iter::repeat_n(p, n_dwell));
    }
    let still: Vec<bool> = (0..plan.poses.len())
        .flat_map(|k| std::iter::repeat_n(false, if k > 0 { n_move } else { 0 }).chain(std::iter::repeat_n(true, n_dwell)))
        .collect();
    for (i, &p) in run.positions.iter().enumerate() {
        let (t, feasible) = tensions_at(&models, &truth.platform_points, truth.mass_kg, p, s.min_tension_n);
        // A move may pass where a cable cannot keep the floor (it goes loose for a moment); a
        // dwell may not: its readings are the calibration's data.
        if still[i] && !feasible {
            return Err(SimError::BadScenario("a dwell pose where a cable cannot hold min_tension_n"));
        }
        run.orientations.push([1.0, 0.0, 0.0, 0.0]);
        let mut any_loose = false;
        for j in 0..n {
            let b = truth.platform_points[j];
            let x = [p[0] + b[0], p[1] + b[1], p[2] + b[2]];
            let path = models[j].path(x);
            let loose = t[j] <= 0.0;
            any_loose |= loose;
            let len = if loose {
                path.length()
            } else {
                models[j].taut(x, t[j]).map_err(|e| SimError::Catenary(format!("cable {j}: {e}")))?.unstretched
            };
            run.tensions.push(t[j].max(0.0));
            run.loose.push(loose);
            run.drum_lengths.push(len);
        }
        run.loose_samples += usize::from(any_loose);
    }
    let mut enc_rng = rng(s.seed, STREAM_ENCODER);
    let mut cell_rng = rng(s.seed, STREAM_LOADCELL);
    // The offsets drawn exactly as `Scenario::truth` drew them, then the noise continues the stream.
    let cells: Vec<LoadCell> = (0..n).map(|_| LoadCell::new(&s.noise, &mut cell_rng)).collect();
    let mut encoders: Vec<Encoder> = (0..n).map(|j| Encoder::of_cable(&truth, &s.physics, &s.noise, s.seed, j)).collect();
    run.recording.comments.push(format!(
        " simulated by taut-sim: robot {}, seed {}, {} Hz, {} dwell poses of {} s, no tracker",
        s.robot.robot.name,
        s.seed,
        s.rate_hz,
        plan.poses.len(),
        plan.dwell_s
    ));
    let (mut l, mut f) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..run.positions.len() {
        for j in 0..n {
            l[j] = encoders[j].read(run.drum_lengths[i * n + j], &mut enc_rng) + s.physics.height_error(run.positions[i][2]);
            f[j] = cells[j].read(run.tensions[i * n + j], &mut cell_rng);
        }
        run.recording.push(i as f64 * dt, [f64::NAN; 3], None, &l, s.with_tensions.then_some(&f[..]), None);
    }
    Ok(run)
}
