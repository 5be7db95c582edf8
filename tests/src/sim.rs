//! Simulated recordings for the diagnosis tests and examples.

use taut_sim::{try_simulate, Scenario, SimRun};

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
