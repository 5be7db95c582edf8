//! The files in `udev/`: every rule line parses (keys, operators, quoting), the load-cell rule
//! matches vendor, product and serial and makes `/dev/taut-loadcells` with group `taut` and mode
//! 0660, the CAN rule and the networkd file bring up the interface at the bitrate of the example
//! hardware config, with restart-ms, and those names are the ones the example config uses.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One `KEY{attr}<op>"value"` term of a rule.
#[derive(Debug, Clone, PartialEq)]
struct Term {
    key: String,
    attr: Option<String>,
    op: &'static str,
    value: String,
}

/// Parses one rule line (udev(7): comma-separated `KEY[{attr}] op "value"` terms; operators
/// `==`, `!=` match, `=`, `+=`, `-=`, `:=` assign; values in double quotes, `\"` escapes a quote).
fn parse_rule(line: &str) -> Result<Vec<Term>, String> {
    const MATCH_OPS: [&str; 2] = ["==", "!="];
    const OPS: [&str; 6] = ["==", "!=", "+=", "-=", ":=", "="];
    let mut terms = Vec::new();
    let mut rest = line.trim();
    while !rest.is_empty() {
        let key_end = rest.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).ok_or("term without operator")?;
        let key = &rest[..key_end];
        if key.is_empty() || !key.chars().next().unwrap().is_ascii_uppercase() {
            return Err(format!("bad key at {rest:?}"));
        }
        rest = &rest[key_end..];
        let mut attr = None;
        if let Some(r) = rest.strip_prefix('{') {
            let close = r.find('}').ok_or("unclosed {")?;
            attr = Some(r[..close].to_string());
            rest = &r[close + 1..];
        }
        rest = rest.trim_start();
        let op = *OPS.iter().find(|op| rest.starts_with(**op)).ok_or_else(|| format!("no operator after {key}"))?;
        rest = rest[op.len()..].trim_start();
        let r = rest.strip_prefix('"').ok_or_else(|| format!("{key}: value must be in double quotes"))?;
        let mut value = String::new();
        let mut chars = r.char_indices();
        let end = loop {
            match chars.next() {
                Some((_, '\\')) => {
                    if let Some((_, c)) = chars.next() {
                        value.push('\\');
                        value.push(c);
                    }
                }
                Some((i, '"')) => break i,
                Some((_, c)) => value.push(c),
                None => return Err(format!("{key}: unterminated quote")),
            }
        };
        rest = r[end + 1..].trim_start();
        let assign_only = ["SYMLINK", "GROUP", "MODE", "OWNER", "RUN", "NAME", "ENV", "TAG", "OPTIONS", "LABEL", "GOTO"];
        let match_only = ["SUBSYSTEM", "ACTION", "KERNEL", "DRIVER", "ATTRS", "SUBSYSTEMS", "KERNELS", "DRIVERS", "DEVPATH"];
        if match_only.contains(&key) && !MATCH_OPS.contains(&op) {
            return Err(format!("{key} can only be matched (== or !=), got {op}"));
        }
        if assign_only.contains(&key) && MATCH_OPS.contains(&op) && key != "ENV" && key != "TAG" {
            return Err(format!("{key} can only be assigned, got {op}"));
        }
        terms.push(Term { key: key.to_string(), attr, op, value });
        match rest.strip_prefix(',') {
            Some(r) => rest = r.trim_start(),
            None if rest.is_empty() => {}
            None => return Err(format!("expected ',' before {rest:?}")),
        }
    }
    if terms.is_empty() {
        return Err("empty rule".into());
    }
    Ok(terms)
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// Every rule of a `.rules` file, with its line number; continuation lines joined.
fn rules(file: &Path) -> Vec<(usize, Vec<Term>)> {
    let text = std::fs::read_to_string(file).unwrap();
    let mut out = Vec::new();
    let mut pending = String::new();
    let mut start = 0;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if pending.is_empty() && (t.is_empty() || t.starts_with('#')) {
            continue;
        }
        if pending.is_empty() {
            start = i + 1;
        }
        match t.strip_suffix('\\') {
            Some(head) => pending.push_str(head),
            None => {
                pending.push_str(t);
                let terms = parse_rule(&pending).unwrap_or_else(|e| panic!("{}:{start}: {e}", file.display()));
                out.push((start, terms));
                pending.clear();
            }
        }
    }
    assert!(pending.is_empty(), "{}: dangling line continuation", file.display());
    out
}

fn get<'a>(terms: &'a [Term], key: &str, attr: Option<&str>) -> Option<&'a Term> {
    terms.iter().find(|t| t.key == key && t.attr.as_deref() == attr)
}

fn hw_config() -> taut_config::RobotConfig {
    taut_config::RobotConfig::load(root().join("config/examples/aras-cam-hw.toml")).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn parser_accepts_and_rejects() {
    let ok = parse_rule(r#"SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", SYMLINK+="a b", MODE:="0660", ENV{X}="say \"hi\"""#).unwrap();
    assert_eq!(ok.len(), 5);
    assert_eq!(ok[1], Term { key: "ATTRS".into(), attr: Some("idVendor".into()), op: "==", value: "0403".into() });
    assert_eq!(ok[2].op, "+=");
    assert_eq!(ok[3].op, ":=");
    assert_eq!(ok[4].value, r#"say \"hi\""#);
    for bad in [
        r#"SUBSYSTEM=="tty" MODE="0660""#,
        r#"SUBSYSTEM=tty"#,
        r#"SUBSYSTEM=="tty"#,
        r#"SUBSYSTEM="tty""#,
        r#"MODE=="0660""#,
        r#"ATTRS{idVendor=="0403""#,
        r#"subsystem=="tty""#,
        r#"SUBSYSTEM=="tty",, MODE="1""#,
    ] {
        assert!(parse_rule(bad).is_err(), "should reject {bad}");
    }
}

#[test]
fn every_rule_file_parses() {
    let dir = root().join("udev");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "rules") {
            n += rules(&p).len();
        }
    }
    assert!(n >= 3, "expected the load-cell, latency and CAN rules in {}", dir.display());
}

#[test]
fn loadcell_rule_matches_config() {
    let cfg = hw_config();
    let port = &cfg.loadcells.as_ref().expect("[loadcells] in aras-cam-hw.toml").port;
    let name = port.strip_prefix("/dev/").expect("port under /dev");
    let all = rules(&root().join("udev/99-taut-loadcells.rules"));
    let (line, r) = all.iter().find(|(_, r)| get(r, "SYMLINK", None).is_some()).expect("a SYMLINK rule");
    let at = format!("99-taut-loadcells.rules:{line}");
    assert_eq!(get(r, "SUBSYSTEM", None).map(|t| t.value.as_str()), Some("tty"), "{at}");
    for attr in ["idVendor", "idProduct", "serial"] {
        let t = get(r, "ATTRS", Some(attr)).unwrap_or_else(|| panic!("{at}: must match ATTRS{{{attr}}}"));
        assert_eq!(t.op, "==", "{at}");
        assert!(!t.value.is_empty(), "{at}");
    }
    for attr in ["idVendor", "idProduct"] {
        let v = &get(r, "ATTRS", Some(attr)).unwrap().value;
        assert!(v.len() == 4 && v.chars().all(|c| c.is_ascii_hexdigit()), "{at}: {attr} {v:?} is 4 hex digits");
    }
    let sym = get(r, "SYMLINK", None).unwrap();
    assert_eq!((sym.op, sym.value.as_str()), ("+=", name), "{at}: SYMLINK must make {port}");
    assert_eq!(get(r, "GROUP", None).map(|t| t.value.as_str()), Some("taut"), "{at}");
    assert_eq!(get(r, "MODE", None).map(|t| t.value.as_str()), Some("0660"), "{at}");
}

#[test]
fn can_rule_and_network_match_config() {
    let cfg = hw_config();
    let can = cfg.can.as_ref().expect("[can] in aras-cam-hw.toml");
    let all = rules(&root().join("udev/80-taut-can.rules"));
    let (line, r) = all.iter().find(|(_, r)| get(r, "SUBSYSTEM", None).is_some_and(|t| t.value == "net")).expect("a net rule");
    let at = format!("80-taut-can.rules:{line}");
    assert_eq!(get(r, "KERNEL", None).map(|t| t.value.as_str()), Some(can.interface.as_str()), "{at}");
    let runs: Vec<&str> = r.iter().filter(|t| t.key == "RUN").map(|t| t.value.as_str()).collect();
    let setup = runs.iter().find(|v| v.contains("type can")).unwrap_or_else(|| panic!("{at}: a RUN with `ip link set .. type can`"));
    let words: Vec<&str> = setup.split_whitespace().collect();
    let after = |w: &str| words.iter().position(|x| *x == w).and_then(|i| words.get(i + 1)).copied();
    assert_eq!(after("set"), Some(can.interface.as_str()), "{at}");
    assert_eq!(after("bitrate"), Some(can.bitrate.to_string().as_str()), "{at}: bitrate must be [can] bitrate");
    assert!(after("restart-ms").is_some_and(|v| v.parse::<u32>().is_ok_and(|ms| ms > 0)), "{at}: restart-ms");
    assert!(runs.iter().any(|v| v.ends_with(&format!("{} up", can.interface))), "{at}: brings the link up");
    for r in &runs {
        assert!(r.starts_with('/'), "{at}: udev RUN needs an absolute path, got {r:?}");
    }

    // The systemd-networkd alternative says the same.
    let net = std::fs::read_to_string(root().join("udev/80-taut-can.network")).unwrap();
    let mut section = String::new();
    let mut kv = BTreeMap::new();
    for (i, l) in net.lines().enumerate() {
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        if let Some(s) = l.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            section = s.to_string();
            continue;
        }
        let (k, v) = l.split_once('=').unwrap_or_else(|| panic!("80-taut-can.network:{}: not key=value", i + 1));
        kv.insert(format!("{section}.{}", k.trim()), v.trim().to_string());
    }
    assert_eq!(kv.get("Match.Name"), Some(&can.interface));
    assert_eq!(kv.get("CAN.BitRate"), Some(&can.bitrate.to_string()));
    assert!(kv.contains_key("CAN.RestartSec"), "{kv:?}");
}
