//! The library of physical effects the ideal model `l = |X - A| + L0` leaves out.
//!
//! Each effect is one module implementing [`EffectModel`]: its name, its parameter with units
//! and the range where it is physics, which cables share it, its start value, what it needs
//! from a recording, what it mimics and the measurement that separates them, and where the
//! running robot's parameter file keeps it. [`Effect`] is the closed set of names the reports,
//! the JSON output and the parameter files use; [`Effect::model`] is the one place that maps a
//! name to its module. A fitted value is physics only inside [`EffectModel::internal_range`]:
//! a fit that lands outside is not claimed.
//!
//! The modelled encoder reading of cable `j` at sample `i` is built up in this order (the
//! prediction and its derivatives, the data it reads and the joint fit: [`model`]):
//!
//! ```text
//! X      = P(t_i - delta) + R b_j                      time-offset: delta > 0, encoder lags tracker
//! G      = |X - A|          or  r*beta + sqrt(|X - C|^2 - r^2)      pulley (swivel, radius r)
//! G     += s(a, h, w, T) - sqrt(a^2 + h^2)             sag: catenary arc minus chord
//! U      = G / (1 + T c),   c = 1/EA                   elasticity: encoder sees unstretched length
//! U     -= k T                                         compliance: winch, frame or anchor deflection
//! B      = 2 U / (1 + sqrt(1 + 4 q U))                 drum build-up: B + q B^2 = U
//! v      = (1 + k) B + L0                              scale k = scale - 1
//! l_hat  = play(v; w_b)                                backlash: play operator of width w_b
//! ```
//!
//! The play runs over the samples in time order (see [`model::PlayState`]): the
//! reading stays put while `v` moves inside `[l_hat - w_b/2, l_hat + w_b/2]` and is pushed
//! along once `v` leaves it, so `l_hat_i = v_c - sigma w_b / 2` with `c` the last sample that
//! pushed and `sigma = +1` paying out, `-1` reeling in.
//!
//! Loose cables (`slack`) are not modelled: their samples are found and excluded.
//!
//! Effects that change the load cells' readings or the platform's force balance, not a length
//! (load-cell gain, friction, inertia), are the library's [`tension`] side.
//!
//! Each module also holds its stage of the prediction with its derivatives on the library's
//! [`Path`] and [`Unstretched`] ([`pulley::path`], [`sag::add_excess`], [`stretch::unstretch`],
//! [`compliance::deflect`], [`drum_buildup::encoder_length`], [`drum_scale::factor`]); [`model::Joint`] composes them in the order above, and the time
//! offset and the play, which act on the sample series rather than on one reading, live there.
//!
//! Adding an effect: a module here implementing [`EffectModel`] with its stage and its test; a
//! variant of [`Effect`], its line in [`Effect::model`] and in [`Effect::ALL`]; the stage's
//! call in [`model::Joint`]; its key in the parameter file (`taut_config::params::Effects`,
//! which [`EffectModel::store`] and [`EffectModel::start_from`] read and write); and its
//! physics in the simulator.

pub mod backlash;
pub mod compliance;
pub mod drum_buildup;
pub mod drum_scale;
pub mod model;
pub mod pulley;
pub mod sag;
pub mod slack;
pub mod stretch;
pub mod tension;
pub mod time_offset;

use crate::diagnose::analysis::Regressor;
use taut_config::params::Effects;

pub use sag::{catenary, sag_excess};

/// One effect of the library. Names are the `taut-diagnosis v1` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// Cable stretch `T L / EA` that the encoder does not see.
    Elasticity,
    /// Catenary of a cable with weight per length `w`.
    Sag,
    /// Swivel pulley of radius `r`: wrap and moving exit point.
    Pulley,
    /// Drum radius or encoder scale error per cable.
    Scale,
    /// Encoders and tracker sampled with a delay between them.
    TimeOffset,
    /// Play in the drive train: the reading depends on the direction of motion.
    Backlash,
    /// Drum build-up: the drum's effective radius changes with the wound cable, so the length
    /// is quadratic in the drum's angle.
    DrumBuildup,
    /// Compliance independent of the cable's length: the winch, frame or anchor gives way by
    /// `k T`.
    Compliance,
    /// Loose-cable samples (found and excluded, not modelled).
    Slack,
}

/// Whether an effect has one parameter per cable or one for the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sharing {
    /// One value per cable.
    PerCable,
    /// One value shared by all cables.
    Shared,
}

/// Which end of the cable the load cell measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TensionEnd {
    /// At the anchor / winch (a load cell on the frame).
    Anchor,
    /// At the platform attachment.
    Platform,
}

/// What an effect needs from a recording beyond the tracker poses and the encoder readings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Needs {
    /// Measured tensions (without them the effect's term is zero).
    pub tensions: bool,
    /// The readings in time order (velocities, directions of motion, the play's history).
    pub time_series: bool,
}

/// The cable's path from its anchor to its attachment `X` as the prediction builds it (the
/// geometry and the effects that lengthen it): its length `G`, `dG/dX`, and for the
/// errors-in-variables weights (`model::Eiv`) `dG/dT` and `d^2 G / dT dw`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Path {
    /// `G`, m.
    pub g: f64,
    /// `dG/dX`.
    pub gx: [f64; 3],
    /// `dG/dT`, m/N.
    pub g_t: f64,
    /// `d^2 G / dT dw` (the sag weight `w`).
    pub g_tw: f64,
}

impl Path {
    /// The straight cable `G = |X - A|`.
    pub fn straight(x: [f64; 3], anchor: [f64; 3]) -> Path {
        let d = [x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]];
        let rho = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Path { g: rho, gx: [d[0] / rho, d[1] / rho, d[2] / rho], g_t: 0.0, g_tw: 0.0 }
    }
}

/// The length the encoder sees, `U`, built from a [`Path`] (the elasticity's stage: a rigid
/// cable's `U` is `G`), with its derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unstretched {
    /// `U`, m.
    pub u: f64,
    /// `dU/dG`.
    pub du_dg: f64,
    /// `dU/dc` (the compliance).
    pub du_dc: f64,
    /// `dU/dT` and its derivatives by the compliance and the sag weight.
    pub u_t: f64,
    /// `d^2 U / dT dc`.
    pub u_tc: f64,
    /// `d^2 U / dT dw`.
    pub u_tw: f64,
    /// `d (dU/dT) / dG`.
    pub u_tg: f64,
    /// The path's share of `d (dU/dT) / dX`.
    pub u_tx: [f64; 3],
}

impl Unstretched {
    /// A rigid cable: `U = G`; `g_tx` the path's `d (dG/dT) / dX`.
    pub fn rigid(path: &Path, g_tx: [f64; 3]) -> Unstretched {
        Unstretched { u: path.g, du_dg: 1.0, du_dc: 0.0, u_t: path.g_t, u_tc: 0.0, u_tw: path.g_tw, u_tg: 0.0, u_tx: g_tx }
    }
}

/// The measurement that separates an effect from a shifted anchor (and from a pulley, whose
/// fitted form a shifted anchor mimics).
pub(crate) const ANCHOR_SEPARATION: &str = "poses at large wrap angles (the platform far out, cables near horizontal) separate a swivel pulley from a shifted anchor; or measure the pulley radius or the anchor positions";

/// One physical effect: what the fit, the selection and the reports need to know of it.
///
/// The parameter is handled in an *internal* form, the one the model is smooth and the fit
/// well conditioned in (the compliance `1/EA`, `scale - 1`); [`EffectModel::to_physical`]
/// converts for the reports and the parameter file.
pub trait EffectModel: Sync {
    /// The effect's name in reports, the JSON output and the command line.
    fn id(&self) -> Effect;
    /// The `taut-diagnosis v1` name.
    fn name(&self) -> &'static str;
    /// The parameter's name in the output, with its unit.
    fn parameter(&self) -> &'static str;
    /// The parameter as people write it: a label, a unit and the factor from the reported
    /// value ([`EffectModel::to_physical`], SI) to that unit.
    fn parameter_words(&self) -> (&'static str, &'static str, f64);
    /// One parameter per cable, or one shared.
    fn sharing(&self) -> Sharing;
    /// What it needs from a recording.
    fn needs(&self) -> Needs {
        Needs::default()
    }
    /// Plausible range of the internal parameter: a fit outside it is not physics.
    fn internal_range(&self) -> (f64, f64);
    /// The bounds the fit projects the internal parameter onto (wider than the plausible
    /// range: a fit may cross it and come back; a compliance, weight, radius or play below
    /// zero is not physics, so those are fitted on the boundary).
    fn bounds(&self) -> (f64, f64);
    /// A starting value of the internal parameter.
    fn start(&self) -> f64;
    /// The effects (`None`: the anchors) whose fitted form can stand in for this one on some
    /// recordings, and which are therefore also fitted jointly with it.
    fn mimics(&self) -> &'static [Option<Effect>];
    /// The measurement that separates this effect from `other`, where this module knows one
    /// ([`Effect::separating_measurement`] asks both sides).
    fn separation(&self, _other: Option<Effect>) -> Option<&'static str> {
        None
    }
    /// Internal parameter and its 1-sigma -> reported value and its 1-sigma.
    fn to_physical(&self, x: f64, sigma: f64) -> (f64, f64) {
        (x, sigma)
    }
    /// What the residual follows when this effect is left out, in words.
    fn signature(&self) -> &'static str;
    /// The sign of [`signature`](EffectModel::signature): `-1` where the residual follows the
    /// regressor's negative (a stretch shortens the reading as `T L` grows).
    fn signature_sign(&self) -> f64 {
        1.0
    }
    /// The regressor of [`signature`](EffectModel::signature) in the residual analysis.
    fn regressor(&self) -> Regressor;
    /// The key of the parameter file's `[effects]` table that carries this effect
    /// (`taut_config::params::Effects`); `None`: the running robot does not model it.
    fn parameter_key(&self) -> Option<&'static str> {
        None
    }
    /// The internal start of cable `j` from the running robot's parameters, where they have
    /// one.
    fn start_from(&self, _running: &Effects, _j: usize) -> Option<f64> {
        None
    }
    /// Writes fitted values (physical, one per cable; a robot-wide value repeated) and their
    /// sigmas into the running robot's parameters. `Err`: a note why the running robot does not
    /// take it.
    fn store(&self, _out: &mut Effects, _values: Vec<f64>, _sigmas: Option<Vec<f64>>) -> Result<(), &'static str> {
        Ok(())
    }
}

impl Effect {
    /// The effects that are fitted (everything but `slack`), in a fixed order.
    pub const FITTED: [Effect; 8] = [
        Effect::Elasticity,
        Effect::Sag,
        Effect::Pulley,
        Effect::Scale,
        Effect::TimeOffset,
        Effect::Backlash,
        Effect::DrumBuildup,
        Effect::Compliance,
    ];

    /// Every effect, [`Effect::FITTED`] then `slack`.
    pub const ALL: [Effect; Effect::FITTED.len() + 1] = {
        let mut all = [Effect::Slack; Effect::FITTED.len() + 1];
        let mut i = 0;
        while i < Effect::FITTED.len() {
            all[i] = Effect::FITTED[i];
            i += 1;
        }
        all
    };

    /// The effect's module.
    pub fn model(self) -> &'static dyn EffectModel {
        match self {
            Effect::Elasticity => &stretch::Stretch,
            Effect::Sag => &sag::Sag,
            Effect::Pulley => &pulley::Pulley,
            Effect::Scale => &drum_scale::DrumScale,
            Effect::TimeOffset => &time_offset::TimeOffset,
            Effect::Backlash => &backlash::Backlash,
            Effect::DrumBuildup => &drum_buildup::DrumBuildup,
            Effect::Compliance => &compliance::Compliance,
            Effect::Slack => &slack::Slack,
        }
    }

    /// The name in the `taut-diagnosis v1` output.
    pub fn name(self) -> &'static str {
        self.model().name()
    }

    /// The parameter name in the output.
    pub fn parameter(self) -> &'static str {
        self.model().parameter()
    }

    /// Needs measured tensions.
    pub fn needs_tension(self) -> bool {
        self.model().needs().tensions
    }

    /// One parameter per cable, or one shared.
    pub fn sharing(self) -> Sharing {
        self.model().sharing()
    }

    /// Plausible range of the *internal* parameter ([`EffectModel::internal_range`]).
    pub fn internal_range(self) -> (f64, f64) {
        self.model().internal_range()
    }

    /// The effects (`None`: the anchors) whose fitted form can stand in for this one.
    pub fn mimics(self) -> &'static [Option<Effect>] {
        self.model().mimics()
    }

    /// The measurement that would separate this effect from `other` (`None`: a shifted anchor)
    /// when a recording cannot: what either effect's module knows, else a broader recording.
    pub fn separating_measurement(self, other: Option<Effect>) -> &'static str {
        let known = match other {
            None => self.model().separation(None).or(Some(ANCHOR_SEPARATION)),
            Some(o) => self.model().separation(Some(o)).or_else(|| o.model().separation(Some(self))),
        };
        known.unwrap_or("a recording over more of the workspace, at several speeds and tensions, would separate them")
    }

    /// Internal parameter -> reported value and its 1-sigma.
    pub fn to_physical(self, x: f64, sigma: f64) -> (f64, f64) {
        self.model().to_physical(x, sigma)
    }

    /// A starting value of the internal parameter for the fit.
    pub fn start(self) -> f64 {
        self.model().start()
    }

    /// What the residual follows when this effect is left out, in words.
    pub fn signature(self) -> &'static str {
        self.model().signature()
    }

    /// Parses a `taut-diagnosis v1` name, or an older name the configuration and the command
    /// line still accept (`drum-buildup`: `taut_config::EFFECT_ALIASES`).
    pub fn from_name(s: &str) -> Option<Effect> {
        let s = taut_config::canonical_effect_name(s);
        Effect::ALL.into_iter().find(|e| e.name() == s)
    }

    /// Position in [`Effect::ALL`] (for tables indexed by effect).
    pub fn index(self) -> usize {
        self as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for e in Effect::ALL {
            assert_eq!(Effect::from_name(e.name()), Some(e));
            assert_eq!(e.model().id(), e);
            assert_eq!(Effect::ALL[e.index()], e);
        }
        assert_eq!(Effect::TimeOffset.name(), "time-offset");
        assert_eq!(Effect::DrumBuildup.name(), "spool-buildup");
        assert_eq!(Effect::from_name("drum-buildup"), Some(Effect::DrumBuildup), "the old name is still read");
        assert_eq!(Effect::from_name("compliance"), Some(Effect::Compliance));
    }

    /// Every fitted effect starts inside its bounds and its plausible range inside them too,
    /// and what it mimics mimics it back (or is the anchors).
    #[test]
    fn ranges_and_mimics_are_consistent() {
        for e in Effect::FITTED {
            let (lo, hi) = e.model().bounds();
            let (plo, phi) = e.internal_range();
            assert!(lo <= plo && phi <= hi, "{e:?}");
            assert!(lo <= e.start() && e.start() <= hi, "{e:?}");
            for m in e.mimics().iter().flatten() {
                assert!(m.mimics().contains(&Some(e)), "{e:?} / {m:?}");
            }
        }
    }

    /// An effect with a parameter-file key writes that key (and no other) into the running
    /// robot's parameters, and the file knows its range; the others are refused by `store`.
    #[test]
    fn parameter_file_keys_match_what_store_writes() {
        for e in Effect::ALL {
            let mut out = Effects::default();
            let stored = e.model().store(&mut out, vec![0.01; 4], None);
            match e.model().parameter_key() {
                Some(key) => {
                    assert!(stored.is_ok(), "{e:?}");
                    assert_eq!(out.names(), vec![e.name()], "{e:?}");
                    assert!(taut_config::params::EFFECT_RANGES.iter().any(|r| r.0 == key), "{key}");
                }
                None => assert!(out.is_empty(), "{e:?}"),
            }
        }
    }

    #[test]
    fn separating_measurements_are_symmetric() {
        for a in Effect::FITTED {
            for b in Effect::FITTED {
                assert_eq!(a.separating_measurement(Some(b)), b.separating_measurement(Some(a)), "{a:?} / {b:?}");
            }
        }
    }
}
