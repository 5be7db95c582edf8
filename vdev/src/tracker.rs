//! A simulated position tracker: sends pose datagrams in the tracker line format
//! (`t px py pz [qw qx qy qz]`, see `taut_proto::tracker`) over UDP, normally to loopback.
//!
//! ```no_run
//! use taut_vdev::TrackerSender;
//! let tx = TrackerSender::new("127.0.0.1:5005".parse().unwrap()).unwrap();
//! tx.send_pose(0.01, [0.0, 0.0, 1.5], Some([1.0, 0.0, 0.0, 0.0])).unwrap();
//! ```

use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_proto::tracker::{format_line, PoseLine, MAX_LINE};

/// Sends pose lines to one address.
#[derive(Debug)]
pub struct TrackerSender {
    socket: UdpSocket,
    target: SocketAddr,
}

impl TrackerSender {
    /// A sender to `target`, from an ephemeral port on the matching loopback address.
    pub fn new(target: SocketAddr) -> io::Result<TrackerSender> {
        let local: SocketAddr = if target.is_ipv4() { "127.0.0.1:0" } else { "[::1]:0" }.parse().map_err(io::Error::other)?;
        Ok(TrackerSender { socket: UdpSocket::bind(local)?, target })
    }

    /// Sends one pose.
    pub fn send_pose(&self, t: f64, position: [f64; 3], orientation: Option<[f64; 4]>) -> io::Result<()> {
        let mut buf = [0u8; MAX_LINE];
        let n = format_line(&PoseLine { t, position, orientation }, &mut buf);
        self.send_raw(&buf[..n])
    }

    /// Sends arbitrary bytes as one datagram (for malformed-input tests).
    pub fn send_raw(&self, bytes: &[u8]) -> io::Result<()> {
        self.socket.send_to(bytes, self.target).map(|_| ())
    }
}

/// A sender thread streaming poses at a fixed rate; stops on drop.
pub struct TrackerStream {
    stop: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl TrackerStream {
    /// Streams `pose(t)` to `target` every `period`; the tracker clock `t` starts at `t0` s.
    pub fn spawn<F>(target: SocketAddr, period: Duration, t0: f64, mut pose: F) -> io::Result<TrackerStream>
    where
        F: FnMut(f64) -> ([f64; 3], Option<[f64; 4]>) + Send + 'static,
    {
        let tx = TrackerSender::new(target)?;
        let stop = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(AtomicU64::new(0));
        let (stop2, sent2) = (stop.clone(), sent.clone());
        let thread = std::thread::Builder::new().name("taut-sim-tracker".into()).spawn(move || {
            let start = Instant::now();
            let mut k = 0u32;
            while !stop2.load(Ordering::Relaxed) {
                let t = t0 + (period * k).as_secs_f64();
                let (p, q) = pose(t - t0);
                if tx.send_pose(t, p, q).is_ok() {
                    sent2.fetch_add(1, Ordering::Relaxed);
                }
                k += 1;
                let next = start + period * k;
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
        })?;
        Ok(TrackerStream { stop, sent, thread: Some(thread) })
    }

    /// Datagrams sent so far.
    pub fn sent(&self) -> u64 {
        self.sent.load(Ordering::Relaxed)
    }
}

impl Drop for TrackerStream {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
