//! Hostile recordings: generated bad `cdpr-recording` files given to `taut calibrate`
//! and `taut diagnose`. Each must end in a clear error naming the file, line and column (or be
//! accepted where the format allows it), without a panic, a hang, or a changed file.

use crate::hostile;

use hostile::{good_recording, run_suite, set_field, with_line, Case, Entry};

/// Line of the first data row in the base recording (tag, comment, header before it).
const ROW: usize = 4;

fn bad_field(name: &str, col: usize, value: &str, expect: &[&str]) -> Case {
    let text = with_line(&good_recording(), ROW + 5, |l| set_field(l, col, value));
    let mut e = vec!["rec.csv:9"];
    e.extend_from_slice(expect);
    Case::err(name, &["calibrate", "rec.csv"], &e).file("rec.csv", text)
}

fn cases() -> Vec<Case> {
    let good = good_recording();
    let header_line = good.lines().nth(ROW - 2).unwrap().to_string();
    let body: String = good.lines().skip(ROW - 1).map(|l| format!("{l}\n")).collect();
    let row = |k: usize| good.lines().nth(ROW - 1 + k).unwrap().to_string();
    let cal = |name: &str, text: String, expect: &[&str]| Case::err(name, &["calibrate", "rec.csv"], expect).file("rec.csv", text);
    let mut c = vec![
        // Bytes that are not a CSV text.
        Case::err("/dev/zero", &["calibrate", "/dev/zero"], &["/dev/zero:1", "NUL byte"]),
        cal("NUL in a row", with_line(&good, 12, |l| format!("{l}\0")), &["rec.csv:12", "NUL byte"]),
        cal("binary garbage", (0..4096u32).map(|i| (i.wrapping_mul(2654435761u32) >> 24) as u8 as char).collect(), &["rec.csv:1"]),
        cal("one 200 KB line", "7".repeat(200_000), &["rec.csv:1", "longer than 64 KiB"]),
        cal("a 100 KB row", with_line(&good, 20, |l| format!("{l}{}", "9".repeat(100_000))), &["rec.csv:20", "longer than 64 KiB"]),
        Case::err("latin-1 byte", &["calibrate", "rec.csv"], &["rec.csv:15", "not UTF-8"]).file("rec.csv", {
            let mut b = good.clone().into_bytes();
            let at = good.lines().take(14).map(|l| l.len() + 1).sum::<usize>() + 3;
            b[at] = 0xB5;
            b
        }),
        // Spreadsheet exports.
        Case::ok("UTF-8 BOM is accepted", &["calibrate", "rec.csv"], &["byte-order mark"]).file("rec.csv", format!("\u{feff}{good}")),
        cal("quoted header", format!("\"{}\"\n{body}", header_line.replace(',', "\",\"")), &["rec.csv:1", "quoted field"]),
        cal("quoted number", with_line(&good, ROW + 2, |l| set_field(l, 1, "\"1.05\"")), &["rec.csv:6", "quoted field"]),
        cal("quoted number with comma", with_line(&good, ROW + 2, |l| set_field(l, 1, "\"1,05\"")), &["rec.csv:6", "quoted field"]),
        cal("semicolons", good.replace(',', ";"), &["rec.csv:3", "semicolons"]),
        cal("semicolons and decimal commas", good.replace(',', ";").replace('.', ","), &["rec.csv:3", "semicolons"]),
        cal("tabs", good.replace(',', "\t"), &["rec.csv:3", "tabs"]),
        cal("spaces", good.replace(',', " "), &["rec.csv:3", "spaces"]),
        cal("pipes", good.replace(',', "|"), &["rec.csv:3", "`|`"]),
        // Format versions.
        cal("v2 tag", good.replacen("# cdpr-recording v1", "# cdpr-recording v2", 1), &["rec.csv:1", "`v2` is not known"]),
        cal("v0 tag", good.replacen("# cdpr-recording v1", "# cdpr-recording v0.9", 1), &["rec.csv:1", "`v0.9` is not known"]),
        cal("tag without version", good.replacen("# cdpr-recording v1", "# cdpr-recording", 1), &["rec.csv:1", "not known"]),
        cal("upper-case v3 tag", good.replacen("# cdpr-recording v1", "#CDPR-Recording V3", 1), &["rec.csv:1", "not known"]),
        // Time.
        bad_field("t = nan", 0, "nan", &["column `t`", "time is missing"]),
        bad_field("t empty", 0, "", &["column `t`", "time is missing"]),
        bad_field("t = inf", 0, "inf", &["column `t`", "not a finite number"]),
        bad_field("t = 1e400", 0, "1e400", &["column `t`", "not a finite number"]),
        bad_field("t = 1e308", 0, "1e308", &["column `t`", "plausible"]),
        bad_field("t = -1e12", 0, "-1e12", &["column `t`", "plausible"]),
        bad_field("t jumps to 1e6 (blamed on its own row)", 0, "1e6", &["column `t`", "jumps ahead"]),
        cal("t goes backwards", with_line(&good, ROW + 5, |l| set_field(l, 0, "0.0")), &["rec.csv:9", "backwards"]),
        // Phase.
        bad_field("phase = 1.5", 12, "1.5", &["column `phase`", "integer"]),
        bad_field("phase = nan", 12, "nan", &["column `phase`", "integer"]),
        bad_field("phase = -7", 12, "-7", &["column `phase`", "integer"]),
        bad_field("phase = 1e3", 12, "1e3", &["column `phase`", "integer"]),
        bad_field("phase = 99999999999", 12, "99999999999", &["column `phase`", "integer"]),
        bad_field("phase = two", 12, "two", &["column `phase`", "integer"]),
        // Numbers.
        bad_field("px = abc", 1, "abc", &["column `px`", "not a number"]),
        bad_field("l2 = 4.1O3", 6, "4.1O3", &["column `l2`", "`4.1O3` is not a number"]),
        bad_field("f3 = x", 11, "x", &["column `f3`", "not a number"]),
        bad_field("l1 = inf", 5, "inf", &["column `l1`", "not a finite number"]),
        bad_field("f0 = -inf", 8, "-inf", &["column `f0`", "not a finite number"]),
        bad_field("l0 = 1e400", 4, "1e400", &["column `l0`", "not a finite number"]),
        bad_field("pz = 0x10", 3, "0x10", &["column `pz`", "not a number"]),
        bad_field("50 KB field is cut", 2, &"x".repeat(50_000), &["column `py`", "…", "50000 bytes"]),
        // Shape.
        cal("a field too many", with_line(&good, ROW + 3, |l| format!("{l},1")), &["rec.csv:7", "14 fields, but the header has 13"]),
        cal("a field too few", with_line(&good, ROW + 3, |l| l.rsplit_once(',').unwrap().0.to_string()), &["rec.csv:7", "12 fields"]),
        cal("empty file", String::new(), &["rec.csv", "no header"]),
        cal("only comments", "# cdpr-recording v1\n# nothing else\n".into(), &["rec.csv", "no header"]),
        cal("header only", format!("{header_line}\n"), &["rec.csv", "only 0 usable samples"]),
        cal("five rows", format!("{header_line}\n{}\n{}\n{}\n{}\n{}\n", row(0), row(1), row(2), row(3), row(4)), &["only 5 usable"]),
        cal("no pz column", good.replacen(",pz,", ",pq,", 1), &["rec.csv:3", "no `pz` column"]),
        cal("no t column", good.replacen("t,px", "time,px", 1), &["rec.csv:3", "no `t` column"]),
        cal("duplicate column", good.replacen(",l3,", ",l2,", 1), &["rec.csv:3", "`l2` appears twice"]),
        cal("gap in l columns", good.replacen(",l3,", ",l4,", 1), &["rec.csv:3", "l4"]),
        cal("f columns do not match", good.replacen(",f3,", ",g3,", 1), &["rec.csv:3", "tension columns"]),
        cal("partial quaternion", good.replacen("t,px,py,pz,", "t,px,py,pz,qw,", 1), &["rec.csv:3", "qw, qx, qy, qz"]),
        cal(
            "65 cables",
            format!("t,px,py,pz,{}\n", (0..65).map(|j| format!("l{j}")).collect::<Vec<_>>().join(",")),
            &["rec.csv:1", "at most 64 cables"],
        ),
        Case::err("a directory", &["calibrate", "recs"], &["recs", "is a directory"]).entry("recs", Entry::Dir),
        Case::err("no such file", &["calibrate", "missing.csv"], &["missing.csv", "cannot read"]),
        Case::err("a fifo nobody writes to", &["calibrate", "rec.fifo"], &["rec.fifo", "is a fifo and nothing has written to it"])
            .entry("rec.fifo", Entry::Fifo),
        Case::ok("a pipe from a command", &[], &[])
            .shell("\"$TAUT\" calibrate /dev/fd/3 3< rec.csv && cat rec.csv | \"$TAUT\" calibrate /dev/stdin")
            .file("rec.csv", good.clone()),
        Case::ok("CRLF line endings are accepted", &["calibrate", "rec.csv"], &[]).file("rec.csv", good.replace('\n', "\r\n")),
        // diagnose reads with the same reader.
        Case::err("diagnose: v2 tag", &["diagnose", "rec.csv"], &["rec.csv:1", "not known"])
            .file("rec.csv", good.replacen("# cdpr-recording v1", "# cdpr-recording v2", 1)),
        Case::err("diagnose: NUL", &["diagnose", "rec.csv"], &["rec.csv:10", "NUL"])
            .file("rec.csv", with_line(&good, 10, |l| format!("\0{l}"))),
        Case::err("diagnose: /dev/zero", &["diagnose", "/dev/zero"], &["/dev/zero:1"]),
        Case::err("diagnose: phase 1.5", &["diagnose", "rec.csv"], &["rec.csv:9", "integer"])
            .file("rec.csv", with_line(&good, ROW + 5, |l| set_field(l, 12, "1.5"))),
    ];
    // Every row the same (time aside): the platform never moved; both tools name the file.
    let still: String = good
        .lines()
        .enumerate()
        .map(|(i, l)| if i >= ROW { format!("{i},{}\n", row(0).split_once(',').unwrap().1) } else { format!("{l}\n") })
        .collect();
    for tool in ["calibrate", "diagnose"] {
        c.push(
            Case::err(format!("{tool}: all rows identical"), &[tool, "rec.csv"], &["rec.csv", "never moved"])
                .file("rec.csv", still.clone()),
        );
    }
    // Tension columns that are not readings (every value 0, or 1e-300): a data problem in both
    // tools, named with the file and the columns; the recording is used without tensions.
    let cols: Vec<usize> = header_line.split(',').enumerate().filter(|(_, h)| h.starts_with('f')).map(|(i, _)| i).collect();
    assert!(!cols.is_empty(), "the base recording has tension columns: {header_line}");
    for value in ["0", "1e-300"] {
        let dead: String = good
            .lines()
            .enumerate()
            .map(
                |(i, l)| {
                    if i + 1 >= ROW {
                        cols.iter().fold(l.to_string(), |l, &k| set_field(&l, k, value)) + "\n"
                    } else {
                        format!("{l}\n")
                    }
                },
            )
            .collect();
        for tool in ["calibrate", "diagnose"] {
            c.push(
                Case::ok(
                    format!("{tool}: every tension {value}"),
                    &[tool, "rec.csv"],
                    &["data problem: rec.csv", "f0 (cable 1)", "below 0.001 N in every row", "without tensions"],
                )
                .file("rec.csv", dead.clone()),
            );
        }
    }
    // The 65-cable case has no data rows: its error is about the header line.
    c.iter_mut().for_each(|x| x.expect.retain(|s| !s.is_empty()));
    c
}

#[test]
fn hostile_recordings() {
    let t = run_suite("recordings", cases());
    t.finish("recordings");
}
