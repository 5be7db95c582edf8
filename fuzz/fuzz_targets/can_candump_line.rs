//! candump log line parser on arbitrary text; what parses must write back and parse the same.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_driver::transport::candump::{parse_line, write_line, LoggedFrame};

fuzz_target!(|data: &[u8]| {
    let Ok(s) = std::str::from_utf8(data) else { return };
    if let Ok(l) = parse_line(s) {
        if let LoggedFrame::Can(f) = l.frame {
            if !l.iface.is_empty() {
                let mut out = Vec::new();
                write_line(&mut out, l.t_us, l.iface, &f).unwrap();
                let again = String::from_utf8(out).unwrap();
                let l2 = parse_line(&again).expect("our own output parses");
                assert_eq!(l2.frame, l.frame);
                assert_eq!(l2.t_us, l.t_us);
            }
        }
    }
});
