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
