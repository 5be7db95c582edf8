//! The start-up excitation of a configured robot: designed at configure time (never in the
//! loop) from the nominal anchors by [`taut_calib::design`], with the calibration's predicted
//! uncertainty, or the Lissajous curve when the design is switched off or impossible.
//!
//! The plan is handed to the loop as a fixed-size [`taut_calib::design::Tour`] inside the `Copy`
//! [`ControllerConfig`]; the prediction goes to the calibrator (its report compares it with the
//! achieved sigmas) and to `ctl status`.

use crate::vocab::ExcitationPlan;
use taut_calib::design::{self, DesignInput};
use taut_config::RobotConfig;
use taut_rt::motion::ControllerConfig;

/// Acceleration of the tour's speed profile, m/s^2: a tenth of g changes the cables' tensions
/// by 10 % and lets a 0.8 m/s cruise start and stop within 0.8 s.
pub const TOUR_ACCEL_M_S2: f64 = 1.0;

/// The tour's cruise speed as a fraction of `safety.max_cable_speed_m_s` (a cable never moves
/// faster than the platform): the information is gathered at the box's extremes, and a faster
/// tour closes a richer loop within the excitation (`taut_calib::design`: the simulated robot's
/// 30 s tour predicts 0.46 mm at 0.4 m/s, 0.36 mm at 0.6 m/s, 0.275 mm at 0.8 m/s, 0.271 mm at
/// 1 m/s). A fifth of the limit stays for the loop's timing jitter (the speed check divides by
/// the measured period).
pub const TOUR_SPEED_FRACTION: f64 = 0.8;

/// Distance the tour keeps inside the workspace box's faces, m (room for tracking error before
/// the workspace check).
pub const TOUR_MARGIN_M: f64 = 0.05;

/// The length noise the calibration's all-cables refinement starts from (`crate::calib_backend`):
/// conservative, for the convergence from the initial estimate, m.
pub fn bundle_length_sigma_m(encoder_sigma_m: f64) -> f64 {
    (4.0 * encoder_sigma_m).max(2e-4)
}

/// The least length noise the refinement re-estimates from its residuals: the encoders' (a
/// micrometre at least), m. Where the model is right the estimate lands here, and the design
/// predicts with it; where it is not, the residuals raise it (`taut_calib::bundle::refine`).
pub fn length_sigma_floor_m(encoder_sigma_m: f64) -> f64 {
    encoder_sigma_m.max(1e-6)
}

/// The design's inputs for `cfg` (nominal anchors required).
pub fn design_input(cfg: &RobotConfig, ccfg: &ControllerConfig) -> Option<DesignInput> {
    let anchors = cfg.anchors()?;
    let m = &cfg.motion;
    let cal = &cfg.calibration;
    Some(DesignInput {
        anchors,
        platform: cfg.platform_points(),
        workspace: ccfg.workspace,
        margin_m: TOUR_MARGIN_M,
        // A cable never moves faster than the platform.
        speed_m_s: TOUR_SPEED_FRACTION * ccfg.max_cable_speed_m_s,
        accel_m_s2: TOUR_ACCEL_M_S2,
        duration_s: m.excitation_s,
        sample_hz: m.tracker_rate_hz / cfg.daemon.calib_decimation.max(1) as f64,
        used_fraction: 1.0 - cal.heldout_fraction,
        heldout_blocks: crate::vocab::HeldoutBlocks::BLOCKS,
        tracker_sigma_m: cal.tracker_sigma_m,
        length_sigma_m: length_sigma_floor_m(cal.encoder_sigma_m),
        mass_kg: cfg.robot.mass_kg,
        follower: ccfg.follower[..ccfg.n].to_vec(),
        follower_tension_n: ccfg.follower_tension_n,
        min_tension_n: cal.min_tension_n,
        max_tension_n: ccfg.max_tension_n,
    })
}

/// The Lissajous path as the loop runs it (for its prediction).
fn lissajous(ccfg: &ControllerConfig) -> impl Fn(f64) -> [f64; 3] + '_ {
    let w = ccfg.workspace;
    let v = ccfg.excitation_speed_m_s;
    move |t| {
        // The same formula as `Controller::excitation_point` after the approach.
        let c: [f64; 3] = std::array::from_fn(|i| (w[0][i] + w[1][i]) / 2.0);
        let amp: [f64; 3] = std::array::from_fn(|i| 0.8 * (w[1][i] - w[0][i]) / 2.0);
        std::array::from_fn(|i| {
            let omega = taut_rt::motion::LISSAJOUS_RATIO[i] * v / (3f64.sqrt() * amp[i].max(1e-3));
            c[i] + amp[i] * (omega * t + taut_rt::motion::LISSAJOUS_PHASE[i]).sin()
        })
    }
}

/// Plans the excitation of `cfg`: sets `ccfg.tour` when the design is on and succeeds.
pub fn plan(cfg: &RobotConfig, ccfg: &mut ControllerConfig) -> ExcitationPlan {
    ccfg.tour = None;
    let Some(inp) = design_input(cfg, ccfg) else {
        return ExcitationPlan { path: "lissajous", waypoints: 0, predicted: None, note: "no nominal anchors to design from".into() };
    };
    let today = design::predict(&inp, lissajous(ccfg));
    if !cfg.motion.design_excitation {
        return ExcitationPlan { path: "lissajous", waypoints: 0, predicted: today, note: "[motion] design_excitation = false".into() };
    }
    // The design's information covers anchors and offsets only; the effects' parameters
    // (stretch against drum scale needs the tension swing, the pulley the wrap angles) were
    // measured on the Lissajous curve (tests/tests/e2e_effects.rs): it stays theirs.
    if !cfg.calibration.effects.is_empty() {
        return ExcitationPlan {
            path: "lissajous",
            waypoints: 0,
            predicted: today,
            note: "[calibration] effects are modelled: the design covers anchors and offsets only".into(),
        };
    }
    match design::design(&inp) {
        Ok(d) => {
            ccfg.tour = Some(d.tour);
            let note = today.map_or(String::new(), |t| format!("the Lissajous curve: {:.2} mm", t.worst_anchor_sigma_m() * 1e3));
            ExcitationPlan { path: "designed tour", waypoints: d.tour.n, predicted: Some(d.predicted), note }
        }
        Err(e) => ExcitationPlan { path: "lissajous", waypoints: 0, predicted: today, note: format!("no design: {e}") },
    }
}

/// The worst anchor 1-sigma of `anchor_sigma` (root of the sum of each anchor's variances), m.
pub fn worst_anchor_sigma_m(anchor_sigma: &[[f64; 3]]) -> f64 {
    anchor_sigma.iter().map(|s| (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()).fold(0.0, f64::max)
}

/// `predicted worst anchor 1-sigma X mm (path), achieved Y mm`, for the calibration's note.
pub fn predicted_vs_achieved(plan: &ExcitationPlan, anchor_sigma: &[[f64; 3]]) -> String {
    format!(
        "{}: predicted worst anchor 1-sigma {:.2} mm, achieved {:.2} mm",
        plan.path,
        plan.predicted_worst_m() * 1e3,
        worst_anchor_sigma_m(anchor_sigma) * 1e3
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use taut_io::FromRobot;

    fn sim_robot() -> RobotConfig {
        let mut cfg = RobotConfig::load(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml")).unwrap();
        cfg.motion.design_excitation = true;
        cfg
    }

    #[test]
    fn the_simulated_robot_gets_a_tour_inside_its_box_with_a_smaller_predicted_sigma() {
        let cfg = sim_robot();
        let mut ccfg = ControllerConfig::from_robot(&cfg).unwrap();
        let plan = plan(&cfg, &mut ccfg);
        let tour = ccfg.tour.expect("a designed tour");
        assert_eq!(plan.path, "designed tour");
        assert_eq!(plan.waypoints, tour.n);
        let w = ccfg.workspace;
        for p in &tour.waypoints[..tour.n] {
            assert!((0..3).all(|i| p[i] > w[0][i] && p[i] < w[1][i]), "{p:?} outside {w:?}");
        }
        let mut off = cfg.clone();
        off.motion.design_excitation = false;
        let mut ccfg_off = ControllerConfig::from_robot(&off).unwrap();
        let today = super::plan(&off, &mut ccfg_off);
        assert!(ccfg_off.tour.is_none() && today.path == "lissajous");
        let (d, l) = (plan.predicted_worst_m(), today.predicted_worst_m());
        assert!(d.is_finite() && l.is_finite() && d < 0.6 * l, "designed {d} m, Lissajous {l} m");
        assert!(plan.summary().contains("predicted worst anchor 1-sigma"), "{}", plan.summary());
    }

    #[test]
    fn the_design_counts_the_rows_the_calibrator_trains_on() {
        use crate::vocab::HeldoutBlocks;
        for rows in [0usize, 1, 7, 8, 9, 100, 2_500, 3_001] {
            for fraction in [0.0, 0.2, 0.5] {
                let daemon: Vec<usize> = HeldoutBlocks::new(rows, fraction).training().into_iter().flatten().collect();
                let design: Vec<usize> = taut_calib::design::training_rows(rows, 1.0 - fraction, HeldoutBlocks::BLOCKS).collect();
                assert_eq!(daemon, design, "rows {rows} held out {fraction}");
            }
        }
    }

    #[test]
    fn predicted_vs_achieved_names_both() {
        let plan = ExcitationPlan {
            path: "designed tour",
            waypoints: 4,
            predicted: Some(taut_calib::design::Prediction {
                anchor_sigma: vec![[1e-3, 0.0, 0.0]],
                l0_sigma: vec![1e-3],
                samples: 10,
                anchor_cov_m2: vec![],
            }),
            note: String::new(),
        };
        let s = predicted_vs_achieved(&plan, &[[3e-4, 4e-4, 0.0], [0.0, 0.0, 1e-4]]);
        assert_eq!(s, "designed tour: predicted worst anchor 1-sigma 1.00 mm, achieved 0.50 mm");
    }
}
