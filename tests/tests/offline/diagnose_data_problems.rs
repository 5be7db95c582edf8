//! Problems of the data that are not physics are reported as such, with where they are, and
//! excluded: no effect is named to explain them.

use taut_calib::diagnose::{diagnose, DiagnoseOptions, Effect, ProblemKind};
use taut_sim::{simulate, Scenario};

#[test]
fn frozen_encoder_outliers_clock_jump_and_dead_load_cell_are_data_problems_not_physics() {
    let mut s = Scenario::aras_cam(21);
    s.duration_s = 40.0;
    let sim = simulate(&s);
    let mut rec = sim.recording.clone();
    let n = rec.n_cables;
    let m = rec.len();
    // Encoder 1 freezes for 1 s in the middle of the excitation.
    let a = m / 2;
    for i in a..a + 100 {
        rec.l[i * n + 1] = rec.l[(a - 1) * n + 1];
    }
    // A few gross tracker outliers.
    for k in 0..5 {
        rec.p[m / 3 + 97 * k][0] += 0.04;
    }
    // The clock jumps forward by 2 s.
    for t in rec.t[3 * m / 4..].iter_mut() {
        *t += 2.0;
    }
    // Load cell 3 reads nothing.
    let f = rec.f.as_mut().unwrap();
    for i in 0..m {
        f[i * n + 3] = 0.0;
    }
    let opts = DiagnoseOptions::from_config(&s.robot.calibration);
    let d = diagnose(&rec, &sim.truth.platform_points, None, &opts).unwrap();
    let kinds: Vec<(ProblemKind, Option<usize>)> = d.data_problems.iter().map(|p| (p.kind, p.cable)).collect();
    for k in [
        (ProblemKind::FrozenEncoder, Some(1)),
        (ProblemKind::TrackerOutlier, None),
        (ProblemKind::ClockJump, None),
        (ProblemKind::DeadLoadCell, Some(3)),
    ] {
        assert!(kinds.contains(&k), "{k:?} not reported: {:#?}", d.data_problems);
    }
    let named: Vec<Effect> = d.effects.iter().map(|f| f.effect).filter(|e| *e != Effect::Slack).collect();
    assert!(named.is_empty(), "named {named:?} for data problems: {:#?}", d.effects.iter().map(|f| &f.evidence).collect::<Vec<_>>());
}
