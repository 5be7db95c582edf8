//! Modbus RTU hot paths:
//! - `codec_round_trip`: encode a request, decode it as a server, encode the response, decode it
//!   as the master (in memory);
//! - `pty_transaction/*`: one full master transaction (request, wait, response, CRC, checks) to
//!   a responder thread on the other end of a pseudo-terminal pair, with the spec's 1.75 ms
//!   inter-frame silence (115200 baud) and without it (the software's own cost).
//!
//! A pty has no baud rate: on a real 115200-baud line the 17 bytes of a 2-register transaction
//! add ~1.5 ms of wire time.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use serialport::{SerialPort, TTYPort};
use std::hint::black_box;
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use taut_driver::modbus::link::SerialPortLink;
use taut_driver::modbus::master::{Counters, Master, MasterConfig};
use taut_proto::modbus::rtu::{self, Function, Registers, Request, Response, Timing, MAX_FRAME};

fn codec(c: &mut Criterion) {
    let req = Request { unit: 3, function: Function::ReadInputRegisters, address: 0, quantity: 2 };
    let mut g = c.benchmark_group("modbus");
    g.throughput(Throughput::Elements(1));
    g.bench_function("codec_round_trip", |b| {
        let mut buf = [0u8; MAX_FRAME];
        b.iter(|| {
            let n = rtu::encode(black_box(&req), &mut buf);
            let r = rtu::decode_request(&buf[..n]).unwrap();
            let resp = Response::Registers(Registers::new(r.unit, r.function, &[0x1234, 0x5678]));
            let n = rtu::encode_response(&resp, &mut buf);
            black_box(rtu::decode(&buf[..n]).unwrap())
        })
    });
    g.finish();
}

/// Answers every request on the pty master end until stopped.
fn responder(mut port: TTYPort, stop: Arc<AtomicBool>) {
    port.set_timeout(Duration::from_millis(20)).unwrap();
    let mut buf = [0u8; MAX_FRAME];
    let mut len = 0;
    let mut out = [0u8; MAX_FRAME];
    while !stop.load(Ordering::Relaxed) {
        match port.read(&mut buf[len..]) {
            Ok(n) => len += n,
            Err(_) => continue,
        }
        if len >= rtu::REQUEST_LEN {
            if let Ok(r) = rtu::decode_request(&buf[..rtu::REQUEST_LEN]) {
                let n = rtu::encode_response(&Response::Registers(Registers::new(r.unit, r.function, &[0, 4242])), &mut out);
                port.write_all(&out[..n]).unwrap();
            }
            len = 0;
        }
    }
}

fn pty(c: &mut Criterion) {
    let (master_end, slave_end) = TTYPort::pair().expect("pseudo-terminal pair");
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let th = std::thread::spawn(move || responder(master_end, s2));
    let counters = Counters::default();
    let req = Request { unit: 1, function: Function::ReadInputRegisters, address: 0, quantity: 2 };
    let spec = Timing::new(115_200, 10);
    let mut g = c.benchmark_group("modbus/pty_transaction");
    g.throughput(Throughput::Elements(1));
    g.sample_size(30).measurement_time(Duration::from_secs(4));
    let mut m = Master::new(
        SerialPortLink::from_port(slave_end),
        MasterConfig { timing: spec, response_timeout: Duration::from_millis(100), retries: 0 },
        &counters,
    );
    g.bench_function("t3.5_115200", |b| b.iter(|| black_box(m.read(&req).unwrap())));
    let link = m.into_link();
    let no_gap = Timing { t15: Duration::ZERO, t35: Duration::ZERO, ..spec };
    let mut m = Master::new(link, MasterConfig { timing: no_gap, response_timeout: Duration::from_millis(100), retries: 0 }, &counters);
    g.bench_function("no_gap", |b| b.iter(|| black_box(m.read(&req).unwrap())));
    g.finish();
    drop(m);
    stop.store(true, Ordering::Relaxed);
    th.join().unwrap();
    let s = counters.snapshot();
    assert_eq!(s.timeouts + s.crc_errors + s.garbage, 0, "{s:?}");
}

criterion_group!(benches, codec, pty);
criterion_main!(benches);
