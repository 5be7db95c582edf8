//! Bus faults on the in-process CAN bus: error frames in the kernel's `struct can_frame` format,
//! injected through the master endpoint's controller, go through the parser SocketCAN reads use
//! and reach the loop's devices as faults that name the interface (see `busfault/mod.rs`; the
//! same scenario runs on vcan0 in `vcan_busfault`).

use crate::busfault;

use std::time::Duration;
use taut_driver::transport::virtual_bus::VirtualBus;
use taut_vdev::{rack_filters, spawn_rack, DriveParams, VirtualDrive};

#[test]
fn bus_faults_reach_the_loop_on_the_virtual_bus() {
    let bus = VirtualBus::named("can3");
    let nodes = [1u8, 2, 3, 4];
    let master = bus.endpoint_with(1024, &[]);
    let ctl = master.controller();
    let rack =
        spawn_rack(bus.endpoint_with(1024, &rack_filters(&nodes)), nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    busfault::bus_faults_reach_the_loop(master, "can3", |b| ctl.inject(b), Duration::from_secs(20));
    rack.stop();
}

/// The controller itself going bus-off: the master's frames no longer reach the drives (their
/// heartbeats stop reaching the master too), and after the restart the drives are configured
/// again and come back disabled.
#[test]
fn a_bus_off_master_reaches_nobody_until_restarted() {
    use std::time::Instant;
    use taut_io::robot_io::{Peripherals, RobotDevices};
    use taut_rt::io::{BusState, DeviceFault, Devices, DriveRequest, DriveStatus, Inputs, Outputs};
    let bus = VirtualBus::named("can4");
    let nodes = [1u8, 2, 3, 4];
    let master = bus.endpoint_with(1024, &[]);
    let ctl = master.controller();
    let rack =
        spawn_rack(bus.endpoint_with(1024, &rack_filters(&nodes)), nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    let mut dev = RobotDevices::bring_up(&busfault::robot(), master, Peripherals { loadcells: None, tracker: None, pose: None }).unwrap();
    let (mut inp, mut out) = (Inputs::new(4), Outputs::new(4));
    let t0 = Instant::now();
    let until = |dev: &mut RobotDevices<_>, inp: &mut Inputs, out: &Outputs, what: &str, done: &dyn Fn(&Inputs) -> bool| {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut faults = Vec::new();
        while !done(inp) {
            assert!(Instant::now() < deadline, "{what}: {:?} {:?} {faults:?}", &inp.drive[..4], inp.bus);
            dev.read(t0.elapsed().as_secs_f64(), inp);
            faults.extend(inp.fault);
            dev.write(t0.elapsed().as_secs_f64(), out);
            std::thread::sleep(Duration::from_millis(2));
        }
        faults
    };
    out.request = DriveRequest::Enable;
    until(&mut dev, &mut inp, &out, "enabled", &|i| i.drive[..4].iter().all(|&d| d == DriveStatus::Enabled));
    let rx = || rack.with(|ds| ds.iter().map(|d| d.counters().rx).sum::<u64>());
    // A drive's power-on boot-up can cross taut's reset at bring-up (a second boot-up, counted
    // as a reboot): only what the bus-off does is judged here.
    let reboots_before = dev.master().counters().reboots;
    ctl.bus_off();
    // Frames sent before the bus-off may still be on their way to the drives' thread.
    std::thread::sleep(Duration::from_millis(200));
    let rx_off = rx();
    let faults = until(&mut dev, &mut inp, &out, "drives away", &|i| i.drive[..4].iter().all(|&d| d == DriveStatus::Unknown));
    assert!(matches!(faults[0], DeviceFault::Bus { .. }), "{faults:?}");
    assert_eq!(inp.bus.state, BusState::Off);
    assert!(ctl.tx_lost() > 0, "the master's frames were not sent");
    // Nothing the master sent reached the drives (not even the disable of a reaction: a master
    // heartbeat consumer in the drives is what stops them; see docs/canopen.md).
    assert_eq!(rx(), rx_off, "frames reached the drives from a bus-off master");
    ctl.restart();
    out.request = DriveRequest::Disable;
    until(&mut dev, &mut inp, &out, "back, disabled", &|i| i.drive[..4].iter().all(|&d| d == DriveStatus::Disabled));
    assert_eq!(inp.bus.state, BusState::Active);
    assert_eq!(inp.bus.recoveries, 1);
    let c = dev.master().counters();
    assert!(c.reboots == reboots_before && c.heartbeat_losses >= 4, "{c:?}");
    rack.stop();
}
