//! Parameters as the loop holds them, and the inverse kinematics it runs every cycle.
//!
//! Model (as in `calib`): encoder length `l_j = |P + b_j - A_j| + L0_j` for a platform at `P`
//! without rotation, `b_j` the attachment point in the platform frame, `A_j` the anchor; with
//! the effects of a `taut-params` file ([`LoopEffects`]; the formulas are `taut_model`'s, the
//! ones the calibration fits, `taut_calib::diagnose::effects`):
//!
//! ```text
//! G_j = |X - A_j|, or over a swivel pulley of radius r_j (swivel axis u_j through A_j, from
//!       the configuration, vertical by default): r_j beta + sqrt(|X - C_j|^2 - r_j^2)
//! U_j = G_j / (1 + T_j / EA_j) - k_j T_j         k_j: winch, frame and anchor compliance
//! l_j = s_j B_j + L0_j,  B_j + q_j B_j^2 = U_j    s_j: drum scale, q_j: drum build-up,
//!                                                 T_j: cable tension
//! ```
//!
//! The encoder counts unstretched cable: to put the platform at `P` under tension `T_j` the
//! drum must hold `G_j / (1 + T_j / EA_j)`, so inverse kinematics needs a tension. The loop
//! passes the measured one (low-passed), or when it is stale the commanded tension of a
//! torque-mode cable or the last measured one (what the cable is expected to carry).
//! Backlash is modelled in the calibration only: inverse kinematics does not compensate it (a
//! position-mode drive closes its loop on the motor side of the play, and the direction of
//! approach is not known when a pose is commanded, so a half-width correction could be wrong
//! by the full width).
//!
//! The tension side (`taut-params v4`): a load cell reads `gain T exp(-mu_theta s(v))` of the
//! cable's tension `T` (its gain, and the capstan friction of the guides between the platform
//! and the cell, whose sign follows the cable's length rate `v`). The loop turns every reading
//! into the cable's tension with [`LoopEffects::cable_tension`] (`taut_model::cell_tension`, the
//! formula the diagnosis fits) before the follower's statics, the inverse kinematics' stretch
//! and the safety limits read it.

use crate::MAX_CABLES;
use taut_model::geometry::{Field, Geometry, GeometryError};

/// The effects the loop models. `Copy`, fixed size; "off" values make the ideal model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopEffects {
    /// Compliance `1 / EA` per cable, 1/N (0: rigid cable).
    pub compliance: [f64; MAX_CABLES],
    /// Encoder scale per cable (1: exact drum).
    pub scale: [f64; MAX_CABLES],
    /// Drum build-up per cable, 1/m (0: none): the drum pays out `b + q b^2` for an encoder
    /// count `b` (`taut_model::buildup_counted`).
    pub buildup: [f64; MAX_CABLES],
    /// Compliance per cable that does not scale with its length (winch, frame or anchor), m/N
    /// (0: rigid): the drum holds `k T` less (`taut_model::deflection_counted`).
    pub deflection: [f64; MAX_CABLES],
    /// Swivel-pulley radius per cable, m (0: the cable leaves from the anchor point).
    pub pulley_r: [f64; MAX_CABLES],
    /// Backlash width per cable, m (calibration only, see the module documentation).
    pub backlash: [f64; MAX_CABLES],
    /// The encoders lag the tracker by this, s (aligns the calibration data).
    pub time_offset_s: f64,
    /// Load-cell gain per cable (1: the cell reads the tension).
    pub cell_gain: [f64; MAX_CABLES],
    /// Capstan friction `mu theta` per cable between the platform and its load cell (0: none).
    pub friction_mu_theta: [f64; MAX_CABLES],
}

impl LoopEffects {
    /// The ideal model.
    pub const NONE: LoopEffects = LoopEffects {
        compliance: [0.0; MAX_CABLES],
        scale: [1.0; MAX_CABLES],
        buildup: [0.0; MAX_CABLES],
        deflection: [0.0; MAX_CABLES],
        pulley_r: [0.0; MAX_CABLES],
        backlash: [0.0; MAX_CABLES],
        time_offset_s: 0.0,
        cell_gain: [1.0; MAX_CABLES],
        friction_mu_theta: [0.0; MAX_CABLES],
    };

    /// From per-cable values as a parameter file holds them (the non-real-time side reads and
    /// validates the file: `taut_io::EffectsFromFile`): stiffness `EA` in N (0 or
    /// negative: rigid), drum scale, drum build-up in 1/m, pulley radius and backlash width in
    /// m; absent effects are off, values for cables beyond `MAX_CABLES` ignored.
    pub fn from_values(
        ea_n: Option<&[f64]>,
        drum_scale: Option<&[f64]>,
        drum_buildup_per_m: Option<&[f64]>,
        pulley_radius_m: Option<&[f64]>,
        backlash_m: Option<&[f64]>,
        time_offset_s: Option<f64>,
    ) -> LoopEffects {
        let mut out = LoopEffects::NONE;
        let copy = |dst: &mut [f64; MAX_CABLES], src: Option<&[f64]>, f: fn(f64) -> f64| {
            if let Some(v) = src {
                for (d, s) in dst.iter_mut().zip(v) {
                    *d = f(*s);
                }
            }
        };
        copy(&mut out.compliance, ea_n, |ea| if ea > 0.0 { 1.0 / ea } else { 0.0 });
        copy(&mut out.scale, drum_scale, |s| s);
        copy(&mut out.buildup, drum_buildup_per_m, |q| q);
        copy(&mut out.pulley_r, pulley_radius_m, |r| r);
        copy(&mut out.backlash, backlash_m, |w| w);
        out.time_offset_s = time_offset_s.unwrap_or(0.0);
        out
    }

    /// The same effects with each cable's length-independent compliance in m/N as a parameter
    /// file holds it (absent: 0); values for cables beyond `MAX_CABLES` ignored.
    pub fn with_deflection(mut self, compliance_m_per_n: Option<&[f64]>) -> LoopEffects {
        self.deflection = [0.0; MAX_CABLES];
        for (d, s) in self.deflection.iter_mut().zip(compliance_m_per_n.unwrap_or(&[])) {
            *d = *s;
        }
        self
    }

    /// The same effects with the tension side from per-cable values as a parameter file holds
    /// them: load-cell gain (absent: 1) and friction `mu theta` (absent: 0); values for cables
    /// beyond `MAX_CABLES` ignored.
    pub fn with_tension_side(mut self, loadcell_gain: Option<&[f64]>, friction_mu_theta: Option<&[f64]>) -> LoopEffects {
        self.cell_gain = [1.0; MAX_CABLES];
        self.friction_mu_theta = [0.0; MAX_CABLES];
        for (d, s) in self.cell_gain.iter_mut().zip(loadcell_gain.unwrap_or(&[])) {
            *d = *s;
        }
        for (d, s) in self.friction_mu_theta.iter_mut().zip(friction_mu_theta.unwrap_or(&[])) {
            *d = *s;
        }
        self
    }

    /// True if a load cell's reading is not its cable's tension (a gain other than 1, or
    /// friction).
    pub fn corrects_tensions(&self) -> bool {
        self.cell_gain.iter().any(|&g| g != 1.0) || self.friction_mu_theta.iter().any(|&c| c != 0.0)
    }

    /// Cable `j`'s tension from its load cell's reading `reading_n` (N) while the cable's length
    /// changes at `v_m_s` (m/s, > 0 paying out; not finite: unknown, taken as at rest): the
    /// reading without the cell's gain and the guides' friction (`taut_model::cell_tension`).
    /// The reading itself, bit for bit, at gain 1 without friction. Allocates nothing.
    #[inline]
    pub fn cable_tension(&self, j: usize, reading_n: f64, v_m_s: f64) -> f64 {
        taut_model::cell_tension(reading_n, self.cell_gain[j], self.friction_mu_theta[j], v_m_s)
    }

    /// True if nothing is modelled beyond the ideal model.
    pub fn is_none(&self) -> bool {
        *self == LoopEffects::NONE
    }
}

/// The kinematic parameters the loop uses. `Copy` and fixed size, so publishing one through the
/// triple buffer never allocates or frees on the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopParams {
    /// Increases with every accepted set; 0 before any calibration.
    pub version: u64,
    /// Number of cables.
    pub n: usize,
    /// Anchors `A_j`, m.
    pub anchors: [[f64; 3]; MAX_CABLES],
    /// Encoder offsets `L0_j`, m.
    pub l0: [f64; MAX_CABLES],
    /// Platform attachment points `b_j`, m.
    pub platform: [[f64; 3]; MAX_CABLES],
    /// Unit vector of each cable's swivel-pulley axis, pointing from the anchor towards the
    /// winch (configuration, `[[cable]] pulley_axis`; [`taut_model::VERTICAL_AXIS`] by default).
    /// Used where a pulley radius is modelled ([`LoopEffects::pulley_r`]).
    pub pulley_axis: [[f64; 3]; MAX_CABLES],
    /// False until the loop may use these for inverse kinematics (no estimate yet).
    pub valid: bool,
    /// The modelled effects ([`LoopEffects::NONE`]: the ideal model).
    pub effects: LoopEffects,
}

impl LoopParams {
    /// Parameters of `n` cables that are not usable yet.
    pub fn invalid(n: usize) -> LoopParams {
        LoopParams {
            version: 0,
            n,
            anchors: [[0.0; 3]; MAX_CABLES],
            l0: [0.0; MAX_CABLES],
            platform: [[0.0; 3]; MAX_CABLES],
            pulley_axis: [taut_model::VERTICAL_AXIS; MAX_CABLES],
            valid: false,
            effects: LoopEffects::NONE,
        }
    }

    /// Usable parameters from slices.
    pub fn new(version: u64, anchors: &[[f64; 3]], l0: &[f64], platform: &[[f64; 3]]) -> LoopParams {
        let n = anchors.len();
        assert!(n <= MAX_CABLES && l0.len() == n && platform.len() == n, "one anchor, offset and platform point per cable");
        let mut p = LoopParams::invalid(n);
        p.version = version;
        p.anchors[..n].copy_from_slice(anchors);
        p.l0[..n].copy_from_slice(l0);
        p.platform[..n].copy_from_slice(platform);
        p.valid = true;
        p
    }

    /// The loop's form of a calibrated [`Geometry`] with the platform points `b_j` (from the
    /// configuration): the one conversion from the shared type. Runs on the calibrator thread or
    /// at start-up, never in the loop; it copies into the fixed arrays and allocates nothing.
    /// Refuses (naming the cable and field) a geometry that [`Geometry::check`] refuses, more
    /// than [`MAX_CABLES`] cables, or platform points of another count or not finite.
    pub fn from_geometry(version: u64, geometry: &Geometry, platform: &[[f64; 3]]) -> Result<LoopParams, GeometryError> {
        geometry.check()?;
        let n = geometry.n_cables();
        if n > MAX_CABLES {
            return Err(GeometryError::TooManyCables { n, max: MAX_CABLES });
        }
        if platform.len() != n {
            return Err(GeometryError::Length { field: Field::Platform, len: platform.len(), n });
        }
        if let Some(cable) = platform.iter().position(|b| !b.iter().all(|v| v.is_finite())) {
            return Err(GeometryError::NotFinite { cable, field: Field::Platform });
        }
        Ok(LoopParams::new(version, &geometry.anchors, &geometry.l0, platform))
    }

    /// The anchors and offsets back in the shared type (allocates: for reports and the
    /// calibrator thread, never the loop).
    pub fn geometry(&self) -> Geometry {
        Geometry { anchors: self.anchors[..self.n].to_vec(), l0: self.l0[..self.n].to_vec() }
    }

    /// The same parameters with the swivel-pulley axes `axes` (unit vectors, one per cable, from
    /// the configuration: `taut_config::RobotConfig::pulley_axes`); cables beyond `axes` keep
    /// theirs. Allocates nothing.
    pub fn with_pulley_axes(mut self, axes: &[[f64; 3]]) -> LoopParams {
        for (d, a) in self.pulley_axis.iter_mut().zip(axes) {
            *d = *a;
        }
        self
    }

    /// The same parameters with `effects`.
    pub fn with_effects(mut self, effects: LoopEffects) -> LoopParams {
        self.effects = effects;
        self
    }

    /// Encoder length of cable `j` for the platform at `p` with the cable unloaded (no
    /// stretch), m.
    #[inline]
    pub fn length(&self, j: usize, p: &[f64; 3]) -> f64 {
        self.length_at(j, p, 0.0)
    }

    /// Encoder length of cable `j` for the platform at `p` with the cable under `tension_n`
    /// (not finite or negative: no stretch), m. Allocates nothing.
    #[inline]
    pub fn length_at(&self, j: usize, p: &[f64; 3], tension_n: f64) -> f64 {
        let b = &self.platform[j];
        let x = [p[0] + b[0], p[1] + b[1], p[2] + b[2]];
        let e = &self.effects;
        // The unstretched length (scale 1, no offset: `u` itself), less the winch's give,
        // counted on the drum, read.
        let pulley = taut_model::SwivelPulley { r: e.pulley_r[j], axis: self.pulley_axis[j] };
        let u = taut_model::cable_length(x, self.anchors[j], pulley, e.compliance[j], tension_n, 1.0, 0.0);
        let u = taut_model::deflection_counted(u, e.deflection[j], tension_n);
        taut_model::reading(e.scale[j], taut_model::buildup_counted(u, e.buildup[j]), self.l0[j])
    }

    /// Encoder lengths of every cable for the platform at `p` (unloaded cables), into `out`.
    #[inline]
    pub fn lengths(&self, p: &[f64; 3], out: &mut [f64; MAX_CABLES]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = self.length(j, p);
        }
    }

    /// Encoder lengths of every cable for the platform at `p` under `tension_n`, into `out`.
    #[inline]
    pub fn lengths_at(&self, p: &[f64; 3], tension_n: &[f64; MAX_CABLES], out: &mut [f64; MAX_CABLES]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = self.length_at(j, p, tension_n[j]);
        }
    }

    /// Root-mean-square co-registration error (measured minus modelled length) over samples with
    /// a tracker position and, where tensions are given, only taut cables; `None` without any.
    pub fn coregistration_rms<'a>(
        &self,
        samples: impl Iterator<Item = (&'a [f64; 3], &'a [f64], Option<&'a [f64]>)>,
        min_tension_n: f64,
    ) -> Option<f64> {
        let (mut sum, mut count) = (0.0, 0usize);
        for (p, l, f) in samples {
            for j in 0..self.n {
                if let Some(e) = self.coregistration_error(j, p, l, f, min_tension_n) {
                    sum += e * e;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| (sum / count as f64).sqrt())
    }

    /// Measured minus modelled length of cable `j` at pose `p`; `None` without a pose, a
    /// length, or with a tension below `min_tension_n` (loose cable).
    pub fn coregistration_error(&self, j: usize, p: &[f64; 3], l: &[f64], f: Option<&[f64]>, min_tension_n: f64) -> Option<f64> {
        let usable = p.iter().all(|x| x.is_finite()) && l[j].is_finite() && f.is_none_or(|f| f[j] >= min_tension_n);
        usable.then(|| l[j] - self.length_at(j, p, f.map_or(0.0, |f| f[j])))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_follow_the_model() {
        let p = LoopParams::new(1, &[[0.0, 0.0, 4.0], [3.0, 0.0, 4.0], [0.0, 4.0, 4.0]], &[0.1, 0.2, 0.0], &[[0.0; 3]; 3]);
        let mut out = [0.0; MAX_CABLES];
        p.lengths(&[0.0, 0.0, 0.0], &mut out);
        assert!((out[0] - 4.1).abs() < 1e-12);
        assert!((out[1] - 5.2).abs() < 1e-12);
        assert!((out[2] - 32f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn effects_stretch_scale_and_wrap_the_commanded_length() {
        let a = [[0.0, 0.0, 4.0], [3.0, 0.0, 4.0], [0.0, 4.0, 4.0]];
        let ideal = LoopParams::new(1, &a, &[0.1, 0.2, 0.0], &[[0.0; 3]; 3]);
        let effects = LoopEffects::from_values(
            Some(&[20_000.0; 3]),
            Some(&[1.003, 1.0, 0.998]),
            Some(&[0.0, 0.0, -0.004]),
            Some(&[0.0, 0.05, 0.0]),
            None,
            None,
        );
        let p = ideal.with_effects(effects);
        let x = [0.5, 0.5, 1.0];
        // Cable 0: stretch at 100 N and the scale, written out.
        let g = ideal.length(0, &x) - 0.1;
        let want = 1.003 * (g / (1.0 + 100.0 / 20_000.0)) + 0.1;
        assert!((p.length_at(0, &x, 100.0) - want).abs() < 1e-12);
        // No tension: no stretch; a NaN tension is none.
        assert!((p.length_at(0, &x, f64::NAN) - (1.003 * g + 0.1)).abs() < 1e-12);
        // Cable 1 over a 5 cm pulley: the path is longer than the straight line (the wrap), by
        // less than the radius.
        let extra = p.length_at(1, &x, 0.0) - ideal.length(1, &x);
        assert!(extra > 0.0 && extra < 0.05, "{extra}");
        // Cable 2 on a drum with build-up: the count b pays out b + q b^2 = the unstretched
        // length, then the scale.
        let u = (ideal.length(2, &x) - 0.0) / (1.0 + 50.0 / 20_000.0);
        let b = p.length_at(2, &x, 50.0) / 0.998;
        assert!((b + -0.004 * b * b - u).abs() < 1e-12, "{b} {u}");
        assert!(LoopEffects::from_values(None, None, None, None, None, None).is_none());
        // Cable 0 with a compliant winch as well: 1.5 mm/kN less at 300 N, whatever the length;
        // nothing without a tension; bit for bit the same with a compliance of 0.
        let soft = ideal.with_effects(effects.with_deflection(Some(&[1.5e-6, 0.0])));
        for x in [x, [-0.5, 1.0, 0.2]] {
            let d = (p.length_at(0, &x, 300.0) - soft.length_at(0, &x, 300.0)) / 1.003;
            assert!((d - 4.5e-4).abs() < 1e-12, "{d}");
            assert_eq!(soft.length_at(0, &x, f64::NAN), p.length_at(0, &x, f64::NAN));
            assert_eq!(soft.length_at(1, &x, 300.0).to_bits(), p.length_at(1, &x, 300.0).to_bits());
        }
        assert!(!LoopEffects::NONE.with_deflection(Some(&[1e-6])).is_none());
    }

    #[test]
    fn from_geometry_round_trips_and_refuses_naming_the_cable() {
        let g = Geometry { anchors: vec![[0.0, 0.0, 4.0], [3.0, 0.0, 4.0], [0.0, 4.0, 4.0]], l0: vec![0.1, 0.2, 0.0] };
        let b = [[0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]];
        let p = LoopParams::from_geometry(3, &g, &b).unwrap();
        assert_eq!(p, LoopParams::new(3, &g.anchors, &g.l0, &b));
        assert!(p.valid && p.n == 3 && p.version == 3 && p.effects == LoopEffects::NONE);
        assert_eq!(p.geometry(), g);
        assert_eq!(LoopParams::from_geometry(1, &g, &b[..2]), Err(GeometryError::Length { field: Field::Platform, len: 2, n: 3 }));
        let mut nan = b;
        nan[1][2] = f64::NAN;
        assert_eq!(LoopParams::from_geometry(1, &g, &nan), Err(GeometryError::NotFinite { cable: 1, field: Field::Platform }));
        let bad = Geometry { l0: vec![0.1, f64::INFINITY, 0.0], ..g.clone() };
        assert_eq!(LoopParams::from_geometry(1, &bad, &b), Err(GeometryError::NotFinite { cable: 1, field: Field::Offset }));
        let many = Geometry { anchors: vec![[0.0; 3]; MAX_CABLES + 1], l0: vec![0.0; MAX_CABLES + 1] };
        let e = LoopParams::from_geometry(1, &many, &vec![[0.0; 3]; MAX_CABLES + 1]);
        assert_eq!(e, Err(GeometryError::TooManyCables { n: MAX_CABLES + 1, max: MAX_CABLES }));
    }

    /// The configured swivel axis turns the pulley: with the default (vertical) the commanded
    /// length is bit for bit the vertical model's; with a horizontal axis it is the model's path
    /// about that axis, and the axis does nothing without a radius.
    #[test]
    fn the_pulley_turns_about_the_configured_axis() {
        let a = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let effects = LoopEffects::from_values(None, None, None, Some(&[0.03; 4]), None, None);
        let vertical = LoopParams::new(1, &a, &[0.1; 4], &[[0.0; 3]; 4]).with_effects(effects);
        assert_eq!(vertical.pulley_axis, [taut_model::VERTICAL_AXIS; MAX_CABLES]);
        let out = |j: usize| -> [f64; 3] {
            let n = a[j][0].hypot(a[j][1]);
            [a[j][0] / n, a[j][1] / n, 0.0]
        };
        let axes: Vec<[f64; 3]> = (0..4).map(out).collect();
        let horizontal = vertical.with_pulley_axes(&axes);
        let x = [0.4, -0.3, 1.2];
        for j in 0..4 {
            let want = taut_model::pulley_length(x, a[j], taut_model::VERTICAL_AXIS, 0.03).unwrap().0 + 0.1;
            assert_eq!(vertical.length(j, &x).to_bits(), want.to_bits());
            let want = taut_model::pulley_length(x, a[j], axes[j], 0.03).unwrap().0 + 0.1;
            assert_eq!(horizontal.length(j, &x).to_bits(), want.to_bits());
            // The two mountings differ by millimetres at this pose.
            assert!((horizontal.length(j, &x) - vertical.length(j, &x)).abs() > 1e-3, "cable {j}");
        }
        let ideal = LoopParams::new(1, &a, &[0.1; 4], &[[0.0; 3]; 4]);
        assert_eq!(ideal.with_pulley_axes(&axes).length(0, &x), ideal.length(0, &x));
    }
}
