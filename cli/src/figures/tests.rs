//! One test per figure of a calibration: each is drawn from a simulated robot's
//! calibration and rendered to pixels, and the test asserts what the figure must show, from
//! its data and from the rendered colours.

use super::calibration::figures;
use super::{colors, tick, Figure, Panel, PANEL_H};
use crate::calibrate::{pipeline, Outcome};
use plotters::prelude::*;
use std::sync::OnceLock;
use taut_config::recording::Recording;
use taut_config::RobotConfig;

/// A 40 s recording at 50 Hz of the ARAS-CAM-like robot with loose-cable episodes, its
/// configuration (nominal anchors) and its calibration with the unweighted comparison.
fn fixture() -> &'static (Recording, RobotConfig, Outcome) {
    static F: OnceLock<(Recording, RobotConfig, Outcome)> = OnceLock::new();
    F.get_or_init(|| {
        let mut s = taut_sim::Scenario::aras_cam(3);
        s.duration_s = 40.0;
        s.rate_hz = 50.0;
        let run = taut_sim::simulate(&s);
        let out = pipeline(&run.recording, &s.robot, true, &indicatif::ProgressBar::hidden()).expect("calibration");
        let rec = out.screen.recording(&run.recording).clone();
        (rec, s.robot, out)
    })
}

fn figure(out: &Outcome, stem: &str) -> Figure {
    let (rec, cfg, _) = fixture();
    figures(rec, cfg, out).into_iter().find(|f| f.stem == stem).unwrap_or_else(|| panic!("no figure {stem}"))
}

/// The figure rendered: RGB bytes, width, height.
fn render(f: &Figure) -> (Vec<u8>, u32, u32) {
    crate::plot::register_font();
    let (w, h) = f.size();
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        f.draw(&root).expect("draw");
        root.present().expect("present");
    }
    (buf, w, h)
}

fn near(p: &[u8], c: RGBColor, tol: i32) -> bool {
    (p[0] as i32 - c.0 as i32).abs() <= tol && (p[1] as i32 - c.1 as i32).abs() <= tol && (p[2] as i32 - c.2 as i32).abs() <= tol
}

/// Pixels of colour `c` in rows `rows` (inside the plot area: right of the y labels).
fn count(img: &(Vec<u8>, u32, u32), c: RGBColor, rows: std::ops::Range<u32>) -> usize {
    let (buf, w, _) = img;
    rows.flat_map(|y| (80..*w - 10).map(move |x| (x, y))).filter(|(x, y)| near(&buf[((y * w + x) * 3) as usize..][..3], c, 12)).count()
}

/// The chart rows of panel `k` (below its title and legend strip).
fn chart_rows(k: u32) -> std::ops::Range<u32> {
    5 + k * PANEL_H + 70..5 + (k + 1) * PANEL_H - 45
}

fn series<'a>(p: &'a Panel, label: &str) -> &'a super::Series {
    p.series.iter().find(|s| s.label.starts_with(label)).unwrap_or_else(|| {
        panic!("panel `{}` has no series `{label}`: {:?}", p.title, p.series.iter().map(|s| &s.label).collect::<Vec<_>>())
    })
}

/// The tick labels of an SVG (plotters writes `<text ...>\nLABEL\n</text>`).
fn texts(svg: &str) -> Vec<String> {
    svg.split("</text>").filter_map(|t| t.rsplit('>').next()).map(|t| t.trim().to_string()).filter(|t| !t.is_empty()).collect()
}

fn no_spurious_ticks(f: &Figure) {
    let svg = f.svg().unwrap();
    for t in texts(&svg) {
        if let Ok(v) = t.parse::<f64>() {
            assert!(!(v == 0.0 && t.starts_with('-')), "{}: a negative zero `{t}`", f.stem);
            assert!(!(t.contains('.') && v.fract() == 0.0), "{}: an integer shown as `{t}`", f.stem);
        }
        assert_ne!(t, "zero", "{}: a legend entry for the zero line", f.stem);
    }
}

/// The outcome with cable 1's initial anchor 8 mm off in x: an initial estimate that differs.
fn perturbed() -> Outcome {
    let (_, _, out) = fixture();
    let mut o = Outcome {
        init: out.init.clone(),
        force: out.force.clone(),
        plain: out.plain.clone(),
        before: out.before,
        crb: out.crb.clone(),
        screen: out.screen.clone(),
        stale_rows: out.stale_rows,
        column_swap: out.column_swap,
    };
    o.init.params.anchors[0][0] += 0.008;
    o
}

#[test]
fn tick_labels_are_plain_numbers() {
    assert_eq!(tick(1800.0), "1800");
    assert_eq!(tick(-0.0), "0");
    assert_eq!(tick(-1e-17), "0");
    assert_eq!(tick(0.30000000000000004), "0.3");
    assert_eq!(tick(-2.5), "-2.5");
    assert_eq!(tick(50.0), "50");
}

#[test]
fn lengths_before_after_shows_the_initial_estimate_and_a_range_of_taut_readings() {
    let (rec, _, out) = fixture();
    let f = figure(out, "lengths-before-after");
    assert_eq!(f.panels.len(), rec.n_cables);
    assert!(f.panels[0].title.starts_with("cable 1"), "{}", f.panels[0].title);
    for p in &f.panels {
        // The y range comes from the taut readings: a few mm, while the loose readings of the
        // same cable are tens of mm off.
        let (lo, hi) = p.y_range.expect("a y range chosen from the taut readings");
        assert!(hi - lo < 15.0, "{}: y range {lo:.1} .. {hi:.1} mm", p.title);
        assert!(!p.shades[0].spans.is_empty(), "{}: no loose stretch shaded", p.title);
        assert!(p.hlines.iter().all(|h| h.label.is_empty()), "{}: a legend entry for a reference line", p.title);
    }
    series(&f.panels[0], "initial estimate");
    no_spurious_ticks(&f);
    // Where the initial estimate equals the calibration the thick light line shows around the
    // dark one: visible.
    let img = render(&f);
    let sky_same = count(&img, colors::SKY, chart_rows(0));
    assert!(sky_same > 200, "the initial estimate is invisible under the calibration ({sky_same} px)");
    // Where it differs (cable 1's initial anchor 8 mm off) it is drawn apart from the dark line.
    let g = figure(&perturbed(), "lengths-before-after");
    let (ini, cal) = (series(&g.panels[0], "initial estimate"), series(&g.panels[0], "calibrated"));
    let gap: Vec<f64> = ini.points.iter().zip(&cal.points).map(|(a, b)| (a.1 - b.1).abs()).filter(|d| d.is_finite()).collect();
    let median_gap = {
        let mut v = gap.clone();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    assert!(median_gap > 1.0, "the perturbed initial estimate is {median_gap:.2} mm from the calibration");
    let (buf, w, _) = render(&g);
    let apart = chart_rows(0)
        .flat_map(|y| (80..w - 10).map(move |x| (x, y)))
        .filter(|&(x, y)| near(&buf[((y * w + x) * 3) as usize..][..3], colors::SKY, 12))
        .filter(|&(x, y)| {
            // No dark pixel of the calibrated line within 4 px above or below.
            (y.saturating_sub(4)..=y + 4).all(|yy| !near(&buf[((yy * w + x) * 3) as usize..][..3], colors::BLACK, 40))
        })
        .count();
    assert!(apart > 500, "the differing initial estimate is not drawn apart from the calibration ({apart} px)");
    let range = g.panels[0].y_range.unwrap();
    assert!(
        ini.points.iter().filter(|p| p.1.is_finite()).all(|p| p.1 >= range.0 && p.1 <= range.1),
        "the initial series leaves the y range"
    );
}

#[test]
fn errors_taut_shades_loose_stretches_and_has_no_zero_in_the_legend() {
    let (rec, _, out) = fixture();
    let f = figure(out, "errors-taut");
    assert_eq!(f.panels.len(), rec.n_cables);
    for p in &f.panels {
        assert!(series(p, "force-aware").points.iter().any(|q| q.1.is_finite()));
        series(p, "without force weighting");
        assert!(!p.shades[0].spans.is_empty(), "{}: loose stretches not shaded", p.title);
        assert!(p.series.iter().all(|s| !s.label.contains(") (")), "{}: a label with two counts", p.title);
    }
    no_spurious_ticks(&f);
    let img = render(&f);
    assert!(count(&img, colors::BLACK, chart_rows(0)) > 300, "the force-aware curve is not drawn");
    // The shade: light vermilion over white.
    let shade = RGBColor(249, 228, 217);
    assert!(count(&img, shade, chart_rows(0)) > 1000, "no shaded loose stretch in the rendering");
}

#[test]
fn errors_histogram_counts_are_integers() {
    let (_, _, out) = fixture();
    let f = figure(out, "errors-histogram");
    let p = &f.panels[0];
    let force = series(p, "force-aware");
    assert!(force.points.iter().all(|q| q.1.fract() == 0.0), "a count that is not an integer");
    assert!(force.points.iter().map(|q| q.1).fold(0.0, f64::max) > 10.0, "an empty histogram");
    series(p, "without force weighting");
    no_spurious_ticks(&f);
    let svg = f.svg().unwrap();
    let ticks = texts(&svg);
    assert!(ticks.iter().any(|t| t.parse::<u64>().is_ok_and(|v| v >= 100)), "no integer count on the y axis: {ticks:?}");
    let img = render(&f);
    assert!(count(&img, colors::BLACK, chart_rows(0)) > 200 && count(&img, colors::VERMILION, chart_rows(0)) > 100, "curves not drawn");
}

#[test]
fn readings_excluded_puts_tracker_problems_on_the_trackers_panel_only() {
    let (rec, _, out) = fixture();
    let tracker_findings = out.screen.findings.iter().filter(|w| w.cable.is_none()).count();
    assert!(tracker_findings > 0, "the fixture should have tracker jumps to place");
    let f = figure(out, "readings-excluded");
    assert_eq!(f.panels.len(), rec.n_cables + 1, "a panel per cable and the tracker's");
    for (j, p) in f.panels[..rec.n_cables].iter().enumerate() {
        let own = out.screen.findings.iter().filter(|w| w.cable == Some(j)).count();
        let shown = p.series.iter().find(|s| s.label.starts_with("wild value")).map_or(0, |s| s.points.len());
        assert_eq!(shown, own, "{}: wild values of other cables or of the tracker shown", p.title);
        series(p, "loose, excluded");
    }
    let tracker = f.panels.last().unwrap();
    assert!(tracker.title.starts_with("tracker"), "{}", tracker.title);
    assert_eq!(series(tracker, "wild position").points.len(), tracker_findings);
    no_spurious_ticks(&f);
    let img = render(&f);
    let purple_cables: usize = (0..rec.n_cables as u32).map(|k| count(&img, colors::PURPLE, chart_rows(k))).sum();
    let purple_tracker = count(&img, colors::PURPLE, chart_rows(rec.n_cables as u32));
    assert!(purple_tracker > 50, "the tracker's jumps are not drawn ({purple_tracker} px)");
    let cable_wild = out.screen.findings.iter().filter(|w| w.cable.is_some()).count();
    if cable_wild == 0 {
        assert!(purple_cables < 20, "tracker jumps drawn on the cables' panels ({purple_cables} px)");
    }
}

#[test]
fn anchors_shows_nominal_initial_and_calibrated() {
    let (_, cfg, out) = fixture();
    let f = figure(out, "anchors");
    let p = &f.panels[0];
    let nominal = cfg.anchors().unwrap();
    let nom = series(p, "nominal");
    assert_eq!(nom.points.len(), 3 * nominal.len());
    for (q, pt) in nom.points.iter().enumerate() {
        let want = (nominal[q / 3][q % 3] - out.force.params.anchors[q / 3][q % 3]) * 1e3;
        assert!((pt.1 - want).abs() < 1e-9, "nominal marker {q}: {} mm, expected {want} mm", pt.1);
    }
    // The simulated site is off its nominal anchors by centimetres: the markers show it.
    assert!(nom.points.iter().any(|q| q.1.abs() > 5.0), "the nominal anchors sit at zero");
    assert_eq!(p.bars[0].points.len(), 3 * nominal.len());
    assert!(p.bars[0].points.iter().all(|b| b.1 == 0.0 && b.2 > 0.0), "the calibration's bars are not around zero");
    no_spurious_ticks(&f);
    let img = render(&f);
    assert!(count(&img, colors::VERMILION, chart_rows(0)) > 100, "nominal markers not drawn");
    let blue = count(&img, colors::BLUE, chart_rows(0));
    assert!(blue > 50, "initial-estimate markers not drawn ({blue} px)");
    // A differing initial estimate shows where it is.
    let g = figure(&perturbed(), "anchors");
    let ini = series(&g.panels[0], "initial estimate");
    assert!((ini.points[0].1 - (out.init.params.anchors[0][0] + 0.008 - out.force.params.anchors[0][0]) * 1e3).abs() < 1e-9);
    assert!(ini.points[0].1 > 5.0, "cable 1 x initial at {} mm", ini.points[0].1);
    // Without nominal anchors the figure says so instead of drawing nothing.
    let h = super::calibration::anchors(None, &out.init.params.anchors, &out.force.params.anchors, &out.force.sigma.anchors);
    assert!(h.panels[0].series.iter().all(|s| !s.label.starts_with("nominal")) && h.caption.contains("no nominal anchors"));
}

/// A diagnosis of a 40 s recording at 50 Hz with a concealed cable stretch.
fn diagnosis() -> &'static taut_calib::diagnose::Diagnosis {
    static D: OnceLock<taut_calib::diagnose::Diagnosis> = OnceLock::new();
    D.get_or_init(|| {
        let mut s = taut_sim::Scenario::aras_cam(11);
        s.duration_s = 40.0;
        s.rate_hz = 50.0;
        s.physics = taut_sim::Physics { elasticity: Some(20_000.0), ..taut_sim::Physics::default() };
        let run = taut_sim::simulate(&s);
        let opts = taut_calib::diagnose::DiagnoseOptions::from_robot(&s.robot);
        taut_calib::diagnose::diagnose(&run.recording, &s.robot.platform_points(), None, &opts).expect("diagnosis")
    })
}

fn diagnosis_figure(stem: &str) -> Figure {
    super::diagnosis::figures(diagnosis()).into_iter().find(|f| f.stem == stem).unwrap_or_else(|| panic!("no figure {stem}"))
}

#[test]
fn diagnose_residual_vs_time_shows_both_models() {
    let d = diagnosis();
    let f = diagnosis_figure("diagnose-residual-vs-time");
    assert_eq!(f.panels.len(), d.cables);
    for p in &f.panels {
        assert!(series(p, "ideal model").points.iter().any(|q| q.1.is_finite()), "{}", p.title);
        assert!(series(p, "with the named effects").points.iter().any(|q| q.1.is_finite()), "{}", p.title);
        assert!(p.hlines.iter().all(|h| h.label.is_empty()), "{}: a legend entry for the zero line", p.title);
    }
    assert!(f.panels[0].title.starts_with("cable 1:"), "{}", f.panels[0].title);
    no_spurious_ticks(&f);
    let img = render(&f);
    assert!(count(&img, colors::SKY, chart_rows(0)) > 300, "the ideal model's residuals are not drawn");
    assert!(count(&img, colors::BLACK, chart_rows(0)) > 300, "the final residuals are not drawn");
}

#[test]
fn diagnose_effect_figure_shows_the_residual_before_and_after() {
    let d = diagnosis();
    let named: Vec<&str> = d.effects.iter().filter(|f| f.plot.is_some()).map(|f| f.effect.name()).collect();
    assert!(named.contains(&"elasticity"), "the concealed stretch is not named with a figure: {named:?}");
    let f = diagnosis_figure("diagnose-elasticity");
    for p in &f.panels {
        assert!(series(p, "before").points.len() > 10 && series(p, "with elasticity").points.len() > 10, "{}", p.title);
    }
    no_spurious_ticks(&f);
    let img = render(&f);
    assert!(count(&img, colors::SKY, chart_rows(0)) > 300 && count(&img, colors::BLACK, chart_rows(0)) > 300, "series not drawn");
}

#[test]
fn diagnose_anchors_shows_each_move_with_its_bar() {
    let d = diagnosis();
    let f = diagnosis_figure("diagnose-anchors");
    let bars = &f.panels[0].bars[0];
    assert_eq!(bars.points.len(), 3 * d.cables);
    for (q, b) in bars.points.iter().enumerate() {
        let want = (d.final_fit.params.anchors[q / 3][q % 3] - d.baseline.params.anchors[q / 3][q % 3]) * 1e3;
        assert!((b.1 - want).abs() < 1e-9 && b.2 > 0.0, "marker {q}: {} ± {} mm, expected {want} mm", b.1, b.2);
    }
    assert_eq!(f.panels[0].categories.as_ref().unwrap()[0], "cable 1 x");
    no_spurious_ticks(&f);
    let img = render(&f);
    assert!(count(&img, colors::BLUE, chart_rows(0)) > 100, "the moves are not drawn");
}
