//! The bus-fault scenario shared by `canopen_busfault` (in-process virtual bus) and
//! `vcan_busfault` (SocketCAN on vcan0 in the VM): four virtual CiA 402 drives, the loop's
//! devices ([`RobotDevices`]) enabled and holding, and error frames in the kernel's format
//! written to the master's interface. Each must come out of the loop's read as what the loop
//! reacts to, naming the interface, and a recovery must be reported.
#![allow(dead_code)] // each test target uses part of it

use std::time::{Duration, Instant};
use taut_driver::transport::kernel::{err, error_frame, CAN_MTU};
use taut_io::robot_io::{Peripherals, RobotDevices};
use taut_proto::can::CanTransport;
use taut_rt::io::{BusEvent, BusState, CableCommand, DeviceFault, Devices, DriveRequest, DriveStatus, Inputs, Outputs};

/// The robot of `taut start --sim` (four drives, `with_mode` PDOs).
pub fn robot() -> taut_config::RobotConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
    taut_config::RobotConfig::load(path).unwrap()
}

/// What the loop saw in the cycles after an injection.
#[derive(Debug, Default)]
struct Seen {
    faults: Vec<DeviceFault>,
    last: Option<taut_rt::io::BusStatus>,
}

/// Runs the scenario. `inject` writes 16 bytes of `struct can_frame` where the master's
/// interface reads them; `wait` is how long a frame may take to arrive (TCG is slow).
pub fn bus_faults_reach_the_loop<T: CanTransport + Send>(master_bus: T, iface: &str, inject: impl Fn([u8; CAN_MTU]), wait: Duration) {
    bus_faults_reach_the_loop_with(&robot(), master_bus, iface, inject, wait)
}

/// [`bus_faults_reach_the_loop`] with the drives of `cfg`.
pub fn bus_faults_reach_the_loop_with<T: CanTransport + Send>(
    cfg: &taut_config::RobotConfig,
    master_bus: T,
    iface: &str,
    inject: impl Fn([u8; CAN_MTU]),
    wait: Duration,
) {
    let cfg = cfg.clone();
    let mut dev = RobotDevices::bring_up(&cfg, master_bus, Peripherals { loadcells: None, tracker: None, pose: None }).unwrap();
    let mut inp = Inputs::new(4);
    let mut out = Outputs::new(4);
    out.request = DriveRequest::Enable;
    let t0 = Instant::now();
    let cycle = |dev: &mut RobotDevices<T>, inp: &mut Inputs, out: &mut Outputs| {
        dev.read(t0.elapsed().as_secs_f64(), inp);
        for j in 0..4 {
            out.cable[j] = if inp.length_m[j].is_finite() { CableCommand::Position(inp.length_m[j]) } else { CableCommand::Idle };
        }
        dev.write(t0.elapsed().as_secs_f64(), out);
        std::thread::sleep(Duration::from_millis(2));
    };
    // Enabled and holding.
    let deadline = Instant::now() + wait;
    while !inp.drive[..4].iter().all(|&d| d == DriveStatus::Enabled) {
        assert!(Instant::now() < deadline, "drives not enabled: {:?}", &inp.drive[..4]);
        cycle(&mut dev, &mut inp, &mut out);
    }
    assert_eq!(inp.bus.iface.as_str(), iface);
    assert_eq!(inp.bus.state, BusState::Active);
    let mut run_until = |dev: &mut RobotDevices<T>, inp: &mut Inputs, done: &dyn Fn(&Seen) -> bool| -> Seen {
        let mut seen = Seen::default();
        let deadline = Instant::now() + wait;
        while !done(&seen) {
            assert!(Instant::now() < deadline, "not seen within {wait:?}: {seen:?}");
            cycle(dev, inp, &mut out);
            seen.faults.extend(inp.fault);
            seen.last = Some(inp.bus);
        }
        seen
    };

    // Error warning: counted and reported in the bus status, not a fault.
    inject(error_frame(err::CRTL | err::CNT, [0, err::CRTL_TX_WARNING, 0, 0, 0, 0, 97, 0]));
    let s = run_until(&mut dev, &mut inp, &|s| s.last.is_some_and(|b| b.state == BusState::Warning));
    assert!(s.faults.is_empty(), "a warning is no fault: {s:?}");
    assert_eq!(inp.bus.last, Some(BusEvent::ErrorWarning { tx: 97, rx: 0 }));

    // Error-passive: a fault (hold), naming the interface.
    inject(error_frame(err::CRTL | err::CNT, [0, err::CRTL_TX_PASSIVE, 0, 0, 0, 0, 128, 0]));
    let s = run_until(&mut dev, &mut inp, &|s| !s.faults.is_empty());
    let passive = DeviceFault::Bus { iface: inp.bus.iface, event: BusEvent::ErrorPassive { tx: 128, rx: 0 } };
    assert_eq!(s.faults[0], passive);
    assert_eq!(inp.bus.state, BusState::Passive);
    assert_eq!(
        taut_rt::safety::Cause::Bus { iface: inp.bus.iface, event: BusEvent::ErrorPassive { tx: 128, rx: 0 } }.to_string(),
        format!("{iface}: error-passive (tx errors 128, rx errors 0)")
    );
    // Back to error-active: a recovery.
    inject(error_frame(err::CRTL, [0, err::CRTL_ACTIVE, 0, 0, 0, 0, 0, 0]));
    let s = run_until(&mut dev, &mut inp, &|s| s.last.is_some_and(|b| b.recoveries == 1));
    assert!(s.faults.is_empty(), "{s:?}");
    assert_eq!(inp.bus.state, BusState::Active);

    // Bus-off: a fault every cycle while the controller is off (a reset cannot clear it).
    inject(error_frame(err::BUSOFF | err::CNT, [0, 0, 0, 0, 0, 0, 255, 0]));
    let s = run_until(&mut dev, &mut inp, &|s| s.faults.len() >= 5);
    let off = DeviceFault::Bus { iface: inp.bus.iface, event: BusEvent::BusOff };
    assert!(s.faults.iter().all(|f| *f == off), "{s:?}");
    assert_eq!(inp.bus.state, BusState::Off);
    assert_eq!(
        taut_rt::safety::Cause::Bus { iface: inp.bus.iface, event: BusEvent::BusOff }.to_string()[..iface.len() + 9],
        format!("{iface}: bus-off")
    );
    // Bytes that are no frame are not trusted and change nothing.
    let mut junk = error_frame(0, [0; 8]);
    junk[..4].copy_from_slice(&0x0000_0800u32.to_ne_bytes()); // an 11-bit id with bit 11 set
    junk[4] = 3;
    inject(junk);
    run_until(&mut dev, &mut inp, &|s| s.faults.len() >= 3);
    assert_eq!(inp.bus.state, BusState::Off);
    // Restarted: the bus is back, reported as a recovery; no fault from then on.
    inject(error_frame(err::RESTARTED, [0; 8]));
    run_until(&mut dev, &mut inp, &|s| s.last.is_some_and(|b| b.state == BusState::Active));
    assert_eq!(inp.bus.recoveries, 2);
    assert_eq!(inp.bus.last, Some(BusEvent::Restarted));
    for _ in 0..20 {
        cycle(&mut dev, &mut inp, &mut out);
        assert_eq!(inp.fault, None, "no fault once the bus is back");
    }
    assert_eq!(inp.bus.events, 5, "warning, passive, active, bus-off, restarted: {:?}", inp.bus);
    assert!(dev.transport_errors() >= 1, "the junk frame is counted");
}
