//! Load-cell gain: a cell whose scale differs from its data sheet's by a few percent reads
//! `f = g t + o`. Internal parameter `ln g` per cable (the balance divides the reading by `g`).
//!
//! A gain common to every cell is a platform mass error (`sum_j t_j u_j = m (a - g)` scales with
//! both); only the cells' *differences* in gain are told apart from the mass, and the known mass
//! then fixes the common part. Over a narrow range of tensions a gain is an offset
//! (`g t ~ g t_mid + ...`): the range of tension levels separates them.

use super::{BalanceRow, TensionEffect, TensionEffectModel, Term};
use crate::effects::Sharing;

/// The load-cell gain effect (`loadcell-gain` in the reports).
pub struct LoadcellGain;

impl TensionEffectModel for LoadcellGain {
    fn id(&self) -> TensionEffect {
        TensionEffect::LoadcellGain
    }
    fn name(&self) -> &'static str {
        "loadcell-gain"
    }
    fn parameter(&self) -> &'static str {
        "gain"
    }
    fn sharing(&self) -> Sharing {
        Sharing::PerCable
    }
    /// Gains 0.8 to 1.25: a cell more than 20 % off is a wiring or scaling fault, not a gain.
    fn internal_range(&self) -> (f64, f64) {
        (0.8f64.ln(), 1.25f64.ln())
    }
    fn bounds(&self) -> (f64, f64) {
        (0.5f64.ln(), 2.0f64.ln())
    }
    fn start(&self) -> f64 {
        0.0
    }
    fn term(&self, x: f64, _row: &BalanceRow, _j: usize) -> Term {
        Term::CellLogFactor { value: x, d: 1.0 }
    }
    fn to_physical(&self, x: f64, sigma: f64) -> (f64, f64) {
        (x.exp(), x.exp() * sigma)
    }
    fn mimics(&self) -> &'static [(&'static str, &'static str)] {
        &[
            (
                "platform mass",
                "a gain common to every cell is a mass error; give the platform's weighed mass (only the cells' differences are measured)",
            ),
            (
                "loadcell offset",
                "poses with the same cable at different tension levels (a gain grows with the tension, an offset does not)",
            ),
        ]
    }
    fn signature(&self) -> &'static str {
        "the cell's tension level along its cable's direction"
    }
}
