//! `taut start` without the command line: builds the ring, the triple buffers and the command
//! channel, starts the loop, calibrator and control threads, and stops them in order.

use crate::calibrator::{CalibStatus, Calibrate, Calibrator, CalibratorConfig, SharedCalibStatus};
use crate::control::{ControlLinks, ControlServer, ServerLimits, SharedLoopStatus};
use crate::io::Devices;
use crate::kin::LoopParams;
use crate::motion::{Command, Controller, ControllerConfig};
use crate::runner::{run_loop, LoopCore, LoopReport, LoopStatus};
use crate::sample::sample_ring;
use crate::triple::triple_buffer;
use crate::urgent::Urgent;
use crossbeam_channel::Sender;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_config::RobotConfig;

/// Where warnings go (stderr in the binary, a buffer in tests).
pub type WarnFn = Arc<dyn Fn(&str) + Send + Sync>;

/// Options beyond the configuration.
#[derive(Clone)]
pub struct DaemonOptions {
    /// Recording path; default `data_dir/recordings/start-<unix time>.csv`.
    pub recording: Option<PathBuf>,
    /// Serve the control socket (`daemon.socket`).
    pub control: bool,
    /// Warning sink.
    pub warn: WarnFn,
    /// The tracker receiver's counters, shown by `status` (foreign senders included).
    pub tracker: Option<taut_driver::tracker::TrackerStatsHandle>,
}

impl Default for DaemonOptions {
    fn default() -> Self {
        DaemonOptions { recording: None, control: true, warn: Arc::new(|w| eprintln!("warning: {w}")), tracker: None }
    }
}

/// A running daemon.
pub struct Daemon {
    quit: Arc<AtomicBool>,
    loop_thread: Option<JoinHandle<LoopReport>>,
    calib_thread: Option<JoinHandle<()>>,
    control_thread: Option<JoinHandle<()>>,
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
    pub telemetry_stats: Option<Arc<crate::telemetry::TelemetryStats>>,
    telemetry_thread: Option<JoinHandle<()>>,
    urgent: Arc<Urgent>,
}

impl Daemon {
    /// Starts everything. Errors name the configuration key or path to fix.
    pub fn start(cfg: &RobotConfig, devices: Box<dyn Devices>, backend: Box<dyn Calibrate>, opts: DaemonOptions) -> Result<Daemon, String> {
        let ccfg = ControllerConfig::from_robot(cfg)?;
        let n = ccfg.n;
        let (params_tx, params_rx) = triple_buffer(LoopParams::invalid(n));
        let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(cfg.rt.command_capacity);
        let (sample_tx, sample_rx) = sample_ring(cfg.rt.ring_capacity);
        let urgent = Arc::new(Urgent::default());
        let controller = Controller::new(ccfg, cmd_rx, params_rx).with_urgent(urgent.clone());
        let init_status = LoopStatus::initial(controller.snapshot(0.0, &crate::io::Inputs::new(n)));
        let (status_tx, status_rx) = triple_buffer(init_status);
        let loop_status: SharedLoopStatus = Arc::new(Mutex::new(status_rx));
        let calib_status: SharedCalibStatus = Arc::new(Mutex::new(CalibStatus::default()));
        let data_dir = PathBuf::from(&cfg.daemon.data_dir);
        let recording = opts.recording.clone().unwrap_or_else(|| {
            let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
            data_dir.join("recordings").join(format!("start-{t}.csv"))
        });
        // The socket first: a second daemon is refused here, before it creates any file.
        let control = if opts.control {
            let path = PathBuf::from(&cfg.daemon.socket);
            let links = ControlLinks {
                commands: cmd_tx.clone(),
                urgent: urgent.clone(),
                loop_status: loop_status.clone(),
                calib: calib_status.clone(),
                workspace: ccfg.workspace,
                tracker: opts.tracker.clone(),
            };
            Some(
                ControlServer::bind(&path, links, ServerLimits::default())
                    .map_err(|e| format!("cannot serve the control socket {}: {e} (daemon.socket)", path.display()))?,
            )
        } else {
            None
        };
        let fmt = cfg.recording.format;
        let mcap = fmt.mcap().then(|| recording.with_extension("mcap"));
        let recording = if fmt.csv() { recording } else { mcap.clone().unwrap_or(recording) };
        let ccfg_cal = CalibratorConfig::from_robot(cfg);
        let (outputs, telemetry) = crate::channels::open_outputs(&ccfg_cal, cfg, mcap.as_deref())?;
        let calibrator =
            Calibrator::new(ccfg_cal, sample_rx, params_tx, backend, fmt.csv().then(|| recording.clone()), calib_status.clone())
                .map_err(|e| format!("cannot create the recording {}: {e} (daemon.data_dir)", recording.display()))?;
        let calibrator = match outputs {
            Some(o) => calibrator.with_outputs(o),
            None => calibrator,
        };
        let quit = Arc::new(AtomicBool::new(false));
        let (telemetry_addr, telemetry_stats, telemetry_thread) = match telemetry {
            Some(server) => {
                let (addr, stats, q) = (server.addr, server.stats.clone(), quit.clone());
                let t =
                    std::thread::Builder::new().name("taut-telemetry".into()).spawn(move || server.run(q)).map_err(|e| e.to_string())?;
                (Some(addr), Some(stats), Some(t))
            }
            None => (None, None, None),
        };
        let loop_quit = Arc::new(AtomicBool::new(false));
        let calib_quit = quit.clone();
        let calib_thread = std::thread::Builder::new()
            .name("taut-calibrator".into())
            .spawn(move || calibrator.run(calib_quit))
            .map_err(|e| e.to_string())?;
        let control_thread = match control {
            Some(c) => {
                let q = quit.clone();
                Some(std::thread::Builder::new().name("taut-control".into()).spawn(move || c.run(q)).map_err(|e| e.to_string())?)
            }
            None => None,
        };
        let rt = cfg.rt.clone();
        let warn = opts.warn.clone();
        let core = LoopCore::new(n, devices, controller, sample_tx);
        let loop_thread = std::thread::Builder::new()
            .name("taut-rt".into())
            .spawn(move || run_loop(&rt, core, status_tx, loop_quit, &*warn))
            .map_err(|e| e.to_string())?;
        Ok(Daemon {
            quit,
            loop_thread: Some(loop_thread),
            calib_thread: Some(calib_thread),
            control_thread,
            commands: cmd_tx,
            loop_status,
            calib_status,
            recording,
            mcap,
            telemetry: telemetry_addr,
            telemetry_stats,
            telemetry_thread,
            urgent,
        })
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
        let r = self.loop_thread.take().and_then(|t| t.join().ok());
        self.finish();
        r
    }

    /// Controlled stop: asks the loop to stop, waits for it, drains the calibrator, closes the
    /// socket.
    pub fn shutdown(mut self) -> Option<LoopReport> {
        // The flag as well: the queue may be full.
        self.urgent.stop();
        let _ = self.commands.try_send(Command::Stop);
        let r = self.loop_thread.take().and_then(|t| t.join().ok());
        self.finish();
        r
    }

    fn finish(&mut self) {
        // Release: the calibrator's Acquire load then sees every sample pushed before the loop
        // ended.
        self.quit.store(true, Ordering::Release);
        if let Some(t) = self.calib_thread.take() {
            let _ = t.join();
        }
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
            self.urgent.stop();
            let _ = self.commands.try_send(Command::Stop);
            if let Some(t) = self.loop_thread.take() {
                let _ = t.join();
            }
        }
        self.finish();
    }
}
