//! Figures that answer one question each, drawn once and written twice: as SVG and PNG files
//! (`--plot`) and inline in the HTML report (`--report`).
//!
//! Conventions, so that a figure reads at a glance and survives a grey-scale printer:
//! - the legend sits in its own strip above the data, never on it;
//! - every series differs by line style or marker shape as well as by colour (Okabe-Ito
//!   palette: colour-blind friendly);
//! - the series a figure is about is drawn last (on top); comparison series are dashed or hollow;
//! - axes in the units engineers use: mm for errors and anchor moves, N, s.

pub mod calibration;
pub mod diagnosis;
#[cfg(test)]
#[path = "tests.rs"]
mod figure_tests;

use anyhow::{Context, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use taut_config::atomic::Staging;

/// Width of every figure, px.
pub(crate) const WIDTH: u32 = 1000;
/// Height of one panel, px (title, legend strip and chart).
pub(crate) const PANEL_H: u32 = 290;

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Style {
    /// A solid line.
    Line,
    /// A thick solid line (3 px): a comparison drawn under a thin line stays visible around it
    /// where the two agree and beside it where they differ.
    Thick,
    /// A dashed line.
    Dashed,
    /// Markers of this shape, no line.
    Points(Marker),
}

/// Marker shapes; filled and hollow shapes tell series apart without colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Marker {
    /// A small filled dot.
    Dot,
    /// An x.
    Cross,
    /// A hollow circle.
    Circle,
    /// A filled triangle.
    Triangle,
    /// A hollow square.
    Square,
}

/// One series of a panel.
pub struct Series {
    /// Legend label.
    pub label: String,
    /// (x, y) points; a non-finite y is a gap.
    pub points: Vec<(f64, f64)>,
    /// Colour.
    pub color: RGBColor,
    /// Line or markers.
    pub style: Style,
}

/// Points with symmetric vertical error bars: (x, y, half-width).
pub struct Bars {
    /// Legend label.
    pub label: String,
    /// (x, y, half-width of the bar).
    pub points: Vec<(f64, f64, f64)>,
    /// Colour.
    pub color: RGBColor,
    /// Marker at (x, y).
    pub marker: Marker,
}

/// A horizontal reference line (a threshold, zero).
pub struct HLine {
    /// Legend label; empty for a line that needs none (zero).
    pub label: String,
    /// Where, in y units.
    pub y: f64,
    /// Colour.
    pub color: RGBColor,
}

/// Shaded stretches of x (loose cable), the full height of the chart.
pub struct Shade {
    /// Legend label.
    pub label: String,
    /// (start, end) of each stretch, in x units.
    pub spans: Vec<(f64, f64)>,
    /// Colour (drawn light).
    pub color: RGBColor,
}

/// One chart.
pub struct Panel {
    /// Title above the chart.
    pub title: String,
    /// x axis label, with its unit.
    pub x_label: String,
    /// y axis label, with its unit.
    pub y_label: String,
    /// Series, drawn in order (the last on top).
    pub series: Vec<Series>,
    /// Points with error bars, drawn after the series.
    pub bars: Vec<Bars>,
    /// Reference lines, drawn first.
    pub hlines: Vec<HLine>,
    /// Shaded stretches, drawn under everything.
    pub shades: Vec<Shade>,
    /// Integer x positions are categories with these names (e.g. "cable 0"); other ticks unlabelled.
    pub categories: Option<Vec<String>>,
    /// y range to show instead of the data's (e.g. robust percentiles), if any.
    pub y_range: Option<(f64, f64)>,
}

impl Panel {
    /// A panel with no series yet.
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        Panel {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            series: Vec::new(),
            bars: Vec::new(),
            hlines: Vec::new(),
            shades: Vec::new(),
            categories: None,
            y_range: None,
        }
    }

    /// Adds a series (drawn over the ones added before).
    pub fn series(mut self, label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor, style: Style) -> Self {
        self.series.push(Series { label: label.into(), points, color, style });
        self
    }
}

/// A figure: the question it answers, a sentence on how to read it, and its panels.
pub struct Figure {
    /// File stem (`STEM.svg`, `STEM.png`).
    pub stem: String,
    /// The question the figure answers, as a heading.
    pub question: String,
    /// How to read it, one or two sentences.
    pub caption: String,
    /// Panels, stacked vertically.
    pub panels: Vec<Panel>,
}

/// Okabe-Ito colours: distinct for colour-blind readers and in different greys when printed.
pub mod colors {
    use plotters::style::RGBColor;
    /// Black: the result a figure is about.
    pub const BLACK: RGBColor = RGBColor(0, 0, 0);
    /// Blue.
    pub const BLUE: RGBColor = RGBColor(0, 114, 178);
    /// Vermilion: problems (excluded samples).
    pub const VERMILION: RGBColor = RGBColor(213, 94, 0);
    /// Sky blue (light grey in print): comparisons drawn under the result.
    pub const SKY: RGBColor = RGBColor(86, 180, 233);
    /// Reddish purple: data problems.
    pub const PURPLE: RGBColor = RGBColor(204, 121, 167);
    /// Mid grey: context (all samples, references).
    pub const GREY: RGBColor = RGBColor(150, 150, 150);
}

impl Figure {
    fn height(&self) -> u32 {
        PANEL_H * self.panels.len().max(1) as u32 + 10
    }

    /// Width and height, px.
    pub fn size(&self) -> (u32, u32) {
        (WIDTH, self.height())
    }

    /// The figure as an SVG document.
    pub fn svg(&self) -> Result<String> {
        crate::plot::register_font();
        let mut s = String::new();
        {
            let root = SVGBackend::with_string(&mut s, (WIDTH, self.height())).into_drawing_area();
            self.draw(&root)?;
            root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(s)
    }

    /// Writes `STEM.svg` and `STEM.png` into the figure set; they go into place when the set is
    /// committed. Messages name the figure's final place (the staged file is an implementation
    /// detail; on an error the old figures there are kept).
    pub fn write(&self, set: &mut Staging) -> Result<()> {
        crate::plot::register_font();
        let name = |ext: &str| set.target().join(format!("{}.{ext}", self.stem)).display().to_string();
        let (svg_name, png_name) = (name("svg"), name("png"));
        let kept = "the figures already there are kept";
        let svg = set.path(&format!("{}.svg", self.stem))?;
        {
            let root = SVGBackend::new(&svg, (WIDTH, self.height())).into_drawing_area();
            self.draw(&root).with_context(|| format!("drawing {svg_name} ({kept})"))?;
            root.present().map_err(|e| anyhow::anyhow!("{e}")).with_context(|| format!("writing {svg_name} ({kept})"))?;
        }
        let png = set.path(&format!("{}.png", self.stem))?;
        {
            let root = BitMapBackend::new(&png, (WIDTH, self.height())).into_drawing_area();
            self.draw(&root).with_context(|| format!("drawing {png_name} ({kept})"))?;
            root.present().map_err(|e| anyhow::anyhow!("{e}")).with_context(|| format!("writing {png_name} ({kept})"))?;
        }
        Ok(())
    }

    pub(crate) fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e}");
        root.fill(&WHITE).map_err(e)?;
        let root = root.margin(5, 5, 5, 5);
        let areas = root.split_evenly((self.panels.len().max(1), 1));
        for (area, panel) in areas.iter().zip(&self.panels) {
            draw_panel(area, panel)?;
        }
        Ok(())
    }
}

/// Opacity of a shaded stretch.
const SHADE_ALPHA: f64 = 0.18;

/// A tick label: at most 6 significant digits, trailing zeros dropped, integers as integers
/// (`1800`, not `1800.0`) and no negative zero (`0`, not `-0.0`).
pub fn tick(v: f64) -> String {
    if !v.is_finite() {
        return String::new();
    }
    if v.abs() < 1e-9 {
        return "0".into();
    }
    let d = (5 - v.abs().log10().floor() as i32).clamp(0, 12) as usize;
    let s = format!("{v:.d$}");
    let s = if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

/// Pixel width of `s` in the 12 px legend font (DejaVu Sans averages ~0.6 em).
fn text_width(s: &str) -> i32 {
    (s.chars().count() as f64 * 6.3).ceil() as i32
}

/// Legend rows are this tall, px; entries wrap onto a new row at the figure's width.
const LEGEND_ROW: i32 = 18;

/// Where each legend entry goes: (x, row), and the number of rows.
fn legend_layout(labels: &[&str]) -> (Vec<(i32, i32)>, i32) {
    let (mut x, mut row) = (72, 0);
    let mut at = Vec::with_capacity(labels.len());
    for l in labels {
        let w = 30 + text_width(l) + 18;
        if x + w > WIDTH as i32 - 10 && x > 72 {
            x = 72;
            row += 1;
        }
        at.push((x, row));
        x += w;
    }
    (at, row + 1)
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

/// Most points one line draws: min and max per pixel column keep its envelope (spikes
/// included) at a tenth of the size; a line of 100,000 points would make a 3 MB SVG.
const MAX_LINE_POINTS: usize = 2 * WIDTH as usize;

/// `seg` reduced to the first, minimum and maximum point (in order) of each of `WIDTH` equal
/// runs of points, when it is longer than [`MAX_LINE_POINTS`].
fn envelope(seg: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if seg.len() <= MAX_LINE_POINTS {
        return seg.to_vec();
    }
    let runs = WIDTH as usize;
    let mut out = Vec::with_capacity(3 * runs + 1);
    for r in 0..runs {
        let run = &seg[r * seg.len() / runs..(r + 1) * seg.len() / runs];
        let Some(first) = run.first() else { continue };
        let (mut lo, mut hi) = (0, 0);
        for (k, p) in run.iter().enumerate() {
            if p.1 < run[lo].1 {
                lo = k;
            }
            if p.1 > run[hi].1 {
                hi = k;
            }
        }
        out.push(*first);
        let (a, b) = if lo < hi { (lo, hi) } else { (hi, lo) };
        out.push(run[a]);
        out.push(run[b]);
    }
    out.extend(seg.last());
    out
}

fn marker_element<DB: DrawingBackend>(m: Marker, at: (i32, i32), c: RGBColor) -> DynElement<'static, DB, (i32, i32)> {
    match m {
        Marker::Dot => Circle::new(at, 2, c.filled()).into_dyn(),
        Marker::Cross => Cross::new(at, 3, c.stroke_width(1)).into_dyn(),
        Marker::Circle => Circle::new(at, 4, c.stroke_width(2)).into_dyn(),
        Marker::Triangle => TriangleMarker::new(at, 4, c.filled()).into_dyn(),
        Marker::Square => Rectangle::new([(at.0 - 3, at.1 - 3), (at.0 + 3, at.1 + 3)], c.stroke_width(1)).into_dyn(),
    }
}

/// A legend glyph and label at (x, row).
fn legend_entry<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    (x, row): (i32, i32),
    glyph: Glyph,
    c: RGBColor,
    label: &str,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e}");
    let y = 10 + row * LEGEND_ROW;
    match glyph {
        Glyph::Line => area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(2))).map_err(e)?,
        Glyph::Thick => area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(4))).map_err(e)?,
        Glyph::Box => area.draw(&Rectangle::new([(x, y - 6), (x + 24, y + 6)], c.mix(SHADE_ALPHA).filled())).map_err(e)?,
        Glyph::Dashed => {
            for k in 0..3 {
                area.draw(&PathElement::new(vec![(x + 9 * k, y), (x + 9 * k + 5, y)], c.stroke_width(2))).map_err(e)?;
            }
        }
        Glyph::Marker(m) => area.draw(&marker_element::<DB>(m, (x + 12, y), c)).map_err(e)?,
        Glyph::Bar(m) => {
            area.draw(&PathElement::new(vec![(x + 12, y - 7), (x + 12, y + 7)], c.stroke_width(1))).map_err(e)?;
            area.draw(&marker_element::<DB>(m, (x + 12, y), c)).map_err(e)?;
        }
    }
    area.draw(&Text::new(label.to_string(), (x + 30, y - 7), ("sans-serif", 12).into_font().color(&BLACK))).map_err(e)?;
    Ok(())
}

#[derive(Clone, Copy)]
enum Glyph {
    Line,
    Thick,
    Box,
    Dashed,
    Marker(Marker),
    Bar(Marker),
}

fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, panel: &Panel) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e}");
    let area = area.titled(&panel.title, ("sans-serif", 15)).map_err(e)?;
    // The legend strip: rows above the chart, starting where the plot area starts.
    let mut entries: Vec<(Glyph, RGBColor, &str)> = Vec::new();
    entries.extend(panel.shades.iter().filter(|s| !s.spans.is_empty()).map(|s| (Glyph::Box, s.color, s.label.as_str())));
    entries.extend(panel.hlines.iter().filter(|h| !h.label.is_empty()).map(|h| (Glyph::Dashed, h.color, h.label.as_str())));
    entries.extend(panel.series.iter().filter(|s| !s.label.is_empty()).map(|s| {
        let g = match s.style {
            Style::Line => Glyph::Line,
            Style::Thick => Glyph::Thick,
            Style::Dashed => Glyph::Dashed,
            Style::Points(m) => Glyph::Marker(m),
        };
        (g, s.color, s.label.as_str())
    }));
    entries.extend(panel.bars.iter().map(|b| (Glyph::Bar(b.marker), b.color, b.label.as_str())));
    let (at, rows) = legend_layout(&entries.iter().map(|e| e.2).collect::<Vec<_>>());
    let (legend, chart_area) = area.split_vertically(4 + rows * LEGEND_ROW);
    for ((g, c, label), pos) in entries.iter().zip(at) {
        legend_entry(&legend, pos, *g, *c, label)?;
    }
    let xs =
        panel.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).chain(panel.bars.iter().flat_map(|b| b.points.iter().map(|p| p.0)));
    let (x0, x1) = match &panel.categories {
        Some(c) => (-0.5, c.len() as f64 - 0.5),
        None => finite_range(xs),
    };
    let (y0, y1) = panel.y_range.unwrap_or_else(|| {
        finite_range(
            panel
                .series
                .iter()
                .flat_map(|s| s.points.iter().map(|p| p.1))
                .chain(panel.bars.iter().flat_map(|b| b.points.iter().flat_map(|p| [p.1 - p.2, p.1 + p.2])))
                .chain(panel.hlines.iter().map(|h| h.y)),
        )
    });
    // A given range that is empty (all data equal) still gets a height.
    let (y0, y1) = if y1 > y0 { (y0, y1) } else { finite_range([y0, y1].into_iter()) };
    let mut chart = ChartBuilder::on(&chart_area)
        .margin(6)
        .x_label_area_size(36)
        .y_label_area_size(66)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let cats = panel.categories.clone();
    let fmt_x = move |v: &f64| -> String {
        match &cats {
            Some(c) => {
                let k = v.round();
                if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < c.len() {
                    c[k as usize].clone()
                } else {
                    String::new()
                }
            }
            None => tick(*v),
        }
    };
    let fmt_y = |v: &f64| tick(*v);
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .label_style(("sans-serif", 12))
        .light_line_style(WHITE.mix(0.0))
        .x_label_formatter(&fmt_x)
        .y_label_formatter(&fmt_y);
    if let Some(c) = &panel.categories {
        mesh.x_labels(c.len() * 2 + 1);
    }
    mesh.draw().map_err(|e| anyhow::anyhow!("{e}"))?;
    // Shades over the grid (they are light), under every line and marker.
    for sh in &panel.shades {
        let c = sh.color.mix(SHADE_ALPHA).filled();
        chart
            .draw_series(sh.spans.iter().map(|&(a, b)| Rectangle::new([(a.max(x0), y0), (b.min(x1), y1)], c)))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    for h in &panel.hlines {
        let c = h.color;
        chart.draw_series(DashedLineSeries::new([(x0, h.y), (x1, h.y)], 6, 4, c.stroke_width(1))).map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    for s in &panel.series {
        let c = s.color;
        match s.style {
            Style::Points(m) => {
                chart
                    .draw_series(
                        s.points
                            .iter()
                            .filter(|p| p.0.is_finite() && p.1.is_finite())
                            .map(|&(x, y)| EmptyElement::at((x, y)) + marker_element::<DB>(m, (0, 0), c)),
                    )
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
            }
            Style::Line | Style::Thick | Style::Dashed => {
                // Split at non-finite values so gaps stay gaps.
                for seg in s.points.split(|p| !p.1.is_finite() || !p.0.is_finite()).filter(|seg| seg.len() > 1) {
                    let seg = envelope(seg);
                    if s.style != Style::Dashed {
                        let w = if s.style == Style::Thick { 3 } else { 1 };
                        chart.draw_series(LineSeries::new(seg.iter().copied(), c.stroke_width(w))).map_err(|e| anyhow::anyhow!("{e}"))?;
                    } else {
                        chart
                            .draw_series(DashedLineSeries::new(seg.iter().copied(), 5, 4, c.stroke_width(2)))
                            .map_err(|e| anyhow::anyhow!("{e}"))?;
                    }
                }
            }
        }
    }
    for b in &panel.bars {
        let c = b.color;
        for &(x, y, h) in b.points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()) {
            let h = if h.is_finite() { h } else { 0.0 };
            chart.draw_series([PathElement::new(vec![(x, y - h), (x, y + h)], c.stroke_width(2))]).map_err(|e| anyhow::anyhow!("{e}"))?;
            for end in [y - h, y + h] {
                chart
                    .draw_series([EmptyElement::at((x, end)) + PathElement::new(vec![(-5, 0), (5, 0)], c.stroke_width(2))])
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
            }
            chart
                .draw_series([EmptyElement::at((x, y)) + marker_element::<DB>(b.marker, (0, 0), c)])
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn figure() -> Figure {
        let pts: Vec<(f64, f64)> = (0..100).map(|i| (i as f64, (i as f64 * 0.1).sin())).collect();
        let mut p = Panel::new("test <&>", "x, s", "y, mm").series("sin", pts.clone(), colors::SKY, Style::Dashed).series(
            "marks",
            pts.iter().step_by(10).copied().collect(),
            colors::VERMILION,
            Style::Points(Marker::Cross),
        );
        p.bars.push(Bars { label: "bars".into(), points: vec![(10.0, 0.0, 0.5)], color: colors::BLUE, marker: Marker::Circle });
        p.hlines.push(HLine { label: "zero".into(), y: 0.0, color: colors::GREY });
        Figure { stem: "t".into(), question: "q".into(), caption: "c".into(), panels: vec![p] }
    }

    #[test]
    fn writes_svg_and_png_with_text() {
        let dir = std::env::temp_dir().join(format!("taut-figures-{}", std::process::id()));
        let mut set = Staging::new(&dir, &[]).unwrap();
        figure().write(&mut set).unwrap();
        assert!(std::fs::metadata(dir.join("t.svg")).is_err(), "nothing in place before the commit");
        set.commit().unwrap();
        for f in ["t.svg", "t.png"] {
            assert!(std::fs::metadata(dir.join(f)).unwrap().len() > 1000, "{f}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn svg_text_is_escaped_and_the_legend_is_above_the_data() {
        let svg = figure().svg().unwrap();
        assert!(svg.contains("test &lt;&amp;&gt;") && !svg.contains("test <&>"), "title not escaped");
        // Legend labels are drawn in the strip between the title and the chart: above the
        // highest data pixel of the panel.
        let y_of = |label: &str| -> f64 {
            // plotters writes `<text ...>\nLABEL\n</text>`.
            let k = svg.find(&format!("\n{label}\n</text>")).unwrap_or_else(|| panic!("label {label} missing"));
            let tag = &svg[svg[..k].rfind("<text").unwrap()..k];
            let y = tag.split("y=\"").nth(1).unwrap();
            y[..y.find('"').unwrap()].parse().unwrap()
        };
        let legend = y_of("sin");
        let top_of_data = svg
            .match_indices("<polyline")
            .filter_map(|(k, _)| {
                let pts = svg[k..].split("points=\"").nth(1)?;
                let pts = &pts[..pts.find('"')?];
                // Data lines only (the legend's glyphs are two-point lines).
                if pts.split_whitespace().count() < 10 {
                    return None;
                }
                pts.split_whitespace().filter_map(|p| p.split(',').nth(1)?.parse::<f64>().ok()).reduce(f64::min)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(legend + 4.0 < top_of_data, "legend at y = {legend}, data from y = {top_of_data}");
    }
}
