//! The dependency rules of the workspace (docs/architecture.md), checked on the real graph with
//! `cargo tree --offline --locked`:
//!
//! - `taut-driver` (the CANopen master, Modbus, tracker input) depends on neither the physics
//!   (`taut-sim`) nor the virtual devices (`taut-vdev`), not even as a dev-dependency: a bench or
//!   test that needs virtual drives lives in `taut-vdev` or `tests/`.
//! - `taut-sim` is physics only: no `taut-vdev`, no `taut-driver`.
//! - `taut-vdev` (the device side) does not depend on `taut-sim`: the simulated rig couples them.
//! - `taut-calib` is pure: no I/O crates (`socketcan`, `serialport`, `libc`).

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
        violations("taut-driver", "normal,build", &[], &["taut-sim", "taut-vdev"]),
        "the driver must build without the physics and without the device side",
    );
    // Dev-dependencies too: a dev-dependency on a crate that depends on the driver is a cycle
    // (two copies of the driver's types in its unit tests). `--depth 1`: the driver's own
    // dev-dependencies, not those of the crates below it.
    assert_none(
        violations("taut-driver", "dev", &["--depth", "1"], &["taut-sim", "taut-vdev"]),
        "the driver's benches and tests must not need the device side; put them in taut-vdev or tests/",
    );
}

#[test]
fn sim_is_physics_only() {
    assert_none(
        violations("taut-sim", "normal,build", &[], &["taut-vdev", "taut-driver"]),
        "taut-sim is physics only: the devices are in taut-vdev, the simulated rig in rt-core couples them",
    );
}

#[test]
fn virtual_devices_do_not_need_the_physics() {
    assert_none(
        violations("taut-vdev", "normal,build", &[], &["taut-sim"]),
        "taut-vdev is the device side of the protocols; the plant is coupled to it from rt-core's simulated rig",
    );
}

#[test]
fn calib_has_no_io_crates() {
    assert_none(
        violations("taut-calib", "normal,build", &[], &["socketcan", "serialport", "libc", "taut-driver"]),
        "taut-calib is pure computation (no I/O)",
    );
}

/// The checker itself sees a real edge: rt-core with `--features sim` does depend on taut-sim and
/// taut-vdev, and without it on neither (the rules above would not pass by a checker that sees nothing).
#[test]
fn the_checker_finds_a_real_dependency() {
    let with = violations("taut-rt-core", "normal", &["--features", "sim"], &["taut-sim", "taut-vdev"]);
    assert_eq!(with.len(), 2, "{with:?}");
    assert!(with[0].contains("taut-sim") && with[0].contains("taut-rt-core"), "{}", with[0]);
    let without = violations("taut-rt-core", "normal", &[], &["taut-sim", "taut-vdev"]);
    assert!(without.is_empty(), "{without:?}");
}
