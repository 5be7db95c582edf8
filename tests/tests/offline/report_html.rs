//! `--report FILE.html` looked at the way a person would: the calibration and
//! diagnosis reports of a simulated robot with loose-cable episodes are opened in headless
//! Chromium and rendered to PNG.
//!
//! Checked:
//! - the page is self-contained: no scripts, no links to other files, and a Content-Security-Policy
//!   that forbids loading anything, so any attempt shows as a console error;
//! - Chromium exits cleanly and logs no console error while rendering the page;
//! - every figure is there (by id), is an inline SVG, and each one, rendered on its own, has drawn
//!   data: coloured pixels (the axes and text are black and grey), not an empty frame;
//! - hostile strings from outside (a file name and a robot name full of markup) arrive escaped.
//!
//! `scripts/setup-report` installs Chromium. Without it the test prints why it is skipped and
//! passes, unless `TAUT_REQUIRE_EXTERNAL=1` (as in CI), where a missing Chromium fails.

use crate::hostile;

use hostile::{good_recording, run_with_deadline, taut_bin, GOOD_CONFIG};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// A robot name and a file name that would run a script or load an image if pasted in raw.
const EVIL_ROBOT: &str = "<img src=x onerror=alert(1)>&amp;\"robot\"";
/// (No `/`: a file name cannot hold one, so no closing tag.)
const EVIL_FILE: &str = "rec<script>alert(1)<b>&'x'.csv";

fn chromium() -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|p| std::env::split_paths(&p).map(|d| d.join("chromium")).find(|c| c.is_file()));
    if found.is_none() {
        let msg = "report_html: skipped, chromium not found (run scripts/setup-report)";
        if std::env::var("TAUT_REQUIRE_EXTERNAL").is_ok_and(|v| v == "1") {
            panic!("{msg}; TAUT_REQUIRE_EXTERNAL=1 makes this a failure");
        }
        eprintln!("{msg}");
    }
    found
}

/// Renders `html` to `png` in headless Chromium; returns Chromium's stderr. Panics on a failed
/// run or a console error.
fn render(chromium: &Path, html: &Path, png: &Path, size: (u32, u32)) -> String {
    let profile = html.with_extension("profile");
    let mut cmd = Command::new(chromium);
    cmd.args([
        "--headless",
        "--disable-gpu",
        "--no-sandbox",
        "--no-first-run",
        "--disable-extensions",
        "--hide-scrollbars",
        "--enable-logging=stderr",
        "--v=0",
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    .arg(format!("--window-size={},{}", size.0, size.1))
    .arg(format!("--screenshot={}", png.display()))
    .arg(format!("file://{}", html.display()));
    let run = run_with_deadline(cmd, Duration::from_secs(180));
    assert!(!run.timed_out, "chromium did not finish rendering {} in 180 s", html.display());
    assert_eq!(run.code, Some(0), "chromium failed on {}:\n{}", html.display(), run.stderr);
    // Console messages are logged as `CONSOLE(line)] "text"`; a page with nothing to report
    // logs none. A refused resource (CSP) or a script error would be one.
    let console: Vec<&str> = run.stderr.lines().filter(|l| l.contains("CONSOLE")).collect();
    assert!(console.is_empty(), "console messages while rendering {}:\n{}", html.display(), console.join("\n"));
    assert!(png.is_file(), "no screenshot {} (stderr:\n{})", png.display(), run.stderr);
    run.stderr
}

/// Decoded RGB(A) pixels of a PNG: (width, height, channels, bytes).
fn pixels(png: &Path) -> (u32, u32, usize, Vec<u8>) {
    let dec = png::Decoder::new(std::fs::File::open(png).expect("open png"));
    let mut r = dec.read_info().expect("png header");
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).expect("png frame");
    buf.truncate(info.buffer_size());
    let ch = info.color_type.samples();
    assert!(ch >= 3, "{}: expected an RGB screenshot, got {:?}", png.display(), info.color_type);
    (info.width, info.height, ch, buf)
}

/// Pixels that are neither white nor grey (a drawn, coloured series) and all non-white ones.
fn count_ink(png: &Path) -> (usize, usize) {
    let (_, _, ch, buf) = pixels(png);
    let (mut coloured, mut ink) = (0, 0);
    for p in buf.chunks_exact(ch) {
        let (r, g, b) = (p[0] as i32, p[1] as i32, p[2] as i32);
        if r < 245 || g < 245 || b < 245 {
            ink += 1;
        }
        if (r - g).abs() > 40 || (g - b).abs() > 40 || (r - b).abs() > 40 {
            coloured += 1;
        }
    }
    (coloured, ink)
}

/// The inline SVGs of a page, with the id of the figure each belongs to.
fn figures(html: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(k) = rest.find("<figure id=\"") {
        let after = &rest[k + 12..];
        let id = after[..after.find('"').expect("closing quote of the id")].to_string();
        let s = after.find("<svg").unwrap_or_else(|| panic!("figure {id} has no inline <svg>"));
        let e = after.find("</svg>").unwrap_or_else(|| panic!("figure {id}: <svg> not closed"));
        assert!(s < e, "figure {id}: malformed svg");
        out.push((id, after[s..e + 6].to_string()));
        rest = &after[e..];
    }
    out
}

/// Static checks of the page: self-contained, escaped, all figures there.
fn check_page(html: &str, expected: &[&str]) {
    assert!(html.starts_with("<!DOCTYPE html>"), "not an HTML document");
    assert!(html.contains("Content-Security-Policy"), "no CSP: a stray resource load would go unnoticed");
    // (Tags, not attributes: the escaped robot name shows ` src=` and `onerror=` as text.)
    for bad in ["<script", "<link", "<iframe", "<img", "<object", "<embed", "<style>@import", "url(", " href="] {
        assert!(!html.contains(bad), "the page contains `{bad}`: not self-contained or not escaped");
    }
    // The hostile strings arrive as text.
    assert!(html.contains("rec&lt;script&gt;alert(1)&lt;b&gt;&amp;&#39;x&#39;.csv"), "the file name is not shown escaped");
    assert!(html.contains("id=\"verdict\""), "no verdict");
    assert!(html.contains("What to do next"), "no next steps");
    let figs = figures(html);
    let ids: Vec<&str> = figs.iter().map(|f| f.0.as_str()).collect();
    for e in expected {
        assert!(ids.contains(e), "figure {e} missing; the page has {ids:?}");
    }
    for (id, svg) in &figs {
        let drawn = svg.matches("<polyline").count() + svg.matches("<circle").count() + svg.matches("<path").count();
        assert!(drawn > 0, "figure {id}: an SVG with nothing drawn");
    }
}

/// Renders the page and each of its figures alone; every figure must show coloured data.
fn check_rendered(chromium: &Path, dir: &Path, name: &str, html: &str) {
    let page = dir.join(format!("{name}.html"));
    let png = dir.join(format!("{name}.png"));
    render(chromium, &page, &png, (1100, 9000));
    let (w, h, _, _) = pixels(&png);
    assert_eq!((w, h), (1100, 9000), "screenshot size");
    let (coloured, ink) = count_ink(&png);
    assert!(ink > 100_000 && coloured > 5_000, "{name}: the rendered page is nearly blank ({ink} dark, {coloured} coloured pixels)");
    for (id, svg) in figures(html) {
        let one = dir.join(format!("{name}-{id}.html"));
        std::fs::write(&one, format!("<!DOCTYPE html><html><body style=\"margin:0;background:#fff\">{svg}</body></html>")).unwrap();
        let shot = dir.join(format!("{name}-{id}.png"));
        render(chromium, &one, &shot, (1000, 1300));
        let (coloured, ink) = count_ink(&shot);
        eprintln!("{name} {id}: {ink} dark pixels, {coloured} coloured");
        assert!(ink > 5_000, "{name} {id}: the figure rendered nearly blank ({ink} non-white pixels)");
        assert!(coloured > 300, "{name} {id}: no coloured data drawn ({coloured} coloured pixels): axes without series?");
    }
}

#[test]
fn calibration_and_diagnosis_reports_render_in_chromium() {
    let Some(chromium) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join(EVIL_FILE);
    std::fs::write(&rec, good_recording()).unwrap();
    let cfg = dir.path().join("robot.toml");
    std::fs::write(&cfg, GOOD_CONFIG.replace("name = \"hostile\"", &format!("name = {EVIL_ROBOT:?}"))).unwrap();

    let run = |args: &[&str]| {
        let mut cmd = Command::new(taut_bin());
        cmd.current_dir(dir.path()).args(args);
        let r = run_with_deadline(cmd, Duration::from_secs(300));
        assert!(!r.timed_out && r.code == Some(0), "taut {args:?} failed:\n{}\n{}", r.stdout, r.stderr);
    };
    run(&["calibrate", EVIL_FILE, "--config", "robot.toml", "--compare", "--report", "calib.html"]);
    run(&["diagnose", EVIL_FILE, "--config", "robot.toml", "--report", "diag.html"]);

    let calib = std::fs::read_to_string(dir.path().join("calib.html")).unwrap();
    check_page(&calib, &["lengths-before-after", "errors-taut", "errors-histogram", "readings-excluded", "anchors"]);
    assert!(calib.contains("&lt;img src=x onerror=alert(1)&gt;&amp;amp;&quot;robot&quot;"), "the robot name is not shown escaped");
    for words in ["Calibrated", "σx, mm", "held-out RMS", "without force weighting"] {
        assert!(calib.contains(words), "the calibration report lacks `{words}`");
    }
    let diag = std::fs::read_to_string(dir.path().join("diag.html")).unwrap();
    check_page(&diag, &["diagnose-residual-vs-time", "diagnose-anchors"]);
    for words in ["Diagnosis of", "Effects", "σx, mm", "What to do next"] {
        assert!(diag.contains(words), "the diagnosis report lacks `{words}`");
    }

    check_rendered(&chromium, dir.path(), "calib", &calib);
    check_rendered(&chromium, dir.path(), "diag", &diag);
}

#[test]
fn a_figure_with_nothing_drawn_is_caught() {
    // The checks above must be able to fail: a page whose figure is an empty frame.
    let Some(chromium) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let svg = "<svg width=\"1000\" height=\"300\" xmlns=\"http://www.w3.org/2000/svg\"><rect x=\"0\" y=\"0\" width=\"1000\" height=\"300\" fill=\"#FFFFFF\"/><text x=\"10\" y=\"20\">axes only</text></svg>";
    let page = dir.path().join("empty.html");
    std::fs::write(&page, format!("<!DOCTYPE html><html><body style=\"margin:0\">{svg}</body></html>")).unwrap();
    let png = dir.path().join("empty.png");
    render(&chromium, &page, &png, (1000, 400));
    let (coloured, ink) = count_ink(&png);
    assert!(coloured <= 300 && ink < 5_000, "an empty figure passed the blank check: {ink} dark, {coloured} coloured pixels");
}

#[test]
fn a_page_that_loads_something_is_caught() {
    // The console check must be able to fail: a page under the report's CSP that tries to load an
    // image and run a script logs the refusals, and `render` rejects it.
    let Some(chromium) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("loads.html");
    std::fs::write(
        &page,
        "<!DOCTYPE html><html><head><meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; style-src 'unsafe-inline'\">\
         </head><body><img src=\"https://example.invalid/x.png\"><script>document.title='ran'</script></body></html>",
    )
    .unwrap();
    let png = dir.path().join("loads.png");
    let caught = std::panic::catch_unwind(|| render(&chromium, &page, &png, (400, 300)));
    let msg = caught.expect_err("a page that tries to load an image and run a script passed the console check");
    let msg = msg.downcast_ref::<String>().cloned().unwrap_or_default();
    assert!(msg.contains("Content Security Policy"), "rejected for another reason: {msg}");
}

#[test]
fn a_report_over_an_input_or_another_output_is_refused_before_any_work() {
    // `--report` is an output like `--json`: checked before the calibration runs, and the file it
    // would have replaced is left as it was. (No Chromium needed.)
    let dir = tempfile::tempdir().unwrap();
    let rec = good_recording();
    std::fs::write(dir.path().join("rec.csv"), &rec).unwrap();
    for (args, expect) in [
        (&["calibrate", "rec.csv", "--report", "rec.csv"][..], "--report"),
        (&["diagnose", "rec.csv", "--report", "rec.csv"][..], "--report"),
        (&["calibrate", "rec.csv", "--json", "out.html", "--report", "out.html"][..], "name the same file"),
    ] {
        let mut cmd = Command::new(taut_bin());
        cmd.current_dir(dir.path()).args(args);
        let r = run_with_deadline(cmd, Duration::from_secs(300));
        assert_eq!(r.code, Some(1), "taut {args:?} should refuse:\n{}", r.stderr);
        assert!(r.stderr.contains(expect), "taut {args:?}: message lacks `{expect}`:\n{}", r.stderr);
        assert_eq!(std::fs::read_to_string(dir.path().join("rec.csv")).unwrap(), rec, "taut {args:?} changed the recording");
        assert!(!dir.path().join("out.html").exists(), "taut {args:?} wrote an output");
    }
}

/// The text of the element that starts at `open` (up to its closing `close`), tags removed and
/// entities decoded (the few the report writes).
fn element_text(html: &str, open: &str, close: &str) -> String {
    let k = html.find(open).unwrap_or_else(|| panic!("no `{open}` in the page"));
    let rest = &html[k..];
    let body = &rest[..rest.find(close).unwrap_or_else(|| panic!("`{open}` not closed"))];
    let mut text = String::new();
    let mut in_tag = false;
    for c in body.chars() {
        match c {
            '<' => in_tag = true,
            '>' => in_tag = false,
            c if !in_tag => text.push(c),
            _ => {}
        }
    }
    text.replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", "\"").replace("&#39;", "'")
}

/// The verdict box: (tone class, headline, whole text).
fn verdict_box(html: &str) -> (String, String, String) {
    let k = html.find("<div class=\"verdict ").expect("a verdict box");
    let tone = html[k + 20..].split('"').next().unwrap().to_string();
    let headline = element_text(&html[k..], "<strong>", "</strong>");
    let text = element_text(&html[k..], "<div", "</div>");
    (tone, headline, text)
}

/// The "What to do next" items.
fn next_items(html: &str) -> Vec<String> {
    let k = html.find("<ol id=\"next\">").expect("a numbered list of next steps");
    let list = &html[k..k + html[k..].find("</ol>").unwrap()];
    list.split("<li>").skip(1).map(|i| element_text(&format!("<li>{i}"), "<li>", "</li>")).collect()
}

/// The number just before ` mm` after `after` in `text`.
fn mm_after(text: &str, after: &str) -> f64 {
    let k = text.find(after).unwrap_or_else(|| panic!("`{after}` not in: {text}"));
    let rest = &text[k + after.len()..];
    let num: String = rest.trim_start().chars().take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-').collect();
    num.parse().unwrap_or_else(|_| panic!("no number after `{after}` in: {text}"))
}

/// Actions, not observations: each step starts with a verb, none is a count of loose readings
/// or a raw row of a data problem, and there are few.
fn check_actions(name: &str, next: &[String]) {
    assert!(!next.is_empty() && next.len() <= 8, "{name}: {} next steps: {next:#?}", next.len());
    for item in next {
        let verb = item.split_whitespace().next().unwrap_or_default();
        assert!(["Check", "Run", "Write", "Record", "Fix", "Look", "Calibrate"].contains(&verb), "{name}: `{item}` is not an action");
        for bad in ["loose readings excluded", "row ", "e0 m", "e-1 m"] {
            assert!(!item.contains(bad), "{name}: `{item}` lists `{bad}` instead of an action");
        }
    }
}

/// Calibrate's verdict from the page agrees with the numbers in its JSON.
fn check_calibration(name: &str, html: &str, v: &serde_json::Value) {
    let (tone, headline, text) = verdict_box(html);
    assert_eq!(tone, v["verdict"]["tone"].as_str().unwrap(), "{name}: the page's tone is not the JSON's");
    assert_eq!(headline, v["verdict"]["headline"].as_str().unwrap(), "{name}: headline");
    let consistent = v["model_consistent"].as_bool().unwrap();
    let next = next_items(html);
    check_actions(name, &next);
    if consistent {
        assert_eq!((tone.as_str(), headline.as_str()), ("ok", "Calibrated."), "{name}: {text}");
        assert!(text.contains("consistent with the noise model") && !text.contains("does not explain"), "{name}: {text}");
        assert!(next.iter().any(|i| i.contains("--out")), "{name}: no step to write the parameters: {next:#?}");
    } else {
        assert_eq!(tone, "warn", "{name}");
        assert!(headline.contains("does not explain the data"), "{name}: {headline}");
        assert!(next.iter().any(|i| i.contains("taut diagnose")), "{name}: no step to diagnose: {next:#?}");
    }
    // The numbers the verdict quotes are the body's.
    let rms = mm_after(&text, "RMS");
    assert!((rms - v["rms_m"].as_f64().unwrap() * 1e3).abs() <= 0.006, "{name}: verdict RMS {rms} mm vs {}", v["rms_m"]);
    let held = mm_after(&text, "fitted readings,");
    assert!((held - v["heldout_rms_m"].as_f64().unwrap() * 1e3).abs() <= 0.006, "{name}: verdict held-out {held} mm");
    let sig = v["anchor_sigma_m"].as_array().unwrap();
    let (mut worst, mut at) = (0.0, (0, 0));
    for (j, s) in sig.iter().enumerate() {
        for (k, x) in s.as_array().unwrap().iter().enumerate() {
            if x.as_f64().unwrap() > worst {
                worst = x.as_f64().unwrap();
                at = (j, k);
            }
        }
    }
    let words = format!("cable {} {}: 1-sigma", at.0 + 1, ["x", "y", "z"][at.1]);
    let quoted = mm_after(&text, &words);
    assert!((quoted - worst * 1e3).abs() <= 0.05 * worst * 1e3, "{name}: worst sigma {quoted} mm quoted, {} mm in the JSON", worst * 1e3);
}

/// Diagnose's verdict from the page agrees with the effects and numbers in its JSON.
fn check_diagnosis(name: &str, html: &str, v: &serde_json::Value, concealed: &str) {
    let (tone, headline, text) = verdict_box(html);
    assert_eq!(tone, v["verdict"]["tone"].as_str().unwrap(), "{name}: tone");
    assert_eq!(headline, v["verdict"]["headline"].as_str().unwrap(), "{name}: headline");
    let physics: Vec<&str> =
        v["effects"].as_array().unwrap().iter().map(|e| e["effect"].as_str().unwrap()).filter(|e| *e != "slack").collect();
    let next = next_items(html);
    check_actions(name, &next);
    assert!(!text.contains("Named: slack") && !headline.contains("left to look at"), "{name}: {text}");
    if v["unexplained"].is_null() {
        assert_eq!(tone, "ok", "{name}: nothing is unexplained but the tone is {tone}: {text}");
        assert!(headline.contains("what is left is noise"), "{name}: {headline}");
    } else {
        assert!(headline.contains("unexplained"), "{name}: the body says something is unexplained, the headline does not: {headline}");
    }
    if concealed.is_empty() {
        assert!(physics.is_empty(), "{name}: effects named on a clean recording: {physics:?}");
        assert!(headline.starts_with("No effect beyond the ideal model"), "{name}: {headline}");
        assert!(next.iter().any(|i| i.starts_with("Calibrate")), "{name}: {next:#?}");
    } else {
        assert!(physics.contains(&concealed), "{name}: {concealed} not named: {physics:?}");
        for e in &physics {
            assert!(headline.contains(e), "{name}: {e} named in the body, not in the headline `{headline}`");
        }
        let before = mm_after(&text, "from");
        let after = mm_after(&text, "(ideal model) to");
        assert!((before - v["baseline"]["heldout_rms_m"].as_f64().unwrap() * 1e3).abs() <= 0.006, "{name}: {before}");
        assert!((after - v["final"]["heldout_rms_m"].as_f64().unwrap() * 1e3).abs() <= 0.006, "{name}: {after}");
        assert!(next.iter().any(|i| i.contains("taut diagnose") && i.contains("--out")), "{name}: {next:#?}");
    }
    // The body's effects table names the same effects.
    let effects = element_text(html, "<h2>Effects</h2>", "</table>");
    for e in &physics {
        assert!(effects.contains(e), "{name}: {e} missing from the Effects table");
    }
}

/// The verdicts of `taut calibrate` and `taut diagnose` agree with their bodies (issue 24), on a
/// clean simulated recording and on one with a concealed cable stretch; the pages are rendered
/// in headless Chromium with the verdict box's colour. `TAUT_UPDATE_SCREENSHOTS=1` copies the
/// top of each page into docs/screenshots/ for the README.
#[test]
fn verdicts_agree_with_the_body() {
    use taut_sim::{simulate, Physics, Scenario};
    let dir = tempfile::tempdir().unwrap();
    let mut pages = Vec::new();
    for (name, physics, concealed) in
        [("clean", Physics::default(), ""), ("stretch", Physics { elasticity: Some(20_000.0), ..Physics::default() }, "elasticity")]
    {
        let mut s = Scenario::aras_cam(3);
        s.three_phase = None;
        s.duration_s = 90.0;
        s.rate_hz = 20.0;
        s.physics = physics;
        let rec = format!("{name}.csv");
        simulate(&s).recording.save_atomic(dir.path().join(&rec)).unwrap();
        for cmd in ["calibrate", "diagnose"] {
            let (json, html) = (format!("{cmd}-{name}.json"), format!("{cmd}-{name}.html"));
            let mut c = Command::new(taut_bin());
            c.current_dir(dir.path()).args([cmd, rec.as_str(), "--json", json.as_str(), "--report", html.as_str()]);
            let r = run_with_deadline(c, Duration::from_secs(300));
            assert!(!r.timed_out && r.code == Some(0), "taut {cmd} {rec}:\n{}", r.stderr);
            let page = std::fs::read_to_string(dir.path().join(&html)).unwrap();
            let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join(&json)).unwrap()).unwrap();
            assert_eq!(v["robot"], "aras-cam", "{cmd} {name}: the robot is named as the recording names it");
            assert!(page.contains("<title>") && page.contains("of aras-cam"), "{cmd} {name}: not named after the recording's robot");
            assert!(!page.contains("Unix time") && page.contains("written by taut"), "{cmd} {name}: time stamp");
            assert!(page.contains("id=\"terms\"") && page.contains("docs/reports.md"), "{cmd} {name}: no Terms appendix into docs/");
            if cmd == "calibrate" {
                check_calibration(&format!("{cmd} {name}"), &page, &v);
            } else {
                check_diagnosis(&format!("{cmd} {name}"), &page, &v, concealed);
            }
            pages.push((format!("{cmd}-{name}"), v["verdict"]["tone"].as_str().unwrap().to_string()));
        }
    }
    let Some(chromium) = chromium() else { return };
    let shots = std::env::var("TAUT_UPDATE_SCREENSHOTS").is_ok_and(|v| v == "1");
    let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/screenshots");
    for (name, tone) in &pages {
        let png = dir.path().join(format!("{name}.png"));
        render(&chromium, &dir.path().join(format!("{name}.html")), &png, (1100, 1500));
        // The verdict box is drawn in its tone's colour (green #009e73, amber #e69f00).
        let want: [i32; 3] = if tone == "ok" { [0, 158, 115] } else { [230, 159, 0] };
        let (_, _, ch, buf) = pixels(&png);
        let border = buf.chunks_exact(ch).filter(|p| (0..3).all(|i| (p[i] as i32 - want[i]).abs() <= 10)).count();
        assert!(border > 500, "{name}: the {tone} verdict box is not drawn ({border} px of its colour)");
        if shots {
            std::fs::create_dir_all(&docs).unwrap();
            std::fs::copy(&png, docs.join(format!("{name}.png"))).unwrap();
        }
    }
}
