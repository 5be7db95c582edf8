//! Hostile command-line arguments: rates, durations, sample counts, effect
//! parameters, unknown names. Each is refused before anything is simulated or allocated, with the
//! argument named and the allowed range said; nothing panics or aborts.

use crate::hostile;

use hostile::{good_recording, run_suite, Case};

/// `taut simulate` with `extra` arguments, expecting an error.
fn sim(name: &str, extra: &[&str], expect: &[&str]) -> Case {
    let mut args = vec!["simulate", "--no-three-phase", "-o", "out.csv"];
    if !extra.iter().any(|a| a.starts_with("--duration")) {
        args.extend_from_slice(&["--duration", "1"]);
    }
    args.extend_from_slice(extra);
    Case::err(name, &args, expect)
}

fn effect(value: &str, expect: &[&str]) -> Case {
    sim(&format!("--effect {}", &value[..value.len().min(40)]), &["--effect", value], expect)
}

fn cases() -> Vec<Case> {
    let long_name = format!("{}=1", "e".repeat(50_000));
    let long_value = format!("sag={}", "9".repeat(50_000));
    vec![
        // Rate and duration, and their product.
        sim("--rate 1e9", &["--rate", "1e9"], &["--rate 1e9", "1 to 10000 Hz"]),
        sim("--rate 0", &["--rate", "0"], &["--rate 0", "1 to 10000 Hz"]),
        sim("--rate nan", &["--rate", "nan"], &["--rate NaN", "Hz"]),
        sim("--rate inf", &["--rate", "inf"], &["--rate inf", "Hz"]),
        sim("--rate=-100", &["--rate=-100"], &["--rate -100", "Hz"]),
        sim("--rate abc", &["--rate", "abc"], &["--rate", "abc"]),
        sim("--rate 0.001", &["--rate", "0.001"], &["--rate 0.001", "Hz"]),
        sim("--duration 1e12", &["--duration", "1e12"], &["--duration 1e12", "86400 s"]),
        sim("--duration 0", &["--duration", "0"], &["--duration 0", "more than 0"]),
        sim("--duration nan", &["--duration", "nan"], &["--duration NaN"]),
        sim("--duration=-5", &["--duration=-5"], &["--duration -5"]),
        sim("--duration inf", &["--duration", "inf"], &["--duration inf"]),
        sim("a day at 100 Hz is too many samples", &["--duration", "86400"], &["8.640e6 samples", "shorten it or lower the rate"]),
        sim("an hour at 10 kHz", &["--duration", "3600", "--rate", "10000"], &["samples", "lower the rate"]),
        sim("--loose-fraction 2", &["--loose-fraction", "2"], &["--loose-fraction 2", "[0, 0.9)"]),
        sim("--loose-fraction nan", &["--loose-fraction", "nan"], &["--loose-fraction NaN"]),
        sim("--seed -1", &["--seed=-1"], &["--seed"]),
        sim("--seed 2^64", &["--seed", "18446744073709551616"], &["--seed"]),
        // Effects.
        effect("elasticity=0", &["--effect elasticity=0", "1000 to 1e8 N"]),
        effect("elasticity=-5", &["--effect elasticity=-5", "axial stiffness"]),
        effect("elasticity=nan", &["--effect elasticity=NaN"]),
        effect("elasticity=inf", &["--effect elasticity=inf"]),
        effect("elasticity=1e300", &["elasticity", "1000 to 1e8 N"]),
        effect("elasticity=abc", &["--effect `elasticity=abc`", "`abc` is not a number"]),
        effect("elasticity=", &["--effect `elasticity=`", "not a number"]),
        effect("elasticity", &["--effect `elasticity`", "NAME=VALUE"]),
        effect("=5", &["is not a simulated effect"]),
        effect("sag=-1", &["--effect sag=-1", "0 to 20 N/m"]),
        effect("sag=1e9", &["--effect sag=1e9", "cable weight"]),
        effect("pulley=nan", &["--effect pulley=NaN", "pulley radius"]),
        effect("pulley=-0.05", &["--effect pulley=-0.05"]),
        effect("scale=0", &["--effect scale=0", "0.9 to 1.1"]),
        effect("scale=-1", &["--effect scale=-1"]),
        effect("time-offset=1e9", &["--effect time-offset=1e9", "encoder lag"]),
        effect("time-offset=nan", &["--effect time-offset=NaN"]),
        effect("backlash=-1", &["--effect backlash=-1", "play in the drive train"]),
        effect("backlash=1", &["--effect backlash=1"]),
        effect("load-cell-gain=2", &["--effect loadcell-gain=2", "load-cell gain must be 0.8 to 1.25"]),
        effect("friction=-0.1", &["--effect friction=-0.1", "guide friction mu*theta must be 0 to 1"]),
        effect("gravity=2", &["--effect `gravity` is not a simulated effect", "elasticity, sag, pulley"]),
        effect(&long_name, &["is not a simulated effect", "…", "50000 bytes"]),
        effect(&long_value, &["--effect sag=inf", "0 to 20 N/m"]),
        sim("an effect given twice", &["--effect", "sag=0.5", "--effect", "sag=1.0"], &["--effect sag is given twice"]),
        // Other commands.
        Case::err("demo --rate 1e9", &["demo", "--rate", "1e9", "-o", "out.csv"], &["--rate", "Hz"]),
        Case::err("demo --effect elasticity=0", &["demo", "--effect", "elasticity=0", "-o", "out.csv"], &["elasticity"]),
        Case::err(
            "diagnose --tension-at sideways",
            &["diagnose", "rec.csv", "--tension-at", "sideways"],
            &["--tension-at `sideways`", "anchor"],
        )
        .file("rec.csv", good_recording()),
        Case::err("calibrate without a recording", &["calibrate"], &["RECORDING"]),
        Case::err("unknown subcommand", &["calibrat", "rec.csv"], &["calibrat"]),
        Case::err("unknown flag", &["calibrate", "rec.csv", "--outt", "p.toml"], &["--outt"]).file("rec.csv", good_recording()),
        Case::err("unknown: a replacement character as a number", &["simulate", "--rate", "\u{FFFD}"], &["--rate"]),
        Case::err("probe --watch-s inf", &["probe", "--sim", "--watch-s", "inf"], &["--watch-s inf", "0 to 86400 s"]),
        Case::err("probe --watch-s 1e300", &["probe", "--sim", "--watch-s", "1e300"], &["--watch-s", "0 to 86400 s"]),
        Case::err("probe --watch-s nan", &["probe", "--sim", "--watch-s", "nan"], &["--watch-s NaN"]),
        // The control: good arguments are accepted.
        Case::ok(
            "good arguments",
            &["simulate", "--no-three-phase", "--duration", "1", "--rate", "50", "--effect", "elasticity=20000", "-o", "out.csv"],
            &["wrote out.csv: 50 samples"],
        )
        .writes("out.csv"),
    ]
    .into_iter()
    .map(|mut c| {
        // clap's own usage errors exit with 2: still a clean refusal, not a success.
        if c.name.starts_with("--rate abc")
            || c.name.starts_with("--seed")
            || c.name.contains("without a recording")
            || c.name.starts_with("unknown")
        {
            c.code = 2;
        }
        c
    })
    .collect()
}

#[test]
fn hostile_args() {
    let t = run_suite("args", cases());
    t.finish("args");
}
