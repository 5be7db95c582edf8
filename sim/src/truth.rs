//! The ground truth of a simulated robot: where the anchors really are and what the incremental
//! encoders count from.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use taut_config::params::Geometry;
use taut_config::RobotConfig;

use crate::physics::{CableModel, Physics};
use crate::SimError;

/// The true parameters a calibration should recover.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// True anchors (nominal + site error), m.
    pub anchors: Vec<[f64; 3]>,
    /// Encoder offsets: reading = scale x length + `l0`, m.
    pub l0: Vec<f64>,
    /// Platform attachment points `b_j`, platform frame, m.
    pub platform_points: Vec<[f64; 3]>,
    /// Unit vector of each cable's swivel-pulley axis, from the anchor towards the winch (the
    /// configuration's `[[cable]] pulley_axis`, vertical by default). The physics' pulley turns
    /// about it.
    pub pulley_axis: Vec<[f64; 3]>,
    /// Platform mass, kg.
    pub mass_kg: f64,
    /// Encoder scale per cable (1 without a drum radius error).
    pub scale: Vec<f64>,
    /// Load-cell offsets, N (zero without noise).
    pub loadcell_offsets: Vec<f64>,
}

impl Truth {
    /// The true anchors and encoder offsets as the shared geometry type (the one conversion;
    /// the truth holds more: scales, load-cell offsets, mass, platform points).
    pub fn geometry(&self) -> Geometry {
        Geometry { anchors: self.anchors.clone(), l0: self.l0.clone() }
    }

    /// Draws a site: each nominal anchor moved by up to `site_error_m` in a uniformly random
    /// direction (magnitude uniform in [0.1, 1] x `site_error_m`: a quick set-up is off by a few
    /// cm to tens of cm), encoder offsets uniform in +-`l0_range_m`.
    pub fn sample(
        cfg: &RobotConfig,
        physics: &Physics,
        site_error_m: f64,
        l0_range_m: f64,
        rng: &mut ChaCha8Rng,
    ) -> Result<Truth, SimError> {
        let nominal = cfg.anchors().ok_or(SimError::MissingAnchors)?;
        let n = nominal.len();
        let anchors = nominal
            .iter()
            .map(|a| {
                // Uniform direction: rejection sampling in the unit ball, normalised.
                let dir = loop {
                    let v: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
                    let r2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
                    if r2 > 1e-6 && r2 <= 1.0 {
                        let r = r2.sqrt();
                        break [v[0] / r, v[1] / r, v[2] / r];
                    }
                };
                let mag = site_error_m * rng.gen_range(0.1..=1.0);
                [a[0] + mag * dir[0], a[1] + mag * dir[1], a[2] + mag * dir[2]]
            })
            .collect();
        let l0 = (0..n).map(|_| if l0_range_m > 0.0 { rng.gen_range(-l0_range_m..l0_range_m) } else { 0.0 }).collect();
        Ok(Truth {
            anchors,
            l0,
            platform_points: cfg.platform_points(),
            pulley_axis: cfg.pulley_axes(),
            mass_kg: cfg.robot.mass_kg,
            scale: (0..n).map(|j| physics.scale_of(j)).collect(),
            loadcell_offsets: vec![0.0; n],
        })
    }

    /// The cables of this robot with the effects of `physics`: each anchor with its pulley's
    /// axis.
    pub fn cable_models(&self, physics: &Physics) -> Vec<CableModel> {
        self.anchors.iter().enumerate().map(|(j, a)| CableModel::new(*a, self.axis(j), physics)).collect()
    }

    /// Cable `j`'s swivel-pulley axis (vertical when the truth has none for it).
    pub fn axis(&self, j: usize) -> [f64; 3] {
        self.pulley_axis.get(j).copied().unwrap_or([0.0, 0.0, 1.0])
    }

    /// Number of cables.
    pub fn n_cables(&self) -> usize {
        self.anchors.len()
    }

    /// The noise-free encoder reading of cable `j` for an unstretched length `length`.
    pub fn encoder(&self, j: usize, length: f64) -> f64 {
        self.scale[j] * length + self.l0[j]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;
    use rand::SeedableRng;

    #[test]
    fn geometry_is_the_true_anchors_and_offsets() {
        let s = Scenario::aras_cam(3);
        let t = Truth::sample(&s.robot, &s.physics, 0.1, 1.0, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
        let g = t.geometry();
        assert_eq!((g.anchors, g.l0), (t.anchors.clone(), t.l0.clone()));
        assert!(t.geometry().check().is_ok());
    }
}
