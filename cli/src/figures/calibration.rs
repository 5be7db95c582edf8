//! The figures of a calibration, one question each.

use super::{colors, Bars, Figure, HLine, Marker, Panel, Shade, Style};
use crate::calibrate::Outcome;
use taut_calib::{metrics, CalibOptions};
use taut_config::recording::Recording;
use taut_config::RobotConfig;

/// Most markers one series draws; more are thinned evenly and the legend says so (an SVG of
/// 100,000 markers is tens of megabytes and shows no more than 2,000 do at 1000 px).
pub const MAX_MARKERS: usize = 2000;

/// Evenly thinned points, and a legend suffix that says how many are shown.
pub fn thin(points: Vec<(f64, f64)>, label: &str) -> (Vec<(f64, f64)>, String) {
    let n = points.len();
    if n <= MAX_MARKERS {
        return (points, format!("{label} ({n})"));
    }
    let step = n.div_ceil(MAX_MARKERS);
    let kept: Vec<(f64, f64)> = points.into_iter().step_by(step).collect();
    let shown = kept.len();
    (kept, format!("{label} ({n}; 1 in {step} shown: {shown})"))
}

/// Axis names of an anchor coordinate.
const AXES: [&str; 3] = ["x", "y", "z"];

/// The categories of an anchor figure: one per cable and axis (`cable 1 x`, ...).
fn anchor_categories(n: usize) -> Vec<String> {
    (0..n).flat_map(|j| AXES.iter().map(move |a| format!("{} {a}", taut_config::cable_name(j)))).collect()
}

/// "How far did each anchor move, and how sure are we?": the move from `from` to `to` per cable
/// and axis, mm, with +-2 sigma bars (95 % for a normal estimate).
pub fn anchor_moves(stem: &str, what: &str, from: &[[f64; 3]], to: &[[f64; 3]], sigma: &[[f64; 3]]) -> Figure {
    let n = to.len();
    let mut panel = Panel::new(format!("anchor move {what}, per cable and axis, with 2-sigma bars"), "cable and axis", "move, mm");
    panel.categories = Some(anchor_categories(n));
    panel.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
    let pts: Vec<(f64, f64, f64)> =
        (0..3 * n).map(|q| (q as f64, (to[q / 3][q % 3] - from[q / 3][q % 3]) * 1e3, 2.0 * sigma[q / 3][q % 3] * 1e3)).collect();
    panel.bars.push(Bars { label: "move ± 2σ".into(), points: pts, color: colors::BLUE, marker: Marker::Dot });
    Figure {
        stem: stem.into(),
        question: "How far did each anchor move, and how sure are we?".into(),
        caption: format!(
            "Each marker is the change of one anchor coordinate {what}, in mm; the bar spans two standard deviations either side \
             (95 % if the errors are normal). A bar that crosses zero is a move the data cannot tell from none."
        ),
        panels: vec![panel],
    }
}

/// "Where are the anchors?": per cable and axis, the nominal anchor (configuration), the initial
/// estimate and the calibration, as mm from the calibrated anchor; the calibration's 2-sigma
/// bar around zero.
pub fn anchors(nominal: Option<&[[f64; 3]]>, initial: &[[f64; 3]], calibrated: &[[f64; 3]], sigma: &[[f64; 3]]) -> Figure {
    let n = calibrated.len();
    let mut panel =
        Panel::new("anchors relative to the calibrated ones, per cable and axis", "cable and axis", "mm from the calibrated anchor");
    panel.categories = Some(anchor_categories(n));
    panel.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
    let rel = |a: &[[f64; 3]], q: usize| (a[q / 3][q % 3] - calibrated[q / 3][q % 3]) * 1e3;
    panel.bars.push(Bars {
        label: "calibrated ± 2σ".into(),
        points: (0..3 * n).map(|q| (q as f64, 0.0, 2.0 * sigma[q / 3][q % 3] * 1e3)).collect(),
        color: colors::BLACK,
        marker: Marker::Dot,
    });
    // Beside the bar, not on it: a marker at the calibrated anchor would hide it.
    let mut p = panel.series(
        "initial estimate",
        (0..3 * n).map(|q| (q as f64 - 0.2, rel(initial, q))).collect(),
        colors::BLUE,
        Style::Points(Marker::Circle),
    );
    if let Some(nom) = nominal.filter(|a| a.len() == n) {
        p = p.series(
            "nominal (configuration)",
            (0..3 * n).map(|q| (q as f64 + 0.2, rel(nom, q))).collect(),
            colors::VERMILION,
            Style::Points(Marker::Triangle),
        );
    }
    Figure {
        stem: "anchors".into(),
        question: "Where are the anchors: as designed, as first estimated, as calibrated?".into(),
        caption: if nominal.is_some_and(|a| a.len() == n) {
            "Per cable and axis, mm from the calibrated anchor: triangles the nominal anchor of the configuration, circles the \
             initial estimate; the bar is the calibration's 2-sigma (95 % if the errors are normal). A marker outside the bar is \
             an anchor the calibration moved by more than it is unsure of."
                .into()
        } else {
            "Per cable and axis, mm from the calibrated anchor: circles the initial estimate; the bar is the calibration's \
             2-sigma (95 % if the errors are normal). The configuration gives no nominal anchors to compare with."
                .into()
        },
        panels: vec![p],
    }
}

/// Stretches of consecutive rows where `loose(i)`: (first time, last time).
fn spans(t: &[f64], loose: impl Fn(usize) -> bool) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    let mut open: Option<f64> = None;
    for i in 0..t.len() {
        match (loose(i), open) {
            (true, None) => open = Some(t[i]),
            (false, Some(a)) => {
                out.push((a, t[i - 1].max(a)));
                open = None;
            }
            _ => {}
        }
    }
    if let (Some(a), Some(b)) = (open, t.last()) {
        out.push((a, *b));
    }
    out
}

/// The robust range of `v` (0.1 and 99.9 percentiles), padded by 10 %; `None` when empty.
fn robust_range(v: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let mut s: Vec<f64> = v.filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return None;
    }
    s.sort_by(f64::total_cmp);
    let q = |f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
    let (lo, hi) = (q(0.001), q(0.999));
    let pad = 0.1 * (hi - lo).max(1e-3);
    Some((lo - pad, hi + pad))
}

/// The loose-cable shade of cable `j`.
fn loose_shade(rec: &Recording, opts: &CalibOptions, j: usize) -> Shade {
    Shade {
        label: format!("cable loose (tension below {} N): excluded", super::tick(opts.min_tension_n)),
        spans: spans(&rec.t, |i| rec.tensions(i).is_some_and(|f| f[j] < opts.min_tension_n)),
        color: colors::VERMILION,
    }
}

/// All figures of a calibration, in the order they are written (`lengths-before-after` first).
pub fn figures(rec: &Recording, cfg: &RobotConfig, out: &Outcome) -> Vec<Figure> {
    let b = cfg.platform_points();
    let n = rec.n_cables;
    let opts = CalibOptions::from_config(&cfg.calibration);
    let taut = metrics::taut_mask(rec, &opts);
    let before = metrics::co_registration(rec, &b, &out.init.params);
    let after = metrics::co_registration(rec, &b, &out.force.params);
    let plain = out.plain.as_ref().map(|p| metrics::co_registration(rec, &b, &p.params));
    let taut_err = |r: &metrics::Residuals, j: usize| -> Vec<(f64, f64)> {
        (0..rec.len()).map(|i| (rec.t[i], if taut.keep[i * n + j] { r.get(i, j) * 1e3 } else { f64::NAN })).collect()
    };
    let mut figs = Vec::new();

    // 1. Before and after, on the taut readings: every reading after calibration in grey, the
    // running medians of both fits over it; the y range from the taut readings, loose
    // stretches shaded.
    let panels = (0..n)
        .map(|j| {
            let raw = taut_err(&after, j);
            let (mb, ma) = (running_median(&taut_err(&before, j)), running_median(&raw));
            let mut p =
                Panel::new(format!("{}: measured minus modelled length, taut readings", cfg.cable_label(j)), "time, s", "error, mm");
            p.y_range = robust_range(raw.iter().chain(&mb).chain(&ma).map(|q| q.1));
            p.shades.push(loose_shade(rec, &opts, j));
            p.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
            p.series("every reading, calibrated", raw, colors::GREY, Style::Line)
                .series("initial estimate (running median)", mb, colors::SKY, Style::Thick)
                .series("calibrated (running median)", ma, colors::BLACK, Style::Line)
        })
        .collect();
    figs.push(Figure {
        stem: "lengths-before-after".into(),
        question: "How far was the model from the measured cable lengths, before and after calibration?".into(),
        caption: "Measured encoder length minus the length the model predicts from the tracker, per cable, in mm, on the taut \
                  readings: grey every reading after calibration; the thick light line the running median with the initial \
                  estimate, the thin dark line with the calibration (over 1/150 of the recording: the noise averages out, what \
                  is systematic stays). Where the two lines agree the light one shows as a margin around the dark. Shaded: the \
                  cable was loose, its readings excluded. After calibration the error should be noise around zero."
            .into(),
        panels,
    });

    // 2. Loose cables and force weighting: the taut readings' error, smoothed so that what is
    // systematic shows above the noise, with the loose stretches shaded.
    let panels = (0..n)
        .map(|j| {
            let mut p = Panel::new(format!("{}: error of the taut readings, running median", cfg.cable_label(j)), "time, s", "error, mm");
            p.shades.push(loose_shade(rec, &opts, j));
            p.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
            if let Some(pl) = &plain {
                p = p.series("without force weighting", running_median(&taut_err(pl, j)), colors::VERMILION, Style::Dashed);
            }
            p.series("force-aware", running_median(&taut_err(&after, j)), colors::BLACK, Style::Line)
        })
        .collect();
    figs.push(Figure {
        stem: "errors-taut".into(),
        question: "What do loose cables do to the fit?".into(),
        caption: if plain.is_some() {
            "Error of the taut readings per cable, mm, as a running median over 1/150 of the recording (the noise averages out, what \
             is systematic stays). Shaded: the cable was loose (tension below the threshold). The force-aware calibration \
             excludes those readings and stays at zero; the calibration without force weighting (dashed) fits them too, is \
             pulled towards the longer lengths a slack cable reads, and leaves a pose-dependent error on the taut readings."
                .into()
        } else {
            "Error of the taut readings per cable, mm, as a running median over 1/150 of the recording (the noise averages out, what \
             is systematic stays). Shaded: the cable was loose (tension below the threshold); the calibration excludes those \
             readings. (`--compare` adds the calibration without force weighting.)"
                .into()
        },
        panels,
    });

    // 3. What force weighting buys, on the taut samples.
    figs.push(histogram(rec, &taut, &after, plain.as_ref()));

    // 4. Exclusions and their reasons.
    figs.push(excluded(rec, cfg, &opts, &taut, &after, out));

    // 5. The anchors: nominal, initial and calibrated.
    figs.push(anchors(cfg.anchors().as_deref(), &out.init.params.anchors, &out.force.params.anchors, &out.force.sigma.anchors));
    figs
}

/// Running median of the finite values of `pts` over windows of 1/150 of the recording
/// (at least 5 points), one point per window at its median time.
fn running_median(pts: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let w = (pts.len() / 150).max(5);
    let mut out = Vec::with_capacity(pts.len() / w + 1);
    let mut buf: Vec<f64> = Vec::with_capacity(w);
    for chunk in pts.chunks(w) {
        buf.clear();
        buf.extend(chunk.iter().map(|p| p.1).filter(|v| v.is_finite()));
        let t = chunk[chunk.len() / 2].0;
        if buf.len() * 2 < chunk.len() {
            // Mostly loose or missing: a gap, not a median of a few.
            out.push((t, f64::NAN));
            continue;
        }
        let k = buf.len() / 2;
        buf.select_nth_unstable_by(k, f64::total_cmp);
        out.push((t, buf[k]));
    }
    out
}

/// Step outline of a histogram on the bin grid `lo + k w`.
fn steps(data: impl Iterator<Item = f64>, lo: f64, w: f64, bins: usize) -> Vec<(f64, f64)> {
    let mut counts = vec![0usize; bins];
    for v in data.filter(|v| v.is_finite()) {
        let b = ((v - lo) / w).floor();
        if b >= 0.0 && (b as usize) < bins {
            counts[b as usize] += 1;
        }
    }
    let mut pts = Vec::with_capacity(2 * bins);
    for (k, &c) in counts.iter().enumerate() {
        let x = lo + k as f64 * w;
        pts.push((x, c as f64));
        pts.push((x + w, c as f64));
    }
    pts
}

fn histogram(rec: &Recording, taut: &metrics::Mask, after: &metrics::Residuals, plain: Option<&metrics::Residuals>) -> Figure {
    let n = rec.n_cables;
    let taut_of =
        |r: &metrics::Residuals| -> Vec<f64> { (0..rec.len() * n).filter(|&k| taut.keep[k]).map(|k| r.values[k] * 1e3).collect() };
    let a = taut_of(after);
    // The grid: the force-aware errors' robust spread (0.5 and 99.5 percentiles), widened to
    // hold the unweighted fit's shift, so that both shapes are visible and comparable.
    let mut sorted: Vec<f64> = a.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let q = |s: &[f64], f: f64| if s.is_empty() { 0.0 } else { s[((s.len() - 1) as f64 * f) as usize] };
    let mut m = q(&sorted, 0.995).abs().max(q(&sorted, 0.005).abs()).max(1e-3);
    let p = plain.map(taut_of);
    if let Some(p) = &p {
        let mut s: Vec<f64> = p.iter().copied().filter(|v| v.is_finite()).collect();
        s.sort_by(f64::total_cmp);
        m = m.max(q(&s, 0.995).abs()).max(q(&s, 0.005).abs());
    }
    let bins = 60;
    let (lo, w) = (-m, 2.0 * m / bins as f64);
    let mut panel = Panel::new("error of the taut readings (the ones every fit should match)", "error, mm", "readings per bin");
    panel.hlines.clear();
    if let Some(p) = &p {
        panel = panel.series("without force weighting", steps(p.iter().copied(), lo, w, bins), colors::VERMILION, Style::Dashed);
    }
    panel = panel.series("force-aware", steps(a.iter().copied(), lo, w, bins), colors::BLACK, Style::Line);
    // Per-cable bias of the taut readings: what the loose ones did to an unweighted fit.
    let mean = |v: &[f64]| {
        let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        f.iter().sum::<f64>() / f.len().max(1) as f64
    };
    let mut caption = format!(
        "Histogram of measured minus modelled length on the taut readings only, mm (same bins for every curve). Mean error: \
         force-aware {:+.2} mm",
        mean(&a)
    );
    if let Some(p) = &p {
        caption.push_str(&format!(
            ", without force weighting {:+.2} mm: a fit that includes loose readings (cable longer than the straight line) \
             is pulled towards them and leaves the taut readings off-centre and wider.",
            mean(p)
        ));
    } else {
        caption.push_str(". (`--compare` adds the calibration without force weighting.)");
    }
    Figure {
        stem: "errors-histogram".into(),
        question: "Does force weighting keep the loose readings from spoiling the fit?".into(),
        caption,
        panels: vec![panel],
    }
}

fn excluded(
    rec: &Recording,
    cfg: &RobotConfig,
    opts: &CalibOptions,
    taut: &metrics::Mask,
    after: &metrics::Residuals,
    out: &Outcome,
) -> Figure {
    let n = rec.n_cables;
    let with_tension = rec.f.is_some() && out.force.used_tensions;
    let mut panels: Vec<Panel> = (0..n)
        .map(|j| {
            let (y_label, y_of): (&str, Box<dyn Fn(usize) -> f64>) = if with_tension {
                ("tension, N", Box::new(move |i| rec.tensions(i).map_or(f64::NAN, |f| f[j])))
            } else {
                ("error, mm", Box::new(move |i| after.get(i, j) * 1e3))
            };
            let mut p = Panel::new(format!("{}: readings used and excluded", cfg.cable_label(j)), "time, s", y_label);
            if with_tension {
                p.hlines.push(HLine {
                    label: format!("loose threshold {} N", super::tick(opts.min_tension_n)),
                    y: opts.min_tension_n,
                    color: colors::VERMILION,
                });
            }
            p = p.series(
                if with_tension { "tension" } else { "error" },
                (0..rec.len()).map(|i| (rec.t[i], y_of(i))).collect(),
                colors::GREY,
                Style::Line,
            );
            let loose: Vec<(f64, f64)> = (0..rec.len())
                .filter(|&i| !taut.keep[i * n + j] && rec.tensions(i).is_some_and(|f| f[j] < opts.min_tension_n))
                .map(|i| (rec.t[i], y_of(i)))
                .collect();
            if with_tension {
                let (pts, label) = thin(loose, "loose, excluded");
                p = p.series(label, pts, colors::VERMILION, Style::Points(Marker::Cross));
            }
            // Missing: this cable's own length or tension (the tracker's gaps are the tracker's
            // panel's); drawn at the bottom of the panel's data (a missing value has no y).
            let base = (0..rec.len()).map(&y_of).filter(|v| v.is_finite()).fold(f64::INFINITY, f64::min);
            let base = if base.is_finite() { base } else { 0.0 };
            let missing: Vec<(f64, f64)> = (0..rec.len())
                .filter(|&i| !rec.lengths(i)[j].is_finite() || (with_tension && !rec.tensions(i).is_some_and(|f| f[j].is_finite())))
                .map(|i| (rec.t[i], base))
                .collect();
            if !missing.is_empty() {
                let (pts, label) = thin(missing, "length or tension missing");
                p = p.series(label, pts, colors::BLUE, Style::Points(Marker::Triangle));
            }
            let wild: Vec<(f64, f64)> = out
                .screen
                .findings
                .iter()
                .filter(|w| w.cable == Some(j) && w.row < rec.len())
                .map(|w| (w.t, if y_of(w.row).is_finite() { y_of(w.row) } else { base }))
                .collect();
            if !wild.is_empty() {
                let (pts, label) = thin(wild, "wild value, screened out");
                p = p.series(label, pts, colors::PURPLE, Style::Points(Marker::Square));
            }
            p
        })
        .collect();
    // The tracker's own panel: its gaps and the jumps the screen removed.
    let tracker_wild: Vec<(f64, f64)> = out
        .screen
        .findings
        .iter()
        .filter(|w| w.cable.is_none() && w.row < rec.len())
        .map(|w| (w.t, if (w.value - w.expected).is_finite() { (w.value - w.expected) * 1e3 } else { 0.0 }))
        .collect();
    let dropouts: Vec<(f64, f64)> = (0..rec.len())
        .filter(|&i| !rec.p[i].iter().all(|v| v.is_finite()) && !out.screen.removed_rows.get(i).copied().unwrap_or(false))
        .map(|i| (rec.t[i], 0.0))
        .collect();
    if !tracker_wild.is_empty() || !dropouts.is_empty() {
        let mut p = Panel::new(
            "tracker: positions missing or screened out (every cable's readings of that row excluded)",
            "time, s",
            "jump from its neighbours, mm",
        );
        p.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
        let (pts, label) = thin(dropouts, "no position (dropout)");
        p = p.series(label, pts, colors::BLUE, Style::Points(Marker::Triangle));
        let (pts, label) = thin(tracker_wild, "wild position, screened out");
        p = p.series(label, pts, colors::PURPLE, Style::Points(Marker::Square));
        // The x range of the cables' panels.
        p.series.push(super::Series {
            label: String::new(),
            points: vec![(rec.t[0], f64::NAN), (rec.t[rec.len() - 1], f64::NAN)],
            color: colors::GREY,
            style: Style::Line,
        });
        panels.push(p);
    }
    Figure {
        stem: "readings-excluded".into(),
        question: "Which readings were excluded, and why?".into(),
        caption: if with_tension {
            format!(
                "Tension per cable against time, N. Crosses: below {} N, the cable was loose and its encoder does not measure the \
                 straight-line length: excluded. Triangles (at the bottom): the cable's length or tension was missing. Squares: a \
                 wild value the screen removed as a data problem. The last panel is the tracker's: rows without a position, and \
                 positions that jumped from their neighbours (by how much, mm). The counts are in the legends.",
                super::tick(opts.min_tension_n)
            )
        } else {
            "No tensions in this recording: every reading with a position and a length is used. Error per cable, mm, against \
             time; triangles: a length was missing; squares: a wild value the screen removed as a data problem. The last panel \
             is the tracker's: rows without a position, and positions that jumped from their neighbours."
                .into()
        },
        panels,
    }
}
