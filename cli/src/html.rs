//! `--report FILE.html`: a calibration or diagnosis as one self-contained HTML page (no scripts,
//! no external resources): the verdict in words, what to do next, the tables with their
//! uncertainties and the figures inline as SVG. Opened in any browser, mailed, archived.
//!
//! Every string that comes from outside (file names, robot names, notes that quote fields of a
//! recording) goes through [`escape`]; only this module's own markup and the SVG that plotters
//! writes (which escapes its text) go in raw.

use crate::calibrate::Outcome;
use crate::figures::Figure;
use anyhow::Result;
use std::fmt::Write as _;
use taut_calib::diagnose::Diagnosis;
use taut_config::recording::{ParseReport, Recording};
use taut_config::RobotConfig;

/// Text made safe for HTML element content and quoted attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            // Control characters (a NUL, an escape sequence in a file name) are shown, not passed on.
            c if c.is_control() && c != '\n' && c != '\t' => {
                let _ = write!(o, "\\u{{{:x}}}", c as u32);
            }
            c => o.push(c),
        }
    }
    o
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1040px;margin:1.5em auto;padding:0 1em;color:#111;line-height:1.4}\
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;border-bottom:1px solid #aaa;margin-top:1.6em}\
h3{font-size:1.05em;margin-bottom:.2em}table{border-collapse:collapse;margin:.6em 0}\
th,td{border:1px solid #bbb;padding:.2em .6em;text-align:right;font-variant-numeric:tabular-nums}\
th{background:#eee}td.l,th.l{text-align:left}.verdict{border:2px solid #333;padding:.6em 1em;margin:1em 0}\
.ok{border-color:#009e73}.warn{border-color:#e69f00}.fail{border-color:#d55e00}\
figure{margin:1em 0}figure svg{max-width:100%;height:auto;display:block}figcaption{font-size:.92em;color:#333}\
.meta{color:#444;font-size:.92em}";

/// How a verdict reads: good, to look at, or refused.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Tone {
    /// The result can be used.
    Ok,
    /// Usable, with something to look at.
    Warn,
    /// Refused or failed.
    Fail,
}

/// A page under construction. Methods taking `&str` escape it; none takes raw HTML from outside.
pub struct Page {
    html: String,
}

impl Page {
    /// A page with this title (escaped).
    pub fn new(title: &str) -> Self {
        let mut html = String::with_capacity(1 << 16);
        let _ = write!(
            html,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width\">\
             <meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; style-src 'unsafe-inline'\">\
             <title>{}</title><style>{STYLE}</style></head><body>\n<h1>{}</h1>\n",
            escape(title),
            escape(title)
        );
        Page { html }
    }

    /// A section heading.
    pub fn h2(&mut self, s: &str) {
        let _ = writeln!(self.html, "<h2>{}</h2>", escape(s));
    }

    /// A paragraph.
    pub fn p(&mut self, s: &str) {
        let _ = writeln!(self.html, "<p>{}</p>", escape(s));
    }

    /// A small grey paragraph (provenance).
    pub fn meta(&mut self, s: &str) {
        let _ = writeln!(self.html, "<p class=\"meta\">{}</p>", escape(s));
    }

    /// The verdict box: a headline and sentences.
    pub fn verdict(&mut self, tone: Tone, headline: &str, sentences: &[String]) {
        let class = match tone {
            Tone::Ok => "ok",
            Tone::Warn => "warn",
            Tone::Fail => "fail",
        };
        let _ = write!(self.html, "<div class=\"verdict {class}\" id=\"verdict\"><strong>{}</strong>", escape(headline));
        for s in sentences {
            let _ = write!(self.html, " {}", escape(s));
        }
        self.html.push_str("</div>\n");
    }

    /// A bulleted list.
    pub fn list(&mut self, items: &[String]) {
        if items.is_empty() {
            return;
        }
        self.html.push_str("<ul>");
        for i in items {
            let _ = write!(self.html, "<li>{}</li>", escape(i));
        }
        self.html.push_str("</ul>\n");
    }

    /// A table; the first `left` columns are text (left-aligned), the rest numbers.
    pub fn table(&mut self, head: &[&str], rows: &[Vec<String>], left: usize) {
        self.html.push_str("<table><tr>");
        for (k, h) in head.iter().enumerate() {
            let _ = write!(self.html, "<th{}>{}</th>", if k < left { " class=\"l\"" } else { "" }, escape(h));
        }
        self.html.push_str("</tr>\n");
        for r in rows {
            self.html.push_str("<tr>");
            for (k, c) in r.iter().enumerate() {
                let _ = write!(self.html, "<td{}>{}</td>", if k < left { " class=\"l\"" } else { "" }, escape(c));
            }
            self.html.push_str("</tr>\n");
        }
        self.html.push_str("</table>\n");
    }

    /// A figure: its question as a heading, the SVG inline, how to read it below.
    pub fn figure(&mut self, f: &Figure) -> Result<()> {
        let svg = f.svg()?;
        // A viewBox lets the browser scale the figure to the page width.
        let svg = match svg.find("<svg ") {
            Some(k) => {
                let (w, h) = f.size();
                format!("{}<svg viewBox=\"0 0 {w} {h}\" role=\"img\" aria-label=\"{}\" {}", &svg[..k], escape(&f.question), &svg[k + 5..])
            }
            None => svg,
        };
        let _ = write!(
            self.html,
            "<figure id=\"{}\"><h3>{}</h3>\n{svg}\n<figcaption>{}</figcaption></figure>\n",
            escape(&f.stem),
            escape(&f.question),
            escape(&f.caption)
        );
        Ok(())
    }

    /// The finished document.
    pub fn finish(mut self) -> String {
        self.html.push_str("</body></html>\n");
        self.html
    }
}

fn mm(v: f64) -> String {
    if v.is_finite() {
        format!("{:.2}", v * 1e3)
    } else {
        "-".into()
    }
}

fn m4(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "-".into()
    }
}

fn generated() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    format!("written by taut {} at Unix time {secs}", env!("CARGO_PKG_VERSION"))
}

/// What a calibration report needs beyond the outcome.
pub struct CalibrationContext<'a> {
    /// The recording's path as given.
    pub source: &'a str,
    /// The configuration's path, if one was given.
    pub config: Option<&'a str>,
    /// Why the trust checks refused the result, if they did.
    pub refused: Option<String>,
    /// Where the parameters were written (`--out`), if they were.
    pub params_out: Option<&'a str>,
}

/// The calibration report.
pub fn calibration(rec: &Recording, parse: &ParseReport, cfg: &RobotConfig, out: &Outcome, ctx: &CalibrationContext) -> Result<String> {
    let f = &out.force;
    let n = rec.n_cables;
    let mut page = Page::new(&format!("Calibration of {} from {}", cfg.robot.name, ctx.source));
    page.meta(&format!(
        "recording {}; configuration {}; {}",
        ctx.source,
        ctx.config.unwrap_or("none (point-mass platform, default noise model)"),
        generated()
    ));
    // The verdict: the largest 1-sigma, the fit, and whether the result may be used.
    let (mut worst, mut worst_at) = (0.0f64, (0usize, 0usize));
    for (j, s) in f.sigma.anchors.iter().enumerate() {
        for (k, v) in s.iter().enumerate() {
            if !v.is_finite() || *v > worst {
                worst = *v;
                worst_at = (j, k);
            }
        }
    }
    let converged = !matches!(f.termination, taut_calib::solver::Termination::MaxIterations | taut_calib::solver::Termination::Stalled);
    let noise = (cfg.calibration.tracker_sigma_m.powi(2) + cfg.calibration.encoder_sigma_m.powi(2)).sqrt();
    let mut says = vec![
        format!(
            "The solver {} ({:?}, {} iterations) on {} readings of {} cables ({} excluded).",
            if converged { "converged" } else { "did not converge" },
            f.termination,
            f.iterations,
            f.samples_used,
            n,
            f.samples_excluded
        ),
        format!(
            "Measured minus modelled length: RMS {} mm on the fitted readings, {} mm on the held-out end of the recording; the noise model \
             alone expects about {} mm.",
            mm(f.rms_m),
            mm(f.heldout_rms_m),
            mm(noise)
        ),
        format!("The least certain anchor coordinate is cable {} {}: 1-sigma {} mm.", worst_at.0, ["x", "y", "z"][worst_at.1], mm(worst)),
    ];
    match &f.consistency {
        Some(c) if !c.consistent => says.push(format!(
            "The model does not explain the data: {}. The estimates may be biased beyond their stated sigmas; run `taut diagnose` on this recording.",
            c.numbers()
        )),
        Some(c) => says.push(format!("Model check: consistent with the noise model ({}).", c.numbers())),
        None => {}
    }
    let (tone, headline) = match &ctx.refused {
        Some(why) => {
            says.insert(0, format!("{why}."));
            says.push("No parameters were written; the parameters in use stay as they are.".into());
            (Tone::Fail, "Refused.")
        }
        None if !converged => (Tone::Warn, "Calibrated, but the solver did not converge."),
        None if !f.model_consistent() => (Tone::Warn, "Calibrated, but the model does not explain the data."),
        None if !out.screen.findings.is_empty() => (Tone::Warn, "Calibrated, with data problems excluded."),
        None => (Tone::Ok, "Calibrated."),
    };
    if let Some(p) = ctx.params_out {
        if ctx.refused.is_none() {
            says.push(format!("The parameters were written to {p}."));
        }
    }
    page.verdict(tone, headline, &says);

    page.h2("What to do next");
    // Actions only; what the fit noticed (counts of loose readings, rows without a tracker)
    // follows under "Notes".
    let mut next: Vec<String> = Vec::new();
    if ctx.refused.is_some() {
        next.push("Record again with the cables taut and the platform moved through the whole workspace, then calibrate again.".into());
    } else if ctx.params_out.is_none() {
        next.push("Write these parameters with `--out params.toml` to use them in the robot.".into());
    }
    if f.heldout_rms_m.is_finite() && f.heldout_rms_m > 2.0 * noise {
        next.push(format!(
            "The held-out error ({} mm) is more than twice what the sensors' noise explains ({} mm): run `taut diagnose` on this \
             recording to look for physics the ideal model leaves out (sag, elasticity, pulleys, time offset, backlash).",
            mm(f.heldout_rms_m),
            mm(noise)
        ));
    }
    if !out.screen.findings.is_empty() {
        next.push(format!(
            "{} wild values were screened out as data problems (listed below): check the sensors and cables named there.",
            out.screen.findings.len()
        ));
    }
    if next.is_empty() {
        next.push("Nothing: the fit is at the noise the sensors explain.".into());
    }
    page.list(&next);
    if !f.notes.is_empty() {
        page.h2("Notes");
        page.list(&f.notes);
    }

    page.h2("Recording");
    let dur = rec.t.last().unwrap_or(&0.0) - rec.t.first().unwrap_or(&0.0);
    page.table(
        &["what", "value"],
        &[
            vec!["samples".into(), parse.rows.to_string()],
            vec!["cables".into(), n.to_string()],
            vec!["duration, s".into(), format!("{dur:.1}")],
            vec!["rows without a tracker position".into(), parse.missing_position.to_string()],
            vec![
                "tensions".into(),
                if f.used_tensions { "used (force-aware weights, loose readings excluded)".into() } else { "none: uniform weights".into() },
            ],
            vec!["initialisation".into(), out.init.method.to_string()],
        ],
        1,
    );

    page.h2("Anchors and encoder offsets");
    page.p("Anchors A_j in the tracker frame, m; 1-sigma uncertainties in mm (scaled by the fit's reduced chi-square when it exceeds 1).");
    let rows: Vec<Vec<String>> = (0..n)
        .map(|j| {
            let a = f.params.anchors[j];
            let i = out.init.params.anchors[j];
            let s = f.sigma.anchors[j];
            let moved = ((a[0] - i[0]).powi(2) + (a[1] - i[1]).powi(2) + (a[2] - i[2]).powi(2)).sqrt();
            vec![
                format!("cable {j}"),
                m4(a[0]),
                m4(a[1]),
                m4(a[2]),
                mm(s[0]),
                mm(s[1]),
                mm(s[2]),
                mm(moved),
                m4(f.params.l0[j]),
                mm(f.sigma.l0[j]),
            ]
        })
        .collect();
    page.table(&["cable", "x, m", "y, m", "z, m", "σx, mm", "σy, mm", "σz, mm", "moved from initial, mm", "L0, m", "σL0, mm"], &rows, 1);
    let crb = crate::report::rms_sigma(&out.crb.anchor_sigma);
    page.p(&format!(
        "Cramér-Rao bound at this estimate (the best any unbiased estimator could do with these readings): RMS anchor 1-sigma {} mm.",
        mm(crb)
    ));

    page.h2("Fit");
    let mut rows = vec![vec!["before calibration (initial estimate)".into(), mm(out.before.rms), mm(out.before.peak), String::new()]];
    if let Some(p) = &out.plain {
        rows.push(vec!["after, without force weighting".into(), mm(p.rms_m), mm(p.peak_m), mm(p.heldout_rms_m)]);
    }
    rows.push(vec!["after, force-aware".into(), mm(f.rms_m), mm(f.peak_m), mm(f.heldout_rms_m)]);
    page.table(&["measured - modelled length, taut readings", "RMS, mm", "peak, mm", "held-out RMS, mm"], &rows, 1);

    if !out.screen.findings.is_empty() || !parse.notes.is_empty() {
        page.h2("Data problems and notes");
        let mut items: Vec<String> = out.screen.findings.iter().take(50).map(|w| format!("{w} ({})", w.kind.name())).collect();
        if out.screen.findings.len() > 50 {
            items.push(format!("and {} more wild values", out.screen.findings.len() - 50));
        }
        items.extend(parse.notes.iter().cloned());
        page.list(&items);
    }

    page.h2("Figures");
    for fig in crate::figures::calibration::figures(rec, cfg, out) {
        page.figure(&fig)?;
    }
    Ok(page.finish())
}

/// A value and its 1-sigma rounded to the sigma's two significant digits: `19740 ± 570`,
/// `1.0555 ± 0.0023`. Without a usable sigma, the value to 4 decimals.
pub fn plus_minus(v: f64, s: f64) -> String {
    if !(s.is_finite() && s > 0.0 && v.is_finite()) {
        return format!("{v:.4}");
    }
    let decimals = 1 - s.log10().floor() as i32;
    if decimals > 0 {
        let d = decimals as usize;
        format!("{v:.d$} ± {s:.d$}")
    } else {
        let unit = 10f64.powi(-decimals);
        let r = |x: f64| (x / unit).round() * unit;
        format!("{:.0} ± {:.0}", r(v), r(s))
    }
}

/// The diagnosis report.
pub fn diagnosis(d: &Diagnosis, source: &str, robot: &str, refused: Option<String>) -> Result<String> {
    let mut page = Page::new(&format!("Diagnosis of {robot} from {source}"));
    page.meta(&format!("recording {source}; {}", generated()));
    let mut says = Vec::new();
    if let Some(why) = &refused {
        says.push(format!("{why}."));
    }
    if d.effects.is_empty() {
        says.push("No effect beyond the ideal model was found.".into());
    } else {
        let names: Vec<&str> = d.effects.iter().map(|f| f.effect.name()).collect();
        says.push(format!("Named: {}.", names.join(", ")));
    }
    says.push(format!(
        "Held-out RMS {} mm with the ideal model, {} mm with the named effects.",
        mm(d.baseline.heldout_rms_m),
        mm(d.final_fit.heldout_rms_m)
    ));
    if let Some(u) = &d.unexplained {
        says.push(u.clone());
    }
    let tone = if refused.is_some() {
        Tone::Fail
    } else if d.unexplained.is_some() || !d.data_problems.is_empty() {
        Tone::Warn
    } else {
        Tone::Ok
    };
    let headline = match tone {
        Tone::Fail => "Refused.",
        Tone::Warn => "Diagnosed, with something left to look at.",
        Tone::Ok => "Diagnosed.",
    };
    page.verdict(tone, headline, &says);

    page.h2("What to do next");
    let mut next: Vec<String> = Vec::new();
    for p in &d.data_problems {
        next.push(format!("Data problem ({}): {}", p.kind.name(), p.description));
    }
    for f in &d.effects {
        for (e, r) in &f.equally_good {
            next.push(format!(
                "{} and {} fit equally well (held-out {} mm): a recording that moves along the direction where they differ would tell them apart.",
                f.effect.name(),
                e.name(),
                mm(*r)
            ));
        }
    }
    next.extend(d.notes.iter().cloned());
    if next.is_empty() {
        next.push("Nothing: the named effects bring the fit to the noise.".into());
    }
    page.list(&next);

    page.h2("Effects");
    if d.effects.is_empty() {
        page.p("None named.");
    } else {
        let rows: Vec<Vec<String>> = d
            .effects
            .iter()
            .map(|f| {
                let vals: Vec<String> =
                    f.values.iter().zip(f.sigmas.iter().chain(std::iter::repeat(&f64::NAN))).map(|(v, s)| plus_minus(*v, *s)).collect();
                vec![
                    f.effect.name().to_string(),
                    format!("{}: {}", f.effect.parameter(), vals.join(", ")),
                    mm(f.heldout_rms_before_m),
                    mm(f.heldout_rms_after_m),
                    f.evidence.clone(),
                ]
            })
            .collect();
        page.table(&["effect", "parameters ± 1-sigma", "held-out before, mm", "held-out after, mm", "evidence"], &rows, 2);
    }
    if !d.rejected.is_empty() {
        page.h2("Candidates not named");
        page.list(&d.rejected);
    }
    page.h2("Model");
    let fin = &d.final_fit;
    let rows: Vec<Vec<String>> = (0..fin.params.anchors.len())
        .map(|j| {
            let a = fin.params.anchors[j];
            let s = fin.sigma.anchors.get(j).copied().unwrap_or([f64::NAN; 3]);
            vec![
                format!("cable {j}"),
                m4(a[0]),
                m4(a[1]),
                m4(a[2]),
                mm(s[0]),
                mm(s[1]),
                mm(s[2]),
                m4(fin.params.l0[j]),
                mm(fin.sigma.l0.get(j).copied().unwrap_or(f64::NAN)),
                mm(d.baseline.per_cable_rms_m.get(j).copied().unwrap_or(f64::NAN)),
                mm(fin.per_cable_rms_m.get(j).copied().unwrap_or(f64::NAN)),
            ]
        })
        .collect();
    page.table(
        &["cable", "x, m", "y, m", "z, m", "σx, mm", "σy, mm", "σz, mm", "L0, m", "σL0, mm", "RMS ideal, mm", "RMS final, mm"],
        &rows,
        1,
    );
    if !d.mismatch.words.is_empty() {
        page.h2("Where the ideal model misses");
        page.list(&d.mismatch.words);
    }
    page.h2("Figures");
    for fig in crate::figures::diagnosis::figures(d) {
        page.figure(&fig)?;
    }
    Ok(page.finish())
}

#[cfg(test)]
mod plus_minus_tests {
    use super::plus_minus;

    #[test]
    fn values_are_rounded_to_their_uncertainty() {
        assert_eq!(plus_minus(19737.0827, 565.2190), "19740 ± 570");
        assert_eq!(plus_minus(1.05552, 0.0023), "1.0555 ± 0.0023");
        assert_eq!(plus_minus(0.0123456, 0.00098), "0.01235 ± 0.00098");
        assert_eq!(plus_minus(-2.71234, 0.25), "-2.71 ± 0.25");
        assert_eq!(plus_minus(2.5, f64::NAN), "2.5000");
        assert_eq!(plus_minus(2.5, 0.0), "2.5000");
    }
}
