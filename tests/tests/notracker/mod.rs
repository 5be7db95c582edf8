//! Shared by the tracker-free start-up tests in simulated time (`simtime`: `notracker_short`,
//! the short plan; `notracker_3mm` and `notracker_3mm_dynamic`, worst anchor at most 3 mm;
//! `notracker_2mm`, the 3-minute plans): the simulated robot without its tracker sender (`taut start --sim
//! --no-tracker`, config/examples/aras-cam-sim-notracker.toml) holds at rest (the rest
//! estimate), visits the dwell poses planned from the nominal geometry, calibrates from the
//! encoders and load cells (`taut_calib::selfcal`) and hot-swaps; `ctl recalibrate` visits the
//! dwells again.
//!
//! The simulated site's anchors are up to 20 cm from the nominal ones, its encoder offsets up to
//! 2 m, its load cells 0.5 N off; its physics is `taut-sim`'s, not calib's model.
//!
//! Every start-up asserts (failure probabilities for a correct calibration, per start-up;
//! docs/test-robustness.md): each aligned anchor coordinate within [`K_SIGMA`] of the
//! calibration's own sigma (12 coordinates: 1.2e-5), the chi-square of the fit below its 1e-5
//! quantile at the fit's degrees of freedom, the tares recorded, the hot-swap.

#![allow(dead_code)] // each test target uses a part

use std::time::Duration;
use taut_calib::selfcal::align::worst_aligned_error;
use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::OutcomeKind;
use taut_io::FromRobot;
use taut_operator::control;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use taut_rt::motion::{ControllerConfig, State};
use taut_simrig::{self as simrig, SimOptions};

/// Each aligned anchor coordinate within this many of its sigmas: two-sided normal tail 1.0e-6,
/// 1.2e-5 over the 12 coordinates of a start-up.
pub const K_SIGMA: f64 = 4.89;

/// The chi-square check's standard normal quantile: upper tail 1e-5 (Wilson–Hilferty,
/// `taut_calib::selfcal::chi2_quantile`).
pub const CHI2_Z: f64 = 4.265;

/// Which dwell plan a start-up runs.
#[derive(Clone, Copy, PartialEq, Debug)]
pub enum Plan {
    /// The CI test's: 16 poses of 2.5 s, settle 0.3 s, 0.5 m/s, 8 tares.
    Short,
    /// The example configuration's: the acceptance plan for the 3 mm (16 poses of 30 s,
    /// 6 tares), chosen with the planner's prediction at the simulated bus's ~120 tension
    /// readings a second per cable for a predicted P(worst aligned anchor > 3 mm) well below
    /// 5e-4 (BENCHMARKS.md).
    Example,
    /// The example's poses and tares with dwells of [`BUS_DWELL_S`]: the dynamic plant's 3 mm
    /// acceptance (simtime `notracker_3mm_dynamic`) at the ~62 tension readings a second per
    /// cable that the simulated-time bus delivers (the example's 34 s were chosen at the ~128
    /// a second of load cells on a pseudo-terminal).
    Bus,
    /// The best plan of three minutes of robot time that the loop runs (tares as long as a
    /// dwell): 12 poses of [`THREE_MINUTE_DWELL_S`], 4 tares (simtime `notracker_2mm`).
    ThreeMinutes,
}

/// The dwell of [`Plan::ThreeMinutes`], s: 12 poses and 4 tares at the example's settle,
/// speed and acceleration fill 3 minutes of robot time (`plan_robot_time_s`).
pub const THREE_MINUTE_DWELL_S: f64 = 7.5;

/// The dwell of [`Plan::Bus`], s: the plan that meets the 3 mm budget on the dynamic plant at
/// 62 readings a second with its measured honesty (simtime `notracker_3mm_dynamic`).
pub const BUS_DWELL_S: f64 = 130.0;

/// The tracker-free example robot with its files in `dir`, running `plan`.
pub fn robot(dir: &std::path::Path, plan: Plan) -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim-notracker.toml");
    let mut cfg = taut_config::RobotConfig::load(path).unwrap();
    assert!(cfg.tracker.is_none());
    assert_eq!(cfg.motion.startup, Some(taut_config::runtime::Startup::Dwell));
    if plan == Plan::Short {
        cfg.motion.dwell_poses = 16;
        cfg.motion.dwell_s = 2.5;
        cfg.motion.dwell_settle_s = 0.3;
        cfg.motion.dwell_speed_m_s = 0.5;
        cfg.motion.dwell_tares = 8;
    }
    if plan == Plan::Bus {
        cfg.motion.dwell_s = BUS_DWELL_S;
    }
    if plan == Plan::ThreeMinutes {
        cfg.motion.dwell_poses = 12;
        cfg.motion.dwell_s = THREE_MINUTE_DWELL_S;
        cfg.motion.dwell_tares = 4;
    }
    if plan != Plan::Short {
        // A test-machine allowance, not the robot's: the example's 0.5 s (the default is
        // 0.1 s) stays in the configuration that `taut start` runs. On a shared two-core machine
        // (load 5-7) 12-minute start-ups latched a hold on stale
        // tensions while the loop itself was on time: the simulated load cells answer over a
        // pseudo-terminal from a thread without real-time priority, and that thread (and the
        // robot's Modbus thread) went without CPU for over 0.5 s: the machine starving the
        // simulated devices, not a late real cell. scripts/test runs this plan alone; the
        // stale-tension reaction itself is tested by e2e_faults at the configured limit.
        cfg.safety.tension_max_age_s = 2.0;
    }
    cfg.daemon.socket = dir.join("taut.sock").display().to_string();
    cfg.daemon.data_dir = dir.join("data").display().to_string();
    cfg
}

enum Dir {
    Temp(tempfile::TempDir),
    Kept(std::path::PathBuf),
}

impl Dir {
    fn path(&self) -> &std::path::Path {
        match self {
            Dir::Temp(d) => d.path(),
            Dir::Kept(p) => p,
        }
    }
}

pub struct Run {
    pub worst_aligned_m: f64,
    pub predicted_worst_sigma_m: f64,
    /// The planner's prediction again with the tension readings per second measured in the
    /// recording (the planner assumes 50 per second for load cells polled back to back).
    pub repredicted_worst_sigma_m: f64,
    /// The calibration's own worst-anchor 1-sigma (CRB x the variance factor).
    pub achieved_worst_sigma_m: f64,
    pub dwells_note: String,
    pub seconds: f64,
    /// The 99.9 % upper bound of P(worst aligned anchor > 3 mm) for this recording.
    pub p3_upper: f64,
    /// The fit's chi2/dof and its degrees of freedom.
    pub chi2_dof: f64,
    pub dof: usize,
}

/// Starts the simulated robot without a tracker and checks the start-up; `recalibrate`: then
/// `ctl recalibrate` and check that it visits the dwells again.
pub fn start(seed: u64, plan_kind: Plan, recalibrate: bool) -> Run {
    start_on(seed, plan_kind, recalibrate, false)
}

/// [`start`] with the robot stack in simulated time (`sim_time`: lockstep, `taut_simrig::run_startup`)
/// or in real time on threads (the daemon, with its control socket for `recalibrate`).
pub fn start_on(seed: u64, plan_kind: Plan, recalibrate: bool, sim_time: bool) -> Run {
    // TAUT_NOTRACKER_DYNAMIC=1: the same start-up on the dynamic plant ([`start_on_plant`]).
    start_on_plant(seed, plan_kind, recalibrate, sim_time, std::env::var_os("TAUT_NOTRACKER_DYNAMIC").is_some())
}

/// [`start_on`] on the quasi-static plant or on the dynamic one (`dynamics`: the platform
/// swings on 1 MN cables after every move, and the rests begin while it swings). On the dynamic
/// plant every check holds, the chi-square too: the configuration gives the cables' datasheet
/// stiffness and the calibration models their stretch (issue 28's 3 mm there is open,
/// docs/testing.md).
pub fn start_on_plant(seed: u64, plan_kind: Plan, recalibrate: bool, sim_time: bool, dynamics: bool) -> Run {
    assert!(!(sim_time && recalibrate), "the recalibration goes through the daemon's control socket: real time only");
    let t0 = std::time::Instant::now();
    let dir = tempfile::tempdir().unwrap();
    // TAUT_E2E_KEEP: keep the files (recording, parameters) for a look after a failure.
    let dir = if std::env::var_os("TAUT_E2E_KEEP").is_some() {
        tempfile::TempDir::with_prefix("taut-e2e-notracker").map(|d| d.keep()).map(Dir::Kept).unwrap()
    } else {
        Dir::Temp(dir)
    };
    let mut cfg = robot(dir.path(), plan_kind);
    if dynamics {
        // The dynamic plant's cables stretch (EA 1 MN): the configuration knows the datasheet's
        // stiffness, 0.9 MN +- 0.15 MN, as simtime dynamic's (the calibration models the stretch).
        cfg.calibration.cable_ea_n = 0.9e6;
        cfg.calibration.cable_ea_sigma_n = 0.15e6;
    }
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let plan = taut_calibrator::notracker::dwell_plan(&cfg, &ccfg).unwrap();
    let mut so = SimOptions { seed, tracker: false, ..Default::default() };
    if dynamics {
        so.physics.dynamics = Some(taut_sim::Dynamics::default());
    }
    let mut states = Vec::new();
    let limit_s = match plan_kind {
        Plan::Short => 300,
        Plan::Example => 1500,
        Plan::Bus => 4000,
        Plan::ThreeMinutes => 600,
    };
    let mut sampler = None;
    let (d, truth, ok, l, c, recording, failed_steps) = if sim_time {
        let run = taut_tests::startup::in_sim_time(
            &cfg,
            &so,
            simrig::RunOptions { recording: taut_plugin::RecordingPath::Default, budget_s: limit_s as f64, ..Default::default() },
            |l, _| {
                if states.last() != Some(&l.snap.state) {
                    states.push(l.snap.state);
                }
                false
            },
        );
        eprintln!("seed {seed}: {:.0} s simulated in {:.1} s", run.sim_s, run.wall_s);
        (None, run.truth, run.finished, run.loop_status, run.calib_status, run.recording.unwrap(), run.plant_failed_steps)
    } else {
        let sim = simrig::build(&cfg, taut_tests::startup::rest_p0(&cfg, &so), &so).unwrap();
        let truth = sim.truth.clone();
        let faults = sim.faults.clone();
        // TAUT_E2E_TRUTH (with TAUT_E2E_KEEP): the site's true platform position, tensions and drum
        // lengths every 5 ms into truth.csv beside the recording (for tests/examples/notracker_truth).
        sampler = std::env::var_os("TAUT_E2E_TRUTH").map(|_| truth_sampler(sim.platform.clone(), cfg.cables.len(), dir.path()));
        let d = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default()).unwrap();
        eprintln!("e2e files in {}", dir.path().display());
        let ok = d.wait_until(Duration::from_secs(limit_s), |l, c| {
            if states.last() != Some(&l.snap.state) {
                states.push(l.snap.state);
            }
            taut_tests::startup::start_up_over(l, c)
        });
        let (l, c, rec) = (d.loop_status(), d.calib_status(), d.recording.clone());
        let failed = faults.plant_failed_steps.load(std::sync::atomic::Ordering::Relaxed);
        (Some(d), truth, ok, l, c, rec, failed)
    };
    let outcomes: Vec<String> = c
        .outcomes
        .iter()
        .map(|o| format!("{:?} accepted {} {} ({:?})", o.kind, o.accepted, o.reason, o.estimate.as_ref().map(|e| &e.note)))
        .collect();
    assert!(ok, "seed {seed}: start-up did not finish: state {:?}, stage {}, states {states:?}, {outcomes:?}", l.snap.state, c.stage);
    assert!(
        l.snap.fault.is_none(),
        "seed {seed}: fault {:?}, states {states:?}, plant failed steps {}, {outcomes:?}",
        l.snap.fault,
        failed_steps
    );
    // The rest dwell, then the dwell plan; never the three phases.
    assert_eq!(l.snap.phases_completed, 1, "{states:?}");
    assert!(states.contains(&State::Excitation) && !states.contains(&State::InitPhase) || l.snap.phases_completed == 1, "{states:?}");
    let init = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Initial).unwrap();
    assert!(init.accepted, "{}", init.reason);
    assert!(init.estimate.as_ref().unwrap().note.contains("without a tracker"), "{outcomes:?}");
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).unwrap();
    assert!(cal.accepted, "{outcomes:?}");
    let ce = cal.estimate.as_ref().unwrap();
    assert!(ce.note.contains("frame: the nominal anchors'"), "{}", ce.note);
    // The held-out dwells close far better with the calibrated set than with the rest estimate.
    assert!(cal.heldout_rms_new_m < 0.2 * cal.heldout_rms_old_m, "{} vs {}", cal.heldout_rms_new_m, cal.heldout_rms_old_m);
    let worst = worst_aligned_error(&ce.geometry.anchors, &truth.anchors);
    eprintln!(
        "seed {seed}: worst anchor error after translation + yaw alignment {:.2} mm (predicted worst-anchor sigma {:.2} mm); held-out closure {:.4} mm vs {:.2} mm; {}",
        worst * 1e3,
        plan.worst_anchor_sigma_m * 1e3,
        cal.heldout_rms_new_m * 1e3,
        cal.heldout_rms_old_m * 1e3,
        ce.note
    );
    // Each anchor coordinate, after the alignment, within K_SIGMA of the calibration's own
    // uncertainty (its CRB scaled by the variance factor) plus encoder quantisation, as in
    // e2e_start (there 4.46 for a 1e-4 family rate; here 4.89, 1.2e-5 for 12 coordinates, so
    // that the 3 mm acceptance's budget is left to the 3 mm). With the short plan the heights'
    // 1-sigma is ~2.3 mm, so its worst anchor exceeds 3 mm in about a quarter of the runs
    // (P printed below): the 3 mm itself is asserted by notracker_3mm with the example's plan.
    let aligned = taut_calib::selfcal::align::align_translation_yaw(&ce.geometry.anchors, &truth.anchors);
    for (j, ((a, t), s)) in aligned.iter().zip(&truth.anchors).zip(&ce.sigma.anchors).enumerate() {
        for i in 0..3 {
            assert!(
                (a[i] - t[i]).abs() < K_SIGMA * s[i] + 2e-4,
                "seed {seed}: anchor {j}[{i}] off by {:.2} mm after alignment, sigma {:.2} mm",
                (a[i] - t[i]).abs() * 1e3,
                s[i] * 1e3
            );
        }
    }
    if worst > 3e-3 {
        eprintln!("seed {seed}: the worst anchor is {:.2} mm off after alignment: above the issue's 3 mm", worst * 1e3);
    }
    // The calibration's chi2/dof is near 1: the noise model (with the variance of repeated
    // load-cell readings, see calib/src/selfcal/dwell.rs) explains the residuals. A model
    // error (motion in the dwells, stale tensions, a wrong mass) shows as a chi2/dof of several;
    // the bound is the chi-square's upper 1e-5 quantile at the fit's degrees of freedom (~80:
    // chi2/dof 1.8; it was a fixed 1.5, which a correct fit exceeds with P ~ 3e-3).
    let field = |key: &str, end: char| ce.note.split(key).nth(1).and_then(|s| s.split(end).next()).map(|s| s.trim().to_string());
    let chi = field("chi2/dof ", ',').and_then(|s| s.parse::<f64>().ok()).unwrap();
    let dof = ce.note.split(" degrees of freedom").next().and_then(|s| s.rsplit(' ').next()).and_then(|s| s.parse::<usize>().ok()).unwrap();
    let chi_bound = taut_calib::selfcal::chi2_quantile(dof, CHI2_Z) / dof as f64;
    // On the dynamic plant too, with the cables' stretch modelled (the datasheet's stiffness,
    // above): seeds 1-5 0.92/1.27/1.34/0.89/0.95 (without it 7.6/8.2/5.2/7.4/10.2).
    assert!(
        chi < chi_bound,
        "seed {seed}: chi2/dof {chi} above {chi_bound:.2} ({dof} dof): the readings disagree with the static model beyond their noise"
    );
    // Hot-swapped, parameter version 1 (rest estimate) -> 2 (calibration), said in the file.
    assert_eq!(l.snap.params_version, 2);
    let params_dir = dir.path().join("data/params");
    let current = taut_config::params::ParamsFile::load(params_dir.join("current.toml")).unwrap();
    assert_eq!(current.version, 2);
    assert!(current.source.contains("without a tracker") && current.source.contains("frame"), "{}", current.source);
    // The swap ramp spreads the jump the new parameters cause (the rest estimate's anchors are
    // the nominal ones, up to 20 cm off: a few cm of length) over motion.swap_ramp_s; its
    // per-cycle step grows with the measured period, which a loaded machine stretches.
    eprintln!("seed {seed}: largest per-cycle step of the swap {:.3} mm", l.snap.max_swap_step_m * 1e3);
    assert!(l.snap.max_swap_step_m > 0.0 && l.snap.max_swap_step_m < 1e-2, "max swap step {} m", l.snap.max_swap_step_m);
    assert_eq!(l.dropped, 0);
    // The recording: every tracker column empty, tensions and lengths present.
    let (rec, _) = taut_config::recording::Recording::load(&recording).unwrap();
    assert!(rec.len() > 5000 && rec.f.is_some());
    assert!(rec.p.iter().flatten().all(|v| v.is_nan()), "the recording has tracker values");
    // The tares were recorded: each tare's slack cable (the follower, or a position cable with
    // the follower holding its length) at zero tension, its load cell reading its offset (0.5 N
    // 1-sigma in the simulator, from the simulated cable's own physics) while the three others
    // hold the platform.
    let tares = plan.tare.iter().filter(|&&m| m != 0).count();
    assert!(tares >= 4 && plan.tare.iter().any(|&m| m != 0 && ccfg.follower.iter().enumerate().all(|(j, &f)| !f || m & (1 << j) == 0)));
    let tare_rows: Vec<usize> = (0..rec.len()).filter(|&i| rec.phase.as_ref().unwrap()[i] >= 64).collect();
    let want = (0.8 * tares as f64 * cfg.motion.dwell_s * cfg.rt.rate_hz) as usize;
    assert!(tare_rows.len() >= want, "{} tare rows, {want} expected", tare_rows.len());
    for (k, &mask) in plan.tare.iter().enumerate().filter(|x| *x.1 != 0) {
        let rows: Vec<usize> = tare_rows.iter().copied().filter(|&i| rec.phase.as_ref().unwrap()[i] == 64 + k as i32).collect();
        assert!(!rows.is_empty(), "tare after pose {k} not recorded");
        for j in 0..ccfg.n {
            let m = rows.iter().map(|&i| rec.tensions(i).unwrap()[j]).sum::<f64>() / rows.len() as f64;
            if mask & (1 << j) != 0 {
                assert!(m.abs() < 2.5, "cable {j} reads {m} N in its tare after pose {k}");
            } else {
                assert!(m > 2.5, "cable {j} reads {m} N holding the platform in the tare after pose {k}");
            }
        }
    }
    // Tension readings per second and cable in the recorded dwells (a new reading is a changed
    // value), for the planner's prediction with the rate the simulated bus achieved.
    let dwell_rows: Vec<usize> = (1..rec.len()).filter(|&i| rec.phase.as_ref().unwrap()[i] >= 0).collect();
    let fresh = dwell_rows.iter().filter(|&&i| rec.tensions(i).unwrap()[0] != rec.tensions(i - 1).unwrap()[0]).count();
    let rate = fresh as f64 / (dwell_rows.len() as f64 / cfg.rt.rate_hz);
    let mut measured = cfg.clone();
    measured.loadcells.get_or_insert_with(|| taut_proto::devices::LoadCellBusConfig::new("")).poll_period_s = 1.0 / rate;
    let replan = taut_calibrator::notracker::dwell_plan(&measured, &ccfg).unwrap();
    let norm = |s: &[f64; 3]| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
    let achieved = ce.sigma.anchors.iter().map(norm).fold(0.0, f64::max);
    eprintln!(
        "seed {seed}: {rate:.0} tension readings/s per cable; worst-anchor 1-sigma: predicted {:.2} mm (at 50/s), {:.2} mm (at {rate:.0}/s), achieved {:.2} mm",
        plan.worst_anchor_sigma_m * 1e3,
        replan.worst_anchor_sigma_m * 1e3,
        achieved * 1e3
    );
    // The prediction at the measured rate matches the achieved bound: the calibration sees 13
    // of the 16 poses (every 5th held out; sqrt(16/13) = 1.11), at the estimated rather than
    // the nominal geometry, with the measured variance factor.
    let ratio = achieved / replan.worst_anchor_sigma_m;
    // On the dynamic plant too (seeds 1-5: 0.89-1.11 with the stretch modelled). Not for
    // [`Plan::Bus`]: its acceptance (simtime `notracker_3mm_dynamic`) states the ratio's
    // distribution over the dynamic plant's sites (36 runs: 0.79-1.34, mean 1.04, sd 0.145), so
    // this range would fail about 6 % of its correct runs below 0.8 (a site whose geometry the
    // nominal prediction underrates: seed 20 at 0.79, worst anchor 0.13 mm) and 2e-3 above 1.5;
    // its high side is the recording's check there.
    if plan_kind != Plan::Bus {
        assert!((0.8..1.5).contains(&ratio), "seed {seed}: achieved / predicted worst-anchor sigma {ratio:.2}");
    }
    // The probability that a correct calibration of this recording has its worst aligned
    // anchor beyond the 3 mm: the planner's covariance at the measured reading rate,
    // scaled up to the achieved sigma where that is larger, by Monte Carlo (1e6 draws, with a
    // 99.9 % upper bound).
    let nominal = cfg.anchors().unwrap();
    let (p3, p3_upper) = replan.worst_exceeds_probability(&nominal, 3e-3, ratio.max(1.0), 1_000_000);
    eprintln!("seed {seed}: P(worst aligned anchor > 3 mm) = {p3:.2e} (upper bound {p3_upper:.2e})");

    if let (true, Some(d)) = (recalibrate, &d) {
        let sock = dir.path().join("taut.sock");
        let r = control::request(&sock, "recalibrate", Duration::from_secs(5)).unwrap();
        assert_eq!(r["ok"], true, "{r}");
        let mut saw_dwells = false;
        let ok = d.wait_until(Duration::from_secs(200), |l, c| {
            saw_dwells |= l.snap.state == State::Excitation;
            l.snap.fault.is_some() || c.outcomes.iter().any(|o| o.run == 1)
        });
        let c = d.calib_status();
        assert!(ok && saw_dwells, "recalibration: {:?}", d.loop_status().snap.fault);
        let last = c.outcomes.last().unwrap();
        assert_eq!(last.run, 1);
        // Accepted (no worse on the held-out dwells) or refused with the reason, version 2 kept.
        if last.accepted {
            assert!(d.wait_until(Duration::from_secs(10), |l, _| l.snap.params_version == 3 && !l.snap.swap_active));
            let e = last.estimate.as_ref().unwrap();
            eprintln!(
                "recalibration: worst anchor {:.2} mm after alignment",
                worst_aligned_error(&e.geometry.anchors, &truth.anchors) * 1e3
            );
        } else {
            assert!(!last.reason.is_empty());
            assert_eq!(d.loop_status().snap.params_version, 2);
        }
    }
    if let Some(d) = d {
        d.commands.try_send(taut_rt::motion::Command::Stop).unwrap();
        d.wait().unwrap();
    }
    if let Some((stop, h)) = sampler {
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        h.join().unwrap();
    }
    Run {
        worst_aligned_m: worst,
        predicted_worst_sigma_m: plan.worst_anchor_sigma_m,
        repredicted_worst_sigma_m: replan.worst_anchor_sigma_m,
        achieved_worst_sigma_m: achieved,
        dwells_note: ce.note.clone(),
        seconds: t0.elapsed().as_secs_f64(),
        p3_upper,
        chi2_dof: chi,
        dof,
    }
}

/// Samples the site's truth every 5 ms (wall clock) into `dir/truth.csv`: seconds since the
/// start, platform position, true tensions, drum lengths.
fn truth_sampler(
    platform: simrig::PlatformTruth,
    n: usize,
    dir: &std::path::Path,
) -> (std::sync::Arc<std::sync::atomic::AtomicBool>, std::thread::JoinHandle<()>) {
    use std::io::Write;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    let path = dir.join("truth.csv");
    let h = std::thread::spawn(move || {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let t0 = std::time::Instant::now();
        let mut rows = 0u64;
        // Relaxed: the flag carries no data; join() synchronises.
        while !flag.load(std::sync::atomic::Ordering::Relaxed) {
            let p = platform.position();
            let (t, d) = platform.cables();
            let mut line = format!("{:.4},{:.9},{:.9},{:.9}", t0.elapsed().as_secs_f64(), p[0], p[1], p[2]);
            for v in &t[..n] {
                line += &format!(",{v:.6}");
            }
            for v in &d[..n] {
                line += &format!(",{v:.9}");
            }
            writeln!(f, "{line}").unwrap();
            rows += 1;
            if rows.is_multiple_of(200) {
                // A failed start-up panics the test: keep what was sampled.
                f.flush().unwrap();
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        f.flush().unwrap();
    });
    (stop, h)
}

pub fn report(seed: u64, r: &Run) {
    eprintln!(
        "seed {seed}: {:.0} s; worst {:.2} mm; worst-anchor sigma predicted {:.2} mm (at 50 readings/s), {:.2} mm (measured rate), achieved {:.2} mm; P(> 3 mm) <= {:.1e}; {}",
        r.seconds,
        r.worst_aligned_m * 1e3,
        r.predicted_worst_sigma_m * 1e3,
        r.repredicted_worst_sigma_m * 1e3,
        r.achieved_worst_sigma_m * 1e3,
        r.p3_upper,
        r.dwells_note
    );
}
