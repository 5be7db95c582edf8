//! Hostile output paths: outputs are never destructive. A device node, symlink,
//! directory or fifo at an output path is refused, never replaced; an output that is an input
//! (by any name) is refused; a write that fails midway leaves the old file; figures go into place
//! all or nothing.

use crate::hostile;

use hostile::{good_recording, run_suite, Case, Entry, GOOD_CONFIG};

fn dev_full_is_a_device() -> Result<(), String> {
    use std::os::unix::fs::FileTypeExt;
    match std::fs::symlink_metadata("/dev/full") {
        Ok(m) if m.file_type().is_char_device() => Ok(()),
        _ => Err("/dev/full is no longer a device node".into()),
    }
}

fn dev_null_is_a_device() -> Result<(), String> {
    use std::os::unix::fs::FileTypeExt;
    match std::fs::symlink_metadata("/dev/null") {
        Ok(m) if m.file_type().is_char_device() => Ok(()),
        _ => Err("/dev/null is no longer a device node".into()),
    }
}

/// `taut calibrate rec.csv` with `extra` arguments; the recording is in place.
fn cal(name: &str, extra: &[&str], expect: &[&str]) -> Case {
    let mut args = vec!["calibrate", "rec.csv"];
    args.extend_from_slice(extra);
    Case::err(name, &args, expect).file("rec.csv", good_recording())
}

/// `taut simulate` (short, no three-phase) with `extra` arguments.
fn sim(name: &str, extra: &[&str], expect: &[&str]) -> Case {
    let mut args = vec!["simulate", "--no-three-phase", "--duration", "2"];
    args.extend_from_slice(extra);
    Case::err(name, &args, expect)
}

fn cases() -> Vec<Case> {
    let old_params = "format = \"taut-params v1\"\n# the parameters the robot runs on\n";
    vec![
        // The input is never an output, by whatever name.
        cal(
            "calibrate same.csv --out same.csv",
            &["--out", "rec.csv"],
            &["--out: rec.csv", "is the input file", "choose another output path"],
        ),
        cal("--out ./rec.csv", &["--out", "./rec.csv"], &["is the input file"]),
        cal("--out sub/../rec.csv", &["--out", "sub/../rec.csv"], &["is the input file"]).entry("sub", Entry::Dir),
        cal("--out a hard link of the input", &["--out", "hard.csv"], &["--out: hard.csv", "is the input file"])
            .entry("hard.csv", Entry::HardLink("rec.csv".into())),
        cal("--json rec.csv", &["--json", "rec.csv"], &["--json: rec.csv", "is the input file"]),
        cal("--out the config", &["--config", "cfg.toml", "--out", "cfg.toml"], &["--out: cfg.toml", "is the input file"])
            .file("cfg.toml", GOOD_CONFIG),
        cal("--json and --out the same", &["--json", "p.toml", "--out", "p.toml"], &["--json and --out name the same file"]),
        cal("--json and --out the same via ./", &["--json", "p.toml", "--out", "./p.toml"], &["name the same file"]),
        // Not a regular file: refused, and left as it was.
        cal("--out /dev/full", &["--out", "/dev/full"], &["/dev/full: is a device node", "refusing to replace it"])
            .after(dev_full_is_a_device),
        cal("--out /dev/null", &["--out", "/dev/null"], &["/dev/null: is a device node"]).after(dev_null_is_a_device),
        cal("--out a symlink", &["--out", "link.toml"], &["link.toml: is a symlink"])
            .file("current.toml", old_params)
            .entry("link.toml", Entry::Symlink("current.toml".into())),
        cal("--out a dangling symlink", &["--out", "link.toml"], &["link.toml: is a symlink"])
            .entry("link.toml", Entry::Symlink("/nonexistent/x".into())),
        cal("--out a symlink to the input", &["--out", "link.csv"], &["link.csv: is a symlink"])
            .entry("link.csv", Entry::Symlink("rec.csv".into())),
        cal("--out a directory", &["--out", "params"], &["params: is a directory"]).entry("params", Entry::Dir),
        cal("--out a fifo", &["--out", "pipe"], &["pipe: is a fifo"]).entry("pipe", Entry::Fifo),
        cal("--json a fifo", &["--json", "pipe"], &["--json: pipe: is a fifo"]).entry("pipe", Entry::Fifo),
        cal("--out in a missing directory", &["--out", "nodir/p.toml"], &["nodir/p.toml: its directory does not exist"]),
        cal("--out ends in a slash", &["--out", "params/"], &["params/"]).entry("params", Entry::Dir),
        cal("--plot a regular file", &["--plot", "figs"], &["--plot: figs is not a directory"]).file("figs", "not a directory"),
        cal("--plot a symlink to a file", &["--plot", "figs"], &["--plot: figs is a symlink"])
            .file("f", "x")
            .entry("figs", Entry::Symlink("f".into())),
        // A figure that would replace a symlink: the whole set is refused after rendering, the
        // old figures stay as they were, no staging directory is left behind.
        cal("--plot over a symlinked figure", &["--plot", "figs"], &["lengths-before-after.svg: is a symlink"])
            .file("figs/errors-taut.svg", "<svg>old figure</svg>")
            .file("elsewhere.svg", "keep")
            .entry("figs/lengths-before-after.svg", Entry::Symlink("../elsewhere.svg".into())),
        // simulate's outputs.
        sim("-o /dev/full", &["-o", "/dev/full"], &["--output: /dev/full: is a device node"]).after(dev_full_is_a_device),
        sim("-o a symlink", &["-o", "rec.csv"], &["--output: rec.csv: is a symlink"])
            .file("real.csv", "keep")
            .entry("rec.csv", Entry::Symlink("real.csv".into())),
        sim("-o a directory", &["-o", "out"], &["is a directory"]).entry("out", Entry::Dir),
        sim("-o a fifo", &["-o", "pipe"], &["is a fifo"]).entry("pipe", Entry::Fifo),
        sim("-o the config", &["--config", "cfg.toml", "-o", "cfg.toml"], &["--output: cfg.toml", "is the input file"])
            .file("cfg.toml", GOOD_CONFIG),
        sim("--truth the config", &["--config", "cfg.toml", "--truth", "cfg.toml"], &["--truth: cfg.toml", "is the input file"])
            .file("cfg.toml", GOOD_CONFIG),
        sim("-o and --truth the same", &["-o", "x.csv", "--truth", "x.csv"], &["--output and --truth name the same file"]),
        sim("--truth /dev/full", &["--truth", "/dev/full"], &["--truth: /dev/full"]).after(dev_full_is_a_device),
        Case::err("diagnose --json the input", &["diagnose", "rec.csv", "--json", "rec.csv"], &["--json: rec.csv", "is the input file"])
            .file("rec.csv", good_recording()),
        Case::err("diagnose --plot a file", &["diagnose", "rec.csv", "--plot", "rec.csv"], &["--plot: rec.csv is not a directory"])
            .file("rec.csv", good_recording()),
        Case::err("demo -o /dev/full", &["demo", "--duration", "1", "-o", "/dev/full"], &["/dev/full: is a device node"])
            .after(dev_full_is_a_device),
        Case::err("probe --log /dev/full", &["probe", "--sim", "--log", "/dev/full"], &["--log: /dev/full: is a device node"])
            .after(dev_full_is_a_device),
        Case::err("probe --log a symlink", &["probe", "--sim", "--log", "bus.log"], &["--log: bus.log: is a symlink"])
            .file("precious.txt", "keep")
            .entry("bus.log", Entry::Symlink("precious.txt".into())),
        cal("--out a 300-character name", &["--out", &"p".repeat(300)], &["--out: ppp", "File name too long"]),
        cal("--out under a file", &["--out", "rec.csv/p.toml"], &["--out: rec.csv/p.toml: its directory does not exist"]),
        // A write that fails midway (file size limit; SIGXFSZ ignored so write(2) fails with
        // EFBIG) leaves the old file as it was and no temporary file.
        Case::err("interrupted simulate -o keeps the old recording", &[], &["writing old.csv", "File too large"])
            .shell("trap '' XFSZ; ulimit -f 8; exec \"$TAUT\" simulate --no-three-phase --duration 20 -o old.csv")
            .file("old.csv", "# cdpr-recording v1\n# the only copy of yesterday's run\n"),
        Case::err("interrupted calibrate --out keeps the old parameters", &[], &["writing p.toml", "File too large"])
            .shell("trap '' XFSZ; ulimit -f 1; exec \"$TAUT\" calibrate rec.csv --out p.toml")
            .file("rec.csv", good_recording())
            .file("p.toml", old_params),
        Case::err(
            "interrupted --plot keeps the old figures",
            &[],
            &["writing figs/lengths-before-after.svg", "figures already there are kept", "File too large"],
        )
        .shell("trap '' XFSZ; ulimit -f 2; exec \"$TAUT\" calibrate rec.csv --plot figs")
        .file("rec.csv", good_recording())
        .file("figs/lengths-before-after.svg", "<svg>old 7</svg>")
        .file("figs/errors-taut.svg", "<svg>old 8</svg>"),
        Case::err(
            "interrupted --plot into a new directory leaves no directory",
            &[],
            &["writing newfigs/lengths-before-after.svg", "File too large"],
        )
        .shell("trap '' XFSZ; ulimit -f 2; exec \"$TAUT\" calibrate rec.csv --plot newfigs")
        .file("rec.csv", good_recording()),
        Case::err(
            "demo --truth /dev/full",
            &["demo", "--duration", "1", "--truth", "/dev/full"],
            &["--truth: /dev/full: is a device node"],
        )
        .after(dev_full_is_a_device),
        // The controls: an existing regular file is replaced, a new one created.
        Case::ok(
            "simulate -o over a regular file",
            &["simulate", "--no-three-phase", "--duration", "1", "-o", "old.csv"],
            &["wrote old.csv"],
        )
        .file("old.csv", "old")
        .writes("old.csv"),
        Case::ok(
            "calibrate --out --json new files",
            &["calibrate", "rec.csv", "--out", "p.toml", "--json", "r.json"],
            &["parameters written to p.toml"],
        )
        .file("rec.csv", good_recording())
        .writes("p.toml")
        .writes("r.json"),
    ]
}

#[test]
fn hostile_outputs() {
    let t = run_suite("outputs", cases());
    t.finish("outputs");
}
