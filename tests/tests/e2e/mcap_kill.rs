//! Power loss: `taut start --sim` killed with SIGKILL mid-run leaves an MCAP file whose closed
//! chunks the independent Python reader reads (all but the last half second), and taut names
//! the file and the problem instead of reading it half.

use crate::hostile;

use hostile::taut_bin;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use taut_config::recording::Recording;
use taut_tests::mcap::{count, read_with_python};

/// The daemon under test, killed when the test ends however it ends: a failed assertion must not
/// leave a simulated robot running beside the rest of the suite.
struct Daemon(std::process::Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn killed_writer_leaves_every_closed_chunk_readable() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let mut child = Daemon(
        Command::new(taut_bin())
            .args(["start", "--sim", "--data-dir", data.to_str().unwrap(), "--socket", dir.path().join("s.sock").to_str().unwrap()])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.path().join("taut.log")).unwrap())
            .spawn()
            .unwrap(),
    );
    let recs = data.join("recordings");
    let find = |ext: &str| std::fs::read_dir(&recs).ok()?.flatten().map(|e| e.path()).find(|p| p.extension().is_some_and(|x| x == ext));
    // Run until the MCAP file holds several chunks (a few seconds of the start-up).
    let t0 = Instant::now();
    loop {
        assert!(t0.elapsed() < Duration::from_secs(120), "no MCAP recording grew in {}; the daemon's log:\n{}", recs.display(), {
            let log = std::fs::read_to_string(dir.path().join("taut.log")).unwrap_or_default();
            log.lines().rev().take(30).collect::<Vec<_>>().into_iter().rev().collect::<Vec<_>>().join("\n")
        });
        if let Some(p) = find("mcap") {
            if std::fs::metadata(&p).map_or(0, |m| m.len()) > 3 << 20 {
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.0.kill().unwrap(); // SIGKILL: no destructor, no summary, no footer.
    child.0.wait().unwrap();
    let mcap = find("mcap").unwrap();
    let csv = find("csv").unwrap();

    let v = read_with_python(&mcap);
    eprintln!("killed file: {} bytes, reader: {}", std::fs::metadata(&mcap).unwrap().len(), v);
    assert_eq!(v["complete"], false, "a killed writer cannot have written the footer");
    assert!(v["json_error"].is_null(), "{v}");
    assert_eq!(v["channels"].as_object().unwrap().len(), 9);
    assert_eq!(v["metadata"]["taut"]["format"], "taut-mcap v1");
    // The CSV of the same run, flushed on the same half-second schedule, as the yardstick:
    // complete rows (the last line may be cut).
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows = text.lines().filter(|l| !l.starts_with('#') && !l.starts_with('t') && l.ends_with(|c: char| c.is_ascii_alphabetic())).count()
        as u64;
    let cables = count(&v, "/cables");
    // At most the last unclosed chunk is lost: half a second, or one 768 KiB chunk (~1.3 s of
    // 500 Hz samples of this robot), plus what the CSV's own buffer held.
    eprintln!("csv rows {rows}, /cables messages read {cables}");
    assert!(cables > 1000, "{cables}");
    assert!(cables + 1000 >= rows, "lost more than the last chunk: {cables} of {rows}");
    assert!(cables <= rows + 1000);

    let e = Recording::load(&mcap).unwrap_err().to_string();
    assert!(e.contains(mcap.to_str().unwrap()) && e.contains("stopped before it finished"), "{e}");
}
