//! The tension side of the effect library: effects that change what the load cells read, or
//! what the platform's tensions must balance, without changing any length.
//!
//! A tracker, the fitted geometry and the platform's mass `m` predict what the cable tensions
//! must do: a point-mass platform is in balance when
//!
//! ```text
//! sum_j t_j u_j = m (a - g)          u_j: unit vector from the platform's attachment to cable j's anchor
//! ```
//!
//! With four or more cables the individual tensions are not unique, so the balance's residual
//! (three numbers per row) is what is tested, not each cell. The load cell of cable `j` reads
//!
//! ```text
//! f_j = t_j exp(lambda_j) + o_j      lambda_j = sum of the cell effects' log factors, o_j its offset
//! ```
//!
//! and the balance is written with the corrected tensions `t_j = (f_j - o_j) exp(-lambda_j)`:
//!
//! ```text
//! r = sum_j (f_j - o_j) exp(-lambda_j) u_j  -  m g_up  -  sum of the platform effects' forces
//! ```
//!
//! The offsets `o_j` belong to the baseline (like the encoders' `L0` on the length side). The
//! effects are [`loadcell_gain`] (a log factor per cable), [`friction`] (a log factor per cable
//! whose sign follows the cable's direction of motion) and [`inertia`] (a platform force `m_i a`).
//!
//! This is a sibling of [`super::EffectModel`], not an implementation of it: a length effect is
//! a stage of the encoder prediction (it acts on the library's `Path` and `Unstretched`, is
//! tested on length residuals and has a length regressor), while a tension effect changes the
//! load-cell reading or the platform's force balance and is tested on the balance residual in
//! newtons. The two share the held-out test, its error rate and the family-wise count
//! (`crate::diagnose::tension`).

pub mod friction;
pub mod inertia;
pub mod loadcell_gain;

use super::Sharing;

/// One effect of the tension side. Names are the `taut-diagnosis v1` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TensionEffect {
    /// A load cell's gain differs from 1 by a few percent.
    LoadcellGain,
    /// Friction in pulleys and guides between the cable and its cell at the winch: the cell
    /// reads more while the cable reels in than while it pays out (capstan factor).
    Friction,
    /// The platform's inertia: the tensions balance `m (a - g)`, not `-m g`.
    Inertia,
}

/// One row of the balance: what a tension effect may read.
#[derive(Debug, Clone, PartialEq)]
pub struct BalanceRow {
    /// Sample time, s.
    pub t: f64,
    /// The platform's acceleration from the tracker's path (local polynomial), m/s^2.
    pub a: [f64; 3],
    /// Its variance per axis from the tracker's noise, (m/s^2)^2.
    pub var_a: f64,
    /// Per cable: unit vector from the platform's attachment to the anchor.
    pub u: Vec<[f64; 3]>,
    /// Per cable: the load cell's reading, N.
    pub f: Vec<f64>,
    /// Per cable: the cable's length rate from the tracker's path, m/s (> 0 paying out).
    pub v: Vec<f64>,
}

/// What a tension effect contributes to the balance for one cable (or the platform).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Term {
    /// A log factor of the cell's reading, `lambda`, and `d lambda / dx`.
    CellLogFactor {
        /// `lambda`.
        value: f64,
        /// `d lambda / dx`.
        d: f64,
    },
    /// A force the platform's tensions must also balance, N, and its derivative by `x`.
    PlatformForce {
        /// The force, N.
        value: [f64; 3],
        /// `d force / dx`.
        d: [f64; 3],
    },
}

/// One tension effect: what the balance's fit, the selection and the reports need to know.
///
/// As on the length side, the parameter is handled in an internal form the fit is well
/// conditioned in (the log gain), converted by [`TensionEffectModel::to_physical`].
pub trait TensionEffectModel: Sync {
    /// The effect.
    fn id(&self) -> TensionEffect;
    /// The `taut-diagnosis v1` name.
    fn name(&self) -> &'static str;
    /// The parameter's name in the output, with its unit.
    fn parameter(&self) -> &'static str;
    /// One parameter per cable, or one for the platform.
    fn sharing(&self) -> Sharing;
    /// Plausible range of the internal parameter: a fit outside it is not physics.
    fn internal_range(&self) -> (f64, f64);
    /// Bounds the fit projects the internal parameter onto.
    fn bounds(&self) -> (f64, f64);
    /// A starting value of the internal parameter.
    fn start(&self) -> f64;
    /// The term of cable `j` (ignored for a platform effect) in row `row` at parameter `x`.
    fn term(&self, x: f64, row: &BalanceRow, j: usize) -> Term;
    /// Internal parameter and its 1-sigma -> reported value and its 1-sigma.
    fn to_physical(&self, x: f64, sigma: f64) -> (f64, f64) {
        (x, sigma)
    }
    /// What else (effects of either side, or the baseline's parameters) can produce the same
    /// balance residual, and what separates them, in words.
    fn mimics(&self) -> &'static [(&'static str, &'static str)];
    /// What the balance residual follows when this effect is left out, in words.
    fn signature(&self) -> &'static str;
}

impl TensionEffect {
    /// Every tension effect, in a fixed order.
    pub const ALL: [TensionEffect; 3] = [TensionEffect::LoadcellGain, TensionEffect::Friction, TensionEffect::Inertia];

    /// The effect's module.
    pub fn model(self) -> &'static dyn TensionEffectModel {
        match self {
            TensionEffect::LoadcellGain => &loadcell_gain::LoadcellGain,
            TensionEffect::Friction => &friction::Friction,
            TensionEffect::Inertia => &inertia::Inertia,
        }
    }

    /// The name in the `taut-diagnosis v1` output.
    pub fn name(self) -> &'static str {
        self.model().name()
    }

    /// Parses a `taut-diagnosis v1` name.
    pub fn from_name(s: &str) -> Option<TensionEffect> {
        TensionEffect::ALL.into_iter().find(|e| e.name() == s)
    }

    /// Parameters it adds for `n` cables.
    pub fn width(self, n: usize) -> usize {
        match self.model().sharing() {
            Sharing::PerCable => n,
            Sharing::Shared => 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_ranges_nest() {
        for e in TensionEffect::ALL {
            assert_eq!(TensionEffect::from_name(e.name()), Some(e));
            assert_eq!(e.model().id(), e);
            let m = e.model();
            let ((lo, hi), (plo, phi)) = (m.bounds(), m.internal_range());
            assert!(lo <= plo && phi <= hi && lo <= m.start() && m.start() <= hi, "{e:?}");
        }
        assert_eq!(TensionEffect::LoadcellGain.name(), "loadcell-gain");
    }

    /// Each term's derivative matches a central difference.
    #[test]
    fn terms_derivatives_match_finite_differences() {
        let row = BalanceRow { t: 0.0, a: [0.3, -1.2, 2.0], var_a: 0.01, u: vec![[0.0, 0.6, 0.8]], f: vec![40.0], v: vec![0.0015] };
        for e in TensionEffect::ALL {
            let x = 0.5 * (e.model().internal_range().0 + e.model().internal_range().1);
            let h = 1e-6;
            let (p, m) = (e.model().term(x + h, &row, 0), e.model().term(x - h, &row, 0));
            match (e.model().term(x, &row, 0), p, m) {
                (Term::CellLogFactor { d, .. }, Term::CellLogFactor { value: vp, .. }, Term::CellLogFactor { value: vm, .. }) => {
                    assert!((d - (vp - vm) / (2.0 * h)).abs() < 1e-6, "{e:?}")
                }
                (Term::PlatformForce { d, .. }, Term::PlatformForce { value: vp, .. }, Term::PlatformForce { value: vm, .. }) => {
                    for k in 0..3 {
                        assert!((d[k] - (vp[k] - vm[k]) / (2.0 * h)).abs() < 1e-6, "{e:?}")
                    }
                }
                _ => panic!("{e:?}: term kinds differ"),
            }
        }
    }
}
