//! Scenarios: a robot, a seed, the motions, the physics and the sensors, simulated into a
//! `cdpr-recording v1` with its ground truth.
//!
//! A run is the optional three-phase initialisation (phases 0, 1, 2) followed by the excitation
//! trajectory, sampled at `rate_hz`. Per excitation sample the controller's tension distribution
//! (see [`crate::tension`]) gives the tensions for the planned motion `p(t)` with its point-mass
//! acceleration (`f = m (a - g)`); a taut cable's encoder counts the unstretched length of a cable
//! of that tension (elasticity, sag, pulley), a loose cable's encoder the path length plus the
//! slack its drum paid out, rising and falling smoothly over each loose episode (peaks 5-50 mm).
//! With [`Scenario::pretension`] a redundant robot's controller also moves the internal force
//! between levels along the excitation (see [`Pretension`]): the same poses at different tensions.
//!
//! Every random draw comes from a `ChaCha8Rng` seeded with the scenario seed, one stream per
//! concern (truth, trajectory, slack, tracker, encoders, load cells): the same scenario gives
//! byte-identical recordings.

use rand::Rng;
use taut_config::recording::Recording;
use taut_config::RobotConfig;

use crate::physics::{CableCommand, CableModel, Physics, G};
use crate::plant::Plant;
use crate::sensors::{capstan_factor, Encoder, LoadCell, Noise, Tracker};
use crate::tension::{distribute, shift_internal, Distribution, Pretension, MAX_SIM_CABLES};
use crate::three_phase::{self, ThreePhaseMotion, ThreePhasePlan};
use crate::trajectory::{rotate, rotation, Excitation, Workspace};
use crate::truth::Truth;
use crate::{rng, SimError, STREAM_ENCODER, STREAM_LOADCELL, STREAM_SLACK, STREAM_TRACKER, STREAM_TRAJECTORY, STREAM_TRUTH};

/// Everything that defines a simulated recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// The robot as configured (nominal anchors, mass, platform points).
    pub robot: RobotConfig,
    /// Seed of every random draw.
    pub seed: u64,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Duration of the excitation, s (0: none).
    pub duration_s: f64,
    /// Target fraction of the recording's samples with a loose cable (excursions are tuned to
    /// it; 0: none). Needs `physics.slack`.
    pub loose_fraction: f64,
    /// The three-phase initialisation motion before the excitation, if any.
    pub three_phase: Option<ThreePhasePlan>,
    /// Sensor noise.
    pub noise: Noise,
    /// Cable physics.
    pub physics: Physics,
    /// Largest distance of a true anchor from its nominal position, m.
    pub site_error_m: f64,
    /// Encoder offsets are uniform in +- this, m.
    pub l0_range_m: f64,
    /// The controller's minimum tension, N.
    pub min_tension_n: f64,
    /// Record load-cell tensions (`f` columns).
    pub with_tensions: bool,
    /// Record the platform orientation (small tilts; attachment points move with it).
    pub with_orientation: bool,
    /// The internal force the controller varies along the excitation, on a robot with four or
    /// more cables (`None`: the minimum-norm distribution alone). The ceiling is the robot's
    /// `safety.max_tension_n`, the floor `min_tension_n`.
    pub pretension: Option<Pretension>,
}

fn robot(name: &str, mass_kg: f64, anchors: &[[f64; 3]]) -> RobotConfig {
    let mut cfg = RobotConfig::point_mass(anchors.len());
    cfg.robot.name = name.into();
    cfg.robot.mass_kg = mass_kg;
    for (c, a) in cfg.cables.iter_mut().zip(anchors) {
        c.anchor = Some(*a);
    }
    cfg
}

impl Scenario {
    /// ARAS-CAM: 4 cables from the top corners of a 7 m x 3.5 m x 4 m frame, 3 kg camera; the
    /// three-phase motion then 90 s of excitation with 20 % loose samples.
    pub fn aras_cam(seed: u64) -> Self {
        Scenario {
            robot: robot("aras-cam", 3.0, &[[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]]),
            seed,
            rate_hz: 100.0,
            duration_s: 90.0,
            loose_fraction: 0.2,
            three_phase: Some(ThreePhasePlan::default()),
            noise: Noise::default(),
            physics: Physics::default(),
            site_error_m: 0.2,
            l0_range_m: 2.0,
            min_tension_n: 5.0,
            with_tensions: true,
            with_orientation: false,
            pretension: None,
        }
    }

    /// An 8-cable robot: anchors on a regular octagon of radius 4 m, 4 m up, 5 kg platform.
    pub fn octagon(seed: u64) -> Self {
        let anchors: Vec<[f64; 3]> = (0..8)
            .map(|k| {
                let a = (k as f64 + 0.5) * std::f64::consts::TAU / 8.0;
                [4.0 * a.cos(), 4.0 * a.sin(), 4.0]
            })
            .collect();
        Scenario { robot: robot("octagon-8", 5.0, &anchors), ..Scenario::aras_cam(seed) }
    }

    /// A small 3-cable robot (anchors on a triangle 3 m up, 2 kg), as `config/examples`.
    pub fn three_cable(seed: u64) -> Self {
        Scenario { robot: robot("tri-3", 2.0, &[[2.0, 0.0, 3.0], [-1.0, 1.732, 3.0], [-1.0, -1.732, 3.0]]), ..Scenario::aras_cam(seed) }
    }

    /// A large outdoor robot: masts 12 m high on a 20 m x 20 m square, 40 kg platform, heavy steel
    /// cables (1.2 N/m, EA 3 MN) whose sag and stretch matter; controller floor 50 N.
    pub fn outdoor(seed: u64) -> Self {
        Scenario {
            robot: robot("outdoor-20m", 40.0, &[[10.0, -10.0, 12.0], [10.0, 10.0, 12.0], [-10.0, 10.0, 12.0], [-10.0, -10.0, 12.0]]),
            duration_s: 120.0,
            three_phase: Some(ThreePhasePlan { reel_m: 1.5, speed_m_s: 0.25, follower_tension_n: 100.0, ..ThreePhasePlan::default() }),
            physics: Physics { sag: Some(1.2), elasticity: Some(3e6), ..Physics::default() },
            site_error_m: 0.3,
            min_tension_n: 50.0,
            ..Scenario::aras_cam(seed)
        }
    }
}

impl Scenario {
    /// The same scenario with every cable's swivel pulley on a horizontal axis pointing from its
    /// anchor away from the frame's centre (the anchors' mean), as on a frame whose winches sit
    /// outside it and feed the cables in horizontally (`[[cable]] pulley_axis`). The axes are
    /// the configuration's: the simulated robot turns its pulleys about them, and a diagnosis
    /// given the configuration assumes them.
    pub fn with_outward_pulley_axes(mut self) -> Self {
        let anchors: Vec<[f64; 3]> = self.robot.cables.iter().filter_map(|c| c.anchor).collect();
        let n = anchors.len().max(1) as f64;
        let centre = [anchors.iter().map(|a| a[0]).sum::<f64>() / n, anchors.iter().map(|a| a[1]).sum::<f64>() / n];
        for c in &mut self.robot.cables {
            if let Some(a) = c.anchor {
                c.pulley_axis = Some([a[0] - centre[0], a[1] - centre[1], 0.0]);
            }
        }
        self
    }

    /// The true robot of this scenario (the same as [`simulate`] uses): anchors with the site
    /// error, encoder offsets, scales, load-cell offsets.
    pub fn truth(&self) -> Result<Truth, SimError> {
        let mut truth = Truth::sample(&self.robot, &self.physics, self.site_error_m, self.l0_range_m, &mut rng(self.seed, STREAM_TRUTH))?;
        let mut cell_rng = rng(self.seed, STREAM_LOADCELL);
        truth.loadcell_offsets = (0..truth.n_cables()).map(|_| LoadCell::new(&self.noise, &mut cell_rng).offset).collect();
        Ok(truth)
    }

    /// The workspace the motions are planned in (from the nominal anchors).
    pub fn workspace(&self) -> Result<Workspace, SimError> {
        Ok(Workspace::from_anchors(&self.robot.anchors().ok_or(SimError::MissingAnchors)?))
    }

    /// A [`Plant`] of this scenario's true robot with its physics and sensor noise, settled at
    /// rest at the workspace centre, and the drum lengths that hold it there.
    pub fn plant(&self) -> Result<(Plant, Vec<f64>), SimError> {
        let truth = self.truth()?;
        let c = self.workspace()?.center_point();
        let mut plant = Plant::new(&truth, &self.physics, c).with_noise(&self.noise, self.seed);
        let hold = plant.lengths_at_rest(c, self.min_tension_n)?;
        let cmds: Vec<CableCommand> = hold.iter().map(|&l| CableCommand::Length(l)).collect();
        let rep = plant.step(0.0, &cmds).report;
        if !rep.converged {
            return Err(SimError::Equilibrium { t: 0.0, residual_n: rep.residual_n });
        }
        Ok((plant, hold))
    }
}

/// A simulated recording and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct SimRun {
    /// What the sensors recorded.
    pub recording: Recording,
    /// The true parameters.
    pub truth: Truth,
    /// Samples with at least one loose cable.
    pub loose_samples: usize,
    /// True platform positions, m.
    pub positions: Vec<[f64; 3]>,
    /// True platform orientations (w, x, y, z).
    pub orientations: Vec<[f64; 4]>,
    /// True platform-end tensions, row-major, N.
    pub tensions: Vec<f64>,
    /// Loose cables, row-major.
    pub loose: Vec<bool>,
    /// True unstretched drum lengths at the encoders' sample times, row-major, m.
    pub drum_lengths: Vec<f64>,
    /// Index of the first excitation sample (the number of three-phase samples).
    pub excitation_start: usize,
    /// Excursion duration chosen to reach `loose_fraction`, s.
    pub excursion_s: f64,
    /// Where the three-phase motion rested between phases (and the excitation started), m.
    pub three_phase_start: Option<[f64; 3]>,
}

impl SimRun {
    /// Fraction of samples with a loose cable.
    pub fn loose_fraction(&self) -> f64 {
        self.loose_samples as f64 / self.recording.len().max(1) as f64
    }
}

/// Simulates a scenario.
///
/// # Panics
/// If the scenario cannot be simulated (see [`try_simulate`]); the message says why.
pub fn simulate(s: &Scenario) -> SimRun {
    try_simulate(s).unwrap_or_else(|e| panic!("simulate `{}` seed {}: {e}", s.robot.robot.name, s.seed))
}

/// The excitation's physical state at one instant.
struct Instant {
    p: [f64; 3],
    q: [f64; 4],
    b: [[f64; 3]; MAX_SIM_CABLES],
    t: [f64; MAX_SIM_CABLES],
    dist: Distribution,
}

struct ExcitationModel<'a> {
    ex: Excitation,
    models: &'a [CableModel],
    truth: &'a Truth,
    t_min: f64,
    t_max: f64,
    with_orientation: bool,
    pretension: Option<&'a Pretension>,
}

impl ExcitationModel<'_> {
    /// State at excitation time `t`; `refine` re-solves the tensions with the catenaries' end
    /// directions (sag).
    fn at(&self, t: f64, refine: bool) -> Instant {
        let n = self.models.len();
        let p = self.ex.position(t);
        let a = self.ex.acceleration(t);
        let q = if self.with_orientation { self.ex.orientation(t) } else { [1.0, 0.0, 0.0, 0.0] };
        let r = rotation(q);
        let mut b = [[0.0; 3]; MAX_SIM_CABLES];
        let mut dirs = [[0.0; 3]; MAX_SIM_CABLES];
        for j in 0..n {
            let o = rotate(&r, self.truth.platform_points[j]);
            b[j] = [p[0] + o[0], p[1] + o[1], p[2] + o[2]];
            dirs[j] = self.models[j].path(b[j]).dir;
        }
        let m = self.truth.mass_kg;
        let f = [m * a[0], m * a[1], m * (a[2] + G)];
        let mut tt = [0.0; MAX_SIM_CABLES];
        let mut dist = self.distribute(t, &dirs[..n], f, &mut tt[..n]);
        if refine && self.models.iter().any(|c| c.w > 0.0) {
            for _ in 0..2 {
                for j in 0..n {
                    if tt[j] > 0.0 {
                        if let Ok(c) = self.models[j].taut(b[j], tt[j]) {
                            dirs[j] = c.dir;
                        }
                    }
                }
                dist = self.distribute(t, &dirs[..n], f, &mut tt[..n]);
            }
        }
        Instant { p, q, b, t: tt, dist }
    }

    /// The controller's tensions at excitation time `t`: the distribution, then (every cable
    /// within its limits) the internal force of the pretension schedule.
    fn distribute(&self, t: f64, dirs: &[[f64; 3]], f: [f64; 3], out: &mut [f64]) -> Distribution {
        let dist = distribute(dirs, f, self.t_min, out);
        if let Some(p) = self.pretension {
            if dist.feasible && dist.loose == 0 {
                shift_internal(dirs, self.t_min, self.t_max, p.level_at(t), out);
            }
        }
        dist
    }

    /// Fraction of samples (every `stride`-th) with a loose cable.
    fn loose_fraction(&self, samples: usize, dt: f64, stride: usize) -> f64 {
        let (mut k, mut c) = (0usize, 0usize);
        for i in (0..samples).step_by(stride) {
            if self.at(i as f64 * dt, false).dist.loose != 0 {
                k += 1;
            }
            c += 1;
        }
        k as f64 / c.max(1) as f64
    }
}

/// Simulates a scenario, or says why it cannot be.
pub fn try_simulate(s: &Scenario) -> Result<SimRun, SimError> {
    if !(s.rate_hz > 0.0 && s.rate_hz.is_finite() && s.duration_s >= 0.0 && s.duration_s.is_finite()) {
        return Err(SimError::BadScenario("rate_hz must be positive and duration_s non-negative"));
    }
    let nominal = s.robot.anchors().ok_or(SimError::MissingAnchors)?;
    let n = nominal.len();
    if !(3..=MAX_SIM_CABLES).contains(&n) {
        return Err(SimError::BadScenario("the simulator handles 3 to 12 cables"));
    }
    if let Some(p) = &s.pretension {
        if !p.is_valid() {
            return Err(SimError::BadScenario("pretension: finite levels, hold_s > 0, 0 <= ramp_s <= hold_s"));
        }
        if n < 4 {
            return Err(SimError::BadScenario(
                "pretension needs four or more cables: three cables' tensions are fixed by the pose, there is no internal force",
            ));
        }
    }
    let truth = s.truth()?;
    // Load-cell noise continues the stream that drew the offsets.
    let mut cell_rng = rng(s.seed, STREAM_LOADCELL);
    let cells: Vec<LoadCell> = (0..n).map(|_| LoadCell::new(&s.noise, &mut cell_rng)).collect();
    let models: Vec<CableModel> = truth.cable_models(&s.physics);
    // The trajectory is planned on the nominal geometry, as a controller would.
    let ws = Workspace::from_anchors(&nominal);
    let dt = 1.0 / s.rate_hz;

    let tp: Option<ThreePhaseMotion> =
        s.three_phase.as_ref().map(|plan| three_phase::simulate(&truth, &s.physics, plan, &ws, s.rate_hz)).transpose()?;
    let n_tp = tp.as_ref().map_or(0, |m| m.t.len());
    let n_ex = (s.duration_s * s.rate_hz).round() as usize;
    let total = n_tp + n_ex;

    let mut ex = Excitation::new(&ws, s.duration_s, &mut rng(s.seed, STREAM_TRAJECTORY));
    if let Some(m) = &tp {
        ex.set_start(m.start);
    }
    let mut exm = ExcitationModel {
        ex,
        models: &models,
        truth: &truth,
        t_min: s.min_tension_n,
        t_max: s.robot.safety.max_tension_n,
        with_orientation: s.with_orientation,
        pretension: s.pretension.as_ref(),
    };
    let excursion_s = if s.physics.slack && s.loose_fraction > 0.0 && n_ex > 0 {
        tune_excursions(&mut exm, s.loose_fraction * total as f64 / n_ex as f64, n_ex, dt, s.rate_hz)
    } else {
        0.0
    };

    let mut run = SimRun {
        recording: Recording::with_capacity(n, total, s.with_tensions, s.with_orientation, s.three_phase.is_some()),
        truth: truth.clone(),
        loose_samples: 0,
        positions: Vec::with_capacity(total),
        orientations: Vec::with_capacity(total),
        tensions: Vec::with_capacity(total * n),
        loose: Vec::with_capacity(total * n),
        drum_lengths: Vec::with_capacity(total * n),
        excitation_start: n_tp,
        excursion_s,
        three_phase_start: tp.as_ref().map(|m| m.start),
    };
    let mut phases = Vec::with_capacity(total);

    // Three-phase part: the plant's equilibria; encoder samples lag by interpolation.
    if let Some(m) = &tp {
        for i in 0..n_tp {
            run.positions.push(m.p[i]);
            run.orientations.push([1.0, 0.0, 0.0, 0.0]);
            run.tensions.extend_from_slice(&m.tension[i * n..(i + 1) * n]);
            run.loose.extend(std::iter::repeat_n(false, n));
            phases.push(m.phase[i]);
            let te = m.t[i] - s.physics.time_offset_s;
            let x = (te / dt).max(0.0);
            let (k0, frac) = (x.floor() as usize, x.fract());
            let k1 = (k0 + 1).min(n_tp - 1);
            let k0 = k0.min(n_tp - 1);
            for j in 0..n {
                let (a, b) = (m.drum[k0 * n + j], m.drum[k1 * n + j]);
                run.drum_lengths.push(a + frac * (b - a));
            }
        }
    }

    // Excitation part: tracker-time state for positions and tensions, encoder-time state for
    // the lengths (the same when there is no time offset).
    let offset = s.physics.time_offset_s;
    let mut enc_loose = vec![false; n_ex * n];
    let mut enc_base = vec![0.0; n_ex * n];
    for i in 0..n_ex {
        let t = i as f64 * dt;
        let st = exm.at(t, true);
        run.positions.push(st.p);
        run.orientations.push(st.q);
        run.tensions.extend_from_slice(&st.t[..n]);
        run.loose.extend((0..n).map(|j| st.dist.loose >> j & 1 == 1));
        phases.push(-1);
        let se = if offset != 0.0 { exm.at(t - offset, true) } else { st };
        for j in 0..n {
            let loose = se.dist.loose >> j & 1 == 1;
            enc_loose[i * n + j] = loose;
            let path = models[j].path(se.b[j]);
            enc_base[i * n + j] = if loose || se.t[j] <= 0.0 {
                path.length()
            } else {
                models[j].taut(se.b[j], se.t[j]).map(|c| c.unstretched).unwrap_or_else(|_| path.length())
            };
        }
    }
    // Slack paid out by the drums of loose cables: a smooth rise and fall over each episode.
    let mut slack_rng = rng(s.seed, STREAM_SLACK);
    let mut slack = vec![0.0; n_ex * n];
    if s.physics.slack {
        for j in 0..n {
            let mut i = 0;
            while i < n_ex {
                if !enc_loose[i * n + j] {
                    i += 1;
                    continue;
                }
                let i0 = i;
                while i < n_ex && enc_loose[i * n + j] {
                    i += 1;
                }
                let len = i - i0;
                // Peak 5-50 mm, but no faster than 0.5 m/s of paid-out cable.
                let peak = slack_rng.gen_range(0.005..0.05_f64).min(0.5 * 0.5 * len as f64 * dt);
                for k in 0..len {
                    let x = (k + 1) as f64 / (len + 1) as f64;
                    slack[(i0 + k) * n + j] = peak * (std::f64::consts::PI * x).sin();
                }
            }
        }
    }
    for k in 0..n_ex * n {
        run.drum_lengths.push(enc_base[k] + slack[k]);
    }

    // Sensors.
    let mut tracker = Tracker::new(&s.noise);
    let mut tr_rng = rng(s.seed, STREAM_TRACKER);
    let mut enc_rng = rng(s.seed, STREAM_ENCODER);
    let mut encoders: Vec<Encoder> = (0..n).map(|j| Encoder::of_cable(&truth, &s.physics, &s.noise, s.seed, j)).collect();
    let mut l = vec![0.0; n];
    let mut f = vec![0.0; n];
    run.recording.comments.push(format!(
        " simulated by taut-sim: robot {}, seed {}, {} Hz, loose fraction target {}",
        s.robot.robot.name, s.seed, s.rate_hz, s.loose_fraction
    ));
    if s.noise.tracker_phi > 0.0 {
        run.recording.comments.push(format!(" tracker noise AR(1), lag-1 correlation {} per sample", s.noise.tracker_phi));
    }
    // What the cells at the winches see: the platform-end tension through the cell's gain and
    // the guides' friction at the cable's speed (central difference of the true path length).
    let mu_theta = s.physics.friction_mu_theta.unwrap_or(0.0);
    let path_len: Vec<f64> = if mu_theta != 0.0 {
        (0..total)
            .flat_map(|i| {
                let r = rotation(run.orientations[i]);
                let p = run.positions[i];
                (0..n)
                    .map(|j| {
                        let o = rotate(&r, truth.platform_points[j]);
                        models[j].path([p[0] + o[0], p[1] + o[1], p[2] + o[2]]).length()
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    } else {
        vec![]
    };
    let cell_input = |i: usize, j: usize| {
        let mut t = s.physics.gain_of(j) * run.tensions[i * n + j];
        if mu_theta != 0.0 {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(total - 1));
            let speed = if b > a { (path_len[b * n + j] - path_len[a * n + j]) / ((b - a) as f64 * dt) } else { 0.0 };
            t *= capstan_factor(speed, mu_theta);
        }
        t
    };
    for i in 0..total {
        let p = tracker.measure(run.positions[i], &mut tr_rng);
        for j in 0..n {
            l[j] = encoders[j].read(run.drum_lengths[i * n + j], &mut enc_rng) + s.physics.height_error(run.positions[i][2]);
            f[j] = cells[j].read(cell_input(i, j), &mut cell_rng);
        }
        let q = if p[0].is_nan() { [f64::NAN; 4] } else { run.orientations[i] };
        run.recording.push(i as f64 * dt, p, Some(q), &l, Some(&f), Some(phases[i]));
        if run.loose[i * n..(i + 1) * n].iter().any(|&x| x) {
            run.loose_samples += 1;
        }
    }
    Ok(run)
}

/// Bisection on the excursion duration until the excitation's loose fraction reaches `target`
/// (on a 25 Hz grid); if the longest excursions are not enough, bisection on their peak
/// acceleration (up to 3x). Returns the chosen duration.
fn tune_excursions(exm: &mut ExcitationModel<'_>, target: f64, n_ex: usize, dt: f64, rate_hz: f64) -> f64 {
    let stride = ((rate_hz / 25.0).round() as usize).max(1);
    let eval = |d: f64, k: f64, exm: &mut ExcitationModel<'_>| {
        exm.ex.set_excursion_duration(d);
        exm.ex.set_accel_scale(k);
        exm.loose_fraction(n_ex, dt, stride)
    };
    let d_max = exm.ex.max_excursion_duration();
    // (parameter, fraction) brackets; the parameter is the duration or the acceleration scale.
    let f_max = eval(d_max, 1.0, exm);
    let (param_is_duration, mut lo, mut hi) = if f_max >= target { (true, 0.0, d_max) } else { (false, 1.0, 3.0) };
    let at = |x: f64, exm: &mut ExcitationModel<'_>| if param_is_duration { eval(x, 1.0, exm) } else { eval(d_max, x, exm) };
    let (mut f_lo, mut f_hi) = (at(lo, exm), at(hi, exm));
    if f_lo < target && f_hi > target {
        for _ in 0..16 {
            let mid = 0.5 * (lo + hi);
            let f = at(mid, exm);
            if f < target {
                (lo, f_lo) = (mid, f);
            } else {
                (hi, f_hi) = (mid, f);
            }
        }
    }
    let x = if (f_lo - target).abs() <= (f_hi - target).abs() { lo } else { hi };
    at(x, exm);
    exm.ex.max_excursion_duration().min(if param_is_duration { x } else { d_max })
}
