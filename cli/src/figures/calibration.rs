//! The figures of a calibration, one question each.

use super::{colors, Bars, Figure, HLine, Marker, Panel, Style};
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

/// "How far did each anchor move, and how sure are we?": the move from `from` to `to` per cable
/// and axis, mm, with +-2 sigma bars (95 % for a normal estimate).
pub fn anchor_moves(stem: &str, what: &str, from: &[[f64; 3]], to: &[[f64; 3]], sigma: &[[f64; 3]]) -> Figure {
    let n = to.len();
    let markers = [Marker::Circle, Marker::Triangle, Marker::Square];
    let cols = [colors::BLUE, colors::VERMILION, colors::BLACK];
    let mut panel = Panel::new(format!("anchor move {what}, per cable and axis, with 2-sigma bars"), "cable", "move, mm");
    panel.categories = Some((0..n).map(|j| format!("cable {j}")).collect());
    panel.hlines.push(HLine { label: "no move".into(), y: 0.0, color: colors::GREY });
    for k in 0..3 {
        let pts: Vec<(f64, f64, f64)> =
            (0..n).map(|j| (j as f64 + (k as f64 - 1.0) * 0.18, (to[j][k] - from[j][k]) * 1e3, 2.0 * sigma[j][k] * 1e3)).collect();
        panel.bars.push(Bars { label: format!("{} ± 2σ", AXES[k]), points: pts, color: cols[k], marker: markers[k] });
    }
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

/// All figures of a calibration, in the order they are written (`fig7-lengths` first).
pub fn figures(rec: &Recording, cfg: &RobotConfig, out: &Outcome) -> Vec<Figure> {
    let b = cfg.platform_points();
    let n = rec.n_cables;
    let opts = CalibOptions::from_config(&cfg.calibration);
    let taut = metrics::taut_mask(rec, &opts);
    let before = metrics::co_registration(rec, &b, &out.init.params);
    let after = metrics::co_registration(rec, &b, &out.force.params);
    let plain = out.plain.as_ref().map(|p| metrics::co_registration(rec, &b, &p.params));
    let series = |r: &metrics::Residuals, j: usize| -> Vec<(f64, f64)> { (0..rec.len()).map(|i| (rec.t[i], r.get(i, j) * 1e3)).collect() };
    let mut figs = Vec::new();

    // 1. Before and after.
    let panels = (0..n)
        .map(|j| {
            Panel::new(format!("cable {j}: measured minus modelled length"), "time, s", "error, mm")
                .series("initial estimate", series(&before, j), colors::SKY, Style::Line)
                .series("calibrated (force-aware)", series(&after, j), colors::BLACK, Style::Line)
        })
        .collect();
    figs.push(Figure {
        stem: "fig7-lengths".into(),
        question: "How far was the model from the measured cable lengths, before and after calibration?".into(),
        caption: "Measured encoder length minus the length the model predicts from the tracker, per cable, in mm: light before \
                  calibration (the initial estimate), dark after. After calibration the error should be noise around zero."
            .into(),
        panels,
    });

    // 2. Loose cables and force weighting: the taut readings' error, smoothed so that what is
    // systematic shows above the noise, with the loose stretches marked below.
    let panels = (0..n)
        .map(|j| {
            let taut_err = |r: &metrics::Residuals| -> Vec<(f64, f64)> {
                (0..rec.len()).map(|i| (rec.t[i], if taut.keep[i * n + j] { r.get(i, j) * 1e3 } else { f64::NAN })).collect()
            };
            let mut p = Panel::new(format!("cable {j}: error of the taut readings, running median"), "time, s", "error, mm");
            p.hlines.push(HLine { label: "zero".into(), y: 0.0, color: colors::GREY });
            let mut curves = vec![running_median(&taut_err(&after))];
            if let Some(pl) = &plain {
                curves.push(running_median(&taut_err(pl)));
                p = p.series("without force weighting", curves[1].clone(), colors::VERMILION, Style::Dashed);
            }
            p = p.series("force-aware", curves[0].clone(), colors::BLACK, Style::Line);
            let (lo, hi) = finite_span(curves.iter().flatten().map(|q| q.1));
            let rug = lo - 0.08 * (hi - lo).max(0.1);
            let loose: Vec<(f64, f64)> = (0..rec.len())
                .filter(|&i| !taut.keep[i * n + j] && rec.tensions(i).is_some_and(|f| f[j] < opts.min_tension_n))
                .map(|i| (rec.t[i], rug))
                .collect();
            let (loose, label) = thin(loose, &format!("cable loose, T < {} N (excluded)", opts.min_tension_n));
            p.series(label, loose, colors::SKY, Style::Points(Marker::Cross))
        })
        .collect();
    figs.push(Figure {
        stem: "fig8-errors".into(),
        question: "What do loose cables do to the fit?".into(),
        caption: if plain.is_some() {
            "Error of the taut readings per cable, mm, as a running median over 1/150 of the recording (the noise averages out, what \
             is systematic stays). Crosses along the bottom: when the cable was loose (tension below the threshold). The \
             force-aware calibration excludes those readings and stays at zero; the calibration without force weighting \
             (dashed) fits them too, is pulled towards the longer lengths a slack cable reads, and leaves a pose-dependent \
             error on the taut readings."
                .into()
        } else {
            "Error of the taut readings per cable, mm, as a running median over 1/150 of the recording (the noise averages out, what \
             is systematic stays). Crosses along the bottom: when the cable was loose (tension below the threshold); the \
             calibration excludes those readings. (`--compare` adds the calibration without force weighting.)"
                .into()
        },
        panels,
    });

    // 3. What force weighting buys, on the taut samples.
    figs.push(histogram(rec, &taut, &after, plain.as_ref()));

    // 4. Exclusions and their reasons.
    figs.push(excluded(rec, &opts, &taut, &after, out));

    // 5. Anchor moves with their uncertainty.
    figs.push(anchor_moves(
        "fig11-anchors",
        "from the initial estimate to the calibration",
        &out.init.params.anchors,
        &out.force.params.anchors,
        &out.force.sigma.anchors,
    ));
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

fn finite_span(it: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = it.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo.is_finite() {
        (lo, hi)
    } else {
        (0.0, 1.0)
    }
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
        stem: "fig9-histogram".into(),
        question: "Does force weighting keep the loose readings from spoiling the fit?".into(),
        caption,
        panels: vec![panel],
    }
}

fn excluded(rec: &Recording, opts: &CalibOptions, taut: &metrics::Mask, after: &metrics::Residuals, out: &Outcome) -> Figure {
    let n = rec.n_cables;
    let with_tension = rec.f.is_some() && out.force.used_tensions;
    let panels = (0..n)
        .map(|j| {
            let (y_label, y_of): (&str, Box<dyn Fn(usize) -> f64>) = if with_tension {
                ("tension, N", Box::new(move |i| rec.tensions(i).map_or(f64::NAN, |f| f[j])))
            } else {
                ("error, mm", Box::new(move |i| after.get(i, j) * 1e3))
            };
            let mut p = Panel::new(format!("cable {j}: readings used and excluded"), "time, s", y_label);
            if with_tension {
                p.hlines.push(HLine {
                    label: format!("loose threshold {} N", opts.min_tension_n),
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
            // Missing: no tracker position, no length or no tension; drawn at the bottom of the
            // panel's data (a missing value has no y of its own).
            let base = (0..rec.len()).map(&y_of).filter(|v| v.is_finite()).fold(f64::INFINITY, f64::min);
            let base = if base.is_finite() { base } else { 0.0 };
            let missing: Vec<(f64, f64)> = (0..rec.len())
                .filter(|&i| {
                    !taut.keep[i * n + j] && !rec.tensions(i).is_some_and(|f| f[j] < opts.min_tension_n) && !out.screen.removed_rows[i]
                })
                .map(|i| (rec.t[i], base))
                .collect();
            let (pts, label) = thin(missing, "missing value");
            p = p.series(label, pts, colors::BLUE, Style::Points(Marker::Triangle));
            let wild: Vec<(f64, f64)> = out
                .screen
                .findings
                .iter()
                .filter(|w| w.cable.is_none_or(|c| c == j) && w.row < rec.len())
                .map(|w| (w.t, if y_of(w.row).is_finite() { y_of(w.row) } else { base }))
                .collect();
            let (pts, label) = thin(wild, "wild value, screened out");
            p.series(label, pts, colors::PURPLE, Style::Points(Marker::Square))
        })
        .collect();
    Figure {
        stem: "fig10-excluded".into(),
        question: "Which readings were excluded, and why?".into(),
        caption: if with_tension {
            format!(
                "Tension per cable against time, N. Crosses: below {} N, the cable was loose and its encoder does not measure the \
                 straight-line length: excluded. Triangles (at the bottom): a value was missing. Squares: a wild value the screen \
                 removed as a data problem. The counts are in the legends.",
                opts.min_tension_n
            )
        } else {
            "No tensions in this recording: every reading with a position and a length is used. Error per cable, mm, against \
             time; triangles: a value was missing; squares: a wild value the screen removed as a data problem."
                .into()
        },
        panels,
    }
}
