//! Latency of `estop` over the control socket with hostile clients connected:
//! 200 idle clients, 20 slow ones (a byte per 100 ms each) and 20 garbage senders (1 KiB of
//! random bytes every 10 ms each), every one reconnecting as soon as the server closes it. A
//! second run replaces the garbage senders by 4 clients that flood random bytes flat out.
//!
//! Measured per estop, from a fresh client: connect, send `estop\n`, read the reply (the
//! latency an operator sees), and the time until a loop-side thread polling the flag every
//! 1 ms took it (what the loop sees, its 1 ms period included). Prints p50/p99/max.
//! A custom harness (`harness = false`): `cargo bench -p taut-operator --bench ctl_estop`.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use taut_calibrator::vocab::CalibStatus;
use taut_io::testkit::quick_config;
use taut_io::FromRobot;
use taut_operator::control::{ControlLinks, ControlServer, ServerLimits};
use taut_rt::cycle::LoopStatus;
use taut_rt::io::Inputs;
use taut_rt::kin::LoopParams;
use taut_rt::motion::{Controller, ControllerConfig};
use taut_rt::triple::triple_buffer;
use taut_rt::urgent::Urgent;

const ESTOPS: usize = 1000;

struct Hostile {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
    reconnects: Arc<AtomicU64>,
}

impl Drop for Hostile {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn connect_nb(sock: &Path) -> Option<UnixStream> {
    let s = UnixStream::connect(sock).ok()?;
    s.set_nonblocking(true).ok()?;
    Some(s)
}

/// True if the server has closed `s` (EOF or an error); drains what it sent.
fn closed(s: &mut UnixStream) -> bool {
    let mut buf = [0u8; 4096];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return false,
            Err(_) => return true,
        }
    }
}

/// `n` clients on one thread, each doing `act` every `every`; a closed one reconnects.
fn clients(
    sock: &Path,
    n: usize,
    every: Duration,
    stop: &Arc<AtomicBool>,
    reconnects: &Arc<AtomicU64>,
    act: fn(&mut UnixStream, &mut u64) -> bool,
) -> std::thread::JoinHandle<()> {
    let (sock, stop, reconnects) = (sock.to_path_buf(), stop.clone(), reconnects.clone());
    std::thread::spawn(move || {
        let mut conns: Vec<Option<UnixStream>> = (0..n).map(|_| connect_nb(&sock)).collect();
        let mut rng = 0x2545_F491_4F6C_DD1Du64;
        while !stop.load(Ordering::Relaxed) {
            for c in conns.iter_mut() {
                let alive = match c {
                    Some(s) => !closed(s) && act(s, &mut rng),
                    None => false,
                };
                if !alive {
                    *c = connect_nb(&sock);
                    reconnects.fetch_add(1, Ordering::Relaxed);
                }
            }
            std::thread::sleep(every);
        }
    })
}

fn idle(_: &mut UnixStream, _: &mut u64) -> bool {
    true
}

fn slow(s: &mut UnixStream, _: &mut u64) -> bool {
    // Never a line end: the request is never complete.
    !matches!(s.write(b"s"), Err(ref e) if e.kind() != std::io::ErrorKind::WouldBlock)
}

fn garbage(s: &mut UnixStream, x: &mut u64) -> bool {
    let mut buf = [0u8; 1024];
    for b in buf.iter_mut() {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        *b = *x as u8;
    }
    !matches!(s.write(&buf), Err(ref e) if e.kind() != std::io::ErrorKind::WouldBlock)
}

fn flood(sock: &Path, stop: &Arc<AtomicBool>, seed: u64) -> std::thread::JoinHandle<()> {
    let (sock, stop) = (sock.to_path_buf(), stop.clone());
    std::thread::spawn(move || {
        let mut x = seed | 1;
        while !stop.load(Ordering::Relaxed) {
            let Ok(mut s) = UnixStream::connect(&sock) else {
                continue;
            };
            let _ = s.set_write_timeout(Some(Duration::from_millis(100)));
            while !stop.load(Ordering::Relaxed) && garbage(&mut s, &mut x) {}
        }
    })
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn run(name: &str, sock: &Path, urgent: &Arc<Urgent>, hostile: &Hostile) {
    // Let the hostile clients settle in (and the idle ones cycle through a deadline once).
    std::thread::sleep(Duration::from_millis(2500));
    // The loop side: takes the flag at 1 kHz and notes when.
    let taken_at = Arc::new(Mutex::new(None::<Instant>));
    let done = Arc::new(AtomicBool::new(false));
    let poller = {
        let (u, t, d) = (urgent.clone(), taken_at.clone(), done.clone());
        std::thread::spawn(move || {
            while !d.load(Ordering::Relaxed) {
                if u.take_estop() {
                    *t.lock().unwrap() = Some(Instant::now());
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        })
    };
    let mut reply_ms = Vec::with_capacity(ESTOPS);
    let mut loop_ms = Vec::with_capacity(ESTOPS);
    for _ in 0..ESTOPS {
        *taken_at.lock().unwrap() = None;
        let t0 = Instant::now();
        let mut s = UnixStream::connect(sock).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        s.write_all(b"estop\n").unwrap();
        let mut line = String::new();
        BufReader::new(&s).read_line(&mut line).unwrap();
        let t1 = Instant::now();
        assert!(line.contains("\"accepted\":\"estop\""), "{line}");
        reply_ms.push((t1 - t0).as_secs_f64() * 1e3);
        let t_wait = Instant::now();
        let taken = loop {
            if let Some(t) = *taken_at.lock().unwrap() {
                break t;
            }
            assert!(t_wait.elapsed() < Duration::from_secs(5), "the loop side never took the estop");
            std::thread::sleep(Duration::from_micros(200));
        };
        loop_ms.push((taken - t0).as_secs_f64() * 1e3);
        std::thread::sleep(Duration::from_millis(5));
    }
    done.store(true, Ordering::Relaxed);
    poller.join().unwrap();
    println!(
        "{name}: {ESTOPS} estops; reply p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms; taken by a 1 kHz loop p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms; hostile reconnects {}",
        pct(&mut reply_ms, 0.5),
        pct(&mut reply_ms, 0.99),
        pct(&mut reply_ms, 1.0),
        pct(&mut loop_ms, 0.5),
        pct(&mut loop_ms, 0.99),
        pct(&mut loop_ms, 1.0),
        hostile.reconnects.load(Ordering::Relaxed),
    );
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` passes nothing we need: run quickly.
    let dir: PathBuf = std::env::temp_dir().join(format!("taut-ctl-estop-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = quick_config(4, &dir);
    let ccfg = ControllerConfig::from_robot(&cfg).unwrap();
    let (cmd_tx, cmd_rx) = crossbeam_channel::bounded(64);
    let (_ptx, prx) = triple_buffer(LoopParams::invalid(4));
    let controller = Controller::new(ccfg, move || cmd_rx.try_recv().ok(), prx);
    let init = LoopStatus::initial(controller.snapshot(0.0, &Inputs::new(4)));
    let (_stx, srx) = triple_buffer(init);
    let urgent = Arc::new(Urgent::default());
    let links = ControlLinks {
        commands: cmd_tx,
        urgent: urgent.clone(),
        loop_status: Arc::new(Mutex::new(srx)),
        calib: Arc::new(Mutex::new(CalibStatus::default())),
        workspace: ccfg.workspace,
        tracker: None,
        operator: Default::default(),
    };
    let sock = dir.join("taut.sock");
    let server = ControlServer::bind(&sock, links, ServerLimits::default()).unwrap();
    let quit = Arc::new(AtomicBool::new(false));
    let q = quit.clone();
    let server_thread = std::thread::spawn(move || server.run(q));
    println!(
        "ctl_estop: {} CPUs; server limits {:?}",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        ServerLimits::default()
    );

    {
        let stop = Arc::new(AtomicBool::new(false));
        let reconnects = Arc::new(AtomicU64::new(0));
        let threads = vec![
            clients(&sock, 200, Duration::from_millis(50), &stop, &reconnects, idle),
            clients(&sock, 20, Duration::from_millis(100), &stop, &reconnects, slow),
            clients(&sock, 20, Duration::from_millis(10), &stop, &reconnects, garbage),
        ];
        let h = Hostile { stop, threads, reconnects };
        run("200 idle + 20 slow + 20 garbage", &sock, &urgent, &h);
    }
    {
        let stop = Arc::new(AtomicBool::new(false));
        let reconnects = Arc::new(AtomicU64::new(0));
        let mut threads = vec![
            clients(&sock, 200, Duration::from_millis(50), &stop, &reconnects, idle),
            clients(&sock, 20, Duration::from_millis(100), &stop, &reconnects, slow),
        ];
        threads.extend((0..4).map(|k| flood(&sock, &stop, 0x9E37_79B9 * (k + 1))));
        let h = Hostile { stop, threads, reconnects };
        run("200 idle + 20 slow + 4 flat-out garbage floods", &sock, &urgent, &h);
    }
    quit.store(true, Ordering::Relaxed);
    server_thread.join().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
