//! The MCAP reader (`taut_config::mcap::parse`, what `taut calibrate rec.mcap` reads) on
//! arbitrary bytes: a recording or a message for a person, never a panic; a recording's columns
//! all have one row per sample. Seeds: `fuzz/seeds/mcap_read` (a file `taut export` wrote).
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_config::mcap::parse;

fuzz_target!(|data: &[u8]| {
    match parse(data) {
        Ok((rec, report)) => {
            let (n, m) = (rec.len(), rec.n_cables);
            assert!(report.rows >= n);
            assert_eq!((rec.p.len(), rec.l.len()), (n, n * m));
            assert!(rec.f.as_ref().map_or(true, |f| f.len() == n * m));
        }
        Err(e) => assert!(!e.is_empty()),
    }
});
