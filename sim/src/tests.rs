//! Scenario-level tests: determinism, physics of the recorded data, each effect.

use crate::*;

#[test]
fn explore() {
    for (name, mut s) in [("aras", Scenario::aras_cam(1)), ("tri", Scenario::three_cable(2)), ("outdoor", Scenario::outdoor(3))] {
        let t0 = std::time::Instant::now();
        s.duration_s = 0.0;
        match try_simulate(&s) { Ok(r) => println!("{name} 3p only: {} samples {:?}", r.recording.len(), t0.elapsed()), Err(e) => println!("{name}: ERR {e} {:?}", t0.elapsed()) };
        let t0 = std::time::Instant::now();
        s.duration_s = 60.0;
        s.three_phase = None;
        let run = match try_simulate(&s) { Ok(r) => r, Err(e) => { println!("{name}: ERR {e}"); continue; } };
        println!("{name}: {} samples, tp {}, loose {:.3}, exc {:.2}s, {:?}", run.recording.len(), run.excitation_start, run.loose_fraction(), run.excursion_s, t0.elapsed());
    }
}

