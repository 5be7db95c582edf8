//! A stepping plant for the real-time loop and the virtual drives: the platform's response to
//! drum commands, quasi-static (the default) or dynamic.
//!
//! Each [`Plant::step`] takes the elapsed time and one [`CableCommand`] per cable and returns the
//! platform position, the encoder readings (scale, offset, backlash, time offset, optional noise)
//! and the platform-end tensions (optional load-cell noise). Everything is allocated in
//! [`Plant::new`]; a step does not allocate.
//!
//! - Quasi-static (`Physics::dynamics` is `None`): each step finds the static equilibrium
//!   (warm-started from the last one, see [`crate::equilibrium`]).
//! - Dynamic (`Physics::dynamics` is `Some(..)`): each step integrates the platform's mass (a
//!   point mass, or a rigid body that also rotates) on elastic, damped cables and the
//!   torque-mode drums (see [`crate::dynamics`]); the first step starts at rest in the static
//!   equilibrium with the orientation imposed. The sensors are the same.
//!
//! ```no_run
//! use taut_sim::{CableCommand, Scenario};
//! // The scenario's true robot at rest at the workspace centre, with its physics and noise.
//! let (mut plant, hold) = Scenario::aras_cam(1).plant().unwrap();
//! let mut cmds: Vec<_> = hold.iter().map(|&l| CableCommand::Length(l)).collect();
//! cmds[3] = CableCommand::Tension(10.0); // cable 3 in torque mode
//! let out = plant.step(0.001, &cmds);
//! println!("{:?} {:?} {:?}", out.position, out.encoder_m, out.tension_n);
//! ```

use std::cell::Cell;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::catenary::Catenary;
use crate::dynamics::{Body, DynState, Mode};
use crate::equilibrium::{EquilibriumReport, System};
use crate::physics::{CableCommand, CableLoad, CableModel, Physics};
use crate::sensors::{Encoder, LoadCell, Noise};
use crate::truth::Truth;
use crate::SimError;

/// Encoder history kept for the time offset, samples per cable.
const HISTORY: usize = 256;

/// One step's outputs, borrowed from the plant.
#[derive(Debug, Clone, Copy)]
pub struct StepOutput<'a> {
    /// Platform reference point, m.
    pub position: [f64; 3],
    /// Encoder readings, m.
    pub encoder_m: &'a [f64],
    /// Load-cell readings, N: the platform-end tensions through the guides' friction and the
    /// cells' gains ([`Physics::friction_mu_theta`], [`Physics::loadcell_gain`]).
    pub tension_n: &'a [f64],
    /// Unstretched lengths paid out by the drums (no sensor effects), m.
    pub drum_m: &'a [f64],
    /// How the equilibrium search went. In dynamic mode: `iterations` is the number of
    /// sub-steps, `residual_n` the net force on the platform (`m |a|`), and `converged` false
    /// only for a step whose state turned non-finite (undone).
    pub report: EquilibriumReport,
}

/// The simulated robot, stepped by time.
#[derive(Debug, Clone)]
pub struct Plant {
    models: Vec<CableModel>,
    offsets: Vec<[f64; 3]>,
    platform_points: Vec<[f64; 3]>,
    mass: f64,
    p: [f64; 3],
    /// Orientation (w, x, y, z): imposed, or the rigid platform's.
    q: [f64; 4],
    t: f64,
    time_offset: f64,
    /// [`crate::Physics::height_error_per_m`].
    height_error: Option<f64>,
    loads: Vec<CableLoad>,
    drum: Vec<f64>,
    encoder_out: Vec<f64>,
    tension_out: Vec<f64>,
    encoders: Vec<Encoder>,
    loadcells: Vec<LoadCell>,
    loadcell_offsets: Vec<f64>,
    // Per cable: the cell's gain; the guides' friction `mu theta` (see `Physics`).
    gains: Vec<f64>,
    mu_theta: f64,
    noisy: bool,
    rng: ChaCha8Rng,
    // Ring buffer of (time, drum lengths) for the time offset.
    hist_t: Vec<f64>,
    hist_l: Vec<f64>,
    hist_len: usize,
    hist_head: usize,
    lagged: Vec<f64>,
    warm: Vec<Cell<Option<Catenary>>>,
    last_report: EquilibriumReport,
    // The last converged step: its commands and loads (see `step`).
    good_cmds: Vec<CableCommand>,
    good_loads: Vec<CableLoad>,
    have_good: bool,
    sub_cmds: Vec<CableCommand>,
    failed_steps: u64,
    // The dynamic mode's state (None: quasi-static).
    dynamic: Option<DynState>,
}

/// Substeps tried when a step's equilibrium search fails from the last equilibrium.
const SUBSTEPS: usize = 8;

impl Plant {
    /// A plant of the true robot with the cable `physics`, platform at `p0` (a starting guess:
    /// the first step finds the equilibrium from there). Exact sensors; see [`Plant::with_noise`].
    /// Dynamic when [`Physics::dynamics`] is set (its cables then have no sag and the dynamics'
    /// EA when elasticity is off).
    ///
    /// # Panics
    /// If the dynamics' [`crate::dynamics::RigidBody`] has an inertia tensor that is not
    /// symmetric positive definite.
    pub fn new(truth: &Truth, physics: &Physics, p0: [f64; 3]) -> Self {
        let n = truth.n_cables();
        let none = Noise::none();
        let rng = ChaCha8Rng::seed_from_u64(0);
        let models = match &physics.dynamics {
            Some(d) => crate::dynamics::models(truth, physics, d),
            None => truth.cable_models(physics).into_iter().map(CableModel::rigidified).collect(),
        };
        Plant {
            models,
            offsets: truth.platform_points.clone(),
            platform_points: truth.platform_points.clone(),
            mass: truth.mass_kg,
            p: p0,
            q: [1.0, 0.0, 0.0, 0.0],
            t: 0.0,
            time_offset: physics.time_offset_s.max(0.0),
            height_error: physics.height_error_per_m,
            loads: vec![CableLoad { force: [0.0; 3], energy: 0.0, tension: 0.0, drum_length: 0.0, slack: false }; n],
            drum: vec![0.0; n],
            encoder_out: vec![0.0; n],
            tension_out: vec![0.0; n],
            encoders: (0..n)
                .map(|j| {
                    Encoder::new(truth.scale[j], truth.l0[j], physics.backlash_m, &none)
                        .with_drum(physics.drum())
                        .with_eccentricity(physics.eccentricity(j))
                })
                .collect(),
            loadcells: (0..n).map(|_| LoadCell::with_offset(0.0, &none)).collect(),
            loadcell_offsets: truth.loadcell_offsets.clone(),
            gains: (0..n).map(|j| physics.gain_of(j)).collect(),
            mu_theta: physics.friction_mu_theta.unwrap_or(0.0),
            noisy: false,
            rng,
            hist_t: vec![f64::NEG_INFINITY; HISTORY],
            hist_l: vec![0.0; HISTORY * n],
            hist_len: 0,
            hist_head: 0,
            lagged: vec![0.0; n],
            warm: vec![Cell::new(None); n],
            last_report: EquilibriumReport { iterations: 0, residual_n: f64::NAN, converged: false, stable: false },
            good_cmds: vec![CableCommand::Tension(0.0); n],
            good_loads: vec![CableLoad { force: [0.0; 3], energy: 0.0, tension: 0.0, drum_length: 0.0, slack: false }; n],
            have_good: false,
            sub_cmds: vec![CableCommand::Tension(0.0); n],
            failed_steps: 0,
            dynamic: physics.dynamics.clone().map(|d| DynState::new(d, n, [1.0, 0.0, 0.0, 0.0])),
        }
    }

    /// Adds encoder noise and quantisation, load-cell noise and the truth's load-cell offsets
    /// (the tracker is not part of the plant), seeded.
    pub fn with_noise(mut self, noise: &Noise, seed: u64) -> Self {
        for (j, e) in self.encoders.iter_mut().enumerate() {
            *e = e.clone().with_noise(noise).with_winding(crate::sensors::Winding::of_cable(noise, seed, j));
        }
        self.loadcells = self.loadcell_offsets.iter().map(|&o| LoadCell::with_offset(o, noise)).collect();
        self.rng = crate::rng(seed, crate::STREAM_PLANT);
        self.noisy = true;
        self
    }

    /// Number of cables.
    pub fn n_cables(&self) -> usize {
        self.models.len()
    }

    /// Current platform position, m.
    pub fn position(&self) -> [f64; 3] {
        self.p
    }

    /// Current velocity of the platform's reference point, m/s (zero in the quasi-static mode).
    pub fn velocity(&self) -> [f64; 3] {
        match self.dynamic.as_ref() {
            None => [0.0; 3],
            Some(d) => match &d.rigid {
                None => d.v,
                Some(r) => {
                    // v_ref = v_com + w x (p - x_com).
                    let u = r.omega().cross(&(-r.com_offset()));
                    std::array::from_fn(|k| d.v[k] + u[k])
                }
            },
        }
    }

    /// Current platform orientation (unit quaternion w, x, y, z): the imposed one
    /// ([`Plant::set_orientation`]), or the rigid platform's ([`crate::dynamics::RigidBody`]).
    pub fn orientation(&self) -> [f64; 4] {
        self.q
    }

    /// Angular velocity of a rigid platform, world frame, rad/s (`None` unless
    /// [`crate::Dynamics::rigid_body`] is set).
    pub fn angular_velocity(&self) -> Option<[f64; 3]> {
        let w = self.dynamic.as_ref()?.rigid.as_ref()?.omega();
        Some([w[0], w[1], w[2]])
    }

    /// Angular momentum of a rigid platform about its centre of mass, world frame, N m s (`None`
    /// unless [`crate::Dynamics::rigid_body`] is set).
    pub fn angular_momentum(&self) -> Option<[f64; 3]> {
        let l = self.dynamic.as_ref()?.rigid.as_ref()?.l;
        Some([l[0], l[1], l[2]])
    }

    /// Mechanical energy of a dynamic plant, J: kinetic (translation of the centre of mass and,
    /// for a rigid platform, rotation about it), gravitational (of the centre of mass) and
    /// elastic (the cables' stretch, with the loads of the last step). `None` when quasi-static.
    pub fn mechanical_energy(&self) -> Option<f64> {
        let d = self.dynamic.as_ref()?;
        let v2: f64 = d.v.iter().map(|x| x * x).sum();
        let (rot, z) = match &d.rigid {
            None => (0.0, self.p[2]),
            Some(r) => (r.kinetic(), self.p[2] + r.com_offset()[2]),
        };
        let elastic: f64 = self.loads.iter().map(|l| l.energy).sum();
        Some(0.5 * self.mass * v2 + rot + self.mass * crate::physics::G * z + elastic)
    }

    /// Adds `dw` (world frame, rad/s) to a rigid platform's angular velocity: a twist. Nothing
    /// for a point-mass or quasi-static platform.
    pub fn nudge_rotation(&mut self, dw: [f64; 3]) {
        if let Some(r) = self.dynamic.as_mut().and_then(|d| d.rigid.as_mut()) {
            r.add_omega(dw);
        }
    }

    /// Whether the plant integrates the dynamics ([`Physics::dynamics`]).
    pub fn is_dynamic(&self) -> bool {
        self.dynamic.is_some()
    }

    /// Moves the platform by `dp` (m) and adds `dv` to its velocity (m/s), drums unchanged: a
    /// push or an impulse. In dynamic mode (after the first step) the platform swings from there;
    /// the quasi-static plant ignores `dv` and finds its equilibrium again from the moved position.
    pub fn nudge(&mut self, dp: [f64; 3], dv: [f64; 3]) {
        for k in 0..3 {
            self.p[k] += dp[k];
        }
        if let Some(d) = &mut self.dynamic {
            for k in 0..3 {
                d.v[k] += dv[k];
            }
        }
    }

    /// The linearised modes at the current position with the current tensions and drums held
    /// (see [`crate::dynamics`]), sorted by natural frequency; `None` for a quasi-static plant.
    /// The translational modes at the current orientation, held (also for a rigid platform).
    pub fn predicted_modes(&self) -> Option<[Mode; 3]> {
        let d = self.dynamic.as_ref()?;
        let t: Vec<f64> = self.loads.iter().map(|l| l.tension).collect();
        let (k, c) = crate::dynamics::linearise(&self.models, &self.offsets, self.mass, &d.params, self.p, &t);
        Some(crate::dynamics::modes(&k, &c, self.mass))
    }

    /// Platform-end tension of each cable at the last equilibrium (dynamic: at the end of the
    /// last step), N: the physics, before the load cells' offset and noise (for measurements of
    /// what the sensors report).
    pub fn true_tension(&self, j: usize) -> f64 {
        self.loads[j].tension
    }

    /// The drum length of cable `j` at which its encoder reads `reading` without noise, m: what
    /// the drive holds when commanded that reading ([`crate::sensors::Encoder::drum_for`]).
    pub fn drum_for_reading(&self, j: usize, reading: f64) -> f64 {
        self.encoders[j].drum_for(reading)
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// The last equilibrium report.
    pub fn report(&self) -> EquilibriumReport {
        self.last_report
    }

    /// Imposes the platform orientation (unit quaternion w, x, y, z; the plant keeps it fixed).
    /// A rigid platform ([`crate::Dynamics::rigid_body`]) is turned there, keeping its angular
    /// momentum, and rotates on from there.
    pub fn set_orientation(&mut self, q: [f64; 4]) {
        self.q = q;
        if let Some(r) = self.dynamic.as_mut().and_then(|d| d.rigid.as_mut()) {
            r.q = q;
        }
        let r = crate::trajectory::rotation(q);
        for (o, b) in self.offsets.iter_mut().zip(&self.platform_points) {
            *o = crate::trajectory::rotate(&r, *b);
        }
    }

    /// Drum lengths (position mode) that hold the platform in equilibrium at `p` with these
    /// platform-end tensions. The tensions must balance the weight; the plant's stiff cables then
    /// settle within microns of `p`.
    pub fn lengths_holding(&self, p: [f64; 3], tensions: &[f64]) -> Result<Vec<f64>, SimError> {
        self.models
            .iter()
            .zip(&self.offsets)
            .zip(tensions)
            .map(|((m, o), &t)| {
                m.taut([p[0] + o[0], p[1] + o[1], p[2] + o[2]], t).map(|c| c.unstretched).map_err(|e| SimError::Catenary(e.to_string()))
            })
            .collect()
    }

    /// Drum lengths that hold the platform at rest at `p` with the tensions a controller would
    /// choose there (minimum norm, at least `min_tension_n`; see [`crate::tension`]).
    pub fn lengths_at_rest(&self, p: [f64; 3], min_tension_n: f64) -> Result<Vec<f64>, SimError> {
        let n = self.models.len();
        let mut dirs = [[0.0; 3]; crate::tension::MAX_SIM_CABLES];
        for j in 0..n {
            let o = self.offsets[j];
            dirs[j] = self.models[j].path([p[0] + o[0], p[1] + o[1], p[2] + o[2]]).dir;
        }
        let mut t = vec![0.0; n];
        let d = crate::tension::distribute(&dirs[..n], [0.0, 0.0, self.mass * crate::physics::G], min_tension_n, &mut t);
        if d.loose != 0 || !d.feasible {
            return Err(SimError::BadScenario("the cables cannot hold the platform at rest there with the minimum tension"));
        }
        self.lengths_holding(p, &t)
    }

    /// Advances by `dt` seconds under `commands` (one per cable).
    ///
    /// # Panics
    /// If the number of commands is not the number of cables.
    pub fn step(&mut self, dt: f64, commands: &[CableCommand]) -> StepOutput<'_> {
        assert_eq!(commands.len(), self.models.len(), "one command per cable");
        self.t += dt;
        let rep = if self.dynamic.is_some() { self.step_dynamic(dt, commands) } else { self.step_static(commands) };
        self.last_report = rep;
        for (j, l) in self.loads.iter().enumerate() {
            // The cell at the winch: the platform-end tension through the guides' friction at
            // the drum's speed, and the cell's gain.
            // (The first step has no drum length before it: at rest.)
            let speed = if dt > 0.0 && self.drum[j] != 0.0 { (l.drum_length - self.drum[j]) / dt } else { 0.0 };
            self.tension_out[j] = self.gains[j] * l.tension * crate::sensors::capstan_factor(speed, self.mu_theta);
            self.drum[j] = l.drum_length;
        }
        self.push_history();
        self.lag_into_scratch();
        for j in 0..self.models.len() {
            let (rng, noisy) = (&mut self.rng, self.noisy);
            self.encoder_out[j] = self.encoders[j].read(self.lagged[j], rng) + self.height_error.map_or(0.0, |k| k * self.p[2] * self.p[2]);
            let t = self.tension_out[j];
            if noisy {
                self.tension_out[j] = self.loadcells[j].read(t, rng);
            }
        }
        StepOutput { position: self.p, encoder_m: &self.encoder_out, tension_n: &self.tension_out, drum_m: &self.drum, report: rep }
    }

    /// The dynamic mode's step: the first one places the platform in the static equilibrium,
    /// at rest; every step integrates `dt`.
    fn step_dynamic(&mut self, dt: f64, commands: &[CableCommand]) -> EquilibriumReport {
        let mut first = None;
        if self.dynamic.as_ref().is_some_and(|d| !d.started) {
            first = Some(self.solve_for(commands));
            let loads = &self.loads;
            self.dynamic.as_mut().expect("dynamic").start_at_rest(loads);
        }
        let body = Body { models: &self.models, offsets: &self.offsets, points: &self.platform_points, mass: self.mass };
        let d = self.dynamic.as_mut().expect("dynamic");
        let rep = d.advance(&body, &mut self.p, dt, commands, &mut self.loads);
        if let Some(r) = &d.rigid {
            self.q = r.q;
            let rot = crate::trajectory::rotation(r.q);
            for (o, b) in self.offsets.iter_mut().zip(&self.platform_points) {
                *o = crate::trajectory::rotate(&rot, *b);
            }
        }
        if !rep.converged {
            self.failed_steps += 1;
        }
        match first {
            Some(f) if dt == 0.0 => f,
            _ => rep,
        }
    }

    /// The quasi-static step: the equilibrium under `commands`.
    fn step_static(&mut self, commands: &[CableCommand]) -> EquilibriumReport {
        let p_before = self.p;
        let mut rep = self.solve_for(commands);
        if !rep.converged && self.have_good {
            // A large change of the commands since the last equilibrium (a stalled caller):
            // walk there in substeps from the last equilibrium (a failed search leaves `p`).
            rep = self.solve_in_substeps(commands);
        }
        if rep.converged {
            self.good_cmds.copy_from_slice(commands);
            self.good_loads.copy_from_slice(&self.loads);
            self.have_good = true;
        } else {
            // No equilibrium (e.g. every cable slack): keep the last one, position (substeps
            // may have moved it part way) and loads together; the loads of the failed search
            // describe a platform somewhere else.
            self.failed_steps += 1;
            self.p = p_before;
            if self.have_good {
                self.loads.copy_from_slice(&self.good_loads);
            }
        }
        rep
    }

    /// Steps whose equilibrium search failed even in substeps (the plant kept the last
    /// equilibrium); in dynamic mode, steps whose state turned non-finite (undone).
    pub fn failed_steps(&self) -> u64 {
        self.failed_steps
    }

    /// One equilibrium search from the current position under `commands`; moves there if it
    /// converged. Fills `self.loads` either way.
    fn solve_for(&mut self, commands: &[CableCommand]) -> EquilibriumReport {
        let sys = System { models: &self.models, offsets: &self.offsets, commands, mass: self.mass, warm: &self.warm };
        let (p, rep) = sys.solve(self.p, &mut self.loads);
        if rep.converged {
            self.p = p;
        }
        rep
    }

    /// From the last converged commands to `commands` in [`SUBSTEPS`] equal steps (lengths and
    /// tensions interpolated; a mode change takes the new command at once).
    fn solve_in_substeps(&mut self, commands: &[CableCommand]) -> EquilibriumReport {
        let mut sub = std::mem::take(&mut self.sub_cmds);
        let mut rep = self.last_report;
        for k in 1..=SUBSTEPS {
            let s = k as f64 / SUBSTEPS as f64;
            for (j, c) in sub.iter_mut().enumerate() {
                *c = match (self.good_cmds[j], commands[j]) {
                    (CableCommand::Length(a), CableCommand::Length(b)) => CableCommand::Length(a + s * (b - a)),
                    (CableCommand::Tension(a), CableCommand::Tension(b)) => CableCommand::Tension(a + s * (b - a)),
                    (_, now) => now,
                };
            }
            rep = self.solve_for(&sub);
            if !rep.converged {
                break;
            }
        }
        self.sub_cmds = sub;
        rep
    }

    fn push_history(&mut self) {
        let n = self.models.len();
        let h = self.hist_head;
        self.hist_t[h] = self.t;
        self.hist_l[h * n..(h + 1) * n].copy_from_slice(&self.drum);
        self.hist_head = (h + 1) % HISTORY;
        self.hist_len = (self.hist_len + 1).min(HISTORY);
    }

    /// Drum lengths at `t - time_offset`, linearly interpolated in the history (the oldest
    /// entry if the history is too short).
    fn lag_into_scratch(&mut self) {
        let n = self.models.len();
        if self.time_offset <= 0.0 {
            self.lagged.copy_from_slice(&self.drum);
            return;
        }
        let target = self.t - self.time_offset;
        // Walk back from the newest entry.
        let idx = |k: usize| (self.hist_head + HISTORY - 1 - k) % HISTORY;
        let mut newer = idx(0);
        for k in 1..self.hist_len {
            let older = idx(k);
            if self.hist_t[older] <= target {
                let (t0, t1) = (self.hist_t[older], self.hist_t[newer]);
                let s = if t1 > t0 { (target - t0) / (t1 - t0) } else { 1.0 };
                for j in 0..n {
                    let (a, b) = (self.hist_l[older * n + j], self.hist_l[newer * n + j]);
                    self.lagged[j] = a + s * (b - a);
                }
                return;
            }
            newer = older;
        }
        let oldest = idx(self.hist_len - 1);
        self.lagged.copy_from_slice(&self.hist_l[oldest * n..(oldest + 1) * n]);
    }
}
