//! Simulated recordings for the diagnosis tests and examples.

use taut_sim::{try_simulate, Physics, Scenario, SimRun};

/// Simulates `s`. A seed whose motion the simulator cannot hold in static equilibrium (a rare
/// planned pose at the small 3-cable robot's workspace edge) is replaced by the seed 10,000
/// higher, up to seed 100,000 (then it panics with the simulator's reason); `s.seed` is left at
/// the seed simulated, so a printed seed reproduces the run.
pub fn simulate_next_seed(s: &mut Scenario) -> SimRun {
    loop {
        match try_simulate(s) {
            Ok(sim) => return sim,
            Err(e) if s.seed < 100_000 => {
                eprintln!("seed {} not simulated ({e}); next seed", s.seed);
                s.seed += 10_000;
            }
            Err(e) => panic!("{e}"),
        }
    }
}

/// The simulated robot an example names on its command line: `three` (the 3-cable robot),
/// `aras` (the 4-cable camera robot) or `outdoor`, at `seed`.
pub fn scenario_named(robot: &str, seed: u64) -> Scenario {
    match robot {
        "three" => Scenario::three_cable(seed),
        "aras" => Scenario::aras_cam(seed),
        "outdoor" => Scenario::outdoor(seed),
        _ => panic!("robot: three | aras | outdoor"),
    }
}

/// The recordings of the time offset + play coverage examples (`offset_backlash_coverage`,
/// `effect_fit_coverage`): the 3-cable robot (`cables` 3) or the 4-cable camera robot (4), 40 s,
/// a time offset and a play, elasticity when `ea_kn` > 0; `clean` turns off the tracker's
/// outliers and dropouts.
pub fn offset_backlash_scenario(seed: u64, cables: u64, ea_kn: u64, play_m: f64, offset_s: f64, clean: bool) -> Scenario {
    let mut s = if cables == 4 { Scenario::aras_cam(seed) } else { Scenario::three_cable(seed) };
    s.physics = Physics {
        elasticity: (ea_kn > 0).then_some(ea_kn as f64 * 1e3),
        backlash_m: play_m,
        time_offset_s: offset_s,
        ..Physics::default()
    };
    s.duration_s = 40.0;
    if clean {
        s.noise.tracker_outlier_prob = 0.0;
        s.noise.tracker_dropout_prob = 0.0;
    }
    s
}

/// What the tension-side recordings conceal (`tension_scenario`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TensionCase {
    /// Nothing: slow motion, no excursions (every sample taut).
    Free,
    /// Per-cell gains [`TENSION_GAINS`], slow motion.
    Gain,
    /// Guide friction `mu theta` [`TENSION_FRICTION`] on every cable, slow motion.
    Friction,
    /// Friction and a 20 ms encoder time offset, slow motion.
    FrictionOffset,
    /// Nothing but the platform's inertia: fast excursions (peak 2.5-4.5 m/s^2, 20 % loose).
    Fast,
}

/// The cells' gains of [`TensionCase::Gain`].
pub const TENSION_GAINS: [f64; 4] = [1.03, 0.97, 1.02, 0.985];

/// `mu theta` of [`TensionCase::Friction`].
pub const TENSION_FRICTION: f64 = 0.05;

/// The 4-cable camera robot, 60 s of excitation at 100 Hz, with the tension-side effect of `case`
/// concealed (see [`tension_scenario_for`]).
pub fn tension_scenario(seed: u64, case: TensionCase) -> Scenario {
    tension_scenario_for(Scenario::aras_cam(seed), case)
}

/// The robot of `s`, 60 s of excitation at 100 Hz, with the tension-side effect of `case`
/// concealed (cable `j` gets the gain `TENSION_GAINS[j % 4]`). Without the three-phase start:
/// its plant is quasi-static, so its tensions balance the weight alone while the platform moves
/// (no inertia), which no real recording does.
pub fn tension_scenario_for(mut s: Scenario, case: TensionCase) -> Scenario {
    let n = s.robot.cables.len();
    s.three_phase = None;
    s.duration_s = 60.0;
    s.loose_fraction = if case == TensionCase::Fast { 0.2 } else { 0.0 };
    s.physics = match case {
        TensionCase::Free | TensionCase::Fast => Physics::default(),
        TensionCase::Gain => Physics { loadcell_gain: Some((0..n).map(|j| TENSION_GAINS[j % 4]).collect()), ..Physics::default() },
        TensionCase::Friction => Physics { friction_mu_theta: Some(TENSION_FRICTION), ..Physics::default() },
        TensionCase::FrictionOffset => Physics { friction_mu_theta: Some(TENSION_FRICTION), time_offset_s: 0.02, ..Physics::default() },
    };
    s
}
