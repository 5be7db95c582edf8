//! Conceals effects that calib's library does not have (an eccentric drum, a length error that
//! follows the platform's height, a drum's winding irregularity) in simulated recordings and
//! counts how often the diagnosis names a library effect while structure above the noise is
//! left: a mismatch forced onto the nearest effect the library knows.
//!
//! ```text
//! cargo run --release -p taut-tests --example outside_library -- ROBOT FIRST_SEED COUNT [key=value ...]
//! ROBOT: three | aras | outdoor; keys: ecc (drum eccentricity, m), height (k in k z^2, 1/m),
//! winding (RMS, m), wavelength (winding's, m), ar (the tracker noise's AR(1) lag-1 correlation),
//! dur (s), and library effects beside: ea (a stretch's EA, N), scale (drum scales off 1 by up to
//! this); VERBOSE=1 prints every recording
//! ```

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect};
use taut_sim::Physics;
use taut_tests::sim::{scenario_named, simulate_next_seed};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let robot = args.first().expect("robot").clone();
    let first: u64 = args.get(1).expect("first seed").parse().expect("seed");
    let count: u64 = args.get(2).expect("count").parse().expect("count");
    let mut physics = Physics::default();
    let (mut dur, mut winding, mut wavelength, mut ar) = (40.0, 0.0, 0.05, 0.0);
    for kv in &args[3..] {
        let (k, v) = kv.split_once('=').expect("key=value");
        let v: f64 = v.parse().expect("a number");
        match k {
            "ecc" => physics.drum_eccentricity_m = Some(v),
            "height" => physics.height_error_per_m = Some(v),
            "winding" => winding = v,
            "wavelength" => wavelength = v,
            "dur" => dur = v,
            "ar" => ar = v,
            // Library effects beside the outside one: a stretch of this EA (N), every drum's
            // scale this far from 1.
            "ea" => physics.elasticity = Some(v),
            "scale" => physics.scale = Some((0..8).map(|j| 1.0 + v * [1.0, -0.7, 0.4, -1.2, 0.9, -0.3, 0.6, -0.8][j]).collect()),
            _ => panic!("unknown key {k}"),
        }
    }
    let verbose = std::env::var("VERBOSE").is_ok_and(|v| v == "1");
    let (mut forced, mut flagged, mut named_clean, mut silent) = (0, 0, 0, 0);
    for seed in first..first + count {
        let mut s = scenario_named(&robot, seed);
        s.physics = physics.clone();
        s.duration_s = dur;
        s.noise.encoder_winding_m = winding;
        s.noise.encoder_winding_wavelength_m = wavelength;
        if ar > 0.0 {
            s.noise.tracker_phi = ar;
        }
        let sim = simulate_next_seed(&mut s);
        let opts = DiagnoseOptions::from_config(&s.robot.calibration);
        let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
        let named: Vec<&str> = d.effects.iter().filter(|f| f.effect != Effect::Slack).map(|f| f.effect.name()).collect();
        let kind = match (named.is_empty(), d.unexplained.is_some()) {
            (false, true) => {
                forced += 1;
                "FORCED"
            }
            (true, true) => {
                flagged += 1;
                "flagged"
            }
            (false, false) => {
                named_clean += 1;
                "named, nothing left"
            }
            (true, false) => {
                silent += 1;
                "nothing named, nothing left"
            }
        };
        println!(
            "seed {seed}: {kind}: [{}] held-out {:.3} -> {:.3} mm",
            named.join(", "),
            d.baseline.heldout_rms_m * 1e3,
            d.final_fit.heldout_rms_m * 1e3
        );
        if verbose {
            for w in &d.mismatch.words {
                println!("    baseline: {w}");
            }
            if let Some(u) = &d.unexplained {
                println!("    unexplained: {u}");
            }
            for f in &d.effects {
                println!("    {}: {}", f.effect.name(), f.evidence);
            }
            for w in d.notes.iter().chain(&d.rejected).filter(|w| w.contains("outside the library")) {
                println!("    {w}");
            }
        }
    }
    println!(
        "{robot} {:?}: {count} recordings: {forced} name a library effect and leave structure, {flagged} name none and report the \
         structure, {named_clean} name one that leaves nothing, {silent} name none and leave nothing",
        &args[3..]
    );
}
