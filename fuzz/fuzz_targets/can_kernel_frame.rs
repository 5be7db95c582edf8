//! The kernel's `struct can_frame` bytes (what a SocketCAN read hands out, error frames
//! included) on arbitrary bytes: never panics; a decoded frame encodes back to bytes that decode
//! to the same frame.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_driver::transport::kernel;

fuzz_target!(|data: &[u8]| {
    if let Ok(f) = kernel::decode(data) {
        assert_eq!(kernel::decode(&kernel::encode(&f)), Ok(f));
    }
});
