//! How old the tension readings of the simulated load cells get, seen from a loop at 500 Hz:
//! the virtual Modbus RTU server on a pty and the driver's load-cell I/O thread, as in the
//! simulated rig. Run it on a loaded machine to see what the real-time loop's staleness limit
//! meets. `[FIFO=server|both] cargo run -p taut-simrig --example loadcell_ages -- SECONDS [CELLS]`
use std::time::{Duration, Instant};
use taut_proto::devices::{LoadCellBusConfig, LoadCellConfig};
use taut_vdev::{TensionHandle, VirtualLoadCells};

fn main() {
    let mut args = std::env::args().skip(1);
    let secs: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(20.0);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(4);
    let cells: Vec<LoadCellConfig> = (0..n).map(|j| LoadCellConfig::new(j as u8 + 1)).collect();
    let tensions = TensionHandle::new(n);
    let server = VirtualLoadCells::spawn(cells.clone(), tensions).expect("virtual load cells");
    let mut bus = LoadCellBusConfig::new(server.path().display().to_string());
    bus.max_age_s = 10.0;
    let pairs: Vec<(usize, LoadCellConfig)> = cells.into_iter().enumerate().collect();
    let (io, mut reader) = taut_driver::loadcell::spawn(&bus, &pairs, n).expect("load-cell bus");
    match std::env::var("FIFO").as_deref() {
        // The cells stand in for hardware with its own processor: the simulated rig runs their
        // server real-time always, the robot's I/O thread only with a real-time loop.
        Ok("server") => server.set_realtime(2).expect("SCHED_FIFO"),
        Ok(_) => server.set_realtime(2).and_then(|_| io.set_realtime(1)).expect("SCHED_FIFO"),
        Err(_) => {}
    }
    // Warm-up: the loop reads from the start, so the ring never fills.
    let warm = Instant::now();
    while warm.elapsed() < Duration::from_millis(500) {
        reader.update();
        std::thread::sleep(Duration::from_millis(2));
    }
    let t0 = Instant::now();
    let period = Duration::from_millis(2);
    let mut next = t0;
    let mut worst = 0.0f64;
    let mut worst_gap = 0.0f64;
    let (mut over50, mut over100, mut cycles) = (0u64, 0u64, 0u64);
    let mut last = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
        let now = Instant::now();
        worst_gap = worst_gap.max(now.duration_since(last).as_secs_f64());
        last = now;
        reader.update();
        let age = (0..n)
            .map(|j| reader.latest(j).map_or(f64::INFINITY, |(_, at)| now.saturating_duration_since(at).as_secs_f64()))
            .fold(0.0, f64::max);
        worst = worst.max(age);
        over50 += u64::from(age > 0.05);
        over100 += u64::from(age > 0.1);
        cycles += 1;
    }
    let c = io.counters();
    println!(
        "{cycles} cycles: worst age {:.1} ms, cycles with an age > 50 ms: {over50}, > 100 ms: {over100}; longest loop gap {:.1} ms; {c:?}; server {:?}",
        worst * 1e3,
        worst_gap * 1e3,
        server.stats()
    );
}
