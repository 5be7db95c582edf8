//! Where calib's play pattern misreads the simulator's play (issue 14, branch eatail): EA 15 kN
//! under a 10 mm play on the 4-cable robot, as `ea_backlash_coverage`. For each seed, the play
//! pattern the diagnosis detects from the readings ([`PlayState::of_readings`]) is compared with
//! the simulator's own play run over its true drum lengths: the error of the play model's
//! noise-free prediction `drum(c) - side w/2` (true drum lengths and play, the detected contact
//! `c` and side) against the simulator's noise-free play output, split by detected pushed
//! (`c == i`) and held readings, and by whether the simulator's play was pushing there.
//! Readings with the cable loose between the contact and the reading are left out.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example ea_play_misfit -- [first seed, default 44] [seeds, default 1] [play mm, default 10]
//! ```

use taut_calib::diagnose::fit::PlayState;
use taut_sim::{simulate, Physics, Scenario};

#[derive(Default)]
struct Tally {
    n: usize,
    ss: f64,
    sum: f64,
    big: usize,
}

impl Tally {
    fn add(&mut self, e: f64) {
        self.n += 1;
        self.ss += e * e;
        self.sum += e;
        if e.abs() > 1e-4 {
            self.big += 1;
        }
    }
    fn line(&self, name: &str) -> String {
        let n = self.n.max(1) as f64;
        format!(
            "{name}: {} readings, error RMS {:.3} mm, mean {:+.3} mm, beyond 0.1 mm {}",
            self.n,
            (self.ss / n).sqrt() * 1e3,
            self.sum / n * 1e3,
            self.big
        )
    }
}

fn main() {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<u64>().expect("a number"));
    let first = args.next().unwrap_or(44);
    let count = args.next().unwrap_or(1);
    let play_m = args.next().unwrap_or(10) as f64 * 1e-3;
    let h = 0.5 * play_m;
    for seed in first..first + count {
        let mut s = Scenario::aras_cam(seed);
        s.physics = Physics { elasticity: Some(15_000.0), backlash_m: play_m, ..Physics::default() };
        s.duration_s = 40.0;
        let sim = simulate(&s);
        let rec = &sim.recording;
        let n = rec.n_cables;
        let m = rec.len();
        let l: Vec<Vec<f64>> = (0..n).map(|j| (0..m).map(|i| rec.l[i * n + j]).collect()).collect();
        let det = PlayState::of_readings(&l, s.noise.encoder_sigma_m);
        // (detected pushed?, truly pushed?)
        let mut t = [[Tally::default(), Tally::default()], [Tally::default(), Tally::default()]];
        let mut worst: Vec<(f64, usize, usize, usize, bool, bool)> = vec![];
        // Detected held, truly held: by the detected contact minus the true one.
        let mut by_lag: std::collections::BTreeMap<i64, Tally> = Default::default();
        for j in 0..n {
            // The simulator's play over its true drum lengths (sensors::Backlash).
            let mut y: Option<f64> = None;
            let mut last_loose: Option<usize> = None;
            let mut true_c = 0usize;
            for i in 0..m {
                let x = sim.drum_lengths[i * n + j];
                let yi = match y {
                    None => x,
                    Some(v) => v.clamp(x - h, x + h),
                };
                let truly_pushed = y.is_none_or(|v| (yi - v).abs() > 0.0);
                y = Some(yi);
                if truly_pushed {
                    true_c = i;
                }
                if sim.loose[i * n + j] {
                    last_loose = Some(i);
                }
                let loose_since = last_loose.map_or(0, |k| k + 1);
                let c = det.contact[j][i] as usize;
                let side = f64::from(det.side[j][i]);
                if side == 0.0 || sim.loose[i * n + j] || loose_since > c {
                    continue;
                }
                let pred = sim.drum_lengths[c * n + j] - side * h;
                let e = yi - pred;
                let dp = c == i;
                t[usize::from(dp)][usize::from(truly_pushed)].add(e);
                if !dp && !truly_pushed {
                    by_lag.entry((c as i64 - true_c as i64).clamp(-5, 5)).or_default().add(e);
                }
                worst.push((e, j, i, i - c, dp, truly_pushed));
            }
        }
        println!("seed {seed}:");
        for (dp, name) in [(1, "detected pushed"), (0, "detected held")] {
            for (tp, tn) in [(1, "truly pushed"), (0, "truly held")] {
                println!("  {}", t[dp][tp].line(&format!("{name}, {tn}")));
            }
        }
        for (k, v) in &by_lag {
            println!("  {}", v.line(&format!("detected held, truly held, detected contact {k:+} samples from the true one")));
        }
        worst.sort_by(|a, b| b.0.abs().total_cmp(&a.0.abs()));
        if std::env::var("MISFIT_CONTEXT").is_ok() {
            for w in worst.iter().take(3) {
                let (j, i) = (w.1, w.2);
                #[allow(clippy::needless_range_loop)] // k indexes four series
                for k in i.saturating_sub(6)..(i + 4).min(m) {
                    println!(
                        "    cable {j} sample {k}: reading {:.4} drum {:.4} tension {:.1} loose {} contact {} side {}",
                        l[j][k] * 1e3,
                        sim.drum_lengths[k * n + j] * 1e3,
                        sim.tensions[k * n + j],
                        sim.loose[k * n + j],
                        det.contact[j][k],
                        det.side[j][k]
                    );
                }
            }
        }
        for w in worst.iter().take(8) {
            println!(
                "  worst: {:+.3} mm cable {} sample {} ({} after its contact) detected {} truly {}",
                w.0 * 1e3,
                w.1,
                w.2,
                w.3,
                if w.4 { "pushed" } else { "held" },
                if w.5 { "pushed" } else { "held" }
            );
        }
    }
}
