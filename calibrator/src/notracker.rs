//! The start-up without a tracker (`motion.startup = "dwell"`): the dwell plan, computed once
//! when the plugin is configured (not in the loop), from the nominal geometry.
//!
//! A robot without a tracker does not know its anchors yet: it moves with the nominal ones (a
//! few cm off, up to ~20 cm for a tape-measured site) and the encoder offsets of its rest
//! estimate ([`taut_calib::selfcal::rest`]). So the plan keeps every planned tension at least
//! [`TENSION_MARGIN`] x `calibration.min_tension_n` (and at least 2 x `safety.loose_tension_n`)
//! and at most `safety.max_tension_n` / [`TENSION_MARGIN`], the moves are slow
//! (`motion.dwell_speed_m_s`), and the loop's safety checks stay active (tension limit, loose
//! position-controlled cables, speed limit, stale load cells). The loop gets the poses as a
//! fixed-size table ([`taut_rt::motion::DwellLoopPlan`]).
//!
//! The calibrator collects the recorded dwells ([`crate::calibrator`]), the backend calibrates
//! them with `taut_calib::selfcal` ([`crate::calib_backend`]), and the result goes through the
//! same acceptance and hot-swap as with a tracker; its held-out check is on held-out dwells
//! ([`heldout_dwells`]): poses the calibration did not see, judged by how well their lengths
//! close (the residual after fitting the platform position), which needs no tracker and no
//! frame.

use crate::vocab::{CalibratorConfig, Estimate, Rejection};
use taut_calib::selfcal::plan::{plan, DwellPlan, PlanError, PlanInput};
use taut_config::recording::Recording;
use taut_config::runtime::Startup;
use taut_config::RobotConfig;
use taut_rt::kin::LoopParams;
use taut_rt::motion::{ControllerConfig, MAX_DWELL_POSES};
use taut_rt::MAX_CABLES;

/// Factor between the planned tensions and the tension bounds (the nominal geometry is a few
/// cm off: the real tensions differ from the planned ones by a few N).
pub const TENSION_MARGIN: f64 = 2.0;

/// Load-cell noise assumed by the planner when the configuration gives none, N (one reading).
pub const PLAN_LOADCELL_SIGMA_N: f64 = 0.3;

/// Tension readings per second assumed by the planner when the load cells are polled back to
/// back (`loadcells.poll_period_s = 0`).
pub const PLAN_TENSION_RATE_HZ: f64 = 50.0;

/// True when the configuration runs the tracker-free start-up.
pub fn is_dwell(cfg: &RobotConfig) -> bool {
    cfg.motion.startup == Some(Startup::Dwell)
}

/// The dwell plan of `cfg` for the controller configuration `ccfg` (its workspace box, its
/// followers and their tension): the plan the loop runs. Deterministic.
pub fn dwell_plan(cfg: &RobotConfig, ccfg: &ControllerConfig) -> Result<DwellPlan, PlanError> {
    dwell_plan_with(cfg, ccfg, &PlanKnobs::default())
}

/// Planner settings beyond the configuration's, for weighing plans the loop does not run:
/// more poses than its table holds, a finer candidate grid, tares of their own length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanKnobs {
    /// Most poses planned (the loop holds [`MAX_DWELL_POSES`]).
    pub max_poses: usize,
    /// Candidate grid points per axis `[x, y, z]` in the workspace box.
    pub grid: [usize; 3],
    /// Recorded time of a tare, s; `None`: `motion.dwell_s`, as the loop records it.
    pub tare_s: Option<f64>,
}

impl Default for PlanKnobs {
    /// The loop's plan: at most [`MAX_DWELL_POSES`] poses from a 7 x 5 x 4 grid, tares as long
    /// as a dwell.
    fn default() -> Self {
        PlanKnobs { max_poses: MAX_DWELL_POSES, grid: [7, 5, 4], tare_s: None }
    }
}

/// [`dwell_plan`] with `knobs` in place of the loop's limits. Deterministic.
pub fn dwell_plan_with(cfg: &RobotConfig, ccfg: &ControllerConfig, knobs: &PlanKnobs) -> Result<DwellPlan, PlanError> {
    let n = ccfg.n;
    let nominal = cfg.anchors().ok_or(PlanError::BadInput("every [[cable]] needs a nominal `anchor` (the start and the frame)"))?;
    let platform = cfg.platform_points();
    let loadcells = cfg.loadcells.is_some() || cfg.cables.iter().any(|c| c.loadcell.is_some());
    let m = &cfg.motion;
    let rate = cfg.rt.rate_hz / cfg.daemon.calib_decimation.max(1) as f64;
    let tension_rate = plan_tension_rate_hz(cfg);
    let w = ccfg.workspace;
    plan(&PlanInput {
        nominal: &nominal,
        platform: &platform,
        mass_kg: cfg.robot.mass_kg,
        workspace: w,
        follower: &ccfg.follower[..n],
        follower_tension_n: ccfg.follower_tension_n,
        min_tension_n: cfg.calibration.min_tension_n.max(cfg.safety.loose_tension_n),
        max_tension_n: cfg.safety.max_tension_n,
        tension_margin: TENSION_MARGIN,
        encoder_sigma_m: cfg.calibration.encoder_sigma_m,
        loadcell_sigma_n: loadcells.then_some(PLAN_LOADCELL_SIGMA_N),
        length_samples: (m.dwell_s * rate).floor().max(1.0) as usize,
        tension_samples: (m.dwell_s * tension_rate).floor().max(1.0) as usize,
        tares: m.dwell_tares,
        tare_samples: (knobs.tare_s.unwrap_or(m.dwell_s) * tension_rate).floor().max(1.0) as usize,
        tare_each_cable: m.dwell_tare_each_cable,
        poses: m.dwell_poses.min(knobs.max_poses),
        start: Some(plan_start(ccfg)),
        grid: knobs.grid,
        // The stretch the calibration models (`[calibration] cable_ea_n` with its sigma): the
        // prediction then carries the stiffness unknowns the calibration fits.
        stretch: taut_calib::selfcal::SelfCalOptions::from_config(cfg).stretch,
    })
}

/// Tension readings a second per cable the planner assumes: `1 / loadcells.poll_period_s`, or
/// [`PLAN_TENSION_RATE_HZ`] when the cells are polled back to back.
fn plan_tension_rate_hz(cfg: &RobotConfig) -> f64 {
    cfg.loadcells
        .as_ref()
        .map_or(PLAN_TENSION_RATE_HZ, |l| if l.poll_period_s > 0.0 { 1.0 / l.poll_period_s } else { PLAN_TENSION_RATE_HZ })
}

/// Where the planned path starts: the workspace box's centre (the rest pose is not known
/// before the robot holds it).
fn plan_start(ccfg: &ControllerConfig) -> [f64; 3] {
    let w = ccfg.workspace;
    std::array::from_fn(|a| (w[0][a] + w[1][a]) / 2.0)
}

/// The robot's time through `plan` as the loop runs it ([`taut_rt::motion::DwellLoopPlan`]),
/// s: the first rest (`settle_s`, then `dwell_s` but at least
/// [`taut_rt::motion::MIN_REST_S`]), then per pose the move (the loop's trapezoid at
/// `motion.dwell_speed_m_s` and the start-up's acceleration; the first from the workspace
/// box's centre), `settle_s` and `dwell_s`, and per tare `settle_s`, `tare_s` (default
/// `dwell_s`, as the loop records it) and `settle_s`. The wait for the rest estimate between
/// the first rest and the first move (the calibrator's computation) is not counted.
pub fn plan_robot_time_s(plan: &DwellPlan, cfg: &RobotConfig, ccfg: &ControllerConfig, tare_s: Option<f64>) -> f64 {
    let m = &cfg.motion;
    let tare_s = tare_s.unwrap_or(m.dwell_s);
    let rest = m.dwell_settle_s + m.dwell_s.max(taut_rt::motion::MIN_REST_S);
    let mut from = plan_start(ccfg);
    let mut t = rest;
    for (p, &mask) in plan.poses.iter().zip(&plan.tare) {
        t += taut_rt::motion::move_time(from, *p, m.dwell_speed_m_s, ccfg.reel_accel_m_s2) + m.dwell_settle_s + m.dwell_s;
        if mask != 0 {
            t += 2.0 * m.dwell_settle_s + tare_s;
        }
        from = *p;
    }
    t
}

/// Splits the dwell rows of a tracker-free data set into training and held-out dwells: every
/// `round(1 / heldout_fraction)`-th dwell (by its phase label, the pose's index) is held out,
/// so the held-out poses are spread over the workspace like the others. Rows without a label
/// (the separators between dwells) go to both; tares (labels from `MAX_DWELL_POSES` on) to
/// the training set (the calibration's load-cell offsets; the held-out check uses lengths).
pub fn split_dwells(rec: &Recording, heldout_fraction: f64) -> (Recording, Recording) {
    let n = rec.n_cables;
    let every = if heldout_fraction > 0.0 { (1.0 / heldout_fraction).round().max(2.0) as i32 } else { i32::MAX };
    let mut train = Recording::with_capacity(n, rec.len(), true, false, true);
    let mut held = Recording::with_capacity(n, rec.len() / every.max(1) as usize + 16, true, false, true);
    for i in 0..rec.len() {
        let ph = rec.phase.as_ref().map_or(-1, |p| p[i]);
        let row = |r: &mut Recording| r.push(rec.t[i], rec.p[i], None, rec.lengths(i), rec.tensions(i), Some(ph));
        if ph < 0 {
            row(&mut train);
            row(&mut held);
        } else if ph >= MAX_DWELL_POSES as i32 {
            row(&mut train);
        } else if ph % every == every - 1 {
            row(&mut held);
        } else {
            row(&mut train);
        }
    }
    (train, held)
}

/// One held-out dwell: mean encoder lengths and tensions over its rows.
struct HeldDwell {
    l: [f64; MAX_CABLES],
    f: [f64; MAX_CABLES],
}

fn held_dwells(rec: &Recording) -> Vec<HeldDwell> {
    let n = rec.n_cables;
    let mut out = Vec::new();
    let mut i = 0;
    while i < rec.len() {
        let ph = rec.phase.as_ref().map_or(-1, |p| p[i]);
        let start = i;
        while i < rec.len() && rec.phase.as_ref().map_or(-1, |p| p[i]) == ph {
            i += 1;
        }
        if ph < 0 || i - start < 10 {
            continue;
        }
        let mut d = HeldDwell { l: [f64::NAN; MAX_CABLES], f: [f64::NAN; MAX_CABLES] };
        for j in 0..n {
            let mean = |v: &mut dyn Iterator<Item = f64>| {
                let (s, c) = v.filter(|x| x.is_finite()).fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
                if c > 0 {
                    s / c as f64
                } else {
                    f64::NAN
                }
            };
            d.l[j] = mean(&mut (start..i).map(|r| rec.lengths(r)[j]));
            d.f[j] = mean(&mut (start..i).map(|r| rec.tensions(r).map_or(f64::NAN, |t| t[j])));
        }
        out.push(d);
    }
    out
}

/// Sum of squared length residuals of a dwell after fitting the platform position to its
/// taut cables' lengths with `p` (the closure of the lengths: `n - 3` degrees of freedom, zero
/// for a perfect model whatever the frame), and the number of cables used.
fn closure(p: &LoopParams, d: &HeldDwell, min_tension_n: f64) -> Option<(f64, usize)> {
    // A missing tension (NaN) does not make a cable loose.
    let used: Vec<usize> = (0..p.n).filter(|&j| d.l[j].is_finite() && (d.f[j].is_nan() || d.f[j] >= min_tension_n)).collect();
    if used.len() < 4 {
        return None;
    }
    let mut x = [0.0; 3];
    for &j in &used {
        for (xa, aa) in x.iter_mut().zip(p.anchors[j]) {
            *xa += aa / used.len() as f64;
        }
    }
    x[2] -= 1.5;
    for _ in 0..50 {
        let (mut h, mut r) = ([[0.0; 3]; 3], [0.0; 3]);
        for &j in &used {
            let dv: [f64; 3] = std::array::from_fn(|a| x[a] + p.platform[j][a] - p.anchors[j][a]);
            let rho = (dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]).sqrt();
            let u: [f64; 3] = std::array::from_fn(|a| dv[a] / rho);
            let e = d.l[j] - p.length_at(j, &x, d.f[j]);
            for a in 0..3 {
                r[a] += u[a] * e;
                for b in 0..3 {
                    h[a][b] += u[a] * u[b];
                }
            }
        }
        let step = taut_rt::motion::solve3(h, r)?;
        let len = (step[0] * step[0] + step[1] * step[1] + step[2] * step[2]).sqrt();
        let k = if len > 0.3 { 0.3 / len } else { 1.0 };
        for a in 0..3 {
            x[a] += k * step[a];
        }
        if len < 1e-10 {
            break;
        }
    }
    let ss = used.iter().map(|&j| (d.l[j] - p.length_at(j, &x, d.f[j])).powi(2)).sum::<f64>();
    ss.is_finite().then_some((ss, used.len()))
}

/// The held-out check without a tracker: on the held-out dwells (poses the calibration did not
/// see), the RMS length closure residual of the new set against the running one, per degree of
/// freedom. The new set is taken when it is lower, or not higher by more than
/// `daemon.heldout_tolerance_m` at 99.9 % confidence (paired differences per dwell,
/// as `acceptance::clearly_worse` tests them), as with a tracker. Returns `(new, old)` RMS, m.
pub fn heldout_dwells(c: &CalibratorConfig, est: &Estimate, heldout: &Recording, current: &LoopParams) -> Result<(f64, f64), Rejection> {
    let new = c.loop_params(0, est).map_err(Rejection::LoopCannotHold)?;
    let dwells = held_dwells(heldout);
    let mut pairs = Vec::new();
    let (mut sn, mut so, mut dof) = (0.0, 0.0, 0usize);
    for d in &dwells {
        if let (Some((a, k)), Some((b, _))) = (closure(&new, d, c.min_tension_n), closure(current, d, c.min_tension_n)) {
            sn += a;
            so += b;
            dof += k - 3;
            pairs.push(a - b);
        }
    }
    if pairs.len() < 2 || dof == 0 {
        return Err(Rejection::TooFewHeldoutDwells { usable: pairs.len() });
    }
    let (n_rms, o_rms) = ((sn / dof as f64).sqrt(), (so / dof as f64).sqrt());
    // The pairs sum to dof times the mean-square difference.
    let worse = crate::acceptance::clearly_worse(&pairs, dof as f64, o_rms, c.heldout_tolerance_m, crate::acceptance::HELDOUT_ALPHA);
    if n_rms < o_rms || !worse {
        Ok((n_rms, o_rms))
    } else {
        Err(Rejection::HeldoutDwellsWorse { dwells: pairs.len(), new_m: n_rms, old_m: o_rms, tolerance_m: c.heldout_tolerance_m })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> (RobotConfig, ControllerConfig) {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim-notracker.toml");
        let cfg = RobotConfig::load(path).unwrap();
        let ccfg = <ControllerConfig as taut_io::FromRobot>::from_robot(&cfg).unwrap();
        (cfg, ccfg)
    }

    #[test]
    fn the_robot_time_counts_the_rest_the_moves_the_dwells_and_the_tares() {
        let (mut cfg, ccfg) = example();
        let plan = dwell_plan(&cfg, &ccfg).unwrap();
        let (poses, tares) = (plan.poses.len() as f64, plan.tare.iter().filter(|&&m| m != 0).count() as f64);
        assert!(tares > 0.0);
        // Each second of dwell: the first rest, every pose, every tare (as long as a dwell).
        let t = plan_robot_time_s(&plan, &cfg, &ccfg, None);
        cfg.motion.dwell_s += 2.0;
        let t2 = plan_robot_time_s(&plan, &cfg, &ccfg, None);
        assert!((t2 - t - 2.0 * (1.0 + poses + tares)).abs() < 1e-9, "{t} -> {t2}");
        // Tares of their own length.
        let t5 = plan_robot_time_s(&plan, &cfg, &ccfg, Some(5.0));
        assert!((t2 - t5 - tares * (cfg.motion.dwell_s - 5.0)).abs() < 1e-9);
        // One pose 2 m from the start, no tare: the rest, a trapezoid (2 m at 0.5 m/s with 0.5
        // m/s^2: 4 s at speed plus 1 s for the ramps), the settle and the dwell.
        let mut one = plan.clone();
        let s = plan_start(&ccfg);
        one.poses = vec![[s[0] + 2.0, s[1], s[2]]];
        one.tare = vec![0];
        let m = &cfg.motion;
        assert_eq!((m.dwell_speed_m_s, ccfg.reel_accel_m_s2), (0.5, 0.5));
        let want = (m.dwell_settle_s + m.dwell_s) + 5.0 + (m.dwell_settle_s + m.dwell_s);
        assert!((plan_robot_time_s(&one, &cfg, &ccfg, None) - want).abs() < 1e-9);
    }

    #[test]
    fn the_default_knobs_are_the_loops_plan() {
        let (cfg, ccfg) = example();
        let plan = dwell_plan(&cfg, &ccfg).unwrap();
        assert_eq!(plan, dwell_plan_with(&cfg, &ccfg, &PlanKnobs { tare_s: Some(cfg.motion.dwell_s), ..PlanKnobs::default() }).unwrap());
        // Longer tares: a smaller bound.
        let long = dwell_plan_with(&cfg, &ccfg, &PlanKnobs { tare_s: Some(3.0 * cfg.motion.dwell_s), ..PlanKnobs::default() }).unwrap();
        assert!(long.worst_anchor_sigma_m < plan.worst_anchor_sigma_m);
        // More poses than the loop holds, from a finer grid.
        let mut many = cfg.clone();
        let knobs = PlanKnobs { max_poses: 100, grid: [11, 7, 6], tare_s: None };
        many.motion.dwell_poses = 80;
        assert_eq!(dwell_plan_with(&many, &ccfg, &knobs).unwrap().poses.len(), 80);
    }

    #[test]
    fn tare_labels_agree_with_calib() {
        // The loop labels a tare of pose k with MAX_DWELL_POSES + k; calib reads labels from
        // TARE_LABEL_BASE on as tares.
        assert_eq!(taut_calib::selfcal::dwell::TARE_LABEL_BASE, MAX_DWELL_POSES as i32);
    }
}

/// The planner's predictions for candidate plans of the example robot at the simulated bus's
/// measured ~128 tension readings a second, with P(worst aligned anchor > 3 mm) at 1, 1.181 and
/// 1.45 x the predicted sigma (the acceptance test's honesty bound and its recording check,
/// tests/tests/simtime/notracker_3mm.rs; the example plan is 16 x 34 s with 8 tares;
/// BENCHMARKS.md, "Start-up without a tracker"):
/// `cargo test -p taut-calibrator --lib plan_predictions -- --ignored --nocapture`.
#[cfg(test)]
mod plan_predictions {
    #[test]
    #[ignore]
    fn plan_predictions() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim-notracker.toml");
        let base = taut_config::RobotConfig::load(path).unwrap();
        // (poses, dwell s, tares, tares through every cable, tension readings/s)
        for &(poses, dwell, tares, each, rate) in &[
            (16usize, 2.5f64, 8usize, true, 128.0f64),
            (16, 2.5, 16, true, 1280.0),
            (16, 20.0, 6, true, 128.0),
            (16, 25.0, 6, true, 128.0),
            (16, 25.0, 8, true, 128.0),
            (12, 40.0, 6, true, 128.0),
            (16, 30.0, 6, true, 128.0),
            (16, 32.0, 6, true, 128.0),
            (16, 30.0, 8, true, 128.0),
            (16, 32.0, 8, true, 128.0),
            (16, 34.0, 8, true, 128.0),
        ] {
            for ea in [false, true] {
                let mut cfg = base.clone();
                cfg.motion.dwell_poses = poses;
                cfg.motion.dwell_s = dwell;
                cfg.motion.dwell_tares = tares;
                cfg.motion.dwell_tare_each_cable = each;
                cfg.motion.dwell_settle_s = 0.5;
                cfg.motion.dwell_speed_m_s = 0.5;
                cfg.loadcells.as_mut().unwrap().poll_period_s = 1.0 / rate;
                if ea {
                    // The dynamic plant's datasheet stiffness (tests/tests/notracker).
                    cfg.calibration.cable_ea_n = 0.9e6;
                    cfg.calibration.cable_ea_sigma_n = 0.15e6;
                }
                let ccfg = <taut_rt::motion::ControllerConfig as taut_io::FromRobot>::from_robot(&cfg).unwrap();
                let p = super::dwell_plan(&cfg, &ccfg).unwrap();
                let nominal = cfg.anchors().unwrap();
                let m = &cfg.motion;
                let ntares = p.tare.iter().filter(|&&t| t != 0).count();
                let wall = poses as f64 * (m.dwell_s + m.dwell_settle_s)
                    + ntares as f64 * (m.dwell_s + 2.0 * m.dwell_settle_s)
                    + p.path_m / m.dwell_speed_m_s;
                let mc = |scale: f64| p.worst_exceeds_probability(&nominal, 3e-3, scale, 4_000_000);
                let ((pr, up), (_, up118), (_, up145)) = (mc(1.0), mc(1.181), mc(1.45));
                eprintln!(
                "{poses} x {dwell} s, {tares} tares (each cable {each}), {rate}/s, stiffness fitted {ea}: worst-anchor sigma {:.3} mm, P(worst > 3 mm) {pr:.1e} (<= {up:.1e}); at 1.181 sigma <= {up118:.1e}, at 1.45 sigma <= {up145:.1e}; ~{wall:.0} s (path {:.1} m), z sigmas {:?} mm, tare masks {:?}",
                p.worst_anchor_sigma_m * 1e3,
                p.path_m,
                p.anchor_sigma_m.iter().map(|s| (s[2] * 1e4).round() / 10.0).collect::<Vec<_>>(),
                p.tare.iter().filter(|&&t| t != 0).collect::<Vec<_>>()
            );
            }
        }
    }
}
