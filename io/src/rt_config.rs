//! The real-time crate's plain configuration, filled from the robot's files on this side:
//! `taut-rt` knows neither `taut-config` nor TOML. Import the traits to call
//! `ControllerConfig::from_robot(&cfg)` and `LoopEffects::from_file(&effects)`.

use taut_config::params::Effects;
use taut_rt::kin::LoopEffects;
use taut_rt::motion::{ControllerConfig, ControllerConfigError};
use taut_rt::MAX_CABLES;

/// [`ControllerConfig::from_robot`]: the controller's numbers from the robot's configuration.
pub trait FromRobot: Sized {
    /// Resolves the configuration. Fails (with the key to set) when no workspace box is given and
    /// none can be derived from nominal anchors.
    fn from_robot(cfg: &taut_config::RobotConfig) -> Result<Self, ControllerConfigError>;
}

/// [`LoopEffects::from_file`]: the loop's effects from a parameter file's.
pub trait EffectsFromFile {
    /// From a parameter file's effects (validated there: [`Effects::check`]); absent effects
    /// are off, values for cables beyond `MAX_CABLES` ignored.
    fn from_file(e: &Effects) -> LoopEffects;
}

impl EffectsFromFile for LoopEffects {
    fn from_file(e: &Effects) -> LoopEffects {
        LoopEffects::from_values(
            e.ea_n.as_deref(),
            e.drum_scale.as_deref(),
            e.drum_buildup_per_m.as_deref(),
            e.pulley_radius_m.as_deref(),
            e.backlash_m.as_deref(),
            e.time_offset_s,
        )
        .with_deflection(e.compliance_m_per_n.as_deref())
        .with_tension_side(e.loadcell_gain.as_deref(), e.friction_mu_theta.as_deref())
    }
}

impl FromRobot for ControllerConfig {
    fn from_robot(cfg: &taut_config::RobotConfig) -> Result<ControllerConfig, ControllerConfigError> {
        let n = cfg.cables.len();
        if n > MAX_CABLES {
            return Err(ControllerConfigError::TooManyCables { n });
        }
        let m = &cfg.motion;
        let s = &cfg.safety;
        let workspace = match (m.workspace_min_m, m.workspace_max_m) {
            (Some(lo), Some(hi)) => [lo, hi],
            _ => {
                let anchors = cfg.anchors().ok_or(ControllerConfigError::NoWorkspace)?;
                let mut lo = [f64::INFINITY; 3];
                let mut hi = [f64::NEG_INFINITY; 3];
                for a in &anchors {
                    for i in 0..3 {
                        lo[i] = lo[i].min(a[i]);
                        hi[i] = hi[i].max(a[i]);
                    }
                }
                // Middle half of the anchors' footprint, 1 m to 3 m below the lowest anchor.
                let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
                let h = [(hi[0] - lo[0]) / 4.0, (hi[1] - lo[1]) / 4.0];
                [[c[0] - h[0], c[1] - h[1], lo[2] - 3.0], [c[0] + h[0], c[1] + h[1], lo[2] - 1.0]]
            }
        };
        let mut node_ids = [0u8; MAX_CABLES];
        let mut follower = [false; MAX_CABLES];
        for (j, c) in cfg.cables.iter().enumerate() {
            node_ids[j] = c.drive.as_ref().map_or(j as u8 + 1, |d| d.node_id);
            // A point mass is fixed by three cables; the others follow in torque mode so that
            // errors in the parameters do not make position-controlled cables fight.
            follower[j] = taut_config::followers::follows_in_operation(j);
        }
        let mut phases = [[0usize; 3]; 3];
        for (k, p) in m.init_phases.iter().take(3).enumerate() {
            phases[k] = *p;
        }
        Ok(ControllerConfig {
            n,
            node_ids,
            follower,
            follower_tension_n: m.init_follower_tension_n.max(s.loose_tension_n * 2.0),
            mass_kg: cfg.robot.mass_kg,
            excitation_tension_swing_n: if cfg.calibration.effects.iter().any(|e| e == "elasticity") {
                taut_rt::motion::EXCITATION_TENSION_SWING_N.min(0.5 * s.max_tension_n)
            } else {
                0.0
            },
            phases,
            reel_m: m.init_reel_m,
            reel_speed_m_s: m.init_reel_speed_m_s,
            reel_accel_m_s2: m.init_reel_accel_m_s2,
            init_follower_tension_n: m.init_follower_tension_n,
            settle_s: m.init_settle_s,
            wiring_check: m.init_wiring_check,
            held_min_tension_n: 2.0 * cfg.calibration.min_tension_n,
            enable_timeout_s: m.enable_timeout_s,
            excitation_s: m.excitation_s,
            excitation_speed_m_s: m.excitation_speed_m_s,
            workspace,
            swap_ramp_s: m.swap_ramp_s,
            move_speed_m_s: m.move_speed_m_s,
            max_tension_n: s.max_tension_n,
            loose_tension_n: s.loose_tension_n,
            tension_max_age_s: if cfg.loadcells.is_some() || cfg.cables.iter().any(|c| c.loadcell.is_some()) {
                s.tension_max_age_s
            } else {
                f64::INFINITY
            },
            tracker_max_age_s: s.tracker_max_age_s,
            max_cable_speed_m_s: s.max_cable_speed_m_s,
            workspace_margin_m: s.workspace_margin_m,
            dwell: None,
            tour: None,
            nominal_statics: cfg.anchors().map(|a| {
                let mut p =
                    taut_rt::kin::LoopParams::new(0, &a, &vec![0.0; n], &cfg.platform_points()).with_pulley_axes(&cfg.pulley_axes());
                // Directions only: the offsets are unknown until the initialisation.
                p.valid = true;
                p
            }),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop's fixed dwell table holds every plan the configuration accepts.
    #[test]
    fn the_loops_dwell_table_matches_the_configurations_bound() {
        assert_eq!(taut_rt::motion::MAX_DWELL_POSES, taut_config::runtime::MAX_DWELL_POSES);
        assert_eq!(taut_rt::MAX_CABLES, taut_config::geometry::MAX_CABLES);
    }

    #[test]
    fn a_parameter_files_effects_become_the_loops() {
        let file = Effects {
            ea_n: Some(vec![20_000.0, 0.0, 40_000.0]),
            drum_scale: Some(vec![1.003, 1.0, 0.998]),
            pulley_radius_m: Some(vec![0.0, 0.05, 0.0]),
            backlash_m: Some(vec![0.001, 0.0, 0.0]),
            time_offset_s: Some(0.004),
            ..Effects::default()
        };
        let e = LoopEffects::from_file(&file);
        assert_eq!(e.compliance[..3], [1.0 / 20_000.0, 0.0, 1.0 / 40_000.0], "EA 0: rigid");
        assert_eq!(e.scale[..4], [1.003, 1.0, 0.998, 1.0], "cables beyond the file's: off");
        assert_eq!(e.pulley_r[1], 0.05);
        assert_eq!(e.backlash[0], 0.001);
        assert_eq!(e.time_offset_s, 0.004);
        assert!(LoopEffects::from_file(&Effects::default()).is_none());
    }
}
