//! The loop thread allocates and frees nothing after start-up: a counting global allocator
//! watches 100,000+ cycles through every state, parameter swaps, safety reactions and a full
//! sample ring.

use std::cell::Cell;
use taut_io::runner::LoopCore;
use taut_io::testkit::{quick_config, truth_params, KinematicRobot};
use taut_io::FromRobot;
use taut_rt::io::{BusEvent, DeviceFault, IfName};
use taut_rt::kin::{LoopEffects, LoopParams};
use taut_rt::motion::{Command, Controller, ControllerConfig, State};
use taut_rt::sample::sample_ring;
use taut_rt::triple::triple_buffer;

// The counting global allocator of this test binary (one per binary): `crate::counting`.
use crate::counting::{ALLOCS, FREES, WATCHING};

#[test]
fn loop_allocates_nothing_in_any_state() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = quick_config(4, dir.path());
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let truth = truth_params(4, 0.1);
    let (mut params_tx, params_rx) = triple_buffer(LoopParams::invalid(4));
    let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(16);
    // A small ring nobody drains: it is full for most of the run, so drops are exercised too.
    let (sample_tx, _sample_rx) = sample_ring(1024);
    let robot = KinematicRobot::new(truth, [0.2, 0.1, 2.0]);
    let mut core = LoopCore::new(4, robot, Controller::new(ccfg, move || cmd_rx.try_recv().ok(), params_rx), sample_tx);

    let dt = 0.002;
    let mut t = 0.0;
    let mut seen = std::collections::BTreeSet::new();
    let cycles = Cell::new(0u64);
    let mut run = |core: &mut LoopCore<KinematicRobot>, k: usize, seen: &mut std::collections::BTreeSet<u8>| {
        for _ in 0..k {
            t += dt;
            WATCHING.with(|w| w.set(true));
            core.cycle(t, dt);
            WATCHING.with(|w| w.set(false));
            seen.insert(core.controller.state() as u8);
            cycles.set(cycles.get() + 1);
        }
    };
    // The calibrated parameters carry every effect the loop models, the tension side's too, and
    // pulleys on horizontal and inclined axes.
    let effects = LoopEffects::from_values(Some(&[20_000.0; 4]), Some(&[1.001; 4]), Some(&[-0.002; 4]), Some(&[0.03; 4]), None, None)
        .with_deflection(Some(&[1.5e-6; 4]))
        .with_tension_side(Some(&[1.03, 0.98, 1.0, 1.01]), Some(&[0.1; 4]));
    let axes = [[1.0, 0.0, 0.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0], [-0.6, 0.0, 0.8]];
    let initial = |v: u64, off: f64| {
        let mut p = truth.with_effects(effects).with_pulley_axes(&axes);
        p.version = v;
        for a in p.anchors.iter_mut().take(4) {
            a[0] += off;
        }
        p
    };

    // Enable and the three phases.
    run(&mut core, 1, &mut seen);
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::AwaitInitial {
            break;
        }
    }
    assert_eq!(core.controller.state(), State::AwaitInitial, "{:?}", core.controller.fault());
    run(&mut core, 50, &mut seen);
    // Initial estimate -> excitation -> operate.
    params_tx.write(initial(1, 0.01));
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::Operate {
            break;
        }
    }
    assert_eq!(core.controller.state(), State::Operate, "{:?}", core.controller.fault());
    // Calibrated parameters: a swap while operating, and a move.
    params_tx.write(initial(2, 0.0));
    run(&mut core, 1000, &mut seen);
    cmd_tx.send(Command::MoveTo([0.5, 0.2, 2.0])).unwrap();
    run(&mut core, 3000, &mut seen);
    // Recalibration run with another swap during its excitation.
    cmd_tx.send(Command::Recalibrate).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Excitation);
    params_tx.write(initial(3, 0.002));
    for _ in 0..20_000 {
        run(&mut core, 1, &mut seen);
        if core.controller.state() == State::Operate {
            break;
        }
    }
    // Safety reactions of each kind, each followed by a reset.
    cmd_tx.send(Command::Estop).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Faulted);
    cmd_tx.send(Command::Reset).unwrap();
    run(&mut core, 500, &mut seen);
    assert_eq!(core.controller.state(), State::Holding);
    core.devices.inject.tension_bias_n = 1000.0;
    run(&mut core, 200, &mut seen);
    core.devices.inject.tension_bias_n = 0.0;
    cmd_tx.send(Command::Reset).unwrap();
    core.devices.inject.fault = Some(DeviceFault::Emcy { node: 2, code: 0x2310 });
    run(&mut core, 200, &mut seen);
    core.devices.inject.fault = Some(DeviceFault::Bus { iface: IfName::new("can0"), event: BusEvent::BusOff });
    run(&mut core, 200, &mut seen);
    core.devices.inject.fault = None;
    cmd_tx.send(Command::Reset).unwrap();
    core.devices.inject.loadcells_silent = true;
    run(&mut core, 200, &mut seen);
    core.devices.inject.loadcells_silent = false;
    cmd_tx.send(Command::Reset).unwrap();
    run(&mut core, 10, &mut seen);
    // Long holding/operating stretch with swaps every few hundred cycles.
    let mut v = 4;
    cmd_tx.send(Command::MoveTo([0.0, 0.0, 2.2])).unwrap();
    while cycles.get() < 110_000 {
        params_tx.write(initial(v, if v % 2 == 0 { 0.001 } else { 0.0 }));
        v += 1;
        run(&mut core, 400, &mut seen);
    }
    cmd_tx.send(Command::Stop).unwrap();
    run(&mut core, 20, &mut seen);
    assert!(core.controller.finished());

    let allocs = ALLOCS.with(|a| a.get());
    let frees = FREES.with(|a| a.get());
    let cycles = cycles.get();
    assert!(cycles >= 100_000);
    for s in [
        State::Enabling,
        State::InitPhase,
        State::AwaitInitial,
        State::Excitation,
        State::Operate,
        State::Holding,
        State::Faulted,
        State::Stopped,
    ] {
        assert!(seen.contains(&(s as u8)), "state {s:?} not visited");
    }
    assert!(core.dropped() > 0, "the ring never filled");
    assert_eq!((allocs, frees), (0, 0), "the loop allocated {allocs} times and freed {frees} times in {cycles} cycles");
}

#[test]
fn the_counter_sees_allocations() {
    WATCHING.with(|w| w.set(true));
    let v = std::hint::black_box(vec![1u8; 10]);
    drop(v);
    WATCHING.with(|w| w.set(false));
    assert!(ALLOCS.with(|a| a.get()) >= 1 && FREES.with(|a| a.get()) >= 1);
}

/// The hardware device path allocates nothing per cycle either: `RobotDevices` (CANopen master
/// on a transport, mode switches, EMCY and heartbeat handling) against virtual CiA 402 drives on
/// their own thread, 20,000 cycles with commands in both modes and faults.
#[test]
fn robot_devices_allocate_nothing_per_cycle() {
    use taut_driver::transport::virtual_bus::VirtualBus;
    use taut_io::robot_io::{Peripherals, RobotDevices};
    use taut_rt::io::{CableCommand, Devices, DriveRequest, Inputs, Outputs};
    use taut_vdev::{rack_filters, spawn_rack, DriveParams, VirtualDrive};

    let mut t = String::from("[robot]\nname = \"alloc\"\nmass_kg = 3.0\n[can]\ninterface = \"vcan0\"\n");
    for (j, a) in [[3.5, -1.75, 4.0], [3.5, 1.75, 4.0], [-3.5, 1.75, 4.0], [-3.5, -1.75, 4.0]].iter().enumerate() {
        t += &format!("[[cable]]\nanchor = [{}, {}, {}]\n[cable.drive]\nnode_id = {}\npdo = \"with_mode\"\n", a[0], a[1], a[2], j + 1);
    }
    let cfg = taut_config::RobotConfig::from_toml_str(&t).unwrap();
    let bus = VirtualBus::new();
    let nodes = [1u8, 2, 3, 4];
    let master_end = bus.endpoint_with(1024, &[]);
    let rack =
        spawn_rack(bus.endpoint_with(1024, &rack_filters(&nodes)), nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    let mut dev = RobotDevices::bring_up(&cfg, master_end, Peripherals { loadcells: None, tracker: None, pose: None }).unwrap();
    let mut inp = Inputs::new(4);
    let mut out = Outputs::new(4);
    let t0 = std::time::Instant::now();
    let cycle = |dev: &mut RobotDevices<_>, out: &Outputs, inp: &mut Inputs| {
        let now = t0.elapsed().as_secs_f64();
        WATCHING.with(|w| w.set(true));
        dev.read(now, inp);
        dev.write(now, out);
        WATCHING.with(|w| w.set(false));
        std::thread::sleep(std::time::Duration::from_micros(200));
    };
    let mut enabled = 0;
    let mut faults = 0;
    out.request = DriveRequest::Enable;
    for k in 0..20_000u32 {
        let x = f64::from(k) * 1e-5;
        for j in 0..4 {
            // Cables 0..2 in position mode, cable 3 switching between torque and position.
            out.cable[j] = if j == 3 && (k / 2000) % 2 == 0 { CableCommand::Tension(10.0) } else { CableCommand::Position(1.0 + x) };
        }
        match k {
            12_000 => {
                rack.with_drive(2, |d| d.inject_fault(0x2310));
            }
            14_000 => out.request = DriveRequest::Disable,
            16_000 => {
                rack.with_drive(3, |d| d.set_heartbeat_off(true));
            }
            _ => {}
        }
        cycle(&mut dev, &out, &mut inp);
        enabled += usize::from(inp.drive[..4].iter().all(|d| *d == taut_rt::io::DriveStatus::Enabled));
        faults += usize::from(inp.fault.is_some());
    }
    rack.stop();
    assert!(enabled > 5_000, "drives enabled in only {enabled} cycles");
    assert!(faults >= 2, "EMCY and heartbeat loss not both reported ({faults})");
    let (allocs, frees) = (ALLOCS.with(|a| a.get()), FREES.with(|a| a.get()));
    assert_eq!((allocs, frees), (0, 0), "RobotDevices allocated {allocs} times and freed {frees} times");
}
