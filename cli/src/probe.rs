//! `taut probe`: find every drive on the CAN bus, configure it, and print what is there.
//!
//! The same driver code runs against real drives (SocketCAN) and, with `--sim`, against the
//! simulator's virtual drives on an in-process bus.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use taut_config::RobotConfig;
use taut_driver::canopen::master::Counters;
use taut_driver::transport::candump::Recorder;
#[cfg(feature = "sim")]
use taut_driver::VirtualBus;
use taut_driver::{DriveSet, MasterConfig, NodeEvent, NodeStatus, Phase, SocketCanTransport};
use taut_io::robot_io::CableUnits;
use taut_proto::can::CanTransport;
use taut_proto::devices::{CanConfig, DriveConfig};
#[cfg(feature = "sim")]
use taut_vdev::{rack_filters, spawn_rack, DriveParams, VirtualDrive};

/// Arguments of `taut probe`.
#[derive(clap::Args, Debug)]
pub struct ProbeArgs {
    /// Robot configuration (TOML) with a `[can]` table and a `[cable.drive]` per driven cable.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Probe the simulated robot's virtual drives on an in-process bus instead of real hardware
    /// (without --config: a 4-cable robot with drives 1..4).
    #[arg(long)]
    pub sim: bool,
    /// CAN interface to use instead of the configuration's `can.interface`.
    #[arg(long)]
    pub interface: Option<String>,
    /// How long to watch the bus after bring-up, s.
    #[arg(long, default_value_t = 0.5)]
    pub watch_s: f64,
    /// Record the session to this file in `candump -l` format.
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// Write, before touching the bus, every object taut reads, writes or maps on each drive with
    /// an `eds` as its EDS describes it (checked: exists, access, PDO mapping, length).
    #[arg(long, value_name = "FILE")]
    pub eds_summary: Option<PathBuf>,
}

/// The EDS-checked summary of every drive with an `eds` (the check itself already passed in
/// `MasterConfig::from_robot`).
fn eds_summary(cfg: &RobotConfig, mcfg: &MasterConfig) -> anyhow::Result<String> {
    use taut_driver::canopen::eds_check;
    let mut out = String::from("# taut probe --eds-summary: objects taut uses on each drive, as its EDS describes them\n");
    let mut any = false;
    for n in &mcfg.nodes {
        let Some(path) = cfg.cables[n.cable].drive.as_ref().and_then(|d| d.eds.as_ref()) else { continue };
        any = true;
        let eds = taut_proto::eds::Eds::load(path)?;
        let uses = eds_check::check(n, &eds).map_err(|p| anyhow::anyhow!("{path}: {p}"))?;
        out += &eds_check::summary(n.node_id, path, &uses);
    }
    if !any {
        bail!("--eds-summary: no [cable.drive] has an `eds = \"FILE\"`; add the drives' EDS files to the configuration");
    }
    Ok(out)
}

/// `--sim`: virtual drives with these node ids on an in-process bus, on their own thread; the
/// master's port, and the rack's handle to keep until the probe ends.
#[cfg(feature = "sim")]
fn virtual_drives(nodes: &[u8]) -> anyhow::Result<(Box<dyn CanTransport>, Box<dyn std::any::Any>)> {
    let bus = VirtualBus::new();
    // As drives in the field: heartbeating (100 ms stored in 0x1017) before taut speaks, so
    // the probe starts on a bus that is already busy.
    let drives = nodes
        .iter()
        .map(|&n| {
            let mut p = DriveParams::new(n);
            p.stored_heartbeat_ms = 100;
            VirtualDrive::new(p)
        })
        .collect();
    let rack = spawn_rack(bus.endpoint_with(4096, &rack_filters(nodes)), drives);
    std::thread::sleep(Duration::from_millis(250));
    println!("bus: in-process virtual bus with {} virtual drives (--sim)", nodes.len());
    Ok((Box::new(bus.endpoint()), Box::new(rack)))
}

/// A robot's build has no virtual drives.
#[cfg(not(feature = "sim"))]
fn virtual_drives(_: &[u8]) -> anyhow::Result<(Box<dyn CanTransport>, Box<dyn std::any::Any>)> {
    bail!("--sim: this taut was built without the simulator (taut-cli's `sim` feature, on by default)")
}

/// A robot with `n` cables and drives 1..=n, for `--sim` without a configuration.
fn sim_robot(n: usize) -> RobotConfig {
    let mut cfg = RobotConfig::point_mass(n);
    for (i, c) in cfg.cables.iter_mut().enumerate() {
        c.drive = Some(DriveConfig::with_node_id(i as u8 + 1));
    }
    cfg
}

fn load(args: &ProbeArgs) -> anyhow::Result<RobotConfig> {
    let mut cfg = match &args.config {
        Some(p) => RobotConfig::load(p)?,
        None if args.sim => sim_robot(4),
        None => bail!("give the robot configuration with --config FILE (or --sim to probe the simulated drives)"),
    };
    if args.sim && cfg.cables.iter().all(|c| c.drive.is_none()) {
        let n = cfg.cables.len();
        cfg = RobotConfig { cables: sim_robot(n).cables, ..cfg };
    }
    let name = args.interface.clone();
    match (&mut cfg.can, name) {
        (Some(can), Some(i)) => can.interface = i,
        (None, i) if args.sim || i.is_some() => {
            cfg.can = Some(toml_can(i.unwrap_or_else(|| "sim0".into()))?);
        }
        _ => {}
    }
    Ok(cfg)
}

fn toml_can(interface: String) -> anyhow::Result<CanConfig> {
    // Through serde so every default is the one a config file gets.
    Ok(toml::from_str::<CanConfig>(&format!("interface = {interface:?}"))?)
}

/// Tensions from the load cells, in cable order, where a load cell reading is available.
///
/// Load cells (Modbus RTU on RS-485) are read by the driver's own I/O thread: start it on the
/// configured port, give it up to 1.5 s to read every cell once, then stop it. Cables without a
/// reading (no `[cable.loadcell]`, no `[loadcells]`, or no answer) show "-".
fn loadcell_tensions(cfg: &RobotConfig) -> Vec<Option<f64>> {
    let n = cfg.cables.len();
    if cfg.loadcells.is_none() || cfg.cables.iter().all(|c| c.loadcell.is_none()) {
        return vec![None; n];
    }
    let (io, mut reader) = match taut_driver::loadcell::spawn_from_config(cfg) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("warning: load cells not read: {e}");
            return vec![None; n];
        }
    };
    let wanted: Vec<usize> = (0..n).filter(|&j| cfg.cables[j].loadcell.is_some()).collect();
    let deadline = std::time::Instant::now() + std::time::Duration::from_millis(1500);
    while std::time::Instant::now() < deadline {
        reader.update();
        if wanted.iter().all(|&j| reader.latest(j).is_some()) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let c = io.counters();
    eprintln!("load cells: {c:?}");
    io.stop();
    (0..n).map(|j| reader.latest(j).map(|(v, _)| v)).collect()
}

/// Runs `taut probe`.
pub fn run(args: &ProbeArgs) -> anyhow::Result<()> {
    // Duration::from_secs_f64 panics on inf or an overflow: bound it before it gets there.
    anyhow::ensure!(
        args.watch_s.is_finite() && (0.0..=86_400.0).contains(&args.watch_s),
        "--watch-s {}: watch the bus for 0 to 86400 s",
        args.watch_s
    );
    if let Some(log) = &args.log {
        let inputs: Vec<&std::path::Path> = args.config.iter().map(|p| p.as_path()).collect();
        crate::outputs::check(&[("--log", log.as_path())], &[], &inputs)?;
    }
    let cfg = load(args)?;
    let mcfg = MasterConfig::from_robot(&cfg).map_err(|e| match &args.config {
        Some(p) => anyhow::anyhow!("{}: {e}", p.display()),
        None => anyhow::anyhow!("{e}"),
    })?;
    let can = cfg.can.as_ref().expect("from_robot checked [can]");
    if let Some(out) = &args.eds_summary {
        let text = eds_summary(&cfg, &mcfg)?;
        taut_config::write_atomic(out, text.as_bytes()).with_context(|| format!("writing {}", out.display()))?;
        println!("EDS summary (every object checked against its EDS) written to {}", out.display());
    }

    let load = mcfg.bus_load();
    println!(
        "CAN bus load: {:.1} % of {} kbit/s ({} frames, {} bits per {:.1} ms cycle, worst-case bit stuffing; heartbeats {:.1} kbit/s)",
        load.load * 100.0,
        can.bitrate / 1000,
        load.frames_per_cycle,
        load.bits_per_cycle,
        can.cycle_s * 1e3,
        load.heartbeat_bits_per_s / 1e3
    );
    if load.is_high() {
        println!(
            "warning: the cyclic traffic needs more than {:.0} % of the bus: lengthen can.cycle_s, raise can.bitrate or use the compact PDO layout",
            taut_driver::canopen::busload::WARN_LOAD * 100.0
        );
    }

    // The virtual drives' thread, kept until the probe ends.
    let mut _rack: Option<Box<dyn std::any::Any>> = None;
    let transport: Box<dyn CanTransport> = if args.sim {
        let (port, rack) = virtual_drives(&mcfg.nodes.iter().map(|n| n.node_id).collect::<Vec<u8>>())?;
        _rack = Some(rack);
        port
    } else {
        let t = SocketCanTransport::open(&can.interface)?;
        println!("bus: SocketCAN {}", can.interface);
        Box::new(t)
    };
    let transport: Box<dyn CanTransport> = match &args.log {
        Some(p) => {
            let f = File::create(p).with_context(|| format!("cannot create the log file {}", p.display()))?;
            Box::new(Recorder::new(transport, BufWriter::new(f), &can.interface))
        }
        None => transport,
    };

    // The tracker listens while the drives come up: its counters show whether poses arrive, and
    // whether anyone outside `tracker.sources` sends some.
    let tracker = match &cfg.tracker {
        Some(t) => match taut_driver::tracker::spawn(t) {
            Ok(x) => Some((t.listen.clone(), x)),
            Err(e) => {
                eprintln!("warning: tracker not watched: tracker.listen {}: {e}", t.listen);
                None
            }
        },
        None => None,
    };
    let set = DriveSet::new(transport, mcfg);
    let (statuses, counters, events, result) = match set.bring_up() {
        Ok(mut set) => {
            let r = set.run_for(Duration::from_secs_f64(args.watch_s.max(0.0)));
            let events = drain(|| set.poll_event());
            (set.statuses(), set.master().counters(), events, r.map_err(anyhow::Error::from))
        }
        Err(mut refused) => {
            let events = drain(|| refused.set.poll_event());
            (refused.set.statuses(), refused.set.master().counters(), events, Err(anyhow::Error::from(refused.error)))
        }
    };
    for e in &events {
        println!("  {e}");
    }
    print_table(&cfg, &statuses, &loadcell_tensions(&cfg));
    print_counters(&counters);
    if let Some((listen, (_thread, reader))) = &tracker {
        let s = reader.stats();
        println!(
            "tracker on {listen}: {} datagrams, {} poses accepted, {} from senders not in tracker.sources, {} malformed, {} late, {} out of order",
            s.received, s.accepted, s.foreign, s.malformed, s.late, s.out_of_order
        );
        if let Some(p) = reader.newest() {
            println!("tracker: newest pose t = {} s at [{:.4}, {:.4}, {:.4}] m", p.t, p.position[0], p.position[1], p.position[2]);
        }
    }
    let missing: Vec<&NodeStatus> = statuses.iter().filter(|s| s.phase != Phase::Operational).collect();
    if !missing.is_empty() {
        let ids: Vec<String> = missing.iter().map(|s| format!("{} ({})", s.node, s.phase.name())).collect();
        return Err(result.err().unwrap_or_else(|| anyhow::anyhow!("not operational")))
            .with_context(|| format!("{} of {} drives not operational: node {}", missing.len(), statuses.len(), ids.join(", ")));
    }
    result
}

fn drain(next: impl FnMut() -> Option<NodeEvent>) -> Vec<NodeEvent> {
    std::iter::from_fn(next).collect()
}

fn print_table(cfg: &RobotConfig, statuses: &[NodeStatus], loadcells: &[Option<f64>]) {
    println!();
    println!(
        "{:>4} {:>5}  {:<15} {:<12} {:<18} {:>4} {:>11} {:>10} {:>10}  {:<10} {:<10} {:>8}  name / last EMCY",
        "node", "cable", "NMT", "phase", "drive", "mode", "position m", "drive N", "cell N", "vendor", "product", "serial",
    );
    for s in statuses {
        let opt = |v: Option<u32>| v.map_or("-".to_string(), |v| format!("0x{v:08X}"));
        // Counts and torque in cable units, as the robot I/O layer converts them.
        let units = cfg.cables.get(s.cable).and_then(|c| c.drive.as_ref()).map(CableUnits::from_drive).filter(|_| s.axis.tpdos > 0);
        let emcy = s.last_emcy.map(|e| format!("  EMCY 0x{:04X} {}", e.code, e.name())).unwrap_or_default();
        println!(
            "{:>4} {:>5}  {:<15} {:<12} {:<18} {:>4} {:>11} {:>10} {:>10}  {:<10} {:<10} {:>8}  {}{}",
            s.node,
            s.cable,
            s.nmt.map_or("-", |n| n.name()),
            s.phase.name(),
            s.axis.state.map_or("-", |st| st.name()),
            s.axis.mode_display.unwrap_or(s.mode).name(),
            units.map_or("-".into(), |u| format!("{:.6}", u.scaling.counts_to_m(s.axis.position))),
            // `+ 0.0` turns -0.0 into 0.0.
            units.map_or("-".into(), |u| format!("{:.1}", u.scaling.permille_to_n(s.axis.torque) + 0.0)),
            loadcells.get(s.cable).copied().flatten().map_or("-".into(), |t| format!("{t:.1}")),
            opt(s.identity.vendor),
            opt(s.identity.product),
            s.identity.serial.map_or("-".into(), |v| v.to_string()),
            s.name(),
            emcy
        );
    }
}

fn print_counters(c: &Counters) {
    println!();
    println!("frames: {} received, {} sent, {} SYNC cycles", c.rx_frames, c.tx_frames, c.sync_cycles);
    println!(
        "ignored input: {} malformed, {} from unknown node ids, {} not for a master, {} unexpected SDO responses",
        c.malformed, c.unknown_node, c.ignored, c.unexpected_sdo
    );
    println!(
        "problems: {} SDO aborts ({} timeouts), {} EMCY, {} heartbeat losses, {} reboots, {} bus errors, {} frames dropped",
        c.sdo_aborts, c.sdo_timeouts, c.emergencies, c.heartbeat_losses, c.reboots, c.bus_errors, c.tx_dropped
    );
    println!(
        "SDO: {} retries, {} late or duplicated responses dropped; {} node(s) configured without a boot-up",
        c.sdo_retries, c.sdo_discarded, c.boot_ups_missing
    );
}
