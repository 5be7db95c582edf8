//! Whether the start-up without a tracker can reach a worst anchor of 2 mm (after the alignment:
//! translation + rotation about the vertical) in 3 minutes of the robot's time: the planner's
//! Cramér–Rao bound for the example robot (config/examples/aras-cam-sim-notracker.toml) over a
//! family of plans, at the simulated bus's 62 tension readings a second per cable and at the 128
//! of cells on a pseudo-terminal, and the shortest robot time that does reach it.
//!
//! `cargo test -p taut-tests --test simtime notracker_2mm::two_mm -- --ignored --nocapture` (a
//! few minutes: planner runs and Monte Carlo only, no start-up). The loop's best 3-minute plan
//! run on the dynamic plant, for the honesty of that bound at 3 minutes and what such a
//! start-up gives: [`three_minute_startups_on_the_dynamic_plant`].
//!
//! # What limits it
//!
//! The worst anchor is the anchor heights (their x and y are 0.1-0.2 mm in the same plans), and
//! the heights are the frame's tilt, which only gravity fixes: through the load cells, 0.3 N of
//! noise per reading against a 29 N weight. The encoders do not: on this robot the anchors are
//! coplanar, and lengths alone leave the horizontal layout undetermined
//! (`TAUT_ENCODERS_ONLY=1 ... plan_candidates`), while the heights they fix in the rigid frame
//! include the tilt. So the load cells carry both the tilt and, through their directions, the
//! layout, and the information on the tilt is the number of tension readings at rest times the
//! weight's share of the force balance: the plan chooses little beyond how long it records.
//! What it does choose: the split between dwells (the tilt) and tares (each cable's offset
//! leaks into the tilt through the cable's horizontal direction, so a tare shorter than the
//! dwells costs more than it saves), and not too many poses (moves and settling record
//! nothing). Many poses with short rests are the worst use of the time.
//!
//! # The budget a plan must meet
//!
//! As the 3 mm acceptance's plan check (`notracker_3mm_dynamic`): P(worst aligned anchor > 2 mm)
//! below [`PLAN_P_MAX`] = 6e-5 (99.9 % Monte Carlo upper bound) at the dynamic plant's honesty
//! bound [`HONESTY_UP`] = 1.54 x the planner's covariance. For the bound alone (honesty 1) the
//! scale at which a plan meets it is printed as well.
//!
//! # The plans
//!
//! [`SHAPES`]: poses, tares (rotating through the four cables) and a tare's recorded time as a
//! multiple of the dwell (the loop records a tare as long as a dwell: ratio 1), at the example's
//! settle (0.5 s), speed (0.5 m/s) and acceleration (0.5 m/s^2), and one with faster moves. For
//! each, the dwell that fills 3 minutes of robot time
//! (`taut_calibrator::notracker::plan_robot_time_s`: the first rest, the moves as the loop's
//! trapezoids, settling, dwells and tares), its sigma and P; then the dwell that meets the
//! budget (the covariance scales as 1 / dwell, checked with the planner at that dwell) and its
//! robot time. Also the floor with every load cell's offset known (tares of 10^6 s, their time
//! not counted), the tension rate at which the best 3-minute plan would meet the budget, and
//! that plan with a heavier platform.

use super::notracker_3mm::{PLAN_P_MAX, SIM_RATE_HZ};
use super::notracker_3mm_dynamic::HONESTY_UP;
use crate::notracker::{report, robot, start_on_plant, Plan};
use taut_calib::selfcal::plan::DwellPlan;
use taut_calibrator::notracker::{dwell_plan_with, plan_robot_time_s, PlanKnobs};
use taut_config::RobotConfig;
use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;

/// The worst aligned anchor the issue asks for, m.
const LIMIT_M: f64 = 2e-3;

/// The robot's time the issue allows, s.
const ROBOT_S: f64 = 180.0;

/// Tension readings a second per cable of load cells on a pseudo-terminal (no character
/// times): what the example's plan was chosen at.
const PTY_RATE_HZ: f64 = 128.0;

/// A family of plans: the dwell is what the search sets.
#[derive(Clone, Copy, Debug)]
struct Shape {
    poses: usize,
    tares: usize,
    /// A tare's recorded time over the dwell's.
    tare_ratio: f64,
    settle_s: f64,
    speed_m_s: f64,
    accel_m_s2: f64,
}

const fn shape(poses: usize, tares: usize, tare_ratio: f64) -> Shape {
    Shape { poses, tares, tare_ratio, settle_s: 0.5, speed_m_s: 0.5, accel_m_s2: 0.5 }
}

/// The plans weighed: 12-40 poses, no tares or each cable tared once or twice, tares as long as
/// a dwell (what the loop runs) or longer; the last with faster moves (0.3 s settle, 1 m/s,
/// 1 m/s^2: optimistic for the dynamic plant's swing).
const SHAPES: [Shape; 9] = [
    shape(12, 4, 1.0),
    shape(12, 4, 3.0),
    shape(16, 0, 1.0),
    shape(16, 4, 1.0),
    shape(16, 4, 3.0),
    shape(16, 8, 1.0),
    shape(16, 8, 2.0),
    shape(40, 4, 6.0),
    Shape { settle_s: 0.3, speed_m_s: 1.0, accel_m_s2: 1.0, ..shape(12, 4, 3.0) },
];

/// The example robot with `s` at `dwell_s`, the cables' datasheet stiffness (the dynamic
/// plant's) and `rate` tension readings a second per cable.
fn configure(base: &RobotConfig, s: &Shape, dwell_s: f64, rate: f64) -> RobotConfig {
    let mut cfg = base.clone();
    cfg.motion.dwell_poses = s.poses;
    cfg.motion.dwell_s = dwell_s;
    cfg.motion.dwell_tares = s.tares;
    cfg.motion.dwell_settle_s = s.settle_s;
    cfg.motion.dwell_speed_m_s = s.speed_m_s;
    cfg.motion.init_reel_accel_m_s2 = s.accel_m_s2;
    cfg.loadcells.as_mut().unwrap().poll_period_s = 1.0 / rate;
    cfg.calibration.cable_ea_n = 0.9e6;
    cfg.calibration.cable_ea_sigma_n = 0.15e6;
    cfg
}

/// The plan of `s` at `dwell_s` and `rate`, and the robot's time through it (tares of
/// `tare_s`, default `tare_ratio x dwell_s`; `count_tares` false: their time left out).
fn plan_of(base: &RobotConfig, s: &Shape, dwell_s: f64, rate: f64, tare_s: Option<f64>, count_tares: bool) -> (DwellPlan, f64) {
    let cfg = configure(base, s, dwell_s, rate);
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let tare_s = tare_s.unwrap_or(s.tare_ratio * dwell_s);
    let knobs = PlanKnobs { tare_s: Some(tare_s), ..PlanKnobs::default() };
    let p = dwell_plan_with(&cfg, &ccfg, &knobs).unwrap();
    let t = plan_robot_time_s(&p, &cfg, &ccfg, Some(if count_tares { tare_s } else { 0.0 }))
        - if count_tares { 0.0 } else { 2.0 * s.settle_s * p.tare.iter().filter(|&&m| m != 0).count() as f64 };
    (p, t)
}

/// P(worst aligned anchor > [`LIMIT_M`]) at `scale` x the plan's covariance: the 99.9 % upper
/// bound.
fn p_exceeds(p: &DwellPlan, nominal: &[[f64; 3]], scale: f64, draws: usize) -> f64 {
    p.worst_exceeds_probability(nominal, LIMIT_M, scale, draws).1
}

/// The largest scale of the plan's covariance at which P(worst > [`LIMIT_M`]) stays below
/// [`PLAN_P_MAX`] (bisection on 1e6 draws).
fn scale_at_budget(p: &DwellPlan, nominal: &[[f64; 3]]) -> f64 {
    let (mut lo, mut hi) = (0.0, 2.0);
    for _ in 0..11 {
        let mid = 0.5 * (lo + hi);
        if p_exceeds(p, nominal, mid, 1_000_000) < PLAN_P_MAX {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The dwell at which `s` takes [`ROBOT_S`] of the robot's time (the time is linear in the
/// dwell for fixed poses; the poses chosen barely move with it), or `None` if even 0.5 s
/// dwells take longer.
fn dwell_for_robot_time(base: &RobotConfig, s: &Shape, rate: f64) -> Option<(f64, DwellPlan, f64)> {
    let mut d = 5.0;
    for _ in 0..6 {
        let (p, t) = plan_of(base, s, d, rate, None, true);
        if (t - ROBOT_S).abs() < 0.5 {
            return Some((d, p, t));
        }
        let tares = p.tare.iter().filter(|&&m| m != 0).count() as f64;
        // Seconds of robot time per second of dwell: the first rest, every pose, every tare.
        let slope = 1.0 + s.poses as f64 + tares * s.tare_ratio;
        d += (ROBOT_S - t) / slope;
        if d < 0.5 {
            return None;
        }
    }
    let (p, t) = plan_of(base, s, d, rate, None, true);
    Some((d, p, t))
}

/// The shortest dwell of `s` that meets the budget at `honesty` x the planner's covariance
/// ([`HONESTY_UP`], or 1: the bound alone), starting from the covariance's 1 / dwell scaling at
/// a plan of `d0` s dwells that has `scale` of room (`scale_at_budget`), then checked with the
/// planner in 3 % steps: the shortest that holds; `offsets_known`: tares of 10^6 s, their
/// time not counted. Returns the dwell, the plan, its time.
fn dwell_for_budget(
    base: &RobotConfig,
    s: &Shape,
    rate: f64,
    (d0, scale): (f64, f64),
    offsets_known: bool,
    honesty: f64,
) -> (f64, DwellPlan, f64) {
    let nominal = base.anchors().unwrap();
    let at = |d: f64| {
        let (p, t) = plan_of(base, s, d, rate, offsets_known.then_some(1e6), !offsets_known);
        let ok = p_exceeds(&p, &nominal, honesty, 2_000_000) < PLAN_P_MAX;
        (ok, (d, p, t))
    };
    let mut d = d0 * (honesty / scale.max(1e-3)).powi(2);
    let (mut ok, mut last) = at(d);
    if ok {
        // Shorter while it holds: the last that held.
        loop {
            d /= 1.03;
            let (held, this) = at(d);
            if !held {
                return last;
            }
            last = this;
        }
    }
    while !ok {
        d *= 1.03;
        (ok, last) = at(d);
    }
    last
}

#[test]
#[ignore]
fn two_mm_in_three_minutes() {
    let dir = tempfile::tempdir().unwrap();
    let base = robot(dir.path(), Plan::Example);
    let nominal = base.anchors().unwrap();
    for rate in [SIM_RATE_HZ, PTY_RATE_HZ] {
        // (shape, 3-minute dwell, its scale at the budget)
        let mut best: Option<(Shape, f64, f64)> = None;
        let mut shortest: Option<(Shape, f64, f64)> = None;
        for s in &SHAPES {
            let Some((d, p, t)) = dwell_for_robot_time(&base, s, rate) else {
                eprintln!("{rate}/s {s:?}: longer than {ROBOT_S} s at 0.5 s dwells");
                continue;
            };
            let scale = scale_at_budget(&p, &nominal);
            let (p1, p_h) = (p_exceeds(&p, &nominal, 1.0, 2_000_000), p_exceeds(&p, &nominal, HONESTY_UP, 2_000_000));
            let sz = p.anchor_sigma_m.iter().map(|a| a[2]).fold(0.0, f64::max);
            eprintln!(
                "{rate}/s, {} poses, {} tares x {} dwells, settle {} s, {} m/s, {} m/s^2: in {t:.0} s the dwell is {d:.2} s; worst-anchor sigma {:.3} mm (heights up to {:.3} mm); P(worst > 2 mm) <= {p1:.1e} at 1, <= {p_h:.1e} at {HONESTY_UP} sigma; the budget holds up to {scale:.3} sigma",
                s.poses,
                s.tares,
                s.tare_ratio,
                s.settle_s,
                s.speed_m_s,
                s.accel_m_s2,
                p.worst_anchor_sigma_m * 1e3,
                sz * 1e3
            );
            // The claim: no plan of the family reaches 2 mm at the budget in 3 minutes.
            assert!(p_h >= PLAN_P_MAX, "{rate}/s {s:?}: the 3-minute plan meets the 2 mm budget (P {p_h:.1e})");
            if best.is_none_or(|b| scale > b.2) {
                best = Some((*s, d, scale));
            }
            let (dn, pn, tn) = dwell_for_budget(&base, s, rate, (d, scale), false, HONESTY_UP);
            eprintln!(
                "    the 2 mm budget at {dn:.1} s dwells: worst-anchor sigma {:.3} mm, {tn:.0} s ({:.1} min) of robot time",
                pn.worst_anchor_sigma_m * 1e3,
                tn / 60.0
            );
            if shortest.is_none_or(|b| tn < b.2) {
                shortest = Some((*s, dn, tn));
            }
        }
        let (s, d, scale) = best.unwrap();
        let (ss, sd, st) = shortest.unwrap();
        eprintln!(
            "{rate}/s: the best 3-minute plan ({} poses, {} tares x {}, {d:.2} s dwells) meets the budget up to {scale:.3} sigma (needs {HONESTY_UP}); the shortest plan that meets it: {} poses, {} tares x {}, {sd:.1} s dwells, {st:.0} s ({:.1} min)",
            s.poses,
            s.tares,
            s.tare_ratio,
            ss.poses,
            ss.tares,
            ss.tare_ratio,
            st / 60.0
        );
        // The same at the bound alone (honesty 1): what the model's own sigma would need.
        let (d1, p1, t1) = dwell_for_budget(&base, &ss, rate, (sd, HONESTY_UP), false, 1.0);
        eprintln!(
            "{rate}/s: at the bound alone (honesty 1) that plan meets P(worst > 2 mm) < {PLAN_P_MAX:.0e} at {d1:.1} s dwells ({:.3} mm), {t1:.0} s ({:.1} min)",
            p1.worst_anchor_sigma_m * 1e3,
            t1 / 60.0
        );
        assert!(t1 > ROBOT_S);
        // The floor: every load cell's offset known (tares of 10^6 s, their time not counted).
        let (p0, _) = plan_of(&base, &s, d, rate, Some(1e6), false);
        let scale0 = scale_at_budget(&p0, &nominal);
        let (fd, fp, ft) = dwell_for_budget(&base, &s, rate, (d, scale0), true, HONESTY_UP);
        eprintln!(
            "{rate}/s, offsets known: the 3-minute dwells give {:.3} mm (budget up to {scale0:.3} sigma); the budget needs {fd:.1} s dwells ({:.3} mm), {ft:.0} s ({:.1} min) without the tares",
            p0.worst_anchor_sigma_m * 1e3,
            fp.worst_anchor_sigma_m * 1e3,
            ft / 60.0
        );
        assert!(ft > ROBOT_S, "{rate}/s: with the offsets known the budget needs only {ft:.0} s");
        assert!(st > ROBOT_S);
        // The tension rate at which the best 3-minute plan meets the budget (the load cells'
        // information grows with the rate; the encoders' is the same).
        let mut r = rate * (HONESTY_UP / scale.max(1e-3)).powi(2);
        loop {
            let (p, _) = plan_of(&base, &s, d, r, None, true);
            if p_exceeds(&p, &nominal, HONESTY_UP, 2_000_000) < PLAN_P_MAX {
                eprintln!(
                    "{rate}/s: the best 3-minute plan meets the budget at {r:.0} tension readings a second per cable (worst-anchor sigma {:.3} mm): {:.2} N per reading at {rate}/s",
                    p.worst_anchor_sigma_m * 1e3,
                    taut_calibrator::notracker::PLAN_LOADCELL_SIGMA_N * (rate / r).sqrt()
                );
                break;
            }
            r *= 1.03;
        }
        // The tilt's information grows with the weight squared (the horizontal force's noise
        // does not change): the same plan with a heavier platform.
        for mass_kg in [6.0, 12.0, 20.0, 30.0] {
            let mut heavy = base.clone();
            heavy.robot.mass_kg = mass_kg;
            let (p, t) = plan_of(&heavy, &s, d, rate, None, true);
            eprintln!(
                "{rate}/s, a {mass_kg} kg platform: the best 3-minute plan ({t:.0} s) gives {:.3} mm; P(worst > 2 mm) <= {:.1e} at {HONESTY_UP} sigma",
                p.worst_anchor_sigma_m * 1e3,
                p_exceeds(&p, &nominal, HONESTY_UP, 2_000_000)
            );
        }
    }
}

/// What a start-up of 3 minutes gives on the dynamic plant: [`Plan::ThreeMinutes`] (12 poses of
/// 7.5 s, 4 tares as long as a dwell: the loop's best 3-minute plan of [`SHAPES`]), seeds 1-5
/// (`TAUT_E2E_SEEDS` for others), with the cables' datasheet stiffness. Every check of
/// `start_on_plant` (each aligned coordinate within 4.89 of its sigmas, the chi-square, the
/// achieved / predicted sigma within 0.8-1.5, the tares, the hot-swap) and the plan's robot time
/// at most 3 minutes; the worst anchors are measured and counted against 2 mm, not asserted:
/// `cargo test -p taut-tests --test simtime notracker_2mm::three_minute -- --ignored --nocapture`
/// (about 2 s of wall time a seed).
#[test]
#[ignore]
fn three_minute_startups_on_the_dynamic_plant() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = robot(dir.path(), Plan::ThreeMinutes);
    cfg.calibration.cable_ea_n = 0.9e6;
    cfg.calibration.cable_ea_sigma_n = 0.15e6;
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let plan = taut_calibrator::notracker::dwell_plan(&cfg, &ccfg).unwrap();
    let robot_s = plan_robot_time_s(&plan, &cfg, &ccfg, None);
    let mut at_bus = cfg.clone();
    at_bus.loadcells.as_mut().unwrap().poll_period_s = 1.0 / SIM_RATE_HZ;
    let bus = taut_calibrator::notracker::dwell_plan(&at_bus, &ccfg).unwrap();
    eprintln!(
        "the plan: {} poses, {} tares, {robot_s:.0} s of robot time; worst-anchor sigma {:.2} mm at {SIM_RATE_HZ}/s",
        plan.poses.len(),
        plan.tare.iter().filter(|&&m| m != 0).count(),
        bus.worst_anchor_sigma_m * 1e3
    );
    assert!(robot_s <= ROBOT_S, "{robot_s} s");
    let seeds: Vec<u64> =
        std::env::var("TAUT_E2E_SEEDS").map_or((1..=5).collect(), |v| v.split(',').map(|x| x.trim().parse().unwrap()).collect());
    let n = seeds.len();
    let (mut over, mut ratios) = (0, Vec::new());
    for seed in seeds {
        let r = start_on_plant(seed, Plan::ThreeMinutes, false, true, true);
        over += usize::from(r.worst_aligned_m > LIMIT_M);
        ratios.push(r.achieved_worst_sigma_m / r.repredicted_worst_sigma_m);
        report(seed, &r);
        eprintln!(
            "3-minute seed {seed}: worst aligned anchor {:.2} mm; achieved / predicted sigma {:.3}; chi2/dof {:.2}; {:.1} s wall",
            r.worst_aligned_m * 1e3,
            r.achieved_worst_sigma_m / r.repredicted_worst_sigma_m,
            r.chi2_dof,
            r.seconds
        );
    }
    let (mean, sd, _) = taut_tests::honesty::upper_prediction_bound(&ratios, 1e-3);
    let nominal = cfg.anchors().unwrap();
    let (p1, _) = bus.worst_exceeds_probability(&nominal, LIMIT_M, 1.0, 1_000_000);
    eprintln!(
        "{over} of {n} start-ups above 2 mm (the plan's bound at {SIM_RATE_HZ}/s: P = {p1:.2}); achieved / predicted sigma mean {mean:.3}, sd {sd:.3}"
    );
}
