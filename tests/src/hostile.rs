#![allow(dead_code)]
//! The hostile-input suite's runner: tables of cases, each run as the real `taut` binary in a
//! fresh directory with a deadline, then judged on five counts (issue 13):
//!
//! - **panic**: "panicked" on stderr, exit code 101, or death by a signal (an abort);
//! - **hang**: still running at the deadline (it is killed);
//! - **wrong success**: exit 0 where an error was expected (or an error where success was);
//! - **message**: the expected substrings (file, line, key, what to do) are not all on stderr;
//! - **data loss**: a file that existed before is changed or gone (unless the case writes it), a
//!   device node is no longer one, or a temporary file is left behind.
//!
//! A case that fails none of these is a clean error (or a clean success). Each suite prints one
//! summary line and fails if any count but the clean ones is not zero.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// How long one subprocess may run. Generous: the machine is shared and debug builds are slow,
/// and a hang is what it catches, not slowness.
pub const DEADLINE: Duration = Duration::from_secs(180);

/// The `taut` binary, built once per test process (`cargo build -p taut-cli`, a no-op when it is
/// up to date) next to this test's own executable; or `$TAUT_HOSTILE_BIN`.
pub fn taut_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        // The binary scripts/test built, or to count what another build does (e.g. the code before
        // issue 13): TAUT_HOSTILE_BIN=path.
        if let Some(p) = std::env::var_os("TAUT_HOSTILE_BIN") {
            return PathBuf::from(p);
        }
        let exe = std::env::current_exe().expect("test executable path");
        // target/<profile>/deps/<test> -> target/debug/taut. Built with the tests' profile and
        // scripts/test's feature set (the whole workspace, the plugin's simulator on), so that
        // only the cli crate itself is compiled on top of what the tests were built from: the
        // dev profile rebuilt every workspace crate unoptimised (and the binary ran its
        // calibrations several times slower in the tests that call it).
        let target = exe.parent().and_then(Path::parent).and_then(Path::parent).expect("target directory");
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../Cargo.toml");
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .args(["build", "-q", "--profile", "test", "--workspace", "--features", "taut-ffi/sim", "--bin", "taut", "--manifest-path"])
            .arg(&manifest)
            .env("CARGO_TARGET_DIR", target)
            .status()
            .expect("running cargo build for the taut binary");
        assert!(status.success(), "cargo build -p taut-cli failed");
        let bin = target.join("debug/taut");
        assert!(bin.is_file(), "no taut binary at {}", bin.display());
        bin
    })
}

/// Something put into a case's directory before the run.
#[derive(Clone, Debug)]
pub enum Entry {
    /// A regular file with these bytes.
    File(Vec<u8>),
    /// An empty directory.
    Dir,
    /// A symlink to this target.
    Symlink(String),
    /// A hard link to another entry of the case (created after it).
    HardLink(String),
    /// A fifo (a reader or writer that opens it would block).
    Fifo,
}

/// One hostile input.
pub struct Case {
    /// Short name, printed on failure.
    pub name: String,
    /// Arguments of `taut` (run in the case directory), or a `sh -c` script when `shell` is set
    /// (`$TAUT` is the binary).
    pub args: Vec<String>,
    /// Run `sh -c` with this script instead of `taut args`.
    pub shell: Option<String>,
    /// What is in the directory before the run, by name (subdirectories with `/`).
    pub entries: Vec<(String, Entry)>,
    /// Expected exit code (1: an error, 0: accepted).
    pub code: i32,
    /// Substrings stderr must contain.
    pub expect: Vec<String>,
    /// Entries the case may replace or create (a successful write).
    pub may_change: Vec<String>,
    /// Extra check after the run (e.g. `/dev/full` is still a device node).
    pub after: Option<fn() -> Result<(), String>>,
}

impl Case {
    /// A case that runs `taut args` and expects an error mentioning every one of `expect`.
    pub fn err(name: impl Into<String>, args: &[&str], expect: &[&str]) -> Self {
        Case {
            name: name.into(),
            args: args.iter().map(|s| s.to_string()).collect(),
            shell: None,
            entries: Vec::new(),
            code: 1,
            expect: expect.iter().map(|s| s.to_string()).collect(),
            may_change: Vec::new(),
            after: None,
        }
    }

    /// A case that expects success.
    pub fn ok(name: impl Into<String>, args: &[&str], expect: &[&str]) -> Self {
        Case { code: 0, ..Case::err(name, args, expect) }
    }

    /// Adds a regular file.
    pub fn file(mut self, name: &str, bytes: impl Into<Vec<u8>>) -> Self {
        self.entries.push((name.into(), Entry::File(bytes.into())));
        self
    }

    /// Adds any entry.
    pub fn entry(mut self, name: &str, e: Entry) -> Self {
        self.entries.push((name.into(), e));
        self
    }

    /// Allows the run to write `name`.
    pub fn writes(mut self, name: &str) -> Self {
        self.may_change.push(name.into());
        self
    }

    /// Runs a shell script instead.
    pub fn shell(mut self, script: &str) -> Self {
        self.shell = Some(script.into());
        self
    }

    /// An extra check after the run.
    pub fn after(mut self, f: fn() -> Result<(), String>) -> Self {
        self.after = Some(f);
        self
    }
}

/// The counts of one suite.
#[derive(Default, Debug)]
pub struct Tally {
    /// Cases run.
    pub cases: usize,
    /// Refused with the expected exit code and message, nothing lost.
    pub clean_errors: usize,
    /// Accepted as expected, nothing lost.
    pub clean_successes: usize,
    /// Panics or aborts.
    pub panics: usize,
    /// Killed at the deadline.
    pub hangs: usize,
    /// Exit 0 where an error was expected (or the reverse).
    pub wrong_exits: usize,
    /// Expected substrings missing.
    pub bad_messages: usize,
    /// A file changed, lost, or litter left.
    pub data_loss: usize,
    /// One line per problem.
    pub problems: Vec<String>,
}

impl Tally {
    /// The summary line the lead counts.
    pub fn summary(&self, suite: &str) -> String {
        format!(
            "hostile suite {suite}: {} cases, {} clean errors, {} clean successes, {} panics, {} hangs, {} wrong successes/exits, {} missing messages, {} data loss",
            self.cases, self.clean_errors, self.clean_successes, self.panics, self.hangs, self.wrong_exits, self.bad_messages, self.data_loss
        )
    }

    /// Prints the problems and the summary; panics if there is any problem.
    pub fn finish(&self, suite: &str) {
        for p in &self.problems {
            eprintln!("{p}");
        }
        let s = self.summary(suite);
        println!("{s}");
        eprintln!("{s}");
        assert!(self.problems.is_empty(), "{} problems in the hostile suite {suite}", self.problems.len());
    }
}

/// What one run did.
pub struct Run {
    /// Exit code, if it exited.
    pub code: Option<i32>,
    /// Signal that killed it, if any.
    pub signal: Option<i32>,
    /// Killed at the deadline.
    pub timed_out: bool,
    /// Its stdout.
    pub stdout: String,
    /// Its stderr.
    pub stderr: String,
}

/// Runs `cmd` with a deadline, collecting its output on threads so a full pipe cannot stall it.
pub fn run_with_deadline(mut cmd: Command, deadline: Duration) -> Run {
    use std::os::unix::process::ExitStatusExt;
    let mut child =
        cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).env("RUST_BACKTRACE", "0").spawn().expect("spawning taut");
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    // Read at most 1 MiB of each: a hostile input must not make the suite itself grow.
    let to = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = (&mut out).take(1 << 20).read_to_end(&mut v);
        let _ = std::io::copy(&mut out, &mut std::io::sink());
        v
    });
    let te = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = (&mut err).take(1 << 20).read_to_end(&mut v);
        let _ = std::io::copy(&mut err, &mut std::io::sink());
        v
    });
    let start = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().expect("waiting for taut") {
            break s;
        }
        if start.elapsed() > deadline {
            timed_out = true;
            let _ = child.kill();
            break child.wait().expect("waiting for killed taut");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Run {
        code: status.code(),
        signal: status.signal(),
        timed_out,
        stdout: String::from_utf8_lossy(&to.join().unwrap_or_default()).into_owned(),
        stderr: String::from_utf8_lossy(&te.join().unwrap_or_default()).into_owned(),
    }
}

/// A snapshot of a directory tree: path -> (kind, bytes or link target).
fn snapshot(dir: &Path) -> BTreeMap<String, (String, Vec<u8>)> {
    let mut m = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else { continue };
        for e in rd.flatten() {
            let p = e.path();
            let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
            let Ok(meta) = std::fs::symlink_metadata(&p) else {
                continue;
            };
            let ft = meta.file_type();
            let v = if ft.is_symlink() {
                ("symlink".into(), std::fs::read_link(&p).map(|t| t.into_os_string().into_encoded_bytes()).unwrap_or_default())
            } else if ft.is_dir() {
                stack.push(p.clone());
                ("dir".into(), Vec::new())
            } else if ft.is_file() {
                ("file".into(), std::fs::read(&p).unwrap_or_default())
            } else {
                ("special".into(), Vec::new())
            };
            m.insert(rel, v);
        }
    }
    m
}

fn make_entries(dir: &Path, entries: &[(String, Entry)]) {
    for (name, e) in entries {
        let p = dir.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        match e {
            Entry::File(b) => std::fs::write(&p, b).unwrap(),
            Entry::Dir => std::fs::create_dir_all(&p).unwrap(),
            Entry::Symlink(t) => std::os::unix::fs::symlink(t, &p).unwrap(),
            Entry::HardLink(t) => std::fs::hard_link(dir.join(t), &p).unwrap(),
            Entry::Fifo => {
                let c = std::ffi::CString::new(p.as_os_str().as_encoded_bytes()).unwrap();
                // SAFETY: a valid NUL-terminated path; mkfifo does not keep the pointer.
                assert_eq!(unsafe { libc_mkfifo(c.as_ptr(), 0o644) }, 0, "mkfifo {}", p.display());
            }
        }
    }
}

extern "C" {
    #[link_name = "mkfifo"]
    fn libc_mkfifo(path: *const std::ffi::c_char, mode: u32) -> i32;
}

/// Runs every case of a suite and tallies them.
pub fn run_suite(suite: &str, cases: Vec<Case>) -> Tally {
    let bin = taut_bin();
    let root = tempfile::Builder::new().prefix(&format!("taut-hostile-{suite}-")).tempdir().unwrap();
    let mut t = Tally::default();
    // HOSTILE_SKIP=a,b: leave out cases whose name contains a or b (for running the suite against
    // an old build, where some cases would exhaust the machine's memory).
    let skip: Vec<String> = std::env::var("HOSTILE_SKIP").map(|s| s.split(',').map(str::to_string).collect()).unwrap_or_default();
    for (k, case) in cases.into_iter().enumerate() {
        if skip.iter().any(|x| !x.is_empty() && case.name.contains(x.as_str())) {
            continue;
        }
        t.cases += 1;
        let dir = root.path().join(format!("{k:03}"));
        std::fs::create_dir_all(&dir).unwrap();
        make_entries(&dir, &case.entries);
        let before = snapshot(&dir);
        let cmd = match &case.shell {
            Some(script) => {
                let mut c = Command::new("sh");
                c.arg("-c").arg(script).env("TAUT", bin);
                c
            }
            None => {
                let mut c = Command::new(bin);
                c.args(&case.args);
                c
            }
        };
        let mut cmd = cmd;
        cmd.current_dir(&dir);
        let r = run_with_deadline(cmd, DEADLINE);
        let after = snapshot(&dir);
        let tag = format!("[{suite} #{k} {}]", case.name);
        if std::env::var_os("HOSTILE_VERBOSE").is_some() {
            eprintln!("{tag} exit {:?}: {}", r.code, r.stderr.trim().replace('\n', " | "));
        }
        let mut bad = false;
        let mut flag = |t: &mut Tally, what: &str, detail: String| {
            t.problems.push(format!("{tag} {what}: {detail}\n  stderr: {}", r.stderr.trim().replace('\n', "\n          ")));
            bad = true;
        };
        if r.timed_out {
            t.hangs += 1;
            flag(&mut t, "HANG", format!("still running after {DEADLINE:?}"));
        } else if r.stderr.contains("panicked") || r.code == Some(101) || r.signal.is_some() {
            t.panics += 1;
            flag(&mut t, "PANIC", format!("exit {:?}, signal {:?}", r.code, r.signal));
        } else if r.code != Some(case.code) {
            t.wrong_exits += 1;
            flag(&mut t, "WRONG EXIT", format!("exit {:?}, expected {}", r.code, case.code));
        }
        let missing: Vec<&String> = case.expect.iter().filter(|s| !r.stderr.contains(s.as_str())).collect();
        if !missing.is_empty() {
            t.bad_messages += 1;
            flag(&mut t, "MESSAGE", format!("stderr lacks {missing:?}"));
        }
        let mut lost = Vec::new();
        for (name, v) in &before {
            if case.may_change.iter().any(|m| m == name) {
                continue;
            }
            match after.get(name) {
                None => lost.push(format!("{name} is gone")),
                Some(w) if w != v => lost.push(format!("{name} changed")),
                _ => {}
            }
        }
        for name in after.keys() {
            if !before.contains_key(name) && !case.may_change.iter().any(|m| m == name) {
                lost.push(format!("{name} appeared (litter)"));
            }
        }
        if let Some(check) = case.after {
            if let Err(e) = check() {
                lost.push(e);
            }
        }
        if !lost.is_empty() {
            t.data_loss += 1;
            flag(&mut t, "DATA", lost.join(", "));
        }
        if !bad {
            if case.code == 0 {
                t.clean_successes += 1;
            } else {
                t.clean_errors += 1;
            }
        }
    }
    t
}

/// A valid recording of the simulated ARAS-CAM robot (4 cables, tensions, phase column), small
/// enough that a calibration of it is quick.
pub fn good_recording() -> String {
    static REC: OnceLock<String> = OnceLock::new();
    REC.get_or_init(|| {
        let mut s = taut_sim::Scenario::aras_cam(7);
        s.duration_s = 20.0;
        s.rate_hz = 20.0;
        let run = taut_sim::try_simulate(&s).expect("simulating the base recording");
        let mut buf = Vec::new();
        run.recording.write_csv(&mut buf).unwrap();
        String::from_utf8(buf).unwrap()
    })
    .clone()
}

/// The base recording with line `line` (1-based) replaced by `f(old line)`.
pub fn with_line(text: &str, line: usize, f: impl Fn(&str) -> String) -> String {
    let mut out = String::with_capacity(text.len() + 64);
    for (i, l) in text.lines().enumerate() {
        if i + 1 == line {
            out.push_str(&f(l));
        } else {
            out.push_str(l);
        }
        out.push('\n');
    }
    out
}

/// Field `col` (0-based) of a CSV line replaced by `v`.
pub fn set_field(line: &str, col: usize, v: &str) -> String {
    let mut f: Vec<&str> = line.split(',').collect();
    f[col] = v;
    f.join(",")
}

/// A valid robot configuration (4 cables with anchors) for the simulator, as TOML text.
pub const GOOD_CONFIG: &str = "[robot]\nname = \"hostile\"\nmass_kg = 3.0\n\
[[cable]]\nanchor = [3.5, -1.75, 4.0]\n\
[[cable]]\nanchor = [3.5, 1.75, 4.0]\n\
[[cable]]\nanchor = [-3.5, 1.75, 4.0]\n\
[[cable]]\nanchor = [-3.5, -1.75, 4.0]\n";
