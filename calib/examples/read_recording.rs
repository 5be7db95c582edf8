//! Reads a recording the way `taut calibrate` does and exits: the parse-only process that
//! `bench/whole_process.py --parse-only` times beside the whole calibration.
//!
//!     read_recording REC
//!
//! Same reader (`Recording::load_with`), same thread count (`par::available(8)`, as the CLI).
//! Prints the row and cable counts so that the reading cannot be optimised away.

use taut_config::recording::Recording;

fn main() {
    let Some(path) = std::env::args_os().nth(1) else {
        eprintln!("usage: read_recording REC");
        std::process::exit(2);
    };
    match Recording::load_with(&path, taut_calib::par::available(8)) {
        Ok((rec, _)) => println!("{} rows x {} cables", rec.len(), rec.n_cables),
        Err(e) => {
            eprintln!("{}: {e}", std::path::Path::new(&path).display());
            std::process::exit(1);
        }
    }
}
