//! The dependency rules of the workspace (docs/architecture.md), checked on the real graph with
//! `cargo tree --offline --locked`:
//!
//! - `taut-driver` (the CANopen master, Modbus, tracker input) depends on neither the physics
//!   (`taut-sim`) nor the virtual devices (`taut-vdev`), not even as a dev-dependency: a bench or
//!   test that needs virtual drives lives in `taut-vdev` or `tests/`.
//! - `taut-sim` is physics only: no `taut-vdev`, no `taut-driver`.
//! - `taut-vdev` (the device side) does not depend on `taut-sim`: the simulated rig couples them.
//! - `taut-proto` (frames, codecs, device configuration) has no I/O crates (`socketcan`,
//!   `serialport`, `libc`, `tungstenite`, `mcap`), no nalgebra or serde_json, and none of the
//!   workspace's crates but `taut-model`.
//! - The master (`taut-driver`) and the device side (`taut-vdev`) do not depend on each other, not
//!   even as a dev-dependency: both use `taut-proto`, and `taut-simrig` puts them together.
//! - `taut-calib` is pure: no I/O crates (`socketcan`, `serialport`, `libc`).
//! - `taut-rt` (what the real-time loop runs every cycle) has none of: nalgebra, serde,
//!   serde_json, toml, crossbeam, libc, the I/O crates, the configuration, the calibration, the
//!   driver, the simulator; its source (and the model crate's) spawns no thread, takes no lock and
//!   opens no file or socket outside its tests.
//! - `taut-model` (the cable model formulas both calib and the loop call) has no dependencies.
//! - `taut-rt-core` (the robot build) contains no simulator: the simulated rig is `taut-simrig`.
//!   Nor does `taut-ffi` by default (the `taut_sim_*` functions are its `sim` feature), nor
//!   `taut-cli` without its `sim` feature (on by default for development and the tests).
//! - `testkit` (a feature of `taut-rt-core`: the kinematic stand-in robot) is not on in a normal
//!   `cargo build --workspace`: only dev-dependencies turn it on.
//! - One number of cables: `taut_model::MAX_CABLES` is the only `MAX_CABLES` written as a number;
//!   the others (the C ABI's `TAUT_MAX_CABLES`) are defined from it or re-export it.
//! - `taut-sim` does not use the model the calibration fits: no direct `taut-model` dependency
//!   and no `taut_model` in its source. It reaches `taut-model` only through `taut-config`
//!   (allowed edge: the parameter file converts to the shared geometry type in one place), and
//!   names the plain data type `Geometry` only through `taut_config::params`.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::Command;

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn cargo_tree(args: &[&str]) -> String {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(&cargo)
        .args(["tree", "--offline", "--locked"])
        .args(args)
        .current_dir(workspace())
        .output()
        .unwrap_or_else(|e| panic!("cannot run `{cargo} tree`: {e}"));
    assert!(
        out.status.success(),
        "`cargo tree --offline --locked {}` failed (is Cargo.lock up to date? run `cargo update -w`):\n{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("cargo tree prints UTF-8")
}

/// Package names in the dependency graph of `package` along the given edge kinds
/// (`normal`, `build`, `dev`), the package itself included.
fn deps(package: &str, edges: &str, extra: &[&str]) -> BTreeSet<String> {
    let mut args = vec!["-p", package, "-e", edges, "--prefix", "none", "-f", "{p}"];
    args.extend_from_slice(extra);
    cargo_tree(&args).lines().filter_map(|l| l.split_whitespace().next()).map(str::to_owned).collect()
}

/// The banned crates found in `package`'s graph, each with the path that pulls it in.
fn violations(package: &str, edges: &str, extra: &[&str], banned: &[&str]) -> Vec<String> {
    let found = deps(package, edges, extra);
    banned
        .iter()
        .filter(|b| found.contains(**b))
        .map(|b| {
            let mut args = vec!["-p", package, "-e", edges, "-i", b];
            args.extend_from_slice(extra);
            format!("{package} depends on {b} ({edges} edges); the path:\n{}", cargo_tree(&args))
        })
        .collect()
}

fn assert_none(v: Vec<String>, rule: &str) {
    assert!(v.is_empty(), "crate graph rule broken: {rule} (docs/architecture.md)\n{}", v.join("\n"));
}

#[test]
fn driver_depends_on_neither_the_simulator_nor_the_virtual_devices() {
    assert_none(
        violations("taut-driver", "normal,build", &[], &["taut-sim", "taut-vdev", "taut-simrig", "taut-rt", "taut-rt-core"]),
        "the driver must build without the physics and without the device side",
    );
    // Dev-dependencies too: a dev-dependency on a crate that depends on the driver is a cycle
    // (two copies of the driver's types in its unit tests). `--depth 1`: the driver's own
    // dev-dependencies, not those of the crates below it.
    assert_none(
        violations("taut-driver", "dev", &["--depth", "1"], &["taut-sim", "taut-vdev", "taut-simrig"]),
        "the driver's benches and tests must not need the device side; put them in taut-vdev or tests/",
    );
}

#[test]
fn sim_is_physics_only() {
    assert_none(
        violations("taut-sim", "normal,build", &[], &["taut-vdev", "taut-driver"]),
        "taut-sim is physics only: the devices are in taut-vdev, the simulated rig (taut-simrig) couples them",
    );
}

#[test]
fn virtual_devices_do_not_need_the_physics() {
    assert_none(
        violations("taut-vdev", "normal,build", &[], &["taut-sim"]),
        "taut-vdev is the device side of the protocols; the plant is coupled to it in taut-simrig",
    );
}

#[test]
fn calib_has_no_io_crates() {
    assert_none(
        violations("taut-calib", "normal,build", &[], &["socketcan", "serialport", "libc", "taut-driver"]),
        "taut-calib is pure computation (no I/O)",
    );
}

#[test]
fn the_protocol_crate_has_no_io() {
    assert_none(
        violations(
            "taut-proto",
            "normal,build",
            &[],
            &["socketcan", "serialport", "libc", "tungstenite", "mcap", "nalgebra", "serde_json", "crossbeam-channel"],
        ),
        "taut-proto holds formats only: no socket, tty, thread or maths library; transports are taut-driver's",
    );
    let taut: BTreeSet<String> = deps("taut-proto", "normal,build", &[]).into_iter().filter(|p| p.starts_with("taut-")).collect();
    assert_eq!(
        taut,
        ["taut-model", "taut-proto"].map(str::to_owned).into(),
        "taut-proto's workspace dependencies: only the model crate (the bus status types)"
    );
}

#[test]
fn master_and_device_side_do_not_depend_on_each_other() {
    assert_none(
        violations("taut-vdev", "normal,build", &[], &["taut-driver", "taut-simrig", "taut-rt-core"]),
        "taut-vdev (the device side) uses taut-proto's codecs, not the master in taut-driver",
    );
    assert_none(
        violations("taut-vdev", "dev", &["--depth", "1"], &["taut-driver", "taut-simrig"]),
        "taut-vdev's benches and tests must not need the master; put them in taut-simrig or tests/",
    );
    // Both sides do use the protocol crate (the rules above do not pass because the graph is empty).
    for side in ["taut-vdev", "taut-driver"] {
        assert_eq!(violations(side, "normal", &["--depth", "1"], &["taut-proto"]).len(), 1, "{side} uses taut-proto");
    }
}

/// What may be linked into the real-time crate: nothing that allocates behind its back, locks,
/// spawns threads or does I/O, and none of the non-real-time side's crates.
const NOT_REAL_TIME: &[&str] = &[
    "nalgebra",
    "serde",
    "serde_json",
    "toml",
    "crossbeam-channel",
    "crossbeam-utils",
    "libc",
    "socketcan",
    "serialport",
    "tungstenite",
    "mcap",
    "ringbuf",
    "rand",
    "taut-config",
    "taut-calib",
    "taut-driver",
    "taut-sim",
    "taut-vdev",
    "taut-rt-core",
];

#[test]
fn the_real_time_crate_links_nothing_from_the_non_real_time_side() {
    assert_none(
        violations("taut-rt", "normal,build", &[], NOT_REAL_TIME),
        "taut-rt runs in the real-time thread: no nalgebra, serde, toml, crossbeam, libc, I/O crates, configuration, calibration or driver",
    );
    // `loom` is the one extra, under `--cfg loom` only (scripts/loom), for the model tests.
    let all = deps("taut-rt", "normal,build", &[]);
    assert_eq!(all, ["taut-model", "taut-rt"].map(str::to_owned).into(), "taut-rt's dependencies: only the model crate");
}

#[test]
fn the_model_crate_has_no_dependencies() {
    assert_eq!(deps("taut-model", "normal,build", &[]), ["taut-model"].map(str::to_owned).into());
}

/// Tokens that must not appear in the real-time crate's or the model crate's non-test code: a
/// thread, a lock, a blocking wait, a file, a socket, a process.
const NOT_IN_THE_LOOP: &[&str] = &[
    "std::thread",
    "thread::spawn",
    "Mutex",
    "RwLock",
    "Condvar",
    "std::sync::mpsc",
    "sleep(",
    "std::fs",
    "std::net",
    "std::io",
    "std::process",
    "std::env",
];

/// The non-test code of a source file: up to its first `#[cfg(test)]`-style module (taut keeps
/// unit tests at the end of the file), without comments.
fn code_of(text: &str) -> String {
    let end = text.find("#[cfg(test)]").or_else(|| text.find("#[cfg(all(test")).unwrap_or(text.len());
    text[..end].lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n")
}

/// Offending (file, line, token) in the `.rs` files under `dir`, `loom_tests.rs` excepted (built
/// under `cfg(all(test, loom))` only).
fn scan(dir: &std::path::Path) -> Vec<String> {
    let mut found = Vec::new();
    let mut files: Vec<_> =
        std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).collect();
    files.sort();
    for f in files {
        if f.extension().is_none_or(|e| e != "rs") || f.file_name().is_some_and(|n| n == "loom_tests.rs") {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, line) in code_of(&text).lines().enumerate() {
            for t in NOT_IN_THE_LOOP {
                if line.contains(t) {
                    found.push(format!("{}: code line {}: `{t}` in `{}`", f.display(), k + 1, line.trim()));
                }
            }
        }
    }
    found
}

#[test]
fn the_real_time_source_spawns_no_thread_takes_no_lock_and_does_no_io() {
    let mut found = scan(&workspace().join("rt/src"));
    found.extend(scan(&workspace().join("model/src")));
    assert!(found.is_empty(), "the real-time rule (docs/architecture.md) broken in taut-rt / taut-model:\n{}", found.join("\n"));
    // The scan sees what it looks for: rt-core's daemon side spawns threads and takes locks.
    let daemon_side = scan(&workspace().join("rt-core/src"));
    assert!(daemon_side.iter().any(|l| l.contains("thread::spawn") || l.contains("std::thread")), "{daemon_side:?}");
    assert!(daemon_side.iter().any(|l| l.contains("Mutex")), "{daemon_side:?}");
}

#[test]
fn the_robot_build_contains_no_simulator() {
    assert_none(
        violations("taut-rt-core", "normal,build", &[], &["taut-sim", "taut-vdev", "taut-simrig"]),
        "taut-rt-core is the robot's build; the simulated rig is taut-simrig (used by `taut start --sim`, ffi and tests)",
    );
    // The robot's `taut`: taut-cli without its `sim` feature (`taut demo`, `simulate`, `start --sim`).
    assert_none(
        violations("taut-cli", "normal,build", &["--no-default-features"], &["taut-sim", "taut-vdev", "taut-simrig"]),
        "the robot's taut binary (taut-cli --no-default-features) links no simulator; `sim` is the feature that does",
    );
    // With its default features the checker does see it there.
    assert_eq!(violations("taut-cli", "normal,build", &[], &["taut-sim", "taut-vdev", "taut-simrig"]).len(), 3);
}

/// The plugin a robot's controller loads: the simulator only with `--features sim` (which
/// scripts/test, tests/vcan/run and the C hosts' builds pass).
#[test]
fn the_plugin_library_contains_no_simulator_by_default() {
    assert_none(
        violations("taut-ffi", "normal,build", &[], &["taut-sim", "taut-vdev", "taut-simrig"]),
        "taut-ffi's default build is the robot's; its taut_sim_* functions are behind the `sim` feature",
    );
    // With the feature the checker does see the simulator.
    let with = violations("taut-ffi", "normal,build", &["--features", "sim"], &["taut-sim", "taut-simrig"]);
    assert_eq!(with.len(), 2, "{with:?}");
}

/// `testkit` is for tests and benches. `cargo tree -e normal,build` resolves features as
/// `cargo build --workspace` does (resolver 2: dev-dependencies are not unified into it).
#[test]
fn testkit_is_off_in_a_normal_workspace_build() {
    let features = |edges: &str| cargo_tree(&["--workspace", "-e", edges, "-i", "taut-rt-core", "--depth", "0", "-f", "{p} [{f}]"]);
    let build = features("normal,build");
    assert!(
        !build.contains("testkit"),
        "crate graph rule broken: taut-rt-core's `testkit` is on in `cargo build --workspace` (docs/architecture.md); \
         a normal dependency turns it on, make it a dev-dependency:\n{build}\n{}",
        cargo_tree(&["--workspace", "-e", "features,normal,build", "-i", "taut-rt-core", "--prefix", "depth"])
    );
    // The checker sees the feature where it is on: the tests' and benches' builds.
    assert!(features("normal,build,dev").contains("testkit"), "{}", features("normal,build,dev"));
}

/// The checker itself sees a real edge: the simulated rig does depend on taut-sim and taut-vdev,
/// through the path printed (the rules above would not pass by a checker that sees nothing).
#[test]
fn the_checker_finds_a_real_dependency() {
    let with = violations("taut-simrig", "normal", &[], &["taut-sim", "taut-vdev"]);
    assert_eq!(with.len(), 2, "{with:?}");
    assert!(with[0].contains("taut-sim") && with[0].contains("taut-simrig"), "{}", with[0]);
    // And the real-time crate's one dependency is seen too.
    let model = violations("taut-rt", "normal", &[], &["taut-model"]);
    assert_eq!(model.len(), 1, "{model:?}");
}

/// The simulator is independent of the calibration's model (brief): it may hold the shared
/// geometry *data* type (through `taut-config`), never the formulas of `taut-model`.
#[test]
fn the_simulator_does_not_use_the_model_crate() {
    let direct = deps("taut-sim", "normal,build", &["--depth", "1"]);
    assert!(!direct.contains("taut-model"), "taut-sim must not depend on taut-model directly: {direct:?}");
    let names = |dir: &str| -> Vec<String> {
        let mut found = vec![];
        for e in std::fs::read_dir(workspace().join(dir)).unwrap() {
            let f = e.unwrap().path();
            if f.extension().is_some_and(|x| x == "rs") && std::fs::read_to_string(&f).unwrap().contains("taut_model") {
                found.push(f.display().to_string());
            }
        }
        found
    };
    assert_eq!(names("sim/src"), Vec::<String>::new(), "taut-sim's source names taut_model");
    // The scan sees what it looks for: the calibration does use the model crate.
    assert!(!names("calib/src").is_empty());
}

/// The `.rs` files under `dir`, recursively, `target/` left out.
fn rust_files(dir: &std::path::Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = e.unwrap().path();
        if p.is_dir() {
            if p.file_name().is_some_and(|n| n != "target") {
                rust_files(&p, out);
            }
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// One `MAX_CABLES`: the loop's arrays, the configuration's bound and the C ABI's arrays are one
/// number. Every constant named `*MAX_CABLES` in the workspace's source is either
/// `taut_model::MAX_CABLES` (the one written as a number) or defined from another constant.
#[test]
fn one_max_cables() {
    let members = ["model", "proto", "config", "calib", "sim", "vdev", "driver", "rt", "rt-core", "simrig", "ffi", "cli", "tests", "fuzz"];
    let mut files = Vec::new();
    for m in members {
        rust_files(&workspace().join(m), &mut files);
    }
    files.sort();
    let (mut numbers, mut derived) = (Vec::new(), Vec::new());
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        for (k, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            let Some((name, rest)) = code.split_once("MAX_CABLES:") else { continue };
            if !name.contains("const ") {
                continue;
            }
            let Some((_, value)) = rest.split_once('=') else { continue };
            let at = format!("{}:{}: {}", f.strip_prefix(workspace()).unwrap_or(f).display(), k + 1, line.trim());
            if value.trim_start().starts_with(|c: char| c.is_ascii_digit()) {
                numbers.push(at);
            } else {
                derived.push(at);
            }
        }
    }
    assert_eq!(
        numbers.len(),
        1,
        "crate graph rule broken: one MAX_CABLES (docs/architecture.md); constants written as numbers:\n{}",
        numbers.join("\n")
    );
    assert!(numbers[0].starts_with("model/src/lib.rs:"), "the one MAX_CABLES is taut_model's: {numbers:?}");
    // The scan sees the C ABI's constant, defined from the one (the header's generator writes it).
    assert!(derived.iter().any(|l| l.starts_with("ffi/src/lib.rs:") && l.contains("TAUT_MAX_CABLES")), "{derived:?}");
}
