//! `taut diagnose` on simulated recordings in which one effect (or a pair) is switched on but
//! nothing in the file says so: the right effect is named, its parameter is recovered within a
//! tolerance derived from the reported uncertainty, and the held-out RMS falls. On effect-free
//! recordings nothing but `slack` is named.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Effect};
use taut_sim::{simulate, Physics, Scenario};

fn run(mut s: Scenario, duration_s: f64) -> (Diagnosis, taut_sim::SimRun) {
    s.duration_s = duration_s;
    let sim = simulate(&s);
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    let d = diagnose(&sim.recording, &sim.truth.platform_points, None, &opts).expect("diagnosis");
    (d, sim)
}

fn named(d: &Diagnosis) -> Vec<Effect> {
    d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect()
}

fn finding(d: &Diagnosis, e: Effect) -> &taut_calib::diagnose::Finding {
    d.effects.iter().find(|f| f.effect == e).unwrap_or_else(|| panic!("{} not named: {:#?}", e.name(), summary(d)))
}

fn summary(d: &Diagnosis) -> Vec<String> {
    let mut v: Vec<String> = d.effects.iter().map(|f| format!("{}: {}", f.effect.name(), f.evidence)).collect();
    v.extend(d.rejected.iter().cloned());
    v.extend(d.mismatch.words.iter().cloned());
    v.push(format!("baseline {:.3} mm held out {:.3} mm", d.baseline.rms_m * 1e3, d.baseline.heldout_rms_m * 1e3));
    v
}

/// |estimate - truth| within 6 reported sigmas, or within `rel` of the truth (the simulator's
/// physics is independent of the diagnosis models, so a small model difference remains).
fn assert_recovered(name: &str, est: f64, sigma: f64, truth: f64, rel: f64) {
    let err = (est - truth).abs();
    assert!(
        err <= 6.0 * sigma || err <= rel * truth.abs(),
        "{name}: estimate {est} ± {sigma} vs truth {truth} (error {err}, {:.1} sigma)",
        err / sigma
    );
}

/// The held-out RMS falls by `factor`, or, when the baseline is already within `factor` of the
/// measurement noise (a 3x fall would be below the noise, which no model can reach), to within
/// 10% of the noise level `sqrt(tracker_sigma^2 + encoder_sigma^2)`.
fn assert_heldout_falls(d: &Diagnosis, noise: f64, factor: f64) {
    let target = (d.baseline.heldout_rms_m / factor).max(1.1 * noise);
    assert!(
        d.final_fit.heldout_rms_m <= target && d.final_fit.heldout_rms_m < d.baseline.heldout_rms_m,
        "held-out RMS {:.3} -> {:.3} mm, expected <= {:.3} mm (a {factor}x fall or 1.1x the noise {:.3} mm): {:#?}",
        d.baseline.heldout_rms_m * 1e3,
        d.final_fit.heldout_rms_m * 1e3,
        target * 1e3,
        noise * 1e3,
        summary(d)
    );
}

fn noise_of(s: &Scenario) -> f64 {
    let c = &s.robot.calibration;
    (c.tracker_sigma_m.powi(2) + c.encoder_sigma_m.powi(2)).sqrt()
}

#[test]
fn noise_only_names_nothing_but_slack() {
    for seed in [3, 4] {
        let (d, _) = run(Scenario::aras_cam(seed), 40.0);
        assert!(named(&d).is_empty(), "seed {seed}: {:#?}", summary(&d));
    }
    let (d, _) = run(Scenario::three_cable(5), 40.0);
    assert!(named(&d).is_empty(), "three-cable: {:#?}", summary(&d));
}

#[test]
fn elasticity_is_named_and_ea_recovered() {
    let mut s = Scenario::aras_cam(11);
    s.physics = Physics { elasticity: Some(20_000.0), ..Physics::default() };
    let noise = noise_of(&s);
    let (d, _) = run(s, 40.0);
    assert_eq!(named(&d).first(), Some(&Effect::Elasticity), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Elasticity);
    for (v, s) in f.values.iter().zip(&f.sigmas) {
        assert_recovered("EA", *v, *s, 20_000.0, 0.05);
    }
    assert_heldout_falls(&d, noise, 3.0);
}

#[test]
fn time_offset_is_named_on_three_cables() {
    let mut s = Scenario::three_cable(12);
    s.physics = Physics { time_offset_s: 0.03, ..Physics::default() };
    let dt = 1.0 / s.rate_hz;
    let (d, _) = run(s, 40.0);
    assert_eq!(named(&d).first(), Some(&Effect::TimeOffset), "{:#?}", summary(&d));
    let f = finding(&d, Effect::TimeOffset);
    // The offset is fitted by linearly interpolating the *noisy* tracker pose; the interpolated
    // noise variance, (s^2 + (1-s)^2) sigma^2, is smallest half-way between samples, so the fit
    // is pulled toward the nearest half-sample (measured: 26.5 ms for 30 ms at 100 Hz). That
    // bias is bounded by half a sample interval, which the reported sigma does not include.
    assert_recovered("offset_s", f.values[0], f.sigmas[0], 0.03, (0.5 * dt / 0.03).max(0.05));
}

#[test]
fn backlash_is_named() {
    let mut s = Scenario::aras_cam(13);
    s.physics = Physics { backlash_m: 0.006, ..Physics::default() };
    let (d, _) = run(s, 40.0);
    assert_eq!(named(&d).first(), Some(&Effect::Backlash), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Backlash);
    for (v, s) in f.values.iter().zip(&f.sigmas) {
        assert_recovered("width_m", *v, *s, 0.006, 0.1);
    }
}

#[test]
fn scale_is_named() {
    let mut s = Scenario::aras_cam(14);
    s.physics = Physics { scale: Some(vec![1.004; 4]), ..Physics::default() };
    let (d, _) = run(s, 40.0);
    assert_eq!(named(&d).first(), Some(&Effect::Scale), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Scale);
    for (v, s) in f.values.iter().zip(&f.sigmas) {
        assert_recovered("scale", *v, *s, 1.004, 0.001);
    }
}

#[test]
fn pulley_is_named() {
    let mut s = Scenario::aras_cam(15);
    s.physics = Physics { pulley: Some(0.08), ..Physics::default() };
    let (d, _) = run(s, 40.0);
    // On this geometry an 8 cm swivel pulley is almost a shifted anchor (the ideal model's
    // held-out RMS is close to the noise), but the held-out test still tells them apart: the
    // pulley must be named (issue 14), not left as "fits equally well".
    assert_eq!(named(&d).first(), Some(&Effect::Pulley), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Pulley);
    assert_recovered("radius_m", f.values[0], f.sigmas[0], 0.08, 0.1);
}

#[test]
fn sag_is_named_on_the_outdoor_robot() {
    let mut s = Scenario::outdoor(16);
    s.physics = Physics { sag: Some(1.2), ..Physics::default() };
    // 60 s: at 40 s the held-out blocks do not cover enough of the workspace to name sag.
    let (d, _) = run(s, 60.0);
    assert_eq!(named(&d).first(), Some(&Effect::Sag), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Sag);
    assert_recovered("w", f.values[0], f.sigmas[0], 1.2, 0.1);
}

/// Seed 17 reaches 1.56 mm held out (goal 1.65 mm); seeds 27 and 57 reach 1.45 and 1.53 mm,
/// 37 and 47 1.65 and 1.63 mm (at the goal: the per-cable EA and play widths trade off).
#[test]
fn elasticity_and_backlash_together() {
    let mut s = Scenario::aras_cam(17);
    s.physics = Physics { elasticity: Some(20_000.0), backlash_m: 0.008, ..Physics::default() };
    let noise = noise_of(&s);
    let (d, _) = run(s, 40.0);
    let n = named(&d);
    assert!(n.contains(&Effect::Elasticity) && n.contains(&Effect::Backlash), "{:#?}", summary(&d));
    assert_heldout_falls(&d, noise, 3.0);
}

#[test]
fn without_tensions_elasticity_is_not_claimed() {
    let mut s = Scenario::aras_cam(18);
    s.physics = Physics { elasticity: Some(20_000.0), ..Physics::default() };
    s.with_tensions = false;
    let (d, _) = run(s, 40.0);
    assert!(!d.used_tensions);
    assert!(!named(&d).iter().any(|e| e.needs_tension()), "{:#?}", summary(&d));
}

#[test]
fn slow_recording_with_orientation_and_platform_points() {
    let mut s = Scenario::aras_cam(19);
    let pts = [[0.12, -0.06, 0.05], [0.12, 0.06, 0.05], [-0.12, 0.06, 0.05], [-0.12, -0.06, 0.05]];
    for (c, p) in s.robot.cables.iter_mut().zip(pts) {
        c.platform_point = p;
    }
    s.with_orientation = true;
    s.rate_hz = 4.0;
    s.physics = Physics { elasticity: Some(20_000.0), ..Physics::default() };
    let (d, sim) = run(s, 400.0);
    assert!(sim.recording.q.is_some());
    assert_eq!(named(&d).first(), Some(&Effect::Elasticity), "{:#?}", summary(&d));
    let f = finding(&d, Effect::Elasticity);
    for (v, s) in f.values.iter().zip(&f.sigmas) {
        assert_recovered("EA", *v, *s, 20_000.0, 0.1);
    }
}
