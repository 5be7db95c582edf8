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
use taut_calib::diagnose::{Diagnosis, Effect, Finding, Sharing};
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
th{background:#eee}td.l,th.l{text-align:left}td.l:first-child{white-space:nowrap}.verdict{border:2px solid #333;padding:.6em 1em;margin:1em 0}\
.ok{border-color:#009e73}.warn{border-color:#e69f00}.fail{border-color:#d55e00}\
figure{margin:1em 0}figure svg{max-width:100%;height:auto;display:block}figcaption{font-size:.92em;color:#333}\
.meta{color:#444;font-size:.92em}dt{font-weight:bold;margin-top:.5em}dd{margin-left:1.5em}";

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

/// Metres as millimetres, 2 decimals (an RMS of thousands of readings is known to well below
/// 0.01 mm relative to its size); `-` when not a number.
fn mm(v: f64) -> String {
    if v.is_finite() {
        format!("{:.2}", v * 1e3)
    } else {
        "-".into()
    }
}

use taut_config::numfmt::{plus_minus, rounded, sig2};

fn generated() -> String {
    format!("written by taut {} on {}", env!("CARGO_PKG_VERSION"), taut_operator::localtime::now())
}

/// How the solver stopped, in words.
pub(crate) fn termination_words(t: taut_calib::solver::Termination) -> &'static str {
    use taut_calib::solver::Termination::*;
    match t {
        SmallStep => "its steps became negligible",
        SmallCostChange => "the error stopped falling",
        SmallGradient => "the error has no slope left",
        MaxIterations => "it ran out of iterations",
        Stalled => "no step lowered the error any more",
    }
}

/// What to do about a data problem of kind `kind` (the `name()` of a screen's wild value or of
/// a diagnosis's data problem) on `who` (a cable's label, or the tracker), `count` times.
fn data_action(kind: &str, who: Option<&str>, count: usize) -> String {
    let who = who.unwrap_or("the tracker");
    match kind {
        "tracker-jump" | "tracker-outlier" => {
            format!("Check the tracker's markers and line of sight: {count} position(s) jumped beyond its noise and were excluded.")
        }
        "tracker-dropout" => format!("Check the tracker's line of sight: {count} sample(s) had no position and were excluded."),
        "frozen-tracker" => "Check the tracker: it repeated one position while the encoders moved.".into(),
        "frozen-encoder" => format!("Check the encoder of {who}: it repeated one reading while the platform moved."),
        "encoder-spike" => format!("Check the encoder wiring of {who}: {count} reading(s) far from their neighbours were excluded."),
        "encoder-jump" => format!("Check {who} for lost encoder counts: {count} step(s) that stay were re-referenced."),
        "dead-load-cell" => format!("Check the load cell of {who}: it reads nothing, so its tensions were ignored."),
        "impossible-tension" => format!("Check the load cell of {who}: {count} impossible tension(s) were excluded."),
        "stale-row" => format!("Check the logger: {count} row(s) paired a new pose with the previous lengths and were left out."),
        "clock-jump" => "Check the logger's clock: time went backwards, repeated or jumped.".into(),
        other => format!("Look at the {other} data problems listed below ({count})."),
    }
}

/// One action per kind of problem and cable, in the order first met: (kind, cable, count).
fn grouped(items: impl Iterator<Item = (&'static str, Option<usize>, usize)>) -> Vec<(&'static str, Option<usize>, usize)> {
    let mut out: Vec<(&'static str, Option<usize>, usize)> = Vec::new();
    for (k, c, n) in items {
        // The tracker's problems are the tracker's, whatever cable they were found on.
        let c = if k.starts_with("tracker") { None } else { c };
        match out.iter_mut().find(|g| g.0 == k && g.1 == c) {
            Some(g) => g.2 += n,
            None => out.push((k, c, n)),
        }
    }
    out
}

/// At most this many actions; the rest are counted.
const MAX_ACTIONS: usize = 6;

/// The data problems' actions, short.
fn data_actions(cfg: &RobotConfig, groups: &[(&'static str, Option<usize>, usize)]) -> Vec<String> {
    let mut v: Vec<String> =
        groups.iter().take(MAX_ACTIONS).map(|(k, c, n)| data_action(k, c.map(|j| cfg.cable_label(j)).as_deref(), *n)).collect();
    if groups.len() > MAX_ACTIONS {
        v.push(format!("Look at the other {} kinds of data problem listed under Data problems.", groups.len() - MAX_ACTIONS));
    }
    v
}

/// The next steps in order: the main actions, the sensor checks, then the last step (use the
/// result); at most `MAX_ACTIONS + 2`, the checks cut first (the rest are under Data problems).
fn finish_next(mut next: Vec<String>, mut checks: Vec<String>, last: Option<String>) -> Vec<String> {
    let limit = MAX_ACTIONS + 2;
    next.truncate(limit - usize::from(last.is_some()) - usize::from(!checks.is_empty()));
    let room = limit - next.len() - usize::from(last.is_some());
    if checks.len() > room {
        checks.truncate(room.saturating_sub(1));
        checks.push("Look at the other data problems listed under Data problems.".into());
    }
    next.extend(checks);
    next.extend(last);
    next
}

/// A verdict: how it reads, its headline, the sentences that back it, and what to do next.
#[derive(Debug, Clone)]
pub struct Verdict {
    /// Good, to look at, or refused.
    pub tone: Tone,
    /// One line.
    pub headline: String,
    /// The numbers behind it.
    pub sentences: Vec<String>,
    /// Actions, a short list.
    pub next: Vec<String>,
}

impl Verdict {
    /// The verdict as JSON (`verdict` in the `--json` documents).
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "tone": match self.tone { Tone::Ok => "ok", Tone::Warn => "warn", Tone::Fail => "fail" },
            "headline": self.headline,
            "sentences": self.sentences,
            "next": self.next,
        })
    }
}

/// The words for the report's appendix: what each term means and where `docs/` explains it.
const TERMS: &[(&str, &str, &str)] = &[
    (
        "taut reading",
        "A reading of a cable taken while its tension was at or above the loose threshold (calibration.min_tension_n). Only taut \
         readings measure the straight line from anchor to platform; loose (slack) ones are excluded from the fit.",
        "docs/reports.md#taut-and-loose-readings",
    ),
    (
        "measured minus modelled length",
        "The encoder's cable length minus the length the model predicts from the tracked pose: the fit's error, per reading.",
        "docs/reports.md#the-fit",
    ),
    (
        "held-out RMS",
        "The RMS error on the end of the recording the fit did not see: how well the model predicts, not how well it memorises.",
        "docs/diagnosis.md#held-out-time-blocked-data",
    ),
    (
        "1-sigma (σ)",
        "The standard uncertainty of an estimate: about 2 in 3 repeats of the recording would land within ± 1 σ. Values are \
         rounded to two significant digits of their σ.",
        "docs/reports.md#numbers",
    ),
    (
        "Cramér-Rao bound",
        "The smallest σ any unbiased estimator could reach with these readings and this noise model; the calibration's σ near \
         it means the data were used well.",
        "docs/reports.md#the-fit",
    ),
    (
        "model check",
        "Every reading is held out once (a 5-block cross-fit) and its error compared with what the noise model predicts; t, \
         dof (degrees of freedom) and p are the one-sided t test of that comparison. p below the false-alarm rate (1e-3) says \
         the readings are not what the model and its noise predict.",
        "docs/diagnosis.md#when-taut-calibrate-says-the-model-does-not-explain-the-data",
    ),
    (
        "solver stop",
        "The least-squares solver stops when its steps become negligible (SmallStep), the error stops falling \
         (SmallCostChange) or has no slope left (SmallGradient): all three mean converged. MaxIterations and Stalled do not.",
        "docs/reports.md#the-fit",
    ),
    (
        "held-out test (t, dof, n, n_eff, p)",
        "A candidate effect is named only when it predicts held-out data better than the current model: t is the test \
         statistic, dof its degrees of freedom, n the held-out samples compared, n_eff how many independent ones they are worth \
         (fewer when the noise is correlated), p the chance of a gain this large from noise alone.",
        "docs/diagnosis.md#the-test-does-the-candidate-predict-held-out-data-better",
    ),
    (
        "slack",
        "The diagnosis's name for loose-cable readings: excluded below the threshold tension, not a physical effect to model.",
        "docs/reports.md#taut-and-loose-readings",
    ),
    (
        "data problem",
        "A reading that cannot be right (a tracker jump, a frozen or lost encoder count, an impossible tension, a stale row): \
         found before the fit, excluded or repaired, and listed.",
        "docs/inputs.md#recordings",
    ),
];

/// The appendix: the terms the page uses, each with the `docs/` page that explains it.
fn terms(page: &mut Page, used: &[&str]) {
    page.h2("Terms used in this report");
    page.html.push_str("<dl id=\"terms\">");
    for (term, words, doc) in TERMS.iter().filter(|t| used.contains(&t.0)) {
        let _ = write!(page.html, "<dt>{}</dt><dd>{} See <code>{}</code>.</dd>", escape(term), escape(words), escape(doc));
    }
    page.html.push_str("</dl>\n");
}

/// "What to do next" as a numbered list (`id="next"`).
fn next_steps(page: &mut Page, items: &[String]) {
    page.h2("What to do next");
    page.html.push_str("<ol id=\"next\">");
    for i in items {
        let _ = write!(page.html, "<li>{}</li>", escape(i));
    }
    page.html.push_str("</ol>\n");
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

/// The sensors' noise as one length: tracker and encoder 1-sigma combined, m.
fn noise_of(cfg: &RobotConfig) -> f64 {
    (cfg.calibration.tracker_sigma_m.powi(2) + cfg.calibration.encoder_sigma_m.powi(2)).sqrt()
}

/// The calibration's verdict and next steps, from the outcome alone (the page's body shows the
/// same numbers).
pub fn calibration_verdict(cfg: &RobotConfig, out: &Outcome, ctx: &CalibrationContext) -> Verdict {
    let f = &out.force;
    let n = f.params.anchors.len();
    let (mut worst, mut worst_at) = (0.0f64, (0usize, 0usize));
    for (j, s) in f.sigma.anchors.iter().enumerate() {
        for (k, v) in s.iter().enumerate() {
            if !v.is_finite() || *v > worst {
                worst = *v;
                worst_at = (j, k);
            }
        }
    }
    let converged = f.termination.was_successful();
    let noise = noise_of(cfg);
    let mut says = vec![
        format!(
            "The solver {} after {} iterations ({}), on {} taut readings of {} cables ({} excluded).",
            if converged { "converged" } else { "did not converge" },
            f.iterations,
            termination_words(f.termination),
            f.samples_used,
            n,
            f.samples_excluded
        ),
        format!(
            "Measured minus modelled length: RMS {} mm on the fitted readings, {} mm held out; the sensors' noise alone gives about {} mm.",
            mm(f.rms_m),
            mm(f.heldout_rms_m),
            mm(noise)
        ),
        format!(
            "The least certain anchor coordinate is {} {}: 1-sigma {} mm.",
            taut_config::cable_name(worst_at.0),
            ["x", "y", "z"][worst_at.1],
            sig2(worst * 1e3)
        ),
    ];
    match &f.consistency {
        Some(c) if !c.consistent => says.push(format!(
            "The model does not explain the data: in the model check's cross-fit the RMS is {} mm against {} mm predicted by the \
             noise model. The estimates may be biased beyond their stated sigmas.",
            mm(c.heldout_rms_m),
            mm(c.expected_rms_m)
        )),
        Some(c) => says.push(format!(
            "Model check: consistent with the noise model (cross-fit RMS {} mm against {} mm predicted).",
            mm(c.heldout_rms_m),
            mm(c.expected_rms_m)
        )),
        None => {}
    }
    let wild = out.screen.findings.len();
    if wild > 0 || out.stale_rows > 0 {
        says.push(format!(
            "{} data problem(s) were excluded before the fit (listed under Data problems).",
            wild + usize::from(out.stale_rows > 0)
        ));
    }
    let (tone, headline) = match &ctx.refused {
        Some(why) => {
            says.insert(0, format!("{why}."));
            says.push("No parameters were written; the parameters in use stay as they are.".into());
            (Tone::Fail, "Refused.")
        }
        None if !converged => (Tone::Warn, "Calibrated, but the solver did not converge."),
        None if !f.model_consistent() => (Tone::Warn, "Calibrated, but the model does not explain the data."),
        None => (Tone::Ok, "Calibrated."),
    };
    if let Some(p) = ctx.params_out {
        if ctx.refused.is_none() {
            says.push(format!("The parameters were written to {p}."));
        }
    }
    // Actions only; what the fit noticed goes under Notes.
    let mut next: Vec<String> = Vec::new();
    if ctx.refused.is_some() {
        next.push("Fix what the verdict names, record again with the cables taut and the platform moved through the whole workspace, then calibrate again.".into());
    } else if !converged {
        next.push("Record again, moving the platform over more of the workspace in all three directions, and calibrate again.".into());
    }
    let consistent = f.model_consistent();
    if ctx.refused.is_none() && !consistent {
        next.push(format!(
            "Run `taut diagnose {} --out params.toml` to find the physics the ideal model leaves out (stretch, sag, pulleys, scale, \
             time offset, backlash) and write the model with it.",
            ctx.source
        ));
    } else if ctx.refused.is_none() && f.heldout_rms_m.is_finite() && f.heldout_rms_m > 2.0 * noise {
        next.push(format!(
            "Check the noise model in [calibration]: the held-out error ({} mm) is more than twice the sensors' noise ({} mm); or run `taut diagnose {}`.",
            mm(f.heldout_rms_m),
            mm(noise),
            ctx.source
        ));
    }
    let groups = grouped(out.screen.findings.iter().map(|w| (w.kind.name(), w.cable, 1)).chain((out.stale_rows > 0).then_some((
        "stale-row",
        None,
        out.stale_rows,
    ))));
    let last = (ctx.refused.is_none() && converged && consistent).then(|| match ctx.params_out {
        None => format!(
            "Write the parameters with `taut calibrate {} --out params.toml` and run the robot with them: `taut start --params params.toml`.",
            ctx.source
        ),
        Some(p) => format!("Run the robot with them: `taut start --params {p}`."),
    });
    let next = finish_next(next, data_actions(cfg, &groups), last);
    Verdict { tone, headline: headline.into(), sentences: says, next }
}

/// The calibration report.
pub fn calibration(rec: &Recording, parse: &ParseReport, cfg: &RobotConfig, out: &Outcome, ctx: &CalibrationContext) -> Result<String> {
    let f = &out.force;
    let n = rec.n_cables;
    let mut page = Page::new(&format!("Calibration of {}", cfg.robot.name));
    page.meta(&format!(
        "recording {}; configuration {}; {}",
        ctx.source,
        ctx.config.unwrap_or("none (point-mass platform, default noise model)"),
        generated()
    ));
    let v = calibration_verdict(cfg, out, ctx);
    page.verdict(v.tone, &v.headline, &v.sentences);
    next_steps(&mut page, &v.next);
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
        2,
    );

    page.h2("Anchors and encoder offsets");
    page.p("Anchors in the tracker frame, m, each coordinate rounded to two significant digits of its 1-sigma (in mm beside it; \
         scaled by the fit's reduced chi-square when that exceeds 1).");
    let nominal = cfg.anchors().filter(|a| a.len() == n);
    let rows: Vec<Vec<String>> = (0..n)
        .map(|j| {
            let a = f.params.anchors[j];
            let i = out.init.params.anchors[j];
            let s = f.sigma.anchors[j];
            let smax = s.iter().copied().fold(0.0, f64::max);
            let moved = ((a[0] - i[0]).powi(2) + (a[1] - i[1]).powi(2) + (a[2] - i[2]).powi(2)).sqrt();
            let from_nominal = nominal.as_ref().map_or("-".to_string(), |nom| {
                let d = ((a[0] - nom[j][0]).powi(2) + (a[1] - nom[j][1]).powi(2) + (a[2] - nom[j][2]).powi(2)).sqrt();
                rounded(d * 1e3, smax * 1e3)
            });
            let mut row = vec![cfg.cable_label(j)];
            row.extend(anchor_cells(a, s));
            row.push(rounded(moved * 1e3, smax * 1e3));
            if nominal.is_some() {
                row.push(from_nominal);
            }
            row.extend([rounded(f.params.l0[j], f.sigma.l0[j]), sig2(f.sigma.l0[j] * 1e3)]);
            row
        })
        .collect();
    let mut head = vec!["cable", "x, m", "y, m", "z, m", "σx, mm", "σy, mm", "σz, mm", "moved from initial, mm"];
    if nominal.is_some() {
        head.push("from nominal, mm");
    }
    head.extend(["L0, m", "σL0, mm"]);
    page.table(&head, &rows, 1);
    let crb = crate::report::rms_sigma(&out.crb.anchor_sigma);
    page.p(&format!(
        "Cramér-Rao bound at this estimate (the best any unbiased estimator could do with these readings): RMS anchor 1-sigma {} mm.",
        sig2(crb * 1e3)
    ));

    page.h2("Fit");
    let mut rows = vec![vec!["before calibration (initial estimate)".into(), mm(out.before.rms), mm(out.before.peak), String::new()]];
    if let Some(p) = &out.plain {
        rows.push(vec!["after, without force weighting".into(), mm(p.rms_m), mm(p.peak_m), mm(p.heldout_rms_m)]);
    }
    rows.push(vec!["after, force-aware".into(), mm(f.rms_m), mm(f.peak_m), mm(f.heldout_rms_m)]);
    page.table(&["measured minus modelled length, taut readings", "RMS, mm", "peak, mm", "held-out RMS, mm"], &rows, 1);
    page.p(&format!(
        "The solver stopped after {} iterations because {} ({:?}).",
        f.iterations,
        termination_words(f.termination),
        f.termination
    ));
    if let Some(c) = &f.consistency {
        page.p(&format!(
            "Model check: held-out RMS {} mm against {} mm predicted; chi-square ratio {:.2}, t = {:.1} with {:.0} degrees of freedom, \
             p = {:.1e} (false-alarm rate {:.0e}); {} readings at {} held-out samples.",
            mm(c.heldout_rms_m),
            mm(c.expected_rms_m),
            c.ratio,
            c.statistic,
            c.dof,
            c.p_value,
            c.alpha,
            c.readings,
            c.samples
        ));
    }

    if !out.screen.findings.is_empty() || !parse.notes.is_empty() || out.stale_rows > 0 {
        page.h2("Data problems");
        let mut items: Vec<String> = out.screen.findings.iter().take(50).map(|w| format!("{w} ({})", w.kind.name())).collect();
        if out.screen.findings.len() > 50 {
            items.push(format!("and {} more wild values", out.screen.findings.len() - 50));
        }
        if out.stale_rows > 0 {
            items.push(format!(
                "{} rows repeat every encoder reading of the row before while the platform moves (stale-row); left out",
                out.stale_rows
            ));
        }
        items.extend(parse.notes.iter().cloned());
        page.list(&items);
        page.meta("Rows are counted from 0, the first data row after the header.");
    }

    page.h2("Figures");
    for fig in crate::figures::calibration::figures(rec, cfg, out) {
        page.figure(&fig)?;
    }
    terms(
        &mut page,
        &[
            "taut reading",
            "measured minus modelled length",
            "held-out RMS",
            "1-sigma (σ)",
            "Cramér-Rao bound",
            "model check",
            "solver stop",
            "data problem",
        ],
    );
    Ok(page.finish())
}

/// An effect's parameter as people write it: label, unit and scale from the model's SI value.
fn parameter_words(e: Effect) -> (&'static str, &'static str, f64) {
    e.model().parameter_words()
}

/// An effect's values with their 1-sigma: `EA 19740 ± 570 N` (shared) or one per cable.
fn effect_values(f: &Finding) -> String {
    let (label, unit, k) = parameter_words(f.effect);
    let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
    let vals: Vec<String> = f
        .values
        .iter()
        .zip(f.sigmas.iter().chain(std::iter::repeat(&f64::NAN)))
        .map(|(v, s)| format!("{}{unit}", plus_minus(v * k, s * k)))
        .collect();
    if f.effect.sharing() == Sharing::PerCable && vals.len() > 1 {
        let per: Vec<String> = vals.iter().enumerate().map(|(j, v)| format!("{v} ({})", taut_config::cable_name(j))).collect();
        format!("{label} {}", per.join(", "))
    } else {
        format!("{label} {}", vals.join(", "))
    }
}

/// The diagnosis's verdict and next steps.
pub fn diagnosis_verdict(d: &Diagnosis, cfg: &RobotConfig, source: &str, refused: Option<&str>) -> Verdict {
    let physics: Vec<&Finding> = d.effects.iter().filter(|f| f.effect != Effect::Slack).collect();
    let slack = d.effects.iter().find(|f| f.effect == Effect::Slack);
    let mut says = Vec::new();
    if let Some(why) = refused {
        says.push(format!("{why}."));
    }
    let names: Vec<&str> = physics.iter().map(|f| f.effect.name()).collect();
    if !physics.is_empty() {
        says.push(format!(
            "Modelling {} brings the held-out error from {} mm (ideal model) to {} mm.",
            names.join(" and "),
            mm(d.baseline.heldout_rms_m),
            mm(d.final_fit.heldout_rms_m)
        ));
        for f in &physics {
            says.push(format!("{}: {}.", f.effect.name(), effect_values(f)));
        }
    } else {
        says.push(format!(
            "Held-out error {} mm with the ideal model; no candidate effect predicts the data better.",
            mm(d.final_fit.heldout_rms_m)
        ));
    }
    if let Some(s) = slack {
        says.push(format!("{} readings of loose cables were excluded.", s.samples.unwrap_or(0)));
    }
    if !d.data_problems.is_empty() {
        says.push(format!("{} data problem(s) were excluded (listed under Data problems).", d.data_problems.len()));
    }
    if let Some(u) = &d.unexplained {
        says.push(u.clone());
    }
    let (tone, headline) = if refused.is_some() {
        (Tone::Fail, "Refused.".to_string())
    } else if d.unexplained.is_some() {
        (
            Tone::Warn,
            format!(
                "Something is left unexplained{}.",
                if names.is_empty() { String::new() } else { format!(" after modelling {}", names.join(" and ")) }
            ),
        )
    } else if !names.is_empty() {
        (Tone::Ok, format!("Found: {}. With it modelled, what is left is noise.", names.join(" and ")))
    } else {
        (Tone::Ok, "No effect beyond the ideal model: what is left is noise.".to_string())
    };
    let mut next: Vec<String> = Vec::new();
    if refused.is_some() {
        next.push("Fix what the verdict names and record again.".into());
    }
    if d.unexplained.is_some() {
        next.push(
            "Look at the residual figures below for drifts, steps or episodes, and at the data problems; record again with the suspect \
             part of the robot exercised."
                .into(),
        );
    }
    for f in &physics {
        for (e, _) in &f.equally_good {
            next.push(format!(
                "Record moving where {} and {} differ (they fit equally well here), then diagnose again to tell them apart.",
                f.effect.name(),
                e.name()
            ));
        }
    }
    let groups = grouped(d.data_problems.iter().map(|p| (p.kind.name(), p.cable, p.samples.max(1))));
    let last = refused.is_none().then(|| {
        if physics.is_empty() {
            format!("Calibrate with the ideal model: `taut calibrate {source} --out params.toml`.")
        } else {
            format!(
                "Write the model with {}: `taut diagnose {source} --out params.toml`, and run the robot with it: `taut start --params params.toml`.",
                names.join(" and ")
            )
        }
    });
    let next = finish_next(next, data_actions(cfg, &groups), last);
    Verdict { tone, headline, sentences: says, next }
}

/// The diagnosis report.
pub fn diagnosis(d: &Diagnosis, source: &str, cfg: &RobotConfig, refused: Option<String>) -> Result<String> {
    let mut page = Page::new(&format!("Diagnosis of {}", cfg.robot.name));
    page.meta(&format!("recording {source}; {}", generated()));
    let v = diagnosis_verdict(d, cfg, source, refused.as_deref());
    page.verdict(v.tone, &v.headline, &v.sentences);
    next_steps(&mut page, &v.next);

    page.h2("Effects");
    if d.effects.is_empty() {
        page.p("None named.");
    } else {
        let rows: Vec<Vec<String>> = d
            .effects
            .iter()
            .map(|f| {
                vec![
                    f.effect.name().to_string(),
                    effect_values(f),
                    f.evidence.clone(),
                    mm(f.heldout_rms_before_m),
                    mm(f.heldout_rms_after_m),
                ]
            })
            .collect();
        page.table(&["effect", "parameters ± 1-sigma", "evidence", "held-out before, mm", "held-out after, mm"], &rows, 3);
    }
    if !d.rejected.is_empty() {
        page.h2("Candidates not named");
        page.p("Each candidate's held-out test (see Terms): a candidate is named only when its p is below its alpha.");
        page.list(&d.rejected);
    }
    if !d.notes.is_empty() {
        page.h2("Notes");
        page.list(&d.notes);
    }
    page.h2("Model");
    let fin = &d.final_fit;
    let rows: Vec<Vec<String>> = (0..fin.params.anchors.len())
        .map(|j| {
            let a = fin.params.anchors[j];
            let s = fin.sigma.anchors.get(j).copied().unwrap_or([f64::NAN; 3]);
            let sl0 = fin.sigma.l0.get(j).copied().unwrap_or(f64::NAN);
            let mut row = vec![cfg.cable_label(j)];
            row.extend(anchor_cells(a, s));
            row.extend([
                rounded(fin.params.l0[j], sl0),
                sig2(sl0 * 1e3),
                mm(d.baseline.per_cable_rms_m.get(j).copied().unwrap_or(f64::NAN)),
                mm(fin.per_cable_rms_m.get(j).copied().unwrap_or(f64::NAN)),
            ]);
            row
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
    if !d.data_problems.is_empty() {
        page.h2("Data problems");
        let items: Vec<String> = d.data_problems.iter().map(|p| format!("{} ({})", p.description, p.kind.name())).collect();
        page.list(&items);
        page.meta("Rows are counted from 0, the first data row after the header.");
    }
    page.h2("Figures");
    for fig in crate::figures::diagnosis::figures(d) {
        page.figure(&fig)?;
    }
    terms(
        &mut page,
        &[
            "taut reading",
            "measured minus modelled length",
            "held-out RMS",
            "1-sigma (σ)",
            "held-out test (t, dof, n, n_eff, p)",
            "slack",
            "data problem",
        ],
    );
    Ok(page.finish())
}

/// An anchor's three coordinates rounded to their sigmas, then the three sigmas in mm: the
/// cells every anchor table of the reports has after the cable.
fn anchor_cells(a: [f64; 3], s: [f64; 3]) -> [String; 6] {
    [rounded(a[0], s[0]), rounded(a[1], s[1]), rounded(a[2], s[2]), sig2(s[0] * 1e3), sig2(s[1] * 1e3), sig2(s[2] * 1e3)]
}

#[cfg(test)]
mod next_tests {
    use super::{finish_next, MAX_ACTIONS};

    #[test]
    fn the_last_step_survives_many_checks() {
        let checks: Vec<String> = (0..20).map(|k| format!("Check sensor {k}.")).collect();
        let next = finish_next(vec!["Run taut diagnose.".into()], checks, Some("Write the parameters.".into()));
        assert_eq!(next.len(), MAX_ACTIONS + 2, "{next:#?}");
        assert_eq!(next[0], "Run taut diagnose.");
        assert_eq!(next.last().unwrap(), "Write the parameters.");
        assert!(next[next.len() - 2].starts_with("Look at the other data problems"), "{next:#?}");
        let few = finish_next(vec![], vec!["Check the tracker.".into()], None);
        assert_eq!(few, vec!["Check the tracker.".to_string()]);
    }
}
