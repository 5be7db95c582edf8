//! Problems of the data that are not physics: frozen readings, tracker outliers and dropouts,
//! clock jumps, dead load cells. They are found before any fitting, reported with where they
//! are, and excluded, so no effect is fitted to explain them.

use taut_config::recording::Recording;

/// What kind of data problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProblemKind {
    /// An encoder repeats the same reading while the platform moves.
    FrozenEncoder,
    /// The tracker repeats the same position while the encoders move.
    FrozenTracker,
    /// A tracker position far from its neighbours.
    TrackerOutlier,
    /// Samples without a tracker position (or orientation).
    TrackerDropout,
    /// Time goes backwards, repeats, or jumps.
    ClockJump,
    /// A load cell that reads nothing (all missing, stuck at zero or constant).
    DeadLoadCell,
    /// Single encoder readings far from their neighbours, or absurd ([`crate::screen`]).
    EncoderSpike,
    /// An encoder step that stays: lost counts ([`crate::screen`]).
    EncoderJump,
    /// A row whose encoder readings all repeat the previous row's exactly while the tracker
    /// moved: the logger wrote a new pose beside old lengths ([`stale_rows`]).
    StaleRow,
    /// Tensions that cannot be: not finite, negative beyond noise, above the maximum
    /// ([`crate::screen`]).
    ImpossibleTension,
}

impl ProblemKind {
    /// Short machine-readable name.
    pub fn name(self) -> &'static str {
        match self {
            ProblemKind::FrozenEncoder => "frozen-encoder",
            ProblemKind::FrozenTracker => "frozen-tracker",
            ProblemKind::TrackerOutlier => "tracker-outlier",
            ProblemKind::TrackerDropout => "tracker-dropout",
            ProblemKind::ClockJump => "clock-jump",
            ProblemKind::DeadLoadCell => "dead-load-cell",
            ProblemKind::EncoderSpike => "encoder-spike",
            ProblemKind::EncoderJump => "encoder-jump",
            ProblemKind::StaleRow => "stale-row",
            ProblemKind::ImpossibleTension => "impossible-tension",
        }
    }
}

/// One data problem and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct DataProblem {
    /// Kind.
    pub kind: ProblemKind,
    /// Cable concerned, if one.
    pub cable: Option<usize>,
    /// Time of the first affected sample, s.
    pub t_start: f64,
    /// Time of the last affected sample, s.
    pub t_end: f64,
    /// Samples affected (and excluded).
    pub samples: usize,
    /// For a person.
    pub description: String,
}

/// Masks that follow from the problems.
#[derive(Debug, Clone)]
pub struct DataMasks {
    /// Row usable at all (position present, not an outlier, not frozen tracker).
    pub row_ok: Vec<bool>,
    /// Cable reading usable (present, not frozen).
    pub cable_ok: Vec<Vec<bool>>,
    /// Load cell of cable j is dead: its tensions must be ignored.
    pub dead_loadcell: Vec<bool>,
    /// Segment id per row: a clock problem or a dropout starts a new segment.
    pub segment: Vec<u32>,
    /// Median sample interval, s.
    pub dt: f64,
}

/// The median of `v` (the upper middle of an even count; NaN for none), reordering `v`.
pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let k = v.len() / 2;
    v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    v[k]
}

/// Runs of `true` in `flags` as (start, end exclusive).
fn runs(flags: &[bool]) -> Vec<(usize, usize)> {
    let mut out = vec![];
    let mut i = 0;
    while i < flags.len() {
        if flags[i] {
            let s = i;
            while i < flags.len() && flags[i] {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

fn summarise(kind: ProblemKind, cable: Option<usize>, t: &[f64], flags: &[bool], what: &str) -> Option<DataProblem> {
    let rs = runs(flags);
    if rs.is_empty() {
        return None;
    }
    let samples: usize = rs.iter().map(|(a, b)| b - a).sum();
    let first = rs[0];
    let last = rs[rs.len() - 1];
    let who = cable.map(|c| format!("{}: ", taut_config::cable_name(c))).unwrap_or_default();
    let places: Vec<String> = rs.iter().take(4).map(|(a, b)| format!("t = {:.2}-{:.2} s", t[*a], t[b - 1])).collect();
    let more = if rs.len() > 4 { format!(" and {} more", rs.len() - 4) } else { String::new() };
    Some(DataProblem {
        kind,
        cable,
        t_start: t[first.0],
        t_end: t[last.1 - 1],
        samples,
        description: format!("{who}{what}: {samples} samples in {} stretch(es) ({}{more}); excluded", rs.len(), places.join(", "),),
    })
}

/// Row `i` of `rec` has no pose (position or orientation missing: a tracker dropout). Such a row
/// is not a row of the fitted data set, in the diagnosis as in the running robot's effect fit
/// ([`crate::effect_fit`]).
pub(crate) fn pose_missing(rec: &Recording, i: usize) -> bool {
    !rec.p[i].iter().all(|v| v.is_finite()) || rec.q.as_ref().is_some_and(|q| !q[i].iter().all(|v| v.is_finite()))
}

/// The tracker outliers of `rec` (the diagnosis's rule, shared with the running robot's effect
/// fit, [`crate::effect_fit`]) and the threshold: `None` with fewer than 7 rows.
///
/// A row's deviation is its distance to the position predicted from the nearest present
/// positions on either side (2 or 3 each; the median of the straight-line interpolations in time
/// between one before and one after, so one outlier among them does not move it); it is an
/// outlier beyond `max(10 x median deviation, 8 tracker_sigma_m, 0.1 mm)` (the median: a robust
/// scale of the same quantity, which includes the motion between samples at low rates). Missing
/// rows are skipped, so an outlier right after a dropout is still caught (a held reading of the
/// play model would otherwise inherit it).
///
/// False exclusions: with Gaussian tracker noise of `s` per axis and the motion between samples
/// interpolated exactly, the deviation is `c s chi(3)` (`c`: 1.1-1.3, the interpolation's own
/// noise), whose median is 1.54 `c s`; the threshold is then at least 10 medians, `chi(3) > 15.4`,
/// a chance below 1e-49 per row; the `8 tracker_sigma_m` floor alone would be `chi(3) > 8 / 1.3 = 6.2`,
/// 2.3e-8 per row (below 3e-3 that one good row of 10^5 is left out), and it is never the binding
/// term under that noise model (10 medians are 15 `c s`).
pub(crate) fn tracker_outliers(rec: &Recording, tracker_sigma_m: f64) -> Option<(Vec<bool>, f64)> {
    let m = rec.len();
    if m < 7 {
        return None;
    }
    let mut dev = vec![f64::NAN; m];
    let present = |i: usize| rec.p[i].iter().all(|v| v.is_finite()) && rec.t[i].is_finite();
    for (i, d) in dev.iter_mut().enumerate() {
        if !present(i) {
            continue;
        }
        let before: Vec<usize> = (i.saturating_sub(12)..i).rev().filter(|&k| present(k) && rec.t[k] < rec.t[i]).take(3).collect();
        let after: Vec<usize> = (i + 1..(i + 13).min(m)).filter(|&k| present(k) && rec.t[k] > rec.t[i]).take(3).collect();
        if before.len() < 2 || after.len() < 2 {
            continue;
        }
        let mut d2 = 0.0;
        for k in 0..3 {
            let mut w: Vec<f64> = before
                .iter()
                .flat_map(|&b| after.iter().map(move |&a| (b, a)))
                .map(|(b, a)| rec.p[b][k] + (rec.t[i] - rec.t[b]) / (rec.t[a] - rec.t[b]) * (rec.p[a][k] - rec.p[b][k]))
                .collect();
            d2 += (rec.p[i][k] - median(&mut w)).powi(2);
        }
        *d = d2.sqrt();
    }
    let mut finite: Vec<f64> = dev.iter().copied().filter(|v| v.is_finite() && *v > 0.0).collect();
    let scale = median(&mut finite);
    let thr = (10.0 * scale).max(8.0 * tracker_sigma_m).max(1e-4);
    Some((dev.iter().map(|&d| d.is_finite() && d > thr).collect(), thr))
}

/// `rec` with the lengths of the rows marked in `rows` set missing (NaN); `None` when no row is
/// marked.
pub fn without_lengths(rec: &Recording, rows: &[bool]) -> Option<Recording> {
    if !rows.iter().any(|r| *r) {
        return None;
    }
    let mut out = rec.clone();
    let n = rec.n_cables;
    for (i, _) in rows.iter().enumerate().filter(|(_, r)| **r) {
        out.l[i * n..(i + 1) * n].iter_mut().for_each(|v| *v = f64::NAN);
    }
    Some(out)
}

/// How far the tracker must move between two rows for a repeat of every encoder reading to be
/// stale rather than a rest: `3 sqrt(2)` tracker sigmas (the distance of two noisy readings of
/// one point is `sqrt(2) s chi(3)`, above this with probability 0.03; a rest row excluded by
/// chance costs one reading of a pose that is measured again), at least 0.1 mm.
pub(crate) fn stale_motion_m(tracker_sigma_m: f64) -> f64 {
    (3.0 * std::f64::consts::SQRT_2 * tracker_sigma_m).max(1e-4)
}

/// How far some encoder must move across a run of repeated readings (from the run's reading to
/// the next different one) for the run to be stale rather than a rest: 20 encoder sigmas, at
/// least 0.2 mm (1 mm at the default 0.05 mm).
pub(crate) fn stale_encoder_step_m(encoder_sigma_m: f64) -> f64 {
    (20.0 * encoder_sigma_m).max(2e-4)
}

/// Longest run of repeated rows (after its first) that the encoders alone call stale
/// ([`stale_rows`]).
const MAX_STALE_RUN: usize = 2;

/// The stale rows of `rec`: row `i` repeats the reading of every cable of the row before it
/// exactly (all finite) while the platform moved, a logger's new pose beside old lengths
/// (their lengths belong to an earlier pose: on a moving platform centimetres off). The
/// platform moved when the tracker moved more than `stale_motion_m` from the first row of the
/// run of repeats that has a pose (a dropout inside the run does not hide it), or, for slow
/// motion that the tracker's noise hides over an interval, when the repeat is at most two rows
/// long and some encoder steps more than `stale_encoder_step_m` out of it (to the next row).
/// The encoders' noise and quantum (0.05 mm, 0.01 mm) make an exact repeat of every cable
/// impossible while the platform moves. A rest of the platform is a repeat without the tracker
/// moving: one of three rows or more is kept; a pause of one or two rows before a motion is
/// left out with the stale rows (it repeats a pose measured the row before, so little is lost).
/// The first row of a run is never stale.
pub fn stale_rows(rec: &Recording, tracker_sigma_m: f64, encoder_sigma_m: f64) -> Vec<bool> {
    let (n, m) = (rec.n_cables, rec.len());
    let thr = stale_motion_m(tracker_sigma_m);
    let step_thr = stale_encoder_step_m(encoder_sigma_m);
    let mut out = vec![false; m];
    if n == 0 {
        return out;
    }
    let same = |a: usize, b: usize| rec.lengths(a).iter().zip(rec.lengths(b)).all(|(x, y)| x.is_finite() && x == y);
    let posed = |i: usize| rec.p[i].iter().all(|v| v.is_finite());
    let mut s = 0;
    while s < m {
        let mut e = s + 1;
        while e < m && same(s, e) {
            e += 1;
        }
        // Rows s..e share one reading; e is the next different row (or the end).
        if e - s > 1 {
            let steps = |a: usize, b: usize| {
                rec.lengths(a).iter().zip(rec.lengths(b)).any(|(x, y)| (x - y).is_finite() && (x - y).abs() > step_thr)
            };
            let stepped = e - s <= MAX_STALE_RUN + 1 && e < m && steps(s, e);
            let first_posed = (s..e).find(|&k| posed(k));
            for i in s + 1..e {
                let moved = first_posed
                    .filter(|&k| k < i && posed(i))
                    .is_some_and(|k| (0..3).map(|c| (rec.p[i][c] - rec.p[k][c]).powi(2)).sum::<f64>().sqrt() > thr);
                out[i] = stepped || moved;
            }
        }
        s = e;
    }
    out
}

/// Finds the data problems of `rec`. `tracker_sigma_m` sets the smallest tracker jump that can be
/// called an outlier.
pub fn detect(rec: &Recording, tracker_sigma_m: f64, encoder_sigma_m: f64) -> (Vec<DataProblem>, DataMasks) {
    detect_screened(rec, tracker_sigma_m, encoder_sigma_m, &[], Some(&[]))
}

/// [`detect`] on a recording the wild-value screen has cleaned: `removed[i]` marks rows whose
/// position the screen removed (already reported as wild), which are excluded but not reported
/// again as tracker dropouts; `stale[i]` marks rows found stale before the screen ([`stale_rows`]
/// of the recording as read, whose lengths the caller then set missing so that the screen does
/// not take them for wild readings), reported and excluded as stale rows with those this finds
/// (`None`: stale rows are neither looked for nor excluded).
pub fn detect_screened(
    rec: &Recording,
    tracker_sigma_m: f64,
    encoder_sigma_m: f64,
    removed: &[bool],
    stale: Option<&[bool]>,
) -> (Vec<DataProblem>, DataMasks) {
    let known_stale = stale;
    let n = rec.n_cables;
    let m = rec.len();
    let mut problems = vec![];
    // Dropouts: position (or orientation) missing.
    let missing: Vec<bool> = (0..m).map(|i| pose_missing(rec, i)).collect();
    let dropout: Vec<bool> = (0..m).map(|i| missing[i] && !removed.get(i).copied().unwrap_or(false)).collect();
    problems.extend(summarise(ProblemKind::TrackerDropout, None, &rec.t, &dropout, "tracker dropout (no position)"));
    let mut row_ok: Vec<bool> = missing.iter().map(|x| !x).collect();

    // Clock.
    let mut dts: Vec<f64> = rec.t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
    let dt = median(&mut dts);
    let mut segment = vec![0u32; m];
    let mut seg = 0;
    let mut clock_events = vec![];
    for i in 1..m {
        let d = rec.t[i] - rec.t[i - 1];
        let bad = !(d > 0.0) || d > 5.0 * dt;
        // A row the screen removed is excluded but does not cut the time series (as an outlier).
        if bad || dropout[i] != dropout[i - 1] {
            seg += 1;
        }
        if bad {
            let moved = (0..3).map(|k| (rec.p[i][k] - rec.p[i - 1][k]).powi(2)).sum::<f64>().sqrt();
            clock_events.push((i, d, moved));
        }
        segment[i] = seg;
    }
    if !clock_events.is_empty() {
        let descr: Vec<String> = clock_events
            .iter()
            .take(4)
            .map(|&(i, d, moved)| {
                if d <= 0.0 {
                    format!(
                        "row {i} at t = {:.3} s goes {} by {:.3} s",
                        rec.t[i],
                        if d < 0.0 { "back" } else { "nowhere (repeated time)" },
                        -d
                    )
                } else if moved.is_finite() && moved < 20.0 * tracker_sigma_m.max(1e-4) {
                    format!("time jumps by {:.3} s at t = {:.3} s while the data continue (clock jump)", d, rec.t[i - 1])
                } else {
                    format!("no samples for {:.3} s after t = {:.3} s (gap)", d, rec.t[i - 1])
                }
            })
            .collect();
        let more = if clock_events.len() > 4 { format!(" and {} more", clock_events.len() - 4) } else { String::new() };
        problems.push(DataProblem {
            kind: ProblemKind::ClockJump,
            cable: None,
            t_start: rec.t[clock_events[0].0],
            t_end: rec.t[clock_events[clock_events.len() - 1].0],
            samples: clock_events.len(),
            description: format!("{}{more}; the time-offset model does not interpolate across them", descr.join("; ")),
        });
        // A sample whose time went backwards or repeated cannot be placed in time: exclude it.
        for &(i, d, _) in &clock_events {
            if d <= 0.0 {
                row_ok[i] = false;
            }
        }
    }

    if let Some((outl, thr)) = tracker_outliers(rec, tracker_sigma_m) {
        if let Some(mut p) = summarise(ProblemKind::TrackerOutlier, None, &rec.t, &outl, "tracker outliers") {
            p.description = format!("{} (more than {:.1} mm from their neighbours)", p.description, thr * 1e3);
            problems.push(p);
        }
        for (o, ok) in outl.iter().zip(row_ok.iter_mut()) {
            if *o {
                *ok = false;
            }
        }
    }

    // Frozen readings: a run of identical values while the other sensor moves.
    let min_run = ((0.1 / dt.max(1e-6)).round() as usize).max(4);
    let moved_thr = (10.0 * tracker_sigma_m).max(5e-3);
    let mut cable_ok = vec![vec![true; m]; n];
    for j in 0..n {
        let mut frozen = vec![false; m];
        let mut i = 0;
        while i < m {
            let v = rec.l[i * n + j];
            let s = i;
            while i + 1 < m && rec.l[(i + 1) * n + j] == v && v.is_finite() {
                i += 1;
            }
            let e = i + 1;
            if e - s >= min_run {
                let moved = (0..3).map(|k| (rec.p[e - 1][k] - rec.p[s][k]).powi(2)).sum::<f64>().sqrt();
                let path: f64 = (s + 1..e)
                    .map(|k| (0..3).map(|c| (rec.p[k][c] - rec.p[k - 1][c]).powi(2)).sum::<f64>().sqrt())
                    .filter(|d| d.is_finite())
                    .sum();
                if moved.max(0.5 * path) > moved_thr {
                    frozen[s..e].iter_mut().for_each(|f| *f = true);
                }
            }
            i += 1;
        }
        for i in 0..m {
            if frozen[i] || !rec.l[i * n + j].is_finite() {
                cable_ok[j][i] = false;
            }
        }
        problems.extend(summarise(
            ProblemKind::FrozenEncoder,
            Some(j),
            &rec.t,
            &frozen,
            "encoder frozen (same reading repeated while the platform moves)",
        ));
    }
    {
        let mut frozen = vec![false; m];
        let mut i = 0;
        while i < m {
            let s = i;
            while i + 1 < m && rec.p[i + 1] == rec.p[s] && rec.p[s][0].is_finite() {
                i += 1;
            }
            let e = i + 1;
            if e - s >= min_run {
                let moved = (0..n).map(|j| (rec.l[(e - 1) * n + j] - rec.l[s * n + j]).abs()).filter(|v| v.is_finite()).fold(0.0, f64::max);
                if moved > moved_thr {
                    frozen[s..e].iter_mut().for_each(|f| *f = true);
                }
            }
            i += 1;
        }
        problems.extend(summarise(
            ProblemKind::FrozenTracker,
            None,
            &rec.t,
            &frozen,
            "tracker frozen (same position repeated while the cables move)",
        ));
        for (f, ok) in frozen.iter().zip(row_ok.iter_mut()) {
            if *f {
                *ok = false;
            }
        }
    }

    // Stale rows: single rows (shorter than a frozen run) whose lengths are the previous row's.
    let mut stale = if known_stale.is_some() { stale_rows(rec, tracker_sigma_m, encoder_sigma_m) } else { vec![false; m] };
    for (i, s) in stale.iter_mut().enumerate() {
        // Already excluded on every cable as a frozen encoder's run.
        *s &= (0..n).any(|j| cable_ok[j][i]);
        *s |= known_stale.and_then(|k| k.get(i)).copied().unwrap_or(false);
    }
    if let Some(mut p) = summarise(ProblemKind::StaleRow, None, &rec.t, &stale, "stale rows") {
        p.description = format!(
            "{} (every encoder repeats the previous row's reading exactly while the platform moves: the tracker more than {:.1} mm or an encoder more than {:.1} mm across the repeat; a new pose logged beside old lengths)",
            p.description,
            stale_motion_m(tracker_sigma_m) * 1e3,
            stale_encoder_step_m(encoder_sigma_m) * 1e3
        );
        problems.push(p);
    }
    for (s, ok) in stale.iter().zip(row_ok.iter_mut()) {
        if *s {
            *ok = false;
        }
    }

    // Dead load cells.
    let mut dead_loadcell = vec![false; n];
    if let Some(f) = &rec.f {
        let spread = |j: usize| {
            let v: Vec<f64> = (0..m).map(|i| f[i * n + j]).filter(|v| v.is_finite()).collect();
            if v.is_empty() {
                return (0usize, 0.0, 0.0, 0.0);
            }
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let zeros = v.iter().filter(|x| x.abs() < 1e-9).count() as f64 / v.len() as f64;
            (v.len(), lo, hi, zeros)
        };
        let stats: Vec<_> = (0..n).map(spread).collect();
        let any_alive = stats.iter().any(|s| s.0 > 0 && s.2 - s.1 > 1.0);
        for j in 0..n {
            let (cnt, lo, hi, zeros) = stats[j];
            let what = if cnt == 0 {
                Some("reads nothing (every tension missing)".to_string())
            } else if any_alive && hi - lo < 1e-3 {
                Some(format!("reads a constant {lo:.2} N over the whole recording"))
            } else if any_alive && zeros > 0.5 {
                Some(format!("reads exactly 0 N in {:.0}% of the samples", zeros * 100.0))
            } else {
                None
            };
            if let Some(w) = what {
                dead_loadcell[j] = true;
                problems.push(DataProblem {
                    kind: ProblemKind::DeadLoadCell,
                    cable: Some(j),
                    t_start: rec.t.first().copied().unwrap_or(0.0),
                    t_end: rec.t.last().copied().unwrap_or(0.0),
                    samples: m,
                    description: format!(
                        "cable {}: load cell {w}; its tensions are ignored (not taken as a loose cable), and effects that need tension are not fitted for this cable", j + 1
                    ),
                });
            }
        }
    }
    (problems, DataMasks { row_ok, cable_ok, dead_loadcell, segment, dt })
}

/// The wild values of [`crate::screen`] as data problems: one per kind and cable (the tracker:
/// one), listing where the first few are.
pub fn from_screen(sc: &crate::screen::Screen) -> Vec<DataProblem> {
    use crate::screen::{Action, WildKind};
    let mut out: Vec<DataProblem> = vec![];
    let mut k = 0;
    let f = &sc.findings;
    while k < f.len() {
        let (kind, cable) = (f[k].kind, f[k].cable);
        let e = k + f[k..].iter().take_while(|w| w.kind == kind && w.cable == cable).count();
        let group = &f[k..e];
        let samples: usize = group
            .iter()
            .map(|w| match w.action {
                Action::Excluded => 1,
                Action::ReReferenced { rows, .. } | Action::RowsExcluded { rows, .. } => rows,
            })
            .sum();
        let (pk, what) = match kind {
            WildKind::EncoderSpike => (ProblemKind::EncoderSpike, "wild encoder readings"),
            WildKind::EncoderJump => (ProblemKind::EncoderJump, "encoder jumps (lost counts)"),
            WildKind::ImpossibleTension => (ProblemKind::ImpossibleTension, "impossible tensions"),
            WildKind::TrackerJump => (ProblemKind::TrackerOutlier, "wild tracker positions"),
        };
        let more = if group.len() > 4 { format!("; and {} more", group.len() - 4) } else { String::new() };
        let list: Vec<String> = group.iter().take(4).map(|w| w.to_string()).collect();
        out.push(DataProblem {
            kind: pk,
            cable,
            t_start: group[0].t,
            t_end: group[group.len() - 1].t,
            samples,
            description: format!(
                "{} {what} (beyond {:.1} noise sigmas of their neighbours): {}{more}",
                group.len(),
                sc.threshold_sigmas,
                list.join("; ")
            ),
        });
        k = e;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(m: usize) -> Recording {
        let mut r = Recording::with_capacity(3, m, true, false, false);
        for i in 0..m {
            let t = i as f64 * 0.01;
            let p = [t.sin(), (1.3 * t).cos(), 1.0 + 0.2 * t.sin()];
            let l: Vec<f64> = (0..3).map(|j| 3.0 + p[0] * (j as f64 - 1.0) + 0.1 * p[2]).collect();
            let f: Vec<f64> = (0..3).map(|j| 20.0 + 5.0 * (t + j as f64).sin()).collect();
            r.push(t, p, None, &l, Some(&f), None);
        }
        r
    }

    #[test]
    fn clean_recording_has_no_problems() {
        let (p, masks) = detect(&rec(2000), 1.5e-3, 5e-5);
        assert!(p.is_empty(), "{p:?}");
        assert!(masks.row_ok.iter().all(|x| *x));
    }

    #[test]
    fn finds_frozen_encoder_outlier_clock_jump_and_dead_load_cell() {
        let mut r = rec(3000);
        for i in 500..560 {
            r.l[i * 3 + 1] = r.l[499 * 3 + 1];
        }
        r.p[1200][2] += 0.05;
        for i in 2000..3000 {
            r.t[i] += 3.0;
        }
        let f = r.f.as_mut().unwrap();
        for i in 0..3000 {
            f[i * 3 + 2] = 0.0;
        }
        let (p, masks) = detect(&r, 1.5e-3, 5e-5);
        let kinds: Vec<_> = p.iter().map(|x| (x.kind, x.cable)).collect();
        assert!(kinds.contains(&(ProblemKind::FrozenEncoder, Some(1))), "{p:#?}");
        assert!(kinds.contains(&(ProblemKind::TrackerOutlier, None)), "{p:#?}");
        assert!(kinds.contains(&(ProblemKind::ClockJump, None)), "{p:#?}");
        assert!(kinds.contains(&(ProblemKind::DeadLoadCell, Some(2))), "{p:#?}");
        assert!(!masks.row_ok[1200] && !masks.cable_ok[1][530] && masks.dead_loadcell[2]);
        assert_ne!(masks.segment[1999], masks.segment[2000]);
        assert!(p.iter().find(|x| x.kind == ProblemKind::ClockJump).unwrap().description.contains("clock jump"));
    }
    #[test]
    fn finds_a_tracker_outlier_right_after_a_dropout() {
        let mut r = rec(2000);
        for i in 800..805 {
            r.p[i] = [f64::NAN; 3];
        }
        r.p[805][1] += 0.05;
        let (p, masks) = detect(&r, 1.5e-3, 5e-5);
        assert!(p.iter().any(|x| x.kind == ProblemKind::TrackerOutlier), "{p:#?}");
        assert!(!masks.row_ok[805]);
        assert!(masks.row_ok[806] && masks.row_ok[799]);
    }

    /// Stale rows: a repeat of every encoder while the platform moves is found (also across a
    /// tracker dropout inside the repeat, and in slow motion that only the encoders show);
    /// a repeat at rest is not, nor a repeat of one cable.
    #[test]
    fn finds_stale_rows_but_not_rests() {
        let mut r = rec(2000);
        // Every 4th row of 200..280 (the tracker moves ~8 mm a row) repeats the row before it.
        let stale: Vec<usize> = (200..280).step_by(4).collect();
        for &i in &stale {
            let prev: Vec<f64> = r.lengths(i - 1).to_vec();
            r.l[i * 3..i * 3 + 3].copy_from_slice(&prev);
        }
        // A run of two stale rows whose first has no pose.
        for i in [901, 902] {
            let prev: Vec<f64> = r.lengths(900).to_vec();
            r.l[i * 3..i * 3 + 3].copy_from_slice(&prev);
        }
        r.p[901] = [f64::NAN; 3];
        // One cable repeats: not a stale row.
        r.l[1201 * 3 + 1] = r.l[1200 * 3 + 1];
        // A rest: pose and lengths constant over 1500..1504, moving before and after.
        for i in 1501..1504 {
            r.p[i] = r.p[1500];
            let prev: Vec<f64> = r.lengths(1500).to_vec();
            r.l[i * 3..i * 3 + 3].copy_from_slice(&prev);
        }
        let (p, masks) = detect(&r, 1.5e-3, 5e-5);
        let found = stale_rows(&r, 1.5e-3, 5e-5);
        let rows: Vec<usize> = (0..r.len()).filter(|&i| found[i]).collect();
        let mut want = stale.clone();
        want.extend([901, 902]);
        assert_eq!(rows, want);
        let ok = |i: usize| masks.row_ok[i];
        // (The sudden stop at 1501 is a tracker outlier to its interpolation; not stale.)
        assert!(want.iter().all(|&i| !ok(i)) && ok(1201) && !found[1502] && !found[1503], "{p:#?}");
        let d = p.iter().find(|x| x.kind == ProblemKind::StaleRow).expect("reported");
        assert_eq!(d.samples, want.len(), "{d:?}");
        // Slow motion: 0.1 mm per row on the tracker (below its noise), the encoders step 1.5 mm
        // a row: a repeat of one row is stale, a pause of three is not.
        let mut r = rec(50);
        for i in 0..50 {
            r.p[i] = [0.0, 0.0, 1.0 + 1e-4 * i as f64];
            for j in 0..3 {
                r.l[i * 3 + j] = 3.0 + 1.5e-3 * i as f64;
            }
        }
        let prev: Vec<f64> = r.lengths(20).to_vec();
        r.l[21 * 3..21 * 3 + 3].copy_from_slice(&prev);
        let prev: Vec<f64> = r.lengths(30).to_vec();
        for i in 31..34 {
            r.l[i * 3..i * 3 + 3].copy_from_slice(&prev);
        }
        let rows: Vec<usize> = stale_rows(&r, 1.5e-3, 5e-5).iter().enumerate().filter(|(_, s)| **s).map(|(i, _)| i).collect();
        assert_eq!(rows, vec![21]);
    }
}
