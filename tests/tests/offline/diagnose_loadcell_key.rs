//! The load cells' noise in the configuration reaches `taut diagnose`: with
//! `[calibration] loadcell_sigma_n` and `loadcell_offset_n` the diagnosis weights stretch and sag
//! by the tension noise (errors in variables) and widens their sigmas by the cells' offsets;
//! without them the tensions are taken as exact. One fixed seed, so every outcome below is
//! deterministic (no failure probability to state).

use crate::taut_diagnose;

use serde_json::Value;
use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect};
use taut_config::recording::Recording;
use taut_sim::{Physics, Scenario};
use taut_tests::sim::simulate_next_seed;

/// The JSON's named effects with their parameters and sigmas, as numbers.
fn effects_of_json(j: &Value) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    let nums = |v: &Value| -> Vec<f64> {
        let v = v.as_object().and_then(|o| o.values().next()).cloned().unwrap_or(Value::Null);
        match v {
            Value::Array(a) => a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect(),
            Value::Null => vec![],
            x => vec![x.as_f64().unwrap_or(f64::NAN)],
        }
    };
    j["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["effect"] != "slack")
        .map(|e| (e["effect"].as_str().unwrap().to_string(), nums(&e["parameters"]), nums(&e["parameters_sigma"])))
        .collect()
}

fn effects_of(d: &Diagnosis) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    d.effects
        .iter()
        .filter(|f| f.effect != Effect::Slack)
        .map(|f| (f.effect.name().to_string(), f.values.clone(), f.sigmas.clone()))
        .collect()
}

fn sag_sigma(e: &[(String, Vec<f64>, Vec<f64>)]) -> Option<f64> {
    e.iter().find(|(n, _, _)| n == "sag").map(|(_, _, s)| s[0])
}

/// Sag 0.33 N/m and EA 500 kN on the 20 m outdoor robot, the diagnosis told a 10 N floor (the
/// controller's is 50 N): `taut diagnose` with the simulated cells' noise (0.3 N) and offsets
/// (0.5 N) in the configuration gives the diagnosis the library gives with those options, and
/// not the one without them: the sag's sigma carries the offsets (0.0039 vs 0.0016 N/m).
#[test]
fn the_load_cell_keys_reach_taut_diagnose() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = Scenario::outdoor(23);
    s.physics = Physics { sag: Some(0.33), elasticity: Some(5e5), ..Physics::default() };
    s.robot.calibration.min_tension_n = 10.0;
    s.duration_s = 60.0;
    let sim = simulate_next_seed(&mut s);
    sim.recording.save_atomic(dir.path().join("rec.csv")).unwrap();
    let plain = s.robot.clone();
    let mut eiv = s.robot.clone();
    eiv.calibration.loadcell_sigma_n = s.noise.loadcell_sigma_n;
    eiv.calibration.loadcell_offset_n = s.noise.loadcell_offset_n;
    assert!(eiv.calibration.loadcell_sigma_n > 0.0 && eiv.calibration.loadcell_offset_n > 0.0);
    let with_keys = effects_of_json(&taut_diagnose(dir.path(), &eiv, "eiv"));
    // The library on the same file, with the options set by hand and without them.
    let (rec, _) = Recording::load(dir.path().join("rec.csv")).unwrap();
    let mut o = DiagnoseOptions::from_config(&plain.calibration);
    let without = effects_of(&diagnose(&rec, &plain.platform_points(), None, &o).expect("diagnosis"));
    o.loadcell_sigma_n = s.noise.loadcell_sigma_n;
    o.loadcell_offset_n = s.noise.loadcell_offset_n;
    let lib = effects_of(&diagnose(&rec, &plain.platform_points(), None, &o).expect("diagnosis"));
    eprintln!("taut diagnose with the keys: {with_keys:?}\nthe library with the options: {lib:?}\nwithout: {without:?}");
    // The same diagnosis, to 1e-9 relative rather than to the bit (seen: a sigma's last digit):
    // serde_json's default float reader may be an ulp off, and the binary is built at another
    // optimisation level than this test.
    let names = |e: &[(String, Vec<f64>, Vec<f64>)]| e.iter().map(|x| x.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&with_keys), names(&lib));
    for ((n, v, sg), (_, lv, lsg)) in with_keys.iter().zip(&lib) {
        for (a, b) in v.iter().chain(sg).zip(lv.iter().chain(lsg)) {
            assert!((a - b).abs() <= 1e-9 * b.abs(), "{n}: taut diagnose {a} vs the library {b}");
        }
    }
    assert_ne!(lib, without);
    // The offsets dominate the sag's uncertainty (its statistical sigma alone is ~0.15 %).
    let s_with = sag_sigma(&with_keys).expect("sag named with the keys");
    assert!(s_with > 0.002, "sag sigma {s_with}");
    if let Some(s_without) = sag_sigma(&without) {
        assert!(s_without < 0.5 * s_with, "sag sigma without the keys {s_without}, with {s_with}");
    }
}
