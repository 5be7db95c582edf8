//! SDO parsers (both directions) and the SDO client state machine on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::time::{Duration, Instant};
use taut_proto::canopen::sdo::{SdoClient, SdoRequest, SdoResponse};

fuzz_target!(|data: &[u8]| {
    let _ = SdoResponse::decode(data);
    let _ = SdoRequest::decode(data);
    // A client in each kind of transfer, fed the input as a sequence of 8-byte responses.
    let t = Instant::now();
    for start in 0..3 {
        let mut c = SdoClient::new(1, Duration::from_millis(10));
        match start {
            0 => c.upload(0x1008, 0, t).unwrap(),
            1 => c.download(0x2000, 0, &[7; 20], false, t).unwrap(),
            _ => c.download(0x6040, 0, &[6, 0], false, t).unwrap(),
        }
        for chunk in data.chunks(8) {
            let _ = c.on_response(chunk, t);
            while c.poll_tx().is_some() {}
        }
        let _ = c.poll(t + Duration::from_secs(1));
    }
});
