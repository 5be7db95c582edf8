//! Tracker pose-line parser on arbitrary datagrams: never panics, and an accepted line formats
//! and parses back to the same pose.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_proto::tracker::{format_line, parse_line, MAX_LINE};

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = parse_line(data) {
        assert!(p.t.is_finite() && p.position.iter().all(|x| x.is_finite()));
        let mut buf = [0u8; MAX_LINE];
        let n = format_line(&p, &mut buf);
        let back = parse_line(&buf[..n]).expect("a formatted pose parses");
        assert_eq!((back.t, back.position), (p.t, p.position));
    }
});
