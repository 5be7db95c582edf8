//! The daemon's calibration backend: `taut-calib`'s initialisation and force-aware calibration,
//! then, when the robot models effects (`[calibration] effects`, or the effects of the
//! parameter file given to `taut start --params`), the anchors, offsets and those effects
//! fitted together ([`taut_calib::effect_fit`]). The model is fixed: no effect is added or
//! dropped in the running robot. A fit with effects that fails (diverges, or a value outside
//! its physical range) fails the calibration, and the daemon keeps the running parameters.
//!
//! The file's tension side (`loadcell_gain`, `friction_mu_theta`) is not fitted here: the
//! daemon's recordings are lengths against the tracker, and the gains and friction are
//! measured on the platform's force balance (`taut diagnose --tension-side`). Every estimate
//! carries the file's values unchanged, so the loop keeps correcting its tensions and the
//! rewritten parameter file keeps the keys.

use crate::vocab::{BackendError, Calibrate, Estimate};
use taut_calib::effect_fit::{fit_effects, EffectFitOptions};
use taut_calib::{init, CalibError, CalibOptions, Geometry, Sigmas};
use taut_config::params::{Effects, ParamsFile};
use taut_config::recording::Recording;
use taut_config::RobotConfig;

/// `taut-calib` with the robot's `[calibration]` options.
pub struct TautCalib {
    platform: Vec<[f64; 3]>,
    /// The swivel-pulley axes (`[[cable]] pulley_axis`, unit vectors).
    pulley_axis: Vec<[f64; 3]>,
    nominal: Option<Vec<[f64; 3]>>,
    opts: CalibOptions,
    /// The effects fitted with the anchors and offsets (`taut diagnose` names).
    effects: Vec<String>,
    /// Their values before any calibration (from a parameter file), the fit's start.
    start_effects: Effects,
    /// Without a tracker (`motion.startup = "dwell"`): the self-calibration's options.
    selfcal: Option<taut_calib::selfcal::SelfCalOptions>,
    /// The cables' stretch modelled in the refinement: the stiffness known to its tolerance
    /// (`[calibration] cable_ea_sigma_n` above 0).
    stretch: Option<taut_calib::bundle::Stretch>,
}

impl TautCalib {
    /// From the robot configuration. The daemon validates on its own held-out block, so the
    /// backend holds nothing out.
    pub fn from_config(cfg: &RobotConfig) -> TautCalib {
        let mut opts = CalibOptions::from_config(&cfg.calibration);
        opts.heldout_fraction = 0.0;
        // The design's tolerances, where the configuration gives them: the start-up's and the
        // recalibrations' estimates are maximum a posteriori.
        opts.priors = cfg.priors();
        TautCalib {
            platform: cfg.platform_points(),
            pulley_axis: cfg.pulley_axes(),
            nominal: cfg.anchors(),
            opts,
            effects: cfg.calibration.effects.clone(),
            start_effects: Effects::default(),
            selfcal: crate::notracker::is_dwell(cfg).then(|| taut_calib::selfcal::SelfCalOptions::from_config(cfg)),
            stretch: stretch_of(&cfg.calibration),
        }
    }

    /// Without a tracker: the rest estimate (nominal anchors, offsets from the force balance).
    fn initialise_without_tracker(&self, rec: &Recording, o: &taut_calib::selfcal::SelfCalOptions) -> Result<Estimate, BackendError> {
        let nominal = self.nominal.as_ref().ok_or(taut_calib::selfcal::SelfCalError::NoNominalAnchors)?;
        let r = taut_calib::selfcal::rest::rest_estimate(rec, &self.platform, nominal, o.mass_kg, o.encoder_sigma_m)?;
        Ok(Estimate { model_consistent: None,
            sigma: Sigmas::unknown(r.params.n_cables()),
            geometry: r.params,
            rms_m: f64::NAN,
            observable: true,
            note: format!(
                "rest estimate without a tracker: nominal anchors, platform at [{:.3}, {:.3}, {:.3}] m by the force balance (residual {:.2} N, {} readings)",
                r.position[0], r.position[1], r.position[2], r.residual_n, r.samples
            ),
            effects: Effects::default(),
        })
    }

    /// Without a tracker: `taut_calib::selfcal` on the recorded dwells.
    fn calibrate_without_tracker(&self, rec: &Recording, o: &taut_calib::selfcal::SelfCalOptions) -> Result<Estimate, BackendError> {
        let r = taut_calib::selfcal::calibrate_without_tracker(rec, &self.platform, self.nominal.as_deref(), o)?;
        let frame = match r.frame {
            taut_calib::selfcal::Frame::NominalTranslationYaw => "the nominal anchors' (best translation and rotation about the vertical)",
            taut_calib::selfcal::Frame::NominalRigid => "the nominal anchors' (best translation and rotation)",
            taut_calib::selfcal::Frame::DesignPriors => "the configuration's (fixed by the design's priors)",
        };
        let mut note = format!(
            "{} dwells, {} readings, chi2/dof {:.2}, {} degrees of freedom, dwell-mean variance x{:.1} (encoders) x{:.1} (load cells) for repeated readings, CRB anchor RMS {:.2} mm, {}; frame: {frame}",
            r.dwells.len(),
            r.samples_used,
            r.chi2 / r.dof.max(1) as f64,
            r.dof,
            r.inflation.0,
            r.inflation.1,
            r.anchor_rms_crb_m * 1e3,
            if r.used_tensions { "encoders and load cells" } else { "encoders only" }
        );
        // The design's priors: how much of each parameter came from the recording.
        let shares: Vec<f64> = r.data_share.iter().flatten().copied().filter(|v| v.is_finite()).collect();
        if !shares.is_empty() {
            let (lo, hi) = shares.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
            note.push_str(&format!(
                "; MAP with the design's priors on {} parameters, data shares {:.0}-{:.0} %",
                shares.len(),
                100.0 * lo,
                100.0 * hi
            ));
        }
        // The stretch modelled with the datasheet stiffness (`cable_ea_sigma_n`): named as the
        // refinement with a tracker names it, and carried as the estimate's `elasticity` (the
        // loop then models the stretch the anchors and offsets were fitted with).
        let mut effects = Effects::default();
        if let Some(ea) = &r.cable_ea_n {
            let each: Vec<String> = ea.iter().map(|e| format!("{:.0}±{:.0}", e.value / 1e3, e.sigma / 1e3)).collect();
            note.push_str(&format!("; stretch modelled: EA {} kN", each.join(", ")));
            effects.ea_n = Some(ea.iter().map(|e| e.value).collect());
            effects.ea_sigma_n = Some(ea.iter().map(|e| e.sigma).collect());
        }
        for w in &r.notes {
            note.push_str("; ");
            note.push_str(w);
        }
        if !self.effects.is_empty() {
            note.push_str(&format!("; {} not fitted (needs a tracker)", self.effects.join(", ")));
        }
        Ok(Estimate { model_consistent: None, geometry: r.params, sigma: r.sigma, rms_m: f64::NAN, observable: true, note, effects })
    }

    /// Also models the effects `file` carries, starting from its values (its time offset
    /// aligns the data from the start).
    pub fn with_params(mut self, file: &ParamsFile) -> TautCalib {
        for name in file.effects.names() {
            // Carried, not fitted (see the module documentation).
            if taut_calib::diagnose::TensionEffect::from_name(name).is_some() {
                continue;
            }
            // A known stiffness (`cable_ea_sigma_n`): the refinement models the stretch, and a
            // file written by it carries the fitted EA.
            let refined = name == "elasticity" && self.stretch.is_some();
            if !refined && !self.effects.iter().any(|e| e == name) {
                self.effects.push(name.to_string());
            }
        }
        self.start_effects = file.effects.clone();
        self
    }

    /// The effects modelled (`taut diagnose` names).
    pub fn effects(&self) -> &[String] {
        &self.effects
    }

    /// The effect values a fit starts from: the running estimate's, else the file's.
    fn start_of(&self, running: &Effects) -> Effects {
        let s = &self.start_effects;
        Effects {
            ea_n: running.ea_n.clone().or_else(|| s.ea_n.clone()),
            drum_scale: running.drum_scale.clone().or_else(|| s.drum_scale.clone()),
            pulley_radius_m: running.pulley_radius_m.clone().or_else(|| s.pulley_radius_m.clone()),
            backlash_m: running.backlash_m.clone().or_else(|| s.backlash_m.clone()),
            time_offset_s: running.time_offset_s.or(s.time_offset_s),
            ..Effects::default()
        }
    }

    /// Anchors, offsets and the modelled effects fitted together from the ideal model's
    /// result. The data were aligned by the running time offset: the fitted one is added to it.
    fn fit_with_effects(&self, rec: &Recording, anchors: &[[f64; 3]], l0: &[f64], running: &Effects) -> Result<Estimate, BackendError> {
        let o = EffectFitOptions {
            effects: self.effects.clone(),
            pulley_axis: self.pulley_axis.clone(),
            ..EffectFitOptions::new(&[], self.opts.min_tension_n, self.opts.tracker_sigma_m, self.opts.encoder_sigma_m)
        };
        let start = self.start_of(running);
        let f = fit_effects(rec, &self.platform, anchors, l0, &start, &o)?;
        let mut effects = f.effects;
        if let Some(d) = effects.time_offset_s.as_mut() {
            *d += running.time_offset_s.unwrap_or(0.0);
        }
        effects.check(anchors.len()).map_err(|(key, message)| BackendError::EffectOutOfRange { key, message })?;
        Ok(Estimate {
            model_consistent: None,
            geometry: f.params,
            sigma: f.sigma,
            rms_m: f.rms_m,
            observable: true,
            note: format!(
                "with {} ({} readings, {} iterations){}{}",
                self.effects.join(", "),
                f.readings,
                f.iterations,
                if f.tracker_outliers == 0 { String::new() } else { format!("; {} tracker outliers left out", f.tracker_outliers) },
                if f.rigid.is_empty() { String::new() } else { format!("; no stretch seen on cables {:?}: held rigid", f.rigid) }
            ),
            effects,
        })
    }
}

impl TautCalib {
    /// The errors-in-variables refinement of `taut_calib::bundle`, if it converges near the start
    /// with a tracker residual that matches the tracker's noise.
    fn refine(&self, rec: &Recording, anchors: &[[f64; 3]], l0: &[f64]) -> Option<taut_calib::bundle::BundleResult> {
        let o = taut_calib::bundle::BundleOptions {
            length_sigma_m: crate::excite::bundle_length_sigma_m(self.opts.encoder_sigma_m),
            tracker_sigma_m: self.opts.tracker_sigma_m,
            min_tension_n: self.opts.min_tension_n,
            // The length noise from the residuals, never below the encoders' (see `bundle::refine`).
            length_sigma_floor_m: crate::excite::length_sigma_floor_m(self.opts.encoder_sigma_m),
            stretch: self.stretch,
            ..Default::default()
        };
        let b = taut_calib::bundle::refine(rec, &self.platform, anchors, l0, &o)?;
        let moved = b
            .params
            .anchors
            .iter()
            .zip(anchors)
            .map(|(a, s)| ((a[0] - s[0]).powi(2) + (a[1] - s[1]).powi(2) + (a[2] - s[2]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        let sane = b.params.check().is_ok();
        (sane && moved < 0.5 && b.tracker_rms_m < 3.0 * self.opts.tracker_sigma_m).then_some(b)
    }
}

impl TautCalib {
    /// The estimate with the file's tension side (see the module documentation).
    fn with_tension_side(&self, mut est: Estimate) -> Estimate {
        let s = &self.start_effects;
        est.effects.loadcell_gain = s.loadcell_gain.clone();
        est.effects.loadcell_gain_sigma = s.loadcell_gain_sigma.clone();
        est.effects.friction_mu_theta = s.friction_mu_theta.clone();
        est.effects.friction_mu_theta_sigma = s.friction_mu_theta_sigma.clone();
        est
    }
}

impl Calibrate for TautCalib {
    fn initialise(&mut self, rec: &Recording) -> Result<Estimate, BackendError> {
        self.initialise_lengths(rec).map(|e| self.with_tension_side(e))
    }

    fn calibrate(&mut self, rec: &Recording, init: &Estimate) -> Result<Estimate, BackendError> {
        self.calibrate_lengths(rec, init).map(|e| self.with_tension_side(e))
    }
}

impl TautCalib {
    /// The initial estimate of the length side.
    fn initialise_lengths(&mut self, rec: &Recording) -> Result<Estimate, BackendError> {
        if let Some(o) = &self.selfcal {
            return self.initialise_without_tracker(rec, o);
        }
        let r = init::initialise(rec, &self.platform, &self.opts)?;
        let n = r.params.n_cables();
        let (mut anchors, mut l0) = (r.params.anchors, r.params.l0);
        let mut note = r.method.json_name().to_string();
        // A cable held in fewer than two phases (the followers) gets its anchor from
        // multilateration on the phases' short arcs only, which can be far off. The followers are
        // torque-controlled during the excitation, so their estimate does not steer the motion:
        // start them at the nominal anchor and let the calibration find them.
        if let Some(nominal) = &self.nominal {
            for (j, c) in r.cables.iter().enumerate() {
                if c.source != init::AnchorSource::HeldPhases {
                    anchors[j] = nominal[j];
                    l0[j] = median_offset(rec, &self.platform, j, nominal[j], self.opts.min_tension_n).unwrap_or(l0[j]);
                    note.push_str(&format!("; {}: nominal anchor", taut_config::cable_name(j)));
                }
            }
        }
        // Every taut cable's length at once, with the platform positions as unknowns: the
        // redundant cables (the follower too) pin the geometry better than the tracker alone.
        // Only the file's time offset: it aligns the excitation data the calibration gets.
        // The other effects belong to anchors fitted with them, which the initial estimate's
        // are not; they return with the calibration. The stretch of a known stiffness is
        // fitted with them in the refinement: its EA goes with them (the loop's inverse
        // kinematics and the held-out check model the same stretch).
        let mut effects = Effects { time_offset_s: self.start_effects.time_offset_s, ..Effects::default() };
        if let Some(b) = self.refine(rec, &anchors, &l0) {
            note.push_str(&format!("; refined on all cables ({} samples, errors-in-variables{})", b.samples, stretch_note(&b)));
            with_stretch(&mut effects, &b);
            (anchors, l0) = (b.params.anchors, b.params.l0);
        }
        Ok(Estimate {
            model_consistent: None,
            geometry: Geometry { anchors, l0 },
            sigma: Sigmas::unknown(n),
            rms_m: f64::NAN,
            observable: true,
            note,
            effects,
        })
    }

    /// The calibration of the length side.
    fn calibrate_lengths(&mut self, rec: &Recording, init: &Estimate) -> Result<Estimate, BackendError> {
        if let Some(o) = &self.selfcal {
            return self.calibrate_without_tracker(rec, o);
        }
        let r = match taut_calib::calibrate(rec, &self.platform, &init.geometry, &self.opts) {
            Ok(r) => r,
            Err(e @ CalibError::NotObservable { .. }) => {
                return Ok(Estimate {
                    model_consistent: None,
                    geometry: init.geometry.clone(),
                    sigma: Sigmas::uniform(init.geometry.n_cables(), f64::INFINITY),
                    rms_m: f64::NAN,
                    observable: false,
                    note: e.to_string(),
                    effects: init.effects.clone(),
                })
            }
            Err(e) => return Err(e.into()),
        };
        if !r.was_successful() {
            return Err(BackendError::NotConverged(r.termination));
        }
        // `calibrate` refuses beyond `calibration.max_sigma_m`: what it returns is an estimate,
        // weakly determined parameters included (named in the note).
        let mut weak: Vec<String> = r.weak.iter().map(|w| w.to_string()).collect();
        // Then all taut cables at once with the platform positions as unknowns (see
        // `taut_calib::bundle`): the force-aware fit is its start and its fallback.
        let refined = self.refine(rec, &r.params.anchors, &r.params.l0);
        if let Some(b) = &refined {
            // The refined set's uncertainty is the one published: warn by it, not by the
            // per-cable first pass (which named parameters the refinement determines well).
            weak = taut_calib::WeakParam::of_sigmas(&b.sigma, self.opts.weak_sigma_m).iter().map(|w| w.to_string()).collect();
        }
        let mut effects = Effects { time_offset_s: init.effects.time_offset_s, ..Effects::default() };
        if let Some(b) = &refined {
            with_stretch(&mut effects, b);
        }
        let (geometry, sigma, how) = match refined {
            Some(b) => {
                let how = format!(
                    ", refined on all cables ({} samples, errors-in-variables, length noise {:.3} mm{})",
                    b.samples,
                    b.length_sigma_m * 1e3,
                    stretch_note(&b)
                );
                (b.params, b.sigma, how)
            }
            None => (r.params, r.sigma, String::new()),
        };
        // With effects: all of it again, the effects' parameters with the anchors and offsets
        // (`calibrate` has refused beyond `calibration.max_sigma_m`; the start-up's initial
        // estimate does not come here, see `initialise`).
        if !self.effects.is_empty() {
            let mut est = self.fit_with_effects(rec, &geometry.anchors, &geometry.l0, &init.effects)?;
            let cand = taut_calib::trust::Candidate { params: &est.geometry, sigma: &est.sigma, rms_m: est.rms_m };
            taut_calib::trust::check(&cand, rec, None)?;
            est.note = format!("{} readings{how}; {}", r.samples_used, est.note);
            return Ok(est);
        }
        // Nothing non-finite or absurd is offered as the robot's parameters.
        let cand = taut_calib::trust::Candidate { params: &geometry, sigma: &sigma, rms_m: r.rms_m };
        taut_calib::trust::check(&cand, rec, None)?;
        // A model the held-out data contradict is said first (not refused).
        let check: Vec<String> = r.consistency.filter(|c| !c.consistent).map(|c| c.to_string()).into_iter().collect();
        Ok(Estimate {
            model_consistent: r.consistency.map(|c| c.consistent),
            geometry,
            sigma,
            rms_m: r.rms_m,
            observable: true,
            note: std::iter::once(format!("{} readings{how}", r.samples_used)).chain(check).chain(weak).collect::<Vec<_>>().join("; "),
            effects,
        })
    }
}

/// The refinement's modelled stretch for a note: `, stretch modelled: EA 950±70, ... kN`.
fn stretch_note(b: &taut_calib::bundle::BundleResult) -> String {
    b.ea.as_ref().map_or(String::new(), |ea| {
        format!(
            ", stretch modelled: EA {} kN",
            ea.iter().map(|(v, s)| format!("{:.0}±{:.0}", v / 1e3, s / 1e3)).collect::<Vec<_>>().join(", ")
        )
    })
}

/// The refinement's fitted stiffness as the estimate's `elasticity` effect (the loop then
/// models the stretch the anchors and offsets were fitted with).
fn with_stretch(effects: &mut Effects, b: &taut_calib::bundle::BundleResult) {
    if let Some(ea) = &b.ea {
        effects.ea_n = Some(ea.iter().map(|e| e.0).collect());
        effects.ea_sigma_n = Some(ea.iter().map(|e| e.1).collect());
    }
}

/// The stretch the refinement models: with `cable_ea_sigma_n` above 0 the configured stiffness
/// is a datasheet value (validated below `cable_ea_n`), else none.
fn stretch_of(c: &taut_config::CalibrationConfig) -> Option<taut_calib::bundle::Stretch> {
    (c.cable_ea_sigma_n > 0.0 && c.cable_ea_n > 0.0 && c.cable_ea_n.is_finite())
        .then(|| taut_calib::bundle::Stretch { ea_n: c.cable_ea_n, rel_sigma: c.cable_ea_sigma_n / c.cable_ea_n })
}

/// Median of `l - |p + b - a|` over the taut readings of cable `j`.
fn median_offset(rec: &Recording, platform: &[[f64; 3]], j: usize, a: [f64; 3], min_tension_n: f64) -> Option<f64> {
    let b = platform[j];
    let mut v: Vec<f64> = (0..rec.len())
        .filter(|&i| rec.tensions(i).is_none_or(|f| f[j] >= min_tension_n))
        .filter_map(|i| {
            let p = rec.p[i];
            let l = rec.lengths(i)[j];
            let d = ((p[0] + b[0] - a[0]).powi(2) + (p[1] + b[1] - a[1]).powi(2) + (p[2] + b[2] - a[2]).powi(2)).sqrt();
            (l - d).is_finite().then_some(l - d)
        })
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(|x, y| x.total_cmp(y));
    Some(v[v.len() / 2])
}
