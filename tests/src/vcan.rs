//! Helpers for tests that need a real SocketCAN interface (`vcan0`, `vcan1`).
//!
//! The `tests/vcan/run` script boots a QEMU VM with the CAN modules loaded,
//! `vcan0` and `vcan1` up, and [`REQUIRED_ENV`] set to `1`, then runs every
//! module of the `vcan` test target (`tests/tests/vcan/`) there. On a normal host (`cargo test`) the
//! interfaces are usually missing and the tests skip themselves:
//!
//! ```no_run
//! #[test]
//! fn talks_to_the_bus() {
//!     let Some(iface) = taut_tests::vcan::iface_or_skip("vcan0", "talks_to_the_bus") else {
//!         return;
//!     };
//!     // ... open `iface` with the socketcan crate ...
//! #   let _ = iface;
//! }
//! ```

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

/// Environment variable that turns a missing interface or tool into a test
/// failure instead of a skip. The VM's init sets it to `1`.
pub const REQUIRED_ENV: &str = "TAUT_VCAN_REQUIRED";

/// Linux `ARPHRD_CAN`, the link type `/sys/class/net/<if>/type` reports for
/// CAN interfaces.
const ARPHRD_CAN: u32 = 280;

/// True when [`REQUIRED_ENV`] is `1` (or `true`/`yes`): missing CAN
/// interfaces or tools must fail the test.
pub fn required() -> bool {
    matches!(env::var(REQUIRED_ENV).as_deref().map(str::trim), Ok("1") | Ok("true") | Ok("yes"))
}

/// Why `iface` cannot be used, or `None` if it is an existing, up, CAN
/// interface.
pub fn iface_problem(iface: &str) -> Option<String> {
    let dir = Path::new("/sys/class/net").join(iface);
    if !dir.exists() {
        return Some(format!("network interface {iface} does not exist"));
    }
    match fs::read_to_string(dir.join("type")) {
        Ok(t) if t.trim().parse::<u32>().ok() == Some(ARPHRD_CAN) => {}
        Ok(t) => return Some(format!("{iface} is not a CAN interface (link type {})", t.trim())),
        Err(e) => return Some(format!("cannot read the link type of {iface}: {e}")),
    }
    // IFF_UP is bit 0 of the flags.
    match fs::read_to_string(dir.join("flags")) {
        Ok(f) => {
            let flags = u32::from_str_radix(f.trim().trim_start_matches("0x"), 16).unwrap_or(0);
            if flags & 1 == 0 {
                return Some(format!("{iface} is down"));
            }
        }
        Err(e) => return Some(format!("cannot read the flags of {iface}: {e}")),
    }
    None
}

/// Skip-or-fail gate for a CAN interface.
///
/// Returns `Some(iface)` when the interface is usable. Otherwise, prints a
/// skip message and returns `None` (the test should `return`), or panics if
/// [`required()`] is true.
pub fn iface_or_skip<'a>(iface: &'a str, test: &str) -> Option<&'a str> {
    match iface_problem(iface) {
        None => Some(iface),
        Some(why) => skip_or_fail(test, &why),
    }
}

/// Like [`iface_or_skip`] for several interfaces at once.
pub fn ifaces_or_skip<'a, const N: usize>(ifaces: [&'a str; N], test: &str) -> Option<[&'a str; N]> {
    for iface in ifaces {
        iface_or_skip(iface, test)?;
    }
    Some(ifaces)
}

/// Looks up an executable (e.g. `candump`) in `PATH`.
pub fn find_tool(name: &str) -> Option<PathBuf> {
    let path = env::var_os("PATH")?;
    env::split_paths(&path).map(|dir| dir.join(name)).find(|p| is_executable(p))
}

/// Skip-or-fail gate for an external tool such as `candump`.
pub fn tool_or_skip(name: &str, test: &str) -> Option<PathBuf> {
    match find_tool(name) {
        Some(p) => Some(p),
        None => skip_or_fail(test, &format!("{name} not found in PATH")),
    }
}

/// Prints a skip message and returns `None`, or panics when [`required()`].
pub fn skip_or_fail<T>(test: &str, why: &str) -> Option<T> {
    if required() {
        panic!("{test}: {why} (and {REQUIRED_ENV}=1, so this is a failure)");
    }
    eprintln!(
        "SKIPPED {test}: {why}. Real SocketCAN tests run in a VM via tests/vcan/run \
         (set {REQUIRED_ENV}=1 to make this a failure)."
    );
    None
}

fn is_executable(p: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    fs::metadata(p).map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0).unwrap_or(false)
}

/// The CANopen master's configuration for virtual drives `nodes` over vcan under TCG emulation:
/// generous periods and timeouts (timing in the VM means nothing), heartbeats every 250 ms
/// consumed with 3 s of patience. Each test sets what its scenario needs on top (the master's
/// own heartbeat period, `reset_on_start`, `boot_wait`).
pub fn master_config(nodes: &[u8]) -> taut_driver::canopen::master::MasterConfig {
    use std::time::Duration;
    use taut_driver::canopen::master::{MasterConfig, NodeConfig};
    let mut cfg = MasterConfig::new(
        nodes
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                let mut c = NodeConfig::new(n, i);
                c.heartbeat_ms = 250;
                c.heartbeat_timeout = Duration::from_secs(3);
                c
            })
            .collect(),
    );
    cfg.sync_period = Duration::from_millis(10);
    cfg.sdo_timeout = Duration::from_secs(2);
    cfg.bringup_timeout = Duration::from_secs(60);
    cfg
}
