//! The whole master on arbitrary frames: never panics, every frame is counted.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::time::{Duration, Instant};
use taut_driver::canopen::master::{Master, MasterConfig, NodeConfig};
use taut_proto::can::Frame;

fuzz_target!(|data: &[u8]| {
    let mut m = Master::new(MasterConfig::new(vec![NodeConfig::new(1, 0), NodeConfig::new(2, 1)]));
    let mut t = Instant::now();
    // Each record: 2 bytes id (bit 15 = extended), 1 byte dlc, up to 8 data bytes.
    let mut rest = data;
    let mut n = 0u64;
    while rest.len() >= 3 {
        let id = u16::from_le_bytes([rest[0], rest[1]]);
        let len = usize::from(rest[2] % 9).min(rest.len() - 3);
        let payload = &rest[3..3 + len];
        rest = &rest[3 + len..];
        let f = if id & 0x8000 != 0 {
            Frame::try_new(u32::from(id & 0x7FFF) << 10, true, payload).unwrap()
        } else {
            Frame::new(id & 0x7FF, payload)
        };
        t += Duration::from_micros(700);
        m.poll(t);
        while m.poll_tx().is_some() {}
        m.on_frame(&f, t);
        while m.poll_event().is_some() {}
        n += 1;
    }
    assert_eq!(m.counters().rx_frames, n);
});
