//! Figures in the spirit of the paper's Fig. 7-9, written as SVG and PNG.
//!
//! PNG text needs a font; none is installed at a fixed path on the machines this runs on, so the
//! binary embeds DejaVu Sans (`assets/`, Bitstream Vera licence) and registers it once.

use anyhow::{Context, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::sync::Once;
use taut_config::atomic::Staging;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // The only way this fails is a corrupt embedded font, which a test would catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One series of a time plot.
pub struct Series<'a> {
    /// Legend label.
    pub label: String,
    /// (x, y) points; NaN y values are gaps.
    pub points: &'a [(f64, f64)],
    /// Colour.
    pub color: RGBColor,
    /// Draw as markers instead of a line.
    pub markers: bool,
}

/// A panel: title, axis labels, series.
pub struct Panel<'a> {
    /// Title above the panel.
    pub title: String,
    /// x axis label.
    pub x_label: &'a str,
    /// y axis label.
    pub y_label: &'a str,
    /// The series.
    pub series: Vec<Series<'a>>,
}

/// Colour of series `k` (a colour-blind friendly palette).
pub fn color(k: usize) -> RGBColor {
    const P: [RGBColor; 6] = [
        RGBColor(0, 114, 178),
        RGBColor(213, 94, 0),
        RGBColor(0, 158, 115),
        RGBColor(204, 121, 167),
        RGBColor(230, 159, 0),
        RGBColor(86, 180, 233),
    ];
    P[k % P.len()]
}

/// Red used for loose-cable samples, as in the paper's Fig. 8.
pub const LOOSE: RGBColor = RGBColor(220, 30, 30);

/// Writes `stem.svg` and `stem.png` into the figure set `set` with the panels stacked
/// vertically; they go into place when the set is committed.
pub fn write_panels(set: &mut Staging, stem: &str, panels: &[Panel]) -> Result<()> {
    register_font();
    let h = 260 * panels.len() as u32 + 20;
    // Messages name the figure's final place; the staged file is an implementation detail, and
    // on an error the old figures there are kept.
    let name = |ext: &str| set.target().join(format!("{stem}.{ext}")).display().to_string();
    let (svg_name, png_name) = (name("svg"), name("png"));
    let kept = "the figures already there are kept";
    let svg = set.path(&format!("{stem}.svg"))?;
    {
        let root = SVGBackend::new(&svg, (1000, h)).into_drawing_area();
        draw_panels(&root, panels).with_context(|| format!("drawing {svg_name} ({kept})"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}")).with_context(|| format!("writing {svg_name} ({kept})"))?;
    }
    let png = set.path(&format!("{stem}.png"))?;
    {
        let root = BitMapBackend::new(&png, (1000, h)).into_drawing_area();
        draw_panels(&root, panels).with_context(|| format!("drawing {png_name} ({kept})"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}")).with_context(|| format!("writing {png_name} ({kept})"))?;
    }
    Ok(())
}

fn finite_range(it: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in it.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        return (lo - 0.5, hi + 0.5);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

fn draw_panels<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, panels: &[Panel]) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let areas = root.split_evenly((panels.len(), 1));
    for (area, panel) in areas.iter().zip(panels) {
        let (x0, x1) = finite_range(panel.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
        let (y0, y1) = finite_range(panel.series.iter().flat_map(|s| s.points.iter().map(|p| p.1)));
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc(panel.x_label)
            .y_desc(panel.y_label)
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for s in &panel.series {
            let c = s.color;
            if s.markers {
                chart
                    .draw_series(s.points.iter().filter(|p| p.1.is_finite()).map(|&(x, y)| Cross::new((x, y), 3, c.stroke_width(1))))
                    .map_err(|e| anyhow::anyhow!("{e}"))?
                    .label(&s.label)
                    .legend(move |(x, y)| Cross::new((x + 8, y), 3, c.stroke_width(1)));
            } else {
                // Split at NaN so gaps stay gaps.
                let mut first = true;
                for seg in s.points.split(|p| !p.1.is_finite()).filter(|seg| seg.len() > 1) {
                    let a =
                        chart.draw_series(LineSeries::new(seg.iter().copied(), c.stroke_width(1))).map_err(|e| anyhow::anyhow!("{e}"))?;
                    if first {
                        a.label(&s.label).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c));
                        first = false;
                    }
                }
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(())
}

/// A histogram of several data sets on a shared bin grid, as step outlines (Fig. 9).
pub fn write_histograms(set: &mut Staging, stem: &str, title: &str, x_label: &str, sets: &[(String, Vec<f64>)]) -> Result<()> {
    let all: Vec<f64> = sets.iter().flat_map(|s| s.1.iter().copied()).filter(|v| v.is_finite()).collect();
    // Robust range: the 0.5 and 99.5 percentiles, so a few outliers do not squash the shape.
    let mut sorted = all.clone();
    sorted.sort_by(f64::total_cmp);
    let (lo, hi) = if sorted.is_empty() {
        (-1.0, 1.0)
    } else {
        let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f) as usize];
        let m = q(0.995).abs().max(q(0.005).abs()).max(1e-9);
        (-m, m)
    };
    let bins = 60;
    let w = (hi - lo) / bins as f64;
    let mut series_pts = Vec::new();
    for (_, data) in sets {
        let mut counts = vec![0usize; bins];
        for &v in data.iter().filter(|v| v.is_finite()) {
            let b = ((v - lo) / w).floor();
            if b >= 0.0 && (b as usize) < bins {
                counts[b as usize] += 1;
            }
        }
        let mut pts = Vec::with_capacity(2 * bins + 2);
        for (k, &c) in counts.iter().enumerate() {
            let x = lo + k as f64 * w;
            pts.push((x, c as f64));
            pts.push((x + w, c as f64));
        }
        series_pts.push(pts);
    }
    let series = sets
        .iter()
        .zip(&series_pts)
        .enumerate()
        .map(|(k, ((label, _), pts))| Series { label: label.clone(), points: pts, color: color(k), markers: false })
        .collect();
    write_panels(set, stem, &[Panel { title: title.into(), x_label, y_label: "samples", series }])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_svg_and_png_with_text() {
        let dir = std::env::temp_dir().join(format!("taut-plot-{}", std::process::id()));
        let pts: Vec<(f64, f64)> = (0..100).map(|i| (i as f64, (i as f64 * 0.1).sin())).collect();
        let mut set = Staging::new(&dir, &[]).unwrap();
        write_panels(
            &mut set,
            "t",
            &[Panel {
                title: "test".into(),
                x_label: "x",
                y_label: "y",
                series: vec![Series { label: "sin".into(), points: &pts, color: color(0), markers: false }],
            }],
        )
        .unwrap();
        write_histograms(&mut set, "h", "hist", "e", &[("a".into(), pts.iter().map(|p| p.1).collect())]).unwrap();
        assert!(std::fs::metadata(dir.join("t.svg")).is_err(), "nothing in place before the commit");
        set.commit().unwrap();
        for f in ["t.svg", "t.png", "h.svg", "h.png"] {
            assert!(std::fs::metadata(dir.join(f)).unwrap().len() > 1000, "{f}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
