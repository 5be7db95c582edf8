//! The calibrator thread: drains the sample ring, records every sample as a `cdpr-recording v1`
//! file, collects the initialisation and excitation data sets, runs the calibration backend on a
//! worker thread, validates the result and publishes it to the loop.
//!
//! It follows the loop through the states carried in the samples: the end of the three phases
//! (`AwaitInitial`) starts the initial estimate; the end of an excitation starts a calibration;
//! a fault during either abandons the run and says why.
//!
//! A calibrated set is published only when
//! 1. its held-out co-registration RMS (on `calibration.heldout_fraction` of the excitation,
//!    the ends of eight time blocks ([`HeldoutBlocks`]), which the backend does not see) does
//!    not exceed the running parameters' by more than `daemon.heldout_tolerance_m` with 99.9 %
//!    one-sided confidence ([`crate::acceptance`]), both over the same rows, tracker outliers
//!    left out ([`crate::heldout`]). The tolerance keeps a set that is worse only by noise
//!    from being refused;
//! 2. every anchor moved less than `daemon.max_anchor_change_m` and every offset less than
//!    `daemon.max_l0_change_m` from the running set;
//! 3. its 1-sigma values are below `daemon.max_sigma_m` and the backend reports the problem
//!    observable.
//!
//! Each published set is written atomically as `params/params-vNNNN.toml` (history, never
//! overwritten) and `params/current.toml`.

use crate::acceptance::validate;
use crate::heldout::HeldoutRms;
use crate::recorder::{push_sample, LengthHistory, RecordingWriter, RowSet, MAX_PENDING_S, MAX_PENDING_TENSION_S};
use crate::vocab::{
    BackendError, Calibrate, CalibrationOutcome, CalibratorConfig, Estimate, HeldoutBlocks, OutcomeKind, RecorderError, Rejection,
    RunOutputs, SharedCalibStatus,
};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use taut_config::params::{ParamsFile, FORMAT};
use taut_config::recording::Recording;
use taut_config::RobotConfig;
use taut_io::EffectsFromFile;
use taut_rt::kin::{LoopEffects, LoopParams};
use taut_rt::motion::State;
use taut_rt::sample::{Sample, SampleRx};
use taut_rt::triple::Writer;

impl CalibratorConfig {
    /// From the robot configuration.
    pub fn from_robot(cfg: &RobotConfig) -> CalibratorConfig {
        CalibratorConfig {
            robot: cfg.robot.name.clone(),
            n: cfg.cables.len(),
            platform: cfg.platform_points(),
            pulley_axis: cfg.pulley_axes(),
            nominal: cfg.anchors(),
            data_dir: PathBuf::from(&cfg.daemon.data_dir),
            decimation: cfg.daemon.calib_decimation,
            heldout_fraction: cfg.calibration.heldout_fraction,
            min_tension_n: cfg.calibration.min_tension_n,
            max_anchor_change_m: cfg.daemon.max_anchor_change_m,
            max_l0_change_m: cfg.daemon.max_l0_change_m,
            max_sigma_m: cfg.daemon.max_sigma_m,
            heldout_tolerance_m: cfg.daemon.heldout_tolerance_m,
            tracker_max_age_s: cfg.safety.tracker_max_age_s,
            tension_max_age_s: cfg.safety.tension_max_age_s,
            tracker: !crate::notracker::is_dwell(cfg),
            excitation: None,
        }
    }

    /// The loop's form of an estimate: its geometry with this robot's platform points and
    /// swivel-pulley axes, and its effects. Refuses (naming the cable and field) what
    /// `LoopParams::from_geometry` refuses. The one place the calibrator makes that form, for
    /// publishing and for the held-out checks.
    pub fn loop_params(&self, version: u64, est: &Estimate) -> Result<LoopParams, taut_calib::GeometryError> {
        Ok(LoopParams::from_geometry(version, &est.geometry, &self.platform)?
            .with_pulley_axes(&self.pulley_axis)
            .with_effects(LoopEffects::from_file(&est.effects)))
    }
}

fn unix_now() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// Highest version among `params-vNNNN.toml` files in `dir`.
fn last_version(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_prefix("params-v")?.strip_suffix(".toml")?.parse::<u64>().ok()
        })
        .max()
        .unwrap_or(0)
}

// A job is built once per calibration run and moved once into the worker's channel: boxing the
// recordings would only add an allocation.
#[allow(clippy::large_enum_variant)]
enum Job {
    Initial { rec: Recording, run: u16 },
    Calibrate { train: Recording, heldout: Recording, init: Estimate, current: LoopParams, run: u16 },
}

struct JobResult {
    kind: OutcomeKind,
    run: u16,
    samples: usize,
    result: Result<Estimate, BackendError>,
    heldout: Option<(Recording, LoopParams)>,
    data_problems: Vec<String>,
}

/// Where calibration jobs run.
enum Jobs {
    /// On the worker thread: jobs out, results back (each with the backend).
    Thread {
        tx: mpsc::Sender<(Job, Box<dyn Calibrate>)>,
        rx: mpsc::Receiver<(JobResult, Box<dyn Calibrate>)>,
        worker: std::thread::JoinHandle<()>,
    },
    /// In the step that submits them (lockstep simulation): the result waits here for the
    /// same step's `poll_results`.
    Inline { done: Option<Box<(JobResult, Box<dyn Calibrate>)>> },
}

/// The calibrator: owns the ring's consumer end and the parameter writer.
pub struct Calibrator {
    cfg: CalibratorConfig,
    rx: SampleRx,
    params_tx: Writer<LoopParams>,
    status: SharedCalibStatus,
    backend: Option<Box<dyn Calibrate>>,
    recorder: Option<RecordingWriter>,
    init_set: Recording,
    exc_set: Recording,
    prev_state: State,
    prev_sample: Option<Sample>,
    lengths: LengthHistory,
    /// The load cells' recent readings, as `lengths`.
    tensions: LengthHistory,
    /// Fresh tracker rows waiting for the encoder and load-cell readings after their poses (see
    /// `on_sample`), oldest first.
    pending: std::collections::VecDeque<(Sample, RowSet)>,
    decim: usize,
    current: Option<Estimate>,
    current_params: LoopParams,
    version: u64,
    jobs: Option<Jobs>,
    busy: bool,
    outputs: Option<Box<dyn RunOutputs>>,
}

impl Calibrator {
    /// A calibrator recording to `recording` (None: no recording).
    pub fn new(
        cfg: CalibratorConfig,
        rx: SampleRx,
        params_tx: Writer<LoopParams>,
        backend: Box<dyn Calibrate>,
        recording: Option<PathBuf>,
        status: SharedCalibStatus,
    ) -> std::io::Result<Calibrator> {
        let recorder = match &recording {
            Some(p) => Some(RecordingWriter::create(p, cfg.n, &cfg.robot, cfg.tracker_max_age_s, cfg.tension_max_age_s)?),
            None => None,
        };
        let version = last_version(&cfg.data_dir.join("params"));
        {
            let mut st = status.lock().unwrap();
            st.stage = "waiting".into();
            st.recording = recording;
        }
        let n = cfg.n;
        Ok(Calibrator {
            init_set: Recording::with_capacity(n, 1 << 14, true, false, true),
            exc_set: Recording::with_capacity(n, 1 << 15, true, false, true),
            cfg,
            rx,
            params_tx,
            status,
            backend: Some(backend),
            recorder,
            prev_state: State::Idle,
            prev_sample: None,
            lengths: LengthHistory::default(),
            tensions: LengthHistory::default(),
            pending: std::collections::VecDeque::new(),
            decim: 0,
            current: None,
            current_params: LoopParams::invalid(n),
            version,
            jobs: None,
            busy: false,
            outputs: None,
        })
    }

    /// Also sends every sample, parameter set and stage to `o` (MCAP recording, telemetry).
    pub fn with_outputs(mut self, o: impl RunOutputs + 'static) -> Calibrator {
        self.outputs = Some(Box::new(o));
        self
    }

    fn stage(&mut self, s: &str) {
        let mut st = self.status.lock().unwrap();
        st.stage = s.into();
        if let Some(o) = &mut self.outputs {
            o.calibrator(s, st.samples_recorded, None);
        }
    }

    /// Sends the newest outcome to the outputs.
    fn outcome_out(&mut self) {
        if let Some(o) = &mut self.outputs {
            let st = self.status.lock().unwrap();
            o.calibrator(&st.stage, st.samples_recorded, st.outcomes.last());
        }
    }

    /// Runs until `quit` is set: drains, records, calibrates. Returns when the ring is empty
    /// after `quit`.
    pub fn run(mut self, quit: Arc<AtomicBool>) {
        self.start_worker();
        loop {
            let got = self.step();
            // Acquire: pairs with the daemon's Release store so the final drain sees every sample
            // the loop pushed before it stopped.
            if got == 0 && quit.load(Ordering::Acquire) && !self.busy {
                break;
            }
            if got == 0 {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        self.finish();
    }

    /// Starts the calibration worker thread (jobs then run beside the loop's sample intake).
    fn start_worker(&mut self) {
        let (job_tx, job_rx) = mpsc::channel::<(Job, Box<dyn Calibrate>)>();
        let (res_tx, res_rx) = mpsc::channel();
        let min_tension_n = self.cfg.min_tension_n;
        let worker = std::thread::Builder::new()
            .name("taut-calib-worker".into())
            .spawn(move || {
                for (job, mut backend) in job_rx {
                    let r = run_job(job, backend.as_mut(), min_tension_n);
                    if res_tx.send((r, backend)).is_err() {
                        break;
                    }
                }
            })
            .expect("spawn the calibration worker");
        self.jobs = Some(Jobs::Thread { tx: job_tx, rx: res_rx, worker });
    }

    /// The calibrator without threads, for a lockstep simulation: the host calls
    /// [`step`](Self::step) at defined points (after every loop cycle), and a calibration runs to
    /// its end inside the step that starts it, so that no result depends on the scheduler.
    pub fn inline(mut self) -> Calibrator {
        self.jobs = Some(Jobs::Inline { done: None });
        self
    }

    /// Takes every sample waiting in the ring, hands out finished results, flushes the
    /// recording; returns the number of samples taken.
    pub fn step(&mut self) -> usize {
        let mut got = 0;
        while let Some(s) = self.rx.pop() {
            self.on_sample(&s);
            got += 1;
        }
        self.poll_results();
        if let Some(r) = &mut self.recorder {
            if r.last_flush.elapsed() >= Duration::from_millis(500) {
                if let Err(e) = r.flush() {
                    self.status.lock().unwrap().recorder_error = Some(r.error(e));
                }
            }
        }
        if let Some(o) = &mut self.outputs {
            o.tick();
            if let Some(e) = o.take_error() {
                self.status.lock().unwrap().recorder_error = Some(RecorderError::Mcap(Arc::new(e)));
            }
        }
        got
    }

    /// Drains what is left, finishes the recording and the outputs, joins the worker.
    pub fn finish(&mut self) {
        while self.step() > 0 || self.busy {
            if self.busy {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        if let Some(r) = &mut self.recorder {
            let _ = r.flush();
        }
        if let Some(o) = &mut self.outputs {
            o.finish();
        }
        if let Some(Jobs::Thread { tx, rx, worker }) = self.jobs.take() {
            drop((tx, rx));
            let _ = worker.join();
        }
    }

    fn on_sample(&mut self, s: &Sample) {
        if let Some(r) = &mut self.recorder {
            match r.push(s) {
                Ok(()) => self.status.lock().unwrap().samples_recorded = r.rows,
                Err(e) => self.status.lock().unwrap().recorder_error = Some(r.error(e)),
            }
        }
        if let Some(o) = &mut self.outputs {
            o.sample(s);
            if self.recorder.is_none() {
                self.status.lock().unwrap().samples_recorded += 1;
            }
        }
        let state = State::from_u8(s.state);
        let prev = self.prev_state;
        self.prev_state = state;
        self.lengths.push(s, self.cfg.n);
        self.tensions.push_readings(s.t, &s.tension_age_s, &s.tension_n, self.cfg.n);
        // A row waiting for its lengths goes into its set before the set is handed on.
        self.flush_pending(s.t, state != prev);
        if state != prev {
            self.on_transition(prev, state, s);
        }
        // One data-set row per fresh tracker pose (every `decimation`-th one).
        let prev = self.prev_sample.replace(*s);
        if !self.cfg.tracker {
            return self.push_dwell_row(s, prev.as_ref(), state);
        }
        let fresh = prev.as_ref().is_none_or(|q| q.pose_m != s.pose_m) && s.pose_age_s <= self.cfg.tracker_max_age_s;
        if !fresh {
            return;
        }
        // `%` keeps the panic on a zero decimation (`is_multiple_of(0)` would not) and the MSRV 1.80.
        #[allow(clippy::manual_is_multiple_of)]
        let keep = self.decim % self.cfg.decimation == 0;
        self.decim += 1;
        let set = match state {
            State::InitPhase if s.phase >= 0 => RowSet::Init,
            State::Excitation if keep => RowSet::Excitation,
            _ => return,
        };
        // The pose is usually newer than the newest encoder reading (a TPDO answers the SYNC
        // of the cycle before; the tracker's datagram comes within a millisecond): read at
        // once, the lengths would be extrapolated from the last two readings, which multiplies
        // their noise ((1 + f) l_k - f l_(k-1), f up to ~1.5). The row waits for the next
        // readings and is interpolated; and for the load cells' next readings, up to a polling
        // round later.
        self.pending.push_back((*s, set));
        self.flush_pending(s.t, false);
    }

    /// Appends the waiting tracker rows, oldest first, once the encoder readings cover a
    /// row's pose instant (after [`MAX_PENDING_S`]: extrapolated) and the load cells' readings
    /// do too (after [`MAX_PENDING_TENSION_S`]: the newest held); `force`: all now, e.g.
    /// before their data set is handed on.
    fn flush_pending(&mut self, now_t: f64, force: bool) {
        let offset = self.current_params.effects.time_offset_s;
        while let Some(&(p, set)) = self.pending.front() {
            let at = p.t - p.pose_age_s.max(0.0) + offset;
            let lengths = self.lengths.covers(self.cfg.n, at) || now_t - p.t > MAX_PENDING_S;
            let tensions = self.tensions.covers(self.cfg.n, at) || now_t - p.t > MAX_PENDING_TENSION_S;
            if !(force || lengths && tensions) {
                return;
            }
            self.pending.pop_front();
            let rec = match set {
                RowSet::Init => &mut self.init_set,
                RowSet::Excitation => &mut self.exc_set,
            };
            push_sample(rec, &self.lengths, &self.tensions, &p, &self.cfg, offset);
            let len = rec.len();
            self.status.lock().unwrap().dataset_samples = len;
        }
    }

    /// Without a tracker: every `decimation`-th sample of a recorded dwell (phase label >= 0),
    /// the encoder lengths as read and each tension only when it is a new reading (a repeated
    /// one would count twice in the dwell's mean); a row without lengths between two dwells,
    /// so that the dwell search never joins them.
    fn push_dwell_row(&mut self, s: &Sample, prev: Option<&Sample>, state: State) {
        let n = self.cfg.n;
        let set = match state {
            State::InitPhase => &mut self.init_set,
            State::Excitation => &mut self.exc_set,
            _ => return,
        };
        if s.phase < 0 {
            return;
        }
        let nan = [f64::NAN; taut_rt::MAX_CABLES];
        if prev.is_none_or(|q| q.phase != s.phase) && !set.is_empty() {
            set.push(s.t, [f64::NAN; 3], None, &nan[..n], Some(&nan[..n]), Some(-1));
        }
        // `%` keeps the panic on a zero decimation and the MSRV (see `on_sample`).
        #[allow(clippy::manual_is_multiple_of)]
        let keep = self.decim % self.cfg.decimation == 0;
        self.decim += 1;
        if !keep {
            return;
        }
        let mut l = nan;
        let mut f = nan;
        for j in 0..n {
            if s.length_m[j].is_finite() {
                l[j] = s.length_m[j];
            }
            // A reading the loop saw again has the same value bit for bit. (Not the reading's
            // instant `t - age`: `t` is the loop's clock, the age the load-cell thread's wall
            // clock, so the difference moves every cycle.) A new reading with an identical value
            // is dropped: rare at 1 mN resolution and 0.3 N noise, and it only costs that reading.
            let new = prev.is_none_or(|q| q.tension_n[j].to_bits() != s.tension_n[j].to_bits());
            if new && s.tension_age_s[j] <= self.cfg.tension_max_age_s && s.tension_n[j].is_finite() {
                f[j] = s.tension_n[j];
            }
        }
        set.push(s.t, [f64::NAN; 3], None, &l[..n], Some(&f[..n]), Some(i32::from(s.phase)));
        let len = set.len();
        self.status.lock().unwrap().dataset_samples = len;
    }

    fn on_transition(&mut self, prev: State, state: State, s: &Sample) {
        match (prev, state) {
            (_, State::InitPhase) if prev != State::InitPhase => {
                self.init_set = Recording::with_capacity(self.cfg.n, 1 << 14, true, false, true);
                self.stage("collecting-init");
            }
            (State::InitPhase, State::AwaitInitial) => {
                let rec = std::mem::replace(&mut self.init_set, Recording::with_capacity(self.cfg.n, 0, true, false, true));
                self.stage("initialising");
                self.submit(Job::Initial { rec, run: s.run });
            }
            (_, State::Excitation) => {
                self.exc_set = Recording::with_capacity(self.cfg.n, 1 << 15, true, false, true);
                self.stage("collecting-excitation");
            }
            (State::Excitation, State::Operate) => {
                let rec = std::mem::replace(&mut self.exc_set, Recording::with_capacity(self.cfg.n, 0, true, false, true));
                let (train, heldout) = if self.cfg.tracker {
                    HeldoutBlocks::new(rec.len(), self.cfg.heldout_fraction).split(&rec)
                } else {
                    crate::notracker::split_dwells(&rec, self.cfg.heldout_fraction)
                };
                match self.current.clone() {
                    Some(init) => {
                        self.stage("calibrating");
                        self.submit(Job::Calibrate { train, heldout, init, current: self.current_params, run: s.run });
                    }
                    None => self.reject(OutcomeKind::Calibration, s.run, rec.len(), None, Rejection::NoRunningParameters),
                }
            }
            (State::InitPhase | State::Excitation, State::Faulted | State::Stopped) => {
                let kind = if prev == State::InitPhase { OutcomeKind::Initial } else { OutcomeKind::Calibration };
                let samples = if prev == State::InitPhase { self.init_set.len() } else { self.exc_set.len() };
                self.reject(kind, s.run, samples, None, Rejection::Interrupted { kind, state });
                self.stage("idle");
            }
            _ => {}
        }
    }

    fn submit(&mut self, job: Job) {
        let Some(backend) = self.backend.take() else {
            let (kind, run) = match &job {
                Job::Initial { run, .. } => (OutcomeKind::Initial, *run),
                Job::Calibrate { run, .. } => (OutcomeKind::Calibration, *run),
            };
            self.reject(kind, run, 0, None, Rejection::Busy);
            return;
        };
        let min_tension_n = self.cfg.min_tension_n;
        match &mut self.jobs {
            Some(Jobs::Thread { tx, .. }) => {
                self.busy = true;
                let _ = tx.send((job, backend));
            }
            Some(Jobs::Inline { done }) => {
                let mut backend = backend;
                let r = run_job(job, backend.as_mut(), min_tension_n);
                *done = Some(Box::new((r, backend)));
                self.busy = true;
            }
            None => self.backend = Some(backend),
        }
    }

    fn poll_results(&mut self) {
        let (r, backend) = match &mut self.jobs {
            Some(Jobs::Thread { rx, .. }) => match rx.try_recv() {
                Ok(x) => x,
                Err(_) => return,
            },
            Some(Jobs::Inline { done }) => match done.take() {
                Some(x) => *x,
                None => return,
            },
            None => return,
        };
        self.backend = Some(backend);
        self.busy = false;
        self.stage("idle");
        match r.result {
            Err(e) => self.reject(r.kind, r.run, r.samples, None, Rejection::Failed(e)),
            Ok(mut est) => {
                // The excitation's predicted uncertainty beside the achieved one.
                if let (OutcomeKind::Calibration, Some(plan)) = (r.kind, &self.cfg.excitation) {
                    est.note.push_str(&format!("; {}", crate::excite::predicted_vs_achieved(plan, &est.sigma.anchors)));
                }
                match self.validate(r.kind, &est, r.heldout.as_ref()) {
                    Ok(rms) => self.publish(r.kind, r.run, r.samples, est, rms),
                    Err(why) => self.reject(r.kind, r.run, r.samples, Some(est), why),
                }
            }
        }
        if let Some(o) = self.status.lock().unwrap().outcomes.last_mut() {
            o.data_problems = r.data_problems;
        }
    }

    fn validate(&self, kind: OutcomeKind, est: &Estimate, heldout: Option<&(Recording, LoopParams)>) -> Result<HeldoutRms, Rejection> {
        validate(&self.cfg, self.current.as_ref(), kind, est, heldout)
    }

    fn publish(&mut self, kind: OutcomeKind, run: u16, samples: usize, est: Estimate, rms: HeldoutRms) {
        let version = self.version + 1;
        // The loop's form first: a set the loop cannot hold is refused before anything is written
        // (`validate` has checked the geometry; this is the platform points or the cable count).
        let lp = match self.cfg.loop_params(version, &est) {
            Ok(lp) => lp,
            Err(e) => {
                self.reject(kind, run, samples, Some(est), Rejection::LoopCannotHold(e));
                return;
            }
        };
        let file = ParamsFile {
            format: FORMAT.into(),
            version,
            created_unix_s: unix_now(),
            robot: self.cfg.robot.clone(),
            source: match kind {
                OutcomeKind::Initial => format!("start-up initial estimate ({})", est.note),
                OutcomeKind::Calibration if !self.cfg.tracker => format!(
                    "{} without a tracker ({})",
                    if run == 0 { "start-up calibration".to_string() } else { format!("recalibration {run}") },
                    est.note
                ),
                OutcomeKind::Calibration if run == 0 => "start-up calibration".into(),
                OutcomeKind::Calibration => format!("recalibration {run}"),
            },
            rms_m: est.rms_m,
            heldout_rms_m: rms.new_m,
            effects: est.effects.clone(),
            ..ParamsFile::from_geometry(&est.geometry, &est.sigma)
        };
        let dir = self.cfg.data_dir.join("params");
        let written = std::fs::create_dir_all(&dir)
            .and_then(|_| file.save_atomic(dir.join(format!("params-v{version:04}.toml"))))
            .and_then(|_| file.save_atomic(dir.join("current.toml")));
        if let Err(e) = written {
            // Never run parameters that are not on disk: a restart would not know them.
            self.reject(kind, run, samples, Some(est), Rejection::Write { dir, error: Arc::new(e) });
            return;
        }
        self.version = version;
        // The displaced value is Copy; it is dropped here, on the calibrator thread.
        self.params_tx.write(lp);
        self.current_params = lp;
        self.current = Some(est.clone());
        if let Some(o) = &mut self.outputs {
            o.params(&file);
        }
        let mut st = self.status.lock().unwrap();
        st.current = Some(file);
        st.outcomes.push(CalibrationOutcome {
            run,
            kind,
            accepted: true,
            rejection: None,
            reason: String::new(),
            version,
            estimate: Some(est),
            heldout_rms_new_m: rms.new_m,
            heldout_rms_old_m: rms.old_m,
            heldout_outliers: rms.outliers,
            heldout_rows: rms.rows,
            heldout_rms_with_outliers_m: [rms.new_all_m, rms.old_all_m],
            samples,
            data_problems: vec![],
        });
        drop(st);
        self.outcome_out();
    }

    fn reject(&mut self, kind: OutcomeKind, run: u16, samples: usize, est: Option<Estimate>, why: Rejection) {
        let mut st = self.status.lock().unwrap();
        st.outcomes.push(CalibrationOutcome {
            run,
            kind,
            accepted: false,
            reason: why.to_string(),
            rejection: Some(why),
            version: 0,
            estimate: est,
            heldout_rms_new_m: f64::NAN,
            heldout_rms_old_m: f64::NAN,
            heldout_outliers: 0,
            heldout_rows: 0,
            heldout_rms_with_outliers_m: [f64::NAN; 2],
            samples,
            data_problems: vec![],
        });
        drop(st);
        self.outcome_out();
    }
}

/// One calibration of a data set as the daemon runs it, without publishing: the excitation
/// `rec` split into training and held-out rows, both screened for wild values, the backend's
/// calibration from `init`, and the acceptance rules against `current` (the running set). The
/// outcome says whether the daemon would publish the result, and why not.
pub fn evaluate(
    cfg: &CalibratorConfig,
    backend: &mut dyn Calibrate,
    rec: &Recording,
    init: &Estimate,
    current: LoopParams,
) -> CalibrationOutcome {
    let (train, heldout) = HeldoutBlocks::new(rec.len(), cfg.heldout_fraction).split(rec);
    let job = Job::Calibrate { train, heldout, init: init.clone(), current, run: 1 };
    let r = run_job(job, backend, cfg.min_tension_n);
    let none = HeldoutRms::plain(f64::NAN, f64::NAN, 0);
    let (rejection, estimate, rms) = match r.result {
        Err(e) => (Some(Rejection::Failed(e)), None, none),
        Ok(est) => match validate(cfg, Some(init), r.kind, &est, r.heldout.as_ref()) {
            Ok(rms) => (None, Some(est), rms),
            Err(why) => (Some(why), Some(est), none),
        },
    };
    CalibrationOutcome {
        run: r.run,
        kind: r.kind,
        accepted: rejection.is_none(),
        reason: rejection.as_ref().map_or_else(String::new, ToString::to_string),
        rejection,
        version: 0,
        estimate,
        heldout_rms_new_m: rms.new_m,
        heldout_rms_old_m: rms.old_m,
        heldout_outliers: rms.outliers,
        heldout_rows: rms.rows,
        heldout_rms_with_outliers_m: [rms.new_all_m, rms.old_all_m],
        samples: r.samples,
        data_problems: r.data_problems,
    }
}

/// Screens a data set for wild values ([`taut_calib::screen`]): the cleaned recording (wild
/// readings missing, encoder jumps re-referenced) and one line per wild value, saying where.
fn screened(rec: Recording, min_tension_n: f64, part: &str, out: &mut Vec<String>) -> Recording {
    let sc = taut_calib::screen::screen(
        &rec,
        &taut_calib::screen::ScreenOptions { jumps: false, ..taut_calib::screen::ScreenOptions::new(min_tension_n) },
    );
    out.extend(sc.findings.iter().map(|w| format!("{part}: {} {w}", w.kind.name())));
    sc.cleaned.unwrap_or(rec)
}

fn run_job(job: Job, backend: &mut dyn Calibrate, min_tension_n: f64) -> JobResult {
    let mut data_problems = vec![];
    match job {
        Job::Initial { rec, run } => {
            let samples = rec.len();
            let rec = screened(rec, min_tension_n, "initialisation data", &mut data_problems);
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| backend.initialise(&rec)))
                .unwrap_or(Err(BackendError::Panicked(OutcomeKind::Initial)));
            JobResult { kind: OutcomeKind::Initial, run, samples, result, heldout: None, data_problems }
        }
        Job::Calibrate { train, heldout, init, current, run } => {
            let samples = train.len() + heldout.len();
            // The held-out block is screened too: it decides whether the new set replaces the
            // running one, and a single 1e308 would make both RMS values infinite.
            let train = screened(train, min_tension_n, "excitation (training rows)", &mut data_problems);
            let heldout = screened(heldout, min_tension_n, "excitation (held-out rows)", &mut data_problems);
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| backend.calibrate(&train, &init)))
                .unwrap_or(Err(BackendError::Panicked(OutcomeKind::Calibration)));
            JobResult { kind: OutcomeKind::Calibration, run, samples, result, heldout: Some((heldout, current)), data_problems }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::acceptance::{clearly_worse, comparison_worse, significantly_worse, HELDOUT_ALPHA};
    use crate::heldout::HeldoutComparison;

    fn sample(t: f64, age: f64, l: f64) -> Sample {
        let mut s = Sample::empty(1);
        s.t = t;
        s.length_age_s[0] = age;
        s.length_m[0] = l;
        s
    }

    #[test]
    fn lengths_are_read_at_the_pose_time() {
        // A cable paying out at 1 m/s, read every 2 ms, each reading 1.5 ms old.
        let mut h = LengthHistory::default();
        for k in 0..10 {
            let t = 0.002 * f64::from(k);
            h.push(&sample(t, 0.0015, t - 0.0015), 1);
        }
        // Between readings: interpolated; after the newest: extrapolated; long after: held.
        assert!((h.at(0, 0.0101) - 0.0101).abs() < 1e-12);
        assert!((h.at(0, 0.0180) - 0.0180).abs() < 1e-12);
        assert!((h.at(0, 0.5) - 0.0165).abs() < 1e-12);
        // Before the history: the oldest reading.
        assert!((h.at(0, -1.0) + 0.0015).abs() < 1e-12);
        // A repeated reading (no new TPDO) is not a second point.
        h.push(&sample(0.020, 0.0035, 0.0165), 1);
        assert_eq!(h.rows.len(), 10);
    }

    #[test]
    fn history_covers_a_time_once_every_cable_has_a_reading_after_it() {
        let mut h = LengthHistory::default();
        let mut s = Sample::empty(2);
        s.length_m[..2].copy_from_slice(&[1.0, 2.0]);
        s.t = 0.010;
        s.length_age_s[..2].copy_from_slice(&[0.002, 0.004]);
        h.push(&s, 2);
        assert!(h.covers(2, 0.006) && !h.covers(2, 0.007) && !h.covers(2, 0.009));
        // A cable's older reading decides for it; a cable without any does not hold a row back.
        s.length_m[1] = f64::NAN;
        s.t = 0.012;
        s.length_age_s[0] = 0.001;
        h.push(&s, 2);
        assert!(h.covers(2, 0.006) && !h.covers(2, 0.007));
        let mut h = LengthHistory::default();
        h.push(&s, 2);
        assert!(h.covers(2, 0.011) && !h.covers(2, 0.0111));
    }

    /// The example robot's calibrator taking every sample (decimation 1), fed by the tests
    /// through `on_sample`; with the ring's producer and the parameters' reader, kept alive.
    #[allow(clippy::type_complexity)]
    fn example_calibrator() -> (Calibrator, (taut_rt::sample::SampleTx, taut_rt::triple::Reader<LoopParams>)) {
        let cfg = RobotConfig::load(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml")).unwrap();
        let mut ccfg = CalibratorConfig::from_robot(&cfg);
        ccfg.decimation = 1;
        let n = ccfg.n;
        let (tx, rx) = taut_rt::sample::sample_ring(16);
        let (params_tx, params_rx) = taut_rt::triple::triple_buffer(LoopParams::invalid(n));
        let backend = Box::new(crate::calib_backend::TautCalib::from_config(&cfg));
        (Calibrator::new(ccfg, rx, params_tx, backend, None, SharedCalibStatus::default()).unwrap(), (tx, params_rx))
    }

    /// The loop's form of an estimate carries the configuration's pulley axes, normalised
    /// (vertical where a cable gives none), with the estimate's effects.
    #[test]
    fn the_loops_parameters_carry_the_configured_pulley_axes() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/");
        let est = |n: usize| Estimate {
            geometry: taut_calib::Geometry {
                anchors: vec![[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]][..n].to_vec(),
                l0: vec![0.1; n],
            },
            sigma: taut_calib::Sigmas { anchors: vec![[1e-4; 3]; n], l0: vec![1e-4; n] },
            rms_m: 1e-4,
            observable: true,
            note: String::new(),
            effects: taut_config::params::Effects { pulley_radius_m: Some(vec![0.03; n]), ..Default::default() },
            model_consistent: None,
        };
        let horizontal = CalibratorConfig::from_robot(&RobotConfig::load(format!("{dir}aras-cam-horizontal-pulleys.toml")).unwrap());
        let lp = horizontal.loop_params(3, &est(4)).unwrap();
        let n = 3.5f64.hypot(1.75);
        assert_eq!(lp.pulley_axis[0], [3.5 / n, -1.75 / n, 0.0]);
        assert_eq!(lp.pulley_axis[2], [-3.5 / n, 1.75 / n, 0.0]);
        assert_eq!((lp.version, lp.effects.pulley_r[1]), (3, 0.03));
        let vertical = CalibratorConfig::from_robot(&RobotConfig::load(format!("{dir}aras-cam.toml")).unwrap());
        let lp = vertical.loop_params(3, &est(4)).unwrap();
        assert!(lp.pulley_axis.iter().all(|a| *a == [0.0, 0.0, 1.0]));
        assert!(vertical.loop_params(3, &est(3)).is_err());
    }

    /// A tracker pose is newer than the newest encoder reading (TPDOs answer the SYNC of the
    /// cycle before, the pose datagram comes within a millisecond): its row waits for the next
    /// readings and interpolates between two, rather than extrapolating from the last two,
    /// `(1 + f) l_k - f l_(k-1)`, which multiplies their noise.
    #[test]
    fn tracker_rows_interpolate_the_encoder_readings_not_extrapolate() {
        let (mut c, _ends) = example_calibrator();
        let n = c.cfg.n;
        // Every cable paying out at 1 m/s; readings every 2 ms, each 2 ms old (the SYNC before),
        // with +-e of noise alternating; a pose every 10 ms, 0.5 ms old.
        let e = 1e-4;
        let truth = |t: f64| 3.0 + t;
        let mut s = Sample::empty(n);
        s.state = State::Excitation as u8;
        s.phase = 0;
        let mut pose_t = f64::NAN;
        for k in 0..200 {
            let t = 0.002 * f64::from(k);
            s.t = t;
            let read = t - 0.002;
            let noise = if k % 2 == 0 { e } else { -e };
            for j in 0..n {
                s.length_m[j] = truth(read) + noise;
                s.length_age_s[j] = 0.002;
            }
            if k % 5 == 0 {
                pose_t = t - 0.0005;
                s.pose_m = [t, 0.0, 2.0];
            }
            s.pose_age_s = t - pose_t;
            c.on_sample(&s);
        }
        let rows = c.exc_set.len();
        assert!(rows >= 38, "{rows} rows");
        for i in 0..rows {
            for j in 0..n {
                let err = c.exc_set.lengths(i)[j] - truth(c.exc_set.t[i]);
                // Between two readings the error is at most the readings' (e); extrapolated
                // 0.75 of a period past the newest it would be up to 2.5 e.
                assert!(err.abs() <= e * (1.0 + 1e-9), "row {i} cable {j}: {err:e}");
            }
        }
    }

    /// The dynamic plant's start-up: a load cell's reading is up to a polling round old while
    /// the swing changes the tension, and with it the stretch the refinement models. A tracker
    /// row's tensions are interpolated at its instant between the readings around it.
    #[test]
    fn tracker_rows_interpolate_the_tensions_between_the_polling_rounds() {
        let (mut c, _ends) = example_calibrator();
        let n = c.cfg.n;
        // Tensions rising at 200 N/s; the cells read in turn, a round every 16 ms (cable j at
        // 4 j ms into it); encoders every 2 ms; a pose every 10 ms, 0.5 ms old.
        let truth = |j: usize, t: f64| 20.0 + 5.0 * j as f64 + 200.0 * t;
        let mut s = Sample::empty(n);
        s.state = State::Excitation as u8;
        s.phase = 0;
        let mut read = [f64::NAN; taut_rt::MAX_CABLES];
        let mut pose_t = f64::NAN;
        for k in 0..200 {
            let t = 0.002 * f64::from(k);
            s.t = t;
            s.length_m[..n].fill(3.0);
            s.length_age_s[..n].fill(0.002);
            for (j, rj) in read[..n].iter_mut().enumerate() {
                if (k % 8) as usize == 2 * j {
                    *rj = t;
                    s.tension_n[j] = truth(j, t);
                }
                s.tension_age_s[j] = t - *rj;
            }
            if k % 5 == 0 {
                pose_t = t - 0.0005;
                s.pose_m = [t, 0.0, 2.0];
            }
            s.pose_age_s = t - pose_t;
            c.on_sample(&s);
        }
        let rows = c.exc_set.len();
        assert!(rows >= 36, "{rows} rows");
        let mut held = 0.0f64;
        for i in 0..rows {
            for (j, &fj) in c.exc_set.tensions(i).unwrap().iter().enumerate() {
                if fj.is_nan() {
                    // Before the cell's first reading.
                    assert!(c.exc_set.t[i] < 0.004 * j as f64, "row {i} cable {j}");
                    continue;
                }
                let t = c.exc_set.t[i];
                let err = fj - truth(j, t);
                // Before a cell's second reading there is nothing to interpolate between.
                if t > 0.004 * j as f64 + 0.016 {
                    assert!(err.abs() < 1e-9, "row {i} cable {j}: {err:e} N");
                    // The newest reading at the row's instant, what holding would give.
                    let newest = ((t - 0.004 * j as f64) / 0.016).floor() * 0.016 + 0.004 * j as f64;
                    held = held.max(200.0 * (t - newest));
                }
            }
        }
        // Holding would be up to a round (3.2 N) off.
        assert!(held > 2.0, "{held}");
    }

    #[test]
    fn heldout_blocks_partition_the_rows_and_spread_over_the_path() {
        for rows in [0usize, 1, 7, 8, 9, 100, 12_345] {
            for fraction in [0.0, 0.2, 0.5] {
                let h = HeldoutBlocks::new(rows, fraction);
                let (train, held) = (h.training(), h.heldout());
                // Every row in exactly one part, in time order, and part_of agrees.
                let mut seen = vec![0u8; rows];
                let (mut kt, mut kh) = (0, 0);
                let mut all: Vec<(usize, bool)> = train.iter().flat_map(|r| r.clone().map(|i| (i, false))).collect();
                all.extend(held.iter().flat_map(|r| r.clone().map(|i| (i, true))));
                all.sort();
                for &(i, is_held) in &all {
                    seen[i] += 1;
                    let k = if is_held { &mut kh } else { &mut kt };
                    assert_eq!(h.part_of(i), (is_held, *k), "rows {rows} fraction {fraction} row {i}");
                    *k += 1;
                }
                assert!(seen.iter().all(|&c| c == 1), "rows {rows} fraction {fraction}");
                let nh: usize = held.iter().map(|r| r.len()).sum();
                assert!((nh as f64 - rows as f64 * fraction).abs() <= HeldoutBlocks::BLOCKS as f64, "{nh} of {rows}");
                if rows >= 100 && fraction > 0.0 {
                    // Held-out rows in every eighth of the path.
                    assert_eq!(held.len(), HeldoutBlocks::BLOCKS);
                }
            }
        }
        // The split recordings carry the rows' values.
        let mut rec = Recording::with_capacity(2, 0, true, false, true);
        for i in 0..80 {
            let x = i as f64;
            rec.push(x, [x, 0.0, 0.0], None, &[x, -x], Some(&[2.0 * x, 3.0]), Some(i));
        }
        let h = HeldoutBlocks::new(rec.len(), 0.2);
        let (train, held) = h.split(&rec);
        assert_eq!(train.len() + held.len(), 80);
        for i in 0..80 {
            let (is_held, k) = h.part_of(i);
            let r = if is_held { &held } else { &train };
            assert_eq!((r.t[k], r.lengths(k)[1], r.tensions(k).unwrap()[0]), (i as f64, -(i as f64), 2.0 * i as f64));
            assert_eq!(r.phase.as_ref().unwrap()[k], i as i32);
        }
    }

    #[test]
    fn a_tie_is_not_significantly_worse_a_shifted_anchor_is() {
        let anchors = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];
        let truth = LoopParams::new(1, &anchors, &[0.5; 4], &[[0.0; 3]; 4]);
        let mut off = anchors;
        off[2][0] += 0.005;
        let shifted = LoopParams::new(2, &off, &[0.5; 4], &[[0.0; 3]; 4]);
        let mut rec = Recording::with_capacity(4, 500, false, false, false);
        let mut rng = taut_calib::synth::Rng::new(3);
        for i in 0..500 {
            let p = [rng.range(-1.0, 1.0), rng.range(-0.5, 0.5), rng.range(1.5, 2.5)];
            let l: Vec<f64> = (0..4).map(|j| truth.length(j, &p)).collect();
            let m = [p[0] + 1.5e-3 * rng.normal(), p[1] + 1.5e-3 * rng.normal(), p[2] + 1.5e-3 * rng.normal()];
            rec.push(f64::from(i) * 0.01, m, None, &l, None, None);
        }
        assert!(!significantly_worse(&truth, &truth, &rec, 1.0, 1e-4, HELDOUT_ALPHA));
        assert!(!significantly_worse(&truth, &shifted, &rec, 1.0, 1e-4, HELDOUT_ALPHA));
        assert!(significantly_worse(&shifted, &truth, &rec, 1.0, 1e-4, HELDOUT_ALPHA));
    }

    #[test]
    fn clearly_worse_compares_the_mean_square_difference_with_the_tolerance() {
        // Ten held-out dwells of 3 degrees of freedom each (scale 30), the running set at 1.5 mm:
        // the tolerance 0.1 mm is a mean-square difference of 0.1 * (2 * 1.5 + 0.1) = 0.31 mm^2,
        // a sum of 30 * 0.31 mm^2 over the dwells.
        let at = |f: f64| -> Vec<f64> { (0..10).map(|i| f * 30.0 * 0.31e-6 / 10.0 * (1.0 + 0.01 * f64::from(i % 3))).collect() };
        assert!(clearly_worse(&at(2.0), 30.0, 1.5e-3, 1e-4, HELDOUT_ALPHA));
        assert!(!clearly_worse(&at(0.5), 30.0, 1.5e-3, 1e-4, HELDOUT_ALPHA));
        // Zero tolerance: any consistent increase.
        assert!(clearly_worse(&at(0.5), 30.0, 1.5e-3, 0.0, HELDOUT_ALPHA));
        // Noisy pairs: a mean 2x the margin with a spread of 10x it is not evidence.
        let noisy: Vec<f64> = at(2.0).iter().enumerate().map(|(i, d)| d + if i % 2 == 0 { 10.0 } else { -10.0 } * 0.93e-6).collect();
        assert!(!clearly_worse(&noisy, 30.0, 1.5e-3, 1e-4, HELDOUT_ALPHA));
        // Fewer than two units: no evidence either way, refused (the caller says why).
        assert!(clearly_worse(&[0.0], 3.0, 1.5e-3, 1e-4, HELDOUT_ALPHA));
    }

    #[test]
    fn the_t_quantile_matches_the_table() {
        // Student's t 0.999 quantiles from the standard table.
        for (dof, want) in [(1, 318.31), (2, 22.327), (5, 5.893), (10, 4.144), (19, 3.579)] {
            let got = taut_calib::diagnose::select::student_t_upper_quantile(HELDOUT_ALPHA, dof as f64);
            assert!((got / want - 1.0).abs() < 1e-3, "dof {dof}: {got} vs {want}");
        }
    }

    /// A synthetic start-up: a four-cable robot, a smooth 2000-row excitation tour (a Lissajous
    /// figure through the workspace), split as the daemon splits it; the held-out rows carry
    /// tracker noise of 1.5 mm per axis and exact lengths from `truth`.
    struct Tour {
        truth: LoopParams,
        path: Vec<[f64; 3]>,
    }

    const ANCHORS: [[f64; 3]; 4] = [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]];

    impl Tour {
        fn new() -> Tour {
            let rows = 2000;
            let all: Vec<[f64; 3]> = (0..rows)
                .map(|i| {
                    let t = i as f64 / rows as f64 * std::f64::consts::TAU;
                    [1.5 * (3.0 * t).sin(), 0.8 * (2.0 * t).sin(), 2.0 + 0.6 * (5.0 * t).cos()]
                })
                .collect();
            let h = HeldoutBlocks::new(rows, 0.2);
            let path = h.heldout().into_iter().flat_map(|r| all[r].to_vec()).collect();
            Tour { truth: LoopParams::new(1, &ANCHORS, &[0.5; 4], &[[0.0; 3]; 4]), path }
        }

        fn heldout(&self, rng: &mut taut_calib::synth::Rng) -> Recording {
            let mut rec = Recording::with_capacity(4, self.path.len(), false, false, false);
            for (i, p) in self.path.iter().enumerate() {
                let l: Vec<f64> = (0..4).map(|j| self.truth.length(j, p)).collect();
                let m = std::array::from_fn(|a| p[a] + 1.5e-3 * rng.normal());
                rec.push(i as f64 * 0.01, m, None, &l, None, None);
            }
            rec
        }

        /// A set with every anchor coordinate and offset off by N(0, sigma).
        fn estimate(rng: &mut taut_calib::synth::Rng, sigma: f64) -> LoopParams {
            let a: Vec<[f64; 3]> = ANCHORS.iter().map(|a| std::array::from_fn(|k| a[k] + sigma * rng.normal())).collect();
            let l0: Vec<f64> = (0..4).map(|_| 0.5 + sigma * rng.normal()).collect();
            LoopParams::new(2, &a, &l0, &[[0.0; 3]; 4])
        }

        /// The population RMS of `p` on this path (noise-free model error plus the tracker's
        /// 1.5 mm projected on the cable), m.
        fn rms(&self, p: &LoopParams) -> f64 {
            let ms = self.path.iter().flat_map(|x| (0..4).map(move |j| (p.length(j, x) - self.truth.length(j, x)).powi(2))).sum::<f64>()
                / (4 * self.path.len()) as f64;
            (ms + 1.5e-3f64.powi(2)).sqrt()
        }
    }

    /// Refusals in `trials` synthetic start-ups of the pair `(new, old)` drawn by `sets`, by the
    /// rule with `tolerance_m` and `alpha`, tallied by how much worse the new set truly is on the
    /// held-out path (its population RMS minus the running set's, `Tour::rms`): `[(trials,
    /// refused); 3]` for a new set no worse (<= 0), worse by at most the tolerance, and worse by
    /// more (where a refusal is right).
    fn refusals(
        seed: u64,
        trials: usize,
        tolerance_m: f64,
        alpha: f64,
        mut sets: impl FnMut(&mut taut_calib::synth::Rng) -> (LoopParams, LoopParams),
    ) -> [(usize, usize); 3] {
        let tour = Tour::new();
        let mut rng = taut_calib::synth::Rng::new(seed);
        let mut tally = [(0, 0); 3];
        for _ in 0..trials {
            let (new, old) = sets(&mut rng);
            let rec = tour.heldout(&mut rng);
            // As `validate`: lower is taken without a test.
            let cmp = HeldoutComparison::new(&new, &old, &rec, 1.0);
            let r = cmp.rms().unwrap();
            let refused = r.new_m >= r.old_m && comparison_worse(&cmp, r.old_m, tolerance_m, alpha);
            let worse = tour.rms(&new) - tour.rms(&old);
            let k = if worse <= 0.0 {
                0
            } else if worse <= tolerance_m.max(1e-4) {
                1
            } else {
                2
            };
            tally[k].0 += 1;
            tally[k].1 += usize::from(refused);
        }
        tally
    }

    #[test]
    fn the_heldout_rule_does_not_refuse_an_equal_set_by_chance() {
        // New and running sets of the same expected quality (each anchor coordinate and offset
        // 0.5 mm off, independent draws), so in about half the trials the new one is truly no
        // worse on the held-out path. A rule with zero tolerance at 2.5 % (`former`, printed for
        // comparison) refuses some of those by design. This rule must refuse none of them: its
        // lower confidence bound would have to clear 0.31 mm^2 of mean-square difference while
        // the true difference is <= 0, many standard errors (a chance far below 1e-6 per trial,
        // so 0 is what a correct rule gives; the seed is fixed, so this test is deterministic).
        // Between 0 and the tolerance its refusal rate is at most alpha = 1e-3 (asserted <= 1 %:
        // for a correct rule Binomial(<= 2000, 1e-3) exceeds 1 % with probability below 1e-6).
        let trials = 2000;
        let equal = |rng: &mut taut_calib::synth::Rng| (Tour::estimate(rng, 0.5e-3), Tour::estimate(rng, 0.5e-3));
        let former = refusals(11, trials, 0.0, 0.025, equal);
        let now = refusals(11, trials, 1e-4, HELDOUT_ALPHA, equal);
        eprintln!("equal-quality sets, [(trials, refused)] for new no worse / worse by <= 0.1 mm / worse by more: former rule {former:?}, the rule now {now:?}");
        assert_eq!(now[0].1, 0, "a set no worse than the running one was refused: {now:?}");
        assert!(now[1].1 * 100 <= now[1].0, "a set worse by less than the tolerance was refused too often: {now:?}");
        // And the tie: the calibrated set equal to the running one is never refused.
        let tie = |rng: &mut taut_calib::synth::Rng| {
            let p = Tour::estimate(rng, 1e-3);
            (p, p)
        };
        assert_eq!(refusals(12, 200, 1e-4, HELDOUT_ALPHA, tie)[0], (200, 0));
    }

    #[test]
    fn the_heldout_rule_refuses_a_set_worse_by_the_tolerance_rarely_and_a_bad_one_always() {
        let tour = Tour::new();
        let truth = tour.truth;
        // One anchor shifted along x by `s`, against the truth.
        let shifted = |s: f64| {
            let mut a = ANCHORS;
            a[2][0] += s;
            LoopParams::new(3, &a, &[0.5; 4], &[[0.0; 3]; 4])
        };
        // The shift whose population RMS is exactly the tolerance above the truth's.
        let (mut lo, mut hi) = (0.0, 0.05);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if tour.rms(&shifted(mid)) - tour.rms(&truth) < 1e-4 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let at_tol = shifted(lo);
        // At the tolerance the rule refuses with probability alpha = 1e-3 (if the batch means
        // were exactly normal and independent): expected 2 in 2000. Asserted <= 10: for a
        // correct rule the count is Poisson(2) and exceeds 10 with probability 8e-6 (and the
        // fixed seed makes it deterministic).
        let trials = 2000;
        let n_tol = refusals(21, trials, 1e-4, HELDOUT_ALPHA, |_| (at_tol, truth))[1].1;
        // A set 5 mm off on one anchor (several tenths of a mm of RMS): refused every time.
        let bad = shifted(5e-3);
        let n_bad = refusals(22, 500, 1e-4, HELDOUT_ALPHA, |_| (bad, truth))[2].1;
        let twice = {
            let (mut lo2, mut hi2) = (0.0, 0.05);
            for _ in 0..60 {
                let mid = 0.5 * (lo2 + hi2);
                if tour.rms(&shifted(mid)) - tour.rms(&truth) < 3e-4 {
                    lo2 = mid;
                } else {
                    hi2 = mid;
                }
            }
            shifted(lo2)
        };
        let n_3tol = refusals(23, 500, 1e-4, HELDOUT_ALPHA, |_| (twice, truth))[2].1;
        eprintln!(
            "shift at the tolerance {:.2} mm: refused {n_tol} of {trials}; RMS +0.3 mm (shift {:.2} mm): {n_3tol} of 500; 5 mm: {n_bad} of 500 (RMS +{:.3} mm)",
            lo * 1e3,
            twice.geometry().anchors[2][0] * 1e3 - ANCHORS[2][0] * 1e3,
            (tour.rms(&bad) - tour.rms(&truth)) * 1e3
        );
        assert!(n_tol <= 10, "refused {n_tol} of {trials} at the tolerance");
        assert_eq!(n_bad, 500, "a 5 mm anchor error passed");
    }

    /// Tracker outliers in the held-out rows (two of ~5 cm per set, the simulator's kind) move
    /// neither the decision nor the reported RMS: a set equal to the running one is taken, a set
    /// with one anchor 5 mm off is refused, and the RMS the outcome reports is the noise's
    /// (with the outliers kept it would be ~1.9 mm on 1.5 mm noise).
    #[test]
    fn tracker_outliers_in_the_heldout_rows_decide_nothing() {
        let tour = Tour::new();
        let truth = tour.truth;
        let mut a = ANCHORS;
        a[2][0] += 5e-3;
        let bad = LoopParams::new(3, &a, &[0.5; 4], &[[0.0; 3]; 4]);
        let mut rng = taut_calib::synth::Rng::new(31);
        for trial in 0..300 {
            let mut rec = tour.heldout(&mut rng);
            for _ in 0..2 {
                let i = (rng.uniform() * rec.len() as f64) as usize % rec.len();
                let u = rng.unit_vector();
                for (x, uk) in rec.p[i].iter_mut().zip(u) {
                    *x += 0.05 * uk;
                }
            }
            let equal = Tour::estimate(&mut rng, 0.2e-3);
            let cmp = HeldoutComparison::new(&equal, &equal, &rec, 1.0);
            let r = cmp.rms().unwrap();
            assert!(r.outliers >= 1 && !comparison_worse(&cmp, r.old_m, 1e-4, HELDOUT_ALPHA), "trial {trial}: {r:?}");
            // 1600 readings: the RMS's standard error is ~2 % (rows of four correlated
            // cables); 10 % is 4.5 of it (and the seed is fixed).
            assert!((r.new_m / tour.rms(&equal) - 1.0).abs() < 0.1 && r.new_all_m > r.new_m, "trial {trial}: {r:?}");
            assert!(significantly_worse(&bad, &truth, &rec, 1.0, 1e-4, HELDOUT_ALPHA), "trial {trial}: a 5 mm anchor error passed");
        }
    }
}
