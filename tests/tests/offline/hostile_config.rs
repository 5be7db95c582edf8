//! Hostile robot configurations: every value with physical bounds, arrays of exactly
//! three numbers, degenerate geometry; each refused with the file, line and key, never a panic.

use crate::hostile;

use hostile::{good_recording, run_suite, Case, Entry, GOOD_CONFIG};

/// `taut simulate --config cfg.toml` on `text`.
fn sim(name: &str, text: &str, expect: &[&str]) -> Case {
    Case::err(name, &["simulate", "--config", "cfg.toml", "--duration", "1", "-o", "out.csv"], expect).file("cfg.toml", text)
}

/// The good configuration with line `line` (1-based) replaced.
fn line(k: usize, new: &str) -> String {
    GOOD_CONFIG.lines().enumerate().map(|(i, l)| format!("{}\n", if i + 1 == k { new } else { l })).collect()
}

fn cases() -> Vec<Case> {
    let many = format!("[{}]", vec!["1.0"; 1000].join(", "));
    let cables = |anchors: &[&str]| -> String {
        let mut s = String::from("[robot]\nname = \"x\"\nmass_kg = 3.0\n");
        for a in anchors {
            s.push_str(&format!("[[cable]]\nanchor = {a}\n"));
        }
        s
    };
    let nine: Vec<String> = (0..9)
        .map(|j| {
            let a = j as f64 * std::f64::consts::TAU / 9.0;
            format!("[{:.3}, {:.3}, 4.0]", 3.0 * a.cos(), 3.0 * a.sin())
        })
        .collect();
    let nine: Vec<&str> = nine.iter().map(String::as_str).collect();
    vec![
        // Points of exactly three numbers.
        sim("anchor of 4 numbers", &line(5, "anchor = [3.5, -1.75, 4.0, 9.0]"), &["cfg.toml:5", "cable[0].anchor", "found 4"]),
        sim("anchor of 1000 numbers", &line(7, &format!("anchor = {many}")), &["cfg.toml:7", "cable[1].anchor", "found 1000"]),
        sim("anchor of 2 numbers", &line(9, "anchor = [3.5, 1.75]"), &["cfg.toml:9", "cable[2].anchor", "found 2"]),
        sim("anchor empty", &line(11, "anchor = []"), &["cfg.toml:11", "cable[3].anchor", "found 0"]),
        sim("anchor a string", &line(5, "anchor = \"north-east\""), &["cfg.toml:5", "cable[0].anchor"]),
        sim("anchor nan", &line(5, "anchor = [nan, 0.0, 4.0]"), &["cfg.toml:4", "cable[0].anchor", "finite"]),
        sim("anchor inf", &line(7, "anchor = [3.5, inf, 4.0]"), &["cfg.toml:6", "cable[1].anchor", "finite"]),
        sim(
            "platform point of 4",
            &format!("{GOOD_CONFIG}platform_point = [0, 0, 0, 1]\n"),
            &["cfg.toml:12", "cable[3].platform_point", "found 4"],
        ),
        sim(
            "workspace of 4",
            &format!("{GOOD_CONFIG}[motion]\nworkspace_min_m = [0, 0, 0, 0]\n"),
            &["cfg.toml:13", "motion.workspace_min_m", "found 4"],
        ),
        sim(
            "init phase of 4 cables",
            &format!("{GOOD_CONFIG}[motion]\ninit_phases = [[0, 1, 2, 3], [1, 2, 0], [2, 0, 1]]\n"),
            &["cfg.toml:13", "motion.init_phases", "found 4"],
        ),
        // Geometry.
        sim("coincident anchors", &line(7, "anchor = [3.5, -1.75, 4.0]"), &["cfg.toml:6", "cable[1].anchor", "apart"]),
        sim("anchors 1 mm apart", &line(7, "anchor = [3.501, -1.75, 4.0]"), &["cfg.toml:6", "cable[1].anchor", "apart"]),
        sim("tiny frame", &cables(&["[0, 0, 1]", "[0.1, 0, 1]", "[0, 0.1, 1]", "[0.1, 0.1, 1]"]), &["cfg.toml:4", "span only"]),
        sim("collinear anchors", &cables(&["[0, 0, 4]", "[1, 0, 4]", "[2, 0, 4]", "[3, 0, 4]"]), &["cfg.toml:4", "one line"]),
        sim(
            "anchors in mm",
            &cables(&["[3500, -1750, 4000]", "[3500, 1750, 4000]", "[-3500, 1750, 4000]"]),
            &["cable[0].anchor", "1000 m"],
        ),
        sim(
            "platform larger than the frame",
            &format!("{GOOD_CONFIG}platform_point = [9, 0, 0]\n"),
            &["cfg.toml:10", "cable[3].platform_point", "cannot fit inside its frame"],
        ),
        sim("9 cables", &cables(&nine), &["cfg.toml:20", "at most 8 cables"]),
        sim("2 cables", &cables(&["[1, 0, 3]", "[-1, 0, 3]"]), &["cfg.toml", "at least 3"]),
        sim("no anchors to simulate", "[robot]\nname = \"x\"\nmass_kg = 3.0\n[[cable]]\n[[cable]]\n[[cable]]\n", &["cfg.toml", "anchor"]),
        // Swivel-pulley axes: a direction, any finite non-zero length.
        sim(
            "pulley axis zero",
            &format!("{GOOD_CONFIG}pulley_axis = [0, 0, 0]\n"),
            &["cfg.toml:12", "cable[3].pulley_axis", "zero vector"],
        ),
        sim(
            "pulley axis 1e-9",
            &format!("{GOOD_CONFIG}pulley_axis = [1e-9, 0, 0]\n"),
            &["cfg.toml:12", "cable[3].pulley_axis", "zero vector"],
        ),
        sim("pulley axis nan", &format!("{GOOD_CONFIG}pulley_axis = [nan, 0, 1]\n"), &["cfg.toml:12", "cable[3].pulley_axis", "finite"]),
        sim("pulley axis inf", &format!("{GOOD_CONFIG}pulley_axis = [0, -inf, 1]\n"), &["cfg.toml:12", "cable[3].pulley_axis", "finite"]),
        sim(
            "pulley axis whose length overflows",
            &format!("{GOOD_CONFIG}pulley_axis = [1e300, 1e300, 0]\n"),
            &["cfg.toml:12", "cable[3].pulley_axis", "finite"],
        ),
        sim("pulley axis of 4", &format!("{GOOD_CONFIG}pulley_axis = [1, 0, 0, 0]\n"), &["cfg.toml:12", "cable[3].pulley_axis", "found 4"]),
        sim("pulley axis a string", &format!("{GOOD_CONFIG}pulley_axis = \"horizontal\"\n"), &["cfg.toml:12", "cable[3].pulley_axis"]),
        sim(
            "pulley axis of cable 0",
            &line(5, "anchor = [3.5, -1.75, 4.0]\npulley_axis = [0.0, 0.0, 0.0]"),
            &["cfg.toml:6", "cable[0].pulley_axis"],
        ),
        // Mass.
        sim("mass 1e-9 kg", &line(3, "mass_kg = 1e-9"), &["cfg.toml:3", "robot.mass_kg", "0.01 to 5000"]),
        sim("mass 1e308 kg", &line(3, "mass_kg = 1e308"), &["cfg.toml:3", "robot.mass_kg", "got 1e308"]),
        sim("mass 0", &line(3, "mass_kg = 0.0"), &["cfg.toml:3", "robot.mass_kg"]),
        sim("mass negative", &line(3, "mass_kg = -3.0"), &["cfg.toml:3", "robot.mass_kg"]),
        sim("mass nan", &line(3, "mass_kg = nan"), &["cfg.toml:3", "robot.mass_kg"]),
        sim("mass a string", &line(3, "mass_kg = \"3 kg\""), &["cfg.toml:3", "robot.mass_kg"]),
        // Other tables.
        sim("unknown key", &line(3, "mas_kg = 3.0"), &["cfg.toml", "mas_kg"]),
        sim(
            "heldout fraction 2",
            &format!("{GOOD_CONFIG}[calibration]\nheldout_fraction = 2.0\n"),
            &["cfg.toml:12", "calibration.heldout_fraction"],
        ),
        sim(
            "negative tracker sigma",
            &format!("{GOOD_CONFIG}[calibration]\ntracker_sigma_m = -1.0\n"),
            &["cfg.toml:12", "calibration.tracker_sigma_m"],
        ),
        sim("loop rate 1e9", &format!("{GOOD_CONFIG}[rt]\nrate_hz = 1e9\n"), &["cfg.toml:12", "rt.rate_hz"]),
        sim("not TOML", "this is = = not toml\n", &["cfg.toml:1"]),
        sim("binary config", "\u{0}\u{1}\u{2}garbage", &["cfg.toml"]),
        sim("empty config", "", &["cfg.toml", "robot"]),
        Case::err("config is a directory", &["simulate", "--config", "cfg", "-o", "out.csv"], &["cfg", "cannot read"])
            .entry("cfg", Entry::Dir),
        Case::err(
            "config /dev/zero",
            &["simulate", "--config", "/dev/zero", "-o", "out.csv"],
            &["/dev/zero: cannot read the file", "NUL byte"],
        ),
        Case::err(
            "config /dev/urandom",
            &["simulate", "--config", "/dev/urandom", "-o", "out.csv"],
            &["/dev/urandom: cannot read the file"],
        ),
        Case::err("config a fifo nobody writes to", &["simulate", "--config", "cfg.fifo", "-o", "out.csv"], &["cfg.fifo", "is a fifo"])
            .entry("cfg.fifo", Entry::Fifo),
        Case::err(
            "config of 2 MB",
            &["simulate", "--config", "cfg.toml", "-o", "out.csv"],
            &["cfg.toml: cannot read the file", "larger than 1024 KiB"],
        )
        .file("cfg.toml", format!("{GOOD_CONFIG}# {}\n", "x".repeat(2 << 20))),
        Case::err("a recording given as the config", &["calibrate", "rec.csv", "--config", "rec.csv"], &["rec.csv:"])
            .file("rec.csv", good_recording()),
        Case::err("config missing", &["simulate", "--config", "nope.toml", "-o", "out.csv"], &["nope.toml", "cannot read"]),
        // calibrate and diagnose read the same configurations.
        Case::err("calibrate: anchor of 4", &["calibrate", "rec.csv", "--config", "cfg.toml"], &["cfg.toml:5", "cable[0].anchor"])
            .file("rec.csv", good_recording())
            .file("cfg.toml", line(5, "anchor = [3.5, -1.75, 4.0, 9.0]")),
        Case::err(
            "calibrate: 3 cables for a 4-cable recording",
            &["calibrate", "rec.csv", "--config", "cfg.toml"],
            &["cfg.toml: the configuration has 3 [[cable]] tables", "4 length columns"],
        )
        .file("rec.csv", good_recording())
        .file("cfg.toml", cables(&["[2, 0, 3]", "[-1, 1.7, 3]", "[-1, -1.7, 3]"])),
        Case::err("diagnose: mass nan", &["diagnose", "rec.csv", "--config", "cfg.toml"], &["cfg.toml:3", "robot.mass_kg"])
            .file("rec.csv", good_recording())
            .file("cfg.toml", line(3, "mass_kg = nan")),
        Case::err(
            "diagnose: load-cell sigma negative",
            &["diagnose", "rec.csv", "--config", "cfg.toml"],
            &["cfg.toml:13", "calibration.loadcell_sigma_n", "0 (exact) to 1000"],
        )
        .file("rec.csv", good_recording())
        .file("cfg.toml", format!("{GOOD_CONFIG}[calibration]\nloadcell_sigma_n = -0.3\n")),
        Case::err(
            "calibrate: pulley axis zero",
            &["calibrate", "rec.csv", "--config", "cfg.toml"],
            &["cfg.toml:12", "cable[3].pulley_axis", "zero vector"],
        )
        .file("rec.csv", good_recording())
        .file("cfg.toml", format!("{GOOD_CONFIG}pulley_axis = [0, 0, 0]\n")),
        Case::err(
            "diagnose: pulley axis nan",
            &["diagnose", "rec.csv", "--config", "cfg.toml"],
            &["cfg.toml:12", "cable[3].pulley_axis", "finite"],
        )
        .file("rec.csv", good_recording())
        .file("cfg.toml", format!("{GOOD_CONFIG}pulley_axis = [nan, 0, 1]\n")),
        Case::err(
            "diagnose: --loadcell-offset nan",
            &["diagnose", "rec.csv", "--loadcell-offset", "nan"],
            &["--loadcell-offset NaN", "0 (exact) to 1000"],
        )
        .file("rec.csv", good_recording()),
        // At the bounds: the simulator either simulates or says why it cannot, never panics.
        sim("mass 0.01 kg: three-phase infeasible", &line(3, "mass_kg = 0.01"), &["cannot simulate this robot", "three-phase plan"]),
        sim(
            "0.35 m frame: no equilibrium",
            &cables(&["[0.2, 0, 1]", "[-0.1, 0.17, 1]", "[-0.1, -0.17, 1]"]),
            &["cannot simulate this robot"],
        ),
        sim(
            "8 cables: three-phase infeasible",
            &cables(&[
                "[3.5, -1.75, 4]",
                "[3.5, 1.75, 4]",
                "[-3.5, 1.75, 4]",
                "[-3.5, -1.75, 4]",
                "[0, 2, 4]",
                "[0, -2, 4]",
                "[2, 0, 4]",
                "[-2, 0, 4]",
            ]),
            &["cannot simulate this robot"],
        ),
        Case::ok("mass 5000 kg", &["simulate", "--config", "cfg.toml", "--duration", "1", "-o", "out.csv"], &["wrote out.csv"])
            .file("cfg.toml", line(3, "mass_kg = 5000.0"))
            .writes("out.csv"),
        Case::ok("a 1 km frame", &["simulate", "--config", "cfg.toml", "--duration", "1", "-o", "out.csv"], &["wrote out.csv"])
            .file("cfg.toml", cables(&["[500, 0, 900]", "[-250, 433, 900]", "[-250, -433, 900]"]))
            .writes("out.csv"),
        // Horizontal pulley axes of any length are directions: simulated with a pulley.
        Case::ok(
            "horizontal pulley axes",
            &["simulate", "--config", "cfg.toml", "--duration", "1", "--no-three-phase", "--effect", "pulley=0.03", "-o", "out.csv"],
            &["wrote out.csv"],
        )
        .file(
            "cfg.toml",
            GOOD_CONFIG
                .replace("[3.5, -1.75, 4.0]\n", "[3.5, -1.75, 4.0]\npulley_axis = [2, 0, 0]\n")
                .replace("[3.5, 1.75, 4.0]\n", "[3.5, 1.75, 4.0]\npulley_axis = [1, 0, 0]\n")
                .replace("[-3.5, 1.75, 4.0]\n", "[-3.5, 1.75, 4.0]\npulley_axis = [-1, 0, 0]\n")
                .replace("[-3.5, -1.75, 4.0]\n", "[-3.5, -1.75, 4.0]\npulley_axis = [-0.5, 0, 0]\n"),
        )
        .writes("out.csv"),
        // The good configuration is accepted (the suite's control).
        Case::ok(
            "good configuration",
            &["simulate", "--config", "cfg.toml", "--duration", "1", "--no-three-phase", "-o", "out.csv"],
            &["wrote out.csv"],
        )
        .file("cfg.toml", GOOD_CONFIG)
        .writes("out.csv"),
    ]
}

#[test]
fn hostile_configs() {
    let t = run_suite("config", cases());
    t.finish("config");
}
