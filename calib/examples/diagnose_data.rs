//! Writes the diagnosis benchmark's recording (the same as `benches/diagnose.rs`: a 4-cable
//! ARAS-CAM-like robot, 12,000 samples, concealed elasticity EA = 20 kN, 5 % loose readings,
//! seed 7), so that the whole `taut diagnose` process can be timed and profiled on it.
//!
//! ```text
//! cargo run --release -p taut-calib --example diagnose_data -- OUT.csv
//! ```

use taut_calib::synth::{self, Spec, Stretch};

fn main() {
    let out = std::env::args().nth(1).unwrap_or_else(|| "diagnose-12k.csv".into());
    let mut spec = Spec::new(synth::aras_cam());
    spec.stretch = Stretch::Physical;
    spec.cable_ea_n = 20_000.0;
    spec.loose_fraction = 0.05;
    let rec = synth::box_recording(&spec, 12_000, [-2.5, -1.2, 0.5], [2.5, 1.2, 2.8], 7);
    rec.save_atomic(&out).unwrap_or_else(|e| panic!("writing {out}: {e}"));
    eprintln!("wrote {out} ({} samples x {} cables)", rec.len(), rec.n_cables);
}
