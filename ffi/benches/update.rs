//! `update` through the C ABI beside the direct Rust call (figures for BENCHMARKS.md).
//!
//! Two plugins in host-owned mode, each driving its own simulated robot (aras-cam-sim.toml, 4
//! cables, 500 Hz) from cold through enabling and the three initialisation phases: one called
//! through `taut_update` (`#[repr(C)]` structs in and out, the busy flag, `catch_unwind`, the
//! conversion to the plugin's host structs), the other through `Plugin::update_with` directly.
//! Only the update call is timed; the simulator's physics runs between calls.
//!
//! 1. per-call latency of every cycle into a histogram: p50 / p99 / max for both, one run;
//! 2. criterion's mean of the same call (`iter_custom`, the simulator stepped outside the timing).
//!
//! `cargo bench -p taut-ffi --features sim --bench update`

use criterion::{criterion_group, criterion_main, Criterion};
use std::ffi::CString;
use std::time::{Duration, Instant};
use taut::sim::*;
use taut::*;
use taut_plugin::HostOutputs;

const CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");
const PERIOD: f64 = 0.002;

/// A plugin and its simulated robot.
struct Rig {
    h: *mut TautPlugin,
    sim: *mut TautSim,
    k: u64,
    inp: TautInputs,
    cmd: TautCommands,
    _dir: tempfile::TempDir,
}

impl Rig {
    fn new() -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let cfg = CString::new(CONFIG).unwrap();
        let data = CString::new(dir.path().to_str().unwrap()).unwrap();
        let (mut h, mut sim) = (std::ptr::null_mut(), std::ptr::null_mut());
        unsafe {
            let mut o = std::mem::zeroed::<TautOptions>();
            taut_options_init(&mut o);
            o.data_dir = data.as_ptr();
            assert_eq!(taut_sim_new(cfg.as_ptr(), 2, &mut sim), TautError::Ok);
            assert_eq!(taut_configure(cfg.as_ptr(), TAUT_CONFIG_PATH, &o, &mut h), TautError::Ok);
            assert_eq!(taut_activate(h), TautError::Ok);
        }
        Rig { h, sim, k: 0, inp: TautInputs::default(), cmd: TautCommands::default(), _dir: dir }
    }

    /// One cycle; returns the time spent in the update call.
    fn cycle(&mut self, via_c: bool) -> Duration {
        let now = self.k as f64 * PERIOD;
        self.k += 1;
        unsafe { taut_sim_read(self.sim, now, &mut self.inp) };
        let d = if via_c {
            let t0 = Instant::now();
            let r = unsafe { taut_update(self.h, now, PERIOD, &self.inp, &mut self.cmd) };
            let d = t0.elapsed();
            assert_eq!(r, TautError::Ok);
            d
        } else {
            let hi = taut::host_inputs(&self.inp);
            let mut out = HostOutputs::default();
            let p = unsafe { &mut *self.h };
            let t0 = Instant::now();
            let t = rust_update(p, now, PERIOD, &hi, &mut out);
            let d = t0.elapsed();
            let t = t.expect("update_with");
            self.cmd = TautCommands {
                n_cables: u32::from(out.n_cables),
                setpoint: out.setpoint,
                mode: out.mode,
                request: out.request,
                faulted: t.faulted as u8,
                ..TautCommands::default()
            };
            d
        };
        assert_eq!(self.cmd.faulted, 0, "a safety reaction at t = {now:.3} s");
        unsafe { taut_sim_write(self.sim, now, PERIOD, &self.cmd) };
        d
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        unsafe {
            taut_cleanup(self.h);
            taut_sim_free(self.sim);
        }
    }
}

fn pct(v: &mut [u64], p: f64) -> f64 {
    v.sort_unstable();
    v[((v.len() as f64 - 1.0) * p).round() as usize] as f64 * 1e-3
}

/// Both rigs cycled alternately (same machine load for both), `cycles` each.
fn histogram(cycles: usize) {
    let (mut c, mut r) = (Rig::new(), Rig::new());
    let (mut tc, mut tr) = (Vec::with_capacity(cycles), Vec::with_capacity(cycles));
    for _ in 0..cycles {
        tc.push(c.cycle(true).as_nanos() as u64);
        tr.push(r.cycle(false).as_nanos() as u64);
    }
    for (name, v) in [("C ABI taut_update  ", &mut tc), ("Rust update_with   ", &mut tr)] {
        let (p50, p99, max) = (pct(v, 0.5), pct(v, 0.99), pct(v, 1.0));
        println!("{name} {cycles} cycles from cold (enabling, init phases): p50 {p50:.2} us  p99 {p99:.2} us  max {max:.1} us");
    }
}

fn bench(cr: &mut Criterion) {
    histogram(std::env::var("TAUT_FFI_CYCLES").ok().and_then(|s| s.parse().ok()).unwrap_or(20_000));
    let mut g = cr.benchmark_group("plugin_update");
    for (name, via_c) in [("c_abi", true), ("rust", false)] {
        let mut rig = Rig::new();
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    total += rig.cycle(via_c);
                }
                total
            })
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    targets = bench
}
criterion_main!(benches);
