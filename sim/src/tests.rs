//! Scenario-level tests: determinism, the physics of the recorded data, each effect, the plant.
//!
//! Checks compute their references here, from the truth and the true positions, not with the
//! simulator's own cable model (except where a test compares one effect on against off).

use crate::physics::G;
use crate::*;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// A short excitation-only ARAS-CAM run with exact sensors and ideal cables.
fn quiet(seed: u64) -> Scenario {
    Scenario {
        rate_hz: 50.0,
        duration_s: 20.0,
        loose_fraction: 0.0,
        three_phase: None,
        noise: Noise::none(),
        physics: Physics::ideal(),
        ..Scenario::aras_cam(seed)
    }
}

fn csv(run: &SimRun) -> Vec<u8> {
    let mut out = Vec::new();
    run.recording.write_csv(&mut out).unwrap();
    out
}

#[test]
fn same_seed_same_bytes() {
    let mut s = Scenario::aras_cam(7);
    s.duration_s = 20.0;
    s.three_phase = Some(ThreePhasePlan { reel_m: 0.2, speed_m_s: 0.2, start: Some([0.5, 0.0, 2.0]), ..ThreePhasePlan::default() });
    s.with_orientation = true;
    let a = csv(&simulate(&s));
    let b = csv(&simulate(&s));
    assert!(a == b, "same scenario, different bytes");
    s.seed = 8;
    assert!(csv(&simulate(&s)) != a, "another seed gives the same recording");
}

#[test]
fn recording_has_the_requested_columns() {
    let mut s = quiet(3);
    s.duration_s = 2.0;
    let r = simulate(&s).recording;
    assert!(r.f.is_some() && r.q.is_none() && r.phase.is_none());
    assert_eq!(r.len(), 100);
    s.with_tensions = false;
    s.with_orientation = true;
    s.three_phase = Some(ThreePhasePlan { reel_m: 0.1, speed_m_s: 0.2, start: Some([0.5, 0.0, 2.0]), ..ThreePhasePlan::default() });
    let r = simulate(&s).recording;
    assert!(r.f.is_none() && r.q.is_some() && r.phase.is_some());
    for k in 0..3 {
        assert!(r.phase.as_ref().unwrap().contains(&k));
    }
}

/// The recorded tensions balance gravity and m a along the true cable directions (accelerations
/// from second differences of the true path), at least the floor where every cable is taut.
#[test]
fn tensions_balance_the_platform() {
    let mut s = quiet(5);
    s.physics = Physics::default();
    s.loose_fraction = 0.2;
    s.duration_s = 30.0;
    let run = simulate(&s);
    let n = 4;
    let dt = 1.0 / s.rate_hz;
    let m = run.truth.mass_kg;
    let (mut checked, mut loose_checked) = (0, 0);
    for i in 1..run.positions.len() - 1 {
        let p = run.positions[i];
        let a: [f64; 3] = std::array::from_fn(|k| (run.positions[i - 1][k] - 2.0 * p[k] + run.positions[i + 1][k]) / (dt * dt));
        let mut r = [m * a[0], m * a[1], m * (a[2] + G)];
        for j in 0..n {
            let d = sub(run.truth.anchors[j], p);
            let t = run.tensions[i * n + j];
            assert!(t >= 0.0);
            for k in 0..3 {
                r[k] -= t * d[k] / norm(d);
            }
        }
        let loose = run.loose[i * n..(i + 1) * n].iter().any(|&x| x);
        if loose {
            // Where a cable is loose the trajectory may ask for more than the cables can give,
            // but never for a force they pull against.
            loose_checked += 1;
        } else {
            assert!(norm(r) < 2e-3 * m * G, "sample {i}: residual {r:?}");
            if run.tensions[i * n..(i + 1) * n].iter().all(|&t| t >= s.min_tension_n - 1e-9) {
                checked += 1;
            }
        }
    }
    assert!(checked > run.positions.len() / 2 && loose_checked > 0, "{checked} {loose_checked}");
}

/// The pretension schedule moves the tensions at the very poses of the run without it: still
/// balancing the platform, within the floor and the ceiling, unchanged where the level is 0,
/// and the drums hold the unstretched length of each tension, `L / (1 + T / EA) - k T`; a
/// 3-cable robot has no internal force to move and is refused.
#[test]
fn pretension_moves_the_tensions_at_the_same_poses() {
    let (ea, k) = (2e4, 5e-5);
    let mut s = quiet(5);
    s.physics = Physics { elasticity: Some(ea), compliance_m_per_n: Some(k), ..Physics::default() };
    let off = simulate(&s);
    s.pretension = Some(tension::Pretension { levels_n: vec![0.0, 15.0, -15.0], hold_s: 4.0, ramp_s: 1.0 });
    let on = simulate(&s);
    assert_eq!(off.positions, on.positions);
    let n = 4;
    let (dt, m) = (1.0 / s.rate_hz, on.truth.mass_kg);
    let (mut moved, mut level0) = (0, 0);
    for i in 1..on.positions.len() - 1 {
        let p = on.positions[i];
        let a: [f64; 3] = std::array::from_fn(|k| (on.positions[i - 1][k] - 2.0 * p[k] + on.positions[i + 1][k]) / (dt * dt));
        let mut r = [m * a[0], m * a[1], m * (a[2] + G)];
        let (t_on, t_off) = (&on.tensions[i * n..(i + 1) * n], &off.tensions[i * n..(i + 1) * n]);
        for j in 0..n {
            let d = sub(on.truth.anchors[j], p);
            let drum = norm(d) / (1.0 + t_on[j] / ea) - k * t_on[j];
            assert!((on.drum_lengths[i * n + j] - drum).abs() < 1e-9, "sample {i} cable {j}: {} vs {drum}", on.drum_lengths[i * n + j]);
            for k in 0..3 {
                r[k] -= t_on[j] * d[k] / norm(d);
            }
        }
        assert!(norm(r) < 2e-3 * m * G, "sample {i}: residual {r:?}");
        assert!(t_on.iter().all(|&t| t >= s.min_tension_n - 1e-9 && t <= s.robot.safety.max_tension_n), "{t_on:?}");
        let change = (0..n).map(|j| (t_on[j] - t_off[j]).abs()).fold(0.0, f64::max);
        let phase = (i as f64 * dt) % 12.0;
        if (1.0..4.0).contains(&phase) {
            assert_eq!(t_on, t_off, "sample {i}: level 0");
            level0 += 1;
        }
        moved += usize::from(change > 3.0);
    }
    assert!(level0 > 200, "{level0}");
    assert!(moved > on.positions.len() / 2, "{moved} of {} samples moved by more than 3 N", on.positions.len());
    let mut three = Scenario { pretension: s.pretension.clone(), ..Scenario::three_cable(1) };
    three.duration_s = 5.0;
    assert!(matches!(try_simulate(&three), Err(SimError::BadScenario(m)) if m.contains("four or more cables")));
}

/// During phase k the two held cables keep their lengths, and the platform stays on the circle
/// where their spheres meet (computed here), while the reeled cable shortens by the plan.
#[test]
fn three_phase_paths_are_circles() {
    for mut s in [Scenario::three_cable(21), Scenario::aras_cam(22)] {
        s.duration_s = 0.0;
        s.noise = Noise::none();
        s.physics = Physics::ideal();
        s.rate_hz = 20.0;
        let plan = ThreePhasePlan { reel_m: 0.4, speed_m_s: 0.2, ..ThreePhasePlan::default() };
        s.three_phase = Some(plan.clone());
        let run = simulate(&s);
        let start = run.three_phase_start.unwrap();
        assert!(norm(sub(run.positions[0], start)) < 1e-5);
        let rec = &run.recording;
        let phase = rec.phase.as_ref().unwrap();
        let n = rec.n_cables;
        for k in 0..3 {
            let idx: Vec<usize> = (0..rec.len()).filter(|&i| phase[i] == k as i32).collect();
            assert!(idx.len() > 20, "phase {k}: {} samples", idx.len());
            let held: Vec<usize> = (0..3).filter(|&j| j != k).collect();
            let (ai, aj) = (run.truth.anchors[held[0]], run.truth.anchors[held[1]]);
            let p0 = rec.p[idx[0]];
            let (ri, rj) = (norm(sub(p0, ai)), norm(sub(p0, aj)));
            // Circle of the two spheres: centre on the axis, radius, plane normal e.
            let d = norm(sub(aj, ai));
            let e = sub(aj, ai).map(|x| x / d);
            let along = (d * d + ri * ri - rj * rj) / (2.0 * d);
            let c: [f64; 3] = std::array::from_fn(|q| ai[q] + along * e[q]);
            let rho = (ri * ri - along * along).sqrt();
            let mut arc = 0.0;
            for w in idx.windows(2) {
                arc += norm(sub(rec.p[w[1]], rec.p[w[0]]));
            }
            assert!(arc > 0.2, "phase {k}: the platform barely moved ({arc} m)");
            for &i in &idx {
                let p = rec.p[i];
                assert!((norm(sub(p, ai)) - ri).abs() < 1e-5 && (norm(sub(p, aj)) - rj).abs() < 1e-5, "held lengths changed");
                let v = sub(p, c);
                let off_plane = dot(v, e);
                let radial = norm(std::array::from_fn(|q| v[q] - off_plane * e[q]));
                assert!(off_plane.abs() < 1e-5 && (radial - rho).abs() < 1e-5, "phase {k} sample {i}: {off_plane} {}", radial - rho);
                // Position-mode cables taut throughout.
                for j in 0..3 {
                    assert!(run.tensions[i * n + j] > 1.0);
                }
            }
            // The reeled cable's reading drops by the reel length.
            let l = |i: usize| rec.lengths(i)[k];
            let drop = l(idx[0]) - idx.iter().map(|&i| l(i)).fold(f64::INFINITY, f64::min);
            assert!((drop - plan.reel_m).abs() < 0.2 * plan.speed_m_s / s.rate_hz + 1e-9, "drop {drop}");
        }
    }
}

/// The fraction of samples with a loose cable follows the knob, and loose cables read ~0 N and
/// more cable than the geometry.
#[test]
fn loose_fraction_knob() {
    for (mut s, target) in [(Scenario::aras_cam(31), 0.2), (Scenario::three_cable(32), 0.2), (Scenario::aras_cam(33), 0.0)] {
        s.duration_s = 60.0;
        s.rate_hz = 50.0;
        s.loose_fraction = target;
        s.three_phase = None;
        let run = simulate(&s);
        let f = run.loose_fraction();
        if target > 0.0 {
            assert!((0.15..=0.25).contains(&f), "{}: loose fraction {f}", s.robot.robot.name);
        } else {
            assert!(f < 0.01, "loose fraction {f} without excursions");
        }
        let n = run.truth.n_cables();
        let rec = &run.recording;
        let mut slack_seen = 0.0f64;
        for i in 0..rec.len() {
            for j in 0..n {
                if !run.loose[i * n + j] {
                    continue;
                }
                let t = rec.tensions(i).unwrap()[j];
                assert!(t.abs() < 3.0, "a loose cable reads {t} N");
                // Ideal geometry under default physics: reading - offset - |p - a| = slack.
                let geo = norm(sub(run.positions[i], run.truth.anchors[j]));
                let slack = rec.lengths(i)[j] - run.truth.l0[j] - geo;
                assert!(slack > -1e-3 && slack < 0.051, "slack {slack}");
                slack_seen = slack_seen.max(slack);
            }
        }
        if target > 0.0 {
            assert!(slack_seen > 0.005, "no slack of several mm: {slack_seen}");
        }
    }
    // With the three-phase motion first, the fraction is of the whole recording.
    let mut s = Scenario::aras_cam(34);
    s.duration_s = 60.0;
    s.rate_hz = 25.0;
    let run = simulate(&s);
    assert!((0.15..=0.25).contains(&run.loose_fraction()), "{}", run.loose_fraction());
}

/// Runs `quiet(seed)` with `physics`, returning (run, readings minus the ideal run's).
fn effect(physics: Physics) -> (SimRun, SimRun) {
    let base = simulate(&quiet(41));
    let on = simulate(&Scenario { physics, ..quiet(41) });
    assert_eq!(base.positions, on.positions, "the trajectory must not depend on the physics");
    (base, on)
}

#[test]
fn elasticity_shortens_readings_by_t_l_over_ea() {
    let ea = 2e5;
    let (base, on) = effect(Physics { elasticity: Some(ea), ..Physics::ideal() });
    let n = 4;
    let mut mean = 0.0;
    for i in 0..base.recording.len() {
        for j in 0..n {
            let l = norm(sub(on.positions[i], on.truth.anchors[j]));
            let t = on.tensions[i * n + j];
            let d = on.recording.lengths(i)[j] - base.recording.lengths(i)[j];
            // Unstretched = L / (1 + T/EA): shorter by ~T L / EA.
            assert!((d + l * t / (ea + t)).abs() < 1e-9, "{d} vs {}", -t * l / ea);
            mean += d;
        }
    }
    mean /= (base.recording.len() * n) as f64;
    assert!(mean < -1e-4 && mean > -2e-3, "mean shortening {mean}");
}

#[test]
fn sag_lengthens_readings_like_a_hanging_cable() {
    let w = 0.5;
    let (base, on) = effect(Physics { sag: Some(w), ..Physics::ideal() });
    let n = 4;
    for i in (0..base.recording.len()).step_by(7) {
        for j in 0..n {
            let c = sub(on.truth.anchors[j], on.positions[i]);
            let l = norm(c);
            let cos = c[0].hypot(c[1]) / l;
            let t = on.tensions[i * n + j];
            let d = on.recording.lengths(i)[j] - base.recording.lengths(i)[j];
            // Parabolic estimate: arc - chord ~ w^2 L^3 cos^4 / (24 H^2), H the horizontal force
            // (~ the mean tension x cos); the exact catenary agrees to a few per cent when
            // w L / T is small.
            let h = (t + 0.5 * w * c[2]) * cos;
            let approx = w * w * l.powi(3) * cos.powi(4) / (24.0 * h * h);
            assert!(d > 0.0, "a hanging cable is longer than its chord");
            assert!((d / approx - 1.0).abs() < 0.15, "sample {i} cable {j}: {d} vs {approx} (T {t})");
        }
    }
}

#[test]
fn pulley_adds_the_wrap_and_moves_the_exit_point() {
    let r = 0.06;
    let (base, on) = effect(Physics { pulley: Some(r), ..Physics::ideal() });
    let n = 4;
    let pi = std::f64::consts::PI;
    for i in (0..base.recording.len()).step_by(25) {
        for j in 0..n {
            let (a, b) = (on.truth.anchors[j], on.positions[i]);
            // Independent reference: wrap the cable down the pulley (centre c, in the vertical
            // plane through the swivel axis and b) until the line to b no longer cuts into the
            // pulley: the first angle where (b - e).(e - c) >= 0, by a fine scan and bisection.
            let d = sub(b, a);
            let rho = d[0].hypot(d[1]);
            let uh = [d[0] / rho, d[1] / rho];
            let c = [a[0] + r * uh[0], a[1] + r * uh[1], a[2]];
            let e = |phi: f64| [c[0] + r * uh[0] * phi.cos(), c[1] + r * uh[1] * phi.cos(), c[2] + r * phi.sin()];
            let cuts = |phi: f64| dot(sub(b, e(phi)), sub(e(phi), c)) < 0.0;
            let mut hi = (1..=4000).map(|k| pi + 1.5 * pi * k as f64 / 4000.0).find(|&phi| !cuts(phi)).unwrap();
            let mut lo = hi - 1.5 * pi / 4000.0;
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if cuts(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let reference = r * (hi - pi) + norm(sub(b, e(hi))) - norm(d);
            let diff = on.recording.lengths(i)[j] - base.recording.lengths(i)[j];
            assert!((diff - reference).abs() < 1e-7, "sample {i} cable {j}: {diff} vs {reference}");
            assert!(diff.abs() < 2.0 * r, "{diff}");
        }
    }
}

#[test]
fn scale_multiplies_the_length() {
    let s = vec![1.001, 0.999, 1.002, 0.998];
    let (base, on) = effect(Physics { scale: Some(s.clone()), ..Physics::ideal() });
    for i in 0..base.recording.len() {
        for j in 0..4 {
            let l = base.recording.lengths(i)[j] - base.truth.l0[j];
            let d = on.recording.lengths(i)[j] - base.recording.lengths(i)[j];
            assert!((d - (s[j] - 1.0) * l).abs() < 1e-9);
        }
    }
}

/// Drum build-up: the reading is the nominal radius times the angle whose arc on the growing
/// radius (integrated numerically here) is the length paid out; shorter readings on a drum
/// whose radius shrinks as it pays out, and the drive holds the length it is commanded.
#[test]
fn drum_buildup_reads_the_angle_of_a_shrinking_radius() {
    let per_turn = -1e-4;
    let (base, on) = effect(Physics { drum_buildup_m_per_turn: Some(per_turn), ..Physics::ideal() });
    let (r0, g) = (crate::physics::DRUM_RADIUS_M, per_turn / std::f64::consts::TAU);
    // Arc length of the angle phi: the integral of r0 + g phi, by the midpoint rule.
    let arc = |phi: f64| (0..2000).map(|k| (r0 + g * (k as f64 + 0.5) * phi / 2000.0) * phi / 2000.0).sum::<f64>();
    for i in (0..base.recording.len()).step_by(7) {
        for j in 0..4 {
            let len = base.recording.lengths(i)[j] - base.truth.l0[j];
            let enc = on.recording.lengths(i)[j] - on.truth.l0[j];
            assert!((arc(enc / r0) - len).abs() < 1e-9, "{} vs {len}", arc(enc / r0));
            assert!(enc > len || len <= 0.0);
        }
    }
    let drum = Physics { drum_buildup_m_per_turn: Some(per_turn), ..Physics::ideal() }.drum().unwrap();
    assert!((drum.quadratic_per_m() - per_turn / (4.0 * std::f64::consts::PI * r0 * r0)).abs() < 1e-15);
    let enc = crate::sensors::Encoder::new(1.001, 0.2, 0.0, &crate::sensors::Noise::none()).with_drum(Some(drum));
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
    let read = enc.clone().read(3.0, &mut rng);
    assert!((enc.drum_for(read) - 3.0).abs() < 1e-12);
}

#[test]
fn time_offset_delays_the_encoders() {
    // Two samples at 50 Hz.
    let (base, on) = effect(Physics { time_offset_s: 0.04, ..Physics::ideal() });
    for i in 2..base.recording.len() {
        for j in 0..4 {
            assert!((on.recording.lengths(i)[j] - base.recording.lengths(i - 2)[j]).abs() < 1e-9);
        }
    }
    assert_eq!(on.recording.p, base.recording.p);
}

#[test]
fn backlash_lags_the_direction_of_motion() {
    let w = 1e-3;
    let (base, on) = effect(Physics { backlash_m: w, ..Physics::ideal() });
    let (mut up, mut down) = (0, 0);
    for i in 10..base.recording.len() {
        for j in 0..4 {
            let d = on.recording.lengths(i)[j] - base.recording.lengths(i)[j];
            assert!(d.abs() <= 0.5 * w + 1e-12);
            let hist: Vec<f64> = (i - 10..=i).map(|k| base.recording.lengths(k)[j]).collect();
            let rising = hist.windows(2).all(|x| x[1] > x[0]) && hist[10] - hist[0] > w;
            let falling = hist.windows(2).all(|x| x[1] < x[0]) && hist[0] - hist[10] > w;
            if rising {
                assert!((d + 0.5 * w).abs() < 1e-12, "paying out: reading lags by half the play");
                up += 1;
            }
            if falling {
                assert!((d - 0.5 * w).abs() < 1e-12);
                down += 1;
            }
        }
    }
    assert!(up > 50 && down > 50, "{up} {down}");
}

#[test]
fn orientation_moves_the_attachment_points() {
    let mut s = quiet(51);
    s.with_orientation = true;
    s.robot.cables[0].platform_point = [0.1, 0.05, 0.0];
    s.robot.cables[2].platform_point = [-0.1, 0.05, 0.02];
    let run = simulate(&s);
    let q = run.recording.q.as_ref().unwrap();
    let mut max_tilt: f64 = 0.0;
    for i in 0..run.recording.len() {
        let [w, x, y, z] = q[i];
        assert!(((w * w + x * x + y * y + z * z) - 1.0).abs() < 1e-12);
        max_tilt = max_tilt.max(2.0 * (x * x + y * y).sqrt().asin());
        let r = trajectory::rotation(q[i]);
        for j in 0..4 {
            let b = trajectory::rotate(&r, run.truth.platform_points[j]);
            let pt = [run.positions[i][0] + b[0], run.positions[i][1] + b[1], run.positions[i][2] + b[2]];
            let l = norm(sub(run.truth.anchors[j], pt));
            assert!((run.recording.lengths(i)[j] - run.truth.l0[j] - l).abs() < 1e-9);
        }
    }
    assert!(max_tilt > 0.01 && max_tilt < 0.1, "tilt {max_tilt}");
}

#[test]
fn outdoor_scenario_runs_with_sag_and_stretch() {
    let mut s = Scenario::outdoor(61);
    s.duration_s = 20.0;
    s.rate_hz = 20.0;
    s.three_phase = None;
    s.noise = Noise::none();
    let run = simulate(&s);
    let n = 4;
    // Heavy cables: readings exceed the chord by centimetres where the tension is low.
    let mut max_excess: f64 = 0.0;
    for i in 0..run.recording.len() {
        for j in 0..n {
            if run.loose[i * n + j] {
                continue;
            }
            let geo = norm(sub(run.positions[i], run.truth.anchors[j]));
            max_excess = max_excess.max(run.recording.lengths(i)[j] - run.truth.l0[j] - geo);
        }
    }
    assert!(max_excess > 0.005, "sag should matter outdoors: {max_excess}");
}

mod plant {
    use super::*;
    use crate::physics::CableCommand;
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    /// Counts allocations of the current thread (other tests run in parallel).
    struct Counting;
    thread_local! {
        static ALLOCS: Cell<usize> = const { Cell::new(0) };
    }
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
            unsafe { System.alloc(l) }
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            unsafe { System.dealloc(p, l) }
        }
    }
    #[global_allocator]
    static GLOBAL: Counting = Counting;

    fn truth(physics: &Physics) -> Truth {
        let s = Scenario::aras_cam(71);
        Truth::sample(&s.robot, physics, 0.1, 1.0, &mut rng(71, 0)).unwrap()
    }

    #[test]
    fn holds_position_and_follows_length_commands_without_allocating() {
        let physics = Physics { elasticity: Some(2e5), ..Physics::ideal() };
        let truth = truth(&physics);
        let p0 = [0.3, 0.2, 1.8];
        let mut plant = Plant::new(&truth, &physics, [0.0, 0.0, 2.5]);
        let hold = balanced_hold(&plant, &truth, p0);
        let mut cmds: Vec<CableCommand> = hold.iter().map(|&l| CableCommand::Length(l)).collect();
        let out = plant.step(0.01, &cmds);
        assert!(out.report.was_successful(), "{:?}", out.report);
        assert!(norm(sub(out.position, p0)) < 1e-6, "{:?}", out.position);
        // Reel cable 0 in by 5 cm in 50 steps; count allocations.
        let before = ALLOCS.with(Cell::get);
        for k in 1..=50 {
            cmds[0] = CableCommand::Length(hold[0] - 0.001 * k as f64);
            let out = plant.step(0.01, &cmds);
            assert!(out.report.converged);
        }
        let allocs = ALLOCS.with(Cell::get) - before;
        assert_eq!(allocs, 0, "the plant allocated in its loop");
        let out = plant.step(0.01, &cmds);
        let moved = norm(sub(out.position, p0));
        assert!(moved > 0.02 && moved < 0.2, "moved {moved}");
        // Position-mode drums read their commands (plus the encoder offset).
        assert!((out.encoder_m[0] - (hold[0] - 0.05) * truth.scale[0] - truth.l0[0]).abs() < 1e-12);
    }

    #[test]
    fn scenario_plant_starts_at_rest_with_the_scenario_truth() {
        let s = Scenario::aras_cam(81);
        let (mut plant, hold) = s.plant().unwrap();
        let c = s.workspace().unwrap().center_point();
        let cmds: Vec<CableCommand> = hold.iter().map(|&l| CableCommand::Length(l)).collect();
        let out = plant.step(0.01, &cmds);
        assert!(norm(sub(out.position, c)) < 1e-5, "{:?}", out.position);
        assert!(out.tension_n.iter().all(|&t| t > s.min_tension_n - 2.0), "{:?}", out.tension_n);
        assert_eq!(s.truth().unwrap(), simulate(&Scenario { duration_s: 1.0, three_phase: None, ..s.clone() }).truth);
    }

    #[test]
    fn torque_mode_follower_reads_the_stretched_geometry() {
        let ea = 1e5;
        let physics = Physics { elasticity: Some(ea), ..Physics::ideal() };
        let truth = truth(&physics);
        let p0 = [0.0, 0.0, 1.6];
        let mut plant = Plant::new(&truth, &physics, p0);
        // Three cables hold, the fourth pulls 15 N.
        let mut t = [0.0; 4];
        let u: Vec<[f64; 3]> = truth.anchors.iter().map(|a| sub(*a, p0).map(|x| x / norm(sub(*a, p0)))).collect();
        let m = nalgebra::Matrix3::from_fn(|r, c| u[c][r]);
        let rhs = nalgebra::Vector3::new(0.0, 0.0, truth.mass_kg * G) - 15.0 * nalgebra::Vector3::from(u[3]);
        let x = m.lu().solve(&rhs).unwrap();
        t[..3].copy_from_slice(x.as_slice());
        t[3] = 15.0;
        let hold = plant.lengths_holding(p0, &t).unwrap();
        let cmds =
            [CableCommand::Length(hold[0]), CableCommand::Length(hold[1]), CableCommand::Length(hold[2]), CableCommand::Tension(15.0)];
        let out = plant.step(0.01, &cmds);
        assert!(out.report.was_successful());
        assert!(norm(sub(out.position, p0)) < 1e-6);
        let l = norm(sub(truth.anchors[3], out.position));
        assert!((out.drum_m[3] - l / (1.0 + 15.0 / ea)).abs() < 1e-9);
        assert!((out.tension_n[3] - 15.0).abs() < 1e-9);
        for j in 0..3 {
            assert!((out.tension_n[j] - t[j]).abs() < 1e-3, "{j}: {} vs {}", out.tension_n[j], t[j]);
        }
    }

    #[test]
    fn time_offset_delays_the_plant_encoders() {
        let physics = Physics { time_offset_s: 0.05, ..Physics::ideal() };
        let truth = truth(&physics);
        let p0 = [0.0, 0.0, 1.6];
        let mut plant = Plant::new(&truth, &physics, p0);
        let hold = balanced_hold(&plant, &truth, p0);
        let mut drums = Vec::new();
        let mut enc = Vec::new();
        for k in 0..40 {
            let cmds: Vec<_> = hold.iter().map(|&l| CableCommand::Length(l - 0.001 * k as f64)).collect();
            let out = plant.step(0.01, &cmds);
            drums.push(out.drum_m[1]);
            enc.push(out.encoder_m[1] - truth.l0[1]);
        }
        for k in 5..40 {
            assert!((enc[k] - drums[k - 5]).abs() < 1e-9, "{k}");
        }
    }

    #[test]
    fn a_step_without_equilibrium_keeps_the_last_position_and_tensions_together() {
        let physics = Physics::ideal();
        let truth = truth(&physics);
        let p0 = [0.3, 0.2, 1.8];
        let mut plant = Plant::new(&truth, &physics, p0);
        let hold = balanced_hold(&plant, &truth, p0);
        let mut cmds: Vec<CableCommand> = hold.iter().map(|&l| CableCommand::Length(l)).collect();
        cmds[3] = CableCommand::Tension(10.0);
        let good = plant.step(0.01, &cmds);
        assert!(good.report.converged);
        let (p, t) = (good.position, good.tension_n.to_vec());
        // Every drive lets go (torque mode, no tension): nothing holds the platform up.
        let slack = vec![CableCommand::Tension(0.0); hold.len()];
        let out = plant.step(0.01, &slack);
        assert!(!out.report.converged);
        assert_eq!(out.position, p);
        assert_eq!(out.tension_n, &t[..], "tensions of the kept equilibrium, not of the failed search");
        assert_eq!(plant.failed_steps(), 1);
        // A large jump that has an equilibrium is reached (in substeps if need be) and matches
        // the same change made in small steps.
        let mut fine = plant.clone();
        let mut jump = cmds.clone();
        jump[2] = CableCommand::Length(hold[2] + 0.3);
        let big = plant.step(0.01, &jump).position;
        let mut small = p;
        for k in 1..=30 {
            let mut c = cmds.clone();
            c[2] = CableCommand::Length(hold[2] + 0.01 * k as f64);
            small = fine.step(0.01, &c).position;
        }
        assert!(norm(sub(big, small)) < 1e-6, "{big:?} vs {small:?}");
    }

    /// Drum lengths that hold the platform at `p`: cable 3 at 10 N, cables 0-2 balancing.
    fn balanced_hold(plant: &Plant, truth: &Truth, p: [f64; 3]) -> Vec<f64> {
        let u: Vec<[f64; 3]> = truth.anchors.iter().map(|a| sub(*a, p).map(|x| x / norm(sub(*a, p)))).collect();
        let m = nalgebra::Matrix3::from_fn(|r, c| u[c][r]);
        let rhs = nalgebra::Vector3::new(0.0, 0.0, truth.mass_kg * G) - 10.0 * nalgebra::Vector3::from(u[3]);
        let x = m.lu().solve(&rhs).unwrap();
        let t = [x[0], x[1], x[2], 10.0];
        assert!(t.iter().all(|&v| v > 1.0), "{t:?}");
        plant.lengths_holding(p, &t).unwrap()
    }
}

#[test]
fn an_eccentric_drum_reads_a_lead_periodic_in_the_drums_circumference() {
    let e = 0.5e-3;
    let physics = Physics { drum_eccentricity_m: Some(e), ..Physics::ideal() };
    let ecc = physics.eccentricity(1).expect("on");
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut enc = crate::sensors::Encoder::new(1.0, 0.0, 0.0, &crate::Noise::none()).with_eccentricity(Some(ecc));
    let circumference = std::f64::consts::TAU * crate::physics::DRUM_RADIUS_M;
    let mut worst: f64 = 0.0;
    for k in 0..200 {
        let d = 1.0 + k as f64 * 1e-3;
        let reading = enc.read(d, &mut rng);
        // The reading lags the paid-out length by the lead, which repeats every circumference.
        assert!((d - reading - ecc.lead(reading)).abs() < 1e-9, "{d}: {reading}");
        assert!((ecc.lead(d) - ecc.lead(d + circumference)).abs() < 1e-12);
        worst = worst.max((d - reading).abs());
        // A position-mode drive holding this reading pays out `d` again.
        assert!((enc.drum_for(reading) - d).abs() < 1e-9);
    }
    assert!(worst > 0.9 * e && worst <= 2.0 * e, "largest lead {worst}");
    assert!(Physics::ideal().eccentricity(0).is_none());
}

#[test]
fn the_height_error_grows_with_the_square_of_the_height() {
    let physics = Physics { height_error_per_m: Some(2e-3), ..Physics::ideal() };
    assert_eq!(physics.height_error(0.0), 0.0);
    assert!((physics.height_error(1.5) - 4.5e-3).abs() < 1e-15);
    assert_eq!(Physics::ideal().height_error(1.5), 0.0);
}
