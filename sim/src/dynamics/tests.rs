use super::*;
use crate::physics::G;
use crate::{Noise, Plant, Scenario};

const EA: f64 = 40_000.0;
const DT: f64 = 1e-3;

fn scenario(dynamics: Option<Dynamics>) -> Scenario {
    let mut s = Scenario::aras_cam(5);
    s.physics = Physics { elasticity: Some(EA), dynamics, ..Physics::ideal() };
    s.noise = Noise::none();
    s
}

fn lengths(l: &[f64]) -> Vec<CableCommand> {
    l.iter().map(|&d| CableCommand::Length(d)).collect()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Unit vector from the platform point towards anchor `a` (the scenario has no pulleys and a
/// point-mass platform).
fn toward(a: [f64; 3], p: [f64; 3]) -> [f64; 3] {
    let d = sub(a, p);
    let l = norm(d);
    [d[0] / l, d[1] / l, d[2] / l]
}

/// The platform's acceleration by the second difference of three positions `DT` apart.
fn accel(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|k| (p2[k] - 2.0 * p1[k] + p0[k]) / (DT * DT))
}

/// Zero crossings (interpolated, in samples) and positive peaks (parabola through the top three
/// samples: index, value) of `x`.
fn crossings_and_peaks(x: &[f64]) -> (Vec<f64>, Vec<(f64, f64)>) {
    let mut zc = Vec::new();
    let mut peaks = Vec::new();
    for i in 1..x.len() {
        if (x[i - 1] > 0.0) != (x[i] > 0.0) {
            zc.push((i - 1) as f64 + x[i - 1] / (x[i - 1] - x[i]));
        }
        if i + 1 < x.len() && x[i] > 0.0 && x[i] > x[i - 1] && x[i] >= x[i + 1] {
            let (a, b, c) = (x[i - 1], x[i], x[i + 1]);
            let den = a - 2.0 * b + c;
            let off = if den != 0.0 { 0.5 * (a - c) / den } else { 0.0 };
            peaks.push((i as f64 + off, b - 0.25 * (a - c) * off));
        }
    }
    (zc, peaks)
}

/// A 1 mm push along the lowest mode's shape: the platform swings at that mode's damped
/// frequency and decays with its damping ratio (zero crossings and logarithmic decrement of the
/// simulated trajectory against the eigenvalues of the linearised model).
#[test]
fn swing_matches_the_linearised_lowest_mode() {
    for zeta in [0.02, 0.1] {
        let s = scenario(Some(Dynamics { damping_ratio: zeta, ..Dynamics::default() }));
        let (mut plant, hold) = s.plant().unwrap();
        let cmds = lengths(&hold);
        let p_eq = plant.position();
        let modes = plant.predicted_modes().unwrap();
        // The free function agrees with the plant's own.
        let t: Vec<f64> = (0..4).map(|j| plant.true_tension(j)).collect();
        let free = predicted_modes(&s.truth().unwrap(), &s.physics, p_eq, &t);
        assert!((free[0].natural_hz - modes[0].natural_hz).abs() < 1e-9 * modes[0].natural_hz, "{free:?} {modes:?}");
        let m0 = modes[0];
        assert!(m0.natural_hz < 0.8 * modes[1].natural_hz, "a separate lowest mode: {modes:?}");
        plant.nudge(m0.shape.map(|c| 1e-3 * c), [0.0; 3]);
        let x: Vec<f64> = (0..4000).map(|_| dot(sub(plant.step(DT, &cmds).position, p_eq), m0.shape)).collect();
        let (zc, peaks) = crossings_and_peaks(&x);
        // Peaks above 2 % of the push (the other modes' share and round-off stay far below).
        let peaks: Vec<_> = peaks.into_iter().take_while(|p| p.1 > 2e-5).collect();
        assert!(peaks.len() >= 8, "{} peaks", peaks.len());
        let last = peaks.last().unwrap().0;
        let zc: Vec<f64> = zc.into_iter().filter(|&z| z <= last).collect();
        let half_periods = (zc.len() - 1) as f64;
        let freq = half_periods / (2.0 * (zc[zc.len() - 1] - zc[0]) * DT);
        let cycles = peaks.len() - 1;
        let delta = (peaks[0].1 / peaks[cycles].1).ln() / cycles as f64;
        let zeta_meas = delta / (4.0 * std::f64::consts::PI.powi(2) + delta * delta).sqrt();
        let freq_peaks = cycles as f64 / ((peaks[cycles].0 - peaks[0].0) * DT);
        println!(
            "cable zeta {zeta}: modes {:?}; lowest measured {freq:.3} Hz (peaks {freq_peaks:.3}) zeta {zeta_meas:.4} vs \
             predicted {:.3} Hz zeta {:.4} ({} peaks, substeps {})",
            modes.map(|m| (m.natural_hz, m.damping_ratio)),
            m0.damped_hz,
            m0.damping_ratio,
            peaks.len(),
            plant.report().iterations
        );
        assert!((freq / m0.damped_hz - 1.0).abs() < 0.1, "frequency {freq} vs {}", m0.damped_hz);
        assert!((zeta_meas / m0.damping_ratio - 1.0).abs() < 0.1, "damping {zeta_meas} vs {}", m0.damping_ratio);
    }
}

/// From rest, ramped to other drum lengths with one cable in torque mode, the dynamic plant
/// settles where the quasi-static plant's equilibrium is.
#[test]
fn settles_at_the_quasi_static_equilibrium() {
    let sd = scenario(Some(Dynamics::default()));
    let sq = scenario(None);
    let truth = sd.truth().unwrap();
    let (mut dynp, hold_a) = sd.plant().unwrap();
    let s_min = sd.min_tension_n;
    let c = dynp.position();
    let target = [c[0] + 0.3, c[1] - 0.2, c[2] + 0.25];
    let hold_b = dynp.lengths_at_rest(target, s_min).unwrap();
    let mut qs = Plant::new(&truth, &sq.physics, target);
    assert!(qs.step(0.0, &lengths(&hold_b)).report.converged);
    let t3 = qs.true_tension(3);
    let mut mixed = lengths(&hold_b);
    mixed[3] = CableCommand::Tension(t3);
    let q = qs.step(DT, &mixed);
    assert!(q.report.was_successful());
    let (p_qs, drum3_qs) = (q.position, q.drum_m[3]);
    let t_qs: Vec<f64> = (0..4).map(|j| qs.true_tension(j)).collect();
    let ta = dynp.true_tension(3);
    for k in 1..=1000 {
        let s = k as f64 / 1000.0;
        let mut cmds: Vec<_> = (0..4).map(|j| CableCommand::Length(hold_a[j] + s * (hold_b[j] - hold_a[j]))).collect();
        cmds[3] = CableCommand::Tension(ta + s * (t3 - ta));
        dynp.step(DT, &cmds);
    }
    let moved = norm(sub(dynp.position(), c));
    for _ in 0..9000 {
        dynp.step(DT, &mixed);
    }
    let out = dynp.step(DT, &mixed);
    let (p, drum3) = (out.position, out.drum_m[3]);
    let dp = norm(sub(p, p_qs));
    println!("moved {moved:.3} m; settled {dp:.2e} m from the quasi-static equilibrium; drum 3 {drum3} vs {drum3_qs}");
    assert!(moved > 0.3, "the platform moved: {moved}");
    assert!(dp < 1e-4, "{p:?} vs {p_qs:?}");
    for j in 0..4 {
        let t = dynp.true_tension(j);
        assert!((t / t_qs[j] - 1.0).abs() < 0.01, "cable {j}: {t} vs {}", t_qs[j]);
    }
    assert!((drum3 - drum3_qs).abs() < 1e-4, "torque-mode drum {drum3} vs {drum3_qs}");
}

/// Moving with accelerations of several m/s², the reported tensions balance the mass times the
/// acceleration (second difference of the reported positions) and gravity.
#[test]
fn tensions_balance_mass_times_acceleration() {
    let s = scenario(Some(Dynamics::default()));
    let truth = s.truth().unwrap();
    let (mut plant, _) = s.plant().unwrap();
    let (c, m, s_min) = (plant.position(), truth.mass_kg, s.min_tension_n);
    let mut ps = Vec::new();
    let mut ts = Vec::new();
    // A suspended robot's pretension is bounded by its weight: lengths for 10 N at least carry
    // a ~1.5 m/s² swing of the drums' targets; the cables add their own oscillation.
    for k in 1..=2000 {
        let w = 2.0 * std::f64::consts::PI;
        let s = 0.5 * (1.0 - (w * k as f64 * DT).cos());
        let target = [c[0] + 0.08 * s, c[1] + 0.03 * s, c[2] + 0.03 * s];
        let cmds = lengths(&plant.lengths_at_rest(target, s_min.max(10.0)).unwrap());
        let out = plant.step(DT, &cmds);
        assert!(out.tension_n.iter().all(|&t| t > 0.0), "a cable went slack at step {k}");
        ps.push(out.position);
        ts.push(out.tension_n.to_vec());
    }
    let (mut worst, mut max_ma) = (0.0f64, 0.0f64);
    for k in 1..ps.len() - 1 {
        let a = accel(ps[k - 1], ps[k], ps[k + 1]);
        let mut f = [0.0, 0.0, -m * G];
        for j in 0..4 {
            let u = toward(truth.anchors[j], ps[k]);
            for i in 0..3 {
                f[i] += ts[k][j] * u[i];
            }
        }
        worst = worst.max(norm(sub(f, a.map(|x| m * x))));
        max_ma = max_ma.max(m * norm(a));
    }
    println!("max m|a| {max_ma:.2} N, worst |sum T u + m g - m a| {worst:.3e} N");
    assert!(max_ma > 0.1 * m * G, "accelerations of {max_ma} N only");
    assert!(worst < 0.005 * m * G, "{worst} N unbalanced");
}

/// All drums pay out 2 cm at once: the cables go slack, their tensions read 0 and the platform
/// falls freely, then they catch it again and it settles at the new equilibrium.
#[test]
fn cables_go_slack_in_a_drop_and_recover() {
    let s = scenario(Some(Dynamics::default()));
    let truth = s.truth().unwrap();
    let (mut plant, hold) = s.plant().unwrap();
    assert!((0..4).all(|j| plant.true_tension(j) > 10.0));
    let low: Vec<f64> = hold.iter().map(|l| l + 0.02).collect();
    let cmds = lengths(&low);
    let mut ps = vec![plant.position()];
    let mut slack_steps = 0;
    let mut free_fall = 0;
    let mut recovered_at = None;
    let mut max_t = 0.0f64;
    for k in 0..3000 {
        let out = plant.step(DT, &cmds);
        ps.push(out.position);
        let t = out.tension_n.to_vec();
        max_t = t.iter().fold(max_t, |a, &b| a.max(b));
        if t.iter().all(|&x| x == 0.0) {
            slack_steps += 1;
            assert!((0..4).all(|j| plant.true_tension(j) == 0.0));
            if ps.len() >= 3 {
                let n = ps.len();
                // Slack at the previous step's end too: the step integrated free fall.
                let a = accel(ps[n - 3], ps[n - 2], ps[n - 1]);
                if recovered_at.is_none() && slack_steps >= 2 {
                    assert!(norm(sub(a, [0.0, 0.0, -G])) < 1e-6, "free fall at step {k}: {a:?}");
                    free_fall += 1;
                }
            }
        } else if slack_steps > 0 && recovered_at.is_none() && t.iter().all(|&x| x > 0.0) {
            recovered_at = Some(k);
        }
    }
    let mut qs = Plant::new(&truth, &scenario(None).physics, plant.position());
    let q = qs.step(0.0, &cmds);
    let dp = norm(sub(plant.position(), q.position));
    println!("slack for {slack_steps} steps ({free_fall} checked free fall), all taut again at step {recovered_at:?}, peak {max_t:.1} N, settled {dp:.1e} m off");
    assert!(slack_steps >= 20, "{slack_steps} slack steps");
    assert!(free_fall >= 10);
    assert!(recovered_at.is_some(), "never taut again");
    assert!(dp < 1e-4, "settled {dp} m from the equilibrium");
    for j in 0..4 {
        assert!((plant.true_tension(j) / qs.true_tension(j) - 1.0).abs() < 0.01);
    }
}

/// Cables stiff enough that 1 ms is beyond the stability limit: the plant sub-steps below it
/// and a push decays instead of growing.
#[test]
fn stiff_cables_sub_step_inside_the_stability_limit() {
    let mut s = scenario(Some(Dynamics::default()));
    s.physics.elasticity = Some(5e7);
    let (mut plant, hold) = s.plant().unwrap();
    let cmds = lengths(&hold);
    let p_eq = plant.position();
    let w_max = 2.0 * std::f64::consts::PI * plant.predicted_modes().unwrap()[2].natural_hz;
    plant.nudge([1e-4, -1e-4, 1e-4], [0.0; 3]);
    let mut h = 0.0;
    for _ in 0..2000 {
        let out = plant.step(DT, &cmds);
        h = DT / out.report.iterations as f64;
    }
    let left = norm(sub(plant.position(), p_eq));
    println!("w_max {w_max:.0} rad/s, sub-step {h:.2e} s (limit 2/w {:.2e} s), {left:.1e} m left of a 0.17 mm push", 2.0 / w_max);
    assert!(h < 2.0 / w_max && h < DT, "sub-step {h}");
    assert!(left < 1e-5 && plant.failed_steps() == 0, "{left} m");
}

/// A mixed run (noise, time offset, backlash, torque mode, a drop) twice: bit for bit the same.
#[test]
fn dynamic_plant_is_deterministic() {
    let run = || {
        let mut s = scenario(Some(Dynamics::default()));
        s.noise = Noise::default();
        s.physics.time_offset_s = 0.02;
        s.physics.backlash_m = 0.002;
        let (mut plant, hold) = s.plant().unwrap();
        let mut bits = Vec::new();
        for k in 0..2000 {
            let mut cmds = lengths(&hold.iter().map(|l| l + if k > 1200 { 0.01 } else { 1e-5 * k as f64 }).collect::<Vec<_>>());
            cmds[2] = CableCommand::Tension(30.0 + (k as f64 * 0.01).sin());
            let dt = if k % 3 == 0 { 0.002 } else { DT };
            let out = plant.step(dt, &cmds);
            bits.extend(out.position.iter().chain(out.encoder_m).chain(out.tension_n).chain(out.drum_m).map(|x| x.to_bits()));
            bits.extend(plant.velocity().map(f64::to_bits));
        }
        bits
    };
    let (a, b) = (run(), run());
    assert_eq!(a.len(), b.len());
    assert!(a == b, "two runs differ");
}

/// 60 s of simulated time at 1 kHz steps (`cargo test --release -- --ignored --nocapture`).
#[test]
#[ignore = "timing"]
fn sixty_seconds_timing() {
    let mut s = scenario(Some(Dynamics::default()));
    s.noise = Noise::default();
    let (mut plant, hold) = s.plant().unwrap();
    let t0 = std::time::Instant::now();
    let mut sub = 0;
    for k in 0..60_000 {
        let cmds = lengths(&hold.iter().map(|l| l + 0.02 * (k as f64 * 1e-3).sin()).collect::<Vec<_>>());
        sub += plant.step(DT, &cmds).report.iterations;
    }
    println!("60 s simulated in {:?} ({sub} sub-steps)", t0.elapsed());
}

/// Three cables held in position mode, the fourth following in torque mode at 10 N (the
/// start-up's phases): a 1 mm push decays, the follower's tension returns to its command and
/// never goes slack on the way.
#[test]
fn a_torque_mode_follower_keeps_the_swing_stable() {
    let s = scenario(Some(Dynamics::default()));
    let (mut plant, hold) = s.plant().unwrap();
    let mut cmds = lengths(&hold);
    cmds[3] = CableCommand::Tension(10.0);
    for _ in 0..3000 {
        plant.step(DT, &cmds);
    }
    let p_eq = plant.position();
    plant.nudge([1e-3, -1e-3, 1e-3], [0.0; 3]);
    let mut env = [0.0f64; 6];
    let mut min_follower = f64::INFINITY;
    for k in 0..6000 {
        let out = plant.step(DT, &cmds);
        let d = norm(sub(out.position, p_eq));
        env[k / 1000] = env[k / 1000].max(d);
        min_follower = min_follower.min(plant.true_tension(3));
    }
    println!("swing envelope per second {:?} mm; follower tension at least {min_follower:.2} N", env.map(|e| e * 1e3));
    assert!(env[5] < 0.5 * env[0], "the swing grows or hardly decays: {env:?}");
    assert!(min_follower > 1.0, "the follower went slack: {min_follower} N");
    assert!((plant.true_tension(3) - 10.0).abs() < 0.1, "follower at {} N", plant.true_tension(3));
}

/// Platform points of the rigid platform's tests: a 0.3 m x 0.2 m frame 5 cm above the
/// reference point.
const RIGID_POINTS: [[f64; 3]; 4] = [[0.15, -0.1, 0.05], [0.15, 0.1, 0.05], [-0.15, 0.1, 0.05], [-0.15, -0.1, 0.05]];

/// The test scenario with the platform points, 13 kg, a rigid platform of a 0.4 m x 0.3 m x
/// 0.2 m box with its centre of mass at `com`, damping ratio `zeta`, sub-steps of `h` at most.
fn rigid_scenario(com: [f64; 3], zeta: f64, h: f64) -> Scenario {
    let mass = 13.0;
    let body = RigidBody::uniform_box(mass, [0.4, 0.3, 0.2], com);
    let mut s = scenario(Some(Dynamics { damping_ratio: zeta, max_substep_s: h, rigid_body: Some(body), ..Dynamics::default() }));
    s.robot.robot.mass_kg = mass;
    for (c, b) in s.robot.cables.iter_mut().zip(RIGID_POINTS) {
        c.platform_point = b;
    }
    s
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Largest change of the mechanical energy over 10 s of an undamped swing and twist, relative
/// to the kinetic energy the push gave, sub-steps of at most `h`; and the smallest tension.
fn free_swing_energy_drift(h: f64) -> (f64, f64) {
    let s = rigid_scenario([0.0, 0.0, -0.1], 0.0, h);
    let (mut plant, hold) = s.plant().unwrap();
    let cmds = lengths(&hold);
    let e_rest = plant.mechanical_energy().unwrap();
    plant.nudge([0.0; 3], [0.05, -0.03, 0.02]);
    plant.nudge_rotation([0.1, -0.15, 0.2]);
    let e0 = plant.mechanical_energy().unwrap();
    let (mut worst, mut t_min) = (0.0f64, f64::INFINITY);
    for _ in 0..10_000 {
        plant.step(DT, &cmds);
        worst = worst.max((plant.mechanical_energy().unwrap() - e0).abs());
        t_min = (0..4).map(|j| plant.true_tension(j)).fold(t_min, f64::min);
    }
    (worst / (e0 - e_rest), t_min)
}

/// A rigid platform swinging and twisting without damping keeps its mechanical energy: the
/// semi-implicit Euler's energy error is bounded and of first order in the sub-step, so the
/// drift (relative to the energy of the push) is small at 1 ms and halves with the sub-step.
#[test]
fn rigid_free_swing_conserves_energy() {
    let (d1, t_min) = free_swing_energy_drift(1e-3);
    let (d2, _) = free_swing_energy_drift(5e-4);
    println!("energy drift: {d1:.2e} at 1 ms, {d2:.2e} at 0.5 ms; smallest tension {t_min:.1} N");
    // All cables stay taut: the motion is smooth (no slack events, whose kinks cost energy
    // errors of their own).
    assert!(t_min > 1.0, "a cable went slack: {t_min} N");
    assert!(d1 < 0.02, "energy drift {d1} of the push's energy");
    // First order: halving the sub-step halves the error (within 30 %).
    assert!((d1 / d2 - 2.0).abs() < 0.6, "drift {d1} at 1 ms, {d2} at 0.5 ms");
}

/// With its centre of mass off-centre the rigid platform tilts as it settles; at rest the
/// cables' moments about the centre of mass cancel, and the quasi-static solver at the settled
/// orientation finds the settled position: the static equilibrium with the orientation free.
#[test]
fn rigid_static_hang_settles_at_the_free_orientation_equilibrium() {
    let com = [0.04, -0.03, -0.1];
    let mut s = rigid_scenario(com, 0.05, 1e-3);
    // Four cables leave two modes that stretch none: drag settles them.
    let body = s.physics.dynamics.as_mut().unwrap().rigid_body.as_mut().unwrap();
    (body.drag_n_s_m, body.angular_drag_n_m_s) = (20.0, 2.0);
    let truth = s.truth().unwrap();
    let (mut plant, hold) = s.plant().unwrap();
    let cmds = lengths(&hold);
    for _ in 0..15_000 {
        plant.step(DT, &cmds);
    }
    let p = plant.position();
    let q = plant.orientation();
    let tilt = 2.0 * q[0].abs().min(1.0).acos();
    let (v, w) = (norm(plant.velocity()), norm(plant.angular_velocity().unwrap()));
    // Moments about the centre of mass from the reported tensions.
    let dynamics = s.physics.dynamics.clone().unwrap();
    let models = models(&truth, &s.physics, &dynamics);
    let r = crate::trajectory::rotation(q);
    let c = crate::trajectory::rotate(&r, com);
    let offsets: Vec<[f64; 3]> = RIGID_POINTS.iter().map(|b| crate::trajectory::rotate(&r, *b)).collect();
    let mut tau = [0.0; 3];
    for j in 0..4 {
        let a = [p[0] + offsets[j][0], p[1] + offsets[j][1], p[2] + offsets[j][2]];
        let u = models[j].path(a).dir;
        let t = plant.true_tension(j);
        let m = cross(sub(offsets[j], c), u.map(|x| t * x));
        tau = std::array::from_fn(|k| tau[k] + m[k]);
    }
    // The quasi-static solver with that orientation imposed, from 1 cm away.
    let sys = crate::equilibrium::System { models: &models, offsets: &offsets, commands: &cmds, mass: truth.mass_kg, warm: &[] };
    let mut loads = vec![CableLoad { force: [0.0; 3], energy: 0.0, tension: 0.0, drum_length: 0.0, slack: false }; 4];
    let (p_qs, rep) = sys.solve([p[0] + 0.01, p[1] - 0.01, p[2] + 0.01], &mut loads);
    let dp = norm(sub(p, p_qs));
    // The moment a 1 mm lever of the weight makes, N m.
    let scale = truth.mass_kg * G * 1e-3;
    println!(
        "tilt {:.2} deg; |v| {v:.1e} m/s, |w| {w:.1e} rad/s; |tau| {:.2e} N m; {dp:.1e} m from the quasi-static solver",
        tilt.to_degrees(),
        norm(tau)
    );
    assert!(rep.was_successful(), "{rep:?}");
    assert!(tilt.to_degrees() > 1.0, "the off-centre mass tilts the platform: {} deg", tilt.to_degrees());
    assert!(v < 1e-5 && w < 1e-4, "at rest: {v} m/s, {w} rad/s");
    assert!(norm(tau) < 1e-3 * scale, "moment {tau:?} N m");
    assert!(dp < 1e-6, "{p:?} vs {p_qs:?}");
}

/// A platform on no cables spins about its intermediate axis (unstable: it tumbles) while it
/// falls. Its angular momentum is kept to round-off, its energy to the first-order error, and
/// its body-frame angular velocity follows an independent integration of Euler's equations
/// (RK4 at 0.1 ms).
#[test]
fn torque_free_spin_keeps_its_angular_momentum() {
    let body = RigidBody::uniform_box(13.0, [0.4, 0.3, 0.2], [0.0; 3]);
    let i = [body.inertia_kg_m2[0][0], body.inertia_kg_m2[1][1], body.inertia_kg_m2[2][2]];
    let mut st = DynState::new(Dynamics { rigid_body: Some(body), ..Dynamics::default() }, 0, [1.0, 0.0, 0.0, 0.0]);
    let w0 = [0.1, 3.0, 0.1];
    st.rigid.as_mut().unwrap().add_omega(w0);
    let b = Body { models: &[], offsets: &[], points: &[], mass: 13.0 };
    let l0 = st.rigid.as_ref().unwrap().l;
    let e0 = st.rigid.as_ref().unwrap().kinetic();
    let mut p = [0.0; 3];
    let mut worst_e = 0.0f64;
    let mut min_wy = f64::INFINITY;
    for _ in 0..8000 {
        st.advance(&b, &mut p, DT, &[], &mut []);
        let r = st.rigid.as_ref().unwrap();
        worst_e = worst_e.max((r.kinetic() / e0 - 1.0).abs());
        let wb = rigid::matrix(r.q).transpose() * r.omega();
        min_wy = min_wy.min(wb[1]);
    }
    let r = st.rigid.as_ref().unwrap();
    let dl = (r.l - l0).norm() / l0.norm();
    let wb = rigid::matrix(r.q).transpose() * r.omega();
    // Euler's equations in the body frame, RK4.
    let f = |w: [f64; 3]| [(i[1] - i[2]) * w[1] * w[2] / i[0], (i[2] - i[0]) * w[2] * w[0] / i[1], (i[0] - i[1]) * w[0] * w[1] / i[2]];
    let mut w = w0;
    let hr = 1e-4;
    for _ in 0..80_000 {
        let k1 = f(w);
        let k2 = f(std::array::from_fn(|k| w[k] + 0.5 * hr * k1[k]));
        let k3 = f(std::array::from_fn(|k| w[k] + 0.5 * hr * k2[k]));
        let k4 = f(std::array::from_fn(|k| w[k] + hr * k3[k]));
        w = std::array::from_fn(|k| w[k] + hr / 6.0 * (k1[k] + 2.0 * k2[k] + 2.0 * k3[k] + k4[k]));
    }
    let dw = norm(sub([wb[0], wb[1], wb[2]], w)) / norm(w0);
    println!("|dL|/|L| {dl:.1e}; energy within {worst_e:.1e}; body rate {wb:?} vs Euler {w:?} ({dw:.1e}); smallest w_y {min_wy:.2}");
    assert!(min_wy < 0.0, "the intermediate axis tumbles: smallest w_y {min_wy}");
    assert!(dl < 1e-12, "angular momentum changed by {dl}");
    assert!(worst_e < 1e-2, "energy drift {worst_e}");
    assert!(dw < 0.05, "body rate {wb:?} vs {w:?}");
    assert!(p[2] < -300.0, "falls freely: {p:?}");
}
