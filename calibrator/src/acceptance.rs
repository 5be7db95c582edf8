//! Whether a new parameter set may replace the running one: the checks of `validate` (cable
//! count, finite values, anchor and offset changes, 1-sigma bounds, observability) and the
//! held-out comparison's one-sided test (`clearly_worse` at [`HELDOUT_ALPHA`] with
//! `daemon.heldout_tolerance_m`), on batch means of the paired differences along the path.

use crate::heldout::{HeldoutComparison, HeldoutRms};
use crate::vocab::{CalibratorConfig, Estimate, OutcomeKind, Rejection};
use taut_config::recording::Recording;
use taut_rt::kin::LoopParams;

/// One-sided error rate of the held-out comparison: the chance that a new set no more than
/// `daemon.heldout_tolerance_m` worse than the running one is refused (0.1 %).
pub const HELDOUT_ALPHA: f64 = 1e-3;

/// The new set's held-out fit is clearly worse than the running set's: with one-sided
/// confidence `1 - alpha`, its RMS exceeds the running set's by more than `tolerance_m`.
///
/// `d` are paired differences of squared residuals (new minus old) on independent units (batch
/// means, or held-out dwells) and `scale` converts their mean to a difference of mean squares
/// (`sum(d) / scale`). With the running set's RMS `o`, the new RMS exceeds `o + tol` when the mean
/// square difference exceeds `(o + tol)^2 - o^2`; the test refuses when the lower confidence
/// bound of the mean, `mean - t(1 - alpha, k - 1) * se`, is above it. Fewer than two units: no
/// evidence either way, refused (the caller reports which).
pub(crate) fn clearly_worse(d: &[f64], scale: f64, old_rms: f64, tolerance_m: f64, alpha: f64) -> bool {
    let k = d.len();
    if k < 2 {
        return true;
    }
    let m = d.iter().sum::<f64>() / k as f64;
    let var = d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (k - 1) as f64;
    let lower = m - taut_calib::diagnose::select::student_t_upper_quantile(alpha, (k - 1) as f64) * (var / k as f64).sqrt();
    let margin = tolerance_m * (2.0 * old_rms + tolerance_m) * scale / k as f64;
    lower > margin
}

/// True if `new` fits the held-out readings clearly worse than `old` ([`clearly_worse`] at
/// [`HELDOUT_ALPHA`] with `tolerance_m`), on the paired difference of squared residuals over
/// the rows kept by the tracker-outlier rule ([`crate::heldout`]), by batch means.
///
/// The held-out rows are stretches of path: a parameter error projects smoothly along them, so
/// consecutive differences are correlated and their i.i.d. standard error understates the
/// spread. The rows are cut into 20 consecutive batches (fewer with under 40 rows) and each
/// batch's mean difference is one observation.
///
/// A set a few hundredths of a mm worse on the held-out rows differs by an effect of no
/// consequence that the held-out noise and the choice of held-out rows decide; the tolerance
/// makes this a test about an effect that matters. The reported RMS and the test leave out the
/// same tracker-outlier rows.
#[cfg(test)]
pub(crate) fn significantly_worse(
    new: &LoopParams,
    old: &LoopParams,
    rec: &Recording,
    min_tension_n: f64,
    tolerance_m: f64,
    alpha: f64,
) -> bool {
    let cmp = HeldoutComparison::new(new, old, rec, min_tension_n);
    cmp.rms().is_none_or(|r| comparison_worse(&cmp, r.old_m, tolerance_m, alpha))
}

/// [`significantly_worse`] on a comparison already made, with the running set's RMS over the
/// rows kept.
pub(crate) fn comparison_worse(cmp: &HeldoutComparison, old_rms: f64, tolerance_m: f64, alpha: f64) -> bool {
    let rows = cmp.paired_differences();
    let batches = (rows.len() / 2).min(20);
    if batches < 2 {
        return true;
    }
    let means: Vec<f64> = (0..batches)
        .map(|b| {
            let r = &rows[b * rows.len() / batches..(b + 1) * rows.len() / batches];
            r.iter().sum::<f64>() / r.len() as f64
        })
        .collect();
    // The batch means average to the mean square difference: scale = batches.
    clearly_worse(&means, batches as f64, old_rms, tolerance_m, alpha)
}

/// The daemon's acceptance rules (module documentation) for an estimate, given the
/// configuration, the running estimate and the held-out block with the running parameters.
/// Returns the held-out RMS of the new and the running set (NaN for an initial estimate).
pub(crate) fn validate(
    c: &CalibratorConfig,
    current: Option<&Estimate>,
    kind: OutcomeKind,
    est: &Estimate,
    heldout: Option<&(Recording, LoopParams)>,
) -> Result<HeldoutRms, Rejection> {
    let g = &est.geometry;
    if g.anchors.len() != c.n || g.l0.len() != c.n {
        return Err(Rejection::CableCount { anchors: g.anchors.len(), offsets: g.l0.len(), cables: c.n });
    }
    if g.anchors.iter().flatten().chain(&g.l0).any(|v| !v.is_finite()) {
        return Err(Rejection::NonFinite);
    }
    // Unknown (NaN) uncertainty is allowed for an initial estimate; infinite only with the
    // backend's own verdict that the problem is not observable (refused below, with its reason).
    if est.observable && est.sigma.anchors.iter().flatten().chain(&est.sigma.l0).chain([&est.rms_m]).any(|v| v.is_infinite()) {
        return Err(Rejection::InfiniteUncertainty);
    }
    // Anchors, and the zero lengths when there is a previous estimate.
    type Reference = (Vec<[f64; 3]>, Option<Vec<f64>>);
    let reference: Option<Reference> = match kind {
        OutcomeKind::Initial => c.nominal.clone().map(|a| (a, None)),
        OutcomeKind::Calibration => current.map(|e| (e.geometry.anchors.clone(), Some(e.geometry.l0.clone()))),
    };
    let bound = match kind {
        // The nominal anchors are a tape-measure guess: allow twice the change.
        OutcomeKind::Initial => 2.0 * c.max_anchor_change_m,
        OutcomeKind::Calibration => c.max_anchor_change_m,
    };
    if let Some((anchors, l0)) = reference {
        for (j, (a, b)) in est.geometry.anchors.iter().zip(&anchors).enumerate() {
            let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            if d > bound {
                return Err(Rejection::AnchorMoved { cable: j, moved_m: d, bound_m: bound });
            }
        }
        if let Some(l0) = l0 {
            for (j, (a, b)) in est.geometry.l0.iter().zip(&l0).enumerate() {
                if (a - b).abs() > c.max_l0_change_m {
                    return Err(Rejection::OffsetChanged { cable: j, changed_m: (a - b).abs(), bound_m: c.max_l0_change_m });
                }
            }
        }
    }
    if kind == OutcomeKind::Initial {
        return Ok(HeldoutRms::plain(f64::NAN, f64::NAN, 0));
    }
    if !est.observable {
        return Err(Rejection::NotObservable { note: est.note.clone() });
    }
    let worst =
        est.sigma.anchors.iter().flatten().chain(&est.sigma.l0).fold(0.0f64, |m, &s| if s.is_finite() { m.max(s) } else { f64::INFINITY });
    if worst > c.max_sigma_m {
        return Err(Rejection::SigmaTooLarge { worst_m: worst, max_m: c.max_sigma_m });
    }
    let Some((heldout, current)) = heldout else { return Err(Rejection::NoHeldout) };
    if !c.tracker {
        return crate::notracker::heldout_dwells(c, est, heldout, current).map(|(n, o)| HeldoutRms::plain(n, o, 0));
    }
    let new = c.loop_params(0, est).map_err(Rejection::LoopCannotHold)?;
    // Tracker outliers leave both RMS values and the paired test (the same rows).
    let cmp = HeldoutComparison::new(&new, current, heldout, c.min_tension_n);
    match cmp.rms() {
        Some(r) if r.new_m < r.old_m => Ok(r),
        // Both at the tracker's noise floor: the difference is noise. Take the new set unless it
        // is clearly worse by more than the tolerance (paired test on the same readings), so a
        // start-up whose initial estimate was already good still ends with the calibrated set.
        Some(r) if !comparison_worse(&cmp, r.old_m, c.heldout_tolerance_m, HELDOUT_ALPHA) => Ok(r),
        Some(r) => {
            Err(Rejection::HeldoutWorse { new_m: r.new_m, old_m: r.old_m, tolerance_m: c.heldout_tolerance_m, outliers: r.outliers })
        }
        None => Err(Rejection::NoUsableHeldout),
    }
}
