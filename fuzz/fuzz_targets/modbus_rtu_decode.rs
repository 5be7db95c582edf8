//! Modbus RTU frame decoders on arbitrary bytes (what an RS-485 line can deliver): never panic,
//! and whatever decodes re-encodes to the same bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_proto::modbus::rtu::{self, Function, MAX_FRAME};

fuzz_target!(|data: &[u8]| {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(r) = rtu::decode(data) {
        let n = rtu::encode_response(&r, &mut buf);
        assert_eq!(&buf[..n], data);
        let _ = r.unit();
    }
    if let Ok(q) = rtu::decode_request(data) {
        let n = rtu::encode(&q, &mut buf);
        assert_eq!(&buf[..n], data);
    }
    let _ = rtu::response_len(data);
    let unit = data.first().copied().unwrap_or(1);
    for f in [Function::ReadHoldingRegisters, Function::ReadInputRegisters] {
        if let Some((start, len)) = rtu::find_response(data, unit, f) {
            assert!(start + len <= data.len());
        }
    }
});
