//! The checked-in `include/taut.h` is what cbindgen generates from the source today (CI catches a
//! stale header). `TAUT_BLESS_HEADER=1` rewrites it instead of failing.

use std::path::Path;

#[test]
fn checked_in_header_matches_the_source() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("ffi/cbindgen.toml");
    // cbindgen leaves out a constant defined from another crate's: the one number of cables is
    // written here from its value.
    let max_cables =
        format!("\n// Largest number of cables (the size of every per-cable array).\n#define TAUT_MAX_CABLES {}", taut::TAUT_MAX_CABLES);
    let bindings = cbindgen::Builder::new()
        .with_crate(dir)
        .with_config(config)
        .with_after_include(max_cables)
        .generate()
        .expect("cbindgen could not generate the header");
    let mut fresh = Vec::new();
    bindings.write(&mut fresh);
    let path = dir.join("include/taut.h");
    let on_disk = std::fs::read(&path).unwrap_or_default();
    if fresh == on_disk {
        return;
    }
    if std::env::var_os("TAUT_BLESS_HEADER").is_some() {
        std::fs::write(&path, &fresh).expect("write ffi/include/taut.h");
        return;
    }
    panic!(
        "ffi/include/taut.h is not what cbindgen generates from ffi/src ({} bytes on disk, {} generated): regenerate it with \
         `TAUT_BLESS_HEADER=1 cargo test -p taut-ffi --test header` and commit it",
        on_disk.len(),
        fresh.len()
    );
}
