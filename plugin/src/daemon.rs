//! `taut start` without the command line: a host of the [`Plugin`] (plugin-owned devices)
//! with a real-time thread calling `update`, the control socket and the files. The plugin
//! builds the ring, the triple buffers and the command channel and runs the calibrator thread;
//! the daemon adds the loop thread and the control thread, and stops them in order.
//!
//! ```no_run
//! use taut_plugin::daemon::{Daemon, DaemonOptions};
//! let cfg = taut_config::RobotConfig::load("robot.toml").unwrap();
//! # fn devices() -> Box<dyn taut_rt::io::Devices> { unimplemented!() }
//! # fn calibrator() -> Box<dyn taut_calibrator::vocab::Calibrate> { unimplemented!() }
//! let d = Daemon::start(&cfg, devices(), calibrator(), DaemonOptions::default()).unwrap();
//! d.wait();
//! ```

use crate::{DeviceMode, Plugin, PluginError, PluginHandle, PluginOptions, RecordingPath};
use crossbeam_channel::Sender;
use std::fmt;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_calibrator::vocab::{CalibStatus, Calibrate, CalibratorConfig, SharedCalibStatus};
use taut_config::RobotConfig;
use taut_io::runner::{run_periodic, LoopReport, LoopStatus};
use taut_operator::control::{ControlServer, ServerLimits, SharedLoopStatus};
use taut_rt::io::Devices;
use taut_rt::motion::Command;

/// How long the control socket is served after the loop has stopped: `taut ctl watch`'s poll
/// period and a margin.
const WATCH_LINGER: Duration = Duration::from_millis(300);

/// Where warnings go (stderr in the binary, a buffer in tests).
pub type WarnFn = Arc<dyn Fn(&str) + Send + Sync>;

/// Options beyond the configuration.
#[derive(Clone)]
pub struct DaemonOptions {
    /// Recording path; default `data_dir/recordings/start-<local time, ISO 8601 basic>.csv`.
    pub recording: Option<PathBuf>,
    /// Serve the control socket (`daemon.socket`).
    pub control: bool,
    /// Warning sink.
    pub warn: WarnFn,
    /// The tracker receiver's counters, shown by `status` (foreign senders included).
    pub tracker: Option<taut_driver::tracker::TrackerStatsHandle>,
    /// Where the log lines for people go ([`taut_operator::operator`]: each state and phase with its
    /// expected duration, each calibration outcome, goals, loop health).
    pub log: WarnFn,
}

impl Default for DaemonOptions {
    fn default() -> Self {
        DaemonOptions {
            recording: None,
            control: true,
            warn: Arc::new(|w| eprintln!("warning: {w}")),
            tracker: None,
            log: Arc::new(|l| eprintln!("taut: {l}")),
        }
    }
}

/// Why the daemon did not start.
#[derive(Debug)]
pub enum DaemonError {
    /// The plugin refused the configuration or could not be configured or activated.
    Plugin(PluginError),
    /// The control socket could not be served (another daemon on it, no permission, ...).
    ControlSocket {
        /// `daemon.socket`.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The MCAP recording or the telemetry server could not be opened (`[recording]`,
    /// `[telemetry]`).
    Outputs(taut_operator::channels::FrameSinksError),
    /// A thread could not be started.
    Thread {
        /// Its name.
        name: &'static str,
        /// The error.
        source: std::io::Error,
    },
}

impl fmt::Display for DaemonError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DaemonError::Plugin(e) => e.fmt(f),
            DaemonError::ControlSocket { path, source } => {
                write!(f, "cannot serve the control socket {}: {source} (daemon.socket)", path.display())
            }
            DaemonError::Thread { name, source } => write!(f, "cannot start the {name} thread: {source}"),
            DaemonError::Outputs(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for DaemonError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            DaemonError::Plugin(e) => Some(e),
            DaemonError::ControlSocket { source, .. } | DaemonError::Thread { source, .. } => Some(source),
            DaemonError::Outputs(e) => Some(e),
        }
    }
}

impl From<PluginError> for DaemonError {
    fn from(e: PluginError) -> Self {
        DaemonError::Plugin(e)
    }
}

/// A running daemon.
pub struct Daemon {
    quit: Arc<AtomicBool>,
    loop_thread: Option<JoinHandle<(LoopReport, Plugin)>>,
    control_thread: Option<JoinHandle<()>>,
    plugin: Option<Plugin>,
    /// Commands to the loop.
    pub commands: Sender<Command>,
    /// The loop's status.
    pub loop_status: SharedLoopStatus,
    /// The calibrator's status.
    pub calib_status: SharedCalibStatus,
    /// The recording being written (the CSV; the MCAP file when only MCAP is recorded).
    pub recording: PathBuf,
    /// The MCAP recording, when `[recording] format` asks for one.
    pub mcap: Option<PathBuf>,
    /// Where the telemetry server listens, when `[telemetry]` is enabled.
    pub telemetry: Option<std::net::SocketAddr>,
    /// The telemetry server's counters.
    pub telemetry_stats: Option<Arc<taut_operator::telemetry::TelemetryStats>>,
    telemetry_thread: Option<JoinHandle<()>>,
    handle: PluginHandle,
}

impl Daemon {
    /// Configures the plugin with `devices` (already up), serves the control socket, activates
    /// the plugin (the drives are enabled, holding) and starts the loop thread. Errors name the
    /// configuration key or path to fix.
    pub fn start(
        cfg: &RobotConfig,
        devices: Box<dyn Devices>,
        backend: Box<dyn Calibrate>,
        opts: DaemonOptions,
    ) -> Result<Daemon, DaemonError> {
        Daemon::start_with(cfg, DeviceMode::ready(devices), backend, opts)
    }

    /// [`Daemon::start`] with plugin-owned devices that the plugin's activation brings up
    /// (after the control socket is bound and the recording created).
    pub fn start_with(
        cfg: &RobotConfig,
        devices: DeviceMode,
        backend: Box<dyn Calibrate>,
        opts: DaemonOptions,
    ) -> Result<Daemon, DaemonError> {
        let popts = PluginOptions {
            recording: opts.recording.clone().map_or(RecordingPath::Default, RecordingPath::At),
            backend: Some(backend),
            ..PluginOptions::default()
        };
        let builder = Plugin::builder(cfg, devices, popts)?;
        let handle = builder.handle().clone();
        handle.operator().set_log(opts.log.clone());
        // The socket first: a second daemon is refused here, before it creates any file.
        let control = if opts.control {
            let path = PathBuf::from(&cfg.daemon.socket);
            let links = handle.control_links(opts.tracker.clone());
            Some(ControlServer::bind(&path, links, ServerLimits::default()).map_err(|source| DaemonError::ControlSocket { path, source })?)
        } else {
            None
        };
        // The MCAP recording and the telemetry server read what the calibrator thread reads
        // (the sample stream), never the loop.
        let fmt = cfg.recording.format;
        let base = builder.recording().map(PathBuf::from).unwrap_or_default();
        let mcap = (fmt.mcap() && !base.as_os_str().is_empty()).then(|| base.with_extension("mcap"));
        let (outputs, telemetry) = taut_operator::channels::open_frame_sinks(&CalibratorConfig::from_robot(cfg), cfg, mcap.as_deref())
            .map_err(DaemonError::Outputs)?;
        let mut builder = builder.with_csv(fmt.csv());
        if let Some(o) = outputs {
            builder = builder.with_outputs(o);
        }
        let mut plugin = builder.build()?;
        let recording = if fmt.csv() { base } else { mcap.clone().unwrap_or(base) };
        let quit = Arc::new(AtomicBool::new(false));
        let (telemetry_addr, telemetry_stats, telemetry_thread) = match telemetry {
            Some(server) => {
                let (addr, stats, q) = (server.addr, server.stats.clone(), quit.clone());
                let t = std::thread::Builder::new()
                    .name("taut-telemetry".into())
                    .spawn(move || server.run(q))
                    .map_err(|source| DaemonError::Thread { name: "taut-telemetry", source })?;
                (Some(addr), Some(stats), Some(t))
            }
            None => (None, None, None),
        };
        let control_thread = match control {
            Some(c) => {
                let q = quit.clone();
                Some(
                    std::thread::Builder::new()
                        .name("taut-control".into())
                        .spawn(move || c.run(q))
                        .map_err(|source| DaemonError::Thread { name: "taut-control", source })?,
                )
            }
            None => None,
        };
        let links = handle.control_links(None);
        let mut d = Daemon {
            quit,
            loop_thread: None,
            control_thread,
            plugin: None,
            commands: links.commands,
            loop_status: links.loop_status,
            calib_status: links.calib,
            recording,
            mcap,
            telemetry: telemetry_addr,
            telemetry_stats,
            telemetry_thread,
            handle,
        };
        // From here a failure stops the control thread and the calibrator on drop.
        plugin.activate()?;
        let rt = cfg.rt.clone();
        let warn = opts.warn.clone();
        let loop_quit = Arc::new(AtomicBool::new(false));
        let spawned = std::thread::Builder::new().name("taut-rt".into()).spawn(move || {
            let report = run_periodic(&rt, loop_quit, &*warn, |now, dt, timing| {
                plugin.set_timing(*timing);
                // Update errors are lifecycle and time errors: the plugin is active and the
                // clock monotonic here, so none can happen; end the loop if one does.
                plugin.update(now, dt).map_or(true, |t| t.finished)
            });
            (report, plugin)
        });
        match spawned {
            Ok(t) => d.loop_thread = Some(t),
            Err(source) => return Err(DaemonError::Thread { name: "taut-rt", source }),
        }
        Ok(d)
    }

    /// The operator's handle on the plugin the daemon hosts.
    pub fn handle(&self) -> &PluginHandle {
        &self.handle
    }

    /// The latest loop status.
    pub fn loop_status(&self) -> LoopStatus {
        *self.loop_status.lock().unwrap().read()
    }

    /// A copy of the calibrator's status.
    pub fn calib_status(&self) -> CalibStatus {
        self.calib_status.lock().unwrap().clone()
    }

    /// Polls until `pred` holds or `timeout` passes; true if it held. Also false when the loop
    /// thread has ended.
    pub fn wait_until(&self, timeout: Duration, mut pred: impl FnMut(&LoopStatus, &CalibStatus) -> bool) -> bool {
        let t0 = Instant::now();
        while t0.elapsed() < timeout {
            if pred(&self.loop_status(), &self.calib_status()) {
                return true;
            }
            if self.loop_thread.as_ref().is_some_and(|t| t.is_finished()) {
                return pred(&self.loop_status(), &self.calib_status());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }

    /// Blocks until the loop ends (a `stop` command), then stops the other threads.
    pub fn wait(mut self) -> Option<LoopReport> {
        let r = self.join_loop();
        self.finish();
        r
    }

    /// Controlled stop: asks the loop to stop, waits for it, drains the calibrator, closes the
    /// socket.
    pub fn shutdown(mut self) -> Option<LoopReport> {
        // The flag as well: the queue may be full.
        self.handle.stop();
        let _ = self.commands.try_send(Command::Stop);
        let r = self.join_loop();
        self.finish();
        r
    }

    fn join_loop(&mut self) -> Option<LoopReport> {
        let (report, plugin) = self.loop_thread.take()?.join().ok()?;
        self.plugin = Some(plugin);
        Some(report)
    }

    fn finish(&mut self) {
        if self.plugin.is_some() {
            // The loop has ended: its health once more, clean or not.
            let ls = self.loop_status();
            self.handle.operator().stopped(&ls);
        }
        if let Some(mut p) = self.plugin.take() {
            // The loop has ended (the controller stopped): deactivate runs no further cycle;
            // cleanup drains the calibrator and joins it.
            let _ = p.deactivate();
            let _ = p.cleanup();
        }
        if self.control_thread.is_some() {
            // `taut ctl watch` asks for the journal every 200 ms: the socket stays a little
            // longer so that watchers get the last events (the stop, the loop's health).
            std::thread::sleep(WATCH_LINGER);
        }
        // Relaxed: the control thread only needs to see the flag eventually.
        self.quit.store(true, Ordering::Relaxed);
        if let Some(t) = self.control_thread.take() {
            let _ = t.join();
        }
        if let Some(t) = self.telemetry_thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if self.loop_thread.is_some() {
            self.handle.stop();
            let _ = self.commands.try_send(Command::Stop);
            self.join_loop();
        }
        self.finish();
    }
}
