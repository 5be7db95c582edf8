//! EMCY decoder and error-code names on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_proto::canopen::emcy;

fuzz_target!(|data: &[u8]| {
    if let Ok(e) = emcy::decode(data) {
        assert_eq!(data.len(), 8);
        let _ = e.to_string();
    }
    if data.len() >= 2 {
        let _ = emcy::error_code_name(u16::from_le_bytes([data[0], data[1]]));
    }
});
