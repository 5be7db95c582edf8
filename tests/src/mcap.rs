//! Helpers for the MCAP tests: the independent Python reader (`tests/mcap/read_mcap.py`, the
//! PyPI `mcap` package installed by `scripts/setup-mcap`).

use std::path::Path;
use std::process::Command;

/// What the independent reader found in an MCAP file (its JSON output).
pub fn read_with_python(path: &Path) -> serde_json::Value {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/mcap/read_mcap.py");
    let py = std::env::var("TAUT_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&py).arg(script).arg(path).output().expect("running python3 (scripts/setup-mcap installs the mcap package)");
    assert!(
        out.status.success(),
        "{script} {} failed (is the PyPI `mcap` package installed? run scripts/setup-mcap):\n{}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("read_mcap.py prints JSON")
}

/// Messages on `topic`, or 0.
pub fn count(v: &serde_json::Value, topic: &str) -> u64 {
    v["channels"][topic]["messages"].as_u64().unwrap_or(0)
}
