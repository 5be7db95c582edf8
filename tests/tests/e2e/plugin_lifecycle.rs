//! The plugin as a host sees it: the simulated robot's whole start-up to a hot-swap in
//! host-owned mode (the test is the host: it reads the simulated devices, passes the readings
//! in and writes the commands out), the lifecycle's refusals, a failed activation that leaves
//! the robot safe and succeeds on retry, and the operator's handle from another thread.

use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use taut_calibrator::vocab::OutcomeKind;
use taut_io::rtsys::{monotonic_ns, Periodic};
use taut_io::testkit::{quick_config, truth_params, KinematicRobot};
use taut_plugin::{
    DeviceMode, ErrorKind, HostInputs, HostOutputs, Lifecycle, LoopEvent, ModeKind, Op, Plugin, PluginError, PluginOptions, RecordingPath,
    UpdateError,
};
use taut_rt::io::{DriveRequest, DriveStatus, Inputs, Outputs};
use taut_rt::motion::{ResetOutcome, State};
use taut_rt::safety::{Cause, Reaction};
use taut_tests::startup;

/// The host's side of one cycle: the simulated devices' readings in, the plugin's commands out.
struct Host {
    devices: Box<dyn taut_rt::io::Devices>,
    inputs: Inputs,
    hin: HostInputs,
    hout: HostOutputs,
    timer: Periodic,
    t0: i64,
    last: f64,
}

impl Host {
    fn new(devices: Box<dyn taut_rt::io::Devices>, n: usize, rate_hz: f64) -> Host {
        Host {
            devices,
            inputs: Inputs::new(n),
            hin: HostInputs::default(),
            hout: HostOutputs::default(),
            timer: Periodic::new((1e9 / rate_hz) as i64),
            t0: monotonic_ns(),
            last: 0.0,
        }
    }

    /// One period: wait, read the devices, update the plugin, write the devices.
    fn cycle(&mut self, p: &mut Plugin) -> taut_plugin::Tick {
        self.timer.wait();
        let now = (monotonic_ns() - self.t0) as f64 * 1e-9;
        let dt = if self.last == 0.0 { 1.0 / p.rate_hz() } else { now - self.last };
        self.last = now;
        self.inputs.fault = None;
        self.devices.read(now, &mut self.inputs);
        self.hin = HostInputs::from_inputs(&self.inputs);
        let tick = p.update_with(now, dt, &self.hin, &mut self.hout).expect("active, host-owned");
        assert_eq!(tick.bad_input, None);
        self.devices.write(now, &self.hout.to_outputs());
        tick
    }

    /// Cycles until `pred` holds (true) or `timeout` passes (false).
    fn run_until(&mut self, p: &mut Plugin, timeout: Duration, mut pred: impl FnMut(&Plugin) -> bool) -> bool {
        let t = Instant::now();
        while t.elapsed() < timeout {
            self.cycle(p);
            if pred(p) {
                return true;
            }
        }
        false
    }
}

#[test]
fn host_owned_start_up_to_a_hot_swap_then_operator_from_another_thread() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = startup::sim_robot(dir.path());
    let sim = startup::build_at_rest(&cfg, 5);
    let truth = sim.truth.clone();
    let n = cfg.cables.len();
    let rec = dir.path().join("host.csv");
    let opts = PluginOptions { recording: RecordingPath::At(rec.clone()), ..Default::default() };
    let mut p = Plugin::configure(&cfg, DeviceMode::Host, opts).unwrap();
    assert_eq!((p.lifecycle(), p.mode(), p.cables()), (Lifecycle::Inactive, ModeKind::Host, n));
    let handle = p.handle().clone();
    p.activate().unwrap();
    let mut host = Host::new(sim.devices, n, p.rate_hz());

    // The first cycles ask for the drives to be enabled, each cable held where it stands.
    let tick = host.cycle(&mut p);
    assert_eq!(tick.state, State::Enabling);
    host.cycle(&mut p);
    assert_eq!(host.hout.request, taut_rt::host::REQUEST_ENABLE);
    assert_eq!(usize::from(host.hout.n_cables), n);

    let swapped = |p: &Plugin| startup::start_up_over(&p.handle().loop_status(), &p.handle().calib_status());
    let ok = host.run_until(&mut p, Duration::from_secs(300), swapped);
    let (l, c) = (handle.loop_status(), handle.calib_status());
    assert!(ok, "start-up did not finish: state {:?}, stage {}", l.snap.state, c.stage);
    assert!(l.snap.fault.is_none(), "fault {:?}", l.snap.fault);
    assert_eq!(l.snap.phases_completed, 3);
    let cal = c.outcomes.iter().find(|o| o.kind == OutcomeKind::Calibration).unwrap();
    assert!(cal.accepted, "{}", cal.reason);
    let ce = cal.estimate.as_ref().unwrap();
    // Within k sigma of the calibrator's own uncertainty (plus encoder quantisation), as in
    // e2e_start: k by Bonferroni over the 12 coordinates for a family error rate of 1e-4.
    let k = taut_calib::screen::normal_upper_quantile(1e-4 / (2.0 * 12.0));
    let z_max = ce
        .geometry
        .anchors
        .iter()
        .zip(&truth.anchors)
        .zip(&ce.sigma.anchors)
        .flat_map(|((a, t), s)| (0..3).map(move |i| (a[i] - t[i]).abs() / s[i]))
        .fold(0.0, f64::max);
    eprintln!("ROBUST plugin_lifecycle: largest anchor error {z_max:.2} sigma");
    for (j, ((a, t), s)) in ce.geometry.anchors.iter().zip(&truth.anchors).zip(&ce.sigma.anchors).enumerate() {
        for i in 0..3 {
            assert!(
                (a[i] - t[i]).abs() < k * s[i] + 2e-4,
                "anchor {j}[{i}] off by {:.2} mm, sigma {:.2} mm",
                (a[i] - t[i]).abs() * 1e3,
                s[i] * 1e3
            );
        }
    }
    assert!(l.snap.max_swap_step_m > 0.0 && l.snap.max_swap_step_m < 1e-4, "max swap step {} m", l.snap.max_swap_step_m);
    let st = handle.status();
    assert_eq!((st.state, st.params_version, st.anchor_sigma_m.len(), st.l0_sigma_m.len()), (State::Operate, cal.version, n, n));
    assert_eq!(handle.params().unwrap().version, cal.version);

    // Events: every phase began, both parameter sets were swapped in, the state went through
    // the start-up in order.
    let mut phases = Vec::new();
    let mut versions = Vec::new();
    let mut states = Vec::new();
    while let Some(e) = handle.poll_event() {
        match e {
            LoopEvent::Phase { phase, .. } => phases.push(phase),
            LoopEvent::ParamsSwapped { version, .. } => versions.push(version),
            LoopEvent::State { to, .. } => states.push(to),
            other => panic!("unexpected event {other:?}"),
        }
    }
    assert_eq!(handle.events_dropped(), 0);
    assert_eq!(phases, [0, 1, 2]);
    assert_eq!(versions, [1, cal.version]);
    let order = [State::Enabling, State::InitPhase, State::AwaitInitial, State::Excitation, State::Operate];
    let mut k = 0;
    for s in &states {
        if k < order.len() && *s == order[k] {
            k += 1;
        }
    }
    assert_eq!(k, order.len(), "states {states:?}");

    // The operator, from another thread: recalibrate, estop during the excitation, reset.
    let stage = Arc::new(AtomicU8::new(0));
    let op = {
        let h = handle.clone();
        let stage = stage.clone();
        std::thread::spawn(move || {
            let wait = |pred: &dyn Fn() -> bool| {
                let t = Instant::now();
                while !pred() {
                    assert!(t.elapsed() < Duration::from_secs(60), "operator waited in vain");
                    std::thread::sleep(Duration::from_millis(10));
                }
            };
            h.request_recalibration().unwrap();
            wait(&|| h.status().state == State::Excitation);
            // Not operating now: a second recalibration is refused with the reason.
            let r = h.request_recalibration().unwrap_err();
            assert!(r.to_string().contains("excitation"), "{r}");
            h.estop();
            wait(&|| h.status().fault.is_some());
            stage.store(1, Ordering::SeqCst);
            h.reset().unwrap();
            wait(&|| h.status().state == State::Holding);
            stage.store(2, Ordering::SeqCst);
        })
    };
    let done = host.run_until(&mut p, Duration::from_secs(120), |_| stage.load(Ordering::SeqCst) == 2 || op.is_finished());
    op.join().unwrap();
    assert!(done);
    let l = handle.loop_status();
    assert_eq!((l.snap.state, l.snap.fault, l.snap.run), (State::Holding, None, 1));
    let mut saw = (false, false);
    while let Some(e) = handle.poll_event() {
        match e {
            LoopEvent::Fault { cause: Cause::Estop, reaction: Reaction::QuickStop, .. } => saw.0 = true,
            LoopEvent::Reset { outcome: ResetOutcome::Done, .. } => saw.1 = true,
            _ => {}
        }
    }
    assert_eq!(saw, (true, true), "estop and reset events");

    // Stop: the loop holds, disables and finishes; then the lifecycle ends.
    handle.stop();
    assert!(host.run_until(&mut p, Duration::from_secs(5), |p| p.finished()));
    assert_eq!(host.hout.request, taut_rt::host::REQUEST_DISABLE);
    p.deactivate().unwrap();
    p.cleanup().unwrap();
    let (recording, _) = taut_config::recording::Recording::load(&rec).unwrap();
    assert!(recording.len() > 10_000, "{} rows", recording.len());
}

/// KinematicRobot whose drive of cable 1 refuses to enable while `refuse` is set; the last
/// request written is kept for the test.
struct Refusing {
    robot: KinematicRobot,
    refuse: Arc<AtomicBool>,
    last_request: Arc<AtomicU8>,
}

impl taut_rt::io::Devices for Refusing {
    fn read(&mut self, now: f64, inp: &mut Inputs) {
        self.robot.read(now, inp);
        if self.refuse.load(Ordering::SeqCst) {
            inp.drive[1] = DriveStatus::Disabled;
        }
    }
    fn write(&mut self, now: f64, out: &Outputs) {
        self.last_request.store(out.request as u8, Ordering::SeqCst);
        self.robot.write(now, out);
    }
}

#[test]
fn lifecycle_calls_out_of_order_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = quick_config(4, dir.path());
    let mut p = Plugin::configure(&cfg, DeviceMode::Host, PluginOptions { recording: RecordingPath::Off, ..Default::default() }).unwrap();
    let (i, mut o) = (HostInputs::default(), HostOutputs::default());
    assert_eq!(p.update_with(1.0, 0.002, &i, &mut o), Err(UpdateError::NotActive { state: Lifecycle::Inactive }));
    assert_eq!(p.update(1.0, 0.002).unwrap_err(), UpdateError::NotActive { state: Lifecycle::Inactive });
    let e = p.deactivate().unwrap_err();
    assert!(matches!(e, PluginError::Lifecycle { op: Op::Deactivate, state: Lifecycle::Inactive }), "{e}");
    p.activate().unwrap();
    let e = p.activate().unwrap_err();
    assert!(matches!(e, PluginError::Lifecycle { op: Op::Activate, state: Lifecycle::Active }), "{e}");
    assert_eq!(e.kind(), ErrorKind::Lifecycle);
    assert!(e.to_string().contains("already active"), "{e}");
    let e = p.cleanup().unwrap_err();
    assert!(e.to_string().contains("deactivate first"), "{e}");
    // Host-owned: update without readings is the wrong call; bad times are refused.
    let e = p.update(1.0, 0.002).unwrap_err();
    assert_eq!((e, e.kind()), (UpdateError::WrongMode { mode: ModeKind::Host }, ErrorKind::Mode));
    assert_eq!(p.update_with(1.0, f64::NAN, &i, &mut o), Err(UpdateError::BadTime));
    assert_eq!(p.update_with(1.0, 0.0, &i, &mut o), Err(UpdateError::BadTime));
    assert!(p.update_with(1.0, 0.002, &i, &mut o).is_ok());
    assert_eq!(p.update_with(0.5, 0.002, &i, &mut o), Err(UpdateError::BadTime), "time went backwards");
    // Hostile readings are taken as missing and named.
    let mut bad = i;
    bad.drive[2] = 77;
    let t = p.update_with(1.002, 0.002, &bad, &mut o).unwrap();
    assert_eq!(t.bad_input, Some(taut_plugin::BadInput::Drive { cable: 2, code: 77 }));
    p.deactivate().unwrap();
    // Re-activation: the loop starts over (enable, then the phases), and the host's clock may
    // have restarted.
    p.activate().unwrap();
    let t = p.update_with(0.001, 0.002, &i, &mut o).unwrap();
    assert_eq!((t.state, o.request), (State::Enabling, taut_rt::host::REQUEST_DISABLE));
    let t = p.update_with(0.003, 0.002, &i, &mut o).unwrap();
    assert_eq!((t.state, o.request), (State::Enabling, taut_rt::host::REQUEST_ENABLE));
    p.deactivate().unwrap();
    p.cleanup().unwrap();
    let e = p.activate().unwrap_err();
    assert!(matches!(e, PluginError::Lifecycle { op: Op::Activate, state: Lifecycle::Finalized }), "{e}");
    assert_eq!(p.update_with(2.0, 0.002, &i, &mut o), Err(UpdateError::NotActive { state: Lifecycle::Finalized }));
    assert!(p.cleanup().is_err());

    // Plugin-owned: update_with is the wrong call.
    let robot = KinematicRobot::new(truth_params(4, 0.0), [0.2, 0.1, 2.0]);
    let opts = PluginOptions { recording: RecordingPath::Off, ..Default::default() };
    let mut p = Plugin::configure(&cfg, DeviceMode::ready(Box::new(robot)), opts).unwrap();
    p.activate().unwrap();
    assert_eq!(p.update_with(1.0, 0.002, &i, &mut o), Err(UpdateError::WrongMode { mode: ModeKind::Owned }));
    assert!(p.update(1.0, 0.002).is_ok());
    // Dropping an active plugin stops its loop and joins its threads.
    drop(p);

    // A configuration the loop cannot run is refused at configure with the key to fix.
    let mut bad_cfg = cfg.clone();
    bad_cfg.rt.rate_hz = f64::NAN;
    let e = Plugin::configure(&bad_cfg, DeviceMode::Host, PluginOptions::default()).err().unwrap();
    assert_eq!(e.kind(), ErrorKind::Config);
    assert!(e.to_string().contains("rt.rate_hz"), "{e}");
}

#[test]
fn a_failed_activation_leaves_the_robot_safe_and_a_retry_succeeds() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = quick_config(4, dir.path());
    cfg.motion.enable_timeout_s = 0.3;
    let refuse = Arc::new(AtomicBool::new(true));
    let last_request = Arc::new(AtomicU8::new(255));
    let dev = Refusing {
        robot: KinematicRobot::new(truth_params(4, 0.0), [0.2, 0.1, 2.0]),
        refuse: refuse.clone(),
        last_request: last_request.clone(),
    };
    let opts = PluginOptions { recording: RecordingPath::Off, ..Default::default() };
    let mut p = Plugin::configure(&cfg, DeviceMode::ready(Box::new(dev)), opts).unwrap();
    let h = p.handle().clone();
    let t = Instant::now();
    let e = p.activate().unwrap_err();
    assert!(matches!(e, PluginError::Activation { cause: Cause::EnableTimeout { cable: 1 }, reaction: Reaction::Disable }), "{e}");
    assert_eq!(e.kind(), ErrorKind::Device);
    assert!(e.to_string().contains("activate again"), "{e}");
    assert!(t.elapsed() >= Duration::from_millis(300), "gave up before motion.enable_timeout_s");
    // Held safe: the drives were told to disable, and nothing is commanded while inactive.
    assert_eq!(last_request.load(Ordering::SeqCst), DriveRequest::Disable as u8);
    assert_eq!(p.lifecycle(), Lifecycle::Inactive);
    assert_eq!(p.update(10.0, 0.002).unwrap_err(), UpdateError::NotActive { state: Lifecycle::Inactive });
    assert!(matches!(h.poll_event(), Some(LoopEvent::State { to: State::Enabling, .. })));

    // The drive is fixed: the retry enables every drive and the start-up runs from its first
    // phase.
    refuse.store(false, Ordering::SeqCst);
    p.activate().unwrap();
    assert_eq!(last_request.load(Ordering::SeqCst), DriveRequest::Enable as u8);
    assert_eq!((h.status().state, h.status().fault), (State::Enabling, None));
    let mut now = 100.0;
    let mut reached = false;
    for _ in 0..500 {
        now += 0.002;
        if p.update(now, 0.002).unwrap().state == State::InitPhase {
            reached = true;
            break;
        }
    }
    assert!(reached, "state {:?}", h.status().state);
    p.deactivate().unwrap();
    assert!(p.finished());
    assert_eq!(last_request.load(Ordering::SeqCst), DriveRequest::Disable as u8);
    p.cleanup().unwrap();
}
