//! The EDS (CiA 306) parser on arbitrary bytes: a parse or an error naming a line inside the
//! text, never a panic; a parsed file answers every lookup.
#![no_main]
use libfuzzer_sys::fuzz_target;
use taut_proto::eds::Eds;

fuzz_target!(|data: &[u8]| {
    let lines = data.iter().filter(|&&b| b == b'\n').count() + 1;
    match Eds::parse(data) {
        Ok(eds) => {
            for v in eds.vars() {
                let _ = (v.bits(), eds.var(v.index, v.sub), eds.object_line(v.index));
                assert!(v.line >= 1 && v.line <= lines);
            }
        }
        Err(e) => assert!(e.line.map_or(true, |l| l >= 1 && l <= lines), "{e}"),
    }
});
