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
//! - `taut-io` (the robot's devices and the loop thread, which the real-time thread calls into)
//!   links no calibration (`taut-calib`, nalgebra, `taut-calibrator`), no JSON (serde_json), no
//!   MCAP and no WebSocket (tungstenite), and none of the crates above it (`taut-operator`,
//!   `taut-plugin`).
//! - `taut-calibrator` depends on neither the operator's services (`taut-operator`: control
//!   socket, MCAP channels, telemetry) nor the plugin; its vocabulary module (`vocab`) imports
//!   nothing from the rest of the crate.
//! - The robot build (`taut-plugin` and everything below it) contains no simulator: the
//!   simulated rig is `taut-simrig`. Nor does `taut-ffi` by default (the `taut_sim_*` functions are its `sim` feature), nor
//!   `taut-cli` without its `sim` feature (on by default for development and the tests).
//! - `testkit` (a feature of `taut-io`: the kinematic stand-in robot) is not on in a normal
//!   `cargo build --workspace`: only dev-dependencies turn it on.
//! - One number of cables: `taut_model::MAX_CABLES` is the only `MAX_CABLES` written as a number;
//!   the others (the C ABI's `TAUT_MAX_CABLES`) are defined from it or re-export it.
//! - `taut-sim` does not use the model the calibration fits: no direct `taut-model` dependency
//!   and no `taut_model` in its source. It reaches `taut-model` only through `taut-config`
//!   (allowed edge: the parameter file converts to the shared geometry type in one place), and
//!   names the plain data type `Geometry` only through `taut_config::params`.
//! - No crate re-exports another crate's modules or a whole crate (`pub use taut_rt::motion;`,
//!   `pub use crossbeam_channel;`): code names the crate it uses, so an import shows the real-time
//!   boundary. Another crate's single items stay re-exported only where listed with a reason
//!   (`ITEM_REEXPORTS`: the model's shared data types, the plugin's API types from `taut-rt`).

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
        violations(
            "taut-driver",
            "normal,build",
            &[],
            &["taut-sim", "taut-vdev", "taut-simrig", "taut-rt", "taut-io", "taut-calibrator", "taut-operator", "taut-plugin"],
        ),
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
        violations("taut-vdev", "normal,build", &[], &["taut-driver", "taut-simrig", "taut-io", "taut-plugin"]),
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
    "taut-io",
    "taut-calibrator",
    "taut-operator",
    "taut-plugin",
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
    // The scan sees what it looks for: the plugin's daemon spawns threads and the plugin takes locks.
    let daemon_side = scan(&workspace().join("plugin/src"));
    assert!(daemon_side.iter().any(|l| l.contains("thread::spawn") || l.contains("std::thread")), "{daemon_side:?}");
    assert!(daemon_side.iter().any(|l| l.contains("Mutex")), "{daemon_side:?}");
}

#[test]
fn the_robot_build_contains_no_simulator() {
    assert_none(
        violations("taut-plugin", "normal,build", &[], &["taut-sim", "taut-vdev", "taut-simrig"]),
        "taut-plugin (with taut-io, taut-calibrator and taut-operator below it) is the robot's build; the simulated rig is taut-simrig (used by `taut start --sim`, ffi and tests)",
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
    let features = |edges: &str| cargo_tree(&["--workspace", "-e", edges, "-i", "taut-io", "--depth", "0", "-f", "{p} [{f}]"]);
    let build = features("normal,build");
    assert!(
        !build.contains("testkit"),
        "crate graph rule broken: taut-io's `testkit` is on in `cargo build --workspace` (docs/architecture.md); \
         a normal dependency turns it on, make it a dev-dependency:\n{build}\n{}",
        cargo_tree(&["--workspace", "-e", "features,normal,build", "-i", "taut-io", "--prefix", "depth"])
    );
    // The checker sees the feature where it is on: the tests' and benches' builds.
    assert!(features("normal,build,dev").contains("testkit"), "{}", features("normal,build,dev"));
}

/// The device and loop-thread crate, which the real-time thread calls into (`robot_io`'s read and
/// write, the runner's cycle): no calibration, no JSON, no MCAP, no WebSocket, and none of the
/// crates above it. Its configuration comes from `taut-config` without the `mcap` feature, which
/// is the one that needs serde_json.
const NOT_IN_THE_LOOP_THREAD_CRATE: &[&str] =
    &["taut-calib", "nalgebra", "serde_json", "mcap", "tungstenite", "taut-calibrator", "taut-operator", "taut-plugin"];

#[test]
fn the_loop_thread_crate_links_no_calibration_json_mcap_or_websocket() {
    assert_none(
        violations("taut-io", "normal,build", &[], NOT_IN_THE_LOOP_THREAD_CRATE),
        "taut-io (devices and the loop thread) links neither the calibration nor nalgebra, serde_json, mcap or tungstenite; \
         the calibrator, the operator's services and the plugin are crates above it",
    );
    // The checker sees these crates where they are: the plugin links every one of them but itself.
    let above = violations("taut-plugin", "normal,build", &[], NOT_IN_THE_LOOP_THREAD_CRATE);
    assert_eq!(above.len(), NOT_IN_THE_LOOP_THREAD_CRATE.len(), "{above:#?}");
    // And the loop-thread crate's real edges: the loop and the master.
    assert_eq!(violations("taut-io", "normal", &["--depth", "1"], &["taut-rt", "taut-driver"]).len(), 2);
}

#[test]
fn the_calibrator_depends_on_neither_the_operators_services_nor_the_plugin() {
    assert_none(
        violations("taut-calibrator", "normal,build", &[], &["taut-operator", "taut-plugin", "serde_json", "mcap", "tungstenite"]),
        "taut-calibrator sends its samples and results through its own `vocab::RunOutputs` trait; \
         the MCAP channels and the telemetry (taut-operator) implement it",
    );
    // The checker sees the edge the other way: the operator's services use the calibrator's vocabulary.
    assert_eq!(violations("taut-operator", "normal", &["--depth", "1"], &["taut-calibrator"]).len(), 1);
}

/// The `crate::` paths of a file's non-test code that do not start with `allowed`.
fn crate_paths_outside(text: &str, allowed: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (k, line) in code_of(text).lines().enumerate() {
        let mut rest = line;
        while let Some(i) = rest.find("crate::") {
            let path: String = rest[i..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
            if !path.starts_with(allowed) {
                found.push(format!("code line {}: `{path}` in `{}`", k + 1, line.trim()));
            }
            rest = &rest[i + 7..];
        }
    }
    found
}

/// The calibrator's vocabulary (configuration, estimate, outcome, status, errors) is the module
/// the rest of the calibrator, the operator's services and the plugin import; it imports nothing
/// from the rest of its crate, so no two modules import each other in a circle through it.
#[test]
fn the_calibrators_vocabulary_imports_nothing_from_the_rest_of_its_crate() {
    let mut files = Vec::new();
    rust_files(&workspace().join("calibrator/src/vocab"), &mut files);
    files.sort();
    assert!(files.len() >= 2, "{files:?}");
    let mut found = Vec::new();
    for f in &files {
        for l in crate_paths_outside(&std::fs::read_to_string(f).unwrap(), "crate::vocab") {
            found.push(format!("{}: {l}", f.display()));
        }
    }
    assert!(found.is_empty(), "crate graph rule broken: the calibrator's vocabulary imports the rest of its crate:\n{}", found.join("\n"));
    // The scan sees what it looks for: the calibrator thread's module does use other modules.
    let thread = std::fs::read_to_string(workspace().join("calibrator/src/calibrator.rs")).unwrap();
    assert!(crate_paths_outside(&thread, "crate::vocab").iter().any(|l| l.contains("crate::heldout")));
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
    let members = [
        "model",
        "proto",
        "config",
        "calib",
        "sim",
        "vdev",
        "driver",
        "rt",
        "io",
        "calibrator",
        "operator",
        "plugin",
        "simrig",
        "ffi",
        "cli",
        "tests",
        "fuzz",
    ];
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

/// The workspace's member directories (`taut_io` is `io/`), as `use` paths name them.
const MEMBERS: &[(&str, &str)] = &[
    ("taut_model", "model"),
    ("taut_proto", "proto"),
    ("taut_config", "config"),
    ("taut_calib", "calib"),
    ("taut_sim", "sim"),
    ("taut_vdev", "vdev"),
    ("taut_driver", "driver"),
    ("taut_rt", "rt"),
    ("taut_io", "io"),
    ("taut_calibrator", "calibrator"),
    ("taut_operator", "operator"),
    ("taut_plugin", "plugin"),
    ("taut_simrig", "simrig"),
    ("taut_ffi", "ffi"),
    ("taut_cli", "cli"),
    ("taut_tests", "tests"),
];

/// The `pub use` of another crate's single items (types, functions, constants) that stay, each
/// with its reason: (file, the path re-exported). A new one is added here with a reason, or the
/// user names the item's own crate. Modules and whole crates are never re-exported.
const ITEM_REEXPORTS: &[(&str, &str, &str)] = &[
    // The model's shared data types, in the signatures of the crate that re-exports them.
    ("calib/src/lib.rs", "taut_model::geometry::Geometry", "calib's fit returns the shared geometry"),
    ("calib/src/lib.rs", "taut_model::geometry::GeometryError", "calib's fit returns the shared geometry"),
    ("calib/src/lib.rs", "taut_model::geometry::Sigmas", "calib's fit returns the shared geometry"),
    ("calib/src/design.rs", "taut_model::tour::segment_distance", "the excitation design's result, run by the loop"),
    ("calib/src/design.rs", "taut_model::tour::segment_time", "the excitation design's result, run by the loop"),
    ("calib/src/design.rs", "taut_model::tour::Tour", "the excitation design's result, run by the loop"),
    ("calib/src/design.rs", "taut_model::tour::MAX_WAYPOINTS", "the excitation design's result, run by the loop"),
    ("config/src/geometry.rs", "taut_model::MAX_CABLES", "the configuration's bound is the loop's one number"),
    ("config/src/params.rs", "taut_model::geometry::Geometry", "the parameter file converts to the shared geometry"),
    ("config/src/params.rs", "taut_model::geometry::Sigmas", "the parameter file converts to the shared geometry"),
    ("driver/src/transport/mod.rs", "taut_model::bus::BusEvent", "the transports report the shared bus status"),
    ("driver/src/transport/mod.rs", "taut_model::bus::IfName", "the transports report the shared bus status"),
    ("rt/src/io.rs", "taut_model::bus::BusEvent", "the loop's inputs carry the shared bus status"),
    ("rt/src/io.rs", "taut_model::bus::IfName", "the loop's inputs carry the shared bus status"),
    ("rt/src/lib.rs", "taut_model::geometry::Geometry", "the loop's parameters are built from the shared geometry"),
    ("rt/src/lib.rs", "taut_model::geometry::GeometryError", "the loop's parameters are built from the shared geometry"),
    ("rt/src/lib.rs", "taut_model::geometry::Sigmas", "the loop's parameters are built from the shared geometry"),
    ("rt/src/lib.rs", "taut_model::MAX_CABLES", "the loop's fixed arrays' size"),
    // The plugin's, the operator queue's and the loop thread's API: types of taut-rt in their signatures.
    ("plugin/src/lib.rs", "taut_rt::host::BadInput", "Plugin::update_with's error"),
    ("plugin/src/lib.rs", "taut_rt::host::HostInputs", "Plugin::update_with's argument"),
    ("plugin/src/lib.rs", "taut_rt::host::HostOutputs", "Plugin::update_with's argument"),
    ("plugin/src/lib.rs", "taut_rt::update::Tick", "Plugin::update's result"),
    ("plugin/src/lib.rs", "taut_rt::io::Devices", "DeviceSource::bring_up returns them"),
    ("plugin/src/handle.rs", "taut_rt::update::LoopEvent", "the plugin's event queue carries them"),
    ("operator/src/operator.rs", "taut_rt::update::LoopEvent", "the operator's event queue carries them"),
    ("io/src/runner.rs", "taut_rt::cycle::LoopCore", "run_loop's argument"),
    ("io/src/runner.rs", "taut_rt::cycle::LoopStatus", "run_loop's status output"),
    ("io/src/runner.rs", "taut_rt::cycle::LoopTiming", "run_periodic's per-cycle timing"),
];

/// The paths a `use` tree names: `a::{b, c::{d as e, self}}` is `a::b`, `a::c::d`, `a::c`.
fn use_leaves(tree: &str) -> Vec<String> {
    let tree: String = tree.chars().filter(|c| !c.is_whitespace() || *c == ' ').collect();
    let tree = tree.trim();
    let Some(open) = tree.find('{') else {
        let path = tree.split(" as ").next().unwrap().replace(' ', "");
        return vec![path.strip_suffix("::self").unwrap_or(&path).to_owned()];
    };
    let (prefix, body) = (tree[..open].trim().trim_end_matches("::"), &tree[open + 1..tree.rfind('}').unwrap()]);
    // Split the body at its top-level commas.
    let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
    for (i, c) in body.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&body[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&body[start..]);
    let mut out = Vec::new();
    for p in parts.into_iter().map(str::trim).filter(|p| !p.is_empty()) {
        for leaf in use_leaves(p) {
            out.push(if leaf == "self" { prefix.to_owned() } else { format!("{prefix}::{leaf}") });
        }
    }
    out
}

/// The `pub use` statements (not `pub(crate) use`) of a source text, outside comments, each with
/// its first line's number and the paths it names.
fn pub_uses(text: &str) -> Vec<(usize, Vec<String>)> {
    let lines: Vec<&str> = text.lines().map(|l| l.split("//").next().unwrap_or("")).collect();
    let mut out = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        if let Some(rest) = lines[k].trim_start().strip_prefix("pub use ") {
            let (first, mut stmt) = (k, rest.to_owned());
            while !stmt.contains(';') && k + 1 < lines.len() {
                k += 1;
                stmt.push(' ');
                stmt.push_str(lines[k].trim());
            }
            out.push((first + 1, use_leaves(stmt.split(';').next().unwrap())));
        }
        k += 1;
    }
    out
}

/// The crates a member's `Cargo.toml` names as dependencies (`crossbeam-channel` is
/// `crossbeam_channel`), and the standard ones.
fn dependency_names(member: &str) -> BTreeSet<String> {
    let toml = std::fs::read_to_string(workspace().join(member).join("Cargo.toml")).unwrap();
    let mut names: BTreeSet<String> = ["std", "core", "alloc"].map(str::to_owned).into();
    let mut in_deps = false;
    for line in toml.lines().map(str::trim) {
        if line.starts_with('[') {
            in_deps = line.contains("dependencies]");
            continue;
        }
        if in_deps && !line.starts_with('#') {
            if let Some(name) = line.split(['=', '.', ' ']).next().filter(|n| !n.is_empty()) {
                names.insert(name.replace('-', "_"));
            }
        }
    }
    names
}

/// Whether `path` (`taut_rt::motion`, `taut_rt`) is a workspace crate or one of its modules: a
/// file `<dir>/src/motion.rs` or `<dir>/src/motion/mod.rs` (taut declares no inline public modules).
fn is_workspace_module(path: &str) -> bool {
    let mut segs = path.split("::");
    let first = segs.next();
    let Some(&(_, dir)) = MEMBERS.iter().find(|(name, _)| Some(*name) == first) else { return false };
    let rest: Vec<&str> = segs.collect();
    if rest.is_empty() {
        return true;
    }
    let base = workspace().join(dir).join("src").join(rest.join("/"));
    base.with_extension("rs").is_file() || base.join("mod.rs").is_file()
}

/// Why one `pub use` path in `file` (relative to the workspace) breaks the rule, if it does:
/// another workspace crate or one of its modules, a whole external crate, a glob of another
/// crate, or another crate's item not in [`ITEM_REEXPORTS`].
fn reexport_problem(file: &str, path: &str, deps: &BTreeSet<String>) -> Option<String> {
    let first = path.split("::").next().unwrap();
    if !deps.contains(first) && !MEMBERS.iter().any(|(n, _)| *n == first) {
        return None; // crate-local (`crate::`, `self::`, `super::`, a module of this crate)
    }
    if path.ends_with("::*") {
        Some(format!("a glob of another crate, `{path}`"))
    } else if is_workspace_module(path) {
        Some(format!("another workspace crate's module, `{path}`"))
    } else if !path.contains("::") {
        Some(format!("a whole crate, `{path}`"))
    } else if ITEM_REEXPORTS.iter().any(|(f, p, _)| *f == file && *p == path) {
        None
    } else {
        Some(format!("another crate's item `{path}`, not among the listed exceptions (ITEM_REEXPORTS, with a reason)"))
    }
}

/// The rule's violations in one member's source text.
fn reexport_problems(file: &str, text: &str, deps: &BTreeSet<String>) -> Vec<String> {
    let mut found = Vec::new();
    for (line, paths) in pub_uses(text) {
        for p in paths {
            if let Some(why) = reexport_problem(file, &p, deps) {
                found.push(format!("{file}:{line}: re-exports {why}"));
            }
        }
    }
    found
}

/// No workspace crate re-exports another crate's modules or a whole crate: code that uses
/// `taut_rt::motion` names `taut_rt`, so every import shows which side of the real-time boundary
/// it reaches (issue 25). Single items stay re-exported where a crate's own API uses them
/// ([`ITEM_REEXPORTS`], each with its reason).
#[test]
fn no_crate_reexports_another_crates_modules() {
    let mut found = Vec::new();
    let mut listed_seen = BTreeSet::new();
    for (_, dir) in MEMBERS {
        let deps = dependency_names(dir);
        let mut files = Vec::new();
        rust_files(&workspace().join(dir).join("src"), &mut files);
        files.sort();
        for f in files {
            let rel = f.strip_prefix(workspace()).unwrap_or(&f).display().to_string();
            let text = std::fs::read_to_string(&f).unwrap();
            found.extend(reexport_problems(&rel, &text, &deps));
            for (_, paths) in pub_uses(&text) {
                listed_seen.extend(paths.into_iter().map(|p| (rel.clone(), p)));
            }
        }
    }
    assert!(
        found.is_empty(),
        "crate graph rule broken: no crate re-exports another crate's modules (docs/architecture.md)\n{}",
        found.join("\n")
    );
    // Every listed exception is still there (a stale entry would hide a new one).
    for (f, p, why) in ITEM_REEXPORTS {
        assert!(
            listed_seen.contains(&(f.to_string(), p.to_string())),
            "listed re-export gone: {f}: {p} ({why}); remove it from ITEM_REEXPORTS"
        );
    }
    // The check sees what it looks for: the old non-real-time crate's re-exports of taut-rt's
    // modules and of crossbeam_channel (put in the plugin's lib.rs), and a module re-export
    // spread over lines.
    let plugin = dependency_names("plugin");
    let old = "pub use taut_rt::{follower, io, kin, motion, ramp, safety, sample, spsc, triple, urgent, MAX_CABLES};\n\
               pub use crossbeam_channel;\npub use rt_config::{EffectsFromFile, FromRobot};\n";
    let v = reexport_problems("plugin/src/lib.rs", old, &plugin);
    assert_eq!(v.len(), 12, "{v:#?}"); // ten modules, MAX_CABLES not listed for the plugin, the crate
    assert!(v[3].contains("`taut_rt::motion`") && v[3].contains("module"), "{}", v[3]);
    assert!(v[11].contains("whole crate, `crossbeam_channel`"), "{}", v[11]);
    let spread = "pub use taut_rt::{\n    host, // the host structs\n    update::Tick,\n};\npub(crate) use taut_rt::io;\n";
    assert_eq!(reexport_problems("plugin/src/lib.rs", spread, &plugin).len(), 1);
    assert_eq!(use_leaves("a::{b, c::{d as e, self}}"), ["a::b", "a::c::d", "a::c"]);
}
