//! The C and C++ hosts (`examples/c-host`, `examples/cpp-host`) are compiled with the system's
//! `cc` and `g++` against `include/taut.h` and the `taut` shared library cargo built for this
//! test, and run the simulated robot's whole start-up through the C ABI in host-owned mode, to
//! the hot-swap of the calibrated parameters (each host checks the version and the anchors
//! against the simulated site's truth and exits non-zero otherwise).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The directory of the `libtaut.so` cargo built with this test (the test's own `deps/`, or the
/// profile directory above it).
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    for d in [deps, deps.parent().unwrap()] {
        if d.join("libtaut.so").exists() {
            return d.to_path_buf();
        }
    }
    panic!("no libtaut.so next to {} or in its parent: cargo builds it with this package's tests", exe.display());
}

fn compile(compiler: &str, std: &str, source: &str, out: &Path) {
    let lib = lib_dir();
    let status = Command::new(compiler)
        .arg(std)
        .args(["-Wall", "-Wextra", "-Werror", "-O1", "-I"])
        .arg(root().join("ffi/include"))
        .arg(root().join(source))
        .arg("-L")
        .arg(&lib)
        .arg("-ltaut")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-lm")
        .arg("-o")
        .arg(out)
        .status()
        .unwrap_or_else(|e| panic!("cannot run {compiler} (scripts/setup installs gcc and g++): {e}"));
    assert!(status.success(), "{compiler} failed on {source}");
}

/// Runs the host to the hot-swap (simulated time 4x faster than the wall clock where the
/// machine keeps up), killing it after `limit`.
fn run_host(exe: &Path, name: &str, limit: Duration) {
    let dir = tempfile::tempdir().unwrap();
    let config = root().join("config/examples/aras-cam-sim.toml");
    // cargo test puts the profile directory before deps/ on LD_LIBRARY_PATH, where a libtaut.so
    // of another build may be older: the host finds the one it was linked with by its rpath.
    let mut child = Command::new(exe)
        .env_remove("LD_LIBRARY_PATH")
        .arg(&config)
        .arg(dir.path())
        .args(["3", "4"])
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            assert!(s.success(), "{name} failed ({s}); its output is above");
            break;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{name} did not finish within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    eprintln!("{name}: start-up to hot-swap in {:.1} s wall", t0.elapsed().as_secs_f64());
    // The calibrator recorded the start-up into the data directory it was given.
    let recs: Vec<_> = std::fs::read_dir(dir.path().join("recordings")).unwrap().collect();
    assert_eq!(recs.len(), 1, "one recording in {}", dir.path().display());
}

#[test]
fn c_host_runs_the_simulated_start_up_to_a_hot_swap() {
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("taut-c-host");
    compile("cc", "-std=c11", "examples/c-host/host.c", &exe);
    run_host(&exe, "c-host", Duration::from_secs(900));
}

#[test]
fn cpp_host_runs_the_simulated_start_up_to_a_hot_swap() {
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("taut-cpp-host");
    compile("g++", "-std=c++17", "examples/cpp-host/host.cpp", &exe);
    run_host(&exe, "cpp-host", Duration::from_secs(900));
}
