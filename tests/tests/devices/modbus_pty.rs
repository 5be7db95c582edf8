//! The Modbus RTU master against the virtual load-cell server on a pseudo-terminal pair:
//! normal reads, each injected fault, and the port vanishing and coming back.

use std::time::{Duration, Instant};
use taut_driver::loadcell;
use taut_driver::modbus::link::SerialPortLink;
use taut_driver::modbus::master::{Counters, Master, MasterConfig, TransactionError};
use taut_proto::devices::{LoadCellBusConfig, LoadCellConfig, RegisterKind, ValueFormat, WordOrder};
use taut_proto::modbus::link::LinkError;
use taut_proto::modbus::rtu::{ExceptionCode, Function, Request};
use taut_vdev::{LoadCellFault, TensionHandle, VirtualLoadCells};

fn cells() -> Vec<LoadCellConfig> {
    vec![
        LoadCellConfig { scale: 0.01, ..LoadCellConfig::new(1) },
        LoadCellConfig { registers: RegisterKind::Holding, register: 10, format: ValueFormat::Float32, ..LoadCellConfig::new(2) },
        LoadCellConfig { word_order: WordOrder::Little, format: ValueFormat::Float32, offset: 5.0, ..LoadCellConfig::new(3) },
    ]
}

fn bus(server: &VirtualLoadCells) -> LoadCellBusConfig {
    LoadCellBusConfig {
        // Generous: a loaded machine must not turn a slow answer into a counted timeout (the
        // pseudo-terminal passed answers on up to 425 ms late at load 10-13, tests/src/startup.rs).
        response_timeout_s: 0.5,
        reconnect_min_s: 0.02,
        reconnect_max_s: 0.2,
        ..LoadCellBusConfig::new(server.path().to_str().unwrap())
    }
}

fn req(c: &LoadCellConfig) -> Request {
    let function = match c.registers {
        RegisterKind::Input => Function::ReadInputRegisters,
        RegisterKind::Holding => Function::ReadHoldingRegisters,
    };
    Request { unit: c.unit_id, function, address: c.register, quantity: 2 }
}

fn wait_until(what: &str, timeout: Duration, mut f: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(t0.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn reads_every_encoding() {
    let t = TensionHandle::new(3);
    t.set_all(&[123.45, -2.5, 1000.25]);
    let server = VirtualLoadCells::spawn(cells(), t.clone()).unwrap();
    let b = bus(&server);
    let counters = Counters::default();
    let mut m = Master::new(SerialPortLink::open(&b).unwrap(), MasterConfig::from_bus(&b), &counters);
    for (i, c) in cells().iter().enumerate() {
        let r = m.read(&req(c)).unwrap();
        let v = r.values();
        let n = taut_proto::modbus::value::newtons([v[0], v[1]], c).unwrap();
        assert!((n - t.get(i)).abs() < 1e-3, "cell {i}: {n} vs {}", t.get(i));
    }
    // Wrong table and out-of-range addresses: exception 02, not retried.
    let bad = Request { function: Function::ReadHoldingRegisters, ..req(&cells()[0]) };
    assert_eq!(m.read(&bad), Err(TransactionError::Exception { unit: 1, code: ExceptionCode::IllegalDataAddress }));
    let bad = Request { address: 11, ..req(&cells()[1]) };
    assert_eq!(m.read(&bad), Err(TransactionError::Exception { unit: 2, code: ExceptionCode::IllegalDataAddress }));
    // A unit nobody has: silence, so timeout after every try.
    let nobody = Request { unit: 99, ..req(&cells()[0]) };
    assert_eq!(m.read(&nobody), Err(TransactionError::Timeout { unit: 99 }));
    let s = counters.snapshot();
    assert_eq!((s.ok, s.exceptions, s.timeouts, s.retries, s.failed), (3, 2, 3, 2, 3), "{s:?}");
}

#[test]
fn faults_are_counted_and_retried() {
    let t = TensionHandle::new(3);
    t.set_all(&[10.0, 20.0, 30.0]);
    let server = VirtualLoadCells::spawn(cells(), t).unwrap();
    let b = bus(&server);
    let counters = Counters::default();
    let mut m = Master::new(SerialPortLink::open(&b).unwrap(), MasterConfig::from_bus(&b), &counters);
    let r1 = req(&cells()[0]);

    server.inject(Some(1), LoadCellFault::BadCrc, 1);
    assert!(m.read(&r1).is_ok());
    server.inject(Some(1), LoadCellFault::Silence, 2);
    assert!(m.read(&r1).is_ok(), "third try answers");
    server.inject(Some(1), LoadCellFault::Garbage, 1);
    assert!(m.read(&r1).is_ok());
    server.inject(Some(1), LoadCellFault::NoiseThenAnswer, 1);
    assert!(m.read(&r1).is_ok());
    server.inject(Some(1), LoadCellFault::Exception(0x06), 1); // busy: transient, retried
    assert!(m.read(&r1).is_ok());
    server.inject(Some(1), LoadCellFault::Exception(0x04), 5); // device failure: transient, but persistent
    assert_eq!(m.read(&r1), Err(TransactionError::Exception { unit: 1, code: ExceptionCode::ServerDeviceFailure }));
    server.clear_faults();
    server.inject(Some(1), LoadCellFault::Silence, 3);
    assert_eq!(m.read(&r1), Err(TransactionError::Timeout { unit: 1 }));
    assert!(m.read(&r1).is_ok(), "recovers after the fault");

    let s = counters.snapshot();
    assert_eq!(s.crc_errors, 1, "{s:?}");
    assert_eq!(s.timeouts, 2 + 3, "{s:?}");
    assert_eq!(s.garbage, 1, "{s:?}");
    assert_eq!(s.exceptions, 1 + 3, "{s:?}");
    assert_eq!(s.failed, 2, "{s:?}");
    assert_eq!(s.ok, 6, "{s:?}");
    assert_eq!(server.stats().faults, 1 + 2 + 1 + 1 + 1 + 3 + 3);
}

#[test]
fn io_thread_feeds_the_loop_and_survives_unplug() {
    feeds_the_loop_and_survives_unplug(false);
}

/// The line of the simulated robot's wall-clock start-ups (`taut_simrig::LoadCellLine`): the
/// same I/O thread and master on a socket pair, with the same unplug and replug.
#[test]
fn io_thread_over_a_socket_pair_feeds_the_loop_and_survives_unplug() {
    feeds_the_loop_and_survives_unplug(true);
}

fn feeds_the_loop_and_survives_unplug(socket: bool) {
    let t = TensionHandle::new(3);
    t.set_all(&[50.0, 60.0, 70.0]);
    let server =
        if socket { VirtualLoadCells::spawn_socket(cells(), t.clone()) } else { VirtualLoadCells::spawn(cells(), t.clone()) }.unwrap();
    let b = bus(&server);
    let pairs: Vec<_> = cells().into_iter().enumerate().collect();
    let (io, mut reader) = match server.socket_port() {
        Some(port) => loadcell::spawn_with(&b, &pairs, 4, move || port.open()),
        None => loadcell::spawn(&b, &pairs, 4),
    }
    .unwrap();

    let fresh = |r: &mut loadcell::TensionReader, want: [f64; 3]| {
        r.update();
        let now = Instant::now();
        (0..3).all(|i| r.tension(i, now).is_some_and(|n| (n - want[i]).abs() < 1e-3))
    };
    wait_until("first tensions", Duration::from_secs(5), || fresh(&mut reader, [50.0, 60.0, 70.0]));
    // Cable 3 has no load cell: always missing.
    assert_eq!(reader.tension(3, Instant::now()), None);
    t.set(1, 61.5);
    wait_until("updated tension", Duration::from_secs(5), || fresh(&mut reader, [50.0, 61.5, 70.0]));

    // USB unplug: the port fails, the path vanishes; readings go stale.
    server.unplug();
    let unplugged = Instant::now();
    wait_until("link loss noticed", Duration::from_secs(5), || io.counters().links_lost >= 1);
    std::thread::sleep(Duration::from_millis(120));
    reader.update();
    assert_eq!(reader.tension(0, Instant::now()), None, "stale after max_age");
    wait_until("failed reopen attempts", Duration::from_secs(5), || io.counters().open_failures >= 2);

    // Plugged back in: reconnects on its own and readings resume.
    server.replug();
    t.set(0, 51.0);
    wait_until("readings after replug", Duration::from_secs(5), || fresh(&mut reader, [51.0, 61.5, 70.0]));
    let s = io.counters();
    let down_s = unplugged.elapsed().as_secs_f64();
    assert!(s.reconnects >= 1, "{s:?}");
    // Back-off at 20, 40, 80, 160, then 200 ms: at most 5 attempts in the first 0.3 s and one
    // per 0.2 s after, however long a loaded machine kept the port unplugged (it was a fixed
    // 20, which a test thread starved for 3 s would exceed; without back-off: thousands).
    let most = 5 + (down_s / 0.2).ceil() as u64;
    assert!(s.open_failures <= most, "back-off does not hammer the port: {s:?} in {down_s:.2} s (at most {most})");
    assert_eq!(s.crc_errors, 0, "{s:?}");
    io.stop();
}

#[test]
fn missing_port_is_reported_not_fatal() {
    let b = LoadCellBusConfig { reconnect_min_s: 0.01, reconnect_max_s: 0.05, ..LoadCellBusConfig::new("/nonexistent/taut-loadcells") };
    assert!(matches!(SerialPortLink::open(&b), Err(LinkError::NotFound)));
    let (io, mut reader) = loadcell::spawn(&b, &[(0, LoadCellConfig::new(1))], 1).unwrap();
    wait_until("open failures", Duration::from_secs(5), || io.counters().open_failures >= 2);
    reader.update();
    assert_eq!(reader.tension(0, Instant::now()), None);
    assert_eq!(reader.missing(), 1);
}

#[test]
fn bad_config_is_refused_with_the_key() {
    let b = LoadCellBusConfig::new("/dev/null");
    let e = loadcell::spawn(&b, &[(0, LoadCellConfig::new(1)), (1, LoadCellConfig::new(1))], 2).err().unwrap();
    assert!(e.to_string().contains("cable[1].loadcell.unit_id"), "{e}");
    let e = loadcell::spawn(&b, &[(0, LoadCellConfig::new(0))], 1).err().unwrap();
    assert!(e.to_string().contains("unit_id"), "{e}");
}
