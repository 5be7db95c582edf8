//! The recording reader (`cdpr-recording v1`, CSV, with its own float parser) on arbitrary
//! bytes: a recording or an error naming a line of the input, never a panic; a recording's
//! columns all have one row per sample, and it writes out and reads back to itself. The reader
//! of a file in memory (rows cut into pieces read on threads, as `Recording::load_with` reads a
//! regular file) gives the same recording, report and error as the line-by-line reader.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_config::recording::{fuzzing::parse_in_pieces, parse};

fuzz_target!(|data: &[u8]| {
    let lines = data.iter().filter(|&&b| b == b'\n').count() + 1;
    let one = parse(data);
    // Pieces of at least 16 bytes on three threads: a short input is cut too.
    let pieces = parse_in_pieces(data, 3, 16);
    assert_eq!(format!("{one:?}"), format!("{pieces:?}"), "the piecewise reader differs from the line-by-line reader");
    match one {
        Ok((rec, report)) => {
            let (n, m) = (rec.len(), rec.n_cables);
            assert!(m >= 1 && report.rows >= n);
            assert_eq!((rec.p.len(), rec.l.len()), (n, n * m));
            assert!(rec.f.as_ref().map_or(true, |f| f.len() == n * m));
            assert!(rec.q.as_ref().map_or(true, |q| q.len() == n));
            assert!(rec.phase.as_ref().map_or(true, |ph| ph.len() == n));
            assert!(rec.t.windows(2).all(|w| w[0] <= w[1]), "times go back");
            let mut out = Vec::new();
            rec.write_csv(&mut out).expect("writing to memory");
            let (back, _) = parse(&out[..]).expect("a written recording reads back");
            assert_eq!(back.len(), n);
            assert_eq!(back.n_cables, m);
        }
        Err(e) => assert!(e.line <= lines, "error on line {} of {lines}: {e}", e.line),
    }
});
