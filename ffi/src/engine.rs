//! The plugin behind the C ABI: the daemon's loop core, controller and calibrator thread, with
//! the host owning the devices and the cycle.
//!
//! The real-time half ([`Rt`]) is what `taut_update` touches: the same [`LoopCore`] the daemon's
//! loop thread runs (read -> update -> write -> one sample into the ring), with devices that are
//! the host's readings and commands ([`HostDevices`]). The operator half ([`Operator`]) is the
//! daemon's [`ControlLinks`] and status readers, safe to use from any thread while `update` runs.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use taut_config::RobotConfig;
use taut_rt_core::calib_backend::TautCalib;
use taut_rt_core::calibrator::{CalibStatus, Calibrator, CalibratorConfig, SharedCalibStatus};
use taut_rt_core::control::{ControlLinks, SharedLoopStatus};
use taut_rt_core::io::{Devices, Inputs, Outputs};
use taut_rt_core::kin::LoopParams;
use taut_rt_core::motion::{Controller, ControllerConfig};
use taut_rt_core::runner::{LoopCore, LoopStatus};
use taut_rt_core::sample::sample_ring;
use taut_rt_core::triple::{triple_buffer, Writer};
use taut_rt_core::urgent::Urgent;

/// Devices the host owns: `read` hands the loop what the host passed to `taut_update`, `write`
/// keeps the loop's outputs for the host to take. Both are plain copies of `Copy` structs.
pub(crate) struct HostDevices {
    pub(crate) staged: Inputs,
    pub(crate) written: Outputs,
}

impl Devices for HostDevices {
    fn read(&mut self, _now_s: f64, inputs: &mut Inputs) {
        *inputs = self.staged;
    }
    fn write(&mut self, _now_s: f64, outputs: &Outputs) {
        self.written = *outputs;
    }
}

/// What `taut_update` runs. Touched by one thread at a time (the lib's busy flag).
pub(crate) struct Rt {
    pub(crate) core: LoopCore<HostDevices>,
    status_tx: Writer<LoopStatus>,
    st: LoopStatus,
    pub(crate) n: usize,
}

impl Rt {
    /// One cycle: the host's inputs in, the loop's outputs out. Allocates nothing.
    pub(crate) fn cycle(&mut self, now: f64, dt: f64, inputs: &Inputs) -> Outputs {
        self.core.devices.staged = *inputs;
        self.core.cycle(now, dt);
        let st = &mut self.st;
        st.cycles += 1;
        st.dropped = self.core.dropped();
        st.snap = self.core.controller.snapshot(now, &self.core.inputs);
        // The displaced value is a Copy struct: nothing is freed here.
        self.status_tx.write(*st);
        self.core.devices.written
    }
}

/// The operator's side: any thread, never the real-time one's locks (the status readers are
/// behind mutexes the loop never takes).
pub(crate) struct Operator {
    pub(crate) links: ControlLinks,
    pub(crate) loop_status: SharedLoopStatus,
    pub(crate) calib: SharedCalibStatus,
}

impl Operator {
    pub(crate) fn loop_status(&self) -> LoopStatus {
        *self.loop_status.lock().unwrap_or_else(|e| e.into_inner()).read()
    }
    pub(crate) fn calib_status(&self) -> CalibStatus {
        self.calib.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// The calibrator thread, stopped (after draining the ring) on drop.
pub(crate) struct Background {
    quit: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for Background {
    fn drop(&mut self) {
        // Release: the calibrator's Acquire load then sees every sample pushed before.
        self.quit.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Where configure failed, for the error code.
#[derive(Debug)]
pub(crate) enum ConfigureError {
    /// The configuration was refused (the message names the key).
    Config(String),
    /// A file or thread could not be created.
    Io(String),
}

/// Everything configure builds. No bus traffic, the calibrator thread running.
pub(crate) struct Engine {
    pub(crate) rt: Rt,
    pub(crate) op: Operator,
    pub(crate) background: Background,
    pub(crate) recording: PathBuf,
}

/// Configure-time choices beyond the robot configuration.
pub(crate) struct EngineOptions {
    pub(crate) data_dir: Option<PathBuf>,
    pub(crate) recording: Option<PathBuf>,
}

impl Engine {
    pub(crate) fn configure(cfg: &RobotConfig, opts: EngineOptions) -> Result<Engine, ConfigureError> {
        let mut cfg = cfg.clone();
        if let Some(d) = &opts.data_dir {
            cfg.daemon.data_dir = d.display().to_string();
        }
        let ccfg = ControllerConfig::from_robot(&cfg).map_err(ConfigureError::Config)?;
        let n = ccfg.n;
        let workspace = ccfg.workspace;
        let (params_tx, params_rx) = triple_buffer(LoopParams::invalid(n));
        let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(cfg.rt.command_capacity);
        let (sample_tx, sample_rx) = sample_ring(cfg.rt.ring_capacity);
        let urgent = Arc::new(Urgent::default());
        let controller = Controller::new(ccfg, cmd_rx, params_rx).with_urgent(urgent.clone());
        let init = LoopStatus::initial(controller.snapshot(0.0, &Inputs::new(n)));
        let (status_tx, status_rx) = triple_buffer(init);
        let loop_status: SharedLoopStatus = Arc::new(Mutex::new(status_rx));
        let calib: SharedCalibStatus = Arc::new(Mutex::new(CalibStatus::default()));
        let recording = opts.recording.clone().unwrap_or_else(|| {
            let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
            PathBuf::from(&cfg.daemon.data_dir).join("recordings").join(format!("plugin-{t}.csv"))
        });
        let calibrator = Calibrator::new(
            CalibratorConfig::from_robot(&cfg),
            sample_rx,
            params_tx,
            Box::new(TautCalib::from_config(&cfg)),
            Some(recording.clone()),
            calib.clone(),
        )
        .map_err(|e| ConfigureError::Io(format!("cannot create the recording {}: {e} (daemon.data_dir)", recording.display())))?;
        let quit = Arc::new(AtomicBool::new(false));
        let q = quit.clone();
        let thread = std::thread::Builder::new()
            .name("taut-calibrator".into())
            .spawn(move || calibrator.run(q))
            .map_err(|e| ConfigureError::Io(format!("cannot start the calibrator thread: {e}")))?;
        let links = ControlLinks {
            commands: cmd_tx,
            urgent,
            loop_status: loop_status.clone(),
            calib: calib.clone(),
            workspace,
            tracker: None,
        };
        let devices = HostDevices { staged: Inputs::new(n), written: Outputs::new(n) };
        let rt = Rt { core: LoopCore::new(n, devices, controller, sample_tx), status_tx, st: init, n };
        Ok(Engine {
            rt,
            op: Operator { links, loop_status, calib },
            background: Background { quit, thread: Some(thread) },
            recording,
        })
    }
}
