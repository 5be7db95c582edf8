//! Opening input files that may be anything: a fifo nobody writes to, `/dev/zero`, a 10 GB file
//! given as a configuration.

use std::io::Read;
use std::path::Path;

/// How long to wait for a writer when an input is a fifo.
const FIFO_OPEN_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// Largest configuration or parameter file, bytes. A robot description is a few KiB.
pub const MAX_TEXT_BYTES: u64 = 1 << 20;

/// Opens an input file. Opening a fifo blocks until something writes to it: a pipe from a running
/// command (`<(zcat rec.csv.gz)`) opens at once, a fifo nobody writes to is an error after
/// `FIFO_OPEN_WAIT` (10 s) instead of a hang.
pub fn open(path: &Path) -> Result<std::fs::File, String> {
    use std::os::unix::fs::FileTypeExt;
    let is_fifo = std::fs::metadata(path).is_ok_and(|m| m.file_type().is_fifo());
    if !is_fifo {
        return std::fs::File::open(path).map_err(|e| e.to_string());
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let p = path.to_path_buf();
    // The thread stays blocked in open(2) if nothing ever writes; the command ends with the error.
    std::thread::spawn(move || {
        let _ = tx.send(std::fs::File::open(&p));
    });
    match rx.recv_timeout(FIFO_OPEN_WAIT) {
        Ok(r) => r.map_err(|e| e.to_string()),
        Err(_) => Err(format!(
            "is a fifo and nothing has written to it for {} s; give a file, or start the command that feeds the fifo",
            FIFO_OPEN_WAIT.as_secs()
        )),
    }
}

/// Reads a text file of at most [`MAX_TEXT_BYTES`] (`/dev/zero` or a recording given as a
/// configuration end in an error, not in an exhausted memory).
pub fn read_text(path: &Path) -> Result<String, String> {
    let f = open(path)?;
    if f.metadata().is_ok_and(|m| m.is_dir()) {
        return Err("is a directory".into());
    }
    let mut buf = Vec::new();
    f.take(MAX_TEXT_BYTES + 1).read_to_end(&mut buf).map_err(|e| e.to_string())?;
    if let Some(i) = buf.iter().position(|&b| b == 0) {
        return Err(format!("NUL byte at byte {}: a binary file, not TOML text", i + 1));
    }
    if buf.len() as u64 > MAX_TEXT_BYTES {
        return Err(format!("larger than {} KiB; is this the right file?", MAX_TEXT_BYTES >> 10));
    }
    String::from_utf8(buf).map_err(|e| format!("byte {} is not UTF-8 text", e.utf8_error().valid_up_to() + 1))
}
