//! The parameter-file reader (`taut-params` v1 to v4) on arbitrary text: a parameter set or
//! an error naming the file and a line of it, never a panic; an accepted set has one offset
//! per anchor, finite values, and writes out and reads back to itself.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;
use taut_config::params::ParamsFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = Path::new("fuzz.toml");
    let lines = text.lines().count().max(1);
    match ParamsFile::parse(path, text) {
        Ok(p) => {
            assert_eq!(p.anchors_m.len(), p.l0_m.len());
            assert!(p.check_finite().is_ok());
            let out = p.to_text().expect("an accepted parameter set serialises");
            let back = ParamsFile::parse(path, &out).expect("a written parameter set reads back");
            assert_eq!(format!("{back:?}"), format!("{p:?}"));
        }
        Err(e) => {
            assert_eq!(e.file.as_deref(), Some(path));
            assert!(e.line.map_or(true, |l| l >= 1 && l <= lines), "{e}");
        }
    }
});
