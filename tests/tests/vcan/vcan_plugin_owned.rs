//! The C host in plugin-owned mode over real SocketCAN: `examples/c-host/owned.c`, linked
//! against `libtaut.so`, configures and activates the plugin with `TAUT_DEVICES_PLUGIN` and only
//! gives the cycle; taut opens the configuration's devices itself: the simulated robot's
//! virtual CiA 402 drives on `vcan0`, its Modbus RTU load cells on a pseudo-terminal, its
//! tracker on a loopback UDP port (`taut_simrig::build_site`, the site alone). The start-up runs
//! from cold to the hot-swap of the calibrated parameters.
//!
//! Runs inside the QEMU VM of `tests/vcan/run`, which compiles the host and names it in
//! `TAUT_C_HOST_OWNED` (one emulated CPU: a 100 Hz loop, flow not accuracy). Elsewhere it skips
//! unless `TAUT_VCAN_REQUIRED=1`.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use taut_io::FromRobot;
use taut_rt::motion::ControllerConfig;
use taut_simrig::{self as simrig, SimOptions};
use taut_tests::vcan;

#[test]
fn c_host_in_plugin_owned_mode_reaches_the_hot_swap() {
    let Some(iface) = vcan::iface_or_skip("vcan0", "c_host_in_plugin_owned_mode_reaches_the_hot_swap") else {
        return;
    };
    let host = std::env::var_os("TAUT_C_HOST_OWNED")
        .expect("TAUT_C_HOST_OWNED names the compiled examples/c-host/owned.c (tests/vcan/run builds it)");
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = crate::vcan_start::robot(dir.path());
    // The tracker's datagrams to a loopback port the plugin will listen on.
    let port = std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let listen: std::net::SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
    let mut tracker = taut_proto::devices::TrackerConfig::new(listen.to_string());
    tracker.max_age_s = cfg.safety.tracker_max_age_s;
    cfg.tracker = Some(tracker);
    cfg.can.as_mut().unwrap().interface = iface.to_string();
    let w = ControllerConfig::from_robot(&cfg).unwrap().workspace;
    let p0 = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0, (w[0][2] + w[1][2]) / 2.0];
    let so = SimOptions {
        seed: 5,
        can: Some(iface.to_string()),
        site_period: Duration::from_millis(5),
        load_cell_line: simrig::LoadCellLine::Pty,
        ..Default::default()
    };
    let p0 = simrig::rest_position(&cfg, &so, p0);
    let site = simrig::build_site(&cfg, p0, &so, listen).expect("the simulated site on vcan0");
    cfg.loadcells.as_mut().unwrap().port = site.loadcell_port.display().to_string();
    let config = dir.path().join("robot.toml");
    cfg.save_atomic(&config).unwrap();
    let data = dir.path().join("data");
    let t0 = Instant::now();
    let mut child = Command::new(&host)
        .arg(&config)
        .arg(&data)
        .arg("420")
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", std::path::Path::new(&host).display()));
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > Duration::from_secs(480) {
            let _ = child.kill();
            panic!("the C host did not finish within 480 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    eprintln!(
        "C host exited with {status} after {:.1} s; plant steps without equilibrium {}",
        t0.elapsed().as_secs_f64(),
        site.faults.plant_failed_steps.load(std::sync::atomic::Ordering::Relaxed)
    );
    if !status.success() {
        // What the plugin recorded: per phase label, the rows and those with a tracker position.
        for e in std::fs::read_dir(data.join("recordings")).into_iter().flatten().flatten() {
            match taut_config::recording::Recording::load(e.path()) {
                Ok((rec, _)) => {
                    let mut per: std::collections::BTreeMap<i32, (usize, usize)> = Default::default();
                    for i in 0..rec.len() {
                        let label = rec.phase.as_ref().map_or(-1, |p| p[i]);
                        let c = per.entry(label).or_default();
                        c.0 += 1;
                        c.1 += usize::from(rec.p[i].iter().all(|v| v.is_finite()));
                    }
                    eprintln!("{}: rows and tracked rows per phase label {per:?}", e.path().display());
                }
                Err(err) => eprintln!("{}: {err}", e.path().display()),
            }
        }
    }
    assert!(status.success(), "the C host failed (its reason above)");
    // The calibrated parameters the plugin wrote beside its recordings.
    let written = std::fs::read_dir(&data).map(|d| d.flatten().filter(|e| e.path().extension().is_some_and(|x| x == "toml")).count());
    eprintln!("parameter files in the data directory: {written:?}");
}
